//! Camera geometry: pinhole intrinsics, lens distortion, rigid poses and rigs.
//!
//! Conventions (all frames are right-handed):
//! - Camera frames are ROS *optical* frames: x right, y down, z forward (REP 103).
//! - A transform named `a_from_b` maps a point expressed in frame `b` into frame `a`:
//!   `point_in_a = a_from_b.transform_point(point_in_b)`.
//! - Pixel coordinates are 0-based with the centre of the top-left pixel at (0, 0), as in ROS
//!   `CameraInfo` and OpenCV.
//! - Depth is z along the camera's optical axis, in metres.

use glam::{DMat3, DQuat, DVec2, DVec3};
use serde::{Deserialize, Serialize};

use crate::msgs::CameraInfo;

/// Errors building camera models and rigs.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum GeometryError {
    #[error("camera '{camera}': {reason}")]
    InvalidIntrinsics { camera: String, reason: String },
    #[error("camera '{camera}': unsupported distortion model '{model}' (supported: plumb_bob, rational_polynomial with zero k4..k6, equidistant, none)")]
    UnsupportedDistortion { camera: String, model: String },
    #[error(
        "camera '{camera}': distortion model '{model}' needs {expected} coefficients, got {got}"
    )]
    DistortionCoefficients {
        camera: String,
        model: String,
        expected: usize,
        got: usize,
    },
    #[error("camera '{camera}': the image is {image_width}x{image_height} but its camera_info describes {expected_width}x{expected_height} ({explanation})")]
    ImageSizeMismatch {
        camera: String,
        image_width: u32,
        image_height: u32,
        expected_width: u32,
        expected_height: u32,
        explanation: String,
    },
    #[error("pose of '{frame}' is not a rigid transform: {reason}")]
    InvalidPose { frame: String, reason: String },
    #[error("rig: {0}")]
    InvalidRig(String),
}

/// Pinhole intrinsics of one image, in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PinholeIntrinsics {
    pub width_px: u32,
    pub height_px: u32,
    pub fx_px: f64,
    pub fy_px: f64,
    pub cx_px: f64,
    pub cy_px: f64,
}

impl PinholeIntrinsics {
    pub fn k_matrix(&self) -> DMat3 {
        DMat3::from_cols(
            DVec3::new(self.fx_px, 0.0, 0.0),
            DVec3::new(0.0, self.fy_px, 0.0),
            DVec3::new(self.cx_px, self.cy_px, 1.0),
        )
    }

    /// Ray through pixel `(u, v)` with z = 1 (no distortion).
    pub fn unproject_z1(&self, pixel: DVec2) -> DVec3 {
        DVec3::new(
            (pixel.x - self.cx_px) / self.fx_px,
            (pixel.y - self.cy_px) / self.fy_px,
            1.0,
        )
    }

    /// Scales the image by `factor` (pixel centres stay pixel centres).
    pub fn scaled(&self, factor: f64, width_px: u32, height_px: u32) -> Self {
        Self {
            width_px,
            height_px,
            fx_px: self.fx_px * factor,
            fy_px: self.fy_px * factor,
            cx_px: (self.cx_px + 0.5) * factor - 0.5,
            cy_px: (self.cy_px + 0.5) * factor - 0.5,
        }
    }

    fn validate(&self, camera: &str) -> Result<(), GeometryError> {
        let bad = |reason: &str| GeometryError::InvalidIntrinsics {
            camera: camera.to_string(),
            reason: reason.to_string(),
        };
        if self.width_px == 0 || self.height_px == 0 {
            return Err(bad("image size is zero"));
        }
        for (name, v) in [
            ("fx", self.fx_px),
            ("fy", self.fy_px),
            ("cx", self.cx_px),
            ("cy", self.cy_px),
        ] {
            if !v.is_finite() {
                return Err(bad(&format!("{name} is not finite")));
            }
        }
        if self.fx_px == 0.0 || self.fy_px == 0.0 {
            return Err(bad("focal length is zero (K and P are empty?)"));
        }
        Ok(())
    }
}

