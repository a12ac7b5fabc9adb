//! The joint (colour-weighted) median of the depth after the sweep (issue 29): each pixel takes
//! the weighted median of its window's depths, a neighbour weighing exp(-|colour difference| /
//! `joint_median_colour`) by its colour's L1 distance to the pixel's own in the reference
//! image (Ma et al. 2013's weighted median post-processing). Windows straddle depth edges and
//! SGM smooths across them, so a foreground surface spills a few pixels into the background
//! beside it ("edge fattening"); those pixels have the background's colour, so the background
//! pixels of their window outweigh the foreground ones and the median puts the edge back on
//! the colour edge. Invalid pixels take their window's median too where they have valid
//! neighbours of their own colour (`joint_median_fill`; measured: filling is better than
//! keeping them invalid on every public set with ground truth).
//!
//! A host post-step of both engines' results (`coarse::run`), so the two engines give the
//! same depth whenever their raw maps agree. The median is taken over the planes' bins (the
//! depth's nearest plane in inverse depth): a pixel whose own bin is the median one keeps its
//! sub-plane depth untouched (a flat or smooth region is left as it was); any other takes the
//! weighted mean inverse depth of the window's pixels in the median bin.

use rayon::prelude::*;

use super::SweepParams;
use crate::image::{ImageF32, Rgba8Image};

/// Colour L1 distances 0..=765 (three 8-bit channels).
const MAX_COLOUR_DISTANCE: usize = 3 * 255;

/// The window weight an invalid pixel needs to be filled (one neighbour of its own colour).
const MIN_FILL_WEIGHT: f32 = 1.0;

/// How the filter maps a depth to its plane bin.
#[derive(Debug, Clone, Copy)]
pub struct Bins {
    /// Inverse depth of bin 0 (the farthest plane), 1/m.
    pub inverse_far: f32,
    /// Inverse-depth step between bins (the plane spacing), 1/m.
    pub step: f32,
    /// Number of bins (the planes).
    pub count: usize,
}

impl Bins {
    /// The bins of the sweep's planes (uniform in inverse depth from `max_depth_m` to
    /// `min_depth_m`); `None` for fewer than two planes or a degenerate range.
    pub fn of_params(params: &SweepParams) -> Option<Self> {
        let (near, far) = (1.0 / params.min_depth_m, 1.0 / params.max_depth_m);
        let count = params.num_planes as usize;
        let step = ((near - far) / (count.max(2) - 1) as f64) as f32;
        (count >= 2 && step > 0.0 && step.is_finite()).then_some(Self {
            inverse_far: far as f32,
            step,
            count,
        })
    }

    /// The bin of inverse depth `q`, clamped to the planes.
    fn of(&self, q: f32) -> u32 {
        let k = ((q - self.inverse_far) / self.step).round();
        k.clamp(0.0, (self.count - 1) as f32) as u32
    }
}

/// The filter's settings.
#[derive(Debug, Clone, Copy)]
pub struct JointMedian {
    /// Window radius, pixels ((2r + 1)^2 window); 0 = off.
    pub radius: u32,
    /// L1 RGB distance (0..765) at which a neighbour's weight falls to 1/e.
    pub colour: f32,
    /// Whether invalid pixels take their window's median (from neighbours of their colour).
    pub fill: bool,
}

impl JointMedian {
    pub fn of_params(params: &SweepParams) -> Self {
        Self {
            radius: params.joint_median_radius,
            colour: params.joint_median_colour,
            fill: params.joint_median_fill,
        }
    }

    /// Filters `depth` (metres, NaN invalid) in place, guided by `guide` (the reference
    /// image, the same size); nothing when off or when the sizes differ.
    pub fn apply(&self, depth: &mut ImageF32, guide: &Rgba8Image, bins: &Bins) {
        let (width, height) = (depth.width as usize, depth.height as usize);
        if self.radius == 0
            || self.colour.is_nan()
            || self.colour <= 0.0
            || guide.width != depth.width
            || guide.height != depth.height
            || width * height == 0
        {
            return;
        }
        let weights: Vec<f32> = (0..=MAX_COLOUR_DISTANCE)
            .map(|d| (-(d as f32) / self.colour).exp())
            .collect();
        // Each pixel's inverse depth and bin (u32::MAX: invalid), read (2r + 1)^2 times.
        let inverse: Vec<f32> = depth.data.iter().map(|&z| 1.0 / z).collect();
        let bin: Vec<u32> = inverse
            .iter()
            .map(|&q| {
                if q.is_finite() && q > 0.0 {
                    bins.of(q)
                } else {
                    u32::MAX
                }
            })
            .collect();
        let window = Window {
            width,
            height,
            radius: self.radius as usize,
            inverse: &inverse,
            bin: &bin,
            colours: &guide.pixels,
            weights: &weights,
            fill: self.fill,
        };
        let uniform = uniform_windows(&bin, width, height, self.radius as usize);
        depth.data.par_chunks_mut(width).enumerate().for_each_init(
            || Histogram::new(bins.count),
            |hist, (y, row)| {
                for (x, out) in row.iter_mut().enumerate() {
                    // Every valid depth of the window in the pixel's own bin: the median is
                    // that bin, nothing changes (most pixels; the histogram is skipped).
                    if uniform[y * width + x] {
                        continue;
                    }
                    if let Some(q) = window.median(hist, x, y) {
                        *out = 1.0 / q;
                    }
                }
            },
        );
    }
}

