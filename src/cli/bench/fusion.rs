//! `sweepdepth bench --fusion`: the TSDF fusion (`crate::fusion`) beside Open3D's
//! `VoxelBlockGrid` on the CPU, on the same 640x480 depth maps in the same run (issue 28).
//!
//! Two frames: an ICL-NUIM living-room pair (frames 0010 and 0015, from `../shared/data` next to
//! the repository, or `--fusion-data`) when present, else a built-in synthetic pair (a textured
//! wall 4 m away with a box in front, two converging cameras 0.4 m apart). Timed, each the median
//! of `repeats` runs after a warm-up, at 2 cm voxels with colour:
//! - `integrate first`: frame 0 into an empty grid;
//! - `integrate steady`: frame 1 into a grid that holds frame 0 (already meshed): the live case;
//! - `mesh`: [`Mapper::update_mesh`](crate::fusion::Mapper::update_mesh) of the blocks that frame 1 changed.
//!
//! With `--device gpu` (or `auto` where a hardware GPU exists) the same three on the device
//! ([`GpuTsdf`]) in the same run: integration on the GPU (it waits for the device), the
//! changed blocks copied to the host ([`GpuTsdf::sync_into`], what the map does every
//! [`crate::fusion::mapper::MIRROR_PERIOD`]) and meshed on the device from the device's own
//! record of what changed ([`GpuTsdf::mesh_blocks`], as `Mapper::update_mesh`), each timed
//! apart.
//!
//! The peer, `tools/open3d_fusion_peer.py`, runs the same two integrations
//! (`compute_unique_block_coordinates` + `integrate`, block resolutions 8 and 16) on the same
//! depth maps, colour and poses, written for it as `.npy` files and JSON into a temporary folder,
//! with a Python that imports `open3d` (`--open3d-python`, `$SWEEPDEPTH_OPEN3D_PYTHON`,
//! `target/test-venv`, `/tmp/o3d`, then `python3`). The ratios are to its faster block
//! resolution. Without Open3D the bench says so and prints its own figures alone.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::Context;
use serde::{Deserialize, Serialize};

use super::{median, round3, BenchArgs};
use crate::datasets::icl_nuim::{parse_povray_camera, povray_camera_model, read_icl_depth};
use crate::engine::Device;
use crate::fusion::{
    DepthView, FusionParams, GpuTsdf, IntegrationStats, Mapper, Mesh, VoxelBlockGrid, Weighting,
};
use crate::geometry::{CameraModel, RigidTransform};
use crate::gpu_context::GpuContext;
use crate::image::{ImageF32, Rgba8Image};
use crate::synthetic::{self, Scene};

/// The voxel size of the bar.
pub const VOXEL_SIZE_M: f32 = 0.02;
/// The ICL-NUIM frames used, in `../shared/data`.
const ICL_FOLDER: &str = "iclnuim_livingroom_traj2_frames";
const ICL_FRAMES: [&str; 2] = ["scene_00_0010", "scene_00_0015"];

/// One depth map with its colour and pose.
pub struct Frame {
    pub depth: ImageF32,
    pub colour: Rgba8Image,
    pub world_from_cam: RigidTransform,
}

impl Frame {
    /// The frame with its colour, as the integrations take it (no confidence, no baseline).
    fn view<'a>(&'a self, model: &'a CameraModel) -> DepthView<'a> {
        DepthView {
            depth: &self.depth,
            confidence: None,
            baseline_ratio: None,
            colour: Some(&self.colour),
            model,
            map_from_cam: &self.world_from_cam,
        }
    }
}

/// The bench's input: where it came from, the camera, two frames.
pub struct FusionBenchInput {
    pub source: String,
    pub model: CameraModel,
    pub frames: [Frame; 2],
}

