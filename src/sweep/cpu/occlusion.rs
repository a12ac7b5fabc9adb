//! Twins of `shaders/splat.wgsl` and `shaders/visibility.wgsl`. The z-buffer keeps the nearest
//! depth as the max of the inverted bits, as the shader's atomic max does, so the order of the
//! writes does not matter: splat runs cameras in parallel, visibility rows in parallel.

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
/// Cameras in parallel, each writing only its own section: the nearest depth kept with a plain
/// max of the inverted bits, so the result is the shader's atomic max without atomics.
pub fn splat(plan: &SweepPlan, maps: &Maps, zbuffer: &mut [u32]) {
    let ref_index = plan.params.reference;
    let median = maps.section(MAP_DEPTH_MEDIAN);
    let mut sections: Vec<(&GpuCamera, &mut [u32])> = Vec::with_capacity(plan.cameras.len());
    let mut rest = zbuffer;
    let mut offset = 0usize;
    for (i, cam) in plan.cameras.iter().enumerate() {
        let start = cam.size[2] as usize;
        let len = cam.size[0] as usize * cam.size[1] as usize;
        // Sections lie in camera order (plan.rs); skip any gap before this one.
        let (_, tail) = std::mem::take(&mut rest).split_at_mut(start.saturating_sub(offset));
        let (section, tail) = tail.split_at_mut(len.min(tail.len()));
        rest = tail;
        offset = start + section.len();
        if i as u32 != ref_index {
            sections.push((cam, section));
        }
    }
    sections
        .into_par_iter()
        .for_each(|(cam, section)| splat_camera(plan, cam, median, section));
}

vectorised_fn! {
/// Splats every reference depth into one camera's z-buffer section.
fn splat_camera(plan: &SweepPlan, cam: &GpuCamera, median: &[f32], section: &mut [u32]) {
    let first = cam.size[2] as usize;
    for (pix, &depth) in median.iter().enumerate() {
        if depth.is_nan() {
            continue;
        }
        let projected = project(cam, ref_point(plan, pix, depth));
        if let Some(index) = nearest_texel(cam, projected) {
            if let Some(z) = section.get_mut(index - first) {
                *z = (*z).max(!projected[2].to_bits());
            }
        }
    }
}
}

/// Counts the cameras that see each pixel and invalidates those seen by too few.
pub fn visibility(plan: &SweepPlan, zbuffer: &[u32], maps: &mut Maps) {
    let width = plan.width as usize;
    let [_, median, depth_out, confidence, _, selection, visible] = maps.sections_mut();
    let median = &*median;
    depth_out
        .par_chunks_mut(width)
        .zip(confidence.par_chunks_mut(width))
        .zip(selection.par_chunks_mut(width))
        .zip(visible.par_chunks_mut(width))
        .enumerate()
        .for_each(|(y, (((depth_out, confidence), selection), visible))| {
            let row = VisibilityRow {
                depth_out,
                confidence,
                selection,
                visible,
            };
            visibility_row(plan, zbuffer, median, y, row);
        });
}

/// One reference row's outputs of the visibility stage.
struct VisibilityRow<'a> {
    depth_out: &'a mut [f32],
    confidence: &'a mut [f32],
    selection: &'a mut [f32],
    visible: &'a mut [f32],
}

vectorised_fn! {
/// The visibility of reference row `y` (compiled for AVX2+FMA where the CPU has it: the
/// projections are most of the stage).
fn visibility_row(plan: &SweepPlan, zbuffer: &[u32], median: &[f32], y: usize, row: VisibilityRow<'_>) {
    let params = &plan.params;
    let width = plan.width as usize;
    let ref_index = params.reference;
    let tolerance = params.occlusion_tolerance;
    let VisibilityRow {
        depth_out,
        confidence,
        selection,
        visible,
    } = row;
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
}
}
