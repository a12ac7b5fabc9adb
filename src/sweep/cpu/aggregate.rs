//! Twin of `shaders/aggregate.wgsl` (window placement and scoring), one output row at a time:
//! the window means of every channel for each placement (shiftable: the four windows with the
//! pixel at a corner; centred: one), the score over pairs or halves, and the best placement.
//! Every loop runs along the row over plain slices (one per accumulator), so it vectorises.

use super::boxes::RowRing;
use super::common::fmin;
use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

const SEL_NONE: f32 = 0.0;
const SEL_LEFT: f32 = 1.0;
const SEL_RIGHT: f32 = 2.0;

/// Twin of `half_decisions`: the better half by at least `margin` of the worse score, and never
/// by less than `margin` of HALF_NOISE_FLOOR.
#[inline(always)]
fn half_decision(margin: f32, left: f32, right: f32) -> f32 {
    let is_left =
        left < BIG && (right >= BIG || (right - left) > margin * right.max(HALF_NOISE_FLOOR));
    let is_right =
        right < BIG && (left >= BIG || (left - right) > margin * left.max(HALF_NOISE_FLOOR));
    if is_left {
        SEL_LEFT
    } else if is_right {
        SEL_RIGHT
    } else {
        SEL_NONE
    }
}

#[inline(always)]
fn mean_or_big(sum: f32, count: f32) -> f32 {
    if count > 0.0 {
        sum / count
    } else {
        BIG
    }
}

/// Inserts `v` into the ascending list `list` (one slice per rank) at pixel `x`, dropping the
/// largest: the `list.len()` smallest values stay exact.
#[inline(always)]
fn bubble(list: &mut [Vec<f32>], x: usize, mut v: f32) {
    for rank in list.iter_mut() {
        let b = rank[x];
        rank[x] = fmin(b, v);
        v = if b < v { v } else { b };
    }
}

/// Window geometry of the plan: which rows each output row's placements cover.
#[derive(Debug, Clone, Copy)]
pub struct Windows {
    pub w: usize,
    pub h: usize,
    /// Four placements (shiftable windows larger than 1x1) or one (centred).
    pub shiftable: bool,
}

impl Windows {
    pub fn of(plan: &SweepPlan) -> Self {
        let p = &plan.params;
        let (w, h) = (p.window_w as usize, p.window_h as usize);
        Self {
            w,
            h,
            shiftable: p.window_mode == WINDOW_SHIFTABLE && !(w == 1 && h == 1),
        }
    }

    /// Rows above and below the pixel that its windows reach.
    pub fn reach(&self) -> (usize, usize) {
        if self.shiftable {
            (self.h - 1, self.h - 1)
        } else {
            let up = (self.h - 1) / 2;
            (up, self.h - 1 - up)
        }
    }

    /// The first rows of the window row sets of output row y: (upper, lower) for shiftable
    /// windows, (centred, centred) otherwise; signed (may lie above the image).
    fn anchor_rows(&self, y: usize) -> [isize; 2] {
        let y = y as isize;
        if self.shiftable {
            [y - self.h as isize + 1, y]
        } else {
            let a = y - (self.h as isize - 1) / 2;
            [a, a]
        }
    }

    /// Per placement lane: (row set 0 = upper / 1 = lower, column offset into the padded sums).
    fn lanes(&self) -> Vec<(usize, usize)> {
        if self.shiftable {
            vec![(0, 0), (0, self.w - 1), (1, 0), (1, self.w - 1)]
        } else {
            vec![(0, self.w / 2)]
        }
    }
}

/// Scratch of one plane's scoring; rows of `width` pixels.
pub struct RowScorer {
    width: usize,
    padded: usize,
    windows: Windows,
    /// channel x row set x padded: vertical sums and counts.
    sums: Vec<f32>,
    counts: Vec<f32>,
    mean: Vec<f32>,
    lane_score: Vec<f32>,
    lane_sel: Vec<f32>,
    acc: [Vec<f32>; 6],
    best: Vec<Vec<f32>>,
    left_best: Vec<Vec<f32>>,
    right_best: Vec<Vec<f32>>,
}

impl RowScorer {
    pub fn new(plan: &SweepPlan) -> Self {
        let p = &plan.params;
        let width = p.width as usize;
        let windows = Windows::of(plan);
        let padded = width + windows.w - 1;
        let channels = p.channels as usize;
        let ranks = |n: usize| (0..n).map(|_| vec![BIG; width]).collect();
        Self {
            width,
            padded,
            windows,
            sums: vec![0.0; channels * 2 * padded],
            counts: vec![0.0; channels * 2 * padded],
            mean: vec![0.0; width],
            lane_score: vec![0.0; width],
            lane_sel: vec![0.0; width],
            acc: std::array::from_fn(|_| vec![0.0; width]),
            best: ranks(if p.scoring == SCORING_BEST_N {
                p.best_n as usize
            } else {
                0
            }),
            left_best: ranks(p.half_best_n as usize),
            right_best: ranks(p.half_best_n as usize),
        }
    }

