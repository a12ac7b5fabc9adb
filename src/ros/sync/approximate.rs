//! The approximate-time policy: message_filters' `ApproximateTime`, N-ary.

use std::collections::VecDeque;

use super::time_rules::{TimeGuard, TimeJump, TimeRules};
use super::{
    check_index, check_streams, Admission, Drained, Flushed, Pushed, SyncError, SyncStats,
    SyncedSet, Synchronizer, Tally,
};

/// The current best candidate set. Its message on stream `i` is `deques[i].front()` if that
/// message was never moved to `past[i]`, else `past[i][0]` (`past` is cleared whenever a new
/// candidate is made), so the candidate needs no copy of the messages.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    start: i64,
    end: i64,
    pivot: usize,
    pivot_time: i64,
}

/// Approximate-time policy: a faithful N-ary port of `message_filters::sync_policies::
/// ApproximateTime` (ROS 1 and ROS 2 share the algorithm, by Vincent Rabaud; see
/// <http://wiki.ros.org/message_filters/ApproximateTime>).
///
/// # Algorithm
///
/// Each stream has a queue (`deques_`) and a "past" vector of messages provisionally set aside
/// during a candidate search (`past_`). Whenever every queue is non-empty, `process()` runs:
///
/// 1. The heads of the queues form a set; its earliest head is the *start*, its latest the *end*
///    (`getCandidateBoundary`; ties: the start is the lowest stream index, the end the highest).
/// 2. Without a candidate: a head set whose span exceeds `max_interval`, or whose end stream has
///    dropped messages (queue overflow, see below), is rejected by deleting the start head.
///    Otherwise it becomes the candidate; its end stream becomes the *pivot*. Any future set must
///    contain a pivot message no earlier than the pivot time.
/// 3. With a candidate: the head set replaces it if it is better, i.e. unless
///    `(end - cand_end) * (1 + age_penalty) >= start - cand_start` (the age penalty favours
///    older sets). Making a new candidate discards the messages in `past`.
/// 4. The start head is moved to `past` and the next head set is examined. The candidate is
///    emitted when the pivot itself was the start (all sets containing the pivot message have
///    been examined), or when it is provably optimal:
///    `(end - cand_end) * (1 + age_penalty) >= pivot_time - cand_start`. If a queue ran empty
///    before that, a *virtual* search continues with optimistic stamps for the empty queues
///    (`max(pivot_time, last + inter_message_lower_bound)`) to try to prove optimality early;
///    if it cannot, its moves are undone and the policy waits for more messages.
/// 5. A push that makes `queue + past` of a stream exceed `queue_size` cancels the search,
///    evicts the stream's oldest message, marks the stream as having dropped messages (it may
///    not be a pivot until process() sees a set where it is not the end) and restarts process().
///
/// # Parameters
///
/// * `queue_size` (>= 1; 2 or more recommended),
/// * `age_penalty` (default 0.1, >= 0, finite),
/// * `max_interval` (`max_interval_duration`, default unbounded): sets whose span exceeds it are
///   never emitted,
/// * per-stream `inter_message_lower_bound` (default 0): the minimum stamp gap between two
///   consecutive messages of a stream; it only lets the policy prove optimality (and emit)
///   earlier. It is a promise: if a stream violates it, a non-optimal set may have been emitted.
///
/// # Deviations from `message_filters`
///
/// * N-ary, with `Vec`s instead of 9-element tuples; no upper limit on N.
/// * **The time rules of the module docs apply**: a message whose stamp is older than the last
///   stamp accepted on its stream is rejected and counted in `dropped` (message_filters
///   enqueues it and logs a warning once), and so is a repeated stamp (message_filters accepts
///   it); a stamp more than the reset threshold older resets the synchroniser (queues, `past`
///   and the candidate are discarded, once in `incomplete`); a stamp far in the future is
///   dropped.
/// * Lower-bound violations are checked against the stream's previously accepted message
///   (message_filters checks only against the message still buffered before it, and stops
///   checking a stream after its first warning). Every violation is counted
///   ([`ApproximateSync::bound_violations`]); a `tracing` warning is logged once per stream.
/// * `Duration * (1 + age_penalty)` is computed in `f64` and truncated toward zero (rclcpp uses
///   `long double`); results can differ by a nanosecond for spans above 2^53 ns (~104 days).
///   Stamp differences saturate instead of throwing on overflow.
/// * Parameter errors are `Err`s, not assertions.
///
/// # Counters
///
/// `matched` = sets emitted. `dropped` = messages discarded: rejected on arrival (out of
/// order), evicted by a queue overflow, deleted as the start head of a rejected head set
/// (span > `max_interval`, or pivot stream with dropped messages), or set aside in `past` and
/// then discarded because a better candidate was found. `incomplete` counts the discard
/// *events* of buffered messages (overflow eviction, start-head deletion, past discard), each
/// once however many messages it discarded: each is a partial set (never all N streams) that
/// will not be emitted. Out-of-order rejections count in `dropped` only.
#[derive(Debug)]
pub struct ApproximateSync<T> {
    num_streams: usize,
    queue_size: usize,
    age_penalty: f64,
    max_interval_ns: i64,
    lower_bounds_ns: Vec<i64>,
    deques: Vec<VecDeque<(i64, T)>>,
    past: Vec<Vec<(i64, T)>>,
    has_dropped: Vec<bool>,
    candidate: Option<Candidate>,
    time: TimeGuard,
    bound_warned: Vec<bool>,
    bound_violations: u64,
    tally: Tally,
}

