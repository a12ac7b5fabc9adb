//! The files in `launch_configs/`: the parameter files parse with the node's own parser and set
//! what they say, the rig file they name loads, and the launch file is valid Python.
//!
//! Nothing here opens DDS: the parameter path is `parse_ros_args` -> `ParamSet::from_ros_args`
//! -> `check_node`, and `NodeConfig::from_args` (the node's configuration step, before any
//! participant exists).

use std::path::{Path, PathBuf};
use std::process::Command;

use sweepdepth::geometry::{CameraModel, PinholeIntrinsics, Reference, Rig, RigCamera};
use sweepdepth::node::NodeConfig;
use sweepdepth::params::{apply_to_sweep, ParamSet, ParamSource};
use sweepdepth::pipeline::Output;
use sweepdepth::rig_file::{load_rig_file, RigFile};
use sweepdepth::ros::args::{parse_ros_args, NodeIdentity, DEFAULT_NODE_NAME};
use sweepdepth::sweep::{Aggregation, PairSet, Scoring, SweepParams, WindowMode};

const FOUR_CAMERAS: &str = "launch_configs/four_cameras.params.yaml";
const CAMERA_ROW: &str = "launch_configs/camera_row.params.yaml";
const SURROUND: &str = "launch_configs/surround_rig.params.yaml";
const RIG_CAMERA_ROW: &str = "launch_configs/rig_camera_row.yaml";
const RIG_FOUR_CAMERAS: &str = "launch_configs/rig_four_cameras.yaml";
const LAUNCH_FILE: &str = "launch_configs/sweepdepth.launch.py";

fn repo_path(relative: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(relative)
}

fn strings(v: &[&str]) -> Vec<String> {
    v.iter().map(|s| s.to_string()).collect()
}

/// `--ros-args --params-file <file> -r __ns:=<namespace>` as the node parses it: the parameter
/// set for the node `sweepdepth` in `namespace`, its notes, after the node's cross checks.
fn node_params(file: &str, namespace: &str) -> Result<(ParamSet, Vec<String>), String> {
    let path = repo_path(file);
    let mut args = strings(&["--ros-args", "--params-file"]);
    args.push(path.display().to_string());
    args.push("-r".into());
    args.push(format!("__ns:={namespace}"));
    let ros = parse_ros_args(&args).map_err(|e| e.to_string())?;
    assert!(ros.other.is_empty(), "{:?}", ros.other);
    let identity = ros
        .node_identity(DEFAULT_NODE_NAME, "/")
        .map_err(|e| e.to_string())?;
    assert_eq!(
        identity,
        NodeIdentity {
            name: "sweepdepth".into(),
            namespace: namespace.into(),
        }
    );
    let (set, notes) = ParamSet::from_ros_args(&ros, &identity).map_err(|e| e.to_string())?;
    set.check_node().map_err(|e| e.to_string())?;
    Ok((set, notes))
}

fn sweep_params(set: &ParamSet) -> SweepParams {
    let mut sweep = SweepParams::default();
    apply_to_sweep(set, &mut sweep).unwrap();
    sweep
}

/// A rig of the rig file's poses (cameras in `names` order) with a 640x480 pinhole model.
fn rig_from_file(file: &RigFile, names: &[String], reference: usize) -> Rig {
    let model = CameraModel::pinhole(PinholeIntrinsics {
        width_px: 640,
        height_px: 480,
        fx_px: 500.0,
        fy_px: 500.0,
        cx_px: 319.5,
        cy_px: 239.5,
    });
    let cameras: Vec<RigCamera> = names
        .iter()
        .map(|n| {
            file.camera_for(n)
                .unwrap_or_else(|| panic!("{n} is not in {}", file.path.display()))
                .rig_camera(model)
        })
        .collect();
    Rig::new(cameras, Reference::Camera(reference)).unwrap()
}

fn assert_from_file(set: &ParamSet, name: &str, file: &str) {
    match set.source(name) {
        Some(ParamSource::File { path, .. }) => assert!(path.ends_with(file), "{name}: {path:?}"),
        other => panic!("{name} should come from {file}, comes from {other:?}"),
    }
}

