//! The CPU engine: the pipeline of `shaders/` in Rust, one module per shader written to read
//! like it (`cost.rs` twins `cost.wgsl`, ...), on the same packed [`SweepPlan`], multi-threaded
//! (rayon) and vectorised. The WGSL engine and this one agree stage by stage within the
//! tolerances of `tests/engine/gpu_vs_cpu.rs`.
//!
//! Where the GPU runs one dispatch per stage over the whole image, the CPU fuses a plane's
//! cost, window sums and scoring row by row (`plane.rs`) so the working set stays in cache. Bands
//! of rows run in parallel, each sweeping every plane in order and updating its pixels'
//! winner-take-all state and SGM volume levels right after each plane, while the scores are in
//! cache (no per-plane score images travel through memory).

pub mod aggregate;
pub mod boxes;
pub mod census;
pub mod common;
pub mod cost;
pub mod finalize;
pub mod median;
pub mod occlusion;
pub mod plane;
pub mod refine;
pub mod select;
pub mod sgm;

use std::time::Instant;

use rayon::prelude::*;

use super::gpu_types::*;
use super::plan::SweepPlan;
use super::schedule::{Phase, Schedule};
use super::{check_images, CancelFlag, DepthMaps, StageTimings, SweepError, SweepParams};
use crate::geometry::Rig;
use crate::image::Rgba8Image;
use common::PlanarImage;
use plane::{FrameImages, PlaneScratch};
use select::WtaState;

/// The `maps` buffer of the shaders: MAP_COUNT sections of one reference image each.
pub struct Maps {
    npix: usize,
    pub data: Vec<f32>,
}

impl Maps {
    /// The maps of `npix` pixels in `data` (kept across frame sets), cleared to 0.
    fn reuse(mut data: Vec<f32>, npix: usize) -> Self {
        data.clear();
        data.resize(MAP_COUNT * npix, 0.0);
        Self { npix, data }
    }

    pub fn section(&self, s: usize) -> &[f32] {
        &self.data[s * self.npix..(s + 1) * self.npix]
    }

    /// Every section, mutably (MAP_DEPTH_RAW .. MAP_VISIBLE).
    pub fn sections_mut(&mut self) -> [&mut [f32]; MAP_COUNT] {
        let mut rest = self.data.as_mut_slice();
        std::array::from_fn(|_| {
            let (head, tail) = std::mem::take(&mut rest).split_at_mut(self.npix);
            rest = tail;
            head
        })
    }
}

/// Intermediate results of a CPU run, for stage-by-stage comparison with the GPU.
pub struct CpuTrace {
    /// The `maps` buffer: MAP_COUNT sections of one reference image each.
    pub maps: Vec<f32>,
    pub zbuffer: Vec<u32>,
}

/// The CPU plane-sweep engine. It keeps the plan of the last rig and parameters.
#[derive(Debug)]
pub struct CpuEngine {
    /// The plans of each reference's last rig and parameters (`sweep/coarse.rs`).
    plans: super::coarse::PlanSets,
    /// What the references of one frame set share (`sweep/frame_memo.rs`).
    memo: super::frame_memo::FrameMemo,
    timings: StageTimings,
    fast_paths: bool,
    buffers: Buffers,
    cancel: CancelFlag,
}

/// The buffers of a run, kept across frame sets: fresh ones cost a page fault per 4 KiB on
/// first touch (2-3 ms of the paper configuration's ~15 ms, `perf`), and freeing them
/// costs TLB shootdowns.
#[derive(Default)]
struct Buffers {
    volume: Vec<u16>,
    forward: Vec<u16>,
    backward: Vec<u16>,
    /// The `maps` buffer of the last run (MAP_COUNT sections).
    maps: Vec<f32>,
    /// The z-buffer of the last run (every camera's pixels).
    zbuffer: Vec<u32>,
    state: Option<WtaState>,
    planar: Vec<PlanarImage>,
    /// The images' census words (empty without a census cost).
    census: Vec<Vec<u32>>,
    projections: occlusion::Projections,
    /// One per band of rows, reused by whichever worker sweeps that band.
    bands: Vec<BandScratch>,
}

