//! Twins of `shaders/box_h.wgsl` and the vertical sums of `shaders/aggregate.wgsl`: window sums (sum, count) of the
//! valid costs, added in the shaders' order (left to right, then top to bottom) so the sums are
//! the same floats. Rows are processed as they are made: a ring keeps the last rows' horizontal
//! sums, so a plane never needs its whole cost slab.

/// Scratch of the horizontal window sums of one worker, for rows of `width` costs and windows
/// `w` wide: the zero-padded row, two doubling levels, and the counts of a row whose costs are
/// all valid (the common case, which then skips its own count sums).
pub struct BoxH {
    w: usize,
    pad: Vec<f32>,
    level: Vec<f32>,
    next: Vec<f32>,
    full_counts: Vec<f32>,
    valid: Vec<f32>,
    masked: Vec<f32>,
}

impl BoxH {
    pub fn new(width: usize, w: usize) -> Self {
        let w = w.max(1);
        let len = width + 2 * (w - 1);
        let mut boxes = Self {
            w,
            pad: vec![0.0; len],
            level: vec![0.0; len],
            next: vec![0.0; len],
            full_counts: Vec::new(),
            valid: vec![0.0; width],
            masked: vec![0.0; width],
        };
        let mut full_counts = vec![0.0; width + w - 1];
        boxes.sums(&vec![1.0; width], &mut full_counts);
        boxes.full_counts = full_counts;
        boxes
    }

    /// Horizontal sums of one row of costs for every padded anchor: index i is the window whose
    /// first column is i - (w - 1) (box_h.wgsl); invalid costs (< 0) add nothing, as the shader
    /// skips them, and `counts` holds how many valid costs each window has.
    /// Returns the valid span `lo..hi` when every cost inside it is valid (then `counts` is a
    /// function of the span alone), `None` otherwise.
    #[inline(always)]
    pub fn run(
        &mut self,
        costs: &[f32],
        sums: &mut [f32],
        counts: &mut [f32],
    ) -> Option<(usize, usize)> {
        let width = costs.len();
        let padded = width + self.w - 1;
        // The valid costs' column span lo..hi (a pair's costs are invalid outside the columns
        // both cameras see), and whether every cost inside it is valid. (No early exit inside
        // the span: the and of the tests vectorises.)
        let lo = first_valid(costs);
        let hi = last_valid_end(costs).max(lo);
        let mut span_valid = true;
        for &c in &costs[lo..hi] {
            span_valid &= c >= 0.0;
        }
        if span_valid && lo == 0 && hi == width {
            counts[..padded].copy_from_slice(&self.full_counts[..padded]);
            self.sums(costs, sums);
            return Some((lo, hi));
        }
        let mut masked = std::mem::take(&mut self.masked);
        masked.resize(width, 0.0);
        if span_valid {
            // One span of valid costs: each window's count is its overlap with the span, a
            // whole number, so the same float as the sum of the 0/1 mask in any order.
            let (w, lo, hi) = (self.w as i32, lo as i32, hi as i32);
            for (i, n) in counts[..padded].iter_mut().enumerate() {
                let i = i as i32;
                let overlap = (i + 1).min(hi) - (i + 1 - w).max(lo);
                *n = overlap.max(0) as f32;
            }
            let (lo, hi) = (lo as usize, hi as usize);
            if self.w > 2 {
                // The span straight into the padded row (the zeros around it are the masked
                // costs), without the masked row.
                let w = self.w;
                let len = width + 2 * (w - 1);
                let pad = &mut self.pad[..len];
                pad[..w - 1 + lo].fill(0.0);
                pad[w - 1 + lo..w - 1 + hi].copy_from_slice(&costs[lo..hi]);
                pad[w - 1 + hi..].fill(0.0);
                self.sum_pad(width, sums);
            } else {
                masked[..lo].fill(0.0);
                masked[lo..hi].copy_from_slice(&costs[lo..hi]);
                masked[hi..].fill(0.0);
                self.sums(&masked, sums);
            }
            self.masked = masked;
            return Some((lo, hi));
        }
        let mut valid = std::mem::take(&mut self.valid);
        valid.resize(width, 0.0);
        for ((v, m), &c) in valid.iter_mut().zip(masked.iter_mut()).zip(costs) {
            let ok = c >= 0.0;
            *v = if ok { 1.0 } else { 0.0 };
            *m = if ok { c } else { 0.0 };
        }
        self.sums(&valid, counts);
        self.sums(&masked, sums);
        (self.valid, self.masked) = (valid, masked);
        None
    }

