//! Twins of `shaders/box_h.wgsl` and `shaders/box_v.wgsl`: window sums (sum, count) of the
//! valid costs, added in the shaders' order (left to right, then top to bottom) so the sums are
//! the same floats. Rows are processed as they are made: a ring keeps the last rows' horizontal
//! sums, so a plane never needs its whole cost slab.

/// Horizontal sums of one row of costs for every padded anchor: index i is the window whose
/// first column is i - (w - 1) (box_h.wgsl). `pad` is scratch of at least width + 2 (w - 1).
#[inline(always)]
pub fn box_h(
    costs: &[f32],
    w: usize,
    pad: &mut [f32],
    pad_ones: &mut [f32],
    sums: &mut [f32],
    counts: &mut [f32],
) {
    let width = costs.len();
    let padded = width + w - 1;
    let (pad, pad_ones) = (
        &mut pad[..width + 2 * (w - 1)],
        &mut pad_ones[..width + 2 * (w - 1)],
    );
    pad[..w - 1].fill(0.0);
    pad_ones[..w - 1].fill(0.0);
    pad[w - 1 + width..].fill(0.0);
    pad_ones[w - 1 + width..].fill(0.0);
    for ((v, one), &c) in pad[w - 1..w - 1 + width]
        .iter_mut()
        .zip(&mut pad_ones[w - 1..w - 1 + width])
        .zip(costs)
    {
        // Invalid costs (< 0) add nothing, as the shader skips them.
        let valid = c >= 0.0;
        *v = if valid { c } else { 0.0 };
        *one = if valid { 1.0 } else { 0.0 };
    }
    let (sums, counts) = (&mut sums[..padded], &mut counts[..padded]);
    sums.fill(0.0);
    counts.fill(0.0);
    for dx in 0..w {
        for ((s, n), (&v, &one)) in sums
            .iter_mut()
            .zip(counts.iter_mut())
            .zip(pad[dx..dx + padded].iter().zip(&pad_ones[dx..dx + padded]))
        {
            *s += v;
            *n += one;
        }
    }
}

/// The horizontal sums of the last rows of one plane, per channel (a ring of `slots` rows).
pub struct RowRing {
    padded: usize,
    slots: usize,
    /// channel x slot x (sums, counts) x padded.
    data: Vec<f32>,
}

impl RowRing {
    pub fn new(channels: usize, slots: usize, padded: usize) -> Self {
        Self {
            padded,
            slots,
            data: vec![0.0; channels * slots * 2 * padded],
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

    /// Vertical sums (box_v.wgsl) of rows `first..end` of `channel` into (sums, counts), added
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
