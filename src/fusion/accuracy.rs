//! How well a fused model matches the ground truth (issue 28's accuracy bar), measured in the
//! views that made it.
//!
//! - Depth: per view, the ground-truth depth, the depth map that went into the fusion and the
//!   fused model ray-cast into the same view ([`super::raycast_depth`]). Over the pixels where
//!   the ground truth and the depth map are both valid (pooled over all views): the depth
//!   maps' median absolute error; the share of them where the ray cast has a surface too (the
//!   coverage); over those covered pixels, the fused model's median absolute error (and the
//!   depth maps' own, on the same pixels, for a like-for-like reading).
//! - Mesh: the share of the mesh's vertices within a given number of voxels of the true
//!   surface, by a distance function the caller knows (an analytic scene's exact distance).

use glam::DVec3;
use rayon::prelude::*;

use crate::geometry::{CameraModel, RigidTransform};
use crate::image::ImageF32;

use super::{raycast_depth, FusionError, FusionParams, VoxelBlockGrid};

/// The depth errors of the views added so far ([`DepthAccuracy::add_view`]).
#[derive(Debug, Clone, Default)]
pub struct DepthAccuracy {
    views: usize,
    truth_px: usize,
    /// |depth map - truth| where both are valid.
    depth_map_errors: Vec<f32>,
    /// |fused - truth| where truth, depth map and fused depth are valid.
    fused_errors: Vec<f32>,
    /// |depth map - truth| on the pixels of `fused_errors`.
    depth_map_errors_covered: Vec<f32>,
}

/// What [`DepthAccuracy::summary`] reports. Errors in metres; NaN where there is no pixel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthAccuracySummary {
    pub views: usize,
    /// Pixels with ground truth.
    pub truth_px: usize,
    /// Pixels with ground truth and a depth-map depth.
    pub depth_map_px: usize,
    /// Those of `depth_map_px` where the fused model has a surface too.
    pub covered_px: usize,
    /// Median |depth map - truth| over `depth_map_px`.
    pub depth_maps_median_abs_m: f64,
    /// Median |fused - truth| over `covered_px`.
    pub fused_median_abs_m: f64,
    /// Median |depth map - truth| over `covered_px`.
    pub depth_maps_median_abs_covered_m: f64,
}

impl DepthAccuracySummary {
    /// `covered_px / depth_map_px` (0 without pixels).
    pub fn coverage(&self) -> f64 {
        if self.depth_map_px == 0 {
            0.0
        } else {
            self.covered_px as f64 / self.depth_map_px as f64
        }
    }

    /// The fused model's median error over the depth maps' (the bar: at most 0.7).
    pub fn ratio(&self) -> f64 {
        self.fused_median_abs_m / self.depth_maps_median_abs_m
    }
}

fn valid(depth_m: f32) -> bool {
    depth_m.is_finite() && depth_m > 0.0
}

fn median(values: &mut [f32]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mid = values.len() / 2;
    let (_, m, _) = values.select_nth_unstable_by(mid, f32::total_cmp);
    f64::from(*m)
}

impl DepthAccuracy {
    pub fn new() -> Self {
        Self::default()
    }

    /// One view: its ground truth, the depth map that was fused and the fused model's depth in
    /// the same view (all z-depths in metres, NaN or non-positive where invalid, same size).
    pub fn add_view(
        &mut self,
        truth: &ImageF32,
        depth_map: &ImageF32,
        fused: &ImageF32,
    ) -> Result<(), FusionError> {
        let (width, height) = (truth.width, truth.height);
        for (what, image) in [("depth map", depth_map), ("fused depth", fused)] {
            if image.width != width || image.height != height {
                return Err(FusionError::ImageSize {
                    what,
                    got_width: image.width,
                    got_height: image.height,
                    width,
                    height,
                });
            }
        }
        let pixels = width as usize * height as usize;
        if [truth, depth_map, fused]
            .iter()
            .any(|image| image.data.len() != pixels)
        {
            return Err(FusionError::Camera(format!(
                "an image of {width}x{height} does not hold {pixels} values"
            )));
        }
        self.views += 1;
        for ((&t, &d), &f) in truth.data.iter().zip(&depth_map.data).zip(&fused.data) {
            if !valid(t) {
                continue;
            }
            self.truth_px += 1;
            if !valid(d) {
                continue;
            }
            let depth_error = (d - t).abs();
            self.depth_map_errors.push(depth_error);
            if valid(f) {
                self.fused_errors.push((f - t).abs());
                self.depth_map_errors_covered.push(depth_error);
            }
        }
        Ok(())
    }

    /// [`Self::add_view`] with the fused model ray-cast into the view of `model` at
    /// `world_from_cam` ([`raycast_depth`] with `params`); returns the ray-cast depth.
    pub fn add_fused_view(
        &mut self,
        grid: &VoxelBlockGrid,
        params: &FusionParams,
        model: &CameraModel,
        world_from_cam: &RigidTransform,
        truth: &ImageF32,
        depth_map: &ImageF32,
    ) -> Result<ImageF32, FusionError> {
        let fused = raycast_depth(grid, params, model, world_from_cam)?;
        self.add_view(truth, depth_map, &fused)?;
        Ok(fused)
    }

