//! The GPU integration against the CPU's on analytic scenes (CI runs them on lavapipe): the
//! same blocks, the same stats, TSDF, weights and colours to float rounding, the same mesh.

use std::sync::{Mutex, OnceLock};

use glam::DVec3;

use super::*;
use crate::fusion::test_scenes::{
    camera, look_at, red_left_blue_right, render_plane, sphere_before_slanted_wall,
};
use crate::fusion::{integrate_weighted, observation_weights, BlockMesh, Mesh, Weighting};
use crate::geometry::{CameraModel, Distortion, RigidTransform};
use crate::gpu_context::GpuContext;
use crate::image::Rgba8Image;

/// One device for the tests, and one test at a time on it (a device polled from several
/// threads at once met a wgpu bug; `sweep/gpu/record.rs`).
pub(crate) fn gpu() -> (&'static GpuContext, std::sync::MutexGuard<'static, ()>) {
    static GPU: OnceLock<GpuContext> = OnceLock::new();
    static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());
    let context = GPU.get_or_init(|| match GpuContext::new() {
        Ok(context) => context,
        Err(e) => panic!("GPU tests need an adapter (lavapipe is fine): {e}"),
    });
    let guard = ONE_AT_A_TIME
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    (context, guard)
}

/// A depth map as the GPU integration takes it.
fn view<'a>(
    depth: &'a ImageF32,
    colour: Option<&'a Rgba8Image>,
    model: &'a CameraModel,
    map_from_cam: &'a RigidTransform,
) -> DepthView<'a> {
    DepthView {
        depth,
        confidence: None,
        baseline_ratio: None,
        colour,
        model,
        map_from_cam,
    }
}

/// Tolerances of a voxel: the shader projects as `common.wgsl` does (`x / z` times the focal
/// length, where the CPU multiplies by `1 / z`), so a voxel's pixel position differs in its
/// last bits, and with it the bilinear depth.
const TSDF_TOLERANCE: f32 = 1e-4;
/// Relative, of the weight.
const WEIGHT_TOLERANCE: f32 = 1e-4;
/// The largest share of voxels observed by one path and not the other, or beyond the
/// tolerances (a position at a pixel's or the image's edge rounding the other way).
const MAX_DIFFERING_SHARE: f64 = 1e-4;

/// What differs between the two grids.
#[derive(Debug, Default)]
struct Differences {
    voxels: usize,
    /// Observed by one path only.
    observed: usize,
    /// Beyond the tolerances.
    values: usize,
    worst_tsdf: f32,
}

/// Asserts the same blocks, and returns how their voxels differ.
fn compare_grids(cpu: &VoxelBlockGrid, gpu: &VoxelBlockGrid) -> Differences {
    let mut cpu_blocks: Vec<BlockIndex> = cpu.blocks().map(|(i, _)| *i).collect();
    let mut gpu_blocks: Vec<BlockIndex> = gpu.blocks().map(|(i, _)| *i).collect();
    cpu_blocks.sort_unstable();
    gpu_blocks.sort_unstable();
    if cpu_blocks != gpu_blocks {
        let only = |a: &[BlockIndex], b: &[BlockIndex]| -> Vec<BlockIndex> {
            a.iter()
                .filter(|i| b.binary_search(i).is_err())
                .copied()
                .collect()
        };
        panic!(
            "the blocks differ: {} and {}; on the CPU only {:?}, on the GPU only {:?}",
            cpu_blocks.len(),
            gpu_blocks.len(),
            only(&cpu_blocks, &gpu_blocks),
            only(&gpu_blocks, &cpu_blocks)
        );
    }
    let mut d = Differences::default();
    for index in &cpu_blocks {
        let (Some(a), Some(b)) = (cpu.block(*index), gpu.block(*index)) else {
            unreachable!("both grids hold {index:?}");
        };
        for offset in 0..VOXELS_PER_BLOCK {
            let (a, b) = (a.voxel_at_offset(offset), b.voxel_at_offset(offset));
            d.voxels += 1;
            if a.is_observed() != b.is_observed() {
                d.observed += 1;
                continue;
            }
            let tsdf = (a.tsdf - b.tsdf).abs();
            d.worst_tsdf = d.worst_tsdf.max(tsdf);
            let weight = (a.weight - b.weight).abs() / a.weight.max(1e-6);
            let colour = a
                .colour()
                .iter()
                .zip(b.colour())
                .any(|(x, y)| x.abs_diff(y) > 1);
            if tsdf > TSDF_TOLERANCE
                || weight > WEIGHT_TOLERANCE
                || colour
                || a.colour_weight() != b.colour_weight()
            {
                d.values += 1;
            }
        }
    }
    d
}

