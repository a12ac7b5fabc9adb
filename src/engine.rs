//! Which engine runs the sweep: the WGSL engine on a wgpu adapter, or the CPU engine. `auto`
//! takes a hardware GPU when wgpu offers one (an adapter that is not `DeviceType::Cpu`) and the
//! CPU engine otherwise: on a machine without a GPU, the CPU engine is several times faster than
//! the same shaders on Mesa's lavapipe (see docs/speed.md).

use crate::geometry::{Rig, RigCamera};
use crate::gpu_context::{GpuContext, GpuContextError};
use crate::image::{Rgba8Image, SetImages};
use crate::sweep::coarse::PlanRunner;
use crate::sweep::cpu::CpuEngine;
use crate::sweep::frame_memo::FrameMemo;
use crate::sweep::gpu::GpuEngine;
use crate::sweep::references::{reference_rig, ReferenceDepth, ReferenceRig};
use crate::sweep::{CancelFlag, DepthMaps, StageTimings, SweepError, SweepParams};

/// Which engine runs the sweep (`--device`, parameter `device`): this module.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    serde::Serialize,
    serde::Deserialize,
    clap::ValueEnum,
)]
#[serde(rename_all = "snake_case")]
pub enum Device {
    /// A hardware GPU if wgpu offers one (not a CPU adapter such as lavapipe), else the CPU
    /// engine.
    #[default]
    Auto,
    /// The WGSL engine on the wgpu adapter (`WGPU_ADAPTER_NAME` / `WGPU_BACKEND` pick one;
    /// lavapipe when there is no GPU).
    Gpu,
    /// The CPU engine.
    Cpu,
}

