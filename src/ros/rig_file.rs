//! Rig files: where the cameras sit (and, optionally, their intrinsics), read from the node's
//! `rig_file` parameter. Two formats are read, told apart by their top-level keys
//! ([`load_rig_file`]):
//!
//! # The sweepdepth rig file (a `cameras:` list)
//!
//! ```yaml
//! # sweepdepth rig file
//! rig_frame: rig            # name of the common frame (informational; default "rig")
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
//!   All-zero distortion coefficients give [`Distortion::None`].
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
//!   its topic namespace as well as by name ([`RigFile::camera_for`]); `T_cam_imu` is kept as
//!   [`RigFileCamera::cam_from_imu`]; `cam_overlaps` and `timeshift_cam_imu` are accepted and
//!   unused. Other per-camera keys (Kalibr forks add some) are not errors but are listed in
//!   [`RigFile::notes`] for the node to log; unknown top-level keys are errors.

use std::collections::{BTreeMap, HashSet};
use std::fmt;
use std::path::{Path, PathBuf};

use glam::{DMat3, DQuat, DVec3};
use serde::de::DeserializeOwned;
use serde::Deserialize;
use serde_yaml_ng::Value;

use crate::geometry::{
    CameraModel, Distortion, GeometryError, PinholeIntrinsics, RigCamera, RigidTransform,
};

/// Tolerance on the last row of a Kalibr 4x4 homogeneous matrix being [0, 0, 0, 1].
const HOMOGENEOUS_ROW_TOLERANCE: f64 = 1e-6;

/// Errors reading a rig file. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum RigFileError {
    #[error("cannot read rig file '{}': {source}", path.display())]
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
    #[error("rig file '{}', camera '{camera}': {message}", path.display())]
    Camera {
        path: PathBuf,
        camera: String,
        message: String,
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

    /// The camera for an entry of the node's `cameras` parameter: by name first, then by
    /// Kalibr topic namespace (see [`RigFileCamera::matches`]).
    pub fn camera_for(&self, camera: &str) -> Option<&RigFileCamera> {
        let wanted = camera.trim_matches('/');
        self.cameras
            .iter()
            .find(|c| !wanted.is_empty() && c.name.trim_matches('/') == wanted)
            .or_else(|| self.cameras.iter().find(|c| c.matches(camera)))
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

struct Ctx<'a> {
    path: &'a Path,
    text: &'a str,
}

impl Ctx<'_> {
    fn format(&self, message: String) -> RigFileError {
        RigFileError::Format {
            path: self.path.to_path_buf(),
            message,
        }
    }

    fn camera(&self, camera: &str, message: String) -> RigFileError {
        RigFileError::Camera {
            path: self.path.to_path_buf(),
            camera: camera.to_string(),
            message,
        }
    }

    /// Deserialises one camera's entry. On failure the message comes from parsing the whole
    /// text as `Whole` when that fails too (its message has the key path and line), else from
    /// the entry alone.
    fn entry<T: DeserializeOwned, Whole: DeserializeOwned>(
        &self,
        camera: &str,
        value: &Value,
    ) -> Result<T, RigFileError> {
        T::deserialize(value.clone()).map_err(|entry_error| {
            let message = match serde_yaml_ng::from_str::<Whole>(self.text) {
                Err(whole_error) => whole_error.to_string(),
                Ok(_) => entry_error.to_string(),
            };
            self.camera(camera, message)
        })
    }
}

fn value_kind(value: &Value) -> &'static str {
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

