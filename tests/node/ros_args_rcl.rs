//! `--ros-args` = rcl: the command lines of tests/fixtures/ros_args_cases.json resolved by rcl
//! itself (rclpy.init + a Node, `tools/rclpy_ros_args.py`, through `tools/ros_python`) and by
//! our parser, compared case by case: refused or not, node name and namespace, resolved topic
//! names, parameter values (every parameter rcl declares from the overrides has our value; every
//! parameter we took from the command line rcl has too), the node logger's effective level.
//!
//! SAFETY: rclpy's Node opens DDS: only inside the private network namespace of
//! tests/common/netns.rs.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::{Command, Stdio};

use crate::common::netns::in_private_netns;
use crate::common::rclpy;
use serde_json::{json, Value};
use sweepdepth::params::{ParamSet, ParamSource, ParamValue};
use sweepdepth::ros::args::parse_ros_args;

const INNER: &str = "SWEEPDEPTH_TEST_PRIVATE_NETNS";

#[test]
fn ros_args_resolve_as_rcl_does() {
    in_private_netns(INNER, "ros_args_rcl::ros_args_resolve_as_rcl_does", compare);
}

fn fixture() -> Value {
    let path = rclpy::repo().join("tests/fixtures/ros_args_cases.json");
    let text = std::fs::read_to_string(&path).expect("read the cases");
    serde_json::from_str(&text).expect("cases JSON")
}

/// The cases with `{fileN}` replaced by parameter files written under `dir`.
fn materialise(cases: &Value, dir: &std::path::Path) -> Value {
    let mut paths = Vec::new();
    for (i, text) in cases["files"].as_array().expect("files").iter().enumerate() {
        let path = dir.join(format!("params{i}.yaml"));
        std::fs::write(&path, text.as_str().expect("file text")).expect("write params file");
        paths.push(path.to_string_lossy().into_owned());
    }
    let mut out = cases.clone();
    for case in out["cases"].as_array_mut().expect("cases") {
        for arg in case["args"].as_array_mut().expect("args") {
            let mut s = arg.as_str().expect("arg").to_string();
            for (i, p) in paths.iter().enumerate() {
                s = s.replace(&format!("{{file{i}}}"), p);
            }
            *arg = json!(s);
        }
    }
    out
}

fn param_json(value: &ParamValue) -> Value {
    match value {
        ParamValue::Bool(b) => json!(b),
        ParamValue::Int(i) => json!(i),
        ParamValue::Double(d) => json!(d),
        ParamValue::String(s) => json!(s),
        ParamValue::BoolArray(v) => json!(v),
        ParamValue::IntArray(v) => json!(v),
        ParamValue::DoubleArray(v) => json!(v),
        ParamValue::StringArray(v) => json!(v),
    }
}

/// Equal as JSON, integers and doubles compared as numbers (rcl keeps `min_depth:=1` an
/// integer; our double parameter holds 1.0).
fn same(a: &Value, b: &Value) -> bool {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => x.as_f64() == y.as_f64(),
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(a, b)| same(a, b))
        }
        _ => a == b,
    }
}

/// What our parser makes of a case, in the shape the Python side prints.
fn ours(case: &Value, topics: &[String]) -> Value {
    let args: Vec<String> = std::iter::once("--ros-args".to_string())
        .chain(
            case["args"]
                .as_array()
                .expect("args")
                .iter()
                .map(|a| a.as_str().expect("arg").to_string()),
        )
        .collect();
    let ros = match parse_ros_args(&args) {
        Ok(ros) => ros,
        Err(e) => return json!({ "error": e.to_string() }),
    };
    let node = match ros.node_identity("sweepdepth", "/") {
        Ok(node) => node,
        Err(e) => return json!({ "error": e.to_string() }),
    };
    let mut resolved = BTreeMap::new();
    for t in topics {
        match ros.resolve_topic(t, &node) {
            Ok(r) => resolved.insert(t.clone(), json!(r)),
            Err(e) => return json!({ "error": format!("topic {t}: {e}") }),
        };
    }
    let params = match ParamSet::from_ros_args(&ros, &node) {
        Ok((set, _notes)) => set,
        Err(e) => return json!({ "error": e.to_string() }),
    };
    let given: BTreeMap<String, Value> = params
        .iter()
        .filter(|(spec, _)| !matches!(params.source(spec.name), Some(ParamSource::Default)))
        .map(|(spec, v)| (spec.name.to_string(), param_json(v)))
        .collect();
    let mut all: BTreeMap<String, Value> = params
        .iter()
        .map(|(spec, v)| (spec.name.to_string(), param_json(v)))
        .collect();
    // Beside the table, as on every rcl node.
    all.insert("use_sim_time".into(), json!(params.use_sim_time()));
    let logger = node.fqn().trim_start_matches('/').replace('/', ".");
    json!({
        "name": node.name,
        "namespace": node.namespace,
        "topics": resolved,
        "params": given,
        "all_params": all,
        "log_level": ros.log_level(&logger),
    })
}

