//! The `--ros-args` block of a command line, split and parsed as rcl does: remaps (`-r`),
//! parameters (`-p`), parameter files (`--params-file`, read right away), log levels; the
//! security and logging switches are accepted and ignored with a note.

use std::path::Path;

use super::names::{
    resolve_topic, validate_namespace, validate_node_name, validate_param_name, validate_topic_name,
};
use super::params_file::{load_params_file, ParamsFile};
use super::RosArgsError;
use crate::ros::param_value::ParamValue;

pub use super::remap::{RemapKind, RemapRule};

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
        validate_param_name(name).map_err(|e| bad(e.to_string()))?;
        let value = ParamValue::parse_yaml(value).map_err(|e| bad(format!("value: {e}")))?;
        Ok(ParamOverride {
            node,
            name: name.to_string(),
            value,
            rule: rule.to_string(),
        })
    }
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

/// The ROS part of a command line, and the rest.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RosArgs {
    /// Arguments outside `--ros-args ... [--]`, in order (for clap).
    pub other: Vec<String>,
    /// `-r` rules in order (the first matching rule wins).
    pub remaps: Vec<RemapRule>,
    /// `-p` rules in order (merged with the files as rcl does: `ParamSet::from_ros_args`).
    pub params: Vec<ParamOverride>,
    /// `--params-file`s in order.
    pub params_files: Vec<ParamsFile>,
    /// `--log-level`s in order.
    pub log_levels: Vec<LogLevel>,
    /// The `--params-file`s and `-p`s in command-line order (rcl merges them in that order:
    /// [`crate::params::ParamSet::from_ros_args`]).
    pub param_order: Vec<ParamArg>,
    /// What was accepted and ignored.
    pub notes: Vec<String>,
}

/// One parameter source on the command line: `--params-file` number i or `-p` number i.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParamArg {
    File(usize),
    Param(usize),
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

    /// The effective level of `logger` (dotted, as rcl names a node's logger: `ns.name`) as
    /// rcutils has it: the last `--log-level` for the logger or its nearest ancestor, else the
    /// last one without a logger, else `info`.
    pub fn log_level(&self, logger: &str) -> &str {
        let mut name = logger;
        loop {
            if let Some(rule) = self
                .log_levels
                .iter()
                .rev()
                .find(|l| l.logger.as_deref() == Some(name) && l.level != "unset")
            {
                return &rule.level;
            }
            match name.rsplit_once('.') {
                Some((parent, _)) => name = parent,
                None => break,
            }
        }
        self.log_levels
            .iter()
            .rev()
            .find(|l| l.logger.is_none() && l.level != "unset")
            .map_or("info", |l| l.level.as_str())
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
            "-p" | "--param" => {
                out.params.push(ParamOverride::parse(value(arg)?)?);
                out.param_order.push(ParamArg::Param(out.params.len() - 1));
            }
            "--params-file" => {
                let path = value(arg)?;
                out.params_files.push(load_params_file(Path::new(path))?);
                out.param_order
                    .push(ParamArg::File(out.params_files.len() - 1));
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
