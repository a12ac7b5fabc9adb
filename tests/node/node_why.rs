//! Never silent (issue 34): when no depth comes out, `sweepdepth node` says why, in its log
//! (a WARN line "no depth: ...") and as the status message of `/diagnostics`, naming the
//! topic or camera and the cause; once depth flows, it says nothing.
//!
//! Each test starts the node and a ros2-client peer that feeds it a synthetic 4-camera row rig
//! with one thing wrong, and WAITS for the node's line (its stderr, piped and read line by
//! line) and for the same text in `/diagnostics`, within the one generous limit of
//! tests/common/dds.rs: no test assumes how fast the machine is.
//!
//! SAFETY: no DDS packet may leave the machine: every test runs inside a private network
//! namespace with only loopback (tests/common/netns.rs).

use std::io::BufRead;
use std::process::Stdio;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use crate::common::dds::{self, frame, Diagnostics, NodeProcess, Peer};
use crate::common::netns::in_private_netns;
use ros2_client::{Publisher, QosProfile};
use sweepdepth::geometry::{CameraModel, Rig};
use sweepdepth::msgs::{
    CameraInfo, Header, Image, Quaternion, TFMessage, Time, Transform, TransformStamped, Vector3,
};
use sweepdepth::synthetic::{self, Scene};

const INNER: &str = "SWEEPDEPTH_TEST_PRIVATE_NETNS_WHY";
const DOMAIN: u16 = 43;
const WIDTH: u32 = 80;
const HEIGHT: u32 = 60;
const CAMERAS: usize = 4;

#[test]
fn why_no_publisher() {
    in_private_netns(INNER, "node_why::why_no_publisher", no_publisher);
}

#[test]
fn why_incompatible_qos() {
    in_private_netns(INNER, "node_why::why_incompatible_qos", incompatible_qos);
}

#[test]
fn why_camera_info_missing() {
    in_private_netns(
        INNER,
        "node_why::why_camera_info_missing",
        camera_info_missing,
    );
}

#[test]
fn why_tf_static_link_missing() {
    in_private_netns(
        INNER,
        "node_why::why_tf_static_link_missing",
        tf_static_link_missing,
    );
}

#[test]
fn why_stamps_offset_beyond_sync_max_interval() {
    in_private_netns(
        INNER,
        "node_why::why_stamps_offset_beyond_sync_max_interval",
        stamps_offset,
    );
}

#[test]
fn why_exact_sync_with_unequal_stamps() {
    in_private_netns(
        INNER,
        "node_why::why_exact_sync_with_unequal_stamps",
        exact_unequal,
    );
}

#[test]
fn why_moving_rig_without_tf() {
    in_private_netns(
        INNER,
        "node_why::why_moving_rig_without_tf",
        moving_rig_without_tf,
    );
}

#[test]
fn why_moving_rig_whose_tf_never_comes_skips_sets() {
    in_private_netns(
        INNER,
        "node_why::why_moving_rig_whose_tf_never_comes_skips_sets",
        moving_rig_tf_timeout,
    );
}

#[test]
fn why_moving_rig_whose_tf_names_another_world() {
    in_private_netns(
        INNER,
        "node_why::why_moving_rig_whose_tf_names_another_world",
        moving_rig_tf_misnamed,
    );
}

#[test]
fn why_silent_while_depth_flows() {
    in_private_netns(
        INNER,
        "node_why::why_silent_while_depth_flows",
        silent_while_depth_flows,
    );
}

/// Set `k`'s stamp: 1000.1 s, 1000.2 s, ... (10 Hz).
fn stamp_ns(k: u32) -> i64 {
    1_000_000_000_000 + i64::from(k) * 100_000_000
}

fn time_of(ns: i64) -> Time {
    Time {
        sec: ns.div_euclid(1_000_000_000) as i32,
        nanosec: ns.rem_euclid(1_000_000_000) as u32,
    }
}

/// The node with its stderr read line by line on a thread (each line echoed to ours).
struct Node {
    process: NodeProcess,
    lines: mpsc::Receiver<String>,
    /// Every line so far.
    seen: Vec<String>,
}

