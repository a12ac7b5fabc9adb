//! `sweepdepth node` ends cleanly and promptly on SIGINT and SIGTERM (as `ros2 launch` stops
//! it): exit status 0, a log line, and no error line in the whole log, from a start on a
//! headless machine (no `XDG_RUNTIME_DIR`, no `ROS_DISTRO`) on both engines, and with a set
//! in flight: the running set is cancelled between passes and the pending one abandoned.
//!
//! Pace: the set in flight is made long (640x480, 160 planes), and the test paces on the node's
//! own log line that the set started, never on a guess of the machine's speed. How long the
//! node may take to stop is judged against how long one such set takes in the same run (the
//! first set is let through and timed): at most half of it, and never more than needed where
//! it is below 2 s; a hard limit only bounds how long a stuck node takes to fail.
//!
//! SAFETY: DDS only inside the private network namespace of tests/common/netns.rs.

use std::io::{BufRead, BufReader};
use std::process::{Command, ExitStatus, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

use crate::common::dds::{self, NodeProcess, Peer, RigFeed};
use crate::common::netns;
use sweepdepth::geometry::CameraModel;
use sweepdepth::msgs::{Image, Time};
use sweepdepth::synthetic::{self, Scene};

const INNER: &str = "SWEEPDEPTH_TEST_PRIVATE_NETNS";
/// A node that takes this long to stop is stuck (the real bounds are below): the tests' one
/// limit (`SWEEPDEPTH_TEST_TIMEOUT_S`).
fn stop_limit() -> Duration {
    dds::timeout()
}
/// The promptness the node promises on a machine where one set takes less than 4 s.
const PROMPT: Duration = Duration::from_secs(2);

#[test]
fn node_stops_cleanly_on_sigint_and_sigterm() {
    netns::in_private_netns(
        INNER,
        "node_shutdown::node_stops_cleanly_on_sigint_and_sigterm",
        || {
            // The WGSL engine (Vulkan: lavapipe here) and the default device, both headless.
            stop_idle("INT", &["-p", "device:=gpu"]);
            stop_idle("TERM", &[]);
        },
    );
}

/// Alone in the binary: the stop is judged against one set's time in the same run, which another
/// test's load beside it could change between the two.
#[test]
fn node_stops_promptly_with_a_set_in_flight() {
    netns::in_private_netns_alone(
        INNER,
        "node_shutdown::node_stops_promptly_with_a_set_in_flight",
        || {
            stop_in_flight();
        },
    );
}

/// The node's stderr, line by line, as it comes, echoed to the test's stderr.
struct NodeLog {
    lines: Vec<String>,
    rx: Receiver<String>,
}

impl NodeLog {
    /// Starts `command` with its stderr piped; headless: no `XDG_RUNTIME_DIR`, no
    /// `ROS_DISTRO` (the node must not need either to be quiet).
    fn start(mut command: Command) -> (NodeProcess, NodeLog) {
        command
            .env_remove("XDG_RUNTIME_DIR")
            .env_remove("ROS_DISTRO")
            .env_remove("NODEVICE_SELECT")
            .stderr(Stdio::piped());
        let mut node = NodeProcess::spawn(command);
        let stderr = node.take_stderr();
        let (tx, rx) = std::sync::mpsc::channel::<String>();
        // Ends when the node's stderr closes (the node exited).
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                eprintln!("[node] {line}");
                let _ = tx.send(line);
            }
        });
        (
            node,
            NodeLog {
                lines: Vec::new(),
                rx,
            },
        )
    }

    /// Takes what has arrived.
    fn poll(&mut self) {
        while let Ok(line) = self.rx.try_recv() {
            self.lines.push(line);
        }
    }

    fn count(&self, needle: &str) -> usize {
        self.lines.iter().filter(|l| l.contains(needle)).count()
    }

    /// Waits until `count` lines contain `needle` (the node alive all along).
    fn wait_for(&mut self, needle: &str, count: usize, node: &mut NodeProcess) {
        let limit = dds::timeout();
        let started = Instant::now();
        while self.count(needle) < count {
            node.check_alive();
            assert!(
                started.elapsed() < limit,
                "waited {limit:?} for {count} log line(s) with '{needle}': {:?}",
                self.lines
            );
            match self.rx.recv_timeout(Duration::from_millis(20)) {
                Ok(line) => self.lines.push(line),
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => {
                    panic!(
                        "the node exited while waiting for '{needle}': {:?}",
                        self.lines
                    )
                }
            }
        }
    }

    /// Every remaining line, up to the end of the node's stderr (after it exited).
    fn drain(&mut self, what: &str) {
        loop {
            match self.rx.recv_timeout(stop_limit()) {
                Ok(line) => self.lines.push(line),
                Err(RecvTimeoutError::Disconnected) => break,
                Err(RecvTimeoutError::Timeout) => {
                    panic!(
                        "{what}: the node's stderr did not close within {:?} after it exited",
                        stop_limit()
                    )
                }
            }
        }
    }

    /// No line at ERROR level, no library's "error: ..." line (libwayland's XDG_RUNTIME_DIR
    /// complaint), no ROS_DISTRO warning.
    fn assert_quiet(&self, what: &str) {
        let noisy: Vec<&String> = self
            .lines
            .iter()
            .filter(|l| {
                l.contains("ERROR")
                    || l.trim_start().to_ascii_lowercase().starts_with("error")
                    || (l.contains("WARN") && l.contains("ROS_DISTRO"))
            })
            .collect();
        assert!(
            noisy.is_empty(),
            "{what}: error lines in the log: {noisy:?}"
        );
    }
}

