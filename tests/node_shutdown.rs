//! `sweepdepth node` ends cleanly on SIGINT and SIGTERM (as `ros2 launch` stops it): exit status
//! 0 and a log line, within seconds.
//!
//! SAFETY: DDS only inside the private network namespace of tests/common/netns.rs.

#[path = "common/netns.rs"]
mod netns;

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const INNER: &str = "SWEEPDEPTH_TEST_PRIVATE_NETNS";

#[test]
fn node_stops_cleanly_on_sigint_and_sigterm() {
    netns::in_private_netns(INNER, "node_stops_cleanly_on_sigint_and_sigterm", || {
        for signal in ["INT", "TERM"] {
            stop_with(signal);
        }
    });
}

fn stop_with(signal: &str) {
    let mut node = Command::new(env!("CARGO_BIN_EXE_sweepdepth"))
        .args(["node", "--ros-args", "-p", "cameras:=[a, b]"])
        .env("ROS_DOMAIN_ID", "45")
        .env("RUST_LOG", "warn,sweepdepth=info")
        .stdin(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start the node");
    let stderr = node.stderr.take().expect("stderr");
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let mut log = Vec::new();
    let started = Instant::now();
    while !log.iter().any(|l: &String| l.contains("is up")) {
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "the node did not come up: {log:?}"
        );
        if let Ok(line) = rx.recv_timeout(Duration::from_millis(100)) {
            log.push(line);
        }
    }
    let status = Command::new("kill")
        .args([format!("-{signal}"), node.id().to_string()])
        .status()
        .expect("kill");
    assert!(status.success());
    let stopped = Instant::now();
    let exit = loop {
        if let Some(s) = node.try_wait().expect("wait") {
            break s;
        }
        if stopped.elapsed() > Duration::from_secs(10) {
            let _ = node.kill();
            panic!("SIG{signal}: the node did not stop within 10 s");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    while let Ok(line) = rx.recv_timeout(Duration::from_millis(200)) {
        log.push(line);
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
