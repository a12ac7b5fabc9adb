//! Never silent (issue 34): while no depth comes out, the node says why, at most every
//! [`WARN_EVERY`] in the log (WARN, stderr and `/rosout`) and once a second as the status
//! message of `/diagnostics`. The pipeline names the first thing a set is missing
//! ([`Pipeline::why_no_depth`]); this adds what DDS discovery knows of the input topics (no
//! publisher at all; publishers whose QoS cannot match the subscription, naming both QoS) and
//! what happens after the pipeline (sets skipped by the engine, sets still running).

use std::sync::Mutex;
use std::time::{Duration, Instant};

use ros2_client::dds::rustdds::policy::{Durability, Reliability};
use ros2_client::dds::rustdds::DomainParticipant;

use super::diag::{Stats, STALE_AFTER};
use super::log::{lock, node_log};
use crate::pipeline::{Asked, Pipeline, Publishers};

/// The "no depth" warning repeats at most this often.
pub const WARN_EVERY: Duration = Duration::from_secs(5);

/// What a subscription of the node requests, for the check against discovered publishers.
#[derive(Debug, Clone)]
pub(super) struct Requested {
    /// The fully qualified topic name.
    pub topic: String,
    pub reliable: bool,
    pub transient_local: bool,
    /// What to change when a publisher cannot match (the parameter, or the publisher's side).
    pub hint: &'static str,
}

/// A discovered publisher's QoS.
#[derive(Debug, Clone, Copy)]
struct Offered {
    reliable: bool,
    transient_local: bool,
}

fn qos_words(reliable: bool, transient_local: bool) -> String {
    format!(
        "{}, {}",
        if reliable { "reliable" } else { "best-effort" },
        if transient_local {
            "transient-local"
        } else {
            "volatile"
        }
    )
}

/// DDS discovery of the input topics' publishers (RustDDS's discovered writers: topic and
/// QoS; the same rule as RustDDS's matching for reliability and durability).
pub(super) struct Discovery {
    participant: DomainParticipant,
    requested: Vec<Requested>,
}

impl Discovery {
    pub fn new(participant: DomainParticipant, requested: Vec<Requested>) -> Self {
        Self {
            participant,
            requested,
        }
    }

    /// A snapshot of the discovered publishers of the input topics.
    fn snapshot(&self) -> Vec<(String, Offered)> {
        self.participant
            .discovered_writers()
            .into_iter()
            .map(|w| {
                let data = w.publication_topic_data;
                // Absent policies are the DDS defaults of a writer: reliable, volatile.
                let reliable = !matches!(data.reliability, Some(Reliability::BestEffort));
                let transient_local = matches!(
                    data.durability,
                    Some(
                        Durability::TransientLocal | Durability::Transient | Durability::Persistent
                    )
                );
                (
                    data.topic_name,
                    Offered {
                        reliable,
                        transient_local,
                    },
                )
            })
            .collect()
    }

    /// What discovery knows of `topic`'s publishers, from `writers` (a [`Self::snapshot`]).
    fn publishers(&self, writers: &[(String, Offered)], topic: &str) -> Publishers {
        publishers(&self.requested, writers, topic)
    }
}

/// The DDS topic name of a fully qualified ROS topic (`/rig/cost/image` -> `rt/rig/cost/image`),
/// as discovery reports it.
pub(super) fn dds_topic_name(topic: &str) -> String {
    format!("rt/{}", topic.trim_start_matches('/'))
}

/// What `writers` (DDS topic name and QoS) say of `topic`'s publishers, for the subscriptions
/// `requested`; for a topic the node does not subscribe (the other image transport's), whether
/// it has publishers at all (`Matched(n)`: n of any QoS).
fn publishers(requested: &[Requested], writers: &[(String, Offered)], topic: &str) -> Publishers {
    let dds_name = dds_topic_name(topic);
    let Some(requested) = requested.iter().find(|r| r.topic == topic) else {
        return match writers.iter().filter(|(name, _)| *name == dds_name).count() {
            0 => Publishers::None,
            n => Publishers::Matched(n),
        };
    };
    let offered: Vec<Offered> = writers
        .iter()
        .filter(|(name, _)| *name == dds_name)
        .map(|(_, o)| *o)
        .collect();
    let fits = |o: &Offered| {
        (o.reliable || !requested.reliable) && (o.transient_local || !requested.transient_local)
    };
    match offered.iter().filter(|o| fits(o)).count() {
        0 => match offered.first() {
            None => Publishers::None,
            Some(o) => Publishers::Incompatible(format!(
                "{} publisher{} offer{} {}, the node requests {}{}",
                offered.len(),
                if offered.len() == 1 { "" } else { "s" },
                if offered.len() == 1 { "s" } else { "" },
                qos_words(o.reliable, o.transient_local),
                qos_words(requested.reliable, requested.transient_local),
                if requested.hint.is_empty() {
                    String::new()
                } else {
                    format!(" ({})", requested.hint)
                }
            )),
        },
        n => Publishers::Matched(n),
    }
}