impl<T> ApproximateSync<T> {
    /// `num_streams >= 2` inputs, `queue_size >= 1` (messages buffered per stream, including
    /// those set aside during a candidate search), `age_penalty` 0.1, unbounded `max_interval`,
    /// no inter-message lower bounds.
    pub fn new(num_streams: usize, queue_size: usize) -> Result<Self, SyncError> {
        check_streams(num_streams, queue_size)?;
        Ok(Self {
            num_streams,
            queue_size,
            age_penalty: 0.1,
            max_interval_ns: i64::MAX,
            lower_bounds_ns: vec![0; num_streams],
            deques: (0..num_streams).map(|_| VecDeque::new()).collect(),
            past: (0..num_streams).map(|_| Vec::new()).collect(),
            has_dropped: vec![false; num_streams],
            candidate: None,
            time: TimeGuard::new(num_streams),
            bound_warned: vec![false; num_streams],
            bound_violations: 0,
            tally: Tally::default(),
        })
    }

    /// Sets the thresholds of the time rules (default [`TimeRules::default`]).
    pub fn with_time_rules(mut self, rules: TimeRules) -> Result<Self, SyncError> {
        rules.check()?;
        self.time.rules = rules;
        Ok(self)
    }

    /// Discards every buffered message and the candidate search (time rule 2).
    fn reset_buffers(&mut self) {
        let mut discarded = 0;
        for d in &mut self.deques {
            discarded += d.len();
            d.clear();
        }
        for p in &mut self.past {
            discarded += p.len();
            p.clear();
        }
        self.tally.discard(discarded as u64);
        self.candidate = None;
        self.has_dropped.iter_mut().for_each(|d| *d = false);
    }

    /// Sets the age penalty (`>= 0`, finite; default 0.1).
    pub fn with_age_penalty(mut self, age_penalty: f64) -> Result<Self, SyncError> {
        if !(age_penalty.is_finite() && age_penalty >= 0.0) {
            return Err(SyncError::InvalidParameter {
                name: "age_penalty",
                reason: format!("must be finite and >= 0, got {age_penalty}"),
            });
        }
        self.age_penalty = age_penalty;
        Ok(self)
    }

    /// Sets `max_interval` in ns (`>= 0`): sets spanning more are never emitted.
    pub fn with_max_interval_ns(mut self, max_interval_ns: i64) -> Result<Self, SyncError> {
        if max_interval_ns < 0 {
            return Err(SyncError::InvalidParameter {
                name: "max_interval",
                reason: format!("must be >= 0, got {max_interval_ns} ns"),
            });
        }
        self.max_interval_ns = max_interval_ns;
        Ok(self)
    }

    /// Sets the inter-message lower bound of `stream` in ns (`>= 0`).
    pub fn with_inter_message_lower_bound_ns(
        mut self,
        stream: usize,
        bound_ns: i64,
    ) -> Result<Self, SyncError> {
        check_index(stream, self.num_streams)?;
        if bound_ns < 0 {
            return Err(SyncError::InvalidParameter {
                name: "inter_message_lower_bound",
                reason: format!("must be >= 0, got {bound_ns} ns"),
            });
        }
        self.lower_bounds_ns[stream] = bound_ns;
        Ok(self)
    }

    /// The age penalty.
    pub fn age_penalty(&self) -> f64 {
        self.age_penalty
    }