    /// The medians and counts so far.
    pub fn summary(&self) -> DepthAccuracySummary {
        DepthAccuracySummary {
            views: self.views,
            truth_px: self.truth_px,
            depth_map_px: self.depth_map_errors.len(),
            covered_px: self.fused_errors.len(),
            depth_maps_median_abs_m: median(&mut self.depth_map_errors.clone()),
            fused_median_abs_m: median(&mut self.fused_errors.clone()),
            depth_maps_median_abs_covered_m: median(&mut self.depth_map_errors_covered.clone()),
        }
    }
}

/// How close a mesh's vertices lie to the true surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VertexAccuracy {
    pub vertices: usize,
    /// Vertices within `limit_voxels` of the surface.
    pub within: usize,
    pub limit_voxels: f64,
    /// The median distance in voxels (NaN without vertices).
    pub median_voxels: f64,
}

impl VertexAccuracy {
    /// `within / vertices` (0 without vertices).
    pub fn fraction(&self) -> f64 {
        if self.vertices == 0 {
            0.0
        } else {
            self.within as f64 / self.vertices as f64
        }
    }
}

/// The share of `vertices` (world frame, metres) within `limit_voxels` voxels of
/// `voxel_size_m` of the true surface, whose distance from a point `distance_m` gives (`None`:
/// unknown, counted as not within).
pub fn vertex_accuracy(
    vertices: &[[f32; 3]],
    voxel_size_m: f32,
    limit_voxels: f64,
    distance_m: impl Fn(DVec3) -> Option<f64> + Sync,
) -> VertexAccuracy {
    let voxel = f64::from(voxel_size_m);
    let mut distances: Vec<f32> = vertices
        .par_iter()
        .map(|v| {
            let p = DVec3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]));
            distance_m(p).map_or(f32::INFINITY, |d| (d.abs() / voxel) as f32)
        })
        .collect();
    let within = distances
        .iter()
        .filter(|&&d| f64::from(d) <= limit_voxels)
        .count();
    VertexAccuracy {
        vertices: vertices.len(),
        within,
        limit_voxels,
        median_voxels: median(&mut distances),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn img(data: Vec<f32>) -> ImageF32 {
        ImageF32 {
            width: data.len() as u32,
            height: 1,
            data,
        }
    }

    #[test]
    fn depth_accuracy_by_hand() {
        let nan = f32::NAN;
        // Truth 2 m but pixel 5 (unknown). Depth map errors 0.1, 0.2, 0.3, -, 0.05, (no truth).
        // Fused errors 0.01, -, 0.02, 0.5 (no depth map: not counted), 0.04.
        let truth = img(vec![2.0, 2.0, 2.0, 2.0, 2.0, nan]);
        let depth = img(vec![2.1, 1.8, 2.3, nan, 2.05, 1.0]);
        let fused = img(vec![2.01, nan, 1.98, 2.5, 2.04, 1.0]);
        let mut acc = DepthAccuracy::new();
        acc.add_view(&truth, &depth, &fused).unwrap();
        let s = acc.summary();
        assert_eq!(
            (s.views, s.truth_px, s.depth_map_px, s.covered_px),
            (1, 5, 4, 3)
        );
        assert!((s.coverage() - 0.75).abs() < 1e-12);
        // Medians (upper for even counts): of 0.1, 0.2, 0.3, 0.05 -> 0.2; of 0.01, 0.02, 0.04
        // -> 0.02; the depth map on the covered pixels: 0.1, 0.3, 0.05 -> 0.1.
        assert!((s.depth_maps_median_abs_m - 0.2).abs() < 1e-6, "{s:?}");
        assert!((s.fused_median_abs_m - 0.02).abs() < 1e-6, "{s:?}");
        assert!(
            (s.depth_maps_median_abs_covered_m - 0.1).abs() < 1e-6,
            "{s:?}"
        );
        assert!((s.ratio() - 0.1).abs() < 1e-5);
        let small = img(vec![1.0]);
        assert!(matches!(
            acc.add_view(&truth, &small, &fused),
            Err(FusionError::ImageSize { .. })
        ));
        let empty = DepthAccuracy::new().summary();
        assert!(empty.fused_median_abs_m.is_nan() && empty.coverage() == 0.0);
    }

    #[test]
    fn vertex_accuracy_counts_vertices_near_a_plane() {
        // The plane z = 1; voxels of 0.1 m; within 2 voxels: |z - 1| <= 0.2.
        let vertices = [
            [0.0, 0.0, 1.05],
            [1.0, 2.0, 0.85],
            [0.0, 0.0, 1.3],
            [5.0, 5.0, 1.0],
        ];
        let acc = vertex_accuracy(&vertices, 0.1, 2.0, |p| (p.x < 4.0).then_some(p.z - 1.0));
        assert_eq!((acc.vertices, acc.within), (4, 2));
        assert!((acc.fraction() - 0.5).abs() < 1e-12);
        // Distances 0.5, 1.5, 3, inf voxels: the upper median is 3.
        assert!((acc.median_voxels - 3.0).abs() < 1e-5, "{acc:?}");
    }
}
