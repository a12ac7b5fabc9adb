//! End-to-end test of `sweepdepth node` over DDS (ros2-client peers in this process).
//!
//! SAFETY: no DDS packet may leave the machine. The test never opens DDS in the host network
//! namespace: unless it already runs inside the private namespace it creates itself (marker
//! variable [`INNER`] AND a check that only `lo` exists), it re-executes its own binary inside
//! `unshare -n` (`unshare -rn` when not root) with loopback up and a multicast route on `lo`,
//! and fails with a clear message if that is impossible.

use std::collections::HashSet;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{
    Context, ContextOptions, MessageTypeName, Name, NodeName, NodeOptions, QosProfile,
};
use sweepdepth::geometry::CameraModel;
use sweepdepth::image::Rgba8Image;
use sweepdepth::msgs::{
    CameraInfo, Header, Image, Quaternion, TFMessage, Time, Transform, TransformStamped, Vector3,
};
use sweepdepth::synthetic::{self, Scene};

const INNER: &str = "SWEEPDEPTH_TEST_PRIVATE_NETNS";
const TEST_NAME: &str = "node_publishes_depth_over_dds";
const DOMAIN: &str = "42";
const WIDTH: u32 = 80;
const HEIGHT: u32 = 60;

/// Network interfaces of this process's network namespace (from /proc/self/net/dev).
fn interfaces() -> Vec<String> {
    std::fs::read_to_string("/proc/self/net/dev")
        .unwrap_or_default()
        .lines()
        .skip(2)
        .filter_map(|l| l.split(':').next().map(|s| s.trim().to_string()))
        .filter(|s| !s.is_empty())
        .collect()
}

fn is_root() -> bool {
    std::fs::read_to_string("/proc/self/status")
        .unwrap_or_default()
        .lines()
        .find(|l| l.starts_with("Uid:"))
        .and_then(|l| l.split_whitespace().nth(2))
        == Some("0")
}

#[test]
fn node_publishes_depth_over_dds() {
    if std::env::var_os(INNER).is_none() {
        reexec_in_private_netns();
        return;
    }
    let ifaces = interfaces();
    assert!(
        ifaces == ["lo"],
        "refusing to open DDS: {INNER} is set but this network namespace has interfaces {ifaces:?} (only lo allowed)"
    );
    end_to_end();
}

fn reexec_in_private_netns() {
    let exe = std::env::current_exe().expect("test binary path");
    let flags = if is_root() { "-n" } else { "-rn" };
    let script = "ip link set lo up && ip link set lo multicast on && \
                  ip route add 224.0.0.0/4 dev lo && exec \"$0\" \"$@\"";
    let status = Command::new("unshare")
        .arg(flags)
        .args(["sh", "-c", script])
        .arg(&exe)
        .args([TEST_NAME, "--exact", "--nocapture", "--test-threads=1"])
        .env(INNER, "1")
        .status();
    match status {
        Err(e) => panic!(
            "this test must run DDS in a private network namespace and cannot start `unshare {flags}` ({e}); install util-linux and iproute2 (and allow namespaces), it never runs DDS on the host network"
        ),
        Ok(s) => assert!(
            s.success(),
            "the DDS test inside `unshare {flags}` failed ({s}); see its output above (if unshare itself failed, namespaces may be unavailable here)"
        ),
    }
}

/// Kills the node on every exit path.
struct NodeProcess(Child);

