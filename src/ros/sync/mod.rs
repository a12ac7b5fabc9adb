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
//! [`Synchronizer::push_stamped`] to feed a ROS `builtin_interfaces/Time` directly). The files:
//! [`time_rules`] (what happens to a stamp before any policy sees it), [`exact`],
//! [`approximate`].
//!
//! # What a push returns
//!
//! Every push returns its verdict ([`Pushed`]): what the time rules made of the message
//! ([`Admission`]: accepted, dropped and why, or a reset), the sets it completed, and the
//! buffered messages it discarded. A caller counts verdicts ([`SyncStats::count`]); the
//! synchroniser's own running totals ([`Synchronizer::stats`]) are the sum of them.
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

pub mod approximate;
pub mod exact;
pub mod time_rules;

#[cfg(test)]
mod test_support;

pub use approximate::ApproximateSync;
pub use exact::ExactSync;
pub use time_rules::{TimeJump, TimeRules, DEFAULT_FUTURE_WINDOW_NS, DEFAULT_RESET_BACKWARDS_NS};

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

/// Why the time rules dropped a message on arrival.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DropReason {
    /// Rule 1: the stream already delivered this stamp.
    Duplicate,
    /// Rule 3: older than the stream's last accepted stamp, by at most the reset threshold.
    Late,
    /// Rule 4: more than the future window ahead of every other stream.
    Future,
    /// Rule 5: a message of the timeline before the last reset, still in flight.
    BeforeReset,
}

/// What the time rules made of a pushed message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Admission {
    /// Accepted and handed to the policy.
    Accepted,
    /// Rule 2: the stream's time went back by more than the reset threshold. Everything
    /// buffered was discarded and the message starts the new timeline.
    Reset(TimeJump),
    /// Dropped on arrival; it never entered a queue.
    Dropped(DropReason),
}

/// Buffered messages discarded without being emitted, and the partial sets they formed (each
/// policy documents what forms one).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Discarded {
    pub messages: u64,
    pub partial_sets: u64,
}

/// The verdict of one push.
#[derive(Debug, Clone, PartialEq)]
#[must_use]
pub struct Pushed<T> {
    pub admission: Admission,
    /// The sets the message completed, in chronological order.
    pub sets: Vec<SyncedSet<T>>,
    /// What the push discarded from the queues (on a reset: everything that was buffered).
    pub discarded: Discarded,
}

/// What [`Synchronizer::flush`] emitted and discarded.
#[derive(Debug, Clone, PartialEq)]
#[must_use]
pub struct Flushed<T> {
    pub sets: Vec<SyncedSet<T>>,
    pub discarded: Discarded,
}

/// What [`Synchronizer::drain`] emitted and handed back.
#[derive(Debug, Clone, PartialEq)]
#[must_use]
pub struct Drained<T> {
    /// The sets [`Synchronizer::flush`] would emit.
    pub sets: Vec<SyncedSet<T>>,
    pub discarded: Discarded,
    /// Every message still buffered, as `(stream, stamp_ns, message)`, in stamp order (ties
    /// in stream order; each stream's in the order it was pushed).
    pub buffered: Vec<(usize, i64, T)>,
}

impl SyncStats {
    /// Counts one push's verdict (`admission`), or a flush's (`None`): the sets it emitted and
    /// what it discarded. A synchroniser's [`Synchronizer::stats`] is the sum of its pushes'.
    pub fn count(&mut self, admission: Option<Admission>, emitted: usize, discarded: Discarded) {
        self.matched += emitted as u64;
        self.dropped += discarded.messages;
        self.incomplete += discarded.partial_sets;
        match admission {
            Some(Admission::Dropped(reason)) => {
                self.dropped += 1;
                match reason {
                    DropReason::Duplicate => self.duplicates += 1,
                    DropReason::Late | DropReason::BeforeReset => self.out_of_order += 1,
                    DropReason::Future => self.future += 1,
                }
            }
            Some(Admission::Reset(_)) => self.resets += 1,
            Some(Admission::Accepted) | None => {}
        }
    }

    /// [`SyncStats::count`] for a push.
    pub fn count_push<T>(&mut self, pushed: &Pushed<T>) {
        self.count(Some(pushed.admission), pushed.sets.len(), pushed.discarded);
    }
}

/// A policy's running totals and what the current push has discarded so far.
#[derive(Debug, Default)]
pub(super) struct Tally {
    pub stats: SyncStats,
    step: Discarded,
}

impl Tally {
    /// `messages` buffered messages discarded together: one abandoned partial set (nothing
    /// when `messages` is 0).
    pub fn discard(&mut self, messages: u64) {
        if messages == 0 {
            return;
        }
        self.stats.dropped += messages;
        self.stats.incomplete += 1;
        self.step.messages += messages;
        self.step.partial_sets += 1;
    }

    /// What was discarded since the last call (the end of the previous push).
    pub fn take_step(&mut self) -> Discarded {
        std::mem::take(&mut self.step)
    }
}

/// Common interface of the synchronisation policies.
pub trait Synchronizer<T> {
    /// Number of input streams `N`.
    fn num_streams(&self) -> usize;

    /// Feeds `msg`, stamped `stamp_ns` (nanoseconds), on input `stream` (`0..N`). Returns the
    /// verdict on it and the sets it completed (zero, one, or for [`ApproximateSync`] possibly
    /// several, in chronological order). An out-of-range `stream` is an error and changes
    /// nothing.
    fn push(&mut self, stream: usize, stamp_ns: i64, msg: T) -> Result<Pushed<T>, SyncError>;

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
    fn flush(&mut self) -> Flushed<T> {
        Flushed {
            sets: Vec::new(),
            discarded: Discarded::default(),
        }
    }