    /// Window sums of `values` (all taken as valid) into `out[..width + w - 1]`, built from
    /// doubling partial sums: for w = 9, out = s8[i] + s1[i + 8] with s8 made in three steps,
    /// instead of nine additions per anchor. (The rounding differs from the shader's
    /// left-to-right order by float ulps, inside the tolerances of tests/engine/gpu_vs_cpu.rs.)
    /// Windows of 1 and 2 columns (the paper's shiftable 2x2) are summed directly: the same
    /// floats as the doubling (one addition of two values), without its copies; the odd widths
    /// 3 to 9 (the centred windows) in the doubling's tree per anchor (`direct_tree`).
    #[inline(always)]
    fn sums(&mut self, values: &[f32], out: &mut [f32]) {
        let w = self.w;
        let width = values.len();
        let padded = width + w - 1;
        let out = &mut out[..padded];
        match w {
            1 => {
                out.copy_from_slice(values);
                return;
            }
            2 if width > 0 => {
                // Anchor i covers columns i - 1 and i (0 outside the row).
                out[0] = values[0];
                for (o, (&a, &b)) in out[1..width]
                    .iter_mut()
                    .zip(values.iter().zip(&values[1..]))
                {
                    *o = a + b;
                }
                out[width] = values[width - 1];
                return;
            }
            _ => {}
        }
        let len = width + 2 * (w - 1);
        let pad = &mut self.pad[..len];
        pad[..w - 1].fill(0.0);
        pad[w - 1..w - 1 + width].copy_from_slice(values);
        pad[w - 1 + width..].fill(0.0);
        self.sum_pad(width, out);
    }

    /// The window sums of the padded row in `self.pad` (a row of `width` values with `w - 1`
    /// zeros each side, w > 2) into `out[..width + w - 1]`.
    #[inline(always)]
    fn sum_pad(&mut self, width: usize, out: &mut [f32]) {
        let w = self.w;
        let len = width + 2 * (w - 1);
        let out = &mut out[..width + w - 1];
        if !direct_tree(w, &self.pad[..len], out) {
            self.doubling(len, out);
        }
    }

    /// The doubling over the padded row in `self.pad[..len]` into `out` (`sums`).
    #[inline(always)]
    fn doubling(&mut self, len: usize, out: &mut [f32]) {
        let (w, padded) = (self.w, out.len());
        out.fill(0.0);
        // `level` holds s_h[i] = sum of pad[i..i + h] for i < len - h + 1.
        self.level[..len].copy_from_slice(&self.pad[..len]);
        let mut h = 1;
        let mut consumed = 0;
        loop {
            if w & h != 0 {
                let from = w - consumed - h;
                for (o, &v) in out.iter_mut().zip(&self.level[from..from + padded]) {
                    *o += v;
                }
                consumed += h;
            }
            if consumed == w {
                break;
            }
            let n = len + 1 - 2 * h;
            let (level, next) = (&self.level[..n + h], &mut self.next[..n]);
            for ((s, &a), &b) in next.iter_mut().zip(&level[..n]).zip(&level[h..h + n]) {
                *s = a + b;
            }
            std::mem::swap(&mut self.level, &mut self.next);
            h *= 2;
        }
    }
}

/// Lanes a validity scan tests at a time (one AVX-512 vector of f32).
const SCAN: usize = 16;

/// Whether some cost of `chunk` is valid (>= 0): the or of every lane's test, no early exit,
/// so it vectorises.
#[inline(always)]
fn any_valid(chunk: &[f32]) -> bool {
    chunk.iter().fold(false, |any, &c| any | (c >= 0.0))
}

/// The first index of `costs` whose cost is valid (>= 0), or its length: SCAN lanes at a time
/// (the rows of a shifted camera start with tens of invalid costs), then the lane.
#[inline(always)]
fn first_valid(costs: &[f32]) -> usize {
    let start = costs
        .chunks_exact(SCAN)
        .take_while(|c| !any_valid(c))
        .count()
        * SCAN;
    costs[start..]
        .iter()
        .position(|&c| c >= 0.0)
        .map_or(costs.len(), |i| start + i)
}

/// One past the last index of `costs` whose cost is valid, or 0: as [`first_valid`] from the
/// end.
#[inline(always)]
fn last_valid_end(costs: &[f32]) -> usize {
    let end = costs.len()
        - costs
            .rchunks_exact(SCAN)
            .take_while(|c| !any_valid(c))
            .count()
            * SCAN;
    costs[..end]
        .iter()
        .rposition(|&c| c >= 0.0)
        .map_or(0, |j| j + 1)
}

