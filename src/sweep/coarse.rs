//! Coarse to fine (`coarse_to_fine`): a sweep at half resolution over every other plane, then
//! the full-resolution sweep with each reference row narrowed to the planes its neighbourhood
//! chose at half resolution (`SweepPlan::narrow_planes`), so a rig pays for the depths its
//! scene has. The half-resolution sweep is itself coarse to fine where it still [`applies`]
//! (at least MIN_PLANES planes, MIN_SIZE pixels): a 640x480 reference with 96 planes runs
//! three levels (160x120 with 24 planes, 320x240 with 48 narrowed, 640x480 with 96 narrowed;
//! [`levels`]). Both engines' `run` is [`run`] (with or without coarse to fine); what a narrowed
//! row does not sweep scores BIG in both (`aggregate.wgsl`, `cpu/mod.rs`), the WGSL engine
//! costs and sums only the planes a row's windows need, and the CPU engine skips the planes no
//! row of a band sweeps.

use crate::geometry::{CameraModel, Reference, Rig, RigCamera};
use crate::image::{ImageF32, Rgba8Image, SetImages};

use std::cell::OnceCell;

use super::frame_memo::FrameMemo;
use super::joint_median::{Bins, JointMedian};
use super::plan::{range_tiles, SweepPlan, RANGE_TILE};
use super::{DepthMaps, Prefilter, SweepError, SweepParams};

/// Planes added on each side of the span of the half-resolution depths of a row and its
/// neighbours (a half-resolution pixel's plane is about twice as uncertain; chosen on the
/// public sets; docs/engine.md). A tile's range lies within its row's.
pub const MARGIN_PLANES: u32 = 3;

/// Planes added on each side of the span of a tile's half-resolution depths: more than a row's,
/// as a tile's few depths may all miss a thin structure or hold a patch of wrong ones (chosen
/// on the public sets with NEIGHBOUR_COLS: docs/speed.md, "Plane ranges per tile").
pub const TILE_MARGIN_PLANES: u32 = 7;

/// Half-resolution rows above and below a row's own whose depths set its range.
pub const NEIGHBOUR_ROWS: u32 = 2;

/// Half-resolution columns left and right of a range tile's own whose depths set its range.
pub const NEIGHBOUR_COLS: u32 = 8;

/// The smallest reference (width and height, pixels) that is swept coarse to fine; a smaller
/// one is swept at full resolution only (it is fast anyway, and at 80x60 the 40x30
/// half-resolution images are too coarse for 5x5 windows: `tests/engine/engine_analytic.rs`'s
/// synthetic scenes lose most of their depth through wrong ranges).
pub const MIN_SIZE: u32 = 160;

/// The fewest planes that are swept coarse to fine: with fewer the half-resolution pass costs
/// more than the narrowed rows save (`bench --device cpu`: the demo's 32 planes 43 -> 49 ms,
/// the paper's 20 planes 11 -> 15 ms; 9 cameras with 57 planes 183 -> 110 ms).
pub const MIN_PLANES: u32 = 48;

/// The half-resolution pass is always SGM, whatever the optimizer of the full-resolution one:
/// winner-take-all at half resolution is noisy, and its ambiguous pixels alone spread a row
/// over most planes (the bench's ring: 73 % of the planes per row with a wta pass, 24 % with
/// SGM; 640x480x64: 53 %, or 26 % with the wta depths below confidence 0.2 left out), while the
/// SGM pass costs a few milliseconds more. Measured on the public sets (`eval --optimizer wta`,
/// CHANGELOG.md): Teddy 8.72 -> 8.65, Laundry 21.35 -> 21.15 % bad>1 against the filtered wta
/// pass.
pub const COARSE_OPTIMIZER: super::Optimizer = super::Optimizer::Sgm;

/// The images of one level of a frame set: the caller's, halved `halvings` times (each 2x2
/// block averaged per 8-bit channel, [`half_image`]). The half-size images are made where the
/// engine wants them: the WGSL engine in a compute stage from the caller's images
/// (`shaders/half.wgsl`), the CPU engine on the host ([`LevelImages::on_host`], once per
/// level and frame set).
#[derive(Debug, Clone, Copy)]
pub struct LevelImages<'a> {
    full: SetImages<'a>,
    halvings: usize,
    /// The levels made on the host so far (level h at h - 1).
    host: &'a [OnceCell<Vec<Rgba8Image>>],
}

impl<'a> LevelImages<'a> {
    /// The caller's images themselves.
    pub fn given(images: &'a [Rgba8Image]) -> Self {
        Self {
            full: SetImages::All(images),
            halvings: 0,
            host: &[],
        }
    }

