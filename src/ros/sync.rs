//! N-ary time synchronisation of stamped messages (camera images, camera infos, ...).
//!
//! Two policies, both generic over the payload `T` and over the number of input streams
//! `N >= 2` (no upper limit, unlike ROS `message_filters` which stops at 9):
//!
//! * [`ExactSync`]: emits a set when every stream has delivered a message with the *identical*
//!   stamp.
//! * [`ApproximateSync`]: a port of the `message_filters` `ApproximateTime` policy (algorithm by
//!   Vincent Rabaud), which emits the sets minimising the time span (latest stamp - earliest
//!   stamp), and only once it is certain that no better set can still arrive.
//!
//! Both implement [`Synchronizer`]. Stamps are `i64` nanoseconds (use
//! [`Synchronizer::push_stamped`] to feed a ROS `builtin_interfaces/Time` directly).
//!
//! # Counters
//!
//! Every message handed to `push` with a valid stream index ends up in exactly one of three
//! places: it is emitted in a [`SyncedSet`] (counted, per set, by [`SyncStats::matched`]), it is
//! discarded (counted, per message, by [`SyncStats::dropped`]), or it is still buffered
//! ([`Synchronizer::queue_len`]). Hence, at any moment,
//! `accepted_pushes == N * matched + dropped + sum(queue_len)`.
//! [`SyncStats::incomplete`] counts *abandoned partial sets*; what exactly that means depends on
//! the policy and is documented on [`ExactSync`] and [`ApproximateSync`].
//!
//! # Time rules (both policies)
//!
//! Stamps come from other machines, from bags played in a loop, from broken drivers. Before a
//! message reaches the policy, these rules (in this order) decide on it; `F` is
//! [`TimeRules::future_window_ns`] (default 10 s), `B` is [`TimeRules::reset_backwards_ns`]
//! (default 1 s), `last[i]` is the last stamp *accepted* on stream `i` since the last reset,
//! `seen[j]` the last stamp *pushed* on stream `j` (whatever became of it):
//!
//! 1. **Duplicate**: `t == last[i]` (the same stamp twice on one stream). Dropped, counted in
//!    [`SyncStats::duplicates`].
//! 2. **Time went backwards**: `t < last[i] - B` (a bag played in a loop, a restarted
//!    player, a clock stepped back). The synchroniser **resets**: every buffered message is
//!    discarded (counted in `dropped`, the discard once in `incomplete`), every stream's `last`
//!    is forgotten, [`SyncStats::resets`] counts it, [`Synchronizer::last_reset`] says which
//!    stream jumped from which stamp to which, and the message is accepted as the first of the
//!    new timeline.
//! 3. **Out of order**: `t < last[i]` by at most `B` (a late message). Dropped, counted in
//!    [`SyncStats::out_of_order`].
//! 4. **Future**: `t > max(seen[j], j != i) + F` (a stamp far ahead of every other stream;
//!    no rule while no other stream has pushed anything). Dropped, counted in
//!    [`SyncStats::future`]; it never enters a queue nor moves `last[i]`, so it cannot poison
//!    the stream. Since `seen` includes rejected stamps, a jump of the whole rig forward costs
//!    one message (the first stream to jump), not the stream.
//! 5. **From before a reset**: after a reset that jumped from `f` to `r`, a stream that has not
//!    delivered since the reset and sends `t > (r + f) / 2` (closer to the old timeline: a
//!    message of the previous loop still in flight) is dropped, counted in `out_of_order`; the
//!    rule ends once the new timeline's newest accepted stamp passes `(r + f) / 2`.
//! 6. Anything else is accepted and handed to the policy.
//!
//! A stamp `F` or less ahead is accepted; if it was bogus, the stream's next normal stamp is
//! more than `B` behind it and rule 2 resets the synchroniser, so no bogus stamp outlives one
//! reset. The rules keep every invariant of the policies: at most `queue_size` messages per
//! stream, one message per stream in every set, and the conservation above (rejected messages
//! count in `dropped`).

