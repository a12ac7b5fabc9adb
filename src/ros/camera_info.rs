//! `sensor_msgs/CameraInfo` -> camera model, and the image-size rule (REP 104), beside the
//! ROS code that receives it. The geometry itself ([`crate::geometry`]) knows no messages.

use crate::geometry::{CameraModel, Distortion, GeometryError, PinholeIntrinsics};
use crate::msgs::CameraInfo;

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

impl CameraModel {
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
        let model = Self {
            intrinsics,
            distortion,
        };
        model.validate(camera)?;
        Ok(model)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::RegionOfInterest;
    use glam::DVec2;

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
        let point = full.unproject_z1(DVec2::new(331.0, 241.0)).unwrap() * 2.0;
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
}
