//! The live view (issue 13): a Foxglove WebSocket server (the official `foxglove` SDK, its
//! WebSocket server only) that serves one set's outputs as ROS 2 CDR with `ros2msg` schemas, as
//! foxglove_bridge does, and a built-in page (three.js, compiled into the binary) on the next
//! port that subscribes to it and draws the point cloud, depth and confidence, and with fusion
//! the mesh (`visualization_msgs/MarkerArray` deltas: [`Viewer::offer_mesh`]).
//!
//! The engine never waits for a viewer: [`Viewer::offer`] copies the outputs into a one-set
//! hand-over (the newest wins) only while a viewer is subscribed; a thread of its own encodes and
//! logs them into the server, whose per-client queues are bounded and drop the oldest message.
//! `node` starts it when `foxglove_port` is not 0; `bag --view` always.

#[cfg(feature = "viewer")]
mod channels;
#[cfg(feature = "viewer")]
mod mesh;
#[cfg(feature = "viewer")]
mod page;
#[cfg(feature = "viewer")]
mod server;

#[cfg(feature = "viewer")]
pub use channels::{points_topic, MESSAGE_ENCODING, SCHEMA_ENCODING};
#[cfg(feature = "viewer")]
pub use server::Viewer;

use crate::params::NodeValues;

/// The port `bag --view` serves on when `foxglove_port` is not set (Foxglove's default).
pub const DEFAULT_PORT: u16 = 8765;

/// Messages kept per viewer before the oldest is dropped (six outputs a set: two sets).
pub const CLIENT_BACKLOG: usize = 12;

/// Wall-clock time, ns since the Unix epoch (the log time of the viewer's messages).
#[cfg(feature = "viewer")]
fn wall_time_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

/// Where the viewer serves.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ViewerConfig {
    /// Address both servers bind (`foxglove_address`).
    pub address: String,
    /// The Foxglove WebSocket server's port (`foxglove_port`); the page is on the next one.
    pub port: u16,
}

impl ViewerConfig {
    /// From the node's parameters: `None` when `foxglove_port` is 0 (off).
    pub fn from_values(node: &NodeValues) -> Result<Option<Self>, ViewerError> {
        let port = node.foxglove_port;
        let address = node.foxglove_address.clone();
        if port == 0 {
            return Ok(None);
        }
        let port = u16::try_from(port).map_err(|_| ViewerError::Port(port))?;
        Ok(Some(Self { address, port }))
    }

    /// The page's port: the one after the WebSocket server's.
    pub fn page_port(&self) -> Result<u16, ViewerError> {
        self.port
            .checked_add(1)
            .ok_or(ViewerError::Port(i64::from(self.port)))
    }

    /// For `bag --view`: `foxglove_port` and `foxglove_address`, with [`DEFAULT_PORT`] when
    /// the port is not set.
    pub fn for_bag(node: &NodeValues) -> Result<Self, ViewerError> {
        match Self::from_values(node)? {
            Some(config) => Ok(config),
            None => Ok(Self {
                address: node.foxglove_address.clone(),
                port: DEFAULT_PORT,
            }),
        }
    }

    /// The address Foxglove and Lichtblick connect to.
    pub fn websocket_url(&self) -> String {
        format!("ws://{}:{}", self.address, self.port)
    }
}

/// Errors starting or feeding the viewer.
#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    #[error(
        "foxglove_port {0}: the page is served on the next port, so the port must be in 1..=65534"
    )]
    Port(i64),
    #[error("foxglove_port is set, but this sweepdepth was built without the `viewer` cargo feature (build with `--features viewer`)")]
    NotBuilt,
    #[error("cannot start the Foxglove WebSocket server on {address}:{port}: {reason}")]
    Server {
        address: String,
        port: u16,
        reason: String,
    },
    #[error("cannot serve the viewer page on {address}:{port}: {reason}")]
    Page {
        address: String,
        port: u16,
        reason: String,
    },
    #[error("viewer channel {topic}: {reason}")]
    Channel { topic: String, reason: String },
    #[error("cannot encode {topic} for the viewer: {reason}")]
    Encode { topic: String, reason: String },
    #[error("cannot start the viewer thread: {0}")]
    Thread(String),
}

/// Without the `viewer` feature: a viewer that cannot start (the node says why when
/// `foxglove_port` is set).
#[cfg(not(feature = "viewer"))]
#[derive(Clone)]
pub struct Viewer;

#[cfg(not(feature = "viewer"))]
impl Viewer {
    pub fn start(
        _config: &ViewerConfig,
        _topics: &crate::pipeline::OutputTopics,
    ) -> Result<Self, ViewerError> {
        Err(ViewerError::NotBuilt)
    }
    pub fn start_with_mesh(
        _config: &ViewerConfig,
        _topics: &crate::pipeline::OutputTopics,
        _mesh_topic: Option<&str>,
    ) -> Result<Self, ViewerError> {
        Err(ViewerError::NotBuilt)
    }
    pub fn offer_mesh(&self, _markers: &crate::msgs::MarkerArray) {}
    pub fn offer_mesh_owned(&self, _markers: crate::msgs::MarkerArray) {}
    pub fn mesh_size(&self) -> (usize, usize) {
        (0, 0)
    }
    pub fn offer(&self, _out: &crate::pipeline::FrameMessages) {}
    pub fn offer_owned(&self, _out: crate::pipeline::FrameMessages) {}
    pub fn wanted(&self) -> crate::pipeline::Wanted {
        crate::pipeline::Wanted::NONE
    }
    pub fn page_url(&self) -> String {
        String::new()
    }
    pub fn websocket_url(&self) -> String {
        String::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn page_port_is_the_next_one() {
        let config = ViewerConfig {
            address: "127.0.0.1".into(),
            port: 9000,
        };
        assert_eq!(config.page_port().unwrap(), 9001);
        assert_eq!(config.websocket_url(), "ws://127.0.0.1:9000");
        let last = ViewerConfig {
            address: "127.0.0.1".into(),
            port: u16::MAX,
        };
        assert!(last.page_port().is_err());
    }
}
