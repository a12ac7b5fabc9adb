#!/usr/bin/env python3
"""Generate CDR oracle fixtures for `tests/formats/msgs_cdr.rs`.

Each message below is serialised with rosbags' pure-Python ROS 2 Humble typestore and written
to `tests/fixtures/cdr/<name>.bin` as the full serialized payload (4-byte encapsulation header
`00 01 00 00` + little-endian CDR body), i.e. exactly what appears on the wire and in
rosbag2 / MCAP.  The Rust test builds the same values by hand, so any change here must be
mirrored in `tests/formats/msgs_cdr.rs`.

Usage (from the crate root):

    python3 -m venv /tmp/rbvenv && /tmp/rbvenv/bin/pip install rosbags
    /tmp/rbvenv/bin/python tools/gen_cdr_fixtures.py
"""

from __future__ import annotations

import pathlib
from importlib.metadata import version

import numpy as np
from rosbags.typesys import Stores, get_typestore

OUT = pathlib.Path(__file__).resolve().parent.parent / "tests" / "fixtures" / "cdr"

ts = get_typestore(Stores.ROS2_HUMBLE)
T = ts.types

Time = T["builtin_interfaces/msg/Time"]
Header = T["std_msgs/msg/Header"]
Image = T["sensor_msgs/msg/Image"]
CameraInfo = T["sensor_msgs/msg/CameraInfo"]
RegionOfInterest = T["sensor_msgs/msg/RegionOfInterest"]
PointCloud2 = T["sensor_msgs/msg/PointCloud2"]
PointField = T["sensor_msgs/msg/PointField"]
Vector3 = T["geometry_msgs/msg/Vector3"]
Quaternion = T["geometry_msgs/msg/Quaternion"]
Transform = T["geometry_msgs/msg/Transform"]
TransformStamped = T["geometry_msgs/msg/TransformStamped"]
TFMessage = T["tf2_msgs/msg/TFMessage"]
KeyValue = T["diagnostic_msgs/msg/KeyValue"]
DiagnosticStatus = T["diagnostic_msgs/msg/DiagnosticStatus"]
DiagnosticArray = T["diagnostic_msgs/msg/DiagnosticArray"]


def header(sec: int, nanosec: int, frame_id: str):
    return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id)


def transform_stamped(i: int):
    return TransformStamped(
        header=header(1_700_000_000 + i, 250_000_000 * i + 7, "world"),
        child_frame_id=f"cam{i}_optical",  # 12 bytes + NUL -> 13, odd
        transform=Transform(
            translation=Vector3(x=0.5 * i, y=-1.25, z=3.0 + i),
            rotation=Quaternion(x=0.0, y=0.5, z=-0.5, w=0.7071067811865476),
        ),
    )


def status(i: int, level: int):
    return DiagnosticStatus(
        level=level,
        name=f"sweepdepth: cam{i}",
        message="ok" if level == 0 else "late frame",
        hardware_id="gpu0",
        values=[
            KeyValue(key="fps", value=f"{29.5 + i}"),
            KeyValue(key="dropped", value=str(3 * i + 1)),
        ],
    )


MESSAGES = {
    "time": (
        "builtin_interfaces/msg/Time",
        Time(sec=-2, nanosec=999_999_999),
    ),
    "header": (
        "std_msgs/msg/Header",
        header(1_700_000_123, 456_789, "base_link"),
    ),
    "image": (
        "sensor_msgs/msg/Image",
        Image(
            header=header(12, 34, "cam0"),
            height=1,
            width=1,
            encoding="rgb8",
            is_bigendian=0,
            step=3,
            data=np.array([1, 2, 255], dtype=np.uint8),
        ),
    ),
    "region_of_interest": (
        "sensor_msgs/msg/RegionOfInterest",
        RegionOfInterest(x_offset=10, y_offset=20, height=240, width=320, do_rectify=True),
    ),
    "camera_info": (
        "sensor_msgs/msg/CameraInfo",
        CameraInfo(
            header=header(100, 200, "cam1_optical"),
            height=480,
            width=640,
            distortion_model="plumb_bob",
            d=np.array([-0.28, 0.07, 0.001, -0.0005, 0.0], dtype=np.float64),
            k=np.array([525.0, 0.0, 319.5, 0.0, 525.0, 239.5, 0.0, 0.0, 1.0], dtype=np.float64),
            r=np.array([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], dtype=np.float64),
            p=np.array(
                [525.0, 0.0, 319.5, -37.5, 0.0, 525.0, 239.5, 0.0, 0.0, 0.0, 1.0, 0.0],
                dtype=np.float64,
            ),
            binning_x=2,
            binning_y=2,
            roi=RegionOfInterest(x_offset=8, y_offset=4, height=200, width=300, do_rectify=True),
        ),
    ),
    "point_field": (
        "sensor_msgs/msg/PointField",
        PointField(name="rgb", offset=12, datatype=PointField.UINT32, count=1),
    ),
    "point_cloud2": (
        "sensor_msgs/msg/PointCloud2",
        PointCloud2(
            header=header(5, 6, "map"),
            height=1,
            width=2,
            fields=[
                PointField(name="z", offset=0, datatype=PointField.FLOAT32, count=1),
                PointField(name="intensity", offset=4, datatype=PointField.UINT16, count=1),
            ],
            is_bigendian=False,
            point_step=6,
            row_step=12,
            data=np.array([0, 0, 128, 63, 7, 0, 0, 0, 0, 64, 9, 1], dtype=np.uint8),
            is_dense=True,
        ),
    ),
    "vector3": (
        "geometry_msgs/msg/Vector3",
        Vector3(x=1.5, y=-2.25, z=1e-9),
    ),
    "quaternion": (
        "geometry_msgs/msg/Quaternion",
        Quaternion(x=0.1, y=-0.2, z=0.3, w=0.9273618495495703),
    ),
    "transform": (
        "geometry_msgs/msg/Transform",
        transform_stamped(1).transform,
    ),
    "transform_stamped": (
        "geometry_msgs/msg/TransformStamped",
        transform_stamped(1),
    ),
    "tf_message": (
        "tf2_msgs/msg/TFMessage",
        TFMessage(transforms=[transform_stamped(0), transform_stamped(1)]),
    ),
    "key_value": (
        "diagnostic_msgs/msg/KeyValue",
        KeyValue(key="temperature", value="41.5C"),
    ),
    "diagnostic_status": (
        "diagnostic_msgs/msg/DiagnosticStatus",
        status(0, DiagnosticStatus.WARN),
    ),
    "diagnostic_array": (
        "diagnostic_msgs/msg/DiagnosticArray",
        DiagnosticArray(
            header=header(77, 88, ""),
            status=[status(0, DiagnosticStatus.OK), status(1, DiagnosticStatus.ERROR)],
        ),
    ),
}


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for name, (msgtype, msg) in MESSAGES.items():
        raw = bytes(ts.serialize_cdr(msg, msgtype, little_endian=True))
        assert raw[:4] == b"\x00\x01\x00\x00", raw[:4]
        # Round-trip through rosbags itself as a sanity check of the fixture.
        back = ts.deserialize_cdr(raw, msgtype)
        assert bytes(ts.serialize_cdr(back, msgtype)) == raw
        (OUT / f"{name}.bin").write_bytes(raw)
        print(f"{name:20s} {msgtype:40s} {len(raw):4d} bytes")
    print(f"rosbags {version('rosbags')}, numpy {np.__version__}")


if __name__ == "__main__":
    main()
