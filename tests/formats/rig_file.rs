//! Rig files: the sweepdepth format and Kalibr camchain.yaml.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use glam::{DMat3, DQuat, DVec2, DVec3};
use sweepdepth::geometry::{CameraModel, Distortion, RigidTransform};
use sweepdepth::rig_file::*;

/// A YAML file under the temp dir with a unique name; removed on drop.
struct TempYaml(PathBuf);

impl TempYaml {
    fn new(text: &str) -> Self {
        static COUNTER: AtomicUsize = AtomicUsize::new(0);
        let n = COUNTER.fetch_add(1, Ordering::SeqCst);
        let path = std::env::temp_dir().join(format!(
            "sweepdepth_rig_file_{}_{n}_{:?}.yaml",
            std::process::id(),
            std::thread::current().id()
        ));
        std::fs::write(&path, text).unwrap();
        Self(path)
    }

    fn path(&self) -> &Path {
        &self.0
    }

    fn load(&self) -> Result<RigFile, RigFileError> {
        load_rig_file(&self.0)
    }
}

impl Drop for TempYaml {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

fn load_ok(text: &str) -> RigFile {
    let file = TempYaml::new(text);
    match file.load() {
        Ok(rig) => rig,
        Err(e) => panic!("{e}\n--- file ---\n{text}"),
    }
}

/// Loads `text`, expects an error, and checks that its message names the file and `camera`
/// and contains `needle`.
fn load_err(text: &str, camera: Option<&str>, needle: &str) -> RigFileError {
    let file = TempYaml::new(text);
    let err = file.load().expect_err("expected an error");
    let message = err.to_string();
    let path = file.path().display().to_string();
    assert!(message.contains(&path), "no file in: {message}");
    if let Some(camera) = camera {
        assert!(
            message.contains(&format!("camera '{camera}'")),
            "no camera '{camera}' in: {message}"
        );
        assert!(
            matches!(&err, RigFileError::Camera { camera: c, .. } if c == camera),
            "{err:?}"
        );
    }
    assert!(message.contains(needle), "no '{needle}' in: {message}");
    err
}

fn close(a: DVec3, b: DVec3, tol: f64) -> bool {
    (a - b).length() < tol
}

fn assert_same_transform(a: &RigidTransform, b: &RigidTransform, tol: f64) {
    for p in [
        DVec3::ZERO,
        DVec3::X,
        DVec3::Y,
        DVec3::Z,
        DVec3::new(0.3, -1.2, 4.0),
    ] {
        let (pa, pb) = (a.transform_point(p), b.transform_point(p));
        assert!(close(pa, pb, tol), "{p:?}: {pa:?} vs {pb:?}");
    }
}

const ONE_CAMERA_HEAD: &str = "cameras:\n  - name: cam0\n";

fn one_camera(body: &str) -> String {
    format!("{ONE_CAMERA_HEAD}{body}")
}

// ---------------------------------------------------------------------------------------------
// The sweepdepth format.

#[test]
fn quaternion_and_matrix_give_the_same_pose() {
    // 90 degrees about z, written by hand.
    let s = std::f64::consts::FRAC_1_SQRT_2;
    let rig = load_ok(&format!(
        "rig_frame: base\ncameras:\n  - name: q\n    translation: [1.0, 2.0, 3.0]\n    rotation: [0.0, 0.0, {s}, {s}]\n  - name: m\n    translation: [1.0, 2.0, 3.0]\n    rotation_matrix: [[0, -1, 0], [1, 0, 0], [0, 0, 1]]\n  - name: flat\n    translation: [1.0, 2.0, 3.0]\n    rotation_matrix: [0, -1, 0, 1, 0, 0, 0, 0, 1]\n"
    ));
    assert_eq!(rig.rig_frame, "base");
    assert_eq!(rig.format, RigFileFormat::Sweepdepth);
    assert_eq!(rig.cameras.len(), 3);
    assert_same_transform(
        &rig.cameras[0].cam_from_rig,
        &rig.cameras[1].cam_from_rig,
        1e-12,
    );
    assert_same_transform(
        &rig.cameras[0].cam_from_rig,
        &rig.cameras[2].cam_from_rig,
        1e-12,
    );

    // A general rotation: the matrix written from the quaternion, row-major, full precision.
    let q = DQuat::from_euler(glam::EulerRot::ZYX, 0.7, -0.4, 1.9);
    let m = DMat3::from_quat(q);
    let row = |i: usize| format!("[{:?}, {:?}, {:?}]", m.row(i).x, m.row(i).y, m.row(i).z);
    let rig = load_ok(&format!(
        "cameras:\n  - name: q\n    translation: [-0.2, 0.05, 0.7]\n    rotation: [{:?}, {:?}, {:?}, {:?}]\n  - name: m\n    translation: [-0.2, 0.05, 0.7]\n    rotation_matrix: [{}, {}, {}]\n",
        q.x,
        q.y,
        q.z,
        q.w,
        row(0),
        row(1),
        row(2)
    ));
    assert_same_transform(
        &rig.cameras[0].cam_from_rig,
        &rig.cameras[1].cam_from_rig,
        1e-12,
    );
    // rig_from_cam is what the file holds; cam_from_rig is its inverse.
    let rig_from_cam = rig.cameras[0].cam_from_rig.inverse();
    assert!(close(
        rig_from_cam.translation,
        DVec3::new(-0.2, 0.05, 0.7),
        1e-12
    ));
    assert!(close(rig_from_cam.rotation * DVec3::Z, q * DVec3::Z, 1e-12));
}

#[test]
fn a_rig_point_lands_where_hand_computation_says() {
    // cam_a: at (1, 2, 3), rotated +90 degrees about the rig's z axis (rig_from_cam = Rz(90)).
    //   p_cam = Rz(-90) * (p_rig - t); Rz(-90) maps (x, y, z) to (y, -x, z).
    //   p_rig = (1, 3, 8): p_rig - t = (0, 1, 5) -> p_cam = (1, 0, 5).
    // cam_b: at (0.12, 0, 0), no rotation: p_cam = p_rig - t = (0.88, 3, 8).
    // cam_c: looking along the rig's +x (rotation +90 degrees about y: cam z -> rig x,
    //   cam x -> rig -z, cam y -> rig y), at the origin: p_cam = R^T p_rig with
    //   R = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]] -> p_cam = (-8, 3, 1).
    let rig = load_ok(
        "cameras:
  - name: cam_a
    translation: [1, 2, 3]
    rotation: [0.0, 0.0, 0.7071067811865476, 0.7071067811865476]
    intrinsics: {width: 640, height: 480, fx: 500, fy: 400, cx: 319.5, cy: 239.5}
  - name: cam_b
    translation: [0.12, 0.0, 0.0]
    rotation: [0, 0, 0, 1]
  - name: cam_c
    translation: [0, 0, 0]
    rotation_matrix: [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]
",
    );
    let p_rig = DVec3::new(1.0, 3.0, 8.0);
    let expected = [
        DVec3::new(1.0, 0.0, 5.0),
        DVec3::new(0.88, 3.0, 8.0),
        DVec3::new(-8.0, 3.0, 1.0),
    ];
    for (camera, want) in rig.cameras.iter().zip(expected) {
        let got = camera.cam_from_rig.transform_point(p_rig);
        assert!(
            close(got, want, 1e-12),
            "{}: {got:?} vs {want:?}",
            camera.name
        );
    }
    // And the pixel in cam_a: u = 500 * 1/5 + 319.5, v = 400 * 0/5 + 239.5.
    let model = rig.cameras[0].model.unwrap();
    let px = model
        .project(rig.cameras[0].cam_from_rig.transform_point(p_rig))
        .unwrap();
    assert!((px - DVec2::new(419.5, 239.5)).length() < 1e-9, "{px:?}");
    assert!(close(
        rig.cameras[1].centre_in_rig(),
        DVec3::new(0.12, 0.0, 0.0),
        1e-15
    ));
    // RigCamera from the file camera keeps the pose.
    let rc = rig.cameras[1].rig_camera(model);
    assert_eq!(rc.cam_from_rig, rig.cameras[1].cam_from_rig);
    assert_eq!(rc.name, "cam_b");
}

#[test]
fn intrinsics_and_distortion_are_parsed() {
    let rig = load_ok(
        "cameras:
  - name: pb
    translation: [0, 0, 0]
    rotation: [0, 0, 0, 1]
    intrinsics: {width: 640, height: 480, fx: 500.0, fy: 501.0, cx: 319.5, cy: 239.0}
    distortion: {model: plumb_bob, coefficients: [-0.28, 0.07, 0.001, -0.002, 0.01]}
  - name: fish
    translation: [0.1, 0, 0]
    rotation: [0, 0, 0, 1]
    intrinsics: {width: 1280, height: 800, fx: 300, fy: 300, cx: 640, cy: 400}
    distortion: {model: equidistant, coefficients: [0.01, -0.005, 0.001, 0.0002]}
  - name: plain
    translation: [0.2, 0, 0]
    rotation: [0, 0, 0, 1]
    intrinsics: {width: 320, height: 240, fx: 250, fy: 250, cx: 159.5, cy: 119.5}
  - name: zeros
    translation: [0.3, 0, 0]
    rotation: [0, 0, 0, 1]
    intrinsics: {width: 320, height: 240, fx: 250, fy: 250, cx: 159.5, cy: 119.5}
    distortion: {model: plumb_bob, coefficients: [0, 0, 0, 0, 0]}
  - name: none
    translation: [0.4, 0, 0]
    rotation: [0, 0, 0, 1]
    intrinsics: {width: 320, height: 240, fx: 250, fy: 250, cx: 159.5, cy: 119.5}
    distortion: {model: none}
  - name: pose_only
    translation: [0.5, 0, 0]
    rotation: [0, 0, 0, 1]
",
    );
    let pb = rig.camera("pb").unwrap().model.unwrap();
    assert_eq!(
        (pb.intrinsics.width_px, pb.intrinsics.height_px),
        (640, 480)
    );
    assert_eq!(
        (
            pb.intrinsics.fx_px,
            pb.intrinsics.fy_px,
            pb.intrinsics.cx_px,
            pb.intrinsics.cy_px
        ),
        (500.0, 501.0, 319.5, 239.0)
    );
    assert_eq!(
        pb.distortion,
        Distortion::PlumbBob {
            k1: -0.28,
            k2: 0.07,
            p1: 0.001,
            p2: -0.002,
            k3: 0.01
        }
    );
    assert_eq!(
        rig.camera("fish").unwrap().model.unwrap().distortion,
        Distortion::Equidistant {
            k1: 0.01,
            k2: -0.005,
            k3: 0.001,
            k4: 0.0002
        }
    );
    for name in ["plain", "zeros", "none"] {
        let m: CameraModel = rig.camera(name).unwrap().model.unwrap();
        assert_eq!(m.distortion, Distortion::None, "{name}");
        assert_eq!(m.intrinsics.fx_px, 250.0);
    }
    assert_eq!(rig.camera("pose_only").unwrap().model, None);
    assert_eq!(rig.camera("pose_only").unwrap().rostopic, None);
    assert!(rig.notes.is_empty());
    assert_eq!(rig.camera_for("/none").unwrap().name, "none");
}

#[test]
fn sweepdepth_errors_name_the_file_and_camera() {
    load_err(
        &one_camera("    translation: [0, 0, 0]\n    rotation: [0, 0, 0, 1.1]\n"),
        Some("cam0"),
        "not unit length",
    );
    load_err(
        &one_camera("    translation: [0, 0, 0]\n    rotation: [0, 0, 1]\n"),
        Some("cam0"),
        "4 numbers",
    );
    load_err(
        &one_camera(
            "    translation: [0, 0, 0]\n    rotation_matrix: [[1, 0.1, 0], [0, 1, 0], [0, 0, 1]]\n",
        ),
        Some("cam0"),
        "orthonormal",
    );
    // A reflection (det -1) is orthogonal but not a rotation.
    load_err(
        &one_camera(
            "    translation: [0, 0, 0]\n    rotation_matrix: [[-1, 0, 0], [0, 1, 0], [0, 0, 1]]\n",
        ),
        Some("cam0"),
        "det",
    );
    load_err(
        &one_camera("    translation: [0, 0, 0]\n    rotation_matrix: [[1, 0], [0, 1]]\n"),
        Some("cam0"),
        "3x3",
    );
    load_err(
        &one_camera(
            "    translation: [0, 0, 0]\n    rotation: [0, 0, 0, 1]\n    rotation_matrix: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n",
        ),
        Some("cam0"),
        "not both",
    );
    load_err(
        &one_camera("    translation: [0, 0, 0]\n"),
        Some("cam0"),
        "missing the orientation",
    );
    load_err(
        &one_camera("    translation: [0, .nan, 0]\n    rotation: [0, 0, 0, 1]\n"),
        Some("cam0"),
        "NaN or infinite",
    );
    load_err(
        &one_camera("    translation: [0, 0]\n    rotation: [0, 0, 0, 1]\n"),
        Some("cam0"),
        "3 numbers",
    );
    // Unknown field: a misspelt key, with the key in the message.
    load_err(
        &one_camera("    translation: [0, 0, 0]\n    rotaton: [0, 0, 0, 1]\n"),
        Some("cam0"),
        "rotaton",
    );
    load_err(
        &one_camera(
            "    translation: [0, 0, 0]\n    rotation: [0, 0, 0, 1]\n    intrinsics: {width: 640, height: 480, fx: 500, fy: 500, cx: 320, cy: 240, skew: 0}\n",
        ),
        Some("cam0"),
        "skew",
    );
    // Wrong distortion coefficient counts.
    load_err(
        &one_camera(
            "    translation: [0, 0, 0]\n    rotation: [0, 0, 0, 1]\n    intrinsics: {width: 640, height: 480, fx: 500, fy: 500, cx: 320, cy: 240}\n    distortion: {model: plumb_bob, coefficients: [0.1, 0.01, 0, 0]}\n",
        ),
        Some("cam0"),
        "needs 5 coefficients, got 4",
    );
    load_err(
        &one_camera(
            "    translation: [0, 0, 0]\n    rotation: [0, 0, 0, 1]\n    intrinsics: {width: 640, height: 480, fx: 500, fy: 500, cx: 320, cy: 240}\n    distortion: {model: equidistant, coefficients: [0.1, 0.01, 0, 0, 0]}\n",
        ),
        Some("cam0"),
        "needs 4 coefficients, got 5",
    );
    load_err(
        &one_camera(
            "    translation: [0, 0, 0]\n    rotation: [0, 0, 0, 1]\n    intrinsics: {width: 640, height: 480, fx: 500, fy: 500, cx: 320, cy: 240}\n    distortion: {model: rational_polynomial, coefficients: [0, 0, 0, 0, 0, 0, 0, 0]}\n",
        ),
        Some("cam0"),
        "unknown model 'rational_polynomial'",
    );
    load_err(
        &one_camera(
            "    translation: [0, 0, 0]\n    rotation: [0, 0, 0, 1]\n    distortion: {model: none}\n",
        ),
        Some("cam0"),
        "without `intrinsics`",
    );
    load_err(
        &one_camera(
            "    translation: [0, 0, 0]\n    rotation: [0, 0, 0, 1]\n    intrinsics: {width: 640, height: 0, fx: 500, fy: 500, cx: 320, cy: 240}\n",
        ),
        Some("cam0"),
        "zero side",
    );
    load_err(
        &one_camera(
            "    translation: [0, 0, 0]\n    rotation: [0, 0, 0, 1]\n    intrinsics: {width: 640, height: 480, fx: -500, fy: 500, cx: 320, cy: 240}\n",
        ),
        Some("cam0"),
        "positive",
    );
    // Duplicate names: the second one is named.
    load_err(
        "cameras:
  - {name: left, translation: [0, 0, 0], rotation: [0, 0, 0, 1]}
  - {name: right, translation: [0.1, 0, 0], rotation: [0, 0, 0, 1]}
  - {name: left, translation: [0.2, 0, 0], rotation: [0, 0, 0, 1]}
",
        Some("left"),
        "more than one camera",
    );
    // The second camera is named even though the first is fine.
    load_err(
        "cameras:
  - {name: good, translation: [0, 0, 0], rotation: [0, 0, 0, 1]}
  - {name: bad, translation: [0.1, 0, 0], rotation: [0, 0, 0, 2]}
",
        Some("bad"),
        "not unit length",
    );
    // A camera without a name is named by its index.
    load_err(
        "cameras:
  - {name: good, translation: [0, 0, 0], rotation: [0, 0, 0, 1]}
  - {translation: [0.1, 0, 0], rotation: [0, 0, 0, 1]}
",
        Some("cameras[1]"),
        "name",
    );
    load_err(
        "cameras:\n  - {name: '', translation: [0.1, 0, 0], rotation: [0, 0, 0, 1]}\n",
        Some("cameras[0]"),
        "empty",
    );
}

#[test]
fn file_level_errors_name_the_file() {
    let err = load_err("cameras: []\n", None, "at least one camera");
    assert!(matches!(err, RigFileError::Format { .. }), "{err:?}");
    let err = load_err(
        "rig_frame: rig\nrig_name: oops\ncameras:\n  - {name: a, translation: [0, 0, 0], rotation: [0, 0, 0, 1]}\n",
        None,
        "rig_name",
    );
    assert!(matches!(err, RigFileError::Format { .. }), "{err:?}");
    // Bad YAML: the file and the line.
    let err = load_err(
        "cameras:\n  - name: cam0\n    translation: [0, 0, 0\n    rotation: [0, 0, 0, 1]\n",
        None,
        "line",
    );
    assert!(matches!(err, RigFileError::Yaml { .. }), "{err:?}");
    load_err("", None, "empty file");
    load_err("- a\n- b\n", None, "found a list");
    load_err("foo: 1\n", None, "neither a sweepdepth rig file");
    // A missing file.
    let missing = std::env::temp_dir().join(format!(
        "sweepdepth_rig_file_{}_does_not_exist.yaml",
        std::process::id()
    ));
    let err = load_rig_file(&missing).unwrap_err();
    assert!(matches!(err, RigFileError::Read { .. }));
    assert!(err.to_string().contains(&missing.display().to_string()));
}

// ---------------------------------------------------------------------------------------------
// Kalibr.

fn kalibr_camera(index: usize, t_cn_cnm1: Option<&str>, distortion: &str) -> String {
    let mut s = format!("cam{index}:\n");
    if let Some(t) = t_cn_cnm1 {
        s.push_str("  T_cn_cnm1:\n");
        s.push_str(t);
    }
    s.push_str(&format!(
        "  cam_overlaps: []\n  camera_model: pinhole\n{distortion}  intrinsics: [458.654, 457.296, 367.215, 248.375]\n  resolution: [752, 480]\n  rostopic: /cam{index}/image_raw\n"
    ));
    s
}

const RADTAN: &str = "  distortion_coeffs: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]\n  distortion_model: radtan\n";
const EQUI: &str =
    "  distortion_coeffs: [0.01, -0.005, 0.001, 0.0002]\n  distortion_model: equidistant\n";
const RIGHT_10CM: &str = "  - [1.0, 0.0, 0.0, -0.1]\n  - [0.0, 1.0, 0.0, 0.0]\n  - [0.0, 0.0, 1.0, 0.0]\n  - [0.0, 0.0, 0.0, 1.0]\n";

fn three_camera_chain() -> String {
    [
        kalibr_camera(0, None, RADTAN),
        kalibr_camera(1, Some(RIGHT_10CM), RADTAN),
        kalibr_camera(2, Some(RIGHT_10CM), EQUI),
    ]
    .concat()
}

#[test]
fn kalibr_chain_places_the_cameras_in_cam0s_frame() {
    let rig = load_ok(&three_camera_chain());
    assert_eq!(rig.format, RigFileFormat::Kalibr);
    assert_eq!(rig.rig_frame, "cam0");
    let names: Vec<_> = rig.cameras.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["cam0", "cam1", "cam2"]);
    for (camera, x) in rig.cameras.iter().zip([0.0, 0.1, 0.2]) {
        assert!(
            close(camera.centre_in_rig(), DVec3::new(x, 0.0, 0.0), 1e-12),
            "{}: {:?}",
            camera.name,
            camera.centre_in_rig()
        );
    }
    assert_eq!(
        rig.cameras[0].cam_from_rig.translation,
        RigidTransform::IDENTITY.translation
    );
    // A point 2 m in front of cam2's centre (x = 0.2 in cam0's frame) is straight ahead of cam2.
    let p = rig.cameras[2]
        .cam_from_rig
        .transform_point(DVec3::new(0.2, 0.0, 2.0));
    assert!(close(p, DVec3::new(0.0, 0.0, 2.0), 1e-12), "{p:?}");
    // Topics and matching by namespace.
    assert_eq!(rig.cameras[1].rostopic.as_deref(), Some("/cam1/image_raw"));
    assert_eq!(rig.cameras[1].topic_namespace(), Some("/cam1"));
    assert_eq!(rig.camera_for("cam1").unwrap().name, "cam1");
    assert_eq!(rig.camera_for("/cam2").unwrap().name, "cam2");
    assert!(rig.camera_for("cam3").is_none());
    assert!(rig.notes.is_empty(), "{:?}", rig.notes);
    assert!(rig.topic_notes(&["cam0".into(), "cam2".into()]).is_empty());
}