fn assert_close(what: &str, d: &Differences) {
    let share = (d.observed + d.values) as f64 / d.voxels.max(1) as f64;
    assert!(
        share <= MAX_DIFFERING_SHARE,
        "{what}: {d:?} ({share:.2e} of the voxels differ)"
    );
}

/// The counts a frame reports, which the two paths must agree on exactly but for the
/// voxels updated (within the differing share).
fn assert_same_stats(what: &str, cpu: &IntegrationStats, gpu: &IntegrationStats) {
    let key = |s: &IntegrationStats| {
        (
            s.pixels_valid,
            s.blocks_allocated,
            s.blocks_in_view,
            s.blocks_dropped,
        )
    };
    assert_eq!(key(cpu), key(gpu), "{what}: {cpu:?} against {gpu:?}");
    let voxels = cpu.voxels_updated.abs_diff(gpu.voxels_updated) as f64;
    assert!(
        voxels <= MAX_DIFFERING_SHARE * cpu.voxels_updated as f64,
        "{what}: voxels updated {cpu:?} against {gpu:?}"
    );
    assert!(cpu.voxels_updated > 0, "{what}: nothing updated");
}

/// Each block's mesh: the same triangles, vertices within a hundredth of a voxel.
fn assert_same_mesh(cpu: &VoxelBlockGrid, gpu: &VoxelBlockGrid) -> usize {
    let (mut a, mut b) = (Mesh::new(), Mesh::new());
    let (sa, sb) = (a.rebuild(cpu), b.rebuild(gpu));
    assert_eq!(sa.triangles, sb.triangles, "triangles");
    assert_eq!(sa.blocks_with_surface, sb.blocks_with_surface);
    let tolerance = 0.01 * cpu.voxel_size_m();
    for (index, mesh) in a.blocks() {
        let Some(other) = b.block(*index) else {
            panic!("block {index:?} has a mesh on the CPU only");
        };
        assert_eq!(mesh.triangles, other.triangles, "{index:?}: triangles");
        for (p, q) in mesh.vertices.iter().zip(&other.vertices) {
            let far = p.iter().zip(q).any(|(x, y)| (x - y).abs() > tolerance);
            assert!(!far, "{index:?}: vertex {p:?} against {q:?}");
        }
    }
    sa.triangles
}

/// 2 cm voxels, a 320x240 camera and two oblique poses looking at the sphere before the
/// slanted wall (`sphere_before_slanted_wall`), and a colour image.
fn oblique_scene() -> (FusionParams, CameraModel, [RigidTransform; 2], Rgba8Image) {
    let params = FusionParams {
        voxel_size_m: 0.02,
        ..FusionParams::default()
    };
    let up = DVec3::new(0.1, -1.0, 0.2);
    let target = DVec3::new(0.0, 0.0, 2.0);
    let poses = [
        look_at(DVec3::new(0.7, -0.4, -0.2), target, up),
        look_at(DVec3::new(-0.3, 0.2, 0.1), target, up),
    ];
    (
        params,
        camera(320, 240, 280.0),
        poses,
        red_left_blue_right(320, 240),
    )
}

