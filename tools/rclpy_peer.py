#!/usr/bin/env python3
"""The real ROS 2 stack as a test peer of `sweepdepth node`: rclpy 7.1.6 over rcl 9.2.8 and
rmw_fastrtps_cpp / Fast DDS 2.14.5 (the PyPI wheels of tools/requirements-ros.txt). Run it through
`tools/ros_python` (environment) inside a private network namespace (tests/node/node_rclpy.rs does).

Modes (one JSON object per line on stdout, prefixed `RCLPY_PEER `; errors on stderr):

  latency TOPIC[,TOPIC...] [--bytes]
      A consumer as RViz or image_proc would be one: default QoS (reliable, volatile, keep last
      10), default Fast DDS settings and socket buffers. For every sensor_msgs/Image received it
      prints {"event": "image", "topic", "frame_id", "stamp_ns", "source_ns", "received_ns",
      "now_ns", "bytes"}: `source_ns` is the writer's source timestamp (RTPS INFO_TS, set when the
      publisher wrote the sample), `received_ns` Fast DDS's reception time, `now_ns` the wall time
      in the callback.
  image-pub TOPIC WIDTH HEIGHT
      A Fast DDS publisher of 32FC1 images (reliable keep last 1, the node's output QoS). Reads
      commands on stdin: `pub ID` publishes one image with frame_id ID, `quit` leaves. Prints
      {"event": "ready"} once, {"event": "published", "id", "source_ns"} per image.

  drive DIR
      The camera drivers and a consumer of the node, from DIR/rig.json (written by the Rust test:
      namespace, cameras with their raw rgb8 pixel files and K/P, image QoS, expected depth):
      publishes one set (camera_info + image per camera, one stamp) at a time and waits for the
      depth image with that stamp (default-QoS subscriber) or `set_timeout_s`, then the camera
      period, then the next; listens to /rosout and /diagnostics meanwhile. Prints one
      {"event": "set", ...} per set (depth statistics against the expected depth, latency from
      the node's publish time) and a final {"event": "summary", ...}. rig.json's "encoding"
      (rgb8, bgr8, mono8) and "compressed" (jpeg, png: sensor_msgs/CompressedImage on
      <camera>/image_raw/compressed, made by cv2.imencode as image_transport's compressed
      plugin makes it) choose what the drivers publish.
  probe NODE_FQN
      The graph as rcl sees it (node names and namespaces, topic names and types, endpoint QoS)
      and the node's parameter services (list, get, describe, get types, set: a valid engine
      value, an out-of-range value, a read-only parameter). Prints {"event": "probe", ...}.
  clock NODE_FQN
      A simulator's clock: publishes rosgraph_msgs/Clock on /clock every 50 ms (best effort,
      keep last 1, as `ros2 bag play --clock`), from 1000 s on at the wall clock's pace, and listens to the node's /diagnostics
      and /rosout. Waits for two /diagnostics of the node stamped in simulated time, sets
      num_planes (a /rosout line at simulated time), reads use_sim_time, sets it false and
      waits for two /diagnostics stamped in wall time; listens to /parameter_events meanwhile
      (the node's event of num_planes). The node's /clock readers in the graph while
      use_sim_time is on, and once it is off (waits until there are none); then sets it true
      again and waits for the node's reader and a /diagnostics stamped after the switch, in
      simulated time. Prints {"event": "clock", ...}: every stamp with the simulated and wall
      "now" it was received at.
  fuse-clock NODE_FQN CLOCK_TOPIC
      A simulator's clock on a remapped topic, for `sweepdepth fuse`: the simulated clock as
      in `clock` on CLOCK_TOPIC, a decoy clock from 5000 s on /clock; waits for two
      /diagnostics of the fuse node stamped in either simulated time and for its
      /parameter_events writer and reader of CLOCK_TOPIC. Then its parameter services (list,
      get, describe; setting voxel_size, which is read-only there); sets use_sim_time false and
      waits for its reader of CLOCK_TOPIC to leave the graph, for two /diagnostics stamped in
      wall time and for the /parameter_events entry. Prints {"event": "fuse-clock",
      "diagnostics": [...], ...} with the node's /parameter_events writers and readers of both
      clocks while use_sim_time was on, and what the services answered.

Exit status: 0 done, 2 timeout, 3 bad setup or arguments, 4 rclpy missing.

SAFETY: refuses to open DDS unless this process's network namespace has only `lo`.
"""

import json
import os
import pathlib
import sys
import threading
import time

