//! The live view of `sweepdepth node` (issue 13): a Foxglove WebSocket client (tests/common/
//! foxglove.rs, written from the protocol's spec) connects to a node fed by the test peers over
//! DDS, subscribes, and decodes depth and points equal to what the node publishes over DDS (and
//! the node makes no cost or selection nobody reads); the
//! page is served on the next port; without `foxglove_port` nothing listens; a viewer that
//! reads nothing does not slow the node nor grow its memory (the soak case).
//!
//! SAFETY: DDS only inside a private network namespace (tests/common/netns.rs), as every node
//! test; the WebSocket and HTTP servers bind 127.0.0.1 there too.

// The live view is the cargo feature `viewer` (on by default).
#![cfg(feature = "viewer")]

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use crate::common::dds::{self, frame, Diagnostics, NodeProcess, Peer, RigFeed};
use crate::common::foxglove::Client;
use crate::common::netns::in_private_netns;
use sweepdepth::geometry::CameraModel;
use sweepdepth::msgs::{from_cdr, Image, PointCloud2, Time};
use sweepdepth::synthetic::{self, Scene};

const INNER: &str = "SWEEPDEPTH_TEST_PRIVATE_NETNS";
const DOMAIN: u16 = 44;
const WIDTH: u32 = 80;
const HEIGHT: u32 = 60;
const CAMERAS: usize = 4;
const PORT: u16 = 8765;
/// The channels the viewer serves (under the node's default names).
const VIEWER_TOPICS: [&str; 6] = [
    "/depth/image",
    "/depth/camera_info",
    "/confidence/image",
    "/cost/image",
    "/selection/image",
    "/points",
];

#[test]
fn viewer_serves_what_dds_publishes() {
    in_private_netns(
        INNER,
        "viewer_node::viewer_serves_what_dds_publishes",
        same_as_dds,
    );
}

#[test]
fn viewer_is_off_without_foxglove_port() {
    in_private_netns(
        INNER,
        "viewer_node::viewer_is_off_without_foxglove_port",
        off_by_default,
    );
}

#[test]
fn viewer_that_reads_nothing_does_not_slow_the_node() {
    in_private_netns(
        INNER,
        "viewer_node::viewer_that_reads_nothing_does_not_slow_the_node",
        stuck_viewer,
    );
}

fn stamp_of(k: u32) -> Time {
    Time {
        sec: 1000 + (k / 10) as i32,
        nanosec: (k % 10) * 100_000_000,
    }
}

struct Harness {
    feed: RigFeed,
    peer: Peer,
    node: NodeProcess,
}

impl Harness {
    fn start(extra: &[&str]) -> Harness {
        Self::start_sized(WIDTH, HEIGHT, extra)
    }

    fn start_sized(width: u32, height: u32, extra: &[&str]) -> Harness {
        let model = CameraModel::pinhole(synthetic::intrinsics(width, height));
        let rig = synthetic::row_rig(CAMERAS, 0.1, model, 1).expect("rig");
        let scene = Scene::wall_and_box(
            2.0,
            Some((1.2, 0.2)),
            synthetic::intrinsics(width, height).fx_px,
        );
        let images = synthetic::render_rig(&scene, &rig);
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
            "-p",
            "sync:=exact",
        ];
        for p in extra {
            args.extend(["-p", p]);
        }
        let node = NodeProcess::start(DOMAIN, &args);
        let mut peer = Peer::new(DOMAIN, "sweepdepth_viewer_test_peer");
        let feed = RigFeed::new(&mut peer, rig, &images, &dds::reliable(10), None);
        Harness { feed, peer, node }
    }

    fn publish(&self, k: u32) {
        self.feed.publish_set(&[stamp_of(k); CAMERAS]);
    }
}

