//! Recording a frame set: every level's plane ranges (from the level below, on the device),
//! images and schedule into one command buffer, one compute pass per phase of the schedule
//! (timestamped at its start and end), then the copies of the last level's maps and every
//! level's timestamps into one readback buffer; one submission, then one wait and one mapping
//! that bring both back.

use std::sync::mpsc;
use std::time::Instant;

use super::super::plan::SweepPlan;
use super::super::schedule::{
    sgm_lines, sgm_together_lines, Dispatch, Schedule, SGM_ALL_PASS, SGM_DIRECTIONS, SGM_REST_PASS,
};
use super::super::stages::{Stage, COST_ROW_LANES, SELECT_PIXELS};
use super::super::{CancelFlag, StageTimings, SweepError};
use super::buffers::{Alignments, Buffers};
use super::pipelines::{SgmLayout, Specialisation};
use super::{gpu_err, SetCounts};

/// Workgroups of 8x8 over a w x h grid.
fn tiles(w: u32, h: u32) -> (u32, u32, u32) {
    (w.div_ceil(8), h.div_ceil(8), 1)
}

/// [`tiles`], for the image stages (`pyramid.rs`).
pub(super) fn tiles_of(w: u32, h: u32) -> (u32, u32, u32) {
    tiles(w, h)
}

/// Records the census words of every camera's image (a census cost): one dispatch over the
/// widest and tallest image, the cameras in z (`shaders/census.wgsl`).
pub(super) fn record_census(
    encoder: &mut wgpu::CommandEncoder,
    buffers: &Buffers,
    census: &wgpu::ComputePipeline,
    plan: &SweepPlan,
) {
    let widest = plan.cameras.iter().map(|c| c.size[0]).max().unwrap_or(0);
    let tallest = plan.cameras.iter().map(|c| c.size[1]).max().unwrap_or(0);
    let (x, y, _) = tiles(widest, tallest);
    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: Some("census"),
        timestamp_writes: None,
    });
    pass.set_pipeline(census);
    pass.set_bind_group(0, buffers.bind_group(Stage::Census, 0), &[]);
    pass.dispatch_workgroups(x, y, plan.params.cameras);
}

/// One device poll or queue submission at a time in this process
/// ([`crate::gpu_context::device_poll_lock`], which the fusion's GPU integration takes too).
pub(super) use crate::gpu_context::device_poll_lock;

/// Submits a level's command buffer and brings its results back, counting both (a cancel is
/// seen before the submission and while the host waits).
pub(super) struct Submitter<'a> {
    pub device: &'a wgpu::Device,
    pub queue: &'a wgpu::Queue,
    pub cancel: &'a CancelFlag,
    /// Submissions, readbacks and waits, added to the frame set's.
    pub counts: &'a mut SetCounts,
}

impl<'a> Submitter<'a> {
    pub fn new(
        device: &'a wgpu::Device,
        queue: &'a wgpu::Queue,
        cancel: &'a CancelFlag,
        counts: &'a mut SetCounts,
    ) -> Self {
        Self {
            device,
            queue,
            cancel,
            counts,
        }
    }

    /// Submits `commands` (without waiting).
    pub fn submit(
        &mut self,
        commands: wgpu::CommandBuffer,
    ) -> Result<wgpu::SubmissionIndex, SweepError> {
        self.cancel.check()?;
        let started = Instant::now();
        let index = {
            let _poll = device_poll_lock();
            self.queue.submit([commands])
        };
        self.counts.submissions += 1;
        self.counts.submit_ms += started.elapsed().as_secs_f64() * 1e3;
        Ok(index)
    }

    /// Maps the first `bytes` of every buffer of `buffers`, waits once for the GPU, and copies
    /// them out (once: as 32-bit words, which the maps are).
    pub fn read_back(
        &mut self,
        buffers: &[(&wgpu::Buffer, u64)],
    ) -> Result<Vec<Vec<u32>>, SweepError> {
        let mut out = Vec::with_capacity(buffers.len());
        self.read_back_with(buffers, |_, bytes| {
            out.push(bytemuck::pod_collect_to_vec(bytes));
            Ok(())
        })?;
        Ok(out)
    }

