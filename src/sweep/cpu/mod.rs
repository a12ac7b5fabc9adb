//! The CPU engine: the pipeline of `shaders/` in Rust, one module per shader written to read
//! like it (`cost.rs` twins `cost.wgsl`, ...), on the same packed [`SweepPlan`], multi-threaded
//! (rayon) and vectorised. The WGSL engine and this one agree stage by stage within the
//! tolerances of `tests/gpu_vs_cpu.rs`.
//!
//! Where the GPU runs one dispatch per stage over the whole image, the CPU fuses a plane's
//! cost, window sums and scoring row by row (`plane.rs`) so the working set stays in cache, and
//! runs the planes in parallel; the winner-take-all state and the SGM volume are then updated in
//! plane order, pixels in parallel.

pub mod aggregate;
pub mod boxes;
pub mod common;
pub mod cost;
pub mod finalize;
pub mod median;
pub mod occlusion;
pub mod plane;
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
    fn new(npix: usize) -> Self {
        Self {
            npix,
            data: vec![0.0; MAP_COUNT * npix],
        }
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

/// Bytes of per-plane scores a batch may hold (planes run in parallel within a batch).
const BATCH_BUDGET_BYTES: usize = 64 << 20;

/// The CPU plane-sweep engine. It keeps the plan of the last rig and parameters.
#[derive(Debug)]
pub struct CpuEngine {
    plan: Option<(Rig, SweepParams, SweepPlan)>,
    timings: StageTimings,
    fast_paths: bool,
    buffers: Buffers,
    cancel: CancelFlag,
}

/// The large buffers, kept across frame sets (no page faults for each new set).
#[derive(Debug, Default)]
struct Buffers {
    volume: Vec<u16>,
    forward: Vec<u16>,
    backward: Vec<u16>,
    scores: Vec<f32>,
    sels: Vec<u8>,
}

impl Default for CpuEngine {
    fn default() -> Self {
        Self::new()
    }
}

impl CpuEngine {
    pub fn new() -> Self {
        Self {
            plan: None,
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
        let reuse = matches!(&self.plan, Some((r, p, _)) if r == rig && p == params);
        if !reuse {
            let plan = SweepPlan::new(rig, params)?;
            self.plan = Some((rig.clone(), params.clone(), plan));
        }
        let Some(cached) = self.plan.take() else {
            return Err(SweepError::InvalidParams("internal: no plan".into()));
        };
        let result = self.run_plan(&cached.2, rig, images);
        self.plan = Some(cached);
        result
    }

    /// Runs a prepared plan (e.g. with a custom hypothesis family).
    pub fn run_plan(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: &[Rgba8Image],
    ) -> Result<DepthMaps, SweepError> {
        let trace = self.trace(plan, rig, images)?;
        Ok(plan.depth_maps(&trace.maps))
    }

    /// Runs a plan and returns the raw `maps` buffer (MAP_COUNT sections), for stage comparisons.
    pub fn run_plan_raw(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: &[Rgba8Image],
    ) -> Result<Vec<f32>, SweepError> {
        Ok(self.trace(plan, rig, images)?.maps)
    }

    /// Runs a plan, keeping the intermediate buffers.
    pub fn trace(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: &[Rgba8Image],
    ) -> Result<CpuTrace, SweepError> {
        check_images(rig, images)?;
        let mut clock = StageClock::new();
        let p = &plan.params;
        let npix = plan.pixel_count();
        let planes = plan.num_planes() as usize;
        let frame = FrameImages {
            planar: images
                .par_iter()
                .map(|im| {
                    PlanarImage::from_packed(im.width as usize, im.height as usize, &im.pixels)
                })
                .collect(),
        };
        let mappings: Vec<Vec<cost::Mapping>> = (0..planes)
            .map(|k| cost::mappings(plan, k, self.fast_paths))
            .collect();
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
        let mut state = WtaState::new(npix);
        let batch = (BATCH_BUDGET_BYTES / (npix * 5).max(1)).clamp(1, planes);
        let mut scores = std::mem::take(&mut self.buffers.scores);
        let mut sels = std::mem::take(&mut self.buffers.sels);
        scores.resize(batch * npix, 0.0);
        sels.resize(batch * npix, 0);
        let levels_per_unit = p.sgm_levels_per_unit;
        let cancel = self.cancel.clone();
        for first in (0..planes).step_by(batch) {
            let count = batch.min(planes - first);
            scores[..count * npix]
                .par_chunks_mut(npix)
                .zip(sels[..count * npix].par_chunks_mut(npix))
                .enumerate()
                .for_each_init(
                    || PlaneScratch::new(plan),
                    |scratch, (z, (score, sel))| {
                        if cancel.is_cancelled() {
                            return;
                        }
                        let k = first + z;
                        plane::sweep_plane(plan, &frame, &mappings[k], k, scratch, score, sel);
                    },
                );
            clock.lap("sweep");
            cancel.check()?;
            // The planes of the batch in order: winner-take-all, and the volume levels.
            let chunk = 2048;
            let (scores, sels) = (&scores, &sels);
            let batch = Batch {
                first,
                count,
                npix,
                stride,
                levels_per_unit,
            };
            let merge = |c: usize, st: &mut select::WtaChunk<'_>, vol: Option<&mut [u16]>| {
                merge_batch(&batch, c * chunk, scores, sels, st, vol)
            };
            let mut chunks = state.chunks_mut(chunk);
            if sgm {
                chunks
                    .par_iter_mut()
                    .zip(volume.par_chunks_mut(chunk * stride))
                    .enumerate()
                    .for_each(|(c, (st, vol))| merge(c, st, Some(vol)));
            } else {
                chunks
                    .par_iter_mut()
                    .enumerate()
                    .for_each(|(c, st)| merge(c, st, None));
            }
            clock.lap("select");
        }

        // The rest of the plan's schedule (the sweep above is its first phase).
        let mut maps = Maps::new(npix);
        let mut zbuffer = vec![0u32; plan.total_camera_pixels];
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
                Phase::Median => {
                    median::run(plan, &mut maps);
                    clock.lap("median");
                }
                Phase::Splat => {
                    occlusion::splat(plan, &maps, &mut zbuffer);
                    clock.lap("splat");
                }
                Phase::Visibility => {
                    occlusion::visibility(plan, &zbuffer, &mut maps);
                    clock.lap("visibility");
                }
            }
        }
        self.timings = clock.timings();
        self.buffers.volume = volume;
        self.buffers.scores = scores;
        self.buffers.sels = sels;
        Ok(CpuTrace {
            maps: maps.data,
            zbuffer,
        })
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

/// A batch of planes, merged into the selection state and the volume.
struct Batch {
    first: usize,
    count: usize,
    npix: usize,
    stride: usize,
    levels_per_unit: f32,
}

common::vectorised_fn! {
/// The batch's planes in order into the winner-take-all state of the pixels `start..` of `st`,
/// and their volume levels into `vol` (optimizer sgm).
fn merge_batch(
    b: &Batch,
    start: usize,
    scores: &[f32],
    sels: &[u8],
    st: &mut select::WtaChunk<'_>,
    vol: Option<&mut [u16]>,
) {
    let len = st.best.len();
    for z in 0..b.count {
        let at = z * b.npix + start;
        st.update((b.first + z) as f32, &scores[at..at + len], &sels[at..at + len]);
    }
    if let Some(vol) = vol {
        // Blocks of 16 pixels: their volume rows (16 x stride lanes) stay in L1 while every
        // plane of the batch fills its lane, and each plane's scores are read 16 at a time.
        const BLOCK: usize = 16;
        for block in (0..len).step_by(BLOCK) {
            let pixels = BLOCK.min(len - block);
            for z in 0..b.count {
                let at = z * b.npix + start + block;
                for (i, &score) in scores[at..at + pixels].iter().enumerate() {
                    vol[(block + i) * b.stride + b.first + z] =
                        sgm::volume_level(b.levels_per_unit, score);
                }
            }
        }
    }
}
}
