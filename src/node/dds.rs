//! The node on DDS: the context and the node (with its parameter services), its subscriptions
//! (`inputs.rs`) and output publishers (`topics.rs`), then the event loop (on a `futures`
//! executor that also drives the ros2-client spinner) beside the diagnostics thread until
//! SIGINT/SIGTERM. The diagnostics thread publishes `/diagnostics` from the statistics
//! (`diag.rs`), why no depth comes out (`why.rs`) and fusion's lines (`fusion_services.rs`).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::{Duration, Instant};

use futures::StreamExt;
use ros2_client::qos::{History, WhenFull};
use ros2_client::{Context, ContextOptions, NodeName, Publisher, QosProfile};

use super::clock;
use super::demand::Demand;
use super::events::LoopState;
use super::fusion_services::{diagnostic_values, FusionNode};
use super::inputs::Inputs;
use super::log::{lock, log_info, RateLimited, ROSOUT};
use super::param_services::{Answers, ParamServices};
use super::params::node_options;
use super::shutdown;
use super::sim_time;
use super::topics::{diagnostics_publisher, output_publishers, ros_err};
use super::why::{Discovery, NoDepth};
use super::worker::Outputs;
use super::{NodeConfig, NodeError, Shared};
use crate::msgs::DiagnosticArray;
use crate::pipeline::{ConfigError, FusionHost, Pipeline};

/// The spinner's future, kept until the node is dropped: the node's `Drop` tells the spinner to
/// stop, which fails (with an ERROR line) once the spinner is gone.
pub(super) type SpinFuture =
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
    let param_services = ParamServices::new(
        &mut node,
        &pipeline.identity.fqn(),
        Answers::new(Arc::clone(shared.live)),
    )?;
    let logger_name = pipeline
        .identity
        .fqn()
        .trim_start_matches('/')
        .replace('/', ".");
    *lock(&ROSOUT) = Some((node.logging_handle(), logger_name));

    let inputs = Inputs::subscribe(&mut node, config)?;
    // One set of publishers per reference (`references`), in the configuration's order.
    let output_qos = QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .history(History::KeepLast {
            depth: config.output_depth,
        });
    let mut reference_publishers = Vec::with_capacity(pipeline.references.len());
    for (_, outputs) in &pipeline.references {
        reference_publishers.push(output_publishers(&mut node, outputs, &output_qos)?);
    }
    let diag_pub = diagnostics_publisher(&mut node, &config.diagnostics_topic)?;
    // Live fusion (`fusion`): its thread, `mesh` publisher and services; dropped (the thread
    // joined) before the node.
    let fusion = match &pipeline.fusion {
        Some(fusion_config) => Some(FusionNode::new(
            &mut node,
            &pipeline.identity.fqn(),
            fusion_config,
            FusionHost::Engine(shared.engine_gpu),
            &pipeline.mesh_topic,
            shared.viewer.cloned(),
        )?),
        None => None,
    };
    let fuser_thread = fusion.as_ref().map(FusionNode::worker);
    let published = reference_publishers.iter().flat_map(|p| &p.outputs);
    let demand = Arc::new(Demand::new(
        published.map(|(output, topic, _)| (*output, topic.as_str())),
    ));
    publishers_tx
        .send(Outputs {
            references: reference_publishers,
            fusion: fuser_thread.clone(),
            fusion_follows_engine: fusion.as_ref().is_some_and(FusionNode::on_engine_device),
            world_frame: pipeline.world.as_ref().map(|w| w.frame.clone()),
            demand: Arc::clone(&demand),
        })
        .map_err(|_| NodeError::Gpu("the GPU thread has ended".into()))?;

    let mut events = inputs.events();
    let spinner = node.spinner().map_err(ros_err)?;
    spin = Box::pin(spinner.spin());
    // SIGINT / SIGTERM (Ctrl-C, `ros2 launch` shutting down): leave the loop, so that the
    // publishers, subscriptions and the DDS participant are dropped cleanly. Installed before
    // the node says it is up, so a signal sent as soon as it is up is never the default action.
    let signals = shutdown::signals();
    log_info(&format!("node {} is up", pipeline.identity.fqn()));

    let started = Instant::now();
    let pipeline_state = Mutex::new(Pipeline::new(pipeline).map_err(ConfigError::from)?);
    // While no depth comes out, the diagnostics thread says why (the pipeline's view and DDS
    // discovery's of the input topics, with the QoS each subscription requests).
    let requested = inputs.requested(config);
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
        // The parameter services, and `/clock` while `use_sim_time` is on.
        let params = sim_time::serve_parameters(&param_services, &mut node, &config.clock_topic);
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
    let participant = context.domain_participant();
    let outcome = shutdown::run_until_signal(
        &mut spin,
        event_loop,
        signals,
        "sweepdepth-diagnostics",
        |stop| {
            publish_loop(
                config,
                shared,
                diag_pub,
                fuser_thread.as_deref(),
                (&demand, &participant),
                &mut no_depth,
                stop,
            )
        },
        // The GPU thread at once (its run cancelled, its pending set abandoned), not after
        // the diagnostics thread's next tick: a set that ends meanwhile must not be followed
        // by another.
        &mut *stop_worker,
    );
    // The `/rosout` writer goes before the node and the participant (the GPU thread is gone).
    stop_worker();
    *lock(&ROSOUT) = None;
    outcome
}

/// Publishes `/diagnostics` once a second until `stop` is set; brings the outputs' demand up
/// to date with discovery every time it wakes (10 times a second).
fn publish_loop(
    config: &NodeConfig,
    shared: &Shared<'_>,
    publisher: Publisher<DiagnosticArray>,
    fusion: Option<&crate::pipeline::FuserThread>,
    (demand, participant): (&Demand, &ros2_client::dds::rustdds::DomainParticipant),
    no_depth: &mut NoDepth<'_>,
    stop: &AtomicBool,
) {
    let fqn = config.pipeline.identity.fqn();
    let mut next = Instant::now() + Duration::from_secs(1);
    let mut log = RateLimited::default();
    while !stop.load(Ordering::Relaxed) {
        if demand.refresh(participant) {
            log_info(&format!(
                "outputs made for their subscribers: {}",
                demand.wanted().describe()
            ));
        }
        let now = Instant::now();
        if now < next {
            std::thread::sleep((next - now).min(Duration::from_millis(100)));
            continue;
        }
        next += Duration::from_secs(1);
        if next < now {
            next = now + Duration::from_secs(1);
        }
        no_depth.check(shared.stats, now);
        let mut msg = {
            let mut stats = lock(shared.stats);
            stats.gpu_dropped = shared.slot.dropped();
            stats.diagnostics(
                &fqn,
                &config.pipeline.cameras,
                shared.adapter,
                now,
                clock::now(),
            )
        };
        if let (Some(fusion), Some(status)) = (fusion, msg.status.first_mut()) {
            status.values.extend(diagnostic_values(&fusion.stats()));
        }
        if let Err(e) = publisher.publish(msg) {
            log.warn("diagnostics", || {
                format!("publishing /diagnostics failed: {e:?}")
            });
        }
    }
}
