//! Arbitrary bytes as a CDR `tf2_msgs/TFMessage`; whatever decodes is inserted into a
//! `TfBuffer` (twice, as a re-sent `/tf_static`), then every pair of its frames is looked up.
//! Nothing may panic, and every transform found must be finite.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sweepdepth::msgs::{from_cdr, TFMessage};
use sweepdepth::ros::tf::TfBuffer;

fuzz_target!(|data: &[u8]| {
    let Ok(msg) = from_cdr::<TFMessage>(data) else {
        return;
    };
    let mut tf = TfBuffer::new();
    let _ = tf.insert_message(&msg);
    let _ = tf.insert_message(&msg);
    let mut frames: Vec<String> = tf.frames().into_iter().map(str::to_string).collect();
    frames.truncate(16);
    frames.push("unknown".into());
    for a in &frames {
        let _ = tf.parent_of(a);
        for b in &frames {
            if let Ok(t) = tf.lookup(a, b) {
                assert!(t.translation.is_finite(), "{a} <- {b}: {t:?}");
                assert!(t.rotation.is_finite(), "{a} <- {b}: {t:?}");
            }
        }
    }
});
