//! Twin of `shaders/select.wgsl`: streaming winner-take-all with exact neighbours and rival.

use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

/// Per pixel: [best, best plane, cost before, cost after], [rival, min 0..k-1, min 0..k-2,
/// last cost], [selection at best, 0, 0, 0].
pub type PixelState = [[f32; 4]; 3];

pub fn initial() -> PixelState {
    [[BIG, -1.0, BIG, BIG], [BIG; 4], [3.0, 0.0, 0.0, 0.0]]
}

pub fn run(plan: &SweepPlan, first_plane: u32, plane_count: u32, is_first: bool, agg_slab: &[[f32; 2]], state: &mut [PixelState]) {
    let npix = plan.pixel_count();
    for (pix, st) in state.iter_mut().enumerate().take(npix) {
        if is_first {
            *st = initial();
        }
        let [mut s0, mut s1, mut s2] = *st;
        for z in 0..plane_count as usize {
            let k = (first_plane as usize + z) as f32;
            let [c, sel] = agg_slab[z * npix + pix];
            if c < s0[0] {
                s0 = [c, k, s1[3], BIG];
                s1[0] = s1[2];
                s2[0] = sel;
            } else if k == s0[1] + 1.0 {
                s0[3] = c;
            } else {
                s1[0] = s1[0].min(c);
            }
            s1[2] = s1[1];
            s1[1] = s1[1].min(c);
            s1[3] = c;
        }
        *st = [s0, s1, s2];
    }
}
