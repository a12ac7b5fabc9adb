//! The calibration state (the latest CameraInfo of each camera, the `/tf_static` tree) and how
//! a synchronised set becomes a [`Job`]: a camera model per image (from its CameraInfo, or the
//! rig file's intrinsics), its pose (from `/tf_static`, or the rig file), the virtual
//! reference camera, and the image headers checked before the set goes anywhere.

use super::config::{PipelineConfig, VirtualConfig};
use super::convert::check_image;
use super::outcome::{InputImage, Job, JobReference, Skip, SkipKind, VirtualCamera};
use crate::geometry::{CameraModel, PinholeIntrinsics, RigCamera, RigidTransform};
use crate::msgs::{CameraInfo, Image, TFMessage};
use crate::ros::camera_info::{camera_from_info, check_image_size, CameraCalibration, ImageKind};
use crate::ros::sync::SyncedSet;
use crate::ros::tf::{TfBuffer, TfError};

#[derive(Debug, Default)]
pub(super) struct Calibration {
    infos: Vec<Option<CameraInfo>>,
    tf: TfBuffer,
}

impl Calibration {
    pub fn new(cameras: usize) -> Self {
        Self {
            infos: vec![None; cameras],
            tf: TfBuffer::new(),
        }
    }

    /// The latest CameraInfo of camera `i` replaces the previous one.
    pub fn set_info(&mut self, i: usize, info: CameraInfo) {
        if let Some(slot) = self.infos.get_mut(i) {
            *slot = Some(info);
        }
    }

    /// Adds the transforms of a `/tf_static` message; returns one line per rejected transform.
    pub fn add_tf(&mut self, msg: &TFMessage) -> Vec<String> {
        self.tf
            .insert_message(msg)
            .into_iter()
            .map(|e| e.to_string())
            .collect()
    }

    /// The `/tf_static` tree received so far.
    pub fn tf(&self) -> &TfBuffer {
        &self.tf
    }

    /// The job of `set`, whose message `k` is camera `active[k]`'s, or why it cannot run.
    pub fn job(
        &self,
        config: &PipelineConfig,
        active: &[usize],
        set: SyncedSet<InputImage>,
    ) -> Result<Job, Skip> {
        // Compressed images decoded first (in parallel): what follows needs their sizes.
        let set = super::compressed::decode_set(set, |k| {
            let i = active.get(k).copied().unwrap_or(k);
            (i, config.cameras.get(i).map_or("?", String::as_str))
        })?;
        // The image whose frame anchors the rig (`Job::anchor`): the first reference's, within
        // the set (the active cameras, in rig order).
        let anchor = active
            .iter()
            .position(|&a| a == config.reference())
            .unwrap_or(0);
        let ref_frame = set
            .messages
            .get(anchor)
            .map(|m| m.header.frame_id.clone())
            .unwrap_or_default();
        let mut cameras = Vec::with_capacity(set.messages.len());
        let mut cams_from_frame = Vec::with_capacity(set.messages.len());
        // The anchor's image frame, in the rig.
        let mut ref_frame_from_rig = RigidTransform::IDENTITY;
        for (k, image) in set.messages.iter().enumerate() {
            let i = active.get(k).copied().unwrap_or(k);
            // A rectified image's camera is its frame rotated by R, moved by P's translation
            // when the frame is shared with another camera (see `cam_from_frame`); with a rig
            // file every camera has a pose of its own.
            let frame_shared = config.rig_file.is_none()
                && set
                    .messages
                    .iter()
                    .enumerate()
                    .any(|(other, m)| other != k && m.header.frame_id == image.header.frame_id);
            let placed = self.camera(config, i, image, &ref_frame, frame_shared)?;
            if k == anchor {
                ref_frame_from_rig = placed.frame_from_rig;
            }
            cameras.push(placed.camera);
            cams_from_frame.push(placed.cam_from_frame);
        }
        // The headers, before the set can take the place of another one waiting for the
        // engine (after the calibration, whose complaints about sizes are the more precise).
        for (k, image) in set.messages.iter().enumerate() {
            let i = active.get(k).copied().unwrap_or(k);
            check_image(&config.cameras[i], image)
                .map_err(|e| Skip::new(SkipKind::Image, Some(i), e.to_string()))?;
        }
        // Every configured reference in the set (the first may be a virtual camera).
        let mut references = Vec::with_capacity(config.references.len());
        let mut absent_references = Vec::new();
        for (output, &(camera, _)) in config.references.iter().enumerate() {
            let Some(index) = active.iter().position(|&a| a == camera) else {
                absent_references.push(config.cameras[camera].clone());
                continue;
            };
            let reference = match (&config.virtual_ref, output) {
                (Some(v), 0) => {
                    let anchor = (ref_frame.as_str(), ref_frame_from_rig);
                    self.virtual_reference(config, v, &cameras[index], index, anchor)?
                }
                _ => JobReference {
                    index,
                    output,
                    info: match &self.infos[camera] {
                        Some(info) => info.clone(),
                        None => intrinsics_info(&cameras[index].model.intrinsics),
                    },
                    cam_from_frame: cams_from_frame[index],
                    virtual_camera: None,
                },
            };
            references.push(reference);
        }
        Ok(Job {
            images: set.messages,
            cameras,
            references,
            absent_references,
            ref_frame,
            ref_frame_from_rig,
            world_from_rig: None,
        })
    }

