//! The node's processing pipeline without DDS: what the live node (`node`) and the offline bag
//! processor (`bag`) both run, so that a bag and the same bag played live give the same depth.
//!
//! [`Pipeline`] takes the input messages one at a time (images, camera infos, `/tf_static`),
//! keeps the latest CameraInfo per camera and the transform tree, synchronises the images and
//! turns each complete set into a [`Job`] (images + calibration), or a [`Skip`] that says why
//! the set cannot be processed yet. [`process_job`] runs a job through the engine and builds the
//! output messages ([`FrameOutputs`]); the caller publishes or records them.

use crate::geometry::{
    check_image_size, CameraModel, PinholeIntrinsics, Reference, Rig, RigCamera, RigidTransform,
};
use crate::msgs::{CameraInfo, Header, Image, PointCloud2, TFMessage};
use crate::ros::sync::{SyncError, SyncStats, SyncedSet, Synchronizer};
use crate::ros::tf::TfBuffer;
use crate::sweep::gpu::GpuEngine;
use crate::sweep::SweepParams;

use super::convert::{f32_image_msg, image_to_rgba8, point_cloud_msg, selection_msg};
use super::diag::time_rule_notices;
use super::{NodeConfig, NodeError};

/// One synchronised set with its calibration, ready for the engine.
#[derive(Debug, Clone)]
pub struct Job {
    pub images: Vec<Image>,
    pub cameras: Vec<RigCamera>,
    pub reference: usize,
    /// The virtual reference camera and the outputs' frame_id, when configured.
    pub virtual_ref: Option<(CameraModel, RigidTransform, String)>,
    /// The CameraInfo of the outputs (the reference camera's, or the virtual one's).
    pub ref_info: CameraInfo,
}

impl Job {
    /// The stamp of the outputs: the reference camera's input stamp.
    pub fn stamp(&self) -> crate::msgs::Time {
        self.images
            .get(self.reference)
            .map(|m| m.header.stamp)
            .unwrap_or_default()
    }
}

/// Why a set or a message was not processed. `kind` is a short stable category (used to count
/// skips in the bag summary and to rate-limit log lines), `key` is unique per camera and kind,
/// `message` says precisely what is wrong.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Skip {
    pub kind: &'static str,
    pub key: String,
    pub message: String,
}

impl Skip {
    fn new(kind: &'static str, key: String, message: String) -> Self {
        Self { kind, key, message }
    }
}

impl std::fmt::Display for Skip {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

/// The input side of the node: calibration state and the synchroniser.
pub struct Pipeline<'a> {
    config: &'a NodeConfig,
    infos: Vec<Option<CameraInfo>>,
    tf: TfBuffer,
    sync: Box<dyn Synchronizer<Image> + Send>,
    /// Images the synchroniser's time rules dropped, and its resets, since the last
    /// [`Pipeline::take_notices`].
    notices: Vec<Skip>,
}

impl<'a> Pipeline<'a> {
    pub fn new(config: &'a NodeConfig) -> Result<Self, NodeError> {
        Ok(Self {
            config,
            infos: vec![None; config.cameras.len()],
            tf: TfBuffer::new(),
            sync: config.synchronizer()?,
            notices: Vec::new(),
        })
    }

    pub fn config(&self) -> &NodeConfig {
        self.config
    }

    /// The latest CameraInfo of camera `i` replaces the previous one.
    pub fn on_info(&mut self, i: usize, info: CameraInfo) {
        if let Some(slot) = self.infos.get_mut(i) {
            *slot = Some(info);
        }
    }

    /// Adds the transforms of a `/tf_static` message; returns one line per rejected transform.
    pub fn on_tf(&mut self, msg: &TFMessage) -> Vec<String> {
        self.tf
            .insert_message(msg)
            .into_iter()
            .map(|e| e.to_string())
            .collect()
    }