/// Two frames of a sphere before a slanted wall from two oblique poses, with colour and holes
/// of invalid depth, the second with per-pixel weights (depth and discontinuities): after each, the CPU's and the
/// GPU's grids hold the same blocks with the same voxels, and mesh alike.
#[test]
fn two_frames_integrate_on_the_gpu_as_on_the_cpu() {
    let (context, _one) = gpu();
    let (params, model, poses, colour) = oblique_scene();
    let mut cpu = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
    let mut gpu = GpuTsdf::new(&context.device, &context.queue, params).unwrap();
    let mut mirror = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
    let mut reads = Vec::new();
    for (i, pose) in poses.iter().enumerate() {
        let mut depth = sphere_before_slanted_wall(&model, pose);
        // Invalid pixels (NaN) beside valid ones, a band and scattered: the device reads the
        // CPU's samples as they are and must take their NaNs for invalid (no depth, no weight).
        let width = depth.width as usize;
        for (p, d) in depth.data.iter_mut().enumerate() {
            let (x, y) = (p % width, p / width);
            if (100..106).contains(&x) || (x * 7 + y * 13) % 29 == 0 {
                *d = f32::NAN;
            }
        }
        let weighting = Weighting {
            depth_power: 2.0,
            edge_ratio: Some(0.05),
            ..Weighting::EQUAL
        };
        let weights = (i == 1).then(|| observation_weights(&depth, None, None, &weighting));
        let a = integrate_weighted(
            &mut cpu,
            &params,
            &depth,
            weights.as_ref(),
            Some(&colour),
            &model,
            pose,
        )
        .unwrap();
        let b = gpu
            .integrate(&view(&depth, Some(&colour), &model, pose), weights.as_ref())
            .unwrap();
        let what = format!("frame {i}");
        assert_same_stats(&what, &a, &b);
        assert_eq!(gpu.changed_blocks().len(), b.blocks_updated);
        let read = gpu.read_grid().unwrap();
        let d = compare_grids(&cpu, &read);
        eprintln!("{what}: {d:?}");
        assert_close(&what, &d);
        // The incremental copy holds what the whole read does.
        let copied = gpu.sync_into(&mut mirror).unwrap();
        assert!(copied > 0 && gpu.changed_blocks().is_empty());
        let again = compare_grids(&read, &mirror);
        assert_eq!((again.observed, again.values), (0, 0));
        reads.push(read);
    }
    assert!(cpu.block_count() > 1000, "{} blocks", cpu.block_count());
    // Many voxels were observed in both frames: the second frame's running average met the
    // first's.
    let (first, read) = (&reads[0], &reads[1]);
    let mut twice = 0;
    for (index, block) in first.blocks() {
        let Some(later) = read.block(*index) else {
            continue;
        };
        for offset in 0..VOXELS_PER_BLOCK {
            let (a, b) = (block.voxel_at_offset(offset), later.voxel_at_offset(offset));
            twice += usize::from(a.is_observed() && b.weight > a.weight);
        }
    }
    assert!(twice > 10_000, "{twice} voxels seen twice");
    let triangles = assert_same_mesh(&cpu, read);
    assert!(triangles > 10_000, "{triangles} triangles");
}

/// Each block's mesh made on the device against the CPU's of the same voxels: the same
/// vertices in the same order (positions within a thousandth of a voxel; colours equal, or a
/// level apart where a device's fused multiply-add rounds a half the other way, counted in
/// `off_by_one`) and the same triangles.
fn assert_meshes_equal(cpu: &BlockMesh, gpu: &BlockMesh, what: &str, voxel_m: f32) -> usize {
    assert_eq!(cpu.triangles, gpu.triangles, "{what}: triangles");
    assert_eq!(cpu.vertices.len(), gpu.vertices.len(), "{what}: vertices");
    for (p, q) in cpu.vertices.iter().zip(&gpu.vertices) {
        let far = p.iter().zip(q).any(|(x, y)| (x - y).abs() > 1e-3 * voxel_m);
        assert!(!far, "{what}: vertex {p:?} against {q:?}");
    }
    let mut off_by_one = 0;
    for (a, b) in cpu.colours.iter().zip(&gpu.colours) {
        let worst = a.iter().zip(b).map(|(x, y)| x.abs_diff(*y)).max();
        assert!(worst <= Some(1), "{what}: colour {a:?} against {b:?}");
        off_by_one += usize::from(worst == Some(1));
    }
    off_by_one
}