/// Lens distortion, applied inside the projection (no rectification pass).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(tag = "model", rename_all = "snake_case")]
pub enum Distortion {
    #[default]
    None,
    /// Brown-Conrady as in OpenCV / ROS `plumb_bob`: D = [k1, k2, p1, p2, k3].
    PlumbBob {
        k1: f64,
        k2: f64,
        p1: f64,
        p2: f64,
        k3: f64,
    },
    /// Fisheye (Kannala-Brandt) as in OpenCV fisheye / ROS `equidistant`: D = [k1, k2, k3, k4].
    Equidistant { k1: f64, k2: f64, k3: f64, k4: f64 },
}

impl Distortion {
    /// Maps an undistorted normalised image point (x/z, y/z) to the distorted one.
    pub fn distort(&self, p: DVec2) -> DVec2 {
        match *self {
            Distortion::None => p,
            Distortion::PlumbBob { k1, k2, p1, p2, k3 } => {
                let r2 = p.length_squared();
                let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
                let xy = p.x * p.y;
                DVec2::new(
                    p.x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * p.x * p.x),
                    p.y * radial + p1 * (r2 + 2.0 * p.y * p.y) + 2.0 * p2 * xy,
                )
            }
            Distortion::Equidistant { k1, k2, k3, k4 } => {
                let r = p.length();
                if r < 1e-12 {
                    return p;
                }
                let theta = r.atan();
                let t2 = theta * theta;
                let theta_d = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))));
                p * (theta_d / r)
            }
        }
    }

    /// Inverse of [`Distortion::distort`] by fixed-point iteration (used to unproject pixels of
    /// a distorted reference camera).
    pub fn undistort(&self, distorted: DVec2) -> DVec2 {
        if matches!(self, Distortion::None) {
            return distorted;
        }
        let mut p = distorted;
        for _ in 0..50 {
            let error = self.distort(p) - distorted;
            p -= error;
            if error.length_squared() < 1e-24 {
                break;
            }
        }
        p
    }

    pub fn is_none(&self) -> bool {
        matches!(self, Distortion::None)
    }

    /// Parses a ROS `distortion_model` + `D`.
    pub fn from_ros(camera: &str, model: &str, d: &[f64]) -> Result<Self, GeometryError> {
        let all_zero = d.iter().all(|&v| v == 0.0);
        let need = |expected: usize| {
            if d.len() < expected {
                Err(GeometryError::DistortionCoefficients {
                    camera: camera.to_string(),
                    model: model.to_string(),
                    expected,
                    got: d.len(),
                })
            } else {
                Ok(())
            }
        };
        match model {
            "" | "none" if all_zero => Ok(Distortion::None),
            "plumb_bob" | "rational_polynomial" => {
                if all_zero {
                    return Ok(Distortion::None);
                }
                need(5)?;
                if d.iter().skip(5).any(|&v| v != 0.0) {
                    let model = if model == "rational_polynomial" {
                        "rational_polynomial with non-zero k4..k6".to_string()
                    } else {
                        format!("plumb_bob with {} coefficients (it has 5)", d.len())
                    };
                    return Err(GeometryError::UnsupportedDistortion {
                        camera: camera.to_string(),
                        model,
                    });
                }
                Ok(Distortion::PlumbBob {
                    k1: d[0],
                    k2: d[1],
                    p1: d[2],
                    p2: d[3],
                    k3: d[4],
                })
            }
            "equidistant" | "fisheye" => {
                if all_zero {
                    return Ok(Distortion::None);
                }
                need(4)?;
                if d.iter().skip(4).any(|&v| v != 0.0) {
                    return Err(GeometryError::UnsupportedDistortion {
                        camera: camera.to_string(),
                        model: format!("{model} with {} coefficients (it has 4)", d.len()),
                    });
                }
                Ok(Distortion::Equidistant {
                    k1: d[0],
                    k2: d[1],
                    k3: d[2],
                    k4: d[3],
                })
            }
            other => Err(GeometryError::UnsupportedDistortion {
                camera: camera.to_string(),
                model: other.to_string(),
            }),
        }
    }
}

/// Intrinsics plus distortion: everything needed to go between pixels and camera-frame rays.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CameraModel {
    pub intrinsics: PinholeIntrinsics,
    #[serde(default)]
    pub distortion: Distortion,
}

impl CameraModel {
    pub fn pinhole(intrinsics: PinholeIntrinsics) -> Self {
        Self {
            intrinsics,
            distortion: Distortion::None,
        }
    }