/// `GET path` on 127.0.0.1:`port`: (status line, body).
fn http_get(port: u16, path: &str) -> (String, Vec<u8>) {
    let mut stream = TcpStream::connect(("127.0.0.1", port)).expect("connect to the page server");
    stream
        .set_read_timeout(Some(dds::timeout()))
        .expect("timeout");
    write!(
        stream,
        "GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n"
    )
    .expect("request");
    let mut response = Vec::new();
    stream.read_to_end(&mut response).expect("response");
    let split = response
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("end of the headers");
    let head = String::from_utf8_lossy(&response[..split]).to_string();
    let status = head.lines().next().unwrap_or_default().to_string();
    (status, response[split + 4..].to_vec())
}

fn same_as_dds() {
    let mut h = Harness::start(&["publish_points:=true", &format!("foxglove_port:={PORT}")]);
    let mut diagnostics = Diagnostics::new(&mut h.peer);
    let depth_sub = h
        .peer
        .subscription::<Image>("/depth/image", dds::IMAGE, &dds::reliable(50));
    let points_sub =
        h.peer
            .subscription::<PointCloud2>("/points", dds::POINT_CLOUD2, &dds::reliable(50));

    let mut client = Client::connect("127.0.0.1", PORT, dds::timeout());
    let topics = VIEWER_TOPICS;
    client.wait_for_channels(&topics, dds::timeout());
    for topic in topics {
        let c = client.channel(topic);
        assert_eq!(c.encoding, "cdr", "{topic}");
        assert_eq!(c.schema_encoding, "ros2msg", "{topic}");
        let expected = match topic {
            "/points" => "sensor_msgs/msg/PointCloud2",
            "/depth/camera_info" => "sensor_msgs/msg/CameraInfo",
            _ => "sensor_msgs/msg/Image",
        };
        assert_eq!(c.schema_name, expected, "{topic}");
        assert!(
            c.schema.starts_with("std_msgs/Header header\n")
                && c.schema.contains("MSG: builtin_interfaces/Time"),
            "{topic}: the full ros2msg definition, as foxglove_bridge sends it; got {:?}",
            c.schema
        );
    }
    client.subscribe("/depth/image");
    client.subscribe("/points");

    // Sets keep coming until one stamp has both outputs on both sides.
    let mut ws_depth: Vec<Image> = Vec::new();
    let mut ws_points: Vec<PointCloud2> = Vec::new();
    let mut dds_depth: Vec<Image> = Vec::new();
    let mut dds_points: Vec<PointCloud2> = Vec::new();
    let feed = &h.feed;
    let ((depth, points), _) = dds::feed_until(
        "the same set's depth and points over the WebSocket and DDS",
        &mut h.node,
        1,
        |k| feed.publish_set(&[stamp_of(k); CAMERAS]),
        || {
            while let Some(frame) = client.poll(Duration::from_millis(1)) {
                if let Ok(m) = frame {
                    match m.topic.as_str() {
                        "/depth/image" => ws_depth.push(from_cdr(&m.payload).expect("depth CDR")),
                        "/points" => ws_points.push(from_cdr(&m.payload).expect("points CDR")),
                        other => panic!("not subscribed: {other}"),
                    }
                }
            }
            dds_depth.extend(dds::take_all(&depth_sub));
            dds_points.extend(dds::take_all(&points_sub));
            let stamp = ws_depth.iter().map(|d| d.header.stamp).find(|s| {
                ws_points.iter().any(|p| p.header.stamp == *s)
                    && dds_depth.iter().any(|d| d.header.stamp == *s)
                    && dds_points.iter().any(|p| p.header.stamp == *s)
            })?;
            let pick_image = |v: &[Image]| v.iter().find(|m| m.header.stamp == stamp).cloned();
            let pick_cloud =
                |v: &[PointCloud2]| v.iter().find(|m| m.header.stamp == stamp).cloned();
            Some((
                (pick_image(&ws_depth)?, pick_image(&dds_depth)?),
                (pick_cloud(&ws_points)?, pick_cloud(&dds_points)?),
            ))
        },
    );
    let (ws, over_dds) = depth;
    assert_eq!(ws.header.frame_id, frame(1));
    assert_eq!(
        (ws.width, ws.height, ws.encoding.as_str()),
        (WIDTH, HEIGHT, "32FC1")
    );
    assert_eq!(
        ws, over_dds,
        "the viewer's depth equals the DDS depth, byte for byte"
    );
    let valid = dds::depth_values(&ws)
        .iter()
        .filter(|z| z.is_finite())
        .count();
    assert!(
        valid > (WIDTH * HEIGHT / 2) as usize,
        "{valid} valid depths"
    );
    let (ws, over_dds) = points;
    assert_eq!((ws.width, ws.height), (WIDTH, HEIGHT));
    assert_eq!(
        ws, over_dds,
        "the viewer's points equal the DDS points, byte for byte"
    );
    // Nobody reads the cost or the selection, over DDS or in the viewer: the node makes
    // neither (the engine reads back depth and confidence, and the points are made).
    // A status made now: an older one may tell of a set made before the readers were seen.
    let status = diagnostics.wait_after(dds::wall_time_now(), &mut h.node);
    assert_eq!(
        dds::value_of(&status, "outputs made on demand"),
        Some("points"),
        "{status:?}"
    );

    // The page, on the next port, from the binary (works offline).
    let (status, body) = http_get(PORT + 1, "/");
    assert!(status.contains("200"), "{status}");
    let html = String::from_utf8_lossy(&body);
    assert!(
        html.contains("viewer.js") && html.contains("three.module.min.js"),
        "{html}"
    );
    let (status, body) = http_get(PORT + 1, "/config.json");
    assert!(status.contains("200"), "{status}");
    let config: serde_json::Value = serde_json::from_slice(&body).expect("config.json");
    assert_eq!(config["websocket_port"], PORT);
    let (status, body) = http_get(PORT + 1, "/three.module.min.js");
    assert!(
        status.contains("200") && body.len() > 100_000,
        "{status}, {} bytes",
        body.len()
    );
    let (status, _) = http_get(PORT + 1, "/nothing-here");
    assert!(status.contains("404"), "{status}");
}

