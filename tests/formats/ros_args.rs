//! `--ros-args` parsing, name resolution, parameter files and the parameter table.

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};

use sweepdepth::params::*;
use sweepdepth::ros::args::*;
use sweepdepth::sweep::{Aggregation, Optimizer, PairSet, Scoring, SweepParams, WindowMode};

fn args(v: &[&str]) -> Vec<String> {
    v.iter().map(|s| s.to_string()).collect()
}

fn parse(v: &[&str]) -> RosArgs {
    parse_ros_args(&args(v)).unwrap()
}

fn parse_err(v: &[&str]) -> RosArgsError {
    parse_ros_args(&args(v)).unwrap_err()
}

/// A YAML file under the temp dir with a unique name; removed on drop.
struct TempYaml(PathBuf);

impl TempYaml {
    fn new(text: &str) -> Self {
        static COUNTER: AtomicUsize = AtomicUsize::new(0);
        let n = COUNTER.fetch_add(1, Ordering::SeqCst);
        let path = std::env::temp_dir().join(format!(
            "sweepdepth_ros_args_{}_{n}_{:?}.yaml",
            std::process::id(),
            std::thread::current().id()
        ));
        std::fs::write(&path, text).unwrap();
        TempYaml(path)
    }
    fn path(&self) -> &str {
        self.0.to_str().unwrap()
    }
}