    /// Builds the model from a ROS `sensor_msgs/CameraInfo`.
    ///
    /// - With no distortion (D empty or all zero) the image is taken as rectified and the
    ///   intrinsics come from P (its left 3x3), falling back to K when P is all zero.
    /// - With distortion, the image is the raw one (`image_raw`): K and D describe it, while P
    ///   describes the rectified image that we never form, so K is used.
    /// - ROI and binning are honoured (REP 104: ROI in full-resolution pixels, binning after it).
    ///
    /// Refused (typed errors naming the camera): a NaN or infinite entry anywhere in K, P or D;
    /// K and P both all zero (uncalibrated); a focal length that is not positive; an unknown
    /// distortion model, too few coefficients, or non-zero coefficients the model does not
    /// have; an ROI that does not lie inside the `width` x `height` sensor; a binned ROI of
    /// zero pixels. [`check_image_size`] then checks an image against it.
    pub fn from_camera_info(camera: &str, info: &CameraInfo) -> Result<Self, GeometryError> {
        let bad = |reason: String| GeometryError::InvalidIntrinsics {
            camera: camera.to_string(),
            reason,
        };
        for (matrix, values) in [("K", &info.k[..]), ("P", &info.p[..]), ("D", &info.d[..])] {
            if let Some((i, v)) = values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
                return Err(bad(format!(
                    "camera_info {matrix}[{i}] is {v} (calibration values must be finite)"
                )));
            }
        }
        let distortion = Distortion::from_ros(camera, &info.distortion_model, &info.d)?;
        let p_is_set = info.p.iter().any(|&v| v != 0.0);
        let k_is_set = info.k.iter().any(|&v| v != 0.0);
        let (fx, fy, cx, cy) = if distortion.is_none() && p_is_set {
            (info.p[0], info.p[5], info.p[2], info.p[6])
        } else if k_is_set {
            (info.k[0], info.k[4], info.k[2], info.k[5])
        } else if p_is_set {
            (info.p[0], info.p[5], info.p[2], info.p[6])
        } else {
            return Err(GeometryError::InvalidIntrinsics {
                camera: camera.to_string(),
                reason: "both K and P are all zero (uncalibrated camera)".to_string(),
            });
        };
        if !(fx > 0.0 && fy > 0.0) {
            return Err(bad(format!(
                "focal lengths must be positive, got fx = {fx}, fy = {fy}"
            )));
        }
        let binning_x = f64::from(info.binning_x.max(1));
        let binning_y = f64::from(info.binning_y.max(1));
        let roi = &info.roi;
        let roi_set = roi.width > 0 && roi.height > 0;
        let inside = |offset: u32, size: u32, full: u32| {
            full == 0 || u64::from(offset) + u64::from(size) <= u64::from(full)
        };
        if roi_set
            && !(inside(roi.x_offset, roi.width, info.width)
                && inside(roi.y_offset, roi.height, info.height))
        {
            return Err(bad(format!(
                "ROI {}x{} at ({}, {}) does not lie inside the {}x{} sensor",
                roi.width, roi.height, roi.x_offset, roi.y_offset, info.width, info.height
            )));
        }
        let (x_offset, y_offset, full_w, full_h) = if roi_set {
            (
                f64::from(roi.x_offset),
                f64::from(roi.y_offset),
                roi.width,
                roi.height,
            )
        } else {
            (0.0, 0.0, info.width, info.height)
        };
        let intrinsics = PinholeIntrinsics {
            width_px: full_w / info.binning_x.max(1),
            height_px: full_h / info.binning_y.max(1),
            fx_px: fx / binning_x,
            fy_px: fy / binning_y,
            cx_px: (cx - x_offset + 0.5) / binning_x - 0.5,
            cy_px: (cy - y_offset + 0.5) / binning_y - 0.5,
        };
        intrinsics.validate(camera)?;
        Ok(Self {
            intrinsics,
            distortion,
        })
    }

    /// Projects a point in this camera's frame to a pixel; `None` if it is not in front.
    pub fn project(&self, point_in_cam: DVec3) -> Option<DVec2> {
        if point_in_cam.z <= 1e-9 {
            return None;
        }
        let normalised = DVec2::new(
            point_in_cam.x / point_in_cam.z,
            point_in_cam.y / point_in_cam.z,
        );
        let d = self.distortion.distort(normalised);
        let k = &self.intrinsics;
        Some(DVec2::new(k.fx_px * d.x + k.cx_px, k.fy_px * d.y + k.cy_px))
    }

    /// The ray through a pixel, scaled to z = 1, in this camera's frame.
    pub fn unproject_z1(&self, pixel: DVec2) -> DVec3 {
        let k = &self.intrinsics;
        let distorted = DVec2::new((pixel.x - k.cx_px) / k.fx_px, (pixel.y - k.cy_px) / k.fy_px);
        let p = self.distortion.undistort(distorted);
        DVec3::new(p.x, p.y, 1.0)
    }

    pub fn contains(&self, pixel: DVec2) -> bool {
        let k = &self.intrinsics;
        pixel.x >= -0.5
            && pixel.y >= -0.5
            && pixel.x <= f64::from(k.width_px) - 0.5
            && pixel.y <= f64::from(k.height_px) - 0.5
    }
}

