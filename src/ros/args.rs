//! `--ros-args` parsing (as rcl/rclcpp do it), ROS 2 name resolution and the node's parameter
//! table.
//!
//! `ros2-client` parses no ROS command line, so this module does what rcl does for a C++ node:
//!
//! * [`parse_ros_args`] splits the arguments after the subcommand into ours (`other`, for clap)
//!   and the ones inside `--ros-args ... [--]`: remaps (`-r`), parameters (`-p`), parameter files
//!   (`--params-file`, read and parsed right away like rcl does), log levels; `-e`/`--enclave`
//!   and the logging switches are accepted and ignored with a note.
//! * [`RosArgs::node_identity`] applies `__node`/`__ns`; [`resolve_topic`] and
//!   [`resolve_service`] expand relative (`left/image_raw`), private (`~/x`) and absolute names
//!   and apply the remap rules on the fully qualified names.
//! * [`param_table`] is the one list of parameters ([`ParamSpec`]): engine parameters (the
//!   fields of [`SweepParams`]) and node parameters. [`ParamSet::from_ros_args`] starts from the
//!   defaults and applies the parameter files (in order, matching sections only) and then `-p`;
//!   [`apply_to_sweep`] fills a [`SweepParams`]; [`markdown_table`] documents the table.
//! * [`domain_id`] checks `ROS_DOMAIN_ID`.
//!
//! Deliberate differences from rclcpp: a `double` parameter also takes an integer (`-p tau:=100`)
//! and a `double[]` an integer sequence, where rclcpp reports a type error; `-p` overrides
//! parameter files whatever their order on the command line (rcl applies them in order).

use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::LazyLock;

use crate::sweep::gpu_types::{MAX_BEST_N, MAX_HALF_BEST_N, MAX_RIG_CAMERAS};
use crate::sweep::{Aggregation, PairSet, Scoring, SweepParams, WindowMode};

/// The node's default name (before `__node` remaps).
pub const DEFAULT_NODE_NAME: &str = "sweepdepth";

/// Longest fully qualified topic name rmw accepts (`RMW_TOPIC_MAX_NAME_LENGTH`).
const MAX_TOPIC_NAME_LENGTH: usize = 247;
/// Longest node name rmw accepts (`RMW_NODE_NAME_MAX_NAME_LENGTH`).
const MAX_NODE_NAME_LENGTH: usize = 255;
/// Highest `ROS_DOMAIN_ID` accepted (the DDS port formula runs out above it).
pub const MAX_DOMAIN_ID: u16 = 232;

/// Errors from the ROS command line, names, parameter files and parameter values.
#[derive(Debug, thiserror::Error)]
pub enum RosArgsError {
    #[error("ROS argument '{flag}' needs a value after it")]
    MissingValue { flag: String },
    #[error("unknown ROS argument '{arg}' inside --ros-args")]
    UnknownRosArg { arg: String },
    #[error("malformed remap rule '{rule}': {reason}")]
    MalformedRemap { rule: String, reason: String },
    #[error("malformed parameter rule '{rule}': {reason}")]
    MalformedParam { rule: String, reason: String },
    #[error("invalid log level '{value}': {reason}")]
    LogLevel { value: String, reason: String },
    #[error("invalid ROS name '{name}': {reason}")]
    InvalidName { name: String, reason: String },
    #[error("cannot read params file '{}': {source}", path.display())]
    ParamsFileRead {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("params file '{}' is not valid YAML: {message}", path.display())]
    ParamsFileYaml { path: PathBuf, message: String },
    #[error("params file '{}': {message}", path.display())]
    ParamsFileFormat { path: PathBuf, message: String },
    #[error("parameter '{name}' (from {origin}): {reason}")]
    Param {
        name: String,
        origin: String,
        reason: String,
    },
    #[error("invalid ROS_DOMAIN_ID '{value}': {reason}")]
    DomainId { value: String, reason: String },
}

// ---------------------------------------------------------------------------------------------
// Parameter values
// ---------------------------------------------------------------------------------------------

/// A ROS 2 parameter value (byte arrays are not supported).
#[derive(Debug, Clone, PartialEq)]
pub enum ParamValue {
    Bool(bool),
    Int(i64),
    Double(f64),
    String(String),
    BoolArray(Vec<bool>),
    IntArray(Vec<i64>),
    DoubleArray(Vec<f64>),
    StringArray(Vec<String>),
}

/// The ROS 2 parameter types.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParamKind {
    Bool,
    Int,
    Double,
    String,
    BoolArray,
    IntArray,
    DoubleArray,
    StringArray,
}

impl ParamKind {
    /// The ROS type name (`bool`, `integer`, `double`, `string`, `string[]`, ...).
    pub fn ros_name(self) -> &'static str {
        match self {
            ParamKind::Bool => "bool",
            ParamKind::Int => "integer",
            ParamKind::Double => "double",
            ParamKind::String => "string",
            ParamKind::BoolArray => "bool[]",
            ParamKind::IntArray => "integer[]",
            ParamKind::DoubleArray => "double[]",
            ParamKind::StringArray => "string[]",
        }
    }

    fn is_array(self) -> bool {
        matches!(
            self,
            ParamKind::BoolArray
                | ParamKind::IntArray
                | ParamKind::DoubleArray
                | ParamKind::StringArray
        )
    }
}

impl fmt::Display for ParamKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.ros_name())
    }
}

impl ParamValue {
    pub fn kind(&self) -> ParamKind {
        match self {
            ParamValue::Bool(_) => ParamKind::Bool,
            ParamValue::Int(_) => ParamKind::Int,
            ParamValue::Double(_) => ParamKind::Double,
            ParamValue::String(_) => ParamKind::String,
            ParamValue::BoolArray(_) => ParamKind::BoolArray,
            ParamValue::IntArray(_) => ParamKind::IntArray,
            ParamValue::DoubleArray(_) => ParamKind::DoubleArray,
            ParamValue::StringArray(_) => ParamKind::StringArray,
        }
    }

    fn is_empty_array(&self) -> bool {
        match self {
            ParamValue::BoolArray(v) => v.is_empty(),
            ParamValue::IntArray(v) => v.is_empty(),
            ParamValue::DoubleArray(v) => v.is_empty(),
            ParamValue::StringArray(v) => v.is_empty(),
            _ => false,
        }
    }

    pub fn as_bool(&self) -> Option<bool> {
        match self {
            ParamValue::Bool(b) => Some(*b),
            _ => None,
        }
    }

    pub fn as_i64(&self) -> Option<i64> {
        match self {
            ParamValue::Int(i) => Some(*i),
            _ => None,
        }
    }

    /// Doubles, and integers converted.
    pub fn as_f64(&self) -> Option<f64> {
        match self {
            ParamValue::Double(d) => Some(*d),
            ParamValue::Int(i) => Some(*i as f64),
            _ => None,
        }
    }

    pub fn as_str(&self) -> Option<&str> {
        match self {
            ParamValue::String(s) => Some(s),
            _ => None,
        }
    }

    pub fn as_string_array(&self) -> Option<&[String]> {
        match self {
            ParamValue::StringArray(v) => Some(v),
            _ => None,
        }
    }

    pub fn as_f64_array(&self) -> Option<&[f64]> {
        match self {
            ParamValue::DoubleArray(v) => Some(v),
            _ => None,
        }
    }

    /// Parses a `-p name:=VALUE` value like rcl: as one YAML scalar or a flat sequence
    /// (`true`, `3`, `2.5`, `'str'`, `[1, 2]`, `["a", "b"]`); an empty value is the empty string.
    pub fn parse_yaml(text: &str) -> Result<ParamValue, String> {
        if text.trim().is_empty() {
            return Ok(ParamValue::String(String::new()));
        }
        let value: serde_yaml_ng::Value =
            serde_yaml_ng::from_str(text).map_err(|e| format!("not a YAML value: {e}"))?;
        ParamValue::from_yaml(&value)
    }

    /// Converts a parsed YAML value (a scalar or a flat sequence of one type; integers and
    /// doubles mixed make a double sequence).
    pub fn from_yaml(value: &serde_yaml_ng::Value) -> Result<ParamValue, String> {
        use serde_yaml_ng::Value as Y;
        match value {
            Y::Null => Err("has no value (null)".into()),
            Y::Bool(b) => Ok(ParamValue::Bool(*b)),
            Y::Number(n) => yaml_number(n),
            Y::String(s) => Ok(ParamValue::String(s.clone())),
            Y::Tagged(t) => ParamValue::from_yaml(&t.value),
            Y::Mapping(_) => Err("a mapping is not a parameter value".into()),
            Y::Sequence(items) => {
                let scalars = items
                    .iter()
                    .map(|item| match item {
                        Y::Sequence(_) | Y::Mapping(_) => {
                            Err("nested sequences and mappings are not parameter values".into())
                        }
                        other => ParamValue::from_yaml(other),
                    })
                    .collect::<Result<Vec<_>, String>>()?;
                sequence_value(scalars)
            }
        }
    }
}

fn yaml_number(n: &serde_yaml_ng::Number) -> Result<ParamValue, String> {
    if let Some(i) = n.as_i64() {
        Ok(ParamValue::Int(i))
    } else if n.is_u64() {
        Err(format!("integer {n} does not fit a 64-bit signed integer"))
    } else {
        n.as_f64()
            .map(ParamValue::Double)
            .ok_or_else(|| format!("unsupported number {n}"))
    }
}

