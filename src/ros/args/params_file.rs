//! ROS 2 parameter files (`--params-file`): node sections (fully qualified, nested
//! namespaces, `/**` wildcards) with their `ros__parameters`, nested names flattened with `.`.

use std::path::{Path, PathBuf};

use super::names::{validate_param_name, ParamNameError};
use super::RosArgsError;
use crate::ros::param_value::{ParamValue, ValueError};

/// What is wrong in the structure of a parameter file.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ParamsFileError {
    #[error("the top level must be a mapping of node names")]
    TopLevel,
    #[error("keys must be strings, found {0}")]
    KeyNotString(String),
    #[error("'ros__parameters' needs a node name above it")]
    ParametersWithoutNode,
    #[error("'{0}': 'ros__parameters' must be a mapping")]
    ParametersNotMapping(String),
    #[error("empty node name '{0}'")]
    EmptyNodeName(String),
    #[error("'{0}' must hold 'ros__parameters' (or nested node names)")]
    NodeWithoutParameters(String),
    #[error("'{node}': {source}")]
    ParamName {
        node: String,
        source: ParamNameError,
    },
    #[error("'{node}': parameter '{name}': {source}")]
    Value {
        node: String,
        name: String,
        source: ValueError,
    },
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
    let format_error = |source: ParamsFileError| RosArgsError::ParamsFileFormat {
        path: path.to_path_buf(),
        source,
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
        _ => return Err(format_error(ParamsFileError::TopLevel)),
    }
    Ok(ParamsFile {
        path: path.to_path_buf(),
        sections,
    })
}

fn yaml_key(key: &serde_yaml_ng::Value) -> Result<String, ParamsFileError> {
    match key {
        serde_yaml_ng::Value::String(s) => Ok(s.clone()),
        other => Err(ParamsFileError::KeyNotString(format!("{other:?}"))),
    }
}

fn collect_sections(
    map: &serde_yaml_ng::Mapping,
    prefix: &str,
    out: &mut Vec<ParamsSection>,
) -> Result<(), ParamsFileError> {
    for (key, value) in map {
        let key = yaml_key(key)?;
        if key == "ros__parameters" {
            if prefix.is_empty() {
                return Err(ParamsFileError::ParametersWithoutNode);
            }
            let mut params = Vec::new();
            match value {
                serde_yaml_ng::Value::Mapping(m) => flatten_params(m, "", prefix, &mut params)?,
                serde_yaml_ng::Value::Null => {}
                _ => return Err(ParamsFileError::ParametersNotMapping(prefix.to_string())),
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
            return Err(ParamsFileError::EmptyNodeName(key));
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
            _ => return Err(ParamsFileError::NodeWithoutParameters(name)),
        }
    }
    Ok(())
}

fn flatten_params(
    map: &serde_yaml_ng::Mapping,
    prefix: &str,
    node: &str,
    out: &mut Vec<(String, ParamValue)>,
) -> Result<(), ParamsFileError> {
    for (key, value) in map {
        let key = yaml_key(key)?;
        let name = if prefix.is_empty() {
            key
        } else {
            format!("{prefix}.{key}")
        };
        validate_param_name(&name).map_err(|source| ParamsFileError::ParamName {
            node: node.to_string(),
            source,
        })?;
        match value {
            serde_yaml_ng::Value::Mapping(m) => flatten_params(m, &name, node, out)?,
            other => {
                let value =
                    ParamValue::from_yaml(other).map_err(|source| ParamsFileError::Value {
                        node: node.to_string(),
                        name: name.clone(),
                        source,
                    })?;
                out.push((name, value));
            }
        }
    }
    Ok(())
}
