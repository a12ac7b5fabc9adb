//! [`Viewer`]: the Foxglove WebSocket server, its channels, the page server and the thread that
//! logs each offered set into the channels (the mesh's own: `mesh.rs`).

use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use foxglove::websocket::{ChannelView, Client, ServerListener};
use foxglove::{Context, WebSocketServer, WebSocketServerHandle};

use super::channels::OutputChannels;
use super::mesh::MeshFeed;
use super::page::PageServer;
use super::{wall_time_ns, ViewerConfig, ViewerError, CLIENT_BACKLOG};
use crate::handoff::Handoff;
use crate::msgs::MarkerArray;
use crate::pipeline::{FrameMessages, OutputTopics};

/// One set for the viewer's thread, with the wall-clock time it was offered (ns).
type Offered = (Arc<FrameMessages>, u64);

/// The last set offered, sent again to a viewer when it subscribes (as a latched topic), so a
/// page opened after the last set of a bag still shows it.
#[derive(Default)]
struct Latch {
    last: Mutex<Option<Offered>>,
}

impl Latch {
    fn set(&self, offered: Offered) {
        *self.last.lock().unwrap_or_else(|e| e.into_inner()) = Some(offered);
    }
    fn get(&self) -> Option<Offered> {
        self.last.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }
}

/// Hands the latched set to the viewer's thread when a viewer subscribes to a set's channel;
/// the whole mesh to a viewer that subscribes to the mesh.
struct Listener {
    latch: Arc<Latch>,
    handoff: Arc<Handoff<Offered>>,
    mesh: Option<Arc<MeshFeed>>,
}

impl ServerListener for Listener {
    fn on_subscribe(&self, client: Client, channel: ChannelView) {
        if let Some(mesh) = &self.mesh {
            if channel.id() == mesh.channel_id() {
                mesh.subscribed(client.sink_id());
                return;
            }
        }
        if let Some(offered) = self.latch.get() {
            self.handoff.offer(offered);
        }
    }
}

/// A running live view. Cheap to clone (the clones share it) and `Send + Sync`: the engine's
/// thread offers sets, the fusion's thread the mesh. Dropping the last clone stops the servers
/// and the threads.
#[derive(Clone)]
pub struct Viewer {
    inner: Arc<Inner>,
}

struct Inner {
    config: ViewerConfig,
    /// The SDK's context of the channels and the server (they hold it weakly: kept here).
    _context: Arc<Context>,
    channels: Arc<OutputChannels>,
    mesh: Option<Arc<MeshFeed>>,
    latch: Arc<Latch>,
    handoff: Arc<Handoff<Offered>>,
    thread: Option<JoinHandle<()>>,
    server: Option<WebSocketServerHandle>,
    page: Option<PageServer>,
}

impl Viewer {
    /// Starts the WebSocket server on `config.port` with a channel per output of `topics`, and
    /// the page on the next port. Must not be called from inside a tokio runtime (the server
    /// runs its own). Without a mesh channel: [`Viewer::start_with_mesh`].
    pub fn start(config: &ViewerConfig, topics: &OutputTopics) -> Result<Self, ViewerError> {
        Self::start_with_mesh(config, topics, None)
    }

    /// [`Viewer::start`], and with `mesh_topic` (fusion on: the node's resolved `mesh` topic) a
    /// `visualization_msgs/msg/MarkerArray` channel of that name fed by [`Viewer::offer_mesh`].
    pub fn start_with_mesh(
        config: &ViewerConfig,
        topics: &OutputTopics,
        mesh_topic: Option<&str>,
    ) -> Result<Self, ViewerError> {
        let context = Context::new();
        let channels = Arc::new(OutputChannels::new(&context, topics)?);
        let mesh = match mesh_topic {
            Some(topic) => Some(Arc::new(MeshFeed::new(&context, topic)?)),
            None => None,
        };
        let latch = Arc::new(Latch::default());
        let handoff = Arc::new(Handoff::new());
        let listener = Arc::new(Listener {
            latch: Arc::clone(&latch),
            handoff: Arc::clone(&handoff),
            mesh: mesh.clone(),
        });
        let server = WebSocketServer::new()
            .name("sweepdepth")
            .listener(listener)
            .bind(config.address.clone(), config.port)
            .context(&context)
            .message_backlog_size(CLIENT_BACKLOG)
            .start_blocking()
            .map_err(|e| ViewerError::Server {
                address: config.address.clone(),
                port: config.port,
                reason: e.to_string(),
            })?;
        let page = PageServer::start(config)?;
        let thread = {
            let handoff = Arc::clone(&handoff);
            let channels = Arc::clone(&channels);
            std::thread::Builder::new()
                .name("sweepdepth-viewer".into())
                .spawn(move || log_loop(&handoff, &channels))
                .map_err(|e| ViewerError::Thread(e.to_string()))?
        };
        Ok(Self {
            inner: Arc::new(Inner {
                config: config.clone(),
                _context: context,
                channels,
                mesh,
                latch,
                handoff,
                thread: Some(thread),
                server: Some(server),
                page: Some(page),
            }),
        })
    }

