//! The node's parameter values ([`LiveParams`]): validation of sets
//! ([`crate::params::checks::check_change`]) and application of accepted engine parameter
//! changes (the GPU worker takes the new [`SweepParams`] from the next frame set on); the
//! services that serve them: [`super::param_services`]. No DDS; unit-tested.

use std::sync::{Arc, Mutex, MutexGuard};

use ros2_client::parameters::ParameterValue as RosValue;
use ros2_client::NodeOptions;

use crate::params::checks::{check_change, check_changes};
use crate::params::{ParamError, ParamSet, ParamValue};
use crate::sweep::{RigShape, SweepParams};

/// Why a parameter set is refused (the parameter service answers with its message).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SetError {
    #[error(transparent)]
    Unsupported(#[from] UnsupportedValue),
    #[error(transparent)]
    Param(#[from] ParamError),
}

/// A value a ROS peer sent that no parameter of this node can hold.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum UnsupportedValue {
    #[error("parameters of this node cannot be unset")]
    NotSet,
    #[error("byte array parameters are not supported")]
    ByteArray,
}

/// `ParamValue` as a ros2-client value.
pub fn to_ros(value: &ParamValue) -> RosValue {
    match value {
        ParamValue::Bool(b) => RosValue::Boolean(*b),
        ParamValue::Int(i) => RosValue::Integer(*i),
        ParamValue::Double(d) => RosValue::Double(*d),
        ParamValue::String(s) => RosValue::String(s.clone()),
        ParamValue::BoolArray(v) => RosValue::BooleanArray(v.clone()),
        ParamValue::IntArray(v) => RosValue::IntegerArray(v.clone()),
        ParamValue::DoubleArray(v) => RosValue::DoubleArray(v.clone()),
        ParamValue::StringArray(v) => RosValue::StringArray(v.clone()),
    }
}

/// A ros2-client value as a `ParamValue` (not set and byte arrays are not supported).
pub fn from_ros(value: &RosValue) -> Result<ParamValue, UnsupportedValue> {
    Ok(match value {
        RosValue::Boolean(b) => ParamValue::Bool(*b),
        RosValue::Integer(i) => ParamValue::Int(*i),
        RosValue::Double(d) => ParamValue::Double(*d),
        RosValue::String(s) => ParamValue::String(s.clone()),
        RosValue::BooleanArray(v) => ParamValue::BoolArray(v.clone()),
        RosValue::IntegerArray(v) => ParamValue::IntArray(v.clone()),
        RosValue::DoubleArray(v) => ParamValue::DoubleArray(v.clone()),
        RosValue::StringArray(v) => ParamValue::StringArray(v.clone()),
        RosValue::NotSet => return Err(UnsupportedValue::NotSet),
        RosValue::ByteArray(_) => return Err(UnsupportedValue::ByteArray),
    })
}

