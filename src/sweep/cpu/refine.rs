//! Continuous depth after the sweep (issue 29, `subpixel_refine`): a fine local sweep of a
//! few hypotheses around each pixel's depth, a fraction of the plane spacing apart, costed
//! from the images themselves with the sweep's own cost, windows and scoring (the views and
//! half the half-sequence picks). Runs after finalize, before the median, on the raw depth.
//!
//! Each pixel's hypotheses sit around a *base surface*: the mean inverse depth of the
//! window's pixels that lie within `SAME_SURFACE` planes of the pixel's own (the stepped
//! winner-take-all or SGM surface smoothed within one surface, so a slanted or curved surface
//! is no longer a staircase). Hypothesis j of every pixel is its base plus `(j - REACH) STEP`
//! plane spacings in inverse depth, and a window sums its pixels' costs each at its own
//! hypothesis j: the window follows the base surface (a slanted support where the surface is
//! slanted) instead of a fronto-parallel plane. The best j and the parabola through it and its
//! neighbours give the depth; a best hypothesis at either end of the range keeps the
//! finalized depth. Each camera's samples are compared with the reference smoothed as much as
//! their bilinear phase smooths them (`MatchedReference`), so that hypotheses between texels
//! are not favoured. WGSL twin: `shaders/refine_base.wgsl` (the base
//! surface), the sweep's cost, box and aggregate stages in refine batches (`Batch::refine`:
//! hypotheses per pixel, the matched reference in cost.wgsl, no plane ranges, no volume), then
//! `shaders/refine_select.wgsl` (this file's last loop).

use std::sync::Arc;

use rayon::prelude::*;

use super::aggregate::Windows;
use super::common::*;
use super::cost::Mapping;
use super::plane::{self, FrameImages, PlaneScratch};
use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

/// Hypotheses on each side of the base surface (3 measured: the same on synthetic slanted
/// planes, Laundry's bad>0.5 23.93 -> 29.56 %: a best hypothesis 0.5 to 0.75 planes off is
/// mostly the data cost's noise, not the surface).
pub const REACH: usize = 2;
/// Their spacing, in plane spacings.
pub const STEP: f32 = 0.25;
/// Window pixels within this many plane spacings of a pixel's inverse depth are on its
/// surface (the base surface's mean).
pub const SAME_SURFACE: f32 = 1.5;

/// Whether the fine sweep can run on `plan`: a census cost between pairs of sampled cameras
/// (`pairs: all`) reads the nearest words of plane k, not of a hypothesis per pixel.
pub fn supported(plan: &SweepPlan) -> bool {
    plan.num_planes() >= 2 && !(plan.uses_census() && plan.params.pair_mode == PAIRS_ALL)
}

/// The inverse depth of plane `k` on `ray` (`inverse_depth` of finalize).
fn inverse_depth(plan: &SweepPlan, k: usize, ray: Vec3) -> f32 {
    let plane = plan.planes[k];
    dot3(xyz(plane), ray) / plane[3]
}

/// Each camera's mapping of the hypotheses, from the sweep's mappings of every plane
/// (`cost::mappings`, in plane order): `Mapping::GivenRow` where the camera sees the reference's
/// rows as rows on every plane (a rectified pair: the mappings of the first and last planes are
/// translations by the same whole number of rows, and the row formula agrees with the
/// projection on a grid of pixels and depths to 1e-3 px), `Mapping::Given` (each sample
/// projected) elsewhere, and everywhere when the sweep's fast paths are off (no translations).
pub fn row_mappings(plan: &SweepPlan, planes: &[Vec<Mapping>]) -> Vec<Mapping> {
    match (planes.first(), planes.last()) {
        (Some(first), Some(last)) => (0..plan.cameras.len())
            .map(|i| row_mapping(plan, i, first[i], last[i]))
            .collect(),
        _ => vec![Mapping::Given; plan.cameras.len()],
    }
}

