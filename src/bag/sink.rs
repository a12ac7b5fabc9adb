//! Where `bag`'s frame sets go ([`Sink`]): the engine (one set left in flight on the device
//! while the host finishes the one before), the output bag, fusion, the live view and the
//! report.

use std::collections::{HashSet, VecDeque};
use std::time::{Duration, Instant};

use indicatif::ProgressBar;

use super::report::BagReport;
use super::{BagError, BagWriter};
use crate::pipeline::{
    EngineHost, FrameMessages, Fuser, FusionInput, Job, Outcome, Output, OutputTopics,
    PipelineConfig, Skip, Wanted,
};
use crate::viewer::Viewer;

/// Offline every distinct message is printed once (the first 200); the summary counts.
fn warn(bar: &ProgressBar, seen: &mut HashSet<String>, msg: &str) {
    if seen.len() < 200 && seen.insert(msg.to_string()) {
        bar.suspend(|| tracing::warn!("{msg}"));
        if seen.len() == 200 {
            bar.suspend(|| tracing::warn!("further distinct warnings are not printed"));
        }
    }
}

/// Where the sets go: the engine, the output bag, the report.
pub(super) struct Sink<'a> {
    pub(super) config: &'a PipelineConfig,
    pub(super) host: EngineHost,
    pub(super) writer: BagWriter,
    pub(super) report: BagReport,
    pub(super) seen: HashSet<String>,
    pub(super) busy: Duration,
    pub(super) bar: ProgressBar,
    /// `--view`: the live view, fed every processed set.
    pub(super) viewer: Option<Viewer>,
    /// `fusion` or `--mesh`: every reference's depth fused into one mesh.
    pub(super) fuser: Option<BagFusion>,
    /// Sets left in flight on the device while the one before is finished (`--sets-ahead`).
    pub(super) sets_ahead: usize,
    /// The log time of each set in flight, oldest first.
    pub(super) log_times: VecDeque<u64>,
}

/// The bag's fusion: the fuser, and when its markers next go into OUT.
pub(super) struct BagFusion {
    pub(super) fuser: Fuser,
    /// It fuses on the engine's device, and follows the engine onto a new one after a loss.
    pub(super) follows_engine: bool,
    /// The engine's devices made anew that fusion has followed (`Fuser::follow_engine`).
    pub(super) devices_seen: u64,
    pub(super) topic: String,
    /// `mesh_rate` as a period in log time (None: no markers).
    pub(super) period_ns: Option<u64>,
    pub(super) next_ns: u64,
}

impl BagFusion {
    /// The changed blocks' markers into OUT when the mesh period has passed (or `last`), and
    /// to the live view.
    pub(super) fn write_markers(
        &mut self,
        writer: &mut BagWriter,
        viewer: Option<&Viewer>,
        log_time_ns: u64,
        last: bool,
    ) -> Result<(), BagError> {
        let Some(period) = self.period_ns else {
            return Ok(());
        };
        if log_time_ns < self.next_ns && !last {
            return Ok(());
        }
        self.next_ns = log_time_ns.saturating_add(period);
        let markers = self.fuser.markers();
        if !markers.markers.is_empty() {
            writer.write_msg(&self.topic, log_time_ns, &markers)?;
            if let Some(viewer) = viewer {
                viewer.offer_mesh_owned(markers);
            }
        }
        Ok(())
    }
}