/// Kalibr numbers its keys in the order it was given the topics: with the topics given in
/// the other order, key cam0 is the camera on /cam2. The topic decides, and the node says so.
#[test]
fn kalibr_topics_decide_which_camera_a_key_is() {
    let reversed = three_camera_chain()
        .replace("/cam0/image_raw", "/camX/image_raw")
        .replace("/cam2/image_raw", "/cam0/image_raw")
        .replace("/camX/image_raw", "/cam2/image_raw");
    let rig = load_ok(&reversed);
    assert_eq!(rig.camera_for("cam0").unwrap().name, "cam2");
    assert_eq!(rig.camera_for("cam2").unwrap().name, "cam0");
    assert_eq!(rig.camera_for("cam1").unwrap().name, "cam1");
    let cameras: Vec<String> = ["cam0", "cam1", "cam2"].map(String::from).to_vec();
    let notes = rig.topic_notes(&cameras);
    assert_eq!(notes.len(), 2, "{notes:?}");
    assert!(
        notes[0].contains("camera cam0 is Kalibr's cam2 by its rostopic /cam0/image_raw"),
        "{notes:?}"
    );
}

#[test]
fn kalibr_chain_composes_in_the_right_order() {
    // cam1 is cam0 yawed (about its y axis) by 30 degrees and moved; cam2 is cam1 moved.
    // cam2_from_cam0 = T21 * T10, checked on points against nalgebra 4x4 products.
    let (s, c) = (30f64.to_radians().sin(), 30f64.to_radians().cos());
    let t10 = nalgebra::Matrix4::new(
        c, 0.0, s, -0.1, //
        0.0, 1.0, 0.0, 0.02, //
        -s, 0.0, c, 0.03, //
        0.0, 0.0, 0.0, 1.0,
    );
    let t21 = nalgebra::Matrix4::new(
        1.0, 0.0, 0.0, -0.15, //
        0.0, c, -s, 0.0, //
        0.0, s, c, 0.01, //
        0.0, 0.0, 0.0, 1.0,
    );
    let yaml = |m: &nalgebra::Matrix4<f64>| {
        (0..4)
            .map(|r| {
                format!(
                    "  - [{:?}, {:?}, {:?}, {:?}]\n",
                    m[(r, 0)],
                    m[(r, 1)],
                    m[(r, 2)],
                    m[(r, 3)]
                )
            })
            .collect::<String>()
    };
    let text = [
        kalibr_camera(0, None, RADTAN),
        kalibr_camera(1, Some(&yaml(&t10)), RADTAN),
        kalibr_camera(2, Some(&yaml(&t21)), RADTAN),
    ]
    .concat();
    let rig = load_ok(&text);
    let t20 = t21 * t10;
    for p in [
        DVec3::ZERO,
        DVec3::new(0.5, -0.3, 2.0),
        DVec3::new(-1.0, 0.2, 5.0),
    ] {
        let h = nalgebra::Vector4::new(p.x, p.y, p.z, 1.0);
        for (camera, m) in [(&rig.cameras[1], t10), (&rig.cameras[2], t20)] {
            let want = m * h;
            let got = camera.cam_from_rig.transform_point(p);
            assert!(
                close(got, DVec3::new(want[0], want[1], want[2]), 1e-12),
                "{}: {got:?} vs {want:?}",
                camera.name
            );
        }
    }
}