impl Drop for NodeProcess {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn stamp_of(k: u32) -> Time {
    Time {
        sec: 1000 + (k / 10) as i32,
        nanosec: (k % 10) * 100_000_000,
    }
}

fn camera_info(header: &Header, model: &CameraModel) -> CameraInfo {
    let k = model.intrinsics;
    CameraInfo {
        header: header.clone(),
        width: k.width_px,
        height: k.height_px,
        distortion_model: "plumb_bob".into(),
        d: vec![0.0; 5],
        k: [k.fx_px, 0.0, k.cx_px, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [
            k.fx_px, 0.0, k.cx_px, 0.0, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 0.0, 1.0, 0.0,
        ],
        ..CameraInfo::default()
    }
}

fn image_msg(header: &Header, image: &Rgba8Image, bgr: bool) -> Image {
    let mut data = Vec::with_capacity(image.pixels.len() * 3);
    for &p in &image.pixels {
        let [r, g, b, _] = Rgba8Image::unpack(p);
        data.extend_from_slice(&if bgr { [b, g, r] } else { [r, g, b] });
    }
    Image {
        header: header.clone(),
        height: image.height,
        width: image.width,
        encoding: if bgr { "bgr8" } else { "rgb8" }.into(),
        is_bigendian: 0,
        step: image.width * 3,
        data,
    }
}

fn end_to_end() {
    let model = CameraModel::pinhole(synthetic::intrinsics(WIDTH, HEIGHT));
    let rig = synthetic::row_rig(3, 0.1, model, 1).expect("rig");
    let scene = Scene::wall_and_box(2.0, None, model.intrinsics.fx_px);
    let images = synthetic::render_rig(&scene, &rig);
    let frame = |i: usize| format!("cam{i}_optical");

    let node = Command::new(env!("CARGO_BIN_EXE_sweepdepth"))
        .args([
            "node",
            "--ros-args",
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
        ])
        .env("ROS_DOMAIN_ID", DOMAIN)
        .env(
            "RUST_LOG",
            std::env::var("RUST_LOG").unwrap_or_else(|_| "warn,sweepdepth=info".into()),
        )
        .stdin(Stdio::null())
        .spawn()
        .expect("start the node");
    let mut node = NodeProcess(node);

    let context = Context::with_options(ContextOptions::new().domain_id(DOMAIN.parse().unwrap()))
        .expect("DDS context");
    let mut peer = context
        .new_node(
            NodeName::new("/", "sweepdepth_test_peer").unwrap(),
            NodeOptions::new()
                .enable_rosout(false)
                .start_parameter_services(false),
        )
        .expect("test node");
    let reliable = QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .history(History::KeepLast { depth: 10 });
    let tf_qos = reliable.clone().durability(Durability::TransientLocal);
    let image_type = || MessageTypeName::new("sensor_msgs", "Image");
    let info_type = || MessageTypeName::new("sensor_msgs", "CameraInfo");

    let tf_topic = peer
        .create_topic(
            &Name::parse("/tf_static").unwrap(),
            MessageTypeName::new("tf2_msgs", "TFMessage"),
            &tf_qos,
        )
        .unwrap();
    let tf_pub = peer
        .create_publisher::<TFMessage>(&tf_topic, Some(tf_qos.clone()))
        .unwrap();
    let mut image_pubs = Vec::new();
    let mut info_pubs = Vec::new();
    for i in 0..3 {
        let t = peer
            .create_topic(
                &Name::parse(&format!("/cam{i}/image_raw")).unwrap(),
                image_type(),
                &reliable,
            )
            .unwrap();
        image_pubs.push(
            peer.create_publisher::<Image>(&t, Some(reliable.clone()))
                .unwrap(),
        );
        let t = peer
            .create_topic(
                &Name::parse(&format!("/cam{i}/camera_info")).unwrap(),
                info_type(),
                &reliable,
            )
            .unwrap();
        info_pubs.push(
            peer.create_publisher::<CameraInfo>(&t, Some(reliable.clone()))
                .unwrap(),
        );
    }
    let depth_topic = peer
        .create_topic(
            &Name::parse("/depth/image").unwrap(),
            image_type(),
            &reliable,
        )
        .unwrap();
    let depth_sub = peer
        .create_subscription::<Image>(&depth_topic, Some(reliable.clone()))
        .unwrap();

    // The static transforms, published once (transient local: the node gets them late).
    let transforms = rig
        .cameras
        .iter()
        .enumerate()
        .map(|(i, cam)| {
            let c = cam.centre_in_rig();
            TransformStamped {
                header: Header {
                    stamp: stamp_of(0),
                    frame_id: "rig".into(),
                },
                child_frame_id: frame(i),
                transform: Transform {
                    translation: Vector3 {
                        x: c.x,
                        y: c.y,
                        z: c.z,
                    },
                    rotation: Quaternion::default(),
                },
            }
        })
        .collect();
    tf_pub
        .publish(TFMessage { transforms })
        .expect("publish /tf_static");

    let mut sent = HashSet::new();
    let started = Instant::now();
    let mut k = 0u32;
    let received = loop {
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "no depth image within 60 s ({k} sets sent)"
        );
        if let Some(status) = node.0.try_wait().expect("poll node") {
            panic!("the node exited early: {status}");
        }
        k += 1;
        let stamp = stamp_of(k);
        sent.insert((stamp.sec, stamp.nanosec));
        for i in 0..3 {
            let header = Header {
                stamp,
                frame_id: frame(i),
            };
            info_pubs[i]
                .publish(camera_info(&header, &rig.cameras[i].model))
                .expect("info");
            image_pubs[i]
                .publish(image_msg(&header, &images[i], i == 2))
                .expect("image");
        }
        let mut got = None;
        let tick = Instant::now();
        while tick.elapsed() < Duration::from_millis(100) {
            if let Ok(Some((msg, _))) = depth_sub.take() {
                got = Some(msg);
                break;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        if let Some(msg) = got {
            break msg;
        }
    };
    eprintln!("depth image after {:?} and {k} sets", started.elapsed());

    assert_eq!(received.encoding, "32FC1");
    assert_eq!((received.width, received.height), (WIDTH, HEIGHT));
    assert_eq!(received.step, 4 * WIDTH);
    assert_eq!(received.is_bigendian, 0);
    assert_eq!(received.header.frame_id, frame(1));
    assert!(
        sent.contains(&(received.header.stamp.sec, received.header.stamp.nanosec)),
        "stamp {:?} was never sent",
        received.header.stamp
    );
    assert_eq!(received.data.len(), (4 * WIDTH * HEIGHT) as usize);
    let depths: Vec<f32> = received
        .data
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let valid: Vec<f32> = depths.iter().copied().filter(|d| d.is_finite()).collect();
    let within = valid
        .iter()
        .filter(|d| ((**d - 2.0) / 2.0).abs() <= 0.02)
        .count();
    assert!(
        valid.len() * 2 >= depths.len(),
        "only {} of {} depths are valid",
        valid.len(),
        depths.len()
    );
    assert!(
        within * 10 >= valid.len() * 9,
        "only {within} of {} valid depths are within 2 % of 2.0 m",
        valid.len()
    );
    drop(node);
}