/// The doubling's sums for the odd widths 3, 5, 7 and 9 (the centred windows) in one pass
/// over the padded row, each anchor's additions in the doubling's tree (the same floats:
/// s2[i] = p[i] + p[i + 1], s4[i] = s2[i] + s2[i + 2], ..., and `out` gathers the levels of
/// w's bits from the lowest, e.g. w = 7: (p[i + 6] + s2[i + 4]) + s4[i]), without its level
/// rows, fills and copies. False for other widths.
#[inline(always)]
fn direct_tree(w: usize, pad: &[f32], out: &mut [f32]) -> bool {
    let n = out.len();
    let p = |k: usize| &pad[k..k + n];
    match w {
        3 => {
            let (p0, p1, p2) = (p(0), p(1), p(2));
            for (i, o) in out.iter_mut().enumerate() {
                *o = p2[i] + (p0[i] + p1[i]);
            }
        }
        5 => {
            let (p0, p1, p2, p3, p4) = (p(0), p(1), p(2), p(3), p(4));
            for (i, o) in out.iter_mut().enumerate() {
                *o = p4[i] + ((p0[i] + p1[i]) + (p2[i] + p3[i]));
            }
        }
        7 => {
            let (p0, p1, p2, p3, p4, p5, p6) = (p(0), p(1), p(2), p(3), p(4), p(5), p(6));
            for (i, o) in out.iter_mut().enumerate() {
                let s4 = (p0[i] + p1[i]) + (p2[i] + p3[i]);
                *o = (p6[i] + (p4[i] + p5[i])) + s4;
            }
        }
        9 => {
            let (p0, p1, p2, p3, p4, p5, p6, p7, p8) =
                (p(0), p(1), p(2), p(3), p(4), p(5), p(6), p(7), p(8));
            for (i, o) in out.iter_mut().enumerate() {
                let s4a = (p0[i] + p1[i]) + (p2[i] + p3[i]);
                let s4b = (p4[i] + p5[i]) + (p6[i] + p7[i]);
                *o = p8[i] + (s4a + s4b);
            }
        }
        _ => return false,
    }
    true
}

/// The horizontal sums of the last rows of one plane, per channel (a ring of `slots` rows).
pub struct RowRing {
    padded: usize,
    slots: usize,
    /// channel x slot x (sums, counts) x padded.
    data: Vec<f32>,
    /// channel x slot: the row's valid column span when its counts are a function of it
    /// (`BoxH::run`), so two rows with the same span have the same counts.
    spans: Vec<Option<(usize, usize)>>,
}

impl RowRing {
    pub fn new(channels: usize, slots: usize, padded: usize) -> Self {
        Self {
            padded,
            slots,
            data: vec![0.0; channels * slots * 2 * padded],
            spans: vec![None; channels * slots],
        }
    }

    #[inline(always)]
    fn at(&self, channel: usize, row: usize) -> usize {
        (channel * self.slots + row % self.slots) * 2 * self.padded
    }

    /// (sums, counts) of `row` of `channel`, to be written.
    #[inline(always)]
    pub fn row_mut(&mut self, channel: usize, row: usize) -> (&mut [f32], &mut [f32]) {
        let at = self.at(channel, row);
        self.data[at..at + 2 * self.padded].split_at_mut(self.padded)
    }

    /// Records the valid span of `row` of `channel` (what `BoxH::run` returned for it).
    #[inline(always)]
    pub fn set_span(&mut self, channel: usize, row: usize, span: Option<(usize, usize)>) {
        self.spans[channel * self.slots + row % self.slots] = span;
    }

