//! The DDS side shared by the tests that run `sweepdepth node` (node_dds, bag_live, hostile,
//! node_cyclone, node_shutdown, soak): starting the node, a ros2-client peer node with its
//! publishers and subscriptions, a publisher of a synthetic rig, `/diagnostics`, and waiting.
//!
//! Pace: no test may assume how fast the machine is (CI machines vary 3-5x and run beside other
//! jobs). Every wait here is for an outcome (a message, a counter in `/diagnostics`) within the
//! generous limit [`timeout`], checks that the node is still alive, and fails naming what it
//! waited for. A peer that must not overrun the node (the node keeps only the newest set when
//! its GPU is busy) publishes a frame set only after the node answered the previous one.
//!
//! Only for use inside the private network namespace of [`super::netns`].

use std::fmt::Display;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{
    Context, ContextOptions, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher,
    QosProfile, Subscription,
};
use serde::de::DeserializeOwned;
use serde::Serialize;
use sweepdepth::geometry::{CameraModel, Rig};
use sweepdepth::image::Rgba8Image;
use sweepdepth::msgs::{
    CameraInfo, DiagnosticArray, DiagnosticStatus, Header, Image, Quaternion, TFMessage, Time,
    Transform, TransformStamped, Vector3,
};

use super::netns::KillOnDrop;

/// How long any wait for the node may take: `SWEEPDEPTH_TEST_TIMEOUT_S`, default 300 s. A
/// working node answers in seconds even on a slow, loaded machine; the limit only bounds how
/// long a broken one takes to fail.
pub fn timeout() -> Duration {
    super::timeout::test_timeout()
}

/// How often a waiting test looks again.
const POLL: Duration = Duration::from_millis(5);

pub const IMAGE: (&str, &str) = ("sensor_msgs", "Image");
pub const COMPRESSED_IMAGE: (&str, &str) = ("sensor_msgs", "CompressedImage");
pub const CAMERA_INFO: (&str, &str) = ("sensor_msgs", "CameraInfo");
pub const POINT_CLOUD2: (&str, &str) = ("sensor_msgs", "PointCloud2");
pub const TF_MESSAGE: (&str, &str) = ("tf2_msgs", "TFMessage");
pub const DIAGNOSTIC_ARRAY: (&str, &str) = ("diagnostic_msgs", "DiagnosticArray");
pub const LOG: (&str, &str) = ("rcl_interfaces", "Log");

/// Reliable, keep last `depth`, volatile.
pub fn reliable(depth: usize) -> QosProfile {
    QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .history(History::KeepLast { depth })
}

/// Reliable, keep last `depth`, transient local (`/tf_static`, `/rosout`).
pub fn latched(depth: usize) -> QosProfile {
    reliable(depth).durability(Durability::TransientLocal)
}

/// Best effort, keep last `depth` (sensor-data QoS).
pub fn best_effort(depth: usize) -> QosProfile {
    QosProfile::publisher_default()
        .reliability_best_effort()
        .history(History::KeepLast { depth })
}

/// `sweepdepth node --ros-args <ros_args>` on `domain`, logging at `RUST_LOG` (default
/// `warn,sweepdepth=info`) to the inherited stderr.
pub fn node_command(domain: u16, ros_args: &[&str]) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_sweepdepth"));
    command
        .args(["node", "--ros-args"])
        .args(ros_args)
        .env("ROS_DOMAIN_ID", domain.to_string())
        .env(
            "RUST_LOG",
            std::env::var("RUST_LOG").unwrap_or_else(|_| "warn,sweepdepth=info".into()),
        )
        .stdin(Stdio::null());
    command
}

/// The node under test, killed on every exit path.
pub struct NodeProcess(KillOnDrop);

impl NodeProcess {
    /// Starts `sweepdepth node --ros-args <ros_args>` on `domain`.
    pub fn start(domain: u16, ros_args: &[&str]) -> NodeProcess {
        Self::spawn(node_command(domain, ros_args))
    }

