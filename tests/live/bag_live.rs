//! The bag fixture played live over DDS into the running node, the outputs recorded back and
//! compared with `sweepdepth bag` on the same bag: the same depth, stamp by stamp, for every
//! frame set.
//!
//! The player is paced on the node's answers, not on the bag's clock: after a warm-up (copies
//! of the first set, stamped earlier, until one gives depth: then the node's subscriptions and
//! `/tf_static` are known to be in place), each set is published once the node has published
//! the previous one's depth. So the node's newest-wins GPU hand-over never has a reason to drop
//! a set, however slow the machine, and every set must give depth.
//!
//! SAFETY: DDS only inside the private network namespace of tests/common/netns.rs.

use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::process::{Command, Stdio};

use crate::common::dds::{self, NodeProcess, Peer};
use crate::common::netns::in_private_netns;
use crate::common::player::Player;
use sweepdepth::bag::{BagMessage, BagReader};
use sweepdepth::msgs::{from_cdr, CameraInfo, Image, Time};

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

/// The header stamp of an image or camera info message of the bag.
fn stamp_of(m: &BagMessage) -> Option<Time> {
    match m.msg_type.as_str() {
        "sensor_msgs/msg/Image" => Some(from_cdr::<Image>(&m.data).ok()?.header.stamp),
        "sensor_msgs/msg/CameraInfo" => Some(from_cdr::<CameraInfo>(&m.data).ok()?.header.stamp),
        _ => None,
    }
}

#[test]
fn bag_played_live_gives_the_offline_depth() {
    in_private_netns(
        INNER,
        "bag_live::bag_played_live_gives_the_offline_depth",
        live_vs_offline,
    );
}

fn live_vs_offline() {
    let fixture = root().join("tests/fixtures/bags/tsukuba_half.mcap");
    let params = root().join("tests/fixtures/bags/tsukuba_half.params.yaml");

    let started = std::time::Instant::now();
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
    eprintln!("offline done after {:?}", started.elapsed());

    // The bag's frame sets (camera infos and images by stamp, in bag order) and its /tf_static.
    let bag = messages(&fixture);
    let mut sets: BTreeMap<Time, Vec<&BagMessage>> = BTreeMap::new();
    for m in &bag {
        if let Some(stamp) = stamp_of(m) {
            sets.entry(stamp).or_default().push(m);
        }
    }
    assert_eq!(sets.len(), 3, "the fixture has 3 frame sets");
    let first_stamp = *sets.keys().next().unwrap();

    // Live: the node with the same parameter file (inputs reliable: a paced peer must not lose
    // a set; no camera leaves the rig while the peer waits), the bag played into it.
    let mut node = NodeProcess::start(
        DOMAIN,
        &[
            "--params-file",
            params.to_str().unwrap(),
            "-p",
            "input_qos_reliable:=true",
            "-p",
            "camera_timeout:=0.0",
            "-p",
            "output_qos_depth:=10",
        ],
    );
    let mut peer = Peer::new(DOMAIN, "sweepdepth_bag_player");
    let player = Player::new(&mut peer, &bag);
    let depth_sub = peer.subscription::<Image>("/depth/image", dds::IMAGE, &dds::reliable(50));
    peer.spin_in_background();
    player.wait_for_subscribers(&peer, &mut node);
    for m in bag.iter().filter(|m| m.topic == "/tf_static") {
        player.publish(m);
    }

    // Warm-up: the first set stamped 5 s before the bag (1 ms apart) until one gives depth,
    // then that set's depth: from there on the node is idle between sets.
    let warm_stamp = |j: u32| {
        assert!(j < 5000, "more than 5000 warm-up sets");
        dds::time_of_ns(first_stamp.to_nanos() as u64 - 5_000_000_000 + u64::from(j) * 1_000_000)
    };
    let mut live: HashMap<Time, Image> = HashMap::new();
    let collect = |live: &mut HashMap<Time, Image>| {
        for image in dds::take_all(&depth_sub) {
            live.insert(image.header.stamp, image);
        }
    };
    let last = player.warm_up(&sets[&first_stamp], warm_stamp, &mut node, || {
        collect(&mut live);
        !live.is_empty()
    });
    dds::wait_for(
        format!("the depth of the last warm-up set ({:?})", warm_stamp(last)),
        &mut node,
        || {
            collect(&mut live);
            live.contains_key(&warm_stamp(last)).then_some(())
        },
    );

    eprintln!("warm-up done after {:?}", started.elapsed());

    // The bag, one set at a time: each after the previous one's depth.
    for (stamp, messages) in &sets {
        for m in messages {
            player.publish(m);
        }
        dds::wait_for(
            format!("the depth of the bag's set stamped {stamp:?}"),
            &mut node,
            || {
                collect(&mut live);
                live.contains_key(stamp).then_some(())
            },
        );
        eprintln!("set {stamp:?}: depth after {:?}", started.elapsed());
    }
    node.check_alive();

    // Every set's depth is the offline one for that stamp.
    for (stamp, reference) in &offline {
        let image = &live[stamp];
        assert_eq!(image.header, reference.header);
        assert_eq!(
            (image.width, image.height, &image.encoding),
            (reference.width, reference.height, &reference.encoding)
        );
        let (a, b) = (dds::depth_values(image), dds::depth_values(reference));
        let mut worst = 0f32;
        for (x, y) in a.iter().zip(&b) {
            assert_eq!(x.is_nan(), y.is_nan(), "valid pixels differ at {stamp:?}");
            if x.is_finite() {
                worst = worst.max((x - y).abs() / y.abs().max(1e-6));
            }
        }
        assert!(
            worst <= 1e-5,
            "live and offline depth differ by {worst} (relative) at {stamp:?}"
        );
    }
    eprintln!("live: all 3 sets published, each equal to the offline depth");
}
