//! [`Viewer`]: the Foxglove WebSocket server, its channels, the page server and the thread that
//! logs each offered set into the channels.

use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{SystemTime, UNIX_EPOCH};

use foxglove::websocket::{ChannelView, Client, ServerListener};
use foxglove::{Context, WebSocketServer, WebSocketServerHandle};

use super::channels::OutputChannels;
use super::page::PageServer;
use super::{ViewerConfig, ViewerError, CLIENT_BACKLOG};
use crate::handoff::Handoff;
use crate::pipeline::{FrameOutputs, OutputTopics};

/// One set for the viewer's thread, with the wall-clock time it was offered (ns).
type Offered = (Arc<FrameOutputs>, u64);

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

/// Hands the latched set to the viewer's thread when a viewer subscribes.
struct Listener {
    latch: Arc<Latch>,
    handoff: Arc<Handoff<Offered>>,
}

impl ServerListener for Listener {
    fn on_subscribe(&self, _client: Client, _channel: ChannelView) {
        if let Some(offered) = self.latch.get() {
            self.handoff.offer(offered);
        }
    }
}

/// A running live view. Dropping it stops the servers and the thread.
pub struct Viewer {
    config: ViewerConfig,
    /// The SDK's context of the channels and the server (they hold it weakly: kept here).
    _context: Arc<Context>,
    channels: Arc<OutputChannels>,
    latch: Arc<Latch>,
    handoff: Arc<Handoff<Offered>>,
    thread: Option<JoinHandle<()>>,
    server: Option<WebSocketServerHandle>,
    page: Option<PageServer>,
}

fn wall_time_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

impl Viewer {
    /// Starts the WebSocket server on `config.port` with a channel per output of `topics`, and
    /// the page on the next port. Must not be called from inside a tokio runtime (the server
    /// runs its own).
    pub fn start(config: &ViewerConfig, topics: &OutputTopics) -> Result<Self, ViewerError> {
        let context = Context::new();
        let channels = Arc::new(OutputChannels::new(&context, topics)?);
        let latch = Arc::new(Latch::default());
        let handoff = Arc::new(Handoff::new());
        let listener = Arc::new(Listener {
            latch: Arc::clone(&latch),
            handoff: Arc::clone(&handoff),
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
            config: config.clone(),
            _context: context,
            channels,
            latch,
            handoff,
            thread: Some(thread),
            server: Some(server),
            page: Some(page),
        })
    }

    /// Whether a viewer subscribed to the point cloud or anything else (then the engine should
    /// make the point cloud even when it is not published over DDS).
    pub fn wants_points(&self) -> bool {
        self.channels.has_subscribers()
    }

    /// Offers one set's outputs (the live node, which publishes them over DDS after): copied
    /// for the viewer's thread only while a viewer is subscribed; a set the thread has not
    /// taken yet is replaced. Never waits.
    pub fn offer(&self, out: &FrameOutputs) {
        if self.channels.has_subscribers() {
            let offered = (Arc::new(out.clone()), wall_time_ns());
            self.latch.set(offered.clone());
            self.handoff.offer(offered);
        }
    }

    /// Offers one set's outputs that the caller no longer needs (`bag`): kept as the latched
    /// set for viewers that subscribe later, handed to the viewer's thread while one is
    /// subscribed. Never waits.
    pub fn offer_owned(&self, out: FrameOutputs) {
        let offered = (Arc::new(out), wall_time_ns());
        self.latch.set(offered.clone());
        if self.channels.has_subscribers() {
            self.handoff.offer(offered);
        }
    }

    /// Sets replaced before the viewer's thread took them.
    pub fn replaced(&self) -> u64 {
        self.handoff.dropped()
    }

    /// The connection string for Foxglove and Lichtblick.
    pub fn websocket_url(&self) -> String {
        self.config.websocket_url()
    }

    /// The built-in page's address.
    pub fn page_url(&self) -> String {
        match self.config.page_port() {
            Ok(port) => format!("http://{}:{port}/", self.config.address),
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

impl Drop for Viewer {
    fn drop(&mut self) {
        self.handoff.close();
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
        self.channels.close();
        self.page.take();
        if let Some(server) = self.server.take() {
            server.stop().wait_blocking();
        }
    }
}