    pub fn spawn(mut command: Command) -> NodeProcess {
        NodeProcess(KillOnDrop(command.spawn().expect("start the node")))
    }

    pub fn pid(&self) -> u32 {
        self.0 .0.id()
    }

    /// Panics if the node has exited.
    pub fn check_alive(&mut self) {
        if let Some(status) = self.0 .0.try_wait().expect("poll the node") {
            panic!("the node exited early: {status}");
        }
    }

    /// The node's stderr, when the command piped it.
    pub fn take_stderr(&mut self) -> std::process::ChildStderr {
        self.0 .0.stderr.take().expect("the node's stderr is piped")
    }

    /// The exit status once the node has exited.
    pub fn try_wait(&mut self) -> Option<std::process::ExitStatus> {
        self.0 .0.try_wait().expect("poll the node")
    }

    /// Whether the node is still running.
    pub fn is_alive(&mut self) -> bool {
        matches!(self.0 .0.try_wait(), Ok(None))
    }
}

/// Polls `poll` until it returns Some, for at most [`timeout`], checking that the node is alive;
/// panics saying that nothing came of `what`.
pub fn wait_for<T>(
    what: impl Display,
    node: &mut NodeProcess,
    mut poll: impl FnMut() -> Option<T>,
) -> T {
    let limit = timeout();
    let started = Instant::now();
    loop {
        if let Some(r) = poll() {
            return r;
        }
        node.check_alive();
        assert!(
            started.elapsed() < limit,
            "waited {limit:?} for {what} in vain"
        );
        std::thread::sleep(POLL);
    }
}

/// Calls `publish(k)` for `k = first, first + 1, ...` every 100 ms until `poll` returns Some
/// (checked every 5 ms), for at most [`timeout`]; returns the result and the last `k`
/// published. For the start of a test, while it is not known yet when the node's
/// subscriptions have matched the peer's publishers: fresh sets keep coming until one is
/// answered, whatever the pace.
pub fn feed_until<R>(
    what: impl Display,
    node: &mut NodeProcess,
    first: u32,
    mut publish: impl FnMut(u32),
    mut poll: impl FnMut() -> Option<R>,
) -> (R, u32) {
    let limit = timeout();
    let started = Instant::now();
    let mut k = first;
    loop {
        node.check_alive();
        assert!(
            started.elapsed() < limit,
            "waited {limit:?} for {what} in vain ({} sets sent)",
            k - first
        );
        publish(k);
        let tick = Instant::now();
        while tick.elapsed() < Duration::from_millis(100) {
            if let Some(r) = poll() {
                eprintln!(
                    "{what}: after {:?} and {} sets",
                    started.elapsed(),
                    k - first + 1
                );
                return (r, k);
            }
            std::thread::sleep(POLL);
        }
        k += 1;
    }
}

/// A ros2-client node in this process that talks to the node under test.
pub struct Peer {
    pub node: Node,
    _context: Context,
}

impl Peer {
    /// A node `/<name>` on `domain`, without rosout and parameter services.
    pub fn new(domain: u16, name: &str) -> Peer {
        let context =
            Context::with_options(ContextOptions::new().domain_id(domain)).expect("DDS context");
        let node = context
            .new_node(
                NodeName::new("/", name).expect("node name"),
                NodeOptions::new()
                    .enable_rosout(false)
                    .start_parameter_services(false),
            )
            .expect("the test's peer node");
        Peer {
            node,
            _context: context,
        }
    }

    fn topic(
        &self,
        topic: &str,
        (package, type_name): (&str, &str),
        qos: &QosProfile,
    ) -> ros2_client::dds::rustdds::Topic {
        self.node
            .create_topic(
                &Name::parse(topic).unwrap_or_else(|e| panic!("topic name {topic}: {e:?}")),
                MessageTypeName::new(package, type_name),
                qos,
            )
            .unwrap_or_else(|e| panic!("topic {topic}: {e:?}"))
    }

