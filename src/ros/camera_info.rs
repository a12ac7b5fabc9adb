//! `sensor_msgs/CameraInfo` -> camera model, beside the ROS code that receives it (the
//! geometry itself, [`crate::geometry`], knows no messages), with the conventions of
//! image_geometry's `PinholeCameraModel` (ros-perception/vision_opencv,
//! `image_geometry/src/pinhole_camera_model.cpp`, `fromCameraInfo`) and REP 104:
//!
//! - **Raw or rectified is what the user declares** ([`ImageKind`]: the image topic's name,
//!   `image_raw` / `image_rect*`, or the node's `image_kinds` parameter), never guessed from D.
//!   A raw image is described by K and D, in the optical frame its `header.frame_id` names. A
//!   rectified image by P (`fx'`, `fy'`, `cx'`, `cy'`; no distortion), in that frame rotated by
//!   R, with P's `Tx = -fx'·B`, `Ty = -fy'·B` placing the camera of a stereo pair (see
//!   [`CameraCalibration::cam_from_frame`]).
//! - **ROI, then binning**, each as image_geometry applies them to K and P: `cx - x_offset`,
//!   `cy - y_offset` (full-resolution pixels), then `fx / binning_x`, `cx / binning_x`,
//!   `Tx / binning_x` (and y alike). Binning keeps every `b`-th pixel's position, as image_proc's
//!   crop_decimate does: `(cx - x_offset) / b`, not a pixel-centre shift. Binning 0 means 1; an
//!   ROI of all zeros means the full image; `do_rectify` does not change K or P (image_geometry
//!   uses the raw ROI for both, a `@todo` there).
//! - The image must be the ROI's size divided by the binning, rounded down
//!   ([`check_image_size`]).

use glam::{DMat3, DVec3};

use crate::geometry::{CameraModel, Distortion, GeometryError, PinholeIntrinsics, RigidTransform};
use crate::msgs::CameraInfo;

/// What an image topic carries: the raw sensor image or a rectified one. It decides which
/// parts of the CameraInfo describe the image (K + D, or P + R).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ImageKind {
    /// As the sensor took it (`image_raw`, `image`, `image_color`, `image_mono`): K and D.
    Raw,
    /// Undistorted and rotated into the stereo plane (`image_rect`, `image_rect_color`): P and R.
    Rectified,
}

impl ImageKind {
    /// From the image topic's name as image_pipeline names the topics of a camera namespace:
    /// the last segment `image_rect` or `image_rect_*` is rectified; `image_raw`, `image`,
    /// `image_color`, `image_mono` are raw. `None` for any other name (the caller must be told).
    pub fn from_topic(topic: &str) -> Option<Self> {
        let last = topic.rsplit('/').next().unwrap_or(topic);
        if last == "image_rect" || last.starts_with("image_rect_") {
            Some(ImageKind::Rectified)
        } else if matches!(last, "image_raw" | "image" | "image_color" | "image_mono") {
            Some(ImageKind::Raw)
        } else {
            None
        }
    }

    /// The parameter spelling: `raw` or `rect`.
    pub fn parse(value: &str) -> Option<Self> {
        match value {
            "raw" => Some(ImageKind::Raw),
            "rect" => Some(ImageKind::Rectified),
            _ => None,
        }
    }

    pub fn as_str(&self) -> &'static str {
        match self {
            ImageKind::Raw => "raw",
            ImageKind::Rectified => "rect",
        }
    }
}

/// A camera as one CameraInfo describes one kind of its image: the model of that image, and
/// where that camera sits relative to the frame the image's `header.frame_id` names.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraCalibration {
    pub model: CameraModel,
    /// R: the rotation from the image's frame into the rectified camera (identity for a raw
    /// image, or when R is all zero, i.e. not given).
    pub rect_from_frame_rotation: RigidTransform,
    /// P's translation in the rectified camera, `(Tx / fx', Ty / fy', 0)` (zero for a raw
    /// image and for the first camera of a stereo pair): a point in the frame P applies to
    /// lands in this camera at `point + translation`.
    pub p_translation: DVec3,
}

impl CameraCalibration {
    /// A model that needs no pose correction (a raw image, or a rig file's own model).
    pub fn unrectified(model: CameraModel) -> Self {
        Self {
            model,
            rect_from_frame_rotation: RigidTransform::IDENTITY,
            p_translation: DVec3::ZERO,
        }
    }

