//! Raw and rectified images through the node's pipeline (ROS's rules, as image_geometry has
//! them): a raw image is described by K and D in its optical frame, a rectified one by P in that
//! frame rotated by R, with P's translation placing the second camera of a stereo pair that
//! shares the first one's frame. The kind is what the user declares (the topic's name or
//! `image_kinds`), never guessed from D.

use crate::common;

use glam::{DQuat, DVec2, DVec3};
use sweepdepth::geometry::{
    CameraModel, PinholeIntrinsics, Reference, Rig, RigCamera, RigidTransform,
};
use sweepdepth::msgs::{
    CameraInfo, Header, Image, Quaternion, TFMessage, Time, Transform, TransformStamped, Vector3,
};
use sweepdepth::pipeline::{
    process_job, ConfigError, Input, Job, Pipeline, PipelineConfig, Skip, Wanted,
};
use sweepdepth::ros::camera_info::ImageKind;
use sweepdepth::sweep::gpu::GpuEngine;
use sweepdepth::sweep::SweepParams;
use sweepdepth::synthetic::Scene;

const CAMERAS: [&str; 3] = ["left", "mid", "right"];
const WIDTH: u32 = 64;
const HEIGHT: u32 = 48;
const BASELINE_M: f64 = 0.1;

fn config(extra: &[&str]) -> Result<PipelineConfig, ConfigError> {
    let mut args: Vec<String> = ["--ros-args", "-p", "cameras:=[left, mid, right]", "-p"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    args.push("sync:=exact".into());
    for a in extra {
        args.push(a.to_string());
    }
    PipelineConfig::from_args(&args)
}

fn p(params: &[&str]) -> Vec<String> {
    params
        .iter()
        .flat_map(|v| ["-p".to_string(), v.to_string()])
        .collect()
}

fn config_p(params: &[&str]) -> Result<PipelineConfig, ConfigError> {
    let args = p(params);
    config(&args.iter().map(String::as_str).collect::<Vec<_>>())
}

#[test]
fn the_kind_comes_from_the_topic_name_or_image_kinds() {
    use ImageKind::{Raw, Rectified};
    assert_eq!(config(&[]).unwrap().image_kinds, vec![Raw; 3]);
    let c = config_p(&["image_topic:=image_rect_color"]).unwrap();
    assert_eq!(c.image_kinds, vec![Rectified; 3]);
    // A remap decides the name that counts: the resolved topic's.
    let c = config(&["-r", "/mid/image_raw:=/stereo/left/image_rect"]).unwrap();
    assert_eq!(c.image_kinds, vec![Raw, Rectified, Raw]);
    // image_kinds wins; `auto` falls back to the name.
    let c = config_p(&["image_topic:=image_rect", "image_kinds:=[raw, auto, rect]"]).unwrap();
    assert_eq!(c.image_kinds, vec![Raw, Rectified, Rectified]);
    // A name that says neither is raw, with a note naming the camera and the way out.
    let c = config(&["-r", "/right/image_raw:=/right/frames"]).unwrap();
    assert_eq!(c.image_kinds, vec![Raw; 3]);
    assert!(
        c.notes.iter().any(|n| n.contains("camera 'right'")
            && n.contains("/right/frames")
            && n.contains("image_kinds")),
        "{:?}",
        c.notes
    );
    // Bad values and lengths are refused at start-up with the reason.
    let e = config_p(&["image_kinds:=[raw, rect]"])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("2 entries") && e.contains("'cameras' has 3"),
        "{e}"
    );
    let e = config_p(&["image_kinds:=[raw, rectified, raw]"])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("'rectified' is not one of the allowed values"),
        "{e}"
    );
}

/// The truth: rectified cameras in a row along the rig's x, all looking down +z.
fn rect_from_rig(i: usize) -> RigidTransform {
    RigidTransform {
        rotation: DQuat::IDENTITY,
        translation: DVec3::new(-(i as f64 - 1.0) * BASELINE_M, 0.0, 0.0),
    }
}

/// R of camera i: from its raw (physical) optical frame into its rectified camera. The
/// physical cameras are toed in and rolled a little, as a real rig is before rectification.
fn r_of(i: usize) -> DQuat {
    let yaw = [0.05, -0.03, -0.06][i];
    let roll = [0.01, 0.02, -0.015][i];
    DQuat::from_rotation_y(yaw) * DQuat::from_rotation_z(roll)
}

