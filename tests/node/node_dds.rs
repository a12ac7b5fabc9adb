//! End-to-end test of `sweepdepth node` over DDS (ros2-client peers in this process).
//!
//! Pace: each test feeds fresh frame sets until the node answers (whatever the machine's
//! speed), and where it must know that the node is idle (the exact-sync check) it waits for the
//! depth of the last set it sent. Every wait has the generous limit of tests/common/dds.rs.
//!
//! SAFETY: no DDS packet may leave the machine. The test never opens DDS in the host network
//! namespace: unless it already runs inside the private namespace it creates itself (marker
//! variable [`INNER`] AND a check that only `lo` exists), it re-executes its own binary inside
//! `unshare -n` (`unshare -rn` when not root) with loopback up and a multicast route on `lo`,
//! and fails with a clear message if that is impossible.

use std::time::Instant;

use crate::common::dds::{self, frame, Diagnostics, NodeProcess, Peer, RigFeed};
use crate::common::mesh::{ply_vertices, SaveMesh};
use crate::common::netns::in_private_netns;
use ros2_client::log::Log;
use ros2_client::parameters::{Parameter, ParameterValue};
use ros2_client::rcl_interfaces::{SetParametersRequest, SetParametersResponse};
use ros2_client::{Name, ServiceMapping, ServiceTypeName};
use sweepdepth::geometry::{CameraModel, RigidTransform};
use sweepdepth::image::{ImageF32, Rgba8Image};
use sweepdepth::msgs::{CameraInfo, DiagnosticStatus, Image, PointCloud2, PointField, Time};
use sweepdepth::synthetic::{self, Scene};

const INNER: &str = "SWEEPDEPTH_TEST_PRIVATE_NETNS";
const DOMAIN: u16 = 42;
const WIDTH: u32 = 80;
const HEIGHT: u32 = 60;
/// Cameras of the synthetic rig (a row, 10 cm apart; the reference is cam1).
const CAMERAS: usize = 4;

#[test]
fn node_publishes_depth_over_dds() {
    in_private_netns(INNER, "node_dds::node_publishes_depth_over_dds", end_to_end);
}

#[test]
fn node_approximate_sync_with_jittered_stamps() {
    in_private_netns(
        INNER,
        "node_dds::node_approximate_sync_with_jittered_stamps",
        approximate_sync_jitter,
    );
}

#[test]
fn node_publishes_points() {
    in_private_netns(INNER, "node_dds::node_publishes_points", points_cloud);
}

#[test]
fn node_publishes_diagnostics() {
    in_private_netns(INNER, "node_dds::node_publishes_diagnostics", diagnostics);
}

#[test]
fn node_makes_cost_and_selection_on_demand() {
    in_private_netns(
        INNER,
        "node_dds::node_makes_cost_and_selection_on_demand",
        on_demand,
    );
}

#[test]
fn node_parameter_services() {
    in_private_netns(
        INNER,
        "node_dds::node_parameter_services",
        parameter_services,
    );
}

#[test]
fn node_several_references_on_a_moving_rig() {
    in_private_netns(
        INNER,
        "node_dds::node_several_references_on_a_moving_rig",
        references_on_a_moving_rig,
    );
}

#[test]
fn node_fuses_a_moving_rig_and_saves_the_mesh() {
    in_private_netns(
        INNER,
        "node_dds::node_fuses_a_moving_rig_and_saves_the_mesh",
        fuses_a_moving_rig,
    );
}

#[test]
fn node_camera_driver_restart() {
    in_private_netns(
        INNER,
        "node_dds::node_camera_driver_restart",
        camera_driver_restart,
    );
}

#[test]
fn node_virtual_reference() {
    in_private_netns(INNER, "node_dds::node_virtual_reference", virtual_reference);
}