impl Drop for TempYaml {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

fn root_node() -> NodeIdentity {
    NodeIdentity {
        name: "sweepdepth".into(),
        namespace: "/".into(),
    }
}

fn params_for(v: &[&str], node: &NodeIdentity) -> ParamSet {
    ParamSet::from_ros_args(&parse(v), node).unwrap().0
}

// ------------------------------------------------------------------------------------------
// The command line
// ------------------------------------------------------------------------------------------

#[test]
fn other_arguments_pass_through() {
    let a = parse(&[
        "--rig",
        "x.json",
        "--ros-args",
        "-r",
        "a:=b",
        "--",
        "--verbose",
        "--",
        "tail",
        "--ros-args",
        "-p",
        "tau:=5.0",
    ]);
    assert_eq!(
        a.other,
        args(&["--rig", "x.json", "--verbose", "--", "tail"])
    );
    assert_eq!(a.remaps.len(), 1);
    assert_eq!(a.params.len(), 1);
    assert!(parse(&["--a", "b"]).remaps.is_empty());
    assert_eq!(parse(&["--ros-args"]).other, Vec::<String>::new());
}

#[test]
fn long_forms_log_level_and_ignored_flags() {
    let a = parse(&[
        "--ros-args",
        "--remap",
        "a:=b",
        "--param",
        "num_planes:=32",
        "--log-level",
        "DEBUG",
        "--log-level",
        "rcl:=warn",
        "-e",
        "/enclave",
        "--enclave",
        "/e2",
        "--disable-rosout-logs",
    ]);
    assert_eq!(a.remaps.len(), 1);
    assert_eq!(a.params[0].value, ParamValue::Int(32));
    assert_eq!(
        a.log_levels,
        vec![
            LogLevel {
                logger: None,
                level: "debug".into()
            },
            LogLevel {
                logger: Some("rcl".into()),
                level: "warn".into()
            }
        ]
    );
    assert_eq!(a.notes.len(), 3, "{:?}", a.notes);
    assert!(a.notes[0].contains("enclave"));
    assert!(matches!(
        parse_err(&["--ros-args", "--log-level", "loud"]),
        RosArgsError::LogLevel { .. }
    ));
}

#[test]
fn command_line_errors() {
    let e = parse_err(&["--ros-args", "-r", "a_to_b"]);
    assert!(matches!(e, RosArgsError::MalformedRemap { .. }), "{e}");
    assert!(e.to_string().contains("a_to_b"), "{e}");
    assert!(matches!(
        parse_err(&["--ros-args", "-r"]),
        RosArgsError::MissingValue { .. }
    ));
    assert!(matches!(
        parse_err(&["--ros-args", "-p", "tau=3"]),
        RosArgsError::MalformedParam { .. }
    ));
    let e = parse_err(&["--ros-args", "--frobnicate"]);
    assert!(e.to_string().contains("--frobnicate"), "{e}");
    // Invalid names in rules.
    let e = parse_err(&["--ros-args", "-r", "a//b:=c"]);
    assert!(e.to_string().contains("a//b"), "{e}");
    let e = parse_err(&["--ros-args", "-r", "__ns:=relative"]);
    assert!(e.to_string().contains("relative"), "{e}");
    let e = parse_err(&["--ros-args", "-r", "__node:=a/b"]);
    assert!(e.to_string().contains("a/b"), "{e}");
    assert!(parse_ros_args(&args(&["--ros-args", "-r", "1abc:=x"])).is_err());
}

// ------------------------------------------------------------------------------------------
// Remaps and names
// ------------------------------------------------------------------------------------------

#[test]
fn node_and_namespace_remaps() {
    let a = parse(&["--ros-args", "-r", "__ns:=/rig", "-r", "__node:=depth"]);
    let id = a.node_identity("sweepdepth", "/").unwrap();
    assert_eq!(id.name, "depth");
    assert_eq!(id.namespace, "/rig");
    assert_eq!(id.fqn(), "/rig/depth");

    // Targeted at another node: ignored.
    let a = parse(&[
        "--ros-args",
        "-r",
        "other:__node:=x",
        "-r",
        "other:__ns:=/y",
    ]);
    let id = a.node_identity("sweepdepth", "/").unwrap();
    assert_eq!(id.fqn(), "/sweepdepth");

    // Targeted at us; the namespace rule targets the new name (as rcl).
    let a = parse(&[
        "--ros-args",
        "-r",
        "sweepdepth:__node:=depth",
        "-r",
        "depth:__ns:=/a",
    ]);
    assert_eq!(
        a.node_identity("sweepdepth", "/").unwrap().fqn(),
        "/a/depth"
    );

    // The first matching rule wins.
    let a = parse(&["--ros-args", "-r", "__node:=first", "-r", "__node:=second"]);
    assert_eq!(a.node_identity("sweepdepth", "/").unwrap().name, "first");
}

#[test]
fn name_expansion() {
    let r = |name: &str, ns: &str| resolve_topic(name, ns, "sweepdepth", &[]).unwrap();
    assert_eq!(r("left/image_raw", "/"), "/left/image_raw");
    assert_eq!(r("left/image_raw", "/rig"), "/rig/left/image_raw");
    assert_eq!(r("left/image_raw", "/a/b"), "/a/b/left/image_raw");
    assert_eq!(r("~/depth", "/"), "/sweepdepth/depth");
    assert_eq!(r("~/depth", "/rig"), "/rig/sweepdepth/depth");
    assert_eq!(r("~", "/rig"), "/rig/sweepdepth");
    assert_eq!(r("/abs/topic", "/rig"), "/abs/topic");
}

#[test]
fn topic_remaps() {
    let a = parse(&[
        "--ros-args",
        "-r",
        "left/image_raw:=/cams/left/image",
        "-r",
        "~/depth:=depth_out",
        "-r",
        "/abs:=/other",
        "-r",
        "othernode:right/image_raw:=/nope",
        "-r",
        "sweepdepth:centre/image_raw:=/yes",
    ]);
    let rs = |name: &str, ns: &str| resolve_topic(name, ns, "sweepdepth", &a.remaps).unwrap();
    // Relative rule, matched after expansion in the node's namespace.
    assert_eq!(rs("left/image_raw", "/rig"), "/cams/left/image");
    assert_eq!(rs("/rig/left/image_raw", "/rig"), "/cams/left/image");
    // The same rule does not match a name in another namespace.
    assert_eq!(rs("/left/image_raw", "/rig"), "/left/image_raw");
    // Private rule; the relative replacement expands in the namespace.
    assert_eq!(rs("~/depth", "/rig"), "/rig/depth_out");
    assert_eq!(rs("/abs", "/rig"), "/other");
    // Node-targeted rules.
    assert_eq!(rs("right/image_raw", "/"), "/right/image_raw");
    assert_eq!(rs("centre/image_raw", "/"), "/yes");
    assert_eq!(
        resolve_topic("centre/image_raw", "/", "someone_else", &a.remaps).unwrap(),
        "/centre/image_raw"
    );
    // With the node identity from the same command line.
    let id = NodeIdentity {
        name: "sweepdepth".into(),
        namespace: "/rig".into(),
    };
    assert_eq!(
        a.resolve_topic("left/image_raw", &id).unwrap(),
        "/cams/left/image"
    );
}

#[test]
fn topic_and_service_scoped_remaps() {
    let a = parse(&[
        "--ros-args",
        "-r",
        "rostopic://x:=t",
        "-r",
        "rosservice://x:=s",
    ]);
    assert_eq!(resolve_topic("x", "/", "n", &a.remaps).unwrap(), "/t");
    assert_eq!(resolve_service("x", "/", "n", &a.remaps).unwrap(), "/s");
}

#[test]
fn invalid_names_are_named_in_errors() {
    for bad in [
        "a//b",
        "1cam/image",
        "cam/2image",
        "a b",
        "image/",
        "",
        "a~b",
    ] {
        let e = resolve_topic(bad, "/", "sweepdepth", &[]).unwrap_err();
        assert!(
            matches!(e, RosArgsError::InvalidName { ref name, .. } if name == bad),
            "{bad}: {e}"
        );
    }
    let e = resolve_topic("x", "rig", "sweepdepth", &[]).unwrap_err();
    assert!(e.to_string().contains("'rig'"), "{e}");
    let e = resolve_topic("x", "/", "9node", &[]).unwrap_err();
    assert!(e.to_string().contains("9node"), "{e}");
}

// ------------------------------------------------------------------------------------------
// Parameters on the command line and in files
// ------------------------------------------------------------------------------------------

#[test]
fn typed_command_line_params() {
    let a = parse(&[
        "--ros-args",
        "-p",
        "subpixel:=false",
        "-p",
        "num_planes:=3",
        "-p",
        "tau:=2.5",
        "-p",
        "image_topic:='image_rect'",
        "-p",
        "cameras:=[\"l\", \"c\", \"r\"]",
        "-p",
        "x:=[1, 2]",
        "-p",
        "other_node:max_cost:=7.0",
    ]);
    let values: Vec<_> = a.params.iter().map(|p| p.value.clone()).collect();
    assert_eq!(
        values,
        vec![
            ParamValue::Bool(false),
            ParamValue::Int(3),
            ParamValue::Double(2.5),
            ParamValue::String("image_rect".into()),
            ParamValue::StringArray(args(&["l", "c", "r"])),
            ParamValue::IntArray(vec![1, 2]),
            ParamValue::Double(7.0),
        ]
    );
    assert_eq!(a.params[6].node.as_deref(), Some("other_node"));

    // Without the unknown `x`, they apply (the targeted one is for another node).
    let mut a = a;
    a.params.remove(5);
    let (p, notes) = ParamSet::from_ros_args(&a, &root_node()).unwrap();
    assert!(notes.is_empty());
    assert!(!p.get_bool("subpixel").unwrap());
    assert_eq!(p.get_i64("num_planes").unwrap(), 3);
    assert_eq!(p.get_f64("tau").unwrap(), 2.5);
    assert_eq!(p.get_f64("max_cost").unwrap(), 100.0);
    assert_eq!(p.get_str("image_topic").unwrap(), "image_rect");
    assert_eq!(
        p.get_string_array("cameras").unwrap(),
        &args(&["l", "c", "r"])[..]
    );
    assert_eq!(p.source("tau"), Some(&ParamSource::CommandLine));
    assert_eq!(p.source("median"), Some(&ParamSource::Default));
    // An integer for a double parameter is accepted.
    let p = params_for(&["--ros-args", "-p", "tau:=50"], &root_node());
    assert_eq!(p.get("tau"), Some(&ParamValue::Double(50.0)));
    // Targeted at us.
    let p = params_for(&["--ros-args", "-p", "sweepdepth:tau:=7.5"], &root_node());
    assert_eq!(p.get_f64("tau").unwrap(), 7.5);
}

#[test]
fn parameter_value_errors() {
    let node = root_node();
    let check = |rule: &str, what: &str| {
        let a = parse(&["--ros-args", "-p", rule]);
        let e = ParamSet::from_ros_args(&a, &node).unwrap_err();
        let msg = e.to_string();
        assert!(matches!(e, ParamError::From { .. }), "{rule}: {msg}");
        assert!(msg.contains(what), "{rule}: {msg}");
        assert!(msg.contains(rule), "{rule}: {msg}");
    };
    check("no_such_param:=1", "unknown parameter");
    check("num_planes:=2.5", "wrong type");
    check("subpixel:=yes", "wrong type");
    check("num_planes:=1", "out of range");
    check("queue_size:=101", "out of range");
    check("half_margin:=1.0", "out of range");
    check("min_depth:=0.0", "out of range");
    check("scoring:=best_of_all", "not one of the allowed values");
    check("cameras:=[only_one]", "at least 2");
    check("image_topic:=/absolute", "relative");

    assert_eq!(validate("tau", &ParamValue::Double(1.0)), Ok(()));
    assert!(validate("tau", &ParamValue::String("1".into()))
        .unwrap_err()
        .to_string()
        .contains("wrong type"));
    assert!(validate("nope", &ParamValue::Bool(true))
        .unwrap_err()
        .to_string()
        .contains("unknown parameter"));
    assert!(validate("window_mode", &ParamValue::String("left".into()))
        .unwrap_err()
        .to_string()
        .contains("not one of"));
    assert!(validate("best_n", &ParamValue::Int(0))
        .unwrap_err()
        .to_string()
        .contains("out of range"));
}

const FILE_A: &str = r#"
/**:
  ros__parameters:
    num_planes: 100
    tau: 10.0
    use_sim_time: false
    some_other_nodes_param: 3
sweepdepth:
  ros__parameters:
    num_planes: 128
    cameras: ["left", "centre", "right"]
other_node:
  ros__parameters:
    num_planes: 7
    not_ours: true
"#;

#[test]
fn params_file_sections_and_wildcards() {
    let file = TempYaml::new(FILE_A);
    let (p, notes) = ParamSet::from_ros_args(
        &parse(&["--ros-args", "--params-file", file.path()]),
        &root_node(),
    )
    .unwrap();
    // The node section wins over the wildcard before it; other_node's section is ignored.
    assert_eq!(p.get_i64("num_planes").unwrap(), 128);
    assert_eq!(p.get_f64("tau").unwrap(), 10.0);
    assert_eq!(
        p.get_string_array("cameras").unwrap(),
        &args(&["left", "centre", "right"])[..]
    );
    assert!(matches!(p.source("tau"), Some(ParamSource::File { section, .. }) if section == "/**"));
    // The unknown wildcard parameter is a note, not an error; use_sim_time is taken.
    assert_eq!(notes.len(), 1, "{notes:?}");
    assert!(notes.iter().any(|n| n.contains("some_other_nodes_param")));
    assert!(!p.use_sim_time());
    let sim = |rule: &str| {
        ParamSet::from_ros_args(
            &parse(&["--ros-args", "--params-file", file.path(), "-p", rule]),
            &root_node(),
        )
    };
    assert!(sim("use_sim_time:=true").unwrap().0.use_sim_time());
    let error = sim("use_sim_time:=1").unwrap_err().to_string();
    assert!(
        error.contains("use_sim_time") && error.contains("bool"),
        "{error}"
    );

    // A node in a namespace: 'sweepdepth:' is /sweepdepth (root namespace, as rclcpp), so only
    // the wildcard applies.
    let ns_node = NodeIdentity {
        name: "sweepdepth".into(),
        namespace: "/rig".into(),
    };
    let (p, _) = ParamSet::from_ros_args(
        &parse(&["--ros-args", "--params-file", file.path()]),
        &ns_node,
    )
    .unwrap();
    assert_eq!(p.get_i64("num_planes").unwrap(), 100);

    // __node remap: the section of the new name applies.
    let a = parse(&[
        "--ros-args",
        "-r",
        "__node:=other_node",
        "--params-file",
        file.path(),
    ]);
    let id = a.node_identity(DEFAULT_NODE_NAME, "/").unwrap();
    let e = ParamSet::from_ros_args(&a, &id).unwrap_err();
    // other_node's own section has a parameter we lack: an error there (not a wildcard).
    assert!(e.to_string().contains("not_ours"), "{e}");
    assert!(e.to_string().contains(file.path()), "{e}");
}

#[test]
fn params_file_fully_qualified_nested_and_wildcard_paths() {
    let file = TempYaml::new(
        r#"
/rig/sweepdepth:
  ros__parameters:
    num_planes: 200
    tau: 20.0
rig:
  sweepdepth:
    ros__parameters:
      max_cost: 30.0
/**/sweepdepth:
  ros__parameters:
    median: false
/rig/*:
  ros__parameters:
    best_n: 3
/other/sweepdepth:
  ros__parameters:
    num_planes: 9
"#,
    );
    let a = parse(&[
        "--ros-args",
        "-r",
        "__ns:=/rig",
        "--params-file",
        file.path(),
    ]);
    let id = a.node_identity("sweepdepth", "/").unwrap();
    let (p, _) = ParamSet::from_ros_args(&a, &id).unwrap();
    assert_eq!(p.get_i64("num_planes").unwrap(), 200);
    assert_eq!(p.get_f64("tau").unwrap(), 20.0);
    assert_eq!(p.get_f64("max_cost").unwrap(), 30.0);
    assert!(!p.get_bool("median").unwrap());
    assert_eq!(p.get_i64("best_n").unwrap(), 3);

    // Without the namespace only /**/sweepdepth applies.
    let (p, _) = ParamSet::from_ros_args(
        &parse(&["--ros-args", "--params-file", file.path()]),
        &root_node(),
    )
    .unwrap();
    assert_eq!(p.get_i64("num_planes").unwrap(), 64);
    assert!(!p.get_bool("median").unwrap());
    assert_eq!(p.get_i64("best_n").unwrap(), 2);
}