fn sequence_value(items: Vec<ParamValue>) -> Result<ParamValue, String> {
    let Some(first) = items.first() else {
        // An empty sequence has no element type; it fits any array parameter.
        return Ok(ParamValue::StringArray(Vec::new()));
    };
    let mixed = || "sequence elements must all have the same type".to_string();
    match first.kind() {
        ParamKind::Bool => items
            .iter()
            .map(|v| v.as_bool().ok_or_else(mixed))
            .collect::<Result<_, _>>()
            .map(ParamValue::BoolArray),
        ParamKind::String => items
            .iter()
            .map(|v| v.as_str().map(str::to_string).ok_or_else(mixed))
            .collect::<Result<_, _>>()
            .map(ParamValue::StringArray),
        ParamKind::Int | ParamKind::Double => {
            if items.iter().all(|v| matches!(v, ParamValue::Int(_))) {
                items
                    .iter()
                    .map(|v| v.as_i64().ok_or_else(mixed))
                    .collect::<Result<_, _>>()
                    .map(ParamValue::IntArray)
            } else {
                items
                    .iter()
                    .map(|v| v.as_f64().ok_or_else(mixed))
                    .collect::<Result<_, _>>()
                    .map(ParamValue::DoubleArray)
            }
        }
        _ => Err(mixed()),
    }
}

impl fmt::Display for ParamValue {
    /// YAML-like: `true`, `5`, `0.02`, `image_raw`, `[a, b]`, `''` for the empty string.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fn list<T>(
            f: &mut fmt::Formatter<'_>,
            items: &[T],
            each: impl Fn(&T) -> String,
        ) -> fmt::Result {
            let parts: Vec<String> = items.iter().map(each).collect();
            write!(f, "[{}]", parts.join(", "))
        }
        fn string(s: &str) -> String {
            if s.is_empty() {
                "''".into()
            } else {
                s.to_string()
            }
        }
        match self {
            ParamValue::Bool(b) => write!(f, "{b}"),
            ParamValue::Int(i) => write!(f, "{i}"),
            ParamValue::Double(d) => write!(f, "{d:?}"),
            ParamValue::String(s) => f.write_str(&string(s)),
            ParamValue::BoolArray(v) => list(f, v, |b| b.to_string()),
            ParamValue::IntArray(v) => list(f, v, |i| i.to_string()),
            ParamValue::DoubleArray(v) => list(f, v, |d| format!("{d:?}")),
            ParamValue::StringArray(v) => list(f, v, |s| string(s)),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// The parameter table
// ---------------------------------------------------------------------------------------------

/// The accepted values of a parameter (ROS ranges are inclusive; the exclusive bounds here are
/// published as inclusive ranges with a note in the description).
#[derive(Debug, Clone, PartialEq)]
pub enum ParamRange {
    /// Any value of the type.
    Any,
    Int {
        min: i64,
        max: i64,
    },
    /// Always finite; `max = f64::INFINITY` means no upper bound.
    Double {
        min: f64,
        max: f64,
        min_exclusive: bool,
        max_exclusive: bool,
    },
    /// One of these strings.
    OneOf(&'static [&'static str]),
    /// A relative ROS name (no leading `/` or `~`).
    RelativeName,
    /// Empty, or a ROS name.
    OptionalName,
    /// At least `min_len` distinct ROS names.
    NameList {
        min_len: usize,
    },
    /// A list whose every entry is one of these strings.
    EachOneOf(&'static [&'static str]),
}

impl ParamRange {
    const fn at_least(min: f64) -> Self {
        ParamRange::Double {
            min,
            max: f64::INFINITY,
            min_exclusive: false,
            max_exclusive: false,
        }
    }

    const fn above(min: f64) -> Self {
        ParamRange::Double {
            min,
            max: f64::INFINITY,
            min_exclusive: true,
            max_exclusive: false,
        }
    }

    /// How the range reads in the docs and in errors.
    pub fn describe(&self) -> String {
        match self {
            ParamRange::Any => String::new(),
            ParamRange::Int { min, max } => format!("{min} ..= {max}"),
            ParamRange::Double {
                min,
                max,
                min_exclusive,
                max_exclusive,
            } => {
                if max.is_infinite() {
                    format!("{} {min:?}", if *min_exclusive { ">" } else { ">=" })
                } else {
                    format!(
                        "{}{min:?}, {max:?}{}",
                        if *min_exclusive { "(" } else { "[" },
                        if *max_exclusive { ")" } else { "]" }
                    )
                }
            }
            ParamRange::OneOf(values) => values.join(" | "),
            ParamRange::RelativeName => "relative ROS name".into(),
            ParamRange::OptionalName => "empty or a ROS name".into(),
            ParamRange::NameList { min_len } => format!(">= {min_len} distinct ROS names"),
            ParamRange::EachOneOf(values) => format!("each {}", values.join(" | ")),
        }
    }
}

/// One parameter of the node.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamSpec {
    /// The ROS parameter name.
    pub name: &'static str,
    pub kind: ParamKind,
    pub default: ParamValue,
    pub range: ParamRange,
    pub description: &'static str,
    /// Cannot change after the node started.
    pub read_only: bool,
    /// The default is a placeholder; the node does not start without a value.
    pub required: bool,
}

/// Parameters every rclcpp node has, or that tools set for all nodes: accepted from parameter
/// files and ignored with a note.
const IGNORED_STANDARD_PARAMS: &[&str] = &["use_sim_time", "start_type_description_service"];

fn spec(
    name: &'static str,
    default: ParamValue,
    range: ParamRange,
    description: &'static str,
) -> ParamSpec {
    ParamSpec {
        name,
        kind: default.kind(),
        default,
        range,
        description,
        read_only: false,
        required: false,
    }
}

fn node_spec(
    name: &'static str,
    default: ParamValue,
    range: ParamRange,
    description: &'static str,
) -> ParamSpec {
    ParamSpec {
        read_only: true,
        ..spec(name, default, range, description)
    }
}

fn s(v: &str) -> ParamValue {
    ParamValue::String(v.to_string())
}