    /// The caller's (full-resolution) images.
    pub fn full(&self) -> SetImages<'a> {
        self.full
    }

    /// How many times the level halves the caller's images.
    pub fn halvings(&self) -> usize {
        self.halvings
    }

    /// The level below: half the size again.
    fn halved(self) -> Self {
        Self {
            halvings: self.halvings + 1,
            ..self
        }
    }

    /// The level's images on the host (the CPU engine; the cameras' names in `rig` key the
    /// frame set's memo): made level by level on first use.
    pub fn on_host(&self, rig: &Rig, memo: &mut FrameMemo) -> Result<&'a [Rgba8Image], SweepError> {
        let mut images = self.full.as_slice().ok_or_else(|| {
            SweepError::InvalidParams("internal: picked images on the host, not one slice".into())
        })?;
        for level in 0..self.halvings {
            let cell = self.host.get(level).ok_or_else(|| {
                SweepError::InvalidParams(format!(
                    "internal: no room for half-size level {}",
                    level + 1
                ))
            })?;
            let finer = images;
            images = cell.get_or_init(|| {
                rig.cameras
                    .iter()
                    .zip(finer)
                    .map(|(camera, image)| memo.half(&camera.name, image, half_image))
                    .collect()
            });
        }
        Ok(images)
    }
}

/// The depths of a level below the full-resolution one, which set the plane ranges of the next.
pub enum LevelDepth {
    /// Read back: the host makes the next level's ranges ([`plane_ranges`]; the CPU engine).
    Host(DepthMaps),
    /// Kept on the device, which makes the next level's ranges itself (the WGSL engine records
    /// the level into the frame set's command buffer, and the next `run_plan` narrows its rows
    /// from it there: `shaders/plane_spans.wgsl`, `shaders/plane_ranges.wgsl`).
    Device,
    /// The full-resolution level submitted, its maps read back later (the WGSL engine's
    /// references of a set, `GpuEngine::submit_set`; [`finish`] follows).
    Submitted,
}

/// Runs a plan on an engine (both engines implement it).
pub trait PlanRunner {
    fn run_plan(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: LevelImages<'_>,
    ) -> Result<DepthMaps, SweepError>;

    /// Runs the plan of a level below the full-resolution one: its caller reads
    /// `depth_raw_m` alone (the next level's plane ranges), or nothing where the engine keeps
    /// the depths and makes the next level's ranges on the device ([`LevelDepth::Device`]: the
    /// `run_plan` that follows is that next level).
    fn run_plan_for_ranges(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: LevelImages<'_>,
    ) -> Result<LevelDepth, SweepError> {
        self.run_plan(plan, rig, images).map(LevelDepth::Host)
    }

    /// Runs the plan of a frame set's last (full-resolution) level: its maps, or
    /// [`LevelDepth::Submitted`] where the engine reads them back later.
    fn run_plan_last(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: LevelImages<'_>,
    ) -> Result<LevelDepth, SweepError> {
        self.run_plan(plan, rig, images).map(LevelDepth::Host)
    }

    /// The per-stage times of the last run.
    fn timings_mut(&mut self) -> &mut super::StageTimings;

    /// What the references of one frame set share (census words, half-size images).
    fn memo(&mut self) -> &mut super::frame_memo::FrameMemo;

    /// Whether the engine makes a pair's matching images itself from the caller's (the WGSL
    /// engine, on the device) where the plan's colour term reads them
    /// (`Params.colour_in_alpha`); otherwise `run` prefilters them on the host first.
    fn prefilters_on_device(&self) -> bool {
        false
    }
}

/// An engine's plans per reference (the reference camera's name, or "" for a virtual one):
/// several references of one rig (`references`) each keep theirs from set to set.
#[derive(Debug, Default)]
pub struct PlanSets {
    sets: Vec<(String, Plans)>,
}

/// The most references whose plans an engine keeps (the least recently used goes).
const MAX_PLAN_SETS: usize = 32;

impl PlanSets {
    /// The plans of `rig`'s reference, most recently used last.
    pub fn for_rig(&mut self, rig: &Rig) -> &mut Plans {
        let key = match rig.reference {
            Reference::Camera(i) => rig.cameras[i].name.as_str(),
            Reference::Virtual { .. } => "",
        };
        match self.sets.iter().position(|(k, _)| k == key) {
            // Most recently used last, without moving the plans or allocating the key again.
            Some(i) => self.sets[i..].rotate_left(1),
            None => {
                if self.sets.len() >= MAX_PLAN_SETS {
                    self.sets.remove(0);
                }
                self.sets.push((key.to_string(), Plans::default()));
            }
        }
        let last = self.sets.len() - 1;
        &mut self.sets[last].1
    }
}

