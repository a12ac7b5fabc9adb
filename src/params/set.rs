//! The current value of every parameter ([`ParamSet`]), where it came from, how a command
//! line's parameter files and `-p` rules set it for one node, and how the engine's values go
//! into [`SweepParams`] ([`apply_to_sweep`]).

use std::path::PathBuf;

use super::engine::engine_params;
use super::spec::ParamSpec;
use super::table::{coerce, param_index, param_spec, param_table};
use super::ParamError;
use crate::ros::args::{node_pattern_matches, NodeIdentity, ParamArg, RosArgs};
use crate::ros::param_value::ParamValue;
use crate::sweep::SweepParams;

/// Parameters every rclcpp node has, or that tools set for all nodes: accepted from parameter
/// files and ignored with a note.
const IGNORED_STANDARD_PARAMS: &[&str] = &["start_type_description_service"];

/// rcl's `use_sim_time`: the node's time from `/clock` (kept beside the table: every rcl node
/// has it, and the `bag` command has no clock).
pub const USE_SIM_TIME: &str = "use_sim_time";

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
/// (Its node parameters as typed values, and the node's checks across them: `values.rs`.)
#[derive(Debug, Clone, PartialEq)]
pub struct ParamSet {
    values: Vec<ParamValue>,
    sources: Vec<ParamSource>,
    use_sim_time: bool,
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
            use_sim_time: false,
        }
    }

    /// [`USE_SIM_TIME`] as the command line and parameter files set it (default false).
    pub fn use_sim_time(&self) -> bool {
        self.use_sim_time
    }

    pub fn get(&self, name: &str) -> Option<&ParamValue> {
        param_index(name).and_then(|i| self.values.get(i))
    }

    pub fn source(&self, name: &str) -> Option<&ParamSource> {
        param_index(name).and_then(|i| self.sources.get(i))
    }

    /// Validates and sets one value (see [`coerce`]).
    pub fn set(&mut self, name: &str, value: &ParamValue) -> Result<(), ParamError> {
        self.set_from(name, value, ParamSource::Set)
    }

    fn set_from(
        &mut self,
        name: &str,
        value: &ParamValue,
        source: ParamSource,
    ) -> Result<(), ParamError> {
        let value = coerce(name, value)?;
        let i = param_index(name).ok_or_else(|| ParamError::Unknown(name.to_string()))?;
        self.values[i] = value;
        self.sources[i] = source;
        Ok(())
    }

    /// `(spec, value)` for every parameter, in table order.
    pub fn iter(&self) -> impl Iterator<Item = (&'static ParamSpec, &ParamValue)> {
        param_table().iter().zip(self.values.iter())
    }

    fn typed<'a, T>(
        &'a self,
        name: &str,
        f: impl Fn(&'a ParamValue) -> Option<T>,
    ) -> Result<T, ParamError> {
        let v = self
            .get(name)
            .ok_or_else(|| ParamError::Unknown(name.to_string()))?;
        f(v).ok_or_else(|| ParamError::NotA {
            name: name.to_string(),
            kind: v.kind(),
        })
    }

    pub fn get_bool(&self, name: &str) -> Result<bool, ParamError> {
        self.typed(name, ParamValue::as_bool)
    }
    pub fn get_i64(&self, name: &str) -> Result<i64, ParamError> {
        self.typed(name, ParamValue::as_i64)
    }
    pub fn get_f64(&self, name: &str) -> Result<f64, ParamError> {
        self.typed(name, ParamValue::as_f64)
    }
    pub fn get_str(&self, name: &str) -> Result<&str, ParamError> {
        self.typed(name, ParamValue::as_str)
    }
    pub fn get_string_array(&self, name: &str) -> Result<&[String], ParamError> {
        self.typed(name, ParamValue::as_string_array)
    }
    pub fn get_f64_array(&self, name: &str) -> Result<&[f64], ParamError> {
        self.typed(name, ParamValue::as_f64_array)
    }

    /// The node's parameters from the command line, merged as rcl merges them: every
    /// `--params-file` section and every `-p` (under `/**`; a node-targeted one under its node)
    /// go, in command-line order, into one table of node entries kept in the order each entry
    /// first appeared, a later value for the same entry and name replacing the earlier one in
    /// place; then the entries that match the node apply their values, entry by entry in that
    /// order, over the defaults. (So `/**` then `/node` in one file gives the node's value, and
    /// a `-p`, which lives under `/**`, loses to a file's section for the node, as in rcl.)
    /// Returns the notes on what was ignored.
    ///
    /// Unknown parameters are errors in sections for this node and in `-p`; in wildcard
    /// sections (shared with other nodes) they are ignored with a note. Values of known
    /// parameters are always checked.
    pub fn from_ros_args(
        args: &RosArgs,
        node: &NodeIdentity,
    ) -> Result<(ParamSet, Vec<String>), ParamError> {
        let fqn = node.fqn();
        let order: Vec<ParamArg> = if args.param_order.is_empty() {
            (0..args.params_files.len())
                .map(ParamArg::File)
                .chain((0..args.params.len()).map(ParamArg::Param))
                .collect()
        } else {
            args.param_order.clone()
        };
        let mut entries: Vec<Entry> = Vec::new();
        let mut add = |target: Target, item: Item| {
            let at = match entries.iter().position(|e| e.target == target) {
                Some(at) => at,
                None => {
                    entries.push(Entry {
                        target,
                        items: Vec::new(),
                    });
                    entries.len() - 1
                }
            };
            let items = &mut entries[at].items;
            match items.iter_mut().find(|i| i.name == item.name) {
                Some(old) => *old = item,
                None => items.push(item),
            }
        };
        for arg in order {
            match arg {
                ParamArg::File(i) => {
                    let Some(file) = args.params_files.get(i) else {
                        continue;
                    };
                    for section in &file.sections {
                        let origin = format!(
                            "params file '{}', section '{}'",
                            file.path.display(),
                            section.node_pattern
                        );
                        for (name, value) in &section.params {
                            add(
                                Target::pattern(&section.node_pattern),
                                Item {
                                    name: name.clone(),
                                    value: value.clone(),
                                    source: ParamSource::File {
                                        path: file.path.clone(),
                                        section: section.node_pattern.clone(),
                                    },
                                    origin: origin.clone(),
                                    wildcard: section.node_pattern.contains('*'),
                                },
                            );
                        }
                    }
                }
                ParamArg::Param(i) => {
                    let Some(p) = args.params.get(i) else {
                        continue;
                    };
                    let target = match &p.node {
                        Some(name) => Target::NodeName(name.clone()),
                        None => Target::Pattern("/**".into()),
                    };
                    add(
                        target,
                        Item {
                            name: p.name.clone(),
                            value: p.value.clone(),
                            source: ParamSource::CommandLine,
                            origin: format!("-p {}", p.rule),
                            wildcard: false,
                        },
                    );
                }
            }
        }
        let mut set = ParamSet::defaults();
        let mut notes = Vec::new();
        for entry in &entries {
            let applies = match &entry.target {
                Target::Pattern(pattern) => node_pattern_matches(pattern, &fqn),
                Target::NodeName(name) => name == &node.name,
            };
            if !applies {
                continue;
            }
            for item in &entry.items {
                if item.name == USE_SIM_TIME {
                    set.use_sim_time = match item.value {
                        ParamValue::Bool(on) => on,
                        ref other => {
                            return Err(ParamError::From {
                                name: item.name.clone(),
                                origin: item.origin.clone(),
                                source: Box::new(ParamError::WrongType {
                                    expected: crate::ros::param_value::ParamKind::Bool,
                                    got: other.kind(),
                                    value: other.to_string(),
                                }),
                            })
                        }
                    };
                    continue;
                }
                if param_spec(&item.name).is_none() {
                    if let Some(note) = ignored_standard(&item.name) {
                        notes.push(format!("{}: {note}", item.origin));
                        continue;
                    }
                    if item.wildcard {
                        notes.push(format!(
                            "{}: ignoring parameter '{}', which {fqn} does not have",
                            item.origin, item.name
                        ));
                        continue;
                    }
                }
                set.set_from(&item.name, &item.value, item.source.clone())
                    .map_err(|e| ParamError::From {
                        name: item.name.clone(),
                        origin: item.origin.clone(),
                        source: Box::new(e),
                    })?;
            }
        }
        Ok((set, notes))
    }
}