/// For each pixel, whether it is valid and every valid bin of its window is its own: the
/// window's smallest and largest valid bins, by separable passes (rows, then columns).
fn uniform_windows(bin: &[u32], width: usize, height: usize, radius: usize) -> Vec<bool> {
    // (smallest, largest) valid bin of each pixel's row span; (MAX, 0) where none is valid.
    let mut spans = vec![(u32::MAX, 0u32); bin.len()];
    spans
        .par_chunks_mut(width)
        .zip(bin.par_chunks(width))
        .for_each(|(out, row)| {
            for (x, o) in out.iter_mut().enumerate() {
                let span = &row[x.saturating_sub(radius)..=(x + radius).min(width - 1)];
                *o = span.iter().fold((u32::MAX, 0), |(lo, hi), &b| {
                    if b == u32::MAX {
                        (lo, hi)
                    } else {
                        (lo.min(b), hi.max(b))
                    }
                });
            }
        });
    let mut uniform = vec![false; bin.len()];
    uniform
        .par_chunks_mut(width)
        .enumerate()
        .for_each(|(y, out)| {
            let (y0, y1) = (y.saturating_sub(radius), (y + radius).min(height - 1));
            for (x, o) in out.iter_mut().enumerate() {
                let own = bin[y * width + x];
                *o = own != u32::MAX
                    && (y0..=y1).all(|qy| {
                        let (lo, hi) = spans[qy * width + x];
                        lo >= own && (hi <= own)
                    });
            }
        });
    uniform
}

/// What a pixel's window reads.
struct Window<'a> {
    width: usize,
    height: usize,
    radius: usize,
    inverse: &'a [f32],
    bin: &'a [u32],
    colours: &'a [u32],
    weights: &'a [f32],
    fill: bool,
}

/// One worker's per-bin sums, cleared after each pixel over the bins it touched.
struct Histogram {
    weight: Vec<f32>,
    weighted_inverse: Vec<f32>,
}

impl Histogram {
    fn new(bins: usize) -> Self {
        Self {
            weight: vec![0.0; bins],
            weighted_inverse: vec![0.0; bins],
        }
    }
}

fn colour_distance(a: u32, b: u32) -> usize {
    let channel = |shift: u32| ((a >> shift) & 0xff).abs_diff((b >> shift) & 0xff) as usize;
    channel(0) + channel(8) + channel(16)
}

