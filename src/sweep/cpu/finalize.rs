//! Twin of `shaders/finalize.wgsl`.
// The `!(x > 0.0)` tests mirror the shaders and are NaN-safe on purpose.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::common::*;
use super::select::PixelState;
use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

fn inverse_depth(plan: &SweepPlan, k: u32, ray: Vec3) -> f32 {
    let plane = plan.planes[k as usize];
    dot3(xyz(plane), ray) / plane[3]
}

pub fn run(plan: &SweepPlan, state: &[PixelState], maps: &mut [f32]) {
    let params = &plan.params;
    let npix = plan.pixel_count();
    let n_planes = params.planes;
    let max_cost = params.max_cost;
    for pix in 0..npix {
        let [s0, s1, s2] = state[pix];
        let best = s0[0];
        if !(best < 0.5 * BIG) || best > max_cost || s0[1] < 0.0 {
            maps[MAP_DEPTH_RAW * npix + pix] = f32::NAN;
            maps[MAP_CONFIDENCE * npix + pix] = 0.0;
            maps[MAP_COST * npix + pix] = f32::NAN;
            maps[MAP_SELECTION * npix + pix] = 3.0;
            continue;
        }
        let k = s0[1] as u32;
        let ray = xyz(plan.rays[pix]);
        let mut q = inverse_depth(plan, k, ray);
        if params.subpixel != 0
            && k > 0
            && k + 1 < n_planes
            && s0[2] < 0.5 * BIG
            && s0[3] < 0.5 * BIG
        {
            let curvature = s0[2] - 2.0 * best + s0[3];
            if curvature > 0.0 {
                let offset = (0.5 * (s0[2] - s0[3]) / curvature).clamp(-0.5, 0.5);
                if offset > 0.0 {
                    q += offset * (inverse_depth(plan, k + 1, ray) - q);
                } else {
                    q += -offset * (inverse_depth(plan, k - 1, ray) - q);
                }
            }
        }
        let second = s1[0];
        let mut confidence = 1.0;
        if second < 0.5 * BIG {
            confidence = ((second - best) / (second + 1.0)).clamp(0.0, 1.0);
        }
        maps[MAP_DEPTH_RAW * npix + pix] = 1.0 / q;
        maps[MAP_CONFIDENCE * npix + pix] = confidence;
        maps[MAP_COST * npix + pix] = best;
        maps[MAP_SELECTION * npix + pix] = s2[0];
    }
}