/// The peer's answer (`tools/open3d_fusion_peer.py`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Open3dResult {
    pub peer: String,
    pub open3d: String,
    pub threads: u32,
    pub runs: u32,
    pub results: Vec<Open3dTiming>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Open3dTiming {
    pub block_resolution: u32,
    pub integrate_first_ms: f64,
    pub integrate_steady_ms: f64,
    pub extract_mesh_ms: f64,
    pub blocks_in_frame: u64,
    pub triangles: u64,
}

/// What the bench measured.
#[derive(Debug, Serialize)]
pub struct FusionBenchResult {
    pub source: String,
    pub width: u32,
    pub height: u32,
    pub voxel_size_m: f32,
    pub truncation_voxels: f32,
    pub threads: usize,
    pub runs: usize,
    pub integrate_first_ms: f64,
    pub integrate_steady_ms: f64,
    /// Re-meshing the blocks frame 1 changed.
    pub mesh_ms: f64,
    pub first: IntegrationStats,
    pub steady: IntegrationStats,
    pub blocks_meshed: usize,
    pub blocks: usize,
    pub memory_mib: f64,
    /// Open3D's faster block resolution, and our ratios to it (None without the peer).
    pub open3d_block_resolution: Option<u32>,
    pub open3d_integrate_first_ms: Option<f64>,
    pub open3d_integrate_steady_ms: Option<f64>,
    pub open3d_extract_mesh_ms: Option<f64>,
    pub first_vs_open3d: Option<f64>,
    pub steady_vs_open3d: Option<f64>,
    /// `mesh_ms / integrate_steady_ms` (the bar: at most 1).
    pub mesh_vs_integrate: f64,
    /// The GPU path (`--device gpu`, or `auto` on a hardware GPU).
    pub gpu: Option<GpuFusionResult>,
}

/// What the bench measured of the GPU path ([`GpuTsdf`]).
#[derive(Debug, Serialize)]
pub struct GpuFusionResult {
    pub adapter: String,
    pub integrate_first_ms: f64,
    pub integrate_steady_ms: f64,
    /// The host's share of the steady integration (the frame's samples, the blocks in view,
    /// the work list, the uploads): its time less the wait for the device.
    pub integrate_steady_host_ms: f64,
    /// The host's share by step (medians): samples (step 0), blocks (step 1), the work list,
    /// uploads and submission.
    pub host_samples_ms: f64,
    pub host_blocks_ms: f64,
    pub host_work_ms: f64,
    pub host_submit_ms: f64,
    /// Frame 1's changed blocks (and those below them) meshed on the device.
    pub mesh_ms: f64,
    /// Frame 1's changed blocks copied to the host (the map's copy for a lost device).
    pub sync_ms: f64,
    pub first: IntegrationStats,
    pub steady: IntegrationStats,
    pub blocks_meshed: usize,
    /// The device's voxel pool.
    pub pool_mib: f64,
}

/// The parameters of the bench (2 cm voxels, the defaults otherwise).
pub fn bench_params() -> FusionParams {
    FusionParams {
        voxel_size_m: VOXEL_SIZE_M,
        ..FusionParams::default()
    }
}

/// The ICL-NUIM pair from `folder` if it is there, else the synthetic pair.
pub fn load_input(data: Option<&Path>) -> anyhow::Result<FusionBenchInput> {
    let folder = match data {
        Some(dir) => dir.to_path_buf(),
        None => Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../shared/data")
            .join(ICL_FOLDER),
    };
    let present = ICL_FRAMES
        .iter()
        .all(|stem| folder.join(format!("{stem}.depth")).is_file());
    if present {
        return load_icl(&folder).with_context(|| format!("ICL-NUIM in {}", folder.display()));
    }
    if data.is_some() {
        anyhow::bail!(
            "{} lacks the ICL-NUIM frames {}",
            folder.display(),
            ICL_FRAMES.join(", ")
        );
    }
    load_synthetic()
}

