//! `sweepdepth node` ends cleanly on SIGINT and SIGTERM (as `ros2 launch` stops it): exit status
//! 0 and a log line. How long it may take is bounded generously (a stuck node fails; a slow
//! machine does not).
//!
//! SAFETY: DDS only inside the private network namespace of tests/common/netns.rs.

mod common;

use std::io::{BufRead, BufReader};
use std::process::Stdio;
use std::sync::mpsc::RecvTimeoutError;
use std::time::{Duration, Instant};

use common::dds;
use common::netns::{self, KillOnDrop};

const INNER: &str = "SWEEPDEPTH_TEST_PRIVATE_NETNS";
/// An idle node stops in well under a second; one that takes this long is stuck.
const STOP_LIMIT: Duration = Duration::from_secs(60);

#[test]
fn node_stops_cleanly_on_sigint_and_sigterm() {
    netns::in_private_netns(INNER, "node_stops_cleanly_on_sigint_and_sigterm", || {
        for signal in ["INT", "TERM"] {
            stop_with(signal);
        }
    });
}

fn stop_with(signal: &str) {
    let mut command = dds::node_command(45, &["-p", "cameras:=[a, b]"]);
    command
        .env("RUST_LOG", "warn,sweepdepth=info")
        .stderr(Stdio::piped());
    let mut node = KillOnDrop(command.spawn().expect("start the node"));
    let stderr = node.0.stderr.take().expect("stderr");
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    // Ends when the node's stderr closes (the node exited).
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            eprintln!("[node] {line}");
            let _ = tx.send(line);
        }
    });
    let mut log = Vec::new();
    let limit = dds::timeout();
    let started = Instant::now();
    while !log.iter().any(|l: &String| l.contains("is up")) {
        assert!(
            started.elapsed() < limit,
            "the node did not come up within {limit:?}: {log:?}"
        );
        match rx.recv_timeout(Duration::from_millis(100)) {
            Ok(line) => log.push(line),
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => {
                panic!("the node exited before it was up: {log:?}")
            }
        }
    }
    let status = std::process::Command::new("kill")
        .args([format!("-{signal}"), node.0.id().to_string()])
        .status()
        .expect("kill");
    assert!(status.success());
    let stopped = Instant::now();
    let exit = loop {
        if let Some(s) = node.0.try_wait().expect("wait") {
            break s;
        }
        assert!(
            stopped.elapsed() < STOP_LIMIT,
            "SIG{signal}: the node did not stop within {STOP_LIMIT:?}"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    // Every line the node wrote, up to the end of its stderr.
    loop {
        match rx.recv_timeout(STOP_LIMIT) {
            Ok(line) => log.push(line),
            Err(RecvTimeoutError::Disconnected) => break,
            Err(RecvTimeoutError::Timeout) => {
                panic!("SIG{signal}: the node's stderr did not close within {STOP_LIMIT:?} after it exited")
            }
        }
    }
    assert!(
        exit.success(),
        "SIG{signal}: exit status {exit}; log: {log:?}"
    );
    assert!(
        log.iter()
            .any(|l| l.contains("shutting down (signal received)")),
        "SIG{signal}: {log:?}"
    );
}
