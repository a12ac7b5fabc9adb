//! `sweepdepth fuse` across two "hosts": the depth of a moving rig split over two machines,
//! fused by one `fuse` node over DDS, lies on the true scene, as the fusion of one node that
//! computes every reference does.
//!
//! Host A is the test's private network namespace; host B a namespace of its own joined to it
//! by a veth pair with private addresses (`SecondHost`): DDS discovery and data cross the pair,
//! nothing leaves the machine. On A: the camera drivers (the test's peer, a synthetic row of 4
//! cameras moving past a wall and a box that stand still in `world`, each set rendered at the
//! rig's pose; `/tf_static` rig -> cameras, `/tf` world -> rig around each set's stamp, the
//! first pose 1 m up and a quarter turn from the identity), depth node `a` (reference cam0,
//! its depth remapped to `/a/cam0/depth/...`), the `fuse` node (namespace `/fused`) and depth
//! node `one` (references cam0 and cam2, `fusion:=true`: the one-process run, the WGSL engine
//! with fusion on its device). On B: depth node `b` (reference cam2, `/b/cam2/depth/...`). The
//! fuse node (fusing on a device of its own) must count maps from both hosts in
//! `/diagnostics`, and both meshes, saved through `~/save_mesh`, must lie on the true scene in
//! `world` (90 % of the vertices within 2 voxels; the fuse node's mesh gave 93.4-95.7 % over six
//! runs on the 2-core machine with builds beside, as sets dropped under load change which depth
//! maps are fused; the one-process run 96.5-96.9 %; a rig placed without /tf is 0.2-0.5 m, 5-12
//! voxels, off): a node that ignored /tf, or fused one host only, fails.
//! The fuse node takes each depth map's colour from its reference camera's images
//! (`color_topics`; cam2's JPEG-compressed, as image_transport's plugin sends them): none may be
//! fused without its colour (`/diagnostics`), and where the two meshes have their surface at the
//! same place (nearest vertex within half a voxel: 85-96 % of the fuse node's vertices, bar 75 %)
//! the colours must be the one-process node's (85 % within 24 levels: 93.4-96.6 % on the
//! 2-core machine, idle or both cores busy beside; 56 % with cam0's colour image turned round).

use std::process::Command;
use std::time::{Duration, Instant};

use crate::common::dds::{self, NodeProcess, Peer, RigFeed};
use crate::common::mesh::{ply_colours, ply_vertices, SaveMesh};
use crate::common::netns::{in_private_netns, SecondHost};
use glam::{DQuat, DVec3};
use sweepdepth::geometry::CameraModel;
use sweepdepth::geometry::RigidTransform;
use sweepdepth::msgs::{
    CompressedImage, DiagnosticArray, Header, Image, Quaternion, TFMessage, Time, Transform,
    TransformStamped, Vector3,
};
use sweepdepth::pipeline::compressed::{compress, Codec};
use sweepdepth::synthetic::{self, Scene};

const INNER: &str = "SWEEPDEPTH_TEST_PRIVATE_NETNS_FUSE";
const DOMAIN: u16 = 57;
const WIDTH: u32 = 96;
const HEIGHT: u32 = 72;
const CAMERAS: usize = 4;
const VOXEL: f64 = 0.04;

#[test]
fn fuse_node_on_two_hosts_fuses_a_moving_rig() {
    in_private_netns(
        INNER,
        "fuse_node::fuse_node_on_two_hosts_fuses_a_moving_rig",
        two_hosts,
    );
}

/// The engine parameters every depth node shares (so that their depths are the same).
const ENGINE: &[&str] = &[
    "-p",
    "cameras:=[cam0, cam1, cam2, cam3]",
    "-p",
    "min_depth:=1.0",
    "-p",
    "max_depth:=4.0",
    "-p",
    "num_planes:=48",
    "-p",
    "camera_timeout:=0.0",
    "-p",
    "sync:=exact",
];

