//! What both formats check of a camera (intrinsics, distortion, rotations, names), and the
//! errors about one camera's entry ([`CameraError`]).

use std::collections::HashSet;

use glam::{DMat3, DVec3};

use super::{Ctx, RigFileCamera, RigFileError};
use crate::geometry::{Distortion, GeometryError, PinholeIntrinsics};

/// What is wrong with one camera's entry of a rig file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraError {
    /// The entry does not deserialise (YAML's message, with the key path and line).
    #[error("{0}")]
    Entry(String),
    #[error("`name` is empty")]
    EmptyName,
    #[error("the name is used by more than one camera")]
    DuplicateName,
    #[error("give either `rotation` or `rotation_matrix`, not both")]
    BothRotations,
    #[error("missing the orientation: `rotation` (quaternion [x, y, z, w]) or `rotation_matrix` (3x3 row-major)")]
    NoRotation,
    #[error("`rotation` must be a quaternion [x, y, z, w] (4 numbers), got {0} numbers")]
    QuaternionLength(usize),
    #[error("`rotation_matrix` must be a 3x3 row-major matrix: 9 numbers or 3 rows of 3 numbers")]
    MatrixShape,
    #[error("`{field}` must be [x, y, z] (3 numbers), got {got} numbers")]
    VectorLength { field: &'static str, got: usize },
    #[error("`{field}` has a NaN or infinite component")]
    VectorNotFinite { field: &'static str },
    /// A rotation that is not one (not unit, not orthonormal, ...).
    #[error("`{field}`: {reason}")]
    Pose { field: &'static str, reason: String },
    #[error("`intrinsics`: image size {width}x{height} has a zero side")]
    ZeroSize { width: u32, height: u32 },
    #[error("`intrinsics`: {0} is not finite")]
    IntrinsicNotFinite(&'static str),
    #[error("`intrinsics`: focal lengths must be positive (fx = {fx}, fy = {fy})")]
    FocalNotPositive { fx: f64, fy: f64 },
    #[error("`distortion` is given without `intrinsics`")]
    DistortionWithoutIntrinsics,
    #[error("`distortion`: unknown model '{0}' (supported: plumb_bob [k1, k2, p1, p2, k3], equidistant [k1, k2, k3, k4], none)")]
    UnknownDistortion(String),
    #[error("`distortion`: model '{model}' needs {expected} coefficients, got {got}")]
    DistortionCount {
        model: String,
        expected: usize,
        got: usize,
    },
    #[error("`distortion`: a coefficient is NaN or infinite")]
    DistortionNotFinite,
    #[error("Kalibr camera model '{0}' is not supported (only `pinhole`, with radtan, equidistant or no distortion)")]
    KalibrModel(String),
    #[error("`intrinsics` of a pinhole camera must be [fu, fv, pu, pv], got {0} numbers")]
    KalibrIntrinsics(usize),
    #[error("`resolution` must be [width, height], got {0} numbers")]
    KalibrResolution(usize),
    #[error("`distortion_coeffs` of {model} must be {form}, got {got} numbers")]
    KalibrDistortionCount {
        model: &'static str,
        form: &'static str,
        got: usize,
    },
    #[error("`distortion_model` is none but `distortion_coeffs` are not all zero")]
    KalibrNoneWithCoefficients,
    #[error("Kalibr distortion model '{0}' is not supported (radtan, equidistant, none)")]
    KalibrDistortion(String),
    #[error("missing `T_cn_cnm1` (the transform from the previous camera into this one)")]
    MissingChain,
    #[error("`{0}` must be a 4x4 matrix (4 rows of 4 numbers)")]
    HomogeneousShape(&'static str),
    #[error("`{0}` has a NaN or infinite entry")]
    HomogeneousNotFinite(&'static str),
    #[error("`{field}`: the last row must be [0, 0, 0, 1], got {last:?}")]
    HomogeneousLastRow { field: &'static str, last: Vec<f64> },
}

/// A pose the geometry refused, about `field`.
pub(super) fn pose_error(field: &'static str, error: GeometryError) -> CameraError {
    let reason = match error {
        GeometryError::InvalidPose { reason, .. } => reason,
        other => other.to_string(),
    };
    CameraError::Pose { field, reason }
}

pub(super) fn vec3(v: &[f64], field: &'static str) -> Result<DVec3, CameraError> {
    if v.len() != 3 {
        return Err(CameraError::VectorLength {
            field,
            got: v.len(),
        });
    }
    if v.iter().any(|x| !x.is_finite()) {
        return Err(CameraError::VectorNotFinite { field });
    }
    Ok(DVec3::new(v[0], v[1], v[2]))
}

pub(super) fn rows_to_mat3(r: [[f64; 3]; 3]) -> DMat3 {
    DMat3::from_cols(
        DVec3::new(r[0][0], r[1][0], r[2][0]),
        DVec3::new(r[0][1], r[1][1], r[2][1]),
        DVec3::new(r[0][2], r[1][2], r[2][2]),
    )
}

pub(super) fn check_intrinsics(k: &PinholeIntrinsics) -> Result<(), CameraError> {
    if k.width_px == 0 || k.height_px == 0 {
        return Err(CameraError::ZeroSize {
            width: k.width_px,
            height: k.height_px,
        });
    }
    for (name, v) in [
        ("fx", k.fx_px),
        ("fy", k.fy_px),
        ("cx", k.cx_px),
        ("cy", k.cy_px),
    ] {
        if !v.is_finite() {
            return Err(CameraError::IntrinsicNotFinite(name));
        }
    }
    if k.fx_px <= 0.0 || k.fy_px <= 0.0 {
        return Err(CameraError::FocalNotPositive {
            fx: k.fx_px,
            fy: k.fy_px,
        });
    }
    Ok(())
}

/// Our distortion models with exact coefficient counts; all-zero coefficients give `None`.
pub(super) fn distortion_from(model: &str, d: &[f64]) -> Result<Distortion, CameraError> {
    let expected = match model {
        "none" => 0,
        "plumb_bob" => 5,
        "equidistant" => 4,
        other => return Err(CameraError::UnknownDistortion(other.to_string())),
    };
    if d.len() != expected {
        return Err(CameraError::DistortionCount {
            model: model.to_string(),
            expected,
            got: d.len(),
        });
    }
    if d.iter().any(|v| !v.is_finite()) {
        return Err(CameraError::DistortionNotFinite);
    }
    Ok(match model {
        _ if d.iter().all(|&v| v == 0.0) => Distortion::None,
        "plumb_bob" => Distortion::PlumbBob {
            k1: d[0],
            k2: d[1],
            p1: d[2],
            p2: d[3],
            k3: d[4],
        },
        _ => Distortion::Equidistant {
            k1: d[0],
            k2: d[1],
            k3: d[2],
            k4: d[3],
        },
    })
}

pub(super) fn check_unique_names(
    ctx: &Ctx<'_>,
    cameras: &[RigFileCamera],
) -> Result<(), RigFileError> {
    let mut seen = HashSet::new();
    for camera in cameras {
        if !seen.insert(camera.name.as_str()) {
            return Err(ctx.camera(&camera.name, CameraError::DuplicateName));
        }
    }
    Ok(())
}