PREFIX = "RCLPY_PEER "
# Best-effort driver: a set without depth is sent again (same stamps) this often.
RESEND_S = 5.0


def interfaces() -> list[str]:
    try:
        lines = pathlib.Path("/proc/self/net/dev").read_text().splitlines()[2:]
    except OSError:
        return []
    return [l.split(":")[0].strip() for l in lines if l.split(":")[0].strip()]


def fail(code: int, msg: str) -> None:
    print(f"rclpy_peer: {msg}", file=sys.stderr, flush=True)
    sys.exit(code)


def emit(obj: dict) -> None:
    print(PREFIX + json.dumps(obj), flush=True)


if interfaces() != ["lo"]:
    fail(3, f"refusing to open DDS: this network namespace has interfaces {interfaces()} (only lo allowed)")

try:
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo, CompressedImage, Image
    from builtin_interfaces.msg import Time
    from rcl_interfaces.msg import (Log, Parameter, ParameterEvent, ParameterType,
                                     ParameterValue)
    from rcl_interfaces.srv import (DescribeParameters, GetParameters, GetParameterTypes,
                                    ListParameters, SetParameters)
    from diagnostic_msgs.msg import DiagnosticArray
    from std_srvs.srv import Trigger
    from visualization_msgs.msg import Marker, MarkerArray
    from rclpy.qos import qos_profile_sensor_data
    import numpy as np
except ImportError as e:  # the Rust tests look for exit status 4
    fail(4, f"RCLPY_MISSING: cannot import rclpy ({e}); run `sh scripts/setup.sh`")


def default_qos() -> QoSProfile:
    """rclcpp/rclpy's default: reliable, volatile, keep last 10."""
    return QoSProfile(depth=10)


def output_qos() -> QoSProfile:
    """The node's output QoS: reliable, volatile, keep last 1."""
    return QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                      history=HistoryPolicy.KEEP_LAST)


def stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def run_latency(node: Node, topics: list[str]) -> None:
    def callback_for(topic: str):
        def callback(msg: Image, info) -> None:
            now = time.time_ns()
            emit({
                "event": "image", "topic": topic, "frame_id": msg.header.frame_id,
                "stamp_ns": stamp_ns(msg.header.stamp),
                "source_ns": int(info["source_timestamp"]),
                "received_ns": int(info["received_timestamp"]),
                "now_ns": now, "bytes": len(msg.data),
                "width": msg.width, "height": msg.height, "encoding": msg.encoding,
            })
        return callback

    subs = [node.create_subscription(Image, t, callback_for(t), default_qos()) for t in topics]
    emit({"event": "ready", "topics": topics})
    rclpy.spin(node)
    del subs