fn raw_from_rig(i: usize) -> RigidTransform {
    RigidTransform {
        rotation: r_of(i).inverse(),
        translation: DVec3::ZERO,
    }
    .compose(&rect_from_rig(i))
}

fn rect_intrinsics() -> PinholeIntrinsics {
    PinholeIntrinsics {
        width_px: WIDTH,
        height_px: HEIGHT,
        fx_px: 60.0,
        fy_px: 60.0,
        cx_px: 31.5,
        cy_px: 23.5,
    }
}

fn row_major(q: DQuat) -> [f64; 9] {
    let m = glam::DMat3::from_quat(q);
    [
        m.x_axis.x, m.y_axis.x, m.z_axis.x, m.x_axis.y, m.y_axis.y, m.z_axis.y, m.x_axis.z,
        m.y_axis.z, m.z_axis.z,
    ]
}

/// A stereo calibration's CameraInfo: the raw camera (K, a barrel D) and its rectification
/// (R, P with `Tx = tx`).
fn stereo_info(r: DQuat, tx: f64) -> CameraInfo {
    let k = rect_intrinsics();
    CameraInfo {
        width: WIDTH,
        height: HEIGHT,
        distortion_model: "plumb_bob".into(),
        d: vec![-0.12, 0.02, 0.0005, -0.0003, 0.0],
        k: [66.0, 0.0, 32.2, 0.0, 65.5, 23.1, 0.0, 0.0, 1.0],
        r: row_major(r),
        p: [
            k.fx_px, 0.0, k.cx_px, tx, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 0.0, 1.0, 0.0,
        ],
        ..CameraInfo::default()
    }
}

fn transform(parent: &str, child: &str, parent_from_child: RigidTransform) -> TransformStamped {
    let (t, q) = (parent_from_child.translation, parent_from_child.rotation);
    TransformStamped {
        header: Header {
            stamp: Time::default(),
            frame_id: parent.into(),
        },
        child_frame_id: child.into(),
        transform: Transform {
            translation: Vector3 {
                x: t.x,
                y: t.y,
                z: t.z,
            },
            rotation: Quaternion {
                x: q.x,
                y: q.y,
                z: q.z,
                w: q.w,
            },
        },
    }
}

fn image(frame_id: &str, ms: i64, data: Vec<u8>) -> Image {
    Image {
        header: Header {
            stamp: Time::from_nanos(ms * 1_000_000),
            frame_id: frame_id.into(),
        },
        width: WIDTH,
        height: HEIGHT,
        encoding: "rgb8".into(),
        is_bigendian: 0,
        step: WIDTH * 3,
        data,
    }
}

fn grey() -> Vec<u8> {
    vec![128; (WIDTH * HEIGHT * 3) as usize]
}

/// One set through a pipeline: each camera's info, the tf tree, and one image per camera.
fn one_set(
    config: &PipelineConfig,
    infos: &[CameraInfo],
    tf: &[TransformStamped],
    images: Vec<Image>,
) -> Result<Job, Skip> {
    let mut pipeline = Pipeline::new(config).unwrap();
    for (i, info) in infos.iter().enumerate() {
        pipeline.push(
            Input::CameraInfo {
                camera: i,
                info: Box::new(info.clone()),
            },
            0,
        );
    }
    assert!(pipeline
        .push(
            Input::TfStatic(TFMessage {
                transforms: tf.to_vec()
            }),
            0
        )
        .notices
        .is_empty());
    let mut results = Vec::new();
    for (i, image) in images.into_iter().enumerate() {
        results.extend(
            pipeline
                .push(Input::Image { camera: i, image }, i as u64 * 1_000_000)
                .sets,
        );
    }
    assert_eq!(results.len(), 1, "{results:?}");
    results.pop().unwrap()
}

fn rig_of(job: &Job) -> Rig {
    Rig::new(job.cameras.clone(), Reference::Camera(job.anchor())).unwrap()
}

fn assert_pose(what: &str, got: &RigidTransform, want: &RigidTransform) {
    let angle = got.rotation.angle_between(want.rotation);
    let offset = (got.translation - want.translation).length();
    assert!(
        angle < 1e-9 && offset < 1e-9,
        "{what}: got {got:?}, want {want:?} ({angle:e} rad, {offset:e} m off)"
    );
}

