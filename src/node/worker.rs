//! The GPU thread: owns the [`EngineHost`], takes the newest set from the [`Handoff`], runs
//! it with the engine parameters of the moment and publishes its outputs.

use std::sync::{mpsc, Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use ros2_client::Publisher;

use super::clock;
use super::demand::Demand;
use super::diag::Stats;
use super::log::{lock, log_info, RateLimited};
use super::params::LiveParams;
use super::sender::Sender;
use super::NodeError;
use crate::gpu_context::GpuContext;
use crate::handoff::Handoff;
use crate::msgs::{CameraInfo, Image, PointCloud2, Time};
use crate::pipeline::{
    EngineHost, FrameMaps, FrameMessages, FuserThread, FusionInput, HostError, Job, Output,
    OutputMsg, SetOutputs, Wanted,
};
use crate::sweep::CancelFlag;
use crate::viewer::Viewer;

/// One output's publisher, of its message type (`pipeline::OUTPUTS`).
pub(super) enum OutputPublisher {
    Image(Publisher<Image>),
    CameraInfo(Publisher<CameraInfo>),
    PointCloud2(Publisher<PointCloud2>),
}

impl OutputPublisher {
    fn publish(&self, msg: OutputMsg) -> Result<(), String> {
        match (self, msg) {
            (Self::Image(p), OutputMsg::Image(m)) => p.publish(m).map_err(|e| format!("{e:?}")),
            (Self::CameraInfo(p), OutputMsg::CameraInfo(m)) => {
                p.publish(*m).map_err(|e| format!("{e:?}"))
            }
            (Self::PointCloud2(p), OutputMsg::PointCloud2(m)) => {
                p.publish(m).map_err(|e| format!("{e:?}"))
            }
            _ => Err("a message of another type than its topic's".into()),
        }
    }
}

/// The publishers of one reference's outputs (made once DDS is up, then handed to the
/// thread), one per published output of the list, with its topic.
pub(super) struct Publishers {
    pub outputs: Vec<(Output, String, OutputPublisher)>,
}

/// What the GPU thread hands its outputs to: each reference's publishers (in the
/// configuration's order) and, with `fusion`, the fusion thread.
pub(super) struct Outputs {
    pub references: Vec<Publishers>,
    pub fusion: Option<Arc<FuserThread>>,
    /// Fusion runs on the engine's device: it follows the engine to a new one after a loss.
    pub fusion_follows_engine: bool,
    /// `world_frame` on a moving rig (fusion's map frame).
    pub world_frame: Option<String>,
    /// Which optional outputs have subscribers (made only then).
    pub demand: Arc<Demand>,
}

/// The running GPU thread.
pub(super) struct GpuThread {
    pub handle: JoinHandle<()>,
    /// The adapter the engine runs on.
    pub adapter: String,
    /// The WGSL engine's device (None: the CPU engine), for fusion on the same GPU.
    pub gpu: Option<GpuContext>,
    /// Where the publishers go once DDS is up; the thread waits for them.
    pub publishers: mpsc::Sender<Outputs>,
}

/// Starts the GPU thread and waits until its engine is up (so that a missing adapter fails
/// before DDS comes up).
pub(super) fn spawn(
    device: crate::engine::Device,
    cancel: CancelFlag,
    slot: Arc<Handoff<Job>>,
    live: Arc<LiveParams>,
    stats: Arc<Mutex<Stats>>,
    viewer: Option<Viewer>,
) -> Result<GpuThread, NodeError> {
    let (init_tx, init_rx) = mpsc::channel::<Result<(String, Option<GpuContext>), HostError>>();
    let (publishers_tx, publishers_rx) = mpsc::channel::<Outputs>();
    let handle = std::thread::Builder::new()
        .name("sweepdepth-gpu".into())
        .spawn(move || {
            let mut host = match EngineHost::new(device) {
                Ok(host) => host,
                Err(e) => {
                    let _ = init_tx.send(Err(e));
                    return;
                }
            };
            host.set_cancel(cancel);
            let _ = init_tx.send(Ok((host.adapter_label(), host.gpu().cloned())));
            let Ok(publishers) = publishers_rx.recv() else {
                return;
            };
            worker_loop(&slot, &live, &stats, host, publishers, viewer.as_ref());
        })
        .map_err(|e| NodeError::Gpu(format!("cannot start the GPU thread: {e}")))?;
    let (adapter, gpu) = match init_rx.recv() {
        Ok(Ok(engine)) => engine,
        Ok(Err(e)) => return Err(NodeError::Engine(e)),
        Err(_) => {
            return Err(NodeError::Gpu(
                "the GPU thread ended during start-up".into(),
            ))
        }
    };
    Ok(GpuThread {
        handle,
        adapter,
        gpu,
        publishers: publishers_tx,
    })
}

/// How often the GPU thread looks for a new set while the set in flight is on the device.
const NEXT_SET_POLL: Duration = Duration::from_millis(1);

/// One set's messages on their way to the sending thread.
struct Outgoing {
    messages: Vec<(usize, FrameMessages)>,
    /// From the set's start on the GPU thread to its hand-over.
    processing: Duration,
    stamp: Time,
}

/// The sending thread (`sender.rs`): counts each set as published, then publishes it.
fn start_sending(
    publishers: Vec<Publishers>,
    stats: Arc<Mutex<Stats>>,
    dropped: impl Fn() -> u64 + Send + 'static,
) -> std::io::Result<Sender<Outgoing>> {
    let mut log = RateLimited::default();
    let mut published: u64 = 0;
    Sender::spawn(move |set: Outgoing| {
        // Counted before the messages go out, so that /diagnostics never counts fewer sets
        // than a subscriber has received (its thread may run between the two).
        {
            let mut stats = lock(&stats);
            stats.made_on_demand = set
                .messages
                .first()
                .map_or(Wanted::NONE, |(_, m)| Wanted::made(m));
            stats.on_published(set.processing, Instant::now(), clock::now(), set.stamp);
        }
        for (output, messages) in set.messages {
            let Some(publishers) = publishers.get(output) else {
                continue;
            };
            publish(publishers, messages, &mut log);
        }
        published += 1;
        if published == 1 || published.is_multiple_of(100) {
            log_info(&format!(
                "published {published} depth images ({} sets dropped waiting for the GPU)",
                dropped()
            ));
        }
    })
}

fn worker_loop(
    slot: &Arc<Handoff<Job>>,
    live: &LiveParams,
    stats: &Arc<Mutex<Stats>>,
    mut host: EngineHost,
    mut outputs: Outputs,
    viewer: Option<&Viewer>,
) {
    // Only fusion reads the depths as floats: without it the WGSL engine lends them out of
    // its readback buffer and the messages are made from there (one copy fewer per map).
    host.set_keep_floats(outputs.fusion.is_some());
    // Fusion on the engine's device follows it to a new one after a loss.
    if let (Some(fusion), true) = (&outputs.fusion, outputs.fusion_follows_engine) {
        let fusion = Arc::clone(fusion);
        host.on_new_device(move |gpu| fusion.follow_device(gpu.clone()));
    }
    let waiting = Arc::clone(slot);
    let references = std::mem::take(&mut outputs.references);
    let sender = match start_sending(references, Arc::clone(stats), move || waiting.dropped()) {
        Ok(sender) => sender,
        Err(e) => {
            tracing::error!("cannot start the sending thread: {e}; nothing will be published");
            return;
        }
    };
    let mut log = RateLimited::default();
    loop {
        // A set is waited for only when none is in flight.
        if host.in_flight() == 0 {
            let Some(job) = slot.take() else {
                break;
            };
            start_set(&mut host, job, live, viewer, &outputs, &mut log);
            let mut stats = lock(stats);
            stats.most_in_flight = stats.most_in_flight.max(host.in_flight());
        }
        // While the set in flight is still on the device (the WGSL engine), a set that comes
        // goes onto the device too: the device runs it while this thread reads the other back.
        // The one in flight is read back within a millisecond of being done (no set waits
        // longer for its outputs).
        while host.starts_without_waiting() && host.in_flight() < 2 && !host.oldest_done() {
            if let Some(job) = slot.take_timeout(NEXT_SET_POLL) {
                start_set(&mut host, job, live, viewer, &outputs, &mut log);
                let mut stats = lock(stats);
                stats.most_in_flight = stats.most_in_flight.max(host.in_flight());
            } else if slot.is_closed() || host.is_cancelled() {
                break;
            }
        }
        let Some(finished) = host.finish() else {
            continue;
        };
        let stamp = finished
            .job
            .images
            .get(finished.job.anchor())
            .map(|i| i.header.stamp);
        if let Some(stamp) = stamp {
            tracing::debug!(
                "finished the set stamped {}.{:09}",
                stamp.sec,
                stamp.nanosec
            );
        }
        let set = match finished.result {
            Ok(set) => set,
            // Shutting down: the run was stopped between passes; nobody waits for it.
            Err(_) if host.is_cancelled() => {
                log_info("shutting down: the set in flight was cancelled");
                break;
            }
            Err(skip) => {
                {
                    let mut stats = lock(stats);
                    stats.skipped.add(skip.kind.label());
                    stats.engine_skip = Some(skip.to_string());
                }
                log.warn(&skip.key(), || format!("{skip}; skipping this set"));
                continue;
            }
        };
        if host.is_cancelled() {
            log_info("shutting down: the set in flight was cancelled");
            break;
        }
        hand_over(
            set,
            finished.since,
            stats,
            &outputs,
            viewer,
            &sender,
            &mut log,
        );
    }
}

/// Starts one set on the engine with the engine parameters and wanted outputs of the moment.
fn start_set(
    host: &mut EngineHost,
    job: Job,
    live: &LiveParams,
    viewer: Option<&Viewer>,
    outputs: &Outputs,
    log: &mut RateLimited,
) {
    if let Some(image) = job.images.get(job.anchor()) {
        let stamp = image.header.stamp;
        tracing::debug!("running the set stamped {}.{:09}", stamp.sec, stamp.nanosec);
    }
    for name in &job.absent_references {
        log.warn(&format!("absent-reference {name}"), || {
            format!("reference camera '{name}' is out of the rig: no depth for it")
        });
    }
    // Parameter changes apply from the next set on.
    let sweep = live.sweep();
    // The outputs with subscribers over DDS or in a live view (the point cloud even when
    // DDS does not carry it).
    let wanted = viewer
        .map_or(Wanted::NONE, Viewer::wanted)
        .or(outputs.demand.wanted());
    host.start(job, &sweep, wanted);
}

/// A finished set's outputs: counted, shown, fused and handed to the sending thread.
fn hand_over(
    set: SetOutputs,
    since: Instant,
    stats: &Arc<Mutex<Stats>>,
    outputs: &Outputs,
    viewer: Option<&Viewer>,
    sender: &Sender<Outgoing>,
    log: &mut RateLimited,
) {
    if !set.skipped.is_empty() {
        let mut stats = lock(stats);
        for skip in &set.skipped {
            stats.skipped.add(skip.kind.label());
            stats.engine_skip = Some(skip.to_string());
        }
    }
    for skip in &set.skipped {
        log.warn(&skip.key(), || {
            format!("{skip}; no depth for it in this set")
        });
    }
    let Some(stamp) = set.outputs.first().map(|o| o.maps.header.stamp) else {
        return;
    };
    // A copy for the live view (only while a viewer is subscribed; never waits for it):
    // the first reference's outputs.
    if let (Some(viewer), Some(first)) = (viewer, set.outputs.first()) {
        viewer.offer(&first.messages);
    }
    {
        let mut stats = lock(stats);
        for out in &set.outputs {
            if let Some(pose) = out.maps.world_from_frame {
                let header = &out.maps.header;
                stats
                    .world_poses
                    .insert(header.frame_id.clone(), (header.stamp, pose));
            }
        }
    }
    let (maps, messages): (Vec<FrameMaps>, Vec<(usize, FrameMessages)>) = set
        .outputs
        .into_iter()
        .map(|out| (out.maps, (out.output, out.messages)))
        .unzip();
    // Fusion takes the depths as floats, moved (never waits: a fusion that falls behind
    // drops its own oldest waiting set, counted in /diagnostics).
    if let Some(fusion) = &outputs.fusion {
        let world = outputs.world_frame.as_deref();
        fusion.offer(
            maps.into_iter()
                .map(|m| FusionInput::from_maps(m, world))
                .collect(),
        );
    }
    // Sent on the sending thread while the next set runs; a set still waiting there is
    // dropped for this newer one.
    sender.offer(Outgoing {
        messages,
        processing: since.elapsed(),
        stamp,
    });
    lock(stats).send_dropped = sender.dropped();
}

/// Publishes one reference's messages on its publishers.
fn publish(publishers: &Publishers, messages: FrameMessages, log: &mut RateLimited) {
    for (output, msg) in messages.into_list() {
        let Some((_, topic, publisher)) = publishers.outputs.iter().find(|(o, ..)| *o == output)
        else {
            continue;
        };
        if let Err(e) = publisher.publish(msg) {
            log.warn("publish", || format!("publish failed: {topic}: {e}"));
        }
    }
}
