//! Rigid transforms, named `a_from_b`.

use glam::{DMat3, DQuat, DVec3};
use serde::{Deserialize, Serialize};

use super::GeometryError;

/// tf2's tolerance on the squared norm of a quaternion (`QUATERNION_NORMALIZATION_TOLERANCE`
/// in tf2's `buffer_core.cpp`, `BufferCore::setTransformImpl`): a rotation is accepted when
/// `|x² + y² + z² + w² - 1| < 0.01`. A hand-typed `(0.71, 0, 0, 0.71)` (squared norm 1.0082)
/// passes; `(0, 0, 0, 1.1)` (1.21) does not.
pub const QUATERNION_NORM_SQUARED_TOLERANCE: f64 = 0.01;

/// Why a quaternion is not a rotation.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum QuaternionError {
    #[error("quaternion has a NaN or infinite component")]
    NotFinite,
    #[error(
        "quaternion is not unit length (x² + y² + z² + w² = {norm_squared}; tf2 accepts \
         |x² + y² + z² + w² - 1| < {QUATERNION_NORM_SQUARED_TOLERANCE})"
    )]
    NotUnit { norm_squared: f64 },
}

/// The rotation of a quaternion as tf2 accepts it: finite, with
/// `|x² + y² + z² + w² - 1| <` [`QUATERNION_NORM_SQUARED_TOLERANCE`]; returned normalised.
/// (tf2 refuses NaN but not infinity; an infinite component is refused here too.)
pub fn unit_quaternion(q: DQuat) -> Result<DQuat, QuaternionError> {
    if !q.is_finite() {
        return Err(QuaternionError::NotFinite);
    }
    let norm_squared = q.length_squared();
    // Written as tf2 writes it, so that NaN-free values on the boundary fall the same way.
    if (norm_squared - 1.0).abs() < QUATERNION_NORM_SQUARED_TOLERANCE {
        Ok(q / norm_squared.sqrt())
    } else {
        Err(QuaternionError::NotUnit { norm_squared })
    }
}

/// A rigid transform `a_from_b`: `point_in_a = rotation * point_in_b + translation`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RigidTransform {
    pub rotation: DQuat,
    pub translation: DVec3,
}

impl Default for RigidTransform {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl RigidTransform {
    pub const IDENTITY: Self = Self {
        rotation: DQuat::IDENTITY,
        translation: DVec3::ZERO,
    };

    /// From a quaternion accepted by tf2's rule ([`unit_quaternion`]: finite, and
    /// |x² + y² + z² + w² - 1| < 0.01), which is then normalised, and a finite translation.
    pub fn from_quat_translation(
        frame: &str,
        rotation: DQuat,
        translation: DVec3,
    ) -> Result<Self, GeometryError> {
        let bad = |reason: String| GeometryError::InvalidPose {
            frame: frame.to_string(),
            reason,
        };
        let rotation = unit_quaternion(rotation).map_err(|e| bad(e.to_string()))?;
        if !translation.is_finite() {
            return Err(bad(
                "translation has a NaN or infinite component".to_string()
            ));
        }
        Ok(Self {
            rotation,
            translation,
        })
    }

    /// From a rotation matrix (must be orthonormal with det +1, within 1e-3) and a translation.
    pub fn from_matrix_translation(
        frame: &str,
        rotation: DMat3,
        translation: DVec3,
    ) -> Result<Self, GeometryError> {
        let bad = |reason: String| GeometryError::InvalidPose {
            frame: frame.to_string(),
            reason,
        };
        if !rotation.is_finite() || !translation.is_finite() {
            return Err(bad("NaN or infinite entry".to_string()));
        }
        let orthogonality = (rotation.transpose() * rotation - DMat3::IDENTITY)
            .to_cols_array()
            .iter()
            .fold(0.0f64, |m, v| m.max(v.abs()));
        if orthogonality > 1e-3 || (rotation.determinant() - 1.0).abs() > 1e-3 {
            return Err(bad(format!(
                "rotation is not orthonormal with det +1 (max |RᵀR - I| = {orthogonality:.2e}, det = {:.4})",
                rotation.determinant()
            )));
        }
        Ok(Self {
            rotation: DQuat::from_mat3(&rotation).normalize(),
            translation,
        })
    }

    pub fn transform_point(&self, point: DVec3) -> DVec3 {
        self.rotation * point + self.translation
    }

    pub fn transform_vector(&self, vector: DVec3) -> DVec3 {
        self.rotation * vector
    }

    pub fn inverse(&self) -> Self {
        let inv = self.rotation.inverse();
        Self {
            rotation: inv,
            translation: -(inv * self.translation),
        }
    }

    /// `a_from_b * b_from_c = a_from_c`.
    pub fn compose(&self, b_from_c: &RigidTransform) -> RigidTransform {
        RigidTransform {
            rotation: (self.rotation * b_from_c.rotation).normalize(),
            translation: self.rotation * b_from_c.translation + self.translation,
        }
    }

    pub fn rotation_matrix(&self) -> DMat3 {
        DMat3::from_quat(self.rotation)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transforms_compose_and_invert() {
        let a_from_b = RigidTransform::from_quat_translation(
            "b",
            DQuat::from_rotation_y(0.3),
            DVec3::new(1.0, 2.0, 3.0),
        )
        .unwrap();
        let p = DVec3::new(0.5, -0.1, 2.0);
        let back = a_from_b
            .inverse()
            .transform_point(a_from_b.transform_point(p));
        assert!((back - p).length() < 1e-12);
        let id = a_from_b.compose(&a_from_b.inverse());
        assert!(id.translation.length() < 1e-12);
        assert!(RigidTransform::from_quat_translation(
            "x",
            DQuat::from_xyzw(0.0, 0.0, 0.0, 2.0),
            DVec3::ZERO
        )
        .is_err());
        assert!(RigidTransform::from_quat_translation(
            "x",
            DQuat::from_xyzw(f64::NAN, 0.0, 0.0, 1.0),
            DVec3::ZERO
        )
        .is_err());
    }

    #[test]
    fn quaternions_follow_tf2s_tolerance_and_are_normalised() {
        // A hand-typed 90 degrees about x, as `static_transform_publisher` users type it.
        let q = unit_quaternion(DQuat::from_xyzw(0.71, 0.0, 0.0, 0.71)).unwrap();
        assert!((q.length() - 1.0).abs() < 1e-15);
        let p = q * DVec3::Y;
        assert!((p - DVec3::Z).length() < 1e-12, "{p}");
        // Inside / outside the squared-norm tolerance of 0.01 (|q| = 1.004987 / 1.005038).
        assert!(unit_quaternion(DQuat::from_xyzw(0.0, 0.0, 0.0, 1.004987)).is_ok());
        let e = unit_quaternion(DQuat::from_xyzw(0.0, 0.0, 0.0, 1.005038)).unwrap_err();
        assert!(matches!(e, QuaternionError::NotUnit { .. }), "{e}");
        assert!(e.to_string().contains("not unit length"), "{e}");
        assert!(unit_quaternion(DQuat::from_xyzw(0.0, 0.0, 0.0, 0.995)).is_ok());
        assert!(unit_quaternion(DQuat::from_xyzw(0.0, 0.0, 0.0, 0.994)).is_err());
        assert!(unit_quaternion(DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0)).is_err());
        for bad in [f64::NAN, f64::INFINITY] {
            assert_eq!(
                unit_quaternion(DQuat::from_xyzw(bad, 0.0, 0.0, 1.0)),
                Err(QuaternionError::NotFinite)
            );
        }
    }
}