use std::collections::{BTreeMap, VecDeque};

use crate::msgs::Time;

/// Errors of the synchronisers. None of them is fatal: the synchroniser is unchanged.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SyncError {
    /// `push` (or a per-stream setter) was given a stream index `>= num_streams`.
    #[error("stream index {stream} out of range: the synchroniser has {num_streams} streams")]
    StreamOutOfRange { stream: usize, num_streams: usize },
    /// A synchroniser needs at least two streams.
    #[error("a synchroniser needs at least 2 input streams, got {0}")]
    TooFewStreams(usize),
    /// `queue_size` must be at least 1.
    #[error("queue_size must be at least 1")]
    ZeroQueueSize,
    /// A policy parameter is out of its domain.
    #[error("invalid parameter `{name}`: {reason}")]
    InvalidParameter { name: &'static str, reason: String },
}

/// One synchronised set: exactly one message per stream, in stream order.
#[derive(Debug, Clone, PartialEq)]
pub struct SyncedSet<T> {
    /// `stamps_ns[i]` is the stamp of `messages[i]`, the message of stream `i`.
    pub stamps_ns: Vec<i64>,
    /// One message per stream, indexed by stream.
    pub messages: Vec<T>,
}

impl<T> SyncedSet<T> {
    /// Latest stamp minus earliest stamp of the set (0 for exact sets).
    pub fn span_ns(&self) -> i64 {
        let min = self.stamps_ns.iter().copied().min().unwrap_or(0);
        let max = self.stamps_ns.iter().copied().max().unwrap_or(0);
        max.saturating_sub(min)
    }
}

/// Running counters of a synchroniser (monotonic, never reset).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SyncStats {
    /// Number of sets emitted (each holds one message per stream).
    pub matched: u64,
    /// Number of *messages* discarded without ever being emitted: rejected on arrival (stamp
    /// older than the stream's previous accepted stamp; for [`ExactSync`] also equal to it),
    /// evicted by a queue overflow, or discarded by the policy (see each policy).
    pub dropped: u64,
    /// Number of abandoned *partial sets*: groups of buffered messages, from some but not all
    /// streams, discarded together without being emitted. Each such group counts once however
    /// many messages it held (those are counted in `dropped`). See each policy for precisely
    /// what forms a group.
    pub incomplete: u64,
    /// Messages dropped on arrival because their stream already delivered that stamp (time
    /// rule 1; also in `dropped`).
    pub duplicates: u64,
    /// Messages dropped on arrival as older than their stream's last accepted stamp by at most
    /// the reset threshold, or as a message from before a reset (time rules 3 and 5; also in
    /// `dropped`).
    pub out_of_order: u64,
    /// Messages dropped on arrival because their stamp was more than the future window ahead of
    /// every other stream (time rule 4; also in `dropped`).
    pub future: u64,
    /// Resets after a stream's time went backwards by more than the reset threshold (time
    /// rule 2).
    pub resets: u64,
}

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
    fn check(&self) -> Result<(), SyncError> {
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

/// What the time rules make of a pushed stamp.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Verdict {
    Accept,
    /// Discard everything buffered, then accept.
    ResetThenAccept,
    Duplicate,
    OutOfOrder,
    Future,
}

/// The per-stream time state behind the time rules (shared by both policies).
#[derive(Debug, Clone)]
struct TimeGuard {
    rules: TimeRules,
    /// Last accepted stamp per stream since the last reset.
    last: Vec<Option<i64>>,
    /// Last pushed stamp per stream, whatever its verdict.
    seen: Vec<Option<i64>>,
    /// Newest accepted stamp since the last reset.
    newest: Option<i64>,
    /// After a reset: the midpoint between the old and the new timeline (rule 5).
    reset_midpoint: Option<i64>,
    last_reset: Option<TimeJump>,
}

impl TimeGuard {
    fn new(num_streams: usize) -> Self {
        Self {
            rules: TimeRules::default(),
            last: vec![None; num_streams],
            seen: vec![None; num_streams],
            newest: None,
            reset_midpoint: None,
            last_reset: None,
        }
    }