fn depth_node(reference: &str, name: &str, prefix: &str) -> Vec<String> {
    let mut args: Vec<String> = ENGINE.iter().map(|s| s.to_string()).collect();
    args.extend([
        "-r".into(),
        format!("__node:={name}"),
        "-p".into(),
        format!("references:=[{reference}]"),
        "-r".into(),
        format!("depth/image:={prefix}/{reference}/depth/image"),
        "-r".into(),
        format!("depth/camera_info:={prefix}/{reference}/depth/camera_info"),
    ]);
    args
}

fn sweepdepth(mut command: Command, args: &[String]) -> NodeProcess {
    command
        .args(args)
        .env("ROS_DOMAIN_ID", DOMAIN.to_string())
        .env(
            "RUST_LOG",
            std::env::var("RUST_LOG").unwrap_or_else(|_| "warn,sweepdepth=info".into()),
        )
        .stdin(std::process::Stdio::null());
    NodeProcess::spawn(command)
}

fn node_args(kind: &str, args: Vec<String>) -> Vec<String> {
    let mut all = vec![kind.to_string(), "--ros-args".to_string()];
    all.extend(args);
    all
}

fn two_hosts() {
    let host_b = SecondHost::new(INNER);
    let bin = env!("CARGO_BIN_EXE_sweepdepth");
    let mut node_a = sweepdepth(
        Command::new(bin),
        &node_args("node", depth_node("cam0", "depth_a", "/a")),
    );
    let mut node_b = sweepdepth(
        host_b.command(bin),
        &node_args("node", depth_node("cam2", "depth_b", "/b")),
    );
    let mut fuse = sweepdepth(
        Command::new(bin),
        &node_args(
            "fuse",
            [
                "-r",
                "__ns:=/fused",
                "-p",
                "depth_topics:=[/a/cam0/depth/image, /b/cam2/depth/image]",
                // Each depth's colour: its reference camera's images, from the drivers (cam2's
                // as image_transport's compressed plugin sends them).
                "-p",
                "color_topics:=[/cam0/image_raw, /cam2/image_raw/compressed]",
                "-p",
                "world_frame:=world",
                "-p",
                "tf_timeout:=5.0",
                "-p",
                "voxel_size:=0.04",
                "-p",
                "min_depth:=1.0",
                "-p",
                "max_depth:=4.0",
                "-p",
                "mesh_rate:=5.0",
                // On a device of its own (lavapipe without a GPU: `auto` would take the CPU).
                "-p",
                "fusion_device:=gpu",
            ]
            .iter()
            .map(|s| s.to_string())
            .collect(),
        ),
    );
    let mut one_args: Vec<String> = ENGINE.iter().map(|s| s.to_string()).collect();
    one_args.extend(
        [
            "-r",
            "__node:=depth_one",
            "-r",
            "__ns:=/one",
            "-p",
            "references:=[cam0, cam2]",
            "-p",
            "world_frame:=world",
            "-p",
            "tf_timeout:=5.0",
            "-p",
            "fusion:=true",
            // The WGSL engine and fusion on its device, from two threads (lavapipe here).
            "-p",
            "device:=gpu",
            "-p",
            "fusion_device:=gpu",
            "-p",
            "voxel_size:=0.04",
            "-p",
            "mesh_rate:=5.0",
        ]
        .iter()
        .map(|s| s.to_string()),
    );
    // /one's cameras are the same drivers: its camera topics remapped back to the root.
    for i in 0..CAMERAS {
        one_args.extend([
            "-r".to_string(),
            format!("cam{i}/image_raw:=/cam{i}/image_raw"),
            "-r".to_string(),
            format!("cam{i}/camera_info:=/cam{i}/camera_info"),
        ]);
    }
    let mut one = sweepdepth(Command::new(bin), &node_args("node", one_args));

    let model = CameraModel::pinhole(synthetic::intrinsics(WIDTH, HEIGHT));
    let rig = synthetic::row_rig(CAMERAS, 0.1, model, 1).expect("rig");
    // The scene stands still in `world`, placed where the rig's first pose sees it as the
    // row's own frame would.
    let scene = Scene::wall_and_box(2.0, Some((1.2, 0.3)), model.intrinsics.fx_px);
    let world_from_scene = world_from_rig(seconds(0));
    let images = synthetic::render_rig(&scene, &rig);
    let mut peer = Peer::new(DOMAIN, "sweepdepth_fuse_test_peer");
    let feed = RigFeed::new(&mut peer, rig.clone(), &images, &dds::reliable(10), None);
    let tf_pub = peer.publisher::<TFMessage>("/tf", dds::TF_MESSAGE, &dds::reliable(100));
    let compressed_pub = peer.publisher::<CompressedImage>(
        "/cam2/image_raw/compressed",
        dds::COMPRESSED_IMAGE,
        &dds::reliable(10),
    );
    // Set k at its stamp: /tf 50 ms before and after it (tf2 interpolates; the motion is
    // linear and about one axis, so exactly), then the images rendered at the rig's pose.
    let publish_set = |k: u32| {
        let t = seconds(k);
        for dt in [-0.05, 0.05] {
            let pose = world_from_rig(t + dt);
            tf_pub
                .publish(TFMessage {
                    transforms: vec![stamped("world", "rig", time(t + dt), &pose)],
                })
                .expect("publish world -> rig");
        }
        let scene_from_rig = world_from_scene.inverse().compose(&world_from_rig(t));
        let rendered: Vec<_> = rig
            .cameras
            .iter()
            .map(|c| {
                let camera = sweepdepth::geometry::RigCamera {
                    name: c.name.clone(),
                    model: c.model,
                    cam_from_rig: c.cam_from_rig.compose(&scene_from_rig.inverse()),
                };
                scene.render(&camera)
            })
            .collect();
        feed.publish_rendered_set(&[time(t); CAMERAS], &rendered);
        let header = Header {
            stamp: time(t),
            frame_id: dds::frame(2),
        };
        let raw = dds::image_msg(&header, &rendered[2], false);
        let jpeg = compress(&raw, Codec::Jpeg, 95).expect("compress cam2");
        compressed_pub
            .publish(jpeg)
            .expect("publish cam2 compressed");
    };
    let depth_a = peer.subscription::<Image>("/a/cam0/depth/image", dds::IMAGE, &dds::reliable(10));
    let depth_b = peer.subscription::<Image>("/b/cam2/depth/image", dds::IMAGE, &dds::reliable(10));
    let diag = peer.subscription::<DiagnosticArray>(
        "/diagnostics",
        dds::DIAGNOSTIC_ARRAY,
        &dds::reliable(50),
    );

    // Sets until both hosts' depth came and the fuse node fused at least 4 depth maps (so both
    // sources are in its map) and the one-process node 2 sets.
    let fused = |status_name: &str, arrays: &[DiagnosticArray]| -> u64 {
        arrays
            .iter()
            .flat_map(|a| &a.status)
            .filter(|s| s.name.contains(status_name))
            .filter_map(|s| dds::value_of(s, "fusion depth maps"))
            .filter_map(|v| v.parse::<u64>().ok())
            .max()
            .unwrap_or(0)
    };
    let (mut from_a, mut from_b) = (0, 0);
    let mut arrays = Vec::new();
    let mut k = 1u32;
    let started = Instant::now();
    loop {
        for node in [&mut node_a, &mut node_b, &mut fuse, &mut one] {
            node.check_alive();
        }
        assert!(
            started.elapsed() < dds::timeout(),
            "waited {:?} in vain: depth from a {from_a}, from b {from_b}, fused {}, one {}",
            dds::timeout(),
            fused("fuse", &arrays),
            fused("/one/", &arrays)
        );
        publish_set(k);
        k += 1;
        std::thread::sleep(Duration::from_millis(200));
        from_a += dds::take_all(&depth_a).len();
        from_b += dds::take_all(&depth_b).len();
        arrays.extend(dds::take_all(&diag));
        let both_sources = arrays.iter().flat_map(|a| &a.status).any(|s| {
            s.name.contains("fuse")
                && dds::value_of(s, "fusion depth maps from /a/cam0/depth/image").is_some()
                && dds::value_of(s, "fusion depth maps from /b/cam2/depth/image").is_some()
        });
        if from_a >= 2
            && from_b >= 2
            && both_sources
            && fused("fuse", &arrays) >= 4
            && fused("/one/", &arrays) >= 4
        {
            break;
        }
    }
    eprintln!(
        "after {k} sets: depth from host a {from_a}, from host b {from_b}, fused by the fuse node {}, by the one-process node {}",
        fused("fuse", &arrays),
        fused("/one/", &arrays)
    );
    // The fuse node counts the maps it fused per source: both hosts' depth is in its map
    // (host A alone would make 4 maps as well).
    let per_source = |topic: &str| -> u64 {
        arrays
            .iter()
            .flat_map(|a| &a.status)
            .filter(|s| s.name.contains("fuse"))
            .filter_map(|s| dds::value_of(s, &format!("fusion depth maps from {topic}")))
            .filter_map(|v| v.parse::<u64>().ok())
            .max()
            .unwrap_or(0)
    };
    let (maps_a, maps_b) = (
        per_source("/a/cam0/depth/image"),
        per_source("/b/cam2/depth/image"),
    );
    eprintln!("fuse node: {maps_a} maps from host a, {maps_b} from host b");
    // Where each map integrates (`fusion_device:=gpu`): the fuse node on a device of its
    // own, the one-process node on its engine's.
    let on = |status_name: &str| -> Option<String> {
        let statuses = arrays.iter().flat_map(|a| &a.status);
        let mine = statuses.filter(|s| s.name.contains(status_name));
        mine.filter_map(|s| dds::value_of(s, "fusion on"))
            .next_back()
            .map(str::to_string)
    };
    assert_eq!(on("fuse").as_deref(), Some("GPU"), "the fuse node's fusion");
    assert_eq!(
        on("/one/").as_deref(),
        Some("GPU"),
        "the one-process node's fusion"
    );
    // Each map took its colour image (raw for cam0, JPEG for cam2): none was fused without.
    let uncoloured: Vec<String> = (arrays.iter().flat_map(|a| &a.status))
        .filter(|s| s.name.contains("fuse"))
        .flat_map(|s| &s.values)
        .filter(|kv| kv.key.starts_with("fused without colour") && kv.value != "0")
        .map(|kv| format!("{} = {}", kv.key, kv.value))
        .collect();
    assert!(
        uncoloured.is_empty(),
        "the fuse node fused depth maps without their colour: {uncoloured:?}"
    );
    assert!(
        maps_a >= 1 && maps_b >= 1,
        "the fuse node fused {maps_a} maps from host a's /a/cam0/depth/image and {maps_b} from \
         host b's /b/cam2/depth/image; both must be in its map"
    );

    let dir = std::env::temp_dir().join(format!("sweepdepth-fuse-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let fused_ply = dir.join("fused.ply");
    let one_ply = dir.join("one.ply");
    for (service, path, node) in [
        ("/fused/sweepdepth_fuse/save_mesh", &fused_ply, &mut fuse),
        ("/one/depth_one/save_mesh", &one_ply, &mut one),
    ] {
        let answer = SaveMesh::new(&mut peer, service).call(&path.display().to_string(), node);
        assert!(answer.success, "{service}: {answer:?}");
    }
    let fused_bytes = std::fs::read(&fused_ply).unwrap();
    let one_bytes = std::fs::read(&one_ply).unwrap();
    let fused_vertices = ply_vertices(&fused_bytes);
    let one_vertices = ply_vertices(&one_bytes);
    let _ = std::fs::remove_dir_all(&dir);
    assert!(fused_vertices.len() > 100 && one_vertices.len() > 100);
    // Every mesh against the true scene in `world`.
    for (name, vertices) in [
        ("fuse node", &fused_vertices),
        ("one process", &one_vertices),
    ] {
        let on_scene = vertices
            .iter()
            .filter(|p| {
                let in_scene = world_from_scene.inverse().transform_point(**p);
                sweepdepth::eval::fusion::scene_distance_m(&scene, in_scene) <= 2.0 * VOXEL
            })
            .count();
        eprintln!(
            "{name}: {on_scene} of {} vertices within 2 voxels of the true scene",
            vertices.len()
        );
        assert!(
            on_scene * 100 >= vertices.len() * 90,
            "{name}: only {on_scene} of {} mesh vertices lie within 2 voxels of the true scene",
            vertices.len()
        );
    }
    // The fuse node's colours (`color_topics`) are the one-process node's, which colours from
    // its reference images: each vertex against the nearest vertex of the other mesh, where the
    // two meshes have their surface at the same place (nearest within half a voxel). Elsewhere
    // they differ in geometry, not colour: the two nodes fuse different sets (under load the
    // one-process node fused 4 of 44 sets, the fuse node 81 maps), and on a texture about a
    // voxel wide a vertex a voxel away has another colour (there 20-50 % alike).
    let (fused_colours, one_colours) = (ply_colours(&fused_bytes), ply_colours(&one_bytes));
    let (mut shared, mut alike) = (0usize, 0usize);
    for (p, c) in fused_vertices.iter().zip(&fused_colours) {
        let nearest = (one_vertices.iter().enumerate())
            .map(|(i, a)| (i, p.distance_squared(*a)))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        let Some((i, _)) = nearest.filter(|(_, d2)| d2.sqrt() <= 0.5 * VOXEL) else {
            continue;
        };
        shared += 1;
        let n = one_colours[i];
        alike += usize::from((0..3).all(|k| n[k].abs_diff(c[k]) <= COLOUR_TOLERANCE));
    }
    eprintln!(
        "fuse node: {shared} of {} vertices where the one-process mesh has one, {alike} of them \
         with colours within {COLOUR_TOLERANCE} of its",
        fused_vertices.len()
    );
    assert!(
        shared * 100 >= fused_vertices.len() * 75,
        "the two meshes share too little surface to compare colours: {shared} of {} vertices",
        fused_vertices.len()
    );
    assert!(
        alike * 100 >= shared * 85,
        "the fuse node's mesh is not coloured as the one-process node's: {alike} of {shared} \
         vertices alike"
    );
}

/// Levels per channel within which two meshes' colours count as alike.
const COLOUR_TOLERANCE: u8 = 24;

/// Seconds of set `k` (10 sets a second from 1000 s).
fn seconds(k: u32) -> f64 {
    1000.0 + f64::from(k) * 0.1
}

fn time(t: f64) -> Time {
    let ns = (t * 1e9).round() as i64;
    Time {
        sec: ns.div_euclid(1_000_000_000) as i32,
        nanosec: ns.rem_euclid(1_000_000_000) as u32,
    }
}

/// The rig in `world` at `t` s: 1 m up, a quarter turn about z and 0.5 m aside at 1000 s, then
/// moving 0.2 m/s along the row and turning 0.05 rad/s about its vertical (the sets of a few
/// seconds that the test needs see the wall and the box).
fn world_from_rig(t: f64) -> RigidTransform {
    let s = t - 1000.0;
    let start = RigidTransform {
        rotation: DQuat::from_rotation_z(std::f64::consts::FRAC_PI_2),
        translation: DVec3::new(0.5, -0.2, 1.0),
    };
    start.compose(&RigidTransform {
        rotation: DQuat::from_rotation_y(0.05 * s),
        translation: DVec3::new(0.2 * s, 0.0, 0.0),
    })
}

fn stamped(parent: &str, child: &str, stamp: Time, pose: &RigidTransform) -> TransformStamped {
    let (t, q) = (pose.translation, pose.rotation);
    TransformStamped {
        header: Header {
            stamp,
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
