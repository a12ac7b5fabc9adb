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
mod bands;
pub mod boxes;
pub mod census;
pub mod common;
pub mod cost;
pub mod finalize;
mod gather;
pub mod matched;
pub mod median;
pub mod occlusion;
pub mod plane;
pub mod refine;
pub mod select;
pub mod sgm;
pub mod sgm_select;
pub mod sgm_wide;
pub mod sgm_windows;

use std::time::Instant;

use rayon::prelude::*;

use super::gpu_types::*;
use super::plan::SweepPlan;
use super::schedule::{Phase, Schedule};
use super::{check_images, CancelFlag, DepthMaps, StageTimings, SweepError, SweepParams};
use crate::geometry::Rig;
use crate::image::{Rgba8Image, SetImages};
use bands::BandScratch;
use common::PlanarImage;
use plane::FrameImages;
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
    /// The buffers of the plan size that ran last (`buffers_size`: its width and height).
    buffers: Buffers,
    buffers_size: (u32, u32),
    /// The buffers of the other sizes run recently (the levels of coarse to fine), most recent
    /// last: each level keeps its own, so no set allocates and faults in its cost volume and
    /// path sums again (a raw pair's full-resolution volume is 69 MB, the sums twice that).
    parked: Vec<((u32, u32), Buffers)>,
    /// The rectifications of raw pairs (`rectify_pairs`).
    rectified: super::rectify::Rectifications,
    /// Their resampled images, kept from set to set.
    rectified_images: Vec<Rgba8Image>,
    /// The maps a rectified pair's caller reads ([`CpuEngine::set_wanted_maps`]).
    wanted: super::WantedMaps,
    cancel: CancelFlag,
}

/// How far [`CpuEngine`] runs a plan's phases.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Through {
    /// Every phase: the maps the caller unpacks.
    All,
    /// Up to `finalize`: a level below coarse to fine, whose raw depth alone is read (the
    /// median, splat and visibility write other maps).
    Finalize,
}

/// Sizes whose buffers [`CpuEngine`] keeps beside the current one (the coarse-to-fine levels of
/// a rig; a rig of another size takes the oldest's place).
const PARKED_SIZES: usize = 4;

