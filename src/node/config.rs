//! What the node needs from its command line and environment ([`NodeConfig`]): the
//! pipeline's configuration and the DDS side's own (domain, QoS, `/diagnostics`).

use crate::params::ParamError;
use crate::pipeline::{ConfigError, HostError, PipelineConfig};
use crate::ros::args::{domain_id, parse_ros_args, RosArgsError};

/// Errors that stop the node (at start-up).
#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    Args(#[from] RosArgsError),
    #[error(transparent)]
    Param(#[from] ParamError),
    #[error("parameter '{name}': {value} does not fit a usize")]
    Size { name: &'static str, value: i64 },
    #[error("invalid ROS name '{name}': {reason}")]
    Name { name: String, reason: String },
    /// What ros2-client (RustDDS) said, as it says it.
    #[error("ROS 2 (ros2-client): {0}")]
    Ros(String),
    #[error("GPU: {0}")]
    Engine(#[from] HostError),
    /// The live view (`foxglove_port`) could not start.
    #[error("live view: {0}")]
    Viewer(#[from] crate::viewer::ViewerError),
    /// The GPU thread could not start or ended early.
    #[error("GPU: {0}")]
    Gpu(String),
}

/// The pipeline's configuration, and the node's.
#[derive(Debug, Clone)]
pub struct NodeConfig {
    pub pipeline: PipelineConfig,
    pub domain_id: u16,
    pub diagnostics_topic: String,
    /// `/clock` after the remaps (`use_sim_time`).
    pub clock_topic: String,
    pub input_reliable: bool,
    pub input_depth: usize,
    pub output_depth: usize,
}

impl NodeConfig {
    /// From the arguments after `node` and the value of `ROS_DOMAIN_ID`.
    pub fn from_args(args: &[String], domain_env: Option<&str>) -> Result<Self, NodeError> {
        let ros = parse_ros_args(args)?;
        if !ros.other.is_empty() {
            return Err(ConfigError::ExtraArgs(ros.other.clone()).into());
        }
        let pipeline = PipelineConfig::from_ros_args(&ros)?;
        let diagnostics_topic = ros.resolve_topic("/diagnostics", &pipeline.identity)?;
        let clock_topic = ros.resolve_topic("/clock", &pipeline.identity)?;
        let node = &pipeline.node;
        let usize_param = |name: &'static str, value: i64| -> Result<usize, NodeError> {
            usize::try_from(value).map_err(|_| NodeError::Size { name, value })
        };
        Ok(Self {
            domain_id: domain_id(domain_env)?,
            diagnostics_topic,
            clock_topic,
            input_reliable: node.input_qos_reliable,
            input_depth: usize_param("input_qos_depth", node.input_qos_depth)?,
            output_depth: usize_param("output_qos_depth", node.output_qos_depth)?,
            pipeline,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn node_config_from_args() {
        let cfg = NodeConfig::from_args(
            &args(&[
                "--ros-args",
                "-r",
                "__ns:=/rig",
                "-p",
                "cameras:=[a, b, c]",
                "-p",
                "input_qos_depth:=7",
                "-r",
                "/clock:=/sim/clock",
            ]),
            Some("7"),
        )
        .unwrap();
        assert_eq!(cfg.domain_id, 7);
        assert_eq!(cfg.diagnostics_topic, "/diagnostics");
        assert_eq!(
            cfg.clock_topic, "/sim/clock",
            "remapped as rclcpp's TimeSource reads it"
        );
        assert_eq!(cfg.pipeline.outputs().depth(), "/rig/depth/image");
        assert_eq!(
            (cfg.input_reliable, cfg.input_depth, cfg.output_depth),
            (false, 7, 1)
        );
    }

    #[test]
    fn node_config_errors() {
        assert!(matches!(
            NodeConfig::from_args(
                &args(&["extra", "--ros-args", "-p", "cameras:=[a, b]"]),
                None
            ),
            Err(NodeError::Config(ConfigError::ExtraArgs(_)))
        ));
        assert!(matches!(
            NodeConfig::from_args(&args(&["--ros-args", "-p", "cameras:=[a, b]"]), Some("999")),
            Err(NodeError::Args(RosArgsError::DomainId { .. }))
        ));
    }
}