/// Marching cubes on the device (`GpuTsdf::mesh_blocks`) is the CPU's: two frames of the
/// sphere before a slanted wall with colour; after each, every block meshed on both from the
/// device's voxels gives the same mesh, and a `Mesh` updated with the GPU's meshes (only the
/// blocks the frame changed and those below them) holds what one updated on the CPU holds.
/// A failing GPU mesher leaves the update to the CPU, and says why.
#[test]
fn the_gpu_meshes_blocks_as_the_cpu_does() {
    let (context, _one) = gpu();
    let (params, model, poses, colour) = oblique_scene();
    let voxel_m = params.voxel_size_m;
    let mut gpu = GpuTsdf::new(&context.device, &context.queue, params).unwrap();
    let mut mirror = VoxelBlockGrid::new(voxel_m).unwrap();
    let (mut on_cpu, mut on_gpu) = (Mesh::new(), Mesh::new());
    for (i, pose) in poses.iter().enumerate() {
        let depth = sphere_before_slanted_wall(&model, pose);
        gpu.integrate(&view(&depth, Some(&colour), &model, pose), None)
            .unwrap();
        gpu.sync_into(&mut mirror).unwrap();
        // Every block, and one that is not in the grid.
        let mut all: Vec<BlockIndex> = mirror.blocks().map(|(index, _)| *index).collect();
        all.sort_unstable();
        all.push(BlockIndex([1000, 1000, 1000]));
        let made = gpu.mesh_blocks(&all).unwrap();
        let mut whole = Mesh::new();
        whole.rebuild(&mirror);
        let (mut surfaces, mut triangles, mut vertices, mut off_by_one) = (0, 0, 0, 0);
        for (index, mesh) in &made {
            let empty = BlockMesh::default();
            let cpu = whole.block(*index).unwrap_or(&empty);
            let what = format!("frame {i}, block {index:?}");
            off_by_one += assert_meshes_equal(cpu, mesh, &what, voxel_m);
            surfaces += usize::from(!mesh.is_empty());
            triangles += mesh.triangles.len();
            vertices += mesh.vertices.len();
        }
        assert!(made.iter().map(|(index, _)| *index).eq(all.iter().copied()));
        assert!(
            surfaces > 100 && triangles > 10_000,
            "{surfaces} blocks, {triangles} triangles"
        );
        // Halves rounded the other way are rare (none on lavapipe).
        assert!(
            off_by_one * 1000 <= vertices,
            "{off_by_one} of {vertices} colours a level off"
        );
        // The incremental update, from the same changes.
        let mut twin = mirror.clone();
        let a = on_cpu.update(&mut twin);
        let (b, error) = on_gpu.update_with(&mut mirror, |todo| gpu.mesh_blocks(todo));
        assert!(error.is_none(), "{error:?}");
        assert_eq!(a, b, "frame {i}");
        assert!(b.blocks_meshed < mirror.block_count() || i == 0, "{b:?}");
        for (index, mesh) in on_cpu.blocks() {
            let other = on_gpu.block(*index).expect("the same blocks with surface");
            assert_meshes_equal(
                mesh,
                other,
                &format!("update {i}, block {index:?}"),
                voxel_m,
            );
        }
    }
    // A mesher that fails: the blocks are meshed on the CPU, and the error comes back.
    let depth = sphere_before_slanted_wall(&model, &poses[0]);
    gpu.integrate(&view(&depth, Some(&colour), &model, &poses[0]), None)
        .unwrap();
    gpu.sync_into(&mut mirror).unwrap();
    let mut twin = mirror.clone();
    let a = on_cpu.update(&mut twin);
    let (b, error) = on_gpu.update_with(&mut mirror, |_| Err("device lost"));
    assert_eq!((a, error), (b, Some("device lost")));
    assert!(a.blocks_meshed > 0);
    for (index, mesh) in on_cpu.blocks() {
        let other = on_gpu.block(*index).expect("the same blocks with surface");
        assert_meshes_equal(mesh, other, &format!("fallback, block {index:?}"), voxel_m);
    }
}

/// Every block's mesh of `a` is `b`'s (the same blocks with a surface).
fn assert_same_meshes(a: &Mesh, b: &Mesh, what: &str, voxel_m: f32) {
    let sorted = |m: &Mesh| {
        let mut v: Vec<BlockIndex> = m.blocks().map(|(index, _)| *index).collect();
        v.sort_unstable();
        v
    };
    let blocks = sorted(a);
    assert_eq!(blocks, sorted(b), "{what}: the blocks with a surface");
    for index in blocks {
        let (Some(x), Some(y)) = (a.block(index), b.block(index)) else {
            unreachable!("{what}: listed above");
        };
        assert_meshes_equal(x, y, &format!("{what}, block {index:?}"), voxel_m);
    }
}

