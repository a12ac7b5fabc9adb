//! What the pipeline is told ([`PipelineConfig`]): the cameras and their topics, how their
//! images are synchronised, where the calibration comes from (CameraInfo and `/tf_static`, or
//! a rig file), the virtual reference camera, the engine parameters and the output topics.
//! Made from a `--ros-args` command line (the node's, or the equivalent one `bag` builds)
//! through the node's parameter table, with every name resolved as rcl resolves it.

use std::time::Duration;

use glam::{DQuat, DVec3};

use super::outcome::InputImage;
use super::output_list::OutputTopics;
use crate::geometry::{GeometryError, PinholeIntrinsics, RigidTransform};
use crate::params::checks::check_start;
use crate::params::{apply_to_sweep, NodeValues, ParamError, ParamSet, ParamValue};
use crate::rig_file::{load_rig_file, RigFile, RigFileError};
use crate::ros::args::{parse_ros_args, NodeIdentity, RosArgs, RosArgsError, DEFAULT_NODE_NAME};
use crate::ros::camera_info::ImageKind;
use crate::ros::sync::{ApproximateSync, ExactSync, SyncError, Synchronizer, TimeRules};
use crate::sweep::{RigShape, SweepParams};

/// Why a configuration cannot be made.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error(transparent)]
    Args(#[from] RosArgsError),
    #[error(transparent)]
    Fusion(#[from] crate::fusion::FusionError),
    #[error(transparent)]
    Param(#[from] ParamError),
    /// A required parameter with no value, and why none reached the node.
    #[error("{error}; {hint}")]
    Unconfigured { error: String, hint: String },
    #[error("unexpected arguments {0:?}: `sweepdepth node` takes only `--ros-args ...`")]
    ExtraArgs(Vec<String>),
    #[error(transparent)]
    RigFile(#[from] RigFileError),
    #[error("rig file '{path}' has no camera for '{camera}'")]
    RigFileCamera { path: String, camera: String },
    #[error(transparent)]
    Geometry(#[from] GeometryError),
    #[error(transparent)]
    Sync(#[from] SyncError),
    #[error("parameter 'image_kinds' has {kinds} entries but 'cameras' has {cameras}: give one (raw, rect or auto) per camera, or none")]
    ImageKindsCount { kinds: usize, cameras: usize },
    #[error("parameter 'references': '{reference}' is not one of cameras [{}]", cameras.join(", "))]
    UnknownReference {
        reference: String,
        cameras: Vec<String>,
    },
    #[error("parameters 'references' and 'virtual_reference' cannot be used together: a virtual camera is one reference of its own")]
    ReferencesWithVirtual,
    #[error("parameter '{name}': {value} does not fit a {what}")]
    Size {
        name: &'static str,
        value: i64,
        what: &'static str,
    },
}

/// Time synchronisation of the camera images.
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
    fn from_values(node: &NodeValues) -> Result<Self, ConfigError> {
        let pose = node.virtual_pose()?;
        let ref_from_virtual = RigidTransform::from_quat_translation(
            "virtual_pose",
            DQuat::from_xyzw(pose[3], pose[4], pose[5], pose[6]),
            DVec3::new(pose[0], pose[1], pose[2]),
        )?;
        let size = |name: &'static str, value: i64| -> Result<u32, ConfigError> {
            u32::try_from(value).map_err(|_| ConfigError::Size {
                name,
                value,
                what: "u32",
            })
        };
        Ok(Self {
            frame_id: node.virtual_frame_id.clone(),
            ref_from_virtual,
            width: size("virtual_width", node.virtual_width)?,
            height: size("virtual_height", node.virtual_height)?,
            fx: node.virtual_fx,
            fy: node.virtual_fy,
            cx: node.virtual_cx,
            cy: node.virtual_cy,
        })
    }

    /// The virtual intrinsics, 0 values taken from the reference camera's `base`.
    pub fn intrinsics(&self, base: &PinholeIntrinsics) -> PinholeIntrinsics {
        let or = |v: f64, b: f64| if v == 0.0 { b } else { v };
        let or_size = |v: u32, b: u32| if v == 0 { b } else { v };
        PinholeIntrinsics {
            width_px: or_size(self.width, base.width_px),
            height_px: or_size(self.height, base.height_px),
            fx_px: or(self.fx, base.fx_px),
            fy_px: or(self.fy, base.fy_px),
            cx_px: or(self.cx, base.cx_px),
            cy_px: or(self.cy, base.cy_px),
        }
    }
}

/// Live fusion (`fusion`): the grid's parameters, how often the mesh goes out and where.
#[derive(Debug, Clone, PartialEq)]
pub struct FusionConfig {
    /// `voxel_size`, `max_blocks`; the depth range of the sweep.
    pub params: crate::fusion::FusionParams,
    /// `mesh_rate` (Hz; 0: the mesh is only saved).
    pub mesh_rate_hz: f64,
    /// `fusion_device`: where it integrates ([`super::fusion_gpu`] decides).
    pub device: crate::engine::Device,
}

/// A moving rig: where its poses come from (`world_frame`, `tf_timeout`).
#[derive(Debug, Clone, PartialEq)]
pub struct WorldConfig {
    /// The fixed frame the rig moves in.
    pub frame: String,
    /// The resolved name of `/tf`.
    pub tf_topic: String,
    /// How long a set waits for `/tf` to reach its stamp.
    pub tf_timeout: Duration,
}

/// The virtual reference camera, when `virtual_reference` is set (its pairs default to all,
/// in `params`).
fn virtual_config(
    node: &NodeValues,
    params: &mut ParamSet,
    notes: &mut Vec<String>,
) -> Result<Option<VirtualConfig>, ConfigError> {
    Ok(if node.virtual_reference {
        // NodeValues::check rejected an explicit pairs:=reference; the default becomes all.
        if params.get_str("pairs")? != "all" {
            params.set("pairs", &ParamValue::String("all".into()))?;
            notes.push(
                "virtual_reference: pairs set to 'all' (a virtual camera has no image of its own)"
                    .into(),
            );
        }
        let v = VirtualConfig::from_values(node)?;
        if v.frame_id.is_empty() && v.ref_from_virtual != RigidTransform::IDENTITY {
            notes.push("virtual_reference: virtual_frame_id is empty, so the outputs carry the reference camera's frame_id although the virtual camera is at virtual_pose in it".into());
        }
        Some(v)
    } else {
        None
    })
}

/// Each reference camera (index in `cameras`) with its output topics: the one of `listed` (or
/// the `reference` camera) under the node's own names, or each of several under its name.
fn reference_outputs(
    listed: &[String],
    cameras: &[String],
    reference: usize,
    publish_points: bool,
    resolve: &dyn Fn(&str) -> Result<String, RosArgsError>,
) -> Result<Vec<(usize, OutputTopics)>, ConfigError> {
    let mut references = Vec::new();
    if listed.len() <= 1 {
        let index = match listed.first() {
            Some(name) => cameras.iter().position(|c| c == name).ok_or_else(|| {
                ConfigError::UnknownReference {
                    reference: name.clone(),
                    cameras: cameras.to_vec(),
                }
            })?,
            None => reference,
        };
        references.push((index, output_topics("", publish_points, &resolve)?));
    } else {
        // (The parameter's range refused repeated names.)
        for name in listed {
            let index = cameras.iter().position(|c| c == name).ok_or_else(|| {
                ConfigError::UnknownReference {
                    reference: name.clone(),
                    cameras: cameras.to_vec(),
                }
            })?;
            references.push((index, output_topics(name, publish_points, &resolve)?));
        }
    }
    Ok(references)
}

/// Fusion's settings, when `fusion` is set (checked; its depth range is the sweep's).
fn fusion_config(
    node: &NodeValues,
    sweep: &SweepParams,
) -> Result<Option<FusionConfig>, ConfigError> {
    Ok(if node.fusion {
        Some(FusionConfig::new(
            node,
            sweep.min_depth_m,
            sweep.max_depth_m,
        )?)
    } else {
        None
    })
}

impl FusionConfig {
    /// Fusion's settings from `voxel_size`, `max_blocks`, `mesh_rate` and `fusion_device`,
    /// fusing the depths from `min_depth_m` to `max_depth_m` (checked).
    pub fn new(
        node: &NodeValues,
        min_depth_m: f64,
        max_depth_m: f64,
    ) -> Result<Self, crate::fusion::FusionError> {
        let fusion = FusionConfig {
            params: crate::fusion::FusionParams {
                voxel_size_m: node.voxel_size_m as f32,
                max_blocks: usize::try_from(node.max_blocks).unwrap_or(usize::MAX),
                min_depth_m: min_depth_m as f32,
                max_depth_m: max_depth_m as f32,
                ..crate::fusion::FusionParams::default()
            },
            mesh_rate_hz: node.mesh_rate_hz,
            device: node.fusion_device.parse().unwrap_or_default(),
        };
        fusion.params.validate()?;
        Ok(fusion)
    }
}

/// The rig file of `rig_file`, when set: loaded, and holding every camera.
fn rig_file(
    node: &NodeValues,
    cameras: &[String],
    notes: &mut Vec<String>,
) -> Result<Option<RigFile>, ConfigError> {
    let rig_path = node.rig_file.as_str();
    Ok(if rig_path.is_empty() {
        None
    } else {
        let file = load_rig_file(rig_path)?;
        for camera in cameras {
            if file.camera_for(camera).is_none() {
                return Err(ConfigError::RigFileCamera {
                    path: rig_path.to_string(),
                    camera: camera.clone(),
                });
            }
        }
        notes.extend(file.notes.iter().cloned());
        for note in file.topic_notes(cameras).into_iter().chain(file.doubts()) {
            tracing::warn!("{note}");
        }
        Some(file)
    })
}

/// The output topics of a reference whose outputs live under `prefix` ("" for the node's
/// own names), resolved by `resolve`.
fn output_topics(
    prefix: &str,
    points: bool,
    resolve: &dyn Fn(&str) -> Result<String, RosArgsError>,
) -> Result<OutputTopics, ConfigError> {
    let name = |base: &str| {
        if prefix.is_empty() {
            resolve(base)
        } else {
            resolve(&format!("{}/{base}", prefix.trim_end_matches('/')))
        }
    };
    Ok(OutputTopics::new(points, name)?)
}

/// Each camera's [`ImageKind`]: `image_kinds` (one entry per camera, `raw`, `rect` or `auto`),
/// else (empty, or `auto`) the name of its resolved image topic; a name that says neither is
/// taken as raw, with a note.
fn image_kinds(
    node: &NodeValues,
    cameras: &[String],
    image_topics: &[String],
    notes: &mut Vec<String>,
) -> Result<Vec<ImageKind>, ConfigError> {
    let declared = &node.image_kinds;
    if !declared.is_empty() && declared.len() != cameras.len() {
        return Err(ConfigError::ImageKindsCount {
            kinds: declared.len(),
            cameras: cameras.len(),
        });
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

/// Everything the pipeline needs, from the command line.
#[derive(Debug, Clone)]
pub struct PipelineConfig {
    /// The node's name and namespace (names resolve against them).
    pub identity: NodeIdentity,
    /// Every parameter's value at start-up (the node declares them on its services).
    pub params: ParamSet,
    /// The node's own parameters (not the engine's) of `params`, typed.
    pub node: NodeValues,
    pub sweep: SweepParams,
    pub cameras: Vec<String>,
    /// Every reference camera (`references`; the one of `reference` when that list is empty),
    /// never empty, as indices into `cameras`, each with its output topics: with one reference
    /// those of the node (`depth/image`, ...), with several under its camera's namespace
    /// (`<camera>/depth/image`, ...).
    pub references: Vec<(usize, OutputTopics)>,
    /// A moving rig (`world_frame`): the fixed frame, `/tf`'s resolved name, and how long a set
    /// waits for its pose (`tf_timeout`).
    pub world: Option<WorldConfig>,
    /// Live fusion, when `fusion` is true.
    pub fusion: Option<FusionConfig>,
    /// The resolved name of `mesh` (fusion's markers).
    pub mesh_topic: String,
    /// Fully qualified (remapped) image and camera_info topic names, per camera.
    pub image_topics: Vec<String>,
    /// What each camera's image topic carries, raw or rectified (`image_kinds`, else the
    /// topic's name): which part of its CameraInfo describes it.
    pub image_kinds: Vec<ImageKind>,
    pub info_topics: Vec<String>,
    /// `image_transport: compressed`: the images come as `sensor_msgs/CompressedImage` on
    /// [`PipelineConfig::compressed_topics`] (image_transport's `compressed` plugin).
    pub compressed_inputs: bool,
    pub tf_static_topic: String,
    pub rig_file: Option<RigFile>,
    pub sync: SyncPolicy,
    pub queue_size: usize,
    pub time_rules: TimeRules,
    /// A camera silent this long leaves the rig until it sends again (`None`: never).
    pub camera_timeout: Option<Duration>,
    /// The virtual reference camera, when `virtual_reference` is true.
    pub virtual_ref: Option<VirtualConfig>,
    /// What was accepted and ignored or adjusted, for the log.
    pub notes: Vec<String>,
}

impl PipelineConfig {
    /// Index of the first reference camera in `cameras` (`references[0]`): the one whose
    /// frame anchors the rig, and the one a virtual camera stands in for.
    pub fn reference(&self) -> usize {
        self.references[0].0
    }

    /// The first reference's output topics (`references[0]`): with one reference, the node's.
    pub fn outputs(&self) -> &OutputTopics {
        &self.references[0].1
    }

    /// Per camera, its compressed image topic: `<image topic>/compressed`, as image_transport
    /// names it (after the remapping of the image topic).
    pub fn compressed_topics(&self) -> Vec<String> {
        self.image_topics
            .iter()
            .map(|t| format!("{t}/compressed"))
            .collect()
    }

    /// Camera `i`'s image topic as subscribed: `<image topic>/compressed` with
    /// `image_transport: compressed`, else the image topic.
    pub fn input_image_topic(&self, i: usize) -> String {
        let topic = self.image_topics.get(i).cloned().unwrap_or_default();
        if self.compressed_inputs {
            format!("{topic}/compressed")
        } else {
            topic
        }
    }

    /// The `device` parameter: which engine runs the sweep (checked against its range when
    /// the parameters were read; `auto` if it were ever unknown).
    pub fn device(&self) -> crate::engine::Device {
        self.node.device.parse().unwrap_or_default()
    }

    /// From a command line holding only a `--ros-args` block.
    pub fn from_args(args: &[String]) -> Result<Self, ConfigError> {
        let ros = parse_ros_args(args)?;
        if !ros.other.is_empty() {
            return Err(ConfigError::ExtraArgs(ros.other.clone()));
        }
        Self::from_ros_args(&ros)
    }

    /// From a parsed command line: the parameters (defaults, parameter files, `-p`) checked
    /// against each other and against the rig's shape, every topic name resolved.
    pub fn from_ros_args(ros: &RosArgs) -> Result<Self, ConfigError> {
        let identity = ros.node_identity(DEFAULT_NODE_NAME, "/")?;
        let (mut params, mut notes) = ParamSet::from_ros_args(ros, &identity)?;
        notes.extend(ros.notes.iter().cloned());
        let node = NodeValues::read(&params)?;
        node.check(&params).map_err(|e| match e {
            ParamError::Required { .. } => {
                match crate::params::set::unmatched_params_hint(
                    ros,
                    &identity.fqn(),
                    "cameras:=[cam0, cam1, ...]",
                ) {
                    Some(hint) => ConfigError::Unconfigured {
                        error: e.to_string(),
                        hint,
                    },
                    None => ConfigError::Param(e),
                }
            }
            e => ConfigError::Param(e),
        })?;
        let virtual_ref = virtual_config(&node, &mut params, &mut notes)?;
        let mut sweep = SweepParams::default();
        apply_to_sweep(&params, &mut sweep)?;
        let cameras = node.cameras.clone();
        // NodeValues::check made sure the reference is one of the cameras.
        let reference_name = node.reference_camera().unwrap_or_default();
        let reference = cameras
            .iter()
            .position(|c| *c == reference_name)
            .ok_or_else(|| ParamError::UnknownReference {
                reference: reference_name.clone(),
                cameras: cameras.clone(),
            })?;
        let image_topic = &node.image_topic;
        let resolve = |name: &str| ros.resolve_topic(name, &identity);
        let mut image_topics = Vec::new();
        let mut info_topics = Vec::new();
        for camera in &cameras {
            let camera = camera.trim_end_matches('/');
            image_topics.push(resolve(&format!("{camera}/{image_topic}"))?);
            info_topics.push(resolve(&format!("{camera}/camera_info"))?);
        }
        let image_kinds = image_kinds(&node, &cameras, &image_topics, &mut notes)?;
        let listed = &node.references;
        if !listed.is_empty() && virtual_ref.is_some() {
            return Err(ConfigError::ReferencesWithVirtual);
        }
        let references =
            reference_outputs(listed, &cameras, reference, node.publish_points, &resolve)?;
        let world = if node.world_frame.is_empty() {
            None
        } else {
            Some(WorldConfig {
                frame: node.world_frame.clone(),
                tf_topic: resolve("/tf")?,
                tf_timeout: Duration::from_secs_f64(node.tf_timeout_s),
            })
        };
        let fusion = fusion_config(&node, &sweep)?;
        let mesh_topic = resolve("mesh")?;
        let tf_static_topic = resolve("/tf_static")?;
        let rig_file = rig_file(&node, &cameras, &mut notes)?;
        let sync = match node.sync.as_str() {
            "exact" => SyncPolicy::Exact,
            _ => SyncPolicy::Approximate {
                max_interval_ns: seconds_to_ns(node.sync_max_interval_s),
                age_penalty: node.age_penalty,
            },
        };
        let time_rules = TimeRules {
            future_window_ns: seconds_to_ns(node.sync_future_window_s),
            reset_backwards_ns: seconds_to_ns(node.sync_reset_backwards_s),
        };
        let queue_size = {
            let value = node.queue_size;
            usize::try_from(value).map_err(|_| ConfigError::Size {
                name: "queue_size",
                value,
                what: "usize",
            })?
        };
        // The engine parameters against the rig's shape, before any frame arrives.
        let virtual_reference = virtual_ref.is_some();
        check_start(
            &sweep,
            RigShape::chosen_views(cameras.len(), !virtual_reference),
        )?;
        let config = Self {
            identity,
            sweep,
            cameras,
            references,
            world,
            fusion,
            mesh_topic,
            image_topics,
            image_kinds,
            info_topics,
            compressed_inputs: node.image_transport == "compressed",
            tf_static_topic,
            rig_file,
            sync,
            queue_size,
            time_rules,
            camera_timeout: {
                let t = node.camera_timeout_s;
                (t > 0.0).then(|| Duration::from_secs_f64(t))
            },
            virtual_ref,
            params,
            node,
            notes,
        };
        // The synchroniser is made now so that its parameters fail here, not at the first image.
        config.synchronizer(config.cameras.len())?;
        Ok(config)
    }

    /// A synchroniser over `n` of the cameras.
    pub fn synchronizer(
        &self,
        n: usize,
    ) -> Result<Box<dyn Synchronizer<InputImage> + Send>, SyncError> {
        Ok(match &self.sync {
            SyncPolicy::Exact => {
                Box::new(ExactSync::new(n, self.queue_size)?.with_time_rules(self.time_rules)?)
            }
            SyncPolicy::Approximate {
                max_interval_ns,
                age_penalty,
            } => Box::new(
                ApproximateSync::new(n, self.queue_size)?
                    .with_age_penalty(*age_penalty)?
                    .with_max_interval_ns(*max_interval_ns)?
                    .with_time_rules(self.time_rules)?,
            ),
        })
    }
}

fn seconds_to_ns(seconds: f64) -> i64 {
    (seconds * 1e9).round() as i64
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::output_list::Output;

    fn args(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn config_resolves_topics_in_namespace_with_remaps() {
        let cfg = PipelineConfig::from_args(&args(&[
            "--ros-args",
            "-r",
            "__ns:=/rig",
            "-r",
            "/rig/b/image_raw:=/other/image",
            "-p",
            "cameras:=[a, b, c]",
            "-p",
            "sync:=exact",
        ]))
        .unwrap();
        assert_eq!(cfg.identity.name, "sweepdepth");
        assert_eq!(cfg.reference(), 1);
        assert_eq!(
            cfg.image_topics,
            vec!["/rig/a/image_raw", "/other/image", "/rig/c/image_raw"]
        );
        assert_eq!(cfg.info_topics[0], "/rig/a/camera_info");
        assert_eq!(cfg.outputs().depth(), "/rig/depth/image");
        assert_eq!(
            cfg.outputs().get(Output::DepthInfo),
            Some("/rig/depth/camera_info")
        );
        assert_eq!(
            cfg.outputs().get(Output::Selection),
            Some("/rig/selection/image")
        );
        assert_eq!(cfg.outputs().get(Output::Points), None);
        assert_eq!(cfg.tf_static_topic, "/tf_static");
        assert_eq!(cfg.sync, SyncPolicy::Exact);
        assert_eq!(cfg.time_rules, TimeRules::default());
        let with_points = PipelineConfig::from_args(&args(&[
            "--ros-args",
            "-r",
            "__ns:=/rig",
            "-p",
            "cameras:=[a, b]",
            "-p",
            "publish_points:=true",
        ]))
        .unwrap();
        assert_eq!(
            with_points.outputs().get(Output::Points),
            Some("/rig/points")
        );
    }

    /// The stamps (ns) of the set that the configuration's synchroniser emits when camera b
    /// sends images stamped 0 and 32 ms and then camera a one stamped 20 ms.
    fn chosen_stamps(cfg: &PipelineConfig) -> Vec<i64> {
        const MS: i64 = 1_000_000;
        let mut sync = cfg.synchronizer(2).unwrap();
        let image = || InputImage::Raw(crate::msgs::Image::default());
        assert!(sync.push(1, 0, image()).unwrap().sets.is_empty());
        assert!(sync.push(1, 32 * MS, image()).unwrap().sets.is_empty());
        let sets = sync.push(0, 20 * MS, image()).unwrap().sets;
        assert_eq!(sets.len(), 1);
        sets[0].stamps_ns.clone()
    }

    /// `age_penalty` reaches the approximate synchroniser the configuration builds: with the
    /// default (0.1) the tighter, newer set {20, 32} ms is chosen; with `age_penalty:=1.0` the
    /// older set {20, 0} ms is kept (see the policy's `approx_age_penalty_favours_the_older_set`).
    #[test]
    fn config_age_penalty_reaches_the_synchroniser() {
        const MS: i64 = 1_000_000;
        let with = |extra: &[&str]| {
            let mut a = args(&["--ros-args", "-p", "cameras:=[a, b]"]);
            a.extend(args(extra));
            PipelineConfig::from_args(&a).unwrap()
        };
        let default = with(&[]);
        let penalised = with(&["-p", "age_penalty:=1.0"]);
        assert!(matches!(
            penalised.sync,
            SyncPolicy::Approximate { age_penalty, .. } if age_penalty == 1.0
        ));
        assert_eq!(chosen_stamps(&default), vec![20 * MS, 32 * MS]);
        assert_eq!(
            chosen_stamps(&penalised),
            vec![20 * MS, 0],
            "age_penalty 1.0 must keep the older set"
        );
    }

    /// No `cameras` reached the node: the error says why (no parameter file; a file whose
    /// sections are for another node, named, with the remap that fixes it) and not where a
    /// section applies (then the parameter itself is wrong).
    #[test]
    fn missing_cameras_say_why_no_parameter_reached_the_node() {
        let dir = std::env::temp_dir().join(format!("sweepdepth-config-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("rig.params.yaml");
        std::fs::write(
            &file,
            "/rig/sweepdepth:\n  ros__parameters:\n    cameras: [a, b]\n",
        )
        .unwrap();
        let error = |extra: &[&str]| {
            let mut a = args(&["--ros-args"]);
            a.extend(args(extra));
            PipelineConfig::from_args(&a)
                .map(|_| ())
                .unwrap_err()
                .to_string()
        };
        let none = error(&[]);
        assert!(none.contains("no parameter file given"), "{none}");
        let path = file.to_str().unwrap();
        let other = error(&["--params-file", path]);
        assert!(
            other.contains("no section of the parameter file is for this node (/sweepdepth)")
                && other.contains("'/rig/sweepdepth' in")
                && other.contains("-r __ns:=/ns"),
            "{other}"
        );
        // With the namespace the file's section is for, it applies.
        let mut a = args(&["--ros-args", "--params-file", path, "-r", "__ns:=/rig"]);
        a.extend(args(&[]));
        assert!(PipelineConfig::from_args(&a).is_ok());
        // A section that applies but names one camera: the parameter's own error alone.
        std::fs::write(&file, "/**:\n  ros__parameters:\n    cameras: [a]\n").unwrap();
        let one = error(&["--params-file", path]);
        assert!(
            one.contains("needs at least 2 entries, got 1") && !one.contains("no section"),
            "{one}"
        );
    }

    #[test]
    fn config_errors() {
        assert!(PipelineConfig::from_args(&args(&["--ros-args"])).is_err());
        assert!(matches!(
            PipelineConfig::from_args(&args(&["extra", "--ros-args", "-p", "cameras:=[a, b]"])),
            Err(ConfigError::ExtraArgs(_))
        ));
        assert!(matches!(
            PipelineConfig::from_args(&args(&[
                "--ros-args",
                "-p",
                "cameras:=[a, b]",
                "-p",
                "rig_file:=/nonexistent.yaml"
            ])),
            Err(ConfigError::RigFile(_))
        ));
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
        let cfg = PipelineConfig::from_args(&args(&base)).unwrap();
        assert_eq!(cfg.sweep.pairs, crate::sweep::PairSet::All);
        let v = cfg.virtual_ref.unwrap();
        assert_eq!(v.width, 64);
        assert_eq!(v.ref_from_virtual.translation.x, 0.15);
        let mut explicit = args(&base);
        explicit.extend(args(&["-p", "pairs:=reference"]));
        let e = PipelineConfig::from_args(&explicit).unwrap_err();
        assert!(e.to_string().contains("pairs = all"), "{e}");
        let mut bad_pose = args(&base);
        bad_pose.extend(args(&["-p", "virtual_pose:=[1.0, 2.0]"]));
        let e = PipelineConfig::from_args(&bad_pose).unwrap_err();
        assert!(e.to_string().contains("7 values"), "{e}");
        let plain = PipelineConfig::from_args(&args(&base[..3])).unwrap();
        assert!(plain.virtual_ref.is_none());
    }

    #[test]
    fn config_references_topics_and_bad_lists() {
        let with = |extra: &[&str]| {
            let mut a = args(&["--ros-args", "-r", "__ns:=/rig", "-p", "cameras:=[a, b, c]"]);
            a.extend(args(extra));
            PipelineConfig::from_args(&a)
        };
        // One reference (or none listed): the node's own topic names, as always.
        let one = with(&["-p", "references:=[c]"]).unwrap();
        assert_eq!(one.reference(), 2);
        assert_eq!(one.references.len(), 1);
        assert_eq!(one.outputs().depth(), "/rig/depth/image");
        let none = with(&[]).unwrap();
        assert_eq!(none.references, vec![(1, none.outputs().clone())]);
        assert!(none.world.is_none());
        // Several: each under its camera's namespace, remaps apply as to any topic.
        let two = with(&[
            "-p",
            "references:=[c, a]",
            "-r",
            "/rig/a/depth/image:=/left_depth",
        ])
        .unwrap();
        assert_eq!(two.reference(), 2);
        assert_eq!(two.references[0].1.depth(), "/rig/c/depth/image");
        assert_eq!(
            two.references[0].1.get(Output::Selection).unwrap(),
            "/rig/c/selection/image"
        );
        assert_eq!(two.references[1].1.depth(), "/left_depth");
        assert_eq!(
            two.references[1].1.get(Output::DepthInfo),
            Some("/rig/a/depth/camera_info")
        );
        // Bad lists: clear errors at start.
        let e = with(&["-p", "references:=[a, d]"]).unwrap_err();
        assert!(e.to_string().contains("'d' is not one of cameras"), "{e}");
        let e = with(&["-p", "references:=[a, b, a]"]).unwrap_err();
        assert!(e.to_string().contains("'a' appears more than once"), "{e}");
        let e = with(&["-p", "references:=[a, b]", "-p", "virtual_reference:=true"]).unwrap_err();
        assert!(e.to_string().contains("virtual_reference"), "{e}");
        // A moving rig.
        let moving = with(&["-p", "world_frame:=odom", "-p", "tf_timeout:=0.25"]).unwrap();
        let world = moving.world.expect("world");
        assert_eq!(world.frame, "odom");
        assert_eq!(world.tf_topic, "/tf");
        assert_eq!(world.tf_timeout, Duration::from_millis(250));
    }

    /// Any number of cameras starts with the defaults: each reference sweeps with its best
    /// views (8), so per-pair aggregation's 16 pairs bound `max_neighbours`, not the rig.
    #[test]
    fn a_rig_of_many_cameras_starts_with_the_defaults() {
        let rig = |n: usize, extra: &[&str]| {
            let names: Vec<String> = (0..n).map(|i| format!("c{i}")).collect();
            let mut a = args(&["--ros-args", "-p"]);
            a.push(format!("cameras:=[{}]", names.join(", ")));
            a.extend(args(extra));
            PipelineConfig::from_args(&a)
        };
        for n in [17, 18, 24, 40] {
            rig(n, &[]).unwrap_or_else(|e| panic!("{n} cameras: {e}"));
            rig(n, &["-p", "max_neighbours:=16"])
                .unwrap_or_else(|e| panic!("{n} cameras, 16 views: {e}"));
        }
        let e = rig(24, &["-p", "max_neighbours:=17"]).unwrap_err();
        assert!(e.to_string().contains("at most 16"), "{e}");
        // A virtual reference sweeps every camera: all pairs of 24 are too many to aggregate
        // per pair, and the message names the parameters.
        let e = rig(24, &["-p", "virtual_reference:=true"]).unwrap_err();
        assert!(
            e.to_string()
                .contains("aggregation per_pair with pairs all holds at most 16 camera pairs"),
            "{e}"
        );
    }
}
