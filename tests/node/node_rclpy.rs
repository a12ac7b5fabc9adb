//! `sweepdepth node` driven by the real ROS 2 stack: `tools/rclpy_peer.py` on rclpy 7.1.6 over
//! rcl 9.2.8 and rmw_fastrtps_cpp / Fast DDS 2.14.5 (the Jazzy wheels `scripts/setup.sh` installs),
//! run through `tools/ros_python`. The peer is the four camera drivers (rgb8 images of a textured
//! wall at 2 m rendered by `sweepdepth::synthetic`, written to files by this test) and a consumer
//! with default QoS and default socket buffers; it also reads the graph, calls the parameter
//! services and listens to /rosout and /diagnostics. Extrinsics come from a rig file: tf2_msgs is
//! not published as a wheel, so rclpy cannot speak /tf_static here (the Cyclone peer of
//! tests/node/node_cyclone.rs does).
//!
//! Pacing: the peer sends the next frame set only after the depth of the previous one arrived
//! (or a generous timeout), so no test depends on how fast the engine or the machine is.
//!
//! rclpy missing is a FAILURE, not a skip. SAFETY: every test runs its node and peers inside a
//! private network namespace with only loopback (tests/common/netns.rs); the launcher refuses to
//! start outside one.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::common::netns::{in_private_netns, KillOnDrop};
use crate::common::rclpy::{self, event, require_rclpy, Peer};
use serde_json::{json, Value};
use sweepdepth::geometry::CameraModel;
use sweepdepth::image::Rgba8Image;
use sweepdepth::synthetic::{self, Scene};

const INNER: &str = "SWEEPDEPTH_TEST_PRIVATE_NETNS_RCLPY";
const DOMAIN: &str = "48";
const NAMESPACE: &str = "/rig";
const NODE_FQN: &str = "/rig/sweepdepth";
const CAMERAS: usize = 4;
const EXPECTED_DEPTH_M: f64 = 2.0;
const TOLERANCE: f64 = 0.02;
/// How long the peer waits for the depth of one set before it sends the next: the tests' one
/// limit (`SWEEPDEPTH_TEST_TIMEOUT_S`).
fn set_timeout_s() -> f64 {
    rclpy::test_timeout().as_secs_f64()
}

/// The heavy tests one at a time (each runs the engine on both cores).
static SERIAL: Mutex<()> = Mutex::new(());

fn run(test_name: &str, body: impl FnOnce()) {
    require_rclpy();
    let _one_at_a_time = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    in_private_netns(INNER, test_name, body);
}

#[test]
fn rclpy_graph_parameters_rosout_diagnostics_sigint() {
    run(
        "node_rclpy::rclpy_graph_parameters_rosout_diagnostics_sigint",
        graph_parameters_rosout_diagnostics_sigint,
    );
}

#[test]
fn rclpy_sim_time_from_clock() {
    run("node_rclpy::rclpy_sim_time_from_clock", sim_time_from_clock);
}

#[test]
fn rclpy_fuse_sim_time_from_a_remapped_clock() {
    run(
        "node_rclpy::rclpy_fuse_sim_time_from_a_remapped_clock",
        fuse_sim_time_from_a_remapped_clock,
    );
}

#[test]
fn rclpy_depth_640x480_best_effort_driver() {
    run("node_rclpy::rclpy_depth_640x480_best_effort_driver", || {
        depth_run(640, 480, false)
    });
}

#[test]
fn rclpy_depth_640x480_reliable_driver() {
    run("node_rclpy::rclpy_depth_640x480_reliable_driver", || {
        depth_run(640, 480, true)
    });
}

#[test]
fn rclpy_depth_1280x960_best_effort_driver() {
    run(
        "node_rclpy::rclpy_depth_1280x960_best_effort_driver",
        || depth_run(1280, 960, false),
    );
}

#[test]
fn rclpy_depth_1280x960_reliable_driver() {
    run("node_rclpy::rclpy_depth_1280x960_reliable_driver", || {
        depth_run(1280, 960, true)
    });
}

#[test]
fn rclpy_compressed_jpeg_png_as_image_transport() {
    run(
        "node_rclpy::rclpy_compressed_jpeg_png_as_image_transport",
        compressed_as_image_transport,
    );
}

#[test]
fn rclpy_fusion_mesh_and_clear_map() {
    run(
        "node_rclpy::rclpy_fusion_mesh_and_clear_map",
        fusion_mesh_and_clear_map,
    );
}

