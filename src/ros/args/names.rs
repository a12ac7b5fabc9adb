//! ROS 2 names as rcl handles them: validation of node names, namespaces and topic names,
//! expansion (`~`, relative names, `{node}`/`{ns}` substitutions), remapping, and the node
//! patterns of parameter-file sections.

use super::remap::{RemapKind, RemapRule};
use super::RosArgsError;

/// Longest fully qualified topic name rmw accepts (`RMW_TOPIC_MAX_NAME_LENGTH`).
const MAX_TOPIC_NAME_LENGTH: usize = 247;
/// Longest node name rmw accepts (`RMW_NODE_NAME_MAX_NAME_LENGTH`).
const MAX_NODE_NAME_LENGTH: usize = 255;

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
/// `__node`/`__ns` ([`super::RosArgs::node_identity`]).
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

/// Why a parameter name is malformed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ParamNameError {
    #[error("the parameter name is empty")]
    Empty,
    #[error("parameter name '{0}' must be tokens of alphanumerics and '_' separated by '.'")]
    BadToken(String),
}

/// A parameter name: tokens of alphanumerics and `_` separated by `.`.
pub fn validate_param_name(name: &str) -> Result<(), ParamNameError> {
    if name.is_empty() {
        return Err(ParamNameError::Empty);
    }
    for token in name.split('.') {
        if token.is_empty() || !token.chars().all(is_name_char) {
            return Err(ParamNameError::BadToken(name.to_string()));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
