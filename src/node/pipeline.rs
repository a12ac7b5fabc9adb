//! The node's processing pipeline without DDS: what the live node (`node`) and the offline bag
//! processor (`bag`) both run, so that a bag and the same bag played live give the same depth.
//!
//! [`Pipeline`] takes the input messages one at a time (images, camera infos, `/tf_static`),
//! keeps the latest CameraInfo per camera and the transform tree, synchronises the images and
//! turns each complete set into a [`Job`] (images + calibration), or a [`Skip`] that says why
//! the set cannot be processed yet. [`process_job`] runs a job through the engine and builds the
//! output messages ([`FrameOutputs`]); the caller publishes or records them.

use crate::geometry::{CameraModel, PinholeIntrinsics, Reference, Rig, RigCamera, RigidTransform};
use crate::msgs::{CameraInfo, Header, Image, PointCloud2, TFMessage};
use crate::ros::camera_info::{camera_from_info, check_image_size, CameraCalibration, ImageKind};
use crate::ros::sync::{SyncError, SyncStats, SyncedSet, Synchronizer};
use crate::ros::tf::{TfBuffer, TfError};
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
    /// The reference camera (the one its model describes: rotated by R for a rectified image)
    /// in the frame its image's `header.frame_id` names; the points are published in that
    /// frame. Identity for a raw image and for a virtual reference.
    pub ref_cam_from_frame: RigidTransform,
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

/// The input side of the node: calibration state, the synchroniser, and which cameras are in
/// the rig.
///
/// Camera dropout: a camera that has sent nothing for `camera_timeout` (measured on the clock
/// the caller passes: receive time live, log time in a bag) leaves the rig; the synchroniser is
/// rebuilt over the remaining cameras and sets go on with them while at least 2 remain and the
/// reference is among them. Otherwise nothing is published (never an old depth map) and every
/// set says why. A camera that sends again rejoins at once. Changes are reported through
/// [`Pipeline::take_events`].
pub struct Pipeline<'a> {
    config: &'a NodeConfig,
    infos: Vec<Option<CameraInfo>>,
    tf: TfBuffer,
    sync: Box<dyn Synchronizer<Image> + Send>,
    /// The cameras in the synchroniser, in rig order: stream `k` is camera `active[k]`.
    active: Vec<usize>,
    last_seen_ns: Vec<Option<u64>>,
    first_ns: Option<u64>,
    /// Counters of the synchronisers replaced so far (the sum stays monotonic).
    retired: SyncStats,
    events: Vec<String>,
    /// Images the synchroniser's time rules dropped, and its resets, since the last
    /// [`Pipeline::take_notices`].
    notices: Vec<Skip>,
}

impl<'a> Pipeline<'a> {
    pub fn new(config: &'a NodeConfig) -> Result<Self, NodeError> {
        let n = config.cameras.len();
        Ok(Self {
            config,
            infos: vec![None; n],
            tf: TfBuffer::new(),
            sync: config.synchronizer(n)?,
            active: (0..n).collect(),
            last_seen_ns: vec![None; n],
            first_ns: None,
            retired: SyncStats::default(),
            events: Vec::new(),
            notices: Vec::new(),
        })
    }

    /// Rig changes since the last call (a camera left or rejoined), for the log.
    pub fn take_events(&mut self) -> Vec<String> {
        std::mem::take(&mut self.events)
    }

    /// Names of the cameras currently out of the rig.
    pub fn inactive_cameras(&self) -> Vec<String> {
        (0..self.config.cameras.len())
            .filter(|i| !self.active.contains(i))
            .map(|i| self.config.cameras[i].clone())
            .collect()
    }

    fn rebuild_sync(&mut self) -> Result<(), NodeError> {
        self.retired = self.sync_stats();
        // Below 2 cameras nothing is pushed (see on_image); the old one waits, emptied.
        if self.active.len() >= 2 {
            self.sync = self.config.synchronizer(self.active.len())?;
        }
        Ok(())
    }

