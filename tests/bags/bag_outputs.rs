//! Where `bag` and `pack` write, and what `--force` may replace: never the input or a folder
//! that holds it, never a folder of other files or a file that is not a bag; a run that fails
//! leaves no output behind (so that the same command can run again without `--force`; a
//! writer dropped unfinished: `bag::writer`'s unit tests).

use super::util::{fixture_bag, fixture_params, messages, ok, root, scratch, sweepdepth};
use std::path::{Path, PathBuf};

fn fixture() -> PathBuf {
    root().join("tests/fixtures/bags/tsukuba_half.mcap")
}

/// Runs `bag IN OUT` with the fixture's parameters and `extra`: (success, stderr).
fn bag(input: &Path, output: &Path, extra: &[&str]) -> (bool, String) {
    let out = fixture_bag(input, output, extra);
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Every file below `dir` with its bytes, sorted by path.
fn tree(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut files = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else {
                let bytes = std::fs::read(&path).unwrap();
                files.push((path, bytes));
            }
        }
    }
    files.sort();
    files
}

#[test]
fn force_never_replaces_the_input_or_what_is_not_a_bag() {
    let dir = scratch("force");
    let input = dir.join("in.mcap");
    std::fs::copy(fixture(), &input).unwrap();
    let notes = dir.join("notes.txt");
    std::fs::write(&notes, "the user's own file\n").unwrap();
    let before = tree(&dir);

    // OUT is the input.
    let (done, stderr) = bag(&input, &input, &["--force"]);
    assert!(!done, "bag IN IN --force succeeded");
    assert!(stderr.contains("is the input"), "{stderr}");
    // OUT is the folder that holds the input (and the user's file).
    let (done, stderr) = bag(&input, &dir, &["--force"]);
    assert!(!done, "bag IN (its folder) --force succeeded");
    assert!(stderr.contains("or holds it"), "{stderr}");
    // OUT is a file that is not a bag.
    let (done, stderr) = bag(&input, &notes, &["--force"]);
    assert!(!done, "bag IN notes.txt --force succeeded");
    assert!(stderr.contains("is not a bag"), "{stderr}");
    assert_eq!(tree(&dir), before, "a refused --force changed the folder");

    // OUT is a folder of other files.
    let other = dir.join("other");
    std::fs::create_dir(&other).unwrap();
    std::fs::write(other.join("calib.txt"), "x").unwrap();
    let (done, stderr) = bag(&input, &other, &["--force"]);
    assert!(!done);
    assert!(
        stderr.contains("is not a bag (a folder holding calib.txt)"),
        "{stderr}"
    );
    assert!(other.join("calib.txt").is_file());

    // `pack` into the dataset folder it reads.
    let dataset = dir.join("tsukuba");
    std::fs::create_dir(&dataset).unwrap();
    for entry in std::fs::read_dir(root().join("data/tsukuba")).unwrap() {
        let path = entry.unwrap().path();
        if path.is_file() {
            std::fs::copy(&path, dataset.join(path.file_name().unwrap())).unwrap();
        }
    }
    let dataset_before = tree(&dataset);
    let out = sweepdepth(&[
        "pack",
        dataset.to_str().unwrap(),
        dataset.to_str().unwrap(),
        "--force",
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "pack DIR DIR --force succeeded");
    assert!(stderr.contains("is the input"), "{stderr}");
    assert_eq!(tree(&dataset), dataset_before, "pack changed its dataset");

    // A bag in OUT is replaced: the new one holds this run's depth.
    let old = dir.join("old.mcap");
    std::fs::copy(fixture(), &old).unwrap();
    let stderr = ok(
        &sweepdepth(&[
            "bag",
            input.to_str().unwrap(),
            old.to_str().unwrap(),
            "--params-file",
            fixture_params().to_str().unwrap(),
            "--force",
        ]),
        "bag over an older bag with --force",
    );
    assert!(stderr.contains("3 processed"), "{stderr}");
    let depths = messages(&old)
        .iter()
        .filter(|m| m.topic == "/depth/image")
        .count();
    assert_eq!(depths, 3, "the replaced bag's depth messages");
}

#[test]
fn a_failed_run_leaves_no_output_behind() {
    let dir = scratch("failed");
    let out = dir.join("out.mcap");
    // Refused before the bag is read: a mesh into a folder that does not exist, and a voxel
    // size fusion refuses; neither leaves an output.
    let missing = dir.join("no/such/folder/mesh.ply");
    let (done, stderr) = bag(&fixture(), &out, &["--mesh", missing.to_str().unwrap()]);
    assert!(!done);
    assert!(
        stderr.contains("--mesh: cannot write") && stderr.contains("no folder"),
        "{stderr}"
    );
    let mesh = dir.join("mesh.ply");
    let (done, stderr) = bag(
        &fixture(),
        &out,
        &["--mesh", mesh.to_str().unwrap(), "--voxel-size", "0"],
    );
    assert!(!done);
    assert!(stderr.contains("voxel"), "{stderr}");
    let names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(names.is_empty(), "left behind: {names:?}");
    // The same command again, without --force: it runs.
    let stderr = ok(
        &sweepdepth(&[
            "bag",
            fixture().to_str().unwrap(),
            out.to_str().unwrap(),
            "--params-file",
            fixture_params().to_str().unwrap(),
        ]),
        "bag after the failed runs",
    );
    assert!(stderr.contains("3 processed"), "{stderr}");
}

/// `--mesh FILE` is an output too: never the input bag or OUT, an existing file replaced only
/// with `--force` and only when it is a PLY, no mesh written by a run that processed no set
/// (the PLY there stays byte for byte), and `--voxel-size` in the `voxel_size` parameter's range.
#[test]
fn mesh_never_replaces_the_input_or_a_good_mesh() {
    let dir = scratch("mesh-target");
    let input = dir.join("in.mcap");
    std::fs::copy(fixture(), &input).unwrap();
    let out = dir.join("out.mcap");
    let refused = |mesh: &Path, extra: &[&str], why: &str| {
        let before = tree(&dir);
        let mut args = vec!["--mesh", mesh.to_str().unwrap()];
        args.extend_from_slice(extra);
        let (done, stderr) = bag(&input, &out, &args);
        assert!(
            !done && stderr.contains(why),
            "{mesh:?} {extra:?}: {stderr}"
        );
        assert!(
            tree(&dir) == before,
            "{mesh:?} {extra:?}: the folder changed"
        );
    };
    refused(&input, &["--force"], "it is the input bag");
    refused(&out, &[], "it is OUT");
    let notes = dir.join("notes.txt");
    std::fs::write(&notes, "mine").unwrap();
    refused(&notes, &["--force"], "is not a PLY");
    refused(
        &dir.join("m.ply"),
        &["--voxel-size", "0.0001"],
        "--voxel-size",
    );
    // A good mesh, then a run that processes no set: the mesh stays.
    let mesh = dir.join("good.ply");
    let (done, stderr) = bag(&input, &out, &["--mesh", mesh.to_str().unwrap()]);
    assert!(done && stderr.contains("depth maps fused into"), "{stderr}");
    let good = std::fs::read(&mesh).unwrap();
    assert!(good.starts_with(b"ply\n") && good.len() > 10_000);
    std::fs::remove_file(&out).unwrap();
    refused(&mesh, &[], "pass --force");
    let (done, stderr) = bag(
        &input,
        &out,
        &[
            "--mesh",
            mesh.to_str().unwrap(),
            "--force",
            "-p",
            "cameras:=[cam0, cam9]",
            "-p",
            "reference_camera:=cam0",
        ],
    );
    assert!(!done, "{stderr}");
    assert!(
        std::fs::read(&mesh).unwrap() == good,
        "the mesh was replaced"
    );
    assert!(!out.exists(), "a bag was written");
    // With --force and sets processed, the mesh is replaced, no partial file left.
    let (done, stderr) = bag(
        &input,
        &out,
        &[
            "--mesh",
            mesh.to_str().unwrap(),
            "--force",
            "--voxel-size",
            "0.1",
        ],
    );
    assert!(done, "{stderr}");
    assert!(std::fs::read(&mesh).unwrap() != good);
    let names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(!names.iter().any(|n| n.ends_with(".partial")), "{names:?}");
    // `--mesh` alone takes `max_blocks`, and blocks it drops are said.
    let (done, stderr) = bag(
        &input,
        &out,
        &[
            "--mesh",
            mesh.to_str().unwrap(),
            "--force",
            "--voxel-size",
            "0.1",
            "-p",
            "max_blocks:=20",
        ],
    );
    assert!(
        done && stderr.contains("20 blocks of 8^3")
            && stderr.contains("blocks dropped at max_blocks 20"),
        "{stderr}"
    );
}

/// Ctrl-C during a long `bag --mesh`: reading stops, the sets in hand finish, and the bag and
/// the mesh are written with the sets processed before it (the run fails, saying so); the
/// work done is not lost. The signal goes once the first set is on the engine (its reference
/// says which views it sweeps with), long before the 300 sets are through.
#[test]
fn ctrl_c_keeps_the_sets_processed_before_it() {
    use std::io::BufRead;
    let dir = scratch("ctrl_c");
    let long = dir.join("long.mcap");
    ok(
        &sweepdepth(&[
            "pack",
            root().join("data/tsukuba").to_str().unwrap(),
            long.to_str().unwrap(),
            "--scale",
            "0.5",
            "--frames",
            "300",
            "--compressed",
        ]),
        "pack",
    );
    let (out, mesh) = (dir.join("out.mcap"), dir.join("map.ply"));
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_sweepdepth"))
        .args(["bag", long.to_str().unwrap(), out.to_str().unwrap()])
        .args([
            "--params-file",
            dir.join("long.params.yaml").to_str().unwrap(),
        ])
        .args(["--mesh", mesh.to_str().unwrap(), "--voxel-size", "0.1"])
        .env("RUST_LOG", "warn,sweepdepth=info")
        .stdin(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run sweepdepth");
    let stderr = child.stderr.take().expect("stderr");
    let mut lines = std::io::BufReader::new(stderr).lines();
    let mut seen = String::new();
    for line in lines.by_ref() {
        let line = line.expect("stderr line");
        seen += &line;
        seen.push('\n');
        if line.contains("sweeps with") {
            break;
        }
    }
    let kill = std::process::Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .expect("kill");
    assert!(kill.success());
    for line in lines {
        seen += &line.expect("stderr line");
        seen.push('\n');
    }
    let status = child.wait().expect("wait");
    assert!(!status.success(), "{seen}");
    assert!(
        seen.contains("Ctrl-C: stopping") && seen.contains("stopped by Ctrl-C after"),
        "{seen}"
    );
    let depths = messages(&out)
        .iter()
        .filter(|m| m.topic == "/depth/image")
        .count();
    assert!((1..300).contains(&depths), "{depths} depth maps: {seen}");
    assert!(
        seen.contains(&format!("{depths} processed")),
        "the summary counts what the bag holds ({depths}): {seen}"
    );
    let ply = std::fs::read(&mesh).expect("the mesh of the sets before Ctrl-C");
    assert!(ply.starts_with(b"ply\n"), "not a PLY");
}
