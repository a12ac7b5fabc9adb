//! "How to run it": the wgpu engine. It takes a device and queue from its caller, makes its
//! layouts and pipelines from the stage registry (`sweep/stages.rs`) once, and keeps its buffers
//! across frame sets of the same shape; a new rig or new parameters re-plan, a new shape
//! re-allocates. What runs for a plan is the [`Schedule`] of its shape; a frame set's levels
//! (coarse to fine, each level's plane ranges made on the device from the level below) are
//! recorded into one command buffer (one compute pass per phase), submitted once and read back
//! after one wait.
//!
//! - `shape.rs`: the shape of work on this adapter (batches sized on what the mode allocates,
//!   SGM row bands; limits checked).
//! - `pipelines.rs`: layouts, modules and specialised pipelines from the registry.
//! - `buffers.rs`: the buffers of a shape, bind groups by binding name, the plan's upload.
//! - `pyramid.rs`: the frame set's images on the device (uploaded once, a pair's prefiltered
//!   and halved there for coarse to fine, copied into a level's `images` buffer).
//! - `record.rs`: recording the census, the schedule, the submission, the readback and
//!   per-phase timestamps.
//! - `upload.rs`: the set's uploads (images, plane ranges) through one staging buffer kept from
//!   set to set, mapped again right after each submission.
//! - `copies.rs`: those copies and the maps' unpacking split over threads (`HostCopies`).
//! - `level_images.rs`: how a level's images get to the device (uploaded, unpacked, made from
//!   the level above, copied from a held set's).
//! - `set_images.rs`: a frame set's images kept on the device across its references.
//! - `pending.rs`: sets submitted ahead and read back in order; `lent.rs`: their depth and
//!   confidence lent out of the mapped readback buffer.

mod buffers;
pub(crate) mod copies;
mod lent;
mod level_images;
mod pending;
mod pipelines;
mod pyramid;
mod record;
mod set_images;
#[cfg(test)]
mod shader_check;
mod shape;
mod upload;

use std::time::Instant;

use super::coarse::{LevelDepth, LevelImages};
use super::gpu_types::{MAP_COUNT, MAP_DEPTH_RAW};
use super::plan::SweepPlan;
use super::schedule::Schedule;
use super::stages::Stage;
use super::{CancelFlag, DepthMaps, StageTimings, SweepError, SweepParams, WantedMaps};
use crate::geometry::Rig;
use crate::image::{CameraImage, Rgba8Image, SetImages};
use buffers::{Alignments, Buffers};
pub use copies::HostCopies;
pub use lent::LentMaps;
use level_images::LevelInput;
pub use pipelines::SgmLayout;
use pipelines::{Pipelines, Specialisation};
use pyramid::Pyramid;
pub use record::SgmWalks;
use shape::ShapeKey;
pub use shape::{CostRows, SelectReads};

pub use super::schedule::{sgm_lines, SGM_DIRECTIONS};