/// The size of the image a CameraInfo describes (REP 104): its ROI when one is set (else the
/// full `width` x `height`), divided by the binning (0 counts as 1), rounded down.
pub fn camera_info_image_size(info: &CameraInfo) -> (u32, u32) {
    let roi = &info.roi;
    let (w, h) = if roi.width > 0 && roi.height > 0 {
        (roi.width, roi.height)
    } else {
        (info.width, info.height)
    };
    (w / info.binning_x.max(1), h / info.binning_y.max(1))
}

/// Checks that an image of `width` x `height` is the one `info` describes
/// ([`camera_info_image_size`]: the ROI, binned). Any other size is refused with what the
/// CameraInfo says (size, ROI, binning), since the intrinsics would not apply to it.
pub fn check_image_size(
    camera: &str,
    info: &CameraInfo,
    width: u32,
    height: u32,
) -> Result<(), GeometryError> {
    let (expected_width, expected_height) = camera_info_image_size(info);
    if (width, height) == (expected_width, expected_height) {
        return Ok(());
    }
    let roi = &info.roi;
    let mut explanation = format!("camera_info size {}x{}", info.width, info.height);
    if roi.width > 0 && roi.height > 0 {
        explanation += &format!(
            ", ROI {}x{} at ({}, {})",
            roi.width, roi.height, roi.x_offset, roi.y_offset
        );
    } else {
        explanation += ", no ROI";
    }
    if info.binning_x.max(1) > 1 || info.binning_y.max(1) > 1 {
        explanation += &format!(", binning {}x{}", info.binning_x, info.binning_y);
    } else {
        explanation += ", no binning";
    }
    Err(GeometryError::ImageSizeMismatch {
        camera: camera.to_string(),
        image_width: width,
        image_height: height,
        expected_width,
        expected_height,
        explanation,
    })
}

/// A rigid transform `a_from_b`: `point_in_a = rotation * point_in_b + translation`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RigidTransform {
    pub rotation: DQuat,
    pub translation: DVec3,
}

impl Default for RigidTransform {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl RigidTransform {
    pub const IDENTITY: Self = Self {
        rotation: DQuat::IDENTITY,
        translation: DVec3::ZERO,
    };

    /// From a quaternion that must be finite and of unit length (within 1e-3, as tf2 checks),
    /// and a finite translation. The quaternion is renormalised.
    pub fn from_quat_translation(
        frame: &str,
        rotation: DQuat,
        translation: DVec3,
    ) -> Result<Self, GeometryError> {
        let bad = |reason: &str| GeometryError::InvalidPose {
            frame: frame.to_string(),
            reason: reason.to_string(),
        };
        if !rotation.is_finite() {
            return Err(bad("quaternion has a NaN or infinite component"));
        }
        if !translation.is_finite() {
            return Err(bad("translation has a NaN or infinite component"));
        }
        let norm = rotation.length();
        if (norm - 1.0).abs() > 1e-3 {
            return Err(bad(&format!(
                "quaternion is not unit length (|q| = {norm})"
            )));
        }
        Ok(Self {
            rotation: rotation / norm,
            translation,
        })
    }

