//! Running `tools/rclpy_peer.py` (the real rcl stack: rclpy over rmw_fastrtps_cpp) through
//! `tools/ros_python`, reading its `RCLPY_PEER {json}` lines.
//!
//! Every Python process started here runs under a limit: [`require_rclpy`] under the one limit
//! [`test_timeout`] (`SWEEPDEPTH_TEST_TIMEOUT_S`, default 300 s), a [`Peer`] for as long as the
//! test waits on it ([`Peer::wait_for`] takes the limit; pass [`test_timeout`]), and a `Peer` is
//! killed when dropped, on every exit path of the test, a panic included.
#![allow(
    dead_code,
    reason = "a module shared by several test binaries: each uses a part of it"
)]

use std::io::{BufRead, BufReader, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{ChildStdin, Command, Output, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use serde_json::Value;

use super::netns::KillOnDrop;
use super::python::INSTALL_HINT;

pub use super::timeout::test_timeout;

pub const PREFIX: &str = "RCLPY_PEER ";

pub fn repo() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

pub fn launcher() -> PathBuf {
    repo().join("tools/ros_python")
}

pub fn peer_script() -> PathBuf {
    repo().join("tools/rclpy_peer.py")
}

/// Runs `command` to its end with its stdout and stderr collected, as `Command::output` does,
/// but kills it and panics (naming `what`) when it has not exited within `limit`.
pub fn output_within(
    command: &mut Command,
    limit: Duration,
    what: &str,
) -> std::io::Result<Output> {
    let mut child = command
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()?;
    let collect = |pipe: Option<Box<dyn Read + Send>>| {
        std::thread::spawn(move || {
            let mut bytes = Vec::new();
            if let Some(mut pipe) = pipe {
                let _ = pipe.read_to_end(&mut bytes);
            }
            bytes
        })
    };
    let stdout = collect(
        child
            .stdout
            .take()
            .map(|p| Box::new(p) as Box<dyn Read + Send>),
    );
    let stderr = collect(
        child
            .stderr
            .take()
            .map(|p| Box::new(p) as Box<dyn Read + Send>),
    );
    let mut child = KillOnDrop(child);
    let deadline = Instant::now() + limit;
    let status = loop {
        if let Some(status) = child.0.try_wait()? {
            break status;
        }
        assert!(
            Instant::now() < deadline,
            "{what} did not finish within {limit:?} (SWEEPDEPTH_TEST_TIMEOUT_S); killed it"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    Ok(Output {
        status,
        stdout: stdout.join().unwrap_or_default(),
        stderr: stderr.join().unwrap_or_default(),
    })
}

/// Fails (never skips) when rclpy cannot be imported through the launcher's Python (within
/// [`test_timeout`]).
pub fn require_rclpy() {
    let out = output_within(
        Command::new(super::python::python()).args([
            "-c",
            "import rclpy, sensor_msgs.msg, rcl_interfaces.srv, diagnostic_msgs.msg",
        ]),
        test_timeout(),
        "importing rclpy",
    );
    match out {
        Err(e) => panic!("this test needs Python with rclpy (ROS 2 Jazzy wheels) and cannot start it ({e}); {INSTALL_HINT}"),
        Ok(o) if !o.status.success() => panic!(
            "this test needs rclpy (the ROS 2 Jazzy wheels of tools/requirements-ros.txt), which Python cannot import; run `sh scripts/setup.sh`. Python said:\n{}",
            String::from_utf8_lossy(&o.stderr)
        ),
        Ok(_) => {}
    }
}

/// A running `rclpy_peer.py` with its result lines on a channel; killed when dropped.
pub struct Peer {
    pub name: String,
    pub child: KillOnDrop,
    pub stdin: Option<ChildStdin>,
    lines: mpsc::Receiver<Value>,
}

impl Peer {
    /// Starts `rclpy_peer.py args...` on `domain` with extra environment `env`.
    pub fn start(name: &str, domain: &str, args: &[&str], env: &[(&str, &str)]) -> Peer {
        let mut cmd = Command::new(launcher());
        cmd.arg("-u")
            .arg(peer_script())
            .args(args)
            .env("ROS_DOMAIN_ID", domain)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped());
        for (k, v) in env {
            cmd.env(k, v);
        }
        let mut child = cmd.spawn().unwrap_or_else(|e| {
            panic!("start the rclpy peer ({name}) through tools/ros_python: {e}")
        });
        let stdout = child.stdout.take().expect("peer stdout");
        let stdin = child.stdin.take();
        let (tx, rx) = mpsc::channel();
        let tag = name.to_string();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                match line.strip_prefix(PREFIX) {
                    Some(json) => match serde_json::from_str::<Value>(json) {
                        Ok(v) => {
                            if tx.send(v).is_err() {
                                return;
                            }
                        }
                        Err(e) => eprintln!("[{tag}] unparsable result line ({e}): {line}"),
                    },
                    None => eprintln!("[{tag}] {line}"),
                }
            }
        });
        Peer {
            name: name.to_string(),
            child: KillOnDrop(child),
            stdin,
            lines: rx,
        }
    }

    /// Sends one command line on the peer's stdin.
    pub fn command(&mut self, line: &str) {
        let stdin = self.stdin.as_mut().expect("peer stdin");
        writeln!(stdin, "{line}")
            .and_then(|_| stdin.flush())
            .unwrap_or_else(|e| panic!("write to the rclpy peer ({}): {e}", self.name));
    }

    /// The next result line for which `want` is true, within `timeout`; other lines are
    /// passed to `other`. Panics with `what` on timeout or when the peer exits.
    pub fn wait_for(
        &mut self,
        timeout: Duration,
        what: &str,
        want: impl FnMut(&Value) -> bool,
        other: impl FnMut(&Value),
    ) -> Value {
        self.try_wait_for(timeout, what, want, other)
            .unwrap_or_else(|| {
                panic!(
                    "the rclpy peer ({}) gave no {what} within {timeout:?}",
                    self.name
                )
            })
    }

    /// As [`Peer::wait_for`], but `None` on timeout (it still panics when the peer exits).
    pub fn try_wait_for(
        &mut self,
        timeout: Duration,
        what: &str,
        mut want: impl FnMut(&Value) -> bool,
        mut other: impl FnMut(&Value),
    ) -> Option<Value> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self
                .lines
                .recv_timeout(left.min(Duration::from_millis(200)))
            {
                Ok(v) if want(&v) => return Some(v),
                Ok(v) => other(&v),
                Err(mpsc::RecvTimeoutError::Timeout) => {
                    if let Ok(Some(status)) = self.child.0.try_wait() {
                        panic!("the rclpy peer ({}) exited ({status}) while waiting for {what}; see its output above", self.name);
                    }
                    if Instant::now() >= deadline {
                        return None;
                    }
                }
                Err(mpsc::RecvTimeoutError::Disconnected) => {
                    // It closed its output: it is exiting. Its status, within what is left of
                    // the limit (the peer is killed when dropped in any case).
                    let status = loop {
                        match self.child.0.try_wait() {
                            Ok(Some(status)) => break format!("{status}"),
                            Ok(None) if Instant::now() < deadline => {
                                std::thread::sleep(Duration::from_millis(20))
                            }
                            Ok(None) => break "still running".to_string(),
                            Err(e) => break format!("{e}"),
                        }
                    };
                    panic!("the rclpy peer ({}) closed its output ({status}) while waiting for {what}; see its output above", self.name);
                }
            }
        }
    }

    /// Result lines already received, without waiting.
    pub fn drain(&mut self) -> Vec<Value> {
        self.lines.try_iter().collect()
    }
}

/// The event name of a result line.
pub fn event(v: &Value) -> &str {
    v["event"].as_str().unwrap_or("")
}