    /// `max_interval` in ns (`i64::MAX` when unbounded).
    pub fn max_interval_ns(&self) -> i64 {
        self.max_interval_ns
    }

    /// The per-stream queue bound.
    pub fn queue_size(&self) -> usize {
        self.queue_size
    }

    /// Number of accepted messages that arrived closer to their stream's previous message than
    /// the stream's inter-message lower bound.
    pub fn bound_violations(&self) -> u64 {
        self.bound_violations
    }

    // --- the message_filters primitives -----------------------------------------------------

    /// `(d) * (1 + age_penalty_)` with rclcpp's truncation toward zero (saturating).
    fn penalised(&self, d: i64) -> i64 {
        (d as f64 * (1.0 + self.age_penalty)) as i64
    }

    fn all_non_empty(&self) -> bool {
        self.deques.iter().all(|d| !d.is_empty())
    }

    /// `getCandidateBoundary` / `getVirtualCandidateBoundary` over per-stream `times`.
    fn boundary(times: &[i64], end: bool) -> (usize, i64) {
        let mut index = 0;
        let mut time = times.first().copied().unwrap_or(0);
        for (i, &t) in times.iter().enumerate().skip(1) {
            if (t < time) ^ end {
                time = t;
                index = i;
            }
        }
        (index, time)
    }

    fn head_times(&self) -> Vec<i64> {
        self.deques
            .iter()
            .map(|d| d.front().map_or(i64::MAX, |(t, _)| *t))
            .collect()
    }

    /// `getVirtualTime` for every stream (requires a candidate).
    fn virtual_times(&self, pivot_time: i64) -> Vec<i64> {
        (0..self.num_streams)
            .map(|i| match self.deques[i].front() {
                Some((t, _)) => *t,
                None => match self.past[i].last() {
                    Some((t, _)) => t.saturating_add(self.lower_bounds_ns[i]).max(pivot_time),
                    // Unreachable while a candidate exists (each stream holds its candidate
                    // message in the queue or in `past`); be optimistic anyway.
                    None => pivot_time,
                },
            })
            .collect()
    }

    /// `dequeDeleteFront`: discards the head of `i` (the start of a rejected head set).
    fn delete_front(&mut self, i: usize) {
        if self.deques[i].pop_front().is_some() {
            self.tally.discard(1);
        }
    }

    /// `dequeMoveFrontToPast`.
    fn move_front_to_past(&mut self, i: usize) -> bool {
        match self.deques[i].pop_front() {
            Some(m) => {
                self.past[i].push(m);
                true
            }
            None => false,
        }
    }

    /// `makeCandidate` (the candidate is the queue heads, implicitly): discards `past`.
    fn make_candidate(&mut self) {
        let mut discarded = 0;
        for p in &mut self.past {
            discarded += p.len();
            p.clear();
        }
        self.tally.discard(discarded as u64);
    }

    /// `recover(num_messages)`: puts the last `moves[i]` messages of `past[i]` back.
    fn recover_moves(&mut self, moves: &[usize]) {
        for (i, &m) in moves.iter().enumerate() {
            for _ in 0..m {
                if let Some(msg) = self.past[i].pop() {
                    self.deques[i].push_front(msg);
                }
            }
        }
    }

    /// `recover()`: puts all of `past` back.
    fn recover_all(&mut self) {
        for i in 0..self.num_streams {
            while let Some(msg) = self.past[i].pop() {
                self.deques[i].push_front(msg);
            }
        }
    }

    /// `publishCandidate` + `recoverAndDelete`.
    fn publish_candidate(&mut self, out: &mut Vec<SyncedSet<T>>) {
        self.candidate = None;
        self.recover_all();
        let mut stamps_ns = Vec::with_capacity(self.num_streams);
        let mut messages = Vec::with_capacity(self.num_streams);
        for d in &mut self.deques {
            if let Some((t, m)) = d.pop_front() {
                stamps_ns.push(t);
                messages.push(m);
            }
        }
        if messages.len() == self.num_streams {
            self.tally.stats.matched += 1;
            out.push(SyncedSet {
                stamps_ns,
                messages,
            });
        } else if !messages.is_empty() {
            // Unreachable: a candidate holds one message per stream.
            self.tally.discard(messages.len() as u64);
        }
    }

