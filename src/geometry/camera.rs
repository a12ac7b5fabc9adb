//! Pinhole intrinsics and the camera model (intrinsics + distortion): pixels <-> rays.

use glam::{DMat3, DVec2, DVec3};
use serde::{Deserialize, Serialize};

use super::{Distortion, GeometryError};

/// Pinhole intrinsics of one image, in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PinholeIntrinsics {
    pub width_px: u32,
    pub height_px: u32,
    pub fx_px: f64,
    pub fy_px: f64,
    pub cx_px: f64,
    pub cy_px: f64,
}

impl PinholeIntrinsics {
    pub fn k_matrix(&self) -> DMat3 {
        DMat3::from_cols(
            DVec3::new(self.fx_px, 0.0, 0.0),
            DVec3::new(0.0, self.fy_px, 0.0),
            DVec3::new(self.cx_px, self.cy_px, 1.0),
        )
    }

    /// Ray through pixel `(u, v)` with z = 1 (no distortion).
    pub fn unproject_z1(&self, pixel: DVec2) -> DVec3 {
        DVec3::new(
            (pixel.x - self.cx_px) / self.fx_px,
            (pixel.y - self.cy_px) / self.fy_px,
            1.0,
        )
    }

    /// Scales the image by `factor` (pixel centres stay pixel centres).
    pub fn scaled(&self, factor: f64, width_px: u32, height_px: u32) -> Self {
        Self {
            width_px,
            height_px,
            fx_px: self.fx_px * factor,
            fy_px: self.fy_px * factor,
            cx_px: (self.cx_px + 0.5) * factor - 0.5,
            cy_px: (self.cy_px + 0.5) * factor - 0.5,
        }
    }

    pub fn validate(&self, camera: &str) -> Result<(), GeometryError> {
        let bad = |reason: &str| GeometryError::InvalidIntrinsics {
            camera: camera.to_string(),
            reason: reason.to_string(),
        };
        if self.width_px == 0 || self.height_px == 0 {
            return Err(bad("image size is zero"));
        }
        for (name, v) in [
            ("fx", self.fx_px),
            ("fy", self.fy_px),
            ("cx", self.cx_px),
            ("cy", self.cy_px),
        ] {
            if !v.is_finite() {
                return Err(bad(&format!("{name} is not finite")));
            }
        }
        if self.fx_px == 0.0 || self.fy_px == 0.0 {
            return Err(bad("focal length is zero (K and P are empty?)"));
        }
        Ok(())
    }
}
/// Intrinsics plus distortion: everything needed to go between pixels and camera-frame rays.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CameraModel {
    pub intrinsics: PinholeIntrinsics,
    #[serde(default)]
    pub distortion: Distortion,
}

impl CameraModel {
    pub fn pinhole(intrinsics: PinholeIntrinsics) -> Self {
        Self {
            intrinsics,
            distortion: Distortion::None,
        }
    }

    /// Projects a point in this camera's frame to a pixel; `None` if it is not in front.
    pub fn project(&self, point_in_cam: DVec3) -> Option<DVec2> {
        if point_in_cam.z <= 1e-9 {
            return None;
        }
        let normalised = DVec2::new(
            point_in_cam.x / point_in_cam.z,
            point_in_cam.y / point_in_cam.z,
        );
        let d = self.distortion.distort(normalised);
        let k = &self.intrinsics;
        Some(DVec2::new(k.fx_px * d.x + k.cx_px, k.fy_px * d.y + k.cy_px))
    }

    /// The ray through a pixel, scaled to z = 1, in this camera's frame.
    pub fn unproject_z1(&self, pixel: DVec2) -> DVec3 {
        let k = &self.intrinsics;
        let distorted = DVec2::new((pixel.x - k.cx_px) / k.fx_px, (pixel.y - k.cy_px) / k.fy_px);
        let p = self.distortion.undistort(distorted);
        DVec3::new(p.x, p.y, 1.0)
    }

    pub fn contains(&self, pixel: DVec2) -> bool {
        let k = &self.intrinsics;
        pixel.x >= -0.5
            && pixel.y >= -0.5
            && pixel.x <= f64::from(k.width_px) - 0.5
            && pixel.y <= f64::from(k.height_px) - 0.5
    }
}