/// Why a required parameter may have come out empty: no parameter file, or parameter files
/// none of whose sections is for this node (`fqn`), with their sections, as a sentence to add
/// to the error; `None` where some section applies. `example` is the `-p` that would set it
/// (`cameras:=[cam0, cam1, ...]`).
pub fn unmatched_params_hint(ros: &RosArgs, fqn: &str, example: &str) -> Option<String> {
    if ros.params_files.is_empty() {
        return Some(format!(
            "no parameter file given: pass --params-file FILE (examples in launch_configs/) or \
             -p {example}"
        ));
    }
    let applies = ros.params_files.iter().any(|file| {
        file.sections
            .iter()
            .any(|section| node_pattern_matches(&section.node_pattern, fqn))
    });
    if applies {
        return None;
    }
    let sections: Vec<String> = ros
        .params_files
        .iter()
        .flat_map(|file| {
            file.sections
                .iter()
                .map(move |s| format!("'{}' in {}", s.node_pattern, file.path.display()))
        })
        .collect();
    Some(format!(
        "no section of the parameter file is for this node ({fqn}): it has {}; set the node's \
         namespace and name to match (`-r __ns:=/ns`, `-r __node:=name`) or name a section \
         {fqn} or /**",
        if sections.is_empty() {
            "none".to_string()
        } else {
            sections.join(", ")
        }
    ))
}

/// Which nodes an entry of rcl's merged parameter table is for.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Target {
    /// A parameter file's node pattern (`/**`, `/ns/name`, wildcards); `-p` uses `/**`.
    Pattern(String),
    /// A node-targeted `-p name:param:=value`.
    NodeName(String),
}

impl Target {
    /// rcl's YAML parser keys a section `name` as `/name`.
    fn pattern(pattern: &str) -> Self {
        if pattern.starts_with('/') {
            Target::Pattern(pattern.to_string())
        } else {
            Target::Pattern(format!("/{pattern}"))
        }
    }
}

/// One value of an entry, with where it came from.
struct Item {
    name: String,
    value: ParamValue,
    source: ParamSource,
    origin: String,
    wildcard: bool,
}

struct Entry {
    target: Target,
    items: Vec<Item>,
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

/// Copies the engine parameters of `set` into `params`. Each value was range-checked when
/// set; the checks across parameters are [`SweepParams::validate`]'s.
pub fn apply_to_sweep(set: &ParamSet, params: &mut SweepParams) -> Result<(), ParamError> {
    for p in engine_params() {
        let value = set
            .get(p.spec.name)
            .ok_or_else(|| ParamError::Unknown(p.spec.name.to_string()))?;
        (p.set)(params, value)?;
    }
    Ok(())
}
