//! Twin of the census half of `shaders/cost.wgsl` (`census_distance`, `census_nearest`,
//! `mixed_cost`), one reference row at a time. The words themselves are made once per frame set
//! by `sweep/census.rs` for both engines.

use super::common::*;
use super::cost::{Mapping, ShiftedSpan};
use crate::sweep::census::BITS;
use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

#[inline(always)]
fn ones(a: u32, b: u32) -> f32 {
    (a ^ b).count_ones() as f32
}

/// Where reference pixel `x` of row `y` lands in the camera on plane `k` (a visible sample:
/// `visible[x]` is not NaN), as `sample_row` projects it.
#[inline(always)]
fn sample_at(plan: &SweepPlan, cam: &GpuCamera, k: usize, x: usize, y: usize) -> Vec2 {
    let width = plan.params.width as usize;
    let ray = xyz(plan.rays[y * width + x]);
    let depth = plane_depth(plan.planes[k], ray);
    let projected = project(cam, [ray[0] * depth, ray[1] * depth, ray[2] * depth]);
    [projected[0], projected[1]]
}

/// Distances of `refs` to the camera row `row` (sample i between texels i and i + 1 at `fx`).
#[inline(always)]
fn along_row(row: &[u32], refs: &[u32], fx: f32, dst: &mut [f32]) {
    let n = dst.len();
    if fx == 0.0 {
        for ((d, &a), &r) in dst.iter_mut().zip(&row[..n]).zip(&refs[..n]) {
            *d = ones(a, r);
        }
    } else {
        for (((d, &a), &b), &r) in dst
            .iter_mut()
            .zip(&row[..n])
            .zip(&row[1..=n])
            .zip(&refs[..n])
        {
            let (h0, h1) = (ones(a, r), ones(b, r));
            *d = h0 + (h1 - h0) * fx;
        }
    }
}

/// `census_distance` along a row: the Hamming distance of each reference word to the words
/// around the camera's sample, interpolated bilinearly. Only visible samples (`visible[x]` not
/// NaN: the camera's red channel from `cost::sample_row`) are written; mappings other than
/// translations read the samples' positions that `sample_row` left in `coords`.
#[expect(
    clippy::too_many_arguments,
    reason = "each argument is an input of its own (the shader twin's buffers, or slices kept apart so that the loop vectorises); a struct would only rename them"
)]
#[inline(always)]
pub fn distance_row(
    plan: &SweepPlan,
    words: &[u32],
    cam: &GpuCamera,
    mapping: Mapping,
    y: usize,
    visible: &[f32],
    coords: &[Vec<f32>; 2],
    reference: &[u32],
    out: &mut [f32],
) {
    let width = plan.params.width as usize;
    let (cw, ch) = (cam.size[0] as usize, cam.size[1] as usize);
    match mapping {
        Mapping::Translation { dx, dy } => {
            // The columns `sample_row_shifted` found inside, with its constant weights.
            let Some(ShiftedSpan {
                x_lo,
                count,
                first,
                y0,
                fx,
                fy,
            }) = ShiftedSpan::of(cw, ch, dx, dy, y, width)
            else {
                return;
            };
            let refs = &reference[x_lo..x_lo + count];
            let dst = &mut out[x_lo..x_lo + count];
            let row = |yy: usize| &words[yy * cw + first..];
            along_row(row(y0), refs, fx, dst);
            if fy != 0.0 {
                // The next camera row, in chunks on the stack, blended in.
                let mut bottom = [0.0f32; 64];
                let next = row(y0 + 1);
                for (start, chunk) in (0..count).step_by(64).zip(dst.chunks_mut(64)) {
                    let n = chunk.len();
                    along_row(
                        &next[start..],
                        &refs[start..start + n],
                        fx,
                        &mut bottom[..n],
                    );
                    for (d, &b) in chunk.iter_mut().zip(&bottom[..n]) {
                        *d += (b - *d) * fy;
                    }
                }
            }
        }
        _ => {
            let [xs, ys] = coords;
            for x in 0..width {
                if visible[x].is_nan() {
                    continue;
                }
                let r = reference[x];
                out[x] = Bilinear::at(cw, ch, [xs[x], ys[x]]).mix(|i| ones(words[i], r));
            }
        }
    }
}

/// `census_nearest` along a row: the word of the texel nearest to each visible sample (at the
/// positions in `coords` for mappings other than translations, as `distance_row`).
#[expect(
    clippy::too_many_arguments,
    reason = "each argument is an input of its own (the shader twin's buffers, or slices kept apart so that the loop vectorises); a struct would only rename them"
)]
#[inline(always)]
pub fn nearest_row(
    plan: &SweepPlan,
    words: &[u32],
    cam: &GpuCamera,
    mapping: Mapping,
    k: usize,
    y: usize,
    visible: &[f32],
    coords: &[Vec<f32>; 2],
    out: &mut [u32],
) {
    let width = plan.params.width as usize;
    let (cw, ch) = (cam.size[0] as usize, cam.size[1] as usize);
    let translation = matches!(mapping, Mapping::Translation { .. });
    for x in 0..width {
        if visible[x].is_nan() {
            continue;
        }
        let pixel = if translation {
            sample_at(plan, cam, k, x, y)
        } else {
            [coords[0][x], coords[1][x]]
        };
        let xi = ((pixel[0] + 0.5).floor() as usize).min(cw - 1);
        let yi = ((pixel[1] + 0.5).floor() as usize).min(ch - 1);
        out[x] = words[yi * cw + xi];
    }
}

/// `mixed_cost` along a row: the pair's TSSDs in `costs` become the plan's cost (`COST_*`) with
/// the census distances `bits`; missing pairs stay INVALID.
#[inline(always)]
pub fn mix_row(plan: &SweepPlan, bits: &[f32], costs: &mut [f32]) {
    let p = &plan.params;
    let scale = p.tau / BITS as f32;
    let n = costs.len();
    let bits = &bits[..n];
    // Every lane is written (a select, not a masked store: the loop stays vectorised).
    let census_only = p.cost == COST_CENSUS;
    for (c, &b) in costs.iter_mut().zip(bits) {
        let census_cost = b * scale;
        let mixed = if census_only {
            census_cost
        } else {
            0.5 * (*c + census_cost)
        };
        // Missing pairs are INVALID (`pair_cost_row`); writing the constant keeps this a blend.
        *c = if *c >= 0.0 { mixed } else { INVALID };
    }
}

/// The distances of a pair of two sampled cameras (nearest words).
#[inline(always)]
pub fn nearest_distance_row(a: &[u32], b: &[u32], out: &mut [f32]) {
    let n = out.len();
    for x in 0..n {
        out[x] = ones(a[x], b[x]);
    }
}
