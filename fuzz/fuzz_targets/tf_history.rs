//! Arbitrary bytes as a CDR `tf2_msgs/TFMessage`, inserted into a `TfHistory` (as /tf and as
//! /tf_static), with arbitrary "now" stamps noted between; then every pair of its frames is
//! looked up at the message's stamps, between them and far off. Nothing may panic, every
//! transform found must be finite with a unit rotation, and a frame's parent is always one of
//! its frames.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sweepdepth::msgs::{from_cdr, TFMessage, Time};
use sweepdepth::ros::tf_history::TfHistory;

fuzz_target!(|data: &[u8]| {
    let Ok(msg) = from_cdr::<TFMessage>(data) else {
        return;
    };
    let mut history = TfHistory::new();
    let _ = history.insert_message(&msg, false);
    let _ = history.insert_message(&msg, true);
    if let Some(first) = msg.transforms.first() {
        let _ = history.note_time(first.header.stamp);
    }
    let _ = history.insert_message(&msg, false);
    let mut stamps: Vec<Time> = msg
        .transforms
        .iter()
        .map(|t| t.header.stamp)
        .take(8)
        .collect();
    stamps.push(Time::default());
    stamps.push(Time {
        sec: i32::MAX,
        nanosec: 999_999_999,
    });
    if let [a, b, ..] = stamps[..] {
        let mid = (a.to_nanos() / 2).saturating_add(b.to_nanos() / 2);
        stamps.push(Time::from_nanos(mid));
    }
    let mut frames: Vec<String> = history.frames().into_iter().map(str::to_string).collect();
    frames.truncate(12);
    for frame in &frames {
        if let Some(parent) = history.parent_of(frame) {
            assert!(
                history.contains(parent),
                "{frame}'s parent {parent} is unknown"
            );
        }
        let _ = history.oldest_stamp(frame);
        let _ = history.newest_stamp(frame);
    }
    frames.push("unknown".into());
    for a in &frames {
        for b in &frames {
            for &t in &stamps {
                if let Ok(found) = history.lookup_at(a, b, t) {
                    assert!(found.translation.is_finite(), "{a} <- {b}: {found:?}");
                    assert!(found.rotation.is_finite(), "{a} <- {b}: {found:?}");
                    assert!(
                        (found.rotation.length() - 1.0).abs() < 1e-6,
                        "{a} <- {b}: {found:?}"
                    );
                }
            }
        }
    }
    history.clear_dynamic();
});
