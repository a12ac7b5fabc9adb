//! The sweep phase of the CPU engine: bands of rows in parallel, each sweeping every plane in
//! order (`plane.rs` fuses a plane's cost, window sums and scoring row by row), its pixels'
//! winner-take-all state and SGM volume levels updated from each row's scores as soon as they
//! are made, while they are in the first level of cache (no per-plane score images travel
//! through memory).

use rayon::prelude::*;

use super::plane::{self, FrameImages, PlaneScratch};
use super::select::{self, WtaState};
use super::{aggregate, common, cost, sgm, sgm_windows};
use crate::sweep::gpu_types::{GpuParams, BIG};
use crate::sweep::plan::SweepPlan;
use crate::sweep::CancelFlag;

/// Sweeps every plane of `plan` over the reference's rows into the winner-take-all `state`
/// (the last set's, reset; or a new one) and, with SGM, the u16 cost `volume` (kept across
/// sets of the same shape: the planes' lanes are written every time, the padding lanes stay
/// PAD). Returns the state and the rows per band. Stops between planes once `cancel` is set
/// (the caller checks it).
pub(super) fn sweep(
    plan: &SweepPlan,
    frame: &FrameImages,
    mappings: &[Vec<cost::Mapping>],
    cancel: &CancelFlag,
    scratches: &mut Vec<BandScratch>,
    state: Option<WtaState>,
    volume: &mut Vec<u16>,
) -> (WtaState, usize) {
    let p = &plan.params;
    let npix = plan.pixel_count();
    let planes = plan.num_planes() as usize;
    let sgm = plan.sgm_paths() > 0;
    // Each pixel's lanes (`sgm_windows::VolumeLayout`: under coarse to fine, its window's alone).
    let layout = sgm_windows::VolumeLayout::of(plan);
    if !sgm {
        *volume = Vec::new();
    } else {
        // Every lane of every window is written below (each group of a window holds one of
        // its pixel's planes, so its band sweeps the group).
        volume.resize(layout.len(), sgm::PAD);
    }
    let mut state = match state {
        Some(mut state) if sgm => {
            state.reset_for_sgm(npix);
            state
        }
        Some(mut state) => {
            state.reset(npix);
            state
        }
        None => WtaState::new(npix),
    };
    let width = p.width as usize;
    let height = p.height as usize;
    let (up, down) = aggregate::Windows::of(plan).reach();
    let narrowed = plan
        .plane_ranges
        .iter()
        .any(|r| *r != [0, planes as u32 - 1]);
    let band = band_rows(height, rayon::current_num_threads(), up + down, narrowed);
    let rows = |b: usize| b * band..((b + 1) * band).min(height);
    let run_band = |scratch: &mut BandScratch,
                    b: usize,
                    st: &mut select::WtaChunk<'_>,
                    vol: Option<&mut [u16]>| {
        let vol = vol.map(|v| (v, &layout));
        sweep_band(plan, frame, mappings, cancel, rows(b), scratch, st, vol)
    };
    let mut chunks = state.chunks_mut(band * width);
    let levels = if sgm { LEVEL_GROUP * band * width } else { 0 };
    scratches.truncate(chunks.len());
    for scratch in scratches.iter_mut() {
        scratch.fit(plan, levels);
    }
    scratches.resize_with(chunks.len(), || BandScratch::new(plan, levels));
    if sgm {
        // The bands' lanes of the volume.
        let mut bands = Vec::with_capacity(chunks.len());
        let mut rest = &mut volume[..];
        for b in 0..chunks.len() {
            let r = rows(b);
            let lanes = layout.row_start(r.end) - layout.row_start(r.start);
            let lanes = lanes.min(rest.len());
            let (band, after) = std::mem::take(&mut rest).split_at_mut(lanes);
            bands.push(band);
            rest = after;
        }
        chunks
            .par_iter_mut()
            .zip(scratches.par_iter_mut())
            .zip(bands.into_par_iter())
            .enumerate()
            .for_each(|(b, ((st, scratch), vol))| run_band(scratch, b, st, Some(vol)));
    } else {
        chunks
            .par_iter_mut()
            .zip(scratches.par_iter_mut())
            .enumerate()
            .for_each(|(b, (st, scratch))| run_band(scratch, b, st, None));
    }
    drop(chunks);
    (state, band)
}