    /// Applies the rules to stamp `t` of `stream` (a valid index), updates the state and the
    /// counters of the rejections; the caller discards its buffers on `ResetThenAccept`.
    fn admit(&mut self, stream: usize, t: i64, stats: &mut SyncStats) -> Verdict {
        let verdict = self.verdict(stream, t);
        if let Some(seen) = self.seen.get_mut(stream) {
            *seen = Some(t);
        }
        match verdict {
            Verdict::Accept => self.accept(stream, t),
            Verdict::ResetThenAccept => {
                let from = self.last.get(stream).copied().flatten().unwrap_or(t);
                self.last.iter_mut().for_each(|l| *l = None);
                self.newest = None;
                self.reset_midpoint = Some(t.saturating_add(from.saturating_sub(t) / 2));
                self.last_reset = Some(TimeJump {
                    stream,
                    from_ns: from,
                    to_ns: t,
                });
                stats.resets += 1;
                self.accept(stream, t);
            }
            Verdict::Duplicate => {
                stats.duplicates += 1;
                stats.dropped += 1;
            }
            Verdict::OutOfOrder => {
                stats.out_of_order += 1;
                stats.dropped += 1;
            }
            Verdict::Future => {
                stats.future += 1;
                stats.dropped += 1;
            }
        }
        verdict
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
                return Verdict::Duplicate;
            }
            if last.saturating_sub(t) > self.rules.reset_backwards_ns {
                return Verdict::ResetThenAccept;
            }
            if t < last {
                return Verdict::OutOfOrder;
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
            return Verdict::Future;
        }
        if last.is_none() && self.reset_midpoint.is_some_and(|mid| t > mid) {
            return Verdict::OutOfOrder;
        }
        Verdict::Accept
    }
}

/// Common interface of the synchronisation policies.
pub trait Synchronizer<T> {
    /// Number of input streams `N`.
    fn num_streams(&self) -> usize;

    /// Feeds `msg`, stamped `stamp_ns` (nanoseconds), on input `stream` (`0..N`). Returns the
    /// sets this message completed (zero, one, or for [`ApproximateSync`] possibly several, in
    /// chronological order). An out-of-range `stream` is an error and changes nothing.
    fn push(
        &mut self,
        stream: usize,
        stamp_ns: i64,
        msg: T,
    ) -> Result<Vec<SyncedSet<T>>, SyncError>;

    /// The counters (see [`SyncStats`]).
    fn stats(&self) -> SyncStats;

    /// Number of messages of `stream` currently buffered; never exceeds the `queue_size` the
    /// synchroniser was built with once `push` has returned.
    fn queue_len(&self, stream: usize) -> Result<usize, SyncError>;

    /// The latest reset (time rule 2), if any.
    fn last_reset(&self) -> Option<TimeJump>;

    /// End of input (the end of a bag): emits the sets that were only waiting for later
    /// messages to prove them best. [`ApproximateSync`] publishes its pending candidate (with
    /// no more messages to come, no better one can form) and goes on while it can; exact
    /// matching has nothing pending that could complete.
    fn flush(&mut self) -> Vec<SyncedSet<T>> {
        Vec::new()
    }

    /// [`Synchronizer::push`] with a ROS `builtin_interfaces/Time` stamp.
    fn push_stamped(
        &mut self,
        stream: usize,
        stamp: &Time,
        msg: T,
    ) -> Result<Vec<SyncedSet<T>>, SyncError> {
        self.push(stream, time_to_ns(stamp), msg)
    }
}

/// ROS time to signed nanoseconds since the epoch. Cannot overflow: `|sec| * 1e9 + nanosec`
/// stays below `2^62` even for a malformed `nanosec >= 1e9`.
fn time_to_ns(t: &Time) -> i64 {
    i64::from(t.sec) * 1_000_000_000 + i64::from(t.nanosec)
}

