//! Recording a frame set: the schedule's dispatches into one command encoder (each in its own
//! timestamped compute pass), and reading back the maps and the per-stage GPU times.

use std::sync::mpsc;
use std::time::Instant;

use super::super::schedule::{sgm_lines, Schedule, SGM_DIRECTIONS};
use super::super::stages::{Stage, STAGES};
use super::super::{CancelFlag, StageTimings, SweepError};
use super::buffers::{Alignments, Buffers};
use super::pipelines::Specialisation;
use super::{gpu_err, SetCounts};

/// Workgroups of 8x8 over a w x h grid.
fn tiles(w: u32, h: u32) -> (u32, u32, u32) {
    (w.div_ceil(8), h.div_ceil(8), 1)
}

/// How often a wait for the GPU looks at the cancel flag.
const CANCEL_POLL: std::time::Duration = std::time::Duration::from_millis(50);

/// Submits the work of one frame set step by step, so that a cancel is seen between steps: at
/// most two submissions are in flight.
pub(super) struct Submitter<'a> {
    pub device: &'a wgpu::Device,
    pub queue: &'a wgpu::Queue,
    pub cancel: &'a CancelFlag,
    previous: Option<wgpu::SubmissionIndex>,
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
            previous: None,
            counts,
        }
    }

    /// Waits for `index` (None: the latest submission), counted.
    fn wait(&mut self, index: Option<wgpu::SubmissionIndex>) -> Result<(), SweepError> {
        let started = Instant::now();
        let result = wait(self.device, self.cancel, index);
        self.counts.waits += 1;
        self.counts.wait_ms += started.elapsed().as_secs_f64() * 1e3;
        result
    }

    pub fn encoder(&self) -> wgpu::CommandEncoder {
        self.device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("sweep"),
            })
    }

    /// Submits `encoder`, then waits (cancellably) for the submission before it.
    pub fn submit(&mut self, encoder: wgpu::CommandEncoder) -> Result<(), SweepError> {
        self.cancel.check()?;
        let command_buffer = encoder.finish();
        let started = Instant::now();
        let index = self.queue.submit([command_buffer]);
        self.counts.submissions += 1;
        self.counts.submit_ms += started.elapsed().as_secs_f64() * 1e3;
        match self.previous.replace(index) {
            Some(before) => self.wait(Some(before)),
            None => Ok(()),
        }
    }
}

/// Waits for `index` (None: the latest submission), looking at the cancel flag every
/// [`CANCEL_POLL`].
pub(super) fn wait(
    device: &wgpu::Device,
    cancel: &CancelFlag,
    index: Option<wgpu::SubmissionIndex>,
) -> Result<(), SweepError> {
    loop {
        match device.poll(wgpu::PollType::Wait {
            submission_index: index.clone(),
            timeout: Some(CANCEL_POLL),
        }) {
            Ok(_) => return Ok(()),
            Err(wgpu::PollError::Timeout) => cancel.check()?,
            // A submission that failed (a lost device, a validation error) has no index to
            // wait for: nothing is running; the error scope or the read says why.
            Err(wgpu::PollError::WrongSubmissionIndex(..)) => return Ok(()),
        }
    }
}