/// One band of rows (`rows`, its winner-take-all state `st`, its pixels' SGM lanes `vol`):
/// every plane in the shader's order, each costed from the first to the last row of the band
/// that sweeps it, scored, selected and written as volume levels while in cache.
#[expect(
    clippy::too_many_arguments,
    reason = "each argument is an input of its own (the shader twin's buffers, or slices kept apart so that the loop vectorises); a struct would only rename them"
)]
fn sweep_band(
    plan: &SweepPlan,
    frame: &FrameImages,
    mappings: &[Vec<cost::Mapping>],
    cancel: &CancelFlag,
    rows: std::ops::Range<usize>,
    scratch: &mut BandScratch,
    st: &mut select::WtaChunk<'_>,
    mut vol: Option<(&mut [u16], &sgm_windows::VolumeLayout)>,
) {
    let width = plan.params.width as usize;
    let planes = mappings.len();
    let levels_per_unit = plan.params.sgm_levels_per_unit;
    let len = rows.len() * width;
    // With SGM only the winner is needed (its uniqueness is read off the volume later), and
    // of a plan whose scores all carry one selection code (a stereo pair) only its score.
    let constant = scratch.plane.constant_selection();
    let selecting = match (vol.is_some(), constant) {
        (false, _) => Selecting::All,
        (true, None) => Selecting::Best,
        (true, Some(_)) => Selecting::Lowest,
    };
    // The level of a pixel that does not sweep a plane (it scores BIG there).
    let idle_level = sgm::volume_level(levels_per_unit, BIG);
    // Whether some pixel of the band sweeps a plane of the current group of volume levels.
    let mut group_swept = false;
    for (k, plane_mappings) in mappings.iter().enumerate() {
        if cancel.is_cancelled() {
            return;
        }
        // Coarse to fine: a plane is costed only from the first to the last row of the
        // band that sweeps it (from the window sums' restart row at or above the first,
        // so the floats are those of the whole band), and in each row only in the columns
        // whose costs a sweeping pixel's windows read (`SweepPlan::cost_spans`); the pixels
        // that do not sweep it score BIG on it (`plan.plane_ranges`, per tile). `swept`: the
        // band's rows that may score less than BIG. Each row is selected (and made into
        // volume levels) as soon as it is scored, while in cache.
        let g = k % LEVEL_GROUP;
        let mut levels = vol
            .is_some()
            .then(|| &mut scratch.levels[g * len..(g + 1) * len]);
        let sweeping = |y: usize| plan.sweeps(y, k as u32);
        let swept = rows.clone().find(|&y| sweeping(y)).map(|first| {
            let last = rows.clone().rev().find(|&y| sweeping(y)).unwrap_or(first);
            let step = aggregate::RESTART_ROWS;
            let lo = rows.start + (first - rows.start) / step * step;
            let idle = &mut scratch.idle;
            let mut row_done = |y: usize, score: &mut [f32], sel: &mut [f32]| {
                plan.idle_spans(y, k as u32, idle);
                for idle in idle.iter() {
                    score[idle.clone()].fill(BIG);
                    sel[idle.clone()].fill(f32::from(crate::sweep::selection::INVALID));
                }
                // The rows outside `swept` are not selected: a BIG score never wins
                // (`update_best` keeps a strictly better one) and a pixel's planes are one
                // run (`plan.plane_ranges`), so BIG scores before its run leave its state as
                // it began and those after it change only the streaming fields (`last`,
                // `min_to_last`) read at a new winner, which no BIG score makes: the same
                // maps as selecting them all (the shader's way; `narrowed_plane_ranges_agree`).
                let at = (y - rows.start) * width..(y + 1 - rows.start) * width;
                select_plane(
                    k as f32,
                    score,
                    sel,
                    &mut st.sub(at.start, at.end),
                    selecting,
                );
                if let Some(levels) = levels.as_deref_mut() {
                    volume_levels(levels_per_unit, score, &mut levels[at]);
                }
            };
            plane::sweep_plane_rows(
                plan,
                frame,
                plane_mappings,
                k,
                lo..last + 1,
                &mut scratch.plane,
                &mut row_done,
            );
            (lo - rows.start) * width..(last + 1 - rows.start) * width
        });
        let swept = swept.unwrap_or(0..0);
        if let Some((vol, layout)) = vol.as_mut() {
            // Levels of a group of planes are gathered plane by plane, then written
            // pixel by pixel (each pixel's group of lanes at once: the band's volume
            // is far larger than the cache, so a lane at a time would pull every
            // pixel's lanes in once per plane). Only the pixels whose window holds the group
            // have its lanes (`sgm_windows::VolumeLayout`): a group no pixel of the band sweeps is in
            // none of their windows.
            let levels = &mut scratch.levels[g * len..(g + 1) * len];
            levels[..swept.start].fill(idle_level);
            levels[swept.end..].fill(idle_level);
            group_swept |= !swept.is_empty();
            if g + 1 == LEVEL_GROUP || k + 1 == planes {
                let first = k - g;
                if group_swept {
                    let group = Group {
                        rows: rows.clone(),
                        first,
                        count: g + 1,
                    };
                    write_level_group(&scratch.levels, len, layout, group, vol);
                }
                group_swept = false;
            }
        }
    }
    if let (Selecting::Lowest, Some(sel)) = (selecting, constant) {
        st.settle_constant(sel);
    }
}

