#!/usr/bin/env python3
"""Interoperability peer for `tests/node/node_cyclone.rs`: a fake ROS 2 camera driver on Eclipse
Cyclone DDS (the `cyclonedds` Python package, which bundles libddsc), independent of
ros2-client / RustDDS.

It speaks plain ROS 2 over DDS exactly as rclcpp + rmw_cyclonedds would put it on the wire:

* topic `/rig/cam0/image_raw` is the DDS topic `rt/rig/cam0/image_raw`;
* type `sensor_msgs/msg/Image` is the DDS type `sensor_msgs::msg::dds_::Image_` (likewise for
  every message and nested struct);
* payloads are XCDR1 (plain CDR, little endian, encapsulation `00 01 00 00`), all structs final;
* QoS: images and camera_info reliable keep-last 10 (image_transport's default) or best-effort
  keep-last 5 (SensorDataQoS), chosen by rig.json; /tf_static reliable + transient-local
  keep-last 1 (tf2_ros::StaticTransformBroadcaster); depth read reliable keep-last 10.

Usage:

    python3 tools/cyclone_peer.py <dir>         # run the peer (see below)
    python3 tools/cyclone_peer.py --selftest    # compare our CDR with tests/fixtures/cdr/*.bin

`<dir>/rig.json` (written by the Rust test) describes the domain id, the node namespace, the
cameras (frame id, encoding, raw pixel file, K, P, position in the rig) and the expected depth.
The peer publishes /tf_static once, then camera_info + image for each camera at about 10 Hz
with the stamps `sec = 1000 + k // 10, nanosec = (k % 10) * 1e8`, subscribes
`<namespace>/depth/image`, and on the first depth image prints ONE line
`CYCLONE_PEER_RESULT {json}` on stdout and exits 0. Exit 2 on timeout, 3 on a bad setup.

SAFETY: it refuses to open DDS unless this process's network namespace has only `lo`, and it
pins Cyclone to the loopback interface (CYCLONEDDS_URI) in any case.
"""


import json
import math
import os
import pathlib
import struct
import sys
import time
from dataclasses import dataclass, field

RESULT_PREFIX = "CYCLONE_PEER_RESULT "

# Loopback only, multicast forced on lo (SPDP discovery with RustDDS uses 239.255.0.1).
LOOPBACK_CONFIG = (
    "<CycloneDDS><Domain Id=\"any\"><General>"
    "<Interfaces><NetworkInterface name=\"lo\" multicast=\"true\"/></Interfaces>"
    "<AllowMulticast>true</AllowMulticast>"
    "</General></Domain></CycloneDDS>"
)


def interfaces() -> list[str]:
    try:
        lines = pathlib.Path("/proc/self/net/dev").read_text().splitlines()[2:]
    except OSError:
        return []
    return [l.split(":")[0].strip() for l in lines if l.split(":")[0].strip()]


def fail(code: int, msg: str) -> None:
    print(f"cyclone_peer: {msg}", file=sys.stderr, flush=True)
    sys.exit(code)


try:
    from cyclonedds.core import Policy, Qos
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.idl import IdlStruct
    from cyclonedds.idl.types import array, float64, int32, sequence, uint8, uint32
    from cyclonedds.pub import DataWriter
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration
except ImportError as e:  # the Rust test greps for this line
    fail(4, f"CYCLONEDDS_MISSING: cannot import cyclonedds ({e}); run `python3 -m pip install cyclonedds`")


# --------------------------------------------------------------------------------------------
# ROS 2 messages as rosidl -> IDL -> idlc would emit them: module path `pkg::msg::dds_`,
# struct name with a trailing underscore, fields in .msg order. See src/msgs.rs.
# --------------------------------------------------------------------------------------------


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class Image(IdlStruct, typename="sensor_msgs::msg::dds_::Image_"):
    header: Header = field(default_factory=Header)
    height: uint32 = 0
    width: uint32 = 0
    encoding: str = ""
    is_bigendian: uint8 = 0
    step: uint32 = 0
    data: sequence[uint8] = field(default_factory=list)


