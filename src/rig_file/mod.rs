//! Rig files (not ROS plumbing: any caller may read one): where the cameras sit (and, optionally, their intrinsics), read from the node's
//! `rig_file` parameter. Two formats are read, told apart by their top-level keys
//! ([`load_rig_file`]):
//!
//! # The sweepdepth rig file (a `cameras:` list)
//!
//! ```yaml
//! # sweepdepth rig file
//! rig_frame: rig            # name of the common frame (default "rig"; `pack` poses the cameras in it on /tf_static)
//! cameras:
//!   - name: cam0            # must match an entry of the node's `cameras` parameter
//!     # Pose of the camera's optical frame (x right, y down, z forward) in the rig frame:
//!     # rig_from_cam, i.e. what a tf2 transform rig -> cam0 holds. Translation in metres;
//!     # rotation as a unit quaternion [x, y, z, w] (ROS / Eigen order) ...
//!     translation: [0.0, 0.0, 0.0]
//!     rotation: [0.0, 0.0, 0.0, 1.0]
//!     # optional: intrinsics when the camera publishes no (or an uncalibrated) CameraInfo;
//!     # pixels, centre of the top-left pixel at (0, 0) as in CameraInfo / OpenCV
//!     intrinsics: {width: 640, height: 480, fx: 500.0, fy: 500.0, cx: 319.5, cy: 239.5}
//!     # optional (needs intrinsics): plumb_bob [k1, k2, p1, p2, k3], equidistant
//!     # [k1, k2, k3, k4] or none []; absent = none
//!     distortion: {model: plumb_bob, coefficients: [-0.28, 0.07, 0.0002, -0.0001, 0.0]}
//!   - name: cam1
//!     translation: [0.12, 0.0, 0.0]
//!     # ... or as a 3x3 rotation matrix, row-major: 9 numbers or 3 rows of 3
//!     rotation_matrix: [[1.0, 0.0, 0.0],
//!                       [0.0, 1.0, 0.0],
//!                       [0.0, 0.0, 1.0]]
//! ```
//!
//! - **The pose in the file is `rig_from_cam`** (the camera's pose in the rig: its centre is
//!   `translation`, its axes are the columns of the rotation, both in rig coordinates). What is
//!   stored, [`RigFileCamera::cam_from_rig`], is its inverse, as [`RigCamera`] wants.
//! - Checks: unknown keys are errors (a misspelt `rotaton` is not silently ignored); numbers
//!   must be finite; the quaternion must pass tf2's test |x²+y²+z²+w² - 1| < 0.01 (it is then normalised);
//!   the matrix must be orthonormal with determinant +1 (within 1e-3); exactly one of
//!   `rotation` and `rotation_matrix`; names non-empty and unique; at least one camera;
//!   `fx`, `fy` > 0 and a non-zero image size; exact distortion coefficient counts.
//!   All-zero distortion coefficients give [`crate::geometry::Distortion::None`].
//! - Every error names the file and, when it is about one camera, the camera (its name, or
//!   `cameras[i]` when it has none).
//!
//! # Kalibr `camchain.yaml`
//!
//! ```yaml
//! cam0:
//!   camera_model: pinhole
//!   intrinsics: [461.6, 460.3, 363.0, 248.1]        # fu, fv, pu, pv
//!   distortion_model: radtan                        # radtan | equidistant | none
//!   distortion_coeffs: [-0.28, 0.07, 0.0002, 1.8e-05]
//!   resolution: [752, 480]                          # width, height
//!   rostopic: /cam0/image_raw
//! cam1:
//!   T_cn_cnm1:                                      # cam1_from_cam0, 4x4 row-major
//!   - [1.0, 0.0, 0.0, -0.11]
//!   - [0.0, 1.0, 0.0, 0.0]
//!   - [0.0, 0.0, 1.0, 0.0]
//!   - [0.0, 0.0, 0.0, 1.0]
//!   camera_model: pinhole
//!   # ...
//! ```
//!
//! - The keys must be `cam0`, `cam1`, ... without gaps; each camera is named by its key.
//! - `T_cn_cnm1` maps points in camera n-1 into camera n (`cam_n_from_cam_{n-1}`). The rig
//!   frame is cam0's optical frame: `cam0_from_rig` = identity and
//!   `cam_n_from_rig = T_cn_cnm1 * cam_{n-1}_from_rig`. A chain with cam1 0.1 m to the right
//!   of cam0 therefore has a `T_cn_cnm1` translation of [-0.1, 0, 0].
//! - Only `camera_model: pinhole` is supported (`omni`, `ds`, `eucm`, ... are errors naming the
//!   camera). `radtan` [k1, k2, r1, r2] becomes plumb_bob [k1, k2, p1=r1, p2=r2, k3=0];
//!   `equidistant` [k1..k4] stays equidistant; `none` has no (or all-zero) coefficients.
//! - `rostopic` is kept ([`RigFileCamera::rostopic`]) so that the node can match a camera by
//!   its topic namespace first, then by name ([`RigFile::camera_for`]); `T_cam_imu` is kept as
//!   [`RigFileCamera::cam_from_imu`]; `cam_overlaps` and `timeshift_cam_imu` are accepted and
//!   unused. Other per-camera keys (Kalibr forks add some) are not errors but are listed in
//!   [`RigFile::notes`] for the node to log; unknown top-level keys are errors.

