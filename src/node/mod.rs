//! The ROS 2 node (`sweepdepth node --ros-args ...`) over `ros2-client` (DDS): everything
//! that needs DDS around the DDS-free [`crate::pipeline`].
//!
//! Data flow: per camera an image and a camera_info subscription (and `/tf_static` unless
//! `rig_file` is set) feed one async loop on a `futures` executor that also drives the
//! ros2-client spinner (`dds`). Each message goes into the pipeline (`events`); each set
//! it makes ready goes to the GPU thread through a one-set hand-over
//! ([`crate::handoff::Handoff`]: the newest set replaces a pending one). The GPU thread
//! (`worker`) owns the [`crate::pipeline::EngineHost`], runs the sweep and publishes `depth/image`,
//! `depth/camera_info`, `confidence/image`, `cost/image`, `selection/image` and, with
//! `publish_points`, `points` (an organised PointCloud2 coloured from the reference image).
//! With `foxglove_port`, the same outputs go to the live view ([`crate::viewer`]) too.
//!
//! A diagnostics thread publishes `/diagnostics` once a second ([`diag`]). Log messages go to
//! stderr and, once DDS is up, to `/rosout` (`log`). Our own parameter services
//! ([`param_services`], as rclcpp's: descriptors with our descriptions, ranges and read_only)
//! serve every parameter of the table ([`params`]); engine parameters can be set at run time
//! (validated, then used from the next frame set on), node parameters are read-only.
//!
//! SIGINT and SIGTERM end the node cleanly and promptly: the event loop stops, the pending set
//! is abandoned, the running one is cancelled at the engine's next pass boundary
//! ([`crate::sweep::CancelFlag`]), the GPU thread ends and drops its publishers, then the node
//! and the DDS participant are dropped (in that order, so nothing logs an error), and the
//! process exits 0.

mod clock;
pub mod config;
mod dds;
mod demand;
pub mod diag;
mod events;
pub mod fuse_command;
mod fusion_services;
mod inputs;
mod log;
pub mod param_services;
pub mod params;
mod sender;
mod shutdown;
mod sim_time;
mod topics;
mod why;
mod worker;

use std::sync::{Arc, Mutex};

pub use config::{NodeConfig, NodeError};

use self::diag::Stats;
use self::log::{lock, ROSOUT};
use self::params::LiveParams;
use crate::handoff::Handoff;
use crate::pipeline::Job;
use crate::sweep::CancelFlag;
use crate::viewer::{Viewer, ViewerConfig};

/// What the executor side (event loop, parameter callbacks, diagnostics) shares with the GPU
/// thread.
struct Shared<'a> {
    slot: &'a Handoff<Job>,
    live: &'a Arc<LiveParams>,
    stats: &'a Mutex<Stats>,
    /// The adapter the engine runs on.
    adapter: &'a str,
    /// The WGSL engine's device (None: the CPU engine), for fusion (`fusion_device`).
    engine_gpu: Option<&'a crate::gpu_context::GpuContext>,
    /// The live view, for fusion's mesh (the GPU thread has its own handle).
    viewer: Option<&'a Viewer>,
}

/// Runs the node with the arguments after `node` until SIGINT/SIGTERM.
pub fn run(args: &[String]) -> Result<(), NodeError> {
    let domain_env = std::env::var("ROS_DOMAIN_ID").ok();
    let config = NodeConfig::from_args(args, domain_env.as_deref())?;
    let pipeline = &config.pipeline;
    if clock::set_use_sim_time(pipeline.params.use_sim_time()) {
        tracing::info!("use_sim_time: the node's time is /clock's");
    }
    for note in &pipeline.notes {
        tracing::info!("{note}");
    }
    tracing::info!(
        "node {} on domain {}: cameras [{}], reference '{}', images {:?}",
        pipeline.identity.fqn(),
        config.domain_id,
        pipeline.cameras.join(", "),
        pipeline.cameras[pipeline.reference()],
        (0..pipeline.cameras.len())
            .map(|i| pipeline.input_image_topic(i))
            .collect::<Vec<_>>()
    );

    // The live view (`foxglove_port`), before the GPU thread, which owns it.
    let viewer = match ViewerConfig::from_values(&pipeline.node)? {
        Some(viewer_config) => {
            // With fusion, the mesh's channel too (`mesh_rate` 0: no mesh updates to show).
            let mesh_topic = pipeline
                .fusion
                .as_ref()
                .filter(|f| f.mesh_rate_hz > 0.0)
                .map(|_| pipeline.mesh_topic.as_str());
            let viewer = Viewer::start_with_mesh(&viewer_config, pipeline.outputs(), mesh_topic)?;
            tracing::info!(
                "live view: Foxglove/Lichtblick at {}, the page at {}",
                viewer.websocket_url(),
                viewer.page_url()
            );
            Some(viewer)
        }
        None => None,
    };
    // The GPU thread starts first so that a missing adapter fails before DDS comes up.
    let slot: Arc<Handoff<Job>> = Arc::new(Handoff::new());
    let live = LiveParams::new(
        pipeline.params.clone(),
        pipeline.sweep.clone(),
        crate::sweep::RigShape::chosen_views(
            pipeline.cameras.len(),
            pipeline.virtual_ref.is_none(),
        ),
    );
    let stats = Arc::new(Mutex::new(Stats::new(pipeline.cameras.len())));
    let cancel = CancelFlag::new();
    let mesh_viewer = viewer.clone();
    let gpu = worker::spawn(
        pipeline.device(),
        cancel.clone(),
        Arc::clone(&slot),
        Arc::clone(&live),
        Arc::clone(&stats),
        viewer,
    )?;
    tracing::info!("engine: {}", gpu.adapter);

    let shared = Shared {
        slot: &slot,
        live: &live,
        stats: &stats,
        adapter: &gpu.adapter,
        engine_gpu: gpu.gpu.as_ref(),
        viewer: mesh_viewer.as_ref(),
    };
    let mut handle = Some(gpu.handle);
    // On shutdown: no more sets, the pending one abandoned, the running one stopped at its
    // next pass boundary.
    let mut stop_worker = || {
        slot.close();
        cancel.cancel();
        if let Some(handle) = handle.take() {
            let _ = handle.join();
        }
    };
    let result = dds::run(&config, &shared, gpu.publishers, &mut stop_worker);
    *lock(&ROSOUT) = None;
    stop_worker();
    result
}