/// Live fusion seen from rcl: the mesh's markers (visualization_msgs/MarkerArray, one
/// TRIANGLE_LIST per block) arrive at a default rclpy subscriber, lie on the wall at 2 m in
/// the reference image's frame, and `~/clear_map` (std_srvs/Trigger) empties the map with a
/// DELETEALL.
fn fusion_mesh_and_clear_map() {
    const SETS: u32 = 3;
    let dir = TempDir::new();
    let rig_file = write_scene(&dir.0, 160, 120, true, SETS);
    let spec_path = dir.0.join("rig.json");
    let mut spec: Value = serde_json::from_slice(&std::fs::read(&spec_path).unwrap()).unwrap();
    spec["mesh"] = json!(true);
    std::fs::write(&spec_path, serde_json::to_vec_pretty(&spec).unwrap()).unwrap();
    let mut node = Node::start(
        &rig_file,
        &[
            "input_qos_reliable:=true",
            "fusion:=true",
            "voxel_size:=0.04",
            "mesh_rate:=5.0",
        ],
    );
    let (sets, summary) = drive(&dir.0, &mut node, SETS);
    assert!(
        sets.iter().any(|s| s["received"] == true),
        "no depth came: {summary}"
    );
    let mesh = &summary["mesh"];
    eprintln!("mesh at the rclpy subscriber: {mesh}");
    assert!(
        mesh["blocks"].as_u64().unwrap_or(0) > 0,
        "no mesh blocks: {mesh}"
    );
    assert!(mesh["triangles"].as_u64().unwrap_or(0) > 50, "{mesh}");
    assert_eq!(mesh["colors_match"], true, "one colour per point: {mesh}");
    assert_eq!(mesh["types"], json!([11]), "TRIANGLE_LIST markers: {mesh}");
    assert_eq!(mesh["frames"], json!(["cam1_optical"]), "{mesh}");
    let z = mesh["z_median"].as_f64().unwrap();
    assert!(
        (z - EXPECTED_DEPTH_M).abs() <= 0.08,
        "the mesh's median z {z} m is not the wall's {EXPECTED_DEPTH_M} m within 2 voxels"
    );
    assert_eq!(mesh["clear_success"], true, "{mesh}");
    assert!(
        mesh["clear_message"]
            .as_str()
            .unwrap_or("")
            .contains("cleared"),
        "{mesh}"
    );
    assert!(mesh["deleteall"].as_u64().unwrap_or(0) >= 1, "{mesh}");
    assert_eq!(mesh["blocks_after_clear"], 0, "{mesh}");
}

/// A scratch directory removed on every exit path.
struct TempDir(PathBuf);

