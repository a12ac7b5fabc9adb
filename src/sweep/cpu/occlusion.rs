//! Twins of `shaders/splat.wgsl` and `shaders/visibility.wgsl`.

use super::common::*;
use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

fn ref_point(plan: &SweepPlan, pix: usize, depth: f32) -> Vec3 {
    let r = xyz(plan.rays[pix]);
    [r[0] * depth, r[1] * depth, r[2] * depth]
}

/// Index of the nearest texel of camera `cam` to the projection, if inside and in front.
fn nearest_texel(cam: &GpuCamera, projected: Vec3) -> Option<usize> {
    let texel = [(projected[0] + 0.5).floor(), (projected[1] + 0.5).floor()];
    if projected[2] <= 0.0 || !inside(cam, texel) {
        return None;
    }
    Some((cam.size[2] + texel[1] as u32 * cam.size[0] + texel[0] as u32) as usize)
}

pub fn splat(plan: &SweepPlan, maps: &[f32], zbuffer: &mut [u32]) {
    let npix = plan.pixel_count();
    let ref_index = plan.params.reference;
    for pix in 0..npix {
        let depth = maps[MAP_DEPTH_MEDIAN * npix + pix];
        if depth.is_nan() {
            continue;
        }
        let point = ref_point(plan, pix, depth);
        for (i, cam) in plan.cameras.iter().enumerate() {
            if i as u32 == ref_index {
                continue;
            }
            let projected = project(cam, point);
            if let Some(index) = nearest_texel(cam, projected) {
                zbuffer[index] = zbuffer[index].max(!projected[2].to_bits());
            }
        }
    }
}

pub fn visibility(plan: &SweepPlan, zbuffer: &[u32], maps: &mut [f32]) {
    let params = &plan.params;
    let npix = plan.pixel_count();
    let ref_index = params.reference;
    let tolerance = params.occlusion_tolerance;
    for pix in 0..npix {
        let depth = maps[MAP_DEPTH_MEDIAN * npix + pix];
        if depth.is_nan() {
            maps[MAP_DEPTH * npix + pix] = depth;
            maps[MAP_VISIBLE * npix + pix] = 0.0;
            continue;
        }
        let point = ref_point(plan, pix, depth);
        let mut seen = u32::from(ref_index != NO_CAMERA);
        for (i, cam) in plan.cameras.iter().enumerate() {
            if i as u32 == ref_index {
                continue;
            }
            let projected = project(cam, point);
            if let Some(index) = nearest_texel(cam, projected) {
                let stored = zbuffer[index];
                if stored == 0 || projected[2] <= f32::from_bits(!stored) * (1.0 + tolerance) {
                    seen += 1;
                }
            }
        }
        maps[MAP_VISIBLE * npix + pix] = seen as f32;
        if seen < params.min_visible {
            maps[MAP_DEPTH * npix + pix] = f32::NAN;
            maps[MAP_CONFIDENCE * npix + pix] = 0.0;
            maps[MAP_SELECTION * npix + pix] = 3.0;
        } else {
            maps[MAP_DEPTH * npix + pix] = depth;
        }
    }
}
