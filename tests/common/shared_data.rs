//! The real datasets with ground truth in `../shared/data` (next to the repository; CI has them,
//! a user's clone usually does not).
//!
//! Without `SWEEPDEPTH_REQUIRE_SHARED_DATA` a missing folder or set is skipped, loudly (a line
//! on stderr that says which test checked nothing). With it set to anything but `0` or empty
//! (`.ci/run` sets it), a missing set fails the test: on CI the quality bar must really be met.

use std::io::Write;
use std::path::{Path, PathBuf};

/// The variable that makes a missing shared dataset a failure.
pub const REQUIRE: &str = "SWEEPDEPTH_REQUIRE_SHARED_DATA";

/// `../shared/data` relative to the repository.
pub fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data")
}

/// Whether a missing dataset fails the test.
pub fn required() -> bool {
    std::env::var_os(REQUIRE).is_some_and(|v| !v.is_empty() && v != "0")
}

/// The folder of the shared dataset `name`, or None (after a loud note) when it is missing and
/// not required; panics when it is missing and required.
pub fn dataset(test: &str, name: &str) -> Option<PathBuf> {
    let dir = root().join(name);
    if dir.is_dir() {
        return Some(dir);
    }
    assert!(
        !required(),
        "{test}: the shared dataset {} is missing and {REQUIRE} is set (CI must check it)",
        dir.display()
    );
    // Straight to the process's stderr: libtest would hide an eprintln! of a passing test.
    let _ = writeln!(
        std::io::stderr(),
        "\n*** SKIPPED {test}: the shared dataset {} is not here, so this test checked nothing \
         about it (set {REQUIRE}=1 to make that a failure) ***\n",
        dir.display()
    );
    None
}
