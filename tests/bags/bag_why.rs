//! `sweepdepth bag` on a bag that yields no depth says why, with the live node's reasons
//! (issue 34): here the camera_info of one camera was never recorded.

use std::path::PathBuf;
use std::process::{Command, Stdio};

use sweepdepth::bag::{BagReader, BagWriter};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn bag_without_a_camera_info_says_which() {
    let dir = std::env::temp_dir().join(format!("sweepdepth-bagwhy-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch dir");
    let bag = dir.join("no_cam3_info.mcap");
    let mut writer = BagWriter::create(&bag, true).expect("create the bag");
    let fixture = root().join("tests/fixtures/bags/tsukuba_half.mcap");
    for message in BagReader::open(&fixture).expect("open the fixture") {
        let m = message.expect("read a message");
        if m.topic == "/cam3/camera_info" {
            continue;
        }
        writer
            .add_topic(&m.topic, &m.msg_type, None)
            .expect("add a topic");
        writer
            .write(&m.topic, m.log_time_ns, m.publish_time_ns, &m.data)
            .expect("write a message");
    }
    writer.finish().expect("finish the bag");
    let params = root().join("tests/fixtures/bags/tsukuba_half.params.yaml");
    let out = Command::new(env!("CARGO_BIN_EXE_sweepdepth"))
        .args([
            "bag",
            bag.to_str().expect("a path"),
            dir.join("out.mcap").to_str().expect("a path"),
            "--params-file",
            params.to_str().expect("a path"),
        ])
        .env("RUST_LOG", "warn,sweepdepth=info")
        .stdin(Stdio::null())
        .output()
        .expect("run sweepdepth bag");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    let why = "camera_info never recorded for cam3 (/cam3/camera_info)";
    // In the summary line and in the error.
    assert!(
        stderr.contains(&format!("no set processed: {why}")),
        "{stderr}"
    );
    assert!(
        stderr.contains("no frame set could be processed") && stderr.matches(why).count() >= 2,
        "{stderr}"
    );
    // A run that fails leaves no bag (nor its partial file) at OUT.
    let left: Vec<String> = std::fs::read_dir(&dir)
        .expect("read the scratch dir")
        .map(|e| {
            e.expect("an entry")
                .file_name()
                .to_string_lossy()
                .into_owned()
        })
        .filter(|name| name.starts_with("out.mcap"))
        .collect();
    assert!(left.is_empty(), "left behind: {left:?}");
    let _ = std::fs::remove_dir_all(&dir);
}