/// An engine's plans, kept while the rig and the parameters stay the same: the sweep's own,
/// the full-resolution level of a coarse-to-fine sweep, and the plans of the levels below.
#[derive(Debug, Default)]
pub struct Plans {
    whole: Option<(Rig, SweepParams, SweepPlan)>,
    fine: Option<(Rig, SweepParams, SweepPlan)>,
    /// The half-resolution level's own plans (coarse to fine again where it applies).
    below: Option<Box<Plans>>,
    /// `prefilter: auto` on a rig of three cameras or more: the rig whose images were seen to
    /// be a camera's (or to differ in brightness), whose sets take the gradient from then on
    /// (no plan flips back; a moving rig keeps its `Rig`, its motion is the pipeline's
    /// `world_from_rig`).
    auto_gradient: Option<Rig>,
}

impl Plans {
    /// `params` as a frame set of `rig` sweeps them: `prefilter: auto` on three cameras or
    /// more becomes `gradient` from the first set whose cameras differ in brightness
    /// (`prefilter::AUTO_BRIGHTNESS_RATIO`) or whose texture is a camera's, not a render's
    /// (`prefilter::AUTO_RENDER_STEP`; said once), else `none`; anything else as it is.
    fn resolve_prefilter(
        &mut self,
        rig: &Rig,
        images: SetImages<'_>,
        params: &SweepParams,
    ) -> Option<SweepParams> {
        if params.prefilter != Prefilter::Auto || params.prefilter.applies(rig.cameras.len()) {
            return None;
        }
        if self.auto_gradient.as_ref() != Some(rig) {
            let ratio = super::prefilter::brightness_ratio(images);
            let why = if ratio > super::prefilter::AUTO_BRIGHTNESS_RATIO {
                format!("the cameras' mean brightness differs {ratio:.2}x (brightest over darkest)")
            } else {
                let step = super::prefilter::median_step(images);
                if step > super::prefilter::AUTO_RENDER_STEP {
                    return Some(SweepParams {
                        prefilter: Prefilter::None,
                        ..params.clone()
                    });
                }
                format!(
                    "the images' median step between columns is {step:.1} grey levels, a camera's"
                )
            };
            tracing::info!(
                "prefilter auto: {why}: the colour term compares each image's gradient from now on (prefilter: none or gradient to choose)"
            );
            self.auto_gradient = Some(rig.clone());
        }
        Some(SweepParams {
            prefilter: Prefilter::Gradient,
            ..params.clone()
        })
    }
}

fn cached<'a>(
    slot: &'a mut Option<(Rig, SweepParams, SweepPlan)>,
    rig: &Rig,
    params: &SweepParams,
) -> Result<&'a mut SweepPlan, SweepError> {
    let reuse = matches!(slot, Some((r, p, _)) if r == rig && p == params);
    if !reuse {
        *slot = Some((rig.clone(), params.clone(), SweepPlan::new(rig, params)?));
    }
    match slot {
        Some((_, _, plan)) => Ok(plan),
        None => Err(SweepError::InvalidParams("internal: no plan".into())),
    }
}

/// Whether a level of `width` x `height` pixels and `planes` planes has a level below it: large
/// enough, and the level below within what its SGM takes (`COARSE_OPTIMIZER`; with more planes
/// than that, `wta` sweeps at full resolution alone).
fn halves(width: u32, height: u32, planes: u32) -> bool {
    planes >= MIN_PLANES
        && width >= MIN_SIZE
        && height >= MIN_SIZE
        && coarse_planes(planes) <= super::gpu_types::MAX_SGM_PLANES
}

/// Whether a sweep of `rig` with `params` runs coarse to fine.
pub fn applies(rig: &Rig, params: &SweepParams) -> bool {
    let reference = rig.reference_model().intrinsics;
    params.coarse_to_fine && halves(reference.width_px, reference.height_px, params.num_planes)
}

/// How many levels a sweep of `rig` with `params` runs: 1 at full resolution only, 2 with a
/// half-resolution pass, 3 when that pass is itself coarse to fine, ... (the rig's own
/// half-size twin aside: [`run`] sweeps at full resolution when it has none).
pub fn levels(rig: &Rig, params: &SweepParams) -> usize {
    if !params.coarse_to_fine {
        return 1;
    }
    let reference = rig.reference_model().intrinsics;
    let (mut width, mut height, mut planes) =
        (reference.width_px, reference.height_px, params.num_planes);
    let mut levels = 1;
    while halves(width, height, planes) {
        levels += 1;
        (width, height, planes) = (width / 2, height / 2, coarse_planes(planes));
    }
    levels
}

/// The sweep of one frame set, as both engines' `run`: coarse to fine where it [`applies`]
/// (and the rig has a half-resolution twin), else the plan of the rig and parameters.
pub fn run(
    engine: &mut dyn PlanRunner,
    plans: &mut Plans,
    rig: &Rig,
    images: SetImages<'_>,
    params: &SweepParams,
) -> Result<DepthMaps, SweepError> {
    match start(engine, plans, rig, images, params)? {
        LevelDepth::Host(maps) => finish(engine, maps, rig, images, params),
        LevelDepth::Device | LevelDepth::Submitted => Err(SweepError::InvalidParams(
            "internal: a frame set's maps left on the device".into(),
        )),
    }
}