    /// The streams change (a camera left or rejoined the rig): this synchroniser's input
    /// ends, and what it holds moves on to a synchroniser over the new streams. Emits the sets
    /// [`Synchronizer::flush`] would, then hands back every message still buffered
    /// ([`Drained::buffered`]) and leaves the queues empty. The messages handed back left
    /// the synchroniser: they count in no counter (neither matched nor dropped), and the
    /// conservation of the module docs becomes `accepted_pushes == N * matched + dropped +
    /// sum(queue_len) + handed back`.
    fn drain(&mut self) -> Drained<T>;

    /// [`Synchronizer::push`] with a ROS `builtin_interfaces/Time` stamp.
    fn push_stamped(
        &mut self,
        stream: usize,
        stamp: &Time,
        msg: T,
    ) -> Result<Pushed<T>, SyncError> {
        self.push(stream, time_to_ns(stamp), msg)
    }
}

/// ROS time to signed nanoseconds since the epoch. Cannot overflow: `|sec| * 1e9 + nanosec`
/// stays below `2^62` even for a malformed `nanosec >= 1e9`.
pub fn time_to_ns(t: &Time) -> i64 {
    i64::from(t.sec) * 1_000_000_000 + i64::from(t.nanosec)
}

pub(super) fn check_streams(num_streams: usize, queue_size: usize) -> Result<(), SyncError> {
    if num_streams < 2 {
        return Err(SyncError::TooFewStreams(num_streams));
    }
    if queue_size == 0 {
        return Err(SyncError::ZeroQueueSize);
    }
    Ok(())
}

pub(super) fn check_index(stream: usize, num_streams: usize) -> Result<(), SyncError> {
    if stream < num_streams {
        Ok(())
    } else {
        Err(SyncError::StreamOutOfRange {
            stream,
            num_streams,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use test_support::*;

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
            // The verdicts, counted, are the synchronisers' own counters.
            let mut exact_counted = SyncStats::default();
            let mut approx_counted = SyncStats::default();
            let pushes = 600;
            for id in 0..pushes {
                let s = (rng.next() % n as u64) as usize;
                // Mostly forward steps, sometimes backward (out of order) or repeated.
                stamps[s] += rng.range(-5, 60) / 10 * 10 * MS;
                let t = stamps[s];
                let pushed = exact.push(s, t, (s, id)).unwrap();
                exact_counted.count_push(&pushed);
                for set in pushed.sets {
                    assert!(set.stamps_ns.iter().all(|&x| x == set.stamps_ns[0]));
                    for (i, &x) in set.stamps_ns.iter().enumerate() {
                        assert!(x > last_exact[i]);
                        last_exact[i] = x;
                        assert_eq!(set.messages[i].0, i);
                    }
                }
                let pushed = approx.push(s, t, (s, id)).unwrap();
                approx_counted.count_push(&pushed);
                for set in pushed.sets {
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
            assert_eq!(exact_counted, exact.stats());
            let flushed = approx.flush();
            approx_counted.count(None, flushed.sets.len(), flushed.discarded);
            assert_eq!(approx_counted, approx.stats());
        }
    }

    #[test]
    fn drain_hands_back_every_buffered_message_once() {
        // Random streams drained at random moments (the rig changed): every message pushed is
        // emitted, dropped, still buffered or handed back, exactly once; what is handed back
        // comes in stamp order and leaves the queues empty; the sets a drain emits are counted.
        for seed in 1..=30u64 {
            let mut rng = Rng(seed * 104_729);
            let n = 2 + (rng.next() % 5) as usize;
            let q = 1 + (rng.next() % 5) as usize;
            let mut stamps = vec![0i64; n];
            let syncs: [Box<dyn Synchronizer<(usize, u64)>>; 2] = [
                Box::new(ExactSync::new(n, q).unwrap()),
                Box::new(
                    ApproximateSync::new(n, q)
                        .unwrap()
                        .with_max_interval_ns(rng.range(0, 40) * MS)
                        .unwrap(),
                ),
            ];
            for mut sync in syncs {
                let mut counted = SyncStats::default();
                let mut seen = std::collections::HashSet::new();
                let mut handed_back = 0u64;
                let pushes = 400u64;
                for id in 0..pushes {
                    let s = (rng.next() % n as u64) as usize;
                    stamps[s] += rng.range(-5, 60) / 10 * 10 * MS;
                    let pushed = sync.push(s, stamps[s], (s, id)).unwrap();
                    counted.count_push(&pushed);
                    let mut emitted = pushed.sets;
                    if rng.next().is_multiple_of(13) {
                        let drained = sync.drain();
                        counted.count(None, drained.sets.len(), drained.discarded);
                        emitted.extend(drained.sets);
                        assert!(drained
                            .buffered
                            .windows(2)
                            .all(|w| (w[0].1, w[0].0) < (w[1].1, w[1].0)));
                        for (i, _, msg) in drained.buffered {
                            assert_eq!(msg.0, i);
                            assert!(seen.insert(msg), "{msg:?} handed back twice");
                            handed_back += 1;
                        }
                        for i in 0..n {
                            assert_eq!(sync.queue_len(i).unwrap(), 0);
                        }
                    }
                    for set in emitted {
                        for (i, m) in set.messages.iter().enumerate() {
                            assert_eq!(m.0, i);
                            assert!(seen.insert(*m), "{m:?} emitted twice");
                        }
                    }
                    assert_eq!(counted, sync.stats());
                    let st = sync.stats();
                    let buffered: u64 = (0..n).map(|i| sync.queue_len(i).unwrap() as u64).sum();
                    assert_eq!(
                        id + 1,
                        n as u64 * st.matched + st.dropped + buffered + handed_back,
                        "{st:?}"
                    );
                }
            }
        }
    }
}
