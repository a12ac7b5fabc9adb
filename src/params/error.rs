//! Why a parameter value, or a set of them, is refused.

use crate::ros::param_value::ParamKind;

/// Why a parameter value or a combination of values is refused. The messages are what the
/// node logs and what a parameter service answers.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParamError {
    #[error("unknown parameter '{0}'")]
    Unknown(String),
    #[error("wrong type: expected {expected}, got {got} {value}")]
    WrongType {
        expected: ParamKind,
        got: ParamKind,
        /// The value as written.
        value: String,
    },
    #[error("must be finite, got {0}")]
    NotFinite(f64),
    #[error("out of range: must be in {min}..={max}, got {got}")]
    IntOutOfRange { min: i64, max: i64, got: i64 },
    #[error("out of range: {} {range}, got {got:?}", if range.starts_with(['[', '(']) { "must be in" } else { "must be" })]
    DoubleOutOfRange {
        /// The range as the docs write it ([`super::ParamRange::describe`]).
        range: String,
        got: f64,
    },
    #[error("'{value}' is not one of the allowed values: {}", allowed.join(", "))]
    NotOneOf { value: String, allowed: Vec<String> },
    #[error("invalid ROS name '{name}': {reason}")]
    InvalidName { name: String, reason: String },
    #[error("'{0}' is not WxH, e.g. 2x2")]
    NotASize(String),
    #[error("'{0}' must be a relative name")]
    NotRelative(String),
    #[error("needs at least {min_len} entries, got {got}")]
    TooFewEntries { min_len: usize, got: usize },
    #[error("'{0}' appears more than once")]
    Repeated(String),
    /// A declaration whose range does not fit its type (a bug in the table; a test checks
    /// every declaration).
    #[error("internal: range {range} does not apply to a {kind}")]
    RangeMismatch { range: String, kind: ParamKind },
    /// A typed read of a parameter of another type.
    #[error("parameter '{name}' is a {kind}")]
    NotA { name: String, kind: ParamKind },
    #[error("parameter '{name}': {value} does not fit 0..=4294967295")]
    NotU32 { name: String, value: i64 },
    #[error("parameter '{name}': '{value}' is not one of its values")]
    NotAVariant { name: String, value: String },
    /// A value of a parameter that came from a parameter file or `-p`.
    #[error("parameter '{name}' (from {origin}): {source}")]
    From {
        name: String,
        origin: String,
        source: Box<ParamError>,
    },
    #[error("parameter '{name}': {source}")]
    Named {
        name: String,
        source: Box<ParamError>,
    },
    #[error("parameter '{name}' (required): {source}")]
    Required {
        name: String,
        source: Box<ParamError>,
    },
    #[error("reference_camera '{reference}' is not one of cameras [{}]", cameras.join(", "))]
    UnknownReference {
        reference: String,
        cameras: Vec<String>,
    },
    #[error("virtual_reference needs pairs = all (a virtual camera has no image to pair with), but pairs was set to 'reference'")]
    VirtualNeedsAllPairs,
    #[error("parameter 'virtual_pose' needs 7 values [x, y, z, qx, qy, qz, qw], got {0}")]
    PoseLength(usize),
    #[error("parameter 'virtual_pose' has a NaN or infinite value")]
    PoseNotFinite,
    #[error("parameter 'virtual_pose': [qx, qy, qz, qw]: {0}")]
    PoseNotUnit(crate::geometry::pose::QuaternionError),
    #[error("parameter '{0}' is read-only (it is fixed once the node runs)")]
    ReadOnly(String),
    #[error("min_depth ({min}) must be smaller than max_depth ({max})")]
    DepthOrder { min: f64, max: f64 },
    #[error("best_n ({best_n}) is larger than the {pairs} camera pairs of this rig ({cameras} cameras, {pair_set} pairs)")]
    BestNAbovePairs {
        best_n: u32,
        pairs: usize,
        cameras: usize,
        /// `reference` or `all`.
        pair_set: &'static str,
    },
    #[error("min_visible_cameras ({min_visible}) is larger than the {cameras} cameras of this rig (every pixel would be invalid)")]
    MinVisibleAboveCameras { min_visible: u32, cameras: usize },
    /// The engine's own check of the parameters against the rig's shape
    /// ([`crate::sweep::SweepParams::validate`]), with what it said.
    #[error("{context}{message}")]
    Engine {
        /// What the check was about (`virtual_reference: `, or empty).
        context: &'static str,
        message: String,
    },
    /// A change refused because of the rig; the old values stay in force.
    #[error("{0}; the current values stay")]
    KeepCurrent(Box<ParamError>),
}

impl ParamError {
    /// This error about parameter `name`.
    pub fn named(self, name: &str) -> Self {
        ParamError::Named {
            name: name.to_string(),
            source: Box::new(self),
        }
    }
}