/// A map on a GPU meshes from the device's voxels without copying them to the host: after a
/// depth map its host copy has not seen (its period never comes), the mesh update leaves the
/// copy as it was and its mesh is the CPU's mesh of the device's voxels (read here from a
/// second device map fed the same depth maps). Left for the CPU, the map's mesh is made again
/// from the copy: the surface only the device had goes.
#[test]
fn a_gpu_map_meshes_on_the_device_without_copying_back() {
    let (context, _one) = gpu();
    let (params, model, poses, colour) = oblique_scene();
    let voxel_m = params.voxel_size_m;
    let (device, queue) = (&context.device, &context.queue);
    let mut mapper =
        crate::fusion::Mapper::on_gpu(params, Weighting::EQUAL, device, queue).unwrap();
    mapper.set_mirror_period(std::time::Duration::MAX);
    let mut twin = GpuTsdf::new(device, queue, params).unwrap();
    let depths = poses.map(|pose| sphere_before_slanted_wall(&model, &pose));
    let views: Vec<DepthView<'_>> = depths
        .iter()
        .zip(&poses)
        .map(|(depth, pose)| view(depth, Some(&colour), &model, pose))
        .collect();
    // The first depth map is copied to the host at once; the second is not.
    mapper.integrate(&views[0]).unwrap();
    twin.integrate(&views[0], None).unwrap();
    let first = mapper.update_mesh();
    assert!(
        first.blocks_meshed > 0 && first.triangles > 10_000,
        "{first:?}"
    );
    let copy = mapper.grid().clone();
    mapper.integrate(&views[1]).unwrap();
    twin.integrate(&views[1], None).unwrap();
    let second = mapper.update_mesh();
    assert!(mapper.take_gpu_error().is_none());
    assert!(second.blocks_meshed > 0, "{second:?}");
    // Nothing copied back: the host copy is the first depth map's.
    assert_eq!(mapper.grid().block_count(), copy.block_count());
    assert!(
        mapper.block_count() > copy.block_count(),
        "the second view adds blocks"
    );
    for (index, block) in copy.blocks() {
        let mine = mapper.grid().block(*index).expect("the copy's blocks");
        for offset in 0..VOXELS_PER_BLOCK {
            assert_eq!(block.voxel_at_offset(offset), mine.voxel_at_offset(offset));
        }
    }
    // The mesh is the device's voxels' (both depth maps), not the copy's.
    let (mut from_device, mut from_copy) = (Mesh::new(), Mesh::new());
    from_device.rebuild(&twin.read_grid().unwrap());
    from_copy.rebuild(&copy);
    assert!(from_device.triangle_count() != from_copy.triangle_count());
    assert_same_meshes(mapper.mesh(), &from_device, "on the device", voxel_m);
    // Left for the CPU: the copy's mesh, and every block that changed is dirty.
    mapper.mesh_mut().take_dirty();
    assert!(mapper.leave_gpu() && !mapper.is_on_gpu());
    assert_same_meshes(mapper.mesh(), &from_copy, "after leaving the GPU", voxel_m);
    let dirty = mapper.mesh_mut().take_dirty();
    let gone = from_device
        .blocks()
        .filter(|(index, _)| from_copy.block(**index).is_none())
        .count();
    assert!(
        gone > 0 && dirty.len() >= gone,
        "{} dirty, {gone} gone",
        dirty.len()
    );
}

