//! Twin of `shaders/aggregate.wgsl` (window placement and scoring), one output row at a time:
//! the window means of every channel for each placement (shiftable: the four windows with the
//! pixel at a corner; centred: one), the score over pairs or halves, and the best placement.
//! Every loop runs along the row over plain slices (one per accumulator), so it vectorises.

use super::boxes::RowRing;
use super::common::fmin;
use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

/// The vertical window sums slide down the rows and are summed anew every this many rows.
pub const RESTART_ROWS: usize = 16;

// Selection codes as f32, the type the winner-take-all state keeps them in (one lane width
// with the scores, so the loops that carry both vectorise).
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

/// Twin of `half_min`: the smaller half's score, blended with the other where the two are
/// within `h` (HALF_NOISE_FLOOR) of each other (a quadratic smooth minimum, continuous in both halves): where no
/// occlusion hits either side the score follows both halves' curves, not the one that happens to
/// be lower at each plane, so neighbouring planes keep one shape (SGM and the sub-pixel parabola
/// read it; docs/engine.md, Semi-global matching).
#[inline(always)]
fn half_min(h: f32, left: f32, right: f32) -> f32 {
    let m = fmin(left, right);
    let t = (h - (left - right).abs()).max(0.0);
    let both = left < BIG && right < BIG;
    if both {
        m - t * t / (4.0 * h)
    } else {
        m
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
    /// Length of one scored row: `width` placements (centred), or every window anchor of the
    /// padded row (shiftable: each window is scored once and read by its four pixels).
    span: usize,
    /// Shiftable windows: the scores and selection codes of the last `h` window rows (by top
    /// row), `padded` each, and the top row of the next window row to score.
    window_scores: Vec<f32>,
    window_sels: Vec<f32>,
    next_top: isize,
    /// First output row of the band being scored: the vertical sums start anew there.
    band_start: usize,
    windows: Windows,
    /// channel x row set x padded: vertical sums and counts.
    sums: Vec<f32>,
    counts: Vec<f32>,
    mean: Vec<f32>,
    lane_score: Vec<f32>,
    lane_sel: Vec<f32>,
    carry: Vec<f32>,
    acc: [Vec<f32>; 6],
    best: Vec<Vec<f32>>,
    left_best: Vec<Vec<f32>>,
    right_best: Vec<Vec<f32>>,
    /// Half-sequence scoring whose halves each score their best pair or have none
    /// (`score_halves_best_one`).
    best_one: bool,
    /// Per-pair aggregation whose pairs all lie in one half (a reference at an end of its rig,
    /// e.g. a stereo pair): that half's selection code (`score_halves_best_one` then skips the
    /// empty half).
    one_side: Option<f32>,
    /// Whether `score_row` goes through `score_halves_best_one` (per-pair aggregation).
    per_pair: bool,
}

impl RowScorer {
    pub fn new(plan: &SweepPlan) -> Self {
        let p = &plan.params;
        let width = p.width as usize;
        let windows = Windows::of(plan);
        let padded = width + windows.w - 1;
        let channels = p.channels as usize;
        let span = if windows.shiftable { padded } else { width };
        let ring_rows = if windows.shiftable { windows.h } else { 0 };
        let ranks = |n: usize| (0..n).map(|_| vec![BIG; span]).collect();
        let has = |side: u32| plan.pairs.iter().take(channels).any(|p| p[2] == side);
        Self {
            width,
            padded,
            span,
            window_scores: vec![0.0; ring_rows * padded],
            window_sels: vec![0.0; ring_rows * padded],
            next_top: 0,
            band_start: 0,
            windows,
            sums: vec![0.0; channels * 2 * padded],
            counts: vec![0.0; channels * 2 * padded],
            mean: vec![0.0; span],
            lane_score: vec![0.0; span],
            lane_sel: vec![0.0; span],
            carry: vec![0.0; span],
            acc: std::array::from_fn(|_| vec![0.0; span]),
            best: ranks(if p.scoring == SCORING_BEST_N {
                p.best_n as usize
            } else {
                0
            }),
            left_best: ranks(plan.half_ranks()[0] as usize),
            right_best: ranks(plan.half_ranks()[1] as usize),
            best_one: p.scoring == SCORING_HALF
                && [HALF_LEFT, HALF_RIGHT]
                    .into_iter()
                    .zip(plan.half_ranks())
                    .all(|(side, ranks)| ranks == 1 || (ranks == 0 && !has(side))),
            one_side: {
                match (has(HALF_LEFT), has(HALF_RIGHT)) {
                    (true, false) => Some(SEL_LEFT),
                    (false, true) => Some(SEL_RIGHT),
                    _ => None,
                }
            },
            per_pair: p.aggregation == AGG_PER_PAIR,
        }
    }

    /// The selection code that every score below BIG of the plan comes with, where there is
    /// one: per-pair aggregation, each half scoring its best pair, all pairs in one half (a
    /// stereo pair). Its one-sided path gives that half's code wherever it saw something and a
    /// BIG score elsewhere, and every placement (shiftable windows) and idle span keeps that
    /// (an idle pixel scores BIG).
    pub fn constant_selection(&self) -> Option<f32> {
        if self.per_pair && self.best_one {
            self.one_side
        } else {
            None
        }
    }

    /// Starts a band of output rows at `y0`: its first row sums its windows anew (no sliding
    /// from a row of another band), and the shiftable window rows start above it.
    pub fn begin(&mut self, y0: usize) {
        self.band_start = y0;
        self.next_top = y0 as isize - self.windows.h as isize + 1;
    }

    /// Scores output row `y` from the horizontal sums in `ring` (rows of the image `height`):
    /// the best placement's score and selection into `score` and `sel`.
    #[inline(always)]
    pub fn score_row(
        &mut self,
        plan: &SweepPlan,
        ring: &RowRing,
        y: usize,
        height: usize,
        score: &mut [f32],
        sel: &mut [f32],
    ) {
        if self.windows.shiftable {
            self.score_row_shiftable(plan, ring, y, height, score, sel);
            return;
        }
        let p = &plan.params;
        let channels = p.channels as usize;
        let padded = self.padded;
        let anchors = self.windows.anchor_rows(y);
        let row_sets = if self.windows.shiftable { 2 } else { 1 };
        let h = self.windows.h as isize;
        let rows = |from: isize| (from.max(0) as usize).min(height);
        // Sliding by one row: drop the row that left the window, add the one that entered;
        // summed anew (in the shader's order) every RESTART_ROWS rows so rounding cannot drift.
        let slide = !y.is_multiple_of(RESTART_ROWS) && y != self.band_start;
        for ch in 0..channels {
            for (set, &ay) in anchors.iter().enumerate().take(row_sets) {
                let at = (ch * 2 + set) * padded;
                let sums = &mut self.sums[at..at + padded];
                let counts = &mut self.counts[at..at + padded];
                if slide {
                    let inside =
                        |row: isize| (row >= 0 && (row as usize) < height).then_some(row as usize);
                    ring.slide(ch, inside(ay - 1), inside(ay + h - 1), sums, counts);
                } else {
                    ring.box_v(ch, rows(ay), rows(ay + h), sums, counts);
                }
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
                score.copy_from_slice(&self.lane_score);
                sel.copy_from_slice(&self.lane_sel);
            } else {
                // First lane on ties, as `best_placement`.
                take_better(score, sel, &self.lane_score, &self.lane_sel);
            }
        }
    }

    /// Shiftable windows: every window row is scored once over its padded anchors (top rows
    /// y - h + 1 and y are the upper and lower placements of output row y), and each pixel takes
    /// the best of its four windows, the first placement on ties as `best_placement`.
    #[inline(always)]
    fn score_row_shiftable(
        &mut self,
        plan: &SweepPlan,
        ring: &RowRing,
        y: usize,
        height: usize,
        score: &mut [f32],
        sel: &mut [f32],
    ) {
        let h = self.windows.h as isize;
        while self.next_top <= y as isize {
            self.score_window_row(plan, ring, self.next_top, height);
            self.next_top += 1;
        }
        let (padded, width) = (self.padded, self.width);
        let slot = |top: isize| (top + h - 1) as usize % self.windows.h * padded;
        let (upper, lower) = (slot(y as isize - h + 1), slot(y as isize));
        let right = self.windows.w - 1;
        let (score, sel) = (&mut score[..width], &mut sel[..width]);
        score.copy_from_slice(&self.window_scores[upper..upper + width]);
        sel.copy_from_slice(&self.window_sels[upper..upper + width]);
        for at in [upper + right, lower, lower + right] {
            let (lane_score, lane_sel) = (
                &self.window_scores[at..at + width],
                &self.window_sels[at..at + width],
            );
            take_better(score, sel, lane_score, lane_sel);
        }
    }

    /// Scores the windows whose top row is `top` (may lie above the image) at every padded
    /// anchor into the window-row ring. The vertical sums slide down from the previous top row,
    /// summed anew every RESTART_ROWS rows.
    #[inline(always)]
    fn score_window_row(&mut self, plan: &SweepPlan, ring: &RowRing, top: isize, height: usize) {
        let p = &plan.params;
        let channels = p.channels as usize;
        let padded = self.padded;
        let h = self.windows.h as isize;
        let rows = |from: isize| (from.max(0) as usize).min(height);
        let slide =
            (top + h - 1) % RESTART_ROWS as isize != 0 && top != self.band_start as isize - h + 1;
        for ch in 0..channels {
            let at = ch * 2 * padded;
            let sums = &mut self.sums[at..at + padded];
            let counts = &mut self.counts[at..at + padded];
            if slide {
                let inside =
                    |row: isize| (row >= 0 && (row as usize) < height).then_some(row as usize);
                ring.slide(ch, inside(top - 1), inside(top + h - 1), sums, counts);
            } else {
                ring.box_v(ch, rows(top), rows(top + h), sums, counts);
            }
        }
        if p.aggregation == AGG_PER_PAIR {
            self.score_pairs(plan, 0, 0);
        } else {
            self.score_channels(plan, 0, 0);
        }
        let at = (top + h - 1) as usize % self.windows.h * padded;
        self.window_scores[at..at + padded].copy_from_slice(&self.lane_score);
        self.window_sels[at..at + padded].copy_from_slice(&self.lane_sel);
    }

    /// The window means of `channel` for one placement into `self.mean`.
    #[inline(always)]
    fn means(&mut self, channel: usize, set: usize, offset: usize) {
        let at = (channel * 2 + set) * self.padded + offset;
        let (sums, counts) = (
            &self.sums[at..at + self.span],
            &self.counts[at..at + self.span],
        );
        for ((m, &s), &n) in self.mean.iter_mut().zip(sums).zip(counts) {
            *m = mean_or_big(s, n);
        }
    }

    /// Scored or per-half aggregation (`finish_channels`).
    #[inline(always)]
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
        for x in 0..self.span {
            let (left, right) = (self.acc[0][x], self.acc[1][x]);
            self.lane_score[x] = if scored {
                self.mean[x]
            } else {
                left.min(right)
            };
            self.lane_sel[x] = half_decision(margin, left, right);
        }
    }

    /// Per-pair aggregation (`accumulate` + `finish_pairs`), rank by rank along the row.
    #[inline(always)]
    fn score_pairs(&mut self, plan: &SweepPlan, set: usize, offset: usize) {
        let p = &plan.params;
        if self.best_one {
            self.score_halves_best_one(plan, set, offset);
            return;
        }
        let halves = p.scoring == SCORING_HALF || p.scoring == SCORING_BEST_N;
        // Half-sequence scoring reads only the halves' sums: the all-pairs sum is not made.
        let all_pairs = p.scoring != SCORING_HALF;
        let first_acc = if all_pairs { 0 } else { 2 };
        for a in &mut self.acc[first_acc..] {
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
            if all_pairs {
                add_seen(&self.mean, sum, count);
            }
            if halves && half == HALF_LEFT {
                add_seen(&self.mean, left_sum, left_count);
                bubble(&mut self.left_best, &self.mean, &mut self.carry);
            } else if halves && half == HALF_RIGHT {
                add_seen(&self.mean, right_sum, right_count);
                bubble(&mut self.right_best, &self.mean, &mut self.carry);
            }
            bubble(&mut self.best, &self.mean, &mut self.carry);
        }
        let margin = p.half_margin;
        let [sum, count, left_sum, left_count, right_sum, right_count] = &mut self.acc;
        // The halves' scores: the mean of all their pairs, or of their n best.
        if !self.left_best.is_empty() {
            best_mean(&self.left_best, left_sum, left_count);
        }
        if !self.right_best.is_empty() {
            best_mean(&self.right_best, right_sum, right_count);
        }
        let w = self.span;
        for (s, &n) in left_sum[..w].iter_mut().zip(&left_count[..w]) {
            *s = mean_or_big(*s, n);
        }
        for (s, &n) in right_sum[..w].iter_mut().zip(&right_count[..w]) {
            *s = mean_or_big(*s, n);
        }
        let (left, right) = (&left_sum[..w], &right_sum[..w]);
        let (score, sel) = (&mut self.lane_score[..w], &mut self.lane_sel[..w]);
        if p.scoring == SCORING_HALF {
            let h = HALF_NOISE_FLOOR;
            for (((score, sel), &l), &r) in
                score.iter_mut().zip(sel.iter_mut()).zip(left).zip(right)
            {
                *score = half_min(h, l, r);
                *sel = half_decision(margin, l, r);
            }
        } else if p.scoring == SCORING_BEST_N {
            best_mean(&self.best, sum, count);
            for ((((score, sel), &l), &r), (&s, &n)) in score
                .iter_mut()
                .zip(sel.iter_mut())
                .zip(left)
                .zip(right)
                .zip(sum.iter().zip(count.iter()))
            {
                *score = mean_or_big(s, n);
                *sel = half_decision(margin, l, r);
            }
        } else {
            for ((score, sel), (&s, &n)) in score
                .iter_mut()
                .zip(sel.iter_mut())
                .zip(sum.iter().zip(count.iter()))
            {
                *score = mean_or_big(s, n);
                *sel = SEL_NONE;
            }
        }
    }
}

