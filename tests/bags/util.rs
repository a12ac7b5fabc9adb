//! What the bag tests share: the checkout, scratch folders, the `sweepdepth` binary, bags read.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

use sweepdepth::bag::{BagMessage, BagReader};

pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// An empty scratch folder for `name` (unique in this test binary).
pub fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("sweepdepth-bags-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch dir");
    dir
}

/// The parameter file of the Tsukuba bag fixture.
pub fn fixture_params() -> PathBuf {
    root().join("tests/fixtures/bags/tsukuba_half.params.yaml")
}

/// `sweepdepth bag IN OUT --params-file <the fixture's>` plus `extra`.
pub fn fixture_bag(input: &Path, output: &Path, extra: &[&str]) -> Output {
    let params = fixture_params();
    let mut args = vec![
        "bag",
        input.to_str().unwrap(),
        output.to_str().unwrap(),
        "--params-file",
        params.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    sweepdepth(&args)
}

/// Runs the `sweepdepth` binary (the limit of its wait: the test harness's).
pub fn sweepdepth(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_sweepdepth"))
        .args(args)
        .env("RUST_LOG", "warn,sweepdepth=info")
        .stdin(Stdio::null())
        .output()
        .expect("run sweepdepth")
}

/// The run's stderr, after asserting it succeeded.
pub fn ok(out: &Output, what: &str) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{what} failed: {stderr}");
    stderr
}

/// Every message of a bag, in order.
pub fn messages(path: &Path) -> Vec<BagMessage> {
    BagReader::open(path)
        .expect("open bag")
        .map(|m| m.expect("message"))
        .collect()
}

/// `/tf_static` or `/tf`'s entry: `child` at `pose` in `parent`, stamped `stamp`.
pub fn transform_stamped(
    parent: &str,
    child: &str,
    stamp: sweepdepth::msgs::Time,
    pose: &sweepdepth::geometry::RigidTransform,
) -> sweepdepth::msgs::TransformStamped {
    use sweepdepth::msgs::{Header, Quaternion, Transform, TransformStamped, Vector3};
    TransformStamped {
        header: Header {
            stamp,
            frame_id: parent.into(),
        },
        child_frame_id: child.into(),
        transform: Transform {
            translation: Vector3 {
                x: pose.translation.x,
                y: pose.translation.y,
                z: pose.translation.z,
            },
            rotation: Quaternion {
                x: pose.rotation.x,
                y: pose.rotation.y,
                z: pose.rotation.z,
                w: pose.rotation.w,
            },
        },
    }
}