/// A grid made on the CPU goes onto a device as it is (`GpuTsdf::from_grid`, how a map that
/// left a lost device goes onto a new one): the same blocks and every voxel bit for bit, the
/// CPU's meshes; a depth map integrated after on both leaves them alike, and a grid of
/// another voxel size is refused.
#[test]
fn a_grid_uploaded_to_a_device_holds_the_same_voxels_and_fuses_on() {
    let (context, _one) = gpu();
    let (params, model, poses, colour) = oblique_scene();
    let voxel_m = params.voxel_size_m;
    let mut cpu = VoxelBlockGrid::new(voxel_m).unwrap();
    let depths = poses.map(|pose| sphere_before_slanted_wall(&model, &pose));
    integrate_weighted(
        &mut cpu,
        &params,
        &depths[0],
        None,
        Some(&colour),
        &model,
        &poses[0],
    )
    .unwrap();
    let mut gpu = GpuTsdf::from_grid(&context.device, &context.queue, params, &cpu).unwrap();
    assert_eq!(gpu.block_count(), cpu.block_count());
    assert!(gpu.take_unmeshed().is_empty() && gpu.changed_blocks().is_empty());
    let read = gpu.read_grid().unwrap();
    assert_eq!(read.block_count(), cpu.block_count());
    let mut observed = 0;
    for (index, block) in cpu.blocks() {
        let mine = read.block(*index).expect("every block uploaded");
        for offset in 0..VOXELS_PER_BLOCK {
            let (a, b) = (block.voxel_at_offset(offset), mine.voxel_at_offset(offset));
            assert_eq!(a, b, "{index:?} voxel {offset}");
            observed += usize::from(a.is_observed());
        }
    }
    assert!(observed > 10_000, "{observed} voxels observed");
    let mut all: Vec<BlockIndex> = cpu.blocks().map(|(index, _)| *index).collect();
    all.sort_unstable();
    let mut whole = Mesh::new();
    whole.rebuild(&cpu);
    let mut triangles = 0;
    for (index, mesh) in gpu.mesh_blocks(&all).unwrap() {
        let empty = BlockMesh::default();
        let expected = whole.block(index).unwrap_or(&empty);
        assert_meshes_equal(expected, &mesh, &format!("block {index:?}"), voxel_m);
        triangles += mesh.triangles.len();
    }
    assert!(triangles > 10_000, "{triangles} triangles");
    // The next depth map, on both.
    let a = integrate_weighted(
        &mut cpu,
        &params,
        &depths[1],
        None,
        Some(&colour),
        &model,
        &poses[1],
    )
    .unwrap();
    let b = gpu
        .integrate(&view(&depths[1], Some(&colour), &model, &poses[1]), None)
        .unwrap();
    assert_same_stats("after the upload", &a, &b);
    assert_close(
        "after the upload",
        &compare_grids(&cpu, &gpu.read_grid().unwrap()),
    );
    // Another voxel size.
    let coarse = FusionParams {
        voxel_size_m: 2.0 * voxel_m,
        ..params
    };
    let refused = GpuTsdf::from_grid(&context.device, &context.queue, coarse, &cpu);
    assert!(
        matches!(
            refused,
            Err(GpuFusionError::Fusion(
                FusionError::VoxelSizeMismatch { .. }
            ))
        ),
        "{refused:?}"
    );
}

/// A camera at `at` looking along z, moved off the voxel grid: with the camera on it and this
/// focal length, rows of voxel centres project exactly onto the image's edge (u = -0.5), where
/// rounding decides whether they are seen.
fn off_the_grid(at: DVec3) -> RigidTransform {
    RigidTransform {
        translation: at + DVec3::new(0.0123, -0.0071, 0.0037),
        ..RigidTransform::IDENTITY
    }
}

/// A wall seen again and again with a small weight cap: the capped running averages agree
/// (TSDF, weight and colour count at the cap).
#[test]
fn the_weight_cap_holds_on_the_gpu() {
    let (context, _one) = gpu();
    let params = FusionParams {
        max_weight: 3.0,
        ..FusionParams::default()
    };
    let model = camera(160, 120, 150.0);
    let pose = off_the_grid(DVec3::ZERO);
    // Off the voxel centres' planes (5 cm apart), so that no voxel lies exactly at the truncation
    // distance behind the wall, where rounding decides.
    let near = render_plane(&model, &pose, DVec3::Z, 2.513);
    let far = render_plane(&model, &pose, DVec3::Z, 2.717);
    let colour = red_left_blue_right(160, 120);
    let mut cpu = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
    let mut gpu = GpuTsdf::new(&context.device, &context.queue, params).unwrap();
    for depth in [&near, &near, &near, &near, &far, &far] {
        let a = integrate_weighted(&mut cpu, &params, depth, None, Some(&colour), &model, &pose)
            .unwrap();
        let b = gpu
            .integrate(&view(depth, Some(&colour), &model, &pose), None)
            .unwrap();
        assert_same_stats("wall", &a, &b);
    }
    let read = gpu.read_grid().unwrap();
    assert_close("wall", &compare_grids(&cpu, &read));
    let at_cap = read
        .blocks()
        .flat_map(|(_, b)| (0..VOXELS_PER_BLOCK).map(|o| b.voxel_at_offset(o)))
        .filter(|v| v.weight == 3.0 && v.colour_weight() == 3)
        .count();
    assert!(at_cap > 1000, "{at_cap} voxels at the cap");
    assert_same_mesh(&cpu, &read);
}

