//! The engine options of `demo`, `eval` and `bench` (`--planes 32 --window 2x2 ...`), made
//! from the engine parameters' declarations ([`super::engine`]): one option per parameter
//! (`--window WxH` for the window's two), its help the parameter's description, its value
//! checked against the parameter's range as the node checks it.

use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::{Arg, ArgAction, ArgMatches, Command};

use super::engine::{engine_param, engine_params, EngineParam, Flag};
use super::spec::ParamRange;
use super::ParamError;
use crate::ros::param_value::{ParamKind, ParamValue};
use crate::sweep::SweepParams;

/// Engine options from the command line; each overrides the value a command starts from.
/// `#[command(flatten)]` it into a command's arguments.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EngineOptions {
    /// Parameter name and value (of the parameter's kind, in its range), in declaration order.
    values: Vec<(&'static str, ParamValue)>,
}

impl EngineOptions {
    /// The parameters set on the command line.
    pub fn values(&self) -> &[(&'static str, ParamValue)] {
        &self.values
    }

    /// Sets the given parameters in `p`.
    pub fn apply(&self, p: &mut SweepParams) {
        for (name, value) in &self.values {
            // The values were checked against their declaration when parsed, so the setter
            // takes them; anything else is a bug in the declaration, said loudly.
            let set = engine_param(name).map_or_else(
                || Err(ParamError::Unknown(name.to_string())),
                |e| (e.set)(p, value),
            );
            if let Err(e) = set {
                tracing::error!("internal: engine option {name} = {value}: {e}");
                debug_assert!(false, "engine option {name} = {value}: {e}");
            }
        }
    }
}

/// The value name in help (`--planes <PLANES>`).
fn value_name(flag: Flag) -> String {
    match flag {
        Flag::Long(name) => name.to_uppercase().replace('-', "_"),
        Flag::Width(_) | Flag::Height(_) => "WxH".into(),
    }
}

/// A command-line value of `param` as a parameter value: numbers and booleans by the
/// parameter's type, then checked against its range.
fn parse_value(param: &EngineParam, text: &str) -> Result<ParamValue, ParamError> {
    let spec = &param.spec;
    let wrong = || ParamError::WrongType {
        expected: spec.kind,
        got: ParamKind::String,
        value: text.to_string(),
    };
    let value = match spec.kind {
        ParamKind::Int => ParamValue::Int(text.trim().parse().map_err(|_| wrong())?),
        ParamKind::Double => ParamValue::Double(text.trim().parse().map_err(|_| wrong())?),
        ParamKind::Bool => ParamValue::Bool(text.trim().parse().map_err(|_| wrong())?),
        _ => ParamValue::String(text.to_string()),
    };
    spec.coerce(&value)
}

/// `WxH` (or `WXH`) for the width and height parameters of one `--NAME WxH` option, as
/// `IntArray([w, h])`.
fn parse_size(
    width: &EngineParam,
    height: &EngineParam,
    text: &str,
) -> Result<ParamValue, ParamError> {
    let (w, h) = text
        .split_once(['x', 'X'])
        .ok_or_else(|| ParamError::NotASize(text.to_string()))?;
    let part = |param: &EngineParam, t: &str| match parse_value(param, t) {
        Ok(ParamValue::Int(v)) => Ok(v),
        Ok(other) => Err(ParamError::WrongType {
            expected: ParamKind::Int,
            got: other.kind(),
            value: other.to_string(),
        }
        .named(param.spec.name)),
        Err(e) => Err(e.named(param.spec.name)),
    };
    Ok(ParamValue::IntArray(vec![
        part(width, w)?,
        part(height, h)?,
    ]))
}

/// The parameter's default as its option takes it (`best-half-sequence`, `64`, `true`).
fn default_text(param: &EngineParam) -> String {
    match &param.spec.default {
        ParamValue::String(s) => s.replace('_', "-"),
        other => other.to_string(),
    }
}

/// The description with the default.
fn with_default(param: &EngineParam) -> String {
    format!(
        "{} [default: {}]",
        param.spec.description,
        default_text(param)
    )
}

/// The option of `param` (for a `Width`, the option of both halves; `Height` has none of its
/// own).
fn option(param: &'static EngineParam) -> Option<Arg> {
    let flag = param.flag;
    let arg = Arg::new(flag.long())
        .long(flag.long())
        .value_name(value_name(flag))
        .action(ArgAction::Set)
        // `--min-depth -1` is a value to refuse with its range, not an unknown option.
        .allow_negative_numbers(true)
        .required(false);
    Some(match (flag, &param.spec.range) {
        (Flag::Height(_), _) => return None,
        (Flag::Width(long), _) => {
            let height = engine_params()
                .iter()
                .find(|p| p.flag == Flag::Height(long))?;
            arg.help(format!(
                "WxH: {} (W) and {} (H). {} [{} each; default: {}x{}]",
                param.spec.name,
                height.spec.name,
                param.spec.description,
                param.spec.range.describe(),
                param.spec.default,
                height.spec.default
            ))
            .value_parser(move |s: &str| parse_size(param, height, s))
        }
        // Enum values as clap writes them (`best-n-of-m`), taken as the parameter's
        // (`best_n_of_m`).
        (_, ParamRange::OneOf(values)) => {
            let kebab: Vec<String> = values.iter().map(|v| v.replace('_', "-")).collect();
            arg.help(with_default(param)).value_parser(
                PossibleValuesParser::new(kebab)
                    .map(|s: String| ParamValue::String(s.replace('-', "_"))),
            )
        }
        (_, _) if param.spec.kind == ParamKind::Bool => arg.help(with_default(param)).value_parser(
            PossibleValuesParser::new(["true", "false"])
                .map(|s: String| ParamValue::Bool(s == "true")),
        ),
        (_, range) => {
            let help = match range.describe() {
                r if r.is_empty() => with_default(param),
                r => format!(
                    "{} [{r}; default: {}]",
                    param.spec.description,
                    default_text(param)
                ),
            };
            arg.help(help)
                .value_parser(move |s: &str| parse_value(param, s))
        }
    })
}

impl clap::FromArgMatches for EngineOptions {
    fn from_arg_matches(matches: &ArgMatches) -> Result<Self, clap::Error> {
        let mut options = Self::default();
        options.update_from_arg_matches(matches)?;
        Ok(options)
    }

