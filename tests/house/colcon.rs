//! sweepdepth as a colcon package (issue 31 item 3): a scratch workspace with the source tree
//! (a symlink in `src/`), `colcon build` (colcon-core, colcon-ros, colcon-ros-cargo and
//! cargo-ament-build from PyPI, `tools/requirements-colcon.txt`, in the test venv), then what a
//! ROS user relies on: the executable in `lib/sweepdepth/` runs (`--help`, a short `bag` run on
//! the fixture bag), the package is in the ament index and `ament_index_python` finds it, its
//! share directory and the launch, parameter and rig files in it, and the installed launch file
//! starts the installed executable with the installed parameter file.
//!
//! The build reuses the suite's own compiled crate: `CARGO_BUILD_BUILD_DIR` (cargo's
//! `build.build-dir`, where the intermediate artifacts live) is the target directory this test
//! was built in, with the same profile and the same features (`--cargo-args --test house`, this test binary), so
//! the `cargo build` under colcon finds every unit fresh and only copies the executable out (the
//! workspace's `build/sweepdepth` is cargo's `--target-dir`, as colcon-ros-cargo sets it). The
//! installed executable is the suite's own, byte for byte. Not a ROS install: `ament_index_python` is the Jazzy wheel of
//! `tools/requirements-ros.txt`; no DDS is opened (`bag` reads and writes files).

#[path = "../common/python.rs"]
mod python;
#[path = "../common/timeout.rs"]
mod timeout;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use sweepdepth::bag::BagReader;
use sweepdepth::msgs::{from_cdr, Image};

