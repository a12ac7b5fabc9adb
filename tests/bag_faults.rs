//! Faults in a recording, through `sweepdepth bag` (the node's pipeline): cameras that stop and
//! come back. Built from the Tsukuba fixture (tests/fixtures/bags/tsukuba_half.mcap): its first
//! frame set re-stamped at 10 Hz, with cameras left out of chosen sets.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use sweepdepth::bag::{BagMessage, BagReader, BagWriter};
use sweepdepth::msgs::{from_cdr, to_cdr, CameraInfo, Image, Time};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("sweepdepth-faults-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch dir");
    dir
}

fn messages(path: &Path) -> Vec<BagMessage> {
    BagReader::open(path)
        .expect("open bag")
        .map(|m| m.expect("message"))
        .collect()
}

const T0_NS: u64 = 1_700_000_000_000_000_000;
const PERIOD_NS: u64 = 100_000_000;

fn time(ns: u64) -> Time {
    Time {
        sec: (ns / 1_000_000_000) as i32,
        nanosec: (ns % 1_000_000_000) as u32,
    }
}

/// Writes `sets` frame sets of the fixture's five cameras; `present(k, i)` says whether camera
/// `i` sends in set `k`.
fn write_bag(path: &Path, sets: u64, present: impl Fn(u64, usize) -> bool) {
    let fixture = messages(&root().join("tests/fixtures/bags/tsukuba_half.mcap"));
    let tf = fixture.iter().find(|m| m.topic == "/tf_static").unwrap();
    let mut w = BagWriter::create(path, true).unwrap();
    for m in &fixture {
        w.add_topic(&m.topic, &m.msg_type, None).unwrap();
    }
    w.write("/tf_static", T0_NS - 1_000_000, T0_NS - 1_000_000, &tf.data)
        .unwrap();
    for k in 0..sets {
        let stamp_ns = T0_NS + k * PERIOD_NS;
        for i in 0..5usize {
            if !present(k, i) {
                continue;
            }
            let log = stamp_ns + 1_000 * i as u64;
            for (topic, is_image) in [
                (format!("/cam{i}/camera_info"), false),
                (format!("/cam{i}/image_raw"), true),
            ] {
                let original = fixture.iter().find(|m| m.topic == topic).unwrap();
                let data = if is_image {
                    let mut image: Image = from_cdr(&original.data).unwrap();
                    image.header.stamp = time(stamp_ns);
                    to_cdr(&image).unwrap()
                } else {
                    let mut info: CameraInfo = from_cdr(&original.data).unwrap();
                    info.header.stamp = time(stamp_ns);
                    to_cdr(&info).unwrap()
                };
                w.write(&topic, log, log, &data).unwrap();
            }
        }
    }
    w.finish().unwrap();
}

/// Runs `sweepdepth bag` with the fixture's parameters plus `extra`; (stderr, depth stamps in
/// set numbers, depth images).
fn run(input: &Path, output: &Path, extra: &[&str]) -> (String, Vec<u64>, Vec<Image>) {
    let out = Command::new(env!("CARGO_BIN_EXE_sweepdepth"))
        .arg("bag")
        .arg(input)
        .arg(output)
        .arg("--params-file")
        .arg(root().join("tests/fixtures/bags/tsukuba_half.params.yaml"))
        .args(extra)
        .env("RUST_LOG", "warn,sweepdepth=info")
        .stdin(Stdio::null())
        .output()
        .expect("run sweepdepth bag");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "sweepdepth bag failed: {stderr}");
    let depths: Vec<Image> = messages(output)
        .into_iter()
        .filter(|m| m.topic == "/depth/image")
        .map(|m| from_cdr(&m.data).unwrap())
        .collect();
    let sets = depths
        .iter()
        .map(|d| {
            let ns = d.header.stamp.sec as u64 * 1_000_000_000 + u64::from(d.header.stamp.nanosec);
            (ns - T0_NS) / PERIOD_NS
        })
        .collect();
    (stderr, sets, depths)
}

