//! Camera geometry: pinhole intrinsics, lens distortion, rigid poses and rigs. Nothing here
//! knows ROS messages: the `sensor_msgs/CameraInfo` conversion lives in
//! [`crate::ros::camera_info`].
//!
//! - [`camera`]: [`PinholeIntrinsics`] and [`CameraModel`] (pixels <-> camera-frame rays).
//! - [`distortion`]: the lens models ([`Distortion`]: `plumb_bob`, `equidistant`).
//! - [`pose`]: [`RigidTransform`], named `a_from_b`.
//! - [`rig`]: [`Rig`] (cameras + a real or virtual [`Reference`]) and the half-sequence split.
//!
//! Conventions (all frames are right-handed):
//! - Camera frames are ROS *optical* frames: x right, y down, z forward (REP 103).
//! - A transform named `a_from_b` maps a point expressed in frame `b` into frame `a`:
//!   `point_in_a = a_from_b.transform_point(point_in_b)`.
//! - Pixel coordinates are 0-based with the centre of the top-left pixel at (0, 0), as in ROS
//!   `CameraInfo` and OpenCV.
//! - Depth is z along the camera's optical axis, in metres.

pub mod camera;
pub mod distortion;
pub mod neighbours;
pub mod pose;
pub mod rig;

pub use camera::{CameraModel, PinholeIntrinsics};
pub use distortion::Distortion;
pub use pose::RigidTransform;
pub use rig::{Reference, Rig, RigCamera};

/// A length in metres for messages and parameter files: to the micrometre, without float
/// noise (`2.4000000000000004` reads `2.4`), always with a decimal point (`10.0`: a YAML
/// double, not an integer).
pub fn metres(m: f64) -> String {
    if !m.is_finite() {
        return format!("{m}");
    }
    let s = format!("{m:.6}");
    let s = s.trim_end_matches('0');
    if s.ends_with('.') {
        format!("{s}0")
    } else {
        s.to_string()
    }
}

/// Errors building camera models and rigs.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum GeometryError {
    #[error("camera '{camera}': {reason}")]
    InvalidIntrinsics { camera: String, reason: String },
    #[error("camera '{camera}': unsupported distortion model '{model}' (supported: plumb_bob, rational_polynomial with zero k4..k6, equidistant, none); a driver that also publishes rectified images: subscribe its image_rect topic (image_topic), whose CameraInfo P describes it without distortion")]
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
    #[error(
        "camera '{camera}': the {model} distortion {coefficients:?} folds over {fold_deg:.1} \
         degrees off axis (distorted radius {fold_radius:.4}), inside the image, which reaches \
         {image_radius:.4}: pixels beyond the fold have no ray, and rays beyond it would land \
         back in the image; the calibration does not hold over the whole image"
    )]
    DistortionFolds {
        camera: String,
        model: &'static str,
        coefficients: Vec<f64>,
        fold_deg: f64,
        fold_radius: f64,
        image_radius: f64,
    },
    #[error("pose of '{frame}' is not a rigid transform: {reason}")]
    InvalidPose { frame: String, reason: String },
    #[error("rig: {0}")]
    InvalidRig(String),
}

#[cfg(test)]
mod tests {
    #[test]
    fn metres_drop_float_noise_and_keep_a_decimal_point() {
        assert_eq!(super::metres(2.4000000000000004), "2.4");
        assert_eq!(super::metres(76.80000000000001), "76.8");
        assert_eq!(super::metres(10.0), "10.0");
        assert_eq!(super::metres(0.465), "0.465");
        assert_eq!(super::metres(-1.5), "-1.5");
        assert_eq!(super::metres(f64::NAN), "NaN");
    }
}
