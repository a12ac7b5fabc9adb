//! Fusion's mesh from a test's side: the `~/save_mesh` service (`sweepdepth/srv/SaveMesh`) as a
//! ros2-client client, and the vertices of the binary PLY it writes.

use std::time::{Duration, Instant};

use glam::DVec3;
use ros2_client::{Name, ServiceMapping, ServiceTypeName};

use super::dds::{self, NodeProcess, Peer};

/// `sweepdepth/srv/SaveMesh` (msg/srv/SaveMesh.srv) request.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct SaveMeshRequest {
    pub file_path: String,
}
impl ros2_client::Message for SaveMeshRequest {}

/// `sweepdepth/srv/SaveMesh` response.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct SaveMeshResponse {
    pub success: bool,
    pub message: String,
}
impl ros2_client::Message for SaveMeshResponse {}

/// A client of one node's `~/save_mesh`.
pub struct SaveMesh {
    service: String,
    client: ros2_client::Client<SaveMeshRequest, SaveMeshResponse>,
}

impl SaveMesh {
    /// A client of `service` (fully qualified) on `peer`.
    pub fn new(peer: &mut Peer, service: &str) -> SaveMesh {
        let qos = dds::reliable(1);
        let client = peer
            .node
            .create_client(
                ServiceMapping::Enhanced,
                &Name::parse(service).expect("service name"),
                &ServiceTypeName::new("sweepdepth", "SaveMesh"),
                qos.clone(),
                qos,
            )
            .expect("save_mesh client");
        SaveMesh {
            service: service.to_string(),
            client,
        }
    }

    /// Asks for the mesh at `path`; the request is idempotent, so it is sent again every 5 s
    /// until an answer comes (a response can be lost while the server's writer has not matched
    /// this client's reader), within the one limit.
    pub fn call(&self, path: &str, node: &mut NodeProcess) -> SaveMeshResponse {
        let mut ids = Vec::new();
        let mut sent = Instant::now() - Duration::from_secs(5);
        dds::wait_for(format!("an answer from {}", self.service), node, || {
            if sent.elapsed() >= Duration::from_secs(5) {
                let request = SaveMeshRequest {
                    file_path: path.to_string(),
                };
                ids.push(self.client.send_request(request).expect("send the request"));
                sent = Instant::now();
            }
            match self.client.receive_response() {
                Ok(Some((rid, response))) if ids.contains(&rid) => Some(response),
                _ => None,
            }
        })
    }
}

/// The vertex element of a binary little-endian PLY written by `sweepdepth::fusion::write_ply`:
/// where the vertices start, how many there are, the size of one, and each property's name and
/// byte offset in it (read from the header).
fn ply_vertex_layout(ply: &[u8]) -> (usize, usize, usize, Vec<(String, usize)>) {
    let end = ply
        .windows(11)
        .position(|w| w == b"end_header\n")
        .expect("a PLY header")
        + 11;
    let header = String::from_utf8_lossy(&ply[..end]);
    assert!(header.contains("binary_little_endian"), "{header}");
    let (mut count, mut size, mut in_vertex) = (0usize, 0usize, false);
    let mut offsets = Vec::new();
    for line in header.lines() {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["element", "vertex", n] => {
                count = n.parse().expect("vertex count");
                in_vertex = true;
            }
            ["element", ..] => in_vertex = false,
            ["property", kind, name] if in_vertex => {
                offsets.push((name.to_string(), size));
                size += match *kind {
                    "float" | "int" | "uint" => 4,
                    "uchar" | "char" => 1,
                    "double" => 8,
                    "short" | "ushort" => 2,
                    other => panic!("PLY property type {other}"),
                }
            }
            _ => {}
        }
    }
    (end, count, size, offsets)
}

/// The vertices of a binary little-endian PLY written by `sweepdepth::fusion::write_ply` (x, y,
/// z as float first in each vertex; the vertex size read from the header's properties).
pub fn ply_vertices(ply: &[u8]) -> Vec<DVec3> {
    let (end, count, size, _) = ply_vertex_layout(ply);
    (0..count)
        .map(|i| {
            let at = end + i * size;
            let f = |k: usize| {
                let b = &ply[at + 4 * k..at + 4 * k + 4];
                f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            };
            DVec3::new(f(0), f(1), f(2))
        })
        .collect()
}

/// The vertex colours (red, green, blue as uchar properties) of such a PLY.
pub fn ply_colours(ply: &[u8]) -> Vec<[u8; 3]> {
    let (end, count, size, offsets) = ply_vertex_layout(ply);
    let offset = |name: &str| {
        offsets
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, o)| *o)
            .unwrap_or_else(|| panic!("no vertex property {name}"))
    };
    let (r, g, b) = (offset("red"), offset("green"), offset("blue"));
    (0..count)
        .map(|i| {
            let at = end + i * size;
            [ply[at + r], ply[at + g], ply[at + b]]
        })
        .collect()
}