    /// Scores output row `y` from the horizontal sums in `ring` (rows of the image `height`):
    /// the best placement's score and selection into `score` and `sel`.
    pub fn score_row(
        &mut self,
        plan: &SweepPlan,
        ring: &RowRing,
        y: usize,
        height: usize,
        score: &mut [f32],
        sel: &mut [u8],
    ) {
        let p = &plan.params;
        let channels = p.channels as usize;
        let padded = self.padded;
        let anchors = self.windows.anchor_rows(y);
        let row_sets = if self.windows.shiftable { 2 } else { 1 };
        for ch in 0..channels {
            for (set, &ay) in anchors.iter().enumerate().take(row_sets) {
                let first = ay.max(0) as usize;
                let end = ((ay + self.windows.h as isize).max(0) as usize).min(height);
                let at = (ch * 2 + set) * padded;
                ring.box_v(
                    ch,
                    first,
                    end,
                    &mut self.sums[at..at + padded],
                    &mut self.counts[at..at + padded],
                );
            }
        }
        let lanes = self.windows.lanes();
        for (lane, &(set, offset)) in lanes.iter().enumerate() {
            if p.aggregation == AGG_PER_PAIR {
                self.score_pairs(plan, set, offset);
            } else {
                self.score_channels(plan, set, offset);
            }
            let (score, sel) = (&mut score[..self.width], &mut sel[..self.width]);
            if lane == 0 {
                for x in 0..self.width {
                    score[x] = self.lane_score[x];
                    sel[x] = self.lane_sel[x] as u8;
                }
            } else {
                // First lane on ties, as `best_placement`.
                for x in 0..self.width {
                    let better = self.lane_score[x] < score[x];
                    score[x] = if better { self.lane_score[x] } else { score[x] };
                    sel[x] = if better {
                        self.lane_sel[x] as u8
                    } else {
                        sel[x]
                    };
                }
            }
        }
    }

    /// The window means of `channel` for one placement into `self.mean`.
    fn means(&mut self, channel: usize, set: usize, offset: usize) {
        let at = (channel * 2 + set) * self.padded + offset;
        let (sums, counts) = (
            &self.sums[at..at + self.width],
            &self.counts[at..at + self.width],
        );
        for ((m, &s), &n) in self.mean.iter_mut().zip(sums).zip(counts) {
            *m = mean_or_big(s, n);
        }
    }

    /// Scored or per-half aggregation (`finish_channels`).
    fn score_channels(&mut self, plan: &SweepPlan, set: usize, offset: usize) {
        let p = &plan.params;
        if p.scoring != SCORING_HALF {
            self.means(0, set, offset);
            self.lane_score.copy_from_slice(&self.mean);
            self.lane_sel.fill(SEL_NONE);
            return;
        }
        let margin = p.half_margin;
        self.means(0, set, offset);
        self.acc[0].copy_from_slice(&self.mean);
        self.means(1, set, offset);
        self.acc[1].copy_from_slice(&self.mean);
        if p.aggregation == AGG_SCORED {
            self.means(2, set, offset);
        }
        let scored = p.aggregation == AGG_SCORED;
        for x in 0..self.width {
            let (left, right) = (self.acc[0][x], self.acc[1][x]);
            self.lane_score[x] = if scored {
                self.mean[x]
            } else {
                left.min(right)
            };
            self.lane_sel[x] = half_decision(margin, left, right);
        }
    }

    /// Per-pair aggregation (`accumulate` + `finish_pairs`).
    fn score_pairs(&mut self, plan: &SweepPlan, set: usize, offset: usize) {
        let p = &plan.params;
        let width = self.width;
        let halves = p.scoring == SCORING_HALF || p.scoring == SCORING_BEST_N;
        for a in &mut self.acc {
            a.fill(0.0);
        }
        for list in [&mut self.best, &mut self.left_best, &mut self.right_best] {
            for rank in list.iter_mut() {
                rank.fill(BIG);
            }
        }
        for (pair, info) in plan.pairs.iter().enumerate().take(p.channels as usize) {
            self.means(pair, set, offset);
            let half = info[2];
            let [sum, count, left_sum, left_count, right_sum, right_count] = &mut self.acc;
            for x in 0..width {
                let a = self.mean[x];
                let seen = a < BIG;
                let (a0, one) = if seen { (a, 1.0) } else { (0.0, 0.0) };
                sum[x] += a0;
                count[x] += one;
                if halves && half == HALF_LEFT {
                    left_sum[x] += a0;
                    left_count[x] += one;
                } else if halves && half == HALF_RIGHT {
                    right_sum[x] += a0;
                    right_count[x] += one;
                }
            }
            if halves && half == HALF_LEFT && !self.left_best.is_empty() {
                for x in 0..width {
                    bubble(&mut self.left_best, x, self.mean[x]);
                }
            } else if halves && half == HALF_RIGHT && !self.right_best.is_empty() {
                for x in 0..width {
                    bubble(&mut self.right_best, x, self.mean[x]);
                }
            }
            if !self.best.is_empty() {
                for x in 0..width {
                    bubble(&mut self.best, x, self.mean[x]);
                }
            }
        }
        let margin = p.half_margin;
        let best_mean = |list: &[Vec<f32>], x: usize| {
            let (mut s, mut c) = (0.0f32, 0.0f32);
            for rank in list {
                if rank[x] < BIG {
                    s += rank[x];
                    c += 1.0;
                }
            }
            mean_or_big(s, c)
        };
        let [sum, count, left_sum, left_count, right_sum, right_count] = &self.acc;
        for x in 0..width {
            let (left, right) = if self.left_best.is_empty() {
                (
                    mean_or_big(left_sum[x], left_count[x]),
                    mean_or_big(right_sum[x], right_count[x]),
                )
            } else {
                (
                    best_mean(&self.left_best, x),
                    best_mean(&self.right_best, x),
                )
            };
            let (score, sel) = if p.scoring == SCORING_HALF {
                (left.min(right), half_decision(margin, left, right))
            } else if p.scoring == SCORING_BEST_N {
                (best_mean(&self.best, x), half_decision(margin, left, right))
            } else {
                (mean_or_big(sum[x], count[x]), SEL_NONE)
            };
            self.lane_score[x] = score;
            self.lane_sel[x] = sel;
        }
    }
}