#[test]
fn nested_keys_are_flattened() {
    let file = TempYaml::new(
        r#"
sweepdepth:
  ros__parameters:
    group:
      inner:
        x: 1
      y: [1.5, 2]
    tau: 3
"#,
    );
    let a = parse(&["--ros-args", "--params-file", file.path()]);
    let section = &a.params_files[0].sections[0];
    assert_eq!(section.node_pattern, "/sweepdepth");
    assert_eq!(
        section.params,
        vec![
            ("group.inner.x".to_string(), ParamValue::Int(1)),
            (
                "group.y".to_string(),
                ParamValue::DoubleArray(vec![1.5, 2.0])
            ),
            ("tau".to_string(), ParamValue::Int(3)),
        ]
    );
    // group.inner.x is unknown in our own section: an error naming it and the file.
    let e = ParamSet::from_ros_args(&a, &root_node()).unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("group.inner.x") && msg.contains(file.path()),
        "{msg}"
    );
}

#[test]
fn precedence_file_order_then_command_line() {
    let first = TempYaml::new(
        "/**:\n  ros__parameters:\n    num_planes: 10\n    tau: 1.0\n    max_cost: 1.0\n",
    );
    let second =
        TempYaml::new("sweepdepth:\n  ros__parameters:\n    num_planes: 20\n    tau: 2.0\n");
    // As rcl merges them (checked against rcl itself in tests/node/ros_args_rcl.rs): every -p lives
    // under `/**`, so a file's section for the node, a later entry of the merged table, wins
    // over -p, even a later one.
    let p = params_for(
        &[
            "--ros-args",
            "-p",
            "num_planes:=30",
            "--params-file",
            first.path(),
            "--params-file",
            second.path(),
            "-p",
            "num_planes:=40",
        ],
        &root_node(),
    );
    assert_eq!(p.get_i64("num_planes").unwrap(), 20);
    assert_eq!(p.get_f64("tau").unwrap(), 2.0);
    assert_eq!(p.get_f64("max_cost").unwrap(), 1.0);
    // Reverse file order: the node's section is now the first entry, `/**` the later one.
    let p = params_for(
        &[
            "--ros-args",
            "--params-file",
            second.path(),
            "--params-file",
            first.path(),
        ],
        &root_node(),
    );
    assert_eq!(p.get_i64("num_planes").unwrap(), 10);
    assert_eq!(p.get_f64("tau").unwrap(), 1.0);
}