/// What the WGSL engine did on the host since [`GpuEngine::take_set_counts`] was last called
/// (`bench` takes them after every frame set): every level of a coarse-to-fine sweep, every
/// reference of a set.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct SetCounts {
    /// Plans run (levels of coarse to fine, references).
    pub levels: u32,
    /// Command buffers submitted to the queue.
    pub submissions: u32,
    /// SGM's compute dispatches, every level's (one direction each, or several side by side:
    /// [`SgmWalks`]): the walks of one dispatch run one after the other's.
    pub sgm_dispatches: u32,
    /// The sweep's compute dispatches, every level's (cost, row sums, aggregate per batch of
    /// planes and band of the volume; `CostRows`).
    pub sweep_dispatches: u32,
    /// Buffers mapped and read back.
    pub readbacks: u32,
    /// Bytes of those buffers.
    pub readback_bytes: u64,
    /// Blocking waits for the GPU.
    pub waits: u32,
    /// Milliseconds spent in those waits.
    pub wait_ms: f64,
    /// Milliseconds spent in `Queue::submit` (lavapipe blocks there while an earlier
    /// submission runs: a wait in all but name).
    pub submit_ms: f64,
    /// Bytes of the caller's images written up (each reference's views, or each camera of a
    /// set of several references once: `set_images.rs`).
    pub image_bytes: u64,
    /// The most submissions whose maps were not read back yet at once: 1 where each
    /// submission is read back before the next, the references of a set where they are all
    /// submitted first (`GpuEngine::submit_set`).
    pub most_in_flight: u32,
    /// Staging buffers made for the uploads (images, plane ranges): the engine's own, kept
    /// from set to set (so 0 once it is made), and one per write it could not take
    /// (`Queue::write_buffer` makes one per call).
    pub staging_buffers: u32,
    /// Readback buffers made for sets submitted ahead: kept from set to set (and given back
    /// by the maps lent out of them when those are dropped), so 0 once there are enough.
    pub readback_buffers: u32,
    /// Milliseconds of `run` (or `run_plan`) neither waiting for the GPU nor in `submit`: the
    /// host's share of a frame set (planning, images, census, half-size images, uploads,
    /// recording, unpacking the maps).
    pub host_ms: f64,
}

/// A level recorded into the frame set's command buffer.
struct Recorded {
    /// Its `maps` buffer and the bytes of its raw depths there (the plane ranges of the level
    /// after it are made from them on the device).
    maps: wgpu::Buffer,
    depth_raw: std::ops::Range<u64>,
    /// Its resolved timestamps and their count (None where the adapter has none).
    timestamps: Option<(wgpu::Buffer, u32)>,
    schedule: Schedule,
}

/// The frame set being recorded: every level of a coarse-to-fine sweep goes into one command
/// buffer, each level's plane ranges made on the device from the raw depths of the level
/// before it, submitted once with the last level and read back after one wait.
struct OpenSet {
    encoder: wgpu::CommandEncoder,
    levels: Vec<Recorded>,
    started: Instant,
}

/// The GPU plane-sweep engine.
pub struct GpuEngine {
    device: wgpu::Device,
    queue: wgpu::Queue,
    pipelines: Pipelines,
    align: Alignments,
    /// How SGM spreads a path line over the adapter.
    sgm_layout: SgmLayout,
    /// How SGM dispatches its directions (`SgmWalks::Auto`: by the adapter, `gpu`).
    sgm_walks: SgmWalks,
    /// Whether the costs and their row sums run as one stage (`CostRows::Auto`: by the
    /// adapter, `gpu`).
    cost_rows: CostRows,
    /// How SGM's selection reads its words (`SelectReads::Auto`: by the adapter).
    select_reads: SelectReads,
    /// The adapter is not a CPU (lavapipe, llvmpipe).
    gpu: bool,
    /// The adapter's smallest subgroup (the subgroup layout's workgroup).
    subgroup_size: u32,
    /// Path lines per workgroup of the subgroup layout (`sgm_lines_for`).
    sgm_lines: u32,
    /// A smaller limit than the adapter's for one band of the SGM volume (tests of the bands).
    sgm_band_bytes: Option<u64>,
    /// Another budget than `shape::slab_budget`'s for one batch of planes (tests of the
    /// batches, `bench --slab-mib`).
    slab_bytes: Option<u64>,
    /// The buffers of the last shape, and what runs on them.
    buffers: Option<(Buffers, Schedule)>,
    /// The buffers of the shapes before (with the id of the plan uploaded into them), the
    /// latest last: a coarse-to-fine sweep cycles through its levels' shapes every frame set.
    spares: Vec<(Buffers, Schedule, Option<u64>)>,
    /// The plans of each reference's last rig and parameters (`sweep/coarse.rs`).
    plans: super::coarse::PlanSets,
    /// What the references of one frame set share (`sweep/frame_memo.rs`).
    memo: super::frame_memo::FrameMemo,
    /// Id of the plan whose arrays are in the buffers.
    uploaded_plan: Option<u64>,
    /// The frame set's images on the device, level by level (coarse to fine).
    pyramid: Option<Pyramid>,
    /// The deepest level of `pyramid` made for the current `run` (None: nothing uploaded yet;
    /// each `run`, `run_plan` and `run_plan_raw` starts afresh).
    pyramid_filled: Option<usize>,
    /// The images of a frame set of several references, kept across them.
    set_images: set_images::SetOnDevice,
    /// The levels of the current frame set recorded so far (None between frame sets).
    open: Option<OpenSet>,
    /// The staging buffers of the uploads, kept from set to set.
    uploads: upload::Uploads,
    /// Frame sets submitted and not read back yet (`pending.rs`).
    deferred: pending::Deferred,
    /// The maps beyond depth and confidence that `run` reads back and unpacks.
    wanted: WantedMaps,
    /// Whether the images' and the maps' host copies run on several threads.
    host_copies: HostCopies,
    timings: StageTimings,
    cancel: CancelFlag,
    counts: SetCounts,
}

