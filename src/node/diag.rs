//! Run-time statistics of the node ([`Stats`]: input rates, the synchroniser's verdicts
//! counted, GPU drops, processing time, latency), the `/diagnostics` message built from them
//! (unit-tested). The thread that publishes it once a second is `dds.rs`'s: it adds why no depth
//! comes out (`why.rs`) and fusion's lines, which build on these statistics.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use crate::msgs::{DiagnosticArray, DiagnosticStatus, Header, KeyValue, Time};
use crate::ros::sync::SyncStats;

/// Window of the input rates.
pub const RATE_WINDOW: Duration = Duration::from_secs(1);
/// No set published for this long makes the status WARN.
pub const STALE_AFTER: Duration = Duration::from_secs(5);

/// Counters shared by the executor (inputs, the synchroniser's verdicts), the GPU worker
/// (processing, publishing) and the diagnostics publisher.
#[derive(Debug)]
pub struct Stats {
    /// Arrival times of the images of each camera within the last [`RATE_WINDOW`].
    arrivals: Vec<VecDeque<Instant>>,
    /// The synchroniser's verdicts, counted ([`crate::pipeline::SyncVerdict::count`]).
    pub sync: SyncStats,
    pub gpu_dropped: u64,
    /// Sets dropped for newer ones while waiting to be sent (`super::sender`).
    pub send_dropped: u64,
    pub published: u64,
    last_published: Option<Instant>,
    last_processing: Option<Duration>,
    total_processing: Duration,
    /// The node's time ([`super::clock`]) at publication minus the stamp of the set,
    /// milliseconds (none while simulated time has had no `/clock`).
    last_latency_ms: Option<f64>,
    /// Cameras out of the rig (silent longer than `camera_timeout`).
    pub inactive_cameras: Vec<String>,
    /// Why no set is formed while those cameras leave no reference or fewer than two
    /// ([`crate::pipeline::Pipeline::halted`]).
    pub halted: Option<String>,
    /// Sets (or, with several references, one reference of a set) that gave no depth, by
    /// reason ([`crate::pipeline::SkipKind::label`]).
    pub skipped: crate::pipeline::SkipCounts,
    /// Sets waiting for their pose in `world_frame`.
    pub waiting_for_pose: usize,
    /// A moving rig: the latest world pose of each reference's frame, with its stamp.
    pub world_poses: std::collections::BTreeMap<String, (Time, crate::geometry::RigidTransform)>,
    /// Why no depth comes out, while none does (`super::why`): the status message says it.
    pub why: Option<String>,
    /// The engine's last skip (a set that gave no depth after the pipeline).
    pub engine_skip: Option<String>,
    /// The outputs made on demand (`super::demand`) in the last set published.
    pub made_on_demand: crate::pipeline::Wanted,
    /// The most sets on the engine at once: 2 where a set came while the one before was on
    /// the WGSL engine's device and went onto it too.
    pub most_in_flight: usize,
}

impl Stats {
    pub fn new(cameras: usize) -> Self {
        Self {
            arrivals: vec![VecDeque::new(); cameras],
            sync: SyncStats::default(),
            gpu_dropped: 0,
            send_dropped: 0,
            published: 0,
            last_published: None,
            last_processing: None,
            total_processing: Duration::ZERO,
            last_latency_ms: None,
            inactive_cameras: Vec::new(),
            halted: None,
            skipped: Default::default(),
            waiting_for_pose: 0,
            world_poses: Default::default(),
            why: None,
            engine_skip: None,
            made_on_demand: crate::pipeline::Wanted::NONE,
            most_in_flight: 0,
        }
    }

    /// No set published in the last [`STALE_AFTER`] (or none yet).
    pub fn stale(&self, now: Instant) -> bool {
        self.last_published
            .is_none_or(|t| now.saturating_duration_since(t) > STALE_AFTER)
    }

    fn prune(&mut self, now: Instant) {
        for q in &mut self.arrivals {
            while q
                .front()
                .is_some_and(|t| now.saturating_duration_since(*t) > RATE_WINDOW)
            {
                q.pop_front();
            }
        }
    }

    /// An image of camera `i` arrived at `now`.
    pub fn on_image(&mut self, i: usize, now: Instant) {
        if let Some(q) = self.arrivals.get_mut(i) {
            q.push_back(now);
        }
        self.prune(now);
    }

    /// A set was processed in `processing` and is handed to its publishers at `now`, at
    /// `now_ros` on the node's clock (zero: simulated time before the first `/clock`, no
    /// latency).
    pub fn on_published(&mut self, processing: Duration, now: Instant, now_ros: Time, stamp: Time) {
        self.published += 1;
        self.last_published = Some(now);
        self.last_processing = Some(processing);
        self.total_processing += processing;
        self.last_latency_ms = (now_ros != Time::default())
            .then(|| now_ros.to_nanos().saturating_sub(stamp.to_nanos()) as f64 / 1e6);
    }

    /// Images per second of each camera over the last [`RATE_WINDOW`].
    pub fn input_rates(&mut self, now: Instant) -> Vec<f64> {
        self.prune(now);
        let window = RATE_WINDOW.as_secs_f64();
        self.arrivals
            .iter()
            .map(|q| q.len() as f64 / window)
            .collect()
    }

