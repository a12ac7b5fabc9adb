//! Arbitrary bytes as an MCAP bag (the MCAP magic is prepended unless the input starts with
//! it): `BagReader` must open it or refuse it, and iterate it to the end without panicking.
//! After an error it may go on (a damaged chunk is skipped when the summary lists a later one;
//! a message on a non-CDR channel is reported and passed over), but it must always make
//! progress: two million items from an input of at most 64 KiB means it is stuck.
//!
//! The one exception: a panic inside the `mcap` crate (an overflow on a corrupt length) is
//! caught by `BagReader`, which turns it into a corrupt-file error, so such a panic must not
//! abort the fuzzer (libFuzzer's hook aborts on every panic, before it unwinds to the
//! reader). Any other panic still aborts.
#![no_main]

use std::io::Write;
use std::sync::Once;

use libfuzzer_sys::fuzz_target;
use sweepdepth::bag::reader::BagReader;

const MAGIC: &[u8] = b"\x89MCAP0\r\n";

static HOOK: Once = Once::new();

fn install_hook() {
    HOOK.call_once(|| {
        let abort = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let in_mcap = info.location().is_some_and(|l| l.file().contains("/mcap-"));
            if !in_mcap {
                abort(info);
            }
        }));
    });
}

fuzz_target!(|data: &[u8]| {
    install_hook();
    let path = std::env::temp_dir().join(format!("sweepdepth-fuzz-{}.mcap", std::process::id()));
    let written = std::fs::File::create(&path).and_then(|mut f| {
        if !data.starts_with(MAGIC) {
            f.write_all(MAGIC)?;
        }
        f.write_all(data)
    });
    if written.is_err() {
        return;
    }
    if let Ok(reader) = BagReader::open(&path) {
        let _ = reader.topics().len();
        let mut reader = reader;
        const BOUND: usize = 2_000_000;
        let items = reader.by_ref().take(BOUND).count();
        assert!(items < BOUND, "the reader makes no progress");
    }
    let _ = std::fs::remove_file(&path);
});