#[test]
fn kalibr_distortion_models_map_to_ours() {
    let none = "  distortion_coeffs: []\n  distortion_model: none\n";
    let text = [
        kalibr_camera(0, None, RADTAN),
        kalibr_camera(1, Some(RIGHT_10CM), EQUI),
        kalibr_camera(2, Some(RIGHT_10CM), none),
    ]
    .concat();
    let rig = load_ok(&text);
    let m0 = rig.cameras[0].model.unwrap();
    assert_eq!(
        m0.distortion,
        Distortion::PlumbBob {
            k1: -0.28340811,
            k2: 0.07395907,
            p1: 0.00019359,
            p2: 1.76187114e-05,
            k3: 0.0
        }
    );
    assert_eq!(
        (m0.intrinsics.width_px, m0.intrinsics.height_px),
        (752, 480)
    );
    assert_eq!(
        (
            m0.intrinsics.fx_px,
            m0.intrinsics.fy_px,
            m0.intrinsics.cx_px,
            m0.intrinsics.cy_px
        ),
        (458.654, 457.296, 367.215, 248.375)
    );
    assert_eq!(
        rig.cameras[1].model.unwrap().distortion,
        Distortion::Equidistant {
            k1: 0.01,
            k2: -0.005,
            k3: 0.001,
            k4: 0.0002
        }
    );
    assert_eq!(rig.cameras[2].model.unwrap().distortion, Distortion::None);
}

