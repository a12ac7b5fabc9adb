//! The one table of parameters: the engine's (`engine.rs`) then the node's (`node.rs`), each
//! a [`ParamSpec`] (`spec.rs`), and the lookups and checks by name over it. Kept apart from
//! `spec.rs` so that the tables import the spec type and this file imports the tables, with no
//! circle between them.

use std::sync::LazyLock;

use super::spec::ParamSpec;
use super::ParamError;
use crate::ros::param_value::ParamValue;

static PARAM_TABLE: LazyLock<Vec<ParamSpec>> = LazyLock::new(|| {
    super::engine::engine_params()
        .iter()
        .map(|p| p.spec.clone())
        .chain(super::node::node_params())
        .collect()
});

/// Every parameter of the node, engine parameters first.
pub fn param_table() -> &'static [ParamSpec] {
    &PARAM_TABLE
}

/// The table entry of `name`.
pub fn param_spec(name: &str) -> Option<&'static ParamSpec> {
    param_table().iter().find(|p| p.name == name)
}

/// The position of `name` in [`param_table`].
pub(crate) fn param_index(name: &str) -> Option<usize> {
    param_table().iter().position(|p| p.name == name)
}

/// Checks `value` for parameter `name`: known name, type, range or allowed values.
pub fn validate(name: &str, value: &ParamValue) -> Result<(), ParamError> {
    coerce(name, value).map(|_| ())
}

/// [`validate`], returning the value as stored ([`ParamSpec::coerce`]).
pub fn coerce(name: &str, value: &ParamValue) -> Result<ParamValue, ParamError> {
    param_spec(name)
        .ok_or_else(|| ParamError::Unknown(name.to_string()))?
        .coerce(value)
}