    /// The window sliding down by one row: subtracts row `left` and adds row `entered` (each
    /// when inside the image) into (sums, counts), in that order. Where both rows have the
    /// same valid span their count rows are equal whole numbers, so the counts are left as
    /// they are (the same floats as subtracting and adding them).
    #[inline(always)]
    pub fn slide(
        &self,
        channel: usize,
        left: Option<usize>,
        entered: Option<usize>,
        sums: &mut [f32],
        counts: &mut [f32],
    ) {
        if let (Some(left), Some(entered)) = (left, entered) {
            let span = |row: usize| self.spans[channel * self.slots + row % self.slots];
            if span(left).is_some() && span(left) == span(entered) {
                // Both rows in one pass: the row that left taken away, then the row that
                // entered added (the floats of one pass each).
                let (l, e) = (self.at(channel, left), self.at(channel, entered));
                let (l, e) = (
                    &self.data[l..l + self.padded],
                    &self.data[e..e + self.padded],
                );
                let sums = &mut sums[..self.padded];
                for ((s, &a), &b) in sums.iter_mut().zip(l).zip(e) {
                    *s = (*s - a) + b;
                }
                return;
            }
        }
        if let Some(left) = left {
            self.add_row(channel, left, -1.0, sums, counts);
        }
        if let Some(entered) = entered {
            self.add_row(channel, entered, 1.0, sums, counts);
        }
    }

    /// Vertical sums (`box_mean` of aggregate.wgsl) of rows `first..end` of `channel` into (sums, counts), added
    /// top to bottom from zero.
    #[inline(always)]
    pub fn box_v(
        &self,
        channel: usize,
        first: usize,
        end: usize,
        sums: &mut [f32],
        counts: &mut [f32],
    ) {
        sums.fill(0.0);
        counts.fill(0.0);
        for row in first..end {
            let at = self.at(channel, row);
            let (s_row, n_row) = self.data[at..at + 2 * self.padded].split_at(self.padded);
            for ((s, n), (&a, &b)) in sums
                .iter_mut()
                .zip(counts.iter_mut())
                .zip(s_row.iter().zip(n_row))
            {
                *s += a;
                *n += b;
            }
        }
    }