impl Sink<'_> {
    /// A message that could not be decoded: counted per topic, reported once per topic.
    pub(super) fn bad_message(&mut self, topic: &str, message: &str) {
        self.report.bad_messages.add(topic.to_string());
        warn(&self.bar, &mut self.seen, message);
    }

    /// What one input gave: logged, counted, and its sets processed (outputs written at
    /// `log_time_ns`).
    pub(super) fn outcome(&mut self, outcome: Outcome, log_time_ns: u64) -> Result<(), BagError> {
        for event in &outcome.rig_events {
            self.bar.suspend(|| tracing::warn!("{event}"));
        }
        for notice in &outcome.notices {
            warn(&self.bar, &mut self.seen, &notice.message);
        }
        if let Some(verdict) = &outcome.sync {
            verdict.count(&mut self.report.sync);
        }
        for set in outcome.sets {
            self.set(set, log_time_ns)?;
        }
        Ok(())
    }

    /// Starts one synchronised set (or records why not); its outputs are written at
    /// `log_time_ns` when it finishes. On an engine that leaves a set's work on the device
    /// (the WGSL engine) one set stays in flight: the device runs it while this thread reads
    /// the one before back, writes it and fuses it (`--sets-ahead 0`: each set finished
    /// before the next starts).
    fn set(&mut self, set: Result<Job, Skip>, log_time_ns: u64) -> Result<(), BagError> {
        let config = self.config;
        self.report.sets_found += 1;
        let job = match set {
            Ok(job) => job,
            Err(skip) => {
                // The sets before it first, so that the report keeps the bag's order.
                self.finish_all()?;
                self.report.skipped.add(skip.kind.label());
                self.report.last_skip = Some(skip.to_string());
                warn(&self.bar, &mut self.seen, &format!("set skipped: {skip}"));
                return Ok(());
            }
        };
        let t0 = Instant::now();
        // Every output the bag has; the live view always shows the point cloud.
        let with_points = config.outputs().get(Output::Points).is_some() || self.viewer.is_some();
        self.host
            .start(job, &config.sweep, Wanted::all(with_points));
        self.log_times.push_back(log_time_ns);
        let in_flight = self.host.in_flight() as u64;
        self.report.most_in_flight = self.report.most_in_flight.max(in_flight);
        self.busy += t0.elapsed();
        let ahead = match self.host.starts_without_waiting() {
            true => self.sets_ahead,
            false => 0,
        };
        while self.host.in_flight() > ahead {
            self.finish_one()?;
        }
        Ok(())
    }

    /// Finishes every set in flight (at the end of the bag).
    pub(super) fn finish_all(&mut self) -> Result<(), BagError> {
        while self.host.in_flight() > 0 {
            self.finish_one()?;
        }
        Ok(())
    }

    /// Finishes the oldest set in flight: its outputs written, fused and shown.
    fn finish_one(&mut self) -> Result<(), BagError> {
        let config = self.config;
        let t0 = Instant::now();
        let Some(finished) = self.host.finish() else {
            return Ok(());
        };
        let log_time_ns = self.log_times.pop_front().unwrap_or_default();
        // Fusion on the engine's device follows it onto a new one after a loss.
        if let Some(fusion) = self.fuser.as_mut().filter(|f| f.follows_engine) {
            let followed = fusion
                .fuser
                .follow_engine(&self.host, &mut fusion.devices_seen);
            if let Err(e) = followed {
                warn(&self.bar, &mut self.seen, &format!("fusion: {e}"));
            }
        }
        let set = match finished.result {
            Ok(set) => set,
            Err(skip) => {
                self.report.skipped.add(skip.kind.label());
                self.report.last_skip = Some(skip.to_string());
                warn(&self.bar, &mut self.seen, &format!("set skipped: {skip}"));
                return Ok(());
            }
        };
        for skip in &set.skipped {
            self.report.skipped.add(skip.kind.label());
            self.report.last_skip = Some(skip.to_string());
            warn(&self.bar, &mut self.seen, &format!("no depth: {skip}"));
        }
        if let Some(fusion) = &mut self.fuser {
            let world = config.world.as_ref().map(|w| w.frame.as_str());
            for out in &set.outputs {
                let input = FusionInput::from_maps(out.maps.clone(), world);
                if let Err(e) = fusion.fuser.add(&input) {
                    warn(&self.bar, &mut self.seen, &format!("fusion: {e}"));
                }
            }
            fusion.write_markers(&mut self.writer, self.viewer.as_ref(), log_time_ns, false)?;
        }
        // (Points go into OUT only with publish_points: `write_outputs`.)
        for out in &set.outputs {
            if let Some((_, topics)) = config.references.get(out.output) {
                write_outputs(&mut self.writer, topics, log_time_ns, &out.messages)?;
            }
        }
        self.busy += t0.elapsed();
        if !set.outputs.is_empty() {
            self.report.sets_processed += 1;
            self.report.depth_maps += set.outputs.len() as u64;
        }
        // The live view shows the first reference's outputs.
        if let (Some(viewer), Some(first)) = (&self.viewer, set.outputs.into_iter().next()) {
            viewer.offer_owned(first.messages);
        }
        Ok(())
    }
}

/// Writes the outputs of one set.
fn write_outputs(
    writer: &mut BagWriter,
    topics: &OutputTopics,
    log_time_ns: u64,
    messages: &FrameMessages,
) -> Result<(), BagError> {
    for (topic, msg) in messages.with_topics(topics) {
        writer.write_msg(topic, log_time_ns, &msg)?;
    }
    Ok(())
}
