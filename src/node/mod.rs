//! The ROS 2 node (`sweepdepth node --ros-args ...`) over `ros2-client` (DDS).
//!
//! Data flow: per camera an image and a camera_info subscription (and `/tf_static` unless
//! `rig_file` is set) feed one async loop on a `futures` executor that also drives the
//! ros2-client spinner. The loop keeps the latest CameraInfo per camera and the TF tree,
//! synchronises the images ([`ExactSync`] / [`ApproximateSync`]) and hands each complete set,
//! with its calibration, to the GPU worker thread through a one-slot channel ([`LatestSlot`]:
//! the newest set replaces a pending one). The worker owns the [`GpuContext`] and the
//! [`GpuEngine`], converts the images, runs the sweep and publishes `depth/image`,
//! `depth/camera_info`, `confidence/image`, `cost/image`, `selection/image` and, with
//! `publish_points`, `points` (an organised PointCloud2 coloured from the reference image).
//!
//! A diagnostics thread publishes `/diagnostics` once a second ([`diag::Stats`]). Log messages
//! go to stderr (tracing) and, once DDS is up, to `/rosout`. The parameter services of
//! ros2-client serve every parameter of the table; engine parameters can be set at run time
//! (validated, then used from the next frame set on, see [`params::LiveParams`]), node
//! parameters are read-only.
//!
//! SIGINT and SIGTERM end the node cleanly: the event loop stops, the GPU thread finishes its
//! set and ends, DDS entities are dropped, and the process exits 0.

pub mod convert;
pub mod diag;
pub mod params;
pub mod pipeline;
pub mod worker;

use std::collections::HashMap;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use futures::{Stream, StreamExt};
use ros2_client::log::Log;
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{
    Context, ContextOptions, MessageTypeName, Name, NodeLoggingHandle, NodeName, NodeOptions,
    Publisher, QosProfile, RosoutRaw,
};

use glam::{DQuat, DVec3};

use crate::geometry::{PinholeIntrinsics, RigidTransform};
use crate::msgs::{CameraInfo, DiagnosticArray, Image, PointCloud2, TFMessage};
use crate::ros::args::{
    apply_to_sweep, parse_ros_args, NodeIdentity, ParamSet, ParamValue, RosArgs, RosArgsError,
    DEFAULT_NODE_NAME,
};
use crate::ros::camera_info::ImageKind;
use crate::ros::rig_file::{load_rig_file, RigFile, RigFileError};
use crate::ros::sync::{ApproximateSync, ExactSync, SyncError, Synchronizer, TimeRules};
use crate::sweep::SweepParams;

use self::diag::{wall_time_now, Stats};
use self::params::LiveParams;
use self::pipeline::{EngineHost, Job, Pipeline};
use self::worker::LatestSlot;

/// Minimum time between two repetitions of the same warning.
const LOG_INTERVAL: Duration = Duration::from_secs(2);

