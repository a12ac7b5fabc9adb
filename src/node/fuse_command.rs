//! `sweepdepth fuse --ros-args ...`: fusion alone, as a node. It subscribes to `depth_topics`
//! (REP 118 depth images, each with the `camera_info` beside it), `/tf` and `/tf_static`,
//! places every depth image in `world_frame` at its stamp ([`DepthSources`]) and fuses it on
//! the fusion thread (`node::fusion_services`: the mesh on `mesh` as
//! `visualization_msgs/MarkerArray`, `~/save_mesh`, `~/clear_map`), with `/diagnostics` once a
//! second. It is how a rig that outgrows one machine scales: depth nodes on several hosts, each
//! with its share of the references, one `fuse` node collecting their depth over DDS.
//!
//! Parameters (the one table of the depth node, `docs/node.md`; the others are accepted and
//! unused): `depth_topics`, `color_topics` (each depth image's colour, at its stamp),
//! `world_frame` (required), `tf_timeout`, `voxel_size`,
//! `max_blocks`, `mesh_rate`, `fusion_device` (`auto`: a hardware GPU if wgpu offers one, else
//! the CPU), `min_depth` and `max_depth` (the depths fused). It serves them as an rcl node
//! serves its parameters (`ros2 param list/get/describe`), read-only, and `use_sim_time`, which
//! switches at run time as the depth node's.

use std::sync::atomic::Ordering;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use futures::StreamExt;
use ros2_client::qos::History;
use ros2_client::{Context, ContextOptions, NodeName, QosProfile, Subscription};

use super::clock;
use super::fusion_services::{diagnostic_values, FusionNode};
use super::log::{lock, log_info, RateLimited};
use super::param_services::{Answers, ParamServices};
use super::params::node_options;
use super::shutdown;
use super::sim_time::serve_parameters;
use super::topics::{
    self, diagnostics_publisher, ros_err, subscribe, tagged, CAMERA_INFO, COMPRESSED_IMAGE, IMAGE,
    TF_MESSAGE,
};
use super::NodeError;
use crate::msgs::{
    CameraInfo, CompressedImage, DiagnosticArray, DiagnosticStatus, Header, Image, KeyValue,
    TFMessage,
};
use crate::params::{apply_to_sweep, NodeValues, ParamError, ParamSet};
use crate::pipeline::{
    ColourImage, ConfigError, DepthSources, FusionConfig, FusionHost, FusionStats,
};
use crate::ros::args::{domain_id, parse_ros_args};
use crate::sweep::SweepParams;

/// The fuse node's default name.
pub const DEFAULT_FUSE_NODE_NAME: &str = "sweepdepth_fuse";

/// The parameters the fuse node uses, and serves (read-only; `use_sim_time` beside them).
pub const FUSE_PARAMS: &[&str] = &[
    "depth_topics",
    "color_topics",
    "world_frame",
    "tf_timeout",
    "voxel_size",
    "max_blocks",
    "mesh_rate",
    "fusion_device",
    "min_depth",
    "max_depth",
];

/// What the fuse node reads from its command line.
#[derive(Debug, Clone)]
pub struct FuseConfig {
    pub fqn: String,
    pub namespace: String,
    pub name: String,
    pub domain_id: u16,
    /// Resolved depth image topics and their camera_info topics.
    pub depth_topics: Vec<String>,
    pub info_topics: Vec<String>,
    /// Resolved colour image topics, one per depth topic, or none.
    pub color_topics: Vec<String>,
    pub world_frame: String,
    pub tf_timeout: Duration,
    pub tf_topic: String,
    pub tf_static_topic: String,
    pub diagnostics_topic: String,
    pub mesh_topic: String,
    pub fusion: FusionConfig,
    /// `use_sim_time`: the node's own stamps from `/clock`.
    pub use_sim_time: bool,
    /// `/clock` after the remaps.
    pub clock_topic: String,
    /// The parameter values at start, served read-only ([`FUSE_PARAMS`]).
    pub params: ParamSet,
}

