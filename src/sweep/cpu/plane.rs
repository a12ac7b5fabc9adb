//! One plane, top to bottom: the CPU's fused form of a batch's cost -> box_h ->
//! aggregate dispatches. Each reference row's costs are made once (`cost.rs`), summed along the
//! row into a ring (`boxes.rs`), and every output row whose windows are complete is scored
//! (`aggregate.rs`). The working set is a few rows, so it stays in cache; bands of rows run in
//! parallel (`mod.rs`).

use super::aggregate::{RowScorer, Windows};
use super::boxes::{BoxH, RowRing};
use super::census;
use super::common::{vectorised_fn, PlanarImage};
use super::cost::{self, ColourRow, Mapping, ScoreAcc};
use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

/// Everything one worker needs to sweep planes; made once per worker and reused.
pub struct PlaneScratch {
    colours: Vec<ColourRow>,
    /// Per camera, where the row's pixels land in it (`cost::sample_coords`; not written
    /// for translations).
    coords: Vec<[Vec<f32>; 2]>,
    pair_costs: Vec<Vec<f32>>,
    channel_rows: Vec<Vec<f32>>,
    score_acc: ScoreAcc,
    box_h: BoxH,
    ring: RowRing,
    scorer: RowScorer,
    /// Census costs: per camera, the distances to the reference's words (pairs with the
    /// reference) and the nearest words (pairs of two sampled cameras).
    census_distances: Vec<Vec<f32>>,
    census_nearest: Vec<Vec<u32>>,
    /// Per camera: its census distances of the current row were made with its colours
    /// (scattered samples, `cost::sample_row`).
    census_sampled: Vec<bool>,
    census_bits: Vec<f32>,
    /// Per camera: the current row's samples read in place (`Direct`), or made into `colours`.
    rows: Vec<CameraRow>,
    /// The current row's columns whose costs are read (`SweepPlan::cost_spans`).
    spans: Vec<std::ops::Range<usize>>,
    /// The refinement's hypothesis (`refine.rs`): a depth (ray parameter) per reference pixel,
    /// swept instead of plane `k` with `Mapping::Given`; `None` for the planes.
    pub hypothesis: Option<std::sync::Arc<Vec<f32>>>,
    /// With a hypothesis: the reference's row smoothed as the current camera's samples are
    /// (`matched::MatchedReference`), and its second differences.
    matched: ColourRow,
    reference_differences: super::matched::MatchedReference,
    /// The current row's scores and selection codes (`sweep_plane_rows`).
    row_score: Vec<f32>,
    row_sel: Vec<f32>,
}

impl PlaneScratch {
    pub fn new(plan: &SweepPlan) -> Self {
        let p = &plan.params;
        let width = p.width as usize;
        let windows = Windows::of(plan);
        let channels = p.channels as usize;
        let per_pair = p.aggregation == AGG_PER_PAIR;
        let best_n = if p.scoring == SCORING_BEST_N {
            p.best_n as usize
        } else {
            0
        };
        Self {
            colours: (0..p.cameras).map(|_| cost::colour_row(width)).collect(),
            coords: (0..p.cameras)
                .map(|_| [vec![0.0; width], vec![0.0; width]])
                .collect(),
            pair_costs: (0..plan.pairs.len()).map(|_| vec![0.0; width]).collect(),
            channel_rows: (0..if per_pair { 0 } else { channels })
                .map(|_| vec![0.0; width])
                .collect(),
            score_acc: ScoreAcc::new(width, best_n),
            box_h: BoxH::new(width, windows.w),
            ring: RowRing::new(channels, 2 * windows.h, width + windows.w - 1),
            scorer: RowScorer::new(plan),
            census_distances: (0..if plan.uses_census() { p.cameras } else { 0 })
                .map(|_| vec![0.0; width])
                .collect(),
            census_nearest: (0..if plan.uses_census() { p.cameras } else { 0 })
                .map(|_| vec![0; width])
                .collect(),
            census_sampled: vec![false; p.cameras as usize],
            census_bits: vec![0.0; width],
            rows: vec![CameraRow::Sampled; p.cameras as usize],
            spans: Vec::new(),
            hypothesis: None,
            matched: cost::colour_row(width),
            reference_differences: super::matched::MatchedReference::new(width),
            row_score: vec![0.0; width],
            row_sel: vec![0.0; width],
        }
    }
}

