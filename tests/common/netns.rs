//! The DDS safety guard shared by the DDS tests: no DDS packet may leave the machine, so a test
//! that opens DDS runs its body only inside a private network namespace with nothing but
//! loopback. Outside one, the test re-executes its own binary (only that test) under
//! `unshare -n` (`-rn` when not root) with loopback up and a multicast route on `lo`, marked by
//! an environment variable; inside, it refuses to open anything unless `/proc/self/net/dev`
//! lists only `lo`.
//!
//! The outer test passes only if the inner run exited successfully AND the body of exactly that
//! test ran to its end: the inner run writes the test's name into a file the outer one names
//! ([`DONE_FILE`]) after the body returns. A test renamed without updating the name it passes
//! here would otherwise run zero tests inside the namespace and pass.

use std::path::PathBuf;
use std::process::{Child, Command};
use std::sync::{PoisonError, RwLock};

/// The environment variable naming the file the inner run writes when the body has finished.
pub const DONE_FILE: &str = "SWEEPDEPTH_TEST_NETNS_DONE_FILE";

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
/// `marker`; from anywhere else re-executes the test `test_name` (which must be the name of the
/// calling test as libtest names it: in a test binary of several files, `file::test`) inside a
/// new one and checks that exactly that test's body ran to its end.
pub fn in_private_netns(marker: &str, test_name: &str, body: impl FnOnce()) {
    let _shared = ALONE.read().unwrap_or_else(PoisonError::into_inner);
    run_in_private_netns(marker, test_name, body);
}

/// [`in_private_netns`] with no other DDS test of this binary running beside it: for a test
/// whose assertion compares times taken in one run (a delivery bound, a stop judged against one
/// set's time), which ran alone when it was a binary of its own. The others wait (and this one
/// waits for those running); only tests that go through these two functions are held.
pub fn in_private_netns_alone(marker: &str, test_name: &str, body: impl FnOnce()) {
    let _alone = ALONE.write().unwrap_or_else(PoisonError::into_inner);
    run_in_private_netns(marker, test_name, body);
}

/// Held shared by every DDS test's run in this process, exclusively by the ones that run alone.
/// Inside the namespace the run is one test, so it holds nothing back there.
static ALONE: RwLock<()> = RwLock::new(());

fn run_in_private_netns(marker: &str, test_name: &str, body: impl FnOnce()) {
    // libtest names the thread of a test after it (the main thread with one test thread).
    if let Some(thread) = std::thread::current().name() {
        assert!(
            thread == "main" || thread == test_name,
            "in_private_netns was given the name '{test_name}' but runs in the test '{thread}': pass the test's own name"
        );
    }
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
    if let Some(done) = std::env::var_os(DONE_FILE) {
        std::fs::write(&done, test_name).unwrap_or_else(|e| {
            panic!(
                "cannot write the completion marker {}: {e}",
                PathBuf::from(&done).display()
            )
        });
    }
}

fn reexec_in_private_netns(marker: &str, test_name: &str) {
    let exe = std::env::current_exe().expect("test binary path");
    let flags = if is_root() { "-n" } else { "-rn" };
    let done = std::env::temp_dir().join(format!(
        "sweepdepth-netns-done-{}-{test_name}",
        std::process::id()
    ));
    let _ = std::fs::remove_file(&done);
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
        .env(DONE_FILE, &done)
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
    let ran = std::fs::read_to_string(&done);
    let _ = std::fs::remove_file(&done);
    match ran {
        Ok(name) if name == test_name => {}
        Ok(name) => panic!(
            "inside the namespace the test '{name}' finished, not '{test_name}' (completion marker {})",
            done.display()
        ),
        Err(_) => panic!(
            "the run inside the namespace exited successfully but the body of '{test_name}' never finished there (no completion marker {}): no test of that exact name ran; pass the test's own name to in_private_netns",
            done.display()
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

/// A second "host" for the distributed tests (only some test binaries use it): a network namespace of its own (nested in the
/// test's private one, so nothing can leave the machine), joined to the test's namespace by a
/// veth pair with private addresses (10.77.0.1 here, 10.77.0.2 there); multicast (DDS
/// discovery) goes over the pair on both sides. Commands run there through [`Self::command`]
/// (`nsenter`). Only inside [`in_private_netns`]; the namespace goes with the holder process
/// when dropped.
#[allow(
    dead_code,
    reason = "a module shared by several test binaries: each uses a part of it"
)]
pub struct SecondHost {
    holder: KillOnDrop,
}

#[allow(
    dead_code,
    reason = "a module shared by several test binaries: each uses a part of it"
)]
impl SecondHost {
    /// The address of the test's own namespace on the pair, and the second host's.
    pub const HERE: &'static str = "10.77.0.1";
    pub const THERE: &'static str = "10.77.0.2";

    pub fn new(marker: &str) -> SecondHost {
        assert!(
            std::env::var_os(marker).is_some(),
            "a second host only inside the test's private network namespace"
        );
        let holder = Command::new("unshare")
            .args(["-n", "sleep", "100000"])
            .spawn()
            .expect("start the second host's namespace (unshare -n)");
        let host = SecondHost {
            holder: KillOnDrop(holder),
        };
        let pid = host.pid();
        let own = std::fs::read_link("/proc/self/ns/net").expect("own netns");
        let started = std::time::Instant::now();
        while std::fs::read_link(format!("/proc/{pid}/ns/net"))
            .ok()
            .as_ref()
            == Some(&own)
            || std::fs::read_link(format!("/proc/{pid}/ns/net")).is_err()
        {
            assert!(
                started.elapsed() < std::time::Duration::from_secs(60),
                "the second host's namespace did not appear"
            );
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        let pid_s = pid.to_string();
        let here = format!("{}/24", Self::HERE);
        let there = format!("{}/24", Self::THERE);
        run_ip(&[
            "link", "add", "veth_a", "type", "veth", "peer", "name", "veth_b", "netns", &pid_s,
        ]);
        run_ip(&["addr", "add", &here, "dev", "veth_a"]);
        run_ip(&["link", "set", "veth_a", "up", "multicast", "on"]);
        run_ip(&["route", "replace", "224.0.0.0/4", "dev", "veth_a"]);
        for args in [
            vec!["link", "set", "lo", "up"],
            vec!["addr", "add", there.as_str(), "dev", "veth_b"],
            vec!["link", "set", "veth_b", "up", "multicast", "on"],
            vec!["route", "add", "224.0.0.0/4", "dev", "veth_b"],
        ] {
            let status = host
                .command("ip")
                .args(&args)
                .status()
                .expect("run ip on the second host");
            assert!(status.success(), "ip {args:?} on the second host failed");
        }
        host
    }

    pub fn pid(&self) -> u32 {
        self.holder.0.id()
    }

    /// `program` run in the second host's network namespace.
    pub fn command(&self, program: &str) -> Command {
        let mut command = Command::new("nsenter");
        command
            .args(["-t", &self.pid().to_string(), "-n", "--"])
            .arg(program);
        command
    }
}

#[allow(
    dead_code,
    reason = "a module shared by several test binaries: each uses a part of it"
)]
fn run_ip(args: &[&str]) {
    let status = Command::new("ip").args(args).status().expect("run ip");
    assert!(status.success(), "ip {args:?} failed");
}