fn load_icl(folder: &Path) -> anyhow::Result<FusionBenchInput> {
    let mut frames = Vec::new();
    let mut first_model = None;
    for stem in ICL_FRAMES {
        let txt = folder.join(format!("{stem}.txt"));
        let text = std::fs::read_to_string(&txt).with_context(|| txt.display().to_string())?;
        let camera = parse_povray_camera(&txt, &text)?;
        let colour = crate::io::load_rgba8(&folder.join(format!("{stem}.png")))?;
        let (model, cam_from_world) =
            povray_camera_model(&txt, &camera, colour.width, colour.height)?;
        let depth = read_icl_depth(&folder.join(format!("{stem}.depth")), &model.intrinsics)?;
        let (model, depth, colour) = upright(model, depth, colour);
        first_model.get_or_insert(model);
        frames.push(Frame {
            depth,
            colour,
            world_from_cam: cam_from_world.inverse(),
        });
    }
    let model = first_model.context("no frame")?;
    let frames: [Frame; 2] = frames
        .try_into()
        .map_err(|_| anyhow::anyhow!("two frames expected"))?;
    Ok(FusionBenchInput {
        source: format!(
            "ICL-NUIM living room traj2 {} then {} ({})",
            ICL_FRAMES[0], ICL_FRAMES[1], ICL_FOLDER
        ),
        model,
        frames,
    })
}

/// ICL-NUIM's POV-Ray camera has a negative fy (its y axis points up): the same camera with
/// its rows flipped has a positive fy and the same pose, which is what Open3D expects.
fn upright(
    mut model: CameraModel,
    mut depth: ImageF32,
    mut colour: Rgba8Image,
) -> (CameraModel, ImageF32, Rgba8Image) {
    let k = &mut model.intrinsics;
    if k.fy_px >= 0.0 {
        return (model, depth, colour);
    }
    k.fy_px = -k.fy_px;
    k.cy_px = f64::from(k.height_px) - 1.0 - k.cy_px;
    let width = depth.width as usize;
    depth.data = flip_rows(&depth.data, width);
    colour.pixels = flip_rows(&colour.pixels, width);
    (model, depth, colour)
}

fn flip_rows<T: Copy>(data: &[T], width: usize) -> Vec<T> {
    data.chunks_exact(width).rev().flatten().copied().collect()
}

fn load_synthetic() -> anyhow::Result<FusionBenchInput> {
    let model = CameraModel::pinhole(synthetic::intrinsics(640, 480));
    let rig = synthetic::arc_rig(2, 0.105, 4.0, model, 0)?;
    let scene = Scene::wall_and_box(4.0, Some((2.0, 0.4)), model.intrinsics.fx_px);
    let frames: Vec<Frame> = rig
        .cameras
        .iter()
        .map(|camera| Frame {
            depth: scene.depth(&camera.model, &camera.cam_from_rig),
            colour: scene.render(camera),
            world_from_cam: camera.cam_from_rig.inverse(),
        })
        .collect();
    let frames: [Frame; 2] = frames
        .try_into()
        .map_err(|_| anyhow::anyhow!("two frames expected"))?;
    Ok(FusionBenchInput {
        source: "synthetic (built in): a textured wall at 4 m and a box at 2 m, two converging \
                 cameras 0.4 m apart (no ../shared/data ICL-NUIM frames found)"
            .to_string(),
        model,
        frames,
    })
}