//!
//! The files: [`native`] (our own format), [`kalibr`] (camchain), [`checks`] (what both check
//! of a camera: intrinsics, distortion, rotations).

pub mod checks;
pub mod kalibr;
pub mod native;

use std::fmt;
use std::path::{Path, PathBuf};

use glam::DVec3;
use serde::de::DeserializeOwned;
use serde_yaml_ng::Value;

pub use checks::CameraError;

use crate::geometry::{CameraModel, RigCamera, RigidTransform};
use kalibr::{kalibr_index, parse_kalibr};
use native::parse_sweepdepth;

/// Where a relative path was looked for (the working directory), for an error that cannot
/// open it; empty for an absolute one.
fn relative_note(path: &Path) -> String {
    if path.is_absolute() {
        return String::new();
    }
    match std::env::current_dir() {
        Ok(dir) => format!(
            " (a relative path is opened from the working directory, {}; give an absolute one)",
            dir.display()
        ),
        Err(_) => String::new(),
    }
}

/// Errors reading a rig file. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum RigFileError {
    #[error("cannot read rig file '{}': {source}{}", path.display(), relative_note(path))]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("rig file '{}' is not valid YAML: {message}", path.display())]
    Yaml { path: PathBuf, message: String },
    /// About the file as a whole (format, top-level keys, camera count, duplicate names).
    #[error("rig file '{}': {message}", path.display())]
    Format { path: PathBuf, message: String },
    /// About one camera: `camera` is its name, or `cameras[i]` / the Kalibr key.
    #[error("rig file '{}', camera '{camera}': {source}", path.display())]
    Camera {
        path: PathBuf,
        camera: String,
        source: CameraError,
    },
}

/// Which format a rig file was in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RigFileFormat {
    /// The node's own format (a `cameras:` list).
    Sweepdepth,
    /// A Kalibr `camchain.yaml` (`cam0:`, `cam1:`, ...).
    Kalibr,
}

impl fmt::Display for RigFileFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RigFileFormat::Sweepdepth => f.write_str("sweepdepth rig file"),
            RigFileFormat::Kalibr => f.write_str("Kalibr camchain"),
        }
    }
}

/// A parsed and validated rig file.
#[derive(Debug, Clone, PartialEq)]
pub struct RigFile {
    /// The file it came from (for messages).
    pub path: PathBuf,
    pub format: RigFileFormat,
    /// Name of the common frame: `rig_frame` (default `rig`), or `cam0` for Kalibr.
    pub rig_frame: String,
    /// In file order (Kalibr: cam0, cam1, ...); at least one, names unique.
    pub cameras: Vec<RigFileCamera>,
    /// Things worth a log line that are not errors (ignored Kalibr keys).
    pub notes: Vec<String>,
}

/// One camera of a rig file.
#[derive(Debug, Clone, PartialEq)]
pub struct RigFileCamera {
    pub name: String,
    /// Maps points in the rig frame into this camera's optical frame (the inverse of the
    /// `rig_from_cam` pose written in a sweepdepth rig file).
    pub cam_from_rig: RigidTransform,
    /// Intrinsics and distortion, when the file gives them (always for Kalibr).
    pub model: Option<CameraModel>,
    /// Kalibr's `rostopic` (e.g. `/cam0/image_raw`); `None` for the sweepdepth format.
    pub rostopic: Option<String>,
    /// Kalibr's `T_cam_imu` (maps IMU points into this camera), when present.
    pub cam_from_imu: Option<RigidTransform>,
}