/// Where a camera's colours along the current reference row are.
#[derive(Debug, Clone, Copy)]
enum CameraRow {
    /// Sampled into `PlaneScratch::colours` (NaN where not seen), or the reference's own row.
    Sampled,
    /// A whole-texel shift (translation with both bilinear weights 0, as the Tsukuba demo's
    /// planes): reference columns `lo..hi` are the camera's texels from `at` on, read in place
    /// (no copy of the row); the rest are not seen.
    Direct { lo: usize, hi: usize, at: usize },
}

impl CameraRow {
    /// The in-place row of a whole-texel shift, when `mapping` is one and only pairs with the
    /// reference are costed (all-pairs census costs read the sampled colours' visibility).
    #[inline(always)]
    fn direct(plan: &SweepPlan, image: &PlanarImage, mapping: Mapping, y: usize) -> Option<Self> {
        let Mapping::Translation { dx, dy } = mapping else {
            return None;
        };
        if plan.params.pair_mode == PAIRS_ALL {
            return None;
        }
        let width = plan.params.width as usize;
        match cost::ShiftedSpan::of(image.width, image.height, dx, dy, y, width) {
            None => Some(Self::Direct {
                lo: 0,
                hi: 0,
                at: 0,
            }),
            Some(span) if span.fx == 0.0 && span.fy == 0.0 => Some(Self::Direct {
                lo: span.x_lo,
                hi: span.x_lo + span.count,
                at: span.y0 * image.width + span.first,
            }),
            Some(_) => None,
        }
    }
}

impl PlaneScratch {
    /// [`RowScorer::constant_selection`] of the plan the scratch was made for.
    pub fn constant_selection(&self) -> Option<f32> {
        self.scorer.constant_selection()
    }

    /// The fine sweep (`refine.rs`): makes the reference's second differences
    /// (`refine::MatchedReference`) of the rows a band's hypotheses cost (`rows` with the
    /// windows' reach above and below), once for all of its hypotheses.
    pub fn cover_reference(
        &mut self,
        plan: &SweepPlan,
        images: &FrameImages,
        mappings: &[Mapping],
        rows: std::ops::Range<usize>,
    ) {
        let reference = plan.params.reference;
        if reference == NO_CAMERA {
            return;
        }
        let (up, down) = Windows::of(plan).reach();
        let rows = rows.start.saturating_sub(up)..rows.end + down;
        let along = sampled_between_rows(plan, mappings);
        self.reference_differences
            .cover(&images.planar[reference as usize], rows, along);
    }
}

/// Whether some camera other than the reference samples the hypotheses between rows (any
/// mapping but `Mapping::GivenRow`, whose samples lie on whole rows).
fn sampled_between_rows(plan: &SweepPlan, mappings: &[Mapping]) -> bool {
    let reference = plan.params.reference as usize;
    mappings
        .iter()
        .enumerate()
        .any(|(i, m)| i != reference && !matches!(m, Mapping::GivenRow { .. }))
}

/// The camera images of a frame set as the CPU stages read them.
pub struct FrameImages {
    /// Planar colours per rig camera.
    pub planar: Vec<PlanarImage>,
    /// Census words per rig camera (`sweep/census.rs`); empty with the TSSD cost.
    pub census: Vec<Vec<u32>>,
}