/// Says why no depth comes out (the diagnostics thread asks once a second).
pub(super) struct NoDepth<'a> {
    pub pipeline: &'a Mutex<Pipeline<'a>>,
    /// The pipeline's clock (receive time since the event loop started).
    pub started: Instant,
    pub discovery: Discovery,
    last_warned: Option<Instant>,
}

impl<'a> NoDepth<'a> {
    pub fn new(pipeline: &'a Mutex<Pipeline<'a>>, started: Instant, discovery: Discovery) -> Self {
        Self {
            pipeline,
            started,
            discovery,
            last_warned: None,
        }
    }

    /// While no depth was published in the last [`STALE_AFTER`] (and the node has been up
    /// that long, time for discovery): why, in `stats.why` for `/diagnostics`, and a WARN line
    /// at most every [`WARN_EVERY`]. Nothing once depth flows.
    pub fn check(&mut self, stats: &Mutex<Stats>, now: Instant) {
        let up = now.saturating_duration_since(self.started) >= STALE_AFTER;
        let (stale, engine_skip) = {
            let stats = lock(stats);
            (stats.stale(now), stats.engine_skip.clone())
        };
        if !stale || !up {
            lock(stats).why = None;
            if !stale {
                self.last_warned = None;
            }
            return;
        }
        let why = self.explain(now, engine_skip);
        if self
            .last_warned
            .is_none_or(|t| now.saturating_duration_since(t) >= WARN_EVERY)
        {
            self.last_warned = Some(now);
            node_log(tracing::Level::WARN, &format!("no depth: {why}"));
        }
        lock(stats).why = Some(why);
    }

    fn explain(&self, now: Instant, engine_skip: Option<String>) -> String {
        let writers = self.discovery.snapshot();
        let peers = |topic: &str| self.discovery.publishers(&writers, topic);
        let asked = Asked {
            now_ns: u64::try_from(now.saturating_duration_since(self.started).as_nanos())
                .unwrap_or(u64::MAX),
            window_ns: u64::try_from(STALE_AFTER.as_nanos()).ok(),
        };
        let why = lock(self.pipeline).why_no_depth(asked, &peers);
        match (why, engine_skip) {
            (Some(why), _) => why.message,
            (None, Some(skip)) => format!("sets are skipped: {skip}"),
            (None, None) => {
                "sets are ready but none has been published yet (the engine is still at work)"
                    .to_string()
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn discovery_names_missing_and_incompatible_publishers() {
        let requested = vec![
            Requested {
                topic: "/rig/cam0/image_raw".into(),
                reliable: true,
                transient_local: false,
                hint: "a best-effort camera driver needs input_qos_reliable:=false",
            },
            Requested {
                topic: "/tf_static".into(),
                reliable: true,
                transient_local: true,
                hint: "",
            },
        ];
        let offered = |reliable, transient_local| Offered {
            reliable,
            transient_local,
        };
        let writers = vec![
            ("rt/rig/cam0/image_raw".to_string(), offered(false, false)),
            ("rt/tf_static".to_string(), offered(true, true)),
            ("rt/tf_static".to_string(), offered(true, false)),
        ];
        assert_eq!(
            publishers(&requested, &writers, "/rig/cam0/image_raw"),
            Publishers::Incompatible(
                "1 publisher offers best-effort, volatile, the node requests reliable, volatile (a best-effort camera driver needs input_qos_reliable:=false)".into()
            )
        );
        assert_eq!(
            publishers(&requested, &writers, "/tf_static"),
            Publishers::Matched(1)
        );
        assert_eq!(
            publishers(&requested, &writers[..1], "/tf_static"),
            Publishers::None
        );
        assert_eq!(
            publishers(&requested, &writers[2..], "/tf_static"),
            Publishers::Incompatible(
                "1 publisher offers reliable, volatile, the node requests reliable, transient-local"
                    .into()
            )
        );
        // A topic the node does not subscribe: whether it has publishers at all.
        assert_eq!(publishers(&requested, &writers, "/other"), Publishers::None);
        assert_eq!(
            publishers(&requested, &writers, "/rig/cam0/image_raw/compressed"),
            Publishers::None
        );
        let compressed = [(
            "rt/rig/cam0/image_raw/compressed".to_string(),
            offered(false, false),
        )];
        assert_eq!(
            publishers(&requested, &compressed, "/rig/cam0/image_raw/compressed"),
            Publishers::Matched(1)
        );
    }
}
