//! The calibration state (the latest CameraInfo of each camera, the `/tf_static` tree) and how
//! a synchronised set becomes a [`Job`]: a camera model per image (from its CameraInfo, or the
//! rig file's intrinsics), its pose (from `/tf_static`, or the rig file), the virtual
//! reference camera, and the image headers checked before the set goes anywhere.

use super::config::PipelineConfig;
use super::convert::check_image;
use super::outcome::{Job, Skip, SkipKind};
use crate::geometry::{check_image_size, CameraModel, PinholeIntrinsics, RigCamera};
use crate::msgs::{CameraInfo, Image, TFMessage};
use crate::ros::sync::SyncedSet;
use crate::ros::tf::TfBuffer;

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

    /// The job of `set`, whose message `k` is camera `active[k]`'s, or why it cannot run.
    pub fn job(
        &self,
        config: &PipelineConfig,
        active: &[usize],
        set: SyncedSet<Image>,
    ) -> Result<Job, Skip> {
        // Index of the reference within the set (the active cameras, in rig order).
        let reference = active
            .iter()
            .position(|&a| a == config.reference)
            .unwrap_or(0);
        let ref_frame = set
            .messages
            .get(reference)
            .map(|m| m.header.frame_id.clone())
            .unwrap_or_default();
        let mut cameras = Vec::with_capacity(set.messages.len());
        for (k, image) in set.messages.iter().enumerate() {
            let i = active.get(k).copied().unwrap_or(k);
            cameras.push(self.camera(config, i, image, &ref_frame)?);
        }
        // The headers, before the set can take the place of another one waiting for the
        // engine (after the calibration, whose complaints about sizes are the more precise).
        for (k, image) in set.messages.iter().enumerate() {
            let i = active.get(k).copied().unwrap_or(k);
            check_image(&config.cameras[i], image)
                .map_err(|e| Skip::new(SkipKind::Image, Some(i), e.to_string()))?;
        }
        let mut virtual_ref = None;
        let ref_info = if let Some(v) = &config.virtual_ref {
            let intrinsics = v.intrinsics(&cameras[reference].model.intrinsics);
            let ref_from_rig = cameras[reference].cam_from_rig;
            let virtual_from_ref = if !v.frame_id.is_empty() && config.rig_file.is_none() {
                self.tf.lookup(&v.frame_id, &ref_frame).map_err(|e| {
                    let frame = &v.frame_id;
                    Skip::new(
                        SkipKind::WaitingForTransform,
                        None,
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
            match &self.infos[config.reference] {
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

    /// Camera `i` of the rig for its `image`: model and pose (`ref_frame`: the reference
    /// camera's frame).
    fn camera(
        &self,
        config: &PipelineConfig,
        i: usize,
        image: &Image,
        ref_frame: &str,
    ) -> Result<RigCamera, Skip> {
        let name = &config.cameras[i];
        let file_camera = config.rig_file.as_ref().and_then(|f| f.camera_for(name));
        let model = match (&self.infos[i], file_camera.and_then(|c| c.model)) {
            (Some(info), _) => CameraModel::from_camera_info(name, info)
                .and_then(|model| {
                    check_image_size(name, info, image.width, image.height).map(|()| model)
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
                model
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
        let cam_from_rig = match (&config.rig_file, file_camera) {
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
                    Skip::new(
                        SkipKind::WaitingForTransform,
                        Some(i),
                        format!(
                            "waiting for the transform from '{ref_frame}' (reference camera) to '{frame}' (camera '{name}'): {e}"
                        ),
                    )
                })?,
        };
        Ok(RigCamera {
            name: name.clone(),
            model,
            cam_from_rig,
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
