//! The exact-time policy: a set is the messages of every stream with the identical stamp.

use std::collections::BTreeMap;

use super::time_rules::{TimeGuard, TimeJump, TimeRules};
use super::{
    check_index, check_streams, Admission, Discarded, Drained, Pushed, SyncError, SyncStats,
    SyncedSet, Synchronizer, Tally,
};

/// Messages gathered for one stamp.
#[derive(Debug)]
struct Bucket<T> {
    slots: Vec<Option<T>>,
    present: usize,
}

/// Exact-time policy: a set is emitted as soon as all `N` streams have delivered a message with
/// the identical stamp.
///
/// * **Per-stream ordering.** The time rules of the module docs: a message whose stamp is `<=`
///   the last stamp accepted on its stream is rejected (`dropped += 1`; a stream cannot
///   contribute twice to one stamp, and an older stamp could only belong to a set that is
///   already emitted or abandoned), unless it is more than the reset threshold older: then
///   every pending partial set is discarded (each counted in `incomplete`) and the message
///   starts the new timeline.
/// * **Queue bound.** Each stream buffers at most `queue_size` messages (unlike ROS `ExactTime`,
///   which bounds the number of pending stamps). When a push makes a stream exceed it, the
///   stream's oldest buffered message is evicted; since that stream has moved past the stamp, its
///   set can never complete, so the other messages waiting at that stamp are discarded with it.
/// * **Pruning.** When the set at stamp `t` is emitted, every pending partial set with a stamp
///   `< t` is discarded (all streams have moved past it, so it can never complete).
///
/// Counters: `matched` = sets emitted; `dropped` = messages rejected on arrival plus every
/// message of an evicted or pruned partial set; `incomplete` = partial sets (distinct stamps
/// holding at least one but fewer than `N` messages) discarded by eviction or pruning. Caveat:
/// if a stream lags by more than `queue_size` messages and later delivers a stamp whose partial
/// set was already evicted, a new partial set is started for it (it is doomed, and will be
/// counted as incomplete a second time when it is discarded).
#[derive(Debug)]
pub struct ExactSync<T> {
    num_streams: usize,
    queue_size: usize,
    pending: BTreeMap<i64, Bucket<T>>,
    /// Buffered messages per stream.
    counts: Vec<usize>,
    time: TimeGuard,
    tally: Tally,
}

impl<T> ExactSync<T> {
    /// `num_streams >= 2` inputs, at most `queue_size >= 1` buffered messages per input.
    pub fn new(num_streams: usize, queue_size: usize) -> Result<Self, SyncError> {
        check_streams(num_streams, queue_size)?;
        Ok(Self {
            num_streams,
            queue_size,
            pending: BTreeMap::new(),
            counts: vec![0; num_streams],
            time: TimeGuard::new(num_streams),
            tally: Tally::default(),
        })
    }

    /// Sets the thresholds of the time rules (default [`TimeRules::default`]).
    pub fn with_time_rules(mut self, rules: TimeRules) -> Result<Self, SyncError> {
        rules.check()?;
        self.time.rules = rules;
        Ok(self)
    }

    /// The per-stream queue bound.
    pub fn queue_size(&self) -> usize {
        self.queue_size
    }

    /// Discards a partial set, updating the counters.
    fn discard(&mut self, bucket: Bucket<T>) {
        for (i, slot) in bucket.slots.iter().enumerate() {
            if slot.is_some() {
                self.counts[i] -= 1;
            }
        }
        self.tally.discard(bucket.present as u64);
    }
}

impl<T> Synchronizer<T> for ExactSync<T> {
    fn num_streams(&self) -> usize {
        self.num_streams
    }

    fn push(&mut self, stream: usize, stamp_ns: i64, msg: T) -> Result<Pushed<T>, SyncError> {
        check_index(stream, self.num_streams)?;
        let admission = self.time.admit(stream, stamp_ns, &mut self.tally.stats);
        let sets = match admission {
            Admission::Accepted => self.add(stream, stamp_ns, msg),
            Admission::Reset(_) => {
                for (_, bucket) in std::mem::take(&mut self.pending) {
                    self.discard(bucket);
                }
                self.add(stream, stamp_ns, msg)
            }
            Admission::Dropped(_) => Vec::new(),
        };
        Ok(Pushed {
            admission,
            sets,
            discarded: self.tally.take_step(),
        })
    }