/// The buffers of a run, kept across frame sets: fresh ones cost a page fault per 4 KiB on
/// first touch (2-3 ms of the paper configuration's ~15 ms, `perf`), and freeing them
/// costs TLB shootdowns.
#[derive(Default)]
struct Buffers {
    volume: Vec<u16>,
    /// The planes whose lanes `volume` holds: its padding lanes are PAD only for these (a plan
    /// with fewer planes of the same lane stride would read the last plan's levels there).
    volume_planes: usize,
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
            buffers_size: (0, 0),
            parked: Vec::new(),
            rectified: Default::default(),
            rectified_images: Vec::new(),
            wanted: super::WantedMaps::ALL,
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
        self.run_set(rig, SetImages::All(images), params)
    }

    /// [`CpuEngine::run`] with the images as a [`SetImages`]. The CPU engine reads the images
    /// as one slice: picked cameras are copied (packed ones converted) into one here (the WGSL
    /// engine uploads each from where it lies).
    pub fn run_set(
        &mut self,
        rig: &Rig,
        images: SetImages<'_>,
        params: &SweepParams,
    ) -> Result<DepthMaps, SweepError> {
        let copied: Vec<Rgba8Image>;
        let images = match images.as_slice() {
            Some(images) => images,
            None => {
                copied = images.iter().map(|c| c.rgba().into_owned()).collect();
                &copied
            }
        };
        if params.rectify_pairs {
            if let Some(rectified) = self.rectified.for_rig(rig) {
                return self.run_rectified(&rectified, images, params);
            }
        }
        let mut plans = std::mem::take(&mut self.plans);
        let result = super::coarse::run(self, plans.for_rig(rig), rig, images.into(), params);
        self.plans = plans;
        result
    }

    /// A raw pair swept as its rectified pair (`rectify.rs`): the images resampled, the
    /// rectified rig swept, its maps brought back onto the reference's pixels (the `rectify`
    /// stage times both).
    fn run_rectified(
        &mut self,
        rectified: &super::rectify::Rectified,
        images: &[Rgba8Image],
        params: &SweepParams,
    ) -> Result<DepthMaps, SweepError> {
        super::check_images(&rectified.source, images)?;
        let started = std::time::Instant::now();
        let mut resampled = std::mem::take(&mut self.rectified_images);
        rectified.images_into(images, &mut resampled);
        let mut ms = started.elapsed().as_secs_f64() * 1e3;
        let rig = &rectified.rig;
        let mut plans = std::mem::take(&mut self.plans);
        let result = super::coarse::run(
            self,
            plans.for_rig(rig),
            rig,
            (&resampled[..]).into(),
            &rectified.swept_params(params),
        );
        self.plans = plans;
        let started = std::time::Instant::now();
        self.rectified_images = resampled;
        let range = [params.min_depth_m as f32, params.max_depth_m as f32];
        let maps = rectified.maps_back(&result?, self.wanted, range)?;
        ms += started.elapsed().as_secs_f64() * 1e3;
        self.timings.stages.push(("rectify".into(), ms));
        Ok(maps)
    }

    /// The maps beyond depth and confidence the caller reads: a raw pair swept rectified
    /// (`rectify_pairs`) brings only these back onto the reference's pixels (the others come
    /// back empty, as from the WGSL engine); every other sweep makes them all.
    pub fn set_wanted_maps(&mut self, wanted: super::WantedMaps) {
        self.wanted = wanted;
    }

    /// Runs a prepared plan (e.g. with a custom hypothesis family).
    pub fn run_plan(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: &[Rgba8Image],
    ) -> Result<DepthMaps, SweepError> {
        let images = super::prefilter::for_plan(plan, images);
        self.execute(plan, rig, &images, Through::All)?;
        Ok(plan.depth_maps(&self.buffers.maps))
    }

    /// Runs a plan and returns the raw `maps` buffer (MAP_COUNT sections), for stage comparisons.
    pub fn run_plan_raw(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: &[Rgba8Image],
    ) -> Result<Vec<f32>, SweepError> {
        let images = super::prefilter::for_plan(plan, images);
        self.execute(plan, rig, &images, Through::All)?;
        Ok(self.buffers.maps.clone())
    }

    /// Runs a plan, keeping the intermediate buffers.
    pub fn trace(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: &[Rgba8Image],
    ) -> Result<CpuTrace, SweepError> {
        let images = super::prefilter::for_plan(plan, images);
        self.execute(plan, rig, &images, Through::All)?;
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
        through: Through,
    ) -> Result<(), SweepError> {
        check_images(rig, images)?;
        self.buffers_for((plan.params.width, plan.params.height));
        let mut clock = StageClock::new();
        let planes = plan.num_planes() as usize;
        let mappings: Vec<Vec<cost::Mapping>> = (0..planes)
            .map(|k| cost::mappings(plan, k, self.fast_paths))
            .collect();
        // Scattered samples (any mapping but a translation, the reference's own aside) read
        // interleaved texels.
        let refine = crate::sweep::schedule::refines(plan);
        let scattered = refine
            || mappings.iter().any(|m| {
                m.iter().enumerate().any(|(i, m)| {
                    i as u32 != plan.params.reference
                        && !matches!(m, cost::Mapping::Translation { .. })
                })
            });
        let colour_in_alpha = plan.params.colour_in_alpha != 0;
        let frame = self.frame_images(rig, images, plan.uses_census(), colour_in_alpha, scattered);
        clock.lap(Lap::Images);

        // The sweep: bands of rows in parallel, every plane (`bands.rs`).
        let mut volume = std::mem::take(&mut self.buffers.volume);
        if self.buffers.volume_planes != planes {
            // Made anew (every lane PAD) by the sweep.
            volume.clear();
            self.buffers.volume_planes = planes;
        }
        let mut scratches = std::mem::take(&mut self.buffers.bands);
        let (mut state, band) = bands::sweep(
            plan,
            &frame,
            &mappings,
            &self.cancel,
            &mut scratches,
            self.buffers.state.take(),
            &mut volume,
        );
        self.buffers.bands = scratches;
        self.buffers.planar = frame.planar;
        self.buffers.census = frame.census;
        clock.lap(Lap::Phase(Phase::Sweep));
        self.cancel.check()?;

        // The rest of the plan's schedule (the sweep above is its first phase).
        // The fine sweep's mappings of its hypotheses, from the sweep's own.
        let refine = refine.then(|| refine::row_mappings(plan, &mappings));
        let result = self.run_phases(
            plan, images, &volume, &mut state, band, refine, through, &mut clock,
        );
        self.timings = clock.timings();
        self.buffers.volume = volume;
        self.buffers.state = Some(state);
        result
    }

    /// Each image's census words (when the cost uses them) and planar channels, into the
    /// buffers of the last set.
    /// Makes `self.buffers` those of plans of `size` (parking the current ones).
    fn buffers_for(&mut self, size: (u32, u32)) {
        if size == self.buffers_size {
            return;
        }
        let found = self.parked.iter().position(|(s, _)| *s == size);
        let buffers = found.map_or_else(Buffers::default, |i| self.parked.remove(i).1);
        let current = std::mem::replace(&mut self.buffers, buffers);
        if self.buffers_size != (0, 0) {
            self.parked.push((self.buffers_size, current));
        }
        if self.parked.len() > PARKED_SIZES {
            self.parked.remove(0);
        }
        self.buffers_size = size;
    }

    fn frame_images(
        &mut self,
        rig: &Rig,
        images: &[Rgba8Image],
        uses_census: bool,
        colour_in_alpha: bool,
        scattered: bool,
    ) -> FrameImages {
        let mut census = std::mem::take(&mut self.buffers.census);
        census.resize_with(if uses_census { images.len() } else { 0 }, Vec::new);
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
                planar.fill_from_packed(
                    width,
                    height,
                    &im.pixels,
                    colour_in_alpha,
                    scattered,
                    words,
                )
            });
        FrameImages { planar, census }
    }

    /// The plan's schedule after the sweep: SGM, selection, finalize, refinement, median and
    /// the visibility test, into `self.buffers.maps` and `zbuffer`.
    #[expect(
        clippy::too_many_arguments,
        reason = "each argument is an input of its own (the shader twin's buffers, or slices kept apart so that the loop vectorises); a struct would only rename them"
    )]
    fn run_phases(
        &mut self,
        plan: &SweepPlan,
        images: &[Rgba8Image],
        volume: &[u16],
        state: &mut WtaState,
        band: usize,
        refine: Option<Vec<cost::Mapping>>,
        through: Through,
        clock: &mut StageClock,
    ) -> Result<(), SweepError> {
        let p = &plan.params;
        let cancel = self.cancel.clone();
        let mut maps = Maps::reuse(std::mem::take(&mut self.buffers.maps), plan.pixel_count());
        let mut zbuffer = std::mem::take(&mut self.buffers.zbuffer);
        zbuffer.clear();
        zbuffer.resize(plan.total_camera_pixels, 0);
        let mut result = Ok(());
        // Whether SGM's passes selected the winners already (`sgm::run_and_select`).
        let mut selected = false;
        for phase in Schedule::of_plan(plan).phases() {
            if through == Through::Finalize
                && matches!(phase, Phase::Median | Phase::Splat | Phase::Visibility)
            {
                continue;
            }
            if let Err(e) = cancel.check() {
                result = Err(e);
                break;
            }
            match phase {
                Phase::Sweep => {}
                Phase::Sgm => {
                    let colours: &[u32] = if p.reference == NO_CAMERA {
                        &[]
                    } else {
                        &images[p.reference as usize].pixels
                    };
                    let buffers = &mut self.buffers;
                    let (forward, backward) = (&mut buffers.forward, &mut buffers.backward);
                    // Coarse to fine: each pixel's window alone; else the wide layout where
                    // it applies (4 threads or more), else two passes; both two-pass
                    // layouts select as they go.
                    let sums = if plan.narrowed() {
                        selected = true;
                        sgm_windows::run_and_select(
                            plan, colours, volume, forward, backward, state, &cancel,
                        )
                    } else if sgm_wide::applies(plan) {
                        sgm_wide::run(plan, colours, volume, forward, backward, &cancel)
                    } else {
                        selected = true;
                        sgm::run_and_select(
                            plan, colours, volume, forward, backward, state, &cancel,
                        )
                    };
                    if let Err(e) = sums {
                        result = Err(e);
                        break;
                    }
                }
                Phase::SgmSelect if selected => {}
                Phase::SgmSelect => {
                    // The wide layout's sums (`sgm_wide::run`), selected here.
                    let buffers = &self.buffers;
                    sgm::select(plan, volume, &buffers.forward, &buffers.backward, state);
                }
                Phase::Finalize => {
                    finalize::run(plan, state, &mut maps);
                }
                Phase::Refine => {
                    if let Some(hypotheses) = &refine {
                        let frame = FrameImages {
                            planar: std::mem::take(&mut self.buffers.planar),
                            census: std::mem::take(&mut self.buffers.census),
                        };
                        let [raw, ..] = maps.sections_mut();
                        refine::run(plan, &frame, &mut Vec::new(), band, hypotheses, raw);
                        self.buffers.planar = frame.planar;
                        self.buffers.census = frame.census;
                    }
                }
                Phase::Median => {
                    median::run(plan, &mut maps);
                }
                Phase::Splat => {
                    occlusion::splat(plan, &maps, &mut zbuffer, &mut self.buffers.projections);
                }
                Phase::Visibility => {
                    occlusion::visibility(plan, &zbuffer, &self.buffers.projections, &mut maps);
                }
            }
            // The sweep was timed by the caller; the fine sweep only runs with hypotheses.
            if !matches!(phase, Phase::Sweep) && (*phase != Phase::Refine || refine.is_some()) {
                clock.lap(Lap::Phase(*phase));
            }
        }
        self.buffers.maps = maps.data;
        self.buffers.zbuffer = zbuffer;
        result
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

    /// A level below: its caller reads `depth_raw_m` alone, so the phases after `finalize`
    /// (the median, the occlusion splat and the visibility test, which write other maps) are
    /// not run.
    fn run_plan_for_ranges(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: super::coarse::LevelImages<'_>,
    ) -> Result<super::coarse::LevelDepth, SweepError> {
        let images = images.on_host(rig, &mut self.memo)?;
        let images = super::prefilter::for_plan(plan, images);
        self.execute(plan, rig, &images, Through::Finalize)?;
        Ok(super::coarse::LevelDepth::Host(
            plan.depth_maps(&self.buffers.maps),
        ))
    }

    fn timings_mut(&mut self) -> &mut StageTimings {
        &mut self.timings
    }

    fn memo(&mut self) -> &mut super::frame_memo::FrameMemo {
        &mut self.memo
    }
}

/// What a lap of the [`StageClock`] timed: the frame set's images made ready, or a phase of
/// the schedule (named as the WGSL engine's stages, [`Phase::name`]).
#[derive(Debug, Clone, Copy)]
enum Lap {
    Images,
    Phase(Phase),
}

impl Lap {
    fn name(self) -> &'static str {
        match self {
            Lap::Images => "images",
            Lap::Phase(phase) => phase.name(),
        }
    }
}

/// Wall-clock time per stage, summed over repeated laps of the same stage.
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

    fn lap(&mut self, lap: Lap) {
        let now = Instant::now();
        let ms = (now - self.last).as_secs_f64() * 1e3;
        self.last = now;
        super::add_stage_ms(&mut self.stages, lap.name(), ms);
    }

    fn timings(self) -> StageTimings {
        StageTimings {
            stages: self.stages,
            gpu_timestamps: false,
        }
    }
}
