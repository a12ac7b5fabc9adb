//! The ROS command line as rcl/rclcpp handle it: `ros2-client` parses none, so this module does
//! what rcl does for a C++ node.
//!
//! * [`parse`]: [`parse_ros_args`] splits the arguments after the subcommand into ours
//!   (`other`, for clap) and the ones inside `--ros-args ... [--]`: remaps (`-r`), parameters
//!   (`-p`), parameter files (`--params-file`, read and parsed right away like rcl does), log
//!   levels; `-e`/`--enclave` and the logging switches are accepted and ignored with a note.
//! * [`names`]: [`RosArgs::node_identity`] applies `__node`/`__ns`; [`resolve_topic`] and
//!   [`resolve_service`] expand relative (`left/image_raw`), private (`~/x`) and absolute names
//!   and apply the remap rules on the fully qualified names.
//! * [`params_file`]: the YAML of `--params-file` (sections per node, `/**` wildcards).
//! * [`remap`]: the types of a remap rule, read by `parse` and applied by `names`.
//! * [`domain_id`] checks `ROS_DOMAIN_ID`.
//!
//! The node's parameters themselves (the table, values, checks) are [`crate::params`]'s.
//!
//! Deliberate differences from rclcpp: a `double` parameter also takes an integer (`-p tau:=100`)
//! and a `double[]` an integer sequence, where rclcpp reports a type error. Parameter files and
//! `-p` merge as in rcl: in command-line order into one table of node entries (a `-p` is an
//! entry for `/**`), applied entry by entry in the order each first appeared, so a file's
//! section for the node wins over a `-p`, even a later one (`docs/node.md`; checked against rcl
//! by `tests/node/ros_args_rcl.rs`).

pub mod names;
pub mod params_file;
pub mod parse;
pub mod remap;

use std::path::PathBuf;

pub use names::{
    expand_name, node_pattern_matches, resolve_service, resolve_topic, validate_namespace,
    validate_node_name, validate_param_name, validate_topic_name, ParamNameError,
};
pub use params_file::{
    load_params_file, parse_params_yaml, ParamsFile, ParamsFileError, ParamsSection,
};
pub use parse::{
    parse_ros_args, LogLevel, NodeIdentity, ParamArg, ParamOverride, RemapKind, RemapRule, RosArgs,
};

/// The node's default name (before `__node` remaps).
pub const DEFAULT_NODE_NAME: &str = "sweepdepth";

/// Highest `ROS_DOMAIN_ID` accepted (the DDS port formula runs out above it).
pub const MAX_DOMAIN_ID: u16 = 232;

/// Errors from the ROS command line, names and parameter files.
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
    #[error("params file '{}': {source}", path.display())]
    ParamsFileFormat {
        path: PathBuf,
        source: ParamsFileError,
    },
    #[error("invalid ROS_DOMAIN_ID '{value}': {reason}")]
    DomainId { value: String, reason: String },
}

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

/// The level a node's `--ros-args --log-level` gives its own logger (rcl's rules: the node's
/// dotted logger name, `ns.name`, or an ancestor, else the level without a logger), for the
/// `node` and `fuse` commands' arguments; `None` where none is given or they do not parse (the
/// command then reports them).
pub fn node_log_level(args: &[String], default_node_name: &str) -> Option<String> {
    let ros = parse_ros_args(args).ok()?;
    if ros.log_levels.is_empty() {
        return None;
    }
    let identity = ros.node_identity(default_node_name, "/").ok()?;
    let logger = identity.fqn().trim_start_matches('/').replace('/', ".");
    Some(ros.log_level(&logger).to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn domain_ids() {
        assert_eq!(domain_id(Some("232")).ok(), Some(232));
        assert!(domain_id(Some("233")).is_err());
    }

    /// `--log-level` as rcl reads it: the node's own logger (`ns.name`) or an ancestor first,
    /// then the level without a logger.
    #[test]
    fn a_nodes_own_log_level() {
        let args = |a: &[&str]| a.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        let level = |a: &[&str]| super::node_log_level(&args(a), "sweepdepth");
        assert_eq!(level(&["--ros-args", "-p", "cameras:=[a, b]"]), None);
        assert_eq!(
            level(&["--ros-args", "--log-level", "warn"]).as_deref(),
            Some("warn")
        );
        assert_eq!(
            level(&[
                "--ros-args",
                "-r",
                "__ns:=/rig",
                "--log-level",
                "warn",
                "--log-level",
                "rig.sweepdepth:=error"
            ])
            .as_deref(),
            Some("error")
        );
        // Another node's logger: the level without one (here none: rcutils' info).
        assert_eq!(
            level(&["--ros-args", "--log-level", "other:=debug"]).as_deref(),
            Some("info")
        );
    }
}
