//! A frame set's submission and its readback, apart (issue 56): every frame set ends with one
//! submission and one readback ([`GpuEngine::finish_set`]); the references of a set of several
//! go one step further and are all submitted before the first is read back
//! ([`GpuEngine::submit_set`], [`GpuEngine::collect_set`]): the host records the next reference
//! while the GPU runs the one before, and reads a reference's maps while the GPU runs the next,
//! instead of each reference waiting for the one before to come back. Each reference submitted
//! so copies its maps into a readback buffer of its own (kept for the next set), and writes its
//! uploads into a staging buffer of its own (`upload.rs`).

use std::collections::VecDeque;
use std::ops::Range;
use std::time::Instant;

use super::super::coarse::{LevelDepth, LevelImages};
use super::super::gpu_types::{MAP_CONFIDENCE, MAP_COST, MAP_COUNT, MAP_DEPTH};
use super::super::joint_median::JointMedian;
use super::super::plan::{unpack_sections, SweepPlan};
use super::super::references::ReferenceMaps;
use super::super::{StageTimings, SweepError, SweepParams, WantedMaps};
use super::lent::{LentMaps, ReturnedBuffers};
use super::{buffers, record, GpuEngine, HostCopies, OpenSet, Recorded};
use crate::geometry::Rig;
use crate::image::SetImages;

/// A frame set submitted: what its readback needs.
pub(super) struct Submitted {
    index: wgpu::SubmissionIndex,
    /// The last level's maps, then every level's timestamps.
    readback: wgpu::Buffer,
    /// `readback` is one of [`Deferred`]'s (given back once read), not the shape's own.
    pooled: bool,
    /// Bytes of maps, where the timestamps start, and the bytes to map.
    maps_len: u64,
    ticks_at: u64,
    mapped: u64,
    levels: Vec<Recorded>,
    started: Instant,
}

/// A submitted set's readback buffer, mapped once its submission has run.
struct MappedSet {
    view: wgpu::BufferView,
    readback: wgpu::Buffer,
    pooled: bool,
    /// Bytes of maps at the view's start.
    maps_len: usize,
    /// Every level's timestamps.
    ticks: Option<Vec<u32>>,
    levels: Vec<Recorded>,
    started: Instant,
}

/// A frame set submitted by [`GpuEngine::submit_set`], waiting for [`GpuEngine::collect_set`].
struct Pending {
    submitted: Submitted,
    /// The maps' width and height, their sections read back, and how to unpack them.
    size: (u32, u32),
    sections: Range<usize>,
    wanted: WantedMaps,
    copies: HostCopies,
}

/// Frame sets submitted and not read back yet.
pub(super) struct Deferred {
    /// A set's references are submitted ahead (`GpuEngine::set_submit_ahead`).
    allowed: bool,
    /// `run_plan_last` submits the last level without reading it back.
    on: bool,
    sets: VecDeque<Pending>,
    /// Readback buffers free for the next submitted sets.
    readbacks: Vec<wgpu::Buffer>,
    /// Submissions whose maps are not read back yet.
    in_flight: u32,
    /// Readback buffers of maps lent out ([`LentMaps`]) given back when they were dropped.
    returned: ReturnedBuffers,
}

/// Readback buffers kept at most for sets submitted ahead.
const MAX_READBACKS: usize = 8;

impl Default for Deferred {
    fn default() -> Self {
        Self {
            allowed: true,
            on: false,
            sets: VecDeque::new(),
            readbacks: Vec::new(),
            in_flight: 0,
            returned: ReturnedBuffers::default(),
        }
    }
}

impl Deferred {
    /// A free readback buffer of `bytes` (the smallest that holds them), or a new one
    /// (counted in `made`).
    fn take_readback(&mut self, device: &wgpu::Device, bytes: u64, made: &mut u32) -> wgpu::Buffer {
        let returned = std::mem::take(&mut *self.returned.lock());
        for buffer in returned {
            self.give_back(buffer);
        }
        let fitting = self.readbacks.iter().enumerate();
        let fitting = fitting.filter(|(_, b)| b.size() >= bytes);
        match fitting.min_by_key(|(_, b)| b.size()).map(|(i, _)| i) {
            Some(i) => self.readbacks.swap_remove(i),
            None => {
                *made += 1;
                device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("readback, submitted ahead"),
                    size: bytes,
                    usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                })
            }
        }
    }

    fn give_back(&mut self, buffer: wgpu::Buffer) {
        if self.readbacks.len() >= MAX_READBACKS {
            self.readbacks.remove(0);
        }
        self.readbacks.push(buffer);
    }
}