    /// Mean processing time, or None before the first set.
    pub fn mean_processing(&self) -> Option<Duration> {
        u32::try_from(self.published)
            .ok()
            .filter(|n| *n > 0)
            .map(|n| self.total_processing / n)
    }

    /// The diagnostics of the node `fqn` at `now` (`stamp` is the header stamp).
    pub fn diagnostics(
        &mut self,
        fqn: &str,
        cameras: &[String],
        adapter: &str,
        now: Instant,
        stamp: Time,
    ) -> DiagnosticArray {
        let rates = self.input_rates(now);
        let ms = |d: Option<Duration>| {
            d.map_or("n/a".to_string(), |d| {
                format!("{:.3}", d.as_secs_f64() * 1e3)
            })
        };
        let mut values = Vec::new();
        let mut kv = |key: String, value: String| values.push(KeyValue { key, value });
        for (camera, rate) in cameras.iter().zip(&rates) {
            kv(format!("input rate {camera} (Hz)"), format!("{rate:.2}"));
        }
        kv("sync matched".into(), self.sync.matched.to_string());
        kv("sync dropped".into(), self.sync.dropped.to_string());
        kv("sync incomplete".into(), self.sync.incomplete.to_string());
        kv(
            "sync duplicate stamps".into(),
            self.sync.duplicates.to_string(),
        );
        kv(
            "sync late stamps".into(),
            self.sync.out_of_order.to_string(),
        );
        kv("sync future stamps".into(), self.sync.future.to_string());
        kv("sync resets".into(), self.sync.resets.to_string());
        kv("gpu sets dropped".into(), self.gpu_dropped.to_string());
        kv(
            "sets dropped waiting to be sent".into(),
            self.send_dropped.to_string(),
        );
        for (reason, n) in &self.skipped {
            kv(format!("skipped: {reason}"), n.to_string());
        }
        kv(
            "sets waiting for a world pose".into(),
            self.waiting_for_pose.to_string(),
        );
        // "<stamp> [x, y, z] [qx, qy, qz, qw]": the pose of the frame in world_frame that the
        // last published set of that reference carried (what tf2 gives for that stamp).
        for (frame, (stamp, pose)) in &self.world_poses {
            let (t, q) = (pose.translation, pose.rotation);
            kv(
                format!("world pose {frame}"),
                format!(
                    "{}.{:09} [{:.6}, {:.6}, {:.6}] [{:.9}, {:.9}, {:.9}, {:.9}]",
                    stamp.sec, stamp.nanosec, t.x, t.y, t.z, q.x, q.y, q.z, q.w
                ),
            );
        }
        kv("sets published".into(), self.published.to_string());
        kv("processing time last (ms)".into(), ms(self.last_processing));
        kv(
            "processing time mean (ms)".into(),
            ms(self.mean_processing()),
        );
        kv(
            "latency (ms)".into(),
            self.last_latency_ms
                .map_or("n/a".to_string(), |l| format!("{l:.3}")),
        );
        kv("gpu adapter".into(), adapter.to_string());
        kv(
            "gpu sets in flight (most)".into(),
            self.most_in_flight.to_string(),
        );
        kv(
            "outputs made on demand".into(),
            self.made_on_demand.describe(),
        );
        kv(
            "cameras out of the rig".into(),
            if self.inactive_cameras.is_empty() {
                "none".into()
            } else {
                self.inactive_cameras.join(", ")
            },
        );
        let (level, message) = if self.stale(now) {
            // "yet" until the first depth: the node may have been up for less than 5 s.
            let silent = match self.last_published {
                None => "no depth published yet".to_string(),
                Some(_) => format!("no depth published in the last {} s", STALE_AFTER.as_secs()),
            };
            (
                DiagnosticStatus::WARN,
                if let Some(why) = &self.why {
                    format!("{silent}: {why}")
                } else if self.inactive_cameras.is_empty() {
                    silent
                } else {
                    format!(
                        "{silent}; out of the rig (silent): {}",
                        self.inactive_cameras.join(", ")
                    )
                },
            )
        } else if let Some(halted) = &self.halted {
            // Depth came less than STALE_AFTER ago, but none comes now.
            (DiagnosticStatus::WARN, format!("no depth: {halted}"))
        } else if !self.inactive_cameras.is_empty() {
            (
                DiagnosticStatus::WARN,
                format!(
                    "degraded rig: publishing depth without {} (silent longer than camera_timeout)",
                    self.inactive_cameras.join(", ")
                ),
            )
        } else {
            (DiagnosticStatus::OK, "publishing depth".to_string())
        };
        DiagnosticArray {
            header: Header {
                stamp,
                frame_id: String::new(),
            },
            status: vec![DiagnosticStatus {
                level,
                name: format!("sweepdepth: {fqn}"),
                message,
                hardware_id: adapter.to_string(),
                values,
            }],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn value<'a>(a: &'a DiagnosticArray, key: &str) -> &'a str {
        a.status[0]
            .values
            .iter()
            .find(|kv| kv.key == key)
            .map(|kv| kv.value.as_str())
            .unwrap_or_else(|| panic!("no key {key}"))
    }