impl FuseConfig {
    /// From the arguments after `fuse` and the value of `ROS_DOMAIN_ID`.
    pub fn from_args(args: &[String], domain_env: Option<&str>) -> Result<Self, NodeError> {
        let ros = parse_ros_args(args)?;
        if !ros.other.is_empty() {
            return Err(ConfigError::ExtraArgs(ros.other.clone()).into());
        }
        let identity = ros.node_identity(DEFAULT_FUSE_NODE_NAME, "/")?;
        let (params, notes) = ParamSet::from_ros_args(&ros, &identity)?;
        for note in notes.iter().chain(ros.notes.iter()) {
            tracing::info!("{note}");
        }
        let node = NodeValues::read(&params)?;
        let resolve = |name: &str| ros.resolve_topic(name, &identity);
        let listed = &node.depth_topics;
        if listed.is_empty() {
            let error = ParamError::Required {
                name: "depth_topics".into(),
                source: Box::new(ParamError::TooFewEntries { min_len: 1, got: 0 }),
            };
            let example = "depth_topics:=[/a/cam0/depth/image, ...] -p world_frame:=map";
            return Err(
                match crate::params::set::unmatched_params_hint(&ros, &identity.fqn(), example) {
                    Some(hint) => ConfigError::Unconfigured {
                        error: error.to_string(),
                        hint,
                    }
                    .into(),
                    None => NodeError::Param(error),
                },
            );
        }
        let mut depth_topics = Vec::new();
        let mut info_topics = Vec::new();
        for topic in listed {
            let resolved = resolve(topic)?;
            // image_transport's rule: the camera_info beside the image.
            let info = match resolved.rsplit_once('/') {
                Some((ns, _)) if !ns.is_empty() => format!("{ns}/camera_info"),
                _ => "/camera_info".to_string(),
            };
            depth_topics.push(resolved);
            info_topics.push(info);
        }
        let color_topics = node
            .color_topics
            .iter()
            .map(|topic| resolve(topic))
            .collect::<Result<Vec<_>, _>>()?;
        if !color_topics.is_empty() && color_topics.len() != depth_topics.len() {
            return Err(NodeError::Name {
                name: "color_topics".into(),
                reason: format!(
                    "{} colour topics for {} depth topics: one per entry of depth_topics, in its order, or none",
                    color_topics.len(),
                    depth_topics.len()
                ),
            });
        }
        let world_frame = node.world_frame.clone();
        if world_frame.is_empty() {
            return Err(NodeError::Name {
                name: "world_frame".into(),
                reason: "the fuse node needs world_frame: the fixed frame every depth image is placed in (e.g. map, odom)".into(),
            });
        }
        // The depths fused: the engine parameters' `min_depth` and `max_depth`.
        let mut sweep = SweepParams::default();
        apply_to_sweep(&params, &mut sweep)?;
        let fusion = FusionConfig::new(&node, sweep.min_depth_m, sweep.max_depth_m)
            .map_err(ConfigError::from)?;
        Ok(Self {
            fqn: identity.fqn(),
            namespace: identity.namespace.clone(),
            name: identity.name.clone(),
            domain_id: domain_id(domain_env)?,
            depth_topics,
            info_topics,
            color_topics,
            world_frame,
            tf_timeout: Duration::from_secs_f64(node.tf_timeout_s),
            tf_topic: resolve("/tf")?,
            tf_static_topic: resolve("/tf_static")?,
            diagnostics_topic: resolve("/diagnostics")?,
            mesh_topic: resolve("mesh")?,
            use_sim_time: params.use_sim_time(),
            clock_topic: resolve("/clock")?,
            fusion,
            params,
        })
    }
}

/// One subscription event of the fuse node.
enum FuseEvent {
    Depth(usize, Result<Image, String>),
    Info(usize, Result<Box<CameraInfo>, String>),
    Colour(usize, Result<ColourImage, String>),
    Tf(Result<TfMessageIn, String>),
}

struct TfMessageIn {
    msg: TFMessage,
    is_static: bool,
}