/// The rectified stereo setup: each camera's tf frame is its physical optical frame, its
/// CameraInfo has R (toe-in and roll) and P, its image is the rectified one.
fn rectified_rig_inputs() -> (Vec<CameraInfo>, Vec<TransformStamped>) {
    let infos = (0..3).map(|i| stereo_info(r_of(i), 0.0)).collect();
    let tf = (0..3)
        .map(|i| {
            transform(
                "rig",
                &format!("{}_optical", CAMERAS[i]),
                raw_from_rig(i).inverse(),
            )
        })
        .collect();
    (infos, tf)
}

#[test]
fn rectified_images_use_p_in_the_frame_rotated_by_r() {
    let (infos, tf) = rectified_rig_inputs();
    let images = |ms| {
        CAMERAS
            .iter()
            .map(|c| image(&format!("{c}_optical"), ms, grey()))
            .collect::<Vec<_>>()
    };
    let cfg = config_p(&["image_topic:=image_rect"]).unwrap();
    let job = one_set(&cfg, &infos, &tf, images(100)).unwrap();
    let rig = rig_of(&job);
    for i in 0..3 {
        let model = &job.cameras[i].model;
        assert_eq!(model.intrinsics, rect_intrinsics(), "P, not K");
        assert!(model.distortion.is_none(), "no D on a rectified image");
        // The rectified cameras are parallel, one baseline apart: R is folded into the pose.
        let want = rect_from_rig(i).compose(&rect_from_rig(1).inverse());
        assert_pose(&format!("cam_from_ref {i}"), &rig.cam_from_ref(i), &want);
    }
    // The reference's rectified camera in its image's frame (the points are published there).
    assert!(
        job.references[0]
            .cam_from_frame
            .rotation
            .angle_between(r_of(1))
            < 1e-12
    );

    // The same messages read as raw images: K and D, and the physical (toed-in) poses. That
    // is what the node did before for a D = 0 camera with R != I, without the D.
    let cfg = config(&[]).unwrap();
    let job = one_set(&cfg, &infos, &tf, images(100)).unwrap();
    let rig = rig_of(&job);
    assert_eq!(job.cameras[0].model.intrinsics.fx_px, 66.0);
    assert!(!job.cameras[0].model.distortion.is_none());
    let want = raw_from_rig(0).compose(&raw_from_rig(1).inverse());
    assert_pose("raw cam_from_ref 0", &rig.cam_from_ref(0), &want);
    // ... which is far from the rectified geometry: a point 2 m ahead lands pixels away.
    let point = DVec3::new(0.2, 0.1, 2.0);
    let rect_model = CameraModel::pinhole(rect_intrinsics());
    let rect_px = rect_model
        .project(
            rect_from_rig(0)
                .compose(&rect_from_rig(1).inverse())
                .transform_point(point),
        )
        .unwrap();
    let raw_as_rect_px = rect_model.project(want.transform_point(point)).unwrap();
    assert!(
        (rect_px - raw_as_rect_px).length() > 3.0,
        "{rect_px} vs {raw_as_rect_px}"
    );
}

#[test]
fn p_translation_places_a_camera_only_in_a_shared_frame() {
    let fx = rect_intrinsics().fx_px;
    let b = 0.05;
    let two = |extra: &[&str]| {
        let mut params = vec![
            "cameras:=[left, right]",
            "reference_camera:=left",
            "sync:=exact",
        ];
        params.extend_from_slice(extra);
        let args: Vec<String> = std::iter::once("--ros-args".to_string())
            .chain(p(&params))
            .collect();
        PipelineConfig::from_args(&args).unwrap()
    };
    let cfg = two(&["image_topic:=image_rect_raw"]);
    let infos = [
        stereo_info(DQuat::IDENTITY, 0.0),
        stereo_info(DQuat::IDENTITY, -fx * b),
    ];
    let one_pair = |frames: [&str; 2], tf: &[TransformStamped]| {
        let mut pipeline = Pipeline::new(&cfg).unwrap();
        for (i, info) in infos.iter().enumerate() {
            pipeline.push(
                Input::CameraInfo {
                    camera: i,
                    info: Box::new(info.clone()),
                },
                0,
            );
        }
        pipeline.push(
            Input::TfStatic(TFMessage {
                transforms: tf.to_vec(),
            }),
            0,
        );
        let mut results = Vec::new();
        for (i, frame) in frames.iter().enumerate() {
            results.extend(
                pipeline
                    .push(
                        Input::Image {
                            camera: i,
                            image: image(frame, 100, grey()),
                        },
                        i as u64,
                    )
                    .sets,
            );
        }
        let job = results.pop().unwrap().unwrap();
        rig_of(&job).cam_from_ref(1)
    };
    let right_at_b = RigidTransform {
        rotation: DQuat::IDENTITY,
        translation: DVec3::new(-b, 0.0, 0.0),
    };
    // RealSense-style: infra2's images carry infra1's frame id, P's Tx is the only baseline.
    let shared = one_pair(["camera_infra1_optical_frame"; 2], &[]);
    assert_pose("shared frame", &shared, &right_at_b);
    // ZED-style: each camera has its own frame, tf has the baseline, and P's Tx restates it:
    // applied once, not twice.
    let tf = [transform(
        "zed_left_camera_optical_frame",
        "zed_right_camera_optical_frame",
        right_at_b.inverse(),
    )];
    let own = one_pair(
        [
            "zed_left_camera_optical_frame",
            "zed_right_camera_optical_frame",
        ],
        &tf,
    );
    assert_pose("own frames", &own, &right_at_b);
}