#[test]
fn kalibr_imu_extrinsics_and_extra_keys() {
    let text = format!(
        "cam0:\n  T_cam_imu:\n  - [0.0, -1.0, 0.0, 0.01]\n  - [1.0, 0.0, 0.0, 0.02]\n  - [0.0, 0.0, 1.0, 0.03]\n  - [0.0, 0.0, 0.0, 1.0]\n  timeshift_cam_imu: 0.0012\n  line_delay: 0.0\n{}",
        kalibr_camera(0, None, RADTAN)
            .strip_prefix("cam0:\n")
            .unwrap()
    );
    let rig = load_ok(&text);
    let cam_from_imu = rig.cameras[0].cam_from_imu.unwrap();
    let p = cam_from_imu.transform_point(DVec3::X);
    assert!(close(p, DVec3::new(0.01, 1.02, 0.03), 1e-12), "{p:?}");
    assert_eq!(rig.notes.len(), 1, "{:?}", rig.notes);
    assert!(rig.notes[0].contains("line_delay") && rig.notes[0].contains("cam0"));
}

#[test]
fn kalibr_errors_name_the_file_and_camera() {
    let omni = "cam0:\n  camera_model: omni\n  intrinsics: [0.8, 458.0, 457.0, 367.0, 248.0]\n  distortion_model: radtan\n  distortion_coeffs: [0, 0, 0, 0]\n  resolution: [752, 480]\n";
    load_err(omni, Some("cam0"), "'omni' is not supported");
    let ds = [
        kalibr_camera(0, None, RADTAN),
        kalibr_camera(1, Some(RIGHT_10CM), RADTAN).replace("pinhole", "ds"),
    ]
    .concat();
    load_err(&ds, Some("cam1"), "'ds' is not supported");
    load_err(
        &kalibr_camera(
            0,
            None,
            "  distortion_coeffs: [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]\n  distortion_model: fov\n",
        ),
        Some("cam0"),
        "'fov' is not supported",
    );
    load_err(
        &kalibr_camera(
            0,
            None,
            "  distortion_coeffs: [0.1, 0.2, 0.3]\n  distortion_model: radtan\n",
        ),
        Some("cam0"),
        "got 3 numbers",
    );
    // cam1 without T_cn_cnm1.
    let text = [
        kalibr_camera(0, None, RADTAN),
        kalibr_camera(1, None, RADTAN),
    ]
    .concat();
    load_err(&text, Some("cam1"), "missing `T_cn_cnm1`");
    // A non-rigid T_cn_cnm1 and a bad last row.
    let scaled = "  - [2.0, 0.0, 0.0, -0.1]\n  - [0.0, 1.0, 0.0, 0.0]\n  - [0.0, 0.0, 1.0, 0.0]\n  - [0.0, 0.0, 0.0, 1.0]\n";
    let text = [
        kalibr_camera(0, None, RADTAN),
        kalibr_camera(1, Some(scaled), RADTAN),
    ]
    .concat();
    load_err(&text, Some("cam1"), "orthonormal");
    let projective = "  - [1.0, 0.0, 0.0, -0.1]\n  - [0.0, 1.0, 0.0, 0.0]\n  - [0.0, 0.0, 1.0, 0.0]\n  - [0.0, 0.0, 0.1, 1.0]\n";
    let text = [
        kalibr_camera(0, None, RADTAN),
        kalibr_camera(1, Some(projective), RADTAN),
    ]
    .concat();
    load_err(&text, Some("cam1"), "last row");
    // Missing required key.
    load_err(
        "cam0:\n  camera_model: pinhole\n  intrinsics: [1, 1, 0, 0]\n  distortion_model: none\n",
        Some("cam0"),
        "resolution",
    );
    // A gap in the camera keys, and a foreign top-level key.
    let text = [
        kalibr_camera(0, None, RADTAN),
        kalibr_camera(2, Some(RIGHT_10CM), RADTAN),
    ]
    .concat();
    let err = load_err(&text, None, "`cam1` is missing");
    assert!(matches!(err, RigFileError::Format { .. }));
    let text = format!("{}imu0: {{}}\n", kalibr_camera(0, None, RADTAN));
    load_err(&text, None, "`imu0`");
}