/// How much of the winner-take-all state a band's sweep keeps.
#[derive(Debug, Clone, Copy)]
enum Selecting {
    /// Every field (`WtaChunk::update`): the local winner-take-all's maps.
    All,
    /// The winner, its plane and selection (`WtaChunk::update_best`): SGM plans, whose
    /// selection writes the rest.
    Best,
    /// The best score alone (`WtaChunk::update_lowest`, settled with the plan's one selection
    /// code after the last plane): SGM plans whose every score carries that code.
    Lowest,
}

/// Rows per band: a multiple of the window sums' restart interval (so the sums are the same
/// floats whatever the banding), and bands enough for the threads to balance: at least four per
/// thread when a band's windows reach few rows beyond it, two when they reach more (the halo
/// rows' costs are made by both bands beside them, so fewer, taller bands waste less); twice as
/// many for a narrowed plan. Among those, the height whose busiest thread sweeps the fewest
/// rows, halos included (each thread takes a contiguous share of the bands): the demo's 288
/// rows on 2 threads in 6 bands of 48 (3 x 52 rows per thread) rather than 80, 80, 80, 48
/// (2 x 84).
pub(super) fn band_rows(height: usize, threads: usize, halo_rows: usize, narrowed: bool) -> usize {
    const STEP: usize = aggregate::RESTART_ROWS;
    // Narrowed rows (coarse to fine): a band skips only the planes none of its rows needs, so
    // bands half as tall skip more (9 cameras, 57 planes: 119 -> 110 ms per set).
    let per_thread = if halo_rows <= 2 { 4 } else { 2 } * if narrowed { 2 } else { 1 };
    let threads = threads.max(1);
    let min_bands = (per_thread * threads).min(height.div_ceil(STEP));
    let busiest = |band: usize| {
        let bands = height.div_ceil(band);
        let (share, mut rows) = (bands.div_ceil(threads), 0);
        for b in 0..share {
            rows += (height - (b * band).min(height)).min(band) + halo_rows;
        }
        rows
    };
    (1..=height.div_ceil(STEP))
        .map(|m| m * STEP)
        .filter(|&band| height.div_ceil(band) >= min_bands)
        .min_by_key(|&band| (busiest(band), band))
        .unwrap_or(STEP)
}

/// One band's scratch: the plane sweep's rows and the band's volume levels of a group of planes.
pub(super) struct BandScratch {
    plane: PlaneScratch,
    /// The shape of plan the rows were made for (its parameters and pairs: a narrowed plan
    /// or the other level of a coarse-to-fine sweep keeps them when it has the same).
    shape: (GpuParams, Vec<[u32; 4]>),
    /// SGM volume levels of up to LEVEL_GROUP planes, plane-major.
    levels: Vec<u16>,
    /// A row's column spans that do not sweep the current plane (`SweepPlan::idle_spans`).
    idle: Vec<std::ops::Range<usize>>,
}

impl BandScratch {
    fn new(plan: &SweepPlan, levels: usize) -> Self {
        Self {
            plane: PlaneScratch::new(plan),
            shape: (plan.params, plan.pairs.clone()),
            levels: vec![0; levels],
            idle: Vec::new(),
        }
    }

    /// Sized for `plan` (the rows made anew for another plan; every buffer is written before
    /// it is read, so the contents of the last set do not matter).
    fn fit(&mut self, plan: &SweepPlan, levels: usize) {
        if self.shape.0 != plan.params || self.shape.1 != plan.pairs {
            self.plane = PlaneScratch::new(plan);
            self.shape = (plan.params, plan.pairs.clone());
        }
        self.levels.resize(levels, 0);
    }
}

/// Planes whose volume levels a band gathers before writing them into the pixels' lanes: one
/// SIMD group of the SGM volume (a multiple of it divides every stride).
const LEVEL_GROUP: usize = sgm::LANES;