    pub fn publisher<T: Serialize>(
        &mut self,
        topic: &str,
        message_type: (&str, &str),
        qos: &QosProfile,
    ) -> Publisher<T> {
        let t = self.topic(topic, message_type, qos);
        self.node
            .create_publisher::<T>(&t, Some(qos.clone()))
            .unwrap_or_else(|e| panic!("publisher on {topic}: {e:?}"))
    }

    pub fn subscription<T: 'static + DeserializeOwned>(
        &mut self,
        topic: &str,
        message_type: (&str, &str),
        qos: &QosProfile,
    ) -> Subscription<T> {
        let t = self.topic(topic, message_type, qos);
        self.node
            .create_subscription::<T>(&t, Some(qos.clone()))
            .unwrap_or_else(|e| panic!("subscription on {topic}: {e:?}"))
    }

    /// Runs the node's spinner on a thread of its own (for discovery information such as
    /// matched subscriptions).
    pub fn spin_in_background(&mut self) {
        let spinner = self.node.spinner().expect("spinner");
        std::thread::spawn(move || futures::executor::block_on(spinner.spin()));
    }
}

/// Every message taken from `sub` so far, oldest first.
pub fn take_all<T: 'static + DeserializeOwned>(sub: &Subscription<T>) -> Vec<T> {
    let mut out = Vec::new();
    while let Ok(Some((m, _))) = sub.take() {
        out.push(m);
    }
    out
}

/// A stamp from nanoseconds.
pub fn time_of_ns(ns: u64) -> Time {
    Time {
        sec: (ns / 1_000_000_000) as i32,
        nanosec: (ns % 1_000_000_000) as u32,
    }
}

/// The wall clock now, as a stamp (the node stamps `/diagnostics` with it).
pub fn wall_time_now() -> Time {
    let d = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .expect("clock after 1970");
    time_of_ns(d.as_nanos() as u64)
}

/// The values of a 32FC1 image (little endian).
pub fn depth_values(image: &Image) -> Vec<f32> {
    assert_eq!(image.is_bigendian, 0, "a big-endian 32FC1 image");
    image
        .data
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect()
}

