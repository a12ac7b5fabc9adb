//! Pinhole intrinsics and the camera model (intrinsics + distortion): pixels <-> rays.

use std::sync::{Arc, Mutex};

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
/// How many distorted models' pixel rays [`CameraModel::distorted_pixel_rays`] keeps: a reference at its
/// coarse-to-fine levels (32 bytes a pixel: 9.8 MB for 640x480).
pub const RAY_GRIDS: usize = 4;

/// A distorted model and the rays of its pixels.
type RayGrid = (CameraModel, Arc<Vec<Option<DVec3>>>);

static RAY_GRID_CACHE: Mutex<Vec<RayGrid>> = Mutex::new(Vec::new());

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

    /// Projects a point in this camera's frame to a pixel (OpenCV's `projectPoints` /
    /// `fisheye::projectPoints`); `None` if it is not in front, or lies past the distortion
    /// model's fold (where the model would wrongly bring it back into the image).
    pub fn project(&self, point_in_cam: DVec3) -> Option<DVec2> {
        self.project_within(point_in_cam, self.distortion.max_undistorted_radius())
    }

    /// [`Self::project`] with the model's [`Distortion::max_undistorted_radius`] given, for a
    /// caller that projects many points (the radius is a search, kept per thread: a lookup per
    /// call otherwise).
    pub fn project_within(
        &self,
        point_in_cam: DVec3,
        max_undistorted_radius: f64,
    ) -> Option<DVec2> {
        // (NaN fails the test too.)
        if point_in_cam.z.is_nan() || point_in_cam.z <= 1e-9 {
            return None;
        }
        let normalised = DVec2::new(
            point_in_cam.x / point_in_cam.z,
            point_in_cam.y / point_in_cam.z,
        );
        let r = normalised.length();
        if r.is_nan() || r > max_undistorted_radius {
            return None;
        }
        let d = self.distortion.distort(normalised);
        let k = &self.intrinsics;
        Some(DVec2::new(k.fx_px * d.x + k.cx_px, k.fy_px * d.y + k.cy_px))
    }

    /// The ray through a pixel, scaled to z = 1, in this camera's frame; `None` when the pixel
    /// has no ray in front of the camera (a fisheye pixel beyond 90 degrees, or one past the
    /// distortion model's fold). Exact to the last bits of an f64 wherever the model is
    /// defined ([`Distortion::undistort`]).
    pub fn unproject_z1(&self, pixel: DVec2) -> Option<DVec3> {
        let k = &self.intrinsics;
        let distorted = DVec2::new((pixel.x - k.cx_px) / k.fx_px, (pixel.y - k.cy_px) / k.fy_px);
        let p = self.distortion.undistort(distorted)?;
        Some(DVec3::new(p.x, p.y, 1.0))
    }

    /// Checks the intrinsics ([`PinholeIntrinsics::validate`]), that the distortion
    /// coefficients are finite, and that the distortion model does not fold over inside the
    /// image (pixels there would have two rays, or none, and every ray past the fold would
    /// project back into the image): the image's corners (pixel edges) must lie within the
    /// fold's distorted radius.
    pub fn validate(&self, camera: &str) -> Result<(), GeometryError> {
        self.intrinsics.validate(camera)?;
        let coefficients = self.distortion.coefficients();
        if let Some((i, v)) = coefficients
            .iter()
            .enumerate()
            .find(|(_, v)| !v.is_finite())
        {
            return Err(GeometryError::InvalidIntrinsics {
                camera: camera.to_string(),
                reason: format!("distortion coefficient {i} is {v}"),
            });
        }
        if let Some(fold) = self.distortion.fold() {
            let reach = self.max_normalised_radius();
            if reach > fold.distorted_radius {
                return Err(GeometryError::DistortionFolds {
                    camera: camera.to_string(),
                    model: self.distortion.name(),
                    coefficients,
                    fold_deg: fold.angle_rad.to_degrees(),
                    fold_radius: fold.distorted_radius,
                    image_radius: reach,
                });
            }
        }
        Ok(())
    }

    /// The largest distorted normalised radius the image reaches (at a corner's outer edge).
    pub fn max_normalised_radius(&self) -> f64 {
        let k = &self.intrinsics;
        let xs = [-0.5, f64::from(k.width_px) - 0.5];
        let ys = [-0.5, f64::from(k.height_px) - 0.5];
        xs.iter()
            .flat_map(|&x| ys.iter().map(move |&y| (x, y)))
            .map(|(x, y)| DVec2::new((x - k.cx_px) / k.fx_px, (y - k.cy_px) / k.fy_px).length())
            .fold(0.0, f64::max)
    }

    pub fn contains(&self, pixel: DVec2) -> bool {
        let k = &self.intrinsics;
        pixel.x >= -0.5
            && pixel.y >= -0.5
            && pixel.x <= f64::from(k.width_px) - 0.5
            && pixel.y <= f64::from(k.height_px) - 0.5
    }

    /// The ray of every pixel of a distorted model ([`Self::unproject_z1`], row-major), shared:
    /// its unprojection is a Newton solve per pixel (~0.3 ms per thousand pixels), and the point
    /// cloud of every set and the plan of every pose of a moving rig need all of them again, so
    /// the grids of the last [`RAY_GRIDS`] distorted models are kept (the same values). `None`
    /// for a model without distortion: its unprojection is a multiply-add, cheaper than a grid,
    /// so the caller unprojects its pixels itself.
    pub fn distorted_pixel_rays(&self) -> Option<Arc<Vec<Option<DVec3>>>> {
        if self.distortion.is_none() {
            return None;
        }
        let mut grids = RAY_GRID_CACHE
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some((_, rays)) = grids.iter().find(|(m, _)| m == self) {
            return Some(Arc::clone(rays));
        }
        let (w, h) = (self.intrinsics.width_px, self.intrinsics.height_px);
        let rays: Arc<Vec<Option<DVec3>>> = Arc::new(
            (0..h)
                .flat_map(|y| (0..w).map(move |x| (x, y)))
                .map(|(x, y)| self.unproject_z1(DVec2::new(f64::from(x), f64::from(y))))
                .collect(),
        );
        if grids.len() == RAY_GRIDS {
            grids.pop();
        }
        grids.insert(0, (*self, Arc::clone(&rays)));
        Some(rays)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model(fx: f64, distortion: Distortion) -> CameraModel {
        CameraModel {
            intrinsics: PinholeIntrinsics {
                width_px: 640,
                height_px: 480,
                fx_px: fx,
                fy_px: fx,
                cx_px: 319.5,
                cy_px: 239.5,
            },
            distortion,
        }
    }

    #[test]
    fn a_model_that_folds_inside_the_image_is_refused() {
        // Barrel k1 = -0.3 folds at r = 1.054 (46.5 degrees), distorted radius 0.703.
        let barrel = Distortion::PlumbBob {
            k1: -0.3,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
            k3: 0.0,
        };
        // fx = 500: the corners reach 0.8 > 0.703.
        let e = model(500.0, barrel).validate("cam3").unwrap_err();
        assert!(matches!(e, GeometryError::DistortionFolds { .. }), "{e}");
        let text = e.to_string();
        assert!(
            text.contains("cam3") && text.contains("folds over 46.5 degrees"),
            "{text}"
        );
        // fx = 800: the corners reach 0.5: valid; every pixel has a ray, and a point past the
        // fold does not project.
        let m = model(800.0, barrel);
        m.validate("cam3").unwrap();
        for pixel in [DVec2::new(-0.5, -0.5), DVec2::new(639.5, 479.5)] {
            let ray = m.unproject_z1(pixel).unwrap();
            let back = m.project(ray).unwrap();
            assert!((back - pixel).length() < 1e-9, "{back} vs {pixel}");
        }
        assert!(m.project(DVec3::new(1.2, 0.0, 1.0)).is_none());
        assert!(m.project(DVec3::new(1.0, 0.0, 1.0)).is_some());
    }

    #[test]
    fn non_finite_distortion_is_refused() {
        let d = Distortion::Equidistant {
            k1: f64::NAN,
            k2: 0.0,
            k3: 0.0,
            k4: 0.0,
        };
        let e = model(500.0, d).validate("c").unwrap_err();
        assert!(
            e.to_string().contains("distortion coefficient 0 is NaN"),
            "{e}"
        );
    }

    #[test]
    fn distorted_pixel_rays_are_the_unprojections_and_kept_per_model() {
        let model = |k1: f64| CameraModel {
            intrinsics: PinholeIntrinsics {
                width_px: 40,
                height_px: 30,
                fx_px: 30.0,
                fy_px: 30.0,
                cx_px: 19.5,
                cy_px: 14.5,
            },
            distortion: Distortion::PlumbBob {
                k1,
                k2: 0.01,
                p1: 0.001,
                p2: 0.0,
                k3: 0.0,
            },
        };
        // More models than are kept, each asked twice in turn.
        let models: Vec<CameraModel> = (0..RAY_GRIDS + 2)
            .map(|i| model(-0.02 * i as f64))
            .collect();
        for _ in 0..2 {
            for m in &models {
                let rays = m.distorted_pixel_rays().expect("a distorted model's grid");
                assert_eq!(rays.len(), 40 * 30);
                for (i, ray) in rays.iter().enumerate() {
                    let pixel = DVec2::new((i % 40) as f64, (i / 40) as f64);
                    assert_eq!(*ray, m.unproject_z1(pixel), "{m:?} pixel {pixel}");
                }
            }
        }
        // The same model gives the kept grid, not a new one.
        let m = &models[models.len() - 1];
        let grid = || m.distorted_pixel_rays().expect("grid");
        assert!(Arc::ptr_eq(&grid(), &grid()));
        let first = |m: &CameraModel| m.distorted_pixel_rays().expect("grid")[0];
        assert_ne!(first(&models[0]), first(&models[1]));
        // Without distortion the caller unprojects (no grid).
        let pinhole = CameraModel::pinhole(models[0].intrinsics);
        assert!(pinhole.distorted_pixel_rays().is_none());
    }
}