    /// Adds `sign` (1 or -1) times row `row` of `channel` into (sums, counts): the step of a
    /// window sliding down by one row.
    #[inline(always)]
    pub fn add_row(
        &self,
        channel: usize,
        row: usize,
        sign: f32,
        sums: &mut [f32],
        counts: &mut [f32],
    ) {
        let at = self.at(channel, row);
        let (s_row, n_row) = self.data[at..at + 2 * self.padded].split_at(self.padded);
        for ((s, n), (&a, &b)) in sums
            .iter_mut()
            .zip(counts.iter_mut())
            .zip(s_row.iter().zip(n_row))
        {
            *s += sign * a;
            *n += sign * b;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every window width against the plain left-to-right sum (BoxH's anchors: window i covers
    /// columns i - (w - 1) ..= i): equal floats for the direct widths 1 and 2, within float
    /// rounding for the doubling ones.
    /// The validity scans a vector at a time find what `position` and `rposition` find, on
    /// rows of every length with valid costs anywhere.
    #[test]
    fn the_scans_find_the_first_and_last_valid_cost() {
        for len in [0, 1, 15, 16, 17, 40, 384] {
            let mut patterns: Vec<Vec<f32>> = vec![vec![-1.0; len], vec![0.0; len]];
            for at in [0, 1, 15, 16, 17, 33, 200, 383] {
                if at < len {
                    let mut one = vec![-1.0; len];
                    one[at] = 0.5;
                    patterns.push(one);
                    let mut hole = vec![1.0; len];
                    hole[at] = f32::NAN;
                    patterns.push(hole);
                }
            }
            for costs in &patterns {
                let lo = costs.iter().position(|&c| c >= 0.0).unwrap_or(len);
                let hi = costs.iter().rposition(|&c| c >= 0.0).map_or(0, |j| j + 1);
                assert_eq!(first_valid(costs), lo, "{costs:?}");
                assert_eq!(last_valid_end(costs), hi, "{costs:?}");
            }
        }
    }

    /// The direct tree of the odd widths gives the doubling's floats exactly.
    #[test]
    fn direct_tree_equals_the_doubling() {
        let width = 53;
        let values: Vec<f32> = (0..width)
            .map(|i| ((i * 7919) % 101) as f32 * 0.37 + 0.01)
            .collect();
        for w in [3, 5, 7, 9] {
            let mut boxes = BoxH::new(width, w);
            let mut direct = vec![f32::NAN; width + w - 1];
            boxes.sums(&values, &mut direct);
            let mut doubled = vec![f32::NAN; width + w - 1];
            boxes.doubling(width + 2 * (w - 1), &mut doubled);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&direct), bits(&doubled), "w {w}");
        }
    }

    /// `run`'s counts and sums of a row valid over one column span (counts from the span) are
    /// the floats of the summed 0/1 mask and masked costs; also empty, full and holed rows.
    #[test]
    fn span_counts_equal_the_summed_mask() {
        let width = 41;
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for w in 1..=9 {
            for (lo, hi, hole) in [
                (0, 0, None),
                (0, width, None),
                (0, 30, None),
                (7, width, None),
                (5, 33, None),
                (20, 21, None),
                (5, 33, Some(17)),
            ] {
                let costs: Vec<f32> = (0..width)
                    .map(|i| {
                        if i < lo || i >= hi || Some(i) == hole {
                            if i % 2 == 0 {
                                -1.0
                            } else {
                                f32::NAN
                            }
                        } else {
                            ((i * 7919) % 101) as f32 * 0.37 + 0.01
                        }
                    })
                    .collect();
                let mut boxes = BoxH::new(width, w);
                let (mut sums, mut counts) =
                    (vec![f32::NAN; width + w - 1], vec![f32::NAN; width + w - 1]);
                boxes.run(&costs, &mut sums, &mut counts);
                let valid: Vec<f32> = costs
                    .iter()
                    .map(|&c| if c >= 0.0 { 1.0 } else { 0.0 })
                    .collect();
                let masked: Vec<f32> = costs
                    .iter()
                    .map(|&c| if c >= 0.0 { c } else { 0.0 })
                    .collect();
                let (mut want_sums, mut want_counts) =
                    (vec![f32::NAN; width + w - 1], vec![f32::NAN; width + w - 1]);
                boxes.sums(&valid, &mut want_counts);
                boxes.sums(&masked, &mut want_sums);
                assert_eq!(bits(&counts), bits(&want_counts), "w {w}, span {lo}..{hi}");
                assert_eq!(bits(&sums), bits(&want_sums), "w {w}, span {lo}..{hi}");
            }
        }
    }

    /// `slide` gives the floats of subtracting and adding the two rows with `add_row`, whether
    /// their spans match (counts left as they are) or not.
    #[test]
    fn slide_equals_add_row() {
        let (width, w) = (29, 5);
        let mut boxes = BoxH::new(width, w);
        let mut ring = RowRing::new(1, 4, width + w - 1);
        let spans = [(3, 25), (3, 25), (0, 29), (4, 25)];
        for (row, &(lo, hi)) in spans.iter().enumerate() {
            let costs: Vec<f32> = (0..width)
                .map(|i| {
                    if i < lo || i >= hi {
                        -1.0
                    } else {
                        ((i * 31 + row * 17) % 23) as f32 * 0.61 + 0.03
                    }
                })
                .collect();
            let (sums, counts) = ring.row_mut(0, row);
            let span = boxes.run(&costs, sums, counts);
            assert_eq!(span, Some((lo, hi)));
            ring.set_span(0, row, span);
        }
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for (left, entered) in [(0, 1), (1, 2), (1, 3), (2, 3)] {
            let start: Vec<f32> = (0..width + w - 1).map(|i| i as f32 * 1.7 + 9.0).collect();
            let (mut sums, mut counts) = (start.clone(), vec![5.0; width + w - 1]);
            ring.slide(0, Some(left), Some(entered), &mut sums, &mut counts);
            let (mut want_sums, mut want_counts) = (start, vec![5.0; width + w - 1]);
            ring.add_row(0, left, -1.0, &mut want_sums, &mut want_counts);
            ring.add_row(0, entered, 1.0, &mut want_sums, &mut want_counts);
            assert_eq!(bits(&sums), bits(&want_sums), "{left} -> {entered}");
            assert_eq!(bits(&counts), bits(&want_counts), "{left} -> {entered}");
        }
    }

    #[test]
    fn window_sums_match_the_plain_sum() {
        let width = 37;
        let values: Vec<f32> = (0..width)
            .map(|i| ((i * 7919) % 101) as f32 * 0.37 + 0.01)
            .collect();
        for w in 1..=9 {
            let mut boxes = BoxH::new(width, w);
            let mut out = vec![f32::NAN; width + w - 1];
            boxes.sums(&values, &mut out);
            for (i, &got) in out.iter().enumerate() {
                let mut want = 0.0f32;
                for x in i as isize - (w as isize - 1)..=i as isize {
                    if x >= 0 && (x as usize) < width {
                        want += values[x as usize];
                    }
                }
                if w <= 2 {
                    assert_eq!(got, want, "w {w}, anchor {i}");
                } else {
                    assert!(
                        (got - want).abs() <= 1e-5 * want.max(1.0),
                        "w {w}, anchor {i}: {got} vs {want}"
                    );
                }
            }
        }
    }
}
