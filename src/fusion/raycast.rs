//! Ray casting the TSDF into a camera view (KinectFusion's surface prediction, Newcombe et
//! al., 2011): the z-depth of the fused surface at every pixel.
//!
//! Each pixel's ray is marched from `min_depth_m` to `max_depth_m` (along the optical axis).
//! Where the block holding the sample is not allocated the march jumps to where the ray leaves
//! that block (free space and unseen space hold no surface); through allocated blocks it steps
//! [`RAYCAST_STEP_FRACTION`] of the truncation distance and reads the trilinearly interpolated
//! TSDF of the eight voxel centres around the sample, all of which must have been observed. The
//! first crossing from positive (in front) to negative (behind) between two such samples is the
//! surface: its depth by linear interpolation of the two values, refined by one more sample at
//! that depth (regula falsi). A crossing from negative to positive (a surface seen from behind)
//! is not one; a ray with no crossing is NaN.

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use crate::geometry::{CameraModel, RigidTransform};
use crate::image::ImageF32;

use super::blocks::{Block, BlockIndex, Voxel, BLOCK_SIDE};
use super::{FusionError, FusionParams, VoxelBlockGrid};

/// The step through observed voxels, as a fraction of the truncation distance: the TSDF is
/// linear within the band, so a step of half of it finds every crossing of a surface seen from
/// the front and loses nothing to the step in the interpolation.
pub const RAYCAST_STEP_FRACTION: f64 = 0.5;

/// Ray-casts `grid` into the view of `model` at `world_from_cam` (the ROS optical frame in the
/// grid's world frame): the z-depth in metres of the first surface along each pixel's ray
/// within `[params.min_depth_m, params.max_depth_m]`, NaN where there is none. The truncation
/// distance of `params` sets the step; its voxel size must be the grid's.
pub fn raycast_depth(
    grid: &VoxelBlockGrid,
    params: &FusionParams,
    model: &CameraModel,
    world_from_cam: &RigidTransform,
) -> Result<ImageF32, FusionError> {
    let world_from_cam = super::check_view(
        grid.voxel_size_m(),
        params,
        model,
        world_from_cam,
        "ray-cast camera",
    )?;
    let (width, height) = (model.intrinsics.width_px, model.intrinsics.height_px);
    let caster = Caster {
        grid,
        inv_voxel: 1.0 / f64::from(grid.voxel_size_m()),
        step_m: RAYCAST_STEP_FRACTION * f64::from(params.truncation_m()),
        min_depth_m: f64::from(params.min_depth_m),
        max_depth_m: f64::from(params.max_depth_m),
    };
    let mut data = vec![f32::NAN; width as usize * height as usize];
    data.par_chunks_mut(width as usize)
        .enumerate()
        .for_each(|(row, out)| {
            for (col, depth) in out.iter_mut().enumerate() {
                let Some(ray) = model.unproject_z1(DVec2::new(col as f64, row as f64)) else {
                    continue;
                };
                let dir = world_from_cam.transform_vector(ray);
                if let Some(z) = caster.cast(world_from_cam.translation, dir) {
                    *depth = z as f32;
                }
            }
        });
    Ok(ImageF32 {
        width,
        height,
        data,
    })
}

/// One grid as the rays read it.
struct Caster<'a> {
    grid: &'a VoxelBlockGrid,
    inv_voxel: f64,
    step_m: f64,
    min_depth_m: f64,
    max_depth_m: f64,
}

/// Block look-ups of one ray, the last one remembered (the eight voxels around a sample, and
/// consecutive samples, are nearly always in the same block).
struct Lookup<'a> {
    grid: &'a VoxelBlockGrid,
    last: Option<(BlockIndex, Option<&'a Block>)>,
}