/// Sweeps plane `k` over the band of reference rows `rows`: the best placement's score and
/// selection code of every pixel of the band into `score` and `sel` (row-major from the band's
/// first row; the `best` argument of `select_plane`). The costs of the rows the band's windows
/// reach above and below it are made too (a band's halo).
#[expect(
    clippy::too_many_arguments,
    reason = "each argument is an input of its own (the shader twin's buffers, or slices kept apart so that the loop vectorises); a struct would only rename them"
)]
pub fn sweep_plane(
    plan: &SweepPlan,
    images: &FrameImages,
    mappings: &[Mapping],
    k: usize,
    rows: std::ops::Range<usize>,
    scratch: &mut PlaneScratch,
    score: &mut [f32],
    sel: &mut [f32],
) {
    let (width, first) = (plan.params.width as usize, rows.start);
    sweep_plane_rows(plan, images, mappings, k, rows, scratch, &mut |y, s, se| {
        let at = (y - first) * width;
        score[at..at + width].copy_from_slice(s);
        sel[at..at + width].copy_from_slice(se);
    });
}

/// What is done with each row's scores as soon as they are made (in cache): `(y, score,
/// sel)`, the row's best placement's score and selection code of every pixel.
pub type RowDone<'a> = dyn FnMut(usize, &mut [f32], &mut [f32]) + 'a;

vectorised_fn! {
/// [`sweep_plane`], each row's scores handed to `row_done` as soon as they are made (the
/// sweep's selection and SGM levels then read them from the first level of cache, not from a
/// band's scores in memory).
pub fn sweep_plane_rows(
    plan: &SweepPlan,
    images: &FrameImages,
    mappings: &[Mapping],
    k: usize,
    rows: std::ops::Range<usize>,
    scratch: &mut PlaneScratch,
    row_done: &mut RowDone<'_>,
) {
    let p = &plan.params;
    let (width, height) = (p.width as usize, p.height as usize);
    let windows = Windows::of(plan);
    let (up, down) = windows.reach();
    let mut next_row = rows.start.saturating_sub(up);
    scratch.scorer.begin(rows.start);
    scratch.row_score.resize(width, 0.0);
    scratch.row_sel.resize(width, 0.0);
    for y in rows.clone() {
        let needed = (y + down + 1).min(height);
        while next_row < needed {
            cost_row(plan, images, mappings, k, next_row, scratch);
            next_row += 1;
        }
        scratch.scorer.score_row(
            plan,
            &scratch.ring,
            y,
            height,
            &mut scratch.row_score,
            &mut scratch.row_sel,
        );
        row_done(y, &mut scratch.row_score, &mut scratch.row_sel);
    }
}
}