    fn stats(&self) -> SyncStats {
        self.tally.stats
    }

    fn queue_len(&self, stream: usize) -> Result<usize, SyncError> {
        check_index(stream, self.num_streams)?;
        Ok(self.counts[stream])
    }

    fn last_reset(&self) -> Option<TimeJump> {
        self.time.last_reset
    }

    /// Nothing is pending that could complete: every partial set is handed back, stamp by
    /// stamp.
    fn drain(&mut self) -> Drained<T> {
        self.counts.iter_mut().for_each(|c| *c = 0);
        let buffered = std::mem::take(&mut self.pending)
            .into_iter()
            .flat_map(|(t, bucket)| {
                bucket
                    .slots
                    .into_iter()
                    .enumerate()
                    .filter_map(move |(i, slot)| slot.map(|m| (i, t, m)))
            })
            .collect();
        Drained {
            sets: Vec::new(),
            discarded: Discarded::default(),
            buffered,
        }
    }
}

impl<T> ExactSync<T> {
    /// Adds an accepted message to its stamp's partial set; returns the set if it is complete.
    fn add(&mut self, stream: usize, stamp_ns: i64, msg: T) -> Vec<SyncedSet<T>> {
        let n = self.num_streams;
        let bucket = self.pending.entry(stamp_ns).or_insert_with(|| Bucket {
            slots: (0..n).map(|_| None).collect(),
            present: 0,
        });
        bucket.slots[stream] = Some(msg);
        bucket.present += 1;
        self.counts[stream] += 1;
        let complete = bucket.present == n;

        if complete {
            let mut out = Vec::with_capacity(1);
            if let Some(bucket) = self.pending.remove(&stamp_ns) {
                for c in self.counts.iter_mut() {
                    *c -= 1;
                }
                let messages: Vec<T> = bucket.slots.into_iter().flatten().collect();
                self.tally.stats.matched += 1;
                out.push(SyncedSet {
                    stamps_ns: vec![stamp_ns; n],
                    messages,
                });
            }
            // Prune every older partial set.
            let newer = self.pending.split_off(&stamp_ns);
            let older = std::mem::replace(&mut self.pending, newer);
            for (_, bucket) in older {
                self.discard(bucket);
            }
            return out;
        }

        if self.counts[stream] > self.queue_size {
            let oldest = self
                .pending
                .iter()
                .find(|(_, b)| b.slots[stream].is_some())
                .map(|(t, _)| *t);
            if let Some(bucket) = oldest.and_then(|t| self.pending.remove(&t)) {
                self.discard(bucket);
            }
        }
        Vec::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::Time;
    use crate::ros::sync::test_support::*;
    use crate::ros::sync::time_to_ns;

    // --- exact -----------------------------------------------------------------------------

    #[test]
    fn exact_four_streams_interleaved() {
        let n = 4;
        let evs = schedule(n, 30, 100 * MS, 0, 250 * MS, 7, |_, _| true);
        // The latency exceeds the period, so arrivals really interleave across frames.
        assert!(evs.windows(2).any(|w| w[0].k > w[1].k));
        let mut sync = ExactSync::new(n, 10).unwrap();
        let sets = run(&mut sync, &evs, 10);
        assert_eq!(frames_of(&sets), (0..30).collect::<Vec<_>>());
        for (k, set) in sets.iter().enumerate() {
            assert_frame(set, k as i64, &evs);
            assert_eq!(set.stamps_ns, vec![k as i64 * 100 * MS; n]);
            assert_eq!(set.span_ns(), 0);
        }
        assert_eq!(
            sync.stats(),
            SyncStats {
                matched: 30,
                dropped: 0,
                incomplete: 0,
                ..SyncStats::default()
            }
        );
        assert_conservation(&sync, evs.len() as u64);
    }

    #[test]
    fn exact_missing_message_is_incomplete_and_later_sets_match() {
        let n = 4;
        // Stream 2 never sends frames 3 and 7.
        let evs = schedule(n, 12, 100 * MS, 0, 40 * MS, 3, |s, k| {
            !(s == 2 && (k == 3 || k == 7))
        });
        let mut sync = ExactSync::new(n, 10).unwrap();
        let sets = run(&mut sync, &evs, 10);
        let expected: Vec<i64> = (0..12).filter(|k| *k != 3 && *k != 7).collect();
        assert_eq!(frames_of(&sets), expected);
        for set in &sets {
            assert_frame(set, set.messages[0].1, &evs);
        }
        // Frames 3 and 7: three messages each, abandoned when frames 4 and 8 matched.
        assert_eq!(
            sync.stats(),
            SyncStats {
                matched: 10,
                dropped: 6,
                incomplete: 2,
                ..SyncStats::default()
            }
        );
        assert_conservation(&sync, evs.len() as u64);
    }

    #[test]
    fn exact_messages_with_close_but_different_stamps_never_match() {
        let mut sync = ExactSync::new(2, 5).unwrap();
        assert!(sync.push(0, 1000, (0, 0)).unwrap().sets.is_empty());
        assert!(sync.push(1, 1001, (1, 0)).unwrap().sets.is_empty());
        let sets = sync.push(1, 2000, (1, 1)).unwrap().sets;
        assert!(sets.is_empty());
        let sets = sync.push(0, 2000, (0, 1)).unwrap().sets;
        assert_eq!(sets.len(), 1);
        assert_eq!(sets[0].messages, vec![(0, 1), (1, 1)]);
        // 1000 (stream 0) and 1001 (stream 1) were pruned as two partial sets.
        assert_eq!(
            sync.stats(),
            SyncStats {
                matched: 1,
                dropped: 2,
                incomplete: 2,
                ..SyncStats::default()
            }
        );
    }

    #[test]
    fn exact_bounded_memory_with_stalled_stream() {
        let n = 3;
        let q = 4;
        // Stream 1 is silent for frames 0..20.
        let evs = schedule(n, 30, 100 * MS, 0, 30 * MS, 11, |s, k| s != 1 || k >= 20);
        let mut sync = ExactSync::new(n, q).unwrap();
        let sets = run(&mut sync, &evs, q);
        assert_eq!(frames_of(&sets), (20..30).collect::<Vec<_>>());
        for set in &sets {
            assert_frame(set, set.messages[0].1, &evs);
        }
        let st = sync.stats();
        assert_eq!(st.matched, 10);
        // Frames 0..20 of streams 0 and 2: 40 messages in 20 partial sets.
        assert_eq!(st.dropped, 40);
        assert_eq!(st.incomplete, 20);
        assert_conservation(&sync, evs.len() as u64);
    }

    #[test]
    fn exact_out_of_order_and_duplicate_are_dropped() {
        let mut sync = ExactSync::new(2, 5).unwrap();
        assert!(sync.push(0, 200, (0, 2)).unwrap().sets.is_empty());
        assert!(sync.push(0, 100, (0, 1)).unwrap().sets.is_empty()); // out of order
        assert!(sync.push(0, 200, (0, 99)).unwrap().sets.is_empty()); // duplicate stamp
        assert_eq!(sync.queue_len(0).unwrap(), 1);
        assert!(sync.push(1, 100, (1, 1)).unwrap().sets.is_empty());
        let sets = sync.push(1, 200, (1, 2)).unwrap().sets;
        assert_eq!(sets.len(), 1);
        assert_eq!(sets[0].messages, vec![(0, 2), (1, 2)]);
        assert_eq!(sets[0].stamps_ns, vec![200, 200]);
        // 2 rejected on arrival + stream 1's lone stamp 100 pruned.
        assert_eq!(
            sync.stats(),
            SyncStats {
                matched: 1,
                dropped: 3,
                incomplete: 1,
                duplicates: 1,
                out_of_order: 1,
                ..SyncStats::default()
            }
        );
        assert_conservation(&sync, 5);
    }

    #[test]
    fn exact_push_stamped_converts_ros_time() {
        let mut sync = ExactSync::new(2, 2).unwrap();
        let t = Time {
            sec: 3,
            nanosec: 250,
        };
        assert!(sync.push_stamped(0, &t, (0, 0)).unwrap().sets.is_empty());
        let sets = sync.push(1, 3_000_000_250, (1, 0)).unwrap().sets;
        assert_eq!(sets[0].stamps_ns, vec![3_000_000_250; 2]);
        assert_eq!(
            time_to_ns(&Time {
                sec: -1,
                nanosec: 5
            }),
            -999_999_995
        );
    }
}