impl RigFileCamera {
    /// The namespace of [`Self::rostopic`]: `/cam0/image_raw` -> `/cam0`,
    /// `/stereo/left/image_raw` -> `/stereo/left`; `None` without a topic or a namespace.
    pub fn topic_namespace(&self) -> Option<&str> {
        let topic = self.rostopic.as_deref()?.trim_end_matches('/');
        let slash = topic.rfind('/')?;
        let namespace = &topic[..slash];
        if namespace.trim_matches('/').is_empty() {
            None
        } else {
            Some(namespace)
        }
    }

    /// Whether this is the camera the node calls `camera` (an entry of its `cameras`
    /// parameter): its name or its topic namespace, leading and trailing `/` ignored
    /// (`cam0`, `/cam0` and `/cam0/` all match a camera named `cam0`).
    pub fn matches(&self, camera: &str) -> bool {
        let wanted = camera.trim_matches('/');
        if wanted.is_empty() {
            return false;
        }
        self.name.trim_matches('/') == wanted
            || self
                .topic_namespace()
                .is_some_and(|ns| ns.trim_matches('/') == wanted)
    }

    /// The centre of the camera in the rig frame, metres.
    pub fn centre_in_rig(&self) -> DVec3 {
        self.cam_from_rig.inverse().translation
    }

    /// A [`RigCamera`] with this pose and the given model (from CameraInfo, or [`Self::model`]).
    pub fn rig_camera(&self, model: CameraModel) -> RigCamera {
        RigCamera {
            name: self.name.clone(),
            model,
            cam_from_rig: self.cam_from_rig,
        }
    }
}

impl RigFile {
    /// The camera with exactly this name.
    pub fn camera(&self, name: &str) -> Option<&RigFileCamera> {
        self.cameras.iter().find(|c| c.name == name)
    }

    /// The camera for an entry of the node's `cameras` parameter: the one whose Kalibr topic
    /// lies in the camera's namespace (`rostopic: /cam4/image_raw` is camera `cam4`, whatever
    /// its key: Kalibr numbers its keys in the order it was given the topics), else the one of
    /// that name (see [`RigFileCamera::matches`]).
    pub fn camera_for(&self, camera: &str) -> Option<&RigFileCamera> {
        let wanted = camera.trim_matches('/');
        if wanted.is_empty() {
            return None;
        }
        self.cameras
            .iter()
            .find(|c| {
                c.topic_namespace()
                    .is_some_and(|ns| ns.trim_matches('/') == wanted)
            })
            .or_else(|| {
                self.cameras
                    .iter()
                    .find(|c| c.name.trim_matches('/') == wanted)
            })
    }

    /// Intrinsics that are valid but unlikely to be what was meant, as sentences: a pinhole
    /// focal length giving a field of view over 160 degrees (a focal length in millimetres,
    /// not pixels?), a principal point outside the image (intrinsics of another resolution?).
    pub fn doubts(&self) -> Vec<String> {
        let mut doubts = Vec::new();
        for c in &self.cameras {
            let Some(model) = c.model else { continue };
            let k = model.intrinsics;
            let (w, h) = (f64::from(k.width_px), f64::from(k.height_px));
            let fov = |size: f64, f: f64| 2.0 * (0.5 * size / f).atan().to_degrees();
            let wide = fov(w, k.fx_px).max(fov(h, k.fy_px));
            let fisheye = matches!(
                model.distortion,
                crate::geometry::Distortion::Equidistant { .. }
            );
            if wide > 160.0 && !fisheye {
                doubts.push(format!(
                    "{}: camera {}: fx {} / fy {} px give a {wide:.0}-degree field of view \
                     across {}x{} px: focal lengths are in pixels (is it one in millimetres?)",
                    self.path.display(),
                    c.name,
                    k.fx_px,
                    k.fy_px,
                    k.width_px,
                    k.height_px
                ));
            }
            if !(-0.5..=w - 0.5).contains(&k.cx_px) || !(-0.5..=h - 0.5).contains(&k.cy_px) {
                doubts.push(format!(
                    "{}: camera {}: the principal point ({}, {}) lies outside its {}x{} image \
                     (intrinsics of another resolution?)",
                    self.path.display(),
                    c.name,
                    k.cx_px,
                    k.cy_px,
                    k.width_px,
                    k.height_px
                ));
            }
        }
        doubts
    }