common::vectorised_fn! {
/// Plane `k`'s scores of a band's pixels into their winner-take-all state (compiled for AVX2
/// where the CPU has it, as every hot loop here), as much of it as `selecting` says.
fn select_plane(k: f32, scores: &[f32], sels: &[f32], st: &mut select::WtaChunk<'_>, selecting: Selecting) {
    match selecting {
        Selecting::All => st.update(k, scores, sels),
        Selecting::Best => st.update_best(k, scores, sels),
        Selecting::Lowest => st.update_lowest(scores),
    }
}
}

common::vectorised_fn! {
/// One plane's scores as SGM volume levels.
fn volume_levels(levels_per_unit: f32, scores: &[f32], levels: &mut [u16]) {
    for (level, &score) in levels.iter_mut().zip(scores) {
        *level = sgm::volume_level(levels_per_unit, score);
    }
}
}

/// A group of planes of one band whose levels go into the volume.
struct Group {
    /// The band's rows.
    rows: std::ops::Range<usize>,
    /// Its first plane (a multiple of LEVEL_GROUP) and how many planes it has (fewer than
    /// LEVEL_GROUP only at the last plane).
    first: usize,
    count: usize,
}

common::vectorised_fn! {
/// The levels of a group of planes (plane-major in `levels`, `len` pixels each) into the lanes
/// of the band's pixels whose window holds the group (`vol`: the band's lanes of `layout`).
/// The lanes past the last plane are PAD.
fn write_level_group(
    levels: &[u16],
    len: usize,
    layout: &sgm_windows::VolumeLayout,
    group: Group,
    vol: &mut [u16],
) {
    let Group { rows, first, count } = group;
    let width = len / rows.len().max(1);
    let base = layout.row_start(rows.start);
    let g = first / LEVEL_GROUP;
    let tile = crate::sweep::plan::RANGE_TILE as usize;
    let mut rows_of: [&[u16]; LEVEL_GROUP] = [&[]; LEVEL_GROUP];
    for (j, row) in rows_of.iter_mut().enumerate().take(count) {
        *row = &levels[j * len..(j + 1) * len];
    }
    for (i, y) in rows.enumerate() {
        for x0 in (0..width).step_by(tile) {
            let (at, window) = layout.pixel(x0, y);
            let groups = window.groups();
            if !groups.contains(&g) {
                continue;
            }
            // The tile's pixels side by side, each its window's lanes.
            let (lanes, skip) = (window.lanes(), (g - groups.start) * LEVEL_GROUP);
            let at = at - base + skip;
            for x in x0..(x0 + tile).min(width) {
                let from = at + (x - x0) * lanes;
                let Some(out) = vol.get_mut(from..from + LEVEL_GROUP) else {
                    continue;
                };
                // Each pixel's LEVEL_GROUP lanes gathered from the planes' rows into one array
                // and stored at once (a scalar load and store per level was 61 M instructions of
                // a demo set and its warm-up).
                let mut lanes = [sgm::PAD; LEVEL_GROUP];
                let p = i * width + x;
                if count == LEVEL_GROUP {
                    // A whole group: the count known to the compiler (unrolled, in one vector).
                    for (level, row) in lanes.iter_mut().zip(&rows_of) {
                        *level = row[p];
                    }
                } else {
                    for (level, row) in lanes.iter_mut().zip(&rows_of).take(count) {
                        *level = row[p];
                    }
                }
                out.copy_from_slice(&lanes);
            }
        }
    }
}
}

#[cfg(test)]
mod tests {
    use super::band_rows;

    #[test]
    fn bands_balance_the_threads() {
        // The demo (288 rows, 5x5 windows: 4 halo rows) on 2 threads: 6 bands of 48.
        assert_eq!(band_rows(288, 2, 4, false), 48);
        // The paper's configuration (240 rows, shiftable 2x2): 8 bands of 32, as before.
        assert_eq!(band_rows(240, 2, 1, false), 32);
        // Always a multiple of the restart interval, and enough bands for the threads.
        for height in [1, 15, 16, 17, 100, 288, 375, 480, 960] {
            for threads in [1, 2, 3, 8, 16] {
                for (halo, narrowed) in [(1, false), (4, false), (4, true), (8, true)] {
                    let band = band_rows(height, threads, halo, narrowed);
                    assert!(band > 0 && band.is_multiple_of(super::aggregate::RESTART_ROWS));
                    let wanted = (2 * threads).min(height.div_ceil(16));
                    assert!(height.div_ceil(band) >= wanted, "{height} {threads} {halo}");
                }
            }
        }
    }
}