// ---------------------------------------------------------------------------------------------
// The example files.

fn example(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("launch_configs")
        .join(name)
}

#[test]
fn example_four_camera_rig_loads() {
    let rig = load_rig_file(example("rig_four_cameras.yaml")).unwrap();
    assert_eq!(rig.format, RigFileFormat::Sweepdepth);
    assert_eq!(rig.cameras.len(), 4);
    let centres: Vec<DVec3> = rig.cameras.iter().map(|c| c.centre_in_rig()).collect();
    // A 2x2 square with 12 cm sides.
    for (a, b) in [(0, 1), (2, 3), (0, 2), (1, 3)] {
        assert!(
            ((centres[a] - centres[b]).length() - 0.12).abs() < 1e-12,
            "{a}-{b}"
        );
    }
    assert!(((centres[0] - centres[3]).length() - 0.12 * 2f64.sqrt()).abs() < 1e-12);
    // All looking the same way.
    for camera in &rig.cameras {
        assert!(close(
            camera.cam_from_rig.transform_vector(DVec3::Z),
            DVec3::Z,
            1e-12
        ));
    }
    assert!(rig.cameras[0].model.is_some());
    assert!(rig.cameras[3].model.is_none());
}

#[test]
fn example_kalibr_camchain_loads() {
    let rig = load_rig_file(example("kalibr_camchain_example.yaml")).unwrap();
    assert_eq!(rig.format, RigFileFormat::Kalibr);
    assert_eq!(rig.cameras.len(), 3);
    assert!(rig.notes.is_empty(), "{:?}", rig.notes);
    for (camera, x) in rig.cameras.iter().zip([0.0, 0.1, 0.2]) {
        let c = camera.centre_in_rig();
        assert!((c.x - x).abs() < 2e-3, "{}: {c:?}", camera.name);
        assert!(camera.model.is_some());
    }
    assert!(matches!(
        rig.cameras[0].model.unwrap().distortion,
        Distortion::PlumbBob { k3, .. } if k3 == 0.0
    ));
    assert!(matches!(
        rig.cameras[2].model.unwrap().distortion,
        Distortion::Equidistant { .. }
    ));
    assert_eq!(rig.camera_for("/cam1").unwrap().name, "cam1");
}