/// A CameraInfo for a pinhole `model` (no distortion) with `header`.
pub fn camera_info(header: &Header, model: &CameraModel) -> CameraInfo {
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

/// `image` as an rgb8 (or bgr8) Image message with `header`.
pub fn image_msg(header: &Header, image: &Rgba8Image, bgr: bool) -> Image {
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

/// The optical frame of camera `i` of a synthetic rig.
pub fn frame(i: usize) -> String {
    format!("cam{i}_optical")
}

/// A camera driver for a synthetic rig: `/camN/image_raw` and `/camN/camera_info` for every
/// camera and `/tf_static` (published once at creation, transient local) with each camera's
/// optical frame in the frame `rig`.
pub struct RigFeed {
    pub rig: Rig,
    /// The image messages of every camera (the stamp is set per set).
    images: Vec<Image>,
    image_pubs: Vec<Publisher<Image>>,
    info_pubs: Vec<Publisher<CameraInfo>>,
    _tf_pub: Publisher<TFMessage>,
}

impl RigFeed {
    /// Publishers on `peer` with `qos` for the images and camera infos; camera `bgr_camera`
    /// sends bgr8, the others rgb8.
    pub fn new(
        peer: &mut Peer,
        rig: Rig,
        images: &[Rgba8Image],
        qos: &QosProfile,
        bgr_camera: Option<usize>,
    ) -> RigFeed {
        let tf_qos = latched(10);
        let tf_pub = peer.publisher::<TFMessage>("/tf_static", TF_MESSAGE, &tf_qos);
        let mut image_pubs = Vec::new();
        let mut info_pubs = Vec::new();
        for i in 0..rig.cameras.len() {
            image_pubs.push(peer.publisher(&format!("/cam{i}/image_raw"), IMAGE, qos));
            info_pubs.push(peer.publisher(&format!("/cam{i}/camera_info"), CAMERA_INFO, qos));
        }
        let transforms = rig
            .cameras
            .iter()
            .enumerate()
            .map(|(i, cam)| {
                let c = cam.centre_in_rig();
                TransformStamped {
                    header: Header {
                        stamp: Time::default(),
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
        let images = images
            .iter()
            .enumerate()
            .map(|(i, image)| {
                let header = Header {
                    stamp: Time::default(),
                    frame_id: frame(i),
                };
                image_msg(&header, image, bgr_camera == Some(i))
            })
            .collect();
        RigFeed {
            rig,
            images,
            image_pubs,
            info_pubs,
            _tf_pub: tf_pub,
        }
    }

    /// Publishes one set: camera `i`'s camera_info and image stamped `stamps[i]`.
    pub fn publish_set(&self, stamps: &[Time]) {
        assert_eq!(stamps.len(), self.images.len(), "one stamp per camera");
        for (i, stamp) in stamps.iter().enumerate() {
            self.publish_camera(i, *stamp);
        }
    }

    /// Publishes one set of images rendered for it (`images[i]` for camera `i`, stamped
    /// `stamps[i]`), with the camera infos: a rig that moves through a scene.
    pub fn publish_rendered_set(&self, stamps: &[Time], images: &[Rgba8Image]) {
        assert_eq!(stamps.len(), self.images.len(), "one stamp per camera");
        assert_eq!(images.len(), self.images.len(), "one image per camera");
        for (i, (stamp, rendered)) in stamps.iter().zip(images).enumerate() {
            let header = Header {
                stamp: *stamp,
                frame_id: frame(i),
            };
            self.info_pubs[i]
                .publish(camera_info(&header, &self.rig.cameras[i].model))
                .unwrap_or_else(|e| panic!("publish cam{i}/camera_info: {e:?}"));
            self.image_pubs[i]
                .publish(image_msg(&header, rendered, false))
                .unwrap_or_else(|e| panic!("publish cam{i}/image_raw: {e:?}"));
        }
    }

    /// Publishes one set without camera `missing` (its driver has stopped).
    pub fn publish_set_without(&self, stamps: &[Time], missing: usize) {
        assert_eq!(stamps.len(), self.images.len(), "one stamp per camera");
        for (i, stamp) in stamps.iter().enumerate() {
            if i != missing {
                self.publish_camera(i, *stamp);
            }
        }
    }

    /// Camera `i`'s driver restarts: its image and camera_info publishers are dropped (their
    /// writers leave) and made anew on `peer` with `qos` (new writers; the camera_info is sent
    /// again with the next set, as a driver does when it starts).
    pub fn restart_camera(&mut self, peer: &mut Peer, i: usize, qos: &QosProfile) {
        self.image_pubs[i] = peer.publisher(&format!("/cam{i}/image_raw"), IMAGE, qos);
        self.info_pubs[i] = peer.publisher(&format!("/cam{i}/camera_info"), CAMERA_INFO, qos);
    }

    fn publish_camera(&self, i: usize, stamp: Time) {
        let header = Header {
            stamp,
            frame_id: frame(i),
        };
        self.info_pubs[i]
            .publish(camera_info(&header, &self.rig.cameras[i].model))
            .unwrap_or_else(|e| panic!("publish cam{i}/camera_info: {e:?}"));
        let mut image = self.images[i].clone();
        image.header = header;
        self.image_pubs[i]
            .publish(image)
            .unwrap_or_else(|e| panic!("publish cam{i}/image_raw: {e:?}"));
    }
}

/// The node's `/diagnostics` (one status per message), as a peer sees it.
pub struct Diagnostics {
    sub: Subscription<DiagnosticArray>,
    latest: Option<(Time, DiagnosticStatus)>,
}

impl Diagnostics {
    pub fn new(peer: &mut Peer) -> Diagnostics {
        Diagnostics {
            sub: peer.subscription("/diagnostics", DIAGNOSTIC_ARRAY, &reliable(20)),
            latest: None,
        }
    }

    /// Takes what arrived; returns every status received now, oldest first.
    pub fn take(&mut self) -> Vec<DiagnosticStatus> {
        let mut out = Vec::new();
        for array in take_all(&self.sub) {
            assert_eq!(array.status.len(), 1, "{array:?}");
            let stamp = array.header.stamp;
            if let Some(status) = array.status.into_iter().next() {
                self.latest = Some((stamp, status.clone()));
                out.push(status);
            }
        }
        out
    }

    /// Waits for a status that satisfies `pred`, naming `what` on failure (with the latest
    /// status seen).
    pub fn wait_until(
        &mut self,
        what: impl Display,
        node: &mut NodeProcess,
        mut pred: impl FnMut(&DiagnosticStatus) -> bool,
    ) -> DiagnosticStatus {
        let limit = timeout();
        let started = Instant::now();
        loop {
            for status in self.take() {
                if pred(&status) {
                    return status;
                }
            }
            node.check_alive();
            assert!(
                started.elapsed() < limit,
                "waited {limit:?} for /diagnostics to show {what} in vain; the latest: {:?}",
                self.latest
            );
            std::thread::sleep(POLL);
        }
    }

    /// Waits for a status the node made after `wall` (a snapshot of its counters taken after
    /// that moment).
    pub fn wait_after(&mut self, wall: Time, node: &mut NodeProcess) -> DiagnosticStatus {
        let limit = timeout();
        let started = Instant::now();
        loop {
            self.take();
            if let Some((stamp, status)) = &self.latest {
                if stamp.to_nanos() > wall.to_nanos() {
                    return status.clone();
                }
            }
            node.check_alive();
            assert!(
                started.elapsed() < limit,
                "waited {limit:?} for a /diagnostics message made after {wall:?} in vain"
            );
            std::thread::sleep(POLL);
        }
    }
}

/// The value of `key` in a diagnostics status.
pub fn value_of<'a>(status: &'a DiagnosticStatus, key: &str) -> Option<&'a str> {
    status
        .values
        .iter()
        .find(|kv| kv.key == key)
        .map(|kv| kv.value.as_str())
}

/// A counter of a diagnostics status; panics when it is missing or no number.
pub fn counter(status: &DiagnosticStatus, key: &str) -> u64 {
    value_of(status, key)
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no counter '{key}' in {status:?}"))
}

/// The pose `/diagnostics` reports under `key` ("world pose <frame>": "<stamp> [x, y, z]
/// [qx, qy, qz, qw]"): the stamp in seconds and the pose.
pub fn world_pose(
    status: &DiagnosticStatus,
    key: &str,
) -> (f64, sweepdepth::geometry::RigidTransform) {
    let value = value_of(status, key).unwrap_or_else(|| panic!("no '{key}' in {status:?}"));
    let numbers: Vec<f64> = value
        .split([' ', '[', ']', ','])
        .filter(|w| !w.is_empty())
        .map(|w| {
            w.parse()
                .unwrap_or_else(|e| panic!("{key}: '{w}' in '{value}': {e}"))
        })
        .collect();
    assert_eq!(numbers.len(), 8, "{key}: {value}");
    let pose = sweepdepth::geometry::RigidTransform {
        rotation: glam::DQuat::from_xyzw(numbers[4], numbers[5], numbers[6], numbers[7]),
        translation: glam::DVec3::new(numbers[1], numbers[2], numbers[3]),
    };
    (numbers[0], pose)
}

/// `got` within 1 mm and 0.05 degrees of `truth` (the moving-rig tests' bar).
pub fn assert_pose_near(
    what: &str,
    got: &sweepdepth::geometry::RigidTransform,
    truth: &sweepdepth::geometry::RigidTransform,
) {
    let mm = (got.translation - truth.translation).length() * 1e3;
    let deg = got.rotation.angle_between(truth.rotation).to_degrees();
    eprintln!("{what}: {mm:.4} mm, {deg:.5} degrees from the truth");
    assert!(mm < 1.0 && deg < 0.05, "{what}: {mm} mm, {deg} degrees off");
}