impl std::str::FromStr for Device {
    type Err = SweepError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "auto" => Ok(Self::Auto),
            "gpu" => Ok(Self::Gpu),
            "cpu" => Ok(Self::Cpu),
            other => Err(SweepError::InvalidParams(format!(
                "device '{other}' is not one of auto, gpu, cpu"
            ))),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum EngineError {
    #[error(transparent)]
    Gpu(#[from] GpuContextError),
    #[error(transparent)]
    Sweep(#[from] SweepError),
}

/// Runs the sweep; both engines and the wrapper implement it.
pub trait Sweeper {
    /// The depth of `rig`'s reference from `images`, one per camera of the rig.
    fn run(
        &mut self,
        rig: &Rig,
        images: &[Rgba8Image],
        params: &SweepParams,
    ) -> Result<DepthMaps, SweepError> {
        self.run_set(rig, SetImages::All(images), params)
    }

    /// [`Sweeper::run`] with the images as a [`SetImages`] (a frame set's cameras picked
    /// for one reference, not copied).
    fn run_set(
        &mut self,
        rig: &Rig,
        images: SetImages<'_>,
        params: &SweepParams,
    ) -> Result<DepthMaps, SweepError>;

    /// What the references of one frame set share (`sweep/frame_memo.rs`).
    fn memo(&mut self) -> &mut FrameMemo;

    /// The per-stage times of the last run.
    fn timings_mut(&mut self) -> &mut StageTimings;

    /// The depth of `rig`'s reference from the views chosen for it: a camera reference sweeps
    /// with its neighbours (`geometry::neighbours`: at most `max_neighbours`, the best for
    /// depth), as each of several references does in [`Sweeper::run_references`]; a virtual
    /// reference with every camera ([`Sweeper::run`]).
    fn run_views(
        &mut self,
        rig: &Rig,
        images: &[Rgba8Image],
        params: &SweepParams,
    ) -> Result<DepthMaps, SweepError> {
        match rig.reference_index() {
            Some(reference) => self
                .run_references(&rig.cameras, images, &[reference], params)
                .pop()
                .unwrap_or(Err(SweepError::Cancelled))
                .map(|depth| depth.maps.into_owned()),
            None => self.run(rig, images, params),
        }
    }

    /// The depth of each of `references` (indices into the set's `cameras`, one image each
    /// in `images`), each swept with its own neighbours (`sweep/references.rs`); the census
    /// words and half-size images of the set are made once for all of them. One result per
    /// reference, in order: a reference that fails does not stop the others.
    fn run_references(
        &mut self,
        cameras: &[RigCamera],
        images: &[Rgba8Image],
        references: &[usize],
        params: &SweepParams,
    ) -> Vec<Result<ReferenceDepth, SweepError>> {
        self.run_references_set(cameras, SetImages::All(images), references, params)
    }

    /// Whether the engine takes packed images ([`crate::image::PackedImage`]) without a
    /// conversion on the host (the WGSL engine unpacks them on the device).
    fn unpacks_on_device(&self) -> bool {
        false
    }

    /// [`Sweeper::run_references`] with the set's images as a [`SetImages`] (some of them
    /// packed: see [`Sweeper::unpacks_on_device`]).
    fn run_references_set(
        &mut self,
        cameras: &[RigCamera],
        images: SetImages<'_>,
        references: &[usize],
        params: &SweepParams,
    ) -> Vec<Result<ReferenceDepth, SweepError>> {
        each_reference(self, cameras, images, references, params)
    }

    /// Starts the set of [`Sweeper::run_references_set`]: an engine that can
    /// ([`Sweeper::starts_without_waiting`]) submits its work to the device and returns;
    /// [`Sweeper::finish_references_set`] (with the same images and parameters) waits for it.
    /// Several sets may be started before the first is finished; they finish in order. An
    /// engine that cannot runs the set here.
    fn start_references_set(
        &mut self,
        cameras: &[RigCamera],
        images: SetImages<'_>,
        references: &[usize],
        params: &SweepParams,
    ) -> StartedSet {
        let results = self.run_references_set(cameras, images, references, params);
        StartedSet::done(self, results)
    }

    /// The results of the oldest set [`Sweeper::start_references_set`] started.
    fn finish_references_set(
        &mut self,
        started: StartedSet,
        _images: SetImages<'_>,
        _params: &SweepParams,
    ) -> Vec<Result<ReferenceDepth, SweepError>> {
        started.into_results(self)
    }

    /// Whether [`Sweeper::start_references_set`] returns before the set's work is done (the
    /// WGSL engine submits it to the device): a caller may then start the next set before it
    /// finishes this one.
    fn starts_without_waiting(&self) -> bool {
        false
    }
}

/// [`Sweeper::run_references_set`]: each reference swept with its own views, picked from the
/// set's images, within one frame memo.
fn each_reference<S: Sweeper + ?Sized>(
    engine: &mut S,
    cameras: &[RigCamera],
    images: SetImages<'_>,
    references: &[usize],
    params: &SweepParams,
) -> Vec<Result<ReferenceDepth, SweepError>> {
    if images.len() != cameras.len() {
        let error = || SweepError::ImageCount {
            images: images.len(),
            cameras: cameras.len(),
        };
        return references.iter().map(|_| Err(error())).collect();
    }
    engine.memo().begin(cameras.iter().map(|c| c.name.as_str()));
    let mut results = Vec::with_capacity(references.len());
    let mut stages: Vec<(String, f64)> = Vec::new();
    for &reference in references {
        let result = reference_rig(cameras, reference, params).and_then(|r| {
            let maps = engine.run_set(&r.rig, own(images, &r)?, params)?;
            Ok(ReferenceDepth {
                reference,
                cameras: r.cameras,
                maps: maps.into(),
            })
        });
        // The set's timings: every reference's stages summed.
        for (name, ms) in &engine.timings_mut().stages {
            match stages.iter_mut().find(|(n, _)| n == name) {
                Some((_, total)) => *total += ms,
                None => stages.push((name.clone(), *ms)),
            }
        }
        let cancelled = matches!(result, Err(SweepError::Cancelled));
        results.push(result);
        if cancelled {
            break;
        }
    }
    engine.memo().end();
    if references.len() > 1 {
        engine.timings_mut().stages = stages;
    }
    results
}

impl Sweeper for GpuEngine {
    fn run_set(
        &mut self,
        rig: &Rig,
        images: SetImages<'_>,
        params: &SweepParams,
    ) -> Result<DepthMaps, SweepError> {
        GpuEngine::run_set(self, rig, images, params)
    }

    fn unpacks_on_device(&self) -> bool {
        true
    }

    /// Each camera's image goes up once for all of the references (`GpuEngine::hold_set`),
    /// and every reference is submitted before the first is read back.
    fn run_references_set(
        &mut self,
        cameras: &[RigCamera],
        images: SetImages<'_>,
        references: &[usize],
        params: &SweepParams,
    ) -> Vec<Result<ReferenceDepth, SweepError>> {
        if references.len() < 2 {
            return each_reference(self, cameras, images, references, params);
        }
        let started = self.start_references_set(cameras, images, references, params);
        self.finish_references_set(started, images, params)
    }

    /// Submits every reference of the set (each camera's image up once for all of them,
    /// `GpuEngine::hold_set`) and returns without waiting for the device; with submitting
    /// ahead turned off (`GpuEngine::set_submit_ahead`), runs the set here.
    fn start_references_set(
        &mut self,
        cameras: &[RigCamera],
        images: SetImages<'_>,
        references: &[usize],
        params: &SweepParams,
    ) -> StartedSet {
        let run_here = |engine: &mut Self| {
            let results = each_reference(engine, cameras, images, references, params);
            StartedSet::done(engine, results)
        };
        let alone = !self.submits_ahead() && references.len() < 2;
        if alone || references.is_empty() || images.len() != cameras.len() {
            return run_here(self);
        }
        let rigs: Vec<_> = references
            .iter()
            .map(|&r| reference_rig(cameras, r, params))
            .collect();
        let held = references.len() > 1;
        if held {
            let mut used: Vec<usize> = rigs
                .iter()
                .flatten()
                .flat_map(|r| r.cameras.clone())
                .collect();
            used.sort_unstable();
            used.dedup();
            if let Err(e) = self.hold_set(images, &used) {
                tracing::debug!("each reference uploads its own images: {e}");
                return run_here(self);
            }
        }
        let started = match self.submits_ahead() {
            true => StartedSet::Submitted(submit_each(self, images, rigs, params)),
            false => run_here(self),
        };
        if held {
            self.release_set();
        }
        started
    }

    fn finish_references_set(
        &mut self,
        started: StartedSet,
        images: SetImages<'_>,
        params: &SweepParams,
    ) -> Vec<Result<ReferenceDepth, SweepError>> {
        match started {
            StartedSet::Submitted(submitted) => collect_each(self, images, submitted, params),
            done => done.into_results(self),
        }
    }

    fn starts_without_waiting(&self) -> bool {
        self.submits_ahead()
    }

    fn memo(&mut self) -> &mut FrameMemo {
        PlanRunner::memo(self)
    }

    fn timings_mut(&mut self) -> &mut StageTimings {
        PlanRunner::timings_mut(self)
    }
}

/// A frame set's references started by [`Sweeper::start_references_set`], for
/// [`Sweeper::finish_references_set`].
pub enum StartedSet {
    /// Run to the end already, with the set's timings.
    Done {
        results: Vec<Result<ReferenceDepth, SweepError>>,
        timings: StageTimings,
    },
    /// Each reference submitted to the device (or why not), in order, not read back yet.
    Submitted(Vec<Result<ReferenceRig, SweepError>>),
}

impl StartedSet {
    /// A set run to the end by `engine`, with its timings.
    fn done<S: Sweeper + ?Sized>(
        engine: &mut S,
        results: Vec<Result<ReferenceDepth, SweepError>>,
    ) -> Self {
        let timings = engine.timings_mut().clone();
        Self::Done { results, timings }
    }

    /// The results of a set run to the end (its timings made the engine's last again).
    fn into_results<S: Sweeper + ?Sized>(
        self,
        engine: &mut S,
    ) -> Vec<Result<ReferenceDepth, SweepError>> {
        match self {
            Self::Done { results, timings } => {
                *engine.timings_mut() = timings;
                results
            }
            Self::Submitted(submitted) => submitted
                .into_iter()
                .map(|_| {
                    Err(SweepError::InvalidParams(
                        "internal: a set submitted to a device handed to an engine without one"
                            .into(),
                    ))
                })
                .collect(),
        }
    }
}

/// The references of a set on the WGSL engine, each submitted in turn (the host records the
/// next while the GPU runs the one before), none waited for: read back by [`collect_each`].
fn submit_each(
    engine: &mut GpuEngine,
    images: SetImages<'_>,
    rigs: Vec<Result<ReferenceRig, SweepError>>,
    params: &SweepParams,
) -> Vec<Result<ReferenceRig, SweepError>> {
    let mut submitted = Vec::with_capacity(rigs.len());
    for rig in rigs {
        let result = rig.and_then(|r| {
            engine
                .submit_set(&r.rig, own(images, &r)?, params)
                .map(|()| r)
        });
        let cancelled = matches!(result, Err(SweepError::Cancelled));
        submitted.push(result);
        if cancelled {
            break;
        }
    }
    submitted
}

/// The references [`submit_each`] submitted, read back in the same order (the GPU runs the
/// next while the host reads one): one wait per reference. The results and timings as
/// [`each_reference`]'s. Sets submitted after this one stay submitted.
fn collect_each(
    engine: &mut GpuEngine,
    images: SetImages<'_>,
    submitted: Vec<Result<ReferenceRig, SweepError>>,
    params: &SweepParams,
) -> Vec<Result<ReferenceDepth, SweepError>> {
    let mut left = submitted.iter().filter(|r| r.is_ok()).count();
    let mut results = Vec::with_capacity(submitted.len());
    let mut stages: Vec<(String, f64)> = Vec::new();
    for result in submitted {
        let result = result.and_then(|r| {
            left -= 1;
            let maps = engine.collect_set(&r.rig, own(images, &r)?, params)?;
            // The set's timings: every reference's stages summed.
            for (name, ms) in &engine.last_timings().stages {
                crate::sweep::add_stage_ms(&mut stages, name, *ms);
            }
            Ok(ReferenceDepth {
                reference: r.reference,
                cameras: r.cameras,
                maps,
            })
        });
        let cancelled = matches!(result, Err(SweepError::Cancelled));
        results.push(result);
        if cancelled {
            break;
        }
    }
    // A cancelled set's references not read back.
    engine.drop_oldest_submitted(left);
    PlanRunner::timings_mut(engine).stages = stages;
    results
}

/// A reference's views, picked from the set's images without a copy.
fn own<'a>(images: SetImages<'a>, r: &'a ReferenceRig) -> Result<SetImages<'a>, SweepError> {
    images
        .pick(&r.cameras)
        .ok_or_else(|| SweepError::InvalidParams("internal: a view outside the set".into()))
}

impl Sweeper for CpuEngine {
    fn run_set(
        &mut self,
        rig: &Rig,
        images: SetImages<'_>,
        params: &SweepParams,
    ) -> Result<DepthMaps, SweepError> {
        CpuEngine::run_set(self, rig, images, params)
    }

    fn memo(&mut self) -> &mut FrameMemo {
        PlanRunner::memo(self)
    }

    fn timings_mut(&mut self) -> &mut StageTimings {
        PlanRunner::timings_mut(self)
    }
}

/// Whether the machine may have a GPU that wgpu can drive: a DRM render node or an NVIDIA
/// device node. Without one, `auto` does not start wgpu at all, so nothing of Vulkan's (the
/// lavapipe driver's "XDG_RUNTIME_DIR is invalid" line) reaches the log.
fn gpu_device_nodes() -> bool {
    let render = std::fs::read_dir("/dev/dri")
        .map(|dir| {
            dir.flatten()
                .any(|e| e.file_name().to_string_lossy().starts_with("renderD"))
        })
        .unwrap_or(false);
    render || std::path::Path::new("/dev/nvidiactl").exists() || cfg!(not(target_os = "linux"))
}

/// A hardware adapter, if wgpu offers one (not a CPU adapter such as lavapipe). A machine
/// with a GPU's device node but no hardware adapter (a headless server without the vendor's
/// Vulkan driver) runs the CPU engine and says so loudly: that is a slow engine by mistake.
pub fn hardware_gpu() -> Option<GpuContext> {
    let nodes = gpu_device_nodes();
    if !nodes && std::env::var_os("WGPU_ADAPTER_NAME").is_none() {
        return None;
    }
    let found = GpuContext::new().map(|gpu| {
        let info = gpu.adapter.get_info();
        (gpu, info.device_type == wgpu::DeviceType::Cpu, info.name)
    });
    let probe = match &found {
        Ok((_, cpu_adapter, name)) => Ok((*cpu_adapter, name.as_str())),
        Err(e) => Err(e.to_string()),
    };
    if let Some(warning) = auto_fallback_warning(nodes, probe) {
        tracing::warn!("{warning}");
    }
    match found {
        Ok((gpu, false, _)) => Some(gpu),
        _ => None,
    }
}

/// What `device: auto` says when it falls back to the CPU engine although the machine shows a
/// GPU (`nodes`: a DRM render node or NVIDIA's device node): `probe` is wgpu's adapter (whether
/// it is a CPU adapter, its name) or why there was none. `None`: nothing to say (a hardware
/// adapter, or no GPU to expect).
fn auto_fallback_warning(nodes: bool, probe: Result<(bool, &str), String>) -> Option<String> {
    if !nodes {
        return None;
    }
    let found = match probe {
        Ok((false, _)) => return None,
        Ok((true, name)) => format!("only the CPU adapter \"{name}\""),
        Err(reason) => format!("no adapter ({reason})"),
    };
    Some(format!(
        "device auto: this machine has a GPU device node (/dev/dri/renderD* or /dev/nvidiactl) \
         but wgpu found {found}: running the CPU engine. Install the GPU's Vulkan driver \
         (NVIDIA: the libnvidia-gl / nvidia-vulkan-icd package matching the kernel driver, \
         and libglvnd0, which its libGLX_nvidia.so.0 needs: without it the Vulkan loader \
         cannot get vkCreateInstance from it (VK_LOADER_DEBUG=driver shows it); AMD/Intel: \
         mesa-vulkan-drivers) or set device gpu to fail instead"
    ))
}

/// The engine a command runs: the WGSL engine with its device, or the CPU engine.
// One engine per process: the size of the CPU variant does not matter.
#[expect(
    clippy::large_enum_variant,
    reason = "one engine per process: the size of the CPU variant does not matter"
)]
pub enum Engine {
    Gpu {
        gpu: Box<GpuContext>,
        engine: Box<GpuEngine>,
    },
    Cpu(CpuEngine),
}

impl Engine {
    /// The engine for `device` (`auto`: a hardware GPU, else the CPU engine).
    pub fn new(device: Device) -> Result<Self, EngineError> {
        let gpu = match device {
            Device::Cpu => None,
            Device::Gpu => Some(GpuContext::new()?),
            Device::Auto => hardware_gpu(),
        };
        match gpu {
            Some(gpu) => Self::on_gpu(gpu),
            None => Ok(Self::Cpu(CpuEngine::new())),
        }
    }

