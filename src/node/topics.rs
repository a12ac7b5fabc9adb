//! DDS topics, as both nodes (`sweepdepth node`, `sweepdepth fuse`) make them: names checked
//! as ROS names, the QoS profiles ROS peers expect (tf2's, `/diagnostics`'), a typed
//! subscription or publisher in one call, and the depth node's outputs from the list of
//! outputs (`pipeline::OUTPUTS`).

use std::pin::Pin;

use futures::{Stream, StreamExt};
use ros2_client::dds::rustdds::Topic;
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{MessageTypeName, Name, Node, Publisher, QosProfile, Subscription};
use serde::Serialize;

use super::worker::{OutputPublisher, Publishers};
use super::NodeError;
use crate::msgs::DiagnosticArray;
use crate::pipeline::{MsgType, OutputTopics};

/// A ros2-client error, as it says it.
pub(super) fn ros_err(e: impl std::fmt::Debug) -> NodeError {
    NodeError::Ros(format!("{e:?}"))
}

/// A topic's name as a ROS name.
pub(super) fn topic_name(name: &str) -> Result<Name, NodeError> {
    Name::parse(name).map_err(|e| NodeError::Name {
        name: name.to_string(),
        reason: format!("{e:?}"),
    })
}

/// A message type: its package and name (`sensor_msgs`, `Image`).
pub(super) type TypeName = (&'static str, &'static str);

pub(super) const IMAGE: TypeName = ("sensor_msgs", "Image");
pub(super) const COMPRESSED_IMAGE: TypeName = ("sensor_msgs", "CompressedImage");
pub(super) const CAMERA_INFO: TypeName = ("sensor_msgs", "CameraInfo");
pub(super) const TF_MESSAGE: TypeName = ("tf2_msgs", "TFMessage");

/// The topic `name` of type `type_name` (what a subscription or a publisher is made on).
fn topic(
    node: &mut Node,
    name: &str,
    type_name: TypeName,
    qos: &QosProfile,
) -> Result<Topic, NodeError> {
    node.create_topic(
        &topic_name(name)?,
        MessageTypeName::new(type_name.0, type_name.1),
        qos,
    )
    .map_err(ros_err)
}

/// `/clock`'s type.
const CLOCK: TypeName = ("rosgraph_msgs", "Clock");

/// The node's `/clock` subscription ([`super::clock`]): best effort, keep last 1, as rclcpp's
/// `ClockQoS`.
/// `topic` is `/clock` after the remaps.
pub(super) fn subscribe_clock(
    node: &mut Node,
    topic: &str,
) -> Result<Subscription<crate::msgs::Clock>, NodeError> {
    let qos = QosProfile::subscription_default()
        .reliability_best_effort()
        .history(History::KeepLast { depth: 1 });
    subscribe(node, topic, CLOCK, &qos)
}

/// A subscription of type `type_name` on the topic `name`.
pub(super) fn subscribe<M: 'static>(
    node: &mut Node,
    name: &str,
    type_name: TypeName,
    qos: &QosProfile,
) -> Result<Subscription<M>, NodeError> {
    let topic = topic(node, name, type_name, qos)?;
    node.create_subscription(&topic, Some(qos.clone()))
        .map_err(ros_err)
}

/// A subscription's messages as a stream of events: `tag` of each message, or of what
/// ros2-client said instead (both nodes' event loops select over these).
pub(super) fn tagged<'a, M: serde::de::DeserializeOwned + 'static, E: 'a>(
    sub: &'a Subscription<M>,
    tag: impl Fn(Result<M, String>) -> E + 'a,
) -> Pin<Box<dyn Stream<Item = E> + 'a>> {
    Box::pin(
        sub.async_stream()
            .map(move |r| tag(r.map(|(m, _)| m).map_err(|e| format!("{e:?}")))),
    )
}

/// A publisher of type `type_name` on the topic `name`.
pub(super) fn advertise<M: Serialize>(
    node: &mut Node,
    name: &str,
    type_name: TypeName,
    qos: &QosProfile,
) -> Result<Publisher<M>, NodeError> {
    let topic = topic(node, name, type_name, qos)?;
    node.create_publisher(&topic, Some(qos.clone()))
        .map_err(ros_err)
}

/// `/tf_static` as tf2's static listener reads it: reliable, transient local, the last 1000.
pub(super) fn tf_static_qos() -> QosProfile {
    QosProfile::subscription_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth: 1000 })
}

/// `/tf` as tf2_ros's listener reads it: reliable, volatile, the last 100.
pub(super) fn tf_qos() -> QosProfile {
    QosProfile::subscription_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 100 })
}

/// The `/diagnostics` publisher (reliable, the last 10, as diagnostic_updater's).
pub(super) fn diagnostics_publisher(
    node: &mut Node,
    topic: &str,
) -> Result<Publisher<DiagnosticArray>, NodeError> {
    let qos = QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .history(History::KeepLast { depth: 10 });
    advertise(node, topic, ("diagnostic_msgs", "DiagnosticArray"), &qos)
}

/// One reference's publishers: one per published output of the list, in its order.
pub(super) fn output_publishers(
    node: &mut Node,
    outputs: &OutputTopics,
    qos: &QosProfile,
) -> Result<Publishers, NodeError> {
    let mut publishers = Publishers {
        outputs: Vec::new(),
    };
    for (spec, name) in outputs.iter() {
        let type_name = spec.msg_type.ros_name();
        let publisher = match spec.msg_type {
            MsgType::Image => OutputPublisher::Image(advertise(node, name, type_name, qos)?),
            MsgType::CameraInfo => {
                OutputPublisher::CameraInfo(advertise(node, name, type_name, qos)?)
            }
            MsgType::PointCloud2 => {
                OutputPublisher::PointCloud2(advertise(node, name, type_name, qos)?)
            }
        };
        publishers
            .outputs
            .push((spec.output, name.to_string(), publisher));
    }
    Ok(publishers)
}