/// A plumb_bob camera: the shader projects through `common.wgsl`'s distortion (f32) where the
/// CPU uses `CameraModel::project_within` (f64).
#[test]
fn a_distorted_camera_integrates_on_the_gpu_as_on_the_cpu() {
    let (context, _one) = gpu();
    let params = FusionParams::default();
    let mut model = camera(160, 120, 150.0);
    model.distortion = Distortion::PlumbBob {
        k1: -0.1,
        k2: 0.01,
        p1: 0.001,
        p2: -0.002,
        k3: 0.0,
    };
    let pose = look_at(
        DVec3::new(0.2, 0.1, 0.0),
        DVec3::new(0.0, 0.0, 2.0),
        -DVec3::Y,
    );
    let depth = sphere_before_slanted_wall(&model, &pose);
    let colour = red_left_blue_right(160, 120);
    let mut cpu = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
    let mut gpu = GpuTsdf::new(&context.device, &context.queue, params).unwrap();
    let a = integrate_weighted(
        &mut cpu,
        &params,
        &depth,
        None,
        Some(&colour),
        &model,
        &pose,
    )
    .unwrap();
    let b = gpu
        .integrate(&view(&depth, Some(&colour), &model, &pose), None)
        .unwrap();
    assert_same_stats("distorted", &a, &b);
    let read = gpu.read_grid().unwrap();
    assert_close("distorted", &compare_grids(&cpu, &read));
    assert!(assert_same_mesh(&cpu, &read) > 1000);
}

/// A camera sliding along a wall with a bound on the blocks: the same blocks dropped (and
/// their slots reused, cleared) as on the CPU, and the synchronised grid follows.
#[test]
fn dropped_blocks_leave_and_their_slots_come_back_empty() {
    let (context, _one) = gpu();
    let params = FusionParams {
        max_blocks: 120,
        ..FusionParams::default()
    };
    let model = camera(160, 120, 150.0);
    let mut cpu = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
    let mut gpu = GpuTsdf::new(&context.device, &context.queue, params).unwrap();
    let mut mirror = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
    let mut dropped = 0;
    for i in 0..12 {
        let pose = off_the_grid(DVec3::new(0.5 * f64::from(i), 0.0, 0.0));
        // Off the voxel centres' planes (see the weight cap's test).
        let depth = render_plane(&model, &pose, DVec3::Z, 3.013);
        let a = integrate_weighted(&mut cpu, &params, &depth, None, None, &model, &pose).unwrap();
        let b = gpu
            .integrate(&view(&depth, None, &model, &pose), None)
            .unwrap();
        assert_same_stats(&format!("frame {i}"), &a, &b);
        dropped += b.blocks_dropped;
        gpu.sync_into(&mut mirror).unwrap();
    }
    assert!(dropped > 100, "{dropped} dropped");
    assert!(gpu.block_count() <= 120);
    assert_close("sliding", &compare_grids(&cpu, &gpu.read_grid().unwrap()));
    assert_close("mirror", &compare_grids(&cpu, &mirror));
}

