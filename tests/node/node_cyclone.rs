//! Interoperability test of `sweepdepth node` against an independent DDS implementation:
//! `tools/cyclone_peer.py`, a fake ROS 2 camera driver on Eclipse Cyclone DDS (the `cyclonedds`
//! Python package), publishes the images, camera_info and /tf_static of a synthetic 3-camera
//! row rig exactly as rclcpp + rmw_cyclonedds would, and reports the depth image it receives.
//! Nothing in the node knows about Cyclone; this only checks the wire.
//!
//! Requires `python3` with `cyclonedds` (`python3 -m pip install cyclonedds`; the wheel bundles
//! libddsc). Missing is a FAILURE, not a skip.
//!
//! SAFETY: no DDS packet may leave the machine. The test never opens DDS (neither the node nor
//! the peer) in the host network namespace: unless it already runs inside the private namespace
//! it creates itself (marker variable [`INNER`] AND a check that only `lo` exists), it
//! re-executes its own binary inside `unshare -n` (`unshare -rn` when not root) with loopback up
//! and a multicast route on `lo`, and fails with a clear message if that is impossible. The peer
//! checks the interfaces again and Cyclone is pinned to `lo` through `CYCLONEDDS_URI`.

use crate::common::dds::{self, NodeProcess};
use crate::common::netns::{in_private_netns, KillOnDrop};
use crate::common::python::{python, INSTALL_HINT};

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use serde_json::{json, Value};
use sweepdepth::image::Rgba8Image;
use sweepdepth::synthetic::{self, Scene};

const INNER: &str = "SWEEPDEPTH_TEST_PRIVATE_NETNS_CYCLONE";
const DOMAIN: u16 = 43;
const NAMESPACE: &str = "/rig";
const WIDTH: u32 = 80;
const HEIGHT: u32 = 60;
const EXPECTED_DEPTH_M: f64 = 2.0;
const TOLERANCE: f64 = 0.02;
const RESULT_PREFIX: &str = "CYCLONE_PEER_RESULT ";
/// Cyclone restricted to loopback, multicast forced on (SPDP with RustDDS uses 239.255.0.1).
const CYCLONEDDS_URI: &str = "<CycloneDDS><Domain Id=\"any\"><General>\
    <Interfaces><NetworkInterface name=\"lo\" multicast=\"true\"/></Interfaces>\
    <AllowMulticast>true</AllowMulticast>\
    </General></Domain></CycloneDDS>";

fn peer_script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/cyclone_peer.py")
}

/// Fails (never skips) when the Cyclone DDS Python binding is not importable.
fn require_cyclonedds() {
    let py = python();
    let out = Command::new(&py)
        .args([
            "-c",
            "import cyclonedds.domain, cyclonedds.idl; print(cyclonedds.__file__)",
        ])
        .stdin(Stdio::null())
        .output();
    match out {
        Err(e) => panic!(
            "this test needs `{py}` with the `cyclonedds` package, but `{py}` cannot be started ({e}); install Python 3 and run `{INSTALL_HINT}`"
        ),
        Ok(o) if !o.status.success() => panic!(
            "this test needs the Eclipse Cyclone DDS Python binding, which `{py}` cannot import; run `{INSTALL_HINT}` (the wheel bundles libddsc). Python said:\n{}",
            String::from_utf8_lossy(&o.stderr)
        ),
        Ok(_) => {}
    }
}

/// Image and camera_info QoS of the peer's writers, as camera drivers use them.
#[derive(Clone, Copy, Debug)]
enum ImageQos {
    /// `rclcpp::SystemDefaultsQoS` / image_transport's default: reliable, keep last 10.
    Reliable,
    /// `rclcpp::SensorDataQoS`: best effort, keep last 5.
    BestEffort,
}

#[test]
fn node_interoperates_with_cyclone_dds_reliable_images() {
    run_in_private_netns(
        "node_cyclone::node_interoperates_with_cyclone_dds_reliable_images",
        ImageQos::Reliable,
    );
}

#[test]
fn node_interoperates_with_cyclone_dds_best_effort_images() {
    run_in_private_netns(
        "node_cyclone::node_interoperates_with_cyclone_dds_best_effort_images",
        ImageQos::BestEffort,
    );
}

/// A moving rig whose /tf comes from the Cyclone DDS peer (its own IDL types, tf2_ros's
/// broadcaster QoS, twice per set and never at a set's stamp): the pose the node gives the
/// reference's set (reported in /diagnostics) is the true pose at the set's stamp within 1 mm
/// and 0.05 degrees.
#[test]
fn node_poses_sets_from_cyclone_dds_tf() {
    require_cyclonedds();
    in_private_netns(
        INNER,
        "node_cyclone::node_poses_sets_from_cyclone_dds_tf",
        || end_to_end_with(ImageQos::Reliable, true),
    );
}

