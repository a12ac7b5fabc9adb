//! Stage 1: hypothesis generators (the sweep). A hypothesis is a plane in the reference camera
//! frame; the depth of pixel ray r (z = 1) on plane n.X = e is z = e / (n . r). The cost stages
//! only see planes, so any plane family costs the same per hypothesis (the paper's generalized
//! sweep). Planes must be ordered so that neighbouring indices are neighbouring surfaces: the
//! sub-pixel step interpolates between plane k and k +- 1.

use glam::DVec3;

/// A plane `normal_in_ref . X = offset_m` in the reference camera frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    pub normal_in_ref: DVec3,
    pub offset_m: f64,
}

impl Plane {
    /// Depth (z, metres) where the z = 1 ray `ray_in_ref` meets the plane; `None` if never in front.
    pub fn depth_along(&self, ray_in_ref: DVec3) -> Option<f64> {
        let denom = self.normal_in_ref.dot(ray_in_ref);
        if denom.abs() < 1e-12 {
            return None;
        }
        let z = self.offset_m / denom;
        (z > 0.0).then_some(z)
    }

    pub fn to_gpu(&self) -> [f32; 4] {
        [
            self.normal_in_ref.x as f32,
            self.normal_in_ref.y as f32,
            self.normal_in_ref.z as f32,
            self.offset_m as f32,
        ]
    }
}

/// Anything that yields an ordered family of planes.
pub trait HypothesisGenerator {
    fn planes(&self) -> Vec<Plane>;
}

/// The default family: fronto-parallel planes z = d_k, uniform in inverse depth (= uniform in
/// disparity) from `max_depth_m` (k = 0) to `min_depth_m` (k = num_planes - 1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InverseDepthSweep {
    pub min_depth_m: f64,
    pub max_depth_m: f64,
    pub num_planes: u32,
}

impl InverseDepthSweep {
    pub fn depth_of(&self, k: u32) -> f64 {
        let near = 1.0 / self.min_depth_m;
        let far = 1.0 / self.max_depth_m;
        let steps = f64::from(self.num_planes.max(2) - 1);
        1.0 / (far + (near - far) * f64::from(k) / steps)
    }
}

impl HypothesisGenerator for InverseDepthSweep {
    fn planes(&self) -> Vec<Plane> {
        (0..self.num_planes)
            .map(|k| Plane {
                normal_in_ref: DVec3::Z,
                offset_m: self.depth_of(k),
            })
            .collect()
    }
}

/// A family of parallel planes with any normal (e.g. a ground plane sweep), offsets given in
/// order. `normal_in_ref` need not be the optical axis.
#[derive(Debug, Clone, PartialEq)]
pub struct PlaneFamily {
    pub normal_in_ref: DVec3,
    pub offsets_m: Vec<f64>,
}

impl HypothesisGenerator for PlaneFamily {
    fn planes(&self) -> Vec<Plane> {
        let n = self.normal_in_ref.normalize_or_zero();
        self.offsets_m
            .iter()
            .map(|&offset_m| Plane {
                normal_in_ref: n,
                offset_m,
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_depth_planes_are_uniform_in_disparity() {
        let sweep = InverseDepthSweep {
            min_depth_m: 1.0,
            max_depth_m: 4.0,
            num_planes: 4,
        };
        let planes = sweep.planes();
        assert_eq!(planes.len(), 4);
        assert!((planes[0].offset_m - 4.0).abs() < 1e-12);
        assert!((planes[3].offset_m - 1.0).abs() < 1e-12);
        let inv: Vec<f64> = planes.iter().map(|p| 1.0 / p.offset_m).collect();
        let step = inv[1] - inv[0];
        assert!((inv[2] - inv[1] - step).abs() < 1e-12 && (inv[3] - inv[2] - step).abs() < 1e-12);
    }

    #[test]
    fn tilted_plane_depth() {
        // Plane y = 1 (a floor 1 m below an optical frame with y down).
        let plane = Plane {
            normal_in_ref: DVec3::Y,
            offset_m: 1.0,
        };
        assert_eq!(plane.depth_along(DVec3::new(0.0, 0.5, 1.0)), Some(2.0));
        assert_eq!(plane.depth_along(DVec3::new(0.0, -0.5, 1.0)), None);
    }
}