    /// `cam_from_frame`: the camera the model describes, relative to the frame its image's
    /// `header.frame_id` names (or that a rig file's pose gives): R, then, when
    /// `frame_shared` is true, P's translation.
    ///
    /// P's translation is applied only when the image's frame is shared with another camera
    /// of the rig. Then the frame is the one P applies to (image_geometry's
    /// `project3dToPixel` applies `Tx` to points in the image's frame; RealSense publishes
    /// infra2 with infra1's frame id and `Tx = -fx·B`, Gazebo's multicamera both cameras in
    /// one frame) and P's translation is the only thing that tells the cameras apart. A
    /// camera whose image has a frame of its own is where `/tf_static` (or the rig file)
    /// puts it: its frame *is* its centre, and a `Tx` there restates a baseline tf already
    /// has (the ZED wrapper publishes both), which must not be applied twice.
    pub fn cam_from_frame(&self, frame_shared: bool) -> RigidTransform {
        let translation = if frame_shared {
            self.p_translation
        } else {
            DVec3::ZERO
        };
        RigidTransform {
            rotation: self.rect_from_frame_rotation.rotation,
            translation,
        }
    }
}

/// An ROI is set unless all four numbers are zero (image_geometry's rule).
fn roi_is_set(info: &CameraInfo) -> bool {
    let roi = &info.roi;
    (roi.x_offset, roi.y_offset, roi.width, roi.height) != (0, 0, 0, 0)
}