static PARAM_TABLE: LazyLock<Vec<ParamSpec>> = LazyLock::new(|| {
    use ParamValue::{Bool, Double, Int};
    // The engine defaults are literals (readable in the docs); a test checks them against
    // SweepParams::default().
    vec![
        // Engine parameters (SweepParams); they can change at run time.
        spec(
            "min_depth",
            Double(0.5),
            ParamRange::above(0.0),
            "Nearest depth swept, metres (must be < max_depth).",
        ),
        spec(
            "max_depth",
            Double(10.0),
            ParamRange::above(0.0),
            "Farthest depth swept, metres.",
        ),
        spec(
            "num_planes",
            Int(64),
            ParamRange::Int { min: 2, max: 4096 },
            "Number of depth planes, uniform in inverse depth.",
        ),
        spec(
            "scoring",
            s("best_n_of_m"),
            ParamRange::OneOf(&["sssd", "all_pairs", "best_n_of_m", "best_half_sequence"]),
            "How the camera pairs of one hypothesis combine into one score.",
        ),
        spec(
            "pairs",
            s("reference"),
            ParamRange::OneOf(&["reference", "all"]),
            "Camera pairs that are scored: the reference against each other camera, or all pairs.",
        ),
        spec(
            "best_n",
            Int(2),
            ParamRange::Int {
                min: 1,
                max: i64::from(MAX_BEST_N),
            },
            "n of best n of m.",
        ),
        spec(
            "half_best_n",
            Int(2),
            ParamRange::Int {
                min: 0,
                max: i64::from(MAX_HALF_BEST_N),
            },
            "Best half-sequence with per-pair aggregation: mean of the n best pairs of each half (0 = all pairs, the paper's rule).",
        ),
        spec(
            "aggregation",
            s("per_pair"),
            ParamRange::OneOf(&["scored", "per_half", "per_pair"]),
            "Where the windows aggregate: the scored cost, each half, or each camera pair.",
        ),
        spec(
            "window_width",
            Int(9),
            ParamRange::Int { min: 1, max: 33 },
            "Aggregation window width, pixels (1 = none; shiftable windows: 1 or even).",
        ),
        spec(
            "window_height",
            Int(9),
            ParamRange::Int { min: 1, max: 33 },
            "Aggregation window height, pixels (1 = none; shiftable windows: 1 or even).",
        ),
        spec(
            "window_mode",
            s("centred"),
            ParamRange::OneOf(&["shiftable", "centred"]),
            "Window placement: the best of the four corner windows (the paper), or one centred window.",
        ),
        spec(
            "tau",
            Double(100.0),
            ParamRange::above(0.0),
            "Truncation of the colour SSD (sum over RGB of squared 0..255 differences).",
        ),
        spec(
            "max_cost",
            Double(100.0),
            ParamRange::above(0.0),
            "A best score above this makes the pixel invalid.",
        ),
        spec(
            "subpixel",
            Bool(true),
            ParamRange::Any,
            "Sub-pixel (parabola) refinement of the depth.",
        ),
        spec(
            "median",
            Bool(true),
            ParamRange::Any,
            "3x3 median filter on the depth map.",
        ),
        spec(
            "min_visible_cameras",
            Int(2),
            ParamRange::Int {
                min: 0,
                max: i64::from(MAX_RIG_CAMERAS),
            },
            "Pixels seen by fewer cameras (the reference counted) are invalid; 0 or 1 disables.",
        ),
        spec(
            "occlusion_tolerance",
            Double(0.01),
            ParamRange::at_least(0.0),
            "Relative depth tolerance of the occlusion z-test.",
        ),
        spec(
            "half_margin",
            Double(0.1),
            ParamRange::Double {
                min: 0.0,
                max: 1.0,
                min_exclusive: false,
                max_exclusive: true,
            },
            "A half is clearly better when its score is below (1 - margin) times the other's, and lower by at least margin x 25 (the noise floor of an RGB SSD).",
        ),
        spec(
            "optimizer",
            s("sgm"),
            ParamRange::OneOf(&["wta", "sgm"]),
            "Depth selection: local winner-take-all (the paper) or semi-global matching over a u16 cost volume.",
        ),
        spec(
            "sgm_p1",
            Double(3.0),
            ParamRange::at_least(0.0),
            "SGM penalty for a one-plane step between neighbours, score units (those of tau).",
        ),
        spec(
            "sgm_p2",
            Double(100.0),
            ParamRange::at_least(0.0),
            "SGM penalty for a larger step, score units (>= sgm_p1; paths x (tau + P2) must fit 16 bits: P2 <= 7 x tau with 8 paths).",
        ),
        spec(
            "sgm_paths",
            Int(8),
            ParamRange::Int { min: 4, max: 8 },
            "SGM path directions: 4 (rows and columns) or 8 (plus diagonals).",
        ),
        spec(
            "sgm_edge",
            Double(10.0),
            ParamRange::Double {
                min: 0.0,
                max: 255.0,
                min_exclusive: false,
                max_exclusive: false,
            },
            "SGM: colour step (largest RGB difference between path neighbours, 0..255) at which P2 is halved (P2 / (1 + step / sgm_edge), at least P1); 0 = constant P2.",
        ),
        // Node parameters; fixed once the node runs.
        ParamSpec {
            required: true,
            ..node_spec(
                "cameras",
                ParamValue::StringArray(Vec::new()),
                ParamRange::NameList { min_len: 2 },
                "Camera namespaces, left to right; images come from `<camera>/<image_topic>`, calibration from `<camera>/camera_info` or rig_file.",
            )
        },
        node_spec(
            "image_topic",
            s("image_raw"),
            ParamRange::RelativeName,
            "Image topic under each camera namespace.",
        ),
        node_spec(
            "image_kinds",
            ParamValue::StringArray(Vec::new()),
            ParamRange::EachOneOf(&["raw", "rect", "auto"]),
            "Per camera (in the order of cameras), what its image topic carries: raw (described by the CameraInfo's K and D) or rect (rectified: P, in the frame rotated by R); auto or an empty list = from the topic's name (image_raw, image, image_color: raw; image_rect*: rect; any other name: raw, with a note at start-up).",
        ),
        node_spec(
            "reference_camera",
            s(""),
            ParamRange::OptionalName,
            "Camera whose view the depth map is in; empty = the middle entry of cameras.",
        ),
        node_spec(
            "sync",
            s("approximate"),
            ParamRange::OneOf(&["exact", "approximate"]),
            "Time synchronisation of the camera images: equal stamps, or approximate.",
        ),
        node_spec(
            "camera_timeout",
            Double(1.0),
            ParamRange::Double {
                min: 0.0,
                max: 3600.0,
                min_exclusive: false,
                max_exclusive: false,
            },
            "A camera silent for this long (seconds; receive time live, log time in bags) leaves the rig until it sends again; the node goes on with the others while at least 2 remain with the reference among them. 0 = never.",
        ),
        node_spec(
            "sync_max_interval",
            Double(0.02),
            ParamRange::Double {
                min: 0.0,
                max: 60.0,
                min_exclusive: false,
                max_exclusive: false,
            },
            "Approximate sync: largest spread of the stamps of one set, seconds.",
        ),
        node_spec(
            "queue_size",
            Int(5),
            ParamRange::Int { min: 1, max: 100 },
            "Messages kept per camera while waiting for a matching set.",
        ),
        node_spec(
            "age_penalty",
            Double(0.1),
            ParamRange::at_least(0.0),
            "Approximate sync: penalty on waiting for newer messages (as message_filters' ApproximateTime).",
        ),
        node_spec(
            "sync_future_window",
            Double(10.0),
            ParamRange::Double {
                min: 1.0,
                max: 86400.0,
                min_exclusive: false,
                max_exclusive: false,
            },
            "An image stamped more than this many seconds ahead of the newest stamp of every other camera is dropped (counted as future).",
        ),
        node_spec(
            "sync_reset_backwards",
            Double(1.0),
            ParamRange::Double {
                min: 0.0,
                max: 86400.0,
                min_exclusive: true,
                max_exclusive: false,
            },
            "A camera whose stamps go back by more than this many seconds (a bag played in a loop) resets the synchroniser; less is a late image, dropped.",
        ),
        node_spec(
            "rig_file",
            s(""),
            ParamRange::Any,
            "Rig calibration file (our YAML or Kalibr's camchain.yaml); empty = extrinsics from /tf_static and intrinsics from each camera_info.",
        ),
        node_spec(
            "publish_points",
            Bool(false),
            ParamRange::Any,
            "Also publish a sensor_msgs/PointCloud2 of the valid depths.",
        ),
        node_spec(
            "input_qos_reliable",
            Bool(false),
            ParamRange::Any,
            "Subscribe to the images with reliable QoS (default: best effort, the sensor-data profile).",
        ),
        node_spec(
            "input_qos_depth",
            Int(5),
            ParamRange::Int { min: 1, max: 1000 },
            "History depth of the image subscriptions.",
        ),
        node_spec(
            "output_qos_depth",
            Int(1),
            ParamRange::Int { min: 1, max: 1000 },
            "History depth of the publishers.",
        ),
        node_spec(
            "virtual_reference",
            Bool(false),
            ParamRange::Any,
            "Estimate depth for a virtual camera (virtual_* parameters) instead of reference_camera; needs pairs = all (the default reference becomes all).",
        ),
        node_spec(
            "virtual_frame_id",
            s(""),
            ParamRange::Any,
            "Virtual reference: tf frame of its optical frame, the outputs' frame_id; placed from /tf_static (with rig_file: by virtual_pose). Empty = virtual_pose, outputs in the reference camera's frame.",
        ),
        node_spec(
            "virtual_pose",
            ParamValue::DoubleArray(vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]),
            ParamRange::Any,
            "Virtual reference: [x, y, z, qx, qy, qz, qw] pose of its optical frame in the reference camera's optical frame (metres; unit quaternion); unused when virtual_frame_id is placed by /tf_static.",
        ),
        node_spec(
            "virtual_width",
            Int(0),
            ParamRange::Int { min: 0, max: 16384 },
            "Virtual reference: image width, pixels (0 = the reference camera's).",
        ),
        node_spec(
            "virtual_height",
            Int(0),
            ParamRange::Int { min: 0, max: 16384 },
            "Virtual reference: image height, pixels (0 = the reference camera's).",
        ),
        node_spec(
            "virtual_fx",
            Double(0.0),
            ParamRange::at_least(0.0),
            "Virtual reference: focal length fx, pixels (0 = the reference camera's).",
        ),
        node_spec(
            "virtual_fy",
            Double(0.0),
            ParamRange::at_least(0.0),
            "Virtual reference: focal length fy, pixels (0 = the reference camera's).",
        ),
        node_spec(
            "virtual_cx",
            Double(0.0),
            ParamRange::at_least(0.0),
            "Virtual reference: principal point cx, pixels (0 = the reference camera's).",
        ),
        node_spec(
            "virtual_cy",
            Double(0.0),
            ParamRange::at_least(0.0),
            "Virtual reference: principal point cy, pixels (0 = the reference camera's).",
        ),
    ]
});

/// Every parameter of the node, engine parameters first.
pub fn param_table() -> &'static [ParamSpec] {
    &PARAM_TABLE
}

/// The table entry of `name`.
pub fn param_spec(name: &str) -> Option<&'static ParamSpec> {
    param_table().iter().find(|p| p.name == name)
}

fn param_index(name: &str) -> Option<usize> {
    param_table().iter().position(|p| p.name == name)
}

/// Checks `value` for parameter `name`: known name, type, range or allowed values.
pub fn validate(name: &str, value: &ParamValue) -> Result<(), String> {
    coerce(name, value).map(|_| ())
}

/// [`validate`], returning the value as stored (integers become doubles for `double`
/// parameters, empty sequences take the parameter's array type).
pub fn coerce(name: &str, value: &ParamValue) -> Result<ParamValue, String> {
    let spec = param_spec(name).ok_or_else(|| format!("unknown parameter '{name}'"))?;
    let value = coerce_kind(spec, value)?;
    check_range(spec, &value)?;
    Ok(value)
}

