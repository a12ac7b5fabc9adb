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
}

/// A request to the fusion thread.
enum Request {
    Save(PathBuf, oneshot::Sender<Result<SavedMesh, String>>),
    Clear(oneshot::Sender<usize>),
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
    /// Starts the thread. `sink` gets each mesh update (never an empty one) and the `DELETEALL`
    /// of a clear; `mesh_rate_hz` 0: no updates (saving only).
    pub fn spawn(
        params: FusionParams,
        mesh_rate_hz: f64,
        sink: impl FnMut(MarkerArray) + Send + 'static,
    ) -> Result<Self, FusionError> {
        let fuser = Fuser::new(params)?;
        let shared = Arc::new(Shared {
            state: Mutex::new(State::default()),
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

/// The fuser's counts into the shared stats.
fn record(stats: &mut FusionStats, fuser: &Fuser) {
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
        let worker = FuserThread::spawn(params(), 1000.0, move |m| {
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
        let worker = FuserThread::spawn(params(), 1000.0, move |_| {
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
}
