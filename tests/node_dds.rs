//! End-to-end test of `sweepdepth node` over DDS (ros2-client peers in this process).
//!
//! SAFETY: no DDS packet may leave the machine. The test never opens DDS in the host network
//! namespace: unless it already runs inside the private namespace it creates itself (marker
//! variable [`INNER`] AND a check that only `lo` exists), it re-executes its own binary inside
//! `unshare -n` (`unshare -rn` when not root) with loopback up and a multicast route on `lo`,
//! and fails with a clear message if that is impossible.

#[path = "common/netns.rs"]
mod netns;
use netns::{in_private_netns, KillOnDrop};

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use ros2_client::log::Log;
use ros2_client::parameters::{Parameter, ParameterValue};
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::rcl_interfaces::{SetParametersRequest, SetParametersResponse};
use ros2_client::{
    Context, ContextOptions, MessageTypeName, Name, NodeName, NodeOptions, QosProfile,
    ServiceMapping, ServiceTypeName,
};
use sweepdepth::geometry::CameraModel;
use sweepdepth::image::Rgba8Image;
use sweepdepth::msgs::{
    CameraInfo, DiagnosticArray, DiagnosticStatus, Header, Image, PointCloud2, PointField,
    Quaternion, TFMessage, Time, Transform, TransformStamped, Vector3,
};
use sweepdepth::synthetic::{self, Scene};

const INNER: &str = "SWEEPDEPTH_TEST_PRIVATE_NETNS";
const DOMAIN: &str = "42";
const WIDTH: u32 = 80;
const HEIGHT: u32 = 60;
/// Cameras of the synthetic rig (a row, 10 cm apart; the reference is cam1).
const CAMERAS: usize = 4;

#[test]
fn node_publishes_depth_over_dds() {
    in_private_netns(INNER, "node_publishes_depth_over_dds", end_to_end);
}

#[test]
fn node_approximate_sync_with_jittered_stamps() {
    in_private_netns(
        INNER,
        "node_approximate_sync_with_jittered_stamps",
        approximate_sync_jitter,
    );
}

#[test]
fn node_publishes_points() {
    in_private_netns(INNER, "node_publishes_points", points_cloud);
}

#[test]
fn node_publishes_diagnostics() {
    in_private_netns(INNER, "node_publishes_diagnostics", diagnostics);
}

#[test]
fn node_parameter_services() {
    in_private_netns(INNER, "node_parameter_services", parameter_services);
}