    /// `process()`.
    fn process(&mut self, out: &mut Vec<SyncedSet<T>>) {
        while self.all_non_empty() {
            let heads = self.head_times();
            let (end_index, end_time) = Self::boundary(&heads, true);
            let (start_index, start_time) = Self::boundary(&heads, false);
            for (i, dropped) in self.has_dropped.iter_mut().enumerate() {
                if i != end_index {
                    // No dropped message could have been better to use than the ones we have,
                    // so it becomes ok to use this stream as pivot in the future.
                    *dropped = false;
                }
            }
            let cand = match self.candidate {
                None => {
                    if end_time.saturating_sub(start_time) > self.max_interval_ns
                        || self.has_dropped[end_index]
                    {
                        // Too wide to be a candidate, or a bad pivot: move to the next.
                        self.delete_front(start_index);
                        continue;
                    }
                    self.make_candidate();
                    let c = Candidate {
                        start: start_time,
                        end: end_time,
                        pivot: end_index,
                        pivot_time: end_time,
                    };
                    self.candidate = Some(c);
                    self.move_front_to_past(start_index);
                    c
                }
                Some(mut c) => {
                    if self.penalised(end_time.saturating_sub(c.end))
                        < start_time.saturating_sub(c.start)
                    {
                        // A better candidate; keep the same pivot (and pivot time).
                        self.make_candidate();
                        c.start = start_time;
                        c.end = end_time;
                        self.candidate = Some(c);
                    }
                    self.move_front_to_past(start_index);
                    c
                }
            };

            let age_check = self.penalised(end_time.saturating_sub(cand.end));
            if start_index == cand.pivot {
                // All candidates for this pivot have been examined: emit the best one.
                self.publish_candidate(out);
            } else if age_check >= cand.pivot_time.saturating_sub(cand.start) {
                // Provably optimal: any future candidate contains [pivot_time, end_time].
                self.publish_candidate(out);
            } else if !self.all_non_empty() {
                self.virtual_search(cand, out);
            }
        }
    }

    /// The virtual-move search of `process()`: tries to prove optimality of `cand` using the
    /// inter-message lower bounds before waiting for more messages.
    fn virtual_search(&mut self, cand: Candidate, out: &mut Vec<SyncedSet<T>>) {
        let mut moves = vec![0usize; self.num_streams];
        loop {
            let vt = self.virtual_times(cand.pivot_time);
            let (_, end_time) = Self::boundary(&vt, true);
            let (start_index, start_time) = Self::boundary(&vt, false);
            let age_check = self.penalised(end_time.saturating_sub(cand.end));
            if age_check >= cand.pivot_time.saturating_sub(cand.start) {
                // Optimality proved; publishing also undoes the virtual moves.
                self.publish_candidate(out);
                return;
            }
            if age_check < start_time.saturating_sub(cand.start) {
                // An optimistic virtual candidate beats ours: cannot prove optimality yet.
                self.recover_moves(&moves);
                return;
            }
            // Here start_time < pivot_time, so `start_index` is a non-empty queue (empty ones
            // have virtual times >= pivot_time); guard anyway so that the loop always ends.
            if start_index == cand.pivot || !self.move_front_to_past(start_index) {
                self.recover_moves(&moves);
                return;
            }
            moves[start_index] += 1;
        }
    }
}

impl<T> ApproximateSync<T> {
    fn flush_pending(&mut self) -> Vec<SyncedSet<T>> {
        let mut out = Vec::new();
        // Each round publishes one set (the candidate) and lets process() form the next; the
        // bound keeps this finite whatever the state.
        for _ in 0..=self.queue_size * self.num_streams {
            if self.candidate.is_none() {
                break;
            }
            self.publish_candidate(&mut out);
            self.process(&mut out);
        }
        out
    }
}

impl<T> Synchronizer<T> for ApproximateSync<T> {
    fn flush(&mut self) -> Flushed<T> {
        let sets = self.flush_pending();
        Flushed {
            sets,
            discarded: self.tally.take_step(),
        }
    }

    fn num_streams(&self) -> usize {
        self.num_streams
    }