impl RowScorer {
    /// `score_pairs` for the half-sequence whose halves each score their best pair (the
    /// defaults with two pairs a side: `half_ranks` [1, 1]) or have no pair (a stereo pair:
    /// [1, 0] or [0, 1], the empty half BIG as `best_mean` leaves it), the same floats with a third of
    /// the row passes: each pair's window mean goes straight into its half's minimum (the
    /// one-rank bubble), and each half's score is that minimum through `best_mean` and
    /// `mean_or_big` (`(0 + best) / 1`, or BIG when the half saw nothing); the halves' sums of
    /// every pair (which `best_mean` overwrites) are not made.
    #[inline(always)]
    fn score_halves_best_one(&mut self, plan: &SweepPlan, set: usize, offset: usize) {
        let p = &plan.params;
        let w = self.span;
        let [_, _, left, _, right, _] = &mut self.acc;
        let (left, right) = (&mut left[..w], &mut right[..w]);
        // Each half's minimum over its pairs (an empty half of a one-sided plan is not read).
        if self.one_side != Some(SEL_RIGHT) {
            left.fill(BIG);
        }
        if self.one_side != Some(SEL_LEFT) {
            right.fill(BIG);
        }
        for (pair, info) in plan.pairs.iter().enumerate().take(p.channels as usize) {
            let best = match info[2] {
                HALF_LEFT => &mut *left,
                HALF_RIGHT => &mut *right,
                _ => continue,
            };
            let at = (pair * 2 + set) * self.padded + offset;
            let (sums, counts) = (&self.sums[at..at + w], &self.counts[at..at + w]);
            for ((b, &s), &n) in best.iter_mut().zip(sums).zip(counts) {
                *b = fmin(*b, mean_or_big(s, n));
            }
        }
        let margin = p.half_margin;
        let h = HALF_NOISE_FLOOR;
        let one = |b: f32| if b < BIG { (0.0 + b) / 1.0 } else { BIG };
        let (score, sel) = (&mut self.lane_score[..w], &mut self.lane_sel[..w]);
        if let Some(side) = self.one_side {
            // The other half is empty (BIG): `half_min` is the `fmin` of the two, and
            // `half_decision` picks this half wherever it saw something.
            let best = if side == SEL_LEFT { &*left } else { &*right };
            for ((score, sel), &b) in score.iter_mut().zip(sel.iter_mut()).zip(best) {
                let b = one(b);
                *score = if side == SEL_LEFT {
                    fmin(b, BIG)
                } else {
                    fmin(BIG, b)
                };
                *sel = if b < BIG { side } else { SEL_NONE };
            }
            return;
        }
        for (((score, sel), &l), &r) in score
            .iter_mut()
            .zip(sel.iter_mut())
            .zip(&*left)
            .zip(&*right)
        {
            let (l, r) = (one(l), one(r));
            *score = half_min(h, l, r);
            *sel = half_decision(margin, l, r);
        }
    }
}

