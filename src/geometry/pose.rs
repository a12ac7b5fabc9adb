//! Rigid transforms, named `a_from_b`.

use glam::{DMat3, DQuat, DVec3};
use serde::{Deserialize, Serialize};

use super::GeometryError;

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

    /// From a quaternion that must be finite and of unit length (within 1e-3, as tf2 checks),
    /// and a finite translation. The quaternion is renormalised.
    pub fn from_quat_translation(
        frame: &str,
        rotation: DQuat,
        translation: DVec3,
    ) -> Result<Self, GeometryError> {
        let bad = |reason: &str| GeometryError::InvalidPose {
            frame: frame.to_string(),
            reason: reason.to_string(),
        };
        if !rotation.is_finite() {
            return Err(bad("quaternion has a NaN or infinite component"));
        }
        if !translation.is_finite() {
            return Err(bad("translation has a NaN or infinite component"));
        }
        let norm = rotation.length();
        if (norm - 1.0).abs() > 1e-3 {
            return Err(bad(&format!(
                "quaternion is not unit length (|q| = {norm})"
            )));
        }
        Ok(Self {
            rotation: rotation / norm,
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
}