/// Valid intrinsics that are likely a mistake are doubted (the node warns): a focal length
/// in millimetres (a 178-degree pinhole), a principal point of another resolution; a real
/// lens's and a fisheye's are not.
#[test]
fn unlikely_intrinsics_are_doubted() {
    let pose = "    translation: [0, 0, 0]\n    rotation: [0, 0, 0, 1]\n";
    let doubts = |intrinsics: &str, distortion: &str| {
        load_ok(&one_camera(&format!(
            "{pose}    intrinsics: {{{intrinsics}}}\n{distortion}"
        )))
        .doubts()
    };
    let sane = "width: 384, height: 288, fx: 384, fy: 384, cx: 191.5, cy: 143.5";
    assert!(doubts(sane, "").is_empty());
    let mm = doubts(
        "width: 384, height: 288, fx: 3.6, fy: 3.6, cx: 191.5, cy: 143.5",
        "",
    );
    assert!(
        mm.len() == 1 && mm[0].contains("178-degree field of view"),
        "{mm:?}"
    );
    let full = doubts(
        "width: 384, height: 288, fx: 384, fy: 384, cx: 959.5, cy: 539.5",
        "",
    );
    assert!(
        full.len() == 1 && full[0].contains("lies outside its 384x288 image"),
        "{full:?}"
    );
    let fisheye = "    distortion: {model: equidistant, coefficients: [0.01, 0.0, 0.0, 0.0]}\n";
    assert!(doubts(
        "width: 384, height: 288, fx: 30, fy: 30, cx: 191.5, cy: 143.5",
        fisheye
    )
    .is_empty());
}
