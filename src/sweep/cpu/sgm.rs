//! Twin of `shaders/sgm.wgsl` (one path direction of semi-global matching) and
//! `shaders/sgm_select.wgsl` (winner-take-all over the summed path costs). Integer path costs,
//! so both sides agree exactly up to the final f32 scaling.
// The `!(x < BIG)` test mirrors the shader and is NaN-safe on purpose.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::select::{self, PixelState};
use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

/// Twin of `volume_level` (common.wgsl): a scored cost as u16 levels.
pub fn volume_level(plan: &SweepPlan, score: f32) -> u32 {
    if score >= 0.5 * BIG {
        return SGM_COST_MAX;
    }
    ((score * plan.params.sgm_levels_per_unit + 0.5).floor() as u32).min(SGM_COST_MAX)
}

/// Writes plane `plane`'s level at pixel `pix` into the packed volume (aggregate.wgsl's
/// `store_level`, without the write ordering it needs).
pub fn store_level(plan: &SweepPlan, volume: &mut [u32], pix: usize, plane: u32, score: f32) {
    let level = volume_level(plan, score);
    let word = &mut volume[pix * plan.volume_words() + plane as usize / 2];
    if plane & 1 == 0 {
        *word = (*word & 0xffff_0000) | level;
    } else {
        *word = (*word & 0xffff) | (level << 16);
    }
}

/// Twin of `line_start`.
fn line_start(line: i32, dx: i32, dy: i32, w: i32, h: i32) -> (i32, i32) {
    let x_edge = if dx > 0 { 0 } else { w - 1 };
    let y_edge = if dy > 0 { 0 } else { h - 1 };
    if dy == 0 {
        return (x_edge, line);
    }
    if dx == 0 {
        return (line, y_edge);
    }
    if line < h {
        return (x_edge, line);
    }
    let i = line - h + 1;
    (if dx > 0 { i } else { w - 1 - i }, y_edge)
}

/// Twin of `colour_step`: the largest RGB channel difference.
fn colour_step(a: u32, b: u32) -> u32 {
    (0..3)
        .map(|c| {
            let (ca, cb) = ((a >> (8 * c)) & 0xff, (b >> (8 * c)) & 0xff);
            ca.abs_diff(cb)
        })
        .max()
        .unwrap_or(0)
}

/// One direction (dx, dy): every path line, pixel by pixel; the first pass writes `sums`, the
/// others add to it.
#[allow(clippy::too_many_arguments)]
pub fn pass(
    plan: &SweepPlan,
    images: &[u32],
    dx: i32,
    dy: i32,
    lines: u32,
    first_pass: bool,
    volume: &[u32],
    sums: &mut [u32],
) {
    let p = &plan.params;
    let (w, h) = (p.width as i32, p.height as i32);
    let planes = p.planes as usize;
    let words = plan.volume_words();
    let (p1, p2, edge) = (p.sgm_p1, p.sgm_p2, p.sgm_edge);
    let image_offset = if p.reference == NO_CAMERA {
        0
    } else {
        plan.cameras[p.reference as usize].size[2] as usize
    };
    let mut prev_costs = vec![0u32; 2 * words];
    let mut next_costs = vec![0u32; 2 * words];
    for line in 0..lines as i32 {
        let (mut x, mut y) = line_start(line, dx, dy, w, h);
        let mut step = 0u32;
        let mut previous_colour = 0u32;
        let mut prev_min = 0u32;
        while x >= 0 && y >= 0 && x < w && y < h {
            let pix = (y * w + x) as usize;
            let mut penalty2 = p2;
            let mut colour = 0;
            if edge > 0 {
                colour = images[image_offset + pix];
                if step > 0 {
                    penalty2 =
                        p1.max(p2 * edge / (edge + 16 * colour_step(colour, previous_colour)));
                }
            }
            let path_term = |d: usize| {
                let mut best = prev_costs[d].min(prev_min + penalty2);
                if d > 0 {
                    best = best.min(prev_costs[d - 1] + p1);
                }
                if d + 1 < planes {
                    best = best.min(prev_costs[d + 1] + p1);
                }
                best - prev_min
            };
            let mut local_min = u32::MAX;
            for j in 0..words {
                let at = pix * words + j;
                let c = volume[at];
                let d = 2 * j;
                let mut l0 = c & 0xffff;
                let mut l1 = c >> 16;
                if step > 0 {
                    l0 += path_term(d);
                    if d + 1 < planes {
                        l1 += path_term(d + 1);
                    }
                }
                if d + 1 >= planes {
                    l1 = 0;
                } else {
                    local_min = local_min.min(l1);
                }
                local_min = local_min.min(l0);
                next_costs[d] = l0;
                next_costs[d + 1] = l1;
                let packed = l0 | (l1 << 16);
                sums[at] = if first_pass {
                    packed
                } else {
                    sums[at].wrapping_add(packed)
                };
            }
            std::mem::swap(&mut prev_costs, &mut next_costs);
            prev_min = local_min;
            previous_colour = colour;
            x += dx;
            y += dy;
            step += 1;
        }
    }
}

