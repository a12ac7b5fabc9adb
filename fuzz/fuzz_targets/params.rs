//! Arbitrary parameter names and values through the node's parameter validation: the
//! parameter service's check/apply (`LiveParams`) on rigs of 2..6 cameras, YAML values as in
//! `-p name:=value`, and the node's start-up configuration. Nothing may panic; a rejected set
//! must leave the parameters unchanged; an accepted one must leave a consistent engine
//! configuration (min_depth < max_depth, every value within its range).
#![no_main]

use arbitrary::Arbitrary;
use libfuzzer_sys::fuzz_target;
use ros2_client::parameters::ParameterValue as RosValue;
use sweepdepth::node::params::LiveParams;
use sweepdepth::pipeline::PipelineConfig;
use sweepdepth::params::{apply_to_sweep, param_table, validate, ParamSet, ParamValue};
use sweepdepth::sweep::{RigShape, SweepParams};

#[derive(Debug, Arbitrary)]
enum Value {
    Bool(bool),
    Int(i64),
    Double(f64),
    Str(String),
    Strings(Vec<String>),
    Doubles(Vec<f64>),
    Ints(Vec<i64>),
    Bools(Vec<bool>),
    Bytes(Vec<u8>),
    NotSet,
}

impl Value {
    fn ros(&self) -> RosValue {
        match self {
            Value::Bool(b) => RosValue::Boolean(*b),
            Value::Int(i) => RosValue::Integer(*i),
            Value::Double(d) => RosValue::Double(*d),
            Value::Str(s) => RosValue::String(s.clone()),
            Value::Strings(v) => RosValue::StringArray(v.clone()),
            Value::Doubles(v) => RosValue::DoubleArray(v.clone()),
            Value::Ints(v) => RosValue::IntegerArray(v.clone()),
            Value::Bools(v) => RosValue::BooleanArray(v.clone()),
            Value::Bytes(v) => RosValue::ByteArray(v.clone()),
            Value::NotSet => RosValue::NotSet,
        }
    }
}

#[derive(Debug, Arbitrary)]
enum Name {
    /// A parameter of the table, by index.
    Known(u8),
    Any(String),
}

#[derive(Debug, Arbitrary)]
struct Input {
    cameras: u8,
    virtual_reference: bool,
    sets: Vec<(Name, Value)>,
    /// `-p name:=text` at start-up.
    startup: Vec<(Name, String)>,
}

fn name_of(name: &Name) -> String {
    match name {
        Name::Known(i) => {
            let table = param_table();
            table[usize::from(*i) % table.len()].name.to_string()
        }
        Name::Any(s) => s.clone(),
    }
}

fn check_consistent(live: &LiveParams) {
    let params = live.params();
    for (spec, value) in params.iter() {
        assert!(
            validate(spec.name, value).is_ok(),
            "{} = {value:?}",
            spec.name
        );
    }
    let sweep = live.sweep();
    assert!(sweep.min_depth_m < sweep.max_depth_m, "{sweep:?}");
    let mut derived = SweepParams::default();
    apply_to_sweep(&params, &mut derived).unwrap();
    assert_eq!(derived, sweep);
}

fuzz_target!(|input: Input| {
    let cameras = 2 + usize::from(input.cameras % 5);
    let mut set = ParamSet::defaults();
    let names: Vec<String> = (0..cameras).map(|i| format!("cam{i}")).collect();
    set.set("cameras", &ParamValue::StringArray(names)).unwrap();
    if input.virtual_reference {
        set.set("pairs", &ParamValue::String("all".into())).unwrap();
    }
    let mut sweep = SweepParams::default();
    apply_to_sweep(&set, &mut sweep).unwrap();
    let shape = RigShape::chosen_views(cameras, !input.virtual_reference);
    let live = LiveParams::new(set, sweep, shape);
    for (name, value) in input.sets.iter().take(64) {
        let name = name_of(name);
        let value = value.ros();
        let before = (live.params(), live.sweep());
        let checked = live.check(&name, &value);
        let applied = live.apply(&name, &value);
        assert_eq!(checked.is_ok(), applied.is_ok(), "{name} = {value:?}");
        if applied.is_err() {
            assert_eq!(
                (live.params(), live.sweep()),
                before,
                "rejected {name} changed state"
            );
        }
        check_consistent(&live);
    }

    // -p name:=value at start-up (no files: rig_file and parameter files read the disk).
    let mut args: Vec<String> = vec![
        "--ros-args".into(),
        "-p".into(),
        "cameras:=[a, b, c]".into(),
    ];
    for (name, text) in input.startup.iter().take(16) {
        let name = name_of(name);
        if name.contains("rig_file") || text.contains("params-file") {
            continue;
        }
        let _ = ParamValue::parse_yaml(text);
        args.push("-p".into());
        args.push(format!("{name}:={text}"));
    }
    if let Ok(config) = PipelineConfig::from_args(&args) {
        assert!(config.sweep.min_depth_m < config.sweep.max_depth_m);
        assert!(config.time_rules.future_window_ns > 0 && config.time_rules.reset_backwards_ns > 0);
    }
});
