//! The process's log: `tracing` to stderr, filtered by `RUST_LOG` (default
//! `warn,sweepdepth=info,rustdds=error`), with the DDS libraries' own lines rate-limited per
//! call site ([`RateLimitDds`]): RustDDS logs some warnings once per message (a large sample,
//! a late acknowledgement), which at camera rates would bury everything else. One RustDDS line
//! that says nothing wrong is dropped (`is_benign`).

use std::collections::HashMap;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use tracing::callsite::Identifier;
use tracing::{Event, Subscriber};
use tracing_subscriber::layer::{Context, SubscriberExt};
use tracing_subscriber::util::SubscriberInitExt;
use tracing_subscriber::Layer;

/// The targets whose lines are rate-limited: the DDS stack under ros2-client.
const DDS_TARGETS: [&str; 2] = ["rustdds", "ros2_client"];

/// At most one line per call site per this interval.
pub const DDS_LOG_INTERVAL: Duration = Duration::from_secs(10);

/// A layer that lets at most one event per call site of the DDS libraries through per
/// [`DDS_LOG_INTERVAL`] (any level); every other event passes untouched.
#[derive(Debug)]
pub struct RateLimitDds {
    last: Mutex<HashMap<SiteKey, Instant>>,
    /// [`DDS_LOG_INTERVAL`] (tests: longer than any test runs).
    interval: Duration,
}

impl Default for RateLimitDds {
    fn default() -> Self {
        RateLimitDds {
            last: Mutex::default(),
            interval: DDS_LOG_INTERVAL,
        }
    }
}

/// Where an event was made: its call site, or for a line of the `log` crate (RustDDS,
/// ros2-client), whose events share one call site per level, its file and line.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
enum SiteKey {
    Callsite(Identifier),
    Line(String, u32),
}

impl RateLimitDds {
    /// Whether an event of `target` from `site` at `now` may be logged.
    fn admit(&self, target: &str, id: SiteKey, now: Instant) -> bool {
        if !DDS_TARGETS
            .iter()
            .any(|t| target == *t || target.strip_prefix(t).is_some_and(|r| r.starts_with("::")))
        {
            return true;
        }
        let mut last = self.last.lock().unwrap_or_else(|e| e.into_inner());
        match last.get(&id) {
            Some(at) if now.duration_since(*at) < self.interval => false,
            _ => {
                last.insert(id, now);
                true
            }
        }
    }
}

impl<S: Subscriber> Layer<S> for RateLimitDds {
    fn event_enabled(&self, event: &Event<'_>, _ctx: Context<'_, S>) -> bool {
        use tracing_log::NormalizeEvent;
        let normalized = event.normalized_metadata();
        let (meta, site) = match &normalized {
            Some(meta) => {
                let file = meta.file().unwrap_or_default().to_string();
                (meta, SiteKey::Line(file, meta.line().unwrap_or_default()))
            }
            None => (
                event.metadata(),
                SiteKey::Callsite(event.metadata().callsite()),
            ),
        };
        if meta.target() == TOPIC_TYPES_TARGET {
            let mut message = Message(String::new());
            event.record(&mut message);
            if is_benign(&message.0) {
                return false;
            }
        }
        self.admit(meta.target(), site, Instant::now())
    }
}

/// Where RustDDS says one participant announced a topic with two types.
const TOPIC_TYPES_TARGET: &str = "rustdds::discovery::discovery_db";

/// RustDDS's "Inconsistent topic update" between `/clock`'s two types: an unpatched ros2-client
/// 0.12 process on the domain reads `/clock` as `builtin_interfaces/Time` in its spinner, the
/// node as `rosgraph_msgs/Clock` (`node::clock`; its own spinner's reader is off:
/// `vendor/ros2-client`). The same bytes either way, nothing to act on.
fn is_benign(message: &str) -> bool {
    message.starts_with("Inconsistent topic update")
        && message.contains("\"rosgraph_msgs::msg::dds_::Clock_\"")
        && message.contains("\"builtin_interfaces::msg::dds_::Time_\"")
}

/// An event's `message` field, formatted.
struct Message(String);

impl tracing::field::Visit for Message {
    fn record_debug(&mut self, field: &tracing::field::Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            self.0 = format!("{value:?}");
        }
    }
}

/// Whether the log colours its lines: on a terminal, unless `NO_COLOR` is set (no-color.org);
/// a log written to a file or a pipe (`2> log`, journald, a launch file's) holds no escape codes.
fn colours(stderr_is_terminal: bool, no_color: Option<std::ffi::OsString>) -> bool {
    stderr_is_terminal && no_color.is_none_or(|v| v.is_empty())
}

/// The log's filter where `RUST_LOG` sets none: this crate at `level` (an rcutils level name, a
/// node's `--log-level`; `info` when none), everything else at `warn` (RustDDS at `error`).
pub fn default_filter(level: Option<&str>) -> String {
    let ours = match level.map(str::to_ascii_lowercase).as_deref() {
        Some("debug") => "debug",
        Some("warn") => "warn",
        Some("error" | "fatal") => "error",
        _ => "info",
    };
    let others = if ours == "error" { "error" } else { "warn" };
    format!("{others},sweepdepth={ours},rustdds=error")
}

