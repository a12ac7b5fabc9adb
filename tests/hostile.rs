//! The hostile recording: good frame sets interleaved with every kind of bad input the node must
//! survive (bad images, bad CameraInfos, a NaN transform, duplicate / far-future / backwards
//! stamps, undecodable bytes, an unknown type), through `sweepdepth bag` and, played live over
//! DDS, through the running node. Each good set after a hostile one must give the correct depth
//! (the depth of the clean set: the images are the same), no hostile set may give any depth, and
//! the node must be alive at the end.
//!
//! Built from the Tsukuba fixture (tests/fixtures/bags/tsukuba_half.mcap): its first frame set,
//! re-stamped once a second. SAFETY: DDS only inside the private network namespace of
//! tests/common/netns.rs.

#[path = "common/netns.rs"]
mod netns;
#[path = "common/player.rs"]
mod player;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use ros2_client::qos::{History, WhenFull};
use ros2_client::{
    Context, ContextOptions, MessageTypeName, Name, NodeName, NodeOptions, QosProfile,
};
use sweepdepth::bag::{BagMessage, BagReader, BagWriter};
use sweepdepth::msgs::{from_cdr, CameraInfo, Image, TFMessage, Time};

const INNER: &str = "SWEEPDEPTH_TEST_PRIVATE_NETNS";

/// The two tests run one after the other: the live one must not compete with the offline one
/// for the (software) GPU, or the node, correctly, drops sets it cannot keep up with.
static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());
const T0_NS: u64 = 1_700_000_000_000_000_000;
const PERIOD_NS: u64 = 1_000_000_000;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn messages(path: &Path) -> Vec<BagMessage> {
    BagReader::open(path)
        .expect("open bag")
        .map(|m| m.expect("message"))
        .collect()
}

fn time(ns: u64) -> Time {
    Time {
        sec: (ns / 1_000_000_000) as i32,
        nanosec: (ns % 1_000_000_000) as u32,
    }
}

/// What one frame set of the hostile bag is.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Case {
    Good,
    Encoding,
    StepTooSmall,
    DataShort,
    ZeroWidth,
    AbsurdSize,
    InfoZeros,
    InfoNan,
    InfoSize,
    InfoDistortion,
    /// A /tf_static with a NaN quaternion for cam4 first: rejected, the last good one kept.
    TfNan,
    /// cam1's image twice.
    Duplicate,
    /// cam3's image stamped 1000 s ahead.
    Future,
    /// Bytes that are no CDR on cam2's image topic (bag only: a typed player cannot send them).
    Garbage,
}

impl Case {
    /// Whether the set must give depth.
    fn gives_depth(self) -> bool {
        matches!(self, Case::Good | Case::TfNan | Case::Duplicate)
    }
}

/// The schedule: every hostile case followed by a good set, then the first three sets again
/// with their original stamps (a bag played in a loop: time goes back 24 s).
fn schedule(live: bool) -> Vec<(u64, Case)> {
    let hostile = [
        Case::Encoding,
        Case::StepTooSmall,
        Case::DataShort,
        Case::ZeroWidth,
        Case::AbsurdSize,
        Case::InfoZeros,
        Case::InfoNan,
        Case::InfoSize,
        Case::InfoDistortion,
        Case::TfNan,
        Case::Duplicate,
        Case::Future,
        Case::Garbage,
    ];
    let mut out = vec![(0, Case::Good)];
    let mut k = 1;
    for case in hostile {
        if live && case == Case::Garbage {
            continue;
        }
        out.push((k, case));
        out.push((k + 1, Case::Good));
        k += 2;
    }
    for j in 0..3 {
        out.push((j, Case::Good));
    }
    out
}

