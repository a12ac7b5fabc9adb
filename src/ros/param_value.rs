//! ROS 2 parameter values: the types (`bool`, `integer`, `double`, `string` and their arrays),
//! parsed from YAML as rcl does (`-p name:=VALUE`, parameter files) and written YAML-like.

use std::fmt;

/// Why a YAML text or value is not a parameter value.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ValueError {
    #[error("not a YAML value: {0}")]
    NotYaml(String),
    #[error("has no value (null)")]
    Null,
    #[error("a mapping is not a parameter value")]
    Mapping,
    #[error("nested sequences and mappings are not parameter values")]
    Nested,
    #[error("integer {0} does not fit a 64-bit signed integer")]
    IntegerTooLarge(String),
    #[error("unsupported number {0}")]
    UnsupportedNumber(String),
    #[error("sequence elements must all have the same type")]
    MixedSequence,
}

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

    pub fn is_array(self) -> bool {
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

    pub fn is_empty_array(&self) -> bool {
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
    pub fn parse_yaml(text: &str) -> Result<ParamValue, ValueError> {
        if text.trim().is_empty() {
            return Ok(ParamValue::String(String::new()));
        }
        let value: serde_yaml_ng::Value =
            serde_yaml_ng::from_str(text).map_err(|e| ValueError::NotYaml(e.to_string()))?;
        ParamValue::from_yaml(&value)
    }

    /// Converts a parsed YAML value (a scalar or a flat sequence of one type; integers and
    /// doubles mixed make a double sequence).
    pub fn from_yaml(value: &serde_yaml_ng::Value) -> Result<ParamValue, ValueError> {
        use serde_yaml_ng::Value as Y;
        match value {
            Y::Null => Err(ValueError::Null),
            Y::Bool(b) => Ok(ParamValue::Bool(*b)),
            Y::Number(n) => yaml_number(n),
            Y::String(s) => Ok(ParamValue::String(s.clone())),
            Y::Tagged(t) => ParamValue::from_yaml(&t.value),
            Y::Mapping(_) => Err(ValueError::Mapping),
            Y::Sequence(items) => {
                let scalars = items
                    .iter()
                    .map(|item| match item {
                        Y::Sequence(_) | Y::Mapping(_) => Err(ValueError::Nested),
                        other => ParamValue::from_yaml(other),
                    })
                    .collect::<Result<Vec<_>, ValueError>>()?;
                sequence_value(scalars)
            }
        }
    }
}

fn yaml_number(n: &serde_yaml_ng::Number) -> Result<ParamValue, ValueError> {
    if let Some(i) = n.as_i64() {
        Ok(ParamValue::Int(i))
    } else if n.is_u64() {
        Err(ValueError::IntegerTooLarge(n.to_string()))
    } else {
        n.as_f64()
            .map(ParamValue::Double)
            .ok_or_else(|| ValueError::UnsupportedNumber(n.to_string()))
    }
}

fn sequence_value(items: Vec<ParamValue>) -> Result<ParamValue, ValueError> {
    let Some(first) = items.first() else {
        // An empty sequence has no element type; it fits any array parameter.
        return Ok(ParamValue::StringArray(Vec::new()));
    };
    let mixed = || ValueError::MixedSequence;
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

#[cfg(test)]
mod tests {
    use super::*;

    fn s(v: &str) -> ParamValue {
        ParamValue::String(v.to_string())
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
}
