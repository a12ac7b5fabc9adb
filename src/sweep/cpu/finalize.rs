//! Twin of `shaders/finalize.wgsl`: winner -> depth (sub-pixel parabola or V in inverse depth,
//! [`subpixel_offset`]),
//! `max_cost` and range-end invalidation, confidence. Rows in parallel.
// The `!(x > 0.0)` tests mirror the shaders and are NaN-safe on purpose.
#![expect(
    clippy::neg_cmp_op_on_partial_ord,
    reason = "`!(a > b)` on purpose: it is also true for NaN, as the shaders' tests are"
)]

use rayon::prelude::*;

use super::common::*;
use super::select::WtaState;
use super::Maps;
use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

/// The winner's sub-plane offset (-0.5..0.5 planes toward `after`) from its score `best` and
/// its neighbours' `before` and `after`, None where they do not bracket a minimum: the parabola
/// through the three, or (`v_fit`) the symmetric V (Shimizu and Okutomi's equiangular line
/// fit). SGM's summed path costs are piecewise linear around the winner (each path pays P1 per
/// plane it moves): the V is exact for them where the parabola pulls the offset toward the
/// plane (a V's true 0.25 reads 0.17), the layers of a depth map's point cloud. Issue 29,
/// docs/quality.md.
#[inline(always)]
pub fn subpixel_offset(before: f32, best: f32, after: f32, v_fit: bool) -> Option<f32> {
    let curvature = before - 2.0 * best + after;
    if !(curvature > 0.0) {
        return None;
    }
    // The V's slope is its steeper side's rise; the parabola's, the second difference.
    let denominator = if v_fit {
        before.max(after) - best
    } else {
        curvature
    };
    Some((0.5 * (before - after) / denominator).clamp(-0.5, 0.5))
}

fn inverse_depth(plan: &SweepPlan, k: u32, ray: Vec3) -> f32 {
    let plane = plan.planes[k as usize];
    dot3(xyz(plane), ray) / plane[3]
}

pub fn run(plan: &SweepPlan, st: &WtaState, maps: &mut Maps) {
    let params = &plan.params;
    let width = params.width as usize;
    let n_planes = params.planes;
    let max_cost = params.max_cost;
    let v_fit = params.subpixel & SUBPIXEL_V_FIT != 0;
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
                if params.keep_range_ends == 0 && (k == 0 || k + 1 == n_planes) {
                    // At the range's end: the surface is likely nearer or farther than the range.
                    raw[x] = f32::NAN;
                    confidence[x] = 0.0;
                    cost[x] = best;
                    selection[x] = 3.0;
                    continue;
                }
                let ray = xyz(plan.rays[pix]);
                let mut q = inverse_depth(plan, k, ray);
                let (before, after) = (st.before[pix], st.after[pix]);
                if params.subpixel != 0
                    && k > 0
                    && k + 1 < n_planes
                    && before < 0.5 * BIG
                    && after < 0.5 * BIG
                {
                    if let Some(offset) = subpixel_offset(before, best, after, v_fit) {
                        if offset > 0.0 {
                            q += offset * (inverse_depth(plan, k + 1, ray) - q);
                        } else {
                            q += -offset * (inverse_depth(plan, k - 1, ray) - q);
                        }
                    }
                }
                let sgm_conf = super::select::confidence(best, st.rival[pix]);
                // Uniqueness on the matching costs themselves (`sgm::select`): SGM's sums make
                // one of several equally good depths win clearly along every path.
                let local = if params.sgm_paths > 0 {
                    st.local_confidence[pix]
                } else {
                    sgm_conf
                };
                let conf = if params.sgm_paths > 0 && params.ambiguity > 0.0 {
                    sgm_conf * (local / params.ambiguity).min(1.0)
                } else {
                    sgm_conf
                };
                if local < params.uniqueness {
                    // Ambiguous: a rival away from the winner nearly as good (a repeated
                    // pattern, a textureless surface).
                    raw[x] = f32::NAN;
                    confidence[x] = conf;
                    cost[x] = best;
                    selection[x] = 3.0;
                    continue;
                }
                raw[x] = 1.0 / q;
                confidence[x] = conf;
                cost[x] = best;
                selection[x] = st.selection[pix];
            }
        });
}

#[cfg(test)]
mod tests {
    use super::subpixel_offset;

    #[test]
    fn the_v_is_exact_for_a_v_and_the_parabola_for_a_parabola() {
        for true_offset in [-0.45f32, -0.3, -0.1, 0.0, 0.05, 0.25, 0.4] {
            // |x - t| and (x - t)^2 sampled at the planes -1, 0, 1.
            let v = |x: f32| (x - true_offset).abs();
            let p = |x: f32| (x - true_offset) * (x - true_offset);
            let from_v = subpixel_offset(v(-1.0), v(0.0), v(1.0), true).expect("a minimum");
            let from_p = subpixel_offset(p(-1.0), p(0.0), p(1.0), false).expect("a minimum");
            assert!(
                (from_v - true_offset).abs() < 1e-6,
                "{from_v} vs {true_offset}"
            );
            assert!(
                (from_p - true_offset).abs() < 1e-6,
                "{from_p} vs {true_offset}"
            );
            // The parabola through a V pulls toward the plane: what the V fit is for.
            let pulled = subpixel_offset(v(-1.0), v(0.0), v(1.0), false).expect("a minimum");
            if (0.01..=0.4).contains(&true_offset.abs()) {
                assert!(
                    pulled.abs() < 0.9 * true_offset.abs(),
                    "{pulled} vs {true_offset}"
                );
            }
        }
        // By hand: before 3, best 1, after 2: the V's slope is 2, offset 0.5 * 1 / 2.
        assert_eq!(subpixel_offset(3.0, 1.0, 2.0, true), Some(0.25));
        assert_eq!(subpixel_offset(3.0, 1.0, 2.0, false), Some(1.0 / 6.0));
        // No minimum bracketed: flat, or falling.
        assert_eq!(subpixel_offset(1.0, 1.0, 1.0, true), None);
        assert_eq!(subpixel_offset(3.0, 2.0, 1.0, true), None);
        // A neighbour below the winner (never for SGM's winner, which is its pixel's
        // minimum): clamped to half a plane.
        assert_eq!(subpixel_offset(0.5, 1.0, 3.0, true), Some(-0.5));
        assert_eq!(subpixel_offset(0.5, 1.0, 3.0, false), Some(-0.5));
    }
}