#[test]
fn params_file_errors_name_the_file() {
    let bad = TempYaml::new("sweepdepth:\n  ros__parameters:\n    tau: [1, \n");
    let e = parse_err(&["--ros-args", "--params-file", bad.path()]);
    assert!(matches!(e, RosArgsError::ParamsFileYaml { .. }), "{e}");
    assert!(e.to_string().contains(bad.path()), "{e}");

    let missing = std::env::temp_dir().join(format!(
        "sweepdepth_ros_args_missing_{}.yaml",
        std::process::id()
    ));
    let e = parse_err(&["--ros-args", "--params-file", missing.to_str().unwrap()]);
    assert!(matches!(e, RosArgsError::ParamsFileRead { .. }), "{e}");
    assert!(e.to_string().contains(missing.to_str().unwrap()), "{e}");

    let no_section = TempYaml::new("sweepdepth: 3\n");
    let e = parse_err(&["--ros-args", "--params-file", no_section.path()]);
    assert!(matches!(e, RosArgsError::ParamsFileFormat { .. }), "{e}");
    assert!(e.to_string().contains(no_section.path()), "{e}");

    let wrong_type = TempYaml::new("sweepdepth:\n  ros__parameters:\n    subpixel: 1\n");
    let e = ParamSet::from_ros_args(
        &parse(&["--ros-args", "--params-file", wrong_type.path()]),
        &root_node(),
    )
    .unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("subpixel") && msg.contains("wrong type") && msg.contains(wrong_type.path()),
        "{msg}"
    );

    // A known parameter in a wildcard section is still checked.
    let wild = TempYaml::new("/**:\n  ros__parameters:\n    num_planes: 5000\n");
    let e = ParamSet::from_ros_args(
        &parse(&["--ros-args", "--params-file", wild.path()]),
        &root_node(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("out of range"), "{e}");
}

