//! Twin of the selection step of `shaders/aggregate.wgsl`: streaming winner-take-all with exact
//! neighbours and rival.

use crate::sweep::gpu_types::*;

/// Per pixel: [best, best plane, cost before, cost after], [rival, min 0..k-1, min 0..k-2,
/// last cost], [selection at best, 0, 0, 0].
pub type PixelState = [[f32; 4]; 3];

pub fn initial() -> PixelState {
    [[BIG, -1.0, BIG, BIG], [BIG; 4], [3.0, 0.0, 0.0, 0.0]]
}

/// One step of the streaming winner-take-all: plane `k` with aggregated `[cost, selection]`.
pub fn update(st: &mut PixelState, k: f32, [c, sel]: [f32; 2]) {
    let [s0, s1, s2] = st;
    if c < s0[0] {
        *s0 = [c, k, s1[3], BIG];
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