    /// The virtual camera `v` as the first reference, standing in for the reference camera
    /// (`camera`, image `index` of the set); `anchor`: that camera's frame and its pose in the
    /// rig. The virtual camera is placed relative to that frame (tf, or virtual_pose), not to
    /// its rectified camera; its points are in its own frame.
    fn virtual_reference(
        &self,
        config: &PipelineConfig,
        v: &VirtualConfig,
        camera: &RigCamera,
        index: usize,
        (ref_frame, ref_frame_from_rig): (&str, RigidTransform),
    ) -> Result<JobReference, Skip> {
        let intrinsics = v.intrinsics(&camera.model.intrinsics);
        let virtual_from_ref = if !v.frame_id.is_empty() && config.rig_file.is_none() {
            self.tf.lookup(&v.frame_id, ref_frame).map_err(|e| {
                let frame = &v.frame_id;
                tf_skip(
                    &e,
                    None,
                    format!(
                        "the transform from '{ref_frame}' (reference camera) to '{frame}' (virtual_frame_id)"
                    ),
                )
            })?
        } else {
            v.ref_from_virtual.inverse()
        };
        let frame_id = if v.frame_id.is_empty() {
            ref_frame.to_string()
        } else {
            v.frame_id.clone()
        };
        Ok(JobReference {
            index,
            output: 0,
            info: intrinsics_info(&intrinsics),
            cam_from_frame: RigidTransform::IDENTITY,
            virtual_camera: Some(VirtualCamera {
                model: CameraModel::pinhole(intrinsics),
                cam_from_rig: virtual_from_ref.compose(&ref_frame_from_rig),
                frame_id,
            }),
        })
    }

    /// Camera `i` of the rig for its `image`: model and pose (`ref_frame`: the reference
    /// camera's frame; `frame_shared`: another image of the set has the same frame_id).
    fn camera(
        &self,
        config: &PipelineConfig,
        i: usize,
        image: &Image,
        ref_frame: &str,
        frame_shared: bool,
    ) -> Result<PlacedCamera, Skip> {
        let name = &config.cameras[i];
        let file_camera = config.rig_file.as_ref().and_then(|f| f.camera_for(name));
        let kind = config.image_kinds.get(i).copied().unwrap_or(ImageKind::Raw);
        let file_model = file_camera.and_then(|c| c.model);
        // A CameraInfo with K and P all zero (a driver not yet calibrated) gives way to the
        // rig file's intrinsics, as if none had come.
        let info = self.infos[i].as_ref().filter(|info| {
            let uncalibrated = info.k.iter().all(|&v| v == 0.0) && info.p.iter().all(|&v| v == 0.0);
            !(uncalibrated && file_model.is_some())
        });
        let calibration = match (info, file_model) {
            (Some(info), _) => camera_from_info(name, info, kind)
                .and_then(|calibration| {
                    check_image_size(name, info, image.width, image.height).map(|()| calibration)
                })
                .map_err(|e| Skip::new(SkipKind::CameraInfo, Some(i), e.to_string()))?,
            (None, Some(model)) => {
                let k = &model.intrinsics;
                if (image.width, image.height) != (k.width_px, k.height_px) {
                    return Err(Skip::new(
                        SkipKind::RigFile,
                        Some(i),
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
                    SkipKind::WaitingForCameraInfo,
                    Some(i),
                    format!("waiting for camera_info of camera '{name}' on {topic}"),
                ));
            }
        };
        let frame_from_rig = match (&config.rig_file, file_camera) {
            (Some(_), Some(c)) => c.cam_from_rig,
            (Some(file), None) => {
                return Err(Skip::new(
                    SkipKind::RigFile,
                    Some(i),
                    format!(
                        "camera '{name}' is not in the rig file ({} cameras)",
                        file.cameras.len()
                    ),
                ))
            }
            (None, _) => self
                .tf
                .lookup(&image.header.frame_id, ref_frame)
                .map_err(|e| {
                    let frame = &image.header.frame_id;
                    tf_skip(
                        &e,
                        Some(i),
                        format!(
                            "the transform from '{ref_frame}' (reference camera) to '{frame}' (camera '{name}')"
                        ),
                    )
                })?,
        };
        let cam_from_frame = calibration.cam_from_frame(frame_shared);
        Ok(PlacedCamera {
            camera: RigCamera {
                name: name.clone(),
                model: calibration.model,
                cam_from_rig: cam_from_frame.compose(&frame_from_rig),
            },
            frame_from_rig,
            cam_from_frame,
        })
    }
}

/// A camera of the rig, with the pose of its image's frame in the rig and its camera (rotated
/// by R for a rectified image) in that frame.
struct PlacedCamera {
    camera: RigCamera,
    frame_from_rig: RigidTransform,
    cam_from_frame: RigidTransform,
}

/// The skip for a failed transform lookup: "waiting for transform" while the tree may still
/// bring it, "frame_id" when tf2 would refuse the lookup itself (an empty id, or one starting
/// with '/'), which no `/tf_static` can cure.
fn tf_skip(e: &TfError, camera: Option<usize>, what: String) -> Skip {
    match e {
        TfError::InvalidLookupFrame { .. } => Skip::new(
            SkipKind::FrameId,
            camera,
            format!("cannot look up {what}: {e} (publish frame ids as tf2 wants them)"),
        ),
        _ => Skip::new(
            SkipKind::WaitingForTransform,
            camera,
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
