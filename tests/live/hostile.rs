//! The hostile recording: good frame sets interleaved with every kind of bad input the node must
//! survive (bad images, bad CameraInfos, a NaN transform, duplicate / far-future / backwards
//! stamps, undecodable bytes, an unknown type), through `sweepdepth bag` and, played live over
//! DDS, through the running node. Each good set after a hostile one must give the correct depth
//! (the depth of the clean set: the images are the same), no hostile set may give any depth, and
//! the node must be alive at the end.
//!
//! Built from the Tsukuba fixture (tests/fixtures/bags/tsukuba_half.mcap): its first frame set,
//! re-stamped once a second. Live, the player is paced on the node's answers, never on the
//! bag's clock: a set is published once the node has answered the previous one (its depth, or
//! for a set that must give none, `/diagnostics` counting it as matched by the synchroniser, or
//! its image as a future stamp), so no outcome depends on how fast the machine is.
//! SAFETY: DDS only inside the private network namespace of tests/common/netns.rs.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use crate::common::dds::{self, Diagnostics, NodeProcess, Peer};
use crate::common::netns;
use crate::common::player::Player;
use sweepdepth::bag::{BagMessage, BagReader, BagWriter};
use sweepdepth::msgs::{from_cdr, CameraInfo, Image, TFMessage, Time};

const INNER: &str = "SWEEPDEPTH_TEST_PRIVATE_NETNS";
const DOMAIN: u16 = 46;

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
    let expected: Vec<i64> = plan
        .iter()
        .filter(|(_, c)| c.gives_depth())
        .map(|(k, _)| *k as i64)
        .collect();
    // Set numbers, whole seconds from T0 (negative: a stamp from before the schedule).
    let got: Vec<i64> = outputs
        .iter()
        .map(|d| (d.header.stamp.to_nanos() - T0_NS as i64).div_euclid(PERIOD_NS as i64))
        .collect();
    assert_eq!(
        got, expected,
        "{what}: depth for exactly the good sets, in order"
    );
    for (image, k) in outputs.iter().zip(&got) {
        assert_eq!(
            image.header.stamp,
            time(T0_NS + *k as u64 * PERIOD_NS),
            "{what}: set {k}: a stamp that was never sent"
        );
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

/// The clean depth of the fixture's first set (the reference for every good set), from a bag
/// of that set alone.
fn clean_depth(dir: &Path) -> Image {
    let fixture = messages(&root().join("tests/fixtures/bags/tsukuba_half.mcap"));
    let first_stamp = fixture
        .iter()
        .filter(|m| m.msg_type == "sensor_msgs/msg/Image")
        .map(|m| from_cdr::<Image>(&m.data).unwrap().header.stamp)
        .min()
        .expect("images in the fixture");
    let input = dir.join("clean_in.mcap");
    let mut w = BagWriter::create(&input, true).unwrap();
    for m in &fixture {
        w.add_topic(&m.topic, &m.msg_type, None).unwrap();
    }
    for m in &fixture {
        let stamp = match m.msg_type.as_str() {
            "sensor_msgs/msg/Image" => Some(from_cdr::<Image>(&m.data).unwrap().header.stamp),
            "sensor_msgs/msg/CameraInfo" => {
                Some(from_cdr::<CameraInfo>(&m.data).unwrap().header.stamp)
            }
            _ => None,
        };
        if stamp.is_none_or(|s| s == first_stamp) {
            w.write(&m.topic, m.log_time_ns, m.publish_time_ns, &m.data)
                .unwrap();
        }
    }
    w.finish().unwrap();
    let out = dir.join("clean.mcap");
    run_bag(&input, &out);
    let mut depths = depth_outputs(&out);
    assert_eq!(depths.len(), 1, "one set, one depth image");
    depths.remove(0)
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
    let dir = scratch("bag");
    let bag = dir.join("hostile.mcap");
    let plan = write_hostile_bag(&bag, false);
    let clean = clean_depth(&dir);
    let stderr = run_bag(&bag, &dir.join("out.mcap"));
    eprintln!("{stderr}");
    check(&depth_outputs(&dir.join("out.mcap")), &plan, &clean, "bag");
    // Every problem named, the duplicate and the future stamp with their camera and stamp.
    let stamp_of_case = |case: Case| {
        let k = plan
            .iter()
            .find(|(_, c)| *c == case)
            .expect("in the plan")
            .0;
        (T0_NS + k * PERIOD_NS) as f64 / 1e9
    };
    let duplicate = format!(
        "camera 'cam1': image stamped {:.3} s repeats the camera's previous stamp",
        stamp_of_case(Case::Duplicate)
    );
    let future = format!(
        "camera 'cam3': image stamped {:.3} s is more than 10 s (sync_future_window) ahead of every other camera",
        stamp_of_case(Case::Future) + 1000.0
    );
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
        &duplicate,
        &future,
        "topics not read: /unknown",
    ] {
        assert!(
            stderr.contains(needle),
            "no message mentions {needle:?}: {stderr}"
        );
    }
}

#[test]
fn hostile_bag_played_live_into_the_node() {
    netns::in_private_netns(
        INNER,
        "hostile::hostile_bag_played_live_into_the_node",
        live,
    );
}