/// The sweep of [`run`], level by level, up to the last level's maps (or their submission,
/// [`LevelDepth::Submitted`]); [`finish`] makes the rest.
pub fn start(
    engine: &mut dyn PlanRunner,
    plans: &mut Plans,
    rig: &Rig,
    images: SetImages<'_>,
    params: &SweepParams,
) -> Result<LevelDepth, SweepError> {
    // The matching images (issue 52): prefiltered for real cameras, on the host for the CPU
    // engine (the WGSL engine makes them on the device); the joint median below keeps the
    // caller's.
    let resolved = plans.resolve_prefilter(rig, images, params);
    let params = resolved.as_ref().unwrap_or(params);
    let prefiltered;
    let mut prefilter_ms = None;
    let on_host = !engine.prefilters_on_device();
    let matching = if params.prefilter.applies(rig.cameras.len()) && on_host {
        super::check_images(rig, images)?;
        let started = std::time::Instant::now();
        let slice = images.as_slice().ok_or_else(|| {
            SweepError::InvalidParams("internal: picked images on the host, not one slice".into())
        })?;
        prefiltered = super::prefilter::gradient_all(slice);
        prefilter_ms = Some(started.elapsed().as_secs_f64() * 1e3);
        SetImages::All(&prefiltered)
    } else {
        images
    };
    // The half-size levels the CPU engine makes on the host (the WGSL engine on the GPU).
    let host: Vec<OnceCell<Vec<Rgba8Image>>> =
        (1..levels(rig, params)).map(|_| OnceCell::new()).collect();
    let levels = LevelImages {
        full: matching,
        halvings: 0,
        host: &host,
    };
    let depth = run_level(engine, plans, rig, levels, params, Wanted::All)?;
    if let Some(ms) = prefilter_ms {
        engine
            .timings_mut()
            .stages
            .insert(0, ("prefilter".to_string(), ms));
    }
    Ok(depth)
}

/// The host post-step of both engines (issue 29) on the maps of [`start`]: the joint median,
/// guided by the reference's own image (a virtual reference has none).
pub fn finish(
    engine: &mut dyn PlanRunner,
    mut maps: DepthMaps,
    rig: &Rig,
    images: SetImages<'_>,
    params: &SweepParams,
) -> Result<DepthMaps, SweepError> {
    let filter = JointMedian::of_params(params);
    if let (Reference::Camera(r), Some(bins), true) =
        (&rig.reference, Bins::of_params(params), filter.radius > 0)
    {
        if let Some(guide) = images.get(*r) {
            let started = std::time::Instant::now();
            filter.apply(&mut maps.depth_m, &guide.rgba(), &bins);
            let ms = started.elapsed().as_secs_f64() * 1e3;
            engine
                .timings_mut()
                .stages
                .push(("joint_median".to_string(), ms));
        }
    }
    Ok(maps)
}

/// What the caller of a level reads of its maps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Wanted {
    /// Every map: the frame set's result.
    All,
    /// `depth_raw_m` alone: a level below, whose depths set the plane ranges of the next.
    DepthRaw,
}

impl Wanted {
    fn run_plan(
        self,
        engine: &mut dyn PlanRunner,
        plan: &SweepPlan,
        rig: &Rig,
        images: LevelImages<'_>,
    ) -> Result<LevelDepth, SweepError> {
        match self {
            Wanted::All => engine.run_plan_last(plan, rig, images),
            Wanted::DepthRaw => engine.run_plan_for_ranges(plan, rig, images),
        }
    }
}

/// [`run`], for a caller that reads `wanted` of the maps.
fn run_level(
    engine: &mut dyn PlanRunner,
    plans: &mut Plans,
    rig: &Rig,
    images: LevelImages<'_>,
    params: &SweepParams,
    wanted: Wanted,
) -> Result<LevelDepth, SweepError> {
    if images.halvings == 0 {
        super::check_images(rig, images.full)?;
    }
    if applies(rig, params) && images.halvings < images.host.len() {
        match half_rig(rig) {
            Ok(half) => return coarse_to_fine(engine, plans, rig, images, params, &half, wanted),
            Err(e) => tracing::debug!("coarse to fine skipped: {e}"),
        }
    }
    let plan = cached(&mut plans.whole, rig, params)?;
    wanted.run_plan(engine, plan, rig, images)
}

/// The rig and parameters of the level below a coarse-to-fine sweep of `rig` with `params`:
/// the rig at half resolution, every other plane, always SGM ([`COARSE_OPTIMIZER`]), coarse to
/// fine again where it applies.
pub fn coarse_level(rig: &Rig, params: &SweepParams) -> Result<(Rig, SweepParams), SweepError> {
    Ok((half_rig(rig)?, coarse_params(params)))
}

