//! The time rules (see the module docs of [`super`]): what happens to a stamp before either
//! policy sees it: duplicates, late messages, far-future stamps and messages from before a
//! reset are dropped; time going back further than the reset threshold resets the
//! synchroniser.

use super::{Admission, Discarded, DropReason, SyncError, SyncStats};

/// The thresholds of the time rules (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimeRules {
    /// A stamp more than this ahead of the newest stamp of every other stream is dropped (ns,
    /// > 0).
    pub future_window_ns: i64,
    /// A stream whose stamp goes back by more than this resets the synchroniser; less is a late
    /// message, dropped (ns, > 0).
    pub reset_backwards_ns: i64,
}

/// Default of [`TimeRules::future_window_ns`]: 10 s.
pub const DEFAULT_FUTURE_WINDOW_NS: i64 = 10_000_000_000;
/// Default of [`TimeRules::reset_backwards_ns`]: 1 s.
pub const DEFAULT_RESET_BACKWARDS_NS: i64 = 1_000_000_000;

impl Default for TimeRules {
    fn default() -> Self {
        Self {
            future_window_ns: DEFAULT_FUTURE_WINDOW_NS,
            reset_backwards_ns: DEFAULT_RESET_BACKWARDS_NS,
        }
    }
}

impl TimeRules {
    pub(super) fn check(&self) -> Result<(), SyncError> {
        for (name, v) in [
            ("future_window", self.future_window_ns),
            ("reset_backwards", self.reset_backwards_ns),
        ] {
            if v <= 0 {
                return Err(SyncError::InvalidParameter {
                    name,
                    reason: format!("must be > 0, got {v} ns"),
                });
            }
        }
        Ok(())
    }
}

/// A reset of the synchroniser (time rule 2): stream `stream` went back from `from_ns` to
/// `to_ns`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimeJump {
    pub stream: usize,
    pub from_ns: i64,
    pub to_ns: i64,
}

/// What the rules decide on a stamp, before the state is updated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Verdict {
    Accept,
    /// Discard everything buffered, then accept.
    Reset,
    Drop(DropReason),
}

/// The per-stream time state behind the time rules (shared by both policies).
#[derive(Debug, Clone)]
pub(super) struct TimeGuard {
    pub rules: TimeRules,
    /// Last accepted stamp per stream since the last reset.
    pub last: Vec<Option<i64>>,
    /// Last pushed stamp per stream, whatever its verdict.
    seen: Vec<Option<i64>>,
    /// Newest accepted stamp since the last reset.
    newest: Option<i64>,
    /// After a reset: the midpoint between the old and the new timeline (rule 5).
    reset_midpoint: Option<i64>,
    pub last_reset: Option<TimeJump>,
}

impl TimeGuard {
    pub fn new(num_streams: usize) -> Self {
        Self {
            rules: TimeRules::default(),
            last: vec![None; num_streams],
            seen: vec![None; num_streams],
            newest: None,
            reset_midpoint: None,
            last_reset: None,
        }
    }

    /// Applies the rules to stamp `t` of `stream` (a valid index), updates the state and
    /// counts the verdict in `stats`; the caller discards its buffers on a reset.
    pub fn admit(&mut self, stream: usize, t: i64, stats: &mut SyncStats) -> Admission {
        let admission = match self.verdict(stream, t) {
            Verdict::Accept => {
                self.accept(stream, t);
                Admission::Accepted
            }
            Verdict::Reset => {
                let from = self.last.get(stream).copied().flatten().unwrap_or(t);
                self.last.iter_mut().for_each(|l| *l = None);
                self.newest = None;
                self.reset_midpoint = Some(t.saturating_add(from.saturating_sub(t) / 2));
                let jump = TimeJump {
                    stream,
                    from_ns: from,
                    to_ns: t,
                };
                self.last_reset = Some(jump);
                self.accept(stream, t);
                Admission::Reset(jump)
            }
            Verdict::Drop(reason) => Admission::Dropped(reason),
        };
        if let Some(seen) = self.seen.get_mut(stream) {
            *seen = Some(t);
        }
        // The policy counts what it emits and discards; the verdict's own counters are these.
        stats.count(Some(admission), 0, Discarded::default());
        admission
    }