/// Twin of `sgm_select.wgsl`.
pub fn select(plan: &SweepPlan, sums: &[u32], state: &mut [PixelState]) {
    let planes = plan.num_planes() as usize;
    let words = plan.volume_words();
    let unit = plan.params.sgm_unit_per_level;
    for (pix, st) in state.iter_mut().enumerate() {
        let local = st[0];
        if !(local[0] < 0.5 * BIG) || local[1] < 0.0 {
            continue;
        }
        let selection = st[2][0];
        let mut fresh = select::initial();
        fresh[2][0] = selection;
        for j in 0..words {
            let word = sums[pix * words + j];
            let d = 2 * j;
            select::update(
                &mut fresh,
                d as f32,
                [(word & 0xffff) as f32 * unit, selection],
            );
            if d + 1 < planes {
                select::update(
                    &mut fresh,
                    (d + 1) as f32,
                    [(word >> 16) as f32 * unit, selection],
                );
            }
        }
        *st = fresh;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::CameraModel;
    use crate::sweep::{Optimizer, SweepParams};
    use crate::synthetic;

    /// A 2x1 image with 3 planes, one left-to-right path, P1 = 10, P2 = 30 levels.
    fn plan() -> SweepPlan {
        let model = CameraModel::pinhole(synthetic::intrinsics(2, 1));
        let rig = synthetic::row_rig(2, 0.1, model, 0).expect("rig");
        let params = SweepParams {
            num_planes: 3,
            optimizer: Optimizer::Sgm,
            ..SweepParams::default()
        };
        let mut plan = SweepPlan::new(&rig, &params).expect("plan");
        plan.params.sgm_paths = 1;
        plan.params.sgm_p1 = 10;
        plan.params.sgm_p2 = 30;
        plan.params.sgm_edge = 0;
        plan.params.sgm_unit_per_level = 1.0;
        plan
    }

    fn volume(pixels: &[[u32; 3]]) -> Vec<u32> {
        pixels
            .iter()
            .flat_map(|c| [c[0] | (c[1] << 16), c[2]])
            .collect()
    }

    #[test]
    fn path_costs_by_hand() {
        let plan = plan();
        // Pixel 0 is sure of plane 0; pixel 1 slightly prefers plane 2 locally.
        let costs = volume(&[[0, 50, 50], [5, 40, 0]]);
        let mut sums = vec![0u32; costs.len()];
        pass(&plan, &[], 1, 0, 1, true, &costs, &mut sums);
        // Pixel 1: d0 = 5 + min(0, 50 + 10, 0 + 30) - 0 = 5; d1 = 40 + min(50, 0 + 10, 50 + 10,
        // 30) = 50; d2 = 0 + min(50, 50 + 10, 30) = 30.
        assert_eq!(sums, volume(&[[0, 50, 50], [5, 50, 30]]));
        // The second pass adds; the selection over the sums moves pixel 1 to plane 0.
        pass(&plan, &[], 1, 0, 1, false, &costs, &mut sums);
        assert_eq!(sums, volume(&[[0, 100, 100], [10, 100, 60]]));
        let mut state = vec![select::initial(); 2];
        for st in &mut state {
            st[0] = [0.0, 2.0, BIG, BIG];
        }
        select(&plan, &sums, &mut state);
        assert_eq!(state[1][0], [10.0, 0.0, BIG, 100.0]);
        // The rival away from the winner's neighbours is plane 2.
        assert_eq!(state[1][1][0], 60.0);
    }

    #[test]
    fn edge_step_lowers_p2() {
        let mut plan = plan();
        // Edge = 8 grey levels (x 16): a step of 8 halves P2 (30 -> 15).
        plan.params.sgm_edge = 8 * 16;
        let images = [0u32, 8];
        let costs = volume(&[[0, 50, 50], [50, 50, 0]]);
        let mut sums = vec![0u32; costs.len()];
        pass(&plan, &images, 1, 0, 1, true, &costs, &mut sums);
        assert_eq!(sums[2] & 0xffff, 50);
        assert_eq!(sums[3], 15);
    }
}