/// Errors that stop the node (at start-up).
#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    #[error(transparent)]
    Args(#[from] RosArgsError),
    #[error("{0}")]
    Param(String),
    #[error("unexpected arguments {0:?}: `sweepdepth node` takes only `--ros-args ...`")]
    ExtraArgs(Vec<String>),
    #[error(transparent)]
    RigFile(#[from] RigFileError),
    #[error("rig file '{path}' has no camera for '{camera}'")]
    RigFileCamera { path: String, camera: String },
    #[error("invalid ROS name '{name}': {reason}")]
    Name { name: String, reason: String },
    #[error("ROS 2 (ros2-client): {0}")]
    Ros(String),
    #[error("GPU: {0}")]
    Gpu(String),
    #[error(transparent)]
    Sync(#[from] SyncError),
}

fn ros_err(e: impl std::fmt::Debug) -> NodeError {
    NodeError::Ros(format!("{e:?}"))
}

/// Time synchronisation settings.
#[derive(Debug, Clone, PartialEq)]
pub enum SyncPolicy {
    Exact,
    Approximate {
        max_interval_ns: i64,
        age_penalty: f64,
    },
}

/// The virtual reference camera (`virtual_reference:=true`).
///
/// Placement: with `frame_id` set and no rig file, from /tf_static (the transform from the
/// reference camera's frame to `frame_id`); otherwise `ref_from_virtual` (`virtual_pose`)
/// composed with the reference camera's pose. Outputs carry `frame_id`, or the reference
/// camera's frame when it is empty (then `virtual_pose` must be applied by the consumer), and
/// the stamp of the reference camera's image. Intrinsics of 0 copy the reference camera's.
#[derive(Debug, Clone, PartialEq)]
pub struct VirtualConfig {
    pub frame_id: String,
    /// Pose of the virtual optical frame in the reference camera's optical frame.
    pub ref_from_virtual: RigidTransform,
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl VirtualConfig {
    fn from_params(params: &ParamSet) -> Result<Self, NodeError> {
        let p = NodeError::Param;
        let pose = params.virtual_pose().map_err(p)?;
        let ref_from_virtual = RigidTransform::from_quat_translation(
            "virtual_pose",
            DQuat::from_xyzw(pose[3], pose[4], pose[5], pose[6]),
            DVec3::new(pose[0], pose[1], pose[2]),
        )
        .map_err(|e| NodeError::Param(e.to_string()))?;
        let size = |name: &str| -> Result<u32, NodeError> {
            let v = params.get_i64(name).map_err(NodeError::Param)?;
            u32::try_from(v).map_err(|_| NodeError::Param(format!("parameter '{name}': {v}")))
        };
        let f = |name: &str| params.get_f64(name).map_err(NodeError::Param);
        Ok(Self {
            frame_id: params
                .get_str("virtual_frame_id")
                .map_err(NodeError::Param)?
                .to_string(),
            ref_from_virtual,
            width: size("virtual_width")?,
            height: size("virtual_height")?,
            fx: f("virtual_fx")?,
            fy: f("virtual_fy")?,
            cx: f("virtual_cx")?,
            cy: f("virtual_cy")?,
        })
    }

    /// The virtual intrinsics, 0 values taken from the reference camera's `base`.
    pub fn intrinsics(&self, base: &PinholeIntrinsics) -> PinholeIntrinsics {
        let or = |v: f64, b: f64| if v == 0.0 { b } else { v };
        PinholeIntrinsics {
            width_px: if self.width == 0 {
                base.width_px
            } else {
                self.width
            },
            height_px: if self.height == 0 {
                base.height_px
            } else {
                self.height
            },
            fx_px: or(self.fx, base.fx_px),
            fy_px: or(self.fy, base.fy_px),
            cx_px: or(self.cx, base.cx_px),
            cy_px: or(self.cy, base.cy_px),
        }
    }
}

/// Everything the node needs from its command line and environment.
#[derive(Debug, Clone)]
pub struct NodeConfig {
    pub identity: NodeIdentity,
    pub params: ParamSet,
    pub sweep: SweepParams,
    pub domain_id: u16,
    pub cameras: Vec<String>,
    pub reference: usize,
    /// Fully qualified (remapped) topic names, per camera.
    pub image_topics: Vec<String>,
    /// What each camera's image topic carries, raw or rectified (`image_kinds`, else the
    /// topic's name): which part of its CameraInfo describes it.
    pub image_kinds: Vec<ImageKind>,
    pub info_topics: Vec<String>,
    /// Fully qualified output topic names: depth, depth info, confidence, cost, selection.
    pub output_topics: [String; 5],
    /// `points` (PointCloud2), published when `publish_points` is true.
    pub points_topic: String,
    pub publish_points: bool,
    pub diagnostics_topic: String,
    pub tf_static_topic: String,
    pub rig_file: Option<RigFile>,
    pub sync: SyncPolicy,
    pub queue_size: usize,
    /// A camera silent this long leaves the rig until it sends again (`None`: never).
    pub camera_timeout: Option<Duration>,
    pub input_reliable: bool,
    pub input_depth: usize,
    pub output_depth: usize,
    /// The virtual reference camera, when `virtual_reference` is true.
    pub virtual_ref: Option<VirtualConfig>,
    pub notes: Vec<String>,
}

impl NodeConfig {
    /// From the arguments after `node` and the value of `ROS_DOMAIN_ID`.
    pub fn from_args(args: &[String], domain_env: Option<&str>) -> Result<Self, NodeError> {
        let ros: RosArgs = parse_ros_args(args)?;
        if !ros.other.is_empty() {
            return Err(NodeError::ExtraArgs(ros.other.clone()));
        }
        let identity = ros.node_identity(DEFAULT_NODE_NAME, "/")?;
        let (params, mut notes) = ParamSet::from_ros_args(&ros, &identity)?;
        notes.extend(ros.notes.iter().cloned());
        let mut params = params;
        params.check_node().map_err(NodeError::Param)?;
        let virtual_ref = if params
            .get_bool("virtual_reference")
            .map_err(NodeError::Param)?
        {
            // check_node rejected an explicit pairs:=reference; the default becomes all.
            if params.get_str("pairs").map_err(NodeError::Param)? != "all" {
                params
                    .set("pairs", &ParamValue::String("all".into()))
                    .map_err(NodeError::Param)?;
                notes.push("virtual_reference: pairs set to 'all' (a virtual camera has no image of its own)".into());
            }
            let v = VirtualConfig::from_params(&params)?;
            if v.frame_id.is_empty() && v.ref_from_virtual != RigidTransform::IDENTITY {
                notes.push("virtual_reference: virtual_frame_id is empty, so the outputs carry the reference camera's frame_id although the virtual camera is at virtual_pose in it".into());
            }
            Some(v)
        } else {
            None
        };
        let mut sweep = SweepParams::default();
        apply_to_sweep(&params, &mut sweep).map_err(NodeError::Param)?;
        let cameras = params
            .get_string_array("cameras")
            .map_err(NodeError::Param)?
            .to_vec();
        let reference_name = params
            .reference_camera()
            .ok_or_else(|| NodeError::Param("no reference camera".into()))?;
        let reference = cameras
            .iter()
            .position(|c| *c == reference_name)
            .ok_or_else(|| NodeError::Param(format!("unknown reference '{reference_name}'")))?;
        let image_topic = params.get_str("image_topic").map_err(NodeError::Param)?;
        let resolve = |name: &str| ros.resolve_topic(name, &identity);
        let mut image_topics = Vec::new();
        let mut info_topics = Vec::new();
        for camera in &cameras {
            let camera = camera.trim_end_matches('/');
            image_topics.push(resolve(&format!("{camera}/{image_topic}"))?);
            info_topics.push(resolve(&format!("{camera}/camera_info"))?);
        }
        let image_kinds = image_kinds(&params, &cameras, &image_topics, &mut notes)?;
        let output_topics = [
            resolve("depth/image")?,
            resolve("depth/camera_info")?,
            resolve("confidence/image")?,
            resolve("cost/image")?,
            resolve("selection/image")?,
        ];
        let tf_static_topic = resolve("/tf_static")?;
        let points_topic = resolve("points")?;
        let diagnostics_topic = resolve("/diagnostics")?;
        let rig_path = params.get_str("rig_file").map_err(NodeError::Param)?;
        let rig_file = if rig_path.is_empty() {
            None
        } else {
            let file = load_rig_file(rig_path)?;
            for camera in &cameras {
                if file.camera_for(camera).is_none() {
                    return Err(NodeError::RigFileCamera {
                        path: rig_path.to_string(),
                        camera: camera.clone(),
                    });
                }
            }
            notes.extend(file.notes.iter().cloned());
            Some(file)
        };
        let sync = match params.get_str("sync").map_err(NodeError::Param)? {
            "exact" => SyncPolicy::Exact,
            _ => SyncPolicy::Approximate {
                max_interval_ns: (params
                    .get_f64("sync_max_interval")
                    .map_err(NodeError::Param)?
                    * 1e9)
                    .round() as i64,
                age_penalty: params.get_f64("age_penalty").map_err(NodeError::Param)?,
            },
        };
        let usize_param = |name: &str| -> Result<usize, NodeError> {
            let v = params.get_i64(name).map_err(NodeError::Param)?;
            usize::try_from(v).map_err(|_| NodeError::Param(format!("parameter '{name}': {v}")))
        };
        // The engine parameters against the rig's shape, before any frame arrives.
        let virtual_reference = virtual_ref.is_some();
        if let Some(shape) = params::shape_rig(cameras.len(), reference, virtual_reference) {
            let context = if virtual_reference {
                "virtual_reference: "
            } else {
                ""
            };
            sweep
                .validate(&shape)
                .map_err(|e| NodeError::Param(format!("{context}{e}")))?;
            params::check_rig_consistency(&SweepParams::default(), &sweep, cameras.len())
                .map_err(NodeError::Param)?;
        }
        Ok(Self {
            virtual_ref,
            domain_id: crate::ros::args::domain_id(domain_env)?,
            queue_size: usize_param("queue_size")?,
            camera_timeout: {
                let t = params.get_f64("camera_timeout").map_err(NodeError::Param)?;
                (t > 0.0).then(|| Duration::from_secs_f64(t))
            },
            input_reliable: params
                .get_bool("input_qos_reliable")
                .map_err(NodeError::Param)?,
            input_depth: usize_param("input_qos_depth")?,
            output_depth: usize_param("output_qos_depth")?,
            identity,
            sweep,
            cameras,
            reference,
            image_topics,
            image_kinds,
            info_topics,
            output_topics,
            points_topic,
            publish_points: params
                .get_bool("publish_points")
                .map_err(NodeError::Param)?,
            diagnostics_topic,
            tf_static_topic,
            rig_file,
            sync,
            params,
            notes,
        })
    }

    /// A synchroniser over `n` of the cameras.
    fn synchronizer(&self, n: usize) -> Result<Box<dyn Synchronizer<Image> + Send>, NodeError> {
        let rules = self.time_rules()?;
        Ok(match &self.sync {
            SyncPolicy::Exact => {
                Box::new(ExactSync::new(n, self.queue_size)?.with_time_rules(rules)?)
            }
            SyncPolicy::Approximate {
                max_interval_ns,
                age_penalty,
            } => Box::new(
                ApproximateSync::new(n, self.queue_size)?
                    .with_age_penalty(*age_penalty)?
                    .with_max_interval_ns(*max_interval_ns)?
                    .with_time_rules(rules)?,
            ),
        })
    }

    /// The synchroniser's time rules from `sync_future_window` and `sync_reset_backwards`.
    pub fn time_rules(&self) -> Result<TimeRules, NodeError> {
        let ns = |name: &str| -> Result<i64, NodeError> {
            let seconds = self.params.get_f64(name).map_err(NodeError::Param)?;
            Ok((seconds * 1e9).round() as i64)
        };
        Ok(TimeRules {
            future_window_ns: ns("sync_future_window")?,
            reset_backwards_ns: ns("sync_reset_backwards")?,
        })
    }
}

/// Each camera's [`ImageKind`]: `image_kinds` (one entry per camera, `raw`, `rect` or `auto`),
/// else (empty, or `auto`) the name of its resolved image topic; a name that says neither is
/// taken as raw, with a note.
fn image_kinds(
    params: &ParamSet,
    cameras: &[String],
    image_topics: &[String],
    notes: &mut Vec<String>,
) -> Result<Vec<ImageKind>, NodeError> {
    let declared = params
        .get_string_array("image_kinds")
        .map_err(NodeError::Param)?;
    if !declared.is_empty() && declared.len() != cameras.len() {
        return Err(NodeError::Param(format!(
            "parameter 'image_kinds' has {} entries but 'cameras' has {}: give one (raw, rect or auto) per camera, or none",
            declared.len(),
            cameras.len()
        )));
    }
    let mut kinds = Vec::with_capacity(cameras.len());
    for (i, (camera, topic)) in cameras.iter().zip(image_topics).enumerate() {
        let declared = declared.get(i).map(String::as_str).unwrap_or("auto");
        let kind = match ImageKind::parse(declared) {
            Some(kind) => kind,
            None => ImageKind::from_topic(topic).unwrap_or_else(|| {
                notes.push(format!(
                    "camera '{camera}': the name of its image topic '{topic}' says neither raw (image_raw, image, image_color) nor rectified (image_rect*): its images are taken as raw (described by K and D); set image_kinds to say otherwise"
                ));
                ImageKind::Raw
            }),
        };
        kinds.push(kind);
    }
    Ok(kinds)
}

/// The node's `/rosout` writer and logger name (`ns.name`) once DDS is up.
static ROSOUT: Mutex<Option<(NodeLoggingHandle, String)>> = Mutex::new(None);

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Logs `msg` to stderr (tracing) and, when enabled at that level and DDS is up, to `/rosout`
/// (as the node `logger_name`).
fn node_log(level: tracing::Level, msg: &str) {
    match level {
        tracing::Level::ERROR => tracing::error!("{msg}"),
        tracing::Level::WARN => tracing::warn!("{msg}"),
        tracing::Level::INFO => tracing::info!("{msg}"),
        _ => tracing::debug!("{msg}"),
    }
    let enabled = match level {
        tracing::Level::ERROR => tracing::enabled!(tracing::Level::ERROR),
        tracing::Level::WARN => tracing::enabled!(tracing::Level::WARN),
        tracing::Level::INFO => tracing::enabled!(tracing::Level::INFO),
        _ => false,
    };
    if !enabled {
        return;
    }
    let guard = lock(&ROSOUT);
    let Some((handle, name)) = guard.as_ref() else {
        return;
    };
    if let Some(writer) = handle.rosout_writer().as_ref() {
        let ros_level = match level {
            tracing::Level::ERROR => Log::ERROR,
            tracing::Level::WARN => Log::WARN,
            _ => Log::INFO,
        };
        // A failed rosout write is not worth a log line of its own (it would recurse).
        let _ = writer.publish(Log {
            stamp: ros2_client::builtin_interfaces::Time::now(),
            level: ros_level,
            name: name.clone(),
            msg: msg.to_string(),
            file: file!().to_string(),
            function: String::new(),
            line: 0,
        });
    }
}

fn log_info(msg: &str) {
    node_log(tracing::Level::INFO, msg);
}

/// Emits a warning per key at most once per [`LOG_INTERVAL`].
#[derive(Default)]
struct RateLimited {
    last: HashMap<String, Instant>,
}

impl RateLimited {
    fn warn(&mut self, key: &str, message: impl FnOnce() -> String) {
        let now = Instant::now();
        if self
            .last
            .get(key)
            .is_some_and(|t| now.duration_since(*t) < LOG_INTERVAL)
        {
            return;
        }
        self.last.insert(key.to_string(), now);
        node_log(tracing::Level::WARN, &message());
    }
}

struct Outputs {
    points: Option<Publisher<PointCloud2>>,
    depth: Publisher<Image>,
    depth_info: Publisher<CameraInfo>,
    confidence: Publisher<Image>,
    cost: Publisher<Image>,
    selection: Publisher<Image>,
}

fn topic_name(name: &str) -> Result<Name, NodeError> {
    Name::parse(name).map_err(|e| NodeError::Name {
        name: name.to_string(),
        reason: format!("{e:?}"),
    })
}

/// Runs the node with the arguments after `node` until the process is killed.
pub fn run(args: &[String]) -> Result<(), NodeError> {
    let domain_env = std::env::var("ROS_DOMAIN_ID").ok();
    let config = NodeConfig::from_args(args, domain_env.as_deref())?;
    for note in &config.notes {
        tracing::info!("{note}");
    }
    tracing::info!(
        "node {} on domain {}: cameras [{}], reference '{}', images {:?}",
        config.identity.fqn(),
        config.domain_id,
        config.cameras.join(", "),
        config.cameras[config.reference],
        config.image_topics
    );

    // The GPU worker starts first so that a missing adapter fails before DDS comes up.
    let slot: Arc<LatestSlot<Job>> = Arc::new(LatestSlot::new());
    let live = LiveParams::new(
        config.params.clone(),
        config.sweep.clone(),
        config.cameras.len(),
        config.reference,
        config.virtual_ref.is_some(),
    );
    let stats = Arc::new(Mutex::new(Stats::new(config.cameras.len())));
    let (init_tx, init_rx) = std::sync::mpsc::channel::<Result<String, String>>();
    let (outputs_tx, outputs_rx) = std::sync::mpsc::channel::<Outputs>();
    let worker_slot = Arc::clone(&slot);
    let worker_live = Arc::clone(&live);
    let worker_stats = Arc::clone(&stats);
    let worker = std::thread::Builder::new()
        .name("sweepdepth-gpu".into())
        .spawn(move || {
            let host = match EngineHost::new() {
                Ok(host) => host,
                Err(e) => {
                    let _ = init_tx.send(Err(e));
                    return;
                }
            };
            let _ = init_tx.send(Ok(host.adapter_label()));
            let Ok(outputs) = outputs_rx.recv() else {
                return;
            };
            let shared = WorkerShared {
                slot: &worker_slot,
                live: &worker_live,
                stats: &worker_stats,
            };
            worker_loop(&shared, host, &outputs);
        })
        .map_err(|e| NodeError::Gpu(format!("cannot start the GPU thread: {e}")))?;
    let adapter = match init_rx.recv() {
        Ok(Ok(adapter)) => adapter,
        Ok(Err(e)) => return Err(NodeError::Gpu(e)),
        Err(_) => {
            return Err(NodeError::Gpu(
                "the GPU thread ended during start-up".into(),
            ))
        }
    };
    tracing::info!("GPU adapter: {adapter}");

    let shared = DdsShared {
        slot: &slot,
        live: &live,
        stats: &stats,
        adapter: &adapter,
    };
    let result = run_dds(&config, &shared, outputs_tx);
    *lock(&ROSOUT) = None;
    slot.close();
    let _ = worker.join();
    result
}

type EventStream<'a> = Pin<Box<dyn Stream<Item = Event> + 'a>>;

enum Event {
    Image(usize, Result<Image, String>),
    Info(usize, Result<Box<CameraInfo>, String>),
    Tf(Result<TFMessage, String>),
}

/// What the executor side shares with the worker and the parameter callbacks.
struct DdsShared<'a> {
    slot: &'a LatestSlot<Job>,
    live: &'a Arc<LiveParams>,
    stats: &'a Arc<Mutex<Stats>>,
    adapter: &'a str,
}

struct WorkerShared<'a> {
    slot: &'a LatestSlot<Job>,
    live: &'a LiveParams,
    stats: &'a Mutex<Stats>,
}

/// The node's options: rosout on, parameter services with every parameter of the table
/// declared, sets validated and applied by [`LiveParams`].
fn node_options(live: &Arc<LiveParams>) -> NodeOptions {
    let mut options = NodeOptions::new()
        .enable_rosout(true)
        .start_parameter_services(true)
        .allow_undeclared_parameters(false);
    for (name, value) in live.declarations() {
        options = options.declare_parameter(&name, value);
    }
    let validator = Arc::clone(live);
    let action = Arc::clone(live);
    options
        .parameter_validator(Box::new(move |name, value| {
            let r = validator.check(name, value);
            if let Err(e) = &r {
                node_log(
                    tracing::Level::WARN,
                    &format!("rejected setting parameter '{name}' to {value:?}: {e}"),
                );
            }
            r
        }))
        .parameter_set_action(Box::new(move |name, value| {
            if action.apply(name, value)? {
                log_info(&format!(
                    "parameter '{name}' set to {value:?} (used from the next frame set on)"
                ));
            }
            Ok(())
        }))
}

/// Publishes `/diagnostics` once a second until `stop` is set.
fn diagnostics_loop(
    config: &NodeConfig,
    shared: &DdsShared<'_>,
    publisher: Publisher<DiagnosticArray>,
    stop: &AtomicBool,
) {
    let fqn = config.identity.fqn();
    let mut next = Instant::now() + Duration::from_secs(1);
    let mut log = RateLimited::default();
    while !stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        if now < next {
            std::thread::sleep((next - now).min(Duration::from_millis(100)));
            continue;
        }
        next += Duration::from_secs(1);
        if next < now {
            next = now + Duration::from_secs(1);
        }
        let msg = {
            let mut stats = lock(shared.stats);
            stats.gpu_dropped = shared.slot.dropped();
            stats.diagnostics(&fqn, &config.cameras, shared.adapter, now, wall_time_now())
        };
        if let Err(e) = publisher.publish(msg) {
            log.warn("diagnostics", || {
                format!("publishing /diagnostics failed: {e:?}")
            });
        }
    }
}