/// Installs the stderr log (once, in `main`): `RUST_LOG` where set, else
/// [`default_filter`] of `level` (a node's `--log-level`, `ros::args::node_log_level`).
pub fn init(level: Option<&str>) {
    use std::io::IsTerminal;
    let ansi = colours(
        std::io::stderr().is_terminal(),
        std::env::var_os("NO_COLOR"),
    );
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_filter(level)));
    tracing_subscriber::registry()
        .with(filter)
        .with(RateLimitDds::default())
        .with(
            tracing_subscriber::fmt::layer()
                .with_ansi(ansi)
                .with_writer(std::io::stderr),
        )
        .init();
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The filter a node's `--log-level` makes (`ros::args::node_log_level` reads the level).
    #[test]
    fn a_nodes_log_level_sets_the_filter() {
        assert_eq!(default_filter(None), "warn,sweepdepth=info,rustdds=error");
        assert_eq!(
            default_filter(Some("DEBUG")),
            "warn,sweepdepth=debug,rustdds=error"
        );
        assert_eq!(
            default_filter(Some("fatal")),
            "error,sweepdepth=error,rustdds=error"
        );
    }

    #[test]
    fn only_clocks_two_types_are_dropped() {
        let line = |a: &str, b: &str| {
            format!(
                "Inconsistent topic update from GUID {{01128384 EntityId::PARTICIPANT}}: type \
                 was: \"{a}\" new type: \"{b}\""
            )
        };
        let clock = "rosgraph_msgs::msg::dds_::Clock_";
        let time = "builtin_interfaces::msg::dds_::Time_";
        assert!(is_benign(&line(clock, time)));
        assert!(is_benign(&line(time, clock)));
        assert!(!is_benign(&line(clock, "sensor_msgs::msg::dds_::Image_")));
        assert!(!is_benign(&format!("something else {clock} {time}")));
    }

    #[test]
    fn colours_only_on_a_terminal_without_no_color() {
        assert!(colours(true, None));
        assert!(!colours(false, None));
        assert!(!colours(true, Some("1".into())));
        assert!(colours(true, Some("".into())));
    }

    /// Call sites are told apart by address: each has a byte, so two are never one.
    struct Site(
        #[expect(
            dead_code,
            reason = "call sites are told apart by address: the byte only gives each one"
        )]
        u8,
    );
    impl tracing::callsite::Callsite for Site {
        fn set_interest(&self, _: tracing::subscriber::Interest) {}
        fn metadata(&self) -> &tracing::Metadata<'_> {
            panic!("not called by the rate limiter")
        }
    }
    static SITE_A: Site = Site(0);

    #[test]
    fn dds_lines_are_rate_limited_per_call_site() {
        let limit = RateLimitDds::default();
        let a = || SiteKey::Callsite(Identifier(&SITE_A));
        let b = || SiteKey::Line("src/dds/pubsub.rs".into(), 10);
        let t0 = Instant::now();
        assert!(limit.admit("rustdds::network::udp_sender", a(), t0));
        assert!(!limit.admit(
            "rustdds::network::udp_sender",
            a(),
            t0 + Duration::from_secs(1)
        ));
        // Another call site has its own budget.
        assert!(limit.admit("rustdds::dds::pubsub", b(), t0 + Duration::from_secs(1)));
        assert!(limit.admit("rustdds::network::udp_sender", a(), t0 + DDS_LOG_INTERVAL));
        // Our own lines and other crates' are never limited.
        assert!(limit.admit("sweepdepth::node", a(), t0));
        assert!(limit.admit("sweepdepth::node", a(), t0));
        assert!(limit.admit("rustdds_like", a(), t0));
        assert!(limit.admit("rustdds_like", a(), t0));
    }
    /// Lines of the `log` crate (as RustDDS and ros2-client make them) through a subscriber
    /// with the layer: one per file and line per interval, each line its own budget, other
    /// crates' lines all through.
    #[test]
    fn log_crate_lines_are_limited_per_file_and_line() {
        use std::sync::atomic::{AtomicUsize, Ordering};
        use std::sync::Arc;
        struct Count(Arc<AtomicUsize>);
        impl<S: Subscriber> Layer<S> for Count {
            fn on_event(&self, _: &Event<'_>, _: Context<'_, S>) {
                self.0.fetch_add(1, Ordering::SeqCst);
            }
        }
        let seen = Arc::new(AtomicUsize::new(0));
        // A line is refused again however slowly the test runs.
        let limit = RateLimitDds {
            interval: Duration::MAX,
            ..RateLimitDds::default()
        };
        let subscriber = tracing_subscriber::registry()
            .with(limit)
            .with(Count(seen.clone()));
        let line = |target: &str, line: u32| {
            let record = tracing_log::log::Record::builder()
                .target(target)
                .level(tracing_log::log::Level::Warn)
                .file(Some("src/dds/with_key/datawriter.rs"))
                .line(Some(line))
                .args(format_args!("a warning"))
                .build();
            let before = seen.load(Ordering::SeqCst);
            tracing_log::format_trace(&record).expect("traced");
            seen.load(Ordering::SeqCst) > before
        };
        tracing::subscriber::with_default(subscriber, || {
            assert!(line("rustdds::dds::with_key::datawriter", 10));
            assert!(
                line("rustdds::dds::with_key::datawriter", 20),
                "another line"
            );
            assert!(!line("rustdds::dds::with_key::datawriter", 10), "again");
            assert!(!line("rustdds::dds::with_key::datawriter", 20), "again");
            assert!(line("ros2_client::node", 30));
            assert!(!line("ros2_client::node", 30), "ros2-client's too");
            assert!(line("wgpu_core::device", 10));
            assert!(
                line("wgpu_core::device", 10),
                "other crates' lines are not limited"
            );
        });
    }
}
