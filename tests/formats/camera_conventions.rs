//! The camera model against OpenCV and image_geometry's rules, on fixtures
//! `tools/gen_camera_fixtures.py` made (`tests/fixtures/camera/`): projection as
//! `cv2.projectPoints` / `cv2.fisheye.projectPoints`, unprojection as their undistortion where
//! OpenCV converges (and exact where it does not), raw -> rectified pixels as
//! `cv::undistortPoints(raw, K, D, R, P)` (the call image_geometry's `rectifyPoint` makes) run
//! by OpenCV itself to full convergence (100 iterations, eps 1e-14): not the value
//! `rectifyPoint` returns, which stops at OpenCV's default 5 iterations in float32, and ROI +
//! binning as `fromCameraInfo` does it: those fixtures come from our line-for-line Python
//! transcription of image_geometry's C++ (`image_geometry_from_camera_info`), not from
//! image_geometry itself, which has no PyPI wheel to run here. The issue asks for 1e-3 px;
//! every comparison here holds to 1e-6 px.

use crate::common::python;

use std::path::PathBuf;
use std::process::Command;

use glam::{DVec2, DVec3};
use serde_json::Value;
use sweepdepth::msgs::{CameraInfo, RegionOfInterest};
use sweepdepth::ros::camera_info::{camera_from_info, camera_info_image_size, ImageKind};

/// Pixels; the issue's bar is 1e-3.
const TOLERANCE_PX: f64 = 1e-6;

fn fixture(name: &str) -> Value {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/camera")
        .join(name);
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("{}: {e} (run tools/gen_camera_fixtures.py)", path.display()));
    serde_json::from_str(&text).expect("fixture is JSON")
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

fn floats(v: &Value) -> Vec<f64> {
    v.as_array().expect("an array").iter().map(f).collect()
}

fn vec2(v: &Value) -> DVec2 {
    let a = floats(v);
    DVec2::new(a[0], a[1])
}

/// A CameraInfo from the fixture's K (3x3 row-major or fx, fy, cx, cy) and D.
fn info(width: u32, height: u32, k: [f64; 9], model: &str, d: Vec<f64>) -> CameraInfo {
    CameraInfo {
        width,
        height,
        distortion_model: model.into(),
        d,
        k,
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [
            k[0], 0.0, k[2], 0.0, 0.0, k[4], k[5], 0.0, 0.0, 0.0, 1.0, 0.0,
        ],
        ..CameraInfo::default()
    }
}

#[test]
fn projection_and_unprojection_match_opencv() {
    let fixture = fixture("opencv.json");
    let mut report = Vec::new();
    for camera in fixture["cameras"].as_array().unwrap() {
        let name = camera["name"].as_str().unwrap();
        let (fx, fy, cx, cy) = (
            f(&camera["fx"]),
            f(&camera["fy"]),
            f(&camera["cx"]),
            f(&camera["cy"]),
        );
        let k = [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0];
        let width = camera["width"].as_u64().unwrap() as u32;
        let height = camera["height"].as_u64().unwrap() as u32;
        let ros = info(
            width,
            height,
            k,
            camera["model"].as_str().unwrap(),
            floats(&camera["d"]),
        );
        let model = camera_from_info(name, &ros, ImageKind::Raw)
            .unwrap_or_else(|e| panic!("{name}: {e}"))
            .model;
        let samples = camera["samples"].as_array().unwrap();
        assert!(samples.len() > 20, "{name}: {} samples", samples.len());
        let (mut project_err, mut unproject_err, mut opencv_err) = (0.0f64, 0.0f64, 0.0f64);
        let mut opencv_misses = 0;
        for s in samples {
            let p = floats(&s["point"]);
            let point = DVec3::new(p[0], p[1], p[2]);
            let pixel = vec2(&s["pixel"]);
            // Projection: OpenCV's pixel.
            let projected = model
                .project(point)
                .unwrap_or_else(|| panic!("{name}: {point} does not project"));
            project_err = project_err.max((projected - pixel).length());
            // Unprojection: the true ray, in pixels at the focal length.
            let ray = model
                .unproject_z1(pixel)
                .unwrap_or_else(|| panic!("{name}: pixel {pixel} has no ray"));
            let truth = DVec2::new(point.x / point.z, point.y / point.z);
            let to_px = |d: DVec2| DVec2::new(d.x * fx, d.y * fy).length();
            unproject_err = unproject_err.max(to_px(ray.truncate() - truth));
            // OpenCV's own undistortion, where it converged.
            if s["opencv_recovers"].as_bool().unwrap() {
                let opencv = vec2(&s["opencv_undistorted"]);
                opencv_err = opencv_err.max(to_px(ray.truncate() - opencv));
            } else {
                opencv_misses += 1;
            }
        }
        report.push(format!(
            "{name}: project {project_err:.1e} px, unproject {unproject_err:.1e} px, vs OpenCV's undistortion {opencv_err:.1e} px ({opencv_misses} rays it misses)"
        ));
        assert!(project_err < TOLERANCE_PX, "{}", report.join("\n"));
        assert!(unproject_err < TOLERANCE_PX, "{}", report.join("\n"));
        assert!(opencv_err < TOLERANCE_PX, "{}", report.join("\n"));
    }
    eprintln!("{}", report.join("\n"));
}