    /// The WGSL engine on a device the caller made.
    pub fn on_gpu(gpu: GpuContext) -> Result<Self, EngineError> {
        let engine = GpuEngine::new(&gpu.device, &gpu.queue)?;
        Ok(Self::Gpu {
            gpu: Box::new(gpu),
            engine: Box::new(engine),
        })
    }

    /// "WGSL engine on \<adapter\>" or "CPU engine (N threads)".
    pub fn label(&self) -> String {
        match self {
            Self::Gpu { gpu, .. } => format!("WGSL engine on {}", gpu.adapter_label()),
            Self::Cpu(cpu) => cpu.label(),
        }
    }

    /// The wgpu device, for the WGSL engine.
    pub fn gpu(&self) -> Option<&GpuContext> {
        match self {
            Self::Gpu { gpu, .. } => Some(gpu),
            Self::Cpu(_) => None,
        }
    }

    /// Runs stop at their next pass boundary once `cancel` is set ([`SweepError::Cancelled`]).
    pub fn set_cancel(&mut self, cancel: CancelFlag) {
        match self {
            Self::Gpu { engine, .. } => engine.set_cancel(cancel),
            Self::Cpu(cpu) => cpu.set_cancel(cancel),
        }
    }

    /// The maps beyond depth and confidence the WGSL engine reads back and unpacks
    /// (`GpuEngine::set_wanted_maps`; all by default, one left out comes back empty). The CPU
    /// engine makes them all, but brings back only these from a rectified pair
    /// (`CpuEngine::set_wanted_maps`).
    pub fn set_wanted_maps(&mut self, wanted: crate::sweep::WantedMaps) {
        match self {
            Self::Gpu { engine, .. } => engine.set_wanted_maps(wanted),
            Self::Cpu(cpu) => cpu.set_wanted_maps(wanted),
        }
    }

