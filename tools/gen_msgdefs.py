#!/usr/bin/env python3
"""Writes msg/schemas/*.msgdef: the full ROS 2 message definitions (with their dependencies, in
the concatenated form rosbag2 stores in MCAP schema records) of the message types sweepdepth
reads and writes in bags.

Generated with rosbags 0.11.9 (https://gitlab.com/ternaris/rosbags, typestores ROS2_HUMBLE, and ROS2_JAZZY for JAZZY_TYPES):

    python3 -m venv /tmp/venv && /tmp/venv/bin/pip install rosbags==0.11.9
    /tmp/venv/bin/python tools/gen_msgdefs.py
"""
from pathlib import Path

from rosbags.typesys import Stores, get_typestore

TYPES = [
    "sensor_msgs/msg/Image",
    "sensor_msgs/msg/CompressedImage",
    "sensor_msgs/msg/CameraInfo",
    "sensor_msgs/msg/PointCloud2",
    "tf2_msgs/msg/TFMessage",
    "diagnostic_msgs/msg/DiagnosticArray",
]
# Types whose definition changed after Humble, written as Jazzy has them (the wire layout
# the node speaks: visualization_msgs/Marker gained texture, uv_coordinates and mesh_file).
JAZZY_TYPES = [
    "visualization_msgs/msg/MarkerArray",
]

out = Path(__file__).resolve().parent.parent / "msg" / "schemas"
out.mkdir(parents=True, exist_ok=True)
humble = get_typestore(Stores.ROS2_HUMBLE)
jazzy = get_typestore(Stores.ROS2_JAZZY)
for store, name in [(humble, t) for t in TYPES] + [(jazzy, t) for t in JAZZY_TYPES]:
    text, _ = store.generate_msgdef(name, ros_version=2)
    (out / (name.replace("/", "__") + ".msgdef")).write_text(text)
    print("wrote", name)
