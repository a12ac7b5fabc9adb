#!/usr/bin/env python3
"""Writes msg/schemas/*.msgdef: the full ROS 2 message definitions (with their dependencies, in
the concatenated form rosbag2 stores in MCAP schema records) of the message types sweepdepth
reads and writes in bags.

Generated with rosbags 0.11.9 (https://gitlab.com/ternaris/rosbags, typestore ROS2_HUMBLE):

    python3 -m venv /tmp/venv && /tmp/venv/bin/pip install rosbags==0.11.9
    /tmp/venv/bin/python tools/gen_msgdefs.py
"""
from pathlib import Path

from rosbags.typesys import Stores, get_typestore

TYPES = [
    "sensor_msgs/msg/Image",
    "sensor_msgs/msg/CameraInfo",
    "sensor_msgs/msg/PointCloud2",
    "tf2_msgs/msg/TFMessage",
    "diagnostic_msgs/msg/DiagnosticArray",
]

out = Path(__file__).resolve().parent.parent / "msg" / "schemas"
out.mkdir(parents=True, exist_ok=True)
store = get_typestore(Stores.ROS2_HUMBLE)
for name in TYPES:
    text, _ = store.generate_msgdef(name, ros_version=2)
    (out / (name.replace("/", "__") + ".msgdef")).write_text(text)
    print("wrote", name)
