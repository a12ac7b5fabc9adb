//! The fused mesh on the viewer: a `visualization_msgs/msg/MarkerArray` channel fed with the
//! fusion's deltas (one TRIANGLE_LIST marker per block that changed, DELETE for a block whose
//! surface went, DELETEALL for a cleared map).
//!
//! Since the updates are deltas, the viewer keeps the latest marker per (`ns`, `id`) (DELETE and
//! DELETEALL applied): its memory is at most the mesh itself. A viewer that subscribes gets the
//! whole current mesh first (a DELETEALL, then every block's marker, in one message to that
//! viewer only), then the deltas. [`MeshFeed::offer`] never waits for the encoding or the
//! network: it files the delta (the markers shared by `Arc` with the state) and a thread of the
//! viewer encodes and logs it.

use std::collections::BTreeMap;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;

use foxglove::{Context, PartialMetadata, RawChannel, SinkId};
use serde::Serialize;

use super::channels::channel;
use super::{wall_time_ns, ViewerError};
use crate::msgdefs::MARKER_ARRAY;
use crate::msgs::{to_cdr, Header, Marker, MarkerArray};

/// Deltas waiting for the thread beyond which they are dropped and every viewer gets the whole
/// mesh again instead (a viewer that falls this far behind costs no more memory than that).
const MAX_PENDING: usize = 4;

/// A marker's identity, as RViz and Foxglove key them.
type Key = (String, i32);

/// What the thread is to send next.
enum Send {
    /// A delta, to every subscribed viewer.
    Delta(Vec<Arc<Marker>>),
    /// The whole mesh: to one viewer (`Some`) that just subscribed, or to all.
    Whole(Option<SinkId>),
}

#[derive(Default)]
struct State {
    /// The latest marker of every block on show.
    markers: BTreeMap<Key, Arc<Marker>>,
    /// The header of the latest marker (for the DELETEALL that opens a whole mesh).
    header: Header,
    /// The namespace of the latest marker.
    ns: String,
    queue: Vec<Send>,
    closed: bool,
}

impl State {
    /// Applies one marker in order; returns it shared for the delta.
    fn apply(&mut self, marker: Marker) -> Arc<Marker> {
        self.header = marker.header.clone();
        self.ns = marker.ns.clone();
        let key = (marker.ns.clone(), marker.id);
        let shared = Arc::new(marker);
        match shared.action {
            Marker::DELETE => {
                self.markers.remove(&key);
            }
            Marker::DELETEALL => self.markers.clear(),
            Marker::ADD => {
                self.markers.insert(key, Arc::clone(&shared));
            }
            // Not a mesh update (no other action is defined): passed on, not kept.
            _ => {}
        }
        shared
    }

    /// The whole mesh as one update: a DELETEALL, then every block.
    fn whole(&self) -> Vec<Arc<Marker>> {
        let clear = Marker {
            header: self.header.clone(),
            ns: self.ns.clone(),
            action: Marker::DELETEALL,
            ..Marker::default()
        };
        std::iter::once(Arc::new(clear))
            .chain(self.markers.values().cloned())
            .collect()
    }

    fn push(&mut self, send: Send) {
        let deltas = self
            .queue
            .iter()
            .filter(|s| matches!(s, Send::Delta(_)))
            .count();
        if matches!(send, Send::Delta(_)) && deltas >= MAX_PENDING {
            // The thread is behind: the whole mesh to everyone replaces the waiting deltas.
            self.queue.retain(|s| !matches!(s, Send::Delta(_)));
            self.queue.retain(|s| !matches!(s, Send::Whole(None)));
            self.queue.push(Send::Whole(None));
        } else {
            self.queue.push(send);
        }
    }
}

/// A MarkerArray of shared markers, encoded as the MarkerArray itself.
#[derive(Serialize)]
struct MarkerRefs<'a> {
    markers: Vec<&'a Marker>,
}

/// The mesh's channel, its state and the thread that logs it.
pub(super) struct MeshFeed {
    channel: Arc<RawChannel>,
    shared: Arc<Shared>,
    thread: Mutex<Option<JoinHandle<()>>>,
}

struct Shared {
    state: Mutex<State>,
    wake: Condvar,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }
}

impl MeshFeed {
    pub(super) fn new(context: &Arc<Context>, topic: &str) -> Result<Self, ViewerError> {
        let channel = channel(context, topic, MARKER_ARRAY)?;
        let shared = Arc::new(Shared {
            state: Mutex::new(State::default()),
            wake: Condvar::new(),
        });
        let thread = {
            let shared = Arc::clone(&shared);
            let channel = Arc::clone(&channel);
            std::thread::Builder::new()
                .name("sweepdepth-viewer-mesh".into())
                .spawn(move || log_loop(&shared, &channel))
                .map_err(|e| ViewerError::Thread(e.to_string()))?
        };
        Ok(Self {
            channel,
            shared,
            thread: Mutex::new(Some(thread)),
        })
    }

    /// The mesh channel's id (to tell its subscriptions from the others').
    pub(super) fn channel_id(&self) -> foxglove::ChannelId {
        self.channel.id()
    }

