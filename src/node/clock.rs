//! The node's clock, an rcl node's ROS time: the system clock, or with `use_sim_time` the time
//! of the last `/clock` message (`rosgraph_msgs/Clock`, read best effort keep-last-1 as
//! rclcpp's `ClockQoS`; zero until the first, as in rcl). It stamps what the node makes of
//! itself (`/diagnostics`, `/rosout`, `/parameter_events`) and is the "now" of the latency in
//! `/diagnostics`; depth, the outputs and both nodes' meshes keep their inputs' stamps, and the node's timers (the diagnostics' second, "no depth" after 5 s,
//! `camera_timeout`) run on the monotonic clock whatever the parameter says.
//!
//! One clock per process (a process is one node), switched by the parameter at start and
//! through the parameter services at run time. As an rcl node's time source, a node reads
//! `/clock` only while `use_sim_time` is on (`sim_time.rs`).

use std::sync::atomic::{AtomicBool, AtomicI64, Ordering};
use std::task::Poll;

use futures::task::AtomicWaker;

use crate::msgs::{Clock, Time};

/// `use_sim_time`.
static SIMULATED: AtomicBool = AtomicBool::new(false);
/// The last `/clock` time in nanoseconds (0 before the first).
static LAST_NS: AtomicI64 = AtomicI64::new(0);
/// Wakes the waiter of [`switched_from`] when `use_sim_time` changes.
static SWITCHED: AtomicWaker = AtomicWaker::new();

/// The tests that switch the process's clock, one at a time.
#[cfg(test)]
pub(super) static TEST_SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Sets `use_sim_time`; true when it changed.
pub fn set_use_sim_time(on: bool) -> bool {
    let changed = SIMULATED.swap(on, Ordering::Relaxed) != on;
    if changed {
        SWITCHED.wake();
    }
    changed
}

/// `use_sim_time`.
pub fn uses_sim_time() -> bool {
    SIMULATED.load(Ordering::Relaxed)
}

/// Now: the last `/clock` time with `use_sim_time` (zero before the first), else the system
/// clock's.
pub fn now() -> Time {
    if uses_sim_time() {
        Time::from_nanos(LAST_NS.load(Ordering::Relaxed))
    } else {
        wall_time_now()
    }
}

/// The system clock now, as a ROS stamp.
pub fn wall_time_now() -> Time {
    let d = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default();
    Time {
        sec: i32::try_from(d.as_secs()).unwrap_or(i32::MAX),
        nanosec: d.subsec_nanos(),
    }
}

/// Takes a `/clock` message's time.
pub(super) fn on_clock(clock: &Clock) {
    LAST_NS.store(clock.clock.to_nanos(), Ordering::Relaxed);
}

/// Resolves once `use_sim_time` is no longer `on` (one waiter at a time: `sim_time::follow_clock`).
pub(super) async fn switched_from(on: bool) {
    futures::future::poll_fn(|cx| {
        SWITCHED.register(cx.waker());
        match uses_sim_time() != on {
            true => Poll::Ready(()),
            false => Poll::Pending,
        }
    })
    .await
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Both modes in one test: the clock is the process's.
    #[test]
    fn simulated_time_is_the_last_clock_message() {
        let _one = TEST_SERIAL.lock().unwrap_or_else(|e| e.into_inner());
        set_use_sim_time(false);
        on_clock(&Clock {
            clock: Time {
                sec: 1000,
                nanosec: 5,
            },
        });
        assert!(!set_use_sim_time(false), "off from the start");
        let wall = now().sec;
        assert!(wall > 1_700_000_000, "the system clock: {wall}");
        assert!(set_use_sim_time(true));
        assert_eq!(
            now(),
            Time {
                sec: 1000,
                nanosec: 5
            }
        );
        on_clock(&Clock {
            clock: Time {
                sec: 1001,
                nanosec: 0,
            },
        });
        assert_eq!(
            now(),
            Time {
                sec: 1001,
                nanosec: 0
            }
        );
        assert!(set_use_sim_time(false));
        assert!(now().sec >= wall);
    }
}