    /// Maps the first `bytes` of every buffer of `buffers`, waits once for the GPU, and hands
    /// each mapped range to `read` (with its index) before unmapping it: a caller that unpacks
    /// the bytes copies them once.
    pub fn read_back_with(
        &mut self,
        buffers: &[(&wgpu::Buffer, u64)],
        read: impl FnMut(usize, &[u8]) -> Result<(), SweepError>,
    ) -> Result<(), SweepError> {
        self.read_back_after(None, buffers, read)
    }

    /// [`Self::read_back_with`] after the submission `after` alone (None: the last one): the
    /// submissions after it go on running while the host reads.
    pub fn read_back_after(
        &mut self,
        after: Option<wgpu::SubmissionIndex>,
        buffers: &[(&wgpu::Buffer, u64)],
        mut read: impl FnMut(usize, &[u8]) -> Result<(), SweepError>,
    ) -> Result<(), SweepError> {
        let receivers: Vec<_> = buffers
            .iter()
            .map(|&(buffer, bytes)| self.map_counted(buffer, bytes))
            .collect();
        self.wait_after(after)?;
        for (i, (&(buffer, bytes), receiver)) in buffers.iter().zip(receivers).enumerate() {
            receiver.recv().map_err(gpu_err)?.map_err(gpu_err)?;
            let result = read(i, &buffer.get_mapped_range(..bytes).map_err(gpu_err)?[..]);
            buffer.unmap();
            result?;
        }
        Ok(())
    }

    /// Maps `bytes` of `buffer` once the submission `after` alone has run and hands out the
    /// mapped view (the buffer stays mapped: its holder unmaps it when done with it).
    pub fn map_after(
        &mut self,
        after: Option<wgpu::SubmissionIndex>,
        buffer: &wgpu::Buffer,
        bytes: u64,
    ) -> Result<wgpu::BufferView, SweepError> {
        let receiver = self.map_counted(buffer, bytes);
        self.wait_after(after)?;
        receiver.recv().map_err(gpu_err)?.map_err(gpu_err)?;
        buffer.get_mapped_range(..bytes).map_err(gpu_err)
    }

    /// Asks for `bytes` of `buffer` mapped for reading (counted as a readback); the receiver
    /// says when.
    fn map_counted(
        &mut self,
        buffer: &wgpu::Buffer,
        bytes: u64,
    ) -> mpsc::Receiver<Result<(), wgpu::BufferAsyncError>> {
        let (sender, receiver) = mpsc::channel();
        buffer.map_async(wgpu::MapMode::Read, ..bytes, move |r| {
            let _ = sender.send(r);
        });
        self.counts.readbacks += 1;
        self.counts.readback_bytes += bytes;
        receiver
    }

    /// Waits (counted) for the submission `after` alone, or the last one.
    fn wait_after(&mut self, after: Option<wgpu::SubmissionIndex>) -> Result<(), SweepError> {
        let started = Instant::now();
        let waited =
            crate::gpu_context::wait_for_submission(self.device, after, || self.cancel.check());
        self.counts.waits += 1;
        self.counts.wait_ms += started.elapsed().as_secs_f64() * 1e3;
        waited
    }
}

/// How the WGSL engine's SGM dispatches its path directions (the sums are the same, bit for
/// bit: integer adds in any order). A line's walk is one pixel after the other, so dispatches
/// one after the other leave a GPU mostly idle (the H200: the coarse levels' SGM, a quarter of
/// the pixels, took half the fine level's time).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, clap::ValueEnum)]
pub enum SgmWalks {
    /// The adapter's: `together` on GPUs, `one-by-one` on CPU adapters (no idle lanes to fill;
    /// on lavapipe side by side was about 1.6x slower on the demo).
    #[default]
    Auto,
    /// Every direction in one dispatch, adding into the sums cleared before it.
    Together,
    /// Direction 0 in a dispatch of its own (writing the sums), then the others in one.
    FirstApart,
    /// One dispatch per direction.
    OneByOne,
}