/// A bound below what one frame's band crosses: the device's pool never takes more slots than
/// the bound (the farthest new blocks are never given one), and the blocks kept are the CPU's.
#[test]
fn one_frame_past_the_bound_takes_only_the_slots_it_keeps() {
    let (context, _one) = gpu();
    let params = FusionParams {
        max_blocks: 30,
        ..FusionParams::default()
    };
    let model = camera(160, 120, 150.0);
    let mut cpu = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
    let mut gpu = GpuTsdf::new(&context.device, &context.queue, params).unwrap();
    for i in 0..3 {
        let pose = off_the_grid(DVec3::new(0.7 * f64::from(i), 0.0, 0.0));
        let depth = render_plane(&model, &pose, DVec3::Z, 3.013);
        let a = integrate_weighted(&mut cpu, &params, &depth, None, None, &model, &pose).unwrap();
        let b = gpu
            .integrate(&view(&depth, None, &model, &pose), None)
            .unwrap();
        assert_same_stats(&format!("frame {i}"), &a, &b);
        assert!(b.blocks_dropped > 0, "frame {i}: {b:?}");
        assert!(
            gpu.next_slot as usize <= params.max_blocks,
            "frame {i}: {} slots",
            gpu.next_slot
        );
        assert_eq!(gpu.block_count(), params.max_blocks, "frame {i}");
    }
    assert_close("bounded", &compare_grids(&cpu, &gpu.read_grid().unwrap()));
}

/// Bad input is refused as the CPU refuses it, and a frame that needs more blocks than the
/// adapter's largest buffer holds is refused with the sizes, changing nothing.
#[test]
fn bad_input_and_a_full_pool_are_refused() {
    let (context, _one) = gpu();
    let params = FusionParams::default();
    let model = camera(160, 120, 150.0);
    let pose = RigidTransform::IDENTITY;
    let mut gpu = GpuTsdf::new(&context.device, &context.queue, params).unwrap();
    let small = ImageF32 {
        width: 10,
        height: 10,
        data: vec![1.0; 100],
    };
    let err = gpu
        .integrate(&view(&small, None, &model, &pose), None)
        .unwrap_err();
    assert!(
        matches!(err, GpuFusionError::Fusion(FusionError::ImageSize { .. })),
        "{err}"
    );
    let bad = FusionParams {
        max_weight: f32::NAN,
        ..params
    };
    assert!(GpuTsdf::new(&context.device, &context.queue, bad).is_err());
    assert_eq!(gpu.block_count(), 0);
    // 256 KiB: the samples fit, 32 slots do not hold the wall's blocks.
    let tiny = GpuContext::with_max_storage_binding(256 * 1024).unwrap();
    let mut gpu = GpuTsdf::new(&tiny.device, &tiny.queue, params).unwrap();
    let depth = render_plane(&model, &pose, DVec3::Z, 3.0);
    let err = gpu
        .integrate(&view(&depth, None, &model, &pose), None)
        .unwrap_err();
    assert!(matches!(err, GpuFusionError::PoolFull { .. }), "{err}");
    assert!(err.to_string().contains("262144 bytes"), "{err}");
    assert_eq!(gpu.block_count(), 0);
}

/// `source` parsed and validated by naga, as wgpu does, without an adapter (a failure names
/// `path` and the line).
pub(super) fn validated(source: &str, path: &str) -> naga::Module {
    let module = match naga::front::wgsl::parse_str(source) {
        Ok(module) => module,
        Err(e) => panic!("{}", e.emit_to_string_with_path(source, path)),
    };
    let mut validator = naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::default(),
    );
    if let Err(e) = validator.validate(&module) {
        panic!("{}", e.emit_to_string_with_path(source, path));
    }
    module
}

/// The shader parses and validates (naga, as wgpu does), without an adapter.
#[test]
fn the_shader_validates() {
    let module = validated(SHADER, "shaders/tsdf_integrate.wgsl");
    let entry = module
        .entry_points
        .iter()
        .find(|e| e.name == "integrate")
        .expect("entry point");
    // One invocation per row of eight voxels of a block, one workgroup per block.
    assert_eq!(entry.workgroup_size, [64, 1, 1]);
    // The uniform's size as the host lays it out.
    let params = module
        .types
        .iter()
        .find(|(_, t)| t.name.as_deref() == Some("TsdfParams"))
        .expect("TsdfParams");
    assert_eq!(
        params.1.inner.size(module.to_ctx()) as usize,
        std::mem::size_of::<TsdfUniform>()
    );
}