/// Times our integration and meshing on `input`.
pub fn time_ours(
    input: &FusionBenchInput,
    params: &FusionParams,
    repeats: usize,
) -> anyhow::Result<FusionBenchResult> {
    let [a, b] = &input.frames;
    let model = &input.model;
    let run = |mapper: &mut Mapper, frame: &Frame| mapper.integrate(&frame.view(model));
    let new_map = || Mapper::new(*params, Weighting::EQUAL);
    let (mut first_ms, mut steady_ms, mut mesh_ms) = (Vec::new(), Vec::new(), Vec::new());
    let (mut first, mut last) = (None, None);
    for i in 0..=repeats.max(1) {
        let mut mapper = new_map()?;
        let started = Instant::now();
        let first_stats = run(&mut mapper, a)?;
        let first_elapsed = started.elapsed();
        first.get_or_insert(first_stats);
        // The steady state's starting point: frame 0 integrated and meshed.
        mapper.update_mesh();

        let started = Instant::now();
        let steady = run(&mut mapper, b)?;
        let steady_elapsed = started.elapsed();
        let started = Instant::now();
        let stats = mapper.update_mesh();
        let mesh_elapsed = started.elapsed();
        if i > 0 {
            first_ms.push(first_elapsed.as_secs_f64() * 1e3);
            steady_ms.push(steady_elapsed.as_secs_f64() * 1e3);
            mesh_ms.push(mesh_elapsed.as_secs_f64() * 1e3);
        }
        let grid = mapper.grid();
        last = Some((
            steady,
            stats.blocks_meshed,
            grid.block_count(),
            grid.memory_bytes(),
        ));
    }
    let (steady, blocks_meshed, blocks, memory) = last.context("no run")?;
    let first = first.context("no run")?;
    let (integrate_steady_ms, mesh_ms) = (median(steady_ms), median(mesh_ms));
    Ok(FusionBenchResult {
        source: input.source.clone(),
        width: model.intrinsics.width_px,
        height: model.intrinsics.height_px,
        voxel_size_m: params.voxel_size_m,
        truncation_voxels: params.truncation_voxels,
        threads: rayon::current_num_threads(),
        runs: repeats.max(1),
        integrate_first_ms: round3(median(first_ms)),
        integrate_steady_ms: round3(integrate_steady_ms),
        mesh_ms: round3(mesh_ms),
        first,
        steady,
        blocks_meshed,
        blocks,
        memory_mib: round3(memory as f64 / (1024.0 * 1024.0)),
        open3d_block_resolution: None,
        open3d_integrate_first_ms: None,
        open3d_integrate_steady_ms: None,
        open3d_extract_mesh_ms: None,
        first_vs_open3d: None,
        steady_vs_open3d: None,
        mesh_vs_integrate: round3(mesh_ms / integrate_steady_ms),
        gpu: None,
    })
}

/// The device the GPU path runs on: none for `--device cpu`, wgpu's adapter (lavapipe
/// without a GPU) for `gpu`, a hardware GPU if there is one for `auto`.
fn fusion_gpu(device: Device) -> anyhow::Result<Option<GpuContext>> {
    Ok(match device {
        Device::Cpu => None,
        Device::Gpu => Some(GpuContext::new()?),
        Device::Auto => crate::engine::hardware_gpu(),
    })
}