/// The fuse node's `/diagnostics`: fusion's counts, the depth images waiting for /tf (and for
/// colour) and the skips by reason; WARN until a depth map was fused.
fn fuse_diagnostics(stats: &FusionStats, sources: &DepthSources, fqn: &str) -> DiagnosticArray {
    let mut values = diagnostic_values(stats);
    values.push(KeyValue {
        key: "depth images waiting for /tf".into(),
        value: sources.waiting().to_string(),
    });
    if sources.has_colour() {
        values.push(KeyValue {
            key: "depth images waiting for colour".into(),
            value: sources.awaiting_colour().to_string(),
        });
    }
    for (reason, count) in &sources.skipped {
        values.push(KeyValue {
            key: format!("skipped: {reason}"),
            value: count.to_string(),
        });
    }
    for (reason, count) in &sources.uncoloured {
        values.push(KeyValue {
            key: format!("fused without colour: {reason}"),
            value: count.to_string(),
        });
    }
    let level = if stats.integrated > 0 {
        DiagnosticStatus::OK
    } else {
        DiagnosticStatus::WARN
    };
    let message = if stats.integrated > 0 {
        format!("{} depth maps fused", stats.integrated)
    } else {
        "no depth fused yet".into()
    };
    DiagnosticArray {
        header: Header {
            stamp: clock::now(),
            frame_id: String::new(),
        },
        status: vec![DiagnosticStatus {
            level,
            name: format!("sweepdepth fuse: {fqn}"),
            message,
            hardware_id: String::new(),
            values,
        }],
    }
}

/// One subscription event into the depth sources: the depth maps it makes ready to fuse (a
/// depth image whose pose is known, those a /tf message released, those that waited for a
/// colour image), or their skips.
fn take_event(
    s: &mut DepthSources,
    event: FuseEvent,
    now_ns: u64,
    log: &mut RateLimited,
) -> Vec<Result<crate::pipeline::FusionInput, crate::pipeline::DepthSkip>> {
    match event {
        FuseEvent::Depth(i, Ok(image)) => s.push_depth(i, &image, now_ns),
        FuseEvent::Info(i, Ok(info)) => {
            s.push_info(i, *info);
            Vec::new()
        }
        FuseEvent::Colour(i, Ok(image)) => s.push_colour(i, image),
        FuseEvent::Tf(Ok(tf)) => {
            for e in s.push_tf(&tf.msg, tf.is_static) {
                log.warn("tf", || format!("a transform was refused: {e}"));
            }
            s.poll(now_ns)
        }
        FuseEvent::Depth(_, Err(e))
        | FuseEvent::Info(_, Err(e))
        | FuseEvent::Colour(_, Err(e))
        | FuseEvent::Tf(Err(e)) => {
            log.warn("read", || format!("a message could not be read: {e}"));
            Vec::new()
        }
    }
}

/// The fuse node's subscriptions: per source its depth, camera_info and colour (where
/// `color_topics` are set), and `/tf` + `/tf_static`.
struct FuseInputs {
    depth: Vec<Subscription<Image>>,
    info: Vec<Subscription<CameraInfo>>,
    /// Raw colour images, or compressed ones (a topic ending in `/compressed`), by source.
    colour: Vec<ColourSubscription>,
    tf: Subscription<TFMessage>,
    tf_static: Subscription<TFMessage>,
}

enum ColourSubscription {
    Raw(Subscription<Image>),
    Compressed(Subscription<CompressedImage>),
}

type EventStream<'a> = std::pin::Pin<Box<dyn futures::Stream<Item = FuseEvent> + 'a>>;

