//! The DDS safety guard shared by the DDS tests: no DDS packet may leave the machine, so a test
//! that opens DDS runs its body only inside a private network namespace with nothing but
//! loopback. Outside one, the test re-executes its own binary (only that test) under
//! `unshare -n` (`-rn` when not root) with loopback up and a multicast route on `lo`, marked by
//! an environment variable; inside, it refuses to open anything unless `/proc/self/net/dev`
//! lists only `lo`.
#![allow(dead_code)]

use std::process::{Child, Command};

/// Network interfaces of this process's network namespace (from /proc/self/net/dev).
pub fn interfaces() -> Vec<String> {
    std::fs::read_to_string("/proc/self/net/dev")
        .unwrap_or_default()
        .lines()
        .skip(2)
        .filter_map(|l| l.split(':').next().map(|s| s.trim().to_string()))
        .filter(|s| !s.is_empty())
        .collect()
}

fn is_root() -> bool {
    std::fs::read_to_string("/proc/self/status")
        .unwrap_or_default()
        .lines()
        .find(|l| l.starts_with("Uid:"))
        .and_then(|l| l.split_whitespace().nth(2))
        == Some("0")
}

/// Runs `body` only inside a private network namespace marked by the environment variable
/// `marker`; from anywhere else re-executes the test `test_name` inside a new one.
pub fn in_private_netns(marker: &str, test_name: &str, body: impl FnOnce()) {
    if std::env::var_os(marker).is_none() {
        reexec_in_private_netns(marker, test_name);
        return;
    }
    let ifaces = interfaces();
    assert!(
        ifaces == ["lo"],
        "refusing to open DDS: {marker} is set but this network namespace has interfaces {ifaces:?} (only lo allowed)"
    );
    body();
}

fn reexec_in_private_netns(marker: &str, test_name: &str) {
    let exe = std::env::current_exe().expect("test binary path");
    let flags = if is_root() { "-n" } else { "-rn" };
    let script = "ip link set lo up && ip link set lo multicast on && \
                  ip route add 224.0.0.0/4 dev lo && exec \"$0\" \"$@\"";
    let status = Command::new("unshare")
        .arg(flags)
        .args(["sh", "-c", script])
        .arg(&exe)
        .args([
            test_name,
            "--exact",
            "--include-ignored",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(marker, "1")
        .status();
    match status {
        Err(e) => panic!(
            "this test must run DDS in a private network namespace and cannot start `unshare {flags}` ({e}); install util-linux and iproute2 (and allow namespaces), it never runs DDS on the host network"
        ),
        Ok(s) => assert!(
            s.success(),
            "the DDS test {test_name} inside `unshare {flags}` failed ({s}); see its output above (if unshare itself failed, namespaces may be unavailable here)"
        ),
    }
}

/// Kills a child process (the node, a peer) on every exit path.
pub struct KillOnDrop(pub Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            let _ = self.0.kill();
        }
        let _ = self.0.wait();
    }
}