#[test]
fn node_virtual_reference() {
    in_private_netns(INNER, "node_virtual_reference", virtual_reference);
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

/// Nanoseconds of a stamp.
fn nanos(t: Time) -> i64 {
    i64::from(t.sec) * 1_000_000_000 + i64::from(t.nanosec)
}

fn time_of(ns: i64) -> Time {
    Time {
        sec: ns.div_euclid(1_000_000_000) as i32,
        nanosec: ns.rem_euclid(1_000_000_000) as u32,
    }
}

/// The node under test and a peer node that feeds it the synthetic 4-camera rig (wall at
/// 2 m, cam1 the reference).
struct Harness {
    rig: sweepdepth::geometry::Rig,
    images: Vec<Rgba8Image>,
    image_pubs: Vec<ros2_client::Publisher<Image>>,
    info_pubs: Vec<ros2_client::Publisher<CameraInfo>>,
    _tf_pub: ros2_client::Publisher<TFMessage>,
    reliable: QosProfile,
    peer: ros2_client::Node,
    node: KillOnDrop,
    _context: Context,
}

fn frame(i: usize) -> String {
    format!("cam{i}_optical")
}

impl Harness {
    /// Starts the node with `cameras:=[cam0, cam1, cam2, cam3]` (reference cam1), depths 1..4 m, 48 planes and
    /// `extra` parameters (`name:=value`, later ones win), and publishes /tf_static.
    fn start(extra: &[&str]) -> Harness {
        let model = CameraModel::pinhole(synthetic::intrinsics(WIDTH, HEIGHT));
        let rig = synthetic::row_rig(CAMERAS, 0.1, model, 1).expect("rig");
        let scene = Scene::wall_and_box(2.0, None, model.intrinsics.fx_px);
        let images = synthetic::render_rig(&scene, &rig);

        let mut args: Vec<String> = [
            "node",
            "--ros-args",
            "-p",
            "cameras:=[cam0, cam1, cam2, cam3]",
            "-p",
            "reference_camera:=cam1",
            "-p",
            "min_depth:=1.0",
            "-p",
            "max_depth:=4.0",
            "-p",
            "num_planes:=48",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        for p in extra {
            args.push("-p".into());
            args.push(p.to_string());
        }
        let node = Command::new(env!("CARGO_BIN_EXE_sweepdepth"))
            .args(&args)
            .env("ROS_DOMAIN_ID", DOMAIN)
            .env(
                "RUST_LOG",
                std::env::var("RUST_LOG").unwrap_or_else(|_| "warn,sweepdepth=info".into()),
            )
            .stdin(Stdio::null())
            .spawn()
            .expect("start the node");
        let node = KillOnDrop(node);

        let context =
            Context::with_options(ContextOptions::new().domain_id(DOMAIN.parse().unwrap()))
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
        for i in 0..rig.cameras.len() {
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
        Harness {
            rig,
            images,
            image_pubs,
            info_pubs,
            _tf_pub: tf_pub,
            reliable,
            peer,
            node,
            _context: context,
        }
    }

    fn subscribe<T: 'static + serde::de::DeserializeOwned>(
        &mut self,
        topic: &str,
        package: &str,
        type_name: &str,
    ) -> ros2_client::Subscription<T> {
        let t = self
            .peer
            .create_topic(
                &Name::parse(topic).unwrap(),
                MessageTypeName::new(package, type_name),
                &self.reliable,
            )
            .unwrap();
        self.peer
            .create_subscription::<T>(&t, Some(self.reliable.clone()))
            .unwrap()
    }

    /// Publishes one set, camera `i` stamped `stamps[i]`.
    fn publish_set(&self, stamps: [Time; CAMERAS]) {
        for (i, stamp) in stamps.into_iter().enumerate() {
            let header = Header {
                stamp,
                frame_id: frame(i),
            };
            self.info_pubs[i]
                .publish(camera_info(&header, &self.rig.cameras[i].model))
                .expect("info");
            self.image_pubs[i]
                .publish(image_msg(&header, &self.images[i], i == 2))
                .expect("image");
        }
    }

    fn check_alive(&mut self) {
        if let Some(status) = self.node.0.try_wait().expect("poll node") {
            panic!("the node exited early: {status}");
        }
    }

    /// Publishes sets `k = first, first + 1, ...` (stamps from `stamps(k)`) every 100 ms
    /// until `poll` returns Some (checked every 5 ms), for at most `limit`.
    fn feed_until<R>(
        &mut self,
        first: u32,
        limit: Duration,
        stamps: impl Fn(u32) -> [Time; CAMERAS],
        mut poll: impl FnMut() -> Option<R>,
    ) -> (R, u32) {
        let started = Instant::now();
        let mut k = first;
        loop {
            assert!(
                started.elapsed() < limit,
                "nothing within {limit:?} ({} sets sent)",
                k - first
            );
            self.check_alive();
            self.publish_set(stamps(k));
            let tick = Instant::now();
            while tick.elapsed() < Duration::from_millis(100) {
                if let Some(r) = poll() {
                    eprintln!(
                        "got it after {:?} and {} sets",
                        started.elapsed(),
                        k - first + 1
                    );
                    return (r, k);
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            k += 1;
        }
    }
}

fn same_stamps(k: u32) -> [Time; CAMERAS] {
    [stamp_of(k); CAMERAS]
}

/// Camera `i`'s stamp of set `k`: k * 100 ms plus a deterministic jitter in -5..=5 ms,
/// different for the four cameras of a set.
fn jittered_stamps(k: u32) -> [Time; CAMERAS] {
    std::array::from_fn(|i| {
        let jitter_ms = ((k as i64 * 3 + i as i64 * 4) % 11) - 5;
        time_of(nanos(stamp_of(k)) + jitter_ms * 1_000_000)
    })
}

fn depths_of(msg: &Image) -> Vec<f32> {
    msg.data
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect()
}

/// Checks a depth image of the 2 m wall from the reference camera.
fn check_depth_image(received: &Image) {
    assert_eq!(received.encoding, "32FC1");
    assert_eq!((received.width, received.height), (WIDTH, HEIGHT));
    assert_eq!(received.step, 4 * WIDTH);
    assert_eq!(received.is_bigendian, 0);
    assert_eq!(received.header.frame_id, frame(1));
    assert_eq!(received.data.len(), (4 * WIDTH * HEIGHT) as usize);
    check_wall_depths(&depths_of(received));
}

/// At least half the depths valid, 90 % of those within 2 % of 2.0 m.
fn check_wall_depths(depths: &[f32]) {
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
}

fn end_to_end() {
    let mut h = Harness::start(&["sync:=exact"]);
    let depth_sub = h.subscribe::<Image>("/depth/image", "sensor_msgs", "Image");
    let info_sub = h.subscribe::<CameraInfo>("/depth/camera_info", "sensor_msgs", "CameraInfo");
    let (received, k) = h.feed_until(1, Duration::from_secs(60), same_stamps, || {
        depth_sub.take().ok().flatten().map(|(m, _)| m)
    });
    let stamp = received.header.stamp;
    assert!(
        (1..=k).any(|j| stamp_of(j) == stamp),
        "stamp {stamp:?} was never sent"
    );
    check_depth_image(&received);

    // depth/camera_info: the reference camera's model with the depth image's header.
    let deadline = Instant::now() + Duration::from_secs(10);
    let info = loop {
        if let Ok(Some((info, _))) = info_sub.take() {
            if info.header.stamp == stamp {
                break info;
            }
        }
        assert!(
            Instant::now() < deadline,
            "no depth/camera_info stamped {stamp:?}"
        );
        std::thread::sleep(Duration::from_millis(5));
    };
    assert_eq!(info.header.frame_id, received.header.frame_id);
    assert_eq!((info.width, info.height), (WIDTH, HEIGHT));
    let k_ref = h.rig.reference_model().intrinsics;
    assert!((info.k[0] - k_ref.fx_px).abs() < 1e-9 && (info.k[2] - k_ref.cx_px).abs() < 1e-9);
    assert!((info.p[0] - k_ref.fx_px).abs() < 1e-9 && (info.p[6] - k_ref.cy_px).abs() < 1e-9);

    // Exact sync must not pair jittered stamps: after the node has shown it works, sets whose
    // cameras' stamps differ by a few ms produce no depth image.
    std::thread::sleep(Duration::from_millis(500));
    while let Ok(Some(_)) = depth_sub.take() {}
    let first_jittered = k + 1;
    for j in first_jittered..first_jittered + 15 {
        h.publish_set(jittered_stamps(j));
        std::thread::sleep(Duration::from_millis(100));
        h.check_alive();
    }
    std::thread::sleep(Duration::from_millis(500));
    while let Ok(Some((m, _))) = depth_sub.take() {
        let s = m.header.stamp;
        assert!(
            !(first_jittered..first_jittered + 15).any(|j| jittered_stamps(j).contains(&s)),
            "exact sync published a depth image for jittered stamps ({s:?})"
        );
    }
}

fn approximate_sync_jitter() {
    let mut h = Harness::start(&["sync:=approximate"]);
    let depth_sub = h.subscribe::<Image>("/depth/image", "sensor_msgs", "Image");
    // Two depth images, so that at least one set was matched across jittered stamps after
    // the first.
    let mut got = Vec::new();
    let (_, k) = h.feed_until(1, Duration::from_secs(60), jittered_stamps, || {
        while let Ok(Some((m, _))) = depth_sub.take() {
            got.push(m);
        }
        (got.len() >= 2).then_some(())
    });
    for received in &got {
        let stamp = received.header.stamp;
        let set = (1..=k)
            .find(|j| jittered_stamps(*j).contains(&stamp))
            .unwrap_or_else(|| panic!("stamp {stamp:?} was never sent"));
        assert_eq!(
            stamp,
            jittered_stamps(set)[1],
            "the depth image of set {set} is not stamped like the reference camera ({:?})",
            jittered_stamps(set)
        );
        check_depth_image(received);
    }
}

fn points_cloud() {
    let mut h = Harness::start(&["sync:=exact", "publish_points:=true"]);
    let points_sub = h.subscribe::<PointCloud2>("/points", "sensor_msgs", "PointCloud2");
    let (cloud, k) = h.feed_until(1, Duration::from_secs(60), same_stamps, || {
        points_sub.take().ok().flatten().map(|(m, _)| m)
    });
    assert!(
        (1..=k).any(|j| stamp_of(j) == cloud.header.stamp),
        "stamp {:?} was never sent",
        cloud.header.stamp
    );
    assert_eq!(cloud.header.frame_id, frame(1));
    assert_eq!((cloud.width, cloud.height), (WIDTH, HEIGHT));
    let fields: Vec<(&str, u32, u8, u32)> = cloud
        .fields
        .iter()
        .map(|f| (f.name.as_str(), f.offset, f.datatype, f.count))
        .collect();
    let f32t = PointField::FLOAT32;
    assert_eq!(
        fields,
        [
            ("x", 0, f32t, 1),
            ("y", 4, f32t, 1),
            ("z", 8, f32t, 1),
            ("rgb", 12, f32t, 1)
        ]
    );
    assert_eq!(cloud.point_step, 16);
    assert_eq!(cloud.row_step, 16 * WIDTH);
    assert!(!cloud.is_bigendian);
    assert!(!cloud.is_dense);
    assert_eq!(cloud.data.len(), (16 * WIDTH * HEIGHT) as usize);
    let k = h.rig.cameras[1].model.intrinsics;
    let reference = &h.images[1];
    let mut zs = Vec::new();
    for (i, p) in cloud.data.chunks_exact(16).enumerate() {
        let f = |o: usize| f32::from_le_bytes([p[o], p[o + 1], p[o + 2], p[o + 3]]);
        let (x, y, z) = (f(0), f(4), f(8));
        let [r, g, b, _] = Rgba8Image::unpack(reference.pixels[i]);
        assert_eq!(&p[12..16], &[b, g, r, 0], "colour of point {i}");
        zs.push(z);
        if z.is_finite() {
            let u = (i % WIDTH as usize) as f64;
            let v = (i / WIDTH as usize) as f64;
            let ex = (u - k.cx_px) / k.fx_px * f64::from(z);
            let ey = (v - k.cy_px) / k.fy_px * f64::from(z);
            assert!(
                (f64::from(x) - ex).abs() < 1e-4 && (f64::from(y) - ey).abs() < 1e-4,
                "point {i}: ({x}, {y}, {z}), expected x {ex}, y {ey}"
            );
        } else {
            assert!(x.is_nan() && y.is_nan() && z.is_nan(), "point {i}");
        }
    }
    check_wall_depths(&zs);
}

fn diagnostics() {
    let mut h = Harness::start(&["sync:=exact"]);
    let diag_sub =
        h.subscribe::<DiagnosticArray>("/diagnostics", "diagnostic_msgs", "DiagnosticArray");
    // /rosout is transient local (depth 1): the latest log line arrives even if it predates
    // the subscription.
    let rosout_qos = h.reliable.clone().durability(Durability::TransientLocal);
    let rosout_topic = h
        .peer
        .create_topic(
            &Name::parse("/rosout").unwrap(),
            MessageTypeName::new("rcl_interfaces", "Log"),
            &rosout_qos,
        )
        .unwrap();
    let rosout_sub = h
        .peer
        .create_subscription::<Log>(&rosout_topic, Some(rosout_qos))
        .unwrap();
    let mut first_warn = None;
    // Until a diagnostics message reports published sets (at most 1 s after the first).
    let (status, _) = h.feed_until(1, Duration::from_secs(60), same_stamps, || {
        while let Ok(Some((m, _))) = diag_sub.take() {
            assert_eq!(m.status.len(), 1, "{m:?}");
            let status = m.status.into_iter().next()?;
            let published = value_of(&status, "sets published")
                .and_then(|v| v.parse::<u64>().ok())
                .unwrap_or(0);
            if published == 0 {
                first_warn.get_or_insert(status);
            } else {
                return Some(status);
            }
        }
        None
    });
    assert_eq!(status.name, "sweepdepth: /sweepdepth");
    assert_eq!(status.level, DiagnosticStatus::OK, "{status:?}");
    for key in [
        "input rate cam0 (Hz)",
        "input rate cam1 (Hz)",
        "input rate cam2 (Hz)",
        "sync matched",
        "sync dropped",
        "sync incomplete",
        "gpu sets dropped",
        "processing time last (ms)",
        "processing time mean (ms)",
        "latency (ms)",
        "gpu adapter",
    ] {
        assert!(
            value_of(&status, key).is_some(),
            "no key '{key}' in {status:?}"
        );
    }
    let number = |key: &str| -> f64 {
        value_of(&status, key)
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("'{key}' is not a number in {status:?}"))
    };
    for i in 0..CAMERAS {
        let rate = number(&format!("input rate cam{i} (Hz)"));
        assert!(rate > 0.0 && rate <= 40.0, "cam{i} rate {rate}");
    }
    assert!(number("sync matched") >= 1.0);
    assert!(number("processing time last (ms)") > 0.0);
    assert!(number("processing time mean (ms)") > 0.0);
    assert!(number("latency (ms)").is_finite());
    assert!(!value_of(&status, "gpu adapter").unwrap_or("").is_empty());
    if let Some(warn) = first_warn {
        assert_eq!(warn.level, DiagnosticStatus::WARN, "{warn:?}");
    }
    // The node's log lines also go to /rosout.
    let started = Instant::now();
    let log = loop {
        assert!(
            started.elapsed() < Duration::from_secs(20),
            "no /rosout line from the node within 20 s"
        );
        if let Ok(Some((log, _))) = rosout_sub.take() {
            if log.name == "sweepdepth" {
                break log;
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    assert!(log.level == Log::INFO || log.level == Log::WARN, "{log:?}");
    assert!(!log.msg.is_empty());
}

fn value_of<'a>(status: &'a DiagnosticStatus, key: &str) -> Option<&'a str> {
    status
        .values
        .iter()
        .find(|kv| kv.key == key)
        .map(|kv| kv.value.as_str())
}

type SetClient = ros2_client::Client<SetParametersRequest, SetParametersResponse>;

/// Calls `~/set_parameters` with one parameter (retrying until the service answers) and
/// returns (successful, reason).
fn set_parameter(client: &SetClient, name: &str, value: ParameterValue) -> (bool, String) {
    let started = Instant::now();
    while started.elapsed() < Duration::from_secs(30) {
        let request = SetParametersRequest {
            parameter: vec![Parameter {
                name: name.to_string(),
                value: value.clone(),
            }
            .into()],
        };
        let id = client.send_request(request).expect("send the request");
        let tick = Instant::now();
        while tick.elapsed() < Duration::from_secs(1) {
            if let Ok(Some((rid, response))) = client.receive_response() {
                if rid == id {
                    assert_eq!(response.results.len(), 1, "{response:?}");
                    let r = &response.results[0];
                    return (r.successful, r.reason.clone());
                }
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }
    panic!("no answer from /sweepdepth/set_parameters within 30 s");
}

fn parameter_services() {
    let mut h = Harness::start(&["sync:=exact"]);
    let depth_sub = h.subscribe::<Image>("/depth/image", "sensor_msgs", "Image");
    let service_qos = QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .history(History::KeepLast { depth: 1 });
    let client: SetClient = h
        .peer
        .create_client(
            ServiceMapping::Enhanced,
            &Name::parse("/sweepdepth/set_parameters").unwrap(),
            &ServiceTypeName::new("rcl_interfaces", "SetParameters"),
            service_qos.clone(),
            service_qos,
        )
        .expect("set_parameters client");

    // The wall at 2 m, swept over 1..4 m.
    let (before, k) = h.feed_until(1, Duration::from_secs(60), same_stamps, || {
        depth_sub.take().ok().flatten().map(|(m, _)| m)
    });
    check_depth_image(&before);

    // Rejected, with reasons.
    let (ok, reason) = set_parameter(&client, "min_depth", ParameterValue::Double(5.0));
    assert!(!ok && reason.contains("max_depth"), "{reason}");
    let (ok, reason) = set_parameter(&client, "num_planes", ParameterValue::Integer(1));
    assert!(!ok && reason.contains("num_planes"), "{reason}");
    let (ok, reason) = set_parameter(
        &client,
        "sync",
        ParameterValue::String("approximate".into()),
    );
    assert!(!ok && reason.contains("read-only"), "{reason}");
    let (ok, reason) = set_parameter(
        &client,
        "window_mode",
        ParameterValue::String("shiftable".into()),
    );
    assert!(!ok && reason.contains("even"), "{reason}");
    let (ok, reason) = set_parameter(&client, "no_such_parameter", ParameterValue::Integer(1));
    assert!(!ok && !reason.is_empty());
    // Four cameras, reference pairs: best 4 of the 3 pairs does not fit the rig.
    let (ok, reason) = set_parameter(&client, "best_n", ParameterValue::Integer(4));
    assert!(
        !ok && reason.contains("best_n (4)") && reason.contains("3 camera pairs"),
        "{reason}"
    );

    // Sweep 2.5..4 m: the wall at 2 m is out of range, no depth may be near it.
    let (ok, reason) = set_parameter(&client, "min_depth", ParameterValue::Double(2.5));
    assert!(ok, "min_depth:=2.5 rejected: {reason}");
    let first_after = k + 1_000;
    let (after, _) = h.feed_until(first_after, Duration::from_secs(60), same_stamps, || {
        while let Ok(Some((m, _))) = depth_sub.take() {
            if nanos(m.header.stamp) >= nanos(stamp_of(first_after)) {
                return Some(m);
            }
        }
        None
    });
    let depths = depths_of(&after);
    let valid: Vec<f32> = depths.iter().copied().filter(|d| d.is_finite()).collect();
    assert!(
        valid.iter().all(|d| *d >= 2.5 * 0.999 && *d <= 4.0 * 1.001),
        "depths outside 2.5..4 m after min_depth:=2.5: {:?}",
        valid
            .iter()
            .filter(|d| **d < 2.5 * 0.999)
            .take(5)
            .collect::<Vec<_>>()
    );
    let near_wall = valid
        .iter()
        .filter(|d| ((**d - 2.0) / 2.0).abs() <= 0.02)
        .count();
    assert_eq!(near_wall, 0);
    eprintln!(
        "after min_depth:=2.5: {} of {} depths valid, none near the wall",
        valid.len(),
        depths.len()
    );
}

/// A virtual reference camera 15 cm right of cam1 (between cam2 and cam3 of the row, which
/// sit at 0.1 and 0.2 m), 64x48 with its own intrinsics: the depth image is the virtual
/// camera's, stamped like cam1's image and in cam1's frame (virtual_frame_id empty).
fn virtual_reference() {
    let mut h = Harness::start(&[
        "sync:=exact",
        "virtual_reference:=true",
        "virtual_pose:=[0.15, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]",
        "virtual_width:=64",
        "virtual_height:=48",
        "virtual_fx:=60.0",
        "virtual_fy:=60.0",
        "virtual_cx:=31.5",
        "virtual_cy:=23.5",
    ]);
    let depth_sub = h.subscribe::<Image>("/depth/image", "sensor_msgs", "Image");
    let info_sub = h.subscribe::<CameraInfo>("/depth/camera_info", "sensor_msgs", "CameraInfo");
    let mut info: Option<CameraInfo> = None;
    let ((depth, info), k) = h.feed_until(1, Duration::from_secs(60), same_stamps, || {
        if info.is_none() {
            info = info_sub.take().ok().flatten().map(|(m, _)| m);
        }
        info.as_ref()?;
        depth_sub
            .take()
            .ok()
            .flatten()
            .map(|(m, _)| (m, info.clone().unwrap()))
    });
    assert!(
        (1..=k).any(|j| stamp_of(j) == depth.header.stamp),
        "stamp {:?} was never sent",
        depth.header.stamp
    );
    assert_eq!(depth.header.frame_id, frame(1));
    assert_eq!(depth.encoding, "32FC1");
    assert_eq!((depth.width, depth.height), (64, 48));
    assert_eq!(depth.data.len(), 4 * 64 * 48);
    assert_eq!((info.width, info.height), (64, 48));
    assert_eq!(info.header.frame_id, frame(1));
    assert_eq!(info.k, [60.0, 0.0, 31.5, 0.0, 60.0, 23.5, 0.0, 0.0, 1.0]);
    assert_eq!(
        info.p,
        [60.0, 0.0, 31.5, 0.0, 0.0, 60.0, 23.5, 0.0, 0.0, 0.0, 1.0, 0.0]
    );
    assert!(info.d.is_empty(), "{:?}", info.d);
    check_wall_depths(&depths_of(&depth));
}