@dataclass
class RegionOfInterest(IdlStruct, typename="sensor_msgs::msg::dds_::RegionOfInterest_"):
    x_offset: uint32 = 0
    y_offset: uint32 = 0
    height: uint32 = 0
    width: uint32 = 0
    do_rectify: bool = False


@dataclass
class CameraInfo(IdlStruct, typename="sensor_msgs::msg::dds_::CameraInfo_"):
    header: Header = field(default_factory=Header)
    height: uint32 = 0
    width: uint32 = 0
    distortion_model: str = ""
    d: sequence[float64] = field(default_factory=list)
    k: array[float64, 9] = field(default_factory=lambda: [0.0] * 9)
    r: array[float64, 9] = field(default_factory=lambda: [0.0] * 9)
    p: array[float64, 12] = field(default_factory=lambda: [0.0] * 12)
    binning_x: uint32 = 0
    binning_y: uint32 = 0
    roi: RegionOfInterest = field(default_factory=RegionOfInterest)


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: Transform = field(default_factory=Transform)


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: sequence[TransformStamped] = field(default_factory=list)


def dds_topic(ros_name: str) -> str:
    """ROS 2 topic name -> DDS topic name (rmw prefix `rt`)."""
    assert ros_name.startswith("/"), ros_name
    return "rt" + ros_name


def stamp_of(k: int) -> Time:
    return Time(sec=1000 + k // 10, nanosec=(k % 10) * 100_000_000)


def xcdr1() -> list:
    """Plain CDR (XCDR1), as rmw_cyclonedds uses; never XCDR2."""
    return [Policy.DataRepresentation(use_cdrv0_representation=True)]


# --------------------------------------------------------------------------------------------
# Self test: our serialisation must equal the rosbags oracle fixtures byte for byte.
# --------------------------------------------------------------------------------------------


def selftest() -> None:
    fixtures = pathlib.Path(__file__).resolve().parent.parent / "tests" / "fixtures" / "cdr"

    def header(sec, nanosec, frame_id):
        return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id)

    def ts(i):
        return TransformStamped(
            header=header(1_700_000_000 + i, 250_000_000 * i + 7, "world"),
            child_frame_id=f"cam{i}_optical",
            transform=Transform(
                translation=Vector3(x=0.5 * i, y=-1.25, z=3.0 + i),
                rotation=Quaternion(x=0.0, y=0.5, z=-0.5, w=0.7071067811865476),
            ),
        )

    cases = {
        "time": Time(sec=-2, nanosec=999_999_999),
        "header": header(1_700_000_123, 456_789, "base_link"),
        "image": Image(header=header(12, 34, "cam0"), height=1, width=1, encoding="rgb8",
                       is_bigendian=0, step=3, data=[1, 2, 255]),
        "camera_info": CameraInfo(
            header=header(100, 200, "cam1_optical"), height=480, width=640,
            distortion_model="plumb_bob", d=[-0.28, 0.07, 0.001, -0.0005, 0.0],
            k=[525.0, 0.0, 319.5, 0.0, 525.0, 239.5, 0.0, 0.0, 1.0],
            r=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p=[525.0, 0.0, 319.5, -37.5, 0.0, 525.0, 239.5, 0.0, 0.0, 0.0, 1.0, 0.0],
            binning_x=2, binning_y=2,
            roi=RegionOfInterest(x_offset=8, y_offset=4, height=200, width=300, do_rectify=True),
        ),
        "vector3": Vector3(x=1.5, y=-2.25, z=1e-9),
        "quaternion": Quaternion(x=0.1, y=-0.2, z=0.3, w=0.9273618495495703),
        "transform": ts(1).transform,
        "transform_stamped": ts(1),
        "tf_message": TFMessage(transforms=[ts(0), ts(1)]),
    }
    bad = 0
    for name, msg in cases.items():
        want = (fixtures / f"{name}.bin").read_bytes()
        got = msg.serialize(use_version_2=False)
        # DDS implementations may pad the payload to a multiple of 4.
        ok = got[:4] == b"\x00\x01\x00\x00" and got.rstrip(b"\0") == want.rstrip(b"\0") \
            and len(got) - len(want) in range(0, 4)
        back = type(msg).deserialize(want)
        ok = ok and back.serialize(use_version_2=False) == got
        print(f"{name:20s} {len(want):4d} / {len(got):4d} bytes {'ok' if ok else 'MISMATCH'}")
        if not ok:
            print(f"  want {want.hex()}\n  got  {got.hex()}")
            bad += 1
    if bad:
        fail(1, f"{bad} CDR mismatches against tests/fixtures/cdr")
    print("all CDR encodings match the rosbags fixtures")