def run_image_pub(node: Node, topic: str, width: int, height: int) -> None:
    publisher = node.create_publisher(Image, topic, output_qos())
    payload = bytes(range(256)) * (width * height * 4 // 256 + 1)
    payload = payload[: width * height * 4]
    commands: list[str] = []
    lock = threading.Lock()

    def read_stdin() -> None:
        for line in sys.stdin:
            with lock:
                commands.append(line.strip())
        with lock:
            commands.append("quit")

    threading.Thread(target=read_stdin, daemon=True).start()
    emit({"event": "ready", "topic": topic})
    while rclpy.ok():
        rclpy.spin_once(node, timeout_sec=0.005)
        with lock:
            todo, commands[:] = list(commands), []
        for cmd in todo:
            if cmd == "quit":
                return
            if cmd.startswith("pub "):
                msg = Image()
                now = node.get_clock().now().to_msg()
                msg.header.stamp = now
                msg.header.frame_id = cmd[4:]
                msg.width, msg.height, msg.encoding = width, height, "32FC1"
                msg.is_bigendian, msg.step = 0, width * 4
                msg.data = payload
                source = time.time_ns()
                publisher.publish(msg)
                emit({"event": "published", "id": cmd[4:], "source_ns": source})


def qos_name(q) -> dict:
    return {"reliability": q.reliability.name, "durability": q.durability.name,
            "history": q.history.name, "depth": q.depth}


def run_drive(node: Node, directory: pathlib.Path) -> None:
    rig = json.loads((directory / "rig.json").read_text())
    ns = rig["namespace"].rstrip("/")
    w, h = int(rig["width"]), int(rig["height"])
    expected, tolerance = float(rig["expected_depth_m"]), float(rig["tolerance"])
    sets, set_timeout = int(rig["sets"]), float(rig["set_timeout_s"])
    period = float(rig.get("period_s", 0.1))
    image_reliable = bool(rig["image_reliable"])
    # rig.json "encoding" (rgb8, bgr8, mono8; the files are rgb8) and "compressed" (jpeg, png:
    # image_transport's compressed plugin on <base>/image_raw/compressed, made as it makes it:
    # colour through bgr8, cv2.imencode with JPEG quality 95 or PNG level 3).
    encoding = rig.get("encoding", "rgb8")
    compressed = rig.get("compressed")
    if image_reliable:
        image_qos = QoSProfile(depth=10)  # rclcpp's default / image_transport's
    else:
        image_qos = qos_profile_sensor_data  # best effort, keep last 5
    cams = []
    for cam in rig["cameras"]:
        raw = (directory / cam["image_file"]).read_bytes()
        if len(raw) != w * h * 3:
            fail(3, f"{cam['image_file']}: {len(raw)} bytes, expected {w * h * 3}")
        base = f"{ns}/{cam['name']}"
        info = CameraInfo()
        info.header.frame_id = cam["frame_id"]
        info.width, info.height = w, h
        info.distortion_model = "plumb_bob"
        info.d = [0.0] * 5
        info.k = [float(v) for v in cam["k"]]
        info.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        info.p = [float(v) for v in cam["p"]]
        rgb = np.frombuffer(raw, dtype=np.uint8).reshape(h, w, 3)
        if compressed:
            import cv2
            if encoding == "mono8":
                pixels, target = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), "mono8"
            else:
                pixels, target = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), "bgr8"
            if compressed == "jpeg":
                done, buf = cv2.imencode(".jpg", pixels, [cv2.IMWRITE_JPEG_QUALITY, 95])
            else:
                done, buf = cv2.imencode(".png", pixels, [cv2.IMWRITE_PNG_COMPRESSION, 3])
            if not done:
                fail(3, f"cv2.imencode failed for {compressed}")
            image = CompressedImage()
            image.header.frame_id = cam["frame_id"]
            image.format = f"{encoding}; {compressed} compressed {target}"
            image.data = buf.tobytes()
            image_pub = node.create_publisher(
                CompressedImage, f"{base}/image_raw/compressed", image_qos)
        else:
            if encoding == "mono8":
                pixels = (rgb.astype(np.uint32) * [77, 150, 29]).sum(axis=2) // 256
                pixels, channels = pixels.astype(np.uint8), 1
            elif encoding == "bgr8":
                pixels, channels = rgb[:, :, ::-1], 3
            else:
                pixels, channels = rgb, 3
            image = Image()
            image.header.frame_id = cam["frame_id"]
            image.width, image.height, image.encoding = w, h, encoding
            image.is_bigendian, image.step = 0, w * channels
            image.data = np.ascontiguousarray(pixels).tobytes()
            image_pub = node.create_publisher(Image, f"{base}/image_raw", image_qos)
        cams.append({
            "info": info, "image": image,
            "info_pub": node.create_publisher(CameraInfo, f"{base}/camera_info", image_qos),
            "image_pub": image_pub,
        })

    depths: dict[int, tuple] = {}

    def on_depth(msg: Image, info) -> None:
        depths[stamp_ns(msg.header.stamp)] = (msg, info, time.time_ns())

    rosout: list[dict] = []

    def on_rosout(msg: Log) -> None:
        rosout.append({"name": msg.name, "level": int(msg.level), "msg": msg.msg})

    diagnostics: list[dict] = []

    def on_diag(msg: DiagnosticArray) -> None:
        for st in msg.status:
            diagnostics.append({"name": st.name, "level": int.from_bytes(st.level, "little")
                                if isinstance(st.level, bytes) else int(st.level),
                                "message": st.message,
                                "values": {kv.key: kv.value for kv in st.values}})

    # Fusion (rig.json "mesh": true): the mesh's markers, latest per id, and DELETEALLs seen.
    mesh_blocks: dict[int, Marker] = {}
    mesh_events = {"arrays": 0, "deleteall": 0, "frames": set()}

    def on_mesh(msg: MarkerArray) -> None:
        mesh_events["arrays"] += 1
        for m in msg.markers:
            mesh_events["frames"].add(m.header.frame_id)
            if m.action == Marker.DELETEALL:
                mesh_events["deleteall"] += 1
                mesh_blocks.clear()
            elif m.action == Marker.DELETE:
                mesh_blocks.pop(m.id, None)
            else:
                mesh_blocks[m.id] = m

    subs = [
        node.create_subscription(Image, f"{ns}/depth/image", on_depth, default_qos()),
        node.create_subscription(Log, "/rosout", on_rosout, QoSProfile(depth=1000)),
        node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, default_qos()),
    ]
    if rig.get("mesh"):
        subs.append(node.create_subscription(MarkerArray, f"{ns}/mesh", on_mesh, default_qos()))

    def spin_for(seconds: float, until=lambda: False) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end and not until():
            rclpy.spin_once(node, timeout_sec=min(0.01, max(0.0, end - time.monotonic())))

    # Until the node's subscriptions match ours (discovery), nothing sent would arrive.
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and any(
            c["image_pub"].get_subscription_count() == 0 for c in cams):
        spin_for(0.1)
    emit({"event": "matched", "after_s": round(60 - (deadline - time.monotonic()), 3)})
    spin_for(1.0)  # let the node's readers settle (reliable first samples)

    results = []
    for k in range(1, sets + 1):
        stamp = Time(sec=1000 + k, nanosec=0)
        sent_ns = time.time_ns()
        for cam in cams:
            cam["info"].header.stamp = stamp
            cam["image"].header.stamp = stamp
            cam["info_pub"].publish(cam["info"])
            cam["image_pub"].publish(cam["image"])
        key = stamp_ns(stamp)
        # Best effort has no repair: an image lost on the way (a full socket buffer) leaves
        # its set incomplete for good. Such a set is sent again, same stamps, every
        # RESEND_S until its depth comes: the node drops the images it already has as
        # duplicates and completes the set with the one that was lost. Re-sending is
        # harmless while the node is merely slow, so nothing here assumes its pace.
        deadline = time.monotonic() + set_timeout
        resends = 0
        while True:
            wait = max(0.0, deadline - time.monotonic())
            spin_for(wait if image_reliable else min(RESEND_S, wait), lambda: key in depths)
            if key in depths or time.monotonic() >= deadline:
                break
            for cam in cams:
                cam["info_pub"].publish(cam["info"])
                cam["image_pub"].publish(cam["image"])
            resends += 1
        got = depths.get(key)
        result = {"event": "set", "k": k, "received": got is not None, "resends": resends}
        if got is not None:
            msg, info, now = got
            arr = np.frombuffer(bytes(msg.data), dtype=">f4" if msg.is_bigendian else "<f4")
            valid = arr[np.isfinite(arr)]
            within = int(np.sum(np.abs(valid - expected) <= tolerance * expected))
            result.update({
                "encoding": msg.encoding, "width": msg.width, "height": msg.height,
                "frame_id": msg.header.frame_id, "total": int(arr.size),
                "valid": int(valid.size), "within": within,
                "median_m": float(np.median(valid)) if valid.size else None,
                "latency_ms": (now - int(info["source_timestamp"])) / 1e6,
                "reception_ms": (int(info["received_timestamp"]) - int(info["source_timestamp"])) / 1e6,
                "since_sent_ms": (now - sent_ns) / 1e6,
            })
        emit(result)
        results.append(result)
        spin_for(period)
    spin_for(1.5, lambda: bool(diagnostics))  # /diagnostics comes once a second
    mesh = None
    if rig.get("mesh"):
        # The last set's blocks come at the node's mesh_rate; then the map is cleared through
        # ~/clear_map (std_srvs/Trigger) and its DELETEALL awaited.
        spin_for(set_timeout, lambda: bool(mesh_blocks))
        zs = [p.z for m in mesh_blocks.values() for p in m.points]
        mesh = {
            "arrays": mesh_events["arrays"], "blocks": len(mesh_blocks),
            "triangles": sum(len(m.points) // 3 for m in mesh_blocks.values()),
            "colors_match": all(len(m.colors) == len(m.points) for m in mesh_blocks.values()),
            "types": sorted({int(m.type) for m in mesh_blocks.values()}),
            "frames": sorted(mesh_events["frames"]),
            "z_median": float(np.median(zs)) if zs else None,
        }
        answer = call(node, Trigger, f"{ns}/sweepdepth/clear_map", Trigger.Request())
        spin_for(set_timeout, lambda: mesh_events["deleteall"] > 0)
        mesh.update({"clear_success": bool(answer.success), "clear_message": answer.message,
                     "deleteall": mesh_events["deleteall"], "blocks_after_clear": len(mesh_blocks)})
    received = [r for r in results if r["received"]]
    latencies = sorted(r["latency_ms"] for r in received)
    emit({
        "event": "summary", "sets": sets, "received": len(received),
        "latency_median_ms": latencies[len(latencies) // 2] if latencies else None,
        "latency_max_ms": latencies[-1] if latencies else None,
        "image_qos": qos_name(image_qos),
        "rosout": rosout[-200:], "diagnostics": diagnostics[-50:], "mesh": mesh,
    })
    del subs


def test_timeout() -> float:
    """The tests' one generous limit (SWEEPDEPTH_TEST_TIMEOUT_S, default 300 s)."""
    try:
        return float(os.environ.get("SWEEPDEPTH_TEST_TIMEOUT_S", "300"))
    except ValueError:
        return 300.0


def call(node: Node, srv_type, name: str, request, idempotent: bool = True):
    """Calls a service within the tests' one limit. A request sent right after the service was
    discovered can lose its response while the server's response writer has not yet matched
    this client's reader (a known race of ROS 2 services, more likely on a loaded machine), so
    an idempotent request is sent again every few seconds until one answer comes."""
    timeout = test_timeout()
    end = time.monotonic() + timeout
    client = node.create_client(srv_type, name)
    if not client.wait_for_service(timeout_sec=timeout):
        fail(2, f"service {name} not available within {timeout} s")
    while True:
        future = client.call_async(request)
        left = end - time.monotonic()
        rclpy.spin_until_future_complete(
            node, future, timeout_sec=min(left, 5.0) if idempotent else left)
        if future.done():
            break
        if time.monotonic() >= end:
            fail(2, f"no answer from {name} within {timeout} s")
    node.destroy_client(client)
    return future.result()


def value_json(v: ParameterValue):
    t = v.type
    return {
        ParameterType.PARAMETER_NOT_SET: lambda: None,
        ParameterType.PARAMETER_BOOL: lambda: v.bool_value,
        ParameterType.PARAMETER_INTEGER: lambda: v.integer_value,
        ParameterType.PARAMETER_DOUBLE: lambda: v.double_value,
        ParameterType.PARAMETER_STRING: lambda: v.string_value,
        ParameterType.PARAMETER_STRING_ARRAY: lambda: list(v.string_array_value),
        ParameterType.PARAMETER_DOUBLE_ARRAY: lambda: list(v.double_array_value),
        ParameterType.PARAMETER_INTEGER_ARRAY: lambda: list(v.integer_array_value),
        ParameterType.PARAMETER_BOOL_ARRAY: lambda: list(v.bool_array_value),
    }.get(t, lambda: f"type {t}")()


def set_param(node: Node, fqn: str, name: str, value: ParameterValue) -> dict:
    req = SetParameters.Request(parameters=[Parameter(name=name, value=value)])
    res = call(node, SetParameters, f"{fqn}/set_parameters", req, idempotent=False).results[0]
    return {"successful": bool(res.successful), "reason": res.reason}


def run_probe(node: Node, fqn: str) -> None:
    ns, _, name = fqn.rpartition("/")
    ns = ns or "/"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and (name, ns) not in node.get_node_names_and_namespaces():
        rclpy.spin_once(node, timeout_sec=0.1)
    nodes = node.get_node_names_and_namespaces()
    # The graph fills in as discovery goes on (publications and subscriptions on streams of
    # their own): wait for the node's depth output and its subscription of cam0's images.
    want = f"{ns.rstrip('/')}/depth/image"
    images = f"{ns.rstrip('/')}/cam0/image_raw"

    def seen() -> bool:
        return want in dict(node.get_topic_names_and_types()) and any(
            i.node_name == name for i in node.get_subscriptions_info_by_topic(images))

    while time.monotonic() < deadline and not seen():
        rclpy.spin_once(node, timeout_sec=0.1)
    topics = {t: list(types) for t, types in node.get_topic_names_and_types()}

    def endpoints(infos):
        return [{"node_name": i.node_name, "node_namespace": i.node_namespace,
                 "topic_type": i.topic_type, "qos": qos_name(i.qos_profile)} for i in infos]

    pubs = {t: endpoints(node.get_publishers_info_by_topic(t)) for t in topics}
    subs = {t: endpoints(node.get_subscriptions_info_by_topic(t)) for t in topics}
    listed = call(node, ListParameters, f"{fqn}/list_parameters", ListParameters.Request())
    names = list(listed.result.names)
    got = call(node, GetParameters, f"{fqn}/get_parameters", GetParameters.Request(names=names))
    values = {n: value_json(v) for n, v in zip(names, got.values)}
    types = call(node, GetParameterTypes, f"{fqn}/get_parameter_types",
                 GetParameterTypes.Request(names=names)).types
    described = call(node, DescribeParameters, f"{fqn}/describe_parameters",
                     DescribeParameters.Request(names=names)).descriptors
    descriptors = {d.name: {
        "type": int(d.type), "description": d.description, "read_only": bool(d.read_only),
        "integer_range": [[r.from_value, r.to_value, r.step] for r in d.integer_range],
        "floating_point_range": [[r.from_value, r.to_value, r.step] for r in d.floating_point_range],
    } for d in described}
    sets = {
        "num_planes=20": set_param(node, fqn, "num_planes", ParameterValue(
            type=ParameterType.PARAMETER_INTEGER, integer_value=20)),
        "num_planes=1": set_param(node, fqn, "num_planes", ParameterValue(
            type=ParameterType.PARAMETER_INTEGER, integer_value=1)),
        "num_planes='many'": set_param(node, fqn, "num_planes", ParameterValue(
            type=ParameterType.PARAMETER_STRING, string_value="many")),
        "cameras=[a, b]": set_param(node, fqn, "cameras", ParameterValue(
            type=ParameterType.PARAMETER_STRING_ARRAY, string_array_value=["a", "b"])),
    }
    after = call(node, GetParameters, f"{fqn}/get_parameters",
                 GetParameters.Request(names=["num_planes", "cameras"]))
    # /clock again after the service calls: a reader made later than the node's others (a
    # spinner's) is in the graph by now.
    clock_types_late = dict(node.get_topic_names_and_types()).get("/clock", [])
    clock_readers_late = endpoints(node.get_subscriptions_info_by_topic("/clock"))
    emit({
        "event": "probe", "nodes": [list(n) for n in nodes], "topics": topics,
        "clock_types_late": list(clock_types_late), "clock_readers_late": clock_readers_late,
        "publishers": pubs, "subscriptions": subs, "parameters": values,
        "types": dict(zip(names, [int(t) for t in types])), "descriptors": descriptors,
        "sets": sets, "after": {"num_planes": value_json(after.values[0]),
                                "cameras": value_json(after.values[1])},
    })


SIM_BASE_NS = 1000 * 1_000_000_000
# The decoy clock of `fuse-clock`, on the topic the remap replaces.
DECOY_BASE_NS = 5000 * 1_000_000_000


class SimClock:
    """rosgraph_msgs/Clock published every 50 ms from `base_ns` on at the wall clock's pace, best
    effort keep last 1 (rosbag2's player, rclcpp's ClockQoS)."""

    def __init__(self, node: Node, topic: str, base_ns: int) -> None:
        from rosgraph_msgs.msg import Clock

        self.base_ns = base_ns
        self.started = time.monotonic()
        self.stop = threading.Event()
        pub = node.create_publisher(
            Clock, topic, QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))

        def publish() -> None:
            while not self.stop.is_set():
                t = self.now_ns()
                pub.publish(Clock(clock=Time(sec=t // 1_000_000_000, nanosec=t % 1_000_000_000)))
                time.sleep(0.05)

        threading.Thread(target=publish, daemon=True).start()

    def now_ns(self) -> int:
        return self.base_ns + int((time.monotonic() - self.started) * 1e9)


def spin_until(node: Node, deadline: float, what: str, done) -> None:
    """Spins until `done()`; fails once the monotonic clock passes `deadline` (one per mode: the
    tests' one limit)."""
    while not done():
        if time.monotonic() > deadline:
            fail(2, f"no {what} within {test_timeout()} s")
        rclpy.spin_once(node, timeout_sec=0.1)


def diagnostics_of(node: Node, status_name: str, received) -> tuple[list, object]:
    """The /diagnostics of one status name, each as `received(stamp)` makes it."""
    got: list[dict] = []

    def on_diag(msg: DiagnosticArray) -> None:
        if any(s.name == status_name for s in msg.status):
            got.append(received(msg.header.stamp))

    return got, node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, default_qos())


def run_clock(node: Node, fqn: str) -> None:
    clock = SimClock(node, "/clock", SIM_BASE_NS)
    sim_ns = clock.now_ns
    logger = fqn.strip("/").replace("/", ".")
    rosout: list[dict] = []
    parameter_events: list[dict] = []

    def received(stamp) -> dict:
        return {"stamp_ns": stamp_ns(stamp), "sim_ns": sim_ns(), "wall_ns": time.time_ns()}

    diagnostics, diag_sub = diagnostics_of(node, f"sweepdepth: {fqn}", received)

    def on_rosout(msg: Log) -> None:
        if msg.name == logger:
            rosout.append({**received(msg.stamp), "msg": msg.msg})

    def on_parameter_event(msg: ParameterEvent) -> None:
        if msg.node == fqn:
            parameter_events.append({**received(msg.stamp), "changed": [
                p.name for p in msg.changed_parameters]})

    subs = [diag_sub,
            node.create_subscription(Log, "/rosout", on_rosout, QoSProfile(depth=1000)),
            node.create_subscription(ParameterEvent, "/parameter_events", on_parameter_event,
                                     QoSProfile(depth=1000))]

    def simulated(d: dict) -> bool:
        return SIM_BASE_NS <= d["stamp_ns"] < SIM_BASE_NS + 10**12

    deadline = time.monotonic() + test_timeout()
    spin_until(node, deadline, "two /diagnostics in simulated time",
               lambda: sum(simulated(d) for d in diagnostics) >= 2)
    sim_diagnostics = list(diagnostics)
    set_planes = set_param(node, fqn, "num_planes", ParameterValue(
        type=ParameterType.PARAMETER_INTEGER, integer_value=20))
    spin_until(node, deadline, "the /rosout line and the /parameter_events entry of num_planes",
               lambda: any("num_planes" in line["msg"] for line in rosout)
               and any("num_planes" in e["changed"] for e in parameter_events))
    got = call(node, GetParameters, f"{fqn}/get_parameters",
               GetParameters.Request(names=["use_sim_time"]))
    use_sim_time = value_json(got.values[0])
    ns, _, name = fqn.rpartition("/")
    ns = ns or "/"

    def clock_readers() -> list:
        return [{"topic_type": i.topic_type, "qos": qos_name(i.qos_profile)}
                for i in node.get_subscriptions_info_by_topic("/clock")
                if i.node_name == name and i.node_namespace == ns]

    # The node has had /clock (its diagnostics were in simulated time): its reader is known.
    spin_until(node, deadline, "the node's /clock reader in the graph", lambda: clock_readers())
    readers_on = clock_readers()
    set_false = set_param(node, fqn, "use_sim_time", ParameterValue(
        type=ParameterType.PARAMETER_BOOL, bool_value=False))
    diagnostics.clear()
    spin_until(node, deadline, "two /diagnostics in wall time",
               lambda: sum(d["stamp_ns"] > 1_600_000_000 * 10**9 for d in diagnostics) >= 2)
    wall_diagnostics = list(diagnostics)
    spin_until(node, deadline, "the node's /clock reader gone from the graph",
               lambda: not clock_readers())
    # On again: a new reader, and the time from /clock's messages after the switch.
    switched_on_ns = sim_ns()
    set_true = set_param(node, fqn, "use_sim_time", ParameterValue(
        type=ParameterType.PARAMETER_BOOL, bool_value=True))
    diagnostics.clear()
    spin_until(node, deadline, "a /diagnostics stamped in simulated time after the switch",
               lambda: any(switched_on_ns <= d["stamp_ns"] < SIM_BASE_NS + 10**12
                           for d in diagnostics))
    spin_until(node, deadline, "the node's /clock reader back in the graph",
               lambda: clock_readers())
    clock.stop.set()
    emit({"event": "clock", "sim_diagnostics": sim_diagnostics, "set_planes": set_planes,
          "use_sim_time": use_sim_time, "set_false": set_false,
          "wall_diagnostics": wall_diagnostics, "rosout": rosout,
          "parameter_events": parameter_events, "clock_readers_on": readers_on,
          "set_true": set_true, "switched_on_ns": switched_on_ns,
          "sim_again_diagnostics": list(diagnostics), "clock_readers_again": clock_readers()})
    del subs


def run_fuse_clock(node: Node, fqn: str, clock_topic: str) -> None:
    clock = SimClock(node, clock_topic, SIM_BASE_NS)
    decoy = SimClock(node, "/clock", DECOY_BASE_NS)

    def received(stamp) -> dict:
        return {"stamp_ns": stamp_ns(stamp), "sim_ns": clock.now_ns(),
                "decoy_ns": decoy.now_ns(), "wall_ns": time.time_ns()}

    diagnostics, sub = diagnostics_of(node, f"sweepdepth fuse: {fqn}", received)
    # From the start, as `clock`'s (matched long before the switch).
    events: list[dict] = []

    def on_parameter_event(msg: ParameterEvent) -> None:
        if msg.node == fqn:
            events.append({"changed": [
                [p.name, value_json(p.value)] for p in msg.changed_parameters]})

    event_sub = node.create_subscription(ParameterEvent, "/parameter_events",
                                         on_parameter_event, QoSProfile(depth=1000))

    def simulated(d: dict) -> bool:
        return SIM_BASE_NS <= d["stamp_ns"] < SIM_BASE_NS + 10**15

    deadline = time.monotonic() + test_timeout()
    spin_until(node, deadline, "two /diagnostics of the fuse node in simulated time",
               lambda: sum(simulated(d) for d in diagnostics) >= 2)
    sim_diagnostics = list(diagnostics)
    ns, _, name = fqn.rpartition("/")

    def ours(infos) -> list:
        return [{"topic_type": i.topic_type, "qos": qos_name(i.qos_profile)} for i in infos
                if i.node_name == name and i.node_namespace == (ns or "/")]

    # The node's other endpoints: its /parameter_events writer and /clock readers (the
    # remapped one, none on /clock), once its /diagnostics came (its endpoints are known).
    spin_until(node, deadline, "the fuse node's /parameter_events writer and clock reader",
               lambda: ours(node.get_publishers_info_by_topic("/parameter_events"))
               and ours(node.get_subscriptions_info_by_topic(clock_topic)))
    writers = ours(node.get_publishers_info_by_topic("/parameter_events"))
    clock_readers = ours(node.get_subscriptions_info_by_topic(clock_topic))
    decoy_readers = ours(node.get_subscriptions_info_by_topic("/clock"))
    names = list(call(node, ListParameters, f"{fqn}/list_parameters",
                      ListParameters.Request()).result.names)
    got = call(node, GetParameters, f"{fqn}/get_parameters", GetParameters.Request(names=names))
    described = call(node, DescribeParameters, f"{fqn}/describe_parameters",
                     DescribeParameters.Request(names=names)).descriptors
    set_voxel = set_param(node, fqn, "voxel_size", ParameterValue(
        type=ParameterType.PARAMETER_DOUBLE, double_value=0.07))
    voxel_after = value_json(call(node, GetParameters, f"{fqn}/get_parameters",
                                  GetParameters.Request(names=["voxel_size"])).values[0])
    set_false = set_param(node, fqn, "use_sim_time", ParameterValue(
        type=ParameterType.PARAMETER_BOOL, bool_value=False))
    diagnostics.clear()
    spin_until(node, deadline, "two /diagnostics of the fuse node in wall time",
               lambda: sum(d["stamp_ns"] > 1_600_000_000 * 10**9 for d in diagnostics) >= 2)
    spin_until(node, deadline, "the fuse node's clock reader gone from the graph",
               lambda: not ours(node.get_subscriptions_info_by_topic(clock_topic)))
    spin_until(node, deadline, "the fuse node's /parameter_events entry of use_sim_time",
               lambda: any(c[0] == "use_sim_time" for e in events for c in e["changed"]))
    clock.stop.set()
    decoy.stop.set()
    emit({"event": "fuse-clock", "diagnostics": sim_diagnostics,
          "parameter_events_writers": writers, "clock_readers": clock_readers,
          "decoy_readers": decoy_readers, "names": names,
          "values": {n: value_json(v) for n, v in zip(names, got.values)},
          "read_only": {d.name: bool(d.read_only) for d in described},
          "set_voxel": set_voxel, "voxel_after": voxel_after, "set_false": set_false,
          "wall_diagnostics": list(diagnostics), "parameter_events": events})
    del sub, event_sub


def main() -> None:
    args = sys.argv[1:]
    if not args:
        fail(3, "usage: rclpy_peer.py latency TOPICS | image-pub TOPIC W H | drive DIR | probe NODE_FQN | clock NODE_FQN | "
             "fuse-clock NODE_FQN CLOCK_TOPIC")
    mode, rest = args[0], args[1:]
    rclpy.init(args=None)
    node = Node("sweepdepth_rclpy_peer")
    try:
        if mode == "latency" and len(rest) == 1:
            run_latency(node, rest[0].split(","))
        elif mode == "image-pub" and len(rest) == 3:
            run_image_pub(node, rest[0], int(rest[1]), int(rest[2]))
        elif mode == "drive" and len(rest) == 1:
            run_drive(node, pathlib.Path(rest[0]))
        elif mode == "probe" and len(rest) == 1:
            run_probe(node, rest[0])
        elif mode == "clock" and len(rest) == 1:
            run_clock(node, rest[0])
        elif mode == "fuse-clock" and len(rest) == 2:
            run_fuse_clock(node, rest[0], rest[1])
        else:
            fail(3, f"bad arguments {args}")
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


if __name__ == "__main__":
    main()