/// The parameter values and the engine parameters derived from them, shared by the parameter
/// callbacks (spinner) and the GPU worker.
#[derive(Debug)]
pub struct LiveParams {
    params: Mutex<ParamSet>,
    sweep: Mutex<SweepParams>,
    /// The rig's shape (its number of cameras, its kind of reference), for the checks of
    /// [`SweepParams::validate`] that depend on the rig's structure (not its calibration).
    shape: RigShape,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl LiveParams {
    /// A node whose rig has `shape` (its number of cameras, its kind of reference).
    pub fn new(params: ParamSet, sweep: SweepParams, shape: RigShape) -> Arc<Self> {
        Arc::new(Self {
            params: Mutex::new(params),
            sweep: Mutex::new(sweep),
            shape,
        })
    }

    /// The engine parameters for the next frame set.
    pub fn sweep(&self) -> SweepParams {
        lock(&self.sweep).clone()
    }

    pub fn params(&self) -> ParamSet {
        lock(&self.params).clone()
    }

    /// The parameters to declare: every parameter of the table, with its current value.
    pub fn declarations(&self) -> Vec<(String, RosValue)> {
        lock(&self.params)
            .iter()
            .map(|(spec, value)| (spec.name.to_string(), to_ros(value)))
            .collect()
    }

    /// The parameter set and engine parameters that setting `name` to `value` gives, or why
    /// the set is rejected.
    fn candidate(&self, name: &str, value: &RosValue) -> Result<(ParamSet, SweepParams), SetError> {
        let value = from_ros(value)?;
        Ok(check_change(
            &self.params(),
            &self.sweep(),
            Some(self.shape),
            name,
            &value,
        )?)
    }

    /// The validator: Ok if `name` may be set to `value`, else the reason.
    pub fn check(&self, name: &str, value: &RosValue) -> Result<(), SetError> {
        self.candidate(name, value).map(|_| ())
    }

    /// The set action: stores the value; the worker uses the new engine parameters from the
    /// next frame set on. Returns whether the value changed.
    pub fn apply(&self, name: &str, value: &RosValue) -> Result<bool, SetError> {
        let (params, sweep) = self.candidate(name, value)?;
        let mut current = lock(&self.params);
        let changed = current.get(name) != params.get(name);
        *current = params;
        drop(current);
        *lock(&self.sweep) = sweep;
        Ok(changed)
    }

    /// All or none: each change is checked on the values the earlier ones give; when every
    /// one is accepted all are stored. Returns, per change, whether it changed the value.
    pub fn apply_all(&self, changes: &[(String, RosValue)]) -> Result<Vec<bool>, SetError> {
        let mut current = lock(&self.params);
        let values = changes
            .iter()
            .map(|(_, value)| from_ros(value))
            .collect::<Result<Vec<_>, _>>()?;
        let named: Vec<(&str, &ParamValue)> = changes
            .iter()
            .zip(&values)
            .map(|((name, _), value)| (name.as_str(), value))
            .collect();
        // Checked together: the values the others give, not the current ones (a new depth
        // range beyond the current one is one valid change).
        let (params, sweep) = check_changes(&current, &self.sweep(), Some(self.shape), &named)?;
        let changed = changes
            .iter()
            .map(|(name, _)| params.get(name) != current.get(name))
            .collect();
        *current = params;
        drop(current);
        *lock(&self.sweep) = sweep;
        Ok(changed)
    }
}

/// A node's options: rosout on; the parameter services are ours
/// ([`super::param_services`]), not ros2-client's (which cannot serve descriptors); `/clock` is
/// read by the node itself ([`super::topics::subscribe_clock`]: `rosgraph_msgs/Clock`, best
/// effort, remapped), not by ros2-client's spinner (`builtin_interfaces/Time`, never remapped:
/// a second type on `/clock` in the graph); `/parameter_events` is published by the node's own
/// writer with rcl's QoS ([`super::param_services::parameter_events_writer`]), not ros2-client's
/// (transient local, keep last 1: an rcl node has one writer, volatile).
pub(super) fn node_options() -> NodeOptions {
    NodeOptions::new()
        .enable_rosout(true)
        .start_parameter_services(false)
        .publish_parameter_events(false)
        .read_clock(false)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shape(cameras: usize, real_reference: bool) -> RigShape {
        RigShape::chosen_views(cameras, real_reference)
    }

    fn live() -> Arc<LiveParams> {
        let mut set = ParamSet::defaults();
        set.set(
            "cameras",
            &ParamValue::StringArray(vec!["a".into(), "b".into()]),
        )
        .unwrap();
        let mut sweep = SweepParams::default();
        crate::params::apply_to_sweep(&set, &mut sweep).unwrap();
        LiveParams::new(set, sweep, shape(2, true))
    }

    #[test]
    fn declarations_cover_the_table() {
        let l = live();
        let d = l.declarations();
        assert_eq!(d.len(), crate::params::param_table().len());
        assert!(d.contains(&(
            "cameras".to_string(),
            RosValue::StringArray(vec!["a".into(), "b".into()])
        )));
    }

    #[test]
    fn atomic_sets_are_all_or_none() {
        let l = live();
        let int = |i| RosValue::Integer(i);
        // The second change is refused: nothing is stored.
        assert!(l
            .apply_all(&[
                ("num_planes".into(), int(32)),
                ("num_planes".into(), int(1))
            ])
            .is_err());
        assert_eq!(l.sweep().num_planes, 64);
        // Both ends of the depth range moved at once.
        let changed = l
            .apply_all(&[
                ("max_depth".into(), RosValue::Double(200.0)),
                ("min_depth".into(), RosValue::Double(100.0)),
                ("num_planes".into(), int(64)),
            ])
            .unwrap();
        assert_eq!(changed, [true, true, false]);
        assert_eq!(l.sweep().min_depth_m, 100.0);
        // Checked together, not in order: min_depth first, beyond the current max_depth, is
        // valid with the new max_depth (as rclcpp hands its callback the whole list).
        let changed = l
            .apply_all(&[
                ("min_depth".into(), RosValue::Double(300.0)),
                ("max_depth".into(), RosValue::Double(400.0)),
            ])
            .unwrap();
        assert_eq!(changed, [true, true]);
        assert_eq!(
            (l.sweep().min_depth_m, l.sweep().max_depth_m),
            (300.0, 400.0)
        );
        // ... and a range that is none together is refused, nothing stored.
        let e = l
            .apply_all(&[
                ("min_depth".into(), RosValue::Double(50.0)),
                ("max_depth".into(), RosValue::Double(40.0)),
            ])
            .unwrap_err();
        assert!(e.to_string().contains("must be smaller"), "{e}");
        assert_eq!(l.sweep().min_depth_m, 300.0);
    }

    #[test]
    fn sets_are_validated_and_applied() {
        let l = live();
        let e = l
            .check("sync", &RosValue::String("exact".into()))
            .unwrap_err()
            .to_string();
        assert!(e.contains("read-only"), "{e}");
        // The current value of a read-only parameter is accepted (declaration).
        assert!(l
            .check("sync", &RosValue::String("approximate".into()))
            .is_ok());
        assert_eq!(
            l.apply("sync", &RosValue::String("approximate".into())),
            Ok(false)
        );
        let e = l
            .check("num_planes", &RosValue::Integer(1))
            .unwrap_err()
            .to_string();
        assert!(e.contains("num_planes"), "{e}");
        let e = l
            .check("min_depth", &RosValue::Double(100.0))
            .unwrap_err()
            .to_string();
        assert!(e.contains("max_depth"), "{e}");
        assert!(l.check("nope", &RosValue::Integer(1)).is_err());
        // Checks across parameters: a shiftable window must be 1 or even (default 5x5).
        let e = l
            .check("window_mode", &RosValue::String("shiftable".into()))
            .unwrap_err()
            .to_string();
        assert!(e.contains("window_mode") && e.contains("even"), "{e}");
        assert!(l.check("median", &RosValue::NotSet).is_err());
        assert!(l.check("num_planes", &RosValue::Integer(32)).is_ok());
        assert_eq!(l.sweep().num_planes, 64);
        assert_eq!(l.apply("num_planes", &RosValue::Integer(32)), Ok(true));
        assert_eq!(l.sweep().num_planes, 32);
        assert_eq!(l.params().get_i64("num_planes").unwrap(), 32);
        l.apply("max_depth", &RosValue::Double(3.0)).unwrap();
        assert_eq!(l.sweep().max_depth_m, 3.0);
    }

    /// best_n is checked against the rig only while it is read (scoring best_n_of_m).
    fn best_n_of_m() -> ParamValue {
        ParamValue::String("best_n_of_m".into())
    }

    fn live_rig(cameras: usize, set: &[(&str, ParamValue)]) -> Arc<LiveParams> {
        let mut params = ParamSet::defaults();
        let names: Vec<String> = (0..cameras).map(|i| format!("cam{i}")).collect();
        params
            .set("cameras", &ParamValue::StringArray(names))
            .unwrap();
        for (name, value) in set {
            params.set(name, value).unwrap();
        }
        let mut sweep = SweepParams::default();
        crate::params::apply_to_sweep(&params, &mut sweep).unwrap();
        LiveParams::new(params, sweep, shape(cameras, true))
    }

    #[test]
    fn best_n_larger_than_the_pairs_is_rejected_and_the_old_value_stays() {
        // 4 cameras, reference pairs: m = 3.
        let l = live_rig(4, &[("scoring", best_n_of_m())]);
        let e = l
            .apply("best_n", &RosValue::Integer(4))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("best_n (4)") && e.contains("3 camera pairs") && e.contains("4 cameras"),
            "{e}"
        );
        assert_eq!(l.sweep().best_n, 2);
        assert_eq!(l.params().get_i64("best_n").unwrap(), 2);
        assert_eq!(l.apply("best_n", &RosValue::Integer(3)), Ok(true));
        // All pairs: m = 6, so best_n 5 fits; back to reference pairs (m = 3) it would not.
        assert_eq!(l.apply("pairs", &RosValue::String("all".into())), Ok(true));
        assert_eq!(l.apply("best_n", &RosValue::Integer(5)), Ok(true));
        let e = l
            .check("pairs", &RosValue::String("reference".into()))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("parameter 'pairs'") && e.contains("best_n (5)"),
            "{e}"
        );
        assert_eq!(l.params().get_str("pairs").unwrap(), "all");
        // Other scorings do not use best_n.
        assert!(l.check("scoring", &RosValue::String("sssd".into())).is_ok());
    }

    #[test]
    fn a_default_best_n_above_a_small_rig_does_not_block_other_sets() {
        // 2 cameras: m = 1 < the default best_n 2 (harmless: best 1 of 1). Sets that leave
        // best_n alone pass, the declaration of the current value passes, raising it fails.
        let l = live_rig(2, &[("scoring", best_n_of_m())]);
        assert_eq!(l.apply("best_n", &RosValue::Integer(2)), Ok(false));
        assert_eq!(l.apply("num_planes", &RosValue::Integer(32)), Ok(true));
        assert_eq!(l.apply("pairs", &RosValue::String("all".into())), Ok(true));
        assert!(l.check("best_n", &RosValue::Integer(3)).is_err());
        assert!(l.check("best_n", &RosValue::Integer(1)).is_ok());
    }

    #[test]
    fn min_visible_cameras_above_the_rig_is_rejected() {
        let l = live_rig(3, &[]);
        let e = l
            .apply("min_visible_cameras", &RosValue::Integer(4))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("min_visible_cameras (4)") && e.contains("3 cameras"),
            "{e}"
        );
        assert_eq!(l.sweep().min_visible_cameras, 2);
        assert_eq!(
            l.apply("min_visible_cameras", &RosValue::Integer(3)),
            Ok(true)
        );
    }

    #[test]
    fn depth_range_is_checked_against_the_current_other_end() {
        let l = live_rig(3, &[]);
        // max_depth is 10: min_depth 10 (equal) and 20 are refused, 9 is fine.
        for bad in [10.0, 20.0] {
            let e = l
                .apply("min_depth", &RosValue::Double(bad))
                .unwrap_err()
                .to_string();
            assert!(e.contains("max_depth (10)"), "{e}");
        }
        assert_eq!(l.sweep().min_depth_m, 0.5);
        l.apply("min_depth", &RosValue::Double(9.0)).unwrap();
        // Now max_depth below the new min_depth is refused, and the old one stays.
        let e = l
            .apply("max_depth", &RosValue::Double(8.0))
            .unwrap_err()
            .to_string();
        assert!(e.contains("min_depth (9)"), "{e}");
        assert_eq!(l.sweep().max_depth_m, 10.0);
        assert_eq!(l.params().get_f64("max_depth").unwrap(), 10.0);
        // Non-finite and wrong types.
        assert!(l.check("max_depth", &RosValue::Double(f64::NAN)).is_err());
        assert!(l
            .check("max_depth", &RosValue::Double(f64::INFINITY))
            .is_err());
        assert!(l
            .check("max_depth", &RosValue::String("far".into()))
            .is_err());
        assert!(l.check("best_n", &RosValue::Double(2.0)).is_err());
        // Read-only node parameters: reference_camera cannot change at run time.
        let e = l
            .check("reference_camera", &RosValue::String("cam0".into()))
            .unwrap_err()
            .to_string();
        assert!(e.contains("read-only"), "{e}");
    }

    #[test]
    fn virtual_reference_rejects_reference_pairs() {
        let mut set = ParamSet::defaults();
        set.set("pairs", &ParamValue::String("all".into())).unwrap();
        let mut sweep = SweepParams::default();
        crate::params::apply_to_sweep(&set, &mut sweep).unwrap();
        let l = LiveParams::new(set, sweep, shape(3, false));
        let e = l
            .check("pairs", &RosValue::String("reference".into()))
            .unwrap_err()
            .to_string();
        assert!(e.contains("virtual"), "{e}");
        assert!(l.check("num_planes", &RosValue::Integer(32)).is_ok());
    }

    #[test]
    fn value_round_trip() {
        for v in [
            ParamValue::Bool(true),
            ParamValue::Int(3),
            ParamValue::Double(0.5),
            ParamValue::String("x".into()),
            ParamValue::StringArray(vec!["a".into()]),
            ParamValue::DoubleArray(vec![1.0]),
            ParamValue::IntArray(vec![1]),
            ParamValue::BoolArray(vec![false]),
        ] {
            assert_eq!(from_ros(&to_ros(&v)).unwrap(), v);
        }
        assert!(from_ros(&RosValue::ByteArray(vec![1])).is_err());
    }
}