fn coerce_kind(spec: &ParamSpec, value: &ParamValue) -> Result<ParamValue, String> {
    if value.kind() == spec.kind {
        return Ok(value.clone());
    }
    let converted = match (spec.kind, value) {
        (ParamKind::Double, ParamValue::Int(i)) => Some(ParamValue::Double(*i as f64)),
        (ParamKind::DoubleArray, ParamValue::IntArray(v)) => Some(ParamValue::DoubleArray(
            v.iter().map(|i| *i as f64).collect(),
        )),
        (kind, v) if kind.is_array() && v.is_empty_array() => Some(match kind {
            ParamKind::BoolArray => ParamValue::BoolArray(Vec::new()),
            ParamKind::IntArray => ParamValue::IntArray(Vec::new()),
            ParamKind::DoubleArray => ParamValue::DoubleArray(Vec::new()),
            _ => ParamValue::StringArray(Vec::new()),
        }),
        _ => None,
    };
    converted.ok_or_else(|| {
        format!(
            "wrong type: expected {}, got {} {}",
            spec.kind,
            value.kind(),
            value
        )
    })
}

fn check_range(spec: &ParamSpec, value: &ParamValue) -> Result<(), String> {
    match (&spec.range, value) {
        (ParamRange::Any, ParamValue::Double(d)) if !d.is_finite() => {
            Err(format!("must be finite, got {d}"))
        }
        (ParamRange::Any, _) => Ok(()),
        (ParamRange::Int { min, max }, ParamValue::Int(i)) => {
            if (*min..=*max).contains(i) {
                Ok(())
            } else {
                Err(format!("out of range: must be in {min}..={max}, got {i}"))
            }
        }
        (
            ParamRange::Double {
                min,
                max,
                min_exclusive,
                max_exclusive,
            },
            ParamValue::Double(d),
        ) => {
            let above_min = if *min_exclusive {
                *d > *min
            } else {
                *d >= *min
            };
            let below_max = if *max_exclusive {
                *d < *max
            } else {
                *d <= *max
            };
            if d.is_finite() && above_min && below_max {
                Ok(())
            } else {
                let range = spec.range.describe();
                let verb = if range.starts_with(['[', '(']) {
                    "must be in"
                } else {
                    "must be"
                };
                Err(format!("out of range: {verb} {range}, got {d:?}"))
            }
        }
        (ParamRange::OneOf(allowed), ParamValue::String(v)) => {
            if allowed.contains(&v.as_str()) {
                Ok(())
            } else {
                Err(format!(
                    "'{v}' is not one of the allowed values: {}",
                    allowed.join(", ")
                ))
            }
        }
        (ParamRange::RelativeName, ParamValue::String(v)) => {
            validate_topic_name(v).map_err(|e| e.to_string())?;
            if v.starts_with('/') || v.starts_with('~') {
                Err(format!("'{v}' must be a relative name"))
            } else {
                Ok(())
            }
        }
        (ParamRange::OptionalName, ParamValue::String(v)) => {
            if v.is_empty() {
                Ok(())
            } else {
                validate_topic_name(v).map_err(|e| e.to_string())
            }
        }
        (ParamRange::NameList { min_len }, ParamValue::StringArray(names)) => {
            if names.len() < *min_len {
                return Err(format!(
                    "needs at least {min_len} entries, got {}",
                    names.len()
                ));
            }
            for (i, name) in names.iter().enumerate() {
                validate_topic_name(name).map_err(|e| e.to_string())?;
                if names[..i].contains(name) {
                    return Err(format!("'{name}' appears more than once"));
                }
            }
            Ok(())
        }
        (ParamRange::EachOneOf(allowed), ParamValue::StringArray(values)) => {
            match values.iter().find(|v| !allowed.contains(&v.as_str())) {
                None => Ok(()),
                Some(v) => Err(format!(
                    "'{v}' is not one of the allowed values: {}",
                    allowed.join(", ")
                )),
            }
        }
        (range, v) => Err(format!(
            "internal: range {range:?} does not apply to a {}",
            v.kind()
        )),
    }
}

/// Where a parameter's current value came from.
#[derive(Debug, Clone, PartialEq)]
pub enum ParamSource {
    Default,
    /// A parameter file and the section that matched.
    File {
        path: PathBuf,
        section: String,
    },
    /// `-p` on the command line.
    CommandLine,
    /// Set by the program (e.g. a parameter service).
    Set,
}

/// The current value of every parameter in [`param_table`], in table order.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamSet {
    values: Vec<ParamValue>,
    sources: Vec<ParamSource>,
}

impl Default for ParamSet {
    fn default() -> Self {
        Self::defaults()
    }
}

impl ParamSet {
    /// Every parameter at its default.
    pub fn defaults() -> Self {
        Self {
            values: param_table().iter().map(|p| p.default.clone()).collect(),
            sources: vec![ParamSource::Default; param_table().len()],
        }
    }

    pub fn get(&self, name: &str) -> Option<&ParamValue> {
        param_index(name).and_then(|i| self.values.get(i))
    }

    pub fn source(&self, name: &str) -> Option<&ParamSource> {
        param_index(name).and_then(|i| self.sources.get(i))
    }

    /// Validates and sets one value (see [`coerce`]).
    pub fn set(&mut self, name: &str, value: &ParamValue) -> Result<(), String> {
        self.set_from(name, value, ParamSource::Set)
    }

    fn set_from(
        &mut self,
        name: &str,
        value: &ParamValue,
        source: ParamSource,
    ) -> Result<(), String> {
        let value = coerce(name, value)?;
        let i = param_index(name).ok_or_else(|| format!("unknown parameter '{name}'"))?;
        self.values[i] = value;
        self.sources[i] = source;
        Ok(())
    }

    /// `(spec, value)` for every parameter, in table order.
    pub fn iter(&self) -> impl Iterator<Item = (&'static ParamSpec, &ParamValue)> {
        param_table().iter().zip(self.values.iter())
    }

    fn typed<T>(&self, name: &str, f: impl Fn(&ParamValue) -> Option<T>) -> Result<T, String> {
        let v = self
            .get(name)
            .ok_or_else(|| format!("unknown parameter '{name}'"))?;
        f(v).ok_or_else(|| format!("parameter '{name}' is a {}", v.kind()))
    }

    pub fn get_bool(&self, name: &str) -> Result<bool, String> {
        self.typed(name, ParamValue::as_bool)
    }
    pub fn get_i64(&self, name: &str) -> Result<i64, String> {
        self.typed(name, ParamValue::as_i64)
    }
    pub fn get_f64(&self, name: &str) -> Result<f64, String> {
        self.typed(name, ParamValue::as_f64)
    }
    pub fn get_str(&self, name: &str) -> Result<&str, String> {
        let v = self
            .get(name)
            .ok_or_else(|| format!("unknown parameter '{name}'"))?;
        v.as_str()
            .ok_or_else(|| format!("parameter '{name}' is a {}", v.kind()))
    }
    pub fn get_string_array(&self, name: &str) -> Result<&[String], String> {
        let v = self
            .get(name)
            .ok_or_else(|| format!("unknown parameter '{name}'"))?;
        v.as_string_array()
            .ok_or_else(|| format!("parameter '{name}' is a {}", v.kind()))
    }

    /// The node's checks across parameters: `cameras` is set (>= 2 distinct names) and
    /// `reference_camera` is empty or one of them.
    pub fn check_node(&self) -> Result<(), String> {
        let cameras = self.get_string_array("cameras")?;
        if let Some(spec) = param_spec("cameras") {
            check_range(spec, &ParamValue::StringArray(cameras.to_vec()))
                .map_err(|e| format!("parameter 'cameras' (required): {e}"))?;
        }
        let reference = self.get_str("reference_camera")?;
        if !reference.is_empty() && !cameras.iter().any(|c| c == reference) {
            return Err(format!(
                "reference_camera '{reference}' is not one of cameras [{}]",
                cameras.join(", ")
            ));
        }
        if self.get_bool("virtual_reference")? {
            if self.get_str("pairs")? == "reference"
                && self.source("pairs") != Some(&ParamSource::Default)
            {
                return Err("virtual_reference needs pairs = all (a virtual camera has no image to pair with), but pairs was set to 'reference'".into());
            }
            self.virtual_pose()?;
        }
        Ok(())
    }

    /// `virtual_pose` checked: 7 finite numbers `[x, y, z, qx, qy, qz, qw]` with a unit
    /// quaternion by tf2's rule (`geometry::pose::unit_quaternion`).
    pub fn virtual_pose(&self) -> Result<[f64; 7], String> {
        let v = self
            .get("virtual_pose")
            .and_then(ParamValue::as_f64_array)
            .ok_or_else(|| "parameter 'virtual_pose' is not a double[]".to_string())?;
        let pose: [f64; 7] = v.try_into().map_err(|_| {
            format!(
                "parameter 'virtual_pose' needs 7 values [x, y, z, qx, qy, qz, qw], got {}",
                v.len()
            )
        })?;
        if pose.iter().any(|x| !x.is_finite()) {
            return Err("parameter 'virtual_pose' has a NaN or infinite value".into());
        }
        crate::geometry::pose::unit_quaternion(glam::DQuat::from_xyzw(
            pose[3], pose[4], pose[5], pose[6],
        ))
        .map_err(|e| format!("parameter 'virtual_pose': [qx, qy, qz, qw]: {e}"))?;
        Ok(pose)
    }