impl FuseInputs {
    fn subscribe(node: &mut ros2_client::Node, config: &FuseConfig) -> Result<Self, NodeError> {
        // Depth publishers (and their camera_info) are reliable (sweepdepth, stereo_image_proc)
        // or best effort (camera drivers): a best-effort subscription matches both.
        let qos = QosProfile::subscription_default()
            .reliability_best_effort()
            .history(History::KeepLast { depth: 5 });
        Ok(Self {
            depth: (config.depth_topics.iter())
                .map(|topic| subscribe::<Image>(node, topic, IMAGE, &qos))
                .collect::<Result<Vec<_>, _>>()?,
            info: (config.info_topics.iter())
                .map(|topic| subscribe::<CameraInfo>(node, topic, CAMERA_INFO, &qos))
                .collect::<Result<Vec<_>, _>>()?,
            colour: (config.color_topics.iter())
                .map(|topic| {
                    Ok(if topic.ends_with("/compressed") {
                        let sub = subscribe(node, topic, COMPRESSED_IMAGE, &qos)?;
                        ColourSubscription::Compressed(sub)
                    } else {
                        ColourSubscription::Raw(subscribe(node, topic, IMAGE, &qos)?)
                    })
                })
                .collect::<Result<Vec<_>, NodeError>>()?,
            tf: subscribe(node, &config.tf_topic, TF_MESSAGE, &topics::tf_qos())?,
            tf_static: subscribe(
                node,
                &config.tf_static_topic,
                TF_MESSAGE,
                &topics::tf_static_qos(),
            )?,
        })
    }

    /// Every subscription's messages as one stream of events.
    fn events(&self) -> futures::stream::SelectAll<EventStream<'_>> {
        let mut streams: Vec<EventStream<'_>> = Vec::new();
        for (i, sub) in self.depth.iter().enumerate() {
            streams.push(tagged(sub, move |r| FuseEvent::Depth(i, r)));
        }
        for (i, sub) in self.info.iter().enumerate() {
            streams.push(tagged(sub, move |r| FuseEvent::Info(i, r.map(Box::new))));
        }
        for (i, sub) in self.colour.iter().enumerate() {
            streams.push(match sub {
                ColourSubscription::Raw(sub) => {
                    tagged(sub, move |r| FuseEvent::Colour(i, r.map(ColourImage::Raw)))
                }
                ColourSubscription::Compressed(sub) => tagged(sub, move |r| {
                    FuseEvent::Colour(i, r.map(ColourImage::Compressed))
                }),
            });
        }
        for (sub, is_static) in [(&self.tf, false), (&self.tf_static, true)] {
            let tf = move |msg| TfMessageIn { msg, is_static };
            streams.push(tagged(sub, move |r| FuseEvent::Tf(r.map(tf))));
        }
        futures::stream::select_all(streams)
    }
}