    /// Whether the WGSL engine's host copies (images in, maps out) run on several threads
    /// (`GpuEngine::set_host_copies`; nothing for the CPU engine).
    pub fn set_host_copies(&mut self, copies: crate::sweep::gpu::HostCopies) {
        if let Self::Gpu { engine, .. } = self {
            engine.set_host_copies(copies);
        }
    }

    /// Whether the WGSL engine submits every reference of a set before it reads the first back
    /// (`GpuEngine::set_submit_ahead`; nothing for the CPU engine).
    pub fn set_submit_ahead(&mut self, ahead: bool) {
        if let Self::Gpu { engine, .. } = self {
            engine.set_submit_ahead(ahead);
        }
    }

    /// The WGSL engine's SGM path lines per workgroup in its subgroup layout
    /// (`GpuEngine::set_sgm_lines`; nothing for the CPU engine).
    pub fn set_sgm_lines(&mut self, lines: u32) {
        if let Self::Gpu { engine, .. } = self {
            engine.set_sgm_lines(lines);
        }
    }

    /// How the WGSL engine's SGM dispatches its directions (`GpuEngine::set_sgm_walks`;
    /// nothing for the CPU engine).
    pub fn set_sgm_walks(&mut self, walks: crate::sweep::gpu::SgmWalks) {
        if let Self::Gpu { engine, .. } = self {
            engine.set_sgm_walks(walks);
        }
    }

