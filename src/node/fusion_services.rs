//! Live fusion in the node (`fusion`): the [`FuserThread`] beside the GPU thread, its mesh
//! published as `visualization_msgs/MarkerArray` on `mesh`, and its two services:
//! `~/save_mesh` (`sweepdepth/srv/SaveMesh`: the mesh to a PLY file at the path of the request)
//! and `~/clear_map` (`std_srvs/srv/Trigger`: the map emptied, a `DELETEALL` marker sent).

use std::path::PathBuf;
use std::sync::Arc;

use futures::StreamExt;
use ros2_client::qos::{History, WhenFull};
use ros2_client::service::Server;
use ros2_client::{MessageTypeName, Name, Node, QosProfile, ServiceMapping, ServiceTypeName};
use serde::{Deserialize, Serialize};

use super::log::{log_info, RateLimited};
use super::topics::ros_err;
use super::NodeError;
use crate::msgs::{KeyValue, MarkerArray};
use crate::pipeline::{fusion_gpu, FuserThread, FusionConfig, FusionHost, FusionStats};
use crate::viewer::Viewer;

/// `sweepdepth/srv/SaveMesh` request (`msg/srv/SaveMesh.srv`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SaveMeshRequest {
    pub file_path: String,
}
impl ros2_client::Message for SaveMeshRequest {}

/// `sweepdepth/srv/SaveMesh` response; also `std_srvs/srv/Trigger`'s.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ServiceResult {
    pub success: bool,
    pub message: String,
}
impl ros2_client::Message for ServiceResult {}

/// `std_srvs/srv/Trigger` request: empty (IDL gives an empty structure one dummy byte).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct TriggerRequest {
    pub structure_needs_at_least_one_member: u8,
}
impl ros2_client::Message for TriggerRequest {}

/// The fusion thread with its publisher and services.
pub(super) struct FusionNode {
    worker: Arc<FuserThread>,
    /// It fuses on the engine's device (and follows it to a new one after a loss).
    engine_device: bool,
    save: Server<SaveMeshRequest, ServiceResult>,
    clear: Server<TriggerRequest, ServiceResult>,
}

impl FusionNode {
    /// The `mesh` publisher (reliable, volatile, the last 10 updates), the fusion thread that
    /// publishes on it (on a GPU or the CPU as `fusion_device` decides beside `host`:
    /// [`fusion_gpu`]), and the services under the node's name.
    pub fn new(
        node: &mut Node,
        node_fqn: &str,
        config: &FusionConfig,
        host: FusionHost<'_>,
        mesh_topic: &str,
        viewer: Option<Viewer>,
    ) -> Result<Self, NodeError> {
        let qos = QosProfile::publisher_default()
            .reliability_reliable(WhenFull::DEFAULT)
            .history(History::KeepLast { depth: 10 });
        let topic_name = Name::parse(mesh_topic).map_err(|e| NodeError::Name {
            name: mesh_topic.to_string(),
            reason: format!("{e:?}"),
        })?;
        let topic = node
            .create_topic(
                &topic_name,
                MessageTypeName::new("visualization_msgs", "MarkerArray"),
                &qos,
            )
            .map_err(ros_err)?;
        let publisher = node
            .create_publisher::<MarkerArray>(&topic, Some(qos.clone()))
            .map_err(ros_err)?;
        let placement = fusion_gpu(config.device, host)
            .map_err(|e| NodeError::Gpu(format!("fusion_device gpu: {e}")))?;
        let mut log = RateLimited::default();
        let gpu = placement.gpu.as_ref();
        let worker = FuserThread::spawn(config.params, gpu, config.mesh_rate_hz, move |markers| {
            // The live view keeps its own copy of the mesh (never waits for a client).
            if let Some(viewer) = &viewer {
                viewer.offer_mesh(&markers);
            }
            if let Err(e) = publisher.publish(markers) {
                log.warn("mesh", || format!("publishing the mesh failed: {e:?}"));
            }
        })
        .map_err(|e| NodeError::Ros(format!("fusion: {e}")))?;
        let name = |service: &str| {
            Name::new(node_fqn, service).map_err(|e| NodeError::Name {
                name: format!("{node_fqn}/{service}"),
                reason: format!("{e:?}"),
            })
        };
        let save = node
            .create_server(
                ServiceMapping::Enhanced,
                &name("save_mesh")?,
                &ServiceTypeName::new("sweepdepth", "SaveMesh"),
                qos.clone(),
                qos.clone(),
            )
            .map_err(ros_err)?;
        let clear = node
            .create_server(
                ServiceMapping::Enhanced,
                &name("clear_map")?,
                &ServiceTypeName::new("std_srvs", "Trigger"),
                qos.clone(),
                qos,
            )
            .map_err(ros_err)?;
        log_info(&format!(
            "fusion {}: voxels of {} m, at most {} blocks, the mesh on {mesh_topic} at {} Hz; \
             services {node_fqn}/save_mesh, {node_fqn}/clear_map",
            placement.label(),
            config.params.voxel_size_m,
            config.params.max_blocks,
            config.mesh_rate_hz
        ));
        Ok(Self {
            worker: Arc::new(worker),
            engine_device: placement.engine_device,
            save,
            clear,
        })
    }