    /// The outputs made on demand (cost, selection, points) that a viewer subscribed to: the
    /// engine makes them even when nobody reads them over DDS (the point cloud even when it is
    /// not published there).
    pub fn wanted(&self) -> crate::pipeline::Wanted {
        self.inner.channels.wanted()
    }

    /// Offers one set's messages (the live node, which publishes them over DDS after): copied
    /// for the viewer's thread only while a viewer is subscribed; a set the thread has not
    /// taken yet is replaced. Never waits.
    pub fn offer(&self, out: &FrameMessages) {
        let inner = &self.inner;
        if inner.channels.has_subscribers() {
            let offered = (Arc::new(out.clone()), wall_time_ns());
            inner.latch.set(offered.clone());
            inner.handoff.offer(offered);
        }
    }

    /// Offers one set's messages that the caller no longer needs (`bag`): kept as the latched
    /// set for viewers that subscribe later, handed to the viewer's thread while one is
    /// subscribed. Never waits.
    pub fn offer_owned(&self, out: FrameMessages) {
        let inner = &self.inner;
        let offered = (Arc::new(out), wall_time_ns());
        inner.latch.set(offered.clone());
        if inner.channels.has_subscribers() {
            inner.handoff.offer(offered);
        }
    }

    /// Offers one mesh update of the fusion (the blocks that changed, DELETE, DELETEALL): kept
    /// (the latest marker per block, so a viewer that subscribes later gets the whole mesh),
    /// and sent to the viewers subscribed to the mesh by a thread of the viewer. Copies the
    /// markers, never waits for a viewer. Without a mesh channel (started without a mesh
    /// topic) it does nothing.
    pub fn offer_mesh(&self, markers: &MarkerArray) {
        if let Some(mesh) = &self.inner.mesh {
            mesh.offer(markers.clone());
        }
    }

    /// [`Viewer::offer_mesh`] for an update the caller no longer needs (no copy).
    pub fn offer_mesh_owned(&self, markers: MarkerArray) {
        if let Some(mesh) = &self.inner.mesh {
            mesh.offer(markers);
        }
    }

    /// The mesh on show: (blocks, triangles); (0, 0) without a mesh channel.
    pub fn mesh_size(&self) -> (usize, usize) {
        self.inner.mesh.as_ref().map_or((0, 0), |m| m.size())
    }

    /// Sets replaced before the viewer's thread took them.
    pub fn replaced(&self) -> u64 {
        self.inner.handoff.dropped()
    }

    /// The connection string for Foxglove and Lichtblick.
    pub fn websocket_url(&self) -> String {
        self.inner.config.websocket_url()
    }

    /// The built-in page's address.
    pub fn page_url(&self) -> String {
        match self.inner.config.page_port() {
            Ok(port) => format!("http://{}:{port}/", self.inner.config.address),
            Err(_) => String::new(),
        }
    }
}

fn log_loop(handoff: &Handoff<Offered>, channels: &OutputChannels) {
    let mut warned = false;
    while let Some((out, log_time_ns)) = handoff.take() {
        if let Err(e) = channels.log(&out, log_time_ns) {
            if !warned {
                tracing::warn!("{e} (further viewer errors are not printed)");
                warned = true;
            }
        }
    }
}

impl Drop for Inner {
    fn drop(&mut self) {
        self.handoff.close();
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
        self.channels.close();
        if let Some(mesh) = &self.mesh {
            mesh.close();
        }
        self.page.take();
        if let Some(server) = self.server.take() {
            server.stop().wait_blocking();
        }
    }
}

/// The engine's and the fusion's threads share the viewer.
const _: () = {
    const fn send_sync<T: Send + Sync>() {}
    send_sync::<Viewer>();
};
