//! The types of a remap rule (`-r [node:]from:=to`), apart from `parse.rs` (which reads them,
//! [`RemapRule::parse`]) and `names.rs` (which applies them), so that neither imports the other
//! for them.

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