fn write_hostile_bag(path: &Path, live: bool) -> Vec<(u64, Case)> {
    let fixture = messages(&root().join("tests/fixtures/bags/tsukuba_half.mcap"));
    let original = |topic: &str| fixture.iter().find(|m| m.topic == topic).expect("topic");
    let tf = original("/tf_static");
    let mut w = BagWriter::create(path, true).unwrap();
    for m in &fixture {
        w.add_topic(&m.topic, &m.msg_type, None).unwrap();
    }
    if !live {
        w.add_topic("/unknown", "foo_msgs/msg/Bar", Some(b"int32 x"))
            .unwrap();
    }
    w.write("/tf_static", T0_NS - 1_000_000, T0_NS - 1_000_000, &tf.data)
        .unwrap();
    let plan = schedule(live);
    // Receive times keep increasing even when the stamps jump back (the loop).
    for (n, &(k, case)) in plan.iter().enumerate() {
        let stamp_ns = T0_NS + k * PERIOD_NS;
        let log0 = T0_NS + n as u64 * PERIOD_NS;
        if case == Case::TfNan {
            let mut msg: TFMessage = from_cdr(&tf.data).unwrap();
            for t in &mut msg.transforms {
                if t.child_frame_id == "cam4_optical_frame" {
                    t.transform.rotation.x = f64::NAN;
                }
            }
            w.write_msg("/tf_static", log0 - 500_000, &msg).unwrap();
        }
        if !live && n == 3 {
            w.write(
                "/unknown",
                log0 - 400_000,
                log0 - 400_000,
                &[0, 1, 0, 0, 42, 0, 0, 0],
            )
            .unwrap();
        }
        for i in 0..5usize {
            let log = log0 + 1_000 * i as u64;
            let mut info: CameraInfo =
                from_cdr(&original(&format!("/cam{i}/camera_info")).data).unwrap();
            info.header.stamp = time(stamp_ns);
            match (case, i) {
                (Case::InfoZeros, 2) => {
                    info.k = [0.0; 9];
                    info.p = [0.0; 12];
                }
                (Case::InfoNan, 3) => info.k[0] = f64::NAN,
                (Case::InfoSize, 1) => {
                    info.width = 100;
                    info.height = 100;
                }
                (Case::InfoDistortion, 0) => info.distortion_model = "weird_model".into(),
                _ => {}
            }
            w.write_msg(&format!("/cam{i}/camera_info"), log, &info)
                .unwrap();
            let topic = format!("/cam{i}/image_raw");
            let mut image: Image = from_cdr(&original(&topic).data).unwrap();
            image.header.stamp = time(stamp_ns);
            match (case, i) {
                (Case::Encoding, 1) => image.encoding = "yuv422_yuy2_x".into(),
                (Case::StepTooSmall, 3) => image.step = image.width * 3 - 1,
                (Case::DataShort, 0) => image.data.truncate(image.data.len() / 2),
                (Case::ZeroWidth, 4) => image.width = 0,
                (Case::AbsurdSize, 1) => {
                    image.width = 100_000;
                    image.height = 100_000;
                    image.step = 300_000;
                    image.data.truncate(64);
                }
                (Case::Future, 3) => image.header.stamp = time(stamp_ns + 1000 * PERIOD_NS),
                _ => {}
            }
            if case == Case::Garbage && i == 2 {
                w.write(
                    &topic,
                    log + 500,
                    log + 500,
                    &[0xde, 0xad, 0xbe, 0xef, 1, 2, 3],
                )
                .unwrap();
            } else {
                w.write_msg(&topic, log + 500, &image).unwrap();
            }
            if case == Case::Duplicate && i == 1 {
                w.write_msg(&topic, log + 600, &image).unwrap();
            }
        }
    }
    w.finish().unwrap();
    plan
}

fn depth_values(image: &Image) -> Vec<f32> {
    image
        .data
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect()
}

/// Equal within floating-point tolerance, NaN where NaN.
fn same_depth(a: &Image, b: &Image) -> bool {
    let (a, b) = (depth_values(a), depth_values(b));
    a.len() == b.len()
        && a.iter()
            .zip(&b)
            .all(|(x, y)| (x.is_nan() && y.is_nan()) || (x - y).abs() <= 1e-5 * y.abs().max(1e-6))
}

/// Checks the depth images (in output order) against the schedule: exactly the sets that must
/// give depth do (each once, `required` of them at least; live drops none at this rate), all
/// equal to the clean depth.
fn check(outputs: &[Image], plan: &[(u64, Case)], clean: &Image, what: &str) {
    let expected: Vec<u64> = plan
        .iter()
        .filter(|(_, c)| c.gives_depth())
        .map(|(k, _)| *k)
        .collect();
    let got: Vec<u64> = outputs
        .iter()
        .map(|d| (d.header.stamp.to_nanos() as u64 - T0_NS) / PERIOD_NS)
        .collect();
    assert_eq!(
        got, expected,
        "{what}: depth for exactly the good sets, in order"
    );
    for (image, k) in outputs.iter().zip(&got) {
        assert!(
            same_depth(image, clean),
            "{what}: set {k} does not have the clean depth"
        );
    }
}

fn run_bag(input: &Path, output: &Path) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_sweepdepth"))
        .arg("bag")
        .arg(input)
        .arg(output)
        .arg("--params-file")
        .arg(root().join("tests/fixtures/bags/tsukuba_half.params.yaml"))
        .args(["-p", "camera_timeout:=5.0", "--force"])
        .env("RUST_LOG", "warn,sweepdepth=info")
        .stdin(Stdio::null())
        .output()
        .expect("run sweepdepth bag");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "sweepdepth bag failed: {stderr}");
    stderr
}

fn depth_outputs(path: &Path) -> Vec<Image> {
    messages(path)
        .into_iter()
        .filter(|m| m.topic == "/depth/image")
        .map(|m| from_cdr(&m.data).unwrap())
        .collect()
}

