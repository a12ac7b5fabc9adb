//! Overload soak of `sweepdepth node` (a benchmark run by `scripts/soak.sh [MINUTES]`, ignored by
//! `cargo test`): a synthetic 4-camera rig published faster than the GPU can go, while the
//! node's resident memory is sampled. It fails if the node dies or its memory grows by more
//! than 10 % after the first minute.
//!
//! DDS only inside a private network namespace (tests/common/netns.rs). Phases:
//! 1. calibration: 20 s at 30 Hz; the node's output rate is the sustainable rate S;
//! 2. soak: MINUTES at 2 S, the node's VmRSS sampled every 10 s.
//!    Prints one line per sample and a summary (RSS first / last / max, inputs, outputs).

use std::process::{Command, Stdio};
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

const DOMAIN: u16 = 47;
const CAMERAS: usize = 4;
const WIDTH: u32 = 320;
const HEIGHT: u32 = 240;

#[path = "common/netns.rs"]
mod netns;

const INNER: &str = "SWEEPDEPTH_TEST_PRIVATE_NETNS";

/// `SWEEPDEPTH_SOAK_MINUTES` (default 10).
#[test]
#[ignore = "a 10-minute benchmark: scripts/soak.sh"]
fn soak() {
    netns::in_private_netns(INNER, "soak", run);
}