/// Buffers of other shapes kept at most: the levels below the full-resolution one of the
/// deepest coarse-to-fine sweep (4096 planes halve seven times before they fall under 48:
/// `coarse::levels` is at most 8).
const MAX_SPARES: usize = 7;

fn gpu_err(e: impl std::fmt::Display) -> SweepError {
    SweepError::Gpu(e.to_string())
}

impl GpuEngine {
    /// Builds the layouts and shader modules on the caller's device. Shader compilation errors
    /// are caught with an error scope and returned.
    pub fn new(device: &wgpu::Device, queue: &wgpu::Queue) -> Result<Self, SweepError> {
        let pipelines = Pipelines::new(device)?;
        let info = device.adapter_info();
        // Subgroups where the adapter has them: a line's planes across the lanes in registers,
        // no barrier (lavapipe too: its SGM stage 313-334 ms against 500-605 ms one invocation
        // per line and 3715 ms in workgroup memory, Tsukuba 384x288 x 32 planes, 8 paths).
        // Without them a CPU adapter pays for every barrier with a coroutine switch per SIMD
        // batch: there each invocation walks a whole path line; a GPU takes a workgroup per
        // line, the planes across its lanes in workgroup memory.
        let sgm_layout = if pipelines.has_subgroups() {
            SgmLayout::Subgroup
        } else if info.device_type == wgpu::DeviceType::Cpu {
            SgmLayout::LinePerInvocation
        } else {
            SgmLayout::Workgroup
        };
        Ok(Self {
            device: device.clone(),
            queue: queue.clone(),
            pipelines,
            align: Alignments::of(device),
            sgm_layout,
            sgm_walks: SgmWalks::Auto,
            cost_rows: CostRows::Auto,
            select_reads: SelectReads::Auto,
            gpu: info.device_type != wgpu::DeviceType::Cpu,
            subgroup_size: info.subgroup_min_size,
            sgm_lines: shape::sgm_lines_for(&info),
            sgm_band_bytes: None,
            slab_bytes: None,
            buffers: None,
            spares: Vec::new(),
            plans: Default::default(),
            memo: Default::default(),
            uploaded_plan: None,
            pyramid: None,
            pyramid_filled: None,
            set_images: Default::default(),
            open: None,
            uploads: upload::Uploads::new(),
            deferred: pending::Deferred::default(),
            wanted: WantedMaps::ALL,
            host_copies: HostCopies::Auto,
            timings: StageTimings::default(),
            cancel: CancelFlag::new(),
            counts: SetCounts::default(),
        })
    }

    /// Whether the host copies of the images and the maps run on several threads (`copies.rs`).
    pub fn set_host_copies(&mut self, copies: HostCopies) {
        self.host_copies = copies;
    }

    /// Path lines per workgroup of the subgroup SGM instead of the adapter's default (tests and
    /// comparisons; 1: a workgroup per line). The sums are the same whatever the count.
    pub fn set_sgm_lines(&mut self, lines: u32) {
        self.sgm_lines = lines.max(1);
    }

    /// Path lines per workgroup of the subgroup SGM.
    pub fn sgm_lines(&self) -> u32 {
        self.sgm_lines
    }