#[test]
fn four_cameras_params() {
    let (set, notes) = node_params(FOUR_CAMERAS, "/rig").unwrap();
    assert!(notes.is_empty(), "{notes:?}");
    assert_eq!(
        set.get_string_array("cameras").unwrap(),
        strings(&["cam0", "cam1", "cam2", "cam3"]).as_slice()
    );
    assert_eq!(set.get_str("reference_camera").unwrap(), "cam1");
    assert_eq!(set.reference_camera().as_deref(), Some("cam1"));
    assert_eq!(set.get_str("sync").unwrap(), "approximate");
    assert_eq!(set.get_str("image_topic").unwrap(), "image_raw");
    assert_eq!(set.get_str("rig_file").unwrap(), "");
    assert!(set.get_bool("publish_points").unwrap());
    assert_eq!(set.get_str("scoring").unwrap(), "best_half_sequence");
    assert_eq!(set.get_str("window_mode").unwrap(), "shiftable");
    // Every value is written in the file, so every parameter comes from it.
    for (spec, _) in set.iter() {
        assert_from_file(&set, spec.name, FOUR_CAMERAS);
    }

    let sweep = sweep_params(&set);
    assert_eq!(sweep.min_depth_m, 0.5);
    assert_eq!(sweep.max_depth_m, 6.0);
    assert_eq!(sweep.num_planes, 64);
    assert_eq!(sweep.scoring, Scoring::BestHalfSequence);
    assert_eq!(sweep.pairs, PairSet::Reference);
    assert_eq!(sweep.aggregation, Aggregation::PerPair);
    assert_eq!(sweep.window_mode, WindowMode::Shiftable);
    assert_eq!((sweep.window_width, sweep.window_height), (2, 2));
    // The values the file repeats are the engine defaults.
    let defaults = SweepParams::default();
    assert_eq!(sweep.tau, defaults.tau);
    assert_eq!(sweep.max_cost, defaults.max_cost);
    assert_eq!(sweep.half_best_n, defaults.half_best_n);
    assert_eq!(sweep.half_margin, defaults.half_margin);
    assert_eq!(sweep.cost, defaults.cost);
    assert_eq!(
        (sweep.sgm_p1, sweep.sgm_p2),
        (defaults.sgm_p1, defaults.sgm_p2)
    );

    // The engine's own checks, on the 2x2 rig of rig_four_cameras.yaml.
    let rig_file = load_rig_file(repo_path(RIG_FOUR_CAMERAS)).unwrap();
    let cameras = set.get_string_array("cameras").unwrap();
    let rig = rig_from_file(&rig_file, cameras, 1);
    sweep.validate(&rig).unwrap();
}

#[test]
fn four_cameras_params_are_for_the_rig_namespace() {
    // The section is /rig/sweepdepth: in another namespace nothing applies and the node refuses
    // to start for want of `cameras` (rather than running with defaults).
    let err = node_params(FOUR_CAMERAS, "/").unwrap_err();
    assert!(err.contains("cameras"), "{err}");
    let err = node_params(FOUR_CAMERAS, "/other").unwrap_err();
    assert!(err.contains("cameras"), "{err}");
}