/// Times the GPU path on `input`: as [`time_ours`], a fresh [`GpuTsdf`] per run (a grid on
/// the device cannot be cloned: the steady state's frame 0 is integrated again, untimed).
pub fn time_gpu(
    gpu: &GpuContext,
    input: &FusionBenchInput,
    params: &FusionParams,
    repeats: usize,
) -> anyhow::Result<GpuFusionResult> {
    let [a, b] = &input.frames;
    let model = &input.model;
    let run = |tsdf: &mut GpuTsdf, frame: &Frame| tsdf.integrate(&frame.view(model), None);
    let (mut first_ms, mut steady_ms, mut mesh_ms) = (Vec::new(), Vec::new(), Vec::new());
    let (mut sync_ms, mut host_ms) = (Vec::new(), Vec::new());
    let mut host_steps: [Vec<f64>; 4] = Default::default();
    let mut last = None;
    for i in 0..=repeats.max(1) {
        let mut empty = GpuTsdf::new(&gpu.device, &gpu.queue, *params)?;
        let started = Instant::now();
        let first = run(&mut empty, a)?;
        let first_elapsed = started.elapsed();
        drop(empty);

        // Frame 0 integrated and meshed, then frame 1: integrated, its blocks copied to the
        // host (what the map keeps every `MIRROR_PERIOD`), meshed on the device.
        let mut tsdf = GpuTsdf::new(&gpu.device, &gpu.queue, *params)?;
        let mut grid = VoxelBlockGrid::new(params.voxel_size_m)?;
        let mut mesh = Mesh::new();
        let update_mesh =
            |tsdf: &mut GpuTsdf, mesh: &mut Mesh| tsdf.update_mesh(mesh).map_err(|(_, e)| e);
        run(&mut tsdf, a)?;
        tsdf.sync_into(&mut grid)?;
        update_mesh(&mut tsdf, &mut mesh)?;
        let started = Instant::now();
        let steady = run(&mut tsdf, b)?;
        let steady_elapsed = started.elapsed();
        let times = tsdf.last_times();
        let started = Instant::now();
        tsdf.sync_into(&mut grid)?;
        let sync_elapsed = started.elapsed();
        let started = Instant::now();
        let stats = update_mesh(&mut tsdf, &mut mesh)?;
        let mesh_elapsed = started.elapsed();
        if i > 0 {
            first_ms.push(first_elapsed.as_secs_f64() * 1e3);
            steady_ms.push(steady_elapsed.as_secs_f64() * 1e3);
            host_ms.push(steady_elapsed.saturating_sub(times.wait).as_secs_f64() * 1e3);
            let steps = [times.samples, times.blocks, times.work, times.submit];
            for (v, step) in host_steps.iter_mut().zip(steps) {
                v.push(step.as_secs_f64() * 1e3);
            }
            sync_ms.push(sync_elapsed.as_secs_f64() * 1e3);
            mesh_ms.push(mesh_elapsed.as_secs_f64() * 1e3);
        }
        last = Some((first, steady, stats.blocks_meshed, tsdf.pool_bytes()));
    }
    let (first, steady, blocks_meshed, pool) = last.context("no run")?;
    let [samples_ms, blocks_ms, work_ms, submit_ms] = host_steps.map(|v| round3(median(v)));
    Ok(GpuFusionResult {
        adapter: gpu.adapter_label(),
        integrate_first_ms: round3(median(first_ms)),
        integrate_steady_ms: round3(median(steady_ms)),
        integrate_steady_host_ms: round3(median(host_ms)),
        host_samples_ms: samples_ms,
        host_blocks_ms: blocks_ms,
        host_work_ms: work_ms,
        host_submit_ms: submit_ms,
        mesh_ms: round3(median(mesh_ms)),
        sync_ms: round3(median(sync_ms)),
        first,
        steady,
        blocks_meshed,
        pool_mib: round3(pool as f64 / (1024.0 * 1024.0)),
    })
}

/// A Python that imports open3d: `explicit`, `$SWEEPDEPTH_OPEN3D_PYTHON`, the test venv,
/// `/tmp/o3d` (the venv docs/speed.md makes), `python3`.
fn open3d_python(explicit: Option<&Path>) -> Option<PathBuf> {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let candidates: Vec<PathBuf> = match explicit {
        Some(p) => vec![p.to_path_buf()],
        None => std::env::var_os("SWEEPDEPTH_OPEN3D_PYTHON")
            .map(PathBuf::from)
            .into_iter()
            .chain([
                repo.join("target/test-venv/bin/python"),
                PathBuf::from("/tmp/o3d/bin/python"),
                PathBuf::from("python3"),
            ])
            .collect(),
    };
    candidates.into_iter().find(|python| {
        Command::new(python)
            .args(["-c", "import open3d"])
            .output()
            .map(|o| o.status.success())
            .unwrap_or(false)
    })
}

/// How to get the peer, for the message when it is missing.
pub const OPEN3D_INSTALL: &str = "python3 -m venv /tmp/o3d && /tmp/o3d/bin/pip install \
     open3d-cpu (then this bench finds /tmp/o3d, or pass --open3d-python PY or set \
     SWEEPDEPTH_OPEN3D_PYTHON)";

