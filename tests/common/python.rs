//! The Python that has the test tools of `tools/requirements-test.txt` (cyclonedds, rosbags,
//! mcap, cv2): `SWEEPDEPTH_PYTHON`, else the virtual environment `scripts/setup.sh` makes when the
//! system Python lacks them (`target/test-venv`), else `python3`.
#![allow(
    dead_code,
    reason = "a module shared by several test binaries: each uses a part of it"
)]

use std::path::Path;

pub fn python() -> String {
    if let Ok(python) = std::env::var("SWEEPDEPTH_PYTHON") {
        return python;
    }
    let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/test-venv/bin/python3");
    if venv.is_file() {
        return venv.to_string_lossy().into_owned();
    }
    "python3".into()
}

pub const INSTALL_HINT: &str =
    "run `sh scripts/setup.sh` (or `python3 -m pip install -r tools/requirements-test.txt`)";
