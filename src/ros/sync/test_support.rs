//! Helpers of the synchronisers' tests: random schedules of stamped messages and the checks
//! every test makes.

use super::{SyncedSet, Synchronizer};

pub const MS: i64 = 1_000_000;

/// Deterministic xorshift64* generator.
pub struct Rng(pub u64);
impl Rng {
    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    /// Uniform in `lo..=hi`.
    pub fn range(&mut self, lo: i64, hi: i64) -> i64 {
        lo + (self.next() % (hi - lo + 1) as u64) as i64
    }
}

/// Payload: (stream, k) so that tests can check set membership.
pub type Msg = (usize, i64);

#[derive(Debug, Clone, Copy)]
pub struct Ev {
    pub stream: usize,
    pub k: i64,
    pub stamp: i64,
    pub arrival: i64,
}

/// Stream `s` sends frame `k` (when `keep(s, k)`) stamped `period * k + jitter` (uniform in
/// `-jitter..=jitter`), arriving after a random latency in `0..=max_latency` but never
/// before the stream's previous message; events sorted by arrival time, which shuffles the
/// streams within a window of about `max_latency + 2 * jitter`.
pub fn schedule(
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

/// Feeds `evs`, checking after every push the queue bound and that the verdicts, counted,
/// are the synchroniser's own counters; returns the emitted sets.
pub fn run(sync: &mut dyn Synchronizer<Msg>, evs: &[Ev], queue_size: usize) -> Vec<SyncedSet<Msg>> {
    let mut out = Vec::new();
    let mut counted = sync.stats();
    for e in evs {
        let pushed = sync.push(e.stream, e.stamp, (e.stream, e.k)).unwrap();
        counted.count_push(&pushed);
        assert_eq!(counted, sync.stats(), "verdicts vs counters after {e:?}");
        out.extend(pushed.sets);
        for s in 0..sync.num_streams() {
            assert!(sync.queue_len(s).unwrap() <= queue_size);
        }
    }
    out
}

/// Asserts that `set` holds, on every stream, exactly the message of frame `k`, with the
/// stamp that was sent.
pub fn assert_frame(set: &SyncedSet<Msg>, k: i64, evs: &[Ev]) {
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

pub fn frames_of(sets: &[SyncedSet<Msg>]) -> Vec<i64> {
    sets.iter().map(|s| s.messages[0].1).collect()
}

/// `accepted == N * matched + dropped + buffered`.
pub fn assert_conservation(sync: &dyn Synchronizer<Msg>, accepted: u64) {
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