impl Node {
    /// `cameras:=[cam0, cam1, cam2, cam3]`, reference cam1, no camera timeout, and `extra`.
    fn start(extra: &[&str]) -> Node {
        let mut args = vec![
            "-p",
            "cameras:=[cam0, cam1, cam2, cam3]",
            "-p",
            "reference_camera:=cam1",
            "-p",
            "min_depth:=1.0",
            "-p",
            "max_depth:=4.0",
            "-p",
            "num_planes:=48",
            "-p",
            "camera_timeout:=0.0",
        ];
        for p in extra {
            args.extend(["-p", p]);
        }
        let mut command = dds::node_command(DOMAIN, &args);
        command.stderr(Stdio::piped());
        let mut process = NodeProcess::spawn(command);
        let stderr = process.take_stderr();
        let (tx, lines) = mpsc::channel();
        std::thread::spawn(move || {
            for line in std::io::BufReader::new(stderr).lines() {
                let Ok(line) = line else { break };
                eprintln!("[node] {line}");
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        Node {
            process,
            lines,
            seen: Vec::new(),
        }
    }

    /// The lines that arrived since the last call.
    fn take_lines(&mut self) -> Vec<String> {
        let new: Vec<String> = self.lines.try_iter().collect();
        self.seen.extend(new.iter().cloned());
        new
    }
}

/// A peer publishing the synthetic rig, with what is wrong chosen per test.
struct Feed {
    rig: Rig,
    images: Vec<Image>,
    image_pubs: Vec<Publisher<Image>>,
    info_pubs: Vec<Option<Publisher<CameraInfo>>>,
    _tf_pub: Publisher<TFMessage>,
    /// Per camera, added to its stamps.
    offsets_ns: [i64; CAMERAS],
    /// `/tf` sent with each set, at its stamp: (publisher, parent frame) of `parent -> rig`.
    tf: Option<(Publisher<TFMessage>, String)>,
}

impl Feed {
    /// Images on `/camN/image_raw` (with `image_qos`), camera_info for the cameras of
    /// `infos` and `/tf_static` (once, transient local) for the cameras of `tf`.
    fn new(peer: &mut Peer, image_qos: &QosProfile, infos: &[usize], tf: &[usize]) -> Feed {
        let model = CameraModel::pinhole(synthetic::intrinsics(WIDTH, HEIGHT));
        let rig = synthetic::row_rig(CAMERAS, 0.1, model, 1).expect("rig");
        let scene = Scene::wall_and_box(2.0, None, synthetic::intrinsics(WIDTH, HEIGHT).fx_px);
        let rendered = synthetic::render_rig(&scene, &rig);
        let tf_pub = peer.publisher::<TFMessage>("/tf_static", dds::TF_MESSAGE, &dds::latched(10));
        let transforms = tf
            .iter()
            .map(|&i| {
                let c = rig.cameras[i].centre_in_rig();
                TransformStamped {
                    header: Header {
                        stamp: Time::default(),
                        frame_id: "rig".into(),
                    },
                    child_frame_id: frame(i),
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
        tf_pub
            .publish(TFMessage { transforms })
            .expect("publish /tf_static");
        let qos = dds::reliable(10);
        let mut image_pubs = Vec::new();
        let mut info_pubs = Vec::new();
        for i in 0..CAMERAS {
            image_pubs.push(peer.publisher(&format!("/cam{i}/image_raw"), dds::IMAGE, image_qos));
            info_pubs.push(
                infos.contains(&i).then(|| {
                    peer.publisher(&format!("/cam{i}/camera_info"), dds::CAMERA_INFO, &qos)
                }),
            );
        }
        let images = rendered
            .iter()
            .enumerate()
            .map(|(i, image)| {
                let header = Header {
                    stamp: Time::default(),
                    frame_id: frame(i),
                };
                dds::image_msg(&header, image, false)
            })
            .collect();
        Feed {
            rig,
            images,
            image_pubs,
            info_pubs,
            _tf_pub: tf_pub,
            offsets_ns: [0; CAMERAS],
            tf: None,
        }
    }

    /// Also `/tf` `parent -> rig` (identity) at each set's stamp, on `peer`.
    fn with_tf(mut self, peer: &mut Peer, parent: &str) -> Feed {
        let publisher = peer.publisher::<TFMessage>("/tf", dds::TF_MESSAGE, &dds::reliable(100));
        self.tf = Some((publisher, parent.to_string()));
        self
    }

    /// Publishes set `k`: each camera's camera_info (where it has one) and image.
    fn publish(&self, k: u32) {
        if let Some((publisher, parent)) = &self.tf {
            let _ = publisher.publish(TFMessage {
                transforms: vec![TransformStamped {
                    header: Header {
                        stamp: time_of(stamp_ns(k)),
                        frame_id: parent.clone(),
                    },
                    child_frame_id: "rig".into(),
                    transform: Transform {
                        translation: Vector3::default(),
                        rotation: Quaternion::default(),
                    },
                }],
            });
        }
        for i in 0..CAMERAS {
            let header = Header {
                stamp: time_of(stamp_ns(k) + self.offsets_ns[i]),
                frame_id: frame(i),
            };
            if let Some(info_pub) = &self.info_pubs[i] {
                // Best effort towards the node: a lost message is sent again with the next set.
                let _ = info_pub.publish(dds::camera_info(&header, &self.rig.cameras[i].model));
            }
            let mut image = self.images[i].clone();
            image.header = header;
            let _ = self.image_pubs[i].publish(image);
        }
    }
}

/// Publishes a set every 100 ms (with `feed`) until the node has printed a WARN line
/// containing `expected` and a `/diagnostics` status carries it too; returns the line.
fn wait_for_why(
    node: &mut Node,
    diag: &mut Diagnostics,
    feed: Option<&Feed>,
    expected: &[&str],
) -> String {
    let limit = dds::timeout();
    let started = Instant::now();
    let mut line: Option<String> = None;
    let mut statuses: Vec<String> = Vec::new();
    let mut k = 1;
    let matches = |text: &str| expected.iter().all(|e| text.contains(e));
    loop {
        node.process.check_alive();
        assert!(
            started.elapsed() < limit,
            "waited {limit:?} in vain for the node to say {expected:?} (line: {line:?}, /diagnostics: {statuses:?}); its lines: {:#?}",
            node.seen
        );
        if let Some(feed) = feed {
            feed.publish(k);
            k += 1;
        }
        let tick = Instant::now();
        while tick.elapsed() < Duration::from_millis(100) {
            for l in node.take_lines() {
                if l.contains("WARN") && l.contains("no depth: ") && matches(&l) {
                    line.get_or_insert(l);
                }
            }
            for s in diag.take() {
                if matches(&s.message) {
                    assert_eq!(s.level, sweepdepth::msgs::DiagnosticStatus::WARN, "{s:?}");
                    statuses.push(s.message);
                }
            }
            if let Some(line) = &line {
                let why = line
                    .split("no depth: ")
                    .nth(1)
                    .expect("the reason after 'no depth: '");
                // The same text in /diagnostics (the status of the same second).
                if statuses.iter().any(|s| {
                    (s.starts_with("no depth published yet: ")
                        || s.starts_with("no depth published in the last 5 s: "))
                        && s.ends_with(why)
                }) {
                    return why.to_string();
                }
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}

fn no_publisher() {
    let mut node = Node::start(&[]);
    let mut peer = Peer::new(DOMAIN, "sweepdepth_why_peer");
    let mut diag = Diagnostics::new(&mut peer);
    let why = wait_for_why(
        &mut node,
        &mut diag,
        None,
        &["no publisher on /cam0/image_raw: check the namespace, the remaps and ROS_DOMAIN_ID"],
    );
    assert!(why.contains("(nor from 3 other cameras)"), "{why}");
}

fn incompatible_qos() {
    let mut node = Node::start(&["input_qos_reliable:=true"]);
    let mut peer = Peer::new(DOMAIN, "sweepdepth_why_peer");
    let mut diag = Diagnostics::new(&mut peer);
    let feed = Feed::new(
        &mut peer,
        &dds::best_effort(5),
        &[0, 1, 2, 3],
        &[0, 1, 2, 3],
    );
    wait_for_why(
        &mut node,
        &mut diag,
        Some(&feed),
        &[
            "the publisher on /cam0/image_raw cannot match",
            "offers best-effort, volatile, the node requests reliable, volatile",
            "input_qos_reliable",
        ],
    );
}

fn camera_info_missing() {
    let mut node = Node::start(&[]);
    let mut peer = Peer::new(DOMAIN, "sweepdepth_why_peer");
    let mut diag = Diagnostics::new(&mut peer);
    let feed = Feed::new(&mut peer, &dds::reliable(10), &[0, 1, 2], &[0, 1, 2, 3]);
    wait_for_why(
        &mut node,
        &mut diag,
        Some(&feed),
        &["images arrive but no publisher on /cam3/camera_info"],
    );
}

fn tf_static_link_missing() {
    let mut node = Node::start(&[]);
    let mut peer = Peer::new(DOMAIN, "sweepdepth_why_peer");
    let mut diag = Diagnostics::new(&mut peer);
    let feed = Feed::new(&mut peer, &dds::reliable(10), &[0, 1, 2, 3], &[0, 1, 2]);
    wait_for_why(
        &mut node,
        &mut diag,
        Some(&feed),
        &["no transform from 'cam1_optical' to 'cam3_optical' in /tf_static (camera 'cam3')"],
    );
}

/// A moving rig (`world_frame:=world`) with nobody publishing /tf: the sets wait for their
/// world pose (`tf_timeout` 60 s, the most), and the node says so, naming /tf. Where DDS
/// discovery is slow enough (a loaded machine: /tf_static once took 60 s to come) that the
/// first sets outwait `tf_timeout`, they are skipped, and the node says that, naming /tf too.
fn moving_rig_without_tf() {
    let mut node = Node::start(&["world_frame:=world", "tf_timeout:=60.0"]);
    let mut peer = Peer::new(DOMAIN, "sweepdepth_why_peer");
    let mut diag = Diagnostics::new(&mut peer);
    let feed = Feed::new(&mut peer, &dds::reliable(10), &[0, 1, 2, 3], &[0, 1, 2, 3]);
    let line = wait_for_why(
        &mut node,
        &mut diag,
        Some(&feed),
        &[
            "world_frame 'world'",
            "no publisher on /tf: check the namespace, the remaps and ROS_DOMAIN_ID",
        ],
    );
    assert!(
        line.contains(" set(s) wait for their pose in world_frame 'world': no publisher on /tf")
            || line.contains("sets are skipped: no pose of 'cam1_optical' in world_frame 'world'"),
        "{line}"
    );
}

/// A moving rig whose /tf never reaches the sets (none published, `tf_timeout:=0.2`): each
/// set is skipped after the timeout with the reason, which the node gives as why no depth
/// comes out, and /diagnostics counts them under "skipped: no world pose".
fn moving_rig_tf_timeout() {
    let mut node = Node::start(&["world_frame:=world", "tf_timeout:=0.2"]);
    let mut peer = Peer::new(DOMAIN, "sweepdepth_why_peer");
    let mut diag = Diagnostics::new(&mut peer);
    let feed = Feed::new(&mut peer, &dds::reliable(10), &[0, 1, 2, 3], &[0, 1, 2, 3]);
    wait_for_why(
        &mut node,
        &mut diag,
        Some(&feed),
        &[
            "sets are skipped: ",
            "no pose of 'cam1_optical' in world_frame 'world' at the set's stamp",
        ],
    );
    let status = diag.wait_until(
        "a count of sets skipped without a world pose",
        &mut node.process,
        |s| {
            dds::value_of(s, "skipped: no world pose")
                .and_then(|v| v.parse::<u64>().ok())
                .is_some_and(|n| n > 0)
        },
    );
    eprintln!(
        "skipped: no world pose = {:?}",
        dds::value_of(&status, "skipped: no world pose")
    );
}

/// A moving rig whose /tf names another world (`odom -> rig` while `world_frame:=world`):
/// /tf arrives at every set's stamp, but no pose in 'world' can come of it; each set is
/// skipped after `tf_timeout` and the reason says that 'world' is not in the tree.
fn moving_rig_tf_misnamed() {
    let mut node = Node::start(&["world_frame:=world", "tf_timeout:=0.2"]);
    let mut peer = Peer::new(DOMAIN, "sweepdepth_why_peer");
    let mut diag = Diagnostics::new(&mut peer);
    let feed = Feed::new(&mut peer, &dds::reliable(10), &[0, 1, 2, 3], &[0, 1, 2, 3])
        .with_tf(&mut peer, "odom");
    wait_for_why(
        &mut node,
        &mut diag,
        Some(&feed),
        &[
            "sets are skipped: ",
            "no pose of 'cam1_optical' in world_frame 'world'",
            "'world' is not in the tree",
        ],
    );
}

fn stamps_offset() {
    let mut node = Node::start(&["sync_max_interval:=0.02"]);
    let mut peer = Peer::new(DOMAIN, "sweepdepth_why_peer");
    let mut diag = Diagnostics::new(&mut peer);
    let mut feed = Feed::new(&mut peer, &dds::reliable(10), &[0, 1, 2, 3], &[0, 1, 2, 3]);
    feed.offsets_ns[2] = -48_000_000;
    wait_for_why(
        &mut node,
        &mut diag,
        Some(&feed),
        &["cam2 is 48 ms behind the others; sync_max_interval is 20 ms"],
    );
}

fn exact_unequal() {
    let mut node = Node::start(&["sync:=exact"]);
    let mut peer = Peer::new(DOMAIN, "sweepdepth_why_peer");
    let mut diag = Diagnostics::new(&mut peer);
    let mut feed = Feed::new(&mut peer, &dds::reliable(10), &[0, 1, 2, 3], &[0, 1, 2, 3]);
    feed.offsets_ns[2] = 5_000_000;
    let why = wait_for_why(
        &mut node,
        &mut diag,
        Some(&feed),
        &["exact sync: stamps never equal (cam1 ", ", cam2 "],
    );
    // "(cam1 1000.300, cam2 1000.205)": each stamp with its camera, 5 ms apart modulo a set.
    let stamps: Vec<f64> = why
        .split(['(', ')', ','])
        .filter_map(|part| part.trim().split(' ').nth(1)?.parse().ok())
        .collect();
    assert_eq!(stamps.len(), 2, "{why}");
    let apart_ms = ((stamps[1] - stamps[0]) * 1e3).rem_euclid(100.0);
    assert!((apart_ms - 5.0).abs() < 0.5, "{why}");
}

fn silent_while_depth_flows() {
    let mut node = Node::start(&["sync:=exact"]);
    let mut peer = Peer::new(DOMAIN, "sweepdepth_why_peer");
    let depth_sub = peer.subscription::<Image>("/depth/image", dds::IMAGE, &dds::reliable(50));
    let feed = Feed::new(&mut peer, &dds::reliable(10), &[0, 1, 2, 3], &[0, 1, 2, 3]);
    // Sets until the first depth.
    let (_, last) = dds::feed_until(
        "the first depth image",
        &mut node.process,
        1,
        |k| feed.publish(k),
        || dds::take_all(&depth_sub).into_iter().next(),
    );
    // Then many sets, each sent once the previous one's depth is back, for at least 40 sets
    // and at least twice the node's 5 s staleness (a minimum, never a wait for the node).
    let run_started = Instant::now();
    let mut k = last + 1;
    let mut answered = 0;
    while answered < 40 || run_started.elapsed() < Duration::from_secs(12) {
        let stamp = time_of(stamp_ns(k));
        let (_, sent) = dds::feed_until(
            format!("the depth of set {k}"),
            &mut node.process,
            k,
            |j| feed.publish(j),
            || {
                dds::take_all(&depth_sub)
                    .into_iter()
                    .find(|d| d.header.stamp.to_nanos() >= stamp.to_nanos())
            },
        );
        k = sent + 1;
        answered += 1;
        node.take_lines();
        if answered == 1 {
            // Counted from here: a line decided before the first depth was published may
            // still have been on its way.
            node.seen.clear();
        }
    }
    node.take_lines();
    let said: Vec<&String> = node
        .seen
        .iter()
        .filter(|l| l.contains("no depth: "))
        .collect();
    assert!(
        said.is_empty(),
        "the node said 'no depth' while depth flowed ({answered} sets over {:?}): {said:#?}",
        run_started.elapsed()
    );
}
