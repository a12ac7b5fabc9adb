//! The bag fixture played live over DDS into the running node (a player with the original
//! timing), the outputs recorded back and compared with `sweepdepth bag` on the same bag: the
//! same depth, stamp by stamp.
//!
//! SAFETY: DDS only inside the private network namespace of tests/common/netns.rs.

#[path = "common/netns.rs"]
mod netns;
#[path = "common/player.rs"]
mod player;

use std::collections::HashMap;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use netns::{in_private_netns, KillOnDrop};
use ros2_client::qos::{History, WhenFull};
use ros2_client::{
    Context, ContextOptions, MessageTypeName, Name, NodeName, NodeOptions, QosProfile,
};
use sweepdepth::bag::{BagMessage, BagReader};
use sweepdepth::msgs::{from_cdr, Image, Time};

const INNER: &str = "SWEEPDEPTH_TEST_PRIVATE_NETNS";
const DOMAIN: u16 = 44;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn messages(path: &std::path::Path) -> Vec<BagMessage> {
    BagReader::open(path)
        .expect("open bag")
        .map(|m| m.expect("message"))
        .collect()
}

fn depth_values(image: &Image) -> Vec<f32> {
    image
        .data
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect()
}

#[test]
fn bag_played_live_gives_the_offline_depth() {
    in_private_netns(
        INNER,
        "bag_played_live_gives_the_offline_depth",
        live_vs_offline,
    );
}

fn live_vs_offline() {
    let fixture = root().join("tests/fixtures/bags/tsukuba_half.mcap");
    let params = root().join("tests/fixtures/bags/tsukuba_half.params.yaml");

    // Offline.
    let dir = std::env::temp_dir().join(format!("sweepdepth-baglive-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let offline_path = dir.join("offline.mcap");
    let out = Command::new(env!("CARGO_BIN_EXE_sweepdepth"))
        .args([
            "bag",
            fixture.to_str().unwrap(),
            offline_path.to_str().unwrap(),
        ])
        .args(["--params-file", params.to_str().unwrap()])
        .stdin(Stdio::null())
        .output()
        .expect("run sweepdepth bag");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let offline: HashMap<Time, Image> = messages(&offline_path)
        .into_iter()
        .filter(|m| m.topic == "/depth/image")
        .map(|m| {
            let image: Image = from_cdr(&m.data).unwrap();
            (image.header.stamp, image)
        })
        .collect();
    assert_eq!(offline.len(), 3);

    // Live: the node with the same parameter file, the bag played into it.
    let node = Command::new(env!("CARGO_BIN_EXE_sweepdepth"))
        .args([
            "node",
            "--ros-args",
            "--params-file",
            params.to_str().unwrap(),
        ])
        .env("ROS_DOMAIN_ID", DOMAIN.to_string())
        .env("RUST_LOG", "warn,sweepdepth=info")
        .stdin(Stdio::null())
        .spawn()
        .expect("start the node");
    let mut node = KillOnDrop(node);
    let context = Context::with_options(ContextOptions::new().domain_id(DOMAIN)).unwrap();
    let mut peer = context
        .new_node(
            NodeName::new("/", "sweepdepth_bag_player").unwrap(),
            NodeOptions::new()
                .enable_rosout(false)
                .start_parameter_services(false),
        )
        .unwrap();
    let bag = messages(&fixture);
    let player = player::Player::new(&mut peer, &bag);
    let reliable = QosProfile::subscription_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .history(History::KeepLast { depth: 10 });
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
    // Discovery is symmetric but not simultaneous: give the node's readers a moment.
    std::thread::sleep(Duration::from_millis(500));
    player.play(&bag);

    let last_stamp = bag
        .iter()
        .filter(|m| m.topic == "/cam2/image_raw")
        .map(|m| from_cdr::<Image>(&m.data).unwrap().header.stamp)
        .max()
        .unwrap();
    let mut live: HashMap<Time, Image> = HashMap::new();
    let started = Instant::now();
    while !live.contains_key(&last_stamp) {
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "the last set's depth never came (got {} depth images)",
            live.len()
        );
        if let Some(status) = node.0.try_wait().unwrap() {
            panic!("the node exited: {status}");
        }
        match depth_sub.take() {
            Ok(Some((image, _))) => {
                live.insert(image.header.stamp, image);
            }
            _ => std::thread::sleep(Duration::from_millis(10)),
        }
    }
    // The node keeps the newest set when the GPU is busy, so it may skip the middle one; every
    // depth it publishes must be the offline one for that stamp.
    eprintln!("live: {} of 3 sets published", live.len());
    for (stamp, image) in &live {
        let reference = offline
            .get(stamp)
            .unwrap_or_else(|| panic!("live depth stamped {stamp:?}, which no offline output has"));
        assert_eq!(image.header, reference.header);
        assert_eq!(
            (image.width, image.height, &image.encoding),
            (reference.width, reference.height, &reference.encoding)
        );
        let (a, b) = (depth_values(image), depth_values(reference));
        let mut worst = 0f32;
        for (x, y) in a.iter().zip(&b) {
            assert_eq!(x.is_nan(), y.is_nan(), "valid pixels differ");
            if x.is_finite() {
                worst = worst.max((x - y).abs() / y.abs().max(1e-6));
            }
        }
        assert!(
            worst <= 1e-5,
            "live and offline depth differ by {worst} (relative)"
        );
    }
}