/// Runs the fuse node until SIGINT/SIGTERM.
pub fn run(args: &[String]) -> Result<(), NodeError> {
    let domain_env = std::env::var("ROS_DOMAIN_ID").ok();
    let config = FuseConfig::from_args(args, domain_env.as_deref())?;
    clock::set_use_sim_time(config.use_sim_time);
    log_info(&format!(
        "fuse node {} on domain {}: depth from {:?} in '{}'",
        config.fqn, config.domain_id, config.depth_topics, config.world_frame
    ));
    let context = Context::with_options(ContextOptions::new().domain_id(config.domain_id))
        .map_err(ros_err)?;
    // Declared before the node, so dropped after it (see `dds::SpinFuture`).
    let mut spin: super::dds::SpinFuture;
    let node_name =
        NodeName::new(&config.namespace, &config.name).map_err(|e| NodeError::Name {
            name: config.fqn.clone(),
            reason: format!("{e:?}"),
        })?;
    let mut node = context
        .new_node(node_name, node_options())
        .map_err(ros_err)?;
    // Its parameters as an rcl node serves them (read-only but `use_sim_time`), with the one
    // `/parameter_events` writer.
    let answers = Answers::fixed(config.params.clone(), FUSE_PARAMS);
    let param_services = ParamServices::new(&mut node, &config.fqn, answers)?;
    let inputs = FuseInputs::subscribe(&mut node, &config)?;
    let diag_pub = diagnostics_publisher(&mut node, &config.diagnostics_topic)?;
    let fusion = FusionNode::new(
        &mut node,
        &config.fqn,
        &config.fusion,
        FusionHost::Alone,
        &config.mesh_topic,
        None,
    )?;
    let worker = fusion.worker();

    // A tick, so that depth images waiting for /tf time out even when nothing else comes.
    let (tick_tx, tick_rx) = futures::channel::mpsc::unbounded::<()>();
    let mut events = inputs.events();
    let spinner = node.spinner().map_err(ros_err)?;
    spin = Box::pin(spinner.spin());
    let signals = shutdown::signals();
    log_info(&format!("fuse node {} is up", config.fqn));

    let sources = DepthSources::new(
        config.depth_topics.clone(),
        config.world_frame.clone(),
        config.tf_timeout,
    );
    let sources = Mutex::new(sources.with_colour(config.color_topics.clone()));
    let started = Instant::now();
    let now_ns = || u64::try_from(started.elapsed().as_nanos()).unwrap_or(u64::MAX);
    let mut log = RateLimited::default();
    let handle = |ready: Vec<Result<crate::pipeline::FusionInput, crate::pipeline::DepthSkip>>,
                  log: &mut RateLimited| {
        for item in ready {
            match item {
                Ok(input) => {
                    worker.offer(vec![input]);
                }
                Err(skip) => log.warn(skip.label(), || format!("{skip}; not fused")),
            }
        }
    };
    let event_loop = async {
        let mut ticks = tick_rx;
        let serve = futures::FutureExt::fuse(fusion.serve());
        // The parameter services, and `/clock` while `use_sim_time` is on.
        let params = serve_parameters(&param_services, &mut node, &config.clock_topic);
        let params = futures::FutureExt::fuse(params);
        futures::pin_mut!(serve, params);
        loop {
            futures::select! {
                event = events.next() => {
                    let Some(event) = event else {
                        return NodeError::Ros("the subscription streams ended".into());
                    };
                    let ready = take_event(&mut lock(&sources), event, now_ns(), &mut log);
                    handle(ready, &mut log);
                }
                _ = ticks.next() => {
                    let ready = lock(&sources).poll(now_ns());
                    handle(ready, &mut log);
                }
                e = serve => return e,
                e = params => return e,
            }
        }
    };
    // The diagnostics thread also ticks the event loop, so that depth images waiting for /tf
    // time out even when nothing else comes.
    shutdown::run_until_signal(
        &mut spin,
        event_loop,
        signals,
        "sweepdepth-fuse-diagnostics",
        |stop| {
            let mut next = Instant::now();
            while !stop.load(Ordering::Relaxed) {
                std::thread::sleep(Duration::from_millis(100));
                let _ = tick_tx.unbounded_send(());
                if Instant::now() < next {
                    continue;
                }
                next += Duration::from_secs(1);
                let msg = fuse_diagnostics(&worker.stats(), &lock(&sources), &config.fqn);
                let _ = diag_pub.publish(msg);
            }
        },
        || {},
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// No `depth_topics` reached the fuse node: the error says why, as the depth node's does
    /// (no parameter file; a file whose sections are for other nodes, named).
    /// `use_sim_time` and `/clock`'s remap reach the fuse node as the depth node.
    /// The parameters it serves are of the one table.
    /// A colour image that comes after its depth (a RealSense sends its two streams in
    /// either order) is waited for: the event that brings it releases the depth with its
    /// colour, and `/diagnostics` counts the depth waiting meanwhile.
    #[test]
    fn a_colour_after_its_depth_colours_it() {
        use crate::pipeline::depth_in::tests::{depth_mm, info, rgb, tf};
        let mut s = DepthSources::new(
            vec!["/a/depth/image".into()],
            "world".into(),
            Duration::from_secs(1),
        )
        .with_colour(vec!["/a/image_raw".into()]);
        let mut log = RateLimited::default();
        let mut take = |s: &mut DepthSources, event| take_event(s, event, 0, &mut log);
        take(&mut s, FuseEvent::Info(0, Ok(Box::new(info(32, 24)))));
        let tf = TfMessageIn {
            msg: tf(0, 0.0),
            is_static: true,
        };
        take(&mut s, FuseEvent::Tf(Ok(tf)));
        let depth = FuseEvent::Depth(0, Ok(depth_mm(32, 24, 2000, 1)));
        assert!(take(&mut s, depth).is_empty(), "it waits for its colour");
        let waiting = |s: &DepthSources| {
            let diagnostics = fuse_diagnostics(&FusionStats::default(), s, "/fuse");
            diagnostics.status[0]
                .values
                .iter()
                .find(|v| v.key == "depth images waiting for colour")
                .map(|v| v.value.clone())
        };
        assert_eq!(waiting(&s).as_deref(), Some("1"));
        let out = take(&mut s, FuseEvent::Colour(0, Ok(rgb(32, 24, 90, 1))));
        let [Ok(input)] = &out[..] else {
            panic!("the depth did not come with its colour: {out:?}");
        };
        let colour = input
            .colour
            .as_ref()
            .map(|c| crate::image::Rgba8Image::unpack(c.pixels[0]));
        assert_eq!(colour.map(|p| p[0]), Some(90));
        assert_eq!(waiting(&s).as_deref(), Some("0"));
        assert!(s.uncoloured.is_empty());
    }

    #[test]
    fn its_parameters_are_of_the_table() {
        for name in FUSE_PARAMS {
            assert!(crate::params::param_spec(name).is_some(), "{name}");
        }
        let args: Vec<String> = [
            "--ros-args",
            "-p",
            "depth_topics:=[/d]",
            "-p",
            "world_frame:=map",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        let config = FuseConfig::from_args(&args, None).unwrap();
        assert!(config.color_topics.is_empty());
        let with = |colours: &str| {
            let mut with = args.clone();
            with.extend(["-p".to_string(), format!("color_topics:={colours}")]);
            FuseConfig::from_args(&with, None)
        };
        let config = with("[cam/image_raw]").unwrap();
        assert_eq!(config.color_topics, ["/cam/image_raw"]);
        let two = with("[/a, /b]").unwrap_err().to_string();
        assert!(two.contains("2 colour topics for 1 depth topics"), "{two}");
        let frame = config.params.get("world_frame");
        assert_eq!(
            frame,
            Some(&crate::params::ParamValue::String("map".into()))
        );
    }

    #[test]
    fn simulated_time_and_the_clock_topic() {
        let args: Vec<String> = [
            "--ros-args",
            "-p",
            "depth_topics:=[/a/depth/image]",
            "-p",
            "world_frame:=map",
            "-p",
            "use_sim_time:=true",
            "-r",
            "/clock:=/sim/clock",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        let config = FuseConfig::from_args(&args, None).unwrap();
        assert!(config.use_sim_time);
        assert_eq!(config.clock_topic, "/sim/clock");
        let config = FuseConfig::from_args(&args[..5], None).unwrap();
        assert!(!config.use_sim_time && config.clock_topic == "/clock");
    }

    #[test]
    fn missing_depth_topics_say_why_no_parameter_reached_the_node() {
        let args = |extra: &[&str]| -> Vec<String> {
            ["--ros-args"]
                .iter()
                .chain(extra)
                .map(|s| s.to_string())
                .collect()
        };
        let error = |extra: &[&str]| match FuseConfig::from_args(&args(extra), None) {
            Ok(c) => panic!("{extra:?}: configured with {:?}", c.depth_topics),
            Err(e) => crate::cli::error_line(&anyhow::Error::new(e)),
        };
        let none = error(&[]);
        assert!(
            none.contains("'depth_topics'")
                && none.contains("no parameter file given")
                && none.contains("-p depth_topics:=["),
            "{none}"
        );
        let file = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/launch_configs/four_cameras.params.yaml"
        );
        let other = error(&["--params-file", file]);
        assert!(
            other.contains("no section of the parameter file is for this node (/sweepdepth_fuse)"),
            "{other}"
        );
        // A section that applies but lists no topic: the parameter's own error alone.
        let dir = std::env::temp_dir().join(format!("sweepdepth-fuse-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let own = dir.join("fuse.params.yaml");
        std::fs::write(&own, "/**:\n  ros__parameters:\n    world_frame: map\n").unwrap();
        let listed = error(&["--params-file", own.to_str().unwrap()]);
        std::fs::remove_dir_all(&dir).unwrap();
        assert!(
            listed.contains("'depth_topics'") && !listed.contains("no section"),
            "{listed}"
        );
    }
}