impl std::fmt::Debug for Buffers {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Buffers")
            .field("volume", &self.volume.len())
            .field("maps", &self.maps.len())
            .field("zbuffer", &self.zbuffer.len())
            .field("bands", &self.bands.len())
            .finish_non_exhaustive()
    }
}

impl Default for CpuEngine {
    fn default() -> Self {
        Self::new()
    }
}

impl CpuEngine {
    pub fn new() -> Self {
        Self {
            plans: Default::default(),
            memo: Default::default(),
            timings: StageTimings::default(),
            fast_paths: true,
            buffers: Buffers::default(),
            cancel: CancelFlag::new(),
        }
    }

    /// Stops a run between planes and between stages once `cancel` is set
    /// ([`SweepError::Cancelled`]).
    pub fn set_cancel(&mut self, cancel: CancelFlag) {
        self.cancel = cancel;
    }

    /// Turns the translation fast path of the cost stage off (tests compare it with the
    /// general path, which must give the same depth).
    pub fn set_fast_paths(&mut self, on: bool) {
        self.fast_paths = on;
    }

    /// Per-stage times of the last frame set (CPU clock).
    pub fn last_timings(&self) -> &StageTimings {
        &self.timings
    }

    /// "CPU engine (N threads)" for reports.
    pub fn label(&self) -> String {
        format!("CPU engine ({} threads)", rayon::current_num_threads())
    }

    /// Runs the sweep on one frame set (one image per rig camera, in rig order).
    pub fn run(
        &mut self,
        rig: &Rig,
        images: &[Rgba8Image],
        params: &SweepParams,
    ) -> Result<DepthMaps, SweepError> {
        let mut plans = std::mem::take(&mut self.plans);
        let result = super::coarse::run(self, plans.for_rig(rig), rig, images, params);
        self.plans = plans;
        result
    }

    /// Runs a prepared plan (e.g. with a custom hypothesis family).
    pub fn run_plan(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: &[Rgba8Image],
    ) -> Result<DepthMaps, SweepError> {
        self.execute(plan, rig, images)?;
        Ok(plan.depth_maps(&self.buffers.maps))
    }

    /// Runs a plan and returns the raw `maps` buffer (MAP_COUNT sections), for stage comparisons.
    pub fn run_plan_raw(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: &[Rgba8Image],
    ) -> Result<Vec<f32>, SweepError> {
        self.execute(plan, rig, images)?;
        Ok(self.buffers.maps.clone())
    }

    /// Runs a plan, keeping the intermediate buffers.
    pub fn trace(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: &[Rgba8Image],
    ) -> Result<CpuTrace, SweepError> {
        self.execute(plan, rig, images)?;
        Ok(CpuTrace {
            maps: self.buffers.maps.clone(),
            zbuffer: self.buffers.zbuffer.clone(),
        })
    }