    fn accept(&mut self, stream: usize, t: i64) {
        if let Some(last) = self.last.get_mut(stream) {
            *last = Some(t);
        }
        let newest = self.newest.map_or(t, |n| n.max(t));
        self.newest = Some(newest);
        if self.reset_midpoint.is_some_and(|mid| newest > mid) {
            self.reset_midpoint = None;
        }
    }

    fn verdict(&self, stream: usize, t: i64) -> Verdict {
        let last = self.last.get(stream).copied().flatten();
        if let Some(last) = last {
            if t == last {
                return Verdict::Drop(DropReason::Duplicate);
            }
            if last.saturating_sub(t) > self.rules.reset_backwards_ns {
                return Verdict::Reset;
            }
            if t < last {
                return Verdict::Drop(DropReason::Late);
            }
        }
        let others = self
            .seen
            .iter()
            .enumerate()
            .filter(|(j, _)| *j != stream)
            .filter_map(|(_, s)| *s)
            .max();
        if others.is_some_and(|o| t.saturating_sub(o) > self.rules.future_window_ns) {
            return Verdict::Drop(DropReason::Future);
        }
        if last.is_none() && self.reset_midpoint.is_some_and(|mid| t > mid) {
            return Verdict::Drop(DropReason::BeforeReset);
        }
        Verdict::Accept
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ros::sync::test_support::*;
    use crate::ros::sync::{ApproximateSync, DropReason, ExactSync, SyncedSet, Synchronizer};

    // --- time rules (both policies) ---------------------------------------------------------

    type Make = fn(usize, usize) -> Box<dyn Synchronizer<Msg>>;

    fn exact_box(n: usize, q: usize) -> Box<dyn Synchronizer<Msg>> {
        Box::new(ExactSync::new(n, q).unwrap())
    }

    fn approx_box(n: usize, q: usize) -> Box<dyn Synchronizer<Msg>> {
        Box::new(
            ApproximateSync::new(n, q)
                .unwrap()
                .with_max_interval_ns(20 * MS)
                .unwrap(),
        )
    }

    const POLICIES: [(&str, Make); 2] = [("exact", exact_box), ("approximate", approx_box)];

    /// Every set holds one frame (the same `k` on every stream, stream `i` at index `i`).
    fn assert_sets_are_frames(sets: &[SyncedSet<Msg>], n: usize) {
        for set in sets {
            assert_eq!(set.messages.len(), n);
            let k = set.messages[0].1;
            for (i, m) in set.messages.iter().enumerate() {
                assert_eq!(*m, (i, k), "{set:?}");
            }
        }
    }

    #[test]
    fn bag_played_in_a_loop_resets_once_per_wrap() {
        // 4 streams, 30 frames at 10 Hz (3 s), played twice with the same stamps; latencies up
        // to 250 ms make the end of the first loop and the start of the second interleave
        // across streams. Loop 2 carries k + 1000.
        let n = 4;
        let mut late_stale = 0;
        for (policy, make) in POLICIES {
            for seed in 1..=12 {
                let first = schedule(n, 30, 100 * MS, 0, 250 * MS, seed, |_, _| true);
                let second = schedule(n, 30, 100 * MS, 0, 250 * MS, seed + 100, |_, _| true);
                // Each stream stays a FIFO across the wrap (as a topic).
                let mut last_arrival = vec![0; n];
                for e in &first {
                    last_arrival[e.stream] = last_arrival[e.stream].max(e.arrival);
                }
                let mut evs = first.clone();
                evs.extend(second.iter().map(|e| Ev {
                    k: e.k + 1000,
                    arrival: (e.arrival + 3000 * MS).max(last_arrival[e.stream]),
                    ..*e
                }));
                evs.sort_by_key(|e| (e.arrival, e.stream));
                let mut sync = make(n, 10);
                let sets = run(sync.as_mut(), &evs, 10);
                let st = sync.stats();
                assert_eq!(st.resets, 1, "{policy} seed {seed}: {st:?}");
                let jump = sync.last_reset().unwrap();
                assert_eq!(jump.to_ns, 0, "{policy}: the loop restarts at frame 0");
                assert!(jump.from_ns >= 2500 * MS, "{policy}: {jump:?}");
                assert_sets_are_frames(&sets, n);
                let loop1 = sets.iter().filter(|s| s.messages[0].1 < 1000).count();
                let loop2 = sets.len() - loop1;
                // Only frames at the wrap (in flight when the time jumped) may be lost.
                assert!(
                    loop1 >= 26 && loop2 >= 26,
                    "{policy} seed {seed}: {loop1} + {loop2}"
                );
                late_stale += st.out_of_order;
                assert_eq!((st.duplicates, st.future), (0, 0));
                assert_conservation(sync.as_ref(), evs.len() as u64);
            }
        }
        // Rule 5 was exercised: messages of the first loop arrived after the reset.
        assert!(late_stale > 0);
    }

    #[test]
    fn duplicate_stamps_are_dropped_and_counted() {
        for (policy, make) in POLICIES {
            let mut sync = make(2, 5);
            assert!(sync.push(0, 100 * MS, (0, 1)).unwrap().sets.is_empty());
            assert!(sync.push(0, 100 * MS, (0, 99)).unwrap().sets.is_empty());
            assert_eq!(sync.queue_len(0).unwrap(), 1, "{policy}");
            let mut sets = sync.push(1, 100 * MS, (1, 1)).unwrap().sets;
            sets.extend(sync.push(0, 200 * MS, (0, 2)).unwrap().sets);
            sets.extend(sync.push(1, 200 * MS, (1, 2)).unwrap().sets);
            sets.extend(sync.push(1, 200 * MS, (1, 99)).unwrap().sets);
            sets.extend(sync.push(0, 300 * MS, (0, 3)).unwrap().sets);
            assert_eq!(sets[0].messages, vec![(0, 1), (1, 1)], "{policy}");
            assert_eq!(sets[1].messages, vec![(0, 2), (1, 2)], "{policy}");
            let st = sync.stats();
            assert_eq!(
                (st.duplicates, st.dropped, st.resets),
                (2, 2, 0),
                "{policy}"
            );
            assert_conservation(sync.as_ref(), 7);
        }
    }

    #[test]
    fn far_future_stamp_is_dropped_and_does_not_poison_the_stream() {
        let n = 3;
        for (policy, make) in POLICIES {
            let mut sync = make(n, 5);
            let mut sets = Vec::new();
            let mut pushes = 0;
            for k in 0..20i64 {
                for s in 0..n {
                    sets.extend(sync.push(s, k * 100 * MS, (s, k)).unwrap().sets);
                    pushes += 1;
                }
                if k == 5 {
                    // One hour ahead on stream 1, then the stream carries on normally.
                    sets.extend(sync.push(1, 3600 * 1000 * MS, (1, -1)).unwrap().sets);
                    pushes += 1;
                }
            }
            let st = sync.stats();
            assert_eq!((st.future, st.resets), (1, 0), "{policy}: {st:?}");
            assert_sets_are_frames(&sets, n);
            // Every frame but the last (approximate sync waits for a later one) matched.
            assert!(sets.len() >= 19, "{policy}: {} sets", sets.len());
            assert_conservation(sync.as_ref(), pushes);
        }
    }

    #[test]
    fn whole_rig_jumping_forward_loses_one_message_not_the_stream() {
        let n = 3;
        for (policy, make) in POLICIES {
            let mut sync = make(n, 5);
            let mut sets = Vec::new();
            for k in 0..20i64 {
                // At frame 10 every camera jumps 60 s ahead (a gap in a recording).
                let t = k * 100 * MS + if k >= 10 { 60_000 * MS } else { 0 };
                for s in 0..n {
                    sets.extend(sync.push(s, t, (s, k)).unwrap().sets);
                }
            }
            let st = sync.stats();
            // Stream 0 was first to jump: its frame 10 is more than 10 s ahead of the others.
            assert_eq!((st.future, st.resets), (1, 0), "{policy}: {st:?}");
            assert_sets_are_frames(&sets, n);
            let frames = frames_of(&sets);
            assert!(!frames.contains(&10), "{policy}: {frames:?}");
            assert!(
                frames.contains(&11) && frames.contains(&18),
                "{policy}: {frames:?}"
            );
        }
    }

    #[test]
    fn bogus_stamp_within_the_window_costs_one_reset() {
        let n = 2;
        for (policy, make) in POLICIES {
            let mut sync = make(n, 5);
            let mut sets = Vec::new();
            for k in 0..20i64 {
                for s in 0..n {
                    sets.extend(sync.push(s, k * 100 * MS, (s, k)).unwrap().sets);
                }
                if k == 5 {
                    // 5 s ahead on stream 0: within the window, accepted; its next normal
                    // stamp is 4.4 s behind it and resets the synchroniser.
                    sets.extend(sync.push(0, 5600 * MS, (0, -1)).unwrap().sets);
                }
            }
            let st = sync.stats();
            assert_eq!((st.future, st.resets), (0, 1), "{policy}: {st:?}");
            assert_eq!(
                sync.last_reset(),
                Some(TimeJump {
                    stream: 0,
                    from_ns: 5600 * MS,
                    to_ns: 600 * MS
                })
            );
            assert_sets_are_frames(&sets, n);
            let frames = frames_of(&sets);
            assert!(
                frames.contains(&7) && frames.contains(&18),
                "{policy}: {frames:?}"
            );
        }
    }

    #[test]
    fn a_lagging_stream_never_resets() {
        // Stream 1 runs 1.5 s behind the others (its own time is monotonic): no reset, no
        // future drop (the others are 1.5 s ahead, within the 10 s window).
        for (policy, make) in POLICIES {
            let mut sync = make(3, 5);
            for k in 0..40i64 {
                for s in 0..3 {
                    let t = k * 100 * MS - if s == 1 { 1500 * MS } else { 0 };
                    let _ = sync.push(s, t, (s, k)).unwrap();
                }
            }
            let st = sync.stats();
            assert_eq!(
                (st.resets, st.future, st.out_of_order),
                (0, 0, 0),
                "{policy}: {st:?}"
            );
            assert_eq!(st.matched, 0, "{policy}");
            assert_conservation(sync.as_ref(), 120);
        }
    }

    #[test]
    fn small_step_back_is_out_of_order_and_thresholds_are_configurable() {
        let rules = TimeRules {
            future_window_ns: 2000 * MS,
            reset_backwards_ns: 300 * MS,
        };
        let mut exact = ExactSync::new(2, 5)
            .unwrap()
            .with_time_rules(rules)
            .unwrap();
        let mut approx = ApproximateSync::new(2, 5)
            .unwrap()
            .with_time_rules(rules)
            .unwrap();
        let syncs: [&mut dyn Synchronizer<Msg>; 2] = [&mut exact, &mut approx];
        for sync in syncs {
            let mut admit =
                |s: usize, t: i64, k: i64| sync.push(s, t * MS, (s, k)).unwrap().admission;
            assert_eq!(admit(0, 1000, 0), Admission::Accepted);
            // 200 ms back: late, dropped.
            assert_eq!(admit(0, 800, 1), Admission::Dropped(DropReason::Late));
            // 400 ms back: reset.
            assert_eq!(
                admit(0, 600, 2),
                Admission::Reset(TimeJump {
                    stream: 0,
                    from_ns: 1000 * MS,
                    to_ns: 600 * MS
                })
            );
            // Until the new timeline passes the midpoint (600 + 1000) / 2 = 800 ms, a stream
            // that has not delivered since the reset is refused above it (rule 5).
            assert_eq!(
                admit(1, 850, 0),
                Admission::Dropped(DropReason::BeforeReset)
            );
            assert_eq!(admit(0, 900, 3), Admission::Accepted);
            // 2.05 s ahead of stream 0: future; 1.95 s ahead: accepted.
            assert_eq!(admit(1, 2950, 1), Admission::Dropped(DropReason::Future));
            assert_eq!(admit(1, 2850, 2), Admission::Accepted);
            assert_eq!(admit(1, 2850, 3), Admission::Dropped(DropReason::Duplicate));
            let st = sync.stats();
            assert_eq!(
                (st.out_of_order, st.resets, st.future, st.duplicates),
                (2, 1, 1, 1)
            );
            assert_eq!(sync.queue_len(1).unwrap(), 1);
        }
        for bad in [0, -1] {
            let rules = TimeRules {
                future_window_ns: bad,
                ..TimeRules::default()
            };
            assert!(ExactSync::<u8>::new(2, 1)
                .unwrap()
                .with_time_rules(rules)
                .is_err());
            let rules = TimeRules {
                reset_backwards_ns: bad,
                ..TimeRules::default()
            };
            assert!(ApproximateSync::<u8>::new(2, 1)
                .unwrap()
                .with_time_rules(rules)
                .is_err());
        }
    }
}