    /// Pushes the image of camera `i` into the synchroniser; every set it completes becomes a
    /// job or a skip.
    pub fn on_image(
        &mut self,
        i: usize,
        image: Image,
    ) -> Result<Vec<Result<Job, Skip>>, SyncError> {
        let stamp = image.header.stamp;
        let before = self.sync.stats();
        let sets = self.sync.push_stamped(i, &stamp, image)?;
        let (after, jump) = (self.sync.stats(), self.sync.last_reset());
        let config = self.config;
        self.notices
            .extend(time_rule_notices(config, i, stamp, &before, &after, jump));
        Ok(sets.into_iter().map(|set| self.on_set(set)).collect())
    }

    /// What the time rules of the synchroniser did since the last call: one [`Skip`] per
    /// dropped image (duplicate, late, far-future stamp) and per reset, each naming the camera,
    /// for the caller to log (keys per camera and rule, for rate limiting).
    pub fn take_notices(&mut self) -> Vec<Skip> {
        std::mem::take(&mut self.notices)
    }

    pub fn sync_stats(&self) -> SyncStats {
        self.sync.stats()
    }

    fn on_set(&mut self, set: SyncedSet<Image>) -> Result<Job, Skip> {
        let config = self.config;
        let reference = config.reference;
        let ref_frame = set
            .messages
            .get(reference)
            .map(|m| m.header.frame_id.clone())
            .unwrap_or_default();
        let mut cameras = Vec::with_capacity(set.messages.len());
        for (i, image) in set.messages.iter().enumerate() {
            let name = &config.cameras[i];
            let file_camera = config.rig_file.as_ref().and_then(|f| f.camera_for(name));
            let model = match (&self.infos[i], file_camera.and_then(|c| c.model)) {
                (Some(info), _) => CameraModel::from_camera_info(name, info)
                    .and_then(|model| {
                        check_image_size(name, info, image.width, image.height).map(|()| model)
                    })
                    .map_err(|e| Skip::new("camera_info", format!("model{i}"), e.to_string()))?,
                (None, Some(model)) => {
                    let k = &model.intrinsics;
                    if (image.width, image.height) != (k.width_px, k.height_px) {
                        return Err(Skip::new(
                            "rig file",
                            format!("size{i}"),
                            format!(
                                "camera '{name}': the image is {}x{} but the rig file says {}x{}",
                                image.width, image.height, k.width_px, k.height_px
                            ),
                        ));
                    }
                    model
                }
                (None, None) => {
                    let topic = &config.info_topics[i];
                    return Err(Skip::new(
                        "waiting for camera_info",
                        format!("info{i}"),
                        format!("waiting for camera_info of camera '{name}' on {topic}"),
                    ));
                }
            };
            let cam_from_rig = match (&config.rig_file, file_camera) {
                (Some(_), Some(c)) => c.cam_from_rig,
                (Some(path), None) => {
                    return Err(Skip::new(
                        "rig file",
                        format!("rig{i}"),
                        format!(
                            "camera '{name}' is not in the rig file ({} cameras)",
                            path.cameras.len()
                        ),
                    ))
                }
                (None, _) => self
                    .tf
                    .lookup(&image.header.frame_id, &ref_frame)
                    .map_err(|e| {
                        let frame = &image.header.frame_id;
                        Skip::new(
                            "waiting for transform",
                            format!("tf{i}"),
                            format!(
                                "waiting for the transform from '{ref_frame}' (reference camera) to '{frame}' (camera '{name}'): {e}"
                            ),
                        )
                    })?,
            };
            cameras.push(RigCamera {
                name: name.clone(),
                model,
                cam_from_rig,
            });
        }
        let mut virtual_ref = None;
        let ref_info = if let Some(v) = &config.virtual_ref {
            let intrinsics = v.intrinsics(&cameras[reference].model.intrinsics);
            let ref_from_rig = cameras[reference].cam_from_rig;
            let virtual_from_ref = if !v.frame_id.is_empty() && config.rig_file.is_none() {
                self.tf.lookup(&v.frame_id, &ref_frame).map_err(|e| {
                    let frame = &v.frame_id;
                    Skip::new(
                        "waiting for transform",
                        "tf_virtual".into(),
                        format!(
                            "waiting for the transform from '{ref_frame}' (reference camera) to '{frame}' (virtual_frame_id): {e}"
                        ),
                    )
                })?
            } else {
                v.ref_from_virtual.inverse()
            };
            let frame_id = if v.frame_id.is_empty() {
                ref_frame.clone()
            } else {
                v.frame_id.clone()
            };
            virtual_ref = Some((
                CameraModel::pinhole(intrinsics),
                virtual_from_ref.compose(&ref_from_rig),
                frame_id,
            ));
            intrinsics_info(&intrinsics)
        } else {
            match &self.infos[reference] {
                Some(info) => info.clone(),
                None => intrinsics_info(&cameras[reference].model.intrinsics),
            }
        };
        Ok(Job {
            images: set.messages,
            cameras,
            reference,
            virtual_ref,
            ref_info,
        })
    }
}