impl<'a> Lookup<'a> {
    fn block(&mut self, index: BlockIndex) -> Option<&'a Block> {
        match self.last {
            Some((last, block)) if last == index => block,
            _ => {
                let block = self.grid.block(index);
                self.last = Some((index, block));
                block
            }
        }
    }

    fn voxel(&mut self, voxel: [i64; 3]) -> Option<Voxel> {
        let index = BlockIndex::of_voxel(voxel);
        let block = self.block(index)?;
        let first = index.first_voxel();
        let [x, y, z] = [0, 1, 2].map(|a| (voxel[a] - first[a]) as usize);
        Some(block.voxel(x, y, z))
    }

    /// The trilinearly interpolated TSDF at a point in voxel coordinates (voxel centres at
    /// integers); `None` unless all eight voxels around it were observed.
    fn tsdf(&mut self, q: DVec3) -> Option<f64> {
        let base = q.floor();
        let f = q - base;
        let b = [base.x as i64, base.y as i64, base.z as i64];
        let mut value = 0.0;
        for corner in 0..8 {
            let (dx, dy, dz) = (corner & 1, (corner >> 1) & 1, (corner >> 2) & 1);
            let v = self.voxel([b[0] + dx, b[1] + dy, b[2] + dz])?;
            if !v.is_observed() {
                return None;
            }
            let w = |d: i64, t: f64| if d == 1 { t } else { 1.0 - t };
            value += f64::from(v.tsdf) * w(dx, f.x) * w(dy, f.y) * w(dz, f.z);
        }
        Some(value)
    }
}

impl Caster<'_> {
    /// The ray parameter (z-depth, for a `dir` that is the world image of a z = 1 ray) of the
    /// first surface along `origin + t dir`, if any.
    fn cast(&self, origin: DVec3, dir: DVec3) -> Option<f64> {
        let length = dir.length();
        if !length.is_finite() || length <= 0.0 {
            return None;
        }
        let dt = self.step_m / length;
        // In voxel coordinates.
        let (o, d) = (origin * self.inv_voxel, dir * self.inv_voxel);
        let at = |t: f64| o + d * t;
        let side = BLOCK_SIDE as f64;
        let mut lookup = Lookup {
            grid: self.grid,
            last: None,
        };
        let mut t = self.min_depth_m;
        // The last observed sample: (t, tsdf).
        let mut previous: Option<(f64, f64)> = None;
        while t <= self.max_depth_m {
            let q = at(t);
            let voxel = [q.x, q.y, q.z].map(|v| v.floor() as i64);
            let index = BlockIndex::of_voxel(voxel);
            if lookup.block(index).is_none() {
                // Jump to where the ray leaves this block (the floor of the sample is in it for
                // voxel coordinates in [8b, 8b + 8) per axis).
                let lo = index.0.map(|b| f64::from(b) * side);
                let mut exit = f64::INFINITY;
                for (a, (qa, da)) in [(o.x, d.x), (o.y, d.y), (o.z, d.z)].into_iter().enumerate() {
                    if da > 0.0 {
                        exit = exit.min((lo[a] + side - qa) / da);
                    } else if da < 0.0 {
                        exit = exit.min((lo[a] - qa) / da);
                    }
                }
                // A nudge past the boundary, at least a thousandth of a voxel along the ray.
                t = exit.max(t) + 1e-3 / d.length();
                previous = None;
                continue;
            }
            match lookup.tsdf(q) {
                None => previous = None,
                Some(value) => {
                    if let Some((tp, vp)) = previous {
                        if vp > 0.0 && value <= 0.0 {
                            return Some(refine(&mut lookup, &at, (tp, vp), (t, value)));
                        }
                    }
                    previous = Some((t, value));
                }
            }
            t += dt;
        }
        None
    }
}

/// The zero crossing between a positive sample `a` and a non-positive one `b`: linear
/// interpolation, then once more within the half-bracket that holds the crossing.
fn refine(
    lookup: &mut Lookup<'_>,
    at: &impl Fn(f64) -> DVec3,
    a: (f64, f64),
    b: (f64, f64),
) -> f64 {
    let cross = |(ta, va): (f64, f64), (tb, vb): (f64, f64)| {
        if va - vb > 0.0 {
            ta + (tb - ta) * va / (va - vb)
        } else {
            tb
        }
    };
    let t = cross(a, b);
    match lookup.tsdf(at(t)) {
        Some(v) if v > 0.0 => cross((t, v), b),
        Some(v) if v < 0.0 => cross(a, (t, v)),
        _ => t,
    }
}

#[cfg(test)]
mod tests {
    use glam::{DQuat, DVec3};

    use super::*;
    use crate::fusion::integrate;
    use crate::fusion::test_scenes::{camera, look_at, render_plane, render_sphere};
    use crate::geometry::Distortion;

