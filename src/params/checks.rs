//! The checks across parameters that one value's range cannot say: against the rig's shape
//! (best n of m, `min_visible_cameras`, the engine's own [`SweepParams::validate`]) and the
//! depth range, at start-up and for every change of a running node ([`check_change`]).

use super::set::{apply_to_sweep, ParamSet};
use super::table::{param_spec, validate};
use super::ParamError;
use crate::ros::param_value::ParamValue;
use crate::sweep::{PairSet, RigShape, Scoring, SweepParams};

/// Camera pairs a score combines for `sweep` on a rig of `cameras` cameras (m of best n of m).
fn pair_count(sweep: &SweepParams, cameras: usize) -> usize {
    match sweep.effective_pairs() {
        PairSet::Reference => cameras.saturating_sub(1),
        PairSet::All => cameras * cameras.saturating_sub(1) / 2,
    }
}

/// The checks of a parameter set against the rig's shape, for the values it changes (`old` ->
/// `new`; a set to the current value always passes, so the declarations at start-up do too;
/// at start-up `old` is the defaults):
///
/// - best n of m: `best_n` may not exceed the m camera pairs, when `best_n` is set or when a
///   change of `scoring` or `pairs` brings m below a `best_n` that fitted before;
/// - `min_visible_cameras` may not exceed the number of cameras (every pixel would be invalid).
pub fn check_rig_consistency(
    old: &SweepParams,
    new: &SweepParams,
    cameras: usize,
) -> Result<(), ParamError> {
    let m = pair_count(new, cameras);
    let fitted_before =
        old.scoring != Scoring::BestNOfM || old.best_n as usize <= pair_count(old, cameras);
    if new.scoring == Scoring::BestNOfM
        && new.best_n as usize > m
        && (new.best_n != old.best_n || fitted_before)
    {
        return Err(ParamError::BestNAbovePairs {
            best_n: new.best_n,
            pairs: m,
            cameras,
            pair_set: match new.effective_pairs() {
                PairSet::Reference => "reference",
                PairSet::All => "all",
            },
        });
    }
    if new.min_visible_cameras != old.min_visible_cameras
        && new.min_visible_cameras as usize > cameras
    {
        return Err(ParamError::MinVisibleAboveCameras {
            min_visible: new.min_visible_cameras,
            cameras,
        });
    }
    Ok(())
}

/// The engine parameters of a node at start-up against its rig's shape.
pub fn check_start(sweep: &SweepParams, shape: RigShape) -> Result<(), ParamError> {
    sweep
        .validate_shape(shape)
        .map_err(|e| ParamError::Engine {
            context: if !shape.real_reference {
                "virtual_reference: "
            } else {
                ""
            },
            message: e.to_string(),
        })?;
    check_rig_consistency(&SweepParams::default(), sweep, shape.swept(sweep))
}

/// The parameter set and engine parameters that setting `name` to `value` gives a running
/// node (`current`, `current_sweep`; `shape` its rig's shape), or why the change is refused:
/// read-only parameters accept their current value and nothing else (the declaration at
/// start-up sets every parameter to its value); other values are checked against their range,
/// the other end of the depth range and the rig.
pub fn check_change(
    current: &ParamSet,
    current_sweep: &SweepParams,
    shape: Option<RigShape>,
    name: &str,
    value: &ParamValue,
) -> Result<(ParamSet, SweepParams), ParamError> {
    check_changes(current, current_sweep, shape, &[(name, value)])
}

/// [`check_change`] for several parameters set together (`set_parameters_atomically`): each
/// value is checked on its own, then what they give together (the depth range, the rig), so
/// that moving both ends of the depth range at once is one valid change.
pub fn check_changes(
    current: &ParamSet,
    current_sweep: &SweepParams,
    shape: Option<RigShape>,
    changes: &[(&str, &ParamValue)],
) -> Result<(ParamSet, SweepParams), ParamError> {
    let mut params = current.clone();
    for &(name, value) in changes {
        let spec = param_spec(name).ok_or_else(|| ParamError::Unknown(name.to_string()))?;
        if spec.read_only {
            if current.get(name) == Some(value) {
                continue;
            }
            return Err(ParamError::ReadOnly(name.to_string()));
        }
        validate(name, value).map_err(|e| e.named(name))?;
        params.set(name, value).map_err(|e| e.named(name))?;
    }
    let mut sweep = current_sweep.clone();
    apply_to_sweep(&params, &mut sweep)?;
    if sweep.min_depth_m >= sweep.max_depth_m {
        return Err(ParamError::DepthOrder {
            min: sweep.min_depth_m,
            max: sweep.max_depth_m,
        });
    }
    let names: Vec<&str> = changes.iter().map(|(name, _)| *name).collect();
    let names = names.join(", ");
    if let Some(shape) = shape {
        sweep.validate_shape(shape).map_err(|e| {
            ParamError::Engine {
                context: "",
                message: e.to_string(),
            }
            .named(&names)
        })?;
        check_rig_consistency(current_sweep, &sweep, shape.swept(&sweep))
            .map_err(|e| ParamError::KeepCurrent(Box::new(e.named(&names))))?;
    }
    Ok((params, sweep))
}