/// The parameters of the level below (see [`coarse_level`]).
fn coarse_params(params: &SweepParams) -> SweepParams {
    SweepParams {
        num_planes: coarse_planes(params.num_planes),
        optimizer: COARSE_OPTIMIZER,
        // Only the plane ranges are read off the coarse level: no fine sweep there, and no
        // confidence.
        subpixel_refine: false,
        ambiguity: 0.0,
        // A surface beyond the range sets its tile's planes at the range's end.
        keep_range_ends: true,
        ..params.clone()
    }
}

/// The half-resolution sweep, then the full-resolution one with narrowed rows (the module).
fn coarse_to_fine(
    engine: &mut dyn PlanRunner,
    plans: &mut Plans,
    rig: &Rig,
    images: LevelImages<'_>,
    params: &SweepParams,
    coarse_rig: &Rig,
    wanted: Wanted,
) -> Result<LevelDepth, SweepError> {
    let fine_params = SweepParams {
        coarse_to_fine: false,
        ..params.clone()
    };
    // The half-resolution level keeps `coarse_to_fine`: it runs coarse to fine again where it
    // applies.
    let coarse_params = coarse_params(params);
    let started = std::time::Instant::now();
    let below = plans.below.get_or_insert_with(Default::default);
    let coarse = run_level(
        engine,
        below,
        coarse_rig,
        images.halved(),
        &coarse_params,
        Wanted::DepthRaw,
    )?;
    // The levels below stage by stage (`coarse/<stage>`, summed over the levels, as the WGSL
    // engine times them: bench's JSON).
    let mut coarse_stages: Vec<(String, f64)> = Vec::new();
    for (name, ms) in &engine.timings_mut().stages {
        if name == "coarse" {
            continue;
        }
        let name = format!("coarse/{}", name.strip_prefix("coarse/").unwrap_or(name));
        super::add_stage_ms(&mut coarse_stages, &name, *ms);
    }
    let fine = cached(&mut plans.fine, rig, &fine_params)?;
    // The engine that keeps the coarse depths on the device narrows the rows there.
    let on_host = match coarse {
        LevelDepth::Host(coarse) => {
            let ranges = plane_ranges(fine, &coarse.depth_raw_m);
            let swept: u64 = ranges.iter().map(|r| u64::from(r[1] - r[0] + 1)).sum();
            tracing::debug!(
                "coarse to fine: rows sweep {:.0} % of the planes on average",
                100.0 * swept as f64 / (ranges.len() as f64 * f64::from(fine.num_planes()))
            );
            // Narrowed in place: the plan's arrays are neither copied nor uploaded again.
            fine.set_plane_ranges(ranges)?;
            true
        }
        LevelDepth::Device => false,
        LevelDepth::Submitted => {
            return Err(SweepError::InvalidParams(
                "internal: a level below submitted as the last".into(),
            ))
        }
    };
    let coarse_ms = started.elapsed().as_secs_f64() * 1e3;
    let maps = wanted.run_plan(engine, fine, rig, images)?;
    // The fine pass's stages, after the whole half-resolution pass (and the ranges) as one
    // and each of their stages as `coarse/<stage>` (the WGSL engine times its levels below so
    // itself).
    if on_host {
        let stages = &mut engine.timings_mut().stages;
        stages.insert(0, ("coarse".to_string(), coarse_ms));
        stages.extend(coarse_stages);
    }
    Ok(maps)
}

/// Planes of the half-resolution sweep: every other plane of the full sweep's range (a
/// half-resolution pixel tells half as many depths apart), at least 2.
fn coarse_planes(planes: u32) -> u32 {
    planes.div_ceil(2).max(2)
}

/// The camera model of a half-size image (pixel centres: x' = (x + 0.5) / 2 - 0.5).
fn half_model(model: &CameraModel) -> CameraModel {
    let k = model.intrinsics;
    let mut half = *model;
    half.intrinsics.width_px = k.width_px / 2;
    half.intrinsics.height_px = k.height_px / 2;
    half.intrinsics.fx_px = k.fx_px / 2.0;
    half.intrinsics.fy_px = k.fy_px / 2.0;
    half.intrinsics.cx_px = (k.cx_px + 0.5) / 2.0 - 0.5;
    half.intrinsics.cy_px = (k.cy_px + 0.5) / 2.0 - 0.5;
    half
}

/// The rig at half resolution (its images: [`half_image`] of the rig's).
fn half_rig(rig: &Rig) -> Result<Rig, SweepError> {
    let cameras = rig
        .cameras
        .iter()
        .map(|c| RigCamera {
            model: half_model(&c.model),
            ..c.clone()
        })
        .collect();
    let reference = match &rig.reference {
        Reference::Camera(i) => Reference::Camera(*i),
        Reference::Virtual {
            model,
            cam_from_rig,
        } => Reference::Virtual {
            model: half_model(model),
            cam_from_rig: *cam_from_rig,
        },
    };
    Rig::new(cameras, reference)
        .map_err(|e| SweepError::InvalidParams(format!("coarse to fine: {e}")))
}

