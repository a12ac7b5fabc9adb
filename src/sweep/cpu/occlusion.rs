//! Twins of `shaders/splat.wgsl` and `shaders/visibility.wgsl`. Rows in parallel; the z-buffer
//! keeps the nearest depth with an atomic max of the inverted bits, as the shader does, so the
//! order of the writes does not matter.

use std::sync::atomic::{AtomicU32, Ordering};

use rayon::prelude::*;

use super::common::vectorised_fn;
use super::common::*;
use super::Maps;
use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

#[inline(always)]
fn ref_point(plan: &SweepPlan, pix: usize, depth: f32) -> Vec3 {
    let r = xyz(plan.rays[pix]);
    [r[0] * depth, r[1] * depth, r[2] * depth]
}

/// Index of the nearest texel of camera `cam` to the projection, if inside and in front.
#[inline(always)]
fn nearest_texel(cam: &GpuCamera, projected: Vec3) -> Option<usize> {
    let texel = [(projected[0] + 0.5).floor(), (projected[1] + 0.5).floor()];
    if projected[2] <= 0.0 || !inside(cam, texel) {
        return None;
    }
    Some((cam.size[2] + texel[1] as u32 * cam.size[0] + texel[0] as u32) as usize)
}

/// Splats the median depth into every other camera's z-buffer (cleared to 0 = empty).
pub fn splat(plan: &SweepPlan, maps: &Maps, zbuffer: &mut [u32]) {
    let width = plan.width as usize;
    let ref_index = plan.params.reference;
    let median = maps.section(MAP_DEPTH_MEDIAN);
    let atomic: Vec<AtomicU32> = zbuffer.iter().map(|&z| AtomicU32::new(z)).collect();
    median
        .par_chunks(width)
        .enumerate()
        .for_each(|(y, row)| splat_row(plan, ref_index, y * width, row, &atomic));
    for (z, a) in zbuffer.iter_mut().zip(atomic) {
        *z = a.into_inner();
    }
}

vectorised_fn! {
/// Splats one row of depths (first pixel `first`).
fn splat_row(plan: &SweepPlan, ref_index: u32, first: usize, row: &[f32], zbuffer: &[AtomicU32]) {
    for (x, &depth) in row.iter().enumerate() {
        if depth.is_nan() {
            continue;
        }
        let point = ref_point(plan, first + x, depth);
        for (i, cam) in plan.cameras.iter().enumerate() {
            if i as u32 == ref_index {
                continue;
            }
            let projected = project(cam, point);
            if let Some(index) = nearest_texel(cam, projected) {
                zbuffer[index].fetch_max(!projected[2].to_bits(), Ordering::Relaxed);
            }
        }
    }
}
}

/// Counts the cameras that see each pixel and invalidates those seen by too few.
pub fn visibility(plan: &SweepPlan, zbuffer: &[u32], maps: &mut Maps) {
    let params = &plan.params;
    let width = plan.width as usize;
    let ref_index = params.reference;
    let tolerance = params.occlusion_tolerance;
    let [_, median, depth_out, confidence, _, selection, visible] = maps.sections_mut();
    let median = &*median;
    depth_out
        .par_chunks_mut(width)
        .zip(confidence.par_chunks_mut(width))
        .zip(selection.par_chunks_mut(width))
        .zip(visible.par_chunks_mut(width))
        .enumerate()
        .for_each(|(y, (((depth_out, confidence), selection), visible))| {
            for x in 0..width {
                let pix = y * width + x;
                let depth = median[pix];
                if depth.is_nan() {
                    depth_out[x] = depth;
                    visible[x] = 0.0;
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
                        if stored == 0
                            || projected[2] <= f32::from_bits(!stored) * (1.0 + tolerance)
                        {
                            seen += 1;
                        }
                    }
                }
                visible[x] = seen as f32;
                if seen < params.min_visible {
                    depth_out[x] = f32::NAN;
                    confidence[x] = 0.0;
                    selection[x] = 3.0;
                } else {
                    depth_out[x] = depth;
                }
            }
        });
}