/// A CameraInfo of pinhole intrinsics (K and P consistent, no distortion).
pub fn intrinsics_info(k: &PinholeIntrinsics) -> CameraInfo {
    CameraInfo {
        width: k.width_px,
        height: k.height_px,
        distortion_model: "plumb_bob".into(),
        d: Vec::new(),
        k: [k.fx_px, 0.0, k.cx_px, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [
            k.fx_px, 0.0, k.cx_px, 0.0, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 0.0, 1.0, 0.0,
        ],
        ..CameraInfo::default()
    }
}

/// The messages one frame set produces, all with the same header (the reference camera's
/// stamp; its frame_id, or the virtual camera's).
#[derive(Debug, Clone)]
pub struct FrameOutputs {
    pub header: Header,
    pub depth: Image,
    pub depth_info: CameraInfo,
    pub confidence: Image,
    pub cost: Image,
    pub selection: Image,
    pub points: Option<PointCloud2>,
}

/// Runs one job through the engine with the given parameters and builds its output messages.
pub fn process_job(
    engine: &mut GpuEngine,
    job: Job,
    sweep: &SweepParams,
    camera_names: &[String],
    with_points: bool,
) -> Result<FrameOutputs, Skip> {
    let mut images = Vec::with_capacity(job.images.len());
    for (i, msg) in job.images.iter().enumerate() {
        let name = camera_names.get(i).map_or("?", String::as_str);
        images.push(
            image_to_rgba8(name, msg)
                .map_err(|e| Skip::new("image", format!("convert{i}"), e.to_string()))?,
        );
    }
    let mut header: Header = job
        .images
        .get(job.reference)
        .map(|m| m.header.clone())
        .unwrap_or_default();
    let reference = match &job.virtual_ref {
        Some((model, cam_from_rig, frame_id)) => {
            header.frame_id = frame_id.clone();
            Reference::Virtual {
                model: *model,
                cam_from_rig: *cam_from_rig,
            }
        }
        None => Reference::Camera(job.reference),
    };
    let colour = if job.virtual_ref.is_some() {
        None
    } else {
        images.get(job.reference)
    };
    let rig = Rig::new(job.cameras, reference).map_err(|e| {
        Skip::new("rig", "rig".into(), format!("cannot build the rig: {e}"))
    })?;
    let maps = engine
        .run(&rig, &images, sweep)
        .map_err(|e| Skip::new("engine", "engine".into(), format!("sweep failed: {e}")))?;
    let mut depth_info = job.ref_info;
    depth_info.header = header.clone();
    let points = with_points
        .then(|| point_cloud_msg(&header, &maps.depth_m, colour, &rig.reference_model()));
    Ok(FrameOutputs {
        depth: f32_image_msg(&header, &maps.depth_m),
        depth_info,
        confidence: f32_image_msg(&header, &maps.confidence),
        cost: f32_image_msg(&header, &maps.cost),
        selection: selection_msg(&header, maps.width(), maps.height(), &maps.selection),
        points,
        header,
    })
}