fn compare() {
    rclpy::require_rclpy();
    let dir = std::env::temp_dir().join(format!("sweepdepth_ros_args_rcl_{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let cases = materialise(&fixture(), &dir);
    let cases_path: PathBuf = dir.join("cases.json");
    std::fs::write(&cases_path, cases.to_string()).expect("write cases");
    let out = Command::new(rclpy::launcher())
        .arg(rclpy::repo().join("tools/rclpy_ros_args.py"))
        .arg(&cases_path)
        .env("ROS_DOMAIN_ID", "51")
        .stdin(Stdio::null())
        .output()
        .expect("run tools/rclpy_ros_args.py");
    assert!(
        out.status.success(),
        "rclpy_ros_args.py failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rcl: Vec<Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter(|l| l.starts_with('{'))
        .map(|l| serde_json::from_str(l).expect("a JSON line"))
        .collect();
    let topics: Vec<String> = cases["topics"]
        .as_array()
        .expect("topics")
        .iter()
        .map(|t| t.as_str().expect("topic").to_string())
        .collect();
    let list = cases["cases"].as_array().expect("cases");
    assert_eq!(rcl.len(), list.len(), "one answer per case from rcl");
    let mut differences = Vec::new();
    for (case, theirs) in list.iter().zip(&rcl) {
        let name = case["name"].as_str().unwrap_or("?");
        let mine = ours(case, &topics);
        let mut diff = |what: String| differences.push(format!("{name}: {what}"));
        match (theirs.get("error"), mine.get("error")) {
            (Some(_), Some(_)) => continue,
            (Some(e), None) => {
                diff(format!("rcl refuses ({e}), we accept: {mine}"));
                continue;
            }
            (None, Some(e)) => {
                diff(format!("we refuse ({e}), rcl accepts: {theirs}"));
                continue;
            }
            (None, None) => {}
        }
        for key in ["name", "namespace"] {
            if theirs[key] != mine[key] {
                diff(format!("{key}: rcl {} / ours {}", theirs[key], mine[key]));
            }
        }
        for t in &topics {
            if theirs["topics"][t] != mine["topics"][t] {
                diff(format!(
                    "topic {t}: rcl {} / ours {}",
                    theirs["topics"][t], mine["topics"][t]
                ));
            }
        }
        let their_params = theirs["params"].as_object().cloned().unwrap_or_default();
        for (p, v) in &their_params {
            if !same(v, &mine["all_params"][p]) {
                diff(format!(
                    "parameter {p}: rcl {v} / ours {}",
                    mine["all_params"][p]
                ));
            }
        }
        for (p, v) in mine["params"].as_object().cloned().unwrap_or_default() {
            if !their_params.contains_key(&p) {
                diff(format!(
                    "parameter {p}: ours {v} from the command line, rcl has none"
                ));
            }
        }
        if case.get("loggers").is_some() && theirs["log_level"] != mine["log_level"] {
            diff(format!(
                "log level: rcl {} / ours {}",
                theirs["log_level"], mine["log_level"]
            ));
        }
        eprintln!("{name}: same as rcl ({theirs})");
    }
    let _ = std::fs::remove_dir_all(&dir);
    assert!(
        differences.is_empty(),
        "{} difference(s) from rcl:\n{}",
        differences.len(),
        differences.join("\n")
    );
}