    pub fn worker(&self) -> Arc<FuserThread> {
        Arc::clone(&self.worker)
    }

    /// Whether it fuses on the engine's device (`FusionPlacement::engine_device`).
    pub fn on_engine_device(&self) -> bool {
        self.engine_device
    }

    /// Answers requests until a request stream fails.
    pub async fn serve(&self) -> NodeError {
        let mut save = self.save.receive_request_stream();
        let mut clear = self.clear.receive_request_stream();
        loop {
            let sent = futures::select! {
                r = save.select_next_some() => match r {
                    Ok((id, req)) => {
                        let response = self.save_mesh(&req.file_path).await;
                        self.save.async_send_response(id, response).await
                    }
                    Err(e) => return ros_err(e),
                },
                r = clear.select_next_some() => match r {
                    Ok((id, _)) => {
                        let response = match self.worker.clear().await {
                            Ok(blocks) => ServiceResult {
                                success: true,
                                message: format!("cleared the map ({blocks} blocks)"),
                            },
                            Err(_) => stopped(),
                        };
                        log_info(&format!("~/clear_map: {}", response.message));
                        self.clear.async_send_response(id, response).await
                    }
                    Err(e) => return ros_err(e),
                },
            };
            if let Err(e) = sent {
                tracing::warn!("fusion service response: {e:?}");
            }
        }
    }

    async fn save_mesh(&self, file_path: &str) -> ServiceResult {
        if file_path.trim().is_empty() {
            return ServiceResult {
                success: false,
                message: "file_path is empty: give the PLY file's path".into(),
            };
        }
        let path = PathBuf::from(file_path);
        let response = match self.worker.save(path).await {
            Ok(Ok(saved)) => ServiceResult {
                success: true,
                message: format!(
                    "{} triangles, {} vertices to {file_path}",
                    saved.triangles, saved.vertices
                ),
            },
            Ok(Err(e)) => ServiceResult {
                success: false,
                message: format!("cannot write the mesh: {e}"),
            },
            Err(_) => stopped(),
        };
        log_info(&format!("~/save_mesh: {}", response.message));
        response
    }
}

fn stopped() -> ServiceResult {
    ServiceResult {
        success: false,
        message: "the fusion thread has stopped".into(),
    }
}

/// Fusion's lines in `/diagnostics`.
pub fn diagnostic_values(stats: &FusionStats) -> Vec<KeyValue> {
    let kv = |key: &str, value: String| KeyValue {
        key: key.into(),
        value,
    };
    let on = match (stats.on_gpu, &stats.left_gpu) {
        (true, None) => "GPU".to_string(),
        (true, Some(reason)) => format!("GPU (a new device, after leaving one: {reason})"),
        (false, None) => "CPU".to_string(),
        (false, Some(reason)) => format!("CPU (left the GPU: {reason})"),
    };
    let mut values = vec![
        kv("fusion on", on),
        kv("fusion depth maps", stats.integrated.to_string()),
    ];
    for (source, n) in &stats.integrated_by_source {
        values.push(kv(
            &format!("fusion depth maps from {source}"),
            n.to_string(),
        ));
    }
    values.extend([
        kv(
            "fusion sets dropped (fusion behind)",
            stats.dropped_sets.to_string(),
        ),
        kv("fusion blocks", stats.blocks.to_string()),
        kv(
            "fusion memory MiB",
            format!("{:.1}", stats.memory_bytes as f64 / f64::from(1 << 20)),
        ),
        kv("fusion triangles", stats.triangles.to_string()),
        kv(
            "fusion frame",
            stats.frame.clone().unwrap_or_else(|| "(none yet)".into()),
        ),
        kv(
            "fusion last set ms",
            format!("{:.1}", stats.last_integration.as_secs_f64() * 1e3),
        ),
        kv(
            "fusion last mesh ms",
            format!("{:.1}", stats.last_meshing.as_secs_f64() * 1e3),
        ),
    ]);
    for (reason, count) in &stats.skipped {
        values.push(kv(&format!("skipped: {reason}"), count.to_string()));
    }
    values
}

#[cfg(test)]
mod tests {
    use super::*;

    fn on(stats: &FusionStats) -> String {
        let values = diagnostic_values(stats);
        let line = values.iter().find(|kv| kv.key == "fusion on");
        line.map(|kv| kv.value.clone()).expect("a 'fusion on' line")
    }

    /// `/diagnostics` says where the map integrates, why it left its GPU, and that it went
    /// on on a new one.
    #[test]
    fn diagnostics_say_where_fusion_runs_and_why_it_left_the_gpu() {
        let mut stats = FusionStats {
            on_gpu: true,
            ..FusionStats::default()
        };
        assert_eq!(on(&stats), "GPU");
        stats.on_gpu = false;
        assert_eq!(on(&stats), "CPU");
        stats.left_gpu = Some("GPU fusion: reading back: the device is lost".into());
        assert_eq!(
            on(&stats),
            "CPU (left the GPU: GPU fusion: reading back: the device is lost)"
        );
        stats.on_gpu = true;
        assert_eq!(
            on(&stats),
            "GPU (a new device, after leaving one: GPU fusion: reading back: the device is lost)"
        );
    }
}