    fn update_from_arg_matches(&mut self, matches: &ArgMatches) -> Result<(), clap::Error> {
        for param in engine_params() {
            let flag = param.flag;
            let Ok(Some(value)) = matches.try_get_one::<ParamValue>(flag.long()) else {
                continue;
            };
            let value = match (flag, value) {
                (Flag::Width(_), ParamValue::IntArray(wh)) => ParamValue::Int(wh[0]),
                (Flag::Height(_), ParamValue::IntArray(wh)) => ParamValue::Int(wh[1]),
                (_, v) => v.clone(),
            };
            self.values.retain(|(name, _)| *name != param.spec.name);
            self.values.push((param.spec.name, value));
        }
        Ok(())
    }
}

impl clap::Args for EngineOptions {
    fn augment_args(cmd: Command) -> Command {
        engine_params()
            .iter()
            .filter_map(option)
            .fold(cmd, |cmd, arg| cmd.arg(arg))
    }

    fn augment_args_for_update(cmd: Command) -> Command {
        Self::augment_args(cmd)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::{Args, FromArgMatches};

    fn parse(args: &[&str]) -> Result<EngineOptions, clap::Error> {
        let cmd = EngineOptions::augment_args(Command::new("t").no_binary_name(true));
        let matches = cmd.try_get_matches_from(args)?;
        EngineOptions::from_arg_matches(&matches)
    }

    /// Every option `demo`, `eval` and `bench` had before the declaration made them, still
    /// there under its name.
    #[test]
    fn every_option_keeps_its_name() {
        let cmd = EngineOptions::augment_args(Command::new("t"));
        let longs: Vec<&str> = cmd.get_arguments().filter_map(|a| a.get_long()).collect();
        for flag in [
            "min-depth",
            "max-depth",
            "planes",
            "scoring",
            "pairs",
            "best-n",
            "half-best-n",
            "aggregation",
            "window",
            "window-mode",
            "tau",
            "max-cost",
            "subpixel",
            "median",
            "min-visible",
            "occlusion-tolerance",
            "optimizer",
            "sgm-p1",
            "sgm-p2",
            "sgm-paths",
            "sgm-edge",
        ] {
            assert!(longs.contains(&flag), "--{flag} missing: {longs:?}");
        }
    }

    /// Each option's help says its default, as the option takes it.
    #[test]
    fn help_says_every_default() {
        let cmd = EngineOptions::augment_args(Command::new("t"));
        let help = |long: &str| {
            let arg = cmd.get_arguments().find(|a| a.get_long() == Some(long));
            arg.and_then(|a| a.get_help()).map(|h| h.to_string())
        };
        for arg in cmd.get_arguments() {
            let h = arg.get_help().map(|h| h.to_string()).unwrap_or_default();
            assert!(h.contains("default: "), "{:?}: {h}", arg.get_long());
        }
        let planes = help("planes").unwrap_or_default();
        assert!(planes.ends_with("[2 ..= 4096; default: 64]"), "{planes}");
        let scoring = help("scoring").unwrap_or_default();
        assert!(
            scoring.ends_with("[default: best-half-sequence]"),
            "{scoring}"
        );
        let window = help("window").unwrap_or_default();
        assert!(window.ends_with("default: 5x5]"), "{window}");
    }

    #[test]
    fn options_set_their_fields() {
        let o = parse(&[
            "--planes",
            "32",
            "--window",
            "2x4",
            "--scoring",
            "best-half-sequence",
            "--window-mode",
            "shiftable",
            "--tau",
            "50",
            "--subpixel",
            "false",
            "--min-visible",
            "3",
        ])
        .unwrap();
        let mut p = SweepParams::default();
        o.apply(&mut p);
        assert_eq!(p.num_planes, 32);
        assert_eq!((p.window_width, p.window_height), (2, 4));
        assert_eq!(p.scoring, crate::sweep::Scoring::BestHalfSequence);
        assert_eq!(p.window_mode, crate::sweep::WindowMode::Shiftable);
        assert_eq!(p.tau, 50.0);
        assert!(!p.subpixel);
        assert_eq!(p.min_visible_cameras, 3);
        // Nothing given: nothing changes.
        let mut q = SweepParams::default();
        parse(&[]).unwrap().apply(&mut q);
        assert_eq!(q, SweepParams::default());
    }

    #[test]
    fn values_outside_the_declared_range_are_refused() {
        for (args, needle) in [
            (&["--planes", "1"][..], "out of range"),
            (
                &["--window", "2x40"],
                "parameter 'window_height': out of range",
            ),
            (&["--window", "3"], "not WxH"),
            (&["--tau=-1"], "out of range"),
            // A negative value after a space is a value (clap took it for an option).
            (
                &["--min-depth", "-1"],
                "out of range: must be > 0.0, got -1",
            ),
            (&["--max-depth", "inf"], "must be finite, got inf"),
            (&["--tau", "abc"], "wrong type"),
            (&["--scoring", "best"], "possible values"),
            (&["--median", "yes"], "possible values"),
        ] {
            let e = parse(args).unwrap_err().to_string();
            assert!(e.contains(needle), "{args:?}: {e}");
        }
    }
}