#[test]
fn camera_row_params() {
    // A wildcard section: the file applies in any namespace.
    for namespace in ["/", "/row", "/a/b"] {
        let (set, notes) = node_params(CAMERA_ROW, namespace).unwrap();
        assert!(notes.is_empty(), "{namespace}: {notes:?}");
        assert_eq!(
            set.get_string_array("cameras").unwrap(),
            strings(&["cam0", "cam1", "cam2", "cam3", "cam4"]).as_slice()
        );
        assert_eq!(set.reference_camera().as_deref(), Some("cam2"));
        assert_eq!(set.get_str("rig_file").unwrap(), RIG_CAMERA_ROW);
        assert_eq!(set.get_str("scoring").unwrap(), "best_n_of_m");

        let sweep = sweep_params(&set);
        let defaults = SweepParams::default();
        assert_eq!(sweep.scoring, Scoring::BestNOfM);
        assert_eq!(sweep.best_n, 2);
        assert_eq!(sweep.pairs, PairSet::Reference);
        // The engine's default window: per pair, centred, 5x5.
        assert_eq!(sweep.aggregation, defaults.aggregation);
        assert_eq!(sweep.window_mode, defaults.window_mode);
        assert_eq!(
            (sweep.window_width, sweep.window_height),
            (defaults.window_width, defaults.window_height)
        );
        assert_eq!(sweep.aggregation, Aggregation::PerPair);
        assert_eq!(sweep.window_mode, WindowMode::Centred);
        assert_eq!((sweep.window_width, sweep.window_height), (5, 5));
        assert_eq!(sweep.min_depth_m, 0.5);
        assert_eq!(sweep.max_depth_m, 5.0);
        assert_eq!(sweep.num_planes, 128);
    }
}

#[test]
fn camera_row_rig_file() {
    let (set, _) = node_params(CAMERA_ROW, "/row").unwrap();
    // Relative to the working directory, which is the crate root under `cargo test`.
    let rig_path = set.get_str("rig_file").unwrap();
    let file = load_rig_file(rig_path).unwrap_or_else(|e| panic!("{e}"));
    assert!(file.notes.is_empty(), "{:?}", file.notes);
    let names: Vec<&str> = file.cameras.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["cam0", "cam1", "cam2", "cam3", "cam4"]);
    for (i, camera) in file.cameras.iter().enumerate() {
        let centre = camera.centre_in_rig();
        let want = glam::DVec3::new(0.1 * i as f64, 0.0, 0.0);
        assert!(
            (centre - want).length() < 1e-12,
            "{}: centre {centre:?}, want {want:?}",
            camera.name
        );
        // Identity rotations: cam_from_rig is a pure translation by -centre.
        let p = glam::DVec3::new(1.0, 2.0, 3.0);
        let in_cam = camera.cam_from_rig.transform_point(p);
        assert!((in_cam - (p - want)).length() < 1e-12, "{}", camera.name);
        assert!(
            camera.model.is_none(),
            "{}: intrinsics come from CameraInfo",
            camera.name
        );
    }
    // Every entry of `cameras` is in the file, as the node requires.
    let cameras = set.get_string_array("cameras").unwrap();
    for camera in cameras {
        assert!(file.camera_for(camera).is_some(), "{camera}");
    }

    // The engine accepts the parameters on this rig; best half-sequence would split it 2 | 2.
    let rig = rig_from_file(&file, cameras, 2);
    sweep_params(&set).validate(&rig).unwrap();
    assert_eq!(
        rig.half_sequence_split(),
        [Some(false), Some(false), None, Some(true), Some(true)]
    );
}