    /// Cameras of `cameras` that the file names by key but whose Kalibr topic says they are
    /// another camera: "Kalibr's cam0 (rostopic /cam4/image_raw) is taken as camera cam4".
    pub fn topic_notes(&self, cameras: &[String]) -> Vec<String> {
        cameras
            .iter()
            .filter_map(|camera| {
                let by_topic = self.camera_for(camera)?;
                let by_name = self
                    .cameras
                    .iter()
                    .find(|c| c.name.trim_matches('/') == camera.trim_matches('/'))?;
                (by_topic.name != by_name.name).then(|| {
                    format!(
                        "{}: camera {camera} is Kalibr's {} by its rostopic {}, not {} (whose \
                         rostopic is {})",
                        self.path.display(),
                        by_topic.name,
                        by_topic.rostopic.as_deref().unwrap_or(""),
                        by_name.name,
                        by_name.rostopic.as_deref().unwrap_or("none"),
                    )
                })
            })
            .collect()
    }
}

/// Reads a rig file in either format (see the module documentation).
pub fn load_rig_file(path: impl AsRef<Path>) -> Result<RigFile, RigFileError> {
    let path = path.as_ref();
    let text = std::fs::read_to_string(path).map_err(|source| RigFileError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    parse_rig_file(&text, path)
}

/// Parses rig file text; `path` is only used in messages and kept in [`RigFile::path`].
pub fn parse_rig_file(text: &str, path: &Path) -> Result<RigFile, RigFileError> {
    let ctx = Ctx { path, text };
    let doc: Value = serde_yaml_ng::from_str(text).map_err(|e| RigFileError::Yaml {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    let Value::Mapping(map) = &doc else {
        return Err(ctx.format(format!(
            "expected a mapping with a `cameras:` list (sweepdepth) or `cam0:`, `cam1:`, ... \
             (Kalibr camchain) at the top level, found {}",
            value_kind(&doc)
        )));
    };
    if map.contains_key("cameras") {
        parse_sweepdepth(&ctx, map)
    } else if map
        .keys()
        .any(|k| k.as_str().is_some_and(|k| kalibr_index(k).is_some()))
    {
        parse_kalibr(&ctx, map)
    } else {
        Err(ctx.format(
            "neither a sweepdepth rig file (no `cameras:` list) nor a Kalibr camchain \
             (no `cam0:` key)"
                .to_string(),
        ))
    }
}

pub(super) struct Ctx<'a> {
    pub path: &'a Path,
    pub text: &'a str,
}

impl Ctx<'_> {
    pub fn format(&self, message: String) -> RigFileError {
        RigFileError::Format {
            path: self.path.to_path_buf(),
            message,
        }
    }

    pub fn camera(&self, camera: &str, source: CameraError) -> RigFileError {
        RigFileError::Camera {
            path: self.path.to_path_buf(),
            camera: camera.to_string(),
            source,
        }
    }

    /// Deserialises one camera's entry. On failure the message comes from parsing the whole
    /// text as `Whole` when that fails too (its message has the key path and line), else from
    /// the entry alone.
    pub fn entry<T: DeserializeOwned, Whole: DeserializeOwned>(
        &self,
        camera: &str,
        value: &Value,
    ) -> Result<T, RigFileError> {
        T::deserialize(value.clone()).map_err(|entry_error| {
            let message = match serde_yaml_ng::from_str::<Whole>(self.text) {
                Err(whole_error) => whole_error.to_string(),
                Ok(_) => entry_error.to_string(),
            };
            self.camera(camera, CameraError::Entry(message))
        })
    }
}

pub(super) fn value_kind(value: &Value) -> &'static str {
    match value {
        Value::Null => "nothing (empty file?)",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Sequence(_) => "a list",
        Value::Mapping(_) => "a mapping",
        Value::Tagged(_) => "a tagged value",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topic_namespace_and_matching() {
        let mut cam = RigFileCamera {
            name: "left".into(),
            cam_from_rig: RigidTransform::IDENTITY,
            model: None,
            rostopic: Some("/stereo/left/image_raw".into()),
            cam_from_imu: None,
        };
        assert_eq!(cam.topic_namespace(), Some("/stereo/left"));
        assert!(cam.matches("left"));
        assert!(cam.matches("/stereo/left"));
        assert!(cam.matches("stereo/left/"));
        assert!(!cam.matches("stereo"));
        assert!(!cam.matches(""));
        cam.rostopic = Some("image_raw".into());
        assert_eq!(cam.topic_namespace(), None);
        cam.rostopic = Some("/image_raw".into());
        assert_eq!(cam.topic_namespace(), None);
    }
}