    /// The WGSL engine's bytes per batch of planes (`GpuEngine::set_slab_bytes`; nothing for
    /// the CPU engine).
    pub fn set_slab_bytes(&mut self, bytes: Option<u64>) {
        if let Self::Gpu { engine, .. } = self {
            engine.set_slab_bytes(bytes);
        }
    }

    /// Whether the WGSL engine makes the costs and their row sums in one stage
    /// (`GpuEngine::set_cost_rows`; nothing for the CPU engine).
    pub fn set_cost_rows(&mut self, rows: crate::sweep::gpu::CostRows) {
        if let Self::Gpu { engine, .. } = self {
            engine.set_cost_rows(rows);
        }
    }

    /// How the WGSL engine's SGM selection reads each pixel's words
    /// (`GpuEngine::set_select_reads`; nothing for the CPU engine).
    pub fn set_select_reads(&mut self, reads: crate::sweep::gpu::SelectReads) {
        if let Self::Gpu { engine, .. } = self {
            engine.set_select_reads(reads);
        }
    }

    /// The WGSL engine's submissions, readbacks, waits and host time since the last call
    /// (`None` for the CPU engine).
    pub fn take_gpu_counts(&mut self) -> Option<crate::sweep::gpu::SetCounts> {
        match self {
            Self::Gpu { engine, .. } => Some(engine.take_set_counts()),
            Self::Cpu(_) => None,
        }
    }