    /// From a rotation matrix (must be orthonormal with det +1, within 1e-3) and a translation.
    pub fn from_matrix_translation(
        frame: &str,
        rotation: DMat3,
        translation: DVec3,
    ) -> Result<Self, GeometryError> {
        let bad = |reason: String| GeometryError::InvalidPose {
            frame: frame.to_string(),
            reason,
        };
        if !rotation.is_finite() || !translation.is_finite() {
            return Err(bad("NaN or infinite entry".to_string()));
        }
        let orthogonality = (rotation.transpose() * rotation - DMat3::IDENTITY)
            .to_cols_array()
            .iter()
            .fold(0.0f64, |m, v| m.max(v.abs()));
        if orthogonality > 1e-3 || (rotation.determinant() - 1.0).abs() > 1e-3 {
            return Err(bad(format!(
                "rotation is not orthonormal with det +1 (max |RᵀR - I| = {orthogonality:.2e}, det = {:.4})",
                rotation.determinant()
            )));
        }
        Ok(Self {
            rotation: DQuat::from_mat3(&rotation).normalize(),
            translation,
        })
    }

    pub fn transform_point(&self, point: DVec3) -> DVec3 {
        self.rotation * point + self.translation
    }

    pub fn transform_vector(&self, vector: DVec3) -> DVec3 {
        self.rotation * vector
    }

    pub fn inverse(&self) -> Self {
        let inv = self.rotation.inverse();
        Self {
            rotation: inv,
            translation: -(inv * self.translation),
        }
    }

    /// `a_from_b * b_from_c = a_from_c`.
    pub fn compose(&self, b_from_c: &RigidTransform) -> RigidTransform {
        RigidTransform {
            rotation: (self.rotation * b_from_c.rotation).normalize(),
            translation: self.rotation * b_from_c.translation + self.translation,
        }
    }

    pub fn rotation_matrix(&self) -> DMat3 {
        DMat3::from_quat(self.rotation)
    }
}

/// One physical camera of a rig.
#[derive(Debug, Clone, PartialEq)]
pub struct RigCamera {
    pub name: String,
    pub model: CameraModel,
    /// Maps points in the rig frame into this camera's optical frame.
    pub cam_from_rig: RigidTransform,
}

impl RigCamera {
    /// The camera centre in the rig frame, metres.
    pub fn centre_in_rig(&self) -> DVec3 {
        self.cam_from_rig.inverse().translation
    }
}

/// The camera depth is estimated for.
#[derive(Debug, Clone, PartialEq)]
pub enum Reference {
    /// One of the rig's cameras, by index.
    Camera(usize),
    /// A camera of our own choosing (size, intrinsics, pose) with no image of its own.
    Virtual {
        model: CameraModel,
        cam_from_rig: RigidTransform,
    },
}

/// The cameras plus the reference.
#[derive(Debug, Clone, PartialEq)]
pub struct Rig {
    pub cameras: Vec<RigCamera>,
    pub reference: Reference,
}

impl Rig {
    pub fn new(cameras: Vec<RigCamera>, reference: Reference) -> Result<Self, GeometryError> {
        if cameras.len() < 2 {
            return Err(GeometryError::InvalidRig(format!(
                "need at least 2 cameras, got {}",
                cameras.len()
            )));
        }
        for camera in &cameras {
            camera.model.intrinsics.validate(&camera.name)?;
        }
        match &reference {
            Reference::Camera(i) if *i >= cameras.len() => {
                return Err(GeometryError::InvalidRig(format!(
                    "reference camera index {i} out of range (rig has {} cameras)",
                    cameras.len()
                )));
            }
            Reference::Virtual { model, .. } => model.intrinsics.validate("virtual reference")?,
            _ => {}
        }
        Ok(Self { cameras, reference })
    }

    pub fn reference_index(&self) -> Option<usize> {
        match self.reference {
            Reference::Camera(i) => Some(i),
            Reference::Virtual { .. } => None,
        }
    }

    pub fn reference_model(&self) -> CameraModel {
        match &self.reference {
            Reference::Camera(i) => self.cameras[*i].model,
            Reference::Virtual { model, .. } => *model,
        }
    }

    pub fn ref_from_rig(&self) -> RigidTransform {
        match &self.reference {
            Reference::Camera(i) => self.cameras[*i].cam_from_rig,
            Reference::Virtual { cam_from_rig, .. } => *cam_from_rig,
        }
    }

    /// `cam_from_ref` for camera `i`.
    pub fn cam_from_ref(&self, i: usize) -> RigidTransform {
        self.cameras[i]
            .cam_from_rig
            .compose(&self.ref_from_rig().inverse())
    }