    /// Median of |a - b| over pixels where both are finite, and the share of `truth`'s finite
    /// pixels where `a` is finite too.
    fn compare(a: &ImageF32, truth: &ImageF32) -> (f64, f64) {
        let mut errors = Vec::new();
        let mut truth_px = 0;
        for (x, t) in a.data.iter().zip(&truth.data) {
            if t.is_finite() {
                truth_px += 1;
                if x.is_finite() {
                    errors.push(f64::from((x - t).abs()));
                }
            }
        }
        errors.sort_by(f64::total_cmp);
        let median = errors.get(errors.len() / 2).copied().unwrap_or(f64::NAN);
        (median, errors.len() as f64 / f64::from(truth_px.max(1)))
    }

    #[test]
    fn a_sphere_seen_from_six_sides_comes_back_in_a_new_view() {
        let params = FusionParams {
            voxel_size_m: 0.02,
            ..FusionParams::default()
        };
        let model = camera(160, 120, 150.0);
        let centre = DVec3::new(0.2, -0.1, 3.0);
        let radius = 0.5;
        let mut grid = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
        for eye in [
            DVec3::new(0.0, 0.0, -2.0),
            DVec3::new(2.0, 0.0, 0.0),
            DVec3::new(-2.0, 0.0, 0.0),
            DVec3::new(0.0, 2.0, 0.0),
            DVec3::new(0.0, -2.0, 0.0),
            DVec3::new(0.0, 0.0, 2.0),
        ] {
            let pose = look_at(centre + eye, centre, DVec3::new(0.3, 1.0, 0.1));
            let depth = render_sphere(&model, &pose, centre, radius);
            integrate(&mut grid, &params, &depth, None, &model, &pose).unwrap();
        }
        // A view between the integrated ones.
        let pose = look_at(
            centre + DVec3::new(1.2, -0.8, -1.3),
            centre,
            DVec3::new(0.0, 1.0, 0.0),
        );
        let truth = render_sphere(&model, &pose, centre, radius);
        let cast = raycast_depth(&grid, &params, &model, &pose).unwrap();
        let (median, coverage) = compare(&cast, &truth);
        assert!(median < 0.1 * 0.02, "median error {median} m");
        // All but a rim at the silhouette, where the ray grazes voxels not all observed.
        assert!(coverage > 0.95, "coverage {coverage}");
        // Nothing where the sphere is not (beyond its silhouette, a voxel of slack).
        let outside = cast
            .data
            .iter()
            .zip(&truth.data)
            .filter(|(c, t)| c.is_finite() && !t.is_finite())
            .count();
        let silhouette = truth.data.iter().filter(|t| t.is_finite()).count();
        assert!(outside * 20 < silhouette, "{outside} pixels off the sphere");
        // Nearly every depth lies within a voxel of the sphere.
        let far_off = cast
            .data
            .iter()
            .zip(&truth.data)
            .filter(|(c, t)| c.is_finite() && t.is_finite() && (*c - *t).abs() > 0.02)
            .count();
        assert!(
            far_off * 100 < silhouette,
            "{far_off} pixels off by a voxel"
        );
    }

    #[test]
    fn a_tilted_wall_behind_empty_blocks_is_found_at_its_depth() {
        // A wall tilted 30 degrees, integrated from one view; the ray cast from another pose
        // crosses several metres of unallocated space first.
        let params = FusionParams {
            voxel_size_m: 0.04,
            ..FusionParams::default()
        };
        let model = camera(120, 90, 100.0);
        let normal = DVec3::new(
            0.0,
            -(30f64.to_radians().sin()),
            -(30f64.to_radians().cos()),
        );
        let offset = normal.dot(DVec3::new(0.0, 0.0, 6.0));
        let mut grid = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
        let pose = RigidTransform::IDENTITY;
        let depth = render_plane(&model, &pose, normal, offset);
        for _ in 0..2 {
            integrate(&mut grid, &params, &depth, None, &model, &pose).unwrap();
        }
        let other = RigidTransform {
            rotation: DQuat::from_rotation_y(0.05),
            translation: DVec3::new(0.1, -0.05, 0.3),
        };
        let truth = render_plane(&model, &other, normal, offset);
        let cast = raycast_depth(&grid, &params, &model, &other).unwrap();
        let (median, coverage) = compare(&cast, &truth);
        assert!(median < 0.05 * 0.04, "median error {median} m");
        // The other view sees a little beyond the first one's edges.
        assert!(coverage > 0.85, "coverage {coverage}");
        // Beyond max depth, nothing.
        let near_only = FusionParams {
            max_depth_m: 4.0,
            ..params
        };
        let cast = raycast_depth(&grid, &near_only, &model, &other).unwrap();
        assert!(cast.data.iter().all(|d| d.is_nan()));
    }