fn check_streams(num_streams: usize, queue_size: usize) -> Result<(), SyncError> {
    if num_streams < 2 {
        return Err(SyncError::TooFewStreams(num_streams));
    }
    if queue_size == 0 {
        return Err(SyncError::ZeroQueueSize);
    }
    Ok(())
}

fn check_index(stream: usize, num_streams: usize) -> Result<(), SyncError> {
    if stream < num_streams {
        Ok(())
    } else {
        Err(SyncError::StreamOutOfRange {
            stream,
            num_streams,
        })
    }
}

// ---------------------------------------------------------------------------------------------
// Exact
// ---------------------------------------------------------------------------------------------

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
    stats: SyncStats,
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
            stats: SyncStats::default(),
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
        if bucket.present > 0 {
            self.stats.dropped += bucket.present as u64;
            self.stats.incomplete += 1;
        }
    }
}

impl<T> Synchronizer<T> for ExactSync<T> {
    fn num_streams(&self) -> usize {
        self.num_streams
    }

    fn push(
        &mut self,
        stream: usize,
        stamp_ns: i64,
        msg: T,
    ) -> Result<Vec<SyncedSet<T>>, SyncError> {
        check_index(stream, self.num_streams)?;
        match self.time.admit(stream, stamp_ns, &mut self.stats) {
            Verdict::Accept => {}
            Verdict::ResetThenAccept => {
                for (_, bucket) in std::mem::take(&mut self.pending) {
                    self.discard(bucket);
                }
            }
            Verdict::Duplicate | Verdict::OutOfOrder | Verdict::Future => return Ok(Vec::new()),
        }

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
                self.stats.matched += 1;
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
            return Ok(out);
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
        Ok(Vec::new())
    }

    fn stats(&self) -> SyncStats {
        self.stats
    }

    fn queue_len(&self, stream: usize) -> Result<usize, SyncError> {
        check_index(stream, self.num_streams)?;
        Ok(self.counts[stream])
    }

    fn last_reset(&self) -> Option<TimeJump> {
        self.time.last_reset
    }
}