    /// Chooses the SGM layout instead of the adapter's default (tests run every layout the
    /// adapter has). Results are identical. Row bands always use one invocation per line.
    /// `SgmLayout::Subgroup` on an adapter without subgroup operations is an error.
    pub fn set_sgm_layout(&mut self, layout: SgmLayout) -> Result<(), SweepError> {
        if layout == SgmLayout::Subgroup && !self.pipelines.has_subgroups() {
            return Err(SweepError::InvalidParams(
                "the subgroup SGM layout needs an adapter with subgroup operations \
                 (wgpu::Features::SUBGROUP)"
                    .into(),
            ));
        }
        self.sgm_layout = layout;
        Ok(())
    }

    /// How SGM dispatches its directions in the subgroup layout over one band (the default,
    /// `SgmWalks::Auto`: every direction in one dispatch on GPUs, one dispatch per direction
    /// on CPU adapters). Results are identical.
    pub fn set_sgm_walks(&mut self, walks: SgmWalks) {
        self.sgm_walks = walks;
    }

    /// Whether the costs and their row sums run as one stage where the plan allows it (the
    /// default, `CostRows::Auto`: on GPUs, apart on CPU adapters). Results are identical.
    pub fn set_cost_rows(&mut self, rows: CostRows) {
        self.cost_rows = rows;
    }

    /// How SGM's selection reads each pixel's words (the default, `SelectReads::Auto`: through
    /// workgroup memory on GPUs, in place on CPU adapters). Results are identical.
    pub fn set_select_reads(&mut self, reads: SelectReads) {
        self.select_reads = reads;
    }

    /// The SGM layout the engine uses when one band holds the volume.
    pub fn sgm_layout(&self) -> SgmLayout {
        self.sgm_layout
    }

    /// The adapter has subgroup operations (the subgroup SGM layout can run).
    pub fn has_subgroups(&self) -> bool {
        self.pipelines.has_subgroups()
    }

    /// Caps the bytes of one row band of the SGM cost volume below the adapter's storage binding
    /// limit (`None`: the adapter's limit). Tests use it to run small volumes in several bands;
    /// the result equals the run in one band.
    pub fn set_sgm_band_bytes(&mut self, max_bytes: Option<u64>) {
        self.sgm_band_bytes = max_bytes;
    }

    /// The bytes of one batch of planes (cost slab and window sums; `None`: the engine's
    /// budget, 192 MiB on a CPU adapter, 512 MiB on a GPU, at most the adapter's binding
    /// limit). Tests use it to run a plan in several batches (the result equals the run in
    /// one), `bench --slab-mib` to compare budgets on a GPU.
    pub fn set_slab_bytes(&mut self, max_bytes: Option<u64>) {
        self.slab_bytes = max_bytes;
    }

    /// Batches of planes of the last level run (1 when one slab held every plane).
    pub fn batches(&self) -> u32 {
        self.buffers.as_ref().map_or(0, |(b, _)| b.key.batches())
    }

    /// Row bands of the SGM volume in the last frame set (1 when one binding held it).
    pub fn sgm_bands(&self) -> u32 {
        self.buffers.as_ref().map_or(0, |(b, _)| b.key.bands())
    }

    /// The maps beyond depth and confidence that `run` and `run_plan` read back and unpack
    /// (all by default; one left out comes back empty, its bytes never leave the device: the
    /// node and `bag` leave out the diagnostic maps, the node the cost and selection while
    /// nobody subscribes to them).
    pub fn set_wanted_maps(&mut self, wanted: WantedMaps) {
        self.wanted = wanted;
    }

    /// Per-stage times of the last frame set.
    pub fn last_timings(&self) -> &StageTimings {
        &self.timings
    }

    /// Submissions, readbacks, waits and host time since the last call (then zero again).
    pub fn take_set_counts(&mut self) -> SetCounts {
        std::mem::take(&mut self.counts)
    }