    /// Updates the set of active cameras for a message of camera `i` at `now_ns`.
    fn track(&mut self, i: usize, now_ns: u64) -> Result<(), NodeError> {
        let config = self.config;
        let n = config.cameras.len();
        let first = *self.first_ns.get_or_insert(now_ns);
        self.last_seen_ns[i] = Some(now_ns);
        let mut changed = false;
        if !self.active.contains(&i) {
            self.active.push(i);
            self.active.sort_unstable();
            changed = true;
            self.events.push(format!(
                "camera '{}' is sending again and is back in the rig ({} of {n} cameras)",
                config.cameras[i],
                self.active.len()
            ));
        }
        if let Some(timeout) = config.camera_timeout {
            let timeout_ns = u64::try_from(timeout.as_nanos()).unwrap_or(u64::MAX);
            let silent: Vec<(usize, u64)> = self
                .active
                .iter()
                .map(|&j| {
                    (
                        j,
                        now_ns.saturating_sub(self.last_seen_ns[j].unwrap_or(first)),
                    )
                })
                .filter(|&(_, quiet)| quiet > timeout_ns)
                .collect();
            for (j, quiet) in silent {
                self.active.retain(|&a| a != j);
                changed = true;
                let what = if j == config.reference {
                    "it is the reference camera: no depth is published until it is back".to_string()
                } else if self.active.len() < 2 {
                    "fewer than 2 cameras remain: no depth is published".to_string()
                } else {
                    format!("going on with the other {}", self.active.len())
                };
                self.events.push(format!(
                    "camera '{}' has sent nothing for {:.2} s (camera_timeout {} s) and leaves the rig; {what}",
                    config.cameras[j],
                    quiet as f64 * 1e-9,
                    timeout.as_secs_f64()
                ));
            }
        }
        if changed {
            self.rebuild_sync()?;
        }
        Ok(())
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

    /// Pushes the image of camera `i`, received at `now_ns` (any monotonic clock in
    /// nanoseconds: receive time live, log time in a bag), into the synchroniser; every set it
    /// completes becomes a job or a skip.
    pub fn on_image(
        &mut self,
        i: usize,
        image: Image,
        now_ns: u64,
    ) -> Result<Vec<Result<Job, Skip>>, NodeError> {
        if i >= self.config.cameras.len() {
            return Err(NodeError::Sync(SyncError::StreamOutOfRange {
                stream: i,
                num_streams: self.config.cameras.len(),
            }));
        }
        self.track(i, now_ns)?;
        let reference = self.config.reference;
        if !self.active.contains(&reference) || self.active.len() < 2 {
            // Once per round of images (at the first active camera), not once per image.
            if self.active.first() != Some(&i) && self.active.len() > 1 {
                return Ok(Vec::new());
            }
            let silent = self.inactive_cameras().join(", ");
            let why = if !self.active.contains(&reference) {
                format!(
                    "the reference camera '{}' is silent",
                    self.config.cameras[reference]
                )
            } else {
                "fewer than 2 cameras are sending".to_string()
            };
            return Ok(vec![Err(Skip::new(
                "degraded rig",
                "degraded".into(),
                format!("{why} (out of the rig: {silent}); not publishing"),
            ))]);
        }
        let Some(stream) = self.active.iter().position(|&a| a == i) else {
            return Ok(Vec::new());
        };
        let stamp = image.header.stamp;
        let before = self.sync.stats();
        let sets = self
            .sync
            .push_stamped(stream, &stamp, image)
            .map_err(NodeError::Sync)?;
        let after = self.sync.stats();
        // The synchroniser counts streams (the active cameras); the notices name rig cameras.
        let jump = self.sync.last_reset().map(|mut j| {
            j.stream = self.active.get(j.stream).copied().unwrap_or(j.stream);
            j
        });
        self.notices.extend(time_rule_notices(
            self.config,
            i,
            stamp,
            &before,
            &after,
            jump,
        ));
        Ok(sets.into_iter().map(|set| self.on_set(set)).collect())
    }

    /// What the time rules of the synchroniser did since the last call: one [`Skip`] per
    /// dropped image (duplicate, late, far-future stamp) and per reset, each naming the camera,
    /// for the caller to log (keys per camera and rule, for rate limiting).
    pub fn take_notices(&mut self) -> Vec<Skip> {
        std::mem::take(&mut self.notices)
    }

    /// End of input (the end of a bag): the sets the synchroniser still held back.
    pub fn finish(&mut self) -> Vec<Result<Job, Skip>> {
        if !self.active.contains(&self.config.reference) || self.active.len() < 2 {
            return Vec::new();
        }
        let sets = self.sync.flush();
        sets.into_iter().map(|set| self.on_set(set)).collect()
    }

    pub fn sync_stats(&self) -> SyncStats {
        let now = self.sync.stats();
        let r = &self.retired;
        SyncStats {
            matched: r.matched + now.matched,
            dropped: r.dropped + now.dropped,
            incomplete: r.incomplete + now.incomplete,
            duplicates: r.duplicates + now.duplicates,
            out_of_order: r.out_of_order + now.out_of_order,
            future: r.future + now.future,
            resets: r.resets + now.resets,
        }
    }

    fn on_set(&mut self, set: SyncedSet<Image>) -> Result<Job, Skip> {
        let config = self.config;
        // Index of the reference within the set (the active cameras, in rig order).
        let reference = self
            .active
            .iter()
            .position(|&a| a == config.reference)
            .unwrap_or(0);
        let ref_frame = set
            .messages
            .get(reference)
            .map(|m| m.header.frame_id.clone())
            .unwrap_or_default();
        let mut cameras = Vec::with_capacity(set.messages.len());
        // The reference camera's image frame, in the rig, and its camera in that frame.
        let mut ref_frame_from_rig = RigidTransform::IDENTITY;
        let mut ref_cam_from_frame = RigidTransform::IDENTITY;
        for (k, image) in set.messages.iter().enumerate() {
            let i = self.active.get(k).copied().unwrap_or(k);
            let name = &config.cameras[i];
            let file_camera = config.rig_file.as_ref().and_then(|f| f.camera_for(name));
            let kind = config.image_kinds.get(i).copied().unwrap_or(ImageKind::Raw);
            let calibration = match (&self.infos[i], file_camera.and_then(|c| c.model)) {
                (Some(info), _) => camera_from_info(name, info, kind)
                    .and_then(|calibration| {
                        check_image_size(name, info, image.width, image.height)
                            .map(|()| calibration)
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
                    CameraCalibration::unrectified(model)
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
            let frame_from_rig = match (&config.rig_file, file_camera) {
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
                        tf_skip(
                            &e,
                            format!("tf{i}"),
                            format!(
                                "the transform from '{ref_frame}' (reference camera) to '{frame}' (camera '{name}')"
                            ),
                        )
                    })?,
            };
            // A rectified image's camera is its frame rotated by R, moved by P's translation
            // when the frame is shared with another camera (see `cam_from_frame`); with a rig
            // file every camera has a pose of its own.
            let frame_shared = config.rig_file.is_none()
                && set
                    .messages
                    .iter()
                    .enumerate()
                    .any(|(other, m)| other != k && m.header.frame_id == image.header.frame_id);
            let cam_from_frame = calibration.cam_from_frame(frame_shared);
            if k == reference {
                ref_frame_from_rig = frame_from_rig;
                ref_cam_from_frame = cam_from_frame;
            }
            cameras.push(RigCamera {
                name: name.clone(),
                model: calibration.model,
                cam_from_rig: cam_from_frame.compose(&frame_from_rig),
            });
        }
        let mut virtual_ref = None;
        let ref_info = if let Some(v) = &config.virtual_ref {
            let intrinsics = v.intrinsics(&cameras[reference].model.intrinsics);
            // The virtual camera is placed relative to the reference's frame (tf, or
            // virtual_pose), not to its rectified camera.
            let ref_from_rig = ref_frame_from_rig;
            let virtual_from_ref = if !v.frame_id.is_empty() && config.rig_file.is_none() {
                self.tf.lookup(&v.frame_id, &ref_frame).map_err(|e| {
                    let frame = &v.frame_id;
                    tf_skip(
                        &e,
                        "tf_virtual".into(),
                        format!(
                            "the transform from '{ref_frame}' (reference camera) to '{frame}' (virtual_frame_id)"
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
            match &self.infos[config.reference] {
                Some(info) => info.clone(),
                None => intrinsics_info(&cameras[reference].model.intrinsics),
            }
        };
        // A virtual camera's points are in its own frame.
        if virtual_ref.is_some() {
            ref_cam_from_frame = RigidTransform::IDENTITY;
        }
        Ok(Job {
            images: set.messages,
            cameras,
            reference,
            virtual_ref,
            ref_info,
            ref_cam_from_frame,
        })
    }
}

/// The skip for a failed transform lookup: "waiting for transform" while the tree may still
/// bring it, "frame_id" when tf2 would refuse the lookup itself (an empty id, or one starting
/// with '/'), which no `/tf_static` can cure.
fn tf_skip(e: &TfError, key: String, what: String) -> Skip {
    match e {
        TfError::InvalidLookupFrame { .. } => Skip::new(
            "frame_id",
            key,
            format!("cannot look up {what}: {e} (publish frame ids as tf2 wants them)"),
        ),
        _ => Skip::new(
            "waiting for transform",
            key,
            format!("waiting for {what}: {e}"),
        ),
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

/// The GPU side of the node: the device and the engine, recreated when the device is lost
/// (a driver reset, a GPU that fell off the bus, `Device::destroy`).
pub struct EngineHost {
    gpu: crate::gpu_context::GpuContext,
    engine: GpuEngine,
    lost: std::sync::Arc<std::sync::atomic::AtomicBool>,
    /// How many times the device was lost and the engine recreated.
    pub recreated: u64,
}

impl EngineHost {
    pub fn new() -> Result<Self, String> {
        let (gpu, engine, lost) = Self::create()?;
        Ok(Self {
            gpu,
            engine,
            lost,
            recreated: 0,
        })
    }

    #[allow(clippy::type_complexity)]
    fn create() -> Result<
        (
            crate::gpu_context::GpuContext,
            GpuEngine,
            std::sync::Arc<std::sync::atomic::AtomicBool>,
        ),
        String,
    > {
        let gpu = crate::gpu_context::GpuContext::new().map_err(|e| e.to_string())?;
        let lost = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let flag = std::sync::Arc::clone(&lost);
        gpu.device.set_device_lost_callback(move |reason, message| {
            flag.store(true, std::sync::atomic::Ordering::SeqCst);
            tracing::error!("GPU device lost ({reason:?}): {message}");
        });
        let engine = GpuEngine::new(&gpu.device, &gpu.queue).map_err(|e| e.to_string())?;
        Ok((gpu, engine, lost))
    }

    pub fn adapter_label(&self) -> String {
        self.gpu.adapter_label()
    }

    /// The device, e.g. to simulate a loss in tests (`device().destroy()`).
    pub fn device(&self) -> &wgpu::Device {
        &self.gpu.device
    }

    pub fn is_lost(&self) -> bool {
        self.lost.load(std::sync::atomic::Ordering::SeqCst)
    }

    /// Runs `job`; when the device is lost (before or during the run) the device and engine are
    /// made anew and the job runs once more.
    pub fn process(
        &mut self,
        job: &Job,
        sweep: &SweepParams,
        with_points: bool,
    ) -> Result<FrameOutputs, Skip> {
        if !self.is_lost() {
            match process_job(&mut self.engine, job, sweep, with_points) {
                Err(skip) if skip.kind == "engine" && self.is_lost() => {
                    tracing::warn!("{skip}");
                }
                other => return other,
            }
        }
        tracing::warn!("the GPU device was lost: recreating the device and the engine");
        let (gpu, engine, lost) = Self::create().map_err(|e| {
            Skip::new(
                "gpu lost",
                "gpu_lost".into(),
                format!("the GPU device was lost and cannot be recreated: {e}"),
            )
        })?;
        self.gpu = gpu;
        self.engine = engine;
        self.lost = lost;
        self.recreated += 1;
        tracing::info!("GPU engine recreated on {}", self.gpu.adapter_label());
        process_job(&mut self.engine, job, sweep, with_points)
    }
}

/// Runs one job through the engine with the given parameters and builds its output messages.
pub fn process_job(
    engine: &mut GpuEngine,
    job: &Job,
    sweep: &SweepParams,
    with_points: bool,
) -> Result<FrameOutputs, Skip> {
    let mut images = Vec::with_capacity(job.images.len());
    for (i, msg) in job.images.iter().enumerate() {
        let name = job.cameras.get(i).map_or("?", |c| c.name.as_str());
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
    let rig = Rig::new(job.cameras.clone(), reference)
        .map_err(|e| Skip::new("rig", "rig".into(), format!("cannot build the rig: {e}")))?;
    let maps = engine
        .run(&rig, &images, sweep)
        .map_err(|e| Skip::new("engine", "engine".into(), format!("sweep failed: {e}")))?;
    let mut depth_info = job.ref_info.clone();
    depth_info.header = header.clone();
    let points = with_points.then(|| {
        point_cloud_msg(
            &header,
            &maps.depth_m,
            colour,
            &rig.reference_model(),
            &job.ref_cam_from_frame.inverse(),
        )
    });
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