/// Camera `i`'s mapping of the hypotheses given its mappings of the first and last planes
/// ([`row_mappings`]).
fn row_mapping(plan: &SweepPlan, i: usize, first: Mapping, last_plane: Mapping) -> Mapping {
    let last = plan.num_planes() as usize - 1;
    let (Mapping::Translation { dx: dx0, dy }, Mapping::Translation { dx: dx1, dy: dy1 }) =
        (first, last_plane)
    else {
        return Mapping::Given;
    };
    if dy != dy1 || dy != dy.round() || dx0 == dx1 {
        return Mapping::Given;
    }
    let (width, height) = (plan.params.width as usize, plan.params.height as usize);
    let ray = |x: usize, y: usize| xyz(plan.rays[y * width + x]);
    let (q0, q1) = (
        f64::from(inverse_depth(plan, 0, ray(0, 0))),
        f64::from(inverse_depth(plan, last, ray(0, 0))),
    );
    if q0 == q1 {
        return Mapping::Given;
    }
    let per_q = (dx1 - dx0) / (q1 - q0);
    let (x0, per_q) = ((dx0 - per_q * q0) as f32, per_q as f32);
    let cam = &plan.cameras[i];
    let grid = [0, 1, 2].map(|t| (t * (width - 1) / 2, t * (height - 1) / 2));
    for (gx, _) in grid {
        for (_, gy) in grid {
            let r = ray(gx, gy);
            for k in [0, last / 2, last] {
                let q = inverse_depth(plan, k, r);
                let p = project(cam, [r[0] / q, r[1] / q, r[2] / q]);
                let u = (gx as f32 + x0) + per_q * q;
                let v = gy as f64 + dy;
                let seen = p[2] > 0.0 && inside(cam, [p[0], p[1]]);
                if seen && ((p[0] - u).abs() > 1e-3 || (f64::from(p[1]) - v).abs() > 1e-3) {
                    return Mapping::Given;
                }
            }
        }
    }
    Mapping::GivenRow {
        x0,
        per_q,
        dy: dy as i32,
    }
}

/// Per pixel: the plane spacing in inverse depth and the base surface's inverse depth (NaN
/// where the raw depth is invalid).
fn base_surface(plan: &SweepPlan, raw: &[f32]) -> (Vec<f32>, Vec<f32>) {
    let (width, height) = (plan.params.width as usize, plan.params.height as usize);
    let windows = Windows::of(plan);
    let (rx, ry) = ((windows.w - 1) / 2, (windows.h - 1) / 2);
    let spacing: Vec<f32> = (0..width * height)
        .into_par_iter()
        .map(|pix| {
            let ray = xyz(plan.rays[pix]);
            (inverse_depth(plan, 1, ray) - inverse_depth(plan, 0, ray)).abs()
        })
        .collect();
    let inverse: Vec<f32> = raw
        .iter()
        .map(|&t| {
            if t > 0.0 && t.is_finite() {
                1.0 / t
            } else {
                f32::NAN
            }
        })
        .collect();
    let mut base = vec![f32::NAN; width * height];
    base.par_chunks_mut(width).enumerate().for_each_init(
        || {
            (
                vec![0.0f32; width],
                vec![0.0f32; width],
                vec![0.0f32; width],
            )
        },
        |(sum, count, near), (y, row)| {
            let rows = y.saturating_sub(ry)..(y + ry + 1).min(height);
            let at = y * width;
            base_row(
                &inverse,
                &spacing[at..at + width],
                width,
                rows,
                y,
                rx,
                sum,
                count,
                near,
                row,
            );
        },
    );
    (spacing, base)
}