    /// Whether the oldest set started and not finished is done on the device
    /// (`GpuEngine::oldest_submitted_done`; always for the CPU engine, which runs a set when
    /// it starts it).
    pub fn oldest_done(&self) -> bool {
        match self {
            Self::Gpu { engine, .. } => engine.oldest_submitted_done(),
            Self::Cpu(_) => true,
        }
    }

    /// Per-stage times of the last frame set (GPU timestamps, or the CPU clock).
    pub fn last_timings(&self) -> &StageTimings {
        match self {
            Self::Gpu { engine, .. } => engine.last_timings(),
            Self::Cpu(cpu) => cpu.last_timings(),
        }
    }
}

impl Engine {
    /// The engine behind the wrapper, for the [`Sweeper`] calls it forwards.
    fn sweeper(&mut self) -> &mut dyn Sweeper {
        match self {
            Self::Gpu { engine, .. } => engine.as_mut(),
            Self::Cpu(cpu) => cpu,
        }
    }
}

impl Sweeper for Engine {
    fn run_set(
        &mut self,
        rig: &Rig,
        images: SetImages<'_>,
        params: &SweepParams,
    ) -> Result<DepthMaps, SweepError> {
        self.sweeper().run_set(rig, images, params)
    }

    fn unpacks_on_device(&self) -> bool {
        matches!(self, Self::Gpu { .. })
    }