/// Builds the camera of `kind` that `info` describes (see the module docs for the rules).
///
/// Refused (typed errors naming the camera): a NaN or infinite entry anywhere in K, R, P or D;
/// for a raw image, K all zero (uncalibrated), a distortion model we do not have, too few (or
/// extra non-zero) coefficients, or a distortion that folds over inside the image; for a
/// rectified image, P all zero, a P whose third row is not `[0, 0, 1, 0]` (ROS assumes
/// `Tz = 0`), or an R that is not a rotation; a focal length that is not positive; an ROI that
/// is partly zero or does not lie inside the `width` x `height` sensor; a binned ROI of zero
/// pixels. [`check_image_size`] then checks an image against it.
pub fn camera_from_info(
    camera: &str,
    info: &CameraInfo,
    kind: ImageKind,
) -> Result<CameraCalibration, GeometryError> {
    let bad = |reason: String| GeometryError::InvalidIntrinsics {
        camera: camera.to_string(),
        reason,
    };
    for (matrix, values) in [
        ("K", &info.k[..]),
        ("R", &info.r[..]),
        ("P", &info.p[..]),
        ("D", &info.d[..]),
    ] {
        if let Some((i, v)) = values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(bad(format!(
                "camera_info {matrix}[{i}] is {v} (calibration values must be finite)"
            )));
        }
    }
    let k_is_set = info.k.iter().any(|&v| v != 0.0);
    let p_is_set = info.p.iter().any(|&v| v != 0.0);
    if !k_is_set && !p_is_set {
        return Err(bad(
            "both K and P are all zero (uncalibrated camera)".to_string()
        ));
    }
    // fx, fy, cx, cy of the full-resolution image, and the rest of the calibration. (P's
    // Tx / fx' and Ty / fy' do not change with binning, which scales Tx with fx'.)
    let (full, distortion, rotation, p_translation) = match kind {
        ImageKind::Raw => {
            if !k_is_set {
                return Err(bad(
                    "K is all zero, and a raw image is described by K and D (uncalibrated camera, or declare the images rectified)"
                        .to_string(),
                ));
            }
            let k = &info.k;
            let distortion = Distortion::from_ros(camera, &info.distortion_model, &info.d)?;
            (
                [k[0], k[4], k[2], k[5]],
                distortion,
                RigidTransform::IDENTITY,
                DVec3::ZERO,
            )
        }
        ImageKind::Rectified => {
            let p = &info.p;
            if !p_is_set {
                return Err(bad(
                    "P is all zero, and a rectified image is described by P (uncalibrated camera, or declare the images raw)"
                        .to_string(),
                ));
            }
            if (p[8], p[9], p[10], p[11]) != (0.0, 0.0, 1.0, 0.0) {
                return Err(bad(format!(
                    "P's third row is [{}, {}, {}, {}]; a rectified camera's must be [0, 0, 1, 0] (ROS assumes Tz = 0)",
                    p[8], p[9], p[10], p[11]
                )));
            }
            let rotation = if info.r.iter().all(|&v| v == 0.0) {
                RigidTransform::IDENTITY
            } else {
                // CameraInfo's R is row-major.
                let r = DMat3::from_cols_array(&info.r).transpose();
                RigidTransform::from_matrix_translation("camera_info R", r, DVec3::ZERO)
                    .map_err(|e| bad(format!("camera_info R: {e}")))?
            };
            let translation = if p[0] > 0.0 && p[5] > 0.0 {
                DVec3::new(p[3] / p[0], p[7] / p[5], 0.0)
            } else {
                DVec3::ZERO // refused below (focal lengths)
            };
            if !translation.is_finite() {
                return Err(bad(format!(
                    "P's translation (Tx / fx', Ty / fy') = ({}, {}) is not finite",
                    translation.x, translation.y
                )));
            }
            (
                [p[0], p[5], p[2], p[6]],
                Distortion::None,
                rotation,
                translation,
            )
        }
    };
    let [fx, fy, cx, cy] = full;
    if !(fx > 0.0 && fy > 0.0) {
        return Err(bad(format!(
            "focal lengths must be positive, got fx = {fx}, fy = {fy} (from {})",
            if kind == ImageKind::Raw { "K" } else { "P" }
        )));
    }
    let roi = &info.roi;
    let (x_offset, y_offset, roi_width, roi_height) = if roi_is_set(info) {
        let inside = |offset: u32, size: u32, full: u32| {
            full == 0 || u64::from(offset) + u64::from(size) <= u64::from(full)
        };
        if roi.width == 0
            || roi.height == 0
            || !(inside(roi.x_offset, roi.width, info.width)
                && inside(roi.y_offset, roi.height, info.height))
        {
            return Err(bad(format!(
                "ROI {}x{} at ({}, {}) does not lie inside the {}x{} sensor",
                roi.width, roi.height, roi.x_offset, roi.y_offset, info.width, info.height
            )));
        }
        (
            f64::from(roi.x_offset),
            f64::from(roi.y_offset),
            roi.width,
            roi.height,
        )
    } else {
        (0.0, 0.0, info.width, info.height)
    };
    let binning_x = info.binning_x.max(1);
    let binning_y = info.binning_y.max(1);
    let (bx, by) = (f64::from(binning_x), f64::from(binning_y));
    let intrinsics = PinholeIntrinsics {
        width_px: roi_width / binning_x,
        height_px: roi_height / binning_y,
        fx_px: fx / bx,
        fy_px: fy / by,
        cx_px: (cx - x_offset) / bx,
        cy_px: (cy - y_offset) / by,
    };
    let model = CameraModel {
        intrinsics,
        distortion,
    };
    model.validate(camera)?;
    Ok(CameraCalibration {
        model,
        rect_from_frame_rotation: rotation,
        p_translation,
    })
}

