//! Live fusion on its own thread, beside the engine (the node's `fusion`, the `fuse` node): the
//! sets' depth maps come in through [`FuserThread::offer`], which never waits (at most
//! [`PENDING_SETS`] sets wait; when fusion falls behind, the oldest waiting set is dropped and
//! counted, so the engine is never held up by it); the thread integrates them in order and, at
//! most `mesh_rate` times a second, hands the changed blocks' markers to a sink (the node's
//! `mesh` publisher). Saving and clearing are requests answered through a oneshot channel, so
//! that a service handler awaits them without blocking its executor.

use std::collections::{BTreeMap, VecDeque};
use std::path::PathBuf;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use futures::channel::oneshot;

use super::counts::SkipCounts;
use super::fuser::{Fuser, FusionInput, SavedMesh};
use crate::fusion::{FusionError, FusionParams};
use crate::gpu_context::GpuContext;
use crate::msgs::MarkerArray;

/// Sets waiting for the fusion thread at most; an offer beyond drops the oldest.
pub const PENDING_SETS: usize = 2;

/// What the fusion has done so far (for `/diagnostics` and the logs).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FusionStats {
    /// Depth maps integrated.
    pub integrated: u64,
    /// Depth maps integrated, by source (reference frame or depth topic).
    pub integrated_by_source: BTreeMap<String, u64>,
    /// Sets dropped before fusion because it was behind.
    pub dropped_sets: u64,
    /// Depth maps refused, by reason.
    pub skipped: SkipCounts,
    pub blocks: usize,
    pub memory_bytes: usize,
    /// Triangles in the mesh as last meshed.
    pub triangles: usize,
    /// The map's frame (None before the first depth map, and after a clear).
    pub frame: Option<String>,
    /// Mesh updates handed to the sink.
    pub meshes_sent: u64,
    /// The last set's integration (all its depth maps) and the last meshing.
    pub last_integration: Duration,
    pub last_meshing: Duration,
    /// The map integrates on a GPU.
    pub on_gpu: bool,
    /// Why the map left its GPU for the CPU (a lost device; None: it never did).
    pub left_gpu: Option<String>,
}

/// A request to the fusion thread.
enum Request {
    Save(PathBuf, oneshot::Sender<Result<SavedMesh, String>>),
    Clear(oneshot::Sender<usize>),
    /// The engine's device was made anew: the map goes onto it ([`Fuser::move_to_gpu`]).
    Device(GpuContext),
}

#[derive(Default)]
struct State {
    sets: VecDeque<Vec<FusionInput>>,
    requests: VecDeque<Request>,
    /// The thread is working on what it took.
    busy: bool,
    closed: bool,
    stats: FusionStats,
}

struct Shared {
    state: Mutex<State>,
    wake: Condvar,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// The fusion thread. Dropping it stops the thread (a set in integration is finished first)
/// and waits for it.
pub struct FuserThread {
    shared: Arc<Shared>,
    handle: Option<JoinHandle<()>>,
}

impl FuserThread {
    /// Starts the thread, integrating on `gpu`'s device when given ([`Fuser::on`]; a device
    /// that fails, then or later, leaves the map on the CPU from its host copy, logged once
    /// and in [`FusionStats::left_gpu`]). `sink` gets each mesh update (never an empty
    /// one) and the `DELETEALL` of a clear; `mesh_rate_hz` 0: no updates (saving only).
    pub fn spawn(
        params: FusionParams,
        gpu: Option<&GpuContext>,
        mesh_rate_hz: f64,
        sink: impl FnMut(MarkerArray) + Send + 'static,
    ) -> Result<Self, FusionError> {
        let fuser = Fuser::on(params, gpu)?;
        let mut state = State::default();
        record(&mut state.stats, &fuser);
        let shared = Arc::new(Shared {
            state: Mutex::new(state),
            wake: Condvar::new(),
        });
        let period = (mesh_rate_hz > 0.0 && mesh_rate_hz.is_finite())
            .then(|| Duration::from_secs_f64(1.0 / mesh_rate_hz));
        let thread_shared = Arc::clone(&shared);
        let handle = std::thread::Builder::new()
            .name("sweepdepth-fusion".into())
            .spawn(move || run(&thread_shared, fuser, period, sink))
            .map_err(|e| {
                FusionError::InvalidParams(format!("cannot start the fusion thread: {e}"))
            })?;
        Ok(Self {
            shared,
            handle: Some(handle),
        })
    }