/// Records every dispatch of `schedule`, then the copies of the maps (and timestamps) to their
/// readback buffers, submitting at the end of each batch of planes (so that a cancel stops the
/// run between batches) and once at the end.
pub(super) fn record(
    submitter: &mut Submitter<'_>,
    buffers: &Buffers,
    pipelines: &[wgpu::ComputePipeline],
    spec: &Specialisation,
    schedule: &Schedule,
    align: Alignments,
) -> Result<(), SweepError> {
    let key = buffers.key;
    let mut encoder = submitter.encoder();
    encoder.clear_buffer(&buffers.zbuffer, 0, None);
    for (index, dispatch) in schedule.dispatches().iter().enumerate() {
        let stage = dispatch.stage;
        // A new batch of planes begins: the previous one goes to the GPU.
        if stage == Stage::Cost && index > 0 {
            submitter.submit(std::mem::replace(&mut encoder, submitter.encoder()))?;
        }
        let band_rows = key.band(dispatch.band).rows;
        let (offset, groups) = match stage {
            Stage::Cost => (
                Some(u64::from(dispatch.batch) * align.batch),
                tiles(key.width, key.height),
            ),
            Stage::BoxH => (
                Some(u64::from(dispatch.batch) * align.batch),
                tiles(key.padded_width, key.height),
            ),
            Stage::BoxV => (
                Some(u64::from(dispatch.batch) * align.batch),
                tiles(key.padded_width, key.padded_height),
            ),
            Stage::Aggregate => {
                let width = if spec.paired() {
                    key.width.div_ceil(2)
                } else {
                    key.width
                };
                (
                    Some(u64::from(dispatch.batch) * align.batch),
                    tiles(width, band_rows),
                )
            }
            Stage::Sgm => {
                let (dx, dy) = SGM_DIRECTIONS[dispatch.direction as usize];
                let lines = sgm_lines(dx, dy, key.width, key.height);
                let workgroups = if spec.sgm_line_per_invocation {
                    lines.div_ceil(spec.sgm_lanes)
                } else {
                    lines
                };
                (
                    Some(u64::from(dispatch.direction) * align.pass),
                    (workgroups, 1, 1),
                )
            }
            Stage::SgmSelect => (None, tiles(key.width, band_rows)),
            Stage::Finalize | Stage::Median | Stage::Splat | Stage::Visibility => {
                (None, tiles(key.width, key.height))
            }
        };
        let index = index as u32;
        let timestamp_writes =
            buffers
                .timestamps
                .as_ref()
                .map(|t| wgpu::ComputePassTimestampWrites {
                    query_set: &t.query_set,
                    beginning_of_pass_write_index: Some(2 * index),
                    end_of_pass_write_index: Some(2 * index + 1),
                });
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(stage.name()),
            timestamp_writes,
        });
        pass.set_pipeline(&pipelines[stage as usize]);
        let group = buffers.bind_group(stage, dispatch.band);
        match offset {
            Some(o) => pass.set_bind_group(0, group, &[o as u32]),
            None => pass.set_bind_group(0, group, &[]),
        }
        pass.dispatch_workgroups(groups.0, groups.1, groups.2);
    }
    let maps_bytes = buffers.maps.size();
    encoder.copy_buffer_to_buffer(&buffers.maps, 0, &buffers.readback, 0, maps_bytes);
    if let Some(t) = &buffers.timestamps {
        encoder.resolve_query_set(&t.query_set, 0..t.count, &t.resolve, 0);
        encoder.copy_buffer_to_buffer(&t.resolve, 0, &t.readback, 0, t.resolve.size());
    }
    submitter.submit(encoder)
}

/// Maps `buffer`, waits for the GPU, and copies its bytes out.
pub(super) fn read_buffer(
    submitter: &mut Submitter<'_>,
    buffer: &wgpu::Buffer,
) -> Result<Vec<u8>, SweepError> {
    let (sender, receiver) = mpsc::channel();
    buffer.map_async(wgpu::MapMode::Read, .., move |r| {
        let _ = sender.send(r);
    });
    submitter.counts.readbacks += 1;
    submitter.counts.readback_bytes += buffer.size();
    submitter.wait(None)?;
    receiver.recv().map_err(gpu_err)?.map_err(gpu_err)?;
    let data = buffer.get_mapped_range(..).map_err(gpu_err)?.to_vec();
    buffer.unmap();
    Ok(data)
}

/// Per-stage GPU times (summed over a stage's dispatches) from the timestamps of the recorded
/// schedule; `None` without timestamp queries.
pub(super) fn stage_times(
    submitter: &mut Submitter<'_>,
    buffers: &Buffers,
    schedule: &Schedule,
) -> Result<Option<StageTimings>, SweepError> {
    let Some(t) = &buffers.timestamps else {
        return Ok(None);
    };
    let raw = read_buffer(submitter, &t.readback)?;
    // Copied, not cast: a Vec<u8> need not be 8-byte aligned.
    let ticks: Vec<u64> = bytemuck::pod_collect_to_vec(&raw);
    let period_ns = f64::from(submitter.queue.get_timestamp_period());
    let mut per_stage = [0.0f64; STAGES.len()];
    for (p, dispatch) in schedule.dispatches().iter().enumerate() {
        let (Some(&begin), Some(&end)) = (ticks.get(2 * p), ticks.get(2 * p + 1)) else {
            return Err(SweepError::Gpu(format!(
                "internal: {} timestamps for {} dispatches",
                ticks.len(),
                schedule.dispatches().len()
            )));
        };
        per_stage[dispatch.stage as usize] += end.saturating_sub(begin) as f64 * period_ns * 1e-6;
    }
    Ok(Some(StageTimings {
        gpu_timestamps: true,
        stages: STAGES
            .iter()
            .zip(per_stage)
            .map(|(s, ms)| (s.name.to_string(), ms))
            .collect(),
    }))
}