/// Where a lane's score is lower than the best so far, takes its score and selection (the first
/// lane stays on ties). Every operand is loaded before the choice, so the loop is two blends.
#[inline(always)]
fn take_better(score: &mut [f32], sel: &mut [f32], lane_score: &[f32], lane_sel: &[f32]) {
    let n = score.len();
    let (sel, lane_score, lane_sel) = (&mut sel[..n], &lane_score[..n], &lane_sel[..n]);
    for i in 0..n {
        let (best, best_sel, candidate, candidate_sel) =
            (score[i], sel[i], lane_score[i], lane_sel[i]);
        let better = candidate < best;
        // The same value as `if better { candidate } else { best }` for non-NaN scores, as an
        // unconditional min (a select here becomes a masked store).
        score[i] = fmin(best, candidate);
        sel[i] = if better { candidate_sel } else { best_sel };
    }
}

/// Adds the seen values (< BIG) of `values` and their count.
#[inline(always)]
fn add_seen(values: &[f32], sum: &mut [f32], count: &mut [f32]) {
    for ((s, n), &a) in sum.iter_mut().zip(count.iter_mut()).zip(values) {
        let seen = a < BIG;
        *s += if seen { a } else { 0.0 };
        *n += if seen { 1.0 } else { 0.0 };
    }
}

