//! The Foxglove channels of one node's outputs: one per output topic, ROS 2 CDR with the
//! type's full `ros2msg` definition as its schema (as foxglove_bridge advertises them), so that
//! Foxglove and Lichtblick decode them in their image and 3D panels.

use std::sync::Arc;

use foxglove::{ChannelBuilder, Context, PartialMetadata, RawChannel, Schema};
use serde::Serialize;

use super::ViewerError;
use crate::msgdefs;
use crate::msgs::to_cdr;
use crate::pipeline::{FrameMessages, Output, OutputTopics, Wanted, OUTPUTS};

/// The message encoding of every channel (the ROS 2 wire format).
pub const MESSAGE_ENCODING: &str = "cdr";
/// The schema encoding of every channel (a `.msg` definition with its dependencies).
pub const SCHEMA_ENCODING: &str = "ros2msg";

/// The topic of the point cloud on the viewer: `points` beside `depth/image` when the node does
/// not publish it over DDS (the viewer always shows it).
pub fn points_topic(topics: &OutputTopics) -> String {
    match topics.get(Output::Points) {
        Some(points) => points.to_string(),
        None => {
            let base = topics
                .depth()
                .strip_suffix(Output::Depth.spec().name)
                .unwrap_or("/");
            format!("{base}{}", Output::Points.spec().name)
        }
    }
}

/// One channel per output of the list (`pipeline::OUTPUTS`), the point cloud always.
pub(super) struct OutputChannels {
    channels: Vec<(Output, Arc<RawChannel>)>,
}

pub(super) fn channel(
    context: &Arc<Context>,
    topic: &str,
    msg_type: &'static str,
) -> Result<Arc<RawChannel>, ViewerError> {
    let definition = msgdefs::definition(msg_type).ok_or_else(|| ViewerError::Channel {
        topic: topic.to_string(),
        reason: format!("no message definition for {msg_type}"),
    })?;
    ChannelBuilder::new(topic)
        .message_encoding(MESSAGE_ENCODING)
        .schema(Schema::new(
            msg_type,
            SCHEMA_ENCODING,
            definition.as_bytes().to_vec(),
        ))
        .context(context)
        .build_raw()
        .map_err(|e| ViewerError::Channel {
            topic: topic.to_string(),
            reason: e.to_string(),
        })
}

/// Encodes `msg` and logs it, only when a viewer subscribed to the channel (encoding a point
/// cloud nobody reads would be wasted). An encoding failure is returned, not logged here.
fn log<T: Serialize>(channel: &RawChannel, msg: &T, log_time_ns: u64) -> Result<(), ViewerError> {
    if !channel.has_sinks() {
        return Ok(());
    }
    let bytes = to_cdr(msg).map_err(|e| ViewerError::Encode {
        topic: channel.topic().to_string(),
        reason: e.to_string(),
    })?;
    channel.log_with_meta(
        &bytes,
        PartialMetadata {
            log_time: Some(log_time_ns),
        },
    );
    Ok(())
}

impl OutputChannels {
    pub(super) fn new(context: &Arc<Context>, topics: &OutputTopics) -> Result<Self, ViewerError> {
        let mut channels = Vec::with_capacity(OUTPUTS.len());
        for spec in &OUTPUTS {
            let topic = match topics.get(spec.output) {
                Some(topic) => topic.to_string(),
                None if spec.output == Output::Points => points_topic(topics),
                None => continue,
            };
            channels.push((
                spec.output,
                channel(context, &topic, spec.msg_type.schema_name())?,
            ));
        }
        Ok(Self { channels })
    }

    /// Whether any viewer subscribed to any of the channels.
    pub(super) fn has_subscribers(&self) -> bool {
        self.channels.iter().any(|(_, c)| c.has_sinks())
    }

    /// The outputs made on demand that a viewer subscribed to.
    pub(super) fn wanted(&self) -> Wanted {
        let on = |output: Output| {
            self.channels
                .iter()
                .any(|(o, c)| *o == output && c.has_sinks())
        };
        Wanted {
            cost: on(Output::Cost),
            selection: on(Output::Selection),
            points: on(Output::Points),
        }
    }

    /// Logs one set's outputs to the subscribed viewers (`log_time_ns`: wall clock, when the
    /// engine gave them). Each queue is bounded: a viewer that does not keep up loses the
    /// oldest messages, the caller never waits for it.
    pub(super) fn log(&self, out: &FrameMessages, log_time_ns: u64) -> Result<(), ViewerError> {
        for (output, channel) in &self.channels {
            if let Some(msg) = out.get(*output) {
                log(channel, &msg, log_time_ns)?;
            }
        }
        Ok(())
    }

    pub(super) fn close(&self) {
        for (_, channel) in &self.channels {
            channel.close();
        }
    }
}