#[test]
fn rectified_images_give_the_right_depth() {
    // The rectified views of a wall with a box in front, rendered by the rectified cameras;
    // the node gets the stereo calibration (K, D, R, P) and the physical poses in tf.
    let (infos, tf) = rectified_rig_inputs();
    let scene = Scene::wall_and_box(2.0, Some((1.4, 0.25)), 60.0);
    let model = CameraModel::pinhole(rect_intrinsics());
    let frames: Vec<String> = CAMERAS.iter().map(|c| format!("{c}_optical")).collect();
    let images: Vec<Image> = (0..3)
        .map(|i| {
            let render = scene.render(&RigCamera {
                name: CAMERAS[i].into(),
                model,
                cam_from_rig: rect_from_rig(i),
            });
            let mut data = Vec::with_capacity((WIDTH * HEIGHT * 3) as usize);
            for &px in &render.pixels {
                let [r, g, b, _] = sweepdepth::image::Rgba8Image::unpack(px);
                data.extend_from_slice(&[r, g, b]);
            }
            image(&frames[i], 100, data)
        })
        .collect();
    let cfg = config_p(&["image_topic:=image_rect", "publish_points:=true"]).unwrap();
    let job = one_set(&cfg, &infos, &tf, images).unwrap();
    let gpu = common::gpu();
    let mut engine = GpuEngine::new(&gpu.device, &gpu.queue).expect("engine");
    let sweep = SweepParams {
        min_depth_m: 1.0,
        max_depth_m: 3.0,
        num_planes: 48,
        ..SweepParams::default()
    };
    let set = process_job(&mut engine, &job, &sweep, Wanted::all(true)).expect("the set runs");
    assert!(set.skipped.is_empty(), "{:?}", set.skipped);
    let out = set
        .outputs
        .into_iter()
        .next()
        .expect("the reference's outputs");
    let truth = scene.depth(&model, &rect_from_rig(1));
    let depth = sweepdepth::image::ImageF32 {
        width: WIDTH,
        height: HEIGHT,
        data: out
            .messages
            .depth
            .data
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect(),
    };
    let (within, valid) = common::fraction_within(&depth, &truth, 0.02);
    assert!(
        within > 0.85,
        "{:.1} % of pixels within 2 % of the truth ({:.1} % valid)",
        within * 100.0,
        valid * 100.0
    );
    // The points are in the reference image's frame (its physical optical frame): the
    // rectified camera's points rotated back by R.
    let points = out.messages.points.expect("points");
    let (u, v) = (32usize, 24usize);
    let at = (v * WIDTH as usize + u) * 16;
    let xyz: Vec<f64> = (0..3)
        .map(|k| {
            let b = &points.data[at + 4 * k..at + 4 * k + 4];
            f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        })
        .collect();
    let z = f64::from(depth.data[v * WIDTH as usize + u]);
    assert!(z.is_finite());
    let in_rect = model.unproject_z1(DVec2::new(u as f64, v as f64)).unwrap() * z;
    let in_frame = r_of(1).inverse() * in_rect;
    let got = DVec3::new(xyz[0], xyz[1], xyz[2]);
    assert!((got - in_frame).length() < 1e-4, "{got} vs {in_frame}");
}
