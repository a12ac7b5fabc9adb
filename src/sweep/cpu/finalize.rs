//! Twin of `shaders/finalize.wgsl`: winner -> depth (sub-pixel parabola in inverse depth),
//! `max_cost` invalidation, confidence. Rows in parallel.
// The `!(x > 0.0)` tests mirror the shaders and are NaN-safe on purpose.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use rayon::prelude::*;

use super::common::*;
use super::select::WtaState;
use super::Maps;
use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

fn inverse_depth(plan: &SweepPlan, k: u32, ray: Vec3) -> f32 {
    let plane = plan.planes[k as usize];
    dot3(xyz(plane), ray) / plane[3]
}

pub fn run(plan: &SweepPlan, st: &WtaState, maps: &mut Maps) {
    let params = &plan.params;
    let width = params.width as usize;
    let n_planes = params.planes;
    let max_cost = params.max_cost;
    let [raw, _, _, confidence, cost, selection, _] = maps.sections_mut();
    raw.par_chunks_mut(width)
        .zip(confidence.par_chunks_mut(width))
        .zip(cost.par_chunks_mut(width))
        .zip(selection.par_chunks_mut(width))
        .enumerate()
        .for_each(|(y, (((raw, confidence), cost), selection))| {
            for x in 0..width {
                let pix = y * width + x;
                let best = st.best[pix];
                if !(best < 0.5 * BIG) || best > max_cost || st.best_plane[pix] < 0.0 {
                    raw[x] = f32::NAN;
                    confidence[x] = 0.0;
                    cost[x] = f32::NAN;
                    selection[x] = 3.0;
                    continue;
                }
                let k = st.best_plane[pix] as u32;
                let ray = xyz(plan.rays[pix]);
                let mut q = inverse_depth(plan, k, ray);
                let (before, after) = (st.before[pix], st.after[pix]);
                if params.subpixel != 0
                    && k > 0
                    && k + 1 < n_planes
                    && before < 0.5 * BIG
                    && after < 0.5 * BIG
                {
                    let curvature = before - 2.0 * best + after;
                    if curvature > 0.0 {
                        let offset = (0.5 * (before - after) / curvature).clamp(-0.5, 0.5);
                        if offset > 0.0 {
                            q += offset * (inverse_depth(plan, k + 1, ray) - q);
                        } else {
                            q += -offset * (inverse_depth(plan, k - 1, ray) - q);
                        }
                    }
                }
                let second = st.rival[pix];
                let mut conf = 1.0;
                if second < 0.5 * BIG {
                    conf = ((second - best) / (second + 1.0)).clamp(0.0, 1.0);
                }
                raw[x] = 1.0 / q;
                confidence[x] = conf;
                cost[x] = best;
                selection[x] = st.selection[pix];
            }
        });
}