const SETUP_HINT: &str = "run `sh scripts/setup.sh`, which installs colcon-core, colcon-ros-cargo \
     and cargo-ament-build (tools/requirements-colcon.txt) into target/test-venv";

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The files colcon installs under `share/sweepdepth/` (from `[package.metadata.ros]` of
/// Cargo.toml): every file of `launch_configs/`.
fn launch_config_files() -> Vec<String> {
    let mut files: Vec<String> = std::fs::read_dir(root().join("launch_configs"))
        .expect("launch_configs/")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    files.sort();
    files
}

/// The bin folder of the test venv (with `colcon` and `cargo-ament-build`), from the Python the
/// tests use; None for a system Python on PATH.
fn tools_bin() -> Option<PathBuf> {
    let python = PathBuf::from(python::python());
    python
        .is_absolute()
        .then(|| python.parent().expect("python's folder").to_path_buf())
}

/// PATH with the venv's bin first: colcon, and cargo-ament-build for `cargo ament-build`.
fn tools_path() -> String {
    let inherited = std::env::var("PATH").unwrap_or_default();
    match tools_bin() {
        Some(bin) => format!("{}:{inherited}", bin.display()),
        None => inherited,
    }
}

/// The suite's target directory and the profile its `sweepdepth` was built with, from the
/// executable's path (`<target>/<profile dir>/sweepdepth`).
fn suite_build() -> (PathBuf, &'static str) {
    let exe = Path::new(env!("CARGO_BIN_EXE_sweepdepth"));
    let profile_dir = exe.parent().expect("profile folder");
    let target = profile_dir.parent().expect("target folder").to_path_buf();
    let profile = match profile_dir.file_name().and_then(|n| n.to_str()) {
        Some("debug") => "debug",
        Some("release") => "release",
        other => panic!(
            "the suite was built into {other:?}, a profile this test does not pass to colcon \
             (debug or release)"
        ),
    };
    (target, profile)
}

/// Runs a command to its end within the suite's one limit, output captured.
fn run_limited(cmd: &mut Command, what: &str) -> Output {
    let limit = timeout::test_timeout();
    let mut child = cmd
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {what} ({e}); {SETUP_HINT}"));
    // Drain both pipes on threads so that a chatty child cannot block on a full pipe.
    let mut stdout = child.stdout.take().expect("stdout");
    let mut stderr = child.stderr.take().expect("stderr");
    let out_thread = std::thread::spawn(move || {
        let mut buf = Vec::new();
        std::io::Read::read_to_end(&mut stdout, &mut buf).ok();
        buf
    });
    let err_thread = std::thread::spawn(move || {
        let mut buf = Vec::new();
        std::io::Read::read_to_end(&mut stderr, &mut buf).ok();
        buf
    });
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait") {
            break status;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "{what} did not finish within {limit:?} (SWEEPDEPTH_TEST_TIMEOUT_S); with the \
                 suite's build fresh it takes seconds"
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    Output {
        status,
        stdout: out_thread.join().expect("stdout thread"),
        stderr: err_thread.join().expect("stderr thread"),
    }
}

struct Workspace {
    dir: PathBuf,
    build_seconds: f64,
}

impl Workspace {
    fn install(&self) -> PathBuf {
        self.dir.join("install/sweepdepth")
    }

    fn share(&self) -> PathBuf {
        self.install().join("share/sweepdepth")
    }

    fn executable(&self) -> PathBuf {
        self.install().join("lib/sweepdepth/sweepdepth")
    }

    /// A command run by `sh` after sourcing the workspace's `install/setup.sh`, as a user's shell
    /// does: `AMENT_PREFIX_PATH` (and PATH, ...) from colcon's hooks, nothing inherited of them.
    fn sourced(&self, script: &str, args: &[&str]) -> Command {
        let mut cmd = Command::new("sh");
        cmd.arg("-c")
            .arg(format!(". \"$0/install/setup.sh\" && {script}"))
            .arg(&self.dir)
            .args(args)
            .env_remove("AMENT_PREFIX_PATH")
            .env_remove("COLCON_PREFIX_PATH")
            .env("PATH", tools_path());
        cmd
    }
}

/// Checks that colcon and cargo-ament-build are there, with the install hint otherwise.
fn check_tools() {
    let colcon = Command::new("colcon")
        .arg("--help")
        .env("PATH", tools_path())
        .output();
    assert!(
        matches!(&colcon, Ok(out) if out.status.success()),
        "colcon is missing or broken ({:?}); {SETUP_HINT}",
        colcon.map(|o| String::from_utf8_lossy(&o.stderr).into_owned())
    );
    let ament_build = Command::new("cargo")
        .args(["ament-build", "--help"])
        .env("PATH", tools_path())
        .output()
        .expect("cargo runs");
    assert!(
        ament_build.status.success(),
        "`cargo ament-build` is missing ({}); {SETUP_HINT}",
        String::from_utf8_lossy(&ament_build.stderr).trim()
    );
}

/// Makes the scratch workspace and runs `colcon build` in it (once per test process).
fn build_workspace() -> Workspace {
    check_tools();
    // In the target directory, made anew by each run (the installed executable is a copy of
    // the suite's, ~150 MB in a debug build: one at a time, not one per run in /tmp).
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("colcon-workspace");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("src")).expect("scratch workspace");
    std::os::unix::fs::symlink(root(), dir.join("src/sweepdepth")).expect("symlink the package");

    let (target, profile) = suite_build();
    let mut cmd = Command::new("colcon");
    cmd.current_dir(&dir)
        .arg("build")
        .env("PATH", tools_path())
        // The suite's compiled units: cargo's build-dir; the artefacts land in the workspace.
        .env("CARGO_BUILD_BUILD_DIR", &target)
        .env_remove("CARGO_TARGET_DIR")
        .env_remove("AMENT_PREFIX_PATH")
        .env_remove("COLCON_PREFIX_PATH");
    // `--test <this test binary>`: the features as `cargo test` resolved them (dev-dependencies on, which
    // changes some dependencies' features), so that every unit, the executable included, is the
    // one this test binary was built with; a plain `cargo build` would build sweepdepth's library
    // and executable again. (colcon passes `--cargo-args` on to `cargo ament-build -- ...`, that
    // to `cargo build`; a leading space keeps colcon's parser from taking them for its own.)
    cmd.args(["--cargo-args", " --test", env!("CARGO_CRATE_NAME")]);
    if profile == "release" {
        cmd.arg(" --release");
    }
    let start = Instant::now();
    let out = run_limited(&mut cmd, "colcon build");
    let build_seconds = start.elapsed().as_secs_f64();
    if !out.status.success() {
        let log =
            std::fs::read_to_string(dir.join("log/latest_build/sweepdepth/stdout_stderr.log"))
                .unwrap_or_default();
        panic!(
            "colcon build failed ({}):\n{}\n{}\nthe package's build log:\n{log}",
            out.status,
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    eprintln!(
        "colcon build of the scratch workspace {}: {build_seconds:.1} s (build-dir {})",
        dir.display(),
        target.display()
    );
    Workspace { dir, build_seconds }
}

/// The one workspace of this test process; a failed build fails every test with its message
/// without building again.
fn workspace() -> &'static Workspace {
    static WS: Mutex<Option<Result<&'static Workspace, String>>> = Mutex::new(None);
    let mut slot = WS.lock().unwrap_or_else(|e| e.into_inner());
    let result = slot.get_or_insert_with(|| {
        std::panic::catch_unwind(build_workspace)
            .map(|ws| &*Box::leak(Box::new(ws)))
            .map_err(|e| {
                e.downcast_ref::<String>()
                    .cloned()
                    .or_else(|| e.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_else(|| "colcon build panicked".into())
            })
    });
    match result {
        Ok(ws) => ws,
        Err(e) => panic!("{e}"),
    }
}

#[test]
fn colcon_build_installs_the_package() {
    let ws = workspace();
    let install = ws.install();
    // The ament index marker that `ros2 pkg list` and ament_index_python read.
    assert!(
        install
            .join("share/ament_index/resource_index/packages/sweepdepth")
            .is_file(),
        "no ament index marker under {}",
        install.display()
    );
    assert!(ws.share().join("package.xml").is_file());
    for file in launch_config_files() {
        let installed = ws.share().join("launch_configs").join(&file);
        assert_eq!(
            std::fs::read(&installed).unwrap_or_else(|e| panic!("{}: {e}", installed.display())),
            std::fs::read(root().join("launch_configs").join(&file)).expect("source file"),
            "{file} installed differs from the source"
        );
    }
    // The executable is the suite's own build, not a second one: colcon's cargo reused it.
    let installed = std::fs::read(ws.executable()).expect("lib/sweepdepth/sweepdepth");
    let suite = std::fs::read(env!("CARGO_BIN_EXE_sweepdepth")).expect("the suite's sweepdepth");
    assert!(
        installed == suite,
        "the installed executable ({} bytes) is not the suite's ({} bytes): colcon's cargo built \
         its own instead of reusing {}",
        installed.len(),
        suite.len(),
        suite_build().0.display()
    );
    eprintln!("colcon build took {:.1} s", ws.build_seconds);
}

#[test]
fn installed_executable_runs_help_and_a_bag() {
    let ws = workspace();
    // Through the sourced workspace's prefix, where `ros2 run sweepdepth sweepdepth` finds it.
    let help = run_limited(
        &mut ws.sourced(
            "exec \"$AMENT_PREFIX_PATH/lib/sweepdepth/sweepdepth\" --help",
            &[],
        ),
        "sweepdepth --help",
    );
    let text = String::from_utf8_lossy(&help.stdout);
    assert!(
        help.status.success(),
        "--help failed: {}",
        String::from_utf8_lossy(&help.stderr)
    );
    for command in ["node", "bag", "pack", "fuse"] {
        assert!(text.contains(command), "--help lacks {command}:\n{text}");
    }

    let out_bag = ws.dir.join("depth.mcap");
    let _ = std::fs::remove_file(&out_bag);
    let bag = root().join("tests/fixtures/bags/tsukuba_half.mcap");
    let params = root().join("tests/fixtures/bags/tsukuba_half.params.yaml");
    let mut cmd = Command::new(ws.executable());
    cmd.args(["bag"])
        .arg(&bag)
        .arg(&out_bag)
        .arg("--params-file")
        .arg(&params)
        .env("RUST_LOG", "warn,sweepdepth=info");
    let run = run_limited(&mut cmd, "sweepdepth bag");
    assert!(
        run.status.success(),
        "the installed sweepdepth bag failed: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    let depths: Vec<Image> = BagReader::open(&out_bag)
        .expect("open the output bag")
        .map(|m| m.expect("read a message"))
        .filter(|m| m.topic == "/depth/image")
        .map(|m| from_cdr(&m.data).expect("decode a depth image"))
        .collect();
    assert_eq!(depths.len(), 3, "one depth image per set of the fixture");
    for depth in &depths {
        assert_eq!(
            (depth.width, depth.height, depth.encoding.as_str()),
            (192, 144, "32FC1")
        );
        let valid = depth
            .data
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .filter(|d| d.is_finite() && *d > 0.0)
            .count();
        assert!(
            valid > 192 * 144 / 2,
            "only {valid} valid depths of {}",
            192 * 144
        );
    }
}

#[test]
fn ament_index_finds_the_package_and_its_files() {
    let ws = workspace();
    let python = python::python();
    let out = run_limited(
        &mut ws.sourced(
            "exec \"$1\" -c \"$2\"",
            &[
                &python,
                "import json\n\
                 from ament_index_python.packages import (get_package_prefix,\n\
                     get_package_share_directory, get_packages_with_prefixes)\n\
                 from ament_index_python.resources import get_resource\n\
                 content, prefix = get_resource('packages', 'sweepdepth')\n\
                 print(json.dumps({'packages': get_packages_with_prefixes(),\n\
                     'prefix': get_package_prefix('sweepdepth'), 'resource_prefix': prefix,\n\
                     'share': get_package_share_directory('sweepdepth')}))",
            ],
        ),
        "ament_index_python",
    );
    assert!(
        out.status.success(),
        "ament_index_python did not find the package: {}; {}",
        String::from_utf8_lossy(&out.stderr),
        python::INSTALL_HINT
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    let install = ws.install().display().to_string();
    assert_eq!(v["packages"]["sweepdepth"], install.as_str(), "{v}");
    assert_eq!(v["prefix"], install.as_str());
    assert_eq!(v["resource_prefix"], install.as_str());
    let share = PathBuf::from(v["share"].as_str().expect("share directory"));
    assert_eq!(share, ws.share());
    for file in [
        "package.xml",
        "launch_configs/sweepdepth.launch.py",
        "launch_configs/four_cameras.params.yaml",
        "launch_configs/camera_row.params.yaml",
        "launch_configs/rig_four_cameras.yaml",
        "launch_configs/rig_camera_row.yaml",
    ] {
        assert!(
            share.join(file).is_file(),
            "{file} is not in {}",
            share.display()
        );
    }
    assert!(PathBuf::from(&install)
        .join("lib/sweepdepth/sweepdepth")
        .is_file());
}

#[test]
fn installed_launch_file_starts_the_installed_executable() {
    let ws = workspace();
    let python = python::python();
    let stubs = root().join("tests/fixtures/launch_stubs.py");
    let launch = ws.share().join("launch_configs/sweepdepth.launch.py");
    let launch_arg = launch.display().to_string();
    let stubs_arg = stubs.display().to_string();
    let out = run_limited(
        ws.sourced(
            "exec \"$1\" \"$2\" \"$3\"",
            &[&python, &stubs_arg, &launch_arg],
        )
        .env("PYTHONDONTWRITEBYTECODE", "1"),
        "the installed launch file",
    );
    assert!(
        out.status.success(),
        "the installed launch file failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    // The launch file's own folder, as launch's ThisLaunchFileDir gives it.
    let dir = ws.share().join("launch_configs");
    let render = |s: &serde_json::Value| {
        PathBuf::from(
            s.as_str()
                .expect("a string")
                .replace("<dir>", &dir.display().to_string()),
        )
    };
    let cmd = v["cmd"].as_array().expect("cmd");
    assert_eq!(
        PathBuf::from(cmd[0].as_str().unwrap()),
        ws.executable(),
        "{v}"
    );
    assert_eq!(cmd[1], "node");
    let params = render(&v["defaults"]["params_file"]);
    assert!(params.is_file(), "{}", params.display());
    assert!(params.starts_with(ws.share()));
    // The node runs in the share directory, where the parameter files' relative rig files
    // (launch_configs/...) resolve as they do from the repository root.
    let cwd = render(&v["cwd"])
        .canonicalize()
        .expect("the working directory");
    assert_eq!(cwd, ws.share());
    let camera_row = std::fs::read_to_string(dir.join("camera_row.params.yaml")).expect("yaml");
    let rig_line = camera_row
        .lines()
        .find(|l| l.trim_start().starts_with("rig_file:"))
        .expect("camera_row.params.yaml names a rig file");
    let value = rig_line.split_once(':').unwrap().1;
    let rig = value.split('#').next().unwrap().trim().trim_matches('"');
    assert!(
        cwd.join(rig).is_file(),
        "{rig} does not resolve in {}",
        cwd.display()
    );

    // The source tree's launch file, with the package installed, still names `sweepdepth` on
    // PATH: only the installed copy takes the installed executable.
    let source = root().join("launch_configs/sweepdepth.launch.py");
    let source_arg = source.display().to_string();
    let out = run_limited(
        ws.sourced(
            "exec \"$1\" \"$2\" \"$3\"",
            &[&python, &stubs_arg, &source_arg],
        )
        .env("PYTHONDONTWRITEBYTECODE", "1"),
        "the source tree's launch file",
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    assert_eq!(v["cmd"][0], "sweepdepth");
    // And with ament_index_python but no ROS environment at all (no AMENT_PREFIX_PATH, where
    // ament_index_python raises an OSError), the source tree's launch file still loads.
    let out = run_limited(
        Command::new(&python)
            .arg(&stubs)
            .arg(&source)
            .env_remove("AMENT_PREFIX_PATH")
            .env("PYTHONDONTWRITEBYTECODE", "1"),
        "the source tree's launch file without a ROS environment",
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    assert_eq!(v["cmd"][0], "sweepdepth");
}

/// The `pip install` and `colcon build` lines of docs/colcon.md's "Build" block, as a user
/// copies them (comments dropped).
fn documented_commands() -> (Vec<String>, String) {
    let page = std::fs::read_to_string(root().join("docs/colcon.md")).expect("docs/colcon.md");
    let build = page
        .split("\n## Build\n")
        .nth(1)
        .expect("docs/colcon.md has a Build section");
    let block = build
        .split("```sh\n")
        .nth(1)
        .and_then(|b| b.split("```").next())
        .expect("the Build section has a sh code block");
    let line = |start: &str| {
        block
            .lines()
            .map(|l| l.split('#').next().unwrap_or("").trim())
            .find(|l| l.starts_with(start))
            .unwrap_or_else(|| panic!("docs/colcon.md's Build block has no `{start}` line"))
            .to_string()
    };
    let pip: Vec<String> = line("pip install")
        .split_whitespace()
        .skip(2)
        .filter(|w| !w.starts_with('-'))
        .map(str::to_string)
        .collect();
    (pip, line("colcon build"))
}

/// What docs/colcon.md tells a user to install and type holds: every package its `pip
/// install` names is pinned in tools/requirements-colcon.txt (which the test venv installs, so
/// the tools the tests run are the documented ones), and every option of its `colcon build`
/// line is one that `colcon build --help` of those tools offers (`--packages-select` comes
/// from colcon-package-selection: without it colcon stops with "unrecognized arguments").
#[test]
fn the_documented_colcon_commands_are_the_tested_tools() {
    check_tools();
    let (pip, colcon_line) = documented_commands();
    let pinned: Vec<String> = std::fs::read_to_string(root().join("tools/requirements-colcon.txt"))
        .expect("tools/requirements-colcon.txt")
        .lines()
        .filter_map(|l| l.split("==").next())
        .map(|name| name.trim().to_lowercase().replace('_', "-"))
        .collect();
    assert!(!pip.is_empty(), "no package on the documented pip line");
    for package in &pip {
        assert!(
            pinned.contains(&package.to_lowercase().replace('_', "-")),
            "docs/colcon.md installs {package}, which tools/requirements-colcon.txt does not pin"
        );
    }
    let help = Command::new("colcon")
        .args(["build", "--help"])
        .env("PATH", tools_path())
        .output()
        .expect("colcon runs");
    let help = String::from_utf8_lossy(&help.stdout).into_owned();
    // colcon's own options: the words outside quotes (`--cargo-args " --release"` passes
    // the quoted one on to cargo).
    let unquoted: String = colcon_line
        .split('"')
        .step_by(2)
        .collect::<Vec<_>>()
        .join(" ");
    let options: Vec<&str> = unquoted
        .split_whitespace()
        .filter(|w| w.starts_with("--"))
        .collect();
    assert!(options.contains(&"--cargo-args"), "{colcon_line}");
    let offered: Vec<&str> = help
        .split(|c: char| c.is_whitespace() || matches!(c, '[' | ']' | ','))
        .collect();
    for option in options {
        assert!(
            offered.contains(&option),
            "docs/colcon.md's `{colcon_line}` uses {option}, which `colcon build --help` of the \
             pinned tools does not offer"
        );
    }
}

/// The documented `colcon build` line itself, verbatim, in a fresh workspace: a release build
/// from scratch (nothing reused: minutes), then the installed executable runs. CI runs it
/// (`SWEEPDEPTH_COLCON_FROM_SCRATCH=1`, set by .ci/run); elsewhere it says it was skipped,
/// because the other colcon tests cover the package with the suite's own build in seconds.
/// A from-scratch build has no time limit: cargo ends, and how long it takes is the
/// machine's speed, not an outcome.
#[test]
fn the_documented_colcon_build_from_scratch() {
    if std::env::var_os("SWEEPDEPTH_COLCON_FROM_SCRATCH").is_none() {
        eprintln!(
            "skipped: the documented release build from scratch runs with \
             SWEEPDEPTH_COLCON_FROM_SCRATCH=1 (CI sets it)"
        );
        return;
    }
    check_tools();
    let (_, colcon_line) = documented_commands();
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("colcon-from-scratch");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("src")).expect("scratch workspace");
    std::os::unix::fs::symlink(root(), dir.join("src/sweepdepth")).expect("symlink the package");
    let started = Instant::now();
    let out = Command::new("sh")
        .arg("-c")
        .arg(&colcon_line)
        .current_dir(&dir)
        .env("PATH", tools_path())
        .env_remove("CARGO_TARGET_DIR")
        .env_remove("CARGO_BUILD_BUILD_DIR")
        .env_remove("AMENT_PREFIX_PATH")
        .env_remove("COLCON_PREFIX_PATH")
        .stdin(Stdio::null())
        .output()
        .expect("sh runs");
    if !out.status.success() {
        let log =
            std::fs::read_to_string(dir.join("log/latest_build/sweepdepth/stdout_stderr.log"))
                .unwrap_or_default();
        panic!(
            "`{colcon_line}` failed ({}):\n{}\n{}\nthe package's build log:\n{log}",
            out.status,
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    eprintln!(
        "`{colcon_line}` from scratch: {:.0} s",
        started.elapsed().as_secs_f64()
    );
    let exe = dir.join("install/sweepdepth/lib/sweepdepth/sweepdepth");
    let help = run_limited(
        Command::new(&exe).arg("--help"),
        "the installed sweepdepth --help",
    );
    assert!(
        help.status.success(),
        "{}",
        String::from_utf8_lossy(&help.stderr)
    );
    assert!(String::from_utf8_lossy(&help.stdout).contains("node"));
    let _ = std::fs::remove_dir_all(&dir);
}
