//! Twin of `shaders/aggregate.wgsl`: window placement and scoring.

use super::select::{self, PixelState};
use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

/// Twin of `half_decisions`: the better half by at least `margin` of the worse score, and never
/// by less than `margin` of HALF_NOISE_FLOOR.
fn half_decision(margin: f32, left: f32, right: f32) -> f32 {
    let floor_cost = HALF_NOISE_FLOOR;
    if left < BIG && (right >= BIG || (right - left) > margin * right.max(floor_cost)) {
        SEL_LEFT as f32
    } else if right < BIG && (left >= BIG || (left - right) > margin * left.max(floor_cost)) {
        SEL_RIGHT as f32
    } else {
        SEL_NONE as f32
    }
}

const SEL_NONE: u32 = 0;
const SEL_LEFT: u32 = 1;
const SEL_RIGHT: u32 = 2;

/// Mean of the `n` smallest values (all of them when fewer), BIG when there are none.
fn best_mean(values: &mut [f32], n: usize) -> f32 {
    if values.is_empty() {
        return BIG;
    }
    values.sort_by(|a, b| a.total_cmp(b));
    let k = n.min(values.len());
    values[..k].iter().sum::<f32>() / k as f32
}

struct Window<'a> {
    plan: &'a SweepPlan,
    box_sums: &'a [[f32; 2]],
    cost_slab: &'a [f32],
}

impl Window<'_> {
    fn mean(&self, z: usize, ch: usize, ax: i32, ay: i32) -> f32 {
        let p = &self.plan.params;
        if p.window_w <= 2 && p.window_h <= 2 {
            // Direct path, as the shader: sum the slab texels of the window.
            let (width, height) = (p.width as i32, p.height as i32);
            let base = (z * self.plan.channels() + ch) * self.plan.pixel_count();
            let mut acc = [0.0f32; 2];
            for y in ay.max(0)..(ay + p.window_h as i32).min(height) {
                for x in ax.max(0)..(ax + p.window_w as i32).min(width) {
                    let c = self.cost_slab[base + (y * width + x) as usize];
                    if c >= 0.0 {
                        acc[0] += c;
                        acc[1] += 1.0;
                    }
                }
            }
            return if acc[1] <= 0.0 { BIG } else { acc[0] / acc[1] };
        }
        let (padded_w, padded_h) = (p.padded_w as usize, p.padded_h as usize);
        let px = (ax + p.window_w as i32 - 1) as usize;
        let py = (ay + p.window_h as i32 - 1) as usize;
        let s = self.box_sums[((z * self.plan.channels() + ch) * padded_h + py) * padded_w + px];
        if s[1] <= 0.0 {
            BIG
        } else {
            s[0] / s[1]
        }
    }

    fn score(&self, z: usize, ax: i32, ay: i32) -> [f32; 2] {
        let p = &self.plan.params;
        let margin = p.half_margin;
        let (scoring, n) = (p.scoring, p.best_n);
        if p.aggregation == AGG_PER_PAIR {
            let (mut sum, mut count) = (0.0f32, 0u32);
            let (mut left_sum, mut left_count, mut right_sum, mut right_count) =
                (0.0f32, 0u32, 0.0f32, 0u32);
            let mut smallest = [0.0f32; MAX_BEST_N as usize];
            let mut kept = 0u32;
            let mut left_values = Vec::new();
            let mut right_values = Vec::new();
            for pair in 0..self.plan.channels() {
                let a = self.mean(z, pair, ax, ay);
                if a >= BIG {
                    continue;
                }
                sum += a;
                count += 1;
                let half = self.plan.pairs[pair][2];
                if half == HALF_LEFT {
                    left_sum += a;
                    left_count += 1;
                    left_values.push(a);
                } else if half == HALF_RIGHT {
                    right_sum += a;
                    right_count += 1;
                    right_values.push(a);
                }
                if scoring == SCORING_BEST_N && (kept < n || a < smallest[(n - 1) as usize]) {
                    let mut i = kept.min(n - 1) as usize;
                    while i > 0 && smallest[i - 1] > a {
                        smallest[i] = smallest[i - 1];
                        i -= 1;
                    }
                    smallest[i] = a;
                    kept = (kept + 1).min(n);
                }
            }
            let half_n = p.half_best_n as usize;
            let mut left = if left_count > 0 {
                left_sum / left_count as f32
            } else {
                BIG
            };
            let mut right = if right_count > 0 {
                right_sum / right_count as f32
            } else {
                BIG
            };
            if half_n > 0 {
                left = best_mean(&mut left_values, half_n);
                right = best_mean(&mut right_values, half_n);
            }
            if scoring == SCORING_HALF {
                return [left.min(right), half_decision(margin, left, right)];
            }
            if scoring == SCORING_BEST_N {
                // The halves also tell which side matched better (the selection image).
                let sel = half_decision(margin, left, right);
                if kept == 0 {
                    return [BIG, sel];
                }
                return [
                    smallest[..kept as usize].iter().sum::<f32>() / kept as f32,
                    sel,
                ];
            }
            if count == 0 {
                return [BIG, 0.0];
            }
            return [sum / count as f32, 0.0];
        }
        if scoring == SCORING_HALF {
            let left = self.mean(z, 0, ax, ay);
            let right = self.mean(z, 1, ax, ay);
            let mut score = left.min(right);
            if p.aggregation == AGG_SCORED {
                score = self.mean(z, 2, ax, ay);
            }
            return [score, half_decision(margin, left, right)];
        }
        [self.mean(z, 0, ax, ay), 0.0]
    }
}

/// Scores every plane of the batch for every pixel and feeds the winner-take-all state; with
/// a `volume` (optimizer sgm) also writes each score's level into it.
pub fn run(
    plan: &SweepPlan,
    first_plane: u32,
    plane_count: u32,
    box_sums: &[[f32; 2]],
    cost_slab: &[f32],
    state: &mut [PixelState],
    mut volume: Option<&mut [u32]>,
) {
    let p = &plan.params;
    let (width, height) = (p.width as i32, p.height as i32);
    let (w, h) = (p.window_w as i32, p.window_h as i32);
    let window = Window {
        plan,
        box_sums,
        cost_slab,
    };
    for z in 0..plane_count as usize {
        for y in 0..height {
            for x in 0..width {
                let best = if p.window_mode == WINDOW_CENTRED || (w == 1 && h == 1) {
                    window.score(z, x - (w - 1) / 2, y - (h - 1) / 2)
                } else {
                    let mut best = [BIG, 0.0];
                    for corner in 0..4 {
                        let ax = if corner & 1 == 0 { x - w + 1 } else { x };
                        let ay = if corner & 2 == 0 { y - h + 1 } else { y };
                        let s = window.score(z, ax, ay);
                        if s[0] < best[0] {
                            best = s;
                        }
                    }
                    best
                };
                let pix = (y * width + x) as usize;
                let plane = first_plane + z as u32;
                select::update(&mut state[pix], plane as f32, best);
                if let Some(volume) = volume.as_deref_mut() {
                    super::sgm::store_level(plan, volume, pix, plane, best[0]);
                }
            }
        }
    }
}