impl SgmWalks {
    /// What runs for `spec` over `buffers` on an adapter that is a GPU or not: the directions
    /// side by side only in the subgroup layout over one band with more than one direction
    /// (the other layouts and banded runs keep one dispatch per direction: line per invocation
    /// adds without atomics; bands pass each line's state from band to band in order).
    pub(super) fn resolve(self, spec: &Specialisation, buffers: &Buffers, gpu: bool) -> Self {
        let walks = match self {
            Self::Auto if gpu => Self::Together,
            Self::Auto => Self::OneByOne,
            other => other,
        };
        let side_by_side = spec.sgm_layout == SgmLayout::Subgroup
            && buffers.key.bands() == 1
            && buffers.key.sgm_paths > 1;
        if side_by_side {
            walks
        } else {
            Self::OneByOne
        }
    }

    /// The `sgm_passes` element of the dispatch that walks several directions, and the first
    /// direction it walks (the schedule's dispatch of that direction stands for them all).
    fn together_pass(self) -> Option<(usize, u32)> {
        match self {
            Self::Together => Some((SGM_ALL_PASS, 0)),
            Self::FirstApart => Some((SGM_REST_PASS, 1)),
            Self::Auto | Self::OneByOne => None,
        }
    }
}

/// The workgroups of one dispatch and the dynamic offset of its uniform element.
fn workgroups(
    dispatch: &Dispatch,
    buffers: &Buffers,
    spec: &Specialisation,
    align: Alignments,
    walks: SgmWalks,
) -> (Option<u64>, (u32, u32, u32)) {
    let key = buffers.key;
    let band_rows = key.band(dispatch.band).rows;
    let batch = Some(u64::from(dispatch.batch) * align.batch);
    if let (Stage::Sgm, Some((slot, first))) = (dispatch.stage, walks.together_pass()) {
        if dispatch.direction == first {
            let lines = sgm_together_lines(first, key.sgm_paths, key.width, key.height);
            let groups = (lines.div_ceil(spec.sgm_lines), 1, 1);
            return (Some(slot as u64 * align.pass), groups);
        }
    }
    match dispatch.stage {
        Stage::Cost => (batch, tiles(key.width, key.height)),
        Stage::CostRows => {
            // Each group sums the windows of COST_ROW_LANES - (window_w - 1) padded columns.
            let anchors = COST_ROW_LANES - (key.padded_width - key.width);
            (batch, (key.padded_width.div_ceil(anchors), key.height, 1))
        }
        Stage::BoxH => (batch, tiles(key.padded_width, key.height)),
        Stage::Aggregate => {
            let width = if spec.paired() {
                key.width.div_ceil(2)
            } else {
                key.width
            };
            (batch, tiles(width, band_rows))
        }
        Stage::Sgm => {
            let (dx, dy) = SGM_DIRECTIONS[dispatch.direction as usize];
            let lines = sgm_lines(dx, dy, key.width, key.height);
            let workgroups = if spec.sgm_line_per_invocation() {
                lines.div_ceil(spec.sgm_lanes)
            } else {
                lines.div_ceil(spec.sgm_lines)
            };
            (
                Some(u64::from(dispatch.direction) * align.pass),
                (workgroups, 1, 1),
            )
        }
        Stage::SgmSelect => (None, (key.width.div_ceil(SELECT_PIXELS), band_rows, 1)),
        Stage::Finalize
        | Stage::Median
        | Stage::Splat
        | Stage::Visibility
        | Stage::RefineBase
        | Stage::RefineSelect => (None, tiles(key.width, key.height)),
        // Recorded before the schedule (`record_census`, `pyramid.rs`), not dispatched by it.
        Stage::Census
        | Stage::Half
        | Stage::Prefilter
        | Stage::Unpack
        | Stage::PlaneSpans
        | Stage::PlaneRanges => (None, (0, 0, 0)),
    }
}