    /// Simulated time before the first `/clock` is zero: no latency, not one of decades.
    #[test]
    fn no_latency_before_the_first_clock() {
        let t0 = Instant::now();
        let mut s = Stats::new(1);
        let stamp = Time {
            sec: 1_700_000_000,
            nanosec: 0,
        };
        s.on_published(Duration::from_millis(10), t0, Time::default(), stamp);
        let a = s.diagnostics("/n", &["a".to_string()], "gpu", t0, Time::default());
        assert_eq!(value(&a, "latency (ms)"), "n/a");
        let now = Time {
            sec: 1_700_000_000,
            nanosec: 250_000_000,
        };
        s.on_published(Duration::from_millis(10), t0, now, stamp);
        let a = s.diagnostics("/n", &["a".to_string()], "gpu", t0, Time::default());
        assert_eq!(value(&a, "latency (ms)"), "250.000");
    }

    #[test]
    fn rates_counts_and_level() {
        let t0 = Instant::now();
        let mut s = Stats::new(2);
        let cams = ["a".to_string(), "b".to_string()];
        let a = s.diagnostics(
            "/n",
            &cams,
            "gpu",
            t0 + Duration::from_secs(2),
            Time::default(),
        );
        assert_eq!(a.status[0].level, DiagnosticStatus::WARN);
        assert_eq!(a.status[0].name, "sweepdepth: /n");
        // Up for 2 s and nothing published: not "in the last 5 s".
        assert_eq!(a.status[0].message, "no depth published yet");
        assert_eq!(value(&a, "processing time mean (ms)"), "n/a");
        for k in 0..10 {
            s.on_image(0, t0 + Duration::from_millis(1000 + 100 * k));
        }
        s.on_image(1, t0 + Duration::from_millis(1950));
        s.sync.matched = 3;
        s.sync.duplicates = 4;
        s.sync.out_of_order = 5;
        s.sync.future = 6;
        s.sync.resets = 7;
        s.gpu_dropped = 2;
        let now = t0 + Duration::from_millis(1990);
        s.on_published(
            Duration::from_millis(10),
            now,
            Time {
                sec: 10,
                nanosec: 0,
            },
            Time {
                sec: 9,
                nanosec: 500_000_000,
            },
        );
        s.on_published(
            Duration::from_millis(20),
            now,
            Time {
                sec: 10,
                nanosec: 0,
            },
            Time {
                sec: 10,
                nanosec: 0,
            },
        );
        let a = s.diagnostics("/n", &cams, "gpu", now, Time::default());
        assert_eq!(a.status[0].level, DiagnosticStatus::OK);
        assert_eq!(value(&a, "input rate a (Hz)"), "10.00");
        assert_eq!(value(&a, "input rate b (Hz)"), "1.00");
        assert_eq!(value(&a, "sync matched"), "3");
        assert_eq!(value(&a, "sync duplicate stamps"), "4");
        assert_eq!(value(&a, "sync late stamps"), "5");
        assert_eq!(value(&a, "sync future stamps"), "6");
        assert_eq!(value(&a, "sync resets"), "7");
        assert_eq!(value(&a, "gpu sets dropped"), "2");
        assert_eq!(value(&a, "processing time last (ms)"), "20.000");
        assert_eq!(value(&a, "processing time mean (ms)"), "15.000");
        assert_eq!(value(&a, "latency (ms)"), "0.000");
        assert_eq!(value(&a, "gpu adapter"), "gpu");
        let later = now + Duration::from_secs(6);
        let a = s.diagnostics("/n", &cams, "gpu", later, Time::default());
        assert_eq!(a.status[0].level, DiagnosticStatus::WARN);
        assert_eq!(value(&a, "input rate a (Hz)"), "0.00");
        assert_eq!(a.status[0].message, "no depth published in the last 5 s");
        // The reason, while no depth comes out.
        s.why = Some("no image on /rig/cam2/image_raw yet".into());
        let a = s.diagnostics("/n", &cams, "gpu", later, Time::default());
        assert_eq!(
            a.status[0].message,
            "no depth published in the last 5 s: no image on /rig/cam2/image_raw yet"
        );
        // A camera out of the rig: "degraded" while depth goes on over the others, but the
        // reason at once (not "publishing depth") when the others cannot make a set.
        s.why = None;
        s.inactive_cameras = vec!["b".into()];
        let a = s.diagnostics("/n", &cams, "gpu", now, Time::default());
        assert_eq!(
            a.status[0].message,
            "degraded rig: publishing depth without b (silent longer than camera_timeout)"
        );
        s.halted =
            Some("fewer than 2 cameras are sending (out of the rig: b); not publishing".into());
        let a = s.diagnostics("/n", &cams, "gpu", now, Time::default());
        assert_eq!(a.status[0].level, DiagnosticStatus::WARN);
        assert_eq!(
            a.status[0].message,
            "no depth: fewer than 2 cameras are sending (out of the rig: b); not publishing"
        );
    }
}