fn rss_kib(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

fn stamp(ns: u64) -> Time {
    Time {
        sec: (ns / 1_000_000_000) as i32,
        nanosec: (ns % 1_000_000_000) as u32,
    }
}

fn run() {
    let minutes: f64 = std::env::var("SWEEPDEPTH_SOAK_MINUTES")
        .ok()
        .and_then(|a| a.parse().ok())
        .unwrap_or(10.0);
    let mut node = Command::new(env!("CARGO_BIN_EXE_sweepdepth"))
        .args([
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
            "num_planes:=32",
            "-p",
            "sync:=exact",
        ])
        .env("ROS_DOMAIN_ID", DOMAIN.to_string())
        .env("RUST_LOG", "warn,rustdds=error")
        .stdin(Stdio::null())
        .spawn()
        .expect("start the node");
    let pid = node.id();

    let model = CameraModel::pinhole(synthetic::intrinsics(WIDTH, HEIGHT));
    let rig = synthetic::row_rig(CAMERAS, 0.1, model, 1).expect("rig");
    let scene = Scene::wall_and_box(2.0, Some((1.2, 0.3)), model.intrinsics.fx_px);
    let images = synthetic::render_rig(&scene, &rig);
    let context = Context::with_options(ContextOptions::new().domain_id(DOMAIN)).expect("DDS");
    let mut peer = context
        .new_node(
            NodeName::new("/", "sweepdepth_soak").unwrap(),
            NodeOptions::new()
                .enable_rosout(false)
                .start_parameter_services(false),
        )
        .unwrap();
    let qos = QosProfile::publisher_default()
        .reliability_best_effort()
        .history(History::KeepLast { depth: 2 });
    let reliable = QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .history(History::KeepLast { depth: 5 });
    let tf_qos = reliable.clone().durability(Durability::TransientLocal);
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
    for i in 0..CAMERAS {
        let t = peer
            .create_topic(
                &Name::parse(&format!("/cam{i}/image_raw")).unwrap(),
                MessageTypeName::new("sensor_msgs", "Image"),
                &qos,
            )
            .unwrap();
        image_pubs.push(
            peer.create_publisher::<Image>(&t, Some(qos.clone()))
                .unwrap(),
        );
        let t = peer
            .create_topic(
                &Name::parse(&format!("/cam{i}/camera_info")).unwrap(),
                MessageTypeName::new("sensor_msgs", "CameraInfo"),
                &qos,
            )
            .unwrap();
        info_pubs.push(
            peer.create_publisher::<CameraInfo>(&t, Some(qos.clone()))
                .unwrap(),
        );
    }
    let depth_topic = peer
        .create_topic(
            &Name::parse("/depth/image").unwrap(),
            MessageTypeName::new("sensor_msgs", "Image"),
            &reliable,
        )
        .unwrap();
    let depth_sub = peer
        .create_subscription::<Image>(&depth_topic, Some(reliable.clone()))
        .unwrap();
    let transforms = rig
        .cameras
        .iter()
        .enumerate()
        .map(|(i, cam)| {
            let c = cam.centre_in_rig();
            TransformStamped {
                header: Header {
                    stamp: stamp(0),
                    frame_id: "rig".into(),
                },
                child_frame_id: format!("cam{i}_optical"),
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
    tf_pub.publish(TFMessage { transforms }).unwrap();
    let k = model.intrinsics;
    let rgb: Vec<Vec<u8>> = images
        .iter()
        .map(|img: &Rgba8Image| {
            img.pixels
                .iter()
                .flat_map(|&p| {
                    let [r, g, b, _] = Rgba8Image::unpack(p);
                    [r, g, b]
                })
                .collect()
        })
        .collect();
    let mut frame: u64 = 0;
    let publish = |frame: u64| {
        let ns = 1_000_000_000_000 + frame * 1_000_000;
        for i in 0..CAMERAS {
            let header = Header {
                stamp: stamp(ns),
                frame_id: format!("cam{i}_optical"),
            };
            let info = CameraInfo {
                header: header.clone(),
                width: WIDTH,
                height: HEIGHT,
                distortion_model: "plumb_bob".into(),
                d: vec![0.0; 5],
                k: [k.fx_px, 0.0, k.cx_px, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 1.0],
                r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                p: [
                    k.fx_px, 0.0, k.cx_px, 0.0, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 0.0, 1.0, 0.0,
                ],
                ..CameraInfo::default()
            };
            let _ = info_pubs[i].publish(info);
            let _ = image_pubs[i].publish(Image {
                header,
                height: HEIGHT,
                width: WIDTH,
                encoding: "rgb8".into(),
                is_bigendian: 0,
                step: WIDTH * 3,
                data: rgb[i].clone(),
            });
        }
    };
    let drain = || {
        let mut n = 0u64;
        while let Ok(Some(_)) = depth_sub.take() {
            n += 1;
        }
        n
    };

    // Phase 1: calibration at 30 Hz (the first 5 s are warm-up and not counted).
    let started = Instant::now();
    let mut outputs = 0u64;
    let mut counted_from = None;
    while started.elapsed() < Duration::from_secs(25) {
        publish(frame);
        frame += 1;
        let got = drain();
        if started.elapsed() >= Duration::from_secs(5) {
            counted_from.get_or_insert((Instant::now(), frame));
            outputs += got;
        }
        std::thread::sleep(Duration::from_millis(33));
    }
    let (t0, _) = counted_from.unwrap_or((started, 0));
    let sustainable = outputs as f64 / t0.elapsed().as_secs_f64();
    let rate = (2.0 * sustainable).max(1.0);
    println!("soak: sustainable {sustainable:.2} sets/s at 4 x {WIDTH}x{HEIGHT}, 32 planes; soaking at {rate:.2} sets/s for {minutes} min");

    // Phase 2: soak at twice the sustainable rate.
    let period = Duration::from_secs_f64(1.0 / rate);
    let soak_start = Instant::now();
    let mut next_sample = soak_start;
    let (mut sent, mut received) = (0u64, 0u64);
    let mut samples: Vec<u64> = Vec::new();
    let mut next_frame = soak_start;
    while soak_start.elapsed() < Duration::from_secs_f64(minutes * 60.0) {
        if let Ok(Some(status)) = node.try_wait() {
            panic!("soak: the node exited: {status}");
        }
        let now = Instant::now();
        if now >= next_frame {
            publish(frame);
            frame += 1;
            sent += 1;
            next_frame += period;
        }
        received += drain();
        if now >= next_sample {
            let rss = rss_kib(pid).unwrap_or(0);
            samples.push(rss);
            println!(
                "t={:>5.0} s  rss={:>7} KiB  sent={sent} received={received}",
                soak_start.elapsed().as_secs_f64(),
                rss
            );
            next_sample += Duration::from_secs(10);
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let _ = node.kill();
    let _ = node.wait();
    let first = samples.first().copied().unwrap_or(0);
    let last = samples.last().copied().unwrap_or(0);
    let max = samples.iter().copied().max().unwrap_or(0);
    // After the first minute (allocator and pipeline caches warm).
    let settled: Vec<u64> = samples.iter().copied().skip(6).collect();
    let (smin, smax) = (
        settled.iter().copied().min().unwrap_or(0),
        settled.iter().copied().max().unwrap_or(0),
    );
    println!(
        "soak summary: {minutes} min at {rate:.2} sets/s (2 x sustainable {sustainable:.2}); sent {sent} sets, received {received} depth images ({:.0} % dropped); RSS first {first} KiB, last {last} KiB, max {max} KiB; after the first minute {smin}..{smax} KiB",
        100.0 * (1.0 - received as f64 / sent.max(1) as f64)
    );
    assert!(samples.len() >= 2, "no memory samples");
    if settled.len() >= 2 {
        assert!(
            (smax as f64) <= 1.10 * smin as f64,
            "memory grew after the first minute: {smin}..{smax} KiB"
        );
    }
}
