//! `sweepdepth fuse` across two "hosts": the depth of a rig split over two machines, fused by
//! one `fuse` node over DDS, equals the fusion of one node that computes every reference.
//!
//! Host A is the test's private network namespace; host B a namespace of its own joined to it
//! by a veth pair with private addresses (`SecondHost`): DDS discovery and data cross the pair,
//! nothing leaves the machine. On A: the camera drivers (the test's peer, a synthetic row of 4
//! cameras looking at a wall and a box, `/tf_static` world -> rig -> cameras), depth node `a`
//! (reference cam0, its depth remapped to `/a/cam0/depth/...`), the `fuse` node (namespace
//! `/fused`) and depth node `one` (references cam0 and cam2, `fusion:=true`: the one-process
//! run). On B: depth node `b` (reference cam2, `/b/cam2/depth/...`). The rig stands still, so
//! the fused surface does not depend on which sets each node got to: both meshes are saved
//! through `~/save_mesh` and compared vertex by vertex.

use std::collections::HashMap;
use std::process::Command;
use std::time::{Duration, Instant};

use crate::common::dds::{self, NodeProcess, Peer, RigFeed};
use crate::common::mesh::{ply_vertices, SaveMesh};
use crate::common::netns::{in_private_netns, SecondHost};
use glam::DVec3;
use sweepdepth::geometry::CameraModel;
use sweepdepth::msgs::{
    DiagnosticArray, Header, Image, Quaternion, TFMessage, Time, Transform, TransformStamped,
    Vector3,
};
use sweepdepth::synthetic::{self, Scene};

const INNER: &str = "SWEEPDEPTH_TEST_PRIVATE_NETNS_FUSE";
const DOMAIN: u16 = 57;
const WIDTH: u32 = 96;
const HEIGHT: u32 = 72;
const CAMERAS: usize = 4;
const VOXEL: f64 = 0.04;

#[test]
fn fuse_node_on_two_hosts_equals_one_process() {
    in_private_netns(
        INNER,
        "fuse_node::fuse_node_on_two_hosts_equals_one_process",
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
                "-p",
                "world_frame:=world",
                "-p",
                "voxel_size:=0.04",
                "-p",
                "min_depth:=1.0",
                "-p",
                "max_depth:=4.0",
                "-p",
                "mesh_rate:=5.0",
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
            "fusion:=true",
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
    let scene = Scene::wall_and_box(2.0, Some((1.2, 0.3)), model.intrinsics.fx_px);
    let images = synthetic::render_rig(&scene, &rig);
    let mut peer = Peer::new(DOMAIN, "sweepdepth_fuse_test_peer");
    let feed = RigFeed::new(&mut peer, rig, &images, &dds::reliable(10), None);
    // world -> rig, static: the rig stands 1 m up and turned a quarter about z in the world.
    let world_pub = peer.publisher::<TFMessage>("/tf_static", dds::TF_MESSAGE, &dds::latched(10));
    let half = std::f64::consts::FRAC_PI_4;
    world_pub
        .publish(TFMessage {
            transforms: vec![TransformStamped {
                header: Header {
                    stamp: Time::default(),
                    frame_id: "world".into(),
                },
                child_frame_id: "rig".into(),
                transform: Transform {
                    translation: Vector3 {
                        x: 0.5,
                        y: -0.2,
                        z: 1.0,
                    },
                    rotation: Quaternion {
                        x: 0.0,
                        y: 0.0,
                        z: half.sin(),
                        w: half.cos(),
                    },
                },
            }],
        })
        .expect("publish world -> rig");
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
        let stamp = Time {
            sec: 1000 + (k / 10) as i32,
            nanosec: (k % 10) * 100_000_000,
        };
        feed.publish_set(&[stamp; CAMERAS]);
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
    let fused_vertices = ply_vertices(&std::fs::read(&fused_ply).unwrap());
    let one_vertices = ply_vertices(&std::fs::read(&one_ply).unwrap());
    let _ = std::fs::remove_dir_all(&dir);
    assert!(fused_vertices.len() > 100 && one_vertices.len() > 100);
    let near_one = share_within(&fused_vertices, &one_vertices, VOXEL);
    let near_fused = share_within(&one_vertices, &fused_vertices, VOXEL);
    eprintln!(
        "fuse node: {} vertices, {:.1} % within a voxel of the one-process mesh; one process: {} vertices, {:.1} % within a voxel of the fuse node's",
        fused_vertices.len(),
        near_one * 100.0,
        one_vertices.len(),
        near_fused * 100.0
    );
    assert!(near_one >= 0.95 && near_fused >= 0.95);
}

/// The share of `points` with a point of `other` within `radius`.
fn share_within(points: &[DVec3], other: &[DVec3], radius: f64) -> f64 {
    let cell = |p: &DVec3| p.to_array().map(|c| (c / radius).floor() as i64);
    let mut grid: HashMap<[i64; 3], Vec<DVec3>> = HashMap::new();
    for p in other {
        grid.entry(cell(p)).or_default().push(*p);
    }
    let near = points
        .iter()
        .filter(|p| {
            let c = cell(p);
            (-1..=1).any(|dx| {
                (-1..=1).any(|dy| {
                    (-1..=1).any(|dz| {
                        grid.get(&[c[0] + dx, c[1] + dy, c[2] + dz])
                            .is_some_and(|v| {
                                v.iter().any(|q| {
                                    let d: f64 = (0..3).map(|i| (p[i] - q[i]).powi(2)).sum::<f64>();
                                    d.sqrt() <= radius
                                })
                            })
                    })
                })
            })
        })
        .count();
    near as f64 / points.len().max(1) as f64
}