// ---------------------------------------------------------------------------------------------
// The sweepdepth format.

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
#[allow(dead_code)] // only parsed for its error messages
struct RawRigFile {
    #[serde(default)]
    rig_frame: Option<String>,
    cameras: Vec<RawCamera>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRigFileTop {
    #[serde(default)]
    rig_frame: Option<String>,
    cameras: Vec<Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCamera {
    name: String,
    translation: Vec<f64>,
    #[serde(default)]
    rotation: Option<Vec<f64>>,
    #[serde(default)]
    rotation_matrix: Option<Value>,
    #[serde(default)]
    intrinsics: Option<RawIntrinsics>,
    #[serde(default)]
    distortion: Option<RawDistortion>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawIntrinsics {
    width: u32,
    height: u32,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDistortion {
    model: String,
    #[serde(default)]
    coefficients: Vec<f64>,
}

fn parse_sweepdepth(ctx: &Ctx<'_>, map: &serde_yaml_ng::Mapping) -> Result<RigFile, RigFileError> {
    let top = RawRigFileTop::deserialize(Value::Mapping(map.clone())).map_err(|e| {
        let message = match serde_yaml_ng::from_str::<RawRigFile>(ctx.text) {
            Err(whole) => whole.to_string(),
            Ok(_) => e.to_string(),
        };
        ctx.format(message)
    })?;
    let rig_frame = top.rig_frame.unwrap_or_else(|| "rig".to_string());
    if rig_frame.trim().is_empty() {
        return Err(ctx.format("`rig_frame` is empty".to_string()));
    }
    if top.cameras.is_empty() {
        return Err(ctx.format("`cameras` is empty; list at least one camera".to_string()));
    }
    let mut cameras = Vec::with_capacity(top.cameras.len());
    for (i, value) in top.cameras.iter().enumerate() {
        // Name the camera in messages by its `name` when it has one.
        let label = value
            .get("name")
            .and_then(Value::as_str)
            .filter(|n| !n.trim().is_empty())
            .map_or_else(|| format!("cameras[{i}]"), str::to_string);
        let raw: RawCamera = ctx.entry::<RawCamera, RawRigFile>(&label, value)?;
        let camera = convert_camera(raw).map_err(|message| ctx.camera(&label, message))?;
        cameras.push(camera);
    }
    check_unique_names(ctx, &cameras)?;
    Ok(RigFile {
        path: ctx.path.to_path_buf(),
        format: RigFileFormat::Sweepdepth,
        rig_frame,
        cameras,
        notes: Vec::new(),
    })
}

fn convert_camera(raw: RawCamera) -> Result<RigFileCamera, String> {
    if raw.name.trim().is_empty() {
        return Err("`name` is empty".to_string());
    }
    let translation = vec3(&raw.translation, "translation")?;
    let rig_from_cam = match (&raw.rotation, &raw.rotation_matrix) {
        (Some(_), Some(_)) => {
            return Err("give either `rotation` or `rotation_matrix`, not both".to_string())
        }
        (None, None) => {
            return Err(
                "missing the orientation: `rotation` (quaternion [x, y, z, w]) or \
                 `rotation_matrix` (3x3 row-major)"
                    .to_string(),
            )
        }
        (Some(q), None) => {
            if q.len() != 4 {
                return Err(format!(
                    "`rotation` must be a quaternion [x, y, z, w] (4 numbers), got {} numbers",
                    q.len()
                ));
            }
            RigidTransform::from_quat_translation(
                "rotation",
                DQuat::from_xyzw(q[0], q[1], q[2], q[3]),
                translation,
            )
            .map_err(|e| pose_message("rotation", e))?
        }
        (None, Some(m)) => {
            let rotation = matrix3(m)?;
            RigidTransform::from_matrix_translation("rotation_matrix", rotation, translation)
                .map_err(|e| pose_message("rotation_matrix", e))?
        }
    };
    let model = match (raw.intrinsics, raw.distortion) {
        (None, Some(_)) => {
            return Err("`distortion` is given without `intrinsics`".to_string());
        }
        (None, None) => None,
        (Some(k), distortion) => {
            let intrinsics = PinholeIntrinsics {
                width_px: k.width,
                height_px: k.height,
                fx_px: k.fx,
                fy_px: k.fy,
                cx_px: k.cx,
                cy_px: k.cy,
            };
            check_intrinsics(&intrinsics)?;
            let distortion = match distortion {
                None => Distortion::None,
                Some(d) => distortion_from(&d.model, &d.coefficients)?,
            };
            Some(CameraModel {
                intrinsics,
                distortion,
            })
        }
    };
    Ok(RigFileCamera {
        name: raw.name,
        cam_from_rig: rig_from_cam.inverse(),
        model,
        rostopic: None,
        cam_from_imu: None,
    })
}

fn pose_message(field: &str, error: GeometryError) -> String {
    match error {
        GeometryError::InvalidPose { reason, .. } => format!("`{field}`: {reason}"),
        other => format!("`{field}`: {other}"),
    }
}

fn vec3(v: &[f64], field: &str) -> Result<DVec3, String> {
    if v.len() != 3 {
        return Err(format!(
            "`{field}` must be [x, y, z] (3 numbers), got {} numbers",
            v.len()
        ));
    }
    if v.iter().any(|x| !x.is_finite()) {
        return Err(format!("`{field}` has a NaN or infinite component"));
    }
    Ok(DVec3::new(v[0], v[1], v[2]))
}

fn yaml_f64(value: &Value) -> Option<f64> {
    match value {
        Value::Number(n) => n.as_f64(),
        _ => None,
    }
}

/// A 3x3 matrix from 9 numbers or 3 rows of 3, row-major.
fn matrix3(value: &Value) -> Result<DMat3, String> {
    let shape_error = || {
        "`rotation_matrix` must be a 3x3 row-major matrix: 9 numbers or 3 rows of 3 numbers"
            .to_string()
    };
    let Value::Sequence(items) = value else {
        return Err(shape_error());
    };
    let mut entries = Vec::with_capacity(9);
    if items.len() == 9 {
        for item in items {
            entries.push(yaml_f64(item).ok_or_else(shape_error)?);
        }
    } else if items.len() == 3 {
        for row in items {
            let Value::Sequence(row) = row else {
                return Err(shape_error());
            };
            if row.len() != 3 {
                return Err(shape_error());
            }
            for item in row {
                entries.push(yaml_f64(item).ok_or_else(shape_error)?);
            }
        }
    } else {
        return Err(shape_error());
    }
    Ok(rows_to_mat3([
        [entries[0], entries[1], entries[2]],
        [entries[3], entries[4], entries[5]],
        [entries[6], entries[7], entries[8]],
    ]))
}

fn rows_to_mat3(r: [[f64; 3]; 3]) -> DMat3 {
    DMat3::from_cols(
        DVec3::new(r[0][0], r[1][0], r[2][0]),
        DVec3::new(r[0][1], r[1][1], r[2][1]),
        DVec3::new(r[0][2], r[1][2], r[2][2]),
    )
}

fn check_intrinsics(k: &PinholeIntrinsics) -> Result<(), String> {
    if k.width_px == 0 || k.height_px == 0 {
        return Err(format!(
            "`intrinsics`: image size {}x{} has a zero side",
            k.width_px, k.height_px
        ));
    }
    for (name, v) in [
        ("fx", k.fx_px),
        ("fy", k.fy_px),
        ("cx", k.cx_px),
        ("cy", k.cy_px),
    ] {
        if !v.is_finite() {
            return Err(format!("`intrinsics`: {name} is not finite"));
        }
    }
    if k.fx_px <= 0.0 || k.fy_px <= 0.0 {
        return Err(format!(
            "`intrinsics`: focal lengths must be positive (fx = {}, fy = {})",
            k.fx_px, k.fy_px
        ));
    }
    Ok(())
}

/// Our distortion models with exact coefficient counts; all-zero coefficients give `None`.
fn distortion_from(model: &str, d: &[f64]) -> Result<Distortion, String> {
    let expected = match model {
        "none" => 0,
        "plumb_bob" => 5,
        "equidistant" => 4,
        other => {
            return Err(format!(
                "`distortion`: unknown model '{other}' (supported: plumb_bob [k1, k2, p1, p2, k3], \
                 equidistant [k1, k2, k3, k4], none)"
            ))
        }
    };
    if d.len() != expected {
        return Err(format!(
            "`distortion`: model '{model}' needs {expected} coefficients, got {}",
            d.len()
        ));
    }
    if d.iter().any(|v| !v.is_finite()) {
        return Err("`distortion`: a coefficient is NaN or infinite".to_string());
    }
    Ok(match model {
        _ if d.iter().all(|&v| v == 0.0) => Distortion::None,
        "plumb_bob" => Distortion::PlumbBob {
            k1: d[0],
            k2: d[1],
            p1: d[2],
            p2: d[3],
            k3: d[4],
        },
        _ => Distortion::Equidistant {
            k1: d[0],
            k2: d[1],
            k3: d[2],
            k4: d[3],
        },
    })
}

fn check_unique_names(ctx: &Ctx<'_>, cameras: &[RigFileCamera]) -> Result<(), RigFileError> {
    let mut seen = HashSet::new();
    for camera in cameras {
        if !seen.insert(camera.name.as_str()) {
            return Err(ctx.camera(
                &camera.name,
                "the name is used by more than one camera".to_string(),
            ));
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Kalibr camchain.yaml.

/// Per-camera keys of a Kalibr camchain (used or knowingly ignored).
const KALIBR_KEYS: &[&str] = &[
    "camera_model",
    "intrinsics",
    "distortion_model",
    "distortion_coeffs",
    "resolution",
    "rostopic",
    "T_cn_cnm1",
    "T_cam_imu",
    "cam_overlaps",
    "timeshift_cam_imu",
];

#[derive(Deserialize)]
struct RawKalibrCamera {
    camera_model: String,
    intrinsics: Vec<f64>,
    distortion_model: String,
    #[serde(default)]
    distortion_coeffs: Vec<f64>,
    resolution: Vec<u32>,
    #[serde(default)]
    rostopic: Option<String>,
    #[serde(default, rename = "T_cn_cnm1")]
    t_cn_cnm1: Option<Vec<Vec<f64>>>,
    #[serde(default, rename = "T_cam_imu")]
    t_cam_imu: Option<Vec<Vec<f64>>>,
    #[serde(default)]
    #[allow(dead_code)]
    cam_overlaps: Option<Vec<i64>>,
    #[serde(default)]
    #[allow(dead_code)]
    timeshift_cam_imu: Option<f64>,
}

/// `cam12` -> 12.
fn kalibr_index(key: &str) -> Option<usize> {
    let digits = key.strip_prefix("cam")?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    if digits.len() > 1 && digits.starts_with('0') {
        return None;
    }
    digits.parse().ok()
}

fn parse_kalibr(ctx: &Ctx<'_>, map: &serde_yaml_ng::Mapping) -> Result<RigFile, RigFileError> {
    let mut entries: BTreeMap<usize, (String, &Value)> = BTreeMap::new();
    for (key, value) in map {
        let Some(key) = key.as_str() else {
            return Err(ctx.format(format!(
                "Kalibr camchain: top-level keys must be `cam0`, `cam1`, ...; found {}",
                value_kind(key)
            )));
        };
        let Some(index) = kalibr_index(key) else {
            return Err(ctx.format(format!(
                "Kalibr camchain: unexpected top-level key `{key}` (expected `cam0`, `cam1`, ...)"
            )));
        };
        entries.insert(index, (key.to_string(), value));
    }
    for (expected, index) in entries.keys().enumerate() {
        if *index != expected {
            return Err(ctx.format(format!(
                "Kalibr camchain: cameras must be cam0, cam1, ... without gaps; `cam{expected}` \
                 is missing"
            )));
        }
    }
    let mut notes = Vec::new();
    let mut cameras: Vec<RigFileCamera> = Vec::with_capacity(entries.len());
    for (index, (name, value)) in entries {
        if let Value::Mapping(fields) = value {
            for key in fields.keys() {
                let key = key.as_str().unwrap_or("<non-string key>");
                if !KALIBR_KEYS.contains(&key) {
                    notes.push(format!(
                        "rig file '{}', camera '{name}': ignored Kalibr key `{key}`",
                        ctx.path.display()
                    ));
                }
            }
        }
        let raw: RawKalibrCamera =
            ctx.entry::<RawKalibrCamera, BTreeMap<String, RawKalibrCamera>>(&name, value)?;
        let previous = cameras.last().map(|c| c.cam_from_rig);
        let camera = convert_kalibr(&name, raw, previous, &mut notes)
            .map_err(|message| ctx.camera(&name, message))?;
        debug_assert_eq!(cameras.len(), index);
        cameras.push(camera);
    }
    if cameras.is_empty() {
        return Err(ctx.format("Kalibr camchain has no cameras".to_string()));
    }
    Ok(RigFile {
        path: ctx.path.to_path_buf(),
        format: RigFileFormat::Kalibr,
        rig_frame: "cam0".to_string(),
        cameras,
        notes,
    })
}

fn convert_kalibr(
    name: &str,
    raw: RawKalibrCamera,
    previous_from_rig: Option<RigidTransform>,
    notes: &mut Vec<String>,
) -> Result<RigFileCamera, String> {
    if raw.camera_model != "pinhole" {
        return Err(format!(
            "Kalibr camera model '{}' is not supported (only `pinhole`, with radtan, equidistant \
             or no distortion)",
            raw.camera_model
        ));
    }
    if raw.intrinsics.len() != 4 {
        return Err(format!(
            "`intrinsics` of a pinhole camera must be [fu, fv, pu, pv], got {} numbers",
            raw.intrinsics.len()
        ));
    }
    if raw.resolution.len() != 2 {
        return Err(format!(
            "`resolution` must be [width, height], got {} numbers",
            raw.resolution.len()
        ));
    }
    let intrinsics = PinholeIntrinsics {
        width_px: raw.resolution[0],
        height_px: raw.resolution[1],
        fx_px: raw.intrinsics[0],
        fy_px: raw.intrinsics[1],
        cx_px: raw.intrinsics[2],
        cy_px: raw.intrinsics[3],
    };
    check_intrinsics(&intrinsics)?;
    let d = &raw.distortion_coeffs;
    let distortion = match raw.distortion_model.as_str() {
        "radtan" => {
            if d.len() != 4 {
                return Err(format!(
                    "`distortion_coeffs` of radtan must be [k1, k2, r1, r2], got {} numbers",
                    d.len()
                ));
            }
            distortion_from("plumb_bob", &[d[0], d[1], d[2], d[3], 0.0])?
        }
        "equidistant" => {
            if d.len() != 4 {
                return Err(format!(
                    "`distortion_coeffs` of equidistant must be [k1, k2, k3, k4], got {} numbers",
                    d.len()
                ));
            }
            distortion_from("equidistant", d)?
        }
        "none" => {
            if d.iter().any(|&v| v != 0.0) {
                return Err(
                    "`distortion_model` is none but `distortion_coeffs` are not all zero"
                        .to_string(),
                );
            }
            Distortion::None
        }
        other => {
            return Err(format!(
                "Kalibr distortion model '{other}' is not supported (radtan, equidistant, none)"
            ))
        }
    };
    let cam_from_rig = match previous_from_rig {
        None => {
            if raw.t_cn_cnm1.is_some() {
                notes.push(format!(
                    "camera '{name}': `T_cn_cnm1` on the first camera ignored (cam0 is the rig \
                     frame)"
                ));
            }
            RigidTransform::IDENTITY
        }
        Some(previous_from_rig) => {
            let Some(m) = &raw.t_cn_cnm1 else {
                return Err(
                    "missing `T_cn_cnm1` (the transform from the previous camera into this one)"
                        .to_string(),
                );
            };
            let cn_from_cnm1 = homogeneous(m, "T_cn_cnm1")?;
            cn_from_cnm1.compose(&previous_from_rig)
        }
    };
    let cam_from_imu = match &raw.t_cam_imu {
        Some(m) => Some(homogeneous(m, "T_cam_imu")?),
        None => None,
    };
    Ok(RigFileCamera {
        name: name.to_string(),
        cam_from_rig,
        model: Some(CameraModel {
            intrinsics,
            distortion,
        }),
        rostopic: raw.rostopic,
        cam_from_imu,
    })
}

/// A 4x4 row-major homogeneous rigid transform.
fn homogeneous(m: &[Vec<f64>], field: &str) -> Result<RigidTransform, String> {
    if m.len() != 4 || m.iter().any(|row| row.len() != 4) {
        return Err(format!(
            "`{field}` must be a 4x4 matrix (4 rows of 4 numbers)"
        ));
    }
    if m.iter().flatten().any(|v| !v.is_finite()) {
        return Err(format!("`{field}` has a NaN or infinite entry"));
    }
    let last = &m[3];
    if (last[0].abs().max(last[1].abs()).max(last[2].abs())) > HOMOGENEOUS_ROW_TOLERANCE
        || (last[3] - 1.0).abs() > HOMOGENEOUS_ROW_TOLERANCE
    {
        return Err(format!(
            "`{field}`: the last row must be [0, 0, 0, 1], got {last:?}"
        ));
    }
    let rotation = rows_to_mat3([
        [m[0][0], m[0][1], m[0][2]],
        [m[1][0], m[1][1], m[1][2]],
        [m[2][0], m[2][1], m[2][2]],
    ]);
    let translation = DVec3::new(m[0][3], m[1][3], m[2][3]);
    RigidTransform::from_matrix_translation(field, rotation, translation)
        .map_err(|e| pose_message(field, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<RigFile, RigFileError> {
        parse_rig_file(text, Path::new("unit.yaml"))
    }

    #[test]
    fn kalibr_index_parses_only_cam_keys() {
        assert_eq!(kalibr_index("cam0"), Some(0));
        assert_eq!(kalibr_index("cam12"), Some(12));
        assert_eq!(kalibr_index("cam"), None);
        assert_eq!(kalibr_index("cam01"), None);
        assert_eq!(kalibr_index("camera0"), None);
        assert_eq!(kalibr_index("cameras"), None);
    }

    #[test]
    fn pose_is_inverted_to_cam_from_rig() {
        // Camera at x = 0.5 in the rig, rotated 90 degrees about the rig's y axis.
        let text = "cameras:\n  - name: a\n    translation: [0.5, 0.0, 0.0]\n    rotation: [0.0, 0.7071067811865476, 0.0, 0.7071067811865476]\n";
        let rig = parse(text).unwrap();
        let cam = &rig.cameras[0];
        assert!((cam.centre_in_rig() - DVec3::new(0.5, 0.0, 0.0)).length() < 1e-12);
        // The camera's z axis is the rig's +x: a point 1 m further along rig x is at z = 1.
        let p = cam.cam_from_rig.transform_point(DVec3::new(1.5, 0.0, 0.0));
        assert!((p - DVec3::new(0.0, 0.0, 1.0)).length() < 1e-12, "{p:?}");
        assert_eq!(rig.rig_frame, "rig");
        assert_eq!(rig.format, RigFileFormat::Sweepdepth);
    }

    #[test]
    fn matrix_forms_agree_and_bad_shapes_fail() {
        let flat = serde_yaml_ng::from_str::<Value>("[0, -1, 0, 1, 0, 0, 0, 0, 1]").unwrap();
        let rows = serde_yaml_ng::from_str::<Value>("[[0, -1, 0], [1, 0, 0], [0, 0, 1]]").unwrap();
        let a = matrix3(&flat).unwrap();
        assert_eq!(a, matrix3(&rows).unwrap());
        // Row-major: the first row is (0, -1, 0), so R * x = (0, 1, 0).
        assert_eq!(a * DVec3::X, DVec3::Y);
        let bad = serde_yaml_ng::from_str::<Value>("[[1, 0], [0, 1]]").unwrap();
        assert!(matrix3(&bad).is_err());
    }

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