/// Share of valid depths within 5 % of the depth the full rig gives for the same pixel.
fn agreement(a: &Image, b: &Image) -> f64 {
    let f = |img: &Image| -> Vec<f32> {
        img.data
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    };
    let (a, b) = (f(a), f(b));
    let both: Vec<(f32, f32)> = a
        .iter()
        .zip(&b)
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .map(|(x, y)| (*x, *y))
        .collect();
    assert!(both.len() * 2 > a.len(), "too few valid depths");
    both.iter()
        .filter(|(x, y)| ((x - y) / y).abs() <= 0.05)
        .count() as f64
        / both.len() as f64
}

#[test]
fn cameras_that_stop_leave_the_rig_and_come_back() {
    let dir = scratch("dropout");
    let bag = dir.join("dropout.mcap");
    // cam4 silent in sets 3..=7, the reference cam2 silent in sets 11..=14; 18 sets.
    write_bag(&bag, 18, |k, i| {
        !((i == 4 && (3..=7).contains(&k)) || (i == 2 && (11..=14).contains(&k)))
    });
    let (stderr, sets, depths) = run(&bag, &dir.join("out.mcap"), &["-p", "camera_timeout:=0.25"]);
    eprintln!("{stderr}\nsets with depth: {sets:?}");
    assert!(
        stderr.contains("camera 'cam4' has sent nothing for"),
        "{stderr}"
    );
    assert!(stderr.contains("going on with the other 4"), "{stderr}");
    assert!(
        stderr.contains("camera 'cam4' is sending again"),
        "{stderr}"
    );
    assert!(
        stderr.contains("camera 'cam2' has sent nothing for")
            && stderr.contains("it is the reference camera: no depth is published"),
        "{stderr}"
    );
    assert!(
        stderr.contains("degraded rig"),
        "the summary counts the skipped sets: {stderr}"
    );
    // The full rig before the dropout.
    for k in 0..3 {
        assert!(sets.contains(&k), "set {k} missing: {sets:?}");
    }
    // cam4 out (after the timeout, the others go on), back from set 8.
    assert!(
        sets.contains(&6) && sets.contains(&7),
        "degraded sets missing: {sets:?}"
    );
    for k in 8..=10 {
        assert!(sets.contains(&k), "set {k} missing: {sets:?}");
    }
    // Never a depth map for a set without the reference, and none stale.
    for k in 11..=14 {
        assert!(
            !sets.contains(&k),
            "depth published for set {k} without its reference image"
        );
    }
    // The reference is back with set 15; the images of set 15 that came before it were not
    // kept (the rig was not publishing), so set 15 itself may be lost.
    for k in 16..18 {
        assert!(
            sets.contains(&k),
            "set {k} missing after the reference came back: {sets:?}"
        );
    }
    let mut sorted = sets.clone();
    sorted.dedup();
    assert_eq!(sorted, sets, "one output per set, in order");
    // The 4-camera depth agrees with the 5-camera depth.
    let full = &depths[0];
    let degraded = &depths[sets.iter().position(|&k| k == 7).unwrap()];
    let share = agreement(degraded, full);
    assert!(
        share > 0.9,
        "4-camera depth agrees with the full rig on only {share:.3}"
    );
}

#[test]
fn no_timeout_means_waiting_for_every_camera() {
    let dir = scratch("notimeout");
    let bag = dir.join("b.mcap");
    write_bag(&bag, 8, |k, i| !(i == 4 && (3..=5).contains(&k)));
    let (stderr, sets, _) = run(&bag, &dir.join("out.mcap"), &["-p", "camera_timeout:=0.0"]);
    assert!(!stderr.contains("leaves the rig"), "{stderr}");
    assert_eq!(sets, vec![0, 1, 2, 6, 7], "{stderr}");
}