/// A NumPy `.npy` file (format 1.0, C order) of `shape` with the given dtype and raw bytes.
fn write_npy(path: &Path, dtype: &str, shape: &[usize], bytes: &[u8]) -> anyhow::Result<()> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let mut header = format!(
        "{{'descr': '{dtype}', 'fortran_order': False, 'shape': ({},), }}",
        dims.join(", ")
    );
    // Magic (6) + version (2) + length (2) + header + '\n', padded to a multiple of 64.
    let unpadded = 10 + header.len() + 1;
    header.push_str(&" ".repeat(unpadded.next_multiple_of(64) - unpadded));
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + bytes.len());
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&u16::try_from(header.len())?.to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out.extend_from_slice(bytes);
    std::fs::write(path, out).with_context(|| path.display().to_string())
}

/// Writes the input for the peer into `dir`.
fn write_peer_input(
    dir: &Path,
    input: &FusionBenchInput,
    params: &FusionParams,
) -> anyhow::Result<()> {
    let k = &input.model.intrinsics;
    let (w, h) = (k.width_px as usize, k.height_px as usize);
    let mut frames = Vec::new();
    for (i, frame) in input.frames.iter().enumerate() {
        // Open3D reads 0 as invalid; our invalid values are NaN (and out-of-range ones, which
        // both sides drop by their depth limits).
        let depth: Vec<u8> = frame
            .depth
            .data
            .iter()
            .flat_map(|d| (if d.is_finite() { *d } else { 0.0 }).to_le_bytes())
            .collect();
        write_npy(&dir.join(format!("depth_{i}.npy")), "<f4", &[h, w], &depth)?;
        let rgb: Vec<u8> = frame
            .colour
            .pixels
            .iter()
            .flat_map(|p| {
                let [r, g, b, _] = Rgba8Image::unpack(*p);
                [r, g, b]
            })
            .collect();
        write_npy(
            &dir.join(format!("colour_{i}.npy")),
            "|u1",
            &[h, w, 3],
            &rgb,
        )?;
        let cam_from_world = frame.world_from_cam.inverse();
        let r = cam_from_world.rotation_matrix();
        let t = cam_from_world.translation;
        let rows: Vec<[f64; 4]> = (0..3)
            .map(|i| [r.col(0)[i], r.col(1)[i], r.col(2)[i], t[i]])
            .chain([[0.0, 0.0, 0.0, 1.0]])
            .collect();
        frames.push(serde_json::json!({ "cam_from_world": rows }));
    }
    let spec = serde_json::json!({
        "intrinsic": [[k.fx_px, 0.0, k.cx_px], [0.0, k.fy_px, k.cy_px], [0.0, 0.0, 1.0]],
        "frames": frames,
        "voxel_size_m": params.voxel_size_m,
        "truncation_voxels": params.truncation_voxels,
        "max_depth_m": params.max_depth_m,
    });
    let path = dir.join("frames.json");
    std::fs::write(&path, serde_json::to_vec(&spec)?).with_context(|| path.display().to_string())
}

/// Times Open3D on `input`, or says why it could not.
pub fn run_open3d(
    explicit_python: Option<&Path>,
    input: &FusionBenchInput,
    params: &FusionParams,
    repeats: usize,
) -> Result<Open3dResult, String> {
    let python = open3d_python(explicit_python)
        .ok_or_else(|| format!("Open3D not installed: {OPEN3D_INSTALL}"))?;
    let dir = std::env::temp_dir().join(format!("sweepdepth-fusion-peer-{}", std::process::id()));
    let outcome = (|| {
        std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        write_peer_input(&dir, input, params).map_err(|e| format!("{e:#}"))?;
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/open3d_fusion_peer.py");
        let output = Command::new(&python)
            .arg(&script)
            .arg(&dir)
            .args(["--repeats", &repeats.max(1).to_string()])
            .output()
            .map_err(|e| format!("running {}: {e}", python.display()))?;
        if !output.status.success() {
            return Err(format!(
                "{} {} failed: {}",
                python.display(),
                script.display(),
                String::from_utf8_lossy(&output.stderr).trim()
            ));
        }
        serde_json::from_slice(&output.stdout).map_err(|e| format!("the peer's output: {e}"))
    })();
    let _ = std::fs::remove_dir_all(&dir);
    outcome
}