fn run_dds(
    config: &NodeConfig,
    shared: &DdsShared<'_>,
    outputs_tx: std::sync::mpsc::Sender<Outputs>,
) -> Result<(), NodeError> {
    let slot = shared.slot;
    let context = Context::with_options(ContextOptions::new().domain_id(config.domain_id))
        .map_err(ros_err)?;
    let node_name =
        NodeName::new(&config.identity.namespace, &config.identity.name).map_err(|e| {
            NodeError::Name {
                name: config.identity.fqn(),
                reason: format!("{e:?}"),
            }
        })?;
    let mut node = context
        .new_node(node_name, node_options(shared.live))
        .map_err(ros_err)?;
    let logger_name = config
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

    let mut image_subs = Vec::new();
    let mut info_subs = Vec::new();
    for i in 0..config.cameras.len() {
        let topic = node
            .create_topic(
                &topic_name(&config.image_topics[i])?,
                image_type(),
                &input_qos,
            )
            .map_err(ros_err)?;
        image_subs.push(
            node.create_subscription::<Image>(&topic, Some(input_qos.clone()))
                .map_err(ros_err)?,
        );
        let topic = node
            .create_topic(&topic_name(&config.info_topics[i])?, info_type(), &info_qos)
            .map_err(ros_err)?;
        info_subs.push(
            node.create_subscription::<CameraInfo>(&topic, Some(info_qos.clone()))
                .map_err(ros_err)?,
        );
    }
    let tf_sub = if config.rig_file.is_none() {
        let topic = node
            .create_topic(
                &topic_name(&config.tf_static_topic)?,
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

    let mut publisher = |name: &str| -> Result<Publisher<Image>, NodeError> {
        let topic = node
            .create_topic(&topic_name(name)?, image_type(), &output_qos)
            .map_err(ros_err)?;
        node.create_publisher::<Image>(&topic, Some(output_qos.clone()))
            .map_err(ros_err)
    };
    let depth = publisher(&config.output_topics[0])?;
    let confidence = publisher(&config.output_topics[2])?;
    let cost = publisher(&config.output_topics[3])?;
    let selection = publisher(&config.output_topics[4])?;
    let depth_info_topic = node
        .create_topic(
            &topic_name(&config.output_topics[1])?,
            info_type(),
            &output_qos,
        )
        .map_err(ros_err)?;
    let depth_info = node
        .create_publisher::<CameraInfo>(&depth_info_topic, Some(output_qos.clone()))
        .map_err(ros_err)?;
    let points = if config.publish_points {
        let topic = node
            .create_topic(
                &topic_name(&config.points_topic)?,
                MessageTypeName::new("sensor_msgs", "PointCloud2"),
                &output_qos,
            )
            .map_err(ros_err)?;
        Some(
            node.create_publisher::<PointCloud2>(&topic, Some(output_qos.clone()))
                .map_err(ros_err)?,
        )
    } else {
        None
    };
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
    outputs_tx
        .send(Outputs {
            points,
            depth,
            depth_info,
            confidence,
            cost,
            selection,
        })
        .map_err(|_| NodeError::Gpu("the GPU thread has ended".into()))?;

    let mut streams: Vec<EventStream<'_>> = Vec::new();
    for (i, sub) in image_subs.iter().enumerate() {
        streams.push(Box::pin(sub.async_stream().map(move |r| {
            Event::Image(i, r.map(|(m, _)| m).map_err(|e| format!("{e:?}")))
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
    let mut events = futures::stream::select_all(streams);
    let spinner = node.spinner().map_err(ros_err)?;
    // SIGINT / SIGTERM (Ctrl-C, `ros2 launch` shutting down): leave the loop, so that the
    // publishers, subscriptions and the DDS participant are dropped cleanly. Installed before
    // the node says it is up, so a signal sent as soon as it is up is never the default action.
    let (signal_tx, mut signal_rx) = futures::channel::mpsc::unbounded::<()>();
    if let Err(e) = ctrlc::set_handler(move || {
        let _ = signal_tx.unbounded_send(());
    }) {
        tracing::warn!("no clean shutdown on SIGINT/SIGTERM: {e}");
    }
    log_info(&format!("node {} is up", config.identity.fqn()));

    let mut state = LoopState {
        pipeline: Pipeline::new(config)?,
        started: Instant::now(),
        log: RateLimited::default(),
        slot,
        stats: shared.stats,
    };
    let event_loop = async {
        while let Some(event) = events.next().await {
            state.handle(event);
        }
    };
    let stop = AtomicBool::new(false);
    std::thread::scope(|scope| {
        let diag = std::thread::Builder::new()
            .name("sweepdepth-diagnostics".into())
            .spawn_scoped(scope, || diagnostics_loop(config, shared, diag_pub, &stop))
            .map_err(|e| NodeError::Ros(format!("cannot start the diagnostics thread: {e}")))?;
        let outcome = futures::executor::block_on(async {
            futures::pin_mut!(event_loop);
            let spin = spinner.spin();
            futures::pin_mut!(spin);
            let stopped = signal_rx.next();
            match futures::future::select(futures::future::select(spin, event_loop), stopped).await
            {
                futures::future::Either::Left((futures::future::Either::Left((r, _)), _)) => {
                    r.map_err(ros_err)
                }
                futures::future::Either::Left((futures::future::Either::Right(((), _)), _)) => {
                    Err(NodeError::Ros("the subscription streams ended".into()))
                }
                futures::future::Either::Right(_) => {
                    log_info("shutting down (signal received)");
                    Ok(())
                }
            }
        });
        stop.store(true, Ordering::Relaxed);
        let _ = diag.join();
        outcome
    })
}

struct LoopState<'a> {
    pipeline: Pipeline<'a>,
    /// The clock of camera dropout (receive time).
    started: Instant,
    log: RateLimited,
    slot: &'a LatestSlot<Job>,
    stats: &'a Mutex<Stats>,
}

impl LoopState<'_> {
    fn handle(&mut self, event: Event) {
        match event {
            Event::Info(i, Ok(info)) => self.pipeline.on_info(i, *info),
            Event::Tf(Ok(msg)) => {
                for e in self.pipeline.on_tf(&msg) {
                    self.log.warn("tf_insert", || format!("/tf_static: {e}"));
                }
            }
            Event::Image(i, Ok(image)) => {
                let now_ns = u64::try_from(self.started.elapsed().as_nanos()).unwrap_or(u64::MAX);
                let result = self.pipeline.on_image(i, image, now_ns);
                for event in self.pipeline.take_events() {
                    node_log(tracing::Level::WARN, &event);
                }
                for notice in self.pipeline.take_notices() {
                    self.log.warn(&notice.key, || notice.message.clone());
                }
                {
                    let mut stats = lock(self.stats);
                    stats.on_image(i, Instant::now());
                    stats.sync = self.pipeline.sync_stats();
                    stats.inactive_cameras = self.pipeline.inactive_cameras();
                }
                match result {
                    Ok(sets) => {
                        for set in sets {
                            match set {
                                Ok(job) => self.offer(job),
                                Err(skip) => self.log.warn(&skip.key, || skip.message.clone()),
                            }
                        }
                    }
                    Err(e) => self.log.warn("sync", || format!("synchroniser: {e}")),
                }
            }
            Event::Image(i, Err(e)) | Event::Info(i, Err(e)) => {
                let camera = &self.pipeline.config().cameras[i];
                self.log.warn(&format!("read{i}"), || {
                    format!("camera '{camera}': read error: {e}")
                });
            }
            Event::Tf(Err(e)) => self
                .log
                .warn("tf_read", || format!("/tf_static: read error: {e}")),
        }
    }

    fn offer(&mut self, job: Job) {
        if self.slot.offer(job) {
            let dropped = self.slot.dropped();
            lock(self.stats).gpu_dropped = dropped;
            tracing::debug!("a pending set was replaced (dropped: {dropped})");
        }
    }
}

fn worker_loop(shared: &WorkerShared<'_>, mut host: EngineHost, outputs: &Outputs) {
    let slot = shared.slot;
    let mut log = RateLimited::default();
    let mut published: u64 = 0;
    while let Some(job) = slot.take() {
        let started = Instant::now();
        // Parameter changes apply from the next set on.
        let sweep: SweepParams = shared.live.sweep();
        let out = match host.process(&job, &sweep, outputs.points.is_some()) {
            Ok(out) => out,
            Err(skip) => {
                log.warn(&skip.key, || format!("{skip}; skipping this set"));
                continue;
            }
        };
        let stamp = out.header.stamp;
        let points = match (&outputs.points, out.points) {
            (Some(publisher), Some(cloud)) => Some(
                publisher
                    .publish(cloud)
                    .map_err(|e| format!("points: {e:?}")),
            ),
            _ => None,
        };
        let results = [
            outputs
                .depth
                .publish(out.depth)
                .map_err(|e| format!("depth/image: {e:?}")),
            outputs
                .depth_info
                .publish(out.depth_info)
                .map_err(|e| format!("depth/camera_info: {e:?}")),
            outputs
                .confidence
                .publish(out.confidence)
                .map_err(|e| format!("confidence/image: {e:?}")),
            outputs
                .cost
                .publish(out.cost)
                .map_err(|e| format!("cost/image: {e:?}")),
            outputs
                .selection
                .publish(out.selection)
                .map_err(|e| format!("selection/image: {e:?}")),
        ];
        for r in results.into_iter().chain(points) {
            if let Err(e) = r {
                log.warn("publish", || format!("publish failed: {e}"));
            }
        }
        lock(shared.stats).on_published(started.elapsed(), Instant::now(), wall_time_now(), stamp);
        published += 1;
        if published == 1 || published % 100 == 0 {
            log_info(&format!(
                "published {published} depth images ({} sets dropped waiting for the GPU)",
                slot.dropped()
            ));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn config_resolves_topics_in_namespace_with_remaps() {
        let cfg = NodeConfig::from_args(
            &args(&[
                "--ros-args",
                "-r",
                "__ns:=/rig",
                "-r",
                "/rig/b/image_raw:=/other/image",
                "-p",
                "cameras:=[a, b, c]",
                "-p",
                "sync:=exact",
            ]),
            Some("7"),
        )
        .unwrap();
        assert_eq!(cfg.identity.name, "sweepdepth");
        assert_eq!(cfg.domain_id, 7);
        assert_eq!(cfg.reference, 1);
        assert_eq!(
            cfg.image_topics,
            vec!["/rig/a/image_raw", "/other/image", "/rig/c/image_raw"]
        );
        assert_eq!(cfg.info_topics[0], "/rig/a/camera_info");
        assert_eq!(cfg.output_topics[0], "/rig/depth/image");
        assert_eq!(cfg.tf_static_topic, "/tf_static");
        assert_eq!(cfg.points_topic, "/rig/points");
        assert_eq!(cfg.diagnostics_topic, "/diagnostics");
        assert!(!cfg.publish_points);
        assert_eq!(cfg.sync, SyncPolicy::Exact);
        assert!(cfg.synchronizer(cfg.cameras.len()).is_ok());
    }

    #[test]
    fn config_errors() {
        assert!(NodeConfig::from_args(&args(&["--ros-args"]), None).is_err());
        assert!(matches!(
            NodeConfig::from_args(
                &args(&["extra", "--ros-args", "-p", "cameras:=[a, b]"]),
                None
            ),
            Err(NodeError::ExtraArgs(_))
        ));
        assert!(NodeConfig::from_args(
            &args(&["--ros-args", "-p", "cameras:=[a, b]"]),
            Some("999")
        )
        .is_err());
        assert!(NodeConfig::from_args(
            &args(&[
                "--ros-args",
                "-p",
                "cameras:=[a, b]",
                "-p",
                "rig_file:=/nonexistent.yaml"
            ]),
            None
        )
        .is_err());
    }

    #[test]
    fn config_virtual_reference() {
        let base = [
            "--ros-args",
            "-p",
            "cameras:=[a, b, c]",
            "-p",
            "virtual_reference:=true",
            "-p",
            "virtual_width:=64",
            "-p",
            "virtual_pose:=[0.15, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]",
        ];
        let cfg = NodeConfig::from_args(&args(&base), None).unwrap();
        assert_eq!(cfg.sweep.pairs, crate::sweep::PairSet::All);
        let v = cfg.virtual_ref.unwrap();
        assert_eq!(v.width, 64);
        assert_eq!(v.ref_from_virtual.translation.x, 0.15);
        let mut explicit = args(&base);
        explicit.extend(args(&["-p", "pairs:=reference"]));
        let e = NodeConfig::from_args(&explicit, None).unwrap_err();
        assert!(e.to_string().contains("pairs = all"), "{e}");
        let mut bad_pose = args(&base);
        bad_pose.extend(args(&["-p", "virtual_pose:=[1.0, 2.0]"]));
        let e = NodeConfig::from_args(&bad_pose, None).unwrap_err();
        assert!(e.to_string().contains("7 values"), "{e}");
        let plain = NodeConfig::from_args(&args(&base[..3]), None).unwrap();
        assert!(plain.virtual_ref.is_none());
    }

    #[test]
    fn rate_limited_suppresses_repeats() {
        let mut log = RateLimited::default();
        log.warn("k", || "first".into());
        let mut called = false;
        log.warn("k", || {
            called = true;
            String::new()
        });
        assert!(!called);
    }
}