fn stamp_of(k: u32) -> Time {
    Time {
        sec: 1000 + (k / 10) as i32,
        nanosec: (k % 10) * 100_000_000,
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

/// The wall at 2 m alone (the pose of a camera along the row changes nothing but the texture).
fn wall() -> Scene {
    Scene::wall_and_box(2.0, None, synthetic::intrinsics(WIDTH, HEIGHT).fx_px)
}

/// A wall turned about the vertical (z = 2 m + 0.5 x in the rig frame): cameras 0.2 m apart
/// (cam0 and cam2) see it 5-7 % apart in depth at every pixel, so one reference's depth map
/// published under another's name does not pass for it.
fn slanted_wall() -> Scene {
    let focal = synthetic::intrinsics(WIDTH, HEIGHT).fx_px;
    let mut wall = synthetic::TexturedQuad::fronto_parallel(
        2.0,
        glam::DVec2::ZERO,
        None,
        2.5 * 2.0 / focal,
        1,
    );
    wall.u_axis = glam::DVec3::new(1.0, 0.0, 0.5).normalize();
    Scene {
        quads: vec![wall],
        spheres: Vec::new(),
    }
}

/// Depth `depth` against `truth` (one value per pixel): asserts that at least half are valid
/// and returns the median relative error of the valid ones.
fn median_error_against(what: &str, depth: &[f32], truth: &[f32]) -> f32 {
    let mut errors: Vec<f32> = depth
        .iter()
        .zip(truth)
        .filter(|(d, t)| d.is_finite() && t.is_finite())
        .map(|(d, t)| ((d - t) / t).abs())
        .collect();
    assert!(
        errors.len() * 2 >= depth.len(),
        "{what}: only {} of {} depths are valid",
        errors.len(),
        depth.len()
    );
    errors.sort_by(f32::total_cmp);
    errors[errors.len() / 2]
}

/// The wall at 2 m with a square box 40 cm wide at 1.2 m in front of cam1 (the reference):
/// depth that a parameter or a pose changes visibly.
fn wall_and_box() -> Scene {
    Scene::wall_and_box(
        2.0,
        Some((1.2, 0.2)),
        synthetic::intrinsics(WIDTH, HEIGHT).fx_px,
    )
}

/// The node under test and a peer node that feeds it a synthetic 4-camera row rig looking at
/// `scene` (cam1 the reference; cam2 sends bgr8).
struct Harness {
    scene: Scene,
    feed: RigFeed,
    /// The rendered images (cam1's colours the point cloud).
    images: Vec<Rgba8Image>,
    peer: Peer,
    node: NodeProcess,
}

impl Harness {
    /// Starts the node with `cameras:=[cam0, cam1, cam2, cam3]` (reference cam1), depths 1..4 m,
    /// 48 planes, no camera timeout (a test that waits must not see a camera leave the rig)
    /// and `extra` parameters (`name:=value`, later ones win), and publishes /tf_static.
    fn start(scene: Scene, extra: &[&str]) -> Harness {
        let model = CameraModel::pinhole(synthetic::intrinsics(WIDTH, HEIGHT));
        let rig = synthetic::row_rig(CAMERAS, 0.1, model, 1).expect("rig");
        let images = synthetic::render_rig(&scene, &rig);
        let mut args = vec![
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
            "-p",
            "camera_timeout:=0.0",
        ];
        for p in extra {
            args.extend(["-p", p]);
        }
        let node = NodeProcess::start(DOMAIN, &args);
        let mut peer = Peer::new(DOMAIN, "sweepdepth_test_peer");
        let feed = RigFeed::new(&mut peer, rig, &images, &dds::reliable(10), Some(2));
        Harness {
            scene,
            feed,
            images,
            peer,
            node,
        }
    }

    fn subscribe<T: 'static + serde::de::DeserializeOwned>(
        &mut self,
        topic: &str,
        message_type: (&str, &str),
    ) -> ros2_client::Subscription<T> {
        self.peer
            .subscription(topic, message_type, &dds::reliable(50))
    }

    /// Publishes one set, camera `i` stamped `stamps[i]`.
    fn publish_set(&self, stamps: [Time; CAMERAS]) {
        self.feed.publish_set(&stamps);
    }

    /// Publishes sets `k = first, first + 1, ...` (stamps from `stamps(k)`) every 100 ms
    /// until `poll` returns Some; returns it and the last `k` sent.
    fn feed_until<R>(
        &mut self,
        what: &str,
        first: u32,
        stamps: impl Fn(u32) -> [Time; CAMERAS],
        poll: impl FnMut() -> Option<R>,
    ) -> (R, u32) {
        let feed = &self.feed;
        dds::feed_until(
            what,
            &mut self.node,
            first,
            |k| feed.publish_set(&stamps(k)),
            poll,
        )
    }

    /// The true depth of `scene` for the reference camera.
    fn reference_truth(&self) -> ImageF32 {
        synthetic::reference_depth(&self.scene, &self.feed.rig)
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

/// Checks a depth image of the 2 m wall from the reference camera.
fn check_depth_image(received: &Image) {
    assert_eq!(received.encoding, "32FC1");
    assert_eq!((received.width, received.height), (WIDTH, HEIGHT));
    assert_eq!(received.step, 4 * WIDTH);
    assert_eq!(received.is_bigendian, 0);
    assert_eq!(received.header.frame_id, frame(1));
    assert_eq!(received.data.len(), (4 * WIDTH * HEIGHT) as usize);
    check_wall_depths(&dds::depth_values(received));
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

/// Of the pixels whose true depth is `surface_m` (within 0.1 %), how many there are, how many
/// have a valid depth, and how many of those are within `rel` of it.
fn on_surface(depths: &[f32], truth: &ImageF32, surface_m: f32, rel: f32) -> (usize, usize, usize) {
    let (mut total, mut valid, mut within) = (0, 0, 0);
    for (d, t) in depths.iter().zip(&truth.data) {
        if ((t - surface_m) / surface_m).abs() > 1e-3 {
            continue;
        }
        total += 1;
        if d.is_finite() {
            valid += 1;
            if ((d - surface_m) / surface_m).abs() <= rel {
                within += 1;
            }
        }
    }
    (total, valid, within)
}

fn end_to_end() {
    // Reliable inputs: the idle point and the control below wait for one particular set each,
    // which must not be lost; outputs kept 10 deep, so that none is lost to a slow reader.
    let mut h = Harness::start(
        wall(),
        &[
            "sync:=exact",
            "input_qos_reliable:=true",
            "output_qos_depth:=10",
        ],
    );
    let depth_sub = h.subscribe::<Image>("/depth/image", dds::IMAGE);
    let info_sub = h.subscribe::<CameraInfo>("/depth/camera_info", dds::CAMERA_INFO);
    let mut diag = Diagnostics::new(&mut h.peer);
    let mut depths: Vec<Image> = Vec::new();
    let mut infos: Vec<CameraInfo> = Vec::new();
    let (_, k) = h.feed_until("a depth image", 1, same_stamps, || {
        depths.extend(dds::take_all(&depth_sub));
        (!depths.is_empty()).then_some(())
    });
    let received = depths[0].clone();
    let stamp = received.header.stamp;
    assert!(
        (1..=k).any(|j| stamp_of(j) == stamp),
        "stamp {stamp:?} was never sent"
    );
    check_depth_image(&received);

    // depth/camera_info: the reference camera's model with the depth image's header.
    let info = dds::wait_for(
        format!("depth/camera_info stamped {stamp:?}"),
        &mut h.node,
        || {
            infos.extend(dds::take_all(&info_sub));
            infos.iter().find(|i| i.header.stamp == stamp).cloned()
        },
    );
    assert_eq!(info.header.frame_id, received.header.frame_id);
    assert_eq!((info.width, info.height), (WIDTH, HEIGHT));
    let k_ref = h.feed.rig.reference_model().intrinsics;
    assert!((info.k[0] - k_ref.fx_px).abs() < 1e-9 && (info.k[2] - k_ref.cx_px).abs() < 1e-9);
    assert!((info.p[0] - k_ref.fx_px).abs() < 1e-9 && (info.p[6] - k_ref.cy_px).abs() < 1e-9);

    // The node is idle once the last set sent has its depth (each camera's images arrive in
    // order, so every earlier set has been dealt with).
    dds::wait_for(
        format!("the depth of the last set sent ({:?})", stamp_of(k)),
        &mut h.node,
        || {
            depths.extend(dds::take_all(&depth_sub));
            depths
                .iter()
                .any(|d| d.header.stamp == stamp_of(k))
                .then_some(())
        },
    );

    // Exact sync must not pair jittered stamps: sets whose cameras' stamps differ by a few ms
    // give no depth. The synchroniser's own count says so, whatever the GPU hand-over dropped:
    // from the idle point, through the jittered sets and one set with equal stamps (the
    // positive control, which must give depth: a stalled node fails here), exactly one set is
    // matched, and the only depth image is the control's.
    let before = diag.wait_after(dds::wall_time_now(), &mut h.node);
    let seen = depths.len();
    let jittered = k + 1..k + 16;
    for j in jittered.clone() {
        h.publish_set(jittered_stamps(j));
    }
    let control = stamp_of(k + 16);
    h.publish_set([control; CAMERAS]);
    dds::wait_for(
        format!("the depth of the equal-stamp set after the jittered ones ({control:?})"),
        &mut h.node,
        || {
            depths.extend(dds::take_all(&depth_sub));
            depths[seen..]
                .iter()
                .any(|d| d.header.stamp == control)
                .then_some(())
        },
    );
    let after = diag.wait_after(dds::wall_time_now(), &mut h.node);
    depths.extend(dds::take_all(&depth_sub));
    for d in &depths[seen..] {
        let s = d.header.stamp;
        assert!(
            !jittered.clone().any(|j| jittered_stamps(j).contains(&s)),
            "exact sync published a depth image for jittered stamps ({s:?})"
        );
        assert_eq!(
            s, control,
            "a depth image after the idle point that is not the control's"
        );
        check_depth_image(d);
    }
    let matched = |status: &DiagnosticStatus| dds::counter(status, "sync matched");
    assert_eq!(
        matched(&after) - matched(&before),
        1,
        "from the idle point to the control, exact sync matched {} sets where only the control may match: {after:?}",
        matched(&after) - matched(&before)
    );
}

fn approximate_sync_jitter() {
    let mut h = Harness::start(wall(), &["sync:=approximate"]);
    let depth_sub = h.subscribe::<Image>("/depth/image", dds::IMAGE);
    // Two depth images, so that at least one set was matched across jittered stamps after
    // the first.
    let mut got = Vec::new();
    let (_, k) = h.feed_until("two depth images", 1, jittered_stamps, || {
        got.extend(dds::take_all(&depth_sub));
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
    let mut h = Harness::start(wall(), &["sync:=exact", "publish_points:=true"]);
    let points_sub = h.subscribe::<PointCloud2>("/points", dds::POINT_CLOUD2);
    let (cloud, k) = h.feed_until("a point cloud", 1, same_stamps, || {
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
    let k = h.feed.rig.cameras[1].model.intrinsics;
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
    let mut h = Harness::start(wall(), &["sync:=exact"]);
    let mut diag = Diagnostics::new(&mut h.peer);
    // /rosout is transient local (depth 1): the latest log line arrives even if it predates
    // the subscription.
    let rosout_sub = h
        .peer
        .subscription::<Log>("/rosout", dds::LOG, &dds::latched(10));
    let mut first = None;
    // Sets keep coming until a status reports published sets, with every camera's input
    // rate above 0 (it counts the last second) and the level OK (a set published within the
    // last 5 s): what a healthy node says.
    let rates_up = |status: &DiagnosticStatus| {
        (0..CAMERAS).all(|i| {
            dds::value_of(status, &format!("input rate cam{i} (Hz)"))
                .and_then(|v| v.parse::<f64>().ok())
                .is_some_and(|r| r > 0.0)
        })
    };
    let (status, _) = h.feed_until(
        "a /diagnostics status with sets published, every input rate above 0 and level OK",
        1,
        same_stamps,
        || {
            for status in diag.take() {
                first.get_or_insert(status.clone());
                let published = dds::value_of(&status, "sets published")
                    .and_then(|v| v.parse::<u64>().ok())
                    .unwrap_or(0);
                if published > 0 && rates_up(&status) && status.level == DiagnosticStatus::OK {
                    return Some(status);
                }
            }
            None
        },
    );
    assert_eq!(status.name, "sweepdepth: /sweepdepth");
    for key in [
        "input rate cam0 (Hz)",
        "input rate cam1 (Hz)",
        "input rate cam2 (Hz)",
        "input rate cam3 (Hz)",
        "sync matched",
        "sync dropped",
        "sync incomplete",
        "sync duplicate stamps",
        "sync late stamps",
        "sync future stamps",
        "sync resets",
        "gpu sets dropped",
        "sets dropped waiting to be sent",
        "sets published",
        "processing time last (ms)",
        "processing time mean (ms)",
        "latency (ms)",
        "gpu adapter",
        "cameras out of the rig",
    ] {
        assert!(
            dds::value_of(&status, key).is_some(),
            "no key '{key}' in {status:?}"
        );
    }
    let number = |key: &str| -> f64 {
        dds::value_of(&status, key)
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("'{key}' is not a number in {status:?}"))
    };
    for i in 0..CAMERAS {
        // Sets go out every 100 ms; a burst after a stall is at most the input queue deep.
        let rate = number(&format!("input rate cam{i} (Hz)"));
        assert!(rate > 0.0 && rate <= 40.0, "cam{i} rate {rate}");
    }
    assert!(number("sync matched") >= number("sets published"));
    assert!(number("sets published") >= 1.0);
    assert!(number("processing time last (ms)") > 0.0);
    assert!(number("processing time mean (ms)") > 0.0);
    assert!(number("latency (ms)").is_finite());
    assert!(!dds::value_of(&status, "gpu adapter")
        .unwrap_or("")
        .is_empty());
    assert_eq!(
        dds::value_of(&status, "cameras out of the rig"),
        Some("none")
    );
    // The very first status came before any set was published: WARN, saying so.
    let first = first.expect("a first status");
    if dds::counter(&first, "sets published") == 0 {
        assert_eq!(first.level, DiagnosticStatus::WARN, "{first:?}");
        assert!(first.message.contains("no depth published"), "{first:?}");
    }
    // The node's log lines also go to /rosout.
    let log = dds::wait_for("a /rosout line from the node", &mut h.node, || {
        dds::take_all(&rosout_sub)
            .into_iter()
            .find(|log| log.name == "sweepdepth")
    });
    assert!(log.level == Log::INFO || log.level == Log::WARN, "{log:?}");
    assert!(!log.msg.is_empty());
}

/// The cost and selection images are made while someone subscribes to them, as
/// image_pipeline's nodes do (the WGSL engine then reads back only depth and confidence): none
/// while only depth is read, the cost once a subscriber of it appears (a real 32FC1 map of the
/// set's stamp), not the selection, and none again after it leaves.
fn on_demand() {
    const KEY: &str = "outputs made on demand";
    let mut h = Harness::start(wall(), &["sync:=exact"]);
    let mut diag = Diagnostics::new(&mut h.peer);
    let depth_sub = h.subscribe::<Image>("/depth/image", dds::IMAGE);
    let mut depths = 0;
    let (status, sent) = h.feed_until("depth, and a status made after it", 1, same_stamps, || {
        depths += dds::take_all(&depth_sub).len();
        let published = |s: &DiagnosticStatus| dds::counter(s, "sets published") > 0;
        (depths > 0)
            .then(|| diag.take().into_iter().find(published))
            .flatten()
    });
    assert_eq!(dds::value_of(&status, KEY), Some("none"), "{status:?}");

    let cost_sub = h.subscribe::<Image>("/cost/image", dds::IMAGE);
    let (cost, k) = h.feed_until("a cost image", sent + 1, same_stamps, || {
        cost_sub.take().ok().flatten().map(|(m, _)| m)
    });
    assert!(
        (sent + 1..=k).any(|j| stamp_of(j) == cost.header.stamp),
        "stamp {:?} was never sent",
        cost.header.stamp
    );
    assert_eq!((cost.width, cost.height), (WIDTH, HEIGHT));
    assert_eq!(cost.encoding, "32FC1");
    assert_eq!(cost.data.len(), (4 * WIDTH * HEIGHT) as usize);
    let finite = cost
        .data
        .chunks_exact(4)
        .filter(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]).is_finite())
        .count();
    assert!(
        finite * 2 > (WIDTH * HEIGHT) as usize,
        "{finite} finite costs"
    );
    // The last set published had the cost and nothing else made on demand.
    diag.wait_until("the cost made", &mut h.node, |s| {
        dds::value_of(s, KEY) == Some("cost")
    });

    // Its reader gone, the next sets have no cost.
    drop(cost_sub);
    let (status, _) = h.feed_until(
        "a set without the cost once its reader left",
        k + 1,
        same_stamps,
        || {
            diag.take()
                .into_iter()
                .find(|s| dds::value_of(s, KEY) == Some("none"))
        },
    );
    assert!(dds::counter(&status, "sets published") > 1);
}

type SetClient = ros2_client::Client<SetParametersRequest, SetParametersResponse>;

/// Calls `~/set_parameters` with one parameter (sending the request again every second until
/// the service answers) and returns (successful, reason).
fn set_parameter(
    client: &SetClient,
    node: &mut NodeProcess,
    name: &str,
    value: ParameterValue,
) -> (bool, String) {
    let mut ids = Vec::new();
    let mut sent = Instant::now() - std::time::Duration::from_secs(1);
    dds::wait_for(
        format!("an answer from /sweepdepth/set_parameters ({name})"),
        node,
        || {
            if sent.elapsed() >= std::time::Duration::from_secs(1) {
                let request = SetParametersRequest {
                    parameter: vec![Parameter {
                        name: name.to_string(),
                        value: value.clone(),
                    }
                    .into()],
                };
                ids.push(client.send_request(request).expect("send the request"));
                sent = Instant::now();
            }
            match client.receive_response() {
                Ok(Some((rid, response))) if ids.contains(&rid) => {
                    assert_eq!(response.results.len(), 1, "{response:?}");
                    let r = &response.results[0];
                    Some((r.successful, r.reason.clone()))
                }
                _ => None,
            }
        },
    )
}

fn parameter_services() {
    let mut h = Harness::start(wall_and_box(), &["sync:=exact"]);
    let depth_sub = h.subscribe::<Image>("/depth/image", dds::IMAGE);
    let service_qos = dds::reliable(1);
    let client: SetClient = h
        .peer
        .node
        .create_client(
            ServiceMapping::Enhanced,
            &Name::parse("/sweepdepth/set_parameters").unwrap(),
            &ServiceTypeName::new("rcl_interfaces", "SetParameters"),
            service_qos.clone(),
            service_qos,
        )
        .expect("set_parameters client");
    let truth = h.reference_truth();

    // The wall at 2 m and the box at 1.2 m, swept over 1..4 m: both found.
    let (before, k) = h.feed_until("a depth image", 1, same_stamps, || {
        depth_sub.take().ok().flatten().map(|(m, _)| m)
    });
    let depths = dds::depth_values(&before);
    for (surface, name) in [(2.0, "wall"), (1.2, "box")] {
        let (total, valid, within) = on_surface(&depths, &truth, surface, 0.02);
        eprintln!("before: {name}: {valid} of {total} pixels valid, {within} within 2 %");
        assert!(
            total > 300 && within * 10 >= total * 6,
            "before the change only {within} of the {total} pixels of the {name} at {surface} m are within 2 % of it"
        );
    }

    // Rejected, with reasons.
    let node = &mut h.node;
    let (ok, reason) = set_parameter(&client, node, "min_depth", ParameterValue::Double(5.0));
    assert!(!ok && reason.contains("max_depth"), "{reason}");
    let (ok, reason) = set_parameter(&client, node, "num_planes", ParameterValue::Integer(1));
    assert!(!ok && reason.contains("num_planes"), "{reason}");
    let (ok, reason) = set_parameter(
        &client,
        node,
        "sync",
        ParameterValue::String("approximate".into()),
    );
    assert!(!ok && reason.contains("read-only"), "{reason}");
    let (ok, reason) = set_parameter(
        &client,
        node,
        "window_mode",
        ParameterValue::String("shiftable".into()),
    );
    assert!(!ok && reason.contains("even"), "{reason}");
    let (ok, reason) = set_parameter(
        &client,
        node,
        "no_such_parameter",
        ParameterValue::Integer(1),
    );
    assert!(!ok && !reason.is_empty());
    // Four cameras, reference pairs: best 4 of the 3 pairs does not fit the rig (checked while
    // best_n is read: scoring best_n_of_m; the default best half-sequence does not read it).
    let (ok, reason) = set_parameter(
        &client,
        node,
        "scoring",
        ParameterValue::String("best_n_of_m".into()),
    );
    assert!(ok, "scoring:=best_n_of_m rejected: {reason}");
    let (ok, reason) = set_parameter(&client, node, "best_n", ParameterValue::Integer(4));
    assert!(
        !ok && reason.contains("best_n (4)") && reason.contains("3 camera pairs"),
        "{reason}"
    );
    let (ok, reason) = set_parameter(
        &client,
        node,
        "scoring",
        ParameterValue::String("best_half_sequence".into()),
    );
    assert!(ok, "scoring:=best_half_sequence rejected: {reason}");

    // Sweep 1.5..4 m: the box at 1.2 m is out of range, the wall still in it. The next sets'
    // depth has nothing nearer than 1.5 m, and the wall is found as before.
    let (ok, reason) = set_parameter(&client, node, "min_depth", ParameterValue::Double(1.5));
    assert!(ok, "min_depth:=1.5 rejected: {reason}");
    let first_after = k + 1_000;
    let (after, _) = h.feed_until(
        "a depth image of a set sent after min_depth:=1.5",
        first_after,
        same_stamps,
        || {
            dds::take_all(&depth_sub)
                .into_iter()
                .find(|m| nanos(m.header.stamp) >= nanos(stamp_of(first_after)))
        },
    );
    let depths = dds::depth_values(&after);
    let nearer: Vec<f32> = depths
        .iter()
        .copied()
        .filter(|d| d.is_finite() && *d < 1.5 * 0.999)
        .collect();
    assert!(
        nearer.is_empty(),
        "{} depths nearer than 1.5 m after min_depth:=1.5, e.g. {:?}",
        nearer.len(),
        &nearer[..nearer.len().min(5)]
    );
    let (total, valid, within) = on_surface(&depths, &truth, 2.0, 0.02);
    eprintln!("after min_depth:=1.5: wall: {valid} of {total} pixels valid, {within} within 2 %");
    assert!(
        within * 10 >= total * 6,
        "after min_depth:=1.5 only {within} of the {total} wall pixels are within 2 % of 2 m"
    );
}

/// A virtual reference camera 15 cm right of cam1 (between cam2 and cam3 of the row, which
/// sit at 0.1 and 0.2 m), 64x48 with its own intrinsics: the depth image is the virtual
/// camera's, stamped like cam1's image and in cam1's frame (virtual_frame_id empty). The box
/// in front of the wall shows where the camera is: its depth must be where the virtual pose
/// sees it, not where cam1 (the pose ignored) would.
fn virtual_reference() {
    let mut h = Harness::start(
        wall_and_box(),
        &[
            "sync:=exact",
            "virtual_reference:=true",
            "virtual_pose:=[0.15, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]",
            "virtual_width:=64",
            "virtual_height:=48",
            "virtual_fx:=60.0",
            "virtual_fy:=60.0",
            "virtual_cx:=31.5",
            "virtual_cy:=23.5",
            // The default scoring: this virtual camera's right half has no pair (only cam3
            // is right of it), so the half-sequence scores best n of m over all pairs
            // (docs/engine.md, Virtual references; the halves alone got 122 of 280 telling pixels
            // here).
        ],
    );
    let depth_sub = h.subscribe::<Image>("/depth/image", dds::IMAGE);
    let info_sub = h.subscribe::<CameraInfo>("/depth/camera_info", dds::CAMERA_INFO);
    let mut infos: Vec<CameraInfo> = Vec::new();
    let (depth, k) = h.feed_until("a depth image", 1, same_stamps, || {
        depth_sub.take().ok().flatten().map(|(m, _)| m)
    });
    let info = dds::wait_for(
        format!("depth/camera_info stamped {:?}", depth.header.stamp),
        &mut h.node,
        || {
            infos.extend(dds::take_all(&info_sub));
            infos
                .iter()
                .find(|i| i.header.stamp == depth.header.stamp)
                .cloned()
        },
    );
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

    // The true depth from the virtual pose, and from cam1's (where the box appears 7.5 px
    // further right): the pixels where the two differ decide.
    let model = CameraModel::pinhole(sweepdepth::geometry::PinholeIntrinsics {
        width_px: 64,
        height_px: 48,
        fx_px: 60.0,
        fy_px: 60.0,
        cx_px: 31.5,
        cy_px: 23.5,
    });
    let at_x = |x: f64| RigidTransform {
        rotation: glam::DQuat::IDENTITY,
        translation: glam::DVec3::new(-x, 0.0, 0.0),
    };
    let right = h.scene.depth(&model, &at_x(0.15));
    let wrong = h.scene.depth(&model, &at_x(0.0));
    let depths = dds::depth_values(&depth);
    let near = |d: f32, t: f32| d.is_finite() && ((d - t) / t).abs() <= 0.05;
    let (mut telling, mut near_right, mut near_wrong) = (0, 0, 0);
    for ((d, r), w) in depths.iter().zip(&right.data).zip(&wrong.data) {
        if ((r - w) / r).abs() > 0.2 {
            telling += 1;
            near_right += usize::from(near(*d, *r));
            near_wrong += usize::from(near(*d, *w));
        }
    }
    let all_right = depths
        .iter()
        .zip(&right.data)
        .filter(|(d, r)| near(**d, **r))
        .count();
    eprintln!(
        "virtual reference: {all_right} of {} depths within 5 % of the truth; of the {telling} pixels where the pose tells, {near_right} agree with the virtual pose, {near_wrong} with cam1's",
        depths.len()
    );
    assert!(
        all_right * 10 >= depths.len() * 7,
        "only {all_right} of {} depths are within 5 % of the virtual camera's true depth",
        depths.len()
    );
    assert!(
        telling > 100 && near_right * 2 >= telling && near_wrong * 5 <= telling,
        "of the {telling} pixels where the pose tells, {near_right} agree with the virtual pose and {near_wrong} with cam1's"
    );
}

/// The rig's pose in "world" at `t`: along x at 0.3 m/s and forward at 0.1 m/s, turning about
/// y at 0.1 rad/s from stamp_of(0) (tf2's interpolation is exact for it).
/// `/tf`'s world -> rig at `t` ([`world_from_rig`]).
fn tf_at(t: Time) -> sweepdepth::msgs::TFMessage {
    use sweepdepth::msgs::{Header, Quaternion, TFMessage, Transform, TransformStamped, Vector3};
    let pose = world_from_rig(t);
    let (p, q) = (pose.translation, pose.rotation);
    TFMessage {
        transforms: vec![TransformStamped {
            header: Header {
                stamp: t,
                frame_id: "world".into(),
            },
            child_frame_id: "rig".into(),
            transform: Transform {
                translation: Vector3 {
                    x: p.x,
                    y: p.y,
                    z: p.z,
                },
                rotation: Quaternion {
                    x: q.x,
                    y: q.y,
                    z: q.z,
                    w: q.w,
                },
            },
        }],
    }
}

/// The rig's pose in `world`: from about 1 m and 30 degrees off the identity (a node that
/// ignored /tf would put its depth and mesh there), moving along x and forward and turning
/// about y at constant rates (tf2's interpolation is exact for it).
fn world_from_rig(t: Time) -> RigidTransform {
    let s = (nanos(t) - nanos(stamp_of(0))) as f64 * 1e-9;
    RigidTransform {
        rotation: glam::DQuat::from_rotation_y(0.52 + 0.1 * s),
        translation: glam::DVec3::new(0.8 + 0.3 * s, 0.2, -0.5 + 0.1 * s),
    }
}

/// A camera driver restarts over DDS (`camera_timeout:=1.0`): cam3's publishers stop; after
/// the timeout the node logs that it leaves the rig (on /rosout), /diagnostics names it out of
/// the rig and depth goes on without it; then cam3 comes back as new writers (camera_info
/// sent again), the node logs that it is back (4 of 4 cameras), /diagnostics says no camera
/// is out, and depth of sets after the restart comes with every camera.
fn camera_driver_restart() {
    let mut h = Harness::start(wall(), &["sync:=exact", "camera_timeout:=1.0"]);
    let depth = h.subscribe::<Image>("/depth/image", dds::IMAGE);
    let rosout = h
        .peer
        .subscription::<Log>("/rosout", dds::LOG, &dds::reliable(100));
    let mut diagnostics = Diagnostics::new(&mut h.peer);
    let mut lines: Vec<String> = Vec::new();
    let read_log = |lines: &mut Vec<String>| {
        lines.extend(dds::take_all(&rosout).into_iter().map(|l| l.msg));
    };
    // Depth with all four.
    let (_, last) = h.feed_until("the first depth image", 1, same_stamps, || {
        dds::take_all(&depth).pop()
    });
    // cam3's driver stops: sets without it until the node says it left and depth flows again.
    let feed = &h.feed;
    let (_, last) = dds::feed_until(
        "cam3 out of the rig and depth without it",
        &mut h.node,
        last + 1,
        |k| feed.publish_set_without(&same_stamps(k), 3),
        || {
            read_log(&mut lines);
            let left = lines.iter().any(|l| {
                l.contains("camera 'cam3' has sent nothing for") && l.contains("leaves the rig")
            });
            (left && !dds::take_all(&depth).is_empty()).then_some(())
        },
    );
    let status = diagnostics.wait_until("cam3 out of the rig in /diagnostics", &mut h.node, |s| {
        dds::value_of(s, "cameras out of the rig") == Some("cam3")
    });
    assert!(
        status
            .message
            .starts_with("degraded rig: publishing depth without cam3"),
        "{status:?}"
    );
    // The driver starts again: new writers, camera_info again, every camera in each set.
    h.feed.restart_camera(&mut h.peer, 3, &dds::reliable(10));
    let restarted = last + 1;
    let feed = &h.feed;
    let (stamp, _) = dds::feed_until(
        "cam3 back and depth of a set after the restart",
        &mut h.node,
        restarted,
        |k| feed.publish_set(&same_stamps(k)),
        || {
            read_log(&mut lines);
            let back = lines.iter().any(|l| {
                l.contains("camera 'cam3' is sending again and is back in the rig (4 of 4 cameras)")
            });
            let after = dds::take_all(&depth)
                .into_iter()
                .map(|i| i.header.stamp)
                .rfind(|s| nanos(*s) >= nanos(stamp_of(restarted)));
            after.filter(|_| back)
        },
    );
    let status = diagnostics.wait_until("no camera out of the rig", &mut h.node, |s| {
        dds::value_of(s, "cameras out of the rig") == Some("none")
            && s.message == "publishing depth"
    });
    eprintln!(
        "cam3 left and came back; depth at {}.{:09}; /diagnostics: {}",
        stamp.sec, stamp.nanosec, status.message
    );
}

/// `references:=[cam0, cam2]` with `world_frame:=world`: each reference publishes under its
/// camera's namespace (and nothing on the single-reference names), each with its own depth
/// of a slanted wall (each map's median error against its own camera's true depth, pixel by
/// pixel; the other's true depth differs by 5 % everywhere, so swapped or shared maps fail); /tf (world -> rig) comes twice per set, 30 ms before and 40 ms after each
/// set's stamp, never at it; the pose each reference's set carried (reported in
/// /diagnostics) equals the true pose of its camera at the set's stamp within 1 mm and 0.05
/// degrees.
fn references_on_a_moving_rig() {
    use sweepdepth::msgs::TFMessage;
    let mut h = Harness::start(
        slanted_wall(),
        &[
            "sync:=exact",
            "references:=[cam0, cam2]",
            "world_frame:=world",
            "tf_timeout:=5.0",
        ],
    );
    let tf_pub = h
        .peer
        .publisher::<TFMessage>("/tf", dds::TF_MESSAGE, &dds::reliable(100));
    let cam0 = h.subscribe::<Image>("/cam0/depth/image", dds::IMAGE);
    let cam2 = h.subscribe::<Image>("/cam2/depth/image", dds::IMAGE);
    let single = h.subscribe::<Image>("/depth/image", dds::IMAGE);
    let mut diagnostics = Diagnostics::new(&mut h.peer);
    let (mut got0, mut got2): (Vec<Image>, Vec<Image>) = (Vec::new(), Vec::new());
    let feed = &h.feed;
    let (stamp, _) = dds::feed_until(
        "depth from both references for one set",
        &mut h.node,
        1,
        |k| {
            let t = nanos(stamp_of(k));
            for offset in [-30_000_000, 40_000_000] {
                tf_pub
                    .publish(tf_at(time_of(t + offset)))
                    .expect("publish /tf");
            }
            feed.publish_set(&same_stamps(k));
        },
        || {
            got0.extend(dds::take_all(&cam0));
            got2.extend(dds::take_all(&cam2));
            got0.iter()
                .map(|i| i.header.stamp)
                .find(|s| got2.iter().any(|i| i.header.stamp == *s))
        },
    );
    let image0 = got0.iter().find(|i| i.header.stamp == stamp).expect("cam0");
    let image2 = got2.iter().find(|i| i.header.stamp == stamp).expect("cam2");
    assert_eq!(image0.header.frame_id, frame(0));
    assert_eq!(image2.header.frame_id, frame(2));
    let truth = |i: usize| {
        let camera = &h.feed.rig.cameras[i];
        h.scene.depth(&camera.model, &camera.cam_from_rig).data
    };
    let (truth0, truth2) = (truth(0), truth(2));
    let apart = truth0
        .iter()
        .zip(&truth2)
        .filter(|(a, b)| ((*a - *b) / *a).abs() > 0.04)
        .count();
    assert!(
        apart * 10 >= truth0.len() * 9,
        "the two references' true depths differ by > 4 % at {apart} of {} pixels",
        truth0.len()
    );
    for (name, image, own, other) in [
        ("cam0", image0, &truth0, &truth2),
        ("cam2", image2, &truth2, &truth0),
    ] {
        assert_eq!(image.encoding, "32FC1");
        assert_eq!((image.width, image.height), (WIDTH, HEIGHT));
        let depth = dds::depth_values(image);
        let mine = median_error_against(name, &depth, own);
        let theirs = median_error_against(name, &depth, other);
        eprintln!(
            "{name}: median error {:.2} % against its own true depth, {:.2} % against the other \
             reference's",
            100.0 * mine,
            100.0 * theirs
        );
        assert!(
            mine < 0.025 && theirs > 0.035,
            "{name}: median error {:.2} % against its own true depth (want < 2.5 %), {:.2} % \
             against the other reference's (want > 3.5 %)",
            100.0 * mine,
            100.0 * theirs
        );
    }
    assert!(
        dds::take_all(&single).is_empty(),
        "with several references nothing goes to /depth/image"
    );
    // The poses the sets carried: each reference's frame in world at the set's stamp.
    for i in [0, 2] {
        let key = format!("world pose {}", frame(i));
        let status = diagnostics.wait_until(format!("'{key}'"), &mut h.node, |s| {
            dds::value_of(s, &key).is_some()
        });
        let value = dds::value_of(&status, &key).expect("the key").to_string();
        let (seconds, got) = dds::world_pose(&status, &key);
        let t = time_of((seconds * 1e3).round() as i64 * 1_000_000);
        let truth = world_from_rig(t).compose(&h.feed.rig.cameras[i].cam_from_rig.inverse());
        dds::assert_pose_near(&format!("{key}: {value}"), &got, &truth);
    }
}

/// `fusion:=true` on a moving rig (`world_frame:=world`, two references): the mesh's markers
/// come on /mesh in `world`, and `~/save_mesh` writes a PLY whose vertices lie on the wall
/// (2 m in front of the rig at the set's pose) within two voxels; a path in a folder that does
/// not exist gives `success: false` and the reason.
fn fuses_a_moving_rig() {
    use sweepdepth::msgs::{Marker, MarkerArray, TFMessage};
    const VOXEL: f64 = 0.04;
    let mut h = Harness::start(
        wall(),
        &[
            "sync:=exact",
            "references:=[cam0, cam2]",
            "world_frame:=world",
            "tf_timeout:=5.0",
            "fusion:=true",
            "voxel_size:=0.04",
            "mesh_rate:=20.0",
        ],
    );
    let tf_pub = h
        .peer
        .publisher::<TFMessage>("/tf", dds::TF_MESSAGE, &dds::reliable(100));
    let mesh_sub = h.subscribe::<MarkerArray>("/mesh", ("visualization_msgs", "MarkerArray"));
    let save_mesh = SaveMesh::new(&mut h.peer, "/sweepdepth/save_mesh");
    // One set is enough: its markers, in world.
    let mut markers: Vec<Marker> = Vec::new();
    let feed = &h.feed;
    let (stamp, _) = dds::feed_until(
        "the mesh of one set on /mesh",
        &mut h.node,
        1,
        |k| {
            let t = nanos(stamp_of(k));
            for offset in [-30_000_000, 40_000_000] {
                tf_pub
                    .publish(tf_at(time_of(t + offset)))
                    .expect("publish /tf");
            }
            feed.publish_set(&same_stamps(k));
        },
        || {
            for array in dds::take_all(&mesh_sub) {
                markers.extend(array.markers);
            }
            markers.first().map(|m| m.header.stamp)
        },
    );
    assert!(markers.iter().all(|m| m.header.frame_id == "world"
        && m.r#type == Marker::TRIANGLE_LIST
        && (m.action == Marker::DELETE
            || (m.action == Marker::ADD && m.points.len() == m.colors.len()))));
    // The wall in the rig at this set's pose: z_rig = 2 m (the row's cameras look along +z
    // of the rig frame).
    let rig_from_world = world_from_rig(stamp).inverse();
    let on_wall = |p: glam::DVec3| (rig_from_world.transform_point(p).z - 2.0).abs() <= 2.0 * VOXEL;
    let points: Vec<glam::DVec3> = markers
        .iter()
        .filter(|m| m.action == Marker::ADD)
        .flat_map(|m| m.points.iter().map(|p| glam::DVec3::new(p.x, p.y, p.z)))
        .collect();
    let near = points.iter().filter(|p| on_wall(**p)).count();
    eprintln!(
        "{} of {} marker points within 2 voxels of the wall",
        near,
        points.len()
    );
    assert!(!points.is_empty() && near * 100 >= points.len() * 95);

    // Saved where asked.
    let dir = std::env::temp_dir().join(format!("sweepdepth-mesh-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("map.ply");
    let mut call = |file_path: String| save_mesh.call(&file_path, &mut h.node);
    let answer = call(path.display().to_string());
    assert!(answer.success, "{answer:?}");
    assert!(answer.message.contains("triangles"), "{answer:?}");
    let ply = std::fs::read(&path).expect("the PLY file");
    let vertices = ply_vertices(&ply);
    let near = vertices.iter().filter(|p| on_wall(**p)).count();
    eprintln!(
        "{} of {} PLY vertices within 2 voxels of the wall",
        near,
        vertices.len()
    );
    assert!(!vertices.is_empty() && near * 100 >= vertices.len() * 95);
    let refused = call(dir.join("no/such/folder/map.ply").display().to_string());
    assert!(!refused.success, "{refused:?}");
    assert!(refused.message.contains("no/such/folder"), "{refused:?}");
    let _ = std::fs::remove_dir_all(&dir);
}
