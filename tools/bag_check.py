#!/usr/bin/env python3
"""Reads a bag with two independent readers and prints what it holds as one JSON line.

    python3 tools/bag_check.py BAG        # a .mcap file or a rosbag2 directory

- rosbags (AnyReader, typestore ROS2_HUMBLE) deserialises every message; per topic: type,
  count, and for images encoding / size / frame ids / stamps (and for 32FC1 the NaN share and
  median), for CameraInfo size and K.
- mcap (the reference reader of the MCAP format) lists the channels, schema names and message
  encodings of every MCAP file, and counts the messages.
Used by tests/bags/bag.rs; exits non-zero if either reader fails.
"""
import json
import math
import sys
from pathlib import Path

from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore


def main() -> None:
    path = Path(sys.argv[1])
    store = get_typestore(Stores.ROS2_HUMBLE)
    topics = {}
    with AnyReader([path], default_typestore=store) as reader:
        for conn in reader.connections:
            topics[conn.topic] = {"type": conn.msgtype, "count": 0, "stamps": [], "frames": []}
        for conn, _t, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            entry = topics[conn.topic]
            entry["count"] += 1
            header = getattr(msg, "header", None)
            if header is not None:
                entry["stamps"].append([header.stamp.sec, header.stamp.nanosec])
                entry["frames"].append(header.frame_id)
            if conn.msgtype == "sensor_msgs/msg/Image":
                entry["encoding"] = msg.encoding
                entry["width"], entry["height"], entry["step"] = msg.width, msg.height, msg.step
                entry["data_len"] = len(msg.data)
                if msg.encoding == "32FC1":
                    import numpy as np

                    values = np.frombuffer(bytes(msg.data), dtype="<f4")
                    finite = values[np.isfinite(values)]
                    entry["nan_share"] = float(1.0 - finite.size / max(values.size, 1))
                    entry["median"] = float(np.median(finite)) if finite.size else math.nan
            elif conn.msgtype == "sensor_msgs/msg/CameraInfo":
                entry["width"], entry["height"] = msg.width, msg.height
                entry["k"] = [float(v) for v in msg.k]
    files = [path] if path.is_file() else sorted(path.glob("*.mcap"))
    channels = {}
    for f in files:
        with open(f, "rb") as fh:
            r = make_reader(fh)
            summary = r.get_summary()
            for ch in summary.channels.values():
                schema = summary.schemas.get(ch.schema_id)
                channels[ch.topic] = {
                    "schema": schema.name if schema else "",
                    "schema_encoding": schema.encoding if schema else "",
                    "message_encoding": ch.message_encoding,
                    "count": 0,
                }
            for _schema, channel, _message in r.iter_messages():
                channels[channel.topic]["count"] += 1
    print(json.dumps({"rosbags": topics, "mcap": channels}))


if __name__ == "__main__":
    main()