impl GpuEngine {
    /// Whether the references of a set are all submitted before the first is read back (the
    /// default), or each read back before the next is recorded (to compare the two).
    pub fn set_submit_ahead(&mut self, ahead: bool) {
        self.deferred.allowed = ahead;
    }

    /// See [`Self::set_submit_ahead`].
    pub fn submits_ahead(&self) -> bool {
        self.deferred.allowed
    }

    /// Submits the frame set recorded so far (one submission, without waiting): the
    /// `sections` of the last level's maps and every level's timestamps copied into one
    /// readback buffer (the shape's own, or with `pooled` one of its own).
    pub(super) fn submit_open_set(
        &mut self,
        sections: Range<usize>,
        pooled: bool,
    ) -> Result<Submitted, SweepError> {
        let Some(OpenSet {
            mut encoder,
            levels,
            started,
        }) = self.open.take()
        else {
            return Err(SweepError::Gpu("internal: no level recorded".into()));
        };
        // Every upload of the set is written: its staging buffer is unmapped for its copies,
        // and mapped again for a later set right after the submission.
        self.uploads.submitting();
        let Some((buffers, _)) = self.buffers.as_ref() else {
            return Err(SweepError::Gpu("internal: no buffers".into()));
        };
        let readback = match pooled {
            true => self.deferred.take_readback(
                &self.device,
                buffers.readback.size(),
                &mut self.counts.readback_buffers,
            ),
            false => buffers.readback.clone(),
        };
        // Only the sections the caller unpacks (`SweepPlan::unpacked_sections`).
        let section_bytes = buffers.maps.size() / MAP_COUNT as u64;
        let first = section_bytes * sections.start.min(MAP_COUNT) as u64;
        let maps_len = section_bytes * sections.end.min(MAP_COUNT) as u64 - first;
        encoder.copy_buffer_to_buffer(&buffers.maps, first, &readback, 0, maps_len);
        let ticks_at = buffers::timestamps_offset(maps_len);
        let mut mapped = ticks_at;
        for (resolve, count) in levels.iter().filter_map(|l| l.timestamps.as_ref()) {
            let bytes = u64::from(*count) * 8;
            if mapped + bytes > readback.size() {
                return Err(SweepError::Gpu(format!(
                    "internal: no room for the timestamps of {} levels",
                    levels.len()
                )));
            }
            encoder.copy_buffer_to_buffer(resolve, 0, &readback, mapped, bytes);
            mapped += bytes;
        }
        if mapped == ticks_at {
            mapped = maps_len;
        }
        let mut submitter =
            record::Submitter::new(&self.device, &self.queue, &self.cancel, &mut self.counts);
        let index = submitter.submit(encoder.finish());
        self.uploads.submitted();
        let index = index?;
        self.set_images.submitted();
        self.deferred.in_flight += 1;
        let most = &mut self.counts.most_in_flight;
        *most = (*most).max(self.deferred.in_flight);
        Ok(Submitted {
            index,
            readback,
            pooled,
            maps_len,
            ticks_at,
            mapped,
            levels,
            started,
        })
    }

    /// Waits for the set `submitted` alone (later submissions go on running) and maps its
    /// readback buffer: the view, and every level's timestamps read out of it.
    fn map_submitted(&mut self, submitted: Submitted) -> Result<MappedSet, SweepError> {
        let Submitted {
            index,
            readback,
            pooled,
            maps_len,
            ticks_at,
            mapped,
            levels,
            started,
        } = submitted;
        let mut submitter =
            record::Submitter::new(&self.device, &self.queue, &self.cancel, &mut self.counts);
        let view = submitter.map_after(Some(index), &readback, mapped);
        self.deferred.in_flight = self.deferred.in_flight.saturating_sub(1);
        let view = view?;
        let ticks = (mapped > maps_len)
            .then(|| bytemuck::pod_collect_to_vec(&view[ticks_at as usize..mapped as usize]));
        Ok(MappedSet {
            view,
            readback,
            pooled,
            maps_len: maps_len as usize,
            ticks,
            levels,
            started,
        })
    }

