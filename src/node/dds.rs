//! The node on DDS: the context and the node (with its parameter services), a subscription
//! per camera image and camera_info and for `/tf_static`, the output publishers, then the
//! event loop (on a `futures` executor that also drives the ros2-client spinner) beside the
//! diagnostics thread until SIGINT/SIGTERM.

use std::sync::{mpsc, Arc, Mutex};
use std::time::Instant;

use futures::StreamExt;
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{Context, ContextOptions, MessageTypeName, Name, NodeName, QosProfile};

use super::events::{Event, EventStream, LoopState};
use super::fusion::FusionNode;
use super::log::{lock, log_info, RateLimited, ROSOUT};
use super::param_services::ParamServices;
use super::params::node_options;
use super::shutdown;
use super::why::{Discovery, NoDepth, Requested};
use super::worker::{OutputPublisher, Outputs, Publishers};
use super::{diag, NodeConfig, NodeError, Shared};
use crate::msgs::{CameraInfo, CompressedImage, DiagnosticArray, Image, TFMessage};
use crate::pipeline::compressed::carry;
use crate::pipeline::{ConfigError, MsgType, Pipeline};

/// A ros2-client error, as it says it.
fn ros_err(e: impl std::fmt::Debug) -> NodeError {
    NodeError::Ros(format!("{e:?}"))
}

fn topic_name(name: &str) -> Result<Name, NodeError> {
    Name::parse(name).map_err(|e| NodeError::Name {
        name: name.to_string(),
        reason: format!("{e:?}"),
    })
}

/// The spinner's future, kept until the node is dropped: the node's `Drop` tells the spinner to
/// stop, which fails (with an ERROR line) once the spinner is gone.
type SpinFuture =
    std::pin::Pin<Box<dyn std::future::Future<Output = ros2_client::CreateResult<()>>>>;