    /// Runs a plan; the maps and the z-buffer stay in `self.buffers`.
    fn execute(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: &[Rgba8Image],
    ) -> Result<(), SweepError> {
        check_images(rig, images)?;
        let mut clock = StageClock::new();
        let p = &plan.params;
        let npix = plan.pixel_count();
        let planes = plan.num_planes() as usize;
        let mappings: Vec<Vec<cost::Mapping>> = (0..planes)
            .map(|k| cost::mappings(plan, k, self.fast_paths))
            .collect();
        // Scattered samples (any mapping but a translation, the reference's own aside) read
        // interleaved texels.
        let refine = p.subpixel == SUBPIXEL_REFINE && refine::supported(plan);
        let scattered = refine
            || mappings.iter().any(|m| {
                m.iter().enumerate().any(|(i, m)| {
                    i as u32 != p.reference && !matches!(m, cost::Mapping::Translation { .. })
                })
            });
        let mut census = std::mem::take(&mut self.buffers.census);
        census.resize_with(if plan.uses_census() { images.len() } else { 0 }, Vec::new);
        if self.memo.is_active() {
            // Several references of one set: each camera's words once (`frame_memo.rs`).
            for ((words, im), camera) in census.iter_mut().zip(images).zip(&rig.cameras) {
                words.clear();
                self.memo.census_into(&camera.name, im, words);
            }
        } else {
            census.par_iter_mut().zip(images).for_each(|(words, im)| {
                words.clear();
                let (width, height) = (im.width as usize, im.height as usize);
                crate::sweep::census::transform(width, height, &im.pixels, words);
            });
        }
        let mut planar = std::mem::take(&mut self.buffers.planar);
        planar.resize_with(images.len(), PlanarImage::default);
        planar.truncate(images.len());
        planar
            .par_iter_mut()
            .zip(images)
            .enumerate()
            .for_each(|(i, (planar, im))| {
                let (width, height) = (im.width as usize, im.height as usize);
                let words = census.get(i).map(Vec::as_slice);
                planar.fill_from_packed(width, height, &im.pixels, scattered, words)
            });
        let frame = FrameImages { planar, census };
        clock.lap("images");

        let sgm = plan.sgm_paths() > 0;
        let stride = sgm::stride(planes);
        // The volume is kept across frame sets of the same shape: the planes' lanes are written
        // every time, the padding lanes stay PAD.
        let mut volume = std::mem::take(&mut self.buffers.volume);
        if !sgm {
            volume = Vec::new();
        } else if volume.len() != npix * stride {
            volume = vec![sgm::PAD; npix * stride];
        }
        let mut state = match self.buffers.state.take() {
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
        let levels_per_unit = p.sgm_levels_per_unit;
        let cancel = self.cancel.clone();
        // Bands of rows in parallel, each sweeping every plane in order: the winner-take-all
        // state and the volume levels of a band are updated while its scores are in cache,
        // with the planes in the shader's order (no per-plane score images in memory).
        let sweep_band = |scratch: &mut BandScratch,
                          b: usize,
                          st: &mut select::WtaChunk<'_>,
                          mut vol: Option<&mut [u16]>| {
            let rows = b * band..((b + 1) * band).min(height);
            let len = rows.len() * width;
            for (k, plane_mappings) in mappings.iter().enumerate() {
                if cancel.is_cancelled() {
                    return;
                }
                let (score, sel) = (&mut scratch.score[..len], &mut scratch.sel[..len]);
                // Coarse to fine: a plane is costed only from the first to the last row of the
                // band that sweeps it (from the window sums' restart row at or above the first,
                // so the floats are those of the whole band); the rows that do not sweep it
                // score BIG on it (`plan.plane_ranges`).
                let sweeping = |y: usize| plan.sweeps(y, k as u32);
                if let Some(first) = rows.clone().find(|&y| sweeping(y)) {
                    let last = rows.clone().rev().find(|&y| sweeping(y)).unwrap_or(first);
                    let step = aggregate::RESTART_ROWS;
                    let lo = rows.start + (first - rows.start) / step * step;
                    let span = (lo - rows.start) * width..(last + 1 - rows.start) * width;
                    plane::sweep_plane(
                        plan,
                        &frame,
                        plane_mappings,
                        k,
                        lo..last + 1,
                        &mut scratch.plane,
                        &mut score[span.clone()],
                        &mut sel[span],
                    );
                    for (i, y) in rows.clone().enumerate() {
                        if !sweeping(y) {
                            score[i * width..(i + 1) * width].fill(BIG);
                            sel[i * width..(i + 1) * width]
                                .fill(f32::from(crate::sweep::selection::INVALID));
                        }
                    }
                } else {
                    score.fill(BIG);
                    sel.fill(f32::from(crate::sweep::selection::INVALID));
                }
                select_plane(k as f32, score, sel, st);
                if let Some(vol) = vol.as_deref_mut() {
                    // Levels of a group of planes are gathered plane by plane, then written
                    // pixel by pixel (each pixel's group of lanes at once: the band's volume
                    // is far larger than the cache, so a lane at a time would pull every
                    // pixel's lanes in once per plane).
                    let g = k % LEVEL_GROUP;
                    let levels = &mut scratch.levels[g * len..(g + 1) * len];
                    volume_levels(levels_per_unit, score, levels);
                    if g + 1 == LEVEL_GROUP || k + 1 == planes {
                        let first = k - g;
                        write_level_group(&scratch.levels, len, stride, first, g + 1, vol);
                    }
                }
            }
        };
        let mut chunks = state.chunks_mut(band * width);
        let mut scratches = std::mem::take(&mut self.buffers.bands);
        let levels = if sgm { LEVEL_GROUP * band * width } else { 0 };
        scratches.truncate(chunks.len());
        for scratch in &mut scratches {
            scratch.fit(plan, band * width, levels);
        }
        scratches.resize_with(chunks.len(), || {
            BandScratch::new(plan, band * width, levels)
        });
        if sgm {
            chunks
                .par_iter_mut()
                .zip(scratches.par_iter_mut())
                .zip(volume.par_chunks_mut(band * width * stride))
                .enumerate()
                .for_each(|(b, ((st, scratch), vol))| sweep_band(scratch, b, st, Some(vol)));
        } else {
            chunks
                .par_iter_mut()
                .zip(scratches.par_iter_mut())
                .enumerate()
                .for_each(|(b, (st, scratch))| sweep_band(scratch, b, st, None));
        }
        drop(chunks);
        self.buffers.bands = scratches;
        self.buffers.planar = frame.planar;
        self.buffers.census = frame.census;
        clock.lap("sweep");
        cancel.check()?;

        // The rest of the plan's schedule (the sweep above is its first phase).
        let mut maps = Maps::reuse(std::mem::take(&mut self.buffers.maps), npix);
        let mut zbuffer = std::mem::take(&mut self.buffers.zbuffer);
        zbuffer.clear();
        zbuffer.resize(plan.total_camera_pixels, 0);
        for phase in Schedule::of_plan(plan).phases() {
            cancel.check()?;
            match phase {
                Phase::Sweep => {}
                Phase::Sgm => {
                    let colours: &[u32] = if p.reference == NO_CAMERA {
                        &[]
                    } else {
                        &images[p.reference as usize].pixels
                    };
                    let buffers = &mut self.buffers;
                    sgm::run(
                        plan,
                        colours,
                        &volume,
                        &mut buffers.forward,
                        &mut buffers.backward,
                        &cancel,
                    )?;
                    clock.lap("sgm");
                }
                Phase::SgmSelect => {
                    let buffers = &self.buffers;
                    sgm::select(plan, &buffers.forward, &buffers.backward, &mut state);
                    clock.lap("sgm_select");
                }
                Phase::Finalize => {
                    finalize::run(plan, &state, &mut maps);
                    clock.lap("finalize");
                }
                Phase::Refine => {
                    if refine {
                        let frame = FrameImages {
                            planar: std::mem::take(&mut self.buffers.planar),
                            census: std::mem::take(&mut self.buffers.census),
                        };
                        let [raw, ..] = maps.sections_mut();
                        refine::run(plan, &frame, &mut Vec::new(), band, raw);
                        self.buffers.planar = frame.planar;
                        self.buffers.census = frame.census;
                        clock.lap("refine");
                    }
                }
                Phase::Median => {
                    median::run(plan, &mut maps);
                    clock.lap("median");
                }
                Phase::Splat => {
                    occlusion::splat(plan, &maps, &mut zbuffer, &mut self.buffers.projections);
                    clock.lap("splat");
                }
                Phase::Visibility => {
                    occlusion::visibility(plan, &zbuffer, &self.buffers.projections, &mut maps);
                    clock.lap("visibility");
                }
            }
        }
        self.timings = clock.timings();
        self.buffers.volume = volume;
        self.buffers.state = Some(state);
        self.buffers.maps = maps.data;
        self.buffers.zbuffer = zbuffer;
        Ok(())
    }
}

impl super::coarse::PlanRunner for CpuEngine {
    fn run_plan(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: super::coarse::LevelImages<'_>,
    ) -> Result<DepthMaps, SweepError> {
        // The half-size images on the host, once per level and frame set.
        let images = images.on_host(rig, &mut self.memo)?;
        CpuEngine::run_plan(self, plan, rig, images)
    }