    /// Waits for the set `submitted` alone (later submissions go on running) and reads it
    /// back once: its maps `unpack`ed straight out of the mapped range, and every level's
    /// timestamps (the levels below the last as one `coarse` stage) as the engine's timings.
    pub(super) fn read_submitted<T>(
        &mut self,
        submitted: Submitted,
        unpack: impl FnOnce(&[f32]) -> T,
    ) -> Result<T, SweepError> {
        let set = self.map_submitted(submitted)?;
        let map_bytes = &set.view[..set.maps_len];
        let maps = match bytemuck::try_cast_slice::<u8, f32>(map_bytes) {
            Ok(floats) => unpack(floats),
            Err(_) => unpack(&bytemuck::pod_collect_to_vec::<u8, f32>(map_bytes)),
        };
        self.release(set)?;
        Ok(maps)
    }

    /// A set's readback done with: its buffer unmapped (a pooled one back in the pool), its
    /// timings the engine's.
    fn release(&mut self, set: MappedSet) -> Result<(), SweepError> {
        let MappedSet {
            view,
            readback,
            pooled,
            ticks,
            levels,
            started,
            ..
        } = set;
        drop(view);
        readback.unmap();
        if pooled {
            self.deferred.give_back(readback);
        }
        self.set_timings(&levels, ticks, started)
    }

    /// The engine's timings of a set read back: every level's timestamps (`ticks`; the levels
    /// below the last as one `coarse` stage), or the set's wall time where there are none.
    fn set_timings(
        &mut self,
        levels: &[Recorded],
        ticks: Option<Vec<u32>>,
        started: Instant,
    ) -> Result<(), SweepError> {
        self.timings = match ticks {
            Some(ticks) => {
                let levels: Vec<_> = levels
                    .iter()
                    .map(|l| (&l.schedule, l.timestamps.as_ref().map_or(0, |t| t.1)))
                    .collect();
                record::set_timings(&self.queue, &levels, &ticks)?
            }
            None => StageTimings {
                stages: vec![("total".to_string(), started.elapsed().as_secs_f64() * 1e3)],
                gpu_timestamps: false,
            },
        };
        Ok(())
    }

    /// Waits for the set `submitted` alone and lends its depth and confidence out of its
    /// readback buffer, mapped ([`LentMaps`]; the buffer comes back to the pool when they are
    /// dropped). Maps the view cannot lend (not aligned as floats) are copied as `wanted`.
    fn lend_submitted(
        &mut self,
        submitted: Submitted,
        size: (u32, u32),
        wanted: WantedMaps,
    ) -> Result<ReferenceMaps, SweepError> {
        let set = self.map_submitted(submitted)?;
        let readback = set.readback.clone();
        match LentMaps::new(set.view, readback, &self.deferred.returned, size) {
            Ok(lent) => {
                self.set_timings(&set.levels, set.ticks, set.started)?;
                Ok(ReferenceMaps::Lent(lent))
            }
            Err(view) => {
                let floats: Vec<f32> = bytemuck::pod_collect_to_vec(&view[..set.maps_len]);
                self.release(MappedSet { view, ..set })?;
                let maps = unpack_sections(size, &floats, MAP_DEPTH, wanted, false);
                Ok(ReferenceMaps::Owned(maps))
            }
        }
    }

    /// The last level of a set submitted by [`Self::submit_set`]: submitted, its maps read
    /// back by [`Self::collect_set`].
    pub(super) fn submit_maps(&mut self, plan: &SweepPlan) -> Result<LevelDepth, SweepError> {
        let (wanted, copies) = (self.wanted, self.host_copies);
        let sections = SweepPlan::unpacked_sections(wanted);
        let submitted = self.submit_open_set(sections.clone(), true)?;
        self.deferred.sets.push_back(Pending {
            submitted,
            size: (plan.width, plan.height),
            sections,
            wanted,
            copies,
        });
        Ok(LevelDepth::Submitted)
    }