    /// `reference_camera`, or the middle entry of `cameras` when it is empty (None without
    /// cameras).
    pub fn reference_camera(&self) -> Option<String> {
        let reference = self.get_str("reference_camera").ok()?;
        if !reference.is_empty() {
            return Some(reference.to_string());
        }
        let cameras = self.get_string_array("cameras").ok()?;
        cameras.get(cameras.len() / 2).cloned()
    }

    /// Defaults, then the matching sections of the parameter files in command-line order, then
    /// `-p` overrides (in order) for this node. Returns the notes on what was ignored.
    ///
    /// Unknown parameters are errors in sections for this node and in `-p`; in wildcard
    /// sections (shared with other nodes) they are ignored with a note. Values of known
    /// parameters are always checked.
    pub fn from_ros_args(
        args: &RosArgs,
        node: &NodeIdentity,
    ) -> Result<(ParamSet, Vec<String>), RosArgsError> {
        let mut set = ParamSet::defaults();
        let mut notes = Vec::new();
        let fqn = node.fqn();
        for file in &args.params_files {
            for section in &file.sections {
                if !node_pattern_matches(&section.node_pattern, &fqn) {
                    continue;
                }
                let wildcard = section.node_pattern.contains('*');
                let origin = format!(
                    "params file '{}', section '{}'",
                    file.path.display(),
                    section.node_pattern
                );
                for (name, value) in &section.params {
                    if param_spec(name).is_none() {
                        if let Some(note) = ignored_standard(name) {
                            notes.push(format!("{origin}: {note}"));
                            continue;
                        }
                        if wildcard {
                            notes.push(format!(
                                "{origin}: ignoring parameter '{name}', which {fqn} does not have"
                            ));
                            continue;
                        }
                    }
                    let source = ParamSource::File {
                        path: file.path.clone(),
                        section: section.node_pattern.clone(),
                    };
                    set.set_from(name, value, source)
                        .map_err(|reason| RosArgsError::Param {
                            name: name.clone(),
                            origin: origin.clone(),
                            reason,
                        })?;
                }
            }
        }
        for p in &args.params {
            if let Some(target) = &p.node {
                if target != &node.name {
                    continue;
                }
            }
            if param_spec(&p.name).is_none() {
                if let Some(note) = ignored_standard(&p.name) {
                    notes.push(format!("-p {}: {note}", p.rule));
                    continue;
                }
            }
            set.set_from(&p.name, &p.value, ParamSource::CommandLine)
                .map_err(|reason| RosArgsError::Param {
                    name: p.name.clone(),
                    origin: format!("-p {}", p.rule),
                    reason,
                })?;
        }
        Ok((set, notes))
    }
}

fn ignored_standard(name: &str) -> Option<String> {
    if IGNORED_STANDARD_PARAMS.contains(&name) || name.starts_with("qos_overrides.") {
        Some(format!(
            "the standard parameter '{name}' is not supported by this node and is ignored"
        ))
    } else {
        None
    }
}

fn enum_value<T: serde::de::DeserializeOwned>(set: &ParamSet, name: &str) -> Result<T, String> {
    let v = set.get_str(name)?;
    serde_json::from_value(serde_json::Value::String(v.to_string()))
        .map_err(|e| format!("parameter '{name}': '{v}': {e}"))
}

fn u32_value(set: &ParamSet, name: &str) -> Result<u32, String> {
    let v = set.get_i64(name)?;
    u32::try_from(v).map_err(|_| format!("parameter '{name}': {v} does not fit 0..=4294967295"))
}

/// Copies the engine parameters of `set` into `params` (names as in [`param_table`]). Each
/// value was range-checked when set; the checks across parameters are
/// [`SweepParams::validate`]'s.
pub fn apply_to_sweep(set: &ParamSet, params: &mut SweepParams) -> Result<(), String> {
    let scoring: Scoring = enum_value(set, "scoring")?;
    let pairs: PairSet = enum_value(set, "pairs")?;
    let aggregation: Aggregation = enum_value(set, "aggregation")?;
    let window_mode: WindowMode = enum_value(set, "window_mode")?;
    *params = SweepParams {
        min_depth_m: set.get_f64("min_depth")?,
        max_depth_m: set.get_f64("max_depth")?,
        num_planes: u32_value(set, "num_planes")?,
        scoring,
        pairs,
        best_n: u32_value(set, "best_n")?,
        half_best_n: u32_value(set, "half_best_n")?,
        aggregation,
        window_width: u32_value(set, "window_width")?,
        window_height: u32_value(set, "window_height")?,
        window_mode,
        tau: set.get_f64("tau")? as f32,
        max_cost: set.get_f64("max_cost")? as f32,
        subpixel: set.get_bool("subpixel")?,
        median: set.get_bool("median")?,
        min_visible_cameras: u32_value(set, "min_visible_cameras")?,
        occlusion_tolerance: set.get_f64("occlusion_tolerance")? as f32,
        half_margin: set.get_f64("half_margin")? as f32,
        optimizer: enum_value(set, "optimizer")?,
        sgm_p1: set.get_f64("sgm_p1")? as f32,
        sgm_p2: set.get_f64("sgm_p2")? as f32,
        sgm_paths: u32_value(set, "sgm_paths")?,
        sgm_edge: set.get_f64("sgm_edge")? as f32,
    };
    Ok(())
}