/// Records a level's plane ranges on the device (coarse to fine): the raw depths of the level
/// below (`depth_raw`: their bytes in its `maps` buffer, half the width and height of this
/// level) copied into `coarse_depth`, then each half-resolution row's span of planes
/// under each tile (`plane_spans.wgsl`) and each (row, tile)'s range and window hull
/// (`plane_ranges.wgsl`) into the `plane_ranges` buffer the sweep reads.
pub(super) fn record_plane_ranges(
    encoder: &mut wgpu::CommandEncoder,
    buffers: &Buffers,
    pipelines: &[wgpu::ComputePipeline],
    below_maps: &wgpu::Buffer,
    depth_raw: std::ops::Range<u64>,
) -> Result<(), SweepError> {
    let key = buffers.key;
    let bytes = depth_raw.end - depth_raw.start;
    if bytes != u64::from(key.width / 2) * u64::from(key.height / 2) * 4 {
        return Err(SweepError::Gpu(format!(
            "internal: the level below has {bytes} bytes of depth for a {}x{} level",
            key.width, key.height
        )));
    }
    encoder.copy_buffer_to_buffer(below_maps, depth_raw.start, &buffers.coarse_depth, 0, bytes);
    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: Some("plane ranges"),
        timestamp_writes: None,
    });
    pass.set_pipeline(&pipelines[Stage::PlaneSpans as usize]);
    pass.set_bind_group(0, buffers.bind_group(Stage::PlaneSpans, 0), &[]);
    let tiles = crate::sweep::plan::range_tiles(key.width);
    pass.dispatch_workgroups(key.height / 2, 1, 1);
    pass.set_pipeline(&pipelines[Stage::PlaneRanges as usize]);
    pass.set_bind_group(0, buffers.bind_group(Stage::PlaneRanges, 0), &[]);
    pass.dispatch_workgroups(tiles.div_ceil(8), key.height.div_ceil(8), 1);
    Ok(())
}

/// Records every dispatch of `schedule` (after the level's images and plane ranges), one
/// compute pass per phase (every batch of planes in the sweep's pass, every direction and band
/// in SGM's; wgpu orders the dispatches of a pass), each timestamped at its start and end,
/// and resolves the level's timestamps into its `resolve` buffer. Returns SGM's dispatches and
/// the sweep's (cost, row sums, aggregate: every batch's, the fine sweep's included).
pub(super) fn record_sweep(
    encoder: &mut wgpu::CommandEncoder,
    buffers: &Buffers,
    pipelines: &[wgpu::ComputePipeline],
    spec: &Specialisation,
    schedule: &Schedule,
    align: Alignments,
    walks: SgmWalks,
) -> (u32, u32) {
    let together = walks.together_pass();
    let (mut sgm_dispatches, mut sweep_dispatches) = (0, 0);
    encoder.clear_buffer(&buffers.zbuffer, 0, None);
    if let (SgmWalks::Together, Some(sums)) = (walks, buffers.sgm_sums.first()) {
        // Every direction adds into the sums (none writes them first).
        encoder.clear_buffer(sums, 0, None);
    }
    for (p, (phase, dispatches)) in schedule.phase_dispatches().enumerate() {
        let p = p as u32;
        let timestamp_writes =
            buffers
                .timestamps
                .as_ref()
                .map(|t| wgpu::ComputePassTimestampWrites {
                    query_set: &t.query_set,
                    beginning_of_pass_write_index: Some(2 * p),
                    end_of_pass_write_index: Some(2 * p + 1),
                });
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(phase.name()),
            timestamp_writes,
        });
        for dispatch in dispatches {
            // The dispatch of the first direction walked together stands for them all.
            if let (Stage::Sgm, Some((_, first))) = (dispatch.stage, together) {
                if dispatch.direction > first {
                    continue;
                }
            }
            let (offset, groups) = workgroups(dispatch, buffers, spec, align, walks);
            pass.set_pipeline(&pipelines[dispatch.stage as usize]);
            let group = buffers.bind_group(dispatch.stage, dispatch.band);
            match offset {
                Some(o) => pass.set_bind_group(0, group, &[o as u32]),
                None => pass.set_bind_group(0, group, &[]),
            }
            pass.dispatch_workgroups(groups.0, groups.1, groups.2);
            sgm_dispatches += u32::from(dispatch.stage == Stage::Sgm);
            sweep_dispatches += u32::from(matches!(
                dispatch.stage,
                Stage::Cost | Stage::CostRows | Stage::BoxH | Stage::Aggregate
            ));
        }
    }
    if let Some(t) = &buffers.timestamps {
        encoder.resolve_query_set(&t.query_set, 0..t.count, &t.resolve, 0);
    }
    (sgm_dispatches, sweep_dispatches)
}

