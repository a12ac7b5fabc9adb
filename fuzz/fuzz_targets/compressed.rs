//! Arbitrary bytes as a compressed image (`sensor_msgs/CompressedImage` data) under each
//! format the node accepts, decoded as the node and `bag` decode it. Nothing may panic; an
//! image that decodes is `rgb8` or `mono8`, within the size limits, with exactly
//! `step * height` bytes.
//!
//! The one exception: a panic inside an image decoder crate (zune-jpeg's overflow on a damaged
//! JPEG) is caught by `decode`, which turns it into a corrupt-image error, so such a panic must
//! not abort the fuzzer (libFuzzer's hook aborts on every panic, before it unwinds to
//! `decode`). Any other panic still aborts.
#![no_main]

use std::sync::Once;

use libfuzzer_sys::fuzz_target;
use sweepdepth::msgs::{CompressedImage, Header};
use sweepdepth::pipeline::compressed::{decode, MAX_DECODED_MEGAPIXELS};

const FORMATS: [&str; 6] = [
    "rgb8; jpeg compressed bgr8",
    "mono8; jpeg compressed mono8",
    "rgb8; png compressed rgb8",
    "jpeg",
    "png",
    "16UC1; compressedDepth png",
];

static HOOK: Once = Once::new();

/// The crates whose panics `decode` catches (the decoders under `image`).
const DECODERS: [&str; 4] = ["/zune-jpeg-", "/zune-core-", "/png-", "/fdeflate-"];

fn install_hook() {
    HOOK.call_once(|| {
        let abort = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let in_decoder = info
                .location()
                .is_some_and(|l| DECODERS.iter().any(|d| l.file().contains(d)));
            if !in_decoder {
                abort(info);
            }
        }));
    });
}

fuzz_target!(|data: &[u8]| {
    install_hook();
    let Some((&selector, bytes)) = data.split_first() else {
        return;
    };
    let format = FORMATS[usize::from(selector) % FORMATS.len()];
    let msg = CompressedImage {
        header: Header::default(),
        format: format.to_string(),
        data: bytes.to_vec(),
    };
    if let Ok(image) = decode("fuzz", &msg) {
        assert!(image.encoding == "rgb8" || image.encoding == "mono8");
        let pixels = u64::from(image.width) * u64::from(image.height);
        assert!(pixels > 0 && pixels <= MAX_DECODED_MEGAPIXELS << 20);
        let channels = if image.encoding == "rgb8" { 3 } else { 1 };
        assert_eq!(image.step, image.width * channels);
        assert_eq!(
            image.data.len() as u64,
            u64::from(image.step) * u64::from(image.height)
        );
    }
});