#[test]
fn rectified_pixels_match_image_geometry_rectify_point() {
    let fixture = fixture("opencv.json");
    for camera in fixture["rectify"].as_array().unwrap() {
        let name = camera["name"].as_str().unwrap();
        let array = |key: &str| floats(&camera[key]);
        let mut ros = info(
            camera["width"].as_u64().unwrap() as u32,
            camera["height"].as_u64().unwrap() as u32,
            array("k").try_into().unwrap(),
            "plumb_bob",
            array("d"),
        );
        ros.r = array("r").try_into().unwrap();
        ros.p = array("p").try_into().unwrap();
        // The raw image's camera (K, D) and the rectified image's (P, R), from one CameraInfo.
        let raw = camera_from_info(name, &ros, ImageKind::Raw).unwrap();
        let rect = camera_from_info(name, &ros, ImageKind::Rectified).unwrap();
        // A raw pixel's ray, in the camera's frame, seen by the rectified camera: the pixel
        // rectifyPoint gives. (Rays: P's translation does not move directions.)
        let rect_from_frame = rect.cam_from_frame(false);
        let mut worst = 0.0f64;
        for point in camera["points"].as_array().unwrap() {
            let raw_px = vec2(&point["raw"]);
            let ray = raw.model.unproject_z1(raw_px).unwrap();
            let got = rect
                .model
                .project(rect_from_frame.transform_vector(ray))
                .unwrap();
            worst = worst.max((got - vec2(&point["rect"])).length());
        }
        assert!(
            worst < TOLERANCE_PX,
            "{name}: {worst:e} px off rectifyPoint"
        );
    }
}

#[test]
fn roi_and_binning_match_image_geometry_from_camera_info() {
    let fixture = fixture("image_geometry.json");
    assert!(fixture["source"]
        .as_str()
        .unwrap()
        .contains("fromCameraInfo"));
    let cases = fixture["cases"].as_array().unwrap();
    assert!(cases.len() >= 8);
    for case in cases {
        let name = case["name"].as_str().unwrap();
        let u = |key: &str| case[key].as_u64().unwrap() as u32;
        let roi: Vec<u32> = case["roi"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap() as u32)
            .collect();
        let mut ros = info(
            u("width"),
            u("height"),
            floats(&case["k"]).try_into().unwrap(),
            "plumb_bob",
            vec![0.0; 5],
        );
        ros.p = floats(&case["p"]).try_into().unwrap();
        ros.binning_x = u("binning_x");
        ros.binning_y = u("binning_y");
        ros.roi = RegionOfInterest {
            x_offset: roi[0],
            y_offset: roi[1],
            width: roi[2],
            height: roi[3],
            do_rectify: false,
        };
        let k = floats(&case["expected_k"]);
        let p = floats(&case["expected_p"]);
        let size = floats(&case["expected_size"]);
        let expected_size = (size[0] as u32, size[1] as u32);
        assert_eq!(camera_info_image_size(&ros), expected_size, "{name}");
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * b.abs().max(1.0);
        let raw = camera_from_info(name, &ros, ImageKind::Raw)
            .unwrap()
            .model
            .intrinsics;
        assert_eq!((raw.width_px, raw.height_px), expected_size, "{name}");
        for (got, want, what) in [
            (raw.fx_px, k[0], "K fx"),
            (raw.fy_px, k[4], "K fy"),
            (raw.cx_px, k[2], "K cx"),
            (raw.cy_px, k[5], "K cy"),
        ] {
            assert!(
                close(got, want),
                "{name}: {what} {got} vs image_geometry {want}"
            );
        }
        let rect = camera_from_info(name, &ros, ImageKind::Rectified).unwrap();
        let r = rect.model.intrinsics;
        for (got, want, what) in [
            (r.fx_px, p[0], "P fx"),
            (r.fy_px, p[5], "P fy"),
            (r.cx_px, p[2], "P cx"),
            (r.cy_px, p[6], "P cy"),
            (rect.p_translation.x, p[3] / p[0], "P Tx / fx"),
            (rect.p_translation.y, p[7] / p[5], "P Ty / fy"),
        ] {
            assert!(
                close(got, want),
                "{name}: {what} {got} vs image_geometry {want}"
            );
        }
    }
}

/// The fixtures are what OpenCV gives: the generator, run again, reproduces them.
#[test]
fn fixtures_are_reproduced_by_opencv() {
    let py = python::python();
    let out = Command::new(&py)
        .arg(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tools/gen_camera_fixtures.py"
        ))
        .arg("--check")
        .output()
        .unwrap_or_else(|e| panic!("cannot start {py} ({e}); {}", python::INSTALL_HINT));
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "tools/gen_camera_fixtures.py --check failed ({}; OpenCV is opencv-python-headless in tools/requirements-test.txt: {}):\n{stdout}\n{stderr}",
        out.status,
        python::INSTALL_HINT
    );
    assert_eq!(stdout.matches("reproduced").count(), 2, "{stdout}");
}