fn live() {
    let dir = scratch("live");
    let bag = dir.join("hostile_live.mcap");
    let plan = write_hostile_bag(&bag, true);
    let clean = clean_depth(&dir);
    let params = root().join("tests/fixtures/bags/tsukuba_half.params.yaml");
    // Inputs reliable and deep enough that a paced peer loses nothing; no camera leaves the
    // rig while the peer waits for an answer (camera dropout is bag_faults.rs's subject).
    let mut node = NodeProcess::start(
        DOMAIN,
        &[
            "--params-file",
            params.to_str().unwrap(),
            "-p",
            "camera_timeout:=0.0",
            "-p",
            "input_qos_reliable:=true",
            "-p",
            "input_qos_depth:=20",
            "-p",
            "output_qos_depth:=10",
        ],
    );
    let mut peer = Peer::new(DOMAIN, "sweepdepth_hostile_player");
    let bag_messages = messages(&bag);
    let player = Player::new(&mut peer, &bag_messages);
    let depth_sub = peer.subscription::<Image>("/depth/image", dds::IMAGE, &dds::reliable(50));
    let mut diagnostics = Diagnostics::new(&mut peer);
    peer.spin_in_background();
    player.wait_for_subscribers(&peer, &mut node);

    // The bag's messages by schedule entry (entry n is logged from T0 + n s, a NaN /tf_static
    // just before it); the first /tf_static comes before everything.
    let (initial_tf, rest): (Vec<&BagMessage>, Vec<&BagMessage>) = bag_messages
        .iter()
        .partition(|m| m.topic == "/tf_static" && m.log_time_ns < T0_NS);
    let mut entries: Vec<Vec<&BagMessage>> = vec![Vec::new(); plan.len()];
    for m in rest {
        let n = ((m.log_time_ns + PERIOD_NS / 2 - T0_NS) / PERIOD_NS) as usize;
        entries[n].push(m);
    }
    for m in initial_tf {
        player.publish(m);
    }

    // Warm-up: the first (good) set stamped 5 s before T0, 1 ms apart, until one gives depth;
    // after that set's depth the node is idle.
    let warm_stamp = |j: u32| {
        assert!(j < 5000, "more than 5000 warm-up sets");
        dds::time_of_ns(T0_NS - 5_000_000_000 + u64::from(j) * 1_000_000)
    };
    let warm_set: Vec<&BagMessage> = entries[0]
        .iter()
        .copied()
        .filter(|m| m.topic != "/tf_static")
        .collect();
    let mut warm_outputs: Vec<Image> = Vec::new();
    let last = player.warm_up(&warm_set, warm_stamp, &mut node, || {
        warm_outputs.extend(dds::take_all(&depth_sub));
        !warm_outputs.is_empty()
    });
    dds::wait_for(
        format!("the depth of the last warm-up set ({:?})", warm_stamp(last)),
        &mut node,
        || {
            warm_outputs.extend(dds::take_all(&depth_sub));
            warm_outputs
                .iter()
                .any(|d| d.header.stamp == warm_stamp(last))
                .then_some(())
        },
    );
    let before = diagnostics.wait_after(dds::wall_time_now(), &mut node);
    let count = |status: &sweepdepth::msgs::DiagnosticStatus, key: &str| dds::counter(status, key);
    let matched0 = count(&before, "sync matched");
    let future0 = count(&before, "sync future stamps");

    // The schedule, one entry at a time, each once the node has answered the previous one.
    let mut outputs: Vec<Image> = Vec::new();
    let mut matched = matched0;
    for (n, (entry, &(k, case))) in entries.iter().zip(&plan).enumerate() {
        for m in entry {
            player.publish(m);
        }
        // Every set but the one whose cam3 image is dropped as a future stamp is matched.
        if case != Case::Future {
            matched += 1;
        }
        let what = format!("entry {n} of the schedule (set {k}, {case:?})");
        if case.gives_depth() {
            let seen = outputs.len();
            dds::wait_for(format!("the depth of {what}"), &mut node, || {
                outputs.extend(dds::take_all(&depth_sub));
                outputs[seen..]
                    .iter()
                    .any(|d| d.header.stamp == time(T0_NS + k * PERIOD_NS))
                    .then_some(())
            });
        } else if case == Case::Future {
            diagnostics.wait_until(format!("the future stamp of {what}"), &mut node, |s| {
                count(s, "sync future stamps") > future0
            });
        } else {
            diagnostics.wait_until(
                format!("{what} matched (sync matched {matched})"),
                &mut node,
                |s| count(s, "sync matched") >= matched,
            );
        }
    }
    let after = diagnostics.wait_after(dds::wall_time_now(), &mut node);
    outputs.extend(dds::take_all(&depth_sub));
    assert!(node.is_alive(), "the node is alive at the end");
    // The synchroniser saw exactly what was sent: one duplicate, one future stamp, one reset.
    assert_eq!(count(&after, "sync matched"), matched, "{after:?}");
    for (key, n) in [
        ("sync duplicate stamps", 1),
        ("sync future stamps", 1),
        ("sync resets", 1),
    ] {
        assert_eq!(
            count(&after, key) - count(&before, key),
            n,
            "{key}: {after:?}"
        );
    }
    check(&outputs, &plan, &clean, "live");
}