#[test]
fn node_checks() {
    let mut p = ParamSet::defaults();
    assert!(p.check_node().unwrap_err().to_string().contains("cameras"));
    assert_eq!(p.reference_camera(), None);
    p.set(
        "cameras",
        &ParamValue::StringArray(args(&["left", "centre", "right"])),
    )
    .unwrap();
    assert_eq!(p.check_node(), Ok(()));
    assert_eq!(p.reference_camera().as_deref(), Some("centre"));
    p.set("reference_camera", &ParamValue::String("left".into()))
        .unwrap();
    assert_eq!(p.reference_camera().as_deref(), Some("left"));
    p.set("reference_camera", &ParamValue::String("up".into()))
        .unwrap();
    assert!(p.check_node().unwrap_err().to_string().contains("up"));
}

// ------------------------------------------------------------------------------------------
// ROS_DOMAIN_ID
// ------------------------------------------------------------------------------------------

#[test]
fn ros_domain_id() {
    assert_eq!(domain_id(None).unwrap(), 0);
    assert_eq!(domain_id(Some("")).unwrap(), 0);
    assert_eq!(domain_id(Some("  ")).unwrap(), 0);
    assert_eq!(domain_id(Some("0")).unwrap(), 0);
    assert_eq!(domain_id(Some("42")).unwrap(), 42);
    assert_eq!(domain_id(Some(" 7 ")).unwrap(), 7);
    assert_eq!(domain_id(Some("232")).unwrap(), 232);
    for bad in ["233", "-1", "abc", "1.5", "99999999999"] {
        let e = domain_id(Some(bad)).unwrap_err();
        assert!(matches!(e, RosArgsError::DomainId { .. }), "{bad}");
        assert!(e.to_string().contains(bad), "{e}");
    }
}

