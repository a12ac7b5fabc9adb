//! The reference's rows as a camera's bilinear samples see them ([`MatchedReference`]), for
//! the fine sweep's hypotheses (`refine.rs`), whose costs the plane machinery (`plane.rs`)
//! makes: apart from both, so that `refine.rs` imports `plane.rs` and not the other way too.

use super::common::PlanarImage;

/// How much the reference row is smoothed to match a sample's bilinear phase
/// ([`MatchedReference`]): the [v, 1 - 2v, v] kernel with v = `PHASE_SMOOTHING` f (1 - f) for
/// a sample at fraction f of a texel (0.5 and 1 measured too: 60-degree plane refined 0.068 /
/// 0.071, sphere 0.084 / 0.085, with 0.75 in between; docs/notes/quality-history.md).
pub const PHASE_SMOOTHING: f32 = 0.75;

/// The reference's row `y` as a camera's bilinear samples see it: a sample at texel
/// fractions (fx, fy) is the camera's image smoothed by the interpolation, so the reference's
/// sharp texels are smoothed as much, along x by [vx, 1 - 2 vx, vx] (vx = `PHASE_SMOOTHING` fx
/// (1 - fx)) and along y alike. Without it the hypotheses between texels score lower
/// (smoother, less noisy samples) and the fine sweep's parabola leans toward them
/// (docs/quality.md, "Why the steps stay"). [`Self::cover`] the rows (once per band of the
/// fine sweep: the differences are the same for every hypothesis), then [`Self::matched`] per
/// camera and row.
pub struct MatchedReference {
    width: usize,
    /// The rows whose differences are kept: `first..first + rows`.
    first: usize,
    rows: usize,
    /// Whether the differences along the rows were made (samples with whole row coordinates,
    /// `Mapping::GivenRow`, smooth nothing along y).
    with_along: bool,
    /// The rows' second differences across (along x) and along (y) the rows, per channel
    /// (edge texels repeat), row-major from row `first`.
    across: [Vec<f32>; 3],
    along: [Vec<f32>; 3],
}

impl MatchedReference {
    pub fn new(width: usize) -> Self {
        Self {
            width,
            first: 0,
            rows: 0,
            with_along: false,
            across: Default::default(),
            along: Default::default(),
        }
    }

    /// Whether row `y`'s differences are kept (along the rows too, when `along`). They are
    /// the image's that [`Self::cover`] was last given: the fine sweep covers each band's rows
    /// afresh for each frame set.
    pub fn covers(&self, width: usize, y: usize, along: bool) -> bool {
        self.width == width
            && (self.first..self.first + self.rows).contains(&y)
            && (self.with_along || !along)
    }

    /// Makes the second differences of the reference's `rows` (clamped to the image), along
    /// the rows too when `along` (some camera samples between rows).
    pub fn cover(&mut self, image: &PlanarImage, rows: std::ops::Range<usize>, along: bool) {
        let rows = rows.start..rows.end.min(image.height);
        let (w, h) = (image.width, image.height);
        (self.width, self.first, self.rows, self.with_along) = (w, rows.start, rows.len(), along);
        for c in 0..3 {
            self.across[c].resize(rows.len() * w, 0.0);
            self.along[c].resize(if along { rows.len() * w } else { 0 }, 0.0);
        }
        for (r, y) in rows.enumerate() {
            let (up, down) = (y.saturating_sub(1) * w, (y + 1).min(h - 1) * w);
            let at = y * w;
            for (c, channel) in image.channels.iter().enumerate() {
                let row = &channel[at..at + w];
                let across = &mut self.across[c][r * w..(r + 1) * w];
                // (left + right) - 2 centre, the edge texels repeated; the inner columns in
                // a loop that vectorises.
                let edge =
                    |x: usize| row[x.saturating_sub(1)] + row[(x + 1).min(w - 1)] - 2.0 * row[x];
                across[0] = edge(0);
                across[w - 1] = edge(w - 1);
                if w > 2 {
                    let inner = across[1..w - 1].iter_mut().zip(&row[1..w - 1]);
                    for ((o, &centre), (&left, &right)) in
                        inner.zip(row[..w - 2].iter().zip(&row[2..]))
                    {
                        *o = left + right - 2.0 * centre;
                    }
                }
                if along {
                    let (above, below) = (&channel[up..up + w], &channel[down..down + w]);
                    let along = &mut self.along[c][r * w..(r + 1) * w];
                    for (((o, &centre), &a), &b) in along.iter_mut().zip(row).zip(above).zip(below)
                    {
                        *o = a + b - 2.0 * centre;
                    }
                }
            }
        }
    }

    /// The reference's row `y` (whose differences are covered: [`Self::cover`]) as the samples
    /// at `coords` (NaN: not seen, left sharp) see it, into `out` (R, G, B). `along`: whether
    /// the samples' row coordinates may be fractional (false for `Mapping::GivenRow`, whose
    /// vertical weight is 0: the same floats without the term along y).
    #[inline(always)]
    pub fn matched(
        &self,
        image: &PlanarImage,
        y: usize,
        coords: &[Vec<f32>; 2],
        along: bool,
        out: &mut [Vec<f32>; 3],
    ) {
        let w = image.width;
        let (xs, ys) = (&coords[0][..w], &coords[1][..w]);
        let at = y * w;
        let kept = (y - self.first) * w;
        for (c, o) in out.iter_mut().enumerate() {
            let row = &image.channels[c][at..at + w];
            let (across, o) = (&self.across[c][kept..kept + w], &mut o[..w]);
            if !along {
                for x in 0..w {
                    let u = xs[x];
                    // Branch-free (the loop vectorises): NaN coordinates weigh nothing.
                    let fx = if u.is_finite() { u - u.floor() } else { 0.0 };
                    o[x] = row[x] + PHASE_SMOOTHING * (fx * (1.0 - fx) * across[x]);
                }
                continue;
            }
            let along = &self.along[c][kept..kept + w];
            for x in 0..w {
                let (u, v) = (xs[x], ys[x]);
                // Branch-free (the loop vectorises): NaN coordinates weigh nothing.
                let seen = u.is_finite() & v.is_finite();
                let (fx, fy) = if seen {
                    (u - u.floor(), v - v.floor())
                } else {
                    (0.0, 0.0)
                };
                o[x] = row[x]
                    + PHASE_SMOOTHING * (fx * (1.0 - fx) * across[x] + fy * (1.0 - fy) * along[x]);
            }
        }
    }
}