/// `bench --fusion`.
pub fn run(args: &BenchArgs) -> anyhow::Result<()> {
    let repeats = if args.quick { 3 } else { args.repeats };
    let params = bench_params();
    let input = load_input(args.fusion_data.as_deref())?;
    let peer = run_open3d(args.open3d_python.as_deref(), &input, &params, repeats);
    let mut result = time_ours(&input, &params, repeats)?;
    if let Some(gpu) = fusion_gpu(args.device)? {
        result.gpu = Some(time_gpu(&gpu, &input, &params, repeats)?);
    }
    if let Ok(peer) = &peer {
        let best = peer
            .results
            .iter()
            .min_by(|a, b| a.integrate_steady_ms.total_cmp(&b.integrate_steady_ms));
        if let Some(best) = best {
            result.open3d_block_resolution = Some(best.block_resolution);
            result.open3d_integrate_first_ms = Some(round3(best.integrate_first_ms));
            result.open3d_integrate_steady_ms = Some(round3(best.integrate_steady_ms));
            result.open3d_extract_mesh_ms = Some(round3(best.extract_mesh_ms));
            result.first_vs_open3d =
                Some(round3(result.integrate_first_ms / best.integrate_first_ms));
            result.steady_vs_open3d = Some(round3(
                result.integrate_steady_ms / best.integrate_steady_ms,
            ));
        }
    }
    if args.json {
        match &peer {
            Ok(p) => println!("{}", serde_json::to_string(p)?),
            Err(reason) => println!("{}", serde_json::json!({ "peer_missing": reason })),
        }
        println!("{}", serde_json::to_string(&result)?);
        return Ok(());
    }
    println!("fusion input: {}", result.source);
    println!(
        "{}x{}, {} m voxels, truncation {} voxels, colour, {} threads, median of {} runs",
        result.width,
        result.height,
        result.voxel_size_m,
        result.truncation_voxels,
        result.threads,
        result.runs
    );
    match &peer {
        Ok(p) => {
            println!("peer: {} {} ({} cores)", p.peer, p.open3d, p.threads);
            for t in &p.results {
                println!(
                    "  Open3D block_resolution {:>2}: integrate first {:.1} ms, steady {:.1} ms, \
                     extract_triangle_mesh (whole grid) {:.1} ms ({} blocks in frame 1, {} \
                     triangles)",
                    t.block_resolution,
                    t.integrate_first_ms,
                    t.integrate_steady_ms,
                    t.extract_mesh_ms,
                    t.blocks_in_frame,
                    t.triangles
                );
            }
        }
        Err(reason) => println!("peer: {reason}; our figures alone"),
    }
    let ratio = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.2}x Open3D"));
    println!(
        "sweepdepth integrate first:  {:.1} ms ({}; {} blocks allocated)",
        result.integrate_first_ms,
        ratio(result.first_vs_open3d),
        result.first.blocks_allocated
    );
    println!(
        "sweepdepth integrate steady: {:.1} ms ({}; {} blocks in view, {} new, {} voxels updated)",
        result.integrate_steady_ms,
        ratio(result.steady_vs_open3d),
        result.steady.blocks_in_view,
        result.steady.blocks_allocated,
        result.steady.voxels_updated
    );
    println!(
        "sweepdepth mesh update:      {:.1} ms ({} blocks re-meshed; {:.2}x the steady \
         integration)",
        result.mesh_ms, result.blocks_meshed, result.mesh_vs_integrate
    );
    println!(
        "grid: {} blocks, {:.1} MiB",
        result.blocks, result.memory_mib
    );
    if let Some(gpu) = &result.gpu {
        print_gpu(gpu);
    }
    Ok(())
}