/// The parameter table as a Markdown table (name, type, default, range, description) for the
/// README.
pub fn markdown_table() -> String {
    fn cell(s: &str) -> String {
        s.replace('|', "\\|").replace('\n', " ")
    }
    let mut out = String::from(
        "| Parameter | Type | Default | Range | Description |\n|---|---|---|---|---|\n",
    );
    for p in param_table() {
        let default = if p.required {
            "(required)".to_string()
        } else {
            format!("`{}`", p.default)
        };
        let range = match &p.range {
            // Already escaped.
            ParamRange::OneOf(values) => values
                .iter()
                .map(|v| format!("`{v}`"))
                .collect::<Vec<_>>()
                .join(" \\| "),
            other => cell(&other.describe()),
        };
        let mut description = cell(p.description);
        if p.read_only {
            description.push_str(" *(read-only)*");
        }
        out.push_str(&format!(
            "| `{}` | `{}` | {} | {} | {} |\n",
            p.name,
            p.kind,
            cell(&default),
            range,
            description
        ));
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Names
// ---------------------------------------------------------------------------------------------

fn name_error(name: &str, reason: impl Into<String>) -> RosArgsError {
    RosArgsError::InvalidName {
        name: name.to_string(),
        reason: reason.into(),
    }
}

fn is_name_char(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// A node name: `[A-Za-z_][A-Za-z0-9_]*`.
pub fn validate_node_name(name: &str) -> Result<(), RosArgsError> {
    if name.is_empty() {
        return Err(name_error(name, "a node name must not be empty"));
    }
    if let Some(c) = name.chars().find(|c| !is_name_char(*c)) {
        return Err(name_error(
            name,
            format!("node names may only contain alphanumerics and '_', found '{c}'"),
        ));
    }
    if name.starts_with(|c: char| c.is_ascii_digit()) {
        return Err(name_error(name, "a node name must not start with a digit"));
    }
    if name.len() > MAX_NODE_NAME_LENGTH {
        return Err(name_error(
            name,
            format!("longer than {MAX_NODE_NAME_LENGTH} characters"),
        ));
    }
    Ok(())
}

/// Checks the tokens of a fully qualified name or namespace (starts with `/`).
fn validate_absolute(name: &str, what: &str, allow_root: bool) -> Result<(), RosArgsError> {
    if !name.starts_with('/') {
        return Err(name_error(
            name,
            format!("a {what} must be absolute (start with '/')"),
        ));
    }
    if name == "/" {
        return if allow_root {
            Ok(())
        } else {
            Err(name_error(name, format!("'/' alone is not a {what}")))
        };
    }
    if name.ends_with('/') {
        return Err(name_error(name, format!("a {what} must not end with '/'")));
    }
    if name.len() > MAX_TOPIC_NAME_LENGTH {
        return Err(name_error(
            name,
            format!("longer than {MAX_TOPIC_NAME_LENGTH} characters"),
        ));
    }
    for token in name[1..].split('/') {
        check_token(name, token)?;
    }
    Ok(())
}

fn check_token(name: &str, token: &str) -> Result<(), RosArgsError> {
    if token.is_empty() {
        return Err(name_error(name, "must not contain '//'"));
    }
    if let Some(c) = token.chars().find(|c| !is_name_char(*c)) {
        return Err(name_error(
            name,
            format!("names may only contain alphanumerics, '_' and '/', found '{c}'"),
        ));
    }
    if token.starts_with(|c: char| c.is_ascii_digit()) {
        return Err(name_error(
            name,
            format!("token '{token}' must not start with a digit"),
        ));
    }
    Ok(())
}

/// A node namespace: `/` or an absolute name.
pub fn validate_namespace(namespace: &str) -> Result<(), RosArgsError> {
    validate_absolute(namespace, "namespace", true)
}

/// A topic or service name as written (rcl's `rcl_validate_topic_name`): relative, private
/// (`~`, `~/x`) or absolute; alphanumerics, `_`, `/`, substitutions `{node}`, `{ns}`,
/// `{namespace}`; no `//`, no trailing `/`, no token starting with a digit.
pub fn validate_topic_name(name: &str) -> Result<(), RosArgsError> {
    if name.is_empty() {
        return Err(name_error(name, "a name must not be empty"));
    }
    if name.ends_with('/') {
        return Err(name_error(name, "a name must not end with '/'"));
    }
    let body = if let Some(rest) = name.strip_prefix('~') {
        if !(rest.is_empty() || rest.starts_with('/')) {
            return Err(name_error(name, "'~' must be followed by '/' or nothing"));
        }
        rest.strip_prefix('/').unwrap_or(rest)
    } else {
        name.strip_prefix('/').unwrap_or(name)
    };
    if body.is_empty() {
        return if name == "~" {
            Ok(())
        } else {
            Err(name_error(name, "a name must have at least one token"))
        };
    }
    for token in body.split('/') {
        if token.is_empty() {
            return Err(name_error(name, "must not contain '//'"));
        }
        if token.contains('~') {
            return Err(name_error(name, "'~' is only allowed at the start"));
        }
        // Substitutions are whole tokens or parts of one: check the braces, then the rest.
        let mut plain = String::new();
        let mut rest = token;
        while let Some(open) = rest.find('{') {
            plain.push_str(&rest[..open]);
            let after = &rest[open + 1..];
            let close = after
                .find('}')
                .ok_or_else(|| name_error(name, "unbalanced '{' in a substitution"))?;
            let inner = &after[..close];
            if inner.is_empty() || !inner.chars().all(is_name_char) {
                return Err(name_error(name, format!("bad substitution '{{{inner}}}'")));
            }
            plain.push('x'); // a substitution stands for a valid token part
            rest = &after[close + 1..];
        }
        plain.push_str(rest);
        if plain.contains('}') {
            return Err(name_error(name, "unbalanced '}'"));
        }
        check_token(name, &plain)?;
    }
    Ok(())
}

/// Expands a topic or service name to a fully qualified one (rcl's `rcl_expand_topic_name`):
/// `~` becomes the node's fully qualified name, relative names get the namespace in front,
/// `{node}` and `{ns}`/`{namespace}` are substituted. No remapping.
pub fn expand_name(name: &str, namespace: &str, node_name: &str) -> Result<String, RosArgsError> {
    validate_topic_name(name)?;
    validate_namespace(namespace)?;
    validate_node_name(node_name)?;
    let join = |prefix: &str, rest: &str| {
        if prefix == "/" {
            format!("/{rest}")
        } else {
            format!("{prefix}/{rest}")
        }
    };
    let node_fqn = join(namespace, node_name);
    let mut out = if let Some(rest) = name.strip_prefix('~') {
        let rest = rest.strip_prefix('/').unwrap_or(rest);
        if rest.is_empty() {
            node_fqn
        } else {
            join(&node_fqn, rest)
        }
    } else if name.starts_with('/') {
        name.to_string()
    } else {
        join(namespace, name)
    };
    if out.contains('{') {
        let ns_no_slash = namespace.trim_start_matches('/');
        for (key, value) in [
            ("{node}", node_name),
            ("{ns}", ns_no_slash),
            ("{namespace}", ns_no_slash),
        ] {
            out = out.replace(key, value);
        }
        if let Some(start) = out.find('{') {
            let unknown: String = out[start..].chars().take_while(|c| *c != '}').collect();
            return Err(name_error(
                name,
                format!("unknown substitution '{unknown}}}'"),
            ));
        }
        // `{ns}` in the root namespace leaves an empty token.
        while out.contains("//") {
            out = out.replace("//", "/");
        }
    }
    validate_absolute(&out, "topic name", false).map_err(|e| match e {
        RosArgsError::InvalidName { reason, .. } => name_error(
            name,
            format!("expands to '{out}', which is invalid: {reason}"),
        ),
        other => other,
    })?;
    Ok(out)
}

fn resolve(
    name: &str,
    namespace: &str,
    node_name: &str,
    remaps: &[RemapRule],
    service: bool,
) -> Result<String, RosArgsError> {
    let expanded = expand_name(name, namespace, node_name)?;
    for rule in remaps {
        let applies = match rule.kind {
            RemapKind::Name => true,
            RemapKind::Topic => !service,
            RemapKind::Service => service,
            RemapKind::NodeName | RemapKind::Namespace => false,
        };
        if !applies || rule.node.as_deref().is_some_and(|n| n != node_name) {
            continue;
        }
        if expand_name(&rule.from, namespace, node_name)? == expanded {
            return expand_name(&rule.to, namespace, node_name);
        }
    }
    Ok(expanded)
}

/// Resolves a topic name as rcl does: expand it ([`expand_name`]), then apply the first remap
/// rule whose `from`, expanded the same way, equals it (rules targeted at another node are
/// skipped); the rule's `to` is expanded too. `node_name` and `namespace` are the node's after
/// `__node`/`__ns` ([`RosArgs::node_identity`]).
pub fn resolve_topic(
    name: &str,
    namespace: &str,
    node_name: &str,
    remaps: &[RemapRule],
) -> Result<String, RosArgsError> {
    resolve(name, namespace, node_name, remaps, false)
}

/// [`resolve_topic`] for service names (`rostopic://` rules do not apply, `rosservice://` do).
pub fn resolve_service(
    name: &str,
    namespace: &str,
    node_name: &str,
    remaps: &[RemapRule],
) -> Result<String, RosArgsError> {
    resolve(name, namespace, node_name, remaps, true)
}

/// Does a parameter-file section name (`/ns/node`, `/**`, `/**/node`, `/ns/*`) match a node's
/// fully qualified name? As rclcpp: `*` is one token, `**` any number (also none).
pub fn node_pattern_matches(pattern: &str, fqn: &str) -> bool {
    fn tokens(s: &str) -> Vec<&str> {
        s.split('/').filter(|t| !t.is_empty()).collect()
    }
    fn glob(p: &[&str], n: &[&str]) -> bool {
        match p.split_first() {
            None => n.is_empty(),
            Some((&"**", rest)) => (0..=n.len()).any(|skip| glob(rest, &n[skip..])),
            Some((&tok, rest)) => n
                .split_first()
                .is_some_and(|(first, n_rest)| (tok == "*" || tok == *first) && glob(rest, n_rest)),
        }
    }
    glob(&tokens(pattern), &tokens(fqn))
}

// ---------------------------------------------------------------------------------------------
// The command line
// ---------------------------------------------------------------------------------------------

/// What a remap rule renames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RemapKind {
    /// `__node:=name`.
    NodeName,
    /// `__ns:=/ns`.
    Namespace,
    /// `from:=to`: topics and services.
    Name,
    /// `rostopic://from:=to`.
    Topic,
    /// `rosservice://from:=to`.
    Service,
}

/// One `-r [node:]from:=to` rule.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RemapRule {
    /// Applies only to the node of this name.
    pub node: Option<String>,
    pub kind: RemapKind,
    /// As written (`__node`/`__ns` for those kinds).
    pub from: String,
    pub to: String,
}

impl RemapRule {
    /// Parses `[node:][rostopic://|rosservice://]from:=to`, `[node:]__node:=name`,
    /// `[node:]__ns:=/ns`.
    pub fn parse(rule: &str) -> Result<RemapRule, RosArgsError> {
        let bad = |reason: String| RosArgsError::MalformedRemap {
            rule: rule.to_string(),
            reason,
        };
        let (lhs, to) = rule
            .split_once(":=")
            .ok_or_else(|| bad("expected 'from:=to'".into()))?;
        let (scheme, lhs) = if let Some(rest) = lhs.strip_prefix("rostopic://") {
            (Some(RemapKind::Topic), rest)
        } else if let Some(rest) = lhs.strip_prefix("rosservice://") {
            (Some(RemapKind::Service), rest)
        } else {
            (None, lhs)
        };
        let (node, from) = match lhs.split_once(':') {
            Some((node, from)) if scheme.is_none() => {
                let (scheme2, from) = if let Some(rest) = from.strip_prefix("rostopic://") {
                    (Some(RemapKind::Topic), rest)
                } else if let Some(rest) = from.strip_prefix("rosservice://") {
                    (Some(RemapKind::Service), rest)
                } else {
                    (None, from)
                };
                validate_node_name(node).map_err(|e| bad(e.to_string()))?;
                return finish(rule, Some(node.to_string()), scheme2, from, to);
            }
            Some(_) => {
                return Err(bad(
                    "a node name goes before the rostopic:// or rosservice:// prefix".into(),
                ))
            }
            None => (None, lhs),
        };
        finish(rule, node, scheme, from, to)
    }
}

fn finish(
    rule: &str,
    node: Option<String>,
    scheme: Option<RemapKind>,
    from: &str,
    to: &str,
) -> Result<RemapRule, RosArgsError> {
    let bad = |reason: String| RosArgsError::MalformedRemap {
        rule: rule.to_string(),
        reason,
    };
    if from.is_empty() {
        return Err(bad("the name to remap is empty".into()));
    }
    if to.is_empty() {
        return Err(bad("the replacement is empty".into()));
    }
    let kind = match (from, scheme) {
        ("__node" | "__name", None) => {
            validate_node_name(to).map_err(|e| bad(e.to_string()))?;
            RemapKind::NodeName
        }
        ("__ns", None) => {
            validate_namespace(to).map_err(|e| {
                bad(format!(
                    "the namespace must be fully qualified ('/...'): {e}"
                ))
            })?;
            RemapKind::Namespace
        }
        ("__node" | "__name" | "__ns", Some(_)) => {
            return Err(bad(format!(
                "'{from}' cannot take a rostopic:// or rosservice:// prefix"
            )))
        }
        (_, scheme) => {
            validate_topic_name(from).map_err(|e| bad(e.to_string()))?;
            validate_topic_name(to).map_err(|e| bad(e.to_string()))?;
            scheme.unwrap_or(RemapKind::Name)
        }
    };
    let from = if kind == RemapKind::NodeName {
        "__node"
    } else {
        from
    };
    Ok(RemapRule {
        node,
        kind,
        from: from.to_string(),
        to: to.to_string(),
    })
}

/// One `-p [node:]name:=value`.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamOverride {
    /// Applies only to the node of this name.
    pub node: Option<String>,
    pub name: String,
    pub value: ParamValue,
    /// The rule as written, for messages.
    pub rule: String,
}