/// The rig's motion in "world" for the moving test (the peer's "world" entry).
const VELOCITY: [f64; 3] = [0.3, 0.0, 0.1];
const YAW_RATE: f64 = 0.1;

fn run_in_private_netns(test_name: &str, qos: ImageQos) {
    require_cyclonedds();
    in_private_netns(INNER, test_name, || end_to_end(qos));
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
            std::env::temp_dir().join(format!("sweepdepth-cyclone-{}-{nanos}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("create the temp dir");
        TempDir(dir)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Packed 3-byte pixels, as in a `rgb8` / `bgr8` `sensor_msgs/Image`.
fn packed(image: &Rgba8Image, bgr: bool) -> Vec<u8> {
    let mut data = Vec::with_capacity(image.pixels.len() * 3);
    for &p in &image.pixels {
        let [r, g, b, _] = Rgba8Image::unpack(p);
        data.extend_from_slice(&if bgr { [b, g, r] } else { [r, g, b] });
    }
    data
}

/// Renders the rig and writes `rig.json` + raw pixel files for the peer.
fn write_rig(dir: &Path, qos: ImageQos, moving: bool) {
    let model = sweepdepth::geometry::CameraModel::pinhole(synthetic::intrinsics(WIDTH, HEIGHT));
    let rig = synthetic::row_rig(3, 0.1, model, 1).expect("rig");
    let scene = Scene::wall_and_box(EXPECTED_DEPTH_M, None, model.intrinsics.fx_px);
    let images = synthetic::render_rig(&scene, &rig);
    let mut cameras = Vec::new();
    for (i, cam) in rig.cameras.iter().enumerate() {
        // The last camera sends bgr8 to exercise the conversion, as in node_dds.rs.
        let bgr = i == 2;
        let file = format!("cam{i}.raw");
        std::fs::write(dir.join(&file), packed(&images[i], bgr)).expect("write image");
        let k = cam.model.intrinsics;
        let c = cam.centre_in_rig();
        cameras.push(json!({
            "name": format!("cam{i}"),
            "frame_id": format!("cam{i}_optical"),
            "encoding": if bgr { "bgr8" } else { "rgb8" },
            "image_file": file,
            "k": [k.fx_px, 0.0, k.cx_px, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 1.0],
            "p": [k.fx_px, 0.0, k.cx_px, 0.0, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 0.0, 1.0, 0.0],
            "translation": [c.x, c.y, c.z],
            "rotation_xyzw": [0.0, 0.0, 0.0, 1.0],
        }));
    }
    let mut spec = json!({
        "domain_id": DOMAIN,
        "namespace": NAMESPACE,
        "rig_frame": "rig",
        "width": WIDTH,
        "height": HEIGHT,
        "expected_depth_m": EXPECTED_DEPTH_M,
        "tolerance": TOLERANCE,
        "timeout_s": dds::timeout().as_secs(),
        "period_s": 0.1,
        "image_reliable": matches!(qos, ImageQos::Reliable),
        "image_qos_depth": match qos {
            ImageQos::Reliable => 10,
            ImageQos::BestEffort => 5,
        },
        "cameras": cameras,
    });
    if moving {
        spec["world"] = json!({ "frame": "world", "velocity": VELOCITY, "yaw_rate": YAW_RATE });
    }
    std::fs::write(
        dir.join("rig.json"),
        serde_json::to_vec_pretty(&spec).unwrap(),
    )
    .expect("write rig.json");
}

fn end_to_end(qos: ImageQos) {
    end_to_end_with(qos, false)
}

fn end_to_end_with(qos: ImageQos, moving: bool) {
    let dir = TempDir::new();
    write_rig(&dir.0, qos, moving);
    let started = Instant::now();

    let ns = format!("__ns:={NAMESPACE}");
    let mut args = vec![
        "-r",
        &ns,
        "-p",
        "cameras:=[cam0, cam1, cam2]",
        "-p",
        "min_depth:=1.0",
        "-p",
        "max_depth:=4.0",
        "-p",
        "num_planes:=48",
        "-p",
        "sync:=exact",
    ];
    if moving {
        args.extend(["-p", "world_frame:=world", "-p", "tf_timeout:=5.0"]);
    }
    let mut node = NodeProcess::start(DOMAIN, &args);
    // The node's /diagnostics, read by a ros2-client peer (the poses of a moving rig).
    let mut probe = moving.then(|| dds::Peer::new(DOMAIN, "sweepdepth_pose_probe"));
    let mut diagnostics = probe.as_mut().map(dds::Diagnostics::new);

    let peer = Command::new(python())
        .arg("-u")
        .arg(peer_script())
        .arg(&dir.0)
        .env("CYCLONEDDS_URI", CYCLONEDDS_URI)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .spawn()
        .expect("start the Cyclone DDS peer (python3 tools/cyclone_peer.py)");
    let mut peer = KillOnDrop(peer);

    // Forward the peer's stdout and pick out the result line.
    let stdout = peer.0.stdout.take().expect("peer stdout");
    let (tx, rx) = mpsc::channel::<String>();
    let reader = std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            eprintln!("[cyclone_peer] {line}");
            if let Some(rest) = line.strip_prefix(RESULT_PREFIX) {
                let _ = tx.send(rest.to_string());
            }
        }
    });

    // The peer gives up after dds::timeout() without a depth image (exit 2); this is later.
    let peer_timeout = dds::timeout();
    let deadline = peer_timeout + Duration::from_secs(30);
    let mut result = None;
    while result.is_none() {
        if let Ok(line) = rx.recv_timeout(Duration::from_millis(50)) {
            result = Some(line);
            break;
        }
        node.check_alive();
        if let Some(status) = peer.0.try_wait().expect("poll peer") {
            // Drain a result printed just before exiting.
            if let Ok(line) = rx.recv_timeout(Duration::from_millis(500)) {
                result = Some(line);
                break;
            }
            match status.code() {
                Some(4) => panic!(
                    "the peer cannot import cyclonedds; run `{INSTALL_HINT}`"
                ),
                Some(2) => panic!(
                    "the Cyclone DDS peer got no depth image from the node within {peer_timeout:?} ({status}); see its output above"
                ),
                _ => panic!("the Cyclone DDS peer exited without a result: {status}"),
            }
        }
        assert!(
            started.elapsed() < deadline,
            "no result from the Cyclone DDS peer within {deadline:?}"
        );
    }
    let status = peer.0.wait().expect("wait for the peer");
    let _ = reader.join();
    if let Some(diagnostics) = &mut diagnostics {
        check_world_pose(diagnostics, &mut node);
    }
    drop(node);
    let result: Value = serde_json::from_str(&result.unwrap()).expect("peer result JSON");
    eprintln!(
        "depth image via Cyclone DDS ({qos:?} images) after {:?} (peer: {} s, {} sets)",
        started.elapsed(),
        result["elapsed_s"],
        result["sets_sent"]
    );
    assert!(status.success(), "the peer exited with {status}");

    assert_eq!(result["encoding"], "32FC1");
    assert_eq!(result["width"], WIDTH);
    assert_eq!(result["height"], HEIGHT);
    assert_eq!(result["step"], 4 * WIDTH);
    assert_eq!(result["is_bigendian"], 0);
    assert_eq!(result["frame_id"], "cam1_optical");
    assert_eq!(
        result["stamp_was_sent"], true,
        "stamp {} was never sent",
        result["stamp"]
    );
    assert_eq!(result["data_len"], 4 * WIDTH * HEIGHT);
    let total = result["total"].as_u64().unwrap();
    let valid = result["valid"].as_u64().unwrap();
    let within = result["within"].as_u64().unwrap();
    assert!(
        valid * 2 >= total,
        "only {valid} of {total} depths are valid"
    );
    assert!(
        within * 10 >= valid * 9,
        "only {within} of {valid} valid depths are within 2 % of 2.0 m"
    );
}