#[test]
fn node_config_accepts_the_params_files() {
    // The node's whole configuration step (no DDS): topics, rig file, sync.
    let config = |file: &str, namespace: &str| {
        let mut args = strings(&["--ros-args", "--params-file"]);
        args.push(repo_path(file).display().to_string());
        args.push("-r".into());
        args.push(format!("__ns:={namespace}"));
        NodeConfig::from_args(&args, None)
            .unwrap_or_else(|e| panic!("{file}: {e}"))
            .pipeline
    };

    let four = config(FOUR_CAMERAS, "/rig");
    assert_eq!(four.identity.fqn(), "/rig/sweepdepth");
    assert_eq!(four.reference(), 1);
    assert!(four.rig_file.is_none());
    assert_eq!(
        four.image_topics,
        strings(&[
            "/rig/cam0/image_raw",
            "/rig/cam1/image_raw",
            "/rig/cam2/image_raw",
            "/rig/cam3/image_raw"
        ])
    );
    assert_eq!(four.info_topics[3], "/rig/cam3/camera_info");
    assert_eq!(four.outputs().depth(), "/rig/depth/image");
    assert_eq!(four.tf_static_topic, "/tf_static");

    let row = config(CAMERA_ROW, "/row");
    assert_eq!(row.reference(), 2);
    assert_eq!(row.rig_file.as_ref().map(|f| f.cameras.len()), Some(5));
    assert_eq!(row.image_topics[4], "/row/cam4/image_raw");

    // Several references: each under its camera's namespace; a moving rig.
    let surround = config(SURROUND, "/robot");
    let indices: Vec<usize> = surround.references.iter().map(|(i, _)| *i).collect();
    assert_eq!(indices, vec![0, 1, 2, 3, 4, 5]);
    assert_eq!(surround.references[0].1.depth(), "/robot/cam0/depth/image");
    assert_eq!(
        surround.references[5].1.get(Output::DepthInfo),
        Some("/robot/cam5/depth/camera_info")
    );
    assert_eq!(
        surround.references[3].1.get(Output::Confidence),
        Some("/robot/cam3/confidence/image")
    );
    assert_eq!(
        surround.references[2].1.get(Output::Points),
        Some("/robot/cam2/points")
    );
    assert_eq!(*surround.outputs(), surround.references[0].1);
    let world = surround.world.as_ref().expect("world_frame is set");
    assert_eq!(
        (world.frame.as_str(), world.tf_topic.as_str()),
        ("odom", "/tf")
    );
    assert_eq!(world.tf_timeout, std::time::Duration::from_millis(200));
    assert_eq!(surround.sweep.max_neighbours, 2);
}

#[test]
fn params_files_values_are_all_known_parameters() {
    // No typos hiding in the files: every key is a parameter of the node (a wildcard section
    // would otherwise skip an unknown key with only a note).
    for file in [FOUR_CAMERAS, CAMERA_ROW, SURROUND] {
        let parsed = sweepdepth::ros::args::load_params_file(&repo_path(file)).unwrap();
        assert_eq!(parsed.sections.len(), 1, "{file}");
        for (name, value) in &parsed.sections[0].params {
            sweepdepth::params::coerce(name, value)
                .unwrap_or_else(|e| panic!("{file}: {name}: {e}"));
        }
    }
}

fn python3() -> Command {
    let probe = Command::new("python3").arg("--version").output();
    match probe {
        Ok(out) if out.status.success() => Command::new("python3"),
        _ => panic!(
            "python3 is needed to check {LAUNCH_FILE} (python3 -m py_compile) but was not found \
             on PATH; install Python 3 (CI has it)"
        ),
    }
}