    /// Applies one update to the state; queues it for the viewers subscribed to the mesh.
    /// Never waits for them.
    pub(super) fn offer(&self, markers: MarkerArray) {
        if markers.markers.is_empty() {
            return;
        }
        let mut state = self.shared.lock();
        let delta: Vec<Arc<Marker>> = markers
            .markers
            .into_iter()
            .map(|m| state.apply(m))
            .collect();
        if self.channel.has_sinks() {
            state.push(Send::Delta(delta));
            self.shared.wake.notify_one();
        }
    }

    /// A viewer subscribed to the mesh: the whole mesh to it.
    pub(super) fn subscribed(&self, sink: Option<SinkId>) {
        let mut state = self.shared.lock();
        state.push(Send::Whole(sink));
        self.shared.wake.notify_one();
    }

    /// (blocks on show, triangles in them).
    pub(super) fn size(&self) -> (usize, usize) {
        let state = self.shared.lock();
        let triangles = state.markers.values().map(|m| m.points.len() / 3).sum();
        (state.markers.len(), triangles)
    }

    /// Stops the thread and closes the channel.
    pub(super) fn close(&self) {
        self.shared.lock().closed = true;
        self.shared.wake.notify_all();
        let thread = self.thread.lock().unwrap_or_else(|e| e.into_inner()).take();
        if let Some(thread) = thread {
            let _ = thread.join();
        }
        self.channel.close();
    }
}

impl Drop for MeshFeed {
    fn drop(&mut self) {
        self.close();
    }
}

fn log_loop(shared: &Shared, channel: &RawChannel) {
    let mut warned = false;
    loop {
        // Everything queued, in order; a whole mesh is taken from the state at this moment,
        // which includes every delta before it (and the ones after it in the queue: sent again
        // after it, they change nothing).
        let batch: Vec<(Vec<Arc<Marker>>, Option<SinkId>)> = {
            let mut state = shared.lock();
            while state.queue.is_empty() && !state.closed {
                state = shared.wake.wait(state).unwrap_or_else(|e| e.into_inner());
            }
            if state.closed {
                return;
            }
            let queue = std::mem::take(&mut state.queue);
            queue
                .into_iter()
                .map(|send| match send {
                    Send::Delta(delta) => (delta, None),
                    Send::Whole(sink) => (state.whole(), sink),
                })
                .collect()
        };
        for (markers, sink) in batch {
            let msg = MarkerRefs {
                markers: markers.iter().map(|m| m.as_ref()).collect(),
            };
            match to_cdr(&msg) {
                Ok(bytes) => channel.log_with_meta_to_sink(
                    &bytes,
                    PartialMetadata {
                        log_time: Some(wall_time_ns()),
                    },
                    sink,
                ),
                Err(e) if !warned => {
                    tracing::warn!(
                        "cannot encode {} for the viewer: {e} (further viewer errors are not printed)",
                        channel.topic()
                    );
                    warned = true;
                }
                Err(_) => {}
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{ColorRGBA, Point};

    fn block(id: i32, triangles: usize) -> Marker {
        Marker {
            ns: "sweepdepth_mesh".into(),
            id,
            r#type: Marker::TRIANGLE_LIST,
            action: Marker::ADD,
            points: vec![Point::default(); 3 * triangles],
            colors: vec![ColorRGBA::default(); 3 * triangles],
            ..Marker::default()
        }
    }

    fn action(id: i32, action: i32) -> Marker {
        Marker {
            ns: "sweepdepth_mesh".into(),
            id,
            action,
            ..Marker::default()
        }
    }

    #[test]
    fn the_state_keeps_the_latest_marker_per_block() {
        let mut state = State::default();
        for m in [
            block(1, 2),
            block(2, 3),
            block(1, 5),
            action(2, Marker::DELETE),
        ] {
            state.apply(m);
        }
        assert_eq!(state.markers.len(), 1);
        assert_eq!(
            state.markers[&("sweepdepth_mesh".into(), 1)].points.len(),
            15
        );
        let whole = state.whole();
        assert_eq!(whole.len(), 2);
        assert_eq!(whole[0].action, Marker::DELETEALL);
        assert_eq!(whole[1].id, 1);
        state.apply(action(0, Marker::DELETEALL));
        assert!(state.markers.is_empty());
        state.apply(block(7, 1));
        assert_eq!(state.whole().len(), 2);
    }

    #[test]
    fn a_long_queue_becomes_the_whole_mesh() {
        let mut state = State::default();
        state.push(Send::Whole(None));
        for _ in 0..MAX_PENDING + 3 {
            state.push(Send::Delta(vec![Arc::new(block(1, 1))]));
        }
        let deltas = state
            .queue
            .iter()
            .filter(|s| matches!(s, Send::Delta(_)))
            .count();
        let wholes = state
            .queue
            .iter()
            .filter(|s| matches!(s, Send::Whole(None)))
            .count();
        assert!(deltas <= MAX_PENDING, "{deltas} deltas queued");
        assert_eq!(wholes, 1);
        // The whole mesh is encoded as a MarkerArray.
        let whole = state.whole();
        let refs = MarkerRefs {
            markers: whole.iter().map(|m| m.as_ref()).collect(),
        };
        let owned = MarkerArray {
            markers: whole.iter().map(|m| (**m).clone()).collect(),
        };
        assert_eq!(to_cdr(&refs).unwrap(), to_cdr(&owned).unwrap());
    }
}