vectorised_fn! {
    /// Row `y` of the base surface: per pixel, the mean of the window's inverse depths (rows
    /// `rows`, columns within `rx`) that lie within `SAME_SURFACE` plane spacings of its own;
    /// NaN where its own is. The window's offsets outside, the pixels inside, so that the loop
    /// vectorises; each pixel's sums in the window's row-major order (the same floats as one
    /// pixel at a time: a value not on the surface adds +0).
    #[expect(clippy::too_many_arguments, reason = "each argument is an input of its own (the shader twin's buffers, or slices kept apart so that the loop vectorises); a struct would only rename them")]
    fn base_row(
        inverse: &[f32],
        spacing: &[f32],
        width: usize,
        rows: std::ops::Range<usize>,
        y: usize,
        rx: usize,
        sum: &mut [f32],
        count: &mut [f32],
        near: &mut [f32],
        out: &mut [f32],
    ) {
        let q = &inverse[y * width..(y + 1) * width];
        let (sum, count, near, out) =
            (&mut sum[..width], &mut count[..width], &mut near[..width], &mut out[..width]);
        sum.fill(0.0);
        count.fill(0.0);
        for x in 0..width {
            near[x] = SAME_SURFACE * spacing[x];
        }
        for yy in rows {
            let src = &inverse[yy * width..(yy + 1) * width];
            for dx in -(rx as isize)..=rx as isize {
                // Columns x whose neighbour x + dx is inside the row.
                let lo = (-dx).max(0) as usize;
                let hi = (width as isize - dx).min(width as isize).max(lo as isize) as usize;
                let from = (lo as isize + dx) as usize;
                let n = &src[from..from + (hi - lo)];
                let (q, near) = (&q[lo..hi], &near[lo..hi]);
                let (s, c) = (&mut sum[lo..hi], &mut count[lo..hi]);
                for j in 0..n.len() {
                    let on = (n[j] - q[j]).abs() <= near[j];
                    s[j] += if on { n[j] } else { 0.0 };
                    c[j] += if on { 1.0 } else { 0.0 };
                }
            }
        }
        for x in 0..width {
            out[x] = if q[x].is_nan() { f32::NAN } else { sum[x] / count[x] };
        }
    }
}

/// The offset (in hypotheses, -0.5..0.5) of the parabola's minimum through three scores, 0
/// where they do not curve up.
fn parabola(before: f32, best: f32, after: f32) -> f32 {
    let curvature = before - 2.0 * best + after;
    if curvature > 0.0 {
        (0.5 * (before - after) / curvature).clamp(-0.5, 0.5)
    } else {
        0.0
    }
}

