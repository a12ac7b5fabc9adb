//! The node's log: stderr (tracing) and, once DDS is up, `/rosout`; warnings rate-limited
//! per key ([`RateLimited`]).

use std::collections::HashMap;
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use ros2_client::log::Log;
use ros2_client::{NodeLoggingHandle, RosoutRaw};

/// Minimum time between two repetitions of the same warning.
const LOG_INTERVAL: Duration = Duration::from_secs(2);

/// The node's `/rosout` writer and logger name (`ns.name`) once DDS is up.
pub(super) static ROSOUT: Mutex<Option<(NodeLoggingHandle, String)>> = Mutex::new(None);

pub(super) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Logs `msg` to stderr (tracing) and, when enabled at that level and DDS is up, to `/rosout`
/// (as the node `logger_name`).
pub(super) fn node_log(level: tracing::Level, msg: &str) {
    match level {
        tracing::Level::ERROR => tracing::error!("{msg}"),
        tracing::Level::WARN => tracing::warn!("{msg}"),
        tracing::Level::INFO => tracing::info!("{msg}"),
        _ => tracing::debug!("{msg}"),
    }
    let enabled = match level {
        tracing::Level::ERROR => tracing::enabled!(tracing::Level::ERROR),
        tracing::Level::WARN => tracing::enabled!(tracing::Level::WARN),
        tracing::Level::INFO => tracing::enabled!(tracing::Level::INFO),
        _ => false,
    };
    if !enabled {
        return;
    }
    let guard = lock(&ROSOUT);
    let Some((handle, name)) = guard.as_ref() else {
        return;
    };
    if let Some(writer) = handle.rosout_writer().as_ref() {
        let ros_level = match level {
            tracing::Level::ERROR => Log::ERROR,
            tracing::Level::WARN => Log::WARN,
            _ => Log::INFO,
        };
        // A failed rosout write is not worth a log line of its own (it would recurse).
        let _ = writer.publish(Log {
            stamp: ros2_client::builtin_interfaces::Time::from_nanos(
                super::clock::now().to_nanos(),
            ),
            level: ros_level,
            name: name.clone(),
            msg: msg.to_string(),
            file: file!().to_string(),
            function: String::new(),
            line: 0,
        });
    }
}

pub(super) fn log_info(msg: &str) {
    node_log(tracing::Level::INFO, msg);
}

/// Emits a warning per key at most once per [`LOG_INTERVAL`].
#[derive(Default)]
pub(super) struct RateLimited {
    last: HashMap<String, Instant>,
}

impl RateLimited {
    pub fn warn(&mut self, key: &str, message: impl FnOnce() -> String) {
        let now = Instant::now();
        if self
            .last
            .get(key)
            .is_some_and(|t| now.duration_since(*t) < LOG_INTERVAL)
        {
            return;
        }
        self.last.insert(key.to_string(), now);
        node_log(tracing::Level::WARN, &message());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rate_limited_suppresses_repeats() {
        let mut log = RateLimited::default();
        log.warn("k", || "first".into());
        let mut called = false;
        log.warn("k", || {
            called = true;
            String::new()
        });
        assert!(!called);
        log.warn("other", || {
            called = true;
            String::new()
        });
        assert!(called, "another key is not suppressed");
    }
}