/// The clean depth of the fixture's set (the reference for every good set).
fn clean_depth(dir: &Path) -> Image {
    let out = dir.join("clean.mcap");
    run_bag(&root().join("tests/fixtures/bags/tsukuba_half.mcap"), &out);
    depth_outputs(&out).remove(0)
}

fn scratch(name: &str) -> PathBuf {
    let dir =
        std::env::temp_dir().join(format!("sweepdepth-hostile-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn hostile_bag_through_sweepdepth_bag() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let dir = scratch("bag");
    let bag = dir.join("hostile.mcap");
    let plan = write_hostile_bag(&bag, false);
    let clean = clean_depth(&dir);
    let stderr = run_bag(&bag, &dir.join("out.mcap"));
    eprintln!("{stderr}");
    check(&depth_outputs(&dir.join("out.mcap")), &plan, &clean, "bag");
    // Every problem named.
    for needle in [
        "unsupported image encoding 'yuv422_yuy2_x'",
        "step 575 is smaller than one row",
        "needs at least 82944",
        "the image is 0x144",
        "the image is 100000x100000",
        "both K and P are all zero",
        "K[0] is NaN",
        "the image is 192x144 but its camera_info describes 100x100",
        "weird_model",
        "rejected transform 'rig' -> 'cam4_optical_frame'",
        "time went backwards",
        "cannot decode Image on /cam2/image_raw",
    ] {
        assert!(
            stderr.contains(needle),
            "no message mentions {needle:?}: {stderr}"
        );
    }
}

#[test]
fn hostile_bag_played_live_into_the_node() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    netns::in_private_netns(INNER, "hostile_bag_played_live_into_the_node", live);
}

fn live() {
    let dir = scratch("live");
    let bag = dir.join("hostile_live.mcap");
    let plan = write_hostile_bag(&bag, true);
    let clean = clean_depth(&dir);
    let params = root().join("tests/fixtures/bags/tsukuba_half.params.yaml");
    let node = Command::new(env!("CARGO_BIN_EXE_sweepdepth"))
        .args([
            "node",
            "--ros-args",
            "--params-file",
            params.to_str().unwrap(),
        ])
        .args([
            "-p",
            "camera_timeout:=5.0",
            "-p",
            "input_qos_reliable:=true",
            "-p",
            "input_qos_depth:=20",
        ])
        .env("ROS_DOMAIN_ID", "46")
        .env("RUST_LOG", "warn,sweepdepth=info")
        .stdin(Stdio::null())
        .spawn()
        .expect("start the node");
    let mut node = netns::KillOnDrop(node);
    let context = Context::with_options(ContextOptions::new().domain_id(46)).unwrap();
    let mut peer = context
        .new_node(
            NodeName::new("/", "sweepdepth_hostile_player").unwrap(),
            NodeOptions::new()
                .enable_rosout(false)
                .start_parameter_services(false),
        )
        .unwrap();
    let bag_messages = messages(&bag);
    let player = player::Player::new(&mut peer, &bag_messages);
    let reliable = QosProfile::subscription_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .history(History::KeepLast { depth: 50 });
    let topic = peer
        .create_topic(
            &Name::parse("/depth/image").unwrap(),
            MessageTypeName::new("sensor_msgs", "Image"),
            &reliable,
        )
        .unwrap();
    let depth_sub = peer
        .create_subscription::<Image>(&topic, Some(reliable.clone()))
        .unwrap();
    let spinner = peer.spinner().unwrap();
    std::thread::spawn(move || futures::executor::block_on(spinner.spin()));
    player.wait_for_subscribers(&peer, Duration::from_secs(30));
    std::thread::sleep(Duration::from_millis(500));

    // Play on a thread; collect depth meanwhile.
    let played = std::thread::spawn(move || player.play(&bag_messages));
    let mut outputs: Vec<Image> = Vec::new();
    let expected = plan.iter().filter(|(_, c)| c.gives_depth()).count();
    let started = Instant::now();
    let mut finished_at: Option<Instant> = None;
    loop {
        if let Some(status) = node.0.try_wait().unwrap() {
            panic!("the node died: {status}");
        }
        while let Ok(Some((image, _))) = depth_sub.take() {
            outputs.push(image);
        }
        if played.is_finished() && finished_at.is_none() {
            finished_at = Some(Instant::now());
        }
        // After the last message, give the GPU a few seconds for the last set.
        if finished_at.is_some_and(|t| t.elapsed() > Duration::from_secs(5))
            || outputs.len() >= expected
        {
            break;
        }
        assert!(
            started.elapsed() < Duration::from_secs(120),
            "the live run takes too long"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(500));
    while let Ok(Some((image, _))) = depth_sub.take() {
        outputs.push(image);
    }
    assert!(
        node.0.try_wait().unwrap().is_none(),
        "the node is alive at the end"
    );
    check(&outputs, &plan, &clean, "live");
}