impl Window<'_> {
    /// The new inverse depth of pixel (x, y), or `None` to keep its depth.
    fn median(&self, hist: &mut Histogram, x: usize, y: usize) -> Option<f32> {
        let pix = y * self.width + x;
        if !self.fill && self.bin[pix] == u32::MAX {
            return None;
        }
        let own_colour = self.colours[pix];
        let (x0, x1) = (
            x.saturating_sub(self.radius),
            (x + self.radius).min(self.width - 1),
        );
        let (y0, y1) = (
            y.saturating_sub(self.radius),
            (y + self.radius).min(self.height - 1),
        );
        let (mut lo, mut hi) = (u32::MAX, 0u32);
        let mut total = 0.0f32;
        for qy in y0..=y1 {
            let row = qy * self.width;
            for q in row + x0..=row + x1 {
                let b = self.bin[q];
                if b == u32::MAX {
                    continue;
                }
                let w = self.weights[colour_distance(own_colour, self.colours[q])];
                hist.weight[b as usize] += w;
                hist.weighted_inverse[b as usize] += w * self.inverse[q];
                total += w;
                lo = lo.min(b);
                hi = hi.max(b);
            }
        }
        // An invalid pixel is filled only from neighbours of its own colour: at least as much
        // weight as a valid pixel's own (1), so an object does not spread into an unmatched
        // background of another colour (the rings' black backdrop).
        let invalid = self.bin[pix] == u32::MAX;
        if lo > hi || (invalid && total < MIN_FILL_WEIGHT) {
            for b in lo..=hi {
                hist.weight[b as usize] = 0.0;
                hist.weighted_inverse[b as usize] = 0.0;
            }
            return None;
        }
        // The first bin whose cumulative weight reaches half the window's.
        let (mut cumulative, mut median) = (0.0f32, hi);
        for b in lo..=hi {
            cumulative += hist.weight[b as usize];
            if cumulative >= 0.5 * total {
                median = b;
                break;
            }
        }
        let (w, wq) = (
            hist.weight[median as usize],
            hist.weighted_inverse[median as usize],
        );
        for b in lo..=hi {
            hist.weight[b as usize] = 0.0;
            hist.weighted_inverse[b as usize] = 0.0;
        }
        if self.bin[pix] == median || w <= 0.0 {
            return None;
        }
        Some(wq / w)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const BINS: Bins = Bins {
        inverse_far: 0.0,
        step: 0.1,
        count: 20,
    };

    fn grey(v: u8) -> u32 {
        Rgba8Image::pack(v, v, v)
    }

    /// A 16x9 image, dark left of column `edge` and bright from it on, and a depth map.
    fn scene(edge: usize, depth_at: impl Fn(usize, usize) -> f32) -> (ImageF32, Rgba8Image) {
        let (w, h) = (16usize, 9usize);
        let guide = Rgba8Image {
            width: w as u32,
            height: h as u32,
            pixels: (0..w * h)
                .map(|i| if i % w < edge { grey(30) } else { grey(200) })
                .collect(),
        };
        let depth = ImageF32 {
            width: w as u32,
            height: h as u32,
            data: (0..w * h).map(|i| depth_at(i % w, i / w)).collect(),
        };
        (depth, guide)
    }

    const FILTER: JointMedian = JointMedian {
        radius: 4,
        colour: 20.0,
        fill: true,
    };

    #[test]
    fn a_fattened_step_comes_back_to_the_colour_edge() {
        // Near surface (1 m, inverse 1.0) on the dark side, far (2 m, inverse 0.5) on the
        // bright one; the near depth spills two columns past the colour edge at x = 8.
        let (mut depth, guide) = scene(8, |x, _| if x < 10 { 1.0 } else { 2.0 });
        FILTER.apply(&mut depth, &guide, &BINS);
        for y in 0..9 {
            for x in 0..16 {
                let want = if x < 8 { 1.0 } else { 2.0 };
                let got = depth.data[y * 16 + x];
                assert!((got - want).abs() < 1e-5, "({x}, {y}): {got} != {want}");
            }
        }
    }

    #[test]
    fn a_flat_or_smooth_region_is_unchanged() {
        // A ramp within one bin per row and sub-bin noise: every pixel's own bin is its
        // window's median, so nothing moves, not even below a plane.
        let inverse =
            |x: usize, y: usize| 0.98 + 0.002 * x as f32 + 0.005 * ((x * 7 + y * 3) % 5) as f32;
        let (mut depth, guide) = scene(8, |x, y| 1.0 / inverse(x, y));
        let before = depth.data.clone();
        FILTER.apply(&mut depth, &guide, &BINS);
        assert_eq!(depth.data, before);
    }

    /// Pixels whose windows straddle a step (not uniform, so the histogram runs) but whose own
    /// bin is still the median keep their own sub-plane depth, bit for bit; the far side
    /// keeps its own too.
    #[test]
    fn a_pixel_in_the_median_bin_keeps_its_own_depth_beside_a_step() {
        let inverse =
            |x: usize, y: usize| 0.98 + 0.003 * x as f32 + 0.002 * ((x * 7 + y * 3) % 5) as f32;
        let (mut depth, guide) = scene(16, |x, y| if x < 9 { 1.0 / inverse(x, y) } else { 2.0 });
        let before = depth.data.clone();
        let bin: Vec<u32> = before.iter().map(|&z| BINS.of(1.0 / z)).collect();
        let uniform = uniform_windows(&bin, 16, 9, FILTER.radius as usize);
        FILTER.apply(&mut depth, &guide, &BINS);
        for y in 0..9 {
            for x in 5..9 {
                let i = y * 16 + x;
                assert!(!uniform[i], "({x}, {y}): its window holds both bins");
                assert_eq!(depth.data[i].to_bits(), before[i].to_bits(), "({x}, {y})");
            }
        }
        assert_eq!(depth.data, before);
    }

    #[test]
    fn an_invalid_pixel_takes_its_colour_neighbours_depth() {
        let (mut depth, guide) = scene(8, |x, y| {
            if (x, y) == (9, 4) {
                f32::NAN
            } else if x < 8 {
                1.0
            } else {
                2.0
            }
        });
        let mut kept = depth.clone();
        FILTER.apply(&mut depth, &guide, &BINS);
        assert!((depth.data[4 * 16 + 9] - 2.0).abs() < 1e-5);
        JointMedian {
            fill: false,
            ..FILTER
        }
        .apply(&mut kept, &guide, &BINS);
        assert!(kept.data[4 * 16 + 9].is_nan());
    }

    #[test]
    fn an_invalid_region_of_another_colour_stays_invalid() {
        // The bright side has no valid depth: its pixels have no neighbour of their colour to
        // take a depth from, so the dark side's depth does not spread into it.
        let (mut depth, guide) = scene(8, |x, _| if x < 8 { 1.0 } else { f32::NAN });
        FILTER.apply(&mut depth, &guide, &BINS);
        for y in 0..9 {
            for x in 0..16 {
                let got = depth.data[y * 16 + x];
                assert_eq!(got.is_nan(), x >= 8, "({x}, {y}): {got}");
            }
        }
    }

    #[test]
    fn radius_zero_is_off() {
        let (mut depth, guide) = scene(8, |x, _| if x < 10 { 1.0 } else { 2.0 });
        let before = depth.data.clone();
        JointMedian {
            radius: 0,
            ..FILTER
        }
        .apply(&mut depth, &guide, &BINS);
        assert_eq!(depth.data, before);
    }
}
