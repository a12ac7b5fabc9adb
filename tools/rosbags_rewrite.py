#!/usr/bin/env python3
"""Rewrites a bag with rosbags' own writer, as an independent producer of test bags.

    python3 tools/rosbags_rewrite.py IN OUTDIR

Writes three rosbag2 directories under OUTDIR, each with every connection and message of IN
(same topics, types, CDR bytes and receive times):
  OUTDIR/mcap          storage mcap
  OUTDIR/sqlite3       storage sqlite3 (Humble's default)
  OUTDIR/sqlite3_zstd  storage sqlite3, zstd compression per message
  OUTDIR/sqlite3_zstd_file  storage sqlite3, the whole file zstd-compressed
Used by tests/bags/bag.rs (rosbags 0.11.9).
"""
import sys
from pathlib import Path

from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore


def rewrite(src: Path, dst: Path, plugin: StoragePlugin, compress: CompressionMode | None) -> None:
    store = get_typestore(Stores.ROS2_HUMBLE)
    with AnyReader([src], default_typestore=store) as reader:
        writer = Writer(dst, version=8, storage_plugin=plugin)
        if compress is not None:
            writer.set_compression(compress, CompressionFormat.ZSTD)
        with writer:
            conns = {}
            for conn in reader.connections:
                conns[conn.id] = writer.add_connection(conn.topic, conn.msgtype, typestore=store)
            for conn, timestamp, raw in reader.messages():
                writer.write(conns[conn.id], timestamp, raw)


def main() -> None:
    src, out = Path(sys.argv[1]), Path(sys.argv[2])
    out.mkdir(parents=True, exist_ok=True)
    rewrite(src, out / "mcap", StoragePlugin.MCAP, None)
    rewrite(src, out / "sqlite3", StoragePlugin.SQLITE3, None)
    rewrite(src, out / "sqlite3_zstd", StoragePlugin.SQLITE3, CompressionMode.MESSAGE)
    rewrite(src, out / "sqlite3_zstd_file", StoragePlugin.SQLITE3, CompressionMode.FILE)


if __name__ == "__main__":
    main()
