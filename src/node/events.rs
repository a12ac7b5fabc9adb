//! The event loop's handling of one subscription event: the message goes into the pipeline,
//! its outcome is logged and counted, and each ready set is offered to the GPU worker (the
//! newest set replaces one still waiting).

use std::pin::Pin;
use std::sync::Mutex;
use std::time::Instant;

use futures::Stream;

use super::diag::Stats;
use super::log::{lock, node_log, RateLimited};
use crate::handoff::Handoff;
use crate::msgs::{CameraInfo, CompressedImage, Image, TFMessage};
use crate::pipeline::{Input, Job, Pipeline};

/// A subscription's next message, or what ros2-client said instead.
pub(super) enum Event {
    Image(usize, Result<Image, String>),
    Compressed(usize, Result<CompressedImage, String>),
    Info(usize, Result<Box<CameraInfo>, String>),
    Tf(Result<TFMessage, String>),
    /// `/tf` (a moving rig, `world_frame`).
    TfDynamic(Result<TFMessage, String>),
}

pub(super) type EventStream<'a> = Pin<Box<dyn Stream<Item = Event> + 'a>>;

pub(super) struct LoopState<'a> {
    /// Shared with the diagnostics thread, which asks it why no depth comes out.
    pub pipeline: &'a Mutex<Pipeline<'a>>,
    /// The clock of camera dropout (receive time).
    pub started: Instant,
    pub log: RateLimited,
    pub slot: &'a Handoff<Job>,
    pub stats: &'a Mutex<Stats>,
}

impl LoopState<'_> {
    pub fn handle(&mut self, event: Event) {
        let now_ns = u64::try_from(self.started.elapsed().as_nanos()).unwrap_or(u64::MAX);
        let input = match event {
            Event::Image(camera, Ok(image)) => {
                lock(self.stats).on_image(camera, Instant::now());
                Input::Image { camera, image }
            }
            Event::Compressed(camera, Ok(image)) => {
                lock(self.stats).on_image(camera, Instant::now());
                Input::Compressed { camera, image }
            }
            Event::Info(camera, Ok(info)) => Input::CameraInfo { camera, info },
            Event::Tf(Ok(msg)) => Input::TfStatic(msg),
            Event::TfDynamic(Ok(msg)) => Input::Tf(msg),
            Event::Image(i, Err(e)) | Event::Compressed(i, Err(e)) | Event::Info(i, Err(e)) => {
                let pipeline = lock(self.pipeline);
                let camera = pipeline.config().cameras.get(i).map_or("?", String::as_str);
                self.log.warn(&format!("read{i}"), || {
                    format!("camera '{camera}': read error: {e}")
                });
                return;
            }
            Event::Tf(Err(e)) => {
                self.log
                    .warn("tf_read", || format!("/tf_static: read error: {e}"));
                return;
            }
            Event::TfDynamic(Err(e)) => {
                self.log
                    .warn("tf_dynamic_read", || format!("/tf: read error: {e}"));
                return;
            }
        };
        let (outcome, waiting_for_pose, inactive_cameras, halted) = {
            let mut pipeline = lock(self.pipeline);
            let outcome = pipeline.push(input, now_ns);
            (
                outcome,
                pipeline.waiting_for_pose(),
                pipeline.inactive_cameras(),
                pipeline.halted(),
            )
        };
        for event in &outcome.rig_events {
            node_log(tracing::Level::WARN, &event.to_string());
        }
        for notice in &outcome.notices {
            self.log.warn(&notice.key(), || notice.message.clone());
        }
        for skip in outcome.skips() {
            self.log.warn(&skip.key(), || skip.message.clone());
        }
        {
            let mut stats = lock(self.stats);
            for skip in outcome.skips() {
                stats.skipped.add(skip.kind.label());
            }
            stats.waiting_for_pose = waiting_for_pose;
            if let Some(verdict) = &outcome.sync {
                verdict.count(&mut stats.sync);
            }
            stats.inactive_cameras = inactive_cameras;
            stats.halted = halted;
        }
        for job in outcome.jobs() {
            self.offer(job);
        }
    }

    fn offer(&mut self, job: Job) {
        if self.slot.offer(job) {
            let dropped = self.slot.dropped();
            lock(self.stats).gpu_dropped = dropped;
            tracing::debug!("a pending set was replaced (dropped: {dropped})");
        }
    }
}