    /// Splits the non-reference cameras into the two halves of the paper's best half-sequence:
    /// left and right of the reference along the rig's main baseline direction.
    ///
    /// The baseline direction is the principal axis of the camera centres (the reference
    /// included), oriented to agree with the reference's +x axis. A camera is "left" when its
    /// centre lies on the negative side of the reference centre along that axis. Returns one
    /// entry per camera: `Some(false)` = left, `Some(true)` = right, `None` = the reference.
    pub fn half_sequence_split(&self) -> Vec<Option<bool>> {
        let ref_from_rig = self.ref_from_rig();
        let centres_in_ref: Vec<DVec3> = self
            .cameras
            .iter()
            .map(|c| ref_from_rig.transform_point(c.centre_in_rig()))
            .collect();
        let mut points = centres_in_ref.clone();
        if self.reference_index().is_none() {
            points.push(DVec3::ZERO);
        }
        let n = points.len() as f64;
        let mean = points.iter().copied().fold(DVec3::ZERO, |a, b| a + b) / n;
        let mut cov = nalgebra::Matrix3::<f64>::zeros();
        for p in &points {
            let d = nalgebra::Vector3::new(p.x - mean.x, p.y - mean.y, p.z - mean.z);
            cov += d * d.transpose();
        }
        let eigen = nalgebra::SymmetricEigen::new(cov);
        let mut best = 0;
        for i in 1..3 {
            if eigen.eigenvalues[i] > eigen.eigenvalues[best] {
                best = i;
            }
        }
        let v = eigen.eigenvectors.column(best);
        let mut axis = DVec3::new(v[0], v[1], v[2]);
        if axis.length_squared() < 1e-24 || !axis.is_finite() {
            axis = DVec3::X;
        }
        if axis.dot(DVec3::X) < 0.0 {
            axis = -axis;
        }
        let reference = self.reference_index();
        centres_in_ref
            .iter()
            .enumerate()
            .map(|(i, c)| {
                if Some(i) == reference {
                    None
                } else {
                    Some(c.dot(axis) > 0.0)
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{CameraInfo, RegionOfInterest};

    fn info() -> CameraInfo {
        CameraInfo {
            width: 640,
            height: 480,
            distortion_model: "plumb_bob".into(),
            d: vec![0.0; 5],
            k: [500.0, 0.0, 320.0, 0.0, 510.0, 240.0, 0.0, 0.0, 1.0],
            p: [
                490.0, 0.0, 321.0, 0.0, 0.0, 495.0, 241.0, 0.0, 0.0, 0.0, 1.0, 0.0,
            ],
            ..Default::default()
        }
    }

    #[test]
    fn camera_info_prefers_p_without_distortion_and_k_with_it() {
        let m = CameraModel::from_camera_info("c", &info()).unwrap();
        assert_eq!(m.intrinsics.fx_px, 490.0);
        assert_eq!(m.intrinsics.cy_px, 241.0);
        let mut distorted = info();
        distorted.d = vec![-0.1, 0.01, 0.0, 0.0, 0.0];
        let m = CameraModel::from_camera_info("c", &distorted).unwrap();
        assert_eq!(m.intrinsics.fx_px, 500.0);
        assert!(matches!(m.distortion, Distortion::PlumbBob { .. }));
        let mut no_p = info();
        no_p.p = [0.0; 12];
        let m = CameraModel::from_camera_info("c", &no_p).unwrap();
        assert_eq!(m.intrinsics.fx_px, 500.0);
    }

    #[test]
    fn camera_info_honours_roi_and_binning() {
        let mut i = info();
        i.binning_x = 2;
        i.binning_y = 2;
        i.roi = RegionOfInterest {
            x_offset: 100,
            y_offset: 40,
            width: 400,
            height: 300,
            do_rectify: false,
        };
        let m = CameraModel::from_camera_info("c", &i).unwrap();
        assert_eq!((m.intrinsics.width_px, m.intrinsics.height_px), (200, 150));
        assert_eq!(m.intrinsics.fx_px, 245.0);
        // A full-resolution point at pixel (321 + 10, 241) sits at ((331 - 100 + 0.5) / 2 - 0.5).
        let full = CameraModel::from_camera_info("c", &info()).unwrap();
        let point = full.unproject_z1(DVec2::new(331.0, 241.0)) * 2.0;
        let px = m.project(point).unwrap();
        assert!((px.x - ((331.0 - 100.0 + 0.5) / 2.0 - 0.5)).abs() < 1e-9);
        assert!((px.y - ((241.0 - 40.0 + 0.5) / 2.0 - 0.5)).abs() < 1e-9);
    }

    #[test]
    fn camera_info_rejects_bad_input() {
        let mut i = info();
        i.k = [0.0; 9];
        i.p = [0.0; 12];
        assert!(CameraModel::from_camera_info("c", &i).is_err());
        let mut i = info();
        i.distortion_model = "weird".into();
        i.d = vec![0.1];
        assert!(matches!(
            CameraModel::from_camera_info("c", &i),
            Err(GeometryError::UnsupportedDistortion { .. })
        ));
        let mut i = info();
        i.d = vec![0.1, 0.2];
        assert!(matches!(
            CameraModel::from_camera_info("c", &i),
            Err(GeometryError::DistortionCoefficients { .. })
        ));
    }

    #[test]
    fn camera_info_rejects_non_finite_entries_anywhere_in_k_p_d() {
        let invalid = |i: &CameraInfo| match CameraModel::from_camera_info("cam7", i) {
            Err(GeometryError::InvalidIntrinsics { camera, reason }) => {
                assert_eq!(camera, "cam7");
                reason
            }
            other => panic!("expected InvalidIntrinsics, got {other:?}"),
        };
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            // K[0] is unused here (P wins without distortion): still refused.
            let mut i = info();
            i.k[0] = bad;
            assert!(invalid(&i).contains("K[0]"));
            // P[3] (Tx) is never used: still refused.
            let mut i = info();
            i.p[3] = bad;
            assert!(invalid(&i).contains("P[3]"));
            let mut i = info();
            i.d = vec![0.0, bad, 0.0, 0.0, 0.0];
            assert!(invalid(&i).contains("D[1]"));
        }
    }

    #[test]
    fn camera_info_rejects_uncalibrated_and_non_positive_focal_lengths() {
        let mut i = info();
        i.k = [0.0; 9];
        i.p = [0.0; 12];
        let e = CameraModel::from_camera_info("cam8", &i).unwrap_err();
        assert!(e.to_string().contains("cam8") && e.to_string().contains("uncalibrated"));
        let mut i = info();
        i.p[0] = -490.0;
        let e = CameraModel::from_camera_info("c", &i).unwrap_err();
        assert!(e.to_string().contains("positive"), "{e}");
    }

    #[test]
    fn camera_info_rejects_unknown_models_and_extra_coefficients() {
        let mut i = info();
        i.distortion_model = "kannala_brandt_9".into();
        i.d = vec![0.1; 9];
        assert_eq!(
            CameraModel::from_camera_info("c", &i),
            Err(GeometryError::UnsupportedDistortion {
                camera: "c".into(),
                model: "kannala_brandt_9".into()
            })
        );
        let mut i = info();
        i.d = vec![0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.3];
        assert!(matches!(
            CameraModel::from_camera_info("c", &i),
            Err(GeometryError::UnsupportedDistortion { .. })
        ));
        // Trailing zeros are fine (rational_polynomial's k4..k6 = 0 is plumb_bob).
        i.d[7] = 0.0;
        assert!(CameraModel::from_camera_info("c", &i).is_ok());
        let mut i = info();
        i.distortion_model = "equidistant".into();
        i.d = vec![0.1, 0.0, 0.0, 0.0, 0.2];
        assert!(matches!(
            CameraModel::from_camera_info("c", &i),
            Err(GeometryError::UnsupportedDistortion { .. })
        ));
    }

    #[test]
    fn camera_info_rejects_roi_outside_the_sensor() {
        let mut i = info();
        i.roi = RegionOfInterest {
            x_offset: 600,
            y_offset: 0,
            width: 100,
            height: 100,
            do_rectify: false,
        };
        let e = CameraModel::from_camera_info("c", &i).unwrap_err();
        assert!(e.to_string().contains("ROI 100x100 at (600, 0)"), "{e}");
        i.roi.x_offset = u32::MAX; // no overflow
        assert!(CameraModel::from_camera_info("c", &i).is_err());
        i.roi.x_offset = 540;
        assert!(CameraModel::from_camera_info("c", &i).is_ok());
        // A binning larger than the ROI leaves no pixels.
        i.binning_x = 200;
        assert!(CameraModel::from_camera_info("c", &i).is_err());
    }

    #[test]
    fn image_size_must_be_the_binned_roi() {
        let full = info();
        assert_eq!(check_image_size("c", &full, 640, 480), Ok(()));
        let e = check_image_size("cam9", &full, 320, 240).unwrap_err();
        assert_eq!(
            e,
            GeometryError::ImageSizeMismatch {
                camera: "cam9".into(),
                image_width: 320,
                image_height: 240,
                expected_width: 640,
                expected_height: 480,
                explanation: "camera_info size 640x480, no ROI, no binning".into(),
            }
        );
        assert!(e.to_string().contains("cam9") && e.to_string().contains("320x240"));
        // Binning alone explains a half-size image.
        let mut binned = info();
        binned.binning_x = 2;
        binned.binning_y = 2;
        assert_eq!(check_image_size("c", &binned, 320, 240), Ok(()));
        assert!(check_image_size("c", &binned, 640, 480).is_err());
        // ROI + binning (REP 104: the image is the ROI, binned; odd sizes round down).
        let mut roi = info();
        roi.binning_x = 2;
        roi.binning_y = 3;
        roi.roi = RegionOfInterest {
            x_offset: 101,
            y_offset: 40,
            width: 401,
            height: 300,
            do_rectify: false,
        };
        assert_eq!(check_image_size("c", &roi, 200, 100), Ok(()));
        let m = CameraModel::from_camera_info("c", &roi).unwrap();
        assert_eq!((m.intrinsics.width_px, m.intrinsics.height_px), (200, 100));
        let e = check_image_size("c", &roi, 401, 300).unwrap_err();
        assert!(
            e.to_string()
                .contains("ROI 401x300 at (101, 40), binning 2x3"),
            "{e}"
        );
    }

    #[test]
    fn distortion_round_trips() {
        for d in [
            Distortion::PlumbBob {
                k1: -0.28,
                k2: 0.07,
                p1: 0.001,
                p2: -0.0005,
                k3: 0.0,
            },
            Distortion::Equidistant {
                k1: 0.01,
                k2: -0.005,
                k3: 0.001,
                k4: 0.0,
            },
        ] {
            let p = DVec2::new(0.3, -0.2);
            let back = d.undistort(d.distort(p));
            assert!((back - p).length() < 1e-9, "{d:?}: {back:?}");
        }
    }

    #[test]
    fn transforms_compose_and_invert() {
        let a_from_b = RigidTransform::from_quat_translation(
            "b",
            DQuat::from_rotation_y(0.3),
            DVec3::new(1.0, 2.0, 3.0),
        )
        .unwrap();
        let p = DVec3::new(0.5, -0.1, 2.0);
        let back = a_from_b
            .inverse()
            .transform_point(a_from_b.transform_point(p));
        assert!((back - p).length() < 1e-12);
        let id = a_from_b.compose(&a_from_b.inverse());
        assert!(id.translation.length() < 1e-12);
        assert!(RigidTransform::from_quat_translation(
            "x",
            DQuat::from_xyzw(0.0, 0.0, 0.0, 2.0),
            DVec3::ZERO
        )
        .is_err());
        assert!(RigidTransform::from_quat_translation(
            "x",
            DQuat::from_xyzw(f64::NAN, 0.0, 0.0, 1.0),
            DVec3::ZERO
        )
        .is_err());
    }

    #[test]
    fn half_sequence_split_follows_geometry_not_order() {
        let model = CameraModel::pinhole(PinholeIntrinsics {
            width_px: 10,
            height_px: 10,
            fx_px: 10.0,
            fy_px: 10.0,
            cx_px: 4.5,
            cy_px: 4.5,
        });
        // Cameras listed out of order along x; the reference is at x = 0.
        let xs = [0.2, -0.1, 0.0, 0.1, -0.2];
        let cameras = xs
            .iter()
            .enumerate()
            .map(|(i, &x)| RigCamera {
                name: format!("c{i}"),
                model,
                cam_from_rig: RigidTransform {
                    rotation: DQuat::IDENTITY,
                    translation: DVec3::new(-x, 0.0, 0.0),
                },
            })
            .collect();
        let rig = Rig::new(cameras, Reference::Camera(2)).unwrap();
        assert_eq!(
            rig.half_sequence_split(),
            vec![Some(true), Some(false), None, Some(true), Some(false)]
        );
    }
}