impl TempDir {
    fn new() -> Self {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.subsec_nanos())
            .unwrap_or(0);
        let dir =
            std::env::temp_dir().join(format!("sweepdepth-rclpy-{}-{nanos}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("create the temp dir");
        TempDir(dir)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn rgb(image: &Rgba8Image) -> Vec<u8> {
    let mut data = Vec::with_capacity(image.pixels.len() * 3);
    for &p in &image.pixels {
        let [r, g, b, _] = Rgba8Image::unpack(p);
        data.extend_from_slice(&[r, g, b]);
    }
    data
}

/// Renders the 4-camera row (10 cm apart, reference cam1) looking at a textured wall at 2 m and
/// writes the peer's `rig.json` with the raw rgb8 files, and the node's rig file `rig.yaml`.
fn write_scene(dir: &Path, width: u32, height: u32, reliable: bool, sets: u32) -> PathBuf {
    let model = CameraModel::pinhole(synthetic::intrinsics(width, height));
    let rig = synthetic::row_rig(CAMERAS, 0.1, model, 1).expect("rig");
    let scene = Scene::wall_and_box(EXPECTED_DEPTH_M, None, model.intrinsics.fx_px);
    let images = synthetic::render_rig(&scene, &rig);
    let mut cameras = Vec::new();
    let mut yaml = String::from("rig_frame: rig\ncameras:\n");
    for (i, cam) in rig.cameras.iter().enumerate() {
        let file = format!("cam{i}.raw");
        std::fs::write(dir.join(&file), rgb(&images[i])).expect("write image");
        let k = cam.model.intrinsics;
        let c = cam.centre_in_rig();
        cameras.push(json!({
            "name": format!("cam{i}"),
            "frame_id": format!("cam{i}_optical"),
            "image_file": file,
            "k": [k.fx_px, 0.0, k.cx_px, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 1.0],
            "p": [k.fx_px, 0.0, k.cx_px, 0.0, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 0.0, 1.0, 0.0],
        }));
        yaml.push_str(&format!(
            "  - name: cam{i}\n    translation: [{}, {}, {}]\n    rotation: [0.0, 0.0, 0.0, 1.0]\n",
            c.x, c.y, c.z
        ));
    }
    let spec = json!({
        "namespace": NAMESPACE,
        "width": width,
        "height": height,
        "expected_depth_m": EXPECTED_DEPTH_M,
        "tolerance": TOLERANCE,
        "sets": sets,
        "set_timeout_s": set_timeout_s(),
        "period_s": 0.1,
        "image_reliable": reliable,
        "cameras": cameras,
    });
    std::fs::write(
        dir.join("rig.json"),
        serde_json::to_vec_pretty(&spec).unwrap(),
    )
    .expect("write rig.json");
    let rig_file = dir.join("rig.yaml");
    std::fs::write(&rig_file, yaml).expect("write rig.yaml");
    rig_file
}

/// The node under test with its stderr lines kept.
struct Node {
    child: KillOnDrop,
    log: Arc<Mutex<Vec<String>>>,
}

impl Node {
    fn start(rig_file: &Path, extra: &[&str]) -> Node {
        let mut args: Vec<String> = [
            "node",
            "--ros-args",
            "-r",
            &format!("__ns:={NAMESPACE}"),
            "-p",
            "cameras:=[cam0, cam1, cam2, cam3]",
            "-p",
            "reference_camera:=cam1",
            "-p",
            // A narrow range around the wall: 24 planes, steps of 1.6 % in depth at 2 m, so
            // that 1280x960 runs in reasonable time on a software adapter.
            "min_depth:=1.6",
            "-p",
            "max_depth:=2.6",
            "-p",
            "optimizer:=wta",
            "-p",
            "num_planes:=24",
            "-p",
            "window_width:=5",
            "-p",
            "window_height:=5",
            "-p",
            "sync:=exact",
            // The peer sends a set only after the previous depth arrived, so its cameras are
            // silent while the engine runs: they must not leave the rig for it.
            "-p",
            "camera_timeout:=0.0",
            "-p",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        args.push(format!("rig_file:={}", rig_file.display()));
        for p in extra {
            args.push("-p".into());
            args.push(p.to_string());
        }
        Node::spawn(&args)
    }

    /// `sweepdepth` with these arguments, in the tests' domain.
    fn spawn(args: &[String]) -> Node {
        let mut child = Command::new(env!("CARGO_BIN_EXE_sweepdepth"))
            .args(args)
            .env("ROS_DOMAIN_ID", DOMAIN)
            .env(
                "RUST_LOG",
                std::env::var("RUST_LOG").unwrap_or_else(|_| "warn,sweepdepth=info".into()),
            )
            .stdin(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start the node");
        let stderr = child.stderr.take().expect("node stderr");
        let log = Arc::new(Mutex::new(Vec::new()));
        let sink = Arc::clone(&log);
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                eprintln!("[node] {line}");
                sink.lock().unwrap_or_else(|e| e.into_inner()).push(line);
            }
        });
        Node {
            child: KillOnDrop(child),
            log,
        }
    }

    fn lines(&self) -> Vec<String> {
        self.log.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }
}

/// Runs the peer's `drive` over `dir` and returns its summary, checking every set received.
fn drive(dir: &Path, node: &mut Node, sets: u32) -> (Vec<Value>, Value) {
    let dir_arg = dir.to_string_lossy().into_owned();
    let mut peer = Peer::start("rclpy driver", DOMAIN, &["drive", &dir_arg], &[]);
    let mut results = Vec::new();
    // The peer bounds each set by the one limit; the whole drive by one limit more.
    let deadline = rclpy::test_timeout() * (sets + 1);
    let started = Instant::now();
    let summary = loop {
        if let Some(status) = node.child.0.try_wait().expect("poll the node") {
            panic!("the node exited during the run ({status}); see its output above");
        }
        let v = peer.wait_for(
            deadline.saturating_sub(started.elapsed()),
            "the drive summary",
            |_| true,
            |_| {},
        );
        match event(&v) {
            "set" => {
                eprintln!("set {}: {}", v["k"], v);
                results.push(v);
            }
            "summary" => break v,
            _ => eprintln!("peer: {v}"),
        }
    };
    (results, summary)
}

fn depth_run(width: u32, height: u32, reliable: bool) {
    const SETS: u32 = 10;
    let dir = TempDir::new();
    let rig_file = write_scene(&dir.0, width, height, reliable, SETS);
    let qos = if reliable { "reliable" } else { "best_effort" };
    // The node subscribes best effort by default (matches both drivers); reliable on request.
    let reliable_input = format!("input_qos_reliable:={reliable}");
    let mut node = Node::start(&rig_file, &[&reliable_input]);
    let (sets, summary) = drive(&dir.0, &mut node, SETS);
    let received: Vec<&Value> = sets.iter().filter(|s| s["received"] == true).collect();
    // A best-effort set without depth after a few seconds is sent again by the peer (same
    // stamps: the node drops what it already has as duplicates), so a lost image does not
    // lose the set; how often that happened is reported, not judged.
    let resent = sets
        .iter()
        .filter(|s| s["resends"].as_u64().unwrap_or(0) > 0)
        .count();
    eprintln!(
        "{width}x{height} rgb8, {qos} driver: {} of {SETS} depth images ({resent} sets sent again while waiting: a lost best-effort image, or a slow node); latency from the node's publish to the default rclpy subscriber: median {} ms, max {} ms",
        received.len(),
        summary["latency_median_ms"],
        summary["latency_max_ms"]
    );
    assert!(
        received.len() as u32 * 10 >= SETS * 9,
        "only {} of {SETS} sets gave a depth image at the rclpy subscriber ({qos} driver, {width}x{height})",
        received.len()
    );
    for s in &received {
        assert_eq!(s["encoding"], "32FC1");
        assert_eq!(s["width"], width);
        assert_eq!(s["height"], height);
        assert_eq!(s["frame_id"], "cam1_optical");
        let total = s["total"].as_u64().unwrap();
        let valid = s["valid"].as_u64().unwrap();
        let within = s["within"].as_u64().unwrap();
        assert!(
            valid * 2 >= total,
            "set {}: only {valid} of {total} depths valid",
            s["k"]
        );
        assert!(
            within * 10 >= valid * 9,
            "set {}: only {within} of {valid} valid depths within 2 % of {EXPECTED_DEPTH_M} m (median {})",
            s["k"],
            s["median_m"]
        );
    }
}

/// The sets of one run of the wall at 320x240 by a reliable driver publishing `encoding`,
/// raw or `compressed` (`jpeg`, `png`) as image_transport's compressed plugin does, to a node
/// with the matching `image_transport`; every set must give depth.
fn wall_run(encoding: &str, compressed: Option<&str>, sets: u32) -> Vec<Value> {
    let dir = TempDir::new();
    let rig_file = write_scene(&dir.0, 320, 240, true, sets);
    let spec_path = dir.0.join("rig.json");
    let mut spec: Value =
        serde_json::from_slice(&std::fs::read(&spec_path).expect("rig.json")).expect("json");
    spec["encoding"] = json!(encoding);
    if let Some(codec) = compressed {
        spec["compressed"] = json!(codec);
    }
    std::fs::write(&spec_path, serde_json::to_vec_pretty(&spec).unwrap()).expect("rig.json");
    let transport = if compressed.is_some() {
        "image_transport:=compressed"
    } else {
        "image_transport:=raw"
    };
    let mut node = Node::start(&rig_file, &["input_qos_reliable:=true", transport]);
    let (results, _) = drive(&dir.0, &mut node, sets);
    let received: Vec<Value> = results
        .into_iter()
        .filter(|s| s["received"] == true)
        .collect();
    assert_eq!(
        received.len() as u32,
        sets,
        "{encoding} {compressed:?}: not every set gave depth"
    );
    received
}

/// rclpy publishing `sensor_msgs/CompressedImage` made by OpenCV's `imencode` as
/// image_transport's compressed plugin makes it (JPEG quality 95, PNG level 3; colour through
/// bgr8) on `<cam>/image_raw/compressed`: the node's depth of the wall equals the raw run's
/// within JPEG's noise, for rgb8, bgr8 and mono8 sources.
fn compressed_as_image_transport() {
    const SETS: u32 = 2;
    let stat = |s: &Value, key: &str| s[key].as_f64().unwrap_or(f64::NAN);
    let raw = wall_run("rgb8", None, SETS);
    let raw_median = stat(&raw[0], "median_m");
    let raw_valid = stat(&raw[0], "valid");
    for (encoding, codec) in [
        ("rgb8", "jpeg"),
        ("bgr8", "jpeg"),
        ("mono8", "jpeg"),
        ("bgr8", "png"),
    ] {
        for s in wall_run(encoding, Some(codec), SETS) {
            let (median, valid, within) =
                (stat(&s, "median_m"), stat(&s, "valid"), stat(&s, "within"));
            eprintln!(
                "{encoding} {codec}: median {median:.4} m (raw {raw_median:.4}), valid {valid} (raw {raw_valid}), within 2 % of the wall: {:.1} %",
                100.0 * within / valid
            );
            assert!(
                (median - raw_median).abs() <= 0.01 * raw_median,
                "{encoding} {codec}: median {median} m, raw {raw_median} m"
            );
            assert!(
                valid >= 0.9 * raw_valid,
                "{encoding} {codec}: {valid} valid depths, raw {raw_valid}"
            );
            assert!(
                within >= 0.9 * valid,
                "{encoding} {codec}: {within} of {valid} within 2 % of the wall"
            );
        }
    }
}

fn names(v: &Value) -> Vec<String> {
    v.as_array()
        .map(|a| {
            a.iter()
                .filter_map(|x| x.as_str().map(String::from))
                .collect()
        })
        .unwrap_or_default()
}

fn graph_parameters_rosout_diagnostics_sigint() {
    let dir = TempDir::new();
    let rig_file = write_scene(&dir.0, 160, 120, false, 3);
    let mut node = Node::start(&rig_file, &[]);
    let (sets, summary) = drive(&dir.0, &mut node, 3);
    assert!(
        sets.iter().any(|s| s["received"] == true),
        "no depth image reached the rclpy subscriber"
    );

    // /rosout: the node's own log lines, under its logger name.
    let rosout = summary["rosout"].as_array().cloned().unwrap_or_default();
    assert!(
        rosout.iter().any(|l| l["name"] == "rig.sweepdepth"
            && l["msg"].as_str().unwrap_or("").contains("published")),
        "no '/rosout' line of rig.sweepdepth saying it published; got {rosout:?}"
    );
    // /diagnostics: a status of the node once a second.
    let diagnostics = summary["diagnostics"]
        .as_array()
        .cloned()
        .unwrap_or_default();
    assert!(
        diagnostics
            .iter()
            .any(|d| d["name"].as_str().unwrap_or("").contains("sweepdepth")),
        "no /diagnostics status of the node; got {diagnostics:?}"
    );

    // The graph and the parameter services as rcl sees them.
    let mut peer = Peer::start("rclpy probe", DOMAIN, &["probe", NODE_FQN], &[]);
    let probe = peer.wait_for(
        rclpy::test_timeout(),
        "the probe result",
        |v| event(v) == "probe",
        |_| {},
    );
    let nodes = probe["nodes"].as_array().cloned().unwrap_or_default();
    assert!(
        nodes.contains(&json!(["sweepdepth", "/rig"])),
        "rcl does not see the node /rig/sweepdepth; nodes: {nodes:?}"
    );
    let topics = &probe["topics"];
    for (topic, ty) in [
        ("/rig/depth/image", "sensor_msgs/msg/Image"),
        ("/rig/depth/camera_info", "sensor_msgs/msg/CameraInfo"),
        ("/rig/confidence/image", "sensor_msgs/msg/Image"),
        ("/rig/cost/image", "sensor_msgs/msg/Image"),
        ("/rig/selection/image", "sensor_msgs/msg/Image"),
        ("/rig/cam0/image_raw", "sensor_msgs/msg/Image"),
        ("/rig/cam3/camera_info", "sensor_msgs/msg/CameraInfo"),
        ("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray"),
        ("/rosout", "rcl_interfaces/msg/Log"),
    ] {
        assert_eq!(
            names(&topics[topic]),
            vec![ty.to_string()],
            "topic {topic}: types {}",
            topics[topic]
        );
    }
    // As an rcl node's: one /parameter_events writer (rcl's, here the node's own), and no
    // /clock reader without use_sim_time (ros2-client 0.12.1 alone adds a second writer and a
    // /clock reader of builtin_interfaces/Time: vendor/ros2-client). Nothing else here reads
    // or writes /clock, so the topic is not in the graph at all.
    let ours_on = |kind: &str, topic: &str| -> Vec<Value> {
        probe[kind][topic]
            .as_array()
            .cloned()
            .unwrap_or_default()
            .into_iter()
            .filter(|p| p["node_name"] == "sweepdepth" && p["node_namespace"] == "/rig")
            .collect()
    };
    let events = ours_on("publishers", "/parameter_events");
    assert_eq!(
        events.len(),
        1,
        "the node's /parameter_events writers: {events:?}"
    );
    assert_eq!(events[0]["qos"]["durability"], "VOLATILE", "{events:?}");
    for types in [&topics["/clock"], &probe["clock_types_late"]] {
        assert!(names(types).is_empty(), "/clock's types: {types}");
    }
    let late = probe["clock_readers_late"].as_array().cloned();
    assert_eq!(late, Some(Vec::new()), "/clock's readers: {probe}");
    let depth_pubs = probe["publishers"]["/rig/depth/image"]
        .as_array()
        .cloned()
        .unwrap_or_default();
    let ours: Vec<&Value> = depth_pubs
        .iter()
        .filter(|p| p["node_name"] == "sweepdepth")
        .collect();
    assert_eq!(
        ours.len(),
        1,
        "publishers of /rig/depth/image: {depth_pubs:?}"
    );
    assert_eq!(ours[0]["node_namespace"], "/rig");
    assert_eq!(ours[0]["qos"]["reliability"], "RELIABLE");
    let image_subs = probe["subscriptions"]["/rig/cam0/image_raw"]
        .as_array()
        .cloned()
        .unwrap_or_default();
    let ours: Vec<&Value> = image_subs
        .iter()
        .filter(|p| p["node_name"] == "sweepdepth")
        .collect();
    assert_eq!(
        ours.len(),
        1,
        "subscriptions of /rig/cam0/image_raw: {image_subs:?}"
    );
    assert_eq!(
        ours[0]["qos"]["reliability"], "BEST_EFFORT",
        "camera inputs subscribe best effort (sensor data), matching both kinds of driver"
    );

    let params = &probe["parameters"];
    assert_eq!(params["num_planes"], 24);
    assert_eq!(params["cameras"], json!(["cam0", "cam1", "cam2", "cam3"]));
    assert_eq!(params["optimizer"], "wta");
    let sets = &probe["sets"];
    assert_eq!(
        sets["num_planes=20"]["successful"], true,
        "{}",
        sets["num_planes=20"]
    );
    for refused in ["num_planes=1", "num_planes='many'", "cameras=[a, b]"] {
        assert_eq!(
            sets[refused]["successful"], false,
            "{refused}: {}",
            sets[refused]
        );
        assert!(
            !sets[refused]["reason"].as_str().unwrap_or("").is_empty(),
            "{refused} refused without a reason"
        );
    }
    assert_eq!(probe["after"]["num_planes"], 20);
    assert_eq!(
        probe["after"]["cameras"],
        json!(["cam0", "cam1", "cam2", "cam3"])
    );
    // describe_parameters and get_parameter_types: our table, as an rclcpp node that
    // declared it would answer.
    let descriptors = probe["descriptors"]
        .as_object()
        .cloned()
        .unwrap_or_default();
    assert_eq!(
        descriptors.len(),
        params.as_object().map_or(0, |p| p.len()),
        "one descriptor per parameter"
    );
    for spec in sweepdepth::params::param_table() {
        let d = &descriptors[spec.name];
        assert_eq!(d["description"], spec.description, "{}: {d}", spec.name);
        assert_eq!(d["read_only"], spec.read_only, "{}: {d}", spec.name);
        assert_eq!(d["type"], probe["types"][spec.name], "{}: {d}", spec.name);
    }
    // Integer and floating-point ranges with their step (rcl_interfaces' FloatingPointRange
    // and IntegerRange: from_value, to_value, step).
    let num_planes = &descriptors["num_planes"];
    assert_eq!(num_planes["type"], 2, "integer: {num_planes}");
    assert_eq!(num_planes["read_only"], false, "live: {num_planes}");
    assert_eq!(num_planes["integer_range"], json!([[2, 4096, 1]]));
    let sgm_p1 = &descriptors["sgm_p1"];
    assert_eq!(sgm_p1["type"], 3, "double: {sgm_p1}");
    assert_eq!(sgm_p1["floating_point_range"][0][0], 0.0, "{sgm_p1}");
    assert_eq!(
        sgm_p1["floating_point_range"][0][2], 0.0,
        "continuous: {sgm_p1}"
    );
    let cameras = &descriptors["cameras"];
    assert_eq!(cameras["type"], 9, "string array: {cameras}");
    assert_eq!(cameras["read_only"], true, "fixed at start: {cameras}");
    eprintln!(
        "describe_parameters: num_planes {} / cameras {}",
        descriptors["num_planes"], descriptors["cameras"]
    );

    // SIGINT: exit status 0 (what it logs on the way out is reported, issue 12 item 7).
    let status = Command::new("kill")
        .args(["-INT", &node.child.0.id().to_string()])
        .status()
        .expect("kill");
    assert!(status.success());
    let sent = Instant::now();
    let exit = loop {
        if let Some(s) = node.child.0.try_wait().expect("poll the node") {
            break s;
        }
        assert!(
            sent.elapsed() < rclpy::test_timeout(),
            "the node did not stop within {:?} of SIGINT",
            rclpy::test_timeout()
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    let stopped = sent.elapsed();
    std::thread::sleep(Duration::from_millis(200));
    let errors: Vec<String> = node
        .lines()
        .into_iter()
        .filter(|l| l.contains("ERROR"))
        .collect();
    eprintln!(
        "SIGINT: exit {exit} after {stopped:?}; {} ERROR lines: {errors:#?}",
        errors.len()
    );
    assert_eq!(exit.code(), Some(0), "exit status after SIGINT: {exit}");
}

/// `use_sim_time:=true` and a simulator's `/clock` (rclpy, rosgraph_msgs/Clock): the node's
/// `/diagnostics` and `/rosout` are stamped in simulated time; `ros2 param set use_sim_time
/// false` brings them back to the system clock and takes the node's `/clock` reader out of the
/// graph (as an rcl node's time source); switched on again, a new reader brings the time from
/// `/clock` again.
fn sim_time_from_clock() {
    let dir = TempDir::new();
    let rig_file = write_scene(&dir.0, 160, 120, false, 1);
    let node = Node::start(&rig_file, &["use_sim_time:=true"]);
    let mut peer = Peer::start("rclpy clock", DOMAIN, &["clock", NODE_FQN], &[]);
    let v = peer.wait_for(
        rclpy::test_timeout() * 2,
        "the clock result",
        |v| event(v) == "clock",
        |_| {},
    );
    const SIM_BASE_NS: i64 = 1000 * 1_000_000_000;
    // 2020-09-13: any system clock this test runs on is past it.
    const WALL_ERA_NS: i64 = 1_600_000_000 * 1_000_000_000;
    let ns = |d: &Value, key: &str| d[key].as_i64().unwrap_or(-1);
    // Before the node's first /clock, rcl's simulated time is zero; after, the clock's time:
    // one the peer sent, so never later than the peer's clock when the message arrived (no
    // bound on how long before: nothing here depends on the machine's pace).
    let sim = v["sim_diagnostics"].as_array().cloned().unwrap_or_default();
    let simulated: Vec<&Value> = sim
        .iter()
        .filter(|d| ns(d, "stamp_ns") >= SIM_BASE_NS)
        .collect();
    assert!(simulated.len() >= 2, "{v}");
    for d in &sim {
        let (stamp, now) = (ns(d, "stamp_ns"), ns(d, "sim_ns"));
        assert!(
            stamp == 0 || (stamp >= SIM_BASE_NS && stamp <= now),
            "a /diagnostics stamp {stamp} ns received at simulated {now} ns: {v}"
        );
    }
    assert_eq!(v["set_planes"]["successful"], true, "{v}");
    let line = v["rosout"]
        .as_array()
        .and_then(|lines| {
            lines
                .iter()
                .find(|l| l["msg"].as_str().unwrap_or("").contains("num_planes"))
        })
        .cloned()
        .unwrap_or_default();
    let (stamp, now) = (ns(&line, "stamp_ns"), ns(&line, "sim_ns"));
    assert!(
        stamp >= SIM_BASE_NS && stamp <= now,
        "the /rosout line of num_planes at {stamp} ns, simulated now {now} ns: {v}"
    );
    // rcl stamps /parameter_events on the node's clock: simulated time here.
    let entry = v["parameter_events"]
        .as_array()
        .and_then(|events| {
            events.iter().find(|e| {
                e["changed"]
                    .as_array()
                    .is_some_and(|c| c.iter().any(|n| n == "num_planes"))
            })
        })
        .cloned()
        .unwrap_or_default();
    let (stamp, now) = (ns(&entry, "stamp_ns"), ns(&entry, "sim_ns"));
    assert!(
        stamp >= SIM_BASE_NS && stamp <= now,
        "the /parameter_events entry of num_planes at {stamp} ns, simulated now {now} ns: {v}"
    );
    assert_eq!(v["use_sim_time"], true, "{v}");
    assert_eq!(v["set_false"]["successful"], true, "{v}");
    let wall = v["wall_diagnostics"]
        .as_array()
        .cloned()
        .unwrap_or_default();
    let on_wall: Vec<&Value> = wall
        .iter()
        .filter(|d| ns(d, "stamp_ns") > WALL_ERA_NS && ns(d, "stamp_ns") <= ns(d, "wall_ns"))
        .collect();
    assert!(on_wall.len() >= 2, "{v}");
    // One reader of /clock while on, of the one type, best effort (rclcpp's ClockQoS; DDS
    // discovery does not carry the history's depth); none once off (the peer waited for that); one again once on.
    for key in ["clock_readers_on", "clock_readers_again"] {
        let readers = v[key].as_array().cloned().unwrap_or_default();
        assert_eq!(readers.len(), 1, "{key}: {v}");
        assert_eq!(readers[0]["topic_type"], "rosgraph_msgs/msg/Clock", "{v}");
        assert_eq!(readers[0]["qos"]["reliability"], "BEST_EFFORT", "{v}");
    }
    assert_eq!(v["set_true"]["successful"], true, "{v}");
    // After the switch on, a stamp from a /clock message the new reader took: at or after
    // the simulated time of the switch (the time kept from before is earlier).
    let switched_on = ns(&v, "switched_on_ns");
    let again = v["sim_again_diagnostics"]
        .as_array()
        .cloned()
        .unwrap_or_default();
    assert!(
        again.iter().any(|d| {
            let stamp = ns(d, "stamp_ns");
            stamp >= switched_on && stamp <= ns(d, "sim_ns")
        }),
        "no /diagnostics from /clock after use_sim_time was switched on again: {v}"
    );
    assert!(
        node.lines()
            .iter()
            .any(|l| l.contains("use_sim_time") && l.contains("system clock")),
        "no log line of the switch"
    );
    let errors: Vec<String> = node
        .lines()
        .into_iter()
        .filter(|l| l.contains("ERROR"))
        .collect();
    assert!(errors.is_empty(), "{errors:?}");
}

/// `sweepdepth fuse` with `use_sim_time:=true` and `/clock` remapped (`-r /clock:=/sim/clock`):
/// its `/diagnostics` are stamped from the remapped clock, never from a second clock on `/clock`
/// (the peer runs both: 1000 s on, 5000 s on); one reader, of the remapped clock; as an rcl
/// node, one `/parameter_events` writer, reliable and volatile, and its parameters served
/// (listed, read, described read-only, a set refused with the reason); `use_sim_time` set
/// false at run time: its reader leaves the graph, `/diagnostics` in wall time, the event.
fn fuse_sim_time_from_a_remapped_clock() {
    const FQN: &str = "/fused/sweepdepth_fuse";
    let args = [
        "fuse",
        "--ros-args",
        "-r",
        "__ns:=/fused",
        "-p",
        "depth_topics:=[/a/depth/image]",
        "-p",
        "world_frame:=map",
        "-p",
        "use_sim_time:=true",
        "-r",
        "/clock:=/sim/clock",
    ];
    let node = Node::spawn(&args.map(String::from));
    let mut peer = Peer::start(
        "rclpy fuse clock",
        DOMAIN,
        &["fuse-clock", FQN, "/sim/clock"],
        &[],
    );
    let v = peer.wait_for(
        rclpy::test_timeout() * 2,
        "the fuse-clock result",
        |v| event(v) == "fuse-clock",
        |_| {},
    );
    const SIM_BASE_NS: i64 = 1000 * 1_000_000_000;
    const DECOY_BASE_NS: i64 = 5000 * 1_000_000_000;
    let ns = |d: &Value, key: &str| d[key].as_i64().unwrap_or(-1);
    let all = v["diagnostics"].as_array().cloned().unwrap_or_default();
    let simulated = all
        .iter()
        .filter(|d| ns(d, "stamp_ns") >= SIM_BASE_NS)
        .count();
    assert!(simulated >= 2, "{v}");
    for d in &all {
        let (stamp, now) = (ns(d, "stamp_ns"), ns(d, "sim_ns"));
        // Zero before the first message of the remapped clock, then one of its times.
        assert!(
            stamp == 0 || (stamp >= SIM_BASE_NS && stamp <= now && stamp < DECOY_BASE_NS),
            "a /diagnostics stamp {stamp} ns received at simulated {now} ns: {v}"
        );
    }
    let endpoints = |key: &str| v[key].as_array().cloned().unwrap_or_default();
    let writers = endpoints("parameter_events_writers");
    assert_eq!(writers.len(), 1, "{v}");
    assert_eq!(writers[0]["qos"]["reliability"], "RELIABLE", "{v}");
    assert_eq!(writers[0]["qos"]["durability"], "VOLATILE", "{v}");
    let clocks = endpoints("clock_readers");
    assert_eq!(clocks.len(), 1, "{v}");
    assert_eq!(clocks[0]["topic_type"], "rosgraph_msgs/msg/Clock", "{v}");
    assert!(endpoints("decoy_readers").is_empty(), "{v}");
    // Its parameters, as an rcl node serves them: those it uses and use_sim_time, read-only
    // but use_sim_time.
    let mut expected: Vec<&str> = sweepdepth::node::fuse_command::FUSE_PARAMS.to_vec();
    expected.push("use_sim_time");
    expected.sort();
    assert_eq!(names(&v["names"]), expected, "{v}");
    assert_eq!(
        v["values"]["depth_topics"],
        json!(["/a/depth/image"]),
        "{v}"
    );
    assert_eq!(v["values"]["world_frame"], "map", "{v}");
    assert_eq!(v["values"]["use_sim_time"], true, "{v}");
    assert!(
        v["values"]["voxel_size"].as_f64().is_some_and(|x| x > 0.0),
        "{v}"
    );
    for name in &expected {
        let read_only = *name != "use_sim_time";
        assert_eq!(v["read_only"][name], read_only, "{name}: {v}");
    }
    assert_eq!(v["set_voxel"]["successful"], false, "{v}");
    let reason = v["set_voxel"]["reason"].as_str().unwrap_or("");
    assert!(reason.contains("read-only"), "{v}");
    assert_eq!(v["voxel_after"], v["values"]["voxel_size"], "{v}");
    // use_sim_time off at run time: the system clock's stamps, the remapped clock's reader
    // gone (the peer waited for both), and the change on /parameter_events.
    assert_eq!(v["set_false"]["successful"], true, "{v}");
    let wall = v["wall_diagnostics"].as_array().map_or(0, |a| {
        a.iter()
            .filter(|d| ns(d, "stamp_ns") > 1_600_000_000 * 1_000_000_000)
            .count()
    });
    assert!(wall >= 2, "{v}");
    let changed: Vec<Value> = v["parameter_events"]
        .as_array()
        .into_iter()
        .flatten()
        .flat_map(|e| e["changed"].as_array().cloned().unwrap_or_default())
        .collect();
    assert_eq!(changed, [json!(["use_sim_time", false])], "{v}");
    let errors: Vec<String> = node
        .lines()
        .into_iter()
        .filter(|l| l.contains("ERROR"))
        .collect();
    assert!(errors.is_empty(), "{errors:?}");
}