/// Sends SIG`signal`, waits for the exit; returns its status and how long it took.
fn signal_and_wait(node: &mut NodeProcess, signal: &str) -> (ExitStatus, Duration) {
    let status = Command::new("kill")
        .args([format!("-{signal}"), node.pid().to_string()])
        .status()
        .expect("kill");
    assert!(status.success());
    let sent = Instant::now();
    loop {
        if let Some(s) = node.try_wait() {
            return (s, sent.elapsed());
        }
        assert!(
            sent.elapsed() < stop_limit(),
            "SIG{signal}: the node did not stop within {:?}",
            stop_limit()
        );
        std::thread::sleep(Duration::from_millis(5));
    }
}

fn stop_idle(signal: &str, extra: &[&str]) {
    let mut args = vec!["-p", "cameras:=[a, b]"];
    args.extend(extra);
    let mut command = dds::node_command(45, &args);
    command.env("RUST_LOG", "warn,sweepdepth=info");
    let (mut node, mut log) = NodeLog::start(command);
    log.wait_for("is up", 1, &mut node);
    let (exit, took) = signal_and_wait(&mut node, signal);
    log.drain(signal);
    eprintln!("SIG{signal} ({extra:?}): stopped in {took:?}");
    assert!(
        exit.success(),
        "SIG{signal}: exit status {exit}; log: {:?}",
        log.lines
    );
    assert!(
        log.count("shutting down (signal received)") == 1,
        "SIG{signal}: {:?}",
        log.lines
    );
    log.assert_quiet(&format!("SIG{signal} {extra:?}"));
}

const WIDTH: u32 = 640;
const HEIGHT: u32 = 480;
const CAMERAS: usize = 4;
const STARTED: &str = "running the set stamped";

fn stamp_of(k: u32) -> Time {
    Time {
        sec: 1000 + k as i32,
        nanosec: 0,
    }
}

fn stop_in_flight() {
    let domain = 46;
    let model = CameraModel::pinhole(synthetic::intrinsics(WIDTH, HEIGHT));
    let rig = synthetic::row_rig(CAMERAS, 0.1, model, 1).expect("rig");
    let scene = Scene::wall_and_box(2.0, None, synthetic::intrinsics(WIDTH, HEIGHT).fx_px);
    let images = synthetic::render_rig(&scene, &rig);
    let mut command = dds::node_command(
        domain,
        &[
            "-p",
            "cameras:=[cam0, cam1, cam2, cam3]",
            "-p",
            "reference_camera:=cam1",
            "-p",
            "min_depth:=1.0",
            "-p",
            "max_depth:=4.0",
            "-p",
            "num_planes:=160",
            "-p",
            "camera_timeout:=0.0",
            "-p",
            "device:=cpu",
        ],
    );
    command.env("RUST_LOG", "warn,sweepdepth=debug");
    let (mut node, mut log) = NodeLog::start(command);
    let mut peer = Peer::new(domain, "sweepdepth_shutdown_peer");
    let feed = RigFeed::new(&mut peer, rig, &images, &dds::reliable(4), None);
    let depth = peer.subscription::<Image>("/depth/image", dds::IMAGE, &dds::reliable(10));

    // Set A: fed until the node says it started running one.
    let (_, first_k) = dds::feed_until(
        "the first set started",
        &mut node,
        0,
        |k| feed.publish_set(&[stamp_of(k); CAMERAS]),
        || {
            log.poll();
            (log.count(STARTED) > 0).then_some(())
        },
    );
    let a_started = Instant::now();
    // Set B waits in the slot while A runs; A's depth times one set.
    let b = first_k + 1;
    feed.publish_set(&[stamp_of(b); CAMERAS]);
    let a_depth = dds::wait_for("the depth of the first set", &mut node, || {
        dds::take_all(&depth).into_iter().next()
    });
    let one_set = a_started.elapsed();
    // B (or a later retransmitted set) starts; C waits in the slot behind it.
    log.wait_for(STARTED, 2, &mut node);
    let in_flight = log
        .lines
        .iter()
        .filter(|l| l.contains(STARTED))
        .nth(1)
        .cloned()
        .unwrap_or_default();
    feed.publish_set(&[stamp_of(b + 1); CAMERAS]);
    let (exit, took) = signal_and_wait(&mut node, "INT");
    log.drain("SIGINT with a set in flight");
    let late: Vec<Image> = dds::take_all(&depth);
    eprintln!(
        "one set: {one_set:?} (first depth stamped {:?}); in flight: '{in_flight}'; \
         stopped {took:?} after SIGINT",
        a_depth.header.stamp
    );
    assert!(exit.success(), "exit status {exit}; log: {:?}", log.lines);
    assert!(
        log.count("the set in flight was cancelled") == 1,
        "the running set was not cancelled: {:?}",
        log.lines
    );
    // Nothing after A: the set in flight was stopped, the pending one never started.
    assert!(
        late.iter().all(|m| m.header.stamp == a_depth.header.stamp),
        "depth published after the signal: {:?}",
        late.iter().map(|m| m.header.stamp).collect::<Vec<_>>()
    );
    assert_eq!(log.count(STARTED), 2, "{:?}", log.lines);
    let bound = PROMPT.max(one_set / 2);
    assert!(
        took <= bound,
        "the node took {took:?} to stop with a set in flight (bound {bound:?}: 2 s, or half \
         of one set, {one_set:?}, where a set takes longer)"
    );
    log.assert_quiet("SIGINT with a set in flight");
}
