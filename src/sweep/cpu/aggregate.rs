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

fn half_decision(keep: f32, left: f32, right: f32) -> f32 {
    if left < BIG && (right >= BIG || left < keep * right) {
        1.0
    } else if right < BIG && (left >= BIG || right < keep * left) {
        2.0
    } else {
        0.0
    }
}

/// Per-pair aggregation of one pixel and plane: (score, selection).
fn aggregate_pairs(plan: &SweepPlan, z: usize, gx: i32, gy: i32, cost_slab: &[f32]) -> [f32; 2] {
    let params = &plan.params;
    let (width, height, npix) = (params.ref_size[0] as i32, params.ref_size[1] as i32, params.ref_size[2] as usize);
    let m = params.counts[2] as usize;
    let base = z * m * npix;
    let reach_x = params.window[0] as i32 - 1;
    let reach_y = params.window[1] as i32 - 1;
    let keep = 1.0 - params.thresholds[3];
    let mut sums = [[0.0f32; 4]; MAX_PAIRS as usize];
    let mut counts = [[0.0f32; 4]; MAX_PAIRS as usize];
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
            let mask = [on(dx <= 0 && dy <= 0), on(dx >= 0 && dy <= 0), on(dx <= 0 && dy >= 0), on(dx >= 0 && dy >= 0)];
            let t = (y * width + x) as usize;
            for p in 0..m {
                let c = cost_slab[base + p * npix + t];
                if c >= 0.0 {
                    accumulate(&mut sums[p], &mut counts[p], c, mask);
                }
            }
        }
    }
    let n = params.modes[2];
    let mut best = [BIG, 0.0];
    for w in 0..4 {
        let (mut sum, mut count) = (0.0f32, 0u32);
        let (mut left_sum, mut left_count, mut right_sum, mut right_count) = (0.0f32, 0u32, 0.0f32, 0u32);
        let mut smallest = [0.0f32; MAX_BEST_N as usize];
        let mut kept = 0u32;
        for p in 0..m {
            if counts[p][w] <= 0.0 {
                continue;
            }
            let a = sums[p][w] / counts[p][w];
            sum += a;
            count += 1;
            let half = plan.pairs[p][2];
            if half == HALF_LEFT {
                left_sum += a;
                left_count += 1;
            } else if half == HALF_RIGHT {
                right_sum += a;
                right_count += 1;
            }
            if params.modes[0] == SCORING_BEST_N && (kept < n || a < smallest[(n - 1) as usize]) {
                let mut i = kept.min(n - 1) as usize;
                while i > 0 && smallest[i - 1] > a {
                    smallest[i] = smallest[i - 1];
                    i -= 1;
                }
                smallest[i] = a;
                kept = (kept + 1).min(n);
            }
        }
        let mut score = BIG;
        let mut sel = 0.0;
        if params.modes[0] == SCORING_HALF {
            let left = if left_count > 0 { left_sum / left_count as f32 } else { BIG };
            let right = if right_count > 0 { right_sum / right_count as f32 } else { BIG };
            score = left.min(right);
            sel = half_decision(keep, left, right);
        } else if params.modes[0] == SCORING_BEST_N {
            if kept > 0 {
                score = smallest[..kept as usize].iter().sum::<f32>() / kept as f32;
            }
        } else if count > 0 {
            score = sum / count as f32;
        }
        if score < best[0] {
            best = [score, sel];
        }
    }
    best
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
                if params.modes[3] == AGG_PER_PAIR {
                    agg_slab[z * npix + (gy * width + gx) as usize] = aggregate_pairs(plan, z, gx, gy, cost_slab);
                    continue;
                }
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
                agg_slab[out_index] = [score, half_decision(keep, left, right)];
            }
        }
    }
}