# --------------------------------------------------------------------------------------------
# The peer
# --------------------------------------------------------------------------------------------


def run(directory: pathlib.Path) -> None:
    ifaces = interfaces()
    if ifaces != ["lo"]:
        fail(3, f"refusing to open DDS: this network namespace has interfaces {ifaces} (only lo allowed); run inside `unshare -n`")
    os.environ.setdefault("CYCLONEDDS_URI", LOOPBACK_CONFIG)

    rig = json.loads((directory / "rig.json").read_text())
    ns = rig["namespace"].rstrip("/")
    expected = float(rig["expected_depth_m"])
    tolerance = float(rig["tolerance"])
    timeout_s = float(rig.get("timeout_s", 60.0))
    period_s = float(rig.get("period_s", 0.1))

    participant = DomainParticipant(int(rig["domain_id"]))

    def qos(*policies):
        return Qos(*policies, *xcdr1())

    # Images: reliable keep-last 10 (image_transport / SystemDefaultsQoS) or best-effort
    # keep-last 5 (SensorDataQoS); camera_info the same, as drivers use one profile for both.
    image_qos = qos(Policy.Reliability.Reliable(duration(seconds=1))
                    if rig.get("image_reliable", True) else Policy.Reliability.BestEffort,
                    Policy.History.KeepLast(int(rig.get("image_qos_depth", 10))),
                    Policy.Durability.Volatile)
    tf_qos = qos(Policy.Reliability.Reliable(duration(seconds=1)),
                 Policy.History.KeepLast(1),
                 Policy.Durability.TransientLocal)
    depth_qos = qos(Policy.Reliability.Reliable(duration(seconds=1)),
                    Policy.History.KeepLast(10),
                    Policy.Durability.Volatile)

    tf_topic = Topic(participant, dds_topic("/tf_static"), TFMessage)
    tf_writer = DataWriter(participant, tf_topic, qos=tf_qos)

    # A moving rig (rig.json "world"): /tf world -> rig (tf2_ros's broadcaster QoS: reliable,
    # volatile, keep-last 100), twice per set, 30 ms before and 40 ms after its stamp: a pose
    # along "velocity" (m/s) turning about y at "yaw_rate" (rad/s) from stamp_of(0).
    world = rig.get("world")
    dyn_writer = None
    if world:
        dyn_qos = qos(Policy.Reliability.Reliable(duration(seconds=1)),
                      Policy.History.KeepLast(100),
                      Policy.Durability.Volatile)
        dyn_writer = DataWriter(participant, Topic(participant, dds_topic("/tf"), TFMessage),
                                qos=dyn_qos)
    origin = stamp_of(0)
    origin_ns = origin.sec * 1_000_000_000 + origin.nanosec

    def world_tf(t_ns: int) -> TransformStamped:
        s = (t_ns - origin_ns) * 1e-9
        vx, vy, vz = (float(v) for v in world["velocity"])
        yaw = float(world["yaw_rate"]) * s
        return TransformStamped(
            header=Header(stamp=Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000),
                          frame_id=world["frame"]),
            child_frame_id=rig["rig_frame"],
            transform=Transform(
                translation=Vector3(vx * s, vy * s, vz * s),
                rotation=Quaternion(0.0, math.sin(yaw / 2), 0.0, math.cos(yaw / 2)),
            ),
        )

    cams = []
    for cam in rig["cameras"]:
        base = f"{ns}/{cam['name']}"
        raw = (directory / cam["image_file"]).read_bytes()
        w, h = int(rig["width"]), int(rig["height"])
        if len(raw) != w * h * 3:
            fail(3, f"{cam['image_file']}: {len(raw)} bytes, expected {w * h * 3}")
        image_topic = Topic(participant, dds_topic(f"{base}/image_raw"), Image)
        info_topic = Topic(participant, dds_topic(f"{base}/camera_info"), CameraInfo)
        cams.append({
            "frame_id": cam["frame_id"],
            "encoding": cam["encoding"],
            "data": list(raw),
            "k": [float(v) for v in cam["k"]],
            "p": [float(v) for v in cam["p"]],
            "image_writer": DataWriter(participant, image_topic, qos=image_qos),
            "info_writer": DataWriter(participant, info_topic, qos=image_qos),
        })

    depth_topic = Topic(participant, dds_topic(f"{ns}/depth/image"), Image)
    depth_reader = DataReader(participant, depth_topic, qos=depth_qos)

    transforms = [
        TransformStamped(
            header=Header(stamp=stamp_of(0), frame_id=rig["rig_frame"]),
            child_frame_id=cam["frame_id"],
            transform=Transform(
                translation=Vector3(*[float(v) for v in cam["translation"]]),
                rotation=Quaternion(*[float(v) for v in cam["rotation_xyzw"]]),
            ),
        )
        for cam in rig["cameras"]
    ]
    tf_writer.write(TFMessage(transforms=transforms))

    w, h = int(rig["width"]), int(rig["height"])
    sent: set[tuple[int, int]] = set()
    started = time.monotonic()
    k = 0
    while True:
        if time.monotonic() - started > timeout_s:
            fail(2, f"no depth image on {dds_topic(ns + '/depth/image')} within {timeout_s:.0f} s ({k} sets sent)")
        k += 1
        stamp = stamp_of(k)
        sent.add((stamp.sec, stamp.nanosec))
        if dyn_writer is not None:
            t_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
            for offset in (-30_000_000, 40_000_000):
                dyn_writer.write(TFMessage(transforms=[world_tf(t_ns + offset)]))
        for cam in cams:
            header = Header(stamp=stamp, frame_id=cam["frame_id"])
            cam["info_writer"].write(CameraInfo(
                header=header, height=h, width=w, distortion_model="plumb_bob",
                d=[0.0] * 5, k=cam["k"], r=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                p=cam["p"],
            ))
            cam["image_writer"].write(Image(
                header=header, height=h, width=w, encoding=cam["encoding"],
                is_bigendian=0, step=w * 3, data=cam["data"],
            ))
        tick = time.monotonic()
        got = None
        while got is None and time.monotonic() - tick < period_s:
            samples = depth_reader.take(N=1)
            if samples:
                got = samples[0]
            else:
                time.sleep(0.005)
        if got is not None:
            break

    data = bytes(got.data)
    n = len(data) // 4
    depths = struct.unpack(f"<{n}f", data[: 4 * n]) if got.is_bigendian == 0 else \
        struct.unpack(f">{n}f", data[: 4 * n])
    valid = [d for d in depths if math.isfinite(d)]
    within = sum(1 for d in valid if abs((d - expected) / expected) <= tolerance)
    result = {
        "encoding": got.encoding,
        "width": got.width,
        "height": got.height,
        "step": got.step,
        "is_bigendian": got.is_bigendian,
        "data_len": len(data),
        "frame_id": got.header.frame_id,
        "stamp": {"sec": got.header.stamp.sec, "nanosec": got.header.stamp.nanosec},
        "stamp_was_sent": (got.header.stamp.sec, got.header.stamp.nanosec) in sent,
        "total": len(depths),
        "valid": len(valid),
        "within": within,
        "within_fraction": within / len(valid) if valid else 0.0,
        "sets_sent": k,
        "elapsed_s": round(time.monotonic() - started, 3),
    }
    print(RESULT_PREFIX + json.dumps(result), flush=True)


def main() -> None:
    if len(sys.argv) == 2 and sys.argv[1] == "--selftest":
        selftest()
        return
    if len(sys.argv) != 2:
        fail(3, "usage: cyclone_peer.py <dir with rig.json> | --selftest")
    run(pathlib.Path(sys.argv[1]))
    # Leave without running Cyclone's teardown in odd orders; the result is already out.
    sys.stdout.flush()
    os._exit(0)


if __name__ == "__main__":
    main()