/// A frame set's timings from its levels' timestamps, read back one level after the other
/// (`levels`: each level's schedule and its count of timestamps, two words each): the last
/// level's phases, the levels below it as one stage `coarse` and stage by stage as
/// `coarse/<stage>` (bench's JSON).
pub(super) fn set_timings(
    queue: &wgpu::Queue,
    levels: &[(&Schedule, u32)],
    ticks: &[u32],
) -> Result<StageTimings, SweepError> {
    let mut at = 0;
    let mut coarse_ms = 0.0;
    let mut coarse_stages: Vec<(String, f64)> = Vec::new();
    let mut last = StageTimings::default();
    for (i, (schedule, count)) in levels.iter().enumerate() {
        let words = 2 * *count as usize;
        let own = ticks
            .get(at..at + words)
            .ok_or_else(|| SweepError::Gpu("internal: timestamps missing".into()))?;
        at += words;
        let times = phase_times(queue, schedule, own)?;
        if i + 1 == levels.len() {
            last = times;
        } else {
            coarse_ms += times.stages.iter().map(|(_, ms)| ms).sum::<f64>();
            for (name, ms) in times.stages {
                let name = format!("coarse/{name}");
                crate::sweep::add_stage_ms(&mut coarse_stages, &name, ms);
            }
        }
    }
    if levels.len() > 1 {
        last.stages.insert(0, ("coarse".to_string(), coarse_ms));
        last.stages.extend(coarse_stages);
    }
    Ok(last)
}

/// Per-phase GPU times from the timestamps read back (`raw`), in the names the CPU engine's
/// clock uses.
pub(super) fn phase_times(
    queue: &wgpu::Queue,
    schedule: &Schedule,
    raw: &[u32],
) -> Result<StageTimings, SweepError> {
    // Copied, not cast: a Vec<u32> need not be 8-byte aligned.
    let ticks: Vec<u64> = bytemuck::pod_collect_to_vec(raw);
    let period_ns = f64::from(queue.get_timestamp_period());
    let stages = schedule
        .phases()
        .iter()
        .enumerate()
        .map(
            |(p, phase)| match (ticks.get(2 * p), ticks.get(2 * p + 1)) {
                (Some(&begin), Some(&end)) => Ok((
                    phase.name().to_string(),
                    end.saturating_sub(begin) as f64 * period_ns * 1e-6,
                )),
                _ => Err(SweepError::Gpu(format!(
                    "internal: {} timestamps for {} phases",
                    ticks.len(),
                    schedule.phases().len()
                ))),
            },
        )
        .collect::<Result<_, _>>()?;
    Ok(StageTimings {
        gpu_timestamps: true,
        stages,
    })
}

/// Copies the first `bytes` of `buffer` to a fresh readback buffer and reads it back.
pub(super) fn read_buffer(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    cancel: &CancelFlag,
    buffer: &wgpu::Buffer,
    bytes: u64,
) -> Result<Vec<u32>, SweepError> {
    let staging = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("debug readback"),
        size: bytes.max(4),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder =
        device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
    encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, bytes);
    let mut counts = SetCounts::default();
    let mut submitter = Submitter::new(device, queue, cancel, &mut counts);
    submitter.submit(encoder.finish())?;
    let mut words = submitter.read_back(&[(&staging, bytes)])?;
    words
        .pop()
        .ok_or_else(|| SweepError::Gpu("internal: nothing read back".into()))
}