/// The GPU path's rows.
fn print_gpu(gpu: &GpuFusionResult) {
    println!("GPU: {}", gpu.adapter);
    println!(
        "sweepdepth GPU integrate first:  {:.1} ms ({} blocks allocated)",
        gpu.integrate_first_ms, gpu.first.blocks_allocated
    );
    println!(
        "sweepdepth GPU integrate steady: {:.1} ms, the host's share {:.1} ({} blocks in view, {} new, {} voxels updated)",
        gpu.integrate_steady_ms,
        gpu.integrate_steady_host_ms,
        gpu.steady.blocks_in_view,
        gpu.steady.blocks_allocated,
        gpu.steady.voxels_updated
    );
    println!(
        "  the host's share by step: samples {:.2} ms, blocks {:.2}, work list {:.2}, uploads and submission {:.2}",
        gpu.host_samples_ms, gpu.host_blocks_ms, gpu.host_work_ms, gpu.host_submit_ms
    );
    println!(
        "sweepdepth GPU blocks to host:   {:.1} ms (frame 1's changed blocks copied back, as once a second)",
        gpu.sync_ms
    );
    println!(
        "sweepdepth GPU mesh update:      {:.1} ms ({} blocks re-meshed on the device)",
        gpu.mesh_ms, gpu.blocks_meshed
    );
    println!("GPU voxel pool: {:.1} MiB", gpu.pool_mib);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `bench --fusion --device gpu`'s GPU rows on the built-in pair (lavapipe in CI): the GPU
    /// path runs beside the CPU's and does the same work (blocks and voxels updated, blocks
    /// re-meshed). Only the counts are compared, never the times.
    #[test]
    fn the_gpu_rows_do_the_cpus_work() {
        let input = load_synthetic().unwrap();
        let params = bench_params();
        let cpu = time_ours(&input, &params, 1).unwrap();
        let gpu = match fusion_gpu(Device::Gpu) {
            Ok(Some(gpu)) => gpu,
            Ok(None) => unreachable!("--device gpu always asks wgpu"),
            Err(e) => panic!("GPU tests need an adapter (lavapipe is fine): {e}"),
        };
        let result = time_gpu(&gpu, &input, &params, 1).unwrap();
        let counts = |s: &IntegrationStats| {
            (
                s.pixels_valid,
                s.blocks_allocated,
                s.blocks_in_view,
                s.blocks_updated,
            )
        };
        assert_eq!(counts(&result.first), counts(&cpu.first));
        assert_eq!(counts(&result.steady), counts(&cpu.steady));
        assert!(
            result
                .steady
                .voxels_updated
                .abs_diff(cpu.steady.voxels_updated)
                <= 10
        );
        assert_eq!(result.blocks_meshed, cpu.blocks_meshed);
        assert!(result.first.blocks_allocated > 500 && result.pool_mib > 0.0);
        // The host's share is the integration less its wait for the device, which is never
        // nothing (the shader's work and the counts' readback).
        let (host, all) = (result.integrate_steady_host_ms, result.integrate_steady_ms);
        assert!(host > 0.0 && host < all, "host {host} ms of {all} ms");
        // Its steps are parts of it (one run: their sum at most the whole, to rounding), and
        // steps 0 and 1 do work on every pixel.
        let steps = [
            result.host_samples_ms,
            result.host_blocks_ms,
            result.host_work_ms,
            result.host_submit_ms,
        ];
        let sum: f64 = steps.iter().sum();
        assert!(
            steps.iter().all(|&s| s >= 0.0) && sum <= host + 0.01,
            "{steps:?} of {host}"
        );
        assert!(steps[0] > 0.0 && steps[1] > 0.0, "{steps:?}");
        assert!(fusion_gpu(Device::Cpu).unwrap().is_none());
    }
}