/// An image at half size: each 2x2 block averaged per 8-bit channel, (sum + 2) / 4 in integers
/// (an odd last row or column dropped). The WGSL twin is `shaders/half.wgsl`.
pub fn half_image(image: &Rgba8Image) -> Rgba8Image {
    let (w, h) = (image.width / 2, image.height / 2);
    let src = |x: u32, y: u32| image.pixels[(y * image.width + x) as usize];
    let mut pixels = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let quad = [
                src(2 * x, 2 * y),
                src(2 * x + 1, 2 * y),
                src(2 * x, 2 * y + 1),
                src(2 * x + 1, 2 * y + 1),
            ];
            let mut packed = 0u32;
            for shift in [0, 8, 16, 24] {
                let sum: u32 = quad.iter().map(|p| (p >> shift) & 0xff).sum();
                packed |= ((sum + 2) / 4) << shift;
            }
            pixels.push(packed);
        }
    }
    Rgba8Image {
        width: w,
        height: h,
        pixels,
    }
}

/// Each full-resolution (row, tile)'s planes (the layout of `SweepPlan::plane_ranges`): the
/// planes of the half-resolution depths (the plane nearest each depth in inverse depth along
/// the full-resolution ray) of its own and the neighbouring half-resolution rows
/// (NEIGHBOUR_ROWS), in the tile's half-resolution columns and NEIGHBOUR_COLS more each side,
/// widened by TILE_MARGIN_PLANES, within those of the whole rows widened by MARGIN_PLANES; the
/// rows' where the tile's pixels hold no depth, every plane where the rows hold none.
pub fn plane_ranges(plan: &SweepPlan, coarse: &ImageF32) -> Vec<[u32; 2]> {
    let planes = plan.num_planes();
    let (width, height) = (plan.width as usize, plan.height as usize);
    let (cw, ch) = (coarse.width as usize, coarse.height as usize);
    let tiles = range_tiles(plan.width) as usize;
    let all = vec![[0, planes - 1]; height * tiles];
    if cw == 0 || ch == 0 {
        return all;
    }
    let join = |acc: Option<[u32; 2]>, s: [u32; 2]| {
        Some(acc.map_or(s, |a| [a[0].min(s[0]), a[1].max(s[1])]))
    };
    // The span of planes of each half-resolution row's part under each tile (None: no depth
    // there), from the plane of each half-resolution pixel.
    let half_tile = RANGE_TILE as usize / 2;
    let near_cols = NEIGHBOUR_COLS as usize;
    // Each half-resolution pixel's plane (None: no depth there).
    let ks: Vec<Option<u32>> = (0..ch * cw)
        .map(|i| {
            let (cy, cx) = (i / cw, i % cw);
            let depth = coarse.data.get(i).copied().unwrap_or(f32::NAN);
            let pix = (2 * cy).min(height - 1) * width + (2 * cx).min(width - 1);
            (depth.is_finite() && depth > 0.0).then(|| nearest_plane(plan, pix, depth))
        })
        .collect();
    let tile_spans: Vec<Option<[u32; 2]>> = (0..ch * tiles)
        .map(|i| {
            let (cy, t) = (i / tiles, i % tiles);
            let first = (t * half_tile).saturating_sub(near_cols);
            let end = ((t + 1) * half_tile + near_cols).min(cw);
            ks[cy * cw + first.min(end)..cy * cw + end]
                .iter()
                .flatten()
                .fold(None, |acc, &k| join(acc, [k, k]))
        })
        .collect();
    let near = NEIGHBOUR_ROWS as usize;
    // The span of each whole half-resolution row (every column lies in some tile's part).
    let row_spans: Vec<Option<[u32; 2]>> = (0..ch)
        .map(|cy| {
            tile_spans[cy * tiles..(cy + 1) * tiles]
                .iter()
                .flatten()
                .copied()
                .fold(None, join)
        })
        .collect();
    (0..height * tiles)
        .map(|i| {
            let (y, t) = (i / tiles, i % tiles);
            let cy = (y / 2).min(ch - 1);
            let rows = cy.saturating_sub(near)..=(cy + near).min(ch - 1);
            let span = rows
                .clone()
                .filter_map(|r| tile_spans[r * tiles + t])
                .fold(None, join);
            let row = rows
                .filter_map(|r| row_spans[r])
                .fold(None, join)
                .map(|[lo, hi]| {
                    [
                        lo.saturating_sub(MARGIN_PLANES),
                        (hi + MARGIN_PLANES).min(planes - 1),
                    ]
                })
                .unwrap_or([0, planes - 1]);
            match span {
                Some([lo, hi]) => [
                    lo.saturating_sub(TILE_MARGIN_PLANES).max(row[0]),
                    (hi + TILE_MARGIN_PLANES).min(planes - 1).min(row[1]),
                ],
                None => row,
            }
        })
        .collect()
}

