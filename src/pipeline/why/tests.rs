//! Unit tests of the "why no depth" diagnosis, through `Pipeline::push` as the node and `bag`
//! feed it.

use super::*;
use crate::msgs::{
    CameraInfo, Header, Image, TFMessage, Time, Transform, TransformStamped, Vector3,
};
use crate::pipeline::{intrinsics_info, Input, Pipeline};

const W: u32 = 16;
const H: u32 = 12;
const S: u64 = 1_000_000_000;

fn config(extra: &[&str]) -> PipelineConfig {
    let mut args: Vec<String> = [
        "--ros-args",
        "-r",
        "__ns:=/rig",
        "-p",
        "cameras:=[a, b, c]",
        "-p",
        "reference_camera:=a",
        "-p",
        "camera_timeout:=0.0",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    for p in extra {
        args.push("-p".into());
        args.push(p.to_string());
    }
    PipelineConfig::from_args(&args).unwrap()
}

fn stamp(ns: i64) -> Time {
    Time {
        sec: (ns / 1_000_000_000) as i32,
        nanosec: (ns % 1_000_000_000) as u32,
    }
}

fn frame(camera: usize) -> String {
    format!("{}_optical", ["a", "b", "c"][camera])
}

fn image(camera: usize, ns: i64) -> Input {
    Input::Image {
        camera,
        image: Image {
            header: Header {
                stamp: stamp(ns),
                frame_id: frame(camera),
            },
            height: H,
            width: W,
            encoding: "rgb8".into(),
            is_bigendian: 0,
            step: 3 * W,
            data: vec![128; (3 * W * H) as usize],
        },
    }
}

fn info(camera: usize) -> Input {
    let info: CameraInfo = intrinsics_info(&crate::synthetic::intrinsics(W, H));
    Input::CameraInfo {
        camera,
        info: Box::new(info),
    }
}

/// `/tf_static` placing the cameras `cameras` in the frame `rig`, 10 cm apart.
fn tf_static(cameras: &[usize]) -> Input {
    Input::TfStatic(TFMessage {
        transforms: cameras
            .iter()
            .map(|&i| TransformStamped {
                header: Header {
                    stamp: Time::default(),
                    frame_id: "rig".into(),
                },
                child_frame_id: frame(i),
                transform: Transform {
                    translation: Vector3 {
                        x: 0.1 * i as f64,
                        y: 0.0,
                        z: 0.0,
                    },
                    ..Transform::default()
                },
            })
            .collect(),
    })
}

/// 1000.1 s, 1000.2 s, ... (10 Hz).
fn set_stamp(k: i64) -> i64 {
    1000 * S as i64 + k * 100_000_000
}

/// Asked live at `now_ns` with a 5 s window.
fn live(now_ns: u64) -> Asked {
    Asked {
        now_ns,
        window_ns: Some(5 * S),
    }
}

fn unknown(_: &str) -> Publishers {
    Publishers::Unknown
}

/// Pushes `sets` sets of the three cameras, camera `i` stamped `set_stamp(k) + offsets[i]`,
/// one every 100 ms of receive time from `t0`; returns the receive time after the last.
fn feed(p: &mut Pipeline<'_>, t0: u64, sets: i64, offsets_ns: [i64; 3]) -> u64 {
    let mut now = t0;
    for k in 1..=sets {
        for (i, offset) in offsets_ns.iter().enumerate() {
            p.push(image(i, set_stamp(k) + offset), now);
        }
        now += S / 10;
    }
    now
}

fn calibrated(p: &mut Pipeline<'_>) {
    for i in 0..3 {
        p.push(info(i), 0);
    }
    p.push(tf_static(&[0, 1, 2]), 0);
}

#[test]
fn nothing_at_all_names_the_first_image_topic() {
    let config = config(&[]);
    let p = Pipeline::new(&config).unwrap();
    let why = p.why_no_depth(live(6 * S), &unknown).unwrap();
    assert_eq!(why.kind, WhyKind::NoImage);
    assert_eq!(
        why.message,
        "no image on /rig/a/image_raw yet (nor from 2 other cameras)"
    );
    let why = p.why_no_depth(live(6 * S), &|_| Publishers::None).unwrap();
    assert_eq!(why.kind, WhyKind::NoPublisher);
    assert!(
        why.message.starts_with(
            "no publisher on /rig/a/image_raw: check the namespace, the remaps and ROS_DOMAIN_ID"
        ),
        "{why}"
    );
    // A driver that publishes only image_transport's compressed topic: the parameter to set.
    let why = p
        .why_no_depth(live(6 * S), &|topic| {
            if topic.ends_with("/compressed") {
                Publishers::Matched(1)
            } else {
                Publishers::None
            }
        })
        .unwrap();
    assert_eq!(why.kind, WhyKind::NoPublisher);
    assert!(
        why.message.starts_with(
            "no publisher on /rig/a/image_raw, but one on /rig/a/image_raw/compressed: set \
             image_transport to compressed"
        ),
        "{why}"
    );
    let why = p
        .why_no_depth(live(6 * S), &|topic| {
            if topic == "/rig/a/image_raw" {
                Publishers::Incompatible("it offers best-effort, the node requests reliable".into())
            } else {
                Publishers::Matched(1)
            }
        })
        .unwrap();
    assert_eq!(why.kind, WhyKind::IncompatibleQos);
    assert!(
        why.message.starts_with("the publisher on /rig/a/image_raw cannot match: it offers best-effort, the node requests reliable"),
        "{why}"
    );
}

#[test]
fn one_camera_silent_is_named() {
    let config = config(&[]);
    let mut p = Pipeline::new(&config).unwrap();
    calibrated(&mut p);
    for k in 1..=5 {
        p.push(image(0, set_stamp(k)), k as u64 * S / 10);
        p.push(image(2, set_stamp(k)), k as u64 * S / 10);
    }
    let why = p
        .why_no_depth(live(S), &|_| Publishers::Matched(1))
        .unwrap();
    assert_eq!(why.kind, WhyKind::NoImage);
    assert_eq!(why.camera, Some(1));
    assert_eq!(
        why.message,
        "no image on /rig/b/image_raw yet (1 publisher matched, nothing received)"
    );
}

#[test]
fn camera_info_missing_is_named() {
    let config = config(&[]);
    let mut p = Pipeline::new(&config).unwrap();
    p.push(info(0), 0);
    p.push(info(1), 0);
    p.push(tf_static(&[0, 1, 2]), 0);
    let now = feed(&mut p, 0, 20, [0; 3]);
    let why = p.why_no_depth(live(now), &unknown).unwrap();
    assert_eq!(why.kind, WhyKind::NoCameraInfo);
    assert_eq!(why.camera, Some(2));
    assert_eq!(
        why.message,
        "images arrive but no camera_info on /rig/c/camera_info"
    );
    let why = p
        .why_no_depth(live(now), &|topic| {
            if topic.ends_with("camera_info") {
                Publishers::None
            } else {
                Publishers::Matched(1)
            }
        })
        .unwrap();
    assert_eq!(why.kind, WhyKind::NoPublisher);
    assert!(
        why.message
            .starts_with("images arrive but no publisher on /rig/c/camera_info"),
        "{why}"
    );
    // A publisher matched that sent nothing: most likely one camera_info latched before the
    // node started, which a volatile reader never gets.
    let why = p
        .why_no_depth(live(now), &|_| Publishers::Matched(1))
        .unwrap();
    assert_eq!(why.kind, WhyKind::NoCameraInfo);
    assert!(
        why.message.starts_with(
            "images arrive but no camera_info on /rig/c/camera_info (1 publisher matched, \
             nothing received): the node reads camera_info as image_transport does (volatile)"
        ),
        "{why}"
    );
    // A bag says it in the past tense.
    let bag = Asked {
        now_ns: now,
        window_ns: None,
    };
    let why = p.why_no_depth(bag, &unknown).unwrap();
    assert_eq!(
        why.message,
        "camera_info never recorded for c (/rig/c/camera_info)"
    );
}

#[test]
fn missing_tf_static_link_names_the_frames() {
    let config = config(&[]);
    let mut p = Pipeline::new(&config).unwrap();
    for i in 0..3 {
        p.push(info(i), 0);
    }
    let now = feed(&mut p, 0, 20, [0; 3]);
    let why = p.why_no_depth(live(now), &unknown).unwrap();
    assert_eq!(why.kind, WhyKind::NoTransform);
    assert_eq!(
        why.message,
        "no transform from 'a_optical' to 'b_optical' in /tf_static: nothing received on /tf_static yet"
    );
    p.push(tf_static(&[0, 1]), now);
    let why = p.why_no_depth(live(now), &unknown).unwrap();
    assert_eq!(why.kind, WhyKind::NoTransform);
    assert_eq!(why.camera, Some(2));
    assert!(
        why.message.starts_with(
            "no transform from 'a_optical' to 'c_optical' in /tf_static (camera 'c'): "
        ),
        "{why}"
    );
}

#[test]
fn approximate_sync_offset_names_the_camera_and_the_interval() {
    let config = config(&["sync_max_interval:=0.02"]);
    let mut p = Pipeline::new(&config).unwrap();
    calibrated(&mut p);
    let now = feed(&mut p, 0, 30, [0, 0, -48_000_000]);
    let why = p.why_no_depth(live(now + 6 * S), &unknown);
    // (The images are older than the window by then: a silent camera comes first.)
    assert_eq!(why.unwrap().kind, WhyKind::ImagesStopped);
    let why = p.why_no_depth(live(now), &unknown).unwrap();
    assert_eq!(why.kind, WhyKind::SyncOffset, "{why}");
    assert_eq!(why.camera, Some(2));
    assert_eq!(
        why.message,
        "c is 48 ms behind the others; sync_max_interval is 20 ms"
    );

    let mut p = Pipeline::new(&config).unwrap();
    calibrated(&mut p);
    let now = feed(&mut p, 0, 30, [0, 30_000_000, 0]);
    let why = p.why_no_depth(live(now), &unknown).unwrap();
    assert_eq!(
        why.message,
        "b is 30 ms ahead of the others; sync_max_interval is 20 ms"
    );
}

#[test]
fn exact_sync_with_unequal_stamps_shows_them() {
    let config = config(&["sync:=exact"]);
    let mut p = Pipeline::new(&config).unwrap();
    calibrated(&mut p);
    let now = feed(&mut p, 0, 10, [0, 0, 5_000_000]);
    let why = p.why_no_depth(live(now), &unknown).unwrap();
    assert_eq!(why.kind, WhyKind::ExactSyncUnequal);
    assert!(
        why.message
            .starts_with("exact sync: stamps never equal (a 1001.000, c 1001.005)"),
        "{why}"
    );
}

#[test]
fn depth_flowing_is_no_problem_and_a_stop_is_named() {
    let config = config(&[]);
    let mut p = Pipeline::new(&config).unwrap();
    calibrated(&mut p);
    let now = feed(&mut p, 0, 10, [0; 3]);
    assert_eq!(p.why_no_depth(live(now), &unknown), None);
    let why = p.why_no_depth(live(now + 10 * S), &unknown).unwrap();
    assert_eq!(why.kind, WhyKind::ImagesStopped);
    assert!(
        why.message
            .starts_with("no image on /rig/a/image_raw for 10."),
        "{why}"
    );
}

#[test]
fn skipped_sets_give_the_last_reason() {
    let config = config(&[]);
    let mut p = Pipeline::new(&config).unwrap();
    calibrated(&mut p);
    let mut now = 0;
    for k in 1..=5 {
        for i in 0..3 {
            let mut input = image(i, set_stamp(k));
            if let Input::Image { image, .. } = &mut input {
                if i == 1 {
                    image.encoding = "yuv422_yuy2".into();
                }
            }
            p.push(input, now);
        }
        now += S / 10;
    }
    let why = p.why_no_depth(live(now), &unknown).unwrap();
    assert_eq!(why.kind, WhyKind::Skipped);
    assert!(why.message.starts_with("sets are skipped: "), "{why}");
    assert!(why.message.contains('b'), "{why}");
}

/// A moving rig whose sets were skipped without a world pose (`tf_timeout` ran out) while
/// nothing came on /tf: the skip's reason, and the cause, nobody publishing /tf, where DDS
/// discovery says so (where it does not know, the reason alone).
#[test]
fn sets_skipped_without_a_world_pose_name_a_missing_tf_publisher() {
    let config = config(&["world_frame:=world", "tf_timeout:=0.2"]);
    let tf_topic = config.world.as_ref().unwrap().tf_topic.clone();
    let mut p = Pipeline::new(&config).unwrap();
    calibrated(&mut p);
    let now = feed(&mut p, 0, 10, [0; 3]);
    let nobody = |topic: &str| {
        if topic == tf_topic {
            Publishers::None
        } else {
            Publishers::Unknown
        }
    };
    let why = p.why_no_depth(live(now), &nobody).unwrap();
    assert_eq!(why.kind, WhyKind::Skipped);
    assert!(why.message.starts_with("sets are skipped: "), "{why}");
    assert!(why.message.contains("in world_frame 'world'"), "{why}");
    let cause = format!("; no publisher on {tf_topic}: check the namespace");
    assert!(why.message.contains(&cause), "{why}");
    let why = p.why_no_depth(live(now), &unknown).unwrap();
    assert!(!why.message.contains("no publisher"), "{why}");
}
