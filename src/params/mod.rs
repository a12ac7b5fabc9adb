//! The node's parameters and the engine options, each declared once.
//!
//! * [`engine`]: the engine parameters (one line each: the [`crate::sweep::SweepParams`]
//!   field, node name, type, default, command-line option, range, description). The engine's
//!   defaults, the engine part of the node's table, the CLI engine options and their range
//!   checks are all made from it.
//! * [`node`]: the node's own parameters (cameras, topics, synchronisation, QoS, rig file,
//!   virtual reference), read-only once the node runs.
//! * [`spec`]: what a parameter is ([`ParamSpec`], [`ParamRange`]) and the checks of one value.
//! * [`table`]: the one table of all of them ([`param_table`]: the engine's, then the node's)
//!   and the lookups and checks by name.
//! * [`set`]: the current values ([`ParamSet`]), how a command line's parameter files and
//!   `-p` rules set them, and their copy into the engine's parameters ([`apply_to_sweep`]).
//! * [`values`]: the node's own parameters as typed values ([`NodeValues`]), read from a
//!   [`ParamSet`] once, and the node's checks across them.
//! * [`checks`]: the checks across parameters (depth range, best n of m, the rig's shape).
//! * [`cli`]: [`EngineOptions`], the engine options of `demo`, `eval`, `bench`.
//! * [`docs`]: the parameter table of docs/node.md.
//!
//! No DDS: the node serves these over its parameter services (`crate::node::params`).

pub mod checks;
pub mod cli;
pub mod docs;
pub mod engine;
mod error;
pub mod node;
pub mod set;
pub mod spec;
pub mod table;
pub mod values;

pub use crate::ros::param_value::{ParamKind, ParamValue};
pub use cli::EngineOptions;
pub use docs::markdown_table;
pub use engine::{engine_param, engine_params, EngineParam, Flag};
pub use error::ParamError;
pub use set::{apply_to_sweep, ParamSet, ParamSource};
pub use spec::{ParamRange, ParamSpec};
pub use table::{coerce, param_spec, param_table, validate};
pub use values::NodeValues;