/// The world pose the node reports for cam1_optical (the reference) equals the motion the peer
/// published, at the reported stamp.
fn check_world_pose(diagnostics: &mut dds::Diagnostics, node: &mut NodeProcess) {
    let key = "world pose cam1_optical";
    let status = diagnostics.wait_until(format!("'{key}'"), node, |s| {
        dds::value_of(s, key).is_some()
    });
    let value = dds::value_of(&status, key).expect("the key").to_string();
    let (seconds, got) = dds::world_pose(&status, key);
    // Stamps are whole tenths of a second from 1000 s (the peer's stamp_of).
    let s = ((seconds - 1000.0) * 10.0).round() / 10.0;
    let world_from_rig = sweepdepth::geometry::RigidTransform {
        rotation: glam::DQuat::from_rotation_y(YAW_RATE * s),
        translation: glam::DVec3::from_array(VELOCITY) * s,
    };
    // cam1 sits at the rig frame's origin of a 3-camera row centred on it.
    let model = sweepdepth::geometry::CameraModel::pinhole(synthetic::intrinsics(WIDTH, HEIGHT));
    let rig = synthetic::row_rig(3, 0.1, model, 1).expect("rig");
    let truth = world_from_rig.compose(&rig.cameras[1].cam_from_rig.inverse());
    dds::assert_pose_near(&format!("{key}: {value}"), &got, &truth);
}