    #[test]
    fn per_pixel_weights_weigh_the_running_average() {
        // A wall at 3.0 m with weight 1 and at 3.04 m with weight 3 (both within the
        // truncation band of each other): the surface comes back at their weighted mean,
        // 3.03 m; a weight of 0 (or NaN) adds nothing.
        let params = FusionParams {
            voxel_size_m: 0.02,
            truncation_voxels: 6.0,
            ..FusionParams::default()
        };
        let model = camera(80, 60, 70.0);
        let pose = RigidTransform::IDENTITY;
        let weights = |w: f32| ImageF32 {
            width: 80,
            height: 60,
            data: vec![w; 80 * 60],
        };
        let mut grid = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
        let near = render_plane(&model, &pose, DVec3::Z, 3.0);
        let far = render_plane(&model, &pose, DVec3::Z, 3.04);
        let integrate_with = |grid: &mut VoxelBlockGrid, depth: &ImageF32, w: f32| {
            crate::fusion::integrate_weighted(
                grid,
                &params,
                depth,
                Some(&weights(w)),
                None,
                &model,
                &pose,
            )
            .unwrap()
        };
        integrate_with(&mut grid, &near, 1.0);
        integrate_with(&mut grid, &far, 3.0);
        integrate_with(&mut grid, &near, 0.0);
        integrate_with(&mut grid, &near, f32::NAN);
        let cast = raycast_depth(&grid, &params, &model, &pose).unwrap();
        let centre = cast.get(40, 30);
        assert!((centre - 3.03).abs() < 2e-3, "{centre}");
        let small = ImageF32 {
            width: 8,
            height: 6,
            data: vec![1.0; 48],
        };
        assert!(matches!(
            crate::fusion::integrate_weighted(
                &mut grid,
                &params,
                &near,
                Some(&small),
                None,
                &model,
                &pose
            ),
            Err(FusionError::ImageSize {
                what: "weight image",
                ..
            })
        ));
    }

    #[test]
    fn a_distorted_view_an_empty_grid_and_bad_input() {
        let params = FusionParams::default();
        let mut model = camera(80, 60, 70.0);
        model.distortion = Distortion::PlumbBob {
            k1: -0.1,
            k2: 0.01,
            p1: 0.0,
            p2: 0.0,
            k3: 0.0,
        };
        let pose = RigidTransform::IDENTITY;
        let mut grid = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
        let empty = raycast_depth(&grid, &params, &model, &pose).unwrap();
        assert_eq!((empty.width, empty.height), (80, 60));
        assert!(empty.data.iter().all(|d| d.is_nan()));
        let depth = render_plane(&model, &pose, DVec3::Z, 3.0);
        integrate(&mut grid, &params, &depth, None, &model, &pose).unwrap();
        let cast = raycast_depth(&grid, &params, &model, &pose).unwrap();
        let (median, coverage) = compare(&cast, &depth);
        assert!(median < 1e-3, "median error {median} m");
        assert!(coverage > 0.95, "coverage {coverage}");
        let other = FusionParams {
            voxel_size_m: 0.1,
            ..params
        };
        assert!(matches!(
            raycast_depth(&grid, &other, &model, &pose),
            Err(FusionError::VoxelSizeMismatch { .. })
        ));
        let bad_pose = RigidTransform {
            translation: DVec3::new(f64::NAN, 0.0, 0.0),
            ..pose
        };
        assert!(matches!(
            raycast_depth(&grid, &params, &model, &bad_pose),
            Err(FusionError::Pose(_))
        ));
        let mut no_focal = model;
        no_focal.intrinsics.fx_px = 0.0;
        assert!(matches!(
            raycast_depth(&grid, &params, &no_focal, &pose),
            Err(FusionError::Camera(_))
        ));
    }
}