// ------------------------------------------------------------------------------------------
// The table against SweepParams and the docs
// ------------------------------------------------------------------------------------------

/// ROS name of each SweepParams field.
fn ros_name(field: &str) -> &str {
    match field {
        "min_depth_m" => "min_depth",
        "max_depth_m" => "max_depth",
        other => other,
    }
}

#[test]
fn defaults_match_sweep_params() {
    let json = serde_json::to_value(SweepParams::default()).unwrap();
    let fields = json.as_object().unwrap();
    assert_eq!(fields.len(), 36);
    for (field, value) in fields {
        let spec = param_spec(ros_name(field))
            .unwrap_or_else(|| panic!("SweepParams::{field} has no parameter"));
        assert!(!spec.read_only, "{field}: engine parameters are dynamic");
        match (&spec.default, value) {
            (ParamValue::Bool(b), serde_json::Value::Bool(v)) => assert_eq!(b, v, "{field}"),
            (ParamValue::Int(i), serde_json::Value::Number(n)) => {
                assert_eq!(Some(*i), n.as_i64(), "{field}")
            }
            (ParamValue::Double(d), serde_json::Value::Number(n)) => {
                let v = n.as_f64().unwrap();
                // f32 fields: compare at f32 precision.
                assert!(
                    (d - v).abs() <= 1e-6 * v.abs().max(1.0),
                    "{field}: {d} vs {v}"
                )
            }
            (ParamValue::String(s), serde_json::Value::String(v)) => {
                assert_eq!(s, v, "{field}");
                assert!(validate(spec.name, &spec.default).is_ok());
            }
            (d, v) => panic!("{field}: default {d:?} vs {v:?}"),
        }
    }

    // apply_to_sweep sets every field: from a value with every field changed, the defaults
    // give SweepParams::default() back.
    let mut p = SweepParams {
        min_depth_m: 1.0,
        max_depth_m: 2.0,
        num_planes: 3,
        cost: sweepdepth::sweep::Cost::Census,
        scoring: Scoring::Sssd,
        pairs: PairSet::All,
        best_n: 5,
        half_best_n: 0,
        aggregation: Aggregation::Scored,
        window_width: 2,
        window_height: 4,
        window_mode: WindowMode::Shiftable,
        tau: 1.0,
        max_cost: 2.0,
        keep_range_ends: true,
        subpixel: false,
        subpixel_refine: true,
        subpixel_v_fit: true,
        median: false,
        rectify_pairs: false,
        joint_median_radius: 9,
        joint_median_colour: 3.0,
        joint_median_fill: false,
        min_visible_cameras: 7,
        occlusion_tolerance: 0.5,
        half_margin: 0.5,
        optimizer: Optimizer::Wta,
        sgm_p1: 3.0,
        sgm_p2: 4.0,
        sgm_paths: 4,
        sgm_edge: 9.0,
        coarse_to_fine: false,
        max_neighbours: 3,
        prefilter: sweepdepth::sweep::Prefilter::None,
        uniqueness: 0.5,
        ambiguity: 0.4,
    };
    apply_to_sweep(&ParamSet::defaults(), &mut p).unwrap();
    assert_eq!(p, SweepParams::default());
}