    /// `add<i>()`.
    fn push(&mut self, stream: usize, stamp_ns: i64, msg: T) -> Result<Pushed<T>, SyncError> {
        check_index(stream, self.num_streams)?;
        // The stream's previous accepted stamp, for the lower-bound check (none after a reset).
        let previous = self.time.last[stream];
        let admission = self.time.admit(stream, stamp_ns, &mut self.tally.stats);
        let sets = match admission {
            Admission::Accepted => self.add(stream, stamp_ns, msg, previous),
            Admission::Reset(_) => {
                self.reset_buffers();
                self.add(stream, stamp_ns, msg, None)
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
        Ok(self.deques[stream].len() + self.past[stream].len())
    }

    fn last_reset(&self) -> Option<TimeJump> {
        self.time.last_reset
    }

    /// The pending candidate is published (as [`Synchronizer::flush`]); the rest, the queues
    /// with what a search had set aside put back, is handed back.
    fn drain(&mut self) -> Drained<T> {
        let sets = self.flush_pending();
        self.candidate = None;
        self.recover_all();
        self.has_dropped.iter_mut().for_each(|d| *d = false);
        let mut buffered: Vec<(usize, i64, T)> = self
            .deques
            .iter_mut()
            .enumerate()
            .flat_map(|(i, d)| d.drain(..).map(move |(t, m)| (i, t, m)))
            .collect();
        // Stable: each stream's messages keep their order.
        buffered.sort_by_key(|&(i, t, _)| (t, i));
        Drained {
            sets,
            discarded: self.tally.take_step(),
            buffered,
        }
    }
}

impl<T> ApproximateSync<T> {
    /// Adds an accepted message (`previous`: its stream's accepted stamp before it, for the
    /// lower-bound check); returns the sets this completes.
    fn add(
        &mut self,
        stream: usize,
        stamp_ns: i64,
        msg: T,
        previous: Option<i64>,
    ) -> Vec<SyncedSet<T>> {
        if let Some(last) = previous {
            let bound = self.lower_bounds_ns[stream];
            if stamp_ns.saturating_sub(last) < bound {
                self.bound_violations += 1;
                if !self.bound_warned[stream] {
                    self.bound_warned[stream] = true;
                    tracing::warn!(
                        stream,
                        gap_ns = stamp_ns.saturating_sub(last),
                        bound_ns = bound,
                        "messages arrived closer than the inter-message lower bound \
                         (warning once per stream)"
                    );
                }
            }
        }

        let mut out = Vec::new();
        self.deques[stream].push_back((stamp_ns, msg));
        if self.deques[stream].len() == 1 && self.all_non_empty() {
            self.process(&mut out);
        }
        // During process() the queue may transiently hold queue_size + 1 messages.
        if self.deques[stream].len() + self.past[stream].len() > self.queue_size {
            // Cancel the ongoing candidate search, if any, and drop the oldest message.
            self.recover_all();
            if self.deques[stream].pop_front().is_some() {
                self.tally.discard(1);
            }
            self.has_dropped[stream] = true;
            if self.candidate.take().is_some() {
                // There might still be enough messages to make a new candidate.
                self.process(&mut out);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ros::sync::test_support::*;

    // --- approximate -----------------------------------------------------------------------

    /// Checks that `sets` are exactly frames `0..m` for some `m >= frames - slack`, each with
    /// the right members.
    fn assert_all_frames(sets: &[SyncedSet<Msg>], frames: i64, slack: i64, evs: &[Ev]) {
        let got = frames_of(sets);
        assert!(
            got.len() as i64 >= frames - slack,
            "only {} sets: {got:?}",
            got.len()
        );
        assert_eq!(got, (0..got.len() as i64).collect::<Vec<_>>());
        for set in sets {
            assert_frame(set, set.messages[0].1, evs);
            assert!(set.span_ns() <= 16 * MS);
        }
    }

    #[test]
    fn approx_jittered_four_streams_one_set_per_frame() {
        for seed in 1..=20 {
            let n = 4;
            let frames = 60;
            let evs = schedule(n, frames, 100 * MS, 8 * MS, 30 * MS, seed, |_, _| true);
            let mut sync = ApproximateSync::new(n, 5).unwrap();
            let sets = run(&mut sync, &evs, 5);
            // The last frame may still be waiting for proof of optimality.
            assert_all_frames(&sets, frames, 1, &evs);
            assert_eq!(sync.stats().dropped, 0);
            assert_eq!(sync.stats().incomplete, 0);
            assert_conservation(&sync, evs.len() as u64);
        }
    }

    #[test]
    fn approx_jittered_with_cross_frame_interleaving() {
        // Latency up to 1.5 periods: frames k and k+1 arrive interleaved across streams.
        for seed in 1..=10 {
            let n = 4;
            let frames = 60;
            let evs = schedule(n, frames, 100 * MS, 8 * MS, 150 * MS, seed, |_, _| true);
            assert!(evs.windows(2).any(|w| w[0].k > w[1].k));
            let mut sync = ApproximateSync::new(n, 5).unwrap();
            let sets = run(&mut sync, &evs, 5);
            assert_all_frames(&sets, frames, 1, &evs);
            assert_eq!(sync.stats().dropped, 0);
            assert_conservation(&sync, evs.len() as u64);
        }
    }

    #[test]
    fn approx_twelve_streams() {
        for seed in 100..105 {
            let n = 12;
            let frames = 40;
            let evs = schedule(n, frames, 100 * MS, 8 * MS, 30 * MS, seed, |_, _| true);
            let mut sync = ApproximateSync::new(n, 4).unwrap();
            let sets = run(&mut sync, &evs, 4);
            assert_all_frames(&sets, frames, 1, &evs);
            assert!(sets.iter().all(|s| s.messages.len() == 12));
            assert_eq!(sync.stats().dropped, 0);
            assert_conservation(&sync, evs.len() as u64);
        }
    }

    #[test]
    fn approx_identical_stamps_emit_immediately() {
        let mut sync = ApproximateSync::new(3, 3).unwrap();
        assert!(sync.push(0, 500, (0, 0)).unwrap().sets.is_empty());
        assert!(sync.push(2, 500, (2, 0)).unwrap().sets.is_empty());
        let sets = sync.push(1, 500, (1, 0)).unwrap().sets;
        assert_eq!(sets.len(), 1);
        assert_eq!(sets[0].messages, vec![(0, 0), (1, 0), (2, 0)]);
        assert_eq!(sets[0].stamps_ns, vec![500; 3]);
    }

    #[test]
    fn approx_max_interval_rejects_wide_sets() {
        let n = 3;
        let frames = 40;
        // Even frames: stamps within +-1 ms (span <= 2 ms); odd frames: stream s is offset
        // by 5 ms * s (span 10 ms). max_interval is 3 ms, so only even frames may match.
        let mut rng = Rng(42);
        let mut evs = Vec::new();
        for k in 0..frames {
            for s in 0..n {
                let stamp = if k % 2 == 0 {
                    100 * MS * k + rng.range(-MS, MS)
                } else {
                    100 * MS * k + 5 * MS * s as i64
                };
                evs.push(Ev {
                    stream: s,
                    k,
                    stamp,
                    arrival: stamp + rng.range(0, 30 * MS),
                });
            }
        }
        evs.sort_by_key(|e| (e.arrival, e.stream));
        let mut sync = ApproximateSync::new(n, 5)
            .unwrap()
            .with_max_interval_ns(3 * MS)
            .unwrap();
        let sets = run(&mut sync, &evs, 5);
        let got = frames_of(&sets);
        let expected: Vec<i64> = (0..frames).step_by(2).collect();
        // The last even frame may still be pending.
        assert!(got.len() >= expected.len() - 1, "{got:?}");
        assert_eq!(got, expected[..got.len()].to_vec());
        for set in &sets {
            assert_frame(set, set.messages[0].1, &evs);
            assert!(set.span_ns() <= 3 * MS);
        }
        let st = sync.stats();
        assert!(st.dropped >= 3 * (frames as u64 / 2 - 1), "{st:?}");
        assert!(st.incomplete > 0);
        assert_conservation(&sync, evs.len() as u64);
    }

    #[test]
    fn approx_max_interval_below_jitter_emits_nothing() {
        let n = 4;
        // Stream s is offset by 3 ms * s plus +-1 ms jitter: every same-frame set spans >= 7
        // ms, every cross-frame set far more.
        let mut evs = schedule(n, 30, 100 * MS, MS, 30 * MS, 9, |_, _| true);
        for e in &mut evs {
            e.stamp += 3 * MS * e.stream as i64;
        }
        let mut sync = ApproximateSync::new(n, 5)
            .unwrap()
            .with_max_interval_ns(5 * MS)
            .unwrap();
        let sets = run(&mut sync, &evs, 5);
        assert!(sets.is_empty());
        let st = sync.stats();
        assert_eq!(st.matched, 0);
        assert!(st.dropped >= 4 * 28);
        assert_conservation(&sync, evs.len() as u64);

        // Same data without the bound: every frame is matched.
        let mut sync = ApproximateSync::new(n, 5).unwrap();
        let sets = run(&mut sync, &evs, 5);
        let got = frames_of(&sets);
        assert!(got.len() >= 29);
        assert_eq!(got, (0..got.len() as i64).collect::<Vec<_>>());
        for set in &sets {
            assert_frame(set, set.messages[0].1, &evs);
        }
    }

    #[test]
    fn approx_half_rate_stream() {
        for seed in 1..=10 {
            let n = 3;
            let frames = 41;
            // Stream 1 only sends even frames.
            let evs = schedule(n, frames, 100 * MS, 8 * MS, 30 * MS, seed, |s, k| {
                s != 1 || k % 2 == 0
            });
            let mut sync = ApproximateSync::new(n, 6).unwrap();
            let sets = run(&mut sync, &evs, 6);
            let got = frames_of(&sets);
            let expected: Vec<i64> = (0..frames).step_by(2).collect();
            assert!(got.len() >= expected.len() - 1, "seed {seed}: {got:?}");
            assert_eq!(got, expected[..got.len()].to_vec(), "seed {seed}");
            for set in &sets {
                assert_frame(set, set.messages[0].1, &evs);
            }
            // The odd frames of streams 0 and 2 are discarded (all but possibly the last).
            let st = sync.stats();
            assert!(st.dropped >= 2 * (frames as u64 / 2 - 1), "{st:?}");
            assert_conservation(&sync, evs.len() as u64);
        }
    }

    #[test]
    fn approx_bounded_memory_with_stalled_stream() {
        let n = 3;
        let q = 5;
        // Stream 2 is silent for frames 0..40, then resumes.
        let evs = schedule(n, 70, 100 * MS, 8 * MS, 30 * MS, 5, |s, k| {
            s != 2 || k >= 40
        });
        let mut sync = ApproximateSync::new(n, q).unwrap();
        let mut sets = Vec::new();
        let mut max_len = 0;
        for e in &evs {
            sets.extend(sync.push(e.stream, e.stamp, (e.stream, e.k)).unwrap().sets);
            for s in 0..n {
                let len = sync.queue_len(s).unwrap();
                assert!(len <= q);
                max_len = max_len.max(len);
            }
        }
        assert_eq!(max_len, q);
        let got = frames_of(&sets);
        assert!(got.len() >= 29, "{got:?}");
        assert_eq!(got, (40..40 + got.len() as i64).collect::<Vec<_>>());
        for set in &sets {
            assert_frame(set, set.messages[0].1, &evs);
        }
        let st = sync.stats();
        // At least the frames 0..35 of streams 0 and 1 were evicted.
        assert!(st.dropped >= 70, "{st:?}");
        assert_conservation(&sync, evs.len() as u64);
    }

    #[test]
    fn approx_out_of_order_message_is_dropped() {
        let mut sync = ApproximateSync::new(2, 5).unwrap();
        assert!(sync.push(0, 100 * MS, (0, 1)).unwrap().sets.is_empty());
        assert!(sync.push(0, 50 * MS, (0, 0)).unwrap().sets.is_empty()); // out of order
        assert_eq!(sync.queue_len(0).unwrap(), 1);
        assert_eq!(sync.stats().dropped, 1);
        assert_eq!(sync.stats().out_of_order, 1);
        assert_eq!(sync.stats().incomplete, 0);
        // An equal stamp is a duplicate: dropped (message_filters would accept it).
        assert!(sync.push(0, 100 * MS, (0, 2)).unwrap().sets.is_empty());
        assert_eq!(sync.queue_len(0).unwrap(), 1);
        assert_eq!(sync.stats().duplicates, 1);
        assert_eq!(sync.stats().dropped, 2);
        let mut sets = sync.push(1, 101 * MS, (1, 1)).unwrap().sets;
        sets.extend(sync.push(1, 201 * MS, (1, 2)).unwrap().sets);
        sets.extend(sync.push(0, 200 * MS, (0, 3)).unwrap().sets);
        sets.extend(sync.push(1, 301 * MS, (1, 3)).unwrap().sets);
        sets.extend(sync.push(0, 300 * MS, (0, 4)).unwrap().sets);
        // The 50 ms message never shows up.
        assert!(sets.iter().all(|s| s.messages[0] != (0, 0)));
        let pairs: Vec<Vec<i64>> = sets.iter().map(|s| s.stamps_ns.clone()).collect();
        assert_eq!(pairs[0], vec![100 * MS, 101 * MS]);
        assert_eq!(pairs[1], vec![200 * MS, 201 * MS]);
        assert_conservation(&sync, 8);
    }

    #[test]
    fn approx_lower_bound_lets_sets_out_earlier() {
        // Without bounds, {0 ms, 3 ms} cannot be proved optimal until stream 0 sends again.
        let mut plain = ApproximateSync::new(2, 5).unwrap();
        assert!(plain.push(0, 0, (0, 0)).unwrap().sets.is_empty());
        assert!(plain.push(1, 3 * MS, (1, 0)).unwrap().sets.is_empty());
        let sets = plain.push(0, 100 * MS, (0, 1)).unwrap().sets;
        assert_eq!(sets.len(), 1);
        assert_eq!(sets[0].stamps_ns, vec![0, 3 * MS]);

        // With a 90 ms lower bound on stream 0 the next message there cannot be closer to
        // 3 ms than the current one, so the set is emitted right away.
        let mut bounded = ApproximateSync::new(2, 5)
            .unwrap()
            .with_inter_message_lower_bound_ns(0, 90 * MS)
            .unwrap();
        assert!(bounded.push(0, 0, (0, 0)).unwrap().sets.is_empty());
        let sets = bounded.push(1, 3 * MS, (1, 0)).unwrap().sets;
        assert_eq!(sets.len(), 1);
        assert_eq!(sets[0].stamps_ns, vec![0, 3 * MS]);
        assert_eq!(bounded.bound_violations(), 0);
        // A violation is accepted but counted.
        assert!(bounded.push(0, 50 * MS, (0, 1)).unwrap().sets.is_empty());
        assert_eq!(bounded.bound_violations(), 1);
    }

    /// Pushes stream 1's messages at 0 and 32 ms, then stream 0's at 20 ms, through an
    /// approximate sync with `age_penalty`; returns the one set that push emits and the number
    /// of messages dropped.
    fn choice_with_age_penalty(age_penalty: f64) -> (SyncedSet<Msg>, u64) {
        let mut sync = ApproximateSync::new(2, 5)
            .unwrap()
            .with_age_penalty(age_penalty)
            .unwrap();
        assert!(sync.push(1, 0, (1, 0)).unwrap().sets.is_empty());
        assert!(sync.push(1, 32 * MS, (1, 1)).unwrap().sets.is_empty());
        let mut sets = sync.push(0, 20 * MS, (0, 0)).unwrap().sets;
        assert_eq!(sets.len(), 1, "{sets:?}");
        (sets.remove(0), sync.stats().dropped)
    }

    /// message_filters' ApproximateTime semantics of `age_penalty`: with stream 0's 20 ms as
    /// pivot, the older set {20, 0} (span 20 ms) is the first candidate and the newer set
    /// {20, 32} (span 12 ms) replaces it only if `12 * (1 + age_penalty) < 20 - 0`. Penalty 0
    /// (and the default 0.1: 13.2 < 20) picks the tighter newer set and drops the 0 ms message;
    /// penalty 1 (24 >= 20) keeps the older set and keeps 32 ms queued.
    #[test]
    fn approx_age_penalty_favours_the_older_set() {
        let (set, dropped) = choice_with_age_penalty(0.0);
        assert_eq!(set.stamps_ns, vec![20 * MS, 32 * MS]);
        assert_eq!(set.messages, vec![(0, 0), (1, 1)]);
        assert_eq!(dropped, 1);
        let (set, _) = choice_with_age_penalty(0.1);
        assert_eq!(set.stamps_ns, vec![20 * MS, 32 * MS]);
        let (set, dropped) = choice_with_age_penalty(1.0);
        assert_eq!(
            set.stamps_ns,
            vec![20 * MS, 0],
            "penalty 1 must keep the older set"
        );
        assert_eq!(set.messages, vec![(0, 0), (1, 0)]);
        assert_eq!(dropped, 0);
    }

    #[test]
    fn approx_picks_the_tightest_set() {
        // Stream 1 has two messages around stream 0's 100 ms: the closer one must be chosen,
        // and the other one dropped.
        let mut sync = ApproximateSync::new(2, 5).unwrap();
        let mut sets = Vec::new();
        sets.extend(sync.push(1, 90 * MS, (1, 0)).unwrap().sets);
        sets.extend(sync.push(1, 99 * MS, (1, 1)).unwrap().sets);
        sets.extend(sync.push(0, 100 * MS, (0, 1)).unwrap().sets);
        sets.extend(sync.push(1, 130 * MS, (1, 2)).unwrap().sets);
        sets.extend(sync.push(0, 200 * MS, (0, 2)).unwrap().sets);
        assert_eq!(sets[0].stamps_ns, vec![100 * MS, 99 * MS]);
        assert_eq!(sets[0].messages, vec![(0, 1), (1, 1)]);
        assert_eq!(sync.stats().dropped, 1); // the 90 ms message
        assert_eq!(sync.stats().incomplete, 1);
    }
}
