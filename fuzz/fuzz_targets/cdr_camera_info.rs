//! Arbitrary bytes as a CDR `sensor_msgs/CameraInfo`; whatever decodes goes through
//! `camera_from_info` (as a raw and as a rectified image) and the image-size check. An
//! accepted camera must be finite with positive focal lengths, a non-empty image and a rigid
//! pose correction, and projecting through it must not panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sweepdepth::msgs::{from_cdr, CameraInfo};
use sweepdepth::ros::camera_info::{
    camera_from_info, camera_info_image_size, check_image_size, ImageKind,
};

fuzz_target!(|data: &[u8]| {
    let Ok(info) = from_cdr::<CameraInfo>(data) else {
        return;
    };
    let (width, height) = camera_info_image_size(&info);
    let _ = check_image_size("fuzz", &info, width, height);
    let _ = check_image_size("fuzz", &info, info.width, info.height);
    for kind in [ImageKind::Raw, ImageKind::Rectified] {
        let Ok(calibration) = camera_from_info("fuzz", &info, kind) else {
            continue;
        };
        let model = calibration.model;
        let k = model.intrinsics;
        assert!(k.fx_px > 0.0 && k.fy_px > 0.0 && k.fx_px.is_finite() && k.fy_px.is_finite());
        assert!(k.cx_px.is_finite() && k.cy_px.is_finite());
        assert!(k.width_px > 0 && k.height_px > 0);
        assert_eq!((k.width_px, k.height_px), (width, height));
        assert!(check_image_size("fuzz", &info, width, height).is_ok());
        for shared in [false, true] {
            let pose = calibration.cam_from_frame(shared);
            assert!(pose.rotation.is_finite() && pose.translation.is_finite());
            assert!((pose.rotation.length() - 1.0).abs() < 1e-9);
        }
        let centre = glam::DVec2::new(f64::from(width) / 2.0, f64::from(height) / 2.0);
        if let Some(ray) = model.unproject_z1(centre) {
            let _ = model.project(ray);
        }
        let _ = model.contains(centre);
    }
});