impl ParamOverride {
    pub fn parse(rule: &str) -> Result<ParamOverride, RosArgsError> {
        let bad = |reason: String| RosArgsError::MalformedParam {
            rule: rule.to_string(),
            reason,
        };
        let (lhs, value) = rule
            .split_once(":=")
            .ok_or_else(|| bad("expected 'name:=value'".into()))?;
        let (node, name) = match lhs.split_once(':') {
            Some((node, name)) => {
                validate_node_name(node).map_err(|e| bad(e.to_string()))?;
                (Some(node.to_string()), name)
            }
            None => (None, lhs),
        };
        validate_param_name(name).map_err(bad)?;
        let value = ParamValue::parse_yaml(value).map_err(|e| bad(format!("value: {e}")))?;
        Ok(ParamOverride {
            node,
            name: name.to_string(),
            value,
            rule: rule.to_string(),
        })
    }
}

/// A parameter name: tokens of alphanumerics and `_` separated by `.`.
pub fn validate_param_name(name: &str) -> Result<(), String> {
    if name.is_empty() {
        return Err("the parameter name is empty".into());
    }
    for token in name.split('.') {
        if token.is_empty() || !token.chars().all(is_name_char) {
            return Err(format!(
                "parameter name '{name}' must be tokens of alphanumerics and '_' separated by '.'"
            ));
        }
    }
    Ok(())
}

/// One `--log-level [logger:=]level`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogLevel {
    /// None: the default level.
    pub logger: Option<String>,
    /// Lower case: `debug`, `info`, `warn`, `error`, `fatal` or `unset`.
    pub level: String,
}

impl LogLevel {
    pub fn parse(value: &str) -> Result<LogLevel, RosArgsError> {
        let (logger, level) = match value.split_once(":=") {
            Some((logger, level)) => (Some(logger.to_string()), level),
            None => (None, value),
        };
        let level = level.to_ascii_lowercase();
        if !["debug", "info", "warn", "error", "fatal", "unset"].contains(&level.as_str()) {
            return Err(RosArgsError::LogLevel {
                value: value.to_string(),
                reason: "expected debug, info, warn, error, fatal or unset".into(),
            });
        }
        if logger.as_deref() == Some("") {
            return Err(RosArgsError::LogLevel {
                value: value.to_string(),
                reason: "the logger name is empty".into(),
            });
        }
        Ok(LogLevel { logger, level })
    }
}

/// One `ros__parameters` block of a parameter file.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamsSection {
    /// Fully qualified node name or pattern (`/sweepdepth`, `/ns/sweepdepth`, `/**`).
    pub node_pattern: String,
    /// Nested names flattened with `.`, in file order.
    pub params: Vec<(String, ParamValue)>,
}

/// A parsed `--params-file`.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamsFile {
    pub path: PathBuf,
    pub sections: Vec<ParamsSection>,
}

/// Reads and parses a ROS 2 parameter file.
pub fn load_params_file(path: &Path) -> Result<ParamsFile, RosArgsError> {
    let text = std::fs::read_to_string(path).map_err(|source| RosArgsError::ParamsFileRead {
        path: path.to_path_buf(),
        source,
    })?;
    parse_params_yaml(&text, path)
}

/// Parses a ROS 2 parameter file's text:
///
/// ```yaml
/// /**:                       # every node
///   ros__parameters: {use_sim_time: false}
/// sweepdepth:                # the node /sweepdepth (a name without '/' is in the root namespace)
///   ros__parameters:
///     num_planes: 128
///     window: {width: 2}     # nested: window.width
/// /rig/sweepdepth:           # fully qualified
///   ros__parameters: {...}
/// rig:                       # nested namespaces: /rig/sweepdepth
///   sweepdepth:
///     ros__parameters: {...}
/// ```
pub fn parse_params_yaml(text: &str, path: &Path) -> Result<ParamsFile, RosArgsError> {
    let format_error = |message: String| RosArgsError::ParamsFileFormat {
        path: path.to_path_buf(),
        message,
    };
    let doc: serde_yaml_ng::Value =
        serde_yaml_ng::from_str(text).map_err(|e| RosArgsError::ParamsFileYaml {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
    let mut sections = Vec::new();
    match &doc {
        serde_yaml_ng::Value::Null => {}
        serde_yaml_ng::Value::Mapping(map) => {
            collect_sections(map, "", &mut sections).map_err(format_error)?
        }
        _ => {
            return Err(format_error(
                "the top level must be a mapping of node names".into(),
            ))
        }
    }
    Ok(ParamsFile {
        path: path.to_path_buf(),
        sections,
    })
}

fn yaml_key(key: &serde_yaml_ng::Value) -> Result<String, String> {
    match key {
        serde_yaml_ng::Value::String(s) => Ok(s.clone()),
        other => Err(format!("keys must be strings, found {other:?}")),
    }
}

fn collect_sections(
    map: &serde_yaml_ng::Mapping,
    prefix: &str,
    out: &mut Vec<ParamsSection>,
) -> Result<(), String> {
    for (key, value) in map {
        let key = yaml_key(key)?;
        if key == "ros__parameters" {
            if prefix.is_empty() {
                return Err("'ros__parameters' needs a node name above it".into());
            }
            let mut params = Vec::new();
            match value {
                serde_yaml_ng::Value::Mapping(m) => flatten_params(m, "", prefix, &mut params)?,
                serde_yaml_ng::Value::Null => {}
                _ => return Err(format!("'{prefix}': 'ros__parameters' must be a mapping")),
            }
            let node_pattern = if prefix.starts_with('/') {
                prefix.to_string()
            } else {
                format!("/{prefix}")
            };
            out.push(ParamsSection {
                node_pattern,
                params,
            });
            continue;
        }
        let trimmed = key.trim_matches('/');
        if trimmed.is_empty() {
            return Err(format!("empty node name '{key}'"));
        }
        let name = if prefix.is_empty() {
            if key.starts_with('/') {
                format!("/{trimmed}")
            } else {
                trimmed.to_string()
            }
        } else {
            format!("{prefix}/{trimmed}")
        };
        match value {
            serde_yaml_ng::Value::Mapping(m) => collect_sections(m, &name, out)?,
            _ => {
                return Err(format!(
                    "'{name}' must hold 'ros__parameters' (or nested node names)"
                ))
            }
        }
    }
    Ok(())
}

fn flatten_params(
    map: &serde_yaml_ng::Mapping,
    prefix: &str,
    node: &str,
    out: &mut Vec<(String, ParamValue)>,
) -> Result<(), String> {
    for (key, value) in map {
        let key = yaml_key(key)?;
        let name = if prefix.is_empty() {
            key
        } else {
            format!("{prefix}.{key}")
        };
        validate_param_name(&name).map_err(|e| format!("'{node}': {e}"))?;
        match value {
            serde_yaml_ng::Value::Mapping(m) => flatten_params(m, &name, node, out)?,
            other => {
                let value = ParamValue::from_yaml(other)
                    .map_err(|e| format!("'{node}': parameter '{name}': {e}"))?;
                out.push((name, value));
            }
        }
    }
    Ok(())
}

/// The ROS part of a command line, and the rest.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RosArgs {
    /// Arguments outside `--ros-args ... [--]`, in order (for clap).
    pub other: Vec<String>,
    /// `-r` rules in order (the first matching rule wins).
    pub remaps: Vec<RemapRule>,
    /// `-p` rules in order (later ones win; all win over files).
    pub params: Vec<ParamOverride>,
    /// `--params-file`s in order (later ones win).
    pub params_files: Vec<ParamsFile>,
    /// `--log-level`s in order.
    pub log_levels: Vec<LogLevel>,
    /// What was accepted and ignored.
    pub notes: Vec<String>,
}

/// A node's name and namespace after `__node`/`__ns`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeIdentity {
    pub name: String,
    pub namespace: String,
}

impl NodeIdentity {
    /// `/ns/name`.
    pub fn fqn(&self) -> String {
        if self.namespace == "/" {
            format!("/{}", self.name)
        } else {
            format!("{}/{}", self.namespace, self.name)
        }
    }
}