    /// Runs `f`, adding its wall time less the GPU waits it made to `host_ms`.
    /// Each call is a frame set of its own: the image pyramid is filled again.
    fn timed<T>(&mut self, f: impl FnOnce(&mut Self) -> T) -> T {
        self.pyramid_filled = None;
        if self.open.take().is_some() {
            self.uploads.abandoned();
        }
        self.set_images.abandoned();
        self.measured(f)
    }

    /// Runs `f`, adding its wall time less the GPU waits it made to `host_ms`.
    fn measured<T>(&mut self, f: impl FnOnce(&mut Self) -> T) -> T {
        let started = Instant::now();
        let waited_before = self.counts.wait_ms + self.counts.submit_ms;
        let made_before = self.uploads.made();
        let result = f(self);
        let waited = self.counts.wait_ms + self.counts.submit_ms - waited_before;
        self.counts.host_ms += started.elapsed().as_secs_f64() * 1e3 - waited;
        self.counts.staging_buffers += (self.uploads.made() - made_before) as u32;
        result
    }

    pub fn adapter_info(&self) -> wgpu::AdapterInfo {
        self.device.adapter_info()
    }

    /// Stops a run before each level's submission and while it waits for the GPU once
    /// `cancel` is set ([`SweepError::Cancelled`]; the GPU finishes the level it was given).
    pub fn set_cancel(&mut self, cancel: CancelFlag) {
        self.cancel = cancel;
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

    /// [`GpuEngine::run`] with the images as a [`SetImages`]: each uploaded from where it lies.
    pub fn run_set(
        &mut self,
        rig: &Rig,
        images: SetImages<'_>,
        params: &SweepParams,
    ) -> Result<DepthMaps, SweepError> {
        self.sweep_set(rig, params, |engine, plans| {
            super::coarse::run(engine, plans, rig, images, params)
        })
    }

    /// Runs `sweep` (`coarse::run`, or `coarse::start` for a set submitted ahead) as one
    /// timed frame set with the plans of `rig`'s reference.
    fn sweep_set<T>(
        &mut self,
        rig: &Rig,
        params: &SweepParams,
        sweep: impl FnOnce(&mut Self, &mut super::coarse::Plans) -> Result<T, SweepError>,
    ) -> Result<T, SweepError> {
        self.timed(|engine| {
            // One shape at a time outside coarse to fine: the other levels' buffers go; with
            // it, the buffers of every level below the current one stay.
            let below = super::coarse::levels(rig, params) - 1;
            let excess = engine.spares.len().saturating_sub(below);
            engine.spares.drain(..excess);
            let mut plans = std::mem::take(&mut engine.plans);
            let result = sweep(engine, plans.for_rig(rig));
            engine.plans = plans;
            result
        })
    }

    /// Records the next level of the frame set: a level recorded before it in the set is the
    /// level below it (`run_plan_for_ranges`), and this one is narrowed from it.
    fn record_next_level(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: LevelImages<'_>,
    ) -> Result<(), SweepError> {
        let narrowed = self.open.as_ref().is_some_and(|o| !o.levels.is_empty());
        self.record_level(plan, rig, images, narrowed)
    }

    /// Runs a prepared plan (e.g. with a custom hypothesis family).
    pub fn run_plan(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: &[Rgba8Image],
    ) -> Result<DepthMaps, SweepError> {
        // The caller's images: a plan that reads the prefilter's makes them on the device.
        self.timed(|engine| {
            engine.record_level(plan, rig, LevelImages::given(images), false)?;
            engine.finish_maps(plan)
        })
    }

    /// Runs a plan and returns the raw `maps` buffer (MAP_COUNT sections), for stage comparisons.
    pub fn run_plan_raw(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: &[Rgba8Image],
    ) -> Result<Vec<f32>, SweepError> {
        self.timed(|engine| {
            engine.record_level(plan, rig, LevelImages::given(images), false)?;
            engine.finish_set(0..MAP_COUNT, <[f32]>::to_vec)
        })
    }

    /// The words of the last level's `images` buffer (every camera's pixels, then the census
    /// words with a census cost), read back (tests compare them with the CPU twins).
    pub fn device_images(&mut self) -> Result<Vec<u32>, SweepError> {
        let Some((buffers, _)) = self.buffers.as_ref() else {
            return Err(SweepError::Gpu("no level has run".into()));
        };
        let words = buffers.key.image_words as u64;
        self.read_buffer(&buffers.images, words * 4)
    }

    /// The `plane_ranges` buffer of the last level run (per row and tile: its own first and
    /// last plane, then the window hull's; `SweepPlan::shader_plane_ranges`), read
    /// back: in a coarse-to-fine `run`, made on the device from the level below (tests compare
    /// them with `coarse::plane_ranges`).
    pub fn device_plane_ranges(&mut self) -> Result<Vec<[u32; 4]>, SweepError> {
        let Some((buffers, _)) = self.buffers.as_ref() else {
            return Err(SweepError::Gpu("no level has run".into()));
        };
        let tiles = u64::from(crate::sweep::plan::range_tiles(buffers.key.width));
        let bytes = u64::from(buffers.key.height) * tiles * 16;
        let words = self.read_buffer(&buffers.plane_ranges, bytes)?;
        Ok(words
            .chunks_exact(4)
            .map(|r| [r[0], r[1], r[2], r[3]])
            .collect())
    }

    /// The words of level `level` of the image pyramid (every camera's pixels at that level;
    /// 0 = the caller's images) as the last coarse-to-fine `run` made it (tests compare them
    /// with `coarse::half_image`).
    pub fn device_image_level(&mut self, level: usize) -> Result<Vec<u32>, SweepError> {
        let Some((buffer, bytes)) = self.pyramid.as_ref().and_then(|p| p.level_buffer(level))
        else {
            return Err(SweepError::Gpu(format!("no image level {level}")));
        };
        self.read_buffer(buffer, bytes)
    }

    /// Copies the first `bytes` of `buffer` to a fresh readback buffer and reads it back.
    fn read_buffer(&self, buffer: &wgpu::Buffer, bytes: u64) -> Result<Vec<u32>, SweepError> {
        record::read_buffer(&self.device, &self.queue, &self.cancel, buffer, bytes)
    }

    /// Makes the buffers of shape `key` the current ones: kept, taken from the spares, or made;
    /// the replaced ones become a spare.
    fn use_buffers(&mut self, key: ShapeKey) -> Result<(), SweepError> {
        if self.buffers.as_ref().map(|(b, _)| b.key) != Some(key) {
            let (buffers, schedule, uploaded) =
                match self.spares.iter().position(|spare| spare.0.key == key) {
                    Some(i) => self.spares.remove(i),
                    None => {
                        let buffers =
                            Buffers::new(&self.device, &self.pipelines.layouts, self.align, key)?;
                        (buffers, key.schedule(), None)
                    }
                };
            if let Some((old, old_schedule)) = self.buffers.replace((buffers, schedule)) {
                // One per level below the current one: `run` drops the rest before each frame
                // set, and a level's shape is taken out of the spares when it runs. The bound
                // is for callers of `run_plan` alone, who cycle through shapes of their own.
                self.spares.push((old, old_schedule, self.uploaded_plan));
                if self.spares.len() > MAX_SPARES {
                    self.spares.remove(0);
                }
            }
            self.uploaded_plan = uploaded;
        }
        Ok(())
    }

    /// The shape of `plan` on this device, and the SGM layout it runs in.
    fn shape_of(&self, plan: &SweepPlan) -> Result<(ShapeKey, SgmLayout), SweepError> {
        let limits = self.device.limits();
        let fused = self.cost_rows.fused(self.gpu);
        let budget = self.slab_bytes.unwrap_or(shape::slab_budget(self.gpu));
        let key = ShapeKey::of(plan, &limits, self.sgm_band_bytes, Some(budget), fused)?;
        // Workgroup memory does not outlive a dispatch: bands carry the path state in the
        // per-line scratch of the line-per-invocation layout.
        let layout = if key.bands() > 1 {
            SgmLayout::LinePerInvocation
        } else {
            self.sgm_layout
        };
        Ok((key, layout))
    }

    /// Records one plan (one level of a frame set) into the frame set's command buffer: its
    /// uploads, its plane ranges from the level recorded before it (`narrowed`: coarse to fine
    /// on the device; otherwise the plan's own ranges are uploaded), its images and its
    /// schedule. Nothing is submitted: [`Self::finish_set`] does, once per frame set.
    fn record_level(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: LevelImages<'_>,
        narrowed: bool,
    ) -> Result<(), SweepError> {
        self.counts.levels += 1;
        // The level's images (`level_images.rs`).
        let LevelInput {
            prefilter,
            packed,
            held,
            halvings,
            fill,
            from_pyramid,
            missing,
        } = self.level_input(rig, images, plan.params.colour_in_alpha != 0)?;
        let (key, layout) = self.shape_of(plan)?;
        self.use_buffers(key)?;
        let spec = Specialisation {
            select_chunked: self.select_reads.chunked(self.gpu),
            ..Specialisation::of(plan, layout, self.subgroup_size, self.sgm_lines)
        };
        let pipelines = self.pipelines.get(&self.device, &spec)?;
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let Some((buffers, schedule)) = self.buffers.as_ref() else {
            return Err(SweepError::Gpu("internal: no buffers".into()));
        };
        if self.uploaded_plan != Some(plan.id) {
            buffers.upload_plan(&self.queue, self.align, plan);
            self.uploaded_plan = Some(plan.id);
        }
        let open = self.open.get_or_insert_with(|| OpenSet {
            encoder: self
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("frame set"),
                }),
            levels: Vec::new(),
            started: Instant::now(),
        });
        let encoder = &mut open.encoder;
        // The uploads first, through the staging buffer: the plan's own plane ranges (not
        // narrowed on the device), the caller's images, each from its own pixels at its
        // camera's offset (no packing), into the `images` buffer or the pyramid's first level.
        let ranges = (!narrowed).then(|| plan.shader_plane_ranges());
        let mut parts: Vec<upload::Part<'_>> = Vec::with_capacity(plan.cameras.len() + 1);
        if let Some(ranges) = &ranges {
            parts.push(upload::Part {
                target: &buffers.plane_ranges,
                offset: 0,
                data: bytemuck::cast_slice(ranges),
            });
        }
        match (from_pyramid, self.pyramid.as_ref()) {
            (false, _) => {
                for (image, camera) in images.full().iter().zip(&plan.cameras) {
                    let CameraImage::Rgba(image) = image else {
                        return Err(SweepError::Gpu("internal: a packed image uploaded".into()));
                    };
                    parts.push(upload::Part {
                        target: &buffers.images,
                        offset: u64::from(camera.size[2]) * 4,
                        data: bytemuck::cast_slice(&image.pixels),
                    });
                }
            }
            (true, Some(_)) if fill && held => {
                parts.extend(self.set_images.uploads(images.full(), &missing)?);
            }
            (true, Some(pyramid)) if fill => {
                parts.extend(pyramid.uploads(images.full(), prefilter)?);
            }
            (true, Some(_)) => {}
            (true, None) => return Err(SweepError::Gpu("internal: no image pyramid".into())),
        }
        let ranges_bytes = ranges.map_or(0, std::mem::size_of_val);
        let bytes: usize = parts.iter().map(|p| p.data.len()).sum();
        self.counts.image_bytes += (bytes - ranges_bytes) as u64;
        let copies = self.host_copies;
        self.uploads
            .write(&self.device, &self.queue, encoder, &parts, copies);
        drop(parts);
        match (narrowed, open.levels.last()) {
            (false, _) => {}
            (true, Some(below)) => record::record_plane_ranges(
                encoder,
                buffers,
                pipelines,
                &below.maps,
                below.depth_raw.clone(),
            )?,
            (true, None) => {
                return Err(SweepError::Gpu(
                    "internal: a narrowed level with no level below".into(),
                ))
            }
        }
        if let (true, Some(pyramid)) = (from_pyramid, self.pyramid.as_ref()) {
            if fill {
                self.pyramid_filled = Some(halvings);
                let unpack = &pipelines[Stage::Unpack as usize];
                if held {
                    let written = (images.full(), &missing[..]);
                    self.set_images
                        .record(encoder, unpack, written, pyramid, prefilter)?;
                } else if packed {
                    pyramid.record_unpack(encoder, unpack);
                }
                if prefilter {
                    pyramid.record_prefilter(encoder, &pipelines[Stage::Prefilter as usize])?;
                }
                pyramid.record_halvings(encoder, &pipelines[Stage::Half as usize], halvings);
            }
            pyramid.record_copy(encoder, halvings, plan, &buffers.images)?;
        }
        if plan.uses_census() {
            record::record_census(encoder, buffers, &pipelines[Stage::Census as usize], plan);
        }
        let walks = self.sgm_walks.resolve(&spec, buffers, self.gpu);
        let (sgm, sweep) = record::record_sweep(
            encoder, buffers, pipelines, &spec, schedule, self.align, walks,
        );
        self.counts.sgm_dispatches += sgm;
        self.counts.sweep_dispatches += sweep;
        if let Some(error) = futures::executor::block_on(scope.pop()) {
            return Err(SweepError::Gpu(format!("encoding the sweep: {error}")));
        }
        let section = plan.pixel_count() as u64 * 4;
        let first = MAP_DEPTH_RAW as u64 * section;
        open.levels.push(Recorded {
            maps: buffers.maps.clone(),
            depth_raw: first..first + section,
            timestamps: buffers
                .timestamps
                .as_ref()
                .map(|t| (t.resolve.clone(), t.count)),
            schedule: schedule.clone(),
        });
        Ok(())
    }

    /// [`Self::finish_set`] with the wanted maps of `plan` unpacked.
    fn finish_maps(&mut self, plan: &SweepPlan) -> Result<DepthMaps, SweepError> {
        let (wanted, copies) = (self.wanted, self.host_copies);
        let sections = SweepPlan::unpacked_sections(wanted);
        let first = sections.start;
        self.finish_set(sections, |m| {
            plan.unpack_map_sections(m, first, wanted, copies.split(m.len() * 4))
        })
    }

    /// Submits the frame set recorded so far (one submission), waits once and reads back
    /// once (`pending.rs`): the last level's maps, `unpack`ed straight out of the mapped
    /// range, and every level's timestamps.
    fn finish_set<T>(
        &mut self,
        sections: std::ops::Range<usize>,
        unpack: impl FnOnce(&[f32]) -> T,
    ) -> Result<T, SweepError> {
        let submitted = self.submit_open_set(sections, false)?;
        self.read_submitted(submitted, unpack)
    }
}

impl super::coarse::PlanRunner for GpuEngine {
    fn run_plan(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: LevelImages<'_>,
    ) -> Result<DepthMaps, SweepError> {
        // Inside `run`, which times the whole frame set.
        self.record_next_level(plan, rig, images)?;
        self.finish_maps(plan)
    }

    /// The last level read back now, or submitted ahead (`GpuEngine::submit_set`).
    fn run_plan_last(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: LevelImages<'_>,
    ) -> Result<LevelDepth, SweepError> {
        self.run_last_level(plan, rig, images)
    }

    fn run_plan_for_ranges(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: LevelImages<'_>,
    ) -> Result<LevelDepth, SweepError> {
        // Recorded, not submitted: the next level's plane ranges are made from its raw depths
        // on the device, in the same command buffer.
        self.record_next_level(plan, rig, images)?;
        Ok(LevelDepth::Device)
    }

    fn timings_mut(&mut self) -> &mut StageTimings {
        &mut self.timings
    }

    fn memo(&mut self) -> &mut super::frame_memo::FrameMemo {
        &mut self.memo
    }

    fn prefilters_on_device(&self) -> bool {
        true
    }
}