/// Inserts `values` into the ascending lists `list` (one row per rank), dropping the largest:
/// the `list.len()` smallest values of every pixel stay exact (the shader's bubble).
#[inline(always)]
fn bubble(list: &mut [Vec<f32>], values: &[f32], carry: &mut [f32]) {
    let Some((first, rest)) = list.split_first_mut() else {
        return;
    };
    for ((b, &v), c) in first.iter_mut().zip(values).zip(carry.iter_mut()) {
        let old = *b;
        *b = fmin(old, v);
        *c = old.max(v);
    }
    for rank in rest {
        for (b, v) in rank.iter_mut().zip(carry.iter_mut()) {
            let old = *b;
            *b = fmin(old, *v);
            *v = old.max(*v);
        }
    }
}

/// Sum and count of the seen (< BIG) entries of the ranks, in rank order (`best_mean`).
#[inline(always)]
fn best_mean(list: &[Vec<f32>], sum: &mut [f32], count: &mut [f32]) {
    sum.fill(0.0);
    count.fill(0.0);
    for rank in list {
        add_seen(rank, sum, count);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::CameraModel;
    use crate::sweep::SweepParams;
    use crate::synthetic;

    /// The half-sequence's fast paths give `score_pairs`' general floats bit for bit: a stereo
    /// pair (one half empty: `half_ranks` [1, 0]) through the one-sided path and the two-sided
    /// one, and three cameras with the reference in the middle ([1, 1]); window means that saw
    /// nothing (count 0) included.
    #[test]
    fn the_halves_fast_paths_are_the_general_scoring() {
        let model = CameraModel::pinhole(synthetic::intrinsics(40, 3));
        for (cameras, reference, one_sided) in [(2, 0, true), (2, 1, true), (3, 1, false)] {
            let rig = synthetic::row_rig(cameras, 0.1, model, reference).expect("rig");
            let plan = SweepPlan::new(&rig, &SweepParams::default()).expect("plan");
            assert_eq!(plan.params.aggregation, AGG_PER_PAIR);
            let mut scorer = RowScorer::new(&plan);
            assert!(scorer.best_one);
            assert_eq!(scorer.one_side.is_some(), one_sided, "{cameras} cameras");
            for (i, (s, n)) in scorer.sums.iter_mut().zip(&mut scorer.counts).enumerate() {
                *n = (i % 4) as f32 * 5.0;
                *s = *n * ((i * 37) % 101) as f32 * 0.37;
            }
            let side = scorer.one_side;
            let run = |scorer: &mut RowScorer, best_one: bool, one_side: Option<f32>| {
                (scorer.best_one, scorer.one_side) = (best_one, one_side);
                scorer.score_pairs(&plan, 0, 0);
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                (bits(&scorer.lane_score), bits(&scorer.lane_sel))
            };
            let general = run(&mut scorer, false, None);
            let both = run(&mut scorer, true, None);
            assert_eq!(both, general, "{cameras} cameras, both halves");
            let fast = run(&mut scorer, true, side);
            assert_eq!(fast, general, "{cameras} cameras, fast path");
            // Not vacuous: some pixels saw nothing (BIG, no selection) and some chose a half.
            let scores = &scorer.lane_score;
            assert!(scores.iter().any(|&s| s >= BIG) && scores.iter().any(|&s| s < BIG));
            assert!(scorer.lane_sel.iter().any(|&s| s != SEL_NONE));
        }
    }
}