    fn run_references_set(
        &mut self,
        cameras: &[RigCamera],
        images: SetImages<'_>,
        references: &[usize],
        params: &SweepParams,
    ) -> Vec<Result<ReferenceDepth, SweepError>> {
        self.sweeper()
            .run_references_set(cameras, images, references, params)
    }

    fn start_references_set(
        &mut self,
        cameras: &[RigCamera],
        images: SetImages<'_>,
        references: &[usize],
        params: &SweepParams,
    ) -> StartedSet {
        self.sweeper()
            .start_references_set(cameras, images, references, params)
    }

    fn finish_references_set(
        &mut self,
        started: StartedSet,
        images: SetImages<'_>,
        params: &SweepParams,
    ) -> Vec<Result<ReferenceDepth, SweepError>> {
        self.sweeper()
            .finish_references_set(started, images, params)
    }

    fn starts_without_waiting(&self) -> bool {
        match self {
            Self::Gpu { engine, .. } => Sweeper::starts_without_waiting(engine.as_ref()),
            Self::Cpu(_) => false,
        }
    }

    fn memo(&mut self) -> &mut FrameMemo {
        self.sweeper().memo()
    }

    fn timings_mut(&mut self) -> &mut StageTimings {
        self.sweeper().timings_mut()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn device_names() {
        assert_eq!("auto".parse::<Device>().ok(), Some(Device::Auto));
        assert_eq!("cpu".parse::<Device>().ok(), Some(Device::Cpu));
        assert_eq!("gpu".parse::<Device>().ok(), Some(Device::Gpu));
        assert!("tpu".parse::<Device>().is_err());
    }

    #[test]
    fn auto_says_loudly_when_a_gpu_machine_falls_back_to_the_cpu_engine() {
        // A hardware adapter, or no GPU to expect: nothing to say.
        assert_eq!(
            auto_fallback_warning(true, Ok((false, "NVIDIA H100"))),
            None
        );
        assert_eq!(auto_fallback_warning(false, Ok((true, "llvmpipe"))), None);
        assert_eq!(auto_fallback_warning(false, Err("none".into())), None);
        // A device node but only lavapipe, or no adapter at all: a warning naming what wgpu
        // found and what to install.
        let lavapipe = auto_fallback_warning(true, Ok((true, "llvmpipe (LLVM 15)"))).unwrap();
        assert!(lavapipe.contains("llvmpipe (LLVM 15)") && lavapipe.contains("Vulkan driver"));
        // What an H200 machine without libglvnd needed (2026-11-27).
        assert!(lavapipe.contains("libglvnd0"), "{lavapipe}");
        let none = auto_fallback_warning(true, Err("no Vulkan ICD".into())).unwrap();
        assert!(
            none.contains("no Vulkan ICD") && none.contains("CPU engine"),
            "{none}"
        );
    }

    #[test]
    fn cpu_engine_is_labelled() {
        let engine = Engine::new(Device::Cpu).expect("the CPU engine always exists");
        assert!(engine.label().starts_with("CPU engine"));
        assert!(engine.gpu().is_none());
    }
}