    /// Offers one set's depth maps; never waits. Returns whether an older waiting set was
    /// dropped to make room (counted in [`FusionStats::dropped_sets`]).
    pub fn offer(&self, set: Vec<FusionInput>) -> bool {
        if set.is_empty() {
            return false;
        }
        let mut state = self.shared.lock();
        let mut dropped = false;
        while state.sets.len() >= PENDING_SETS {
            state.sets.pop_front();
            state.stats.dropped_sets += 1;
            dropped = true;
        }
        state.sets.push_back(set);
        drop(state);
        self.shared.wake.notify_one();
        dropped
    }

    /// Asks for the whole mesh in a binary PLY file at `path` (after the sets already offered);
    /// the answer comes through the receiver (an error says why, e.g. a folder that does not
    /// exist; a receiver that fails means the thread has stopped).
    pub fn save(&self, path: PathBuf) -> oneshot::Receiver<Result<SavedMesh, String>> {
        let (tx, rx) = oneshot::channel();
        self.request(Request::Save(path, tx));
        rx
    }

    /// Asks for the map to be emptied (the sets already offered are fused first); the answer
    /// is the number of blocks dropped.
    pub fn clear(&self) -> oneshot::Receiver<usize> {
        let (tx, rx) = oneshot::channel();
        self.request(Request::Clear(tx));
        rx
    }

    /// The engine's device was lost and made anew: a map that fused on the old one goes on on
    /// `gpu` (after the sets already offered, which leave the lost device for the CPU), its
    /// blocks uploaded from its host copy. Logged; a device that refuses it leaves it on the
    /// CPU.
    pub fn follow_device(&self, gpu: GpuContext) {
        self.request(Request::Device(gpu));
    }

    fn request(&self, request: Request) {
        self.shared.lock().requests.push_back(request);
        self.shared.wake.notify_one();
    }

    pub fn stats(&self) -> FusionStats {
        self.shared.lock().stats.clone()
    }