/// Brings the node up on DDS and runs it until a signal (or an error) ends it. `stop_worker`
/// stops the GPU thread (cancelling its run) and waits for it: it is called before any DDS
/// entity is dropped, so that the output publishers the thread owns go before the node and
/// the participant.
pub(super) fn run(
    config: &NodeConfig,
    shared: &Shared<'_>,
    publishers_tx: mpsc::Sender<Outputs>,
    stop_worker: &mut dyn FnMut(),
) -> Result<(), NodeError> {
    let pipeline = &config.pipeline;
    let context = Context::with_options(ContextOptions::new().domain_id(config.domain_id))
        .map_err(ros_err)?;
    // Declared before the node, so dropped after it (locals drop in reverse order).
    let mut spin: SpinFuture;
    let node_name =
        NodeName::new(&pipeline.identity.namespace, &pipeline.identity.name).map_err(|e| {
            NodeError::Name {
                name: pipeline.identity.fqn(),
                reason: format!("{e:?}"),
            }
        })?;
    let mut node = context
        .new_node(node_name, node_options())
        .map_err(ros_err)?;
    let param_services =
        ParamServices::new(&mut node, &pipeline.identity.fqn(), Arc::clone(shared.live))?;
    let logger_name = pipeline
        .identity
        .fqn()
        .trim_start_matches('/')
        .replace('/', ".");
    *lock(&ROSOUT) = Some((node.logging_handle(), logger_name));

    let image_type = || MessageTypeName::new("sensor_msgs", "Image");
    let info_type = || MessageTypeName::new("sensor_msgs", "CameraInfo");
    let input_qos = {
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
    let output_qos = QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .history(History::KeepLast {
            depth: config.output_depth,
        });
    let tf_qos = QosProfile::subscription_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth: 1000 });

    let dynamic_tf_sub = match &pipeline.world {
        Some(world) => {
            let qos = QosProfile::subscription_default()
                .reliability_reliable(WhenFull::DEFAULT)
                .durability(Durability::Volatile)
                .history(History::KeepLast { depth: 100 });
            let topic = node
                .create_topic(
                    &topic_name(&world.tf_topic)?,
                    MessageTypeName::new("tf2_msgs", "TFMessage"),
                    &qos,
                )
                .map_err(ros_err)?;
            Some(
                node.create_subscription::<TFMessage>(&topic, Some(qos))
                    .map_err(ros_err)?,
            )
        }
        None => None,
    };

    let mut image_subs = Vec::new();
    // `image_transport: compressed`: sensor_msgs/CompressedImage on `<image topic>/compressed`.
    let mut compressed_subs = Vec::new();
    let mut info_subs = Vec::new();
    for (i, compressed_topic) in pipeline.compressed_topics().iter().enumerate() {
        if pipeline.compressed_inputs {
            let topic = node
                .create_topic(
                    &topic_name(compressed_topic)?,
                    MessageTypeName::new("sensor_msgs", "CompressedImage"),
                    &input_qos,
                )
                .map_err(ros_err)?;
            compressed_subs.push(
                node.create_subscription::<CompressedImage>(&topic, Some(input_qos.clone()))
                    .map_err(ros_err)?,
            );
        } else {
            let topic = node
                .create_topic(
                    &topic_name(&pipeline.image_topics[i])?,
                    image_type(),
                    &input_qos,
                )
                .map_err(ros_err)?;
            image_subs.push(
                node.create_subscription::<Image>(&topic, Some(input_qos.clone()))
                    .map_err(ros_err)?,
            );
        }
        let topic = node
            .create_topic(
                &topic_name(&pipeline.info_topics[i])?,
                info_type(),
                &info_qos,
            )
            .map_err(ros_err)?;
        info_subs.push(
            node.create_subscription::<CameraInfo>(&topic, Some(info_qos.clone()))
                .map_err(ros_err)?,
        );
    }
    // /tf_static for the rig's extrinsics (without a rig file) and for the static links of a
    // moving rig's chain to world_frame; /tf only for a moving rig (tf2_ros's listener QoS:
    // reliable, volatile, the last 100).
    let tf_sub = if pipeline.rig_file.is_none() || pipeline.world.is_some() {
        let topic = node
            .create_topic(
                &topic_name(&pipeline.tf_static_topic)?,
                MessageTypeName::new("tf2_msgs", "TFMessage"),
                &tf_qos,
            )
            .map_err(ros_err)?;
        Some(
            node.create_subscription::<TFMessage>(&topic, Some(tf_qos.clone()))
                .map_err(ros_err)?,
        )
    } else {
        None
    };

    // One set of publishers per reference (`references`), in the configuration's order, one
    // per published output of the list (`pipeline::OUTPUTS`).
    let mut reference_publishers = Vec::with_capacity(pipeline.references.len());
    for (_, outputs) in &pipeline.references {
        let mut publishers = Publishers {
            outputs: Vec::new(),
        };
        for (spec, name) in outputs.iter() {
            let (package, type_name) = spec.msg_type.ros_name();
            let topic = node
                .create_topic(
                    &topic_name(name)?,
                    MessageTypeName::new(package, type_name),
                    &output_qos,
                )
                .map_err(ros_err)?;
            let qos = Some(output_qos.clone());
            let publisher = match spec.msg_type {
                MsgType::Image => {
                    OutputPublisher::Image(node.create_publisher(&topic, qos).map_err(ros_err)?)
                }
                MsgType::CameraInfo => OutputPublisher::CameraInfo(
                    node.create_publisher(&topic, qos).map_err(ros_err)?,
                ),
                MsgType::PointCloud2 => OutputPublisher::PointCloud2(
                    node.create_publisher(&topic, qos).map_err(ros_err)?,
                ),
            };
            publishers
                .outputs
                .push((spec.output, name.to_string(), publisher));
        }
        reference_publishers.push(publishers);
    }
    let diag_qos = QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .history(History::KeepLast { depth: 10 });
    let diag_topic = node
        .create_topic(
            &topic_name(&config.diagnostics_topic)?,
            MessageTypeName::new("diagnostic_msgs", "DiagnosticArray"),
            &diag_qos,
        )
        .map_err(ros_err)?;
    let diag_pub = node
        .create_publisher::<DiagnosticArray>(&diag_topic, Some(diag_qos.clone()))
        .map_err(ros_err)?;
    // Live fusion (`fusion`): its thread, `mesh` publisher and services; dropped (the thread
    // joined) before the node.
    let fusion = match &pipeline.fusion {
        Some(fusion_config) => Some(FusionNode::new(
            &mut node,
            &pipeline.identity.fqn(),
            fusion_config,
            &pipeline.mesh_topic,
            shared.viewer.cloned(),
        )?),
        None => None,
    };
    let fusion_worker = fusion.as_ref().map(FusionNode::worker);
    publishers_tx
        .send(Outputs {
            references: reference_publishers,
            fusion: fusion_worker.clone(),
            world_frame: pipeline.world.as_ref().map(|w| w.frame.clone()),
        })
        .map_err(|_| NodeError::Gpu("the GPU thread has ended".into()))?;

    let mut streams: Vec<EventStream<'_>> = Vec::new();
    for (i, sub) in image_subs.iter().enumerate() {
        streams.push(Box::pin(sub.async_stream().map(move |r| {
            Event::Image(i, r.map(|(m, _)| m).map_err(|e| format!("{e:?}")))
        })));
    }
    for (i, sub) in compressed_subs.iter().enumerate() {
        // Carried compressed into the pipeline, decoded when its set is complete.
        streams.push(Box::pin(sub.async_stream().map(move |r| {
            Event::Image(i, r.map(|(m, _)| carry(m)).map_err(|e| format!("{e:?}")))
        })));
    }
    for (i, sub) in info_subs.iter().enumerate() {
        streams.push(Box::pin(sub.async_stream().map(move |r| {
            Event::Info(i, r.map(|(m, _)| Box::new(m)).map_err(|e| format!("{e:?}")))
        })));
    }
    if let Some(sub) = &tf_sub {
        streams
            .push(Box::pin(sub.async_stream().map(|r| {
                Event::Tf(r.map(|(m, _)| m).map_err(|e| format!("{e:?}")))
            })));
    }
    if let Some(sub) = &dynamic_tf_sub {
        streams.push(Box::pin(sub.async_stream().map(|r| {
            Event::TfDynamic(r.map(|(m, _)| m).map_err(|e| format!("{e:?}")))
        })));
    }
    let mut events = futures::stream::select_all(streams);
    spin = Box::pin(node.spinner().map_err(ros_err)?.spin());
    // SIGINT / SIGTERM (Ctrl-C, `ros2 launch` shutting down): leave the loop, so that the
    // publishers, subscriptions and the DDS participant are dropped cleanly. Installed before
    // the node says it is up, so a signal sent as soon as it is up is never the default action.
    let signals = shutdown::signals();
    log_info(&format!("node {} is up", pipeline.identity.fqn()));

    let started = Instant::now();
    let pipeline_state = Mutex::new(Pipeline::new(pipeline).map_err(ConfigError::from)?);
    // While no depth comes out, the diagnostics thread says why (the pipeline's view and DDS
    // discovery's of the input topics, with the QoS each subscription requests).
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
    if tf_sub.is_some() {
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
    let mut no_depth = NoDepth::new(
        &pipeline_state,
        started,
        Discovery::new(context.domain_participant(), requested),
    );
    let mut state = LoopState {
        pipeline: &pipeline_state,
        started,
        log: RateLimited::default(),
        slot: shared.slot,
        stats: shared.stats,
    };
    let event_loop = async {
        let events = async {
            while let Some(event) = events.next().await {
                state.handle(event);
            }
        };
        let params = param_services.serve();
        let fusion_services = async {
            match &fusion {
                Some(fusion) => fusion.serve().await,
                None => futures::future::pending().await,
            }
        };
        futures::pin_mut!(events, params, fusion_services);
        let services = futures::future::select(params, fusion_services);
        match futures::future::select(events, services).await {
            futures::future::Either::Left(((), _)) => {
                NodeError::Ros("the subscription streams ended".into())
            }
            futures::future::Either::Right((futures::future::Either::Left((e, _)), _))
            | futures::future::Either::Right((futures::future::Either::Right((e, _)), _)) => e,
        }
    };
    let outcome = shutdown::run_until_signal(
        &mut spin,
        event_loop,
        signals,
        "sweepdepth-diagnostics",
        |stop| {
            diag::publish_loop(
                config,
                shared,
                diag_pub,
                fusion_worker.as_deref(),
                &mut no_depth,
                stop,
            )
        },
    );
    // The GPU thread (its run cancelled, its pending set abandoned) and the `/rosout` writer
    // go before the node and the participant.
    stop_worker();
    *lock(&ROSOUT) = None;
    outcome
}