fn off_by_default() {
    let mut h = Harness::start(&[]);
    let depth_sub = h
        .peer
        .subscription::<Image>("/depth/image", dds::IMAGE, &dds::reliable(50));
    let feed = &h.feed;
    // The node is up and answering...
    dds::feed_until(
        "a depth image",
        &mut h.node,
        1,
        |k| feed.publish_set(&[stamp_of(k); CAMERAS]),
        || dds::take_all(&depth_sub).pop(),
    );
    // ... and nothing listens on the viewer's ports.
    for port in [PORT, PORT + 1, sweepdepth::viewer::DEFAULT_PORT] {
        let refused = TcpStream::connect(("127.0.0.1", port));
        assert!(
            refused.is_err(),
            "something listens on {port} without foxglove_port"
        );
    }
}

/// Resident anonymous memory of `pid` (kB, from /proc): heap and stacks, not the mapped
/// libraries (whose pages come in as code paths first run).
fn rss_anon_kb(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).expect("/proc status");
    status
        .lines()
        .find_map(|l| l.strip_prefix("RssAnon:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .expect("RssAnon")
}

/// Feeds `sets` sets one at a time, each after the depth of the one before came back over DDS
/// (closed loop: the node's own pace); returns the time they took.
fn closed_loop(
    h: &mut Harness,
    depth_sub: &ros2_client::Subscription<Image>,
    first: u32,
    sets: u32,
) -> Duration {
    let started = Instant::now();
    for k in first..first + sets {
        h.publish(k);
        let stamp = stamp_of(k);
        let feed = &h.feed;
        // A set lost on the way (reliable QoS: rare) is sent again with the same stamp.
        let mut last_sent = Instant::now();
        dds::wait_for(format!("the depth of set {k}"), &mut h.node, || {
            if last_sent.elapsed() > Duration::from_secs(5) {
                feed.publish_set(&[stamp; CAMERAS]);
                last_sent = Instant::now();
            }
            dds::take_all(depth_sub)
                .into_iter()
                .find(|d| d.header.stamp == stamp)
        });
    }
    started.elapsed()
}

fn stuck_viewer() {
    // 320x240: a set's six outputs are about 2.2 MB on the viewer (the point cloud 1.2 MB), so
    // the 4 x 60 sets below pile up about 530 MB in a queue without a bound: the limits below
    // tell a bounded queue from none by a wide margin (with 80x60 images an unbounded queue grew
    // only about 8 MB and passed).
    let mut h = Harness::start_sized(
        320,
        240,
        &["publish_points:=true", &format!("foxglove_port:={PORT}")],
    );
    let depth_sub = h
        .peer
        .subscription::<Image>("/depth/image", dds::IMAGE, &dds::reliable(50));
    const SETS: u32 = 60;
    // Warm-up (the engine's first set, the DDS matching).
    closed_loop(&mut h, &depth_sub, 1, 5);
    let alone = closed_loop(&mut h, &depth_sub, 100, SETS);
    let rss_alone = rss_anon_kb(h.node.pid());

    // A viewer that subscribes to everything, then never reads again: its socket fills, the
    // server's queue for it drops the oldest messages.
    let mut stuck = Client::connect("127.0.0.1", PORT, dds::timeout());
    let topics = VIEWER_TOPICS;
    stuck.wait_for_channels(&topics, dds::timeout());
    for topic in topics {
        stuck.subscribe(topic);
    }
    // Four runs with the stuck viewer, the node's anonymous memory (the heap: what a queue
    // holds) after each.
    let mut watched = Vec::new();
    let mut rss = Vec::new();
    for run in 0..4 {
        watched.push(closed_loop(&mut h, &depth_sub, 200 + 100 * run, SETS));
        rss.push(rss_anon_kb(h.node.pid()));
    }
    drop(stuck);
    let alone_again = closed_loop(&mut h, &depth_sub, 700, SETS);
    eprintln!(
        "{SETS} sets each: alone {alone:?}, with a viewer reading nothing {watched:?}, alone again {alone_again:?}; anonymous memory alone {rss_alone} kB, after each watched run {rss:?} kB"
    );
    // Throughput: every one of the 4 x SETS sets was answered in its closed loop above while the
    // viewer read nothing (a node that waited for the viewer would stall and `closed_loop` would
    // fail on its wait). The times are printed, not compared: how fast runs go depends on the
    // machine's load from one run to the next, so no assertion is made on them.
    // Memory: bounded (the queues drop the oldest). A bounded queue holds at most 12 messages
    // per client; what the node adds beyond that is the allocator's (freed blocks kept per
    // thread arena), which settles but moves with the machine's load: whole-process RSS once
    // grew 49 MB from one watched run to the next under CI's load (the other live tests
    // running beside it; +9 MB on a quiet machine), over the 48 MB limit of the two-run test
    // this one replaced. Measured (2026-11-26, 2-core machine, the live tests beside it),
    // anonymous memory after each watched run: bounded 216, 219, 230, 233 MB (191 alone);
    // with the bound removed (CLIENT_BACKLOG 1 000 000) 331, 472, 615, 759 MB (174 alone). The
    // limits: from the second run to the fourth +96 MB (bounded +14, unbounded +287), over
    // the node alone +192 MB (bounded +42, unbounded +585).
    let (settled, last) = (rss[1], rss[3]);
    assert!(
        last < settled + 96 * 1024,
        "memory grew with a viewer reading nothing: {settled} kB -> {last} kB over {} sets",
        2 * SETS
    );
    assert!(
        last < rss_alone + 192 * 1024,
        "a viewer reading nothing costs {} kB ({rss_alone} kB alone, {last} kB with it)",
        last.saturating_sub(rss_alone)
    );
}
