//! Arbitrary sequences of pushes (stream index, stamp) into `ExactSync` or `ApproximateSync`
//! with arbitrary queue sizes, max interval and time-rule thresholds. Checks the documented
//! invariants after every push: an out-of-range stream is an error that changes nothing; at
//! most `queue_size` messages per stream; every set has exactly one message per stream, in
//! stream order, each with the stamp it was pushed with, emitted at most once; exact sets share
//! one stamp, approximate sets span at most `max_interval`; `pushes == N * matched + dropped +
//! buffered`; the rejection counters add up to no more than `dropped`; the verdicts of the
//! pushes, counted, are the synchroniser's counters.
#![no_main]

use std::collections::HashMap;

use arbitrary::Arbitrary;
use libfuzzer_sys::fuzz_target;
use sweepdepth::ros::sync::{
    ApproximateSync, ExactSync, SyncError, SyncStats, Synchronizer, TimeRules,
};

#[derive(Debug, Arbitrary)]
enum Stamp {
    /// Any i64 nanoseconds.
    Absolute(i64),
    /// Milliseconds after (or before) the stream's previous push.
    DeltaMs(i16),
    /// Seconds after (or before) the stream's previous push.
    DeltaS(i8),
}

#[derive(Debug, Arbitrary)]
struct Input {
    exact: bool,
    streams: u8,
    queue_size: u8,
    max_interval_ms: Option<u16>,
    age_penalty_tenths: u8,
    future_window_ms: u32,
    reset_backwards_ms: u32,
    pushes: Vec<(u8, Stamp)>,
}

fuzz_target!(|input: Input| {
    let n = 2 + usize::from(input.streams % 7);
    let q = 1 + usize::from(input.queue_size % 10);
    let rules = TimeRules {
        future_window_ns: i64::from(input.future_window_ms.max(1)) * 1_000_000,
        reset_backwards_ns: i64::from(input.reset_backwards_ms.max(1)) * 1_000_000,
    };
    let max_interval_ns = input
        .max_interval_ms
        .map_or(i64::MAX, |ms| i64::from(ms) * 1_000_000);
    let mut sync: Box<dyn Synchronizer<(usize, usize)>> = if input.exact {
        Box::new(
            ExactSync::new(n, q)
                .unwrap()
                .with_time_rules(rules)
                .unwrap(),
        )
    } else {
        Box::new(
            ApproximateSync::new(n, q)
                .unwrap()
                .with_age_penalty(f64::from(input.age_penalty_tenths) / 10.0)
                .unwrap()
                .with_max_interval_ns(max_interval_ns)
                .unwrap()
                .with_time_rules(rules)
                .unwrap(),
        )
    };
    let mut previous = vec![0i64; n];
    let mut stamps: HashMap<usize, i64> = HashMap::new();
    let mut emitted: HashMap<usize, ()> = HashMap::new();
    let mut accepted: u64 = 0;
    let mut counted = SyncStats::default();
    for (id, (stream, stamp)) in input.pushes.iter().take(2000).enumerate() {
        let stream = usize::from(*stream % (n as u8 + 1)); // n is out of range
        let base = previous.get(stream).copied().unwrap_or(0);
        let t = match *stamp {
            Stamp::Absolute(t) => t,
            Stamp::DeltaMs(d) => base.saturating_add(i64::from(d) * 1_000_000),
            Stamp::DeltaS(d) => base.saturating_add(i64::from(d) * 1_000_000_000),
        };
        let before: SyncStats = sync.stats();
        let result = sync.push(stream, t, (stream, id));
        if stream >= n {
            assert_eq!(
                result,
                Err(SyncError::StreamOutOfRange {
                    stream,
                    num_streams: n
                })
            );
            assert_eq!(sync.stats(), before);
            continue;
        }
        previous[stream] = t;
        stamps.insert(id, t);
        accepted += 1;
        let pushed = result.expect("a valid stream index is never an error");
        counted.count_push(&pushed);
        assert_eq!(counted, sync.stats(), "the verdicts, counted, are the counters");
        for set in pushed.sets {
            assert_eq!(set.messages.len(), n);
            assert_eq!(set.stamps_ns.len(), n);
            for (i, (&(s, msg_id), &stamp)) in set.messages.iter().zip(&set.stamps_ns).enumerate() {
                assert_eq!(s, i, "message of stream {s} at index {i}");
                assert_eq!(stamps.get(&msg_id), Some(&stamp));
                assert!(
                    emitted.insert(msg_id, ()).is_none(),
                    "message {msg_id} emitted twice"
                );
            }
            if input.exact {
                assert!(set.stamps_ns.iter().all(|&s| s == set.stamps_ns[0]));
            } else {
                assert!(set.span_ns() <= max_interval_ns);
            }
        }
        let mut buffered = 0u64;
        for s in 0..n {
            let len = sync.queue_len(s).unwrap();
            assert!(len <= q, "stream {s} holds {len} > {q}");
            buffered += len as u64;
        }
        let st = sync.stats();
        assert_eq!(
            accepted,
            n as u64 * st.matched + st.dropped + buffered,
            "{st:?}"
        );
        assert!(
            st.duplicates + st.out_of_order + st.future <= st.dropped,
            "{st:?}"
        );
        assert!(st.resets >= before.resets && st.matched >= before.matched);
    }
});
