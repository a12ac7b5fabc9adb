//! What a parameter is ([`ParamSpec`]: name, type, default, range, description, live or not)
//! and the checks of a value against it. The one table of every parameter (the engine
//! parameters of [`super::engine`], then the node parameters of [`super::node`]) is
//! [`super::table::param_table`].

use super::ParamError;
use crate::ros::args::{validate_topic_name, RosArgsError};
use crate::ros::param_value::{ParamKind, ParamValue};

/// The accepted values of a parameter (ROS ranges are inclusive; the exclusive bounds here are
/// published as inclusive ranges with a note in the description).
#[derive(Debug, Clone, PartialEq)]
pub enum ParamRange {
    /// Any value of the type.
    Any,
    Int {
        min: i64,
        max: i64,
    },
    /// Always finite; `max = f64::INFINITY` means no upper bound.
    Double {
        min: f64,
        max: f64,
        min_exclusive: bool,
        max_exclusive: bool,
    },
    /// One of these strings.
    OneOf(Vec<String>),
    /// A relative ROS name (no leading `/` or `~`).
    RelativeName,
    /// Empty, or a ROS name.
    OptionalName,
    /// At least `min_len` distinct ROS names.
    NameList {
        min_len: usize,
    },
    /// A list whose every entry is one of these strings.
    EachOneOf(Vec<String>),
}

impl ParamRange {
    /// `min..=max`.
    pub const fn ints(min: i64, max: i64) -> Self {
        ParamRange::Int { min, max }
    }

    /// `[min, max]`.
    pub const fn closed(min: f64, max: f64) -> Self {
        ParamRange::Double {
            min,
            max,
            min_exclusive: false,
            max_exclusive: false,
        }
    }

    /// `>= min`.
    pub const fn at_least(min: f64) -> Self {
        ParamRange::Double {
            min,
            max: f64::INFINITY,
            min_exclusive: false,
            max_exclusive: false,
        }
    }

    /// `> min`.
    pub const fn above(min: f64) -> Self {
        ParamRange::Double {
            min,
            max: f64::INFINITY,
            min_exclusive: true,
            max_exclusive: false,
        }
    }

    /// One of `values`.
    pub fn one_of(values: &[&str]) -> Self {
        ParamRange::OneOf(values.iter().map(|v| v.to_string()).collect())
    }

    /// A list whose every entry is one of `values`.
    pub fn each_one_of(values: &[&str]) -> Self {
        ParamRange::EachOneOf(values.iter().map(|v| v.to_string()).collect())
    }

    /// How the range reads in the docs and in errors.
    pub fn describe(&self) -> String {
        match self {
            ParamRange::Any => String::new(),
            ParamRange::Int { min, max } => format!("{min} ..= {max}"),
            ParamRange::Double {
                min,
                max,
                min_exclusive,
                max_exclusive,
            } => {
                if max.is_infinite() {
                    format!("{} {min:?}", if *min_exclusive { ">" } else { ">=" })
                } else {
                    format!(
                        "{}{min:?}, {max:?}{}",
                        if *min_exclusive { "(" } else { "[" },
                        if *max_exclusive { ")" } else { "]" }
                    )
                }
            }
            ParamRange::OneOf(values) => values.join(" | "),
            ParamRange::RelativeName => "relative ROS name".into(),
            ParamRange::OptionalName => "empty or a ROS name".into(),
            ParamRange::NameList { min_len } => format!(">= {min_len} distinct ROS names"),
            ParamRange::EachOneOf(values) => format!("each {}", values.join(" | ")),
        }
    }

    /// Checks a value of the parameter's type against the range.
    pub fn check(&self, value: &ParamValue) -> Result<(), ParamError> {
        match (self, value) {
            (ParamRange::Any, ParamValue::Double(d)) if !d.is_finite() => {
                Err(ParamError::NotFinite(*d))
            }
            (ParamRange::Any, _) => Ok(()),
            (ParamRange::Int { min, max }, ParamValue::Int(i)) => {
                if (*min..=*max).contains(i) {
                    Ok(())
                } else {
                    Err(ParamError::IntOutOfRange {
                        min: *min,
                        max: *max,
                        got: *i,
                    })
                }
            }
            (
                ParamRange::Double {
                    min,
                    max,
                    min_exclusive,
                    max_exclusive,
                },
                ParamValue::Double(d),
            ) => {
                let above_min = if *min_exclusive {
                    *d > *min
                } else {
                    *d >= *min
                };
                let below_max = if *max_exclusive {
                    *d < *max
                } else {
                    *d <= *max
                };
                if !d.is_finite() {
                    Err(ParamError::NotFinite(*d))
                } else if above_min && below_max {
                    Ok(())
                } else {
                    Err(ParamError::DoubleOutOfRange {
                        range: self.describe(),
                        got: *d,
                    })
                }
            }
            (ParamRange::OneOf(allowed), ParamValue::String(v)) => {
                if allowed.contains(v) {
                    Ok(())
                } else {
                    Err(ParamError::NotOneOf {
                        value: v.clone(),
                        allowed: allowed.clone(),
                    })
                }
            }
            (ParamRange::RelativeName, ParamValue::String(v)) => {
                check_name(v)?;
                if v.starts_with('/') || v.starts_with('~') {
                    Err(ParamError::NotRelative(v.clone()))
                } else {
                    Ok(())
                }
            }
            (ParamRange::OptionalName, ParamValue::String(v)) => {
                if v.is_empty() {
                    Ok(())
                } else {
                    check_name(v)
                }
            }
            (ParamRange::NameList { min_len }, ParamValue::StringArray(names)) => {
                if names.len() < *min_len {
                    return Err(ParamError::TooFewEntries {
                        min_len: *min_len,
                        got: names.len(),
                    });
                }
                for (i, name) in names.iter().enumerate() {
                    check_name(name)?;
                    if names[..i].contains(name) {
                        return Err(ParamError::Repeated(name.clone()));
                    }
                }
                Ok(())
            }
            (ParamRange::EachOneOf(allowed), ParamValue::StringArray(values)) => {
                match values.iter().find(|v| !allowed.contains(v)) {
                    None => Ok(()),
                    Some(v) => Err(ParamError::NotOneOf {
                        value: v.clone(),
                        allowed: allowed.clone(),
                    }),
                }
            }
            (range, v) => Err(ParamError::RangeMismatch {
                range: format!("{range:?}"),
                kind: v.kind(),
            }),
        }
    }
}