#[test]
fn apply_to_sweep_maps_names_and_enums() {
    let p = params_for(
        &[
            "--ros-args",
            "-p",
            "min_depth:=0.25",
            "-p",
            "scoring:=best_half_sequence",
            "-p",
            "pairs:=all",
            "-p",
            "aggregation:=per_half",
            "-p",
            "window_mode:=shiftable",
            "-p",
            "window_width:=2",
            "-p",
            "tau:=64",
            "-p",
            "cost:=census",
        ],
        &root_node(),
    );
    let mut s = SweepParams::default();
    apply_to_sweep(&p, &mut s).unwrap();
    assert_eq!(s.cost, sweepdepth::sweep::Cost::Census);
    assert_eq!(s.min_depth_m, 0.25);
    assert_eq!(s.scoring, Scoring::BestHalfSequence);
    assert_eq!(s.pairs, PairSet::All);
    assert_eq!(s.aggregation, Aggregation::PerHalf);
    assert_eq!(s.window_mode, WindowMode::Shiftable);
    assert_eq!(s.window_width, 2);
    assert_eq!(s.tau, 64.0);
    for scoring in ["sssd", "all_pairs", "best_n_of_m", "best_half_sequence"] {
        let mut set = ParamSet::defaults();
        set.set("scoring", &ParamValue::String(scoring.into()))
            .unwrap();
        apply_to_sweep(&set, &mut s).unwrap();
    }
}

