//! Faults in a recording, through `sweepdepth bag` (the node's pipeline): cameras that stop and
//! come back. Built from the Tsukuba fixture (tests/fixtures/bags/tsukuba_half.mcap): its first
//! frame set re-stamped at 10 Hz, with cameras left out of chosen sets. Every image carries a
//! faint pattern of its own (one grey level, different for every set and camera), so that no
//! set looks like another: a stale image or a stale output cannot pass for a fresh one.

use super::util::{messages, root, scratch};
use std::path::Path;
use std::process::{Command, Stdio};

use sweepdepth::bag::BagWriter;
use sweepdepth::msgs::{from_cdr, to_cdr, CameraInfo, Image, PointCloud2, Time};

const T0_NS: u64 = 1_700_000_000_000_000_000;
const PERIOD_NS: u64 = 100_000_000;

fn time(ns: u64) -> Time {
    Time {
        sec: (ns / 1_000_000_000) as i32,
        nanosec: (ns % 1_000_000_000) as u32,
    }
}

/// Camera `i`'s image of set `k`: the fixture's (`original`) with one byte in four moved by 1
/// up or down, chosen by a hash of (k, i, byte): invisible to the depth, unique to the set.
fn set_image(original: &Image, k: u64, i: usize) -> Image {
    let mut image = original.clone();
    for (j, byte) in image.data.iter_mut().enumerate() {
        let h = (k * 1_000_003 + i as u64 * 7_919 + j as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        *byte = match h >> 61 {
            0 => byte.saturating_add(1),
            1 => byte.saturating_sub(1),
            _ => *byte,
        };
    }
    image
}

/// Writes `sets` frame sets of the fixture's five cameras (images from [`set_image`]);
/// `present(k, i)` says whether camera `i` sends in set `k`.
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
                    let mut image = set_image(&from_cdr(&original.data).unwrap(), k, i);
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

/// The outputs of one `sweepdepth bag` run.
struct Run {
    stderr: String,
    /// The set of each depth image, in output order.
    sets: Vec<u64>,
    depths: Vec<Image>,
    /// The point clouds (with `publish_points:=true`), in output order.
    points: Vec<PointCloud2>,
}

/// The set number of a stamp.
fn set_of(t: Time) -> u64 {
    let ns = t.sec as u64 * 1_000_000_000 + u64::from(t.nanosec);
    (ns - T0_NS) / PERIOD_NS
}

/// Runs `sweepdepth bag` with the fixture's parameters plus `extra`.
fn run(input: &Path, output: &Path, extra: &[&str]) -> Run {
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
    let points: Vec<PointCloud2> = messages(output)
        .into_iter()
        .filter(|m| m.topic == "/points")
        .map(|m| from_cdr(&m.data).unwrap())
        .collect();
    let sets = depths.iter().map(|d| set_of(d.header.stamp)).collect();
    Run {
        stderr,
        sets,
        depths,
        points,
    }
}

fn depth_values(image: &Image) -> Vec<f32> {
    image
        .data
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
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

/// Checks that a point cloud is coloured by `reference` (an rgb8 image): the output was made
/// from that very image.
fn coloured_by(cloud: &PointCloud2, reference: &Image) -> bool {
    assert_eq!(reference.encoding, "rgb8");
    let w = reference.width as usize;
    cloud.data.chunks_exact(16).enumerate().all(|(n, p)| {
        let (x, y) = (n % w, n / w);
        let o = y * reference.step as usize + 3 * x;
        let rgb = &reference.data[o..o + 3];
        p[12..16] == [rgb[2], rgb[1], rgb[0], 0]
    })
}

/// Share of valid depths within 5 % of the depth the full rig gives for the same pixel.
fn agreement(a: &Image, b: &Image) -> f64 {
    let (a, b) = (depth_values(a), depth_values(b));
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
    let out = run(
        &bag,
        &dir.join("out.mcap"),
        &["-p", "camera_timeout:=0.25", "-p", "publish_points:=true"],
    );
    let (stderr, sets) = (&out.stderr, &out.sets);
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
    assert!(
        sets.windows(2).all(|w| w[0] < w[1]),
        "one output per set, in order: {sets:?}"
    );
    // The full rig before the dropout.
    for k in 0..3 {
        assert!(sets.contains(&k), "set {k} missing: {sets:?}");
    }
    // cam4 out (after the timeout, the others go on: sets 3 to 5, held for cam4 until it
    // left, too), back from set 8.
    for k in 3..=7 {
        assert!(sets.contains(&k), "degraded set {k} missing: {sets:?}");
    }
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
    // The reference is back with set 15: the images of set 15 that came before it were held
    // for it (issue 32: a camera that comes back costs no set).
    for k in 15..18 {
        assert!(
            sets.contains(&k),
            "set {k} missing after the reference came back: {sets:?}"
        );
    }
    // Every output was made from its own set: its point cloud has the colours of that set's
    // reference image (cam2), and the same stamp as its depth image.
    let fixture = messages(&root().join("tests/fixtures/bags/tsukuba_half.mcap"));
    let cam2: Image = from_cdr(
        &fixture
            .iter()
            .find(|m| m.topic == "/cam2/image_raw")
            .unwrap()
            .data,
    )
    .unwrap();
    assert_eq!(
        out.points.len(),
        sets.len(),
        "one point cloud per depth image"
    );
    for ((cloud, depth), &k) in out.points.iter().zip(&out.depths).zip(sets) {
        assert_eq!(cloud.header, depth.header);
        assert!(
            coloured_by(cloud, &set_image(&cam2, k, 2)),
            "the output of set {k} is not coloured by set {k}'s reference image"
        );
        assert!(
            !coloured_by(cloud, &set_image(&cam2, k + 1, 2)),
            "the colours cannot tell set {k} from set {}",
            k + 1
        );
    }

    // The sets without cam4 are 4-camera jobs: each equals the depth of the same set from a bag
    // in which the 4 cameras are all there is, and differs from the 5-camera depth.
    let reference_bag = dir.join("reference.mcap");
    write_bag(&reference_bag, 18, |k, _| (5..=7).contains(&k));
    let five = run(&reference_bag, &dir.join("five.mcap"), &[]);
    let four = run(
        &reference_bag,
        &dir.join("four.mcap"),
        &["-p", "cameras:=[cam0, cam1, cam2, cam3]"],
    );
    assert_eq!((&five.sets, &four.sets), (&vec![5, 6, 7], &vec![5, 6, 7]));
    for (n, &k) in sets
        .iter()
        .enumerate()
        .filter(|(_, k)| (5..=7).contains(*k))
    {
        let depth = &out.depths[n];
        let (four_k, five_k) = (
            &four.depths[(k - 5) as usize],
            &five.depths[(k - 5) as usize],
        );
        assert!(
            same_depth(depth, four_k),
            "set {k} (cam4 out of the rig) is not the 4-camera depth"
        );
        assert!(
            !same_depth(depth, five_k),
            "set {k}: the 4-camera and 5-camera depths cannot be told apart"
        );
    }
    // The 4-camera depth agrees with the 5-camera depth.
    let share = agreement(&four.depths[2], &five.depths[2]);
    eprintln!("set 7: the 4-camera depth agrees with the 5-camera depth on {share:.3}");
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
    let out = run(&bag, &dir.join("out.mcap"), &["-p", "camera_timeout:=0.0"]);
    assert!(!out.stderr.contains("leaves the rig"), "{}", out.stderr);
    assert_eq!(out.sets, vec![0, 1, 2, 6, 7], "{}", out.stderr);
}
