//! Several references of a rig that does not move, fused by `bag --mesh` without a world
//! frame: the map is in the frame of the set's first reference image (docs/fusion.md), and each
//! other reference's depth map is placed there by the rig's `/tf_static` links. A reference
//! placed at the first one's pose (or with the link's rotation dropped) lies 0.4 m off the
//! scene and fails the mesh's accuracy bar.

use super::util::{ok, scratch, sweepdepth, transform_stamped};
use crate::common;

use glam::{DQuat, DVec3};
use sweepdepth::geometry::{CameraModel, RigCamera, RigidTransform};
use sweepdepth::msgdefs::{CAMERA_INFO, IMAGE, TF_MESSAGE};
use sweepdepth::msgs::{to_cdr, Header, TFMessage, Time, TransformStamped};
use sweepdepth::synthetic::{self, Scene};

/// Where rig camera `i` of four sits on the base (the base is the scene's frame): cam0 and cam1
/// at the back, 10 cm apart; cam2 and cam3 0.4 m ahead of them and turned 6 degrees outwards
/// (to the right, +x).
fn base_from_cam(i: usize) -> RigidTransform {
    let x = 0.1 * i as f64 - 0.15;
    let (ahead, turn) = if i >= 2 {
        (0.4, 6f64.to_radians())
    } else {
        (0.0, 0.0)
    };
    RigidTransform {
        rotation: DQuat::from_rotation_y(turn),
        translation: DVec3::new(x, 0.0, ahead),
    }
}

fn stamped(child: &str, pose: &RigidTransform) -> TransformStamped {
    transform_stamped("base", child, Time { sec: 0, nanosec: 0 }, pose)
}

#[test]
fn references_of_a_fixed_rig_are_fused_where_they_are() {
    let dir = scratch("references");
    let bag = dir.join("rig.mcap");
    let model = CameraModel::pinhole(synthetic::intrinsics(160, 120));
    let scene = Scene::wall_and_box(4.0, Some((2.0, 0.4)), model.intrinsics.fx_px);
    let mut w = sweepdepth::bag::BagWriter::create(&bag, true).unwrap();
    let statics = TFMessage {
        transforms: (0..4)
            .map(|i| stamped(&format!("cam{i}_optical"), &base_from_cam(i)))
            .collect(),
    };
    w.add_topic("/tf_static", TF_MESSAGE, None).unwrap();
    w.write("/tf_static", 1, 1, &to_cdr(&statics).unwrap())
        .unwrap();
    for set in 0..2u32 {
        let log = 1_000_000_000 * u64::from(set + 1);
        for i in 0..4 {
            let camera = RigCamera {
                name: format!("cam{i}"),
                model,
                cam_from_rig: base_from_cam(i).inverse(),
            };
            let header = Header {
                stamp: Time {
                    sec: 100 + set as i32,
                    nanosec: 0,
                },
                frame_id: format!("cam{i}_optical"),
            };
            let image = common::dds::image_msg(&header, &scene.render(&camera), false);
            let info = common::dds::camera_info(&header, &model);
            let (image_topic, info_topic) =
                (format!("/cam{i}/image_raw"), format!("/cam{i}/camera_info"));
            w.add_topic(&info_topic, CAMERA_INFO, None).unwrap();
            w.add_topic(&image_topic, IMAGE, None).unwrap();
            w.write(&info_topic, log, log, &to_cdr(&info).unwrap())
                .unwrap();
            w.write(&image_topic, log + 1, log + 1, &to_cdr(&image).unwrap())
                .unwrap();
        }
    }
    w.finish().unwrap();
    let params = dir.join("rig.params.yaml");
    std::fs::write(
        &params,
        "/**:\n  ros__parameters:\n    cameras: [cam0, cam1, cam2, cam3]\n    references: [cam0, cam3]\n    min_depth: 1.0\n    max_depth: 8.0\n    num_planes: 96\n",
    )
    .unwrap();

    let mesh = dir.join("rig.ply");
    let out = dir.join("out.mcap");
    let stderr = ok(
        &sweepdepth(&[
            "bag",
            bag.to_str().unwrap(),
            out.to_str().unwrap(),
            "--params-file",
            params.to_str().unwrap(),
            "--mesh",
            mesh.to_str().unwrap(),
            "--voxel-size",
            "0.05",
        ]),
        "sweepdepth bag --mesh with two references",
    );
    assert!(
        stderr.contains("2 frame sets found, 2 processed"),
        "{stderr}"
    );
    assert!(stderr.contains("mesh: 4 depth maps fused into"), "{stderr}");

    // The mesh is in cam0's optical frame: its vertices, taken into the base's (the scene's)
    // frame by cam0's own link, lie on the true scene to 2 voxels.
    let bytes = std::fs::read(&mesh).expect("the PLY");
    let base_from_cam0 = base_from_cam(0);
    let points: Vec<[f32; 3]> = common::mesh::ply_vertices(&bytes)
        .iter()
        .map(|p| p.as_vec3().to_array())
        .collect();
    assert!(points.len() > 1000, "{} vertices", points.len());
    let accuracy = sweepdepth::fusion::vertex_accuracy(
        &points,
        0.05,
        sweepdepth::eval::fusion::VERTEX_LIMIT_VOXELS,
        |p| {
            let in_base = base_from_cam0.transform_point(p);
            Some(sweepdepth::eval::fusion::scene_distance_m(&scene, in_base))
        },
    );
    assert!(
        accuracy.fraction() >= sweepdepth::eval::fusion::MIN_VERTICES_WITHIN,
        "only {:.1} % of {} mesh vertices lie within 2 voxels of the true scene (median {:.2} \
         voxels): a reference fused at another's pose?",
        100.0 * accuracy.fraction(),
        points.len(),
        accuracy.median_voxels
    );
    // Both references' surfaces are in it: cam3, turned right, sees the wall beyond cam0's
    // view (right of 4 m x tan(half the field of view) from cam0's axis, in cam0's frame).
    let half_width_at_wall = 4.0 * 80.0 / model.intrinsics.fx_px;
    let beyond = points
        .iter()
        .filter(|p| f64::from(p[0]) > half_width_at_wall + 0.1)
        .count();
    assert!(
        beyond > 50,
        "{beyond} vertices right of cam0's view: cam3's depth maps not fused?"
    );
}