/// A ROS name as the ranges of names want it.
fn check_name(name: &str) -> Result<(), ParamError> {
    validate_topic_name(name).map_err(|e| match e {
        RosArgsError::InvalidName { name, reason } => ParamError::InvalidName { name, reason },
        other => ParamError::InvalidName {
            name: name.to_string(),
            reason: other.to_string(),
        },
    })
}

/// One parameter: what the node declares on its parameter services, docs/node.md documents and
/// every setter checks against.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamSpec {
    /// The ROS parameter name.
    pub name: &'static str,
    pub kind: ParamKind,
    pub default: ParamValue,
    pub range: ParamRange,
    pub description: &'static str,
    /// Cannot change after the node started (node parameters); engine parameters are live:
    /// a change applies from the next frame set.
    pub read_only: bool,
    /// The default is a placeholder; the node does not start without a value.
    pub required: bool,
}

impl ParamSpec {
    /// `value` as stored for this parameter (integers become doubles for `double` parameters,
    /// empty sequences take the parameter's array type), checked against the range.
    pub fn coerce(&self, value: &ParamValue) -> Result<ParamValue, ParamError> {
        let value = self.coerce_kind(value)?;
        self.range.check(&value)?;
        Ok(value)
    }

    fn coerce_kind(&self, value: &ParamValue) -> Result<ParamValue, ParamError> {
        if value.kind() == self.kind {
            return Ok(value.clone());
        }
        let converted = match (self.kind, value) {
            (ParamKind::Double, ParamValue::Int(i)) => Some(ParamValue::Double(*i as f64)),
            (ParamKind::DoubleArray, ParamValue::IntArray(v)) => Some(ParamValue::DoubleArray(
                v.iter().map(|i| *i as f64).collect(),
            )),
            (kind, v) if kind.is_array() && v.is_empty_array() => Some(match kind {
                ParamKind::BoolArray => ParamValue::BoolArray(Vec::new()),
                ParamKind::IntArray => ParamValue::IntArray(Vec::new()),
                ParamKind::DoubleArray => ParamValue::DoubleArray(Vec::new()),
                _ => ParamValue::StringArray(Vec::new()),
            }),
            _ => None,
        };
        converted.ok_or_else(|| ParamError::WrongType {
            expected: self.kind,
            got: value.kind(),
            value: value.to_string(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::table::{coerce, param_table, validate};

    fn strings(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    fn s(v: &str) -> ParamValue {
        ParamValue::String(v.to_string())
    }

    #[test]
    fn table_names_are_unique_and_defaults_valid() {
        for (i, p) in param_table().iter().enumerate() {
            assert!(
                param_table()[..i].iter().all(|q| q.name != p.name),
                "{} twice",
                p.name
            );
            assert_eq!(p.kind, p.default.kind(), "{}", p.name);
            if !p.required {
                assert_eq!(validate(p.name, &p.default), Ok(()), "{}", p.name);
            } else {
                assert!(validate(p.name, &p.default).is_err(), "{}", p.name);
            }
        }
    }

    #[test]
    fn coercions() {
        assert_eq!(
            coerce("tau", &ParamValue::Int(50)),
            Ok(ParamValue::Double(50.0))
        );
        assert!(coerce("num_planes", &ParamValue::Double(64.0)).is_err());
        assert_eq!(
            coerce("cameras", &ParamValue::StringArray(strings(&["a", "b"]))),
            Ok(ParamValue::StringArray(strings(&["a", "b"])))
        );
        assert!(coerce("cameras", &ParamValue::StringArray(strings(&["a", "a"]))).is_err());
        assert!(coerce("cameras", &ParamValue::StringArray(strings(&["a", "1b"]))).is_err());
        assert!(coerce("image_topic", &s("/abs")).is_err());
        assert!(coerce("half_margin", &ParamValue::Double(1.0)).is_err());
        assert!(coerce("half_margin", &ParamValue::Double(0.0)).is_ok());
        assert!(coerce("min_depth", &ParamValue::Double(0.0)).is_err());
        assert!(coerce("min_depth", &ParamValue::Double(f64::INFINITY)).is_err());
    }

    #[test]
    fn range_messages() {
        let e = coerce("num_planes", &ParamValue::Int(1)).unwrap_err();
        assert_eq!(e.to_string(), "out of range: must be in 2..=4096, got 1");
        let e = coerce("half_margin", &ParamValue::Double(1.0)).unwrap_err();
        assert_eq!(
            e.to_string(),
            "out of range: must be in [0.0, 1.0), got 1.0"
        );
        let e = coerce("tau", &ParamValue::Double(0.0)).unwrap_err();
        assert_eq!(e.to_string(), "out of range: must be > 0.0, got 0.0");
        let e = coerce("scoring", &s("best")).unwrap_err();
        assert_eq!(
            e.to_string(),
            "'best' is not one of the allowed values: sssd, all_pairs, best_n_of_m, best_half_sequence"
        );
    }
}