    /// [`Self::run_set`] up to the submission of the set's last level: its maps come with
    /// [`Self::collect_set`] (with the same rig, images and parameters), in the order of the
    /// submissions. Several sets may be submitted before the first is collected.
    pub fn submit_set(
        &mut self,
        rig: &Rig,
        images: SetImages<'_>,
        params: &SweepParams,
    ) -> Result<(), SweepError> {
        self.deferred.on = true;
        let started = self.sweep_set(rig, params, |engine, plans| {
            super::super::coarse::start(engine, plans, rig, images, params)
        });
        self.deferred.on = false;
        match started? {
            LevelDepth::Submitted => Ok(()),
            _ => Err(SweepError::Gpu(
                "internal: a set to submit ahead came back at once".into(),
            )),
        }
    }

    /// The maps of the oldest set [`Self::submit_set`] submitted, read back after its own
    /// submission alone has run (the host's post-step made as `run` does). Lent out of the
    /// readback buffer ([`ReferenceMaps::Lent`]) where the set was submitted for a caller
    /// that keeps no floats and reads depth and confidence alone ([`WantedMaps::floats`]) and
    /// the host has nothing to do to them (no joint median).
    pub fn collect_set(
        &mut self,
        rig: &Rig,
        images: SetImages<'_>,
        params: &SweepParams,
    ) -> Result<ReferenceMaps, SweepError> {
        self.measured(|engine| {
            let Some(pending) = engine.deferred.sets.pop_front() else {
                return Err(SweepError::Gpu("internal: no set submitted ahead".into()));
            };
            let Pending {
                submitted,
                size,
                sections,
                wanted,
                copies,
            } = pending;
            let lend = !wanted.floats
                && sections == (MAP_DEPTH..MAP_COST)
                && MAP_CONFIDENCE == MAP_DEPTH + 1
                && submitted.pooled
                && JointMedian::of_params(params).radius == 0;
            if lend {
                return engine.lend_submitted(submitted, size, wanted);
            }
            let maps = engine.read_submitted(submitted, |m| {
                let split = copies.split(m.len() * 4);
                unpack_sections(size, m, sections.start, wanted, split)
            })?;
            super::super::coarse::finish(engine, maps, rig, images, params)
                .map(ReferenceMaps::Owned)
        })
    }

    /// Whether the oldest set submitted ahead has finished on the device (or none is
    /// waiting), so that [`Self::collect_set`] would not wait for it: a poll that does not
    /// block. A device that fails the poll says so at the collect.
    pub fn oldest_submitted_done(&self) -> bool {
        let Some(oldest) = self.deferred.sets.front() else {
            return true;
        };
        let _poll = crate::gpu_context::device_poll_lock();
        let polled = self.device.poll(wgpu::PollType::Wait {
            submission_index: Some(oldest.submitted.index.clone()),
            timeout: Some(std::time::Duration::ZERO),
        });
        !matches!(polled, Err(wgpu::PollError::Timeout))
    }

    /// Drops the `count` oldest sets submitted ahead and not collected (a set whose run was
    /// cancelled part way); the sets submitted after them stay.
    pub fn drop_oldest_submitted(&mut self, count: usize) {
        let count = count.min(self.deferred.sets.len());
        self.deferred.sets.drain(..count);
        let count = u32::try_from(count).unwrap_or(u32::MAX);
        self.deferred.in_flight = self.deferred.in_flight.saturating_sub(count);
    }

    /// Records the last level of a frame set: read back now, or (sets submitted ahead)
    /// submitted for [`Self::collect_set`].
    pub(super) fn run_last_level(
        &mut self,
        plan: &SweepPlan,
        rig: &Rig,
        images: LevelImages<'_>,
    ) -> Result<LevelDepth, SweepError> {
        self.record_next_level(plan, rig, images)?;
        if self.deferred.on {
            self.submit_maps(plan)
        } else {
            self.finish_maps(plan).map(LevelDepth::Host)
        }
    }
}