#[test]
fn launch_file_compiles() {
    // `python3 -m py_compile`, writing the bytecode to a temporary file instead of a
    // __pycache__ next to the launch file.
    let cfile = std::env::temp_dir().join(format!("sweepdepth_launch_{}.pyc", std::process::id()));
    let out = python3()
        .arg("-c")
        .arg("import py_compile, sys; py_compile.compile(sys.argv[1], cfile=sys.argv[2], doraise=True)")
        .arg(repo_path(LAUNCH_FILE))
        .arg(&cfile)
        .output()
        .unwrap();
    let _ = std::fs::remove_file(&cfile);
    assert!(
        out.status.success(),
        "{LAUNCH_FILE} does not compile:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Stand-ins for the `launch` classes the launch file uses (the real ones need a ROS 2
/// install): they record their arguments, so the test can check the command line built.
const LAUNCH_STUBS: &str = include_str!("../fixtures/launch_stubs.py");

#[test]
fn launch_file_builds_the_node_command() {
    let out = python3()
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .arg("-c")
        .arg(LAUNCH_STUBS)
        .arg(repo_path(LAUNCH_FILE))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "running {LAUNCH_FILE}'s generate_launch_description with stub launch modules failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let defaults = &v["defaults"];
    assert_eq!(defaults["params_file"], "<dir>/four_cameras.params.yaml");
    assert_eq!(defaults["namespace"], "/rig");
    assert_eq!(defaults["sweepdepth_bin"], "sweepdepth");
    assert_eq!(defaults["log_level"], "info");
    assert_eq!(defaults["working_directory"], "<dir>/..");
    let cmd: Vec<String> = v["cmd"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s.as_str().unwrap().to_string())
        .collect();
    assert_eq!(
        cmd,
        strings(&[
            "sweepdepth",
            "node",
            "--ros-args",
            "--params-file",
            "<dir>/four_cameras.params.yaml",
            "-r",
            "__ns:=/rig",
            "--log-level",
            "info",
        ])
    );
    assert_eq!(v["cwd"], "<dir>/..");
    // The arguments after the executable and `node` are what the node's parser accepts.
    let mut node_args = cmd[2..].to_vec();
    node_args[2] = repo_path(FOUR_CAMERAS).display().to_string();
    let ros = parse_ros_args(&node_args).unwrap();
    assert!(ros.other.is_empty());
    assert_eq!(ros.log_levels.len(), 1);
    // Every log level offered is one the node accepts.
    for level in v["log_level_choices"].as_array().unwrap() {
        let level = level.as_str().unwrap();
        let args = strings(&["--ros-args", "--log-level", level]);
        parse_ros_args(&args).unwrap_or_else(|e| panic!("{level}: {e}"));
    }
}

const TWO_MACHINES: &str = "launch_configs/two_machines.params.yaml";

#[test]
fn two_machines_params_split_the_references_and_feed_the_fuse_node() {
    // The depth node of each machine (by node name) and the fuse node, as they configure
    // themselves from the one file (no DDS).
    let args = |node: Option<&str>| {
        let mut args = strings(&["--ros-args", "--params-file"]);
        args.push(repo_path(TWO_MACHINES).display().to_string());
        if let Some(node) = node {
            args.push("-r".into());
            args.push(format!("__node:={node}"));
        }
        args
    };
    let depth = |node: &str| {
        NodeConfig::from_args(&args(Some(node)), None)
            .unwrap_or_else(|e| panic!("{TWO_MACHINES} ({node}): {e}"))
            .pipeline
    };
    let a = depth("depth_a");
    let b = depth("depth_b");
    let topics = |p: &sweepdepth::pipeline::PipelineConfig| -> Vec<String> {
        p.references
            .iter()
            .map(|(_, t)| t.depth().to_string())
            .collect()
    };
    assert_eq!(
        topics(&a),
        strings(&[
            "/cam0/depth/image",
            "/cam1/depth/image",
            "/cam2/depth/image"
        ])
    );
    assert_eq!(
        topics(&b),
        strings(&[
            "/cam3/depth/image",
            "/cam4/depth/image",
            "/cam5/depth/image"
        ])
    );
    for p in [&a, &b] {
        assert_eq!(p.world.as_ref().map(|w| w.frame.as_str()), Some("odom"));
        assert!(p.fusion.is_none(), "the depth nodes do not fuse");
    }
    let fuse = sweepdepth::node::fuse_command::FuseConfig::from_args(&args(None), None)
        .unwrap_or_else(|e| panic!("{TWO_MACHINES} (fuse): {e}"));
    assert_eq!(fuse.fqn, "/sweepdepth_fuse");
    let mut both = topics(&a);
    both.extend(topics(&b));
    assert_eq!(
        fuse.depth_topics, both,
        "the fuse node takes every reference's depth"
    );
    assert_eq!(fuse.info_topics[4], "/cam4/depth/camera_info");
    // Each depth's colour: the image of the camera whose depth it is.
    let colours: Vec<String> = (fuse.depth_topics.iter())
        .map(|t| t.replace("/depth/image", "/image_raw"))
        .collect();
    assert_eq!(fuse.color_topics, colours);
    assert_eq!(fuse.world_frame, "odom");
    assert_eq!(fuse.fusion.params.voxel_size_m, 0.04);
    assert_eq!(fuse.fusion.params.max_blocks, 50_000);
    assert_eq!(
        (
            fuse.fusion.params.min_depth_m,
            fuse.fusion.params.max_depth_m
        ),
        (0.5, 8.0)
    );
    assert_eq!(fuse.mesh_topic, "/mesh");
}