    /// Fuses every set offered so far and waits until the thread is idle (for `bag` and tests).
    pub fn flush(&self) {
        let mut state = self.shared.lock();
        while !state.closed && (state.busy || !state.sets.is_empty() || !state.requests.is_empty())
        {
            state = self
                .shared
                .wake
                .wait_timeout(state, Duration::from_millis(20))
                .map(|(s, _)| s)
                .unwrap_or_else(|p| p.into_inner().0);
        }
    }
}

impl Drop for FuserThread {
    fn drop(&mut self) {
        self.shared.lock().closed = true;
        self.shared.wake.notify_all();
        if let Some(handle) = self.handle.take() {
            let _ = handle.join();
        }
    }
}

fn run(
    shared: &Shared,
    mut fuser: Fuser,
    period: Option<Duration>,
    mut sink: impl FnMut(MarkerArray),
) {
    let mut next_mesh = Instant::now();
    // Integrated since the last mesh update.
    let mut unsent = false;
    loop {
        let (request, set) = {
            let mut state = shared.lock();
            loop {
                if state.closed {
                    return;
                }
                if !state.requests.is_empty() || !state.sets.is_empty() {
                    break;
                }
                let due = match period {
                    Some(_) if unsent => next_mesh.saturating_duration_since(Instant::now()),
                    _ => Duration::from_secs(3600),
                };
                if due.is_zero() {
                    break;
                }
                state = shared
                    .wake
                    .wait_timeout(state, due)
                    .map(|(s, _)| s)
                    .unwrap_or_else(|p| p.into_inner().0);
            }
            // Requests wait for the sets offered before them.
            let request = if state.sets.is_empty() {
                state.requests.pop_front()
            } else {
                None
            };
            state.busy = true;
            (request, state.sets.pop_front())
        };
        if let Some(set) = set {
            let started = Instant::now();
            for input in &set {
                // A refused depth map is counted by the fuser under its reason.
                let _ = fuser.add(input);
            }
            unsent = true;
            let mut state = shared.lock();
            state.stats.last_integration = started.elapsed();
            record(&mut state.stats, &fuser);
        }
        match request {
            Some(Request::Save(path, answer)) => {
                let result = fuser
                    .save(&path)
                    .map_err(|e| format!("{}: {e}", path.display()));
                record(&mut shared.lock().stats, &fuser);
                let _ = answer.send(result);
            }
            Some(Request::Device(gpu)) => {
                match fuser.move_to_gpu(&gpu) {
                    Ok(()) => tracing::info!(
                        "fusion: the map goes on on the new device: {}",
                        gpu.adapter_label()
                    ),
                    Err(e) => tracing::warn!("fusion: the map stays on the CPU: {e}"),
                }
                record(&mut shared.lock().stats, &fuser);
            }
            Some(Request::Clear(answer)) => {
                let (blocks, markers) = fuser.clear();
                unsent = false;
                sink(markers);
                record(&mut shared.lock().stats, &fuser);
                let _ = answer.send(blocks);
            }
            None => {}
        }
        if let Some(period) = period {
            let now = Instant::now();
            if unsent && now >= next_mesh {
                let started = Instant::now();
                let markers = fuser.markers();
                let took = started.elapsed();
                unsent = false;
                next_mesh = now + period;
                let sent = !markers.markers.is_empty();
                if sent {
                    sink(markers);
                }
                let mut state = shared.lock();
                state.stats.last_meshing = took;
                state.stats.meshes_sent += u64::from(sent);
                record(&mut state.stats, &fuser);
            }
        }
        shared.lock().busy = false;
        shared.wake.notify_all();
    }
}

/// The fuser's counts into the shared stats; says once that the map left its GPU.
fn record(stats: &mut FusionStats, fuser: &Fuser) {
    if let (None, Some(reason)) = (&stats.left_gpu, fuser.left_gpu()) {
        tracing::warn!("fusion: the map goes on on the CPU from its host copy: {reason}");
        stats.left_gpu = Some(reason.to_string());
    }
    stats.on_gpu = fuser.is_on_gpu();
    stats.integrated = fuser.integrated;
    stats.integrated_by_source = fuser.integrated_by_source.clone();
    stats.skipped = fuser.skipped.clone();
    let (blocks, bytes) = fuser.blocks();
    stats.blocks = blocks;
    stats.memory_bytes = bytes;
    stats.triangles = fuser.triangles();
    stats.frame = fuser.frame().map(str::to_string);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::FusionParams;
    use crate::geometry::{CameraModel, PinholeIntrinsics, RigidTransform};
    use crate::image::ImageF32;
    use crate::msgs::{Marker, Time};
    use std::sync::mpsc;

    fn wall(stamp: i32) -> FusionInput {
        FusionInput {
            stamp: Time {
                sec: stamp,
                nanosec: 0,
            },
            frame: "map".into(),
            depth: ImageF32 {
                width: 64,
                height: 48,
                data: vec![2.0; 64 * 48],
            },
            colour: None,
            model: CameraModel::pinhole(PinholeIntrinsics {
                width_px: 64,
                height_px: 48,
                fx_px: 60.0,
                fy_px: 60.0,
                cx_px: 31.5,
                cy_px: 23.5,
            }),
            map_from_cam: RigidTransform::IDENTITY,
            confidence: None,
            baseline_ratio: None,
            source: "cam0_optical".into(),
        }
    }

    fn params() -> FusionParams {
        FusionParams {
            voxel_size_m: 0.05,
            ..FusionParams::default()
        }
    }

    #[test]
    fn sets_are_fused_meshed_sent_saved_and_cleared() {
        let (tx, rx) = mpsc::channel();
        let worker = FuserThread::spawn(params(), None, 1000.0, move |m| {
            let _ = tx.send(m);
        })
        .unwrap();
        worker.offer(vec![wall(1)]);
        let first = rx.recv_timeout(Duration::from_secs(600)).unwrap();
        assert!(!first.markers.is_empty());
        assert!(first.markers.iter().all(|m| m.action == Marker::ADD));
        let dir = std::env::temp_dir().join(format!("sweepdepth-fw-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let saved = futures::executor::block_on(worker.save(dir.join("m.ply")))
            .unwrap()
            .unwrap();
        assert!(saved.triangles > 0);
        let missing = futures::executor::block_on(worker.save(dir.join("no/such/dir/m.ply")))
            .unwrap()
            .unwrap_err();
        assert!(missing.contains("no/such/dir"), "{missing}");
        let blocks = futures::executor::block_on(worker.clear()).unwrap();
        assert!(blocks > 0);
        let clear = rx.recv_timeout(Duration::from_secs(600)).unwrap();
        assert_eq!(clear.markers[0].action, Marker::DELETEALL);
        let stats = worker.stats();
        assert_eq!(stats.integrated, 1);
        assert_eq!(stats.blocks, 0);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn offers_never_wait_and_the_oldest_waiting_set_is_dropped() {
        // A sink that holds the thread until told: the sets offered meanwhile wait.
        let (gate_tx, gate_rx) = mpsc::channel::<()>();
        let (sent_tx, sent_rx) = mpsc::channel::<()>();
        let worker = FuserThread::spawn(params(), None, 1000.0, move |_| {
            let _ = sent_tx.send(());
            let _ = gate_rx.recv();
        })
        .unwrap();
        worker.offer(vec![wall(1)]);
        sent_rx.recv_timeout(Duration::from_secs(600)).unwrap();
        // The thread is in the sink: these wait, the first of them is dropped.
        let mut dropped = 0;
        for stamp in 2..=(2 + PENDING_SETS as i32) {
            dropped += u32::from(worker.offer(vec![wall(stamp)]));
        }
        assert_eq!(dropped, 1);
        assert_eq!(worker.stats().dropped_sets, 1);
        drop(gate_tx);
        worker.flush();
        assert_eq!(worker.stats().integrated, 1 + PENDING_SETS as u64);
    }

    /// A depth map of the sphere before the slanted wall (`fusion::test_scenes`) from the
    /// `i`th of three oblique poses.
    fn oblique(i: usize) -> FusionInput {
        use crate::fusion::test_scenes::{camera, look_at, sphere_before_slanted_wall};
        let model = camera(128, 96, 110.0);
        let (up, target) = (
            glam::DVec3::new(0.1, -1.0, 0.2),
            glam::DVec3::new(0.0, 0.0, 2.0),
        );
        let eyes = [
            (0.7, -0.4, -0.2),
            (-0.3, 0.2, 0.1),
            (0.2, 0.5, 0.0),
            (0.4, 0.1, -0.3),
        ];
        let (x, y, z) = eyes[i];
        let pose = look_at(glam::DVec3::new(x, y, z), target, up);
        FusionInput {
            depth: sphere_before_slanted_wall(&model, &pose),
            model,
            map_from_cam: pose,
            ..wall(i as i32)
        }
    }

    /// Waits (one generous limit, whatever the machine's speed) until the thread has taken
    /// `n` depth maps (integrated or refused) and is idle; no set may have been dropped.
    fn settle(worker: &FuserThread, n: u64) -> FusionStats {
        let started = Instant::now();
        loop {
            let stats = worker.stats();
            assert_eq!(stats.dropped_sets, 0, "offer one set at a time");
            if stats.integrated + stats.skipped.total() >= n {
                worker.flush();
                return worker.stats();
            }
            assert!(
                started.elapsed() < Duration::from_secs(600),
                "the fusion thread took {} of {n} depth maps",
                stats.integrated + stats.skipped.total()
            );
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// The whole mesh of `worker` saved: (triangles, vertices).
    fn saved(worker: &FuserThread, name: &str) -> (usize, usize) {
        let dir = std::env::temp_dir().join(format!("sweepdepth-fw-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let saved = futures::executor::block_on(worker.save(dir.join("m.ply")))
            .unwrap()
            .unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        (saved.triangles, saved.vertices)
    }

    /// Two maps' meshes alike: within 1 % (the GPU's voxels differ from the CPU's in their
    /// last bits, `fusion/mapper.rs`'s test; a surface crossing differs with one of them).
    fn assert_alike(what: &str, gpu: (usize, usize), cpu: (usize, usize)) {
        assert!(cpu.0 > 500, "{what}: {cpu:?}");
        for (g, c) in [(gpu.0, cpu.0), (gpu.1, cpu.1)] {
            assert!(g.abs_diff(c) * 100 <= c, "{what}: {gpu:?} against {cpu:?}");
        }
    }

    /// Offers the `views` to both threads one at a time, each after the last was taken (a set
    /// offered while two wait would drop the oldest).
    fn offer_both(a: &FuserThread, b: &FuserThread, views: std::ops::Range<usize>) {
        for i in views {
            a.offer(vec![oblique(i)]);
            b.offer(vec![oblique(i)]);
            settle(a, i as u64 + 1);
            settle(b, i as u64 + 1);
        }
    }

    /// A thread on a GPU (lavapipe here) integrates the depth maps offered as a CPU thread
    /// does: the same blocks, the same mesh to float rounding, and says it is on the GPU.
    #[test]
    fn a_fusion_thread_on_the_gpu_fuses_as_the_cpu_one() {
        let (context, _one_at_a_time) = crate::fusion::gpu::tests::gpu();
        let gpu = FuserThread::spawn(params(), Some(context), 0.0, |_| {}).unwrap();
        let cpu = FuserThread::spawn(params(), None, 0.0, |_| {}).unwrap();
        offer_both(&gpu, &cpu, 0..3);
        let (on_gpu, on_cpu) = (settle(&gpu, 3), settle(&cpu, 3));
        assert!(on_gpu.on_gpu && !on_cpu.on_gpu);
        assert_eq!(on_gpu.left_gpu, None);
        assert_eq!((on_gpu.integrated, on_cpu.integrated), (3, 3));
        assert!(on_gpu.skipped.is_empty(), "{:?}", on_gpu.skipped);
        assert!(on_cpu.blocks > 100, "{} blocks", on_cpu.blocks);
        assert_eq!(on_gpu.blocks, on_cpu.blocks);
        assert_alike("three views", saved(&gpu, "gpu"), saved(&cpu, "cpu"));
    }

    /// The device lost between two depth maps (`Device::destroy`, on a device of the test's
    /// own): the thread says why once, goes on on the CPU with every block fused on the GPU
    /// (the map copies its blocks to the host at its first depth map, then every
    /// `MIRROR_PERIOD`), integrates the depth map whose GPU integration failed and those
    /// after, and its map is the CPU thread's.
    #[test]
    fn a_lost_device_leaves_the_map_on_the_cpu_with_every_block() {
        let (_shared, _one_at_a_time) = crate::fusion::gpu::tests::gpu();
        let own = GpuContext::new().expect("an adapter (lavapipe is fine)");
        let gpu = FuserThread::spawn(params(), Some(&own), 0.0, |_| {}).unwrap();
        let cpu = FuserThread::spawn(params(), None, 0.0, |_| {}).unwrap();
        gpu.offer(vec![oblique(0)]);
        cpu.offer(vec![oblique(0)]);
        let (first, reference) = (settle(&gpu, 1), settle(&cpu, 1));
        assert!(first.on_gpu && first.left_gpu.is_none());
        assert_eq!(first.blocks, reference.blocks);
        own.device.destroy();
        offer_both(&gpu, &cpu, 1..3);
        let (after, reference) = (settle(&gpu, 3), settle(&cpu, 3));
        assert!(!after.on_gpu, "still on the GPU after its loss");
        let reason = after.left_gpu.clone().expect("the reason it left the GPU");
        eprintln!("left the GPU: {reason}");
        assert!(reason.contains("GPU"), "{reason}");
        assert_eq!(
            after.integrated, 3,
            "no depth map lost: {:?}",
            after.skipped
        );
        assert!(
            after.blocks > first.blocks,
            "{} then {}",
            first.blocks,
            after.blocks
        );
        assert_eq!(after.blocks, reference.blocks);
        assert_alike("after the loss", saved(&gpu, "lost"), saved(&cpu, "kept"));
    }

    /// The engine's device lost and made anew (`follow_device`, as the node's GPU thread does
    /// after recreating its engine): a map that left the lost device for the CPU goes on on
    /// the new one with every block, says so, and fuses on as the CPU thread does.
    #[test]
    fn a_map_follows_the_engine_onto_its_new_device() {
        let (_shared, _one_at_a_time) = crate::fusion::gpu::tests::gpu();
        let own = GpuContext::new().expect("an adapter (lavapipe is fine)");
        let gpu = FuserThread::spawn(params(), Some(&own), 0.0, |_| {}).unwrap();
        let cpu = FuserThread::spawn(params(), None, 0.0, |_| {}).unwrap();
        offer_both(&gpu, &cpu, 0..1);
        own.device.destroy();
        offer_both(&gpu, &cpu, 1..2);
        let left = settle(&gpu, 2);
        assert!(!left.on_gpu && left.left_gpu.is_some(), "{left:?}");
        let new = GpuContext::new().expect("a new device");
        gpu.follow_device(new.clone());
        gpu.flush();
        let moved = gpu.stats();
        assert!(moved.on_gpu, "not on the new device: {moved:?}");
        assert!(moved.left_gpu.is_some(), "the loss is still told");
        assert_eq!(
            moved.blocks, left.blocks,
            "every block went onto the new device"
        );
        offer_both(&gpu, &cpu, 2..4);
        let (after, reference) = (settle(&gpu, 4), settle(&cpu, 4));
        assert!(after.on_gpu && after.skipped.is_empty(), "{after:?}");
        assert_eq!(after.blocks, reference.blocks);
        assert_alike(
            "on the new device",
            saved(&gpu, "new"),
            saved(&cpu, "stayed"),
        );
        // Moved again from a device that still answers: nothing is lost on the way.
        gpu.follow_device(GpuContext::new().expect("a third device"));
        gpu.flush();
        let third = gpu.stats();
        assert!(third.on_gpu && third.blocks == after.blocks, "{third:?}");
        assert_alike(
            "on the third device",
            saved(&gpu, "third"),
            saved(&cpu, "still"),
        );
    }
}