// ---------------------------------------------------------------------------------------------
// Approximate
// ---------------------------------------------------------------------------------------------

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
    stats: SyncStats,
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
            stats: SyncStats::default(),
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
        if discarded > 0 {
            self.stats.dropped += discarded as u64;
            self.stats.incomplete += 1;
        }
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
            self.stats.dropped += 1;
            self.stats.incomplete += 1;
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
        if discarded > 0 {
            self.stats.dropped += discarded as u64;
            self.stats.incomplete += 1;
        }
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
            self.stats.matched += 1;
            out.push(SyncedSet {
                stamps_ns,
                messages,
            });
        } else if !messages.is_empty() {
            // Unreachable: a candidate holds one message per stream.
            self.stats.dropped += messages.len() as u64;
            self.stats.incomplete += 1;
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
    fn flush(&mut self) -> Vec<SyncedSet<T>> {
        self.flush_pending()
    }

    fn num_streams(&self) -> usize {
        self.num_streams
    }

    /// `add<i>()`.
    fn push(
        &mut self,
        stream: usize,
        stamp_ns: i64,
        msg: T,
    ) -> Result<Vec<SyncedSet<T>>, SyncError> {
        check_index(stream, self.num_streams)?;
        // The stream's previous accepted stamp, for the lower-bound check (none after a reset).
        let mut previous = self.time.last[stream];
        match self.time.admit(stream, stamp_ns, &mut self.stats) {
            Verdict::Accept => {}
            Verdict::ResetThenAccept => {
                previous = None;
                self.reset_buffers();
            }
            Verdict::Duplicate | Verdict::OutOfOrder | Verdict::Future => return Ok(Vec::new()),
        }
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
                self.stats.dropped += 1;
                self.stats.incomplete += 1;
            }
            self.has_dropped[stream] = true;
            if self.candidate.take().is_some() {
                // There might still be enough messages to make a new candidate.
                self.process(&mut out);
            }
        }
        Ok(out)
    }

    fn stats(&self) -> SyncStats {
        self.stats
    }

    fn queue_len(&self, stream: usize) -> Result<usize, SyncError> {
        check_index(stream, self.num_streams)?;
        Ok(self.deques[stream].len() + self.past[stream].len())
    }

    fn last_reset(&self) -> Option<TimeJump> {
        self.time.last_reset
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: i64 = 1_000_000;

    /// Deterministic xorshift64* generator.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
        }
        /// Uniform in `lo..=hi`.
        fn range(&mut self, lo: i64, hi: i64) -> i64 {
            lo + (self.next() % (hi - lo + 1) as u64) as i64
        }
    }

    /// Payload: (stream, k) so that tests can check set membership.
    type Msg = (usize, i64);

    #[derive(Debug, Clone, Copy)]
    struct Ev {
        stream: usize,
        k: i64,
        stamp: i64,
        arrival: i64,
    }

    /// Stream `s` sends frame `k` (when `keep(s, k)`) stamped `period * k + jitter` (uniform in
    /// `-jitter..=jitter`), arriving after a random latency in `0..=max_latency` but never
    /// before the stream's previous message; events sorted by arrival time, which shuffles the
    /// streams within a window of about `max_latency + 2 * jitter`.
    fn schedule(
        n: usize,
        frames: i64,
        period: i64,
        jitter: i64,
        max_latency: i64,
        seed: u64,
        keep: impl Fn(usize, i64) -> bool,
    ) -> Vec<Ev> {
        let mut rng = Rng(seed);
        let mut evs = Vec::new();
        // Each stream is a FIFO (as a ROS topic): a message never overtakes its predecessor.
        let mut fifo = vec![i64::MIN; n];
        for k in 0..frames {
            for (s, prev) in fifo.iter_mut().enumerate() {
                let stamp = period * k + rng.range(-jitter, jitter);
                let arrival = (stamp + rng.range(0, max_latency)).max(*prev);
                *prev = arrival;
                if keep(s, k) {
                    evs.push(Ev {
                        stream: s,
                        k,
                        stamp,
                        arrival,
                    });
                }
            }
        }
        evs.sort_by_key(|e| (e.arrival, e.stream));
        evs
    }

    /// Feeds `evs`, checking the queue bound after every push; returns the emitted sets.
    fn run(sync: &mut dyn Synchronizer<Msg>, evs: &[Ev], queue_size: usize) -> Vec<SyncedSet<Msg>> {
        let mut out = Vec::new();
        for e in evs {
            let sets = sync.push(e.stream, e.stamp, (e.stream, e.k)).unwrap();
            out.extend(sets);
            for s in 0..sync.num_streams() {
                assert!(sync.queue_len(s).unwrap() <= queue_size);
            }
        }
        out
    }

    /// Asserts that `set` holds, on every stream, exactly the message of frame `k`, with the
    /// stamp that was sent.
    fn assert_frame(set: &SyncedSet<Msg>, k: i64, evs: &[Ev]) {
        let n = set.messages.len();
        for s in 0..n {
            assert_eq!(set.messages[s], (s, k), "stream {s} of frame {k}: {set:?}");
            let sent = evs
                .iter()
                .find(|e| e.stream == s && e.k == k)
                .map(|e| e.stamp);
            assert_eq!(Some(set.stamps_ns[s]), sent);
        }
    }

    fn frames_of(sets: &[SyncedSet<Msg>]) -> Vec<i64> {
        sets.iter().map(|s| s.messages[0].1).collect()
    }

    /// `accepted == N * matched + dropped + buffered`.
    fn assert_conservation(sync: &dyn Synchronizer<Msg>, accepted: u64) {
        let st = sync.stats();
        let buffered: usize = (0..sync.num_streams())
            .map(|s| sync.queue_len(s).unwrap())
            .sum();
        assert_eq!(
            accepted,
            sync.num_streams() as u64 * st.matched + st.dropped + buffered as u64,
            "{st:?}"
        );
    }

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
        assert!(sync.push(0, 1000, (0, 0)).unwrap().is_empty());
        assert!(sync.push(1, 1001, (1, 0)).unwrap().is_empty());
        let sets = sync.push(1, 2000, (1, 1)).unwrap();
        assert!(sets.is_empty());
        let sets = sync.push(0, 2000, (0, 1)).unwrap();
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
        assert!(sync.push(0, 200, (0, 2)).unwrap().is_empty());
        assert!(sync.push(0, 100, (0, 1)).unwrap().is_empty()); // out of order
        assert!(sync.push(0, 200, (0, 99)).unwrap().is_empty()); // duplicate stamp
        assert_eq!(sync.queue_len(0).unwrap(), 1);
        assert!(sync.push(1, 100, (1, 1)).unwrap().is_empty());
        let sets = sync.push(1, 200, (1, 2)).unwrap();
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
        assert!(sync.push_stamped(0, &t, (0, 0)).unwrap().is_empty());
        let sets = sync.push(1, 3_000_000_250, (1, 0)).unwrap();
        assert_eq!(sets[0].stamps_ns, vec![3_000_000_250; 2]);
        assert_eq!(
            time_to_ns(&Time {
                sec: -1,
                nanosec: 5
            }),
            -999_999_995
        );
    }

    // --- errors ----------------------------------------------------------------------------

    #[test]
    fn bad_stream_index_is_an_error() {
        let mut exact = ExactSync::<u8>::new(3, 4).unwrap();
        let mut approx = ApproximateSync::<u8>::new(3, 4).unwrap();
        let err = SyncError::StreamOutOfRange {
            stream: 3,
            num_streams: 3,
        };
        assert_eq!(exact.push(3, 0, 0), Err(err.clone()));
        assert_eq!(approx.push(3, 0, 0), Err(err.clone()));
        let msg = exact.push(usize::MAX, 0, 0).unwrap_err().to_string();
        assert!(msg.contains("out of range"), "{msg}");
        assert_eq!(exact.queue_len(3), Err(err.clone()));
        assert_eq!(approx.queue_len(3), Err(err));
        assert_eq!(exact.stats(), SyncStats::default());
        assert_eq!(approx.stats(), SyncStats::default());
        // Construction errors.
        assert_eq!(
            ExactSync::<u8>::new(1, 4).unwrap_err(),
            SyncError::TooFewStreams(1)
        );
        assert_eq!(
            ApproximateSync::<u8>::new(0, 4).unwrap_err(),
            SyncError::TooFewStreams(0)
        );
        assert_eq!(
            ApproximateSync::<u8>::new(2, 0).unwrap_err(),
            SyncError::ZeroQueueSize
        );
        let a = || ApproximateSync::<u8>::new(2, 3).unwrap();
        assert!(a().with_age_penalty(-0.5).is_err());
        assert!(a().with_age_penalty(f64::NAN).is_err());
        assert!(a().with_max_interval_ns(-1).is_err());
        assert!(a().with_inter_message_lower_bound_ns(2, 5).is_err());
        assert!(a().with_inter_message_lower_bound_ns(1, -5).is_err());
    }

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
        assert!(sync.push(0, 500, (0, 0)).unwrap().is_empty());
        assert!(sync.push(2, 500, (2, 0)).unwrap().is_empty());
        let sets = sync.push(1, 500, (1, 0)).unwrap();
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
            sets.extend(sync.push(e.stream, e.stamp, (e.stream, e.k)).unwrap());
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
        assert!(sync.push(0, 100 * MS, (0, 1)).unwrap().is_empty());
        assert!(sync.push(0, 50 * MS, (0, 0)).unwrap().is_empty()); // out of order
        assert_eq!(sync.queue_len(0).unwrap(), 1);
        assert_eq!(sync.stats().dropped, 1);
        assert_eq!(sync.stats().out_of_order, 1);
        assert_eq!(sync.stats().incomplete, 0);
        // An equal stamp is a duplicate: dropped (message_filters would accept it).
        assert!(sync.push(0, 100 * MS, (0, 2)).unwrap().is_empty());
        assert_eq!(sync.queue_len(0).unwrap(), 1);
        assert_eq!(sync.stats().duplicates, 1);
        assert_eq!(sync.stats().dropped, 2);
        let mut sets = sync.push(1, 101 * MS, (1, 1)).unwrap();
        sets.extend(sync.push(1, 201 * MS, (1, 2)).unwrap());
        sets.extend(sync.push(0, 200 * MS, (0, 3)).unwrap());
        sets.extend(sync.push(1, 301 * MS, (1, 3)).unwrap());
        sets.extend(sync.push(0, 300 * MS, (0, 4)).unwrap());
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
        assert!(plain.push(0, 0, (0, 0)).unwrap().is_empty());
        assert!(plain.push(1, 3 * MS, (1, 0)).unwrap().is_empty());
        let sets = plain.push(0, 100 * MS, (0, 1)).unwrap();
        assert_eq!(sets.len(), 1);
        assert_eq!(sets[0].stamps_ns, vec![0, 3 * MS]);

        // With a 90 ms lower bound on stream 0 the next message there cannot be closer to
        // 3 ms than the current one, so the set is emitted right away.
        let mut bounded = ApproximateSync::new(2, 5)
            .unwrap()
            .with_inter_message_lower_bound_ns(0, 90 * MS)
            .unwrap();
        assert!(bounded.push(0, 0, (0, 0)).unwrap().is_empty());
        let sets = bounded.push(1, 3 * MS, (1, 0)).unwrap();
        assert_eq!(sets.len(), 1);
        assert_eq!(sets[0].stamps_ns, vec![0, 3 * MS]);
        assert_eq!(bounded.bound_violations(), 0);
        // A violation is accepted but counted.
        assert!(bounded.push(0, 50 * MS, (0, 1)).unwrap().is_empty());
        assert_eq!(bounded.bound_violations(), 1);
    }

    #[test]
    fn approx_picks_the_tightest_set() {
        // Stream 1 has two messages around stream 0's 100 ms: the closer one must be chosen,
        // and the other one dropped.
        let mut sync = ApproximateSync::new(2, 5).unwrap();
        let mut sets = Vec::new();
        sets.extend(sync.push(1, 90 * MS, (1, 0)).unwrap());
        sets.extend(sync.push(1, 99 * MS, (1, 1)).unwrap());
        sets.extend(sync.push(0, 100 * MS, (0, 1)).unwrap());
        sets.extend(sync.push(1, 130 * MS, (1, 2)).unwrap());
        sets.extend(sync.push(0, 200 * MS, (0, 2)).unwrap());
        assert_eq!(sets[0].stamps_ns, vec![100 * MS, 99 * MS]);
        assert_eq!(sets[0].messages, vec![(0, 1), (1, 1)]);
        assert_eq!(sync.stats().dropped, 1); // the 90 ms message
        assert_eq!(sync.stats().incomplete, 1);
    }

    #[test]
    fn random_streams_conserve_messages() {
        // Random rates, gaps and bursts: the conservation law and the queue bound hold, sets
        // are chronological per stream, and no message is emitted twice.
        for seed in 1..=30u64 {
            let mut rng = Rng(seed * 7919);
            let n = 2 + (rng.next() % 6) as usize;
            let q = 1 + (rng.next() % 6) as usize;
            let mut stamps = vec![0i64; n];
            let mut exact = ExactSync::new(n, q).unwrap();
            let mut approx = ApproximateSync::new(n, q)
                .unwrap()
                .with_max_interval_ns(rng.range(0, 40) * MS)
                .unwrap();
            let mut last_exact = vec![i64::MIN; n];
            let mut last_approx = vec![i64::MIN; n];
            let mut seen = std::collections::HashSet::new();
            let pushes = 600;
            for id in 0..pushes {
                let s = (rng.next() % n as u64) as usize;
                // Mostly forward steps, sometimes backward (out of order) or repeated.
                stamps[s] += rng.range(-5, 60) / 10 * 10 * MS;
                let t = stamps[s];
                for set in exact.push(s, t, (s, id)).unwrap() {
                    assert!(set.stamps_ns.iter().all(|&x| x == set.stamps_ns[0]));
                    for (i, &x) in set.stamps_ns.iter().enumerate() {
                        assert!(x > last_exact[i]);
                        last_exact[i] = x;
                        assert_eq!(set.messages[i].0, i);
                    }
                }
                for set in approx.push(s, t, (s, id)).unwrap() {
                    assert!(set.span_ns() <= approx.max_interval_ns());
                    for (i, &x) in set.stamps_ns.iter().enumerate() {
                        assert!(x >= last_approx[i]);
                        last_approx[i] = x;
                        assert_eq!(set.messages[i].0, i);
                        assert!(seen.insert(set.messages[i]));
                    }
                }
                for i in 0..n {
                    assert!(exact.queue_len(i).unwrap() <= q);
                    assert!(approx.queue_len(i).unwrap() <= q);
                }
            }
            assert_conservation(&exact, pushes as u64);
            assert_conservation(&approx, pushes as u64);
        }
    }

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
            assert!(sync.push(0, 100 * MS, (0, 1)).unwrap().is_empty());
            assert!(sync.push(0, 100 * MS, (0, 99)).unwrap().is_empty());
            assert_eq!(sync.queue_len(0).unwrap(), 1, "{policy}");
            let mut sets = sync.push(1, 100 * MS, (1, 1)).unwrap();
            sets.extend(sync.push(0, 200 * MS, (0, 2)).unwrap());
            sets.extend(sync.push(1, 200 * MS, (1, 2)).unwrap());
            sets.extend(sync.push(1, 200 * MS, (1, 99)).unwrap());
            sets.extend(sync.push(0, 300 * MS, (0, 3)).unwrap());
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
                    sets.extend(sync.push(s, k * 100 * MS, (s, k)).unwrap());
                    pushes += 1;
                }
                if k == 5 {
                    // One hour ahead on stream 1, then the stream carries on normally.
                    sets.extend(sync.push(1, 3600 * 1000 * MS, (1, -1)).unwrap());
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
                    sets.extend(sync.push(s, t, (s, k)).unwrap());
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
                    sets.extend(sync.push(s, k * 100 * MS, (s, k)).unwrap());
                }
                if k == 5 {
                    // 5 s ahead on stream 0: within the window, accepted; its next normal
                    // stamp is 4.4 s behind it and resets the synchroniser.
                    sets.extend(sync.push(0, 5600 * MS, (0, -1)).unwrap());
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
                    sync.push(s, t, (s, k)).unwrap();
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
            sync.push(0, 1000 * MS, (0, 0)).unwrap();
            sync.push(0, 800 * MS, (0, 1)).unwrap(); // 200 ms back: late, dropped
            assert_eq!((sync.stats().out_of_order, sync.stats().resets), (1, 0));
            sync.push(0, 600 * MS, (0, 2)).unwrap(); // 400 ms back: reset
            assert_eq!(sync.stats().resets, 1);
            assert_eq!(sync.queue_len(0).unwrap(), 1);
            // Until the new timeline passes the midpoint (600 + 1000) / 2 = 800 ms, a stream
            // that has not delivered since the reset is refused above it (rule 5).
            sync.push(1, 850 * MS, (1, 0)).unwrap();
            assert_eq!(
                (sync.stats().out_of_order, sync.queue_len(1).unwrap()),
                (2, 0)
            );
            sync.push(0, 900 * MS, (0, 3)).unwrap();
            sync.push(1, 2950 * MS, (1, 1)).unwrap(); // 2.05 s ahead of stream 0: future
            assert_eq!(sync.stats().future, 1);
            assert_eq!(sync.queue_len(1).unwrap(), 0);
            sync.push(1, 2850 * MS, (1, 2)).unwrap(); // 1.95 s ahead: accepted
            assert_eq!(sync.queue_len(1).unwrap(), 1);
            assert_eq!(sync.stats().out_of_order, 2);
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