/// Costs of reference row `y` on plane `k` into the ring: every camera's colours, the pair
/// TSSDs, the channels, their horizontal window sums.
#[inline(always)]
fn cost_row(
    plan: &SweepPlan,
    images: &FrameImages,
    mappings: &[Mapping],
    k: usize,
    y: usize,
    s: &mut PlaneScratch,
) {
    let p = &plan.params;
    let width = p.width as usize;
    let reference = p.reference;
    // Every camera's colours along the row: the reference's own texels (read in place), the
    // others sampled (scattered samples with their census distances to the reference's words).
    let reference_words = (plan.uses_census() && reference != NO_CAMERA).then(|| {
        let at = y * width;
        &images.census[reference as usize][at..at + width]
    });
    // Coarse to fine: only the columns whose costs some sweeping pixel's windows read are
    // sampled (the others are not seen: INVALID costs, which no sweeping pixel reads).
    if s.hypothesis.is_none() {
        plan.cost_spans(y, k as u32, &mut s.spans);
    } else {
        s.spans.clear();
        s.spans.push(0..width);
    }
    // The columns from the first span's to the last's: the pair costs and channels are made
    // there alone (INVALID elsewhere).
    let hull = match (s.spans.first(), s.spans.last()) {
        (Some(first), Some(last)) => first.start..last.end,
        _ => {
            // No column of the row is read on this plane: its window sums are those of a row
            // of INVALID costs (what `BoxH::run` makes of one: zeros, the span at the end).
            for ch in 0..cost_rows(plan) {
                let (sums, counts) = s.ring.row_mut(ch, y);
                sums.fill(0.0);
                counts.fill(0.0);
                s.ring.set_span(ch, y, Some((width, width)));
            }
            return;
        }
    };
    sample_cameras(plan, images, mappings, k, y, reference_words, s);
    let (colours, camera_rows) = (&s.colours, &s.rows);
    // Camera i's colours of reference columns lo..hi (not seen elsewhere), from column lo.
    let row = |i: usize| -> ([&[f32]; 3], usize, usize) {
        let image = &images.planar[i];
        if i as u32 == reference {
            let at = y * image.width;
            let row = std::array::from_fn(|c| &image.channels[c][at..at + width]);
            return (row, 0, width);
        }
        match camera_rows[i] {
            CameraRow::Direct { lo, hi, at } => {
                let row = std::array::from_fn(|c| &image.channels[c][at..at + hi - lo]);
                (row, lo, hi)
            }
            CameraRow::Sampled => (std::array::from_fn(|c| colours[i][c].as_slice()), 0, width),
        }
    };
    if s.hypothesis.is_some() && reference != NO_CAMERA {
        // The fine sweep covers its band's rows once for all hypotheses
        // (`PlaneScratch::cover_reference`); any other row is made here.
        let image = &images.planar[reference as usize];
        let along = sampled_between_rows(plan, mappings);
        if !s.reference_differences.covers(image.width, y, along) {
            s.reference_differences.cover(image, y..y + 1, along);
        }
    }
    for (pair, costs) in plan.pairs.iter().zip(s.pair_costs.iter_mut()) {
        let ((mut a, a_lo, a_hi), (mut b, b_lo, b_hi)) =
            (row(pair[0] as usize), row(pair[1] as usize));
        // The fine sweep's hypotheses sample between texels: the reference is smoothed as
        // much as each camera's samples are (`refine::MatchedReference`).
        let other = match *pair {
            [a, b, ..] if a == reference => Some(b),
            [a, b, ..] if b == reference => Some(a),
            _ => None,
        };
        if let (Some(other), Some(_)) = (other, &s.hypothesis) {
            let image = &images.planar[reference as usize];
            let coords = &s.coords[other as usize];
            let along = !matches!(mappings[other as usize], Mapping::GivenRow { .. });
            s.reference_differences
                .matched(image, y, coords, along, &mut s.matched);
            let matched: [&[f32]; 3] = std::array::from_fn(|c| s.matched[c].as_slice());
            if pair[0] == reference {
                a = matched;
            } else {
                b = matched;
            }
        }
        // Where either is not seen, INVALID (as a NaN colour makes it in `pair_cost_row`), and
        // outside the columns whose costs are read.
        let lo = a_lo.max(b_lo).max(hull.start);
        let hi = a_hi.min(b_hi).min(hull.end);
        if lo >= hi {
            costs.fill(INVALID);
            continue;
        }
        costs[..lo].fill(INVALID);
        costs[hi..].fill(INVALID);
        fn cut(row: [&[f32]; 3], from: std::ops::Range<usize>) -> [&[f32]; 3] {
            row.map(|channel| &channel[from.clone()])
        }
        let (a, b) = (cut(a, lo - a_lo..hi - a_lo), cut(b, lo - b_lo..hi - b_lo));
        cost::pair_cost_row(p.tau, a, b, &mut costs[lo..hi], p.colour_in_alpha != 0);
    }
    if plan.uses_census() {
        census_costs(plan, images, mappings, k, y, hull.clone(), s);
    }
    let rows: &[Vec<f32>] = if p.aggregation == AGG_PER_PAIR {
        &s.pair_costs
    } else {
        let (acc, channels) = (&mut s.score_acc, &mut s.channel_rows);
        cost::scored_channels(plan, &s.pair_costs, hull, acc, channels);
        &s.channel_rows
    };
    for (ch, costs) in rows.iter().enumerate() {
        let (sums, counts) = s.ring.row_mut(ch, y);
        let span = s.box_h.run(costs, sums, counts);
        s.ring.set_span(ch, y, span);
    }
}