/// The plane whose inverse depth along pixel `pix`'s ray is nearest 1 / `depth` (the sweep's
/// planes are in order of inverse depth: a binary search).
fn nearest_plane(plan: &SweepPlan, pix: usize, depth: f32) -> u32 {
    let ray = plan.rays[pix];
    let q_of = |k: usize| {
        let p = plan.planes[k];
        (p[0] * ray[0] + p[1] * ray[1] + p[2] * ray[2]) / p[3]
    };
    let q = 1.0 / depth;
    let n = plan.planes.len();
    let rising = q_of(n - 1) >= q_of(0);
    // The first plane at or past q in the sweep's direction.
    let (mut lo, mut hi) = (0usize, n);
    while lo < hi {
        let mid = (lo + hi) / 2;
        let before = if rising { q_of(mid) < q } else { q_of(mid) > q };
        if before {
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    let k = if lo == 0 {
        0
    } else if lo == n || (q_of(lo - 1) - q).abs() <= (q_of(lo) - q).abs() {
        lo - 1
    } else {
        lo
    };
    k as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_image_averages_each_channel_of_2x2_blocks() {
        let image = Rgba8Image {
            width: 3,
            height: 2,
            pixels: vec![
                0x0000_0000,
                0x0400_0a02,
                0xffff_ffff,
                0x0000_0000,
                0x0400_0a02,
                0xffff_ffff,
            ],
        };
        let half = half_image(&image);
        assert_eq!((half.width, half.height), (1, 1));
        assert_eq!(half.pixels, vec![0x0200_0501]);
    }

    /// The binary search finds the plane a linear scan finds, and each row's range holds the
    /// planes of the depths around it, widened by the margin.
    #[test]
    fn ranges_hold_the_planes_of_the_coarse_depths() {
        let model = CameraModel::pinhole(crate::synthetic::intrinsics(64, 48));
        let rig = crate::synthetic::row_rig(3, 0.1, model, 1).expect("rig");
        let params = SweepParams {
            min_depth_m: 1.0,
            max_depth_m: 8.0,
            num_planes: 64,
            ..SweepParams::default()
        };
        let plan = SweepPlan::new(&rig, &params).expect("plan");
        for depth in [0.5f32, 1.0, 1.3, 2.0, 3.7, 7.9, 8.0, 20.0] {
            let q = 1.0 / depth;
            let scan = (0..64u32)
                .min_by(|&a, &b| {
                    let qa = plan.planes[a as usize][2] / plan.planes[a as usize][3];
                    let qb = plan.planes[b as usize][2] / plan.planes[b as usize][3];
                    (qa - q).abs().total_cmp(&(qb - q).abs())
                })
                .expect("planes");
            assert_eq!(nearest_plane(&plan, 100, depth), scan, "depth {depth}");
        }
        // Half-resolution depths: 2 m on rows 0..12 (7 m in their columns 24..32), NaN on
        // 12..18, 4 m below.
        let coarse = ImageF32 {
            width: 32,
            height: 24,
            data: (0..24 * 32)
                .map(|i| match (i / 32, i % 32) {
                    (0..12, 24..) => 7.0,
                    (0..12, _) => 2.0,
                    (12..18, _) => f32::NAN,
                    _ => 4.0,
                })
                .collect(),
        };
        let ranges = plane_ranges(&plan, &coarse);
        // 64 columns: four tiles of 16 per row.
        let tiles = 4;
        assert_eq!(ranges.len(), 48 * tiles);
        let at = |y: usize, t: usize| ranges[y * tiles + t];
        let k2 = nearest_plane(&plan, 0, 2.0);
        let k4 = nearest_plane(&plan, 0, 4.0);
        let k7 = nearest_plane(&plan, 60, 7.0);
        assert!(
            k7 < k4 && k4 < k2,
            "farther is a lower plane here: {k7}, {k4}, {k2}"
        );
        let margin = |lo: u32, hi: u32| [lo.saturating_sub(MARGIN_PLANES), hi + MARGIN_PLANES];
        // A tile's span widened by TILE_MARGIN_PLANES within its rows' range.
        let within = |row: [u32; 2], lo: u32, hi: u32| {
            [
                lo.saturating_sub(TILE_MARGIN_PLANES).max(row[0]),
                (hi + TILE_MARGIN_PLANES).min(row[1]),
            ]
        };
        // Row 0 (half-rows 0..=2) holds both depths: tiles 0 and 1 (half-resolution columns
        // 0..16 and 0..24) see 2 m alone, tile 2 (8..32) and tile 3 (16..32) both.
        let row = margin(k7, k2);
        assert_eq!(at(0, 0), within(row, k2, k2));
        assert_ne!(at(0, 0), row, "a tile narrower than its row");
        assert_eq!(at(0, 1), within(row, k2, k2));
        assert_eq!(at(0, 2), row);
        assert_eq!(at(0, 3), row);
        // Row 22 (half-row 11) sees half-rows 9..=13: 2 m and 7 m, and nothing.
        assert_eq!(at(22, 0), within(row, k2, k2));
        // Rows 28 and 29 (half-row 14) see no depth at all (half-rows 12..=16): every plane.
        for t in 0..tiles {
            assert_eq!(at(29, t), [0, 63]);
        }
        // Row 35 (half-row 17) sees half-rows 15..=19: 4 m.
        assert_eq!(at(35, 3), margin(k4, k4));
        assert_eq!(at(47, 0), margin(k4, k4));
    }

    #[test]
    fn levels_halve_until_too_small_or_too_few_planes() {
        let rig = |w: u32, h: u32| {
            let model = CameraModel::pinhole(crate::synthetic::intrinsics(w, h));
            crate::synthetic::row_rig(3, 0.1, model, 1).expect("rig")
        };
        let params = |planes: u32| SweepParams {
            num_planes: planes,
            ..SweepParams::default()
        };
        // 640x480 with 96 planes: 320x240 with 48, then 160x120 with 24 (too few to halve).
        assert_eq!(levels(&rig(640, 480), &params(96)), 3);
        assert_eq!(levels(&rig(640, 480), &params(64)), 2);
        assert_eq!(levels(&rig(450, 375), &params(125)), 3);
        assert_eq!(
            levels(&rig(300, 300), &params(125)),
            2,
            "150 px: too small to halve"
        );
        assert_eq!(levels(&rig(384, 288), &params(32)), 1);
        // The deepest: 2048 planes halve six times (the WGSL engine keeps at most seven spare
        // shapes, gpu/mod.rs MAX_SPARES). With more, the level below would run its SGM over
        // more planes than SGM takes (MAX_SGM_PLANES): `wta` sweeps them at full resolution.
        assert_eq!(levels(&rig(16384, 16384), &params(2048)), 7);
        assert_eq!(levels(&rig(16384, 16384), &params(2049)), 1);
        assert_eq!(levels(&rig(640, 480), &params(4096)), 1);
        let off = SweepParams {
            coarse_to_fine: false,
            ..params(96)
        };
        assert_eq!(levels(&rig(640, 480), &off), 1);
        // `applies` is the first step of `levels`.
        for (w, h, planes) in [
            (640, 480, 96),
            (384, 288, 32),
            (100, 500, 96),
            (640, 480, 4096),
        ] {
            assert_eq!(
                applies(&rig(w, h), &params(planes)),
                levels(&rig(w, h), &params(planes)) > 1
            );
        }
    }

    /// Each reference keeps its plans; the least recently used goes past MAX_PLAN_SETS.
    #[test]
    fn plan_sets_keep_each_reference_most_recent_last() {
        let model = CameraModel::pinhole(crate::synthetic::intrinsics(64, 48));
        let rig = |r: usize| crate::synthetic::row_rig(3, 0.1, model, r).expect("rig");
        let mut sets = PlanSets::default();
        let params = SweepParams::default();
        let plan = SweepPlan::new(&rig(0), &params).expect("plan");
        sets.for_rig(&rig(0)).whole = Some((rig(0), params.clone(), plan));
        sets.for_rig(&rig(1));
        sets.for_rig(&rig(2));
        let keys = |s: &PlanSets| s.sets.iter().map(|(k, _)| k.clone()).collect::<Vec<_>>();
        assert_eq!(keys(&sets), ["cam0", "cam1", "cam2"]);
        // cam0 again: its plans come back, moved last.
        assert!(sets.for_rig(&rig(0)).whole.is_some());
        assert_eq!(keys(&sets), ["cam1", "cam2", "cam0"]);
        assert!(sets.for_rig(&rig(1)).whole.is_none());
        assert_eq!(keys(&sets), ["cam2", "cam0", "cam1"]);
        // Other references fill the cache: the least recently used goes.
        for i in 0..MAX_PLAN_SETS {
            let mut other = rig(1);
            other.cameras[1].name = format!("other{i}");
            sets.for_rig(&other);
        }
        assert_eq!(sets.sets.len(), MAX_PLAN_SETS);
        assert!(!keys(&sets).contains(&"cam0".to_string()));
    }

    #[test]
    fn half_model_keeps_pixel_centres() {
        let model = CameraModel::pinhole(crate::geometry::PinholeIntrinsics {
            width_px: 640,
            height_px: 480,
            fx_px: 500.0,
            fy_px: 500.0,
            cx_px: 319.5,
            cy_px: 239.5,
        });
        let half = half_model(&model).intrinsics;
        assert_eq!((half.width_px, half.height_px), (320, 240));
        assert_eq!((half.cx_px, half.cy_px, half.fx_px), (159.5, 119.5, 250.0));
    }
}
