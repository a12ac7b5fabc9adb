//! The depth node's subscriptions: per camera its image (raw, or `<image>/compressed` with
//! `image_transport: compressed`) and camera_info; `/tf_static` unless a rig file places the
//! cameras (and for a moving rig's static links), `/tf` for a moving rig; their messages as one
//! stream of [`Event`]s; and what each subscription requests, for "why no depth".

use ros2_client::qos::{History, WhenFull};
use ros2_client::{Node, QosProfile, Subscription};

use super::events::{Event, EventStream};
use super::topics::{self, subscribe, tagged, CAMERA_INFO, COMPRESSED_IMAGE, IMAGE, TF_MESSAGE};
use super::why::Requested;
use super::{NodeConfig, NodeError};
use crate::msgs::{CameraInfo, CompressedImage, Image, TFMessage};

/// The node's subscriptions, alive as long as the event loop.
pub(super) struct Inputs {
    images: Vec<Subscription<Image>>,
    compressed: Vec<Subscription<CompressedImage>>,
    infos: Vec<Subscription<CameraInfo>>,
    tf_static: Option<Subscription<TFMessage>>,
    tf: Option<Subscription<TFMessage>>,
}

impl Inputs {
    /// Subscribes to every input of `config` on `node`.
    pub(super) fn subscribe(node: &mut Node, config: &NodeConfig) -> Result<Self, NodeError> {
        let pipeline = &config.pipeline;
        let image_qos = {
            let q = QosProfile::subscription_default().history(History::KeepLast {
                depth: config.input_depth,
            });
            if config.input_reliable {
                q.reliability_reliable(WhenFull::DEFAULT)
            } else {
                q.reliability_best_effort()
            }
        };
        let info_qos = QosProfile::subscription_default().history(History::KeepLast { depth: 1 });
        let mut inputs = Inputs {
            images: Vec::new(),
            compressed: Vec::new(),
            infos: Vec::new(),
            tf_static: None,
            tf: None,
        };
        for (i, compressed_topic) in pipeline.compressed_topics().iter().enumerate() {
            if pipeline.compressed_inputs {
                inputs.compressed.push(subscribe(
                    node,
                    compressed_topic,
                    COMPRESSED_IMAGE,
                    &image_qos,
                )?);
            } else {
                let topic = &pipeline.image_topics[i];
                inputs
                    .images
                    .push(subscribe(node, topic, IMAGE, &image_qos)?);
            }
            inputs.infos.push(subscribe(
                node,
                &pipeline.info_topics[i],
                CAMERA_INFO,
                &info_qos,
            )?);
        }
        if pipeline.rig_file.is_none() || pipeline.world.is_some() {
            inputs.tf_static = Some(subscribe(
                node,
                &pipeline.tf_static_topic,
                TF_MESSAGE,
                &topics::tf_static_qos(),
            )?);
        }
        if let Some(world) = &pipeline.world {
            inputs.tf = Some(subscribe(
                node,
                &world.tf_topic,
                TF_MESSAGE,
                &topics::tf_qos(),
            )?);
        }
        Ok(inputs)
    }

    /// Every subscription's messages as one stream of events (compressed images carried
    /// compressed into the pipeline, decoded when their set is complete).
    pub(super) fn events(&self) -> impl futures::Stream<Item = Event> + '_ {
        let mut streams: Vec<EventStream<'_>> = Vec::new();
        for (i, sub) in self.images.iter().enumerate() {
            streams.push(tagged(sub, move |r| Event::Image(i, r)));
        }
        for (i, sub) in self.compressed.iter().enumerate() {
            streams.push(tagged(sub, move |r| Event::Compressed(i, r)));
        }
        for (i, sub) in self.infos.iter().enumerate() {
            streams.push(tagged(sub, move |r| Event::Info(i, r.map(Box::new))));
        }
        if let Some(sub) = &self.tf_static {
            streams.push(tagged(sub, Event::Tf));
        }
        if let Some(sub) = &self.tf {
            streams.push(tagged(sub, Event::TfDynamic));
        }
        futures::stream::select_all(streams)
    }

    /// What each subscription requests (topic and QoS), for the "why no depth" check of DDS
    /// discovery's publishers.
    pub(super) fn requested(&self, config: &NodeConfig) -> Vec<Requested> {
        let pipeline = &config.pipeline;
        let mut requested = Vec::new();
        for i in 0..pipeline.cameras.len() {
            requested.push(Requested {
                topic: pipeline.input_image_topic(i),
                reliable: config.input_reliable,
                transient_local: false,
                hint: "a best-effort camera driver needs input_qos_reliable:=false",
            });
            requested.push(Requested {
                topic: pipeline.info_topics[i].clone(),
                reliable: false,
                transient_local: false,
                hint: "",
            });
        }
        if self.tf_static.is_some() {
            requested.push(Requested {
                topic: pipeline.tf_static_topic.clone(),
                reliable: true,
                transient_local: true,
                hint: "read as tf2 reads it: publish it with a static transform broadcaster",
            });
        }
        if let Some(world) = &pipeline.world {
            requested.push(Requested {
                topic: world.tf_topic.clone(),
                reliable: true,
                transient_local: false,
                hint: "read as tf2_ros's listener reads it",
            });
        }
        requested
    }
}