impl Distortion {
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

/// The size of the image a CameraInfo describes (REP 104, image_geometry's
/// `reducedResolution`): its ROI when one is set (an ROI of all zeros means the full `width` x
/// `height`), divided by the binning (0 counts as 1), rounded down.
pub fn camera_info_image_size(info: &CameraInfo) -> (u32, u32) {
    let roi = &info.roi;
    let (w, h) = if roi_is_set(info) {
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
    if roi_is_set(info) {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::RegionOfInterest;
    use glam::{DQuat, DVec2};

    fn info() -> CameraInfo {
        CameraInfo {
            width: 640,
            height: 480,
            distortion_model: "plumb_bob".into(),
            d: vec![0.0; 5],
            k: [500.0, 0.0, 320.0, 0.0, 510.0, 240.0, 0.0, 0.0, 1.0],
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: [
                490.0, 0.0, 321.0, 0.0, 0.0, 495.0, 241.0, 0.0, 0.0, 0.0, 1.0, 0.0,
            ],
            ..Default::default()
        }
    }

    fn raw(i: &CameraInfo) -> Result<CameraModel, GeometryError> {
        camera_from_info("c", i, ImageKind::Raw).map(|c| c.model)
    }

    fn rect(i: &CameraInfo) -> Result<CameraCalibration, GeometryError> {
        camera_from_info("c", i, ImageKind::Rectified)
    }

    #[test]
    fn the_declared_kind_decides_k_and_d_or_p() {
        // D = 0 does not make an image rectified: raw is K, whatever D is.
        let m = raw(&info()).unwrap();
        assert_eq!((m.intrinsics.fx_px, m.intrinsics.cy_px), (500.0, 240.0));
        assert!(m.distortion.is_none());
        let mut distorted = info();
        distorted.d = vec![-0.1, 0.01, 0.0, 0.0, 0.0];
        let m = raw(&distorted).unwrap();
        assert_eq!(m.intrinsics.fx_px, 500.0);
        assert!(matches!(m.distortion, Distortion::PlumbBob { .. }));
        // Rectified is P, never D (the image is already undistorted), whatever D says.
        let c = rect(&distorted).unwrap();
        assert_eq!(
            (c.model.intrinsics.fx_px, c.model.intrinsics.cy_px),
            (490.0, 241.0)
        );
        assert!(c.model.distortion.is_none());
        assert_eq!(c.cam_from_frame(true), RigidTransform::IDENTITY);
        // A rectified image does not need a distortion model we know.
        let mut unknown = distorted.clone();
        unknown.distortion_model = "kannala_brandt_9".into();
        assert!(rect(&unknown).is_ok());
        assert!(raw(&unknown).is_err());
    }

    #[test]
    fn rectified_cameras_carry_r_and_ps_translation() {
        // The right camera of a stereo pair: R about y, Tx = -fx' B with B = 0.12 m.
        let angle = 0.05f64;
        let (s, c) = angle.sin_cos();
        let mut i = info();
        i.r = [c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c];
        i.p[3] = -490.0 * 0.12;
        let cal = rect(&i).unwrap();
        let r = DQuat::from_rotation_y(angle);
        assert!(cal.rect_from_frame_rotation.rotation.angle_between(r) < 1e-12);
        assert!((cal.p_translation - DVec3::new(-0.12, 0.0, 0.0)).length() < 1e-15);
        // In a shared frame (the frame P applies to), a point of the frame lands in the
        // rectified right camera at R p + (Tx / fx', 0, 0): P's own projection.
        let point_in_frame = DVec3::new(0.3, -0.2, 2.5);
        let in_cam = cal.cam_from_frame(true).transform_point(point_in_frame);
        let pixel = cal.model.project(in_cam).unwrap();
        let rotated = r * point_in_frame;
        let p = &i.p;
        let u = (p[0] * rotated.x + p[2] * rotated.z + p[3]) / rotated.z;
        let v = (p[5] * rotated.y + p[6] * rotated.z + p[7]) / rotated.z;
        assert!(
            (pixel - DVec2::new(u, v)).length() < 1e-9,
            "{pixel} vs ({u}, {v})"
        );
        // In a frame of its own, tf already says where the camera is: R only.
        let own = cal.cam_from_frame(false);
        assert_eq!(own.translation, DVec3::ZERO);
        // A raw image: no rotation, no translation, whatever R and P say.
        let raw_cal = camera_from_info("c", &i, ImageKind::Raw).unwrap();
        assert_eq!(raw_cal.cam_from_frame(true), RigidTransform::IDENTITY);
        // R all zero (not given) is the identity.
        i.r = [0.0; 9];
        assert_eq!(
            rect(&i).unwrap().rect_from_frame_rotation,
            RigidTransform::IDENTITY
        );
    }

    #[test]
    fn rectified_cameras_refuse_a_bad_r_or_p() {
        let mut i = info();
        i.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0]; // a reflection
        let e = rect(&i).unwrap_err().to_string();
        assert!(e.contains("camera_info R") && e.contains("det"), "{e}");
        let mut i = info();
        i.p[11] = 0.5;
        let e = rect(&i).unwrap_err().to_string();
        assert!(e.contains("Tz = 0"), "{e}");
        let mut i = info();
        i.p = [0.0; 12];
        let e = rect(&i).unwrap_err().to_string();
        assert!(e.contains("P is all zero"), "{e}");
        assert!(raw(&i).is_ok(), "raw needs only K");
        let mut i = info();
        i.k = [0.0; 9];
        let e = raw(&i).unwrap_err().to_string();
        assert!(e.contains("K is all zero"), "{e}");
        assert!(rect(&i).is_ok(), "rect needs only P");
    }

    /// image_geometry's `fromCameraInfo`: ROI offset first (full-resolution pixels), then
    /// `fx / b`, `cx / b` and `Tx / b`.
    #[test]
    fn roi_and_binning_as_image_geometry() {
        let mut i = info();
        i.binning_x = 2;
        i.binning_y = 4;
        i.roi = RegionOfInterest {
            x_offset: 100,
            y_offset: 40,
            width: 400,
            height: 300,
            do_rectify: true,
        };
        i.p[3] = -49.0;
        let m = raw(&i).unwrap();
        assert_eq!((m.intrinsics.width_px, m.intrinsics.height_px), (200, 75));
        assert_eq!(m.intrinsics.fx_px, 250.0);
        assert_eq!(m.intrinsics.fy_px, 127.5);
        assert_eq!(m.intrinsics.cx_px, (320.0 - 100.0) / 2.0);
        assert_eq!(m.intrinsics.cy_px, (240.0 - 40.0) / 4.0);
        let c = rect(&i).unwrap();
        assert_eq!(c.model.intrinsics.fx_px, 245.0);
        assert_eq!(c.model.intrinsics.cx_px, (321.0 - 100.0) / 2.0);
        assert_eq!(c.model.intrinsics.cy_px, (241.0 - 40.0) / 4.0);
        // Tx / fx' does not change with binning.
        assert_eq!(c.p_translation, DVec3::new(-0.1, 0.0, 0.0));
        // A full-resolution pixel (u, v) of the ROI is the binned pixel ((u - x0) / b, ..).
        let full = raw(&info()).unwrap();
        let point = full.unproject_z1(DVec2::new(331.0, 241.0)).unwrap() * 2.0;
        let px = m.project(point).unwrap();
        assert!((px.x - (331.0 - 100.0) / 2.0).abs() < 1e-9, "{px}");
        assert!((px.y - (241.0 - 40.0) / 4.0).abs() < 1e-9, "{px}");
    }

    #[test]
    fn camera_info_rejects_bad_input() {
        let mut i = info();
        i.k = [0.0; 9];
        i.p = [0.0; 12];
        assert!(raw(&i).is_err());
        let mut i = info();
        i.distortion_model = "weird".into();
        i.d = vec![0.1];
        assert!(matches!(
            raw(&i),
            Err(GeometryError::UnsupportedDistortion { .. })
        ));
        let mut i = info();
        i.d = vec![0.1, 0.2];
        assert!(matches!(
            raw(&i),
            Err(GeometryError::DistortionCoefficients { .. })
        ));
    }

    #[test]
    fn camera_info_rejects_non_finite_entries_anywhere_in_k_r_p_d() {
        let invalid = |i: &CameraInfo, kind| match camera_from_info("cam7", i, kind) {
            Err(GeometryError::InvalidIntrinsics { camera, reason }) => {
                assert_eq!(camera, "cam7");
                reason
            }
            other => panic!("expected InvalidIntrinsics, got {other:?}"),
        };
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            for kind in [ImageKind::Raw, ImageKind::Rectified] {
                // K[0] is unused by a rectified image, P[3] by a raw one: still refused.
                let mut i = info();
                i.k[0] = bad;
                assert!(invalid(&i, kind).contains("K[0]"));
                let mut i = info();
                i.p[3] = bad;
                assert!(invalid(&i, kind).contains("P[3]"));
                let mut i = info();
                i.r[4] = bad;
                assert!(invalid(&i, kind).contains("R[4]"));
                let mut i = info();
                i.d = vec![0.0, bad, 0.0, 0.0, 0.0];
                assert!(invalid(&i, kind).contains("D[1]"));
            }
        }
    }

    #[test]
    fn camera_info_rejects_uncalibrated_and_non_positive_focal_lengths() {
        let mut i = info();
        i.k = [0.0; 9];
        i.p = [0.0; 12];
        for kind in [ImageKind::Raw, ImageKind::Rectified] {
            let e = camera_from_info("cam8", &i, kind).unwrap_err();
            assert!(
                e.to_string().contains("cam8") && e.to_string().contains("uncalibrated"),
                "{e}"
            );
        }
        let mut i = info();
        i.p[0] = -490.0;
        let e = rect(&i).unwrap_err();
        assert!(e.to_string().contains("positive"), "{e}");
        let mut i = info();
        i.k[4] = 0.0;
        let e = raw(&i).unwrap_err();
        assert!(e.to_string().contains("positive"), "{e}");
    }

    #[test]
    fn camera_info_rejects_unknown_models_and_extra_coefficients() {
        let mut i = info();
        i.distortion_model = "kannala_brandt_9".into();
        i.d = vec![0.1; 9];
        assert_eq!(
            raw(&i),
            Err(GeometryError::UnsupportedDistortion {
                camera: "c".into(),
                model: "kannala_brandt_9".into()
            })
        );
        let mut i = info();
        i.d = vec![0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.3];
        assert!(matches!(
            raw(&i),
            Err(GeometryError::UnsupportedDistortion { .. })
        ));
        // Trailing zeros are fine (rational_polynomial's k4..k6 = 0 is plumb_bob).
        i.d[7] = 0.0;
        assert!(raw(&i).is_ok());
        let mut i = info();
        i.distortion_model = "equidistant".into();
        i.d = vec![0.1, 0.0, 0.0, 0.0, 0.2];
        assert!(matches!(
            raw(&i),
            Err(GeometryError::UnsupportedDistortion { .. })
        ));
    }

    #[test]
    fn camera_info_rejects_a_distortion_that_folds_inside_the_image() {
        let mut i = info();
        i.d = vec![-0.3, 0.0, 0.0, 0.0, 0.0]; // folds at distorted radius 0.703; corners: 0.8
        let e = raw(&i).unwrap_err();
        assert!(matches!(e, GeometryError::DistortionFolds { .. }), "{e}");
        // The rectified image of the same camera is fine (D does not apply to it).
        assert!(rect(&i).is_ok());
    }

    #[test]
    fn camera_info_rejects_roi_outside_the_sensor_or_partly_zero() {
        let mut i = info();
        i.roi = RegionOfInterest {
            x_offset: 600,
            y_offset: 0,
            width: 100,
            height: 100,
            do_rectify: false,
        };
        let e = raw(&i).unwrap_err();
        assert!(e.to_string().contains("ROI 100x100 at (600, 0)"), "{e}");
        i.roi.x_offset = u32::MAX; // no overflow
        assert!(raw(&i).is_err());
        i.roi.x_offset = 540;
        assert!(raw(&i).is_ok());
        // A binning larger than the ROI leaves no pixels.
        i.binning_x = 200;
        assert!(raw(&i).is_err());
        // An offset without a size is not "no ROI" (only all zeros is).
        let mut i = info();
        i.roi.x_offset = 10;
        let e = raw(&i).unwrap_err();
        assert!(e.to_string().contains("ROI 0x0 at (10, 0)"), "{e}");
    }

    #[test]
    fn image_kind_from_topic_names() {
        use ImageKind::{Raw, Rectified};
        for (topic, kind) in [
            ("/rig/cam0/image_raw", Some(Raw)),
            ("image", Some(Raw)),
            ("/cams/left/image_color", Some(Raw)),
            ("/cams/left/image_mono", Some(Raw)),
            ("/left/image_rect", Some(Rectified)),
            ("/left/image_rect_color", Some(Rectified)),
            ("/camera/infra1/image_rect_raw", Some(Rectified)),
            ("/left/image_rectified", None),
            ("/left/frames", None),
            ("/left/image_raw/compressed", None),
        ] {
            assert_eq!(ImageKind::from_topic(topic), kind, "{topic}");
        }
        assert_eq!(ImageKind::parse("raw"), Some(Raw));
        assert_eq!(ImageKind::parse("rect"), Some(Rectified));
        assert_eq!(ImageKind::parse("rectified"), None);
        assert_eq!(Rectified.as_str(), "rect");
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
        let m = raw(&roi).unwrap();
        assert_eq!((m.intrinsics.width_px, m.intrinsics.height_px), (200, 100));
        let e = check_image_size("c", &roi, 401, 300).unwrap_err();
        assert!(
            e.to_string()
                .contains("ROI 401x300 at (101, 40), binning 2x3"),
            "{e}"
        );
    }
}