impl RosArgs {
    /// The node's name and namespace: the first `__node` rule for all nodes or for
    /// `default_name`, then the first `__ns` rule for all nodes or for the (new) name.
    pub fn node_identity(
        &self,
        default_name: &str,
        default_namespace: &str,
    ) -> Result<NodeIdentity, RosArgsError> {
        validate_node_name(default_name)?;
        validate_namespace(default_namespace)?;
        let targets = |rule: &RemapRule, name: &str| rule.node.as_deref().is_none_or(|n| n == name);
        let name = self
            .remaps
            .iter()
            .find(|r| r.kind == RemapKind::NodeName && targets(r, default_name))
            .map_or(default_name, |r| r.to.as_str())
            .to_string();
        let namespace = self
            .remaps
            .iter()
            .find(|r| r.kind == RemapKind::Namespace && targets(r, &name))
            .map_or(default_namespace, |r| r.to.as_str())
            .to_string();
        Ok(NodeIdentity { name, namespace })
    }

    /// [`resolve_topic`] with this command line's remaps.
    pub fn resolve_topic(&self, name: &str, node: &NodeIdentity) -> Result<String, RosArgsError> {
        resolve_topic(name, &node.namespace, &node.name, &self.remaps)
    }
}

/// Splits the arguments after the subcommand into ours and the ROS ones, as rcl does:
/// `--ros-args` opens a ROS block, `--` closes it (later `--ros-args` open another); outside
/// the blocks everything (also `--`) goes to `other`. Parameter files are read right away.
pub fn parse_ros_args(args: &[String]) -> Result<RosArgs, RosArgsError> {
    let mut out = RosArgs::default();
    let mut in_ros = false;
    let mut it = args.iter();
    while let Some(arg) = it.next() {
        if !in_ros {
            if arg == "--ros-args" {
                in_ros = true;
            } else {
                out.other.push(arg.clone());
            }
            continue;
        }
        let mut value = |flag: &str| {
            it.next().ok_or_else(|| RosArgsError::MissingValue {
                flag: flag.to_string(),
            })
        };
        match arg.as_str() {
            "--" => in_ros = false,
            "--ros-args" => {}
            "-r" | "--remap" => out.remaps.push(RemapRule::parse(value(arg)?)?),
            "-p" | "--param" => out.params.push(ParamOverride::parse(value(arg)?)?),
            "--params-file" => {
                let path = value(arg)?;
                out.params_files.push(load_params_file(Path::new(path))?);
            }
            "--log-level" => out.log_levels.push(LogLevel::parse(value(arg)?)?),
            "-e" | "--enclave" => {
                let enclave = value(arg)?;
                out.notes.push(format!(
                    "{arg} {enclave}: security enclaves are not supported; ignored"
                ));
            }
            "--log-config-file" | "--log-file-name" => {
                let v = value(arg)?;
                out.notes.push(format!(
                    "{arg} {v}: not supported (logging goes to stderr); ignored"
                ));
            }
            "--enable-rosout-logs"
            | "--disable-rosout-logs"
            | "--enable-stdout-logs"
            | "--disable-stdout-logs"
            | "--enable-external-lib-logs"
            | "--disable-external-lib-logs" => {
                out.notes.push(format!("{arg}: not supported; ignored"));
            }
            _ => return Err(RosArgsError::UnknownRosArg { arg: arg.clone() }),
        }
    }
    Ok(out)
}

/// `ROS_DOMAIN_ID` (pass `std::env::var("ROS_DOMAIN_ID").ok().as_deref()`): unset or empty is
/// 0; otherwise a decimal integer in 0..=232. (ROS 2 recommends 0..=101 and 215..=232 on Linux,
/// where 102..=214 can collide with ephemeral ports.)
pub fn domain_id(env_value: Option<&str>) -> Result<u16, RosArgsError> {
    let Some(raw) = env_value else {
        return Ok(0);
    };
    let trimmed = raw.trim();
    if trimmed.is_empty() {
        return Ok(0);
    }
    let bad = |reason: String| RosArgsError::DomainId {
        value: raw.to_string(),
        reason,
    };
    if !trimmed.chars().all(|c| c.is_ascii_digit()) {
        return Err(bad(format!(
            "expected a decimal integer in 0..={MAX_DOMAIN_ID}"
        )));
    }
    match trimmed.parse::<u32>() {
        Ok(id) if id <= u32::from(MAX_DOMAIN_ID) => Ok(id as u16),
        _ => Err(bad(format!(
            "out of range: ROS 2 domain ids are 0..={MAX_DOMAIN_ID}"
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn strings(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn yaml_values() {
        assert_eq!(
            ParamValue::parse_yaml("true").ok(),
            Some(ParamValue::Bool(true))
        );
        assert_eq!(ParamValue::parse_yaml("3").ok(), Some(ParamValue::Int(3)));
        assert_eq!(
            ParamValue::parse_yaml("2.5").ok(),
            Some(ParamValue::Double(2.5))
        );
        assert_eq!(ParamValue::parse_yaml("'3'").ok(), Some(s("3")));
        assert_eq!(ParamValue::parse_yaml("").ok(), Some(s("")));
        assert_eq!(
            ParamValue::parse_yaml("[1, 2.5]").ok(),
            Some(ParamValue::DoubleArray(vec![1.0, 2.5]))
        );
        assert!(ParamValue::parse_yaml("[1, a]").is_err());
        assert!(ParamValue::parse_yaml("[[1]]").is_err());
        assert!(ParamValue::parse_yaml("a: 1").is_err());
        assert!(ParamValue::parse_yaml("~").is_err());
    }

    #[test]
    fn table_names_are_unique_and_defaults_valid() {
        for (i, p) in param_table().iter().enumerate() {
            assert!(
                param_table()[..i].iter().all(|q| q.name != p.name),
                "{} twice",
                p.name
            );
            assert_eq!(p.kind, p.default.kind(), "{}", p.name);
            if !p.required {
                assert_eq!(validate(p.name, &p.default), Ok(()), "{}", p.name);
            } else {
                assert!(validate(p.name, &p.default).is_err(), "{}", p.name);
            }
        }
    }

    #[test]
    fn coercions() {
        assert_eq!(
            coerce("tau", &ParamValue::Int(50)),
            Ok(ParamValue::Double(50.0))
        );
        assert!(coerce("num_planes", &ParamValue::Double(64.0)).is_err());
        assert_eq!(
            coerce("cameras", &ParamValue::StringArray(strings(&["a", "b"]))),
            Ok(ParamValue::StringArray(strings(&["a", "b"])))
        );
        assert!(coerce("cameras", &ParamValue::StringArray(strings(&["a", "a"]))).is_err());
        assert!(coerce("cameras", &ParamValue::StringArray(strings(&["a", "1b"]))).is_err());
        assert!(coerce("image_topic", &s("/abs")).is_err());
        assert!(coerce("half_margin", &ParamValue::Double(1.0)).is_err());
        assert!(coerce("half_margin", &ParamValue::Double(0.0)).is_ok());
        assert!(coerce("min_depth", &ParamValue::Double(0.0)).is_err());
        assert!(coerce("min_depth", &ParamValue::Double(f64::INFINITY)).is_err());
    }

    #[test]
    fn patterns() {
        assert!(node_pattern_matches("/**", "/sweepdepth"));
        assert!(node_pattern_matches("/**", "/a/b/sweepdepth"));
        assert!(node_pattern_matches("/**/sweepdepth", "/sweepdepth"));
        assert!(node_pattern_matches("/**/sweepdepth", "/a/b/sweepdepth"));
        assert!(node_pattern_matches("/a/*", "/a/sweepdepth"));
        assert!(!node_pattern_matches("/a/*", "/a/b/sweepdepth"));
        assert!(!node_pattern_matches("/sweepdepth", "/a/sweepdepth"));
        assert!(node_pattern_matches("/a/sweepdepth", "/a/sweepdepth"));
    }

    #[test]
    fn name_validation() {
        assert!(validate_topic_name("left/image_raw").is_ok());
        assert!(validate_topic_name("~/x").is_ok());
        assert!(validate_topic_name("~").is_ok());
        assert!(validate_topic_name("/{node}/x").is_ok());
        assert!(validate_topic_name("a//b").is_err());
        assert!(validate_topic_name("a/").is_err());
        assert!(validate_topic_name("1a").is_err());
        assert!(validate_topic_name("a/2b").is_err());
        assert!(validate_topic_name("a~").is_err());
        assert!(validate_topic_name("~x").is_err());
        assert!(validate_topic_name("a-b").is_err());
        assert!(validate_topic_name("{x").is_err());
        assert!(validate_namespace("/").is_ok());
        assert!(validate_namespace("ns").is_err());
        assert!(validate_node_name("a/b").is_err());
    }

    #[test]
    fn substitutions() {
        assert_eq!(
            expand_name("{node}/x", "/ns", "n").ok().as_deref(),
            Some("/ns/n/x")
        );
        assert_eq!(expand_name("/{ns}/x", "/", "n").ok().as_deref(), Some("/x"));
        assert!(expand_name("{what}/x", "/ns", "n").is_err());
    }

    #[test]
    fn domain_ids() {
        assert_eq!(domain_id(Some("232")).ok(), Some(232));
        assert!(domain_id(Some("233")).is_err());
    }
}