    fn timings_mut(&mut self) -> &mut StageTimings {
        &mut self.timings
    }

    fn memo(&mut self) -> &mut super::frame_memo::FrameMemo {
        &mut self.memo
    }
}

/// Wall-clock time per stage, summed over repeated laps of the same name.
struct StageClock {
    last: Instant,
    stages: Vec<(String, f64)>,
}

impl StageClock {
    fn new() -> Self {
        Self {
            last: Instant::now(),
            stages: Vec::new(),
        }
    }

    fn lap(&mut self, name: &str) {
        let now = Instant::now();
        let ms = (now - self.last).as_secs_f64() * 1e3;
        self.last = now;
        match self.stages.iter_mut().find(|(n, _)| n == name) {
            Some((_, total)) => *total += ms,
            None => self.stages.push((name.to_string(), ms)),
        }
    }

    fn timings(self) -> StageTimings {
        StageTimings {
            stages: self.stages,
            gpu_timestamps: false,
        }
    }
}

/// Rows per band: a multiple of the window sums' restart interval (so the sums are the same
/// floats whatever the banding), and bands enough for the threads to balance: at least four per
/// thread when a band's windows reach few rows beyond it, two when they reach more (the halo
/// rows' costs are made by both bands beside them, so fewer, taller bands waste less); twice as
/// many for a narrowed plan. Among those, the height whose busiest thread sweeps the fewest
/// rows, halos included (each thread takes a contiguous share of the bands): the demo's 288
/// rows on 2 threads in 6 bands of 48 (3 x 52 rows per thread) rather than 80, 80, 80, 48
/// (2 x 84).
fn band_rows(height: usize, threads: usize, halo_rows: usize, narrowed: bool) -> usize {
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

/// One band's scratch: the plane sweep's rows and the band's scores of one plane.
struct BandScratch {
    plane: PlaneScratch,
    /// The shape of plan the rows were made for (its parameters and pairs: a narrowed plan
    /// or the other level of a coarse-to-fine sweep keeps them when it has the same).
    shape: (GpuParams, Vec<[u32; 4]>),
    score: Vec<f32>,
    sel: Vec<f32>,
    /// SGM volume levels of up to LEVEL_GROUP planes, plane-major.
    levels: Vec<u16>,
}

impl BandScratch {
    fn new(plan: &SweepPlan, pixels: usize, levels: usize) -> Self {
        Self {
            plane: PlaneScratch::new(plan),
            shape: (plan.params, plan.pairs.clone()),
            score: vec![0.0; pixels],
            sel: vec![0.0; pixels],
            levels: vec![0; levels],
        }
    }

    /// Sized for `plan` (the rows made anew for another plan; every buffer is written before
    /// it is read, so the contents of the last set do not matter).
    fn fit(&mut self, plan: &SweepPlan, pixels: usize, levels: usize) {
        if self.shape.0 != plan.params || self.shape.1 != plan.pairs {
            self.plane = PlaneScratch::new(plan);
            self.shape = (plan.params, plan.pairs.clone());
        }
        self.score.resize(pixels, 0.0);
        self.sel.resize(pixels, 0.0);
        self.levels.resize(levels, 0);
    }
}

/// Planes whose volume levels a band gathers before writing them into the pixels' lanes: one
/// SIMD group of the SGM volume (a multiple of it divides every stride).
const LEVEL_GROUP: usize = sgm::LANES;

common::vectorised_fn! {
/// Plane `k`'s scores of a band's pixels into their winner-take-all state (compiled for AVX2
/// where the CPU has it, as every hot loop here).
fn select_plane(k: f32, scores: &[f32], sels: &[f32], st: &mut select::WtaChunk<'_>) {
    st.update(k, scores, sels);
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

common::vectorised_fn! {
/// The levels of planes `first..first + count` (plane-major in `levels`, `len` pixels each)
/// into lanes `first..` of each pixel's `stride` lanes of `vol`.
fn write_level_group(
    levels: &[u16],
    len: usize,
    stride: usize,
    first: usize,
    count: usize,
    vol: &mut [u16],
) {
    for (i, lanes) in vol.chunks_exact_mut(stride).take(len).enumerate() {
        for (g, lane) in lanes[first..first + count].iter_mut().enumerate() {
            *lane = levels[g * len + i];
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
