//! Arbitrary bytes as a CDR `sensor_msgs/Image`; whatever decodes goes through the node's image
//! conversion, which must refuse a bad message with an error, never panic, and, when it
//! accepts one, give exactly width x height pixels.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sweepdepth::msgs::{from_cdr, Image};
use sweepdepth::pipeline::convert::image_to_rgba8;

fuzz_target!(|data: &[u8]| {
    let Ok(msg) = from_cdr::<Image>(data) else {
        return;
    };
    if let Ok(image) = image_to_rgba8("fuzz", &msg) {
        assert_eq!(image.width, msg.width);
        assert_eq!(image.height, msg.height);
        assert_eq!(
            image.pixels.len() as u64,
            u64::from(msg.width) * u64::from(msg.height)
        );
    }
});