#[test]
fn table_has_node_parameters() {
    let expect = [
        ("cameras", ParamValue::StringArray(vec![])),
        ("image_topic", ParamValue::String("image_raw".into())),
        ("image_transport", ParamValue::String("raw".into())),
        ("image_kinds", ParamValue::StringArray(vec![])),
        ("reference_camera", ParamValue::String(String::new())),
        ("references", ParamValue::StringArray(vec![])),
        ("world_frame", ParamValue::String(String::new())),
        ("tf_timeout", ParamValue::Double(0.5)),
        ("device", ParamValue::String("auto".into())),
        ("sync", ParamValue::String("approximate".into())),
        ("sync_max_interval", ParamValue::Double(0.02)),
        ("queue_size", ParamValue::Int(5)),
        ("age_penalty", ParamValue::Double(0.1)),
        ("sync_future_window", ParamValue::Double(10.0)),
        ("sync_reset_backwards", ParamValue::Double(1.0)),
        ("rig_file", ParamValue::String(String::new())),
        ("publish_points", ParamValue::Bool(false)),
        ("input_qos_reliable", ParamValue::Bool(false)),
        ("input_qos_depth", ParamValue::Int(5)),
        ("output_qos_depth", ParamValue::Int(1)),
        ("camera_timeout", ParamValue::Double(1.0)),
        ("foxglove_port", ParamValue::Int(0)),
        ("foxglove_address", ParamValue::String("127.0.0.1".into())),
        ("fusion", ParamValue::Bool(false)),
        ("voxel_size", ParamValue::Double(0.05)),
        ("max_blocks", ParamValue::Int(50_000)),
        ("mesh_rate", ParamValue::Double(1.0)),
        ("fusion_device", ParamValue::String("auto".into())),
        ("depth_topics", ParamValue::StringArray(vec![])),
        ("color_topics", ParamValue::StringArray(vec![])),
    ];
    for (name, default) in &expect {
        let spec = param_spec(name).unwrap_or_else(|| panic!("{name} missing"));
        assert_eq!(&spec.default, default, "{name}");
    }
    assert!(param_spec("cameras").unwrap().required);
    // 36 engine parameters, the node parameters above, and 9 for the virtual reference camera.
    assert_eq!(param_table().len(), 36 + expect.len() + 9);
}

#[test]
fn markdown_table_lists_every_parameter() {
    let md = markdown_table();
    assert!(md.starts_with("| Parameter | Type | Default | Range | Description |"));
    let rows: Vec<&str> = md.lines().skip(2).collect();
    assert_eq!(rows.len(), param_table().len());
    for (p, row) in param_table().iter().zip(&rows) {
        assert!(row.starts_with(&format!("| `{}` |", p.name)), "{row}");
        // Every row has exactly 5 cells (escaped pipes do not split).
        let cells = row.replace("\\|", "").matches('|').count();
        assert_eq!(cells, 6, "{row}");
    }
    assert!(
        md.contains("| `num_planes` | `integer` | `64` | 2 ..= 4096 |"),
        "{md}"
    );
    assert!(md.contains("`best_n_of_m`"));
    assert!(md.contains("(required)"));
}

/// docs/engine.md's list of the engine options names every engine parameter's option.
#[test]
fn engine_page_lists_every_engine_option() {
    let page = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/docs/engine.md"))
        .expect("docs/engine.md is readable");
    let start = page
        .find("## Engine options")
        .expect("an engine options section");
    let end = page[start..]
        .find("\n## ")
        .map_or(page.len(), |e| start + e);
    let section = page[start..end].replace('\n', " ");
    for param in sweepdepth::params::engine::engine_params() {
        let option = match param.flag {
            sweepdepth::params::engine::Flag::Long(name) => format!("`--{name}"),
            other => format!("`--{} WxH`", other.long()),
        };
        assert!(
            section.contains(&option),
            "docs/engine.md's engine options do not name {option}` ({})",
            param.spec.name
        );
    }
}

/// The parameter section of docs/node.md is the table's own rendering (the table drives the
/// docs), and the README links to it.
#[test]
fn readme_links_the_node_page_whose_parameter_section_is_the_generated_table() {
    let readme = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README.md"))
        .expect("README.md is readable");
    assert!(
        readme.contains("(docs/node.md)"),
        "README links to docs/node.md, the page with the parameter table"
    );
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/docs/node.md");
    let page = std::fs::read_to_string(path).expect("docs/node.md is readable");
    let start_marker =
        "<!-- parameter table: generated by `sweepdepth::params::markdown_table()` -->\n";
    let start = page
        .find(start_marker)
        .expect("docs/node.md has the table's start marker")
        + start_marker.len();
    let end = page[start..]
        .find("<!-- end of parameter table -->")
        .expect("docs/node.md has the table's end marker")
        + start;
    let table = sweepdepth::params::markdown_table();
    if std::env::var_os("SWEEPDEPTH_WRITE_DOCS").is_some() && page[start..end] != table {
        let updated = format!("{}{}{}", &page[..start], table, &page[end..]);
        std::fs::write(path, updated).expect("docs/node.md is writable");
        return;
    }
    assert_eq!(
        &page[start..end],
        table,
        "docs/node.md's parameter table is stale: run `SWEEPDEPTH_WRITE_DOCS=1 cargo test --test formats readme` to regenerate it"
    );
}
