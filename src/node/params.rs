//! The node's parameters over ros2-client's parameter services: declaration of the table with
//! the current values, validation of sets (read-only parameters, [`validate`], the checks
//! across engine parameters) and application of accepted engine parameter changes (the GPU
//! worker takes the new [`SweepParams`] from the next frame set on). No DDS; unit-tested.

use std::sync::{Arc, Mutex, MutexGuard};

use ros2_client::parameters::ParameterValue as RosValue;

use crate::geometry::{CameraModel, Reference, Rig};
use crate::ros::args::{apply_to_sweep, param_spec, validate, ParamSet, ParamValue};
use crate::sweep::SweepParams;

/// A stand-in rig with `cameras` cameras and the node's kind of reference (camera `reference`,
/// or a virtual camera there), for the structural checks of [`SweepParams::validate`].
pub fn shape_rig(cameras: usize, reference: usize, virtual_reference: bool) -> Option<Rig> {
    let model = CameraModel::pinhole(crate::synthetic::intrinsics(8, 8));
    let rig = crate::synthetic::row_rig(cameras, 0.1, model, reference).ok()?;
    if !virtual_reference {
        return Some(rig);
    }
    let cam_from_rig = rig.ref_from_rig();
    Rig::new(
        rig.cameras,
        Reference::Virtual {
            model,
            cam_from_rig,
        },
    )
    .ok()
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
pub fn from_ros(value: &RosValue) -> Result<ParamValue, String> {
    Ok(match value {
        RosValue::Boolean(b) => ParamValue::Bool(*b),
        RosValue::Integer(i) => ParamValue::Int(*i),
        RosValue::Double(d) => ParamValue::Double(*d),
        RosValue::String(s) => ParamValue::String(s.clone()),
        RosValue::BooleanArray(v) => ParamValue::BoolArray(v.clone()),
        RosValue::IntegerArray(v) => ParamValue::IntArray(v.clone()),
        RosValue::DoubleArray(v) => ParamValue::DoubleArray(v.clone()),
        RosValue::StringArray(v) => ParamValue::StringArray(v.clone()),
        RosValue::NotSet => return Err("parameters of this node cannot be unset".into()),
        RosValue::ByteArray(_) => return Err("byte array parameters are not supported".into()),
    })
}

/// The parameter values and the engine parameters derived from them, shared by the parameter
/// callbacks (spinner) and the GPU worker.
#[derive(Debug)]
pub struct LiveParams {
    params: Mutex<ParamSet>,
    sweep: Mutex<SweepParams>,
    /// A stand-in rig with the node's number of cameras and reference, for the checks of
    /// [`SweepParams::validate`] that depend on the rig's structure (not its calibration).
    shape: Option<Rig>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl LiveParams {
    /// `cameras` cameras, the reference at index `reference` (or a virtual reference when
    /// `virtual_reference`).
    pub fn new(
        params: ParamSet,
        sweep: SweepParams,
        cameras: usize,
        reference: usize,
        virtual_reference: bool,
    ) -> Arc<Self> {
        let shape = shape_rig(cameras, reference, virtual_reference);
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
    fn candidate(&self, name: &str, value: &RosValue) -> Result<(ParamSet, SweepParams), String> {
        let spec = param_spec(name).ok_or_else(|| format!("unknown parameter '{name}'"))?;
        let value = from_ros(value)?;
        if spec.read_only {
            // ros2-client validates and applies the declared values at start-up: a read-only
            // parameter accepts its current value (no change) and nothing else.
            let params = self.params();
            if params.get(name) == Some(&value) {
                return Ok((params, self.sweep()));
            }
            return Err(format!(
                "parameter '{name}' is read-only (it is fixed once the node runs)"
            ));
        }
        validate(name, &value).map_err(|e| format!("parameter '{name}': {e}"))?;
        let mut params = self.params();
        params
            .set(name, &value)
            .map_err(|e| format!("parameter '{name}': {e}"))?;
        let mut sweep = self.sweep();
        apply_to_sweep(&params, &mut sweep)?;
        if sweep.min_depth_m >= sweep.max_depth_m {
            return Err(format!(
                "min_depth ({}) must be smaller than max_depth ({})",
                sweep.min_depth_m, sweep.max_depth_m
            ));
        }
        if let Some(rig) = &self.shape {
            sweep
                .validate(rig)
                .map_err(|e| format!("parameter '{name}': {e}"))?;
        }
        Ok((params, sweep))
    }

    /// The validator: Ok if `name` may be set to `value`, else the reason.
    pub fn check(&self, name: &str, value: &RosValue) -> Result<(), String> {
        self.candidate(name, value).map(|_| ())
    }

    /// The set action: stores the value; the worker uses the new engine parameters from the
    /// next frame set on. Returns whether the value changed.
    pub fn apply(&self, name: &str, value: &RosValue) -> Result<bool, String> {
        let (params, sweep) = self.candidate(name, value)?;
        let mut current = lock(&self.params);
        let changed = current.get(name) != params.get(name);
        *current = params;
        drop(current);
        *lock(&self.sweep) = sweep;
        Ok(changed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn live() -> Arc<LiveParams> {
        let mut set = ParamSet::defaults();
        set.set(
            "cameras",
            &ParamValue::StringArray(vec!["a".into(), "b".into()]),
        )
        .unwrap();
        let mut sweep = SweepParams::default();
        apply_to_sweep(&set, &mut sweep).unwrap();
        LiveParams::new(set, sweep, 2, 1, false)
    }

    #[test]
    fn declarations_cover_the_table() {
        let l = live();
        let d = l.declarations();
        assert_eq!(d.len(), crate::ros::args::param_table().len());
        assert!(d.contains(&(
            "cameras".to_string(),
            RosValue::StringArray(vec!["a".into(), "b".into()])
        )));
    }

    #[test]
    fn sets_are_validated_and_applied() {
        let l = live();
        let e = l
            .check("sync", &RosValue::String("exact".into()))
            .unwrap_err();
        assert!(e.contains("read-only"), "{e}");
        // The current value of a read-only parameter is accepted (declaration).
        assert!(l
            .check("sync", &RosValue::String("approximate".into()))
            .is_ok());
        assert_eq!(
            l.apply("sync", &RosValue::String("approximate".into())),
            Ok(false)
        );
        let e = l.check("num_planes", &RosValue::Integer(1)).unwrap_err();
        assert!(e.contains("num_planes"), "{e}");
        let e = l.check("min_depth", &RosValue::Double(100.0)).unwrap_err();
        assert!(e.contains("max_depth"), "{e}");
        assert!(l.check("nope", &RosValue::Integer(1)).is_err());
        // Checks across parameters: a shiftable window must be 1 or even (default 9x9).
        let e = l
            .check("window_mode", &RosValue::String("shiftable".into()))
            .unwrap_err();
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

    #[test]
    fn virtual_reference_rejects_reference_pairs() {
        let mut set = ParamSet::defaults();
        set.set("pairs", &ParamValue::String("all".into())).unwrap();
        let mut sweep = SweepParams::default();
        apply_to_sweep(&set, &mut sweep).unwrap();
        let l = LiveParams::new(set, sweep, 3, 1, true);
        let e = l
            .check("pairs", &RosValue::String("reference".into()))
            .unwrap_err();
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