/// Every camera's colours along reference row `y` on plane `k` (not the reference's own):
/// read in place where the row maps onto a row of the camera's image (`CameraRow::direct`),
/// else sampled in `s.spans`, with their census distances to the reference's `words`.
#[inline(always)]
fn sample_cameras(
    plan: &SweepPlan,
    images: &FrameImages,
    mappings: &[Mapping],
    k: usize,
    y: usize,
    reference_words: Option<&[u32]>,
    s: &mut PlaneScratch,
) {
    let reference = plan.params.reference;
    for (i, cam) in plan.cameras.iter().enumerate() {
        if i as u32 != reference {
            let direct = s
                .hypothesis
                .is_none()
                .then(|| CameraRow::direct(plan, &images.planar[i], mappings[i], y))
                .flatten();
            s.rows[i] = direct.unwrap_or(CameraRow::Sampled);
            if direct.is_some() {
                s.census_sampled[i] = false;
                continue;
            }
            if let Some(depths) = &s.hypothesis {
                cost::hypothesis_coords(plan, cam, mappings[i], depths, y, &mut s.coords[i]);
            }
            let census = reference_words.map(|words| (words, &mut s.census_distances[i][..]));
            s.census_sampled[i] = cost::sample_row(
                plan,
                &images.planar[i],
                cam,
                mappings[i],
                k,
                y,
                &s.spans,
                &mut s.coords[i],
                &mut s.colours[i],
                census,
            );
        }
    }
}

/// Census costs (`cost = census | ad_census`) of row `y` on plane `k` in the columns `hull`:
/// the pair TSSDs in `s.pair_costs` become the plan's cost (`reference_pair_cost` and the all-pairs loop of
/// cost.wgsl).
#[inline(always)]
fn census_costs(
    plan: &SweepPlan,
    images: &FrameImages,
    mappings: &[Mapping],
    k: usize,
    y: usize,
    hull: std::ops::Range<usize>,
    s: &mut PlaneScratch,
) {
    let p = &plan.params;
    let width = p.width as usize;
    let reference = p.reference;
    let reference_words = (reference != NO_CAMERA).then(|| {
        let at = y * width;
        &images.census[reference as usize][at..at + width]
    });
    for (i, cam) in plan.cameras.iter().enumerate() {
        if i as u32 == reference {
            continue;
        }
        let visible = &s.colours[i][0];
        if let (Some(words), false) = (reference_words, s.census_sampled[i]) {
            census::distance_row(
                plan,
                &images.census[i],
                cam,
                mappings[i],
                y,
                visible,
                &s.coords[i],
                words,
                &mut s.census_distances[i],
            );
        }
        if p.pair_mode == PAIRS_ALL {
            census::nearest_row(
                plan,
                &images.census[i],
                cam,
                mappings[i],
                k,
                y,
                visible,
                &s.coords[i],
                &mut s.census_nearest[i],
            );
        }
    }
    for (pair, costs) in plan.pairs.iter().zip(s.pair_costs.iter_mut()) {
        let (a, b) = (pair[0], pair[1]);
        let bits: &[f32] = if a == reference {
            &s.census_distances[b as usize]
        } else if b == reference {
            &s.census_distances[a as usize]
        } else {
            census::nearest_distance_row(
                &s.census_nearest[a as usize],
                &s.census_nearest[b as usize],
                &mut s.census_bits,
            );
            &s.census_bits
        };
        census::mix_row(plan, &bits[hull.clone()], &mut costs[hull.clone()]);
    }
}

/// Rows of costs the window sums are made of: one per pair (`AGG_PER_PAIR`), else one per
/// channel of the scoring.
fn cost_rows(plan: &SweepPlan) -> usize {
    if plan.params.aggregation == AGG_PER_PAIR {
        plan.pairs.len()
    } else {
        plan.params.channels as usize
    }
}
