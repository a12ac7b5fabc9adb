//! Twin of `shaders/aggregate.wgsl`.

use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

fn window_min(sums: [f32; 4], counts: [f32; 4]) -> f32 {
    let mut best = BIG;
    for i in 0..4 {
        if counts[i] > 0.0 {
            best = best.min(sums[i] / counts[i]);
        }
    }
    best
}

fn accumulate(sums: &mut [f32; 4], counts: &mut [f32; 4], value: f32, mask: [f32; 4]) {
    for i in 0..4 {
        sums[i] += value * mask[i];
        counts[i] += mask[i];
    }
}

/// Fills `agg_slab` ((score, selection) per pixel per plane of the batch) from `cost_slab`.
pub fn run(plan: &SweepPlan, plane_count: u32, cost_slab: &[f32], agg_slab: &mut [[f32; 2]]) {
    let params = &plan.params;
    let (width, height, npix) = (params.ref_size[0] as i32, params.ref_size[1] as i32, params.ref_size[2] as usize);
    let channels = params.counts[2] as usize;
    let reach_x = params.window[0] as i32 - 1;
    let reach_y = params.window[1] as i32 - 1;
    let keep = 1.0 - params.thresholds[3];
    for z in 0..plane_count as usize {
        let base = z * channels * npix;
        for gy in 0..height {
            for gx in 0..width {
                let mut sums = [[0.0f32; 4]; 3];
                let mut counts = [[0.0f32; 4]; 3];
                for dy in -reach_y..=reach_y {
                    let y = gy + dy;
                    if y < 0 || y >= height {
                        continue;
                    }
                    for dx in -reach_x..=reach_x {
                        let x = gx + dx;
                        if x < 0 || x >= width {
                            continue;
                        }
                        let on = |b: bool| if b { 1.0 } else { 0.0 };
                        let mask = [
                            on(dx <= 0 && dy <= 0),
                            on(dx >= 0 && dy <= 0),
                            on(dx <= 0 && dy >= 0),
                            on(dx >= 0 && dy >= 0),
                        ];
                        let p = (y * width + x) as usize;
                        let c0 = cost_slab[base + p];
                        if c0 >= 0.0 {
                            accumulate(&mut sums[0], &mut counts[0], c0, mask);
                        }
                        if channels == 2 {
                            let c1 = cost_slab[base + npix + p];
                            if c1 >= 0.0 {
                                accumulate(&mut sums[1], &mut counts[1], c1, mask);
                            }
                            let mut m = c0;
                            if c0 < 0.0 || (c1 >= 0.0 && c1 < c0) {
                                m = c1;
                            }
                            if m >= 0.0 {
                                accumulate(&mut sums[2], &mut counts[2], m, mask);
                            }
                        }
                    }
                }
                let out_index = z * npix + (gy * width + gx) as usize;
                if channels == 1 {
                    agg_slab[out_index] = [window_min(sums[0], counts[0]), 0.0];
                    continue;
                }
                let left = window_min(sums[0], counts[0]);
                let right = window_min(sums[1], counts[1]);
                let mut score = left.min(right);
                if params.modes[3] == AGG_SCORED {
                    score = window_min(sums[2], counts[2]);
                }
                let sel = if left < BIG && (right >= BIG || left < keep * right) {
                    1.0
                } else if right < BIG && (left >= BIG || right < keep * left) {
                    2.0
                } else {
                    0.0
                };
                agg_slab[out_index] = [score, sel];
            }
        }
    }
}