/// Refines the raw depth (`MAP_DEPTH_RAW`, ray parameter, NaN invalid) in place. `scratches`
/// are the workers' plane scratches (made for `plan` when there are too few); `band` is the
/// sweep's band height (a multiple of the window sums' restart rows); `mappings` each camera's
/// mapping of the hypotheses ([`row_mappings`]).
pub fn run(
    plan: &SweepPlan,
    images: &FrameImages,
    scratches: &mut Vec<PlaneScratch>,
    band: usize,
    mappings: &[Mapping],
    raw: &mut [f32],
) {
    let (width, height) = (plan.params.width as usize, plan.params.height as usize);
    let (spacing, base) = base_surface(plan, raw);
    let count = 2 * REACH + 1;
    let hypotheses: Vec<Arc<Vec<f32>>> = (0..count)
        .map(|j| {
            let offset = (j as f32 - REACH as f32) * STEP;
            let depths = base
                .par_iter()
                .zip(&spacing)
                .map(|(&q, &dq)| {
                    let q = q + offset * dq;
                    if q > 0.0 {
                        1.0 / q
                    } else {
                        f32::NAN
                    }
                })
                .collect();
            Arc::new(depths)
        })
        .collect();
    let bands = height.div_ceil(band);
    scratches.truncate(bands);
    scratches.resize_with(bands, || PlaneScratch::new(plan));
    raw.par_chunks_mut(band * width)
        .zip(scratches.par_iter_mut())
        .enumerate()
        .for_each(|(b, (raw, scratch))| {
            let rows = b * band..((b + 1) * band).min(height);
            let len = rows.len() * width;
            let mut scores = vec![0.0f32; count * len];
            let mut sel = vec![0.0f32; len];
            scratch.cover_reference(plan, images, mappings, rows.clone());
            for (j, depths) in hypotheses.iter().enumerate() {
                scratch.hypothesis = Some(Arc::clone(depths));
                plane::sweep_plane(
                    plan,
                    images,
                    mappings,
                    0,
                    rows.clone(),
                    scratch,
                    &mut scores[j * len..(j + 1) * len],
                    &mut sel,
                );
            }
            scratch.hypothesis = None;
            let first = rows.start * width;
            for i in 0..len {
                let (q, dq) = (base[first + i], spacing[first + i]);
                if q.is_nan() {
                    continue;
                }
                let score = |j: usize| scores[j * len + i];
                let best = (0..count)
                    .filter(|&j| score(j) < 0.5 * BIG)
                    .min_by(|&a, &b| score(a).total_cmp(&score(b)));
                let Some(j) = best.filter(|&j| j > 0 && j + 1 < count) else {
                    continue;
                };
                let (before, after) = (score(j - 1), score(j + 1));
                let fit = if before < 0.5 * BIG && after < 0.5 * BIG {
                    parabola(before, score(j), after)
                } else {
                    0.0
                };
                let offset = j as f32 - REACH as f32 + fit;
                let refined = q + offset * STEP * dq;
                if refined > 0.0 {
                    raw[i] = 1.0 / refined;
                }
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::CameraModel;
    use crate::sweep::cpu::cost;
    use crate::sweep::cpu::matched::MatchedReference;
    use crate::sweep::SweepParams;
    use crate::synthetic;

    #[test]
    fn parabola_by_hand() {
        // Scores 2, 1, 2: the minimum at the middle; 3, 1, 2: a third of the way to `after`.
        assert_eq!(parabola(2.0, 1.0, 2.0), 0.0);
        assert!((parabola(3.0, 1.0, 2.0) - 1.0 / 6.0).abs() < 1e-6);
        // No upward curvature: no offset; a steep rise on one side puts the minimum almost
        // half a hypothesis toward the other.
        assert_eq!(parabola(1.0, 1.0, 1.0), 0.0);
        assert!(parabola(1.0, 0.9, 100.0) < -0.49);
    }

    /// The matched reference by hand: a sample on a texel leaves the reference sharp; half
    /// way between texels along x smooths it by [3/16, 5/8, 3/16] along the row (v = 0.75 /
    /// 4), and a quarter of the way down by v = 0.75 * 3 / 16 across rows; unseen samples
    /// leave it sharp; edge texels repeat.
    #[test]
    fn matched_reference_by_hand() {
        let (w, h) = (5usize, 3usize);
        let mut spike = vec![0.0f32; w * h];
        spike[w + 2] = 16.0;
        let image = PlanarImage {
            width: w,
            height: h,
            channels: [spike.clone(), spike.clone(), vec![1.0; w * h]],
            texels: Vec::new(),
            grey: false,
        };
        let mut out = [vec![0.0; w], vec![0.0; w], vec![0.0; w]];
        let coords = |xs: [f32; 5], ys: [f32; 5]| [xs.to_vec(), ys.to_vec()];
        let mut reference = MatchedReference::new(w);
        let mut matched_reference =
            |image: &PlanarImage, y, coords: &[Vec<f32>; 2], out: &mut _| {
                reference.cover(image, y..y + 1, true);
                reference.matched(image, y, coords, true, out);
            };
        matched_reference(
            &image,
            1,
            &coords([0.0, 1.0, 2.0, 3.0, 4.0], [1.0; 5]),
            &mut out,
        );
        assert_eq!(out[0], vec![0.0, 0.0, 16.0, 0.0, 0.0]);
        matched_reference(
            &image,
            1,
            &coords([0.5, 1.5, 2.5, 3.5, f32::NAN], [1.0; 5]),
            &mut out,
        );
        assert_eq!(out[0], vec![0.0, 3.0, 10.0, 3.0, 0.0]);
        assert_eq!(out[2], vec![1.0; 5], "a flat channel stays flat");
        matched_reference(&image, 1, &coords([2.0; 5], [1.25; 5]), &mut out);
        // Along y: 16 - 2 * 16 * 0.75 * 3 / 16.
        assert_eq!(out[1][2], 16.0 - 4.5);
        // Row 0 (the edge repeats): the spike below is reached once.
        matched_reference(&image, 0, &coords([2.0; 5], [0.25; 5]), &mut out);
        assert_eq!(out[0][2], 16.0 * 0.75 * 3.0 / 16.0);
    }

    /// The differences covered for a band at once are each row's own, and samples on whole
    /// rows (`Mapping::GivenRow`) give the same floats without the term along y, bit for bit.
    #[test]
    fn a_band_covered_at_once_matches_row_by_row() {
        let (w, h) = (37usize, 9usize);
        let noise = |seed: usize| -> Vec<f32> {
            (0..w * h)
                .map(|i| ((i * 7919 + seed * 104_729) % 255) as f32)
                .collect()
        };
        let image = PlanarImage {
            width: w,
            height: h,
            channels: [noise(1), noise(2), noise(3)],
            texels: Vec::new(),
            grey: false,
        };
        let xs: Vec<f32> = (0..w)
            .map(|x| {
                if x % 11 == 5 {
                    f32::NAN
                } else {
                    x as f32 * 0.93 + 0.37
                }
            })
            .collect();
        let (mut band, mut single) = (MatchedReference::new(w), MatchedReference::new(w));
        band.cover(&image, 2..7, true);
        let mut out = [vec![0.0; w], vec![0.0; w], vec![0.0; w]];
        let mut expected = out.clone();
        for y in 2..7 {
            assert!(band.covers(w, y, true) && band.covers(w, y, false));
            let coords = [xs.clone(), vec![y as f32 + 0.3; w]];
            band.matched(&image, y, &coords, true, &mut out);
            single.cover(&image, y..y + 1, true);
            single.matched(&image, y, &coords, true, &mut expected);
            assert_eq!(out, expected, "row {y}");
            let whole = [xs.clone(), vec![y as f32; w]];
            band.matched(&image, y, &whole, false, &mut out);
            single.matched(&image, y, &whole, true, &mut expected);
            let bits = |v: &[Vec<f32>; 3]| -> Vec<u32> {
                v.iter().flatten().map(|f| f.to_bits()).collect()
            };
            assert_eq!(bits(&out), bits(&expected), "row {y} on whole rows");
        }
        assert!(!band.covers(w, 7, false) && !band.covers(w, 1, false));
        let mut across_only = MatchedReference::new(w);
        across_only.cover(&image, 0..h, false);
        assert!(across_only.covers(w, 4, false) && !across_only.covers(w, 4, true));
    }

    /// What the fine sweep cannot do is refused up front, with the reason: without the
    /// sub-pixel step it refines, and with census costs between two sampled cameras (which
    /// read the nearest words of a plane, not of a per-pixel depth).
    #[test]
    fn what_the_fine_sweep_cannot_do_is_refused() {
        use crate::sweep::{Cost, PairSet, Scoring, SweepError};
        let model = CameraModel::pinhole(synthetic::intrinsics(12, 8));
        let rig = synthetic::row_rig(3, 0.1, model, 1).expect("rig");
        let refined = SweepParams {
            subpixel_refine: true,
            ..SweepParams::default()
        };
        assert!(refined.validate(&rig).is_ok());
        let refused = |p: SweepParams, needle: &str| match p.validate(&rig) {
            Err(SweepError::InvalidParams(m)) => assert!(m.contains(needle), "{m}"),
            other => panic!("expected a refusal, got {other:?}"),
        };
        refused(
            SweepParams {
                subpixel: false,
                ..refined.clone()
            },
            "needs subpixel true",
        );
        refused(
            SweepParams {
                pairs: PairSet::All,
                ..refined.clone()
            },
            "pairs reference or cost tssd",
        );
        refused(
            SweepParams {
                scoring: Scoring::AllPairs,
                cost: Cost::Census,
                ..refined.clone()
            },
            "scoring all_pairs implies",
        );
        let tssd = SweepParams {
            pairs: PairSet::All,
            cost: Cost::Tssd,
            ..refined
        };
        assert!(tssd.validate(&rig).is_ok());
    }

    /// The vectorised base surface is the window mean of one pixel at a time, bit for bit:
    /// every row (the image's first and last rows and columns clip the window), surfaces
    /// within and beyond `SAME_SURFACE` of each other, invalid pixels.
    #[test]
    fn base_row_is_the_scalar_window_mean_bit_for_bit() {
        let (width, height, rx, ry) = (23usize, 9usize, 2usize, 1usize);
        let mut state = 0x2545_f491u32;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            (state >> 8) as f32 / (1 << 24) as f32
        };
        let inverse: Vec<f32> = (0..width * height)
            .map(|i| if i % 11 == 3 { f32::NAN } else { 0.2 + next() })
            .collect();
        let spacing: Vec<f32> = (0..width * height).map(|_| 0.05 + 0.2 * next()).collect();
        let (mut sum, mut count, mut near) = (vec![0.0; width], vec![0.0; width], vec![0.0; width]);
        for y in 0..height {
            let mut row = vec![0.0f32; width];
            let rows = y.saturating_sub(ry)..(y + ry + 1).min(height);
            let at = y * width;
            let spacing = &spacing[at..at + width];
            base_row(
                &inverse, spacing, width, rows, y, rx, &mut sum, &mut count, &mut near, &mut row,
            );
            for x in 0..width {
                let q = inverse[at + x];
                let want = if q.is_nan() {
                    f32::NAN
                } else {
                    let near = SAME_SURFACE * spacing[x];
                    let (mut s, mut c) = (0.0f32, 0.0f32);
                    for yy in y.saturating_sub(ry)..(y + ry + 1).min(height) {
                        for xx in x.saturating_sub(rx)..(x + rx + 1).min(width) {
                            let n = inverse[yy * width + xx];
                            if (n - q).abs() <= near {
                                s += n;
                                c += 1.0;
                            }
                        }
                    }
                    s / c
                };
                assert_eq!(row[x].to_bits(), want.to_bits(), "pixel {x}, {y}");
            }
        }
    }

    /// On a rectified row of cameras every hypothesis of a reference row lands on one camera
    /// row (`Mapping::GivenRow`), where the projection of each sample puts it to 1e-3 px, and
    /// samples outside the camera are not seen in both (the row formula also keeps the first
    /// and last rows' samples that the f32 projection puts a hair outside); converging cameras, and the fast paths
    /// turned off, project each sample (`Mapping::Given`).
    #[test]
    fn hypotheses_on_a_rectified_pair_stay_on_one_row() {
        let (width, height) = (40usize, 12usize);
        let model = CameraModel::pinhole(synthetic::intrinsics(width as u32, height as u32));
        let params = SweepParams {
            num_planes: 16,
            min_depth_m: 1.0,
            max_depth_m: 4.0,
            subpixel_refine: true,
            ..SweepParams::default()
        };
        let rig = synthetic::row_rig(3, 0.1, model, 1).expect("rig");
        let plan = SweepPlan::new(&rig, &params).expect("plan");
        let depths: Vec<f32> = (0..width * height)
            .map(|i| match i % 17 {
                0 => f32::NAN,
                1 => -1.0,
                // Near enough that the outer columns leave the other cameras.
                2 => 0.3,
                _ => 1.0 + 3.0 * (i % 29) as f32 / 28.0,
            })
            .collect();
        // The sweep's mappings of every plane, with its fast paths on and off.
        let sweep = |plan: &SweepPlan, fast: bool| -> Vec<Vec<Mapping>> {
            (0..plan.num_planes() as usize)
                .map(|k| cost::mappings(plan, k, fast))
                .collect()
        };
        let (rows, unmapped) = (
            row_mappings(&plan, &sweep(&plan, true)),
            row_mappings(&plan, &sweep(&plan, false)),
        );
        for i in [0usize, 2] {
            let row = rows[i];
            assert!(
                matches!(row, Mapping::GivenRow { dy: 0, .. }),
                "camera {i}: {row:?}"
            );
            assert_eq!(unmapped[i], Mapping::Given);
            let cam = &plan.cameras[i];
            let mut unseen = 0;
            for y in 0..height {
                let mut fast = [vec![0.0; width], vec![0.0; width]];
                let mut projected = [vec![0.0; width], vec![0.0; width]];
                cost::hypothesis_coords(&plan, cam, row, &depths, y, &mut fast);
                cost::hypothesis_coords(&plan, cam, Mapping::Given, &depths, y, &mut projected);
                for x in 0..width {
                    let (u, p) = (fast[0][x], projected[0][x]);
                    if p.is_nan() {
                        // The projection in f32 puts some samples of the first and last rows
                        // a hair outside the image (-1e-7 px): the row formula keeps them.
                        let edge_row = y == 0 || y == height - 1;
                        assert!(
                            u.is_nan() || edge_row,
                            "camera {i} pixel {x}, {y}: {u} not NaN"
                        );
                        unseen += usize::from(u.is_nan());
                        continue;
                    }
                    assert!(
                        (u - p).abs() < 1e-3,
                        "camera {i} pixel {x}, {y}: {u} vs {p}"
                    );
                    assert_eq!(fast[1][x], y as f32);
                    assert!((projected[1][x] - y as f32).abs() < 1e-3);
                }
            }
            assert!(
                unseen > 3 * height,
                "camera {i}: only {unseen} samples unseen"
            );
        }
        let arc = synthetic::arc_rig(3, 0.2, 2.0, model, 1).expect("arc");
        let plan = SweepPlan::new(&arc, &params).expect("plan");
        assert_eq!(row_mappings(&plan, &sweep(&plan, true))[0], Mapping::Given);
    }

    /// The base surface averages a pixel's window within one surface: a step of many planes
    /// stays a step, a ramp of less than a plane per pixel is kept, invalid pixels stay NaN.
    #[test]
    fn base_surface_keeps_steps_and_ramps() {
        let model = CameraModel::pinhole(synthetic::intrinsics(12, 8));
        let rig = synthetic::row_rig(2, 0.1, model, 0).expect("rig");
        let params = SweepParams {
            num_planes: 16,
            min_depth_m: 1.0,
            max_depth_m: 4.0,
            ..SweepParams::default()
        };
        let plan = SweepPlan::new(&rig, &params).expect("plan");
        let (width, height) = (12usize, 8usize);
        let spacing = (1.0 - 0.25) / 15.0;
        // Left half at inverse depth 0.5, right half a ramp from 0.8 by a tenth of a plane per
        // column; one invalid pixel.
        let mut raw = vec![0.0f32; width * height];
        for y in 0..height {
            for x in 0..width {
                let q = if x < 6 {
                    0.5
                } else {
                    0.8 + 0.1 * spacing * (x - 6) as f32
                };
                raw[y * width + x] = 1.0 / q;
            }
        }
        raw[3 * width + 2] = f32::NAN;
        let (dq, base) = base_surface(&plan, &raw);
        assert!((dq[0] - spacing).abs() < 1e-5, "{} vs {spacing}", dq[0]);
        assert!(base[3 * width + 2].is_nan());
        // Beside the step, each side keeps its own depth.
        assert!((base[4 * width + 5] - 0.5).abs() < 1e-6);
        let at = |x: usize| base[4 * width + x];
        let ramp = |x: usize| 0.8 + 0.1 * spacing * (x - 6) as f32;
        assert!((at(6) - (ramp(6) + ramp(7) + ramp(8)) / 3.0).abs() < 1e-5);
        // Inside the ramp, the window's mean is the ramp itself.
        assert!((at(8) - ramp(8)).abs() < 1e-5);
    }
}
