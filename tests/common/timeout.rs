//! The one limit of every wait in the tests: `SWEEPDEPTH_TEST_TIMEOUT_S`, default 300 s. A
//! working system answers in seconds even on a slow, loaded machine; the limit only bounds how
//! long a broken one takes to fail. A module of common (dds.rs and rclpy.rs use it); included
//! alone with `#[path]` where a test binary takes only a few common files (house/colcon.rs).
#![allow(
    dead_code,
    reason = "a module shared by several test binaries: each uses a part of it"
)]

use std::time::Duration;

/// `SWEEPDEPTH_TEST_TIMEOUT_S` seconds, default 300 (also when it does not parse).
pub fn test_timeout() -> Duration {
    let seconds = std::env::var("SWEEPDEPTH_TEST_TIMEOUT_S")
        .ok()
        .and_then(|s| s.parse::<u64>().ok())
        .unwrap_or(300);
    Duration::from_secs(seconds)
}
