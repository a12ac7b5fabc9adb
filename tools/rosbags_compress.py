#!/usr/bin/env python3
"""Writes a bag with compressed images as a ROS user records one, independently of sweepdepth.

    python3 tools/rosbags_compress.py IN OUT

Reads the raw bag IN with rosbags and writes the rosbag2 directory OUT (storage mcap, Jazzy's
default) with rosbags' writer: every `sensor_msgs/msg/Image` on `<topic>` becomes a
`sensor_msgs/msg/CompressedImage` on `<topic>/compressed`, encoded as image_transport's
`compressed` plugin does (OpenCV's `imencode`, JPEG quality 95; colour images converted to BGR
first and the format written as `<encoding>; jpeg compressed bgr8`, mono8 as
`mono8; jpeg compressed mono8`); every other message (camera_info, /tf_static) is copied as it
is, with the same receive times. Prints one line per compressed topic. Used by
tests/bags/bag_compressed.rs (rosbags 0.11.9, opencv-python-headless of requirements-test.txt).
"""
import sys
from pathlib import Path

import cv2
import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
JPEG_QUALITY = 95


def encode(msg):
    """(format, JPEG bytes) of a sensor_msgs/Image, as image_transport's compressed plugin."""
    height, width, enc = msg.height, msg.width, msg.encoding
    data = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    if enc == "mono8":
        pixels, target = data.reshape(height, msg.step)[:, :width], "mono8"
    elif enc in ("rgb8", "bgr8"):
        pixels = data.reshape(height, msg.step)[:, : width * 3].reshape(height, width, 3)
        if enc == "rgb8":
            pixels = cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR)
        target = "bgr8"
    else:
        raise SystemExit(f"rosbags_compress.py: encoding {enc} not handled")
    ok, jpeg = cv2.imencode(".jpg", np.ascontiguousarray(pixels),
                            [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise SystemExit("rosbags_compress.py: imencode failed")
    return f"{enc}; jpeg compressed {target}", jpeg.tobytes()


def main() -> None:
    src, dst = Path(sys.argv[1]), Path(sys.argv[2])
    store = get_typestore(Stores.ROS2_HUMBLE)
    Compressed = store.types[COMPRESSED]
    with AnyReader([src], default_typestore=store) as reader:
        with Writer(dst, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
            conns = {}
            for conn in reader.connections:
                if conn.msgtype == IMAGE:
                    topic = conn.topic + "/compressed"
                    conns[conn.id] = writer.add_connection(topic, COMPRESSED, typestore=store)
                    print(topic)
                else:
                    conns[conn.id] = writer.add_connection(conn.topic, conn.msgtype,
                                                           typestore=store)
            for conn, timestamp, raw in reader.messages():
                if conn.msgtype == IMAGE:
                    msg = reader.deserialize(raw, conn.msgtype)
                    fmt, jpeg = encode(msg)
                    out = Compressed(header=msg.header, format=fmt,
                                     data=np.frombuffer(jpeg, dtype=np.uint8))
                    raw = store.serialize_cdr(out, COMPRESSED)
                writer.write(conns[conn.id], timestamp, raw)


if __name__ == "__main__":
    main()
