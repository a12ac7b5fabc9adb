//! Arbitrary bytes as an MCAP bag (the MCAP magic is prepended unless the input starts with
//! it): `BagReader` must open it or refuse it, and iterate it to the end or to its first
//! error, without panicking; after an error it must end.
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
        let mut failed = false;
        for item in reader.by_ref().take(100_000) {
            assert!(!failed, "the reader went on after an error");
            if item.is_err() {
                failed = true;
            }
        }
        if failed {
            assert!(reader.next().is_none());
        }
    }
    let _ = std::fs::remove_file(&path);
});
