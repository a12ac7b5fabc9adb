//! `sweepdepth bench`: how fast, compared to what. In one run: the CPU engine and the WGSL
//! engine (on the wgpu adapter, lavapipe without a GPU) on the paper's configuration,
//! 640x480x64, 1280x960x128, a 9-camera 450x375x57 rig (one reference, and three references per
//! set: `references`) and the demo's Tsukuba set, each with
//! winner-take-all and SGM; and the peer, OpenCV StereoSGBM 3-way on two Tsukuba views with 32
//! disparities (`tools/sgbm_baseline.py --time`), with every configuration's ratio to it: the
//! peer is timed again after each configuration, and a ratio divides by the mean of the peer's
//! times just before and after it (`peer ms`), so load that moves during a long bench moves
//! both sides alike.
//! After the table, what decoding a 9-camera 640x480 JPEG set costs ([`decode`]), beside each
//! engine's 9-camera set of the same run, and the node's own host work per set at 1 MP
//! ([`messages`]: image messages in, depth and confidence messages out).
//! `bench --fusion` ([`fusion`]): the TSDF fusion beside Open3D's `VoxelBlockGrid`;
//! `bench --maps-out` ([`maps_out`]): a 1-MP set's maps into messages, copied out or lent.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::Context;
use serde::Serialize;

use crate::engine::{Device, Engine, Sweeper};
use crate::geometry::{CameraModel, Rig};
use crate::image::Rgba8Image;
use crate::params::{EngineOptions, ParamValue};
use crate::sweep::{Cost, Optimizer, Prefilter, Scoring, SweepParams, WantedMaps, WindowMode};
use crate::synthetic::{self, Scene};

mod configs;
pub mod decode;
pub mod fusion;
mod gpu_layout;
pub mod maps_out;
pub mod messages;
mod streamed;

pub use configs::{BenchConfig, PeerKind, Workload, CONFIGS};
pub use gpu_layout::GpuLayout;

#[derive(Debug, clap::Args)]
pub struct BenchArgs {
    /// One JSON object per line: the peer, then one per engine and configuration.
    #[arg(long)]
    pub json: bool,
    /// Timed runs per configuration (after one warm-up run); the median is reported.
    #[arg(long, default_value_t = 7, value_parser = at_least_one)]
    pub repeats: usize,
    /// A short run: the paper's configuration and the demo's set only, 3 timed runs each.
    #[arg(long)]
    pub quick: bool,
    /// Only these configurations (repeatable): paper, demo, 9-camera, 9-camera-near4,
    /// 9-camera-3refs, 9-camera-3refs-near4, vga, ring, ring-distorted, sxga, stereo-rect,
    /// stereo-raw, dome-8, dome-32.
    #[arg(long = "config", value_name = "NAME")]
    pub configs: Vec<String>,
    /// Python with OpenCV for the peer (default: target/test-venv, then python3).
    #[arg(long)]
    pub python: Option<PathBuf>,
    /// Which engines are timed: both (auto, the default), the WGSL engine on the wgpu
    /// adapter (gpu) or the CPU engine (cpu).
    #[arg(long, value_enum, default_value_t = crate::engine::Device::Auto)]
    pub device: crate::engine::Device,
    /// Time the TSDF fusion instead (integrate and mesh one 640x480 depth map at 2 cm voxels)
    /// beside Open3D's VoxelBlockGrid in the same run (`src/cli/bench/fusion.rs`).
    #[arg(long)]
    pub fusion: bool,
    /// Python with `open3d` for the fusion peer (default: $SWEEPDEPTH_OPEN3D_PYTHON,
    /// target/test-venv, /tmp/o3d, then python3).
    #[arg(long, value_name = "PY")]
    pub open3d_python: Option<PathBuf>,
    /// The ICL-NUIM frames for `--fusion` (default: ../shared/data's living room; without it, a
    /// built-in synthetic pair).
    #[arg(long, value_name = "DIR")]
    pub fusion_data: Option<PathBuf>,
    /// How the WGSL engine lays its work out, to compare the ways on a GPU.
    #[command(flatten)]
    pub gpu: GpuLayout,
    /// The timed sets back to back with N sets left on the WGSL engine's device while the one
    /// before is read back (as `bag` runs them): ms per set of the stream (default 0: each set
    /// alone, start to end).
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub sets_ahead: usize,
    /// The WGSL engine reads back depth and confidence alone, as for the node while nobody
    /// subscribes to its cost and selection images (default: those too, as `bag` writes them).
    #[arg(long)]
    pub depth_only: bool,
    /// Only the maps-out line: a 1-MP set's depth and confidence to messages, copied or lent.
    #[arg(long)]
    pub maps_out: bool,
    /// Engine options applied to every configuration (window, scoring, ...).
    #[command(flatten)]
    pub params: EngineOptions,
}

/// The peer's timing (`tools/sgbm_baseline.py --time --json`).
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct PeerResult {
    pub peer: String,
    pub opencv: String,
    pub threads: u32,
    pub pair: String,
    pub width: u32,
    pub height: u32,
    pub num_disparities: u32,
    pub runs: u32,
    pub ms_median: f64,
    pub ms_min: f64,
}

#[derive(Debug, Serialize)]
pub struct BenchResult {
    pub config: &'static str,
    pub engine: String,
    pub cameras: usize,
    pub width: u32,
    pub height: u32,
    pub planes: u32,
    pub settings: String,
    /// Winner-take-all: median ms per frame set, hypotheses (pixels x planes) per second.
    pub wta_ms: Option<f64>,
    pub wta_hypotheses_per_s: Option<f64>,
    /// SGM (`sgm_paths` directions).
    pub sgm_ms: Option<f64>,
    pub sgm_hypotheses_per_s: Option<f64>,
    /// Why a column is empty (e.g. a volume larger than the adapter allows).
    pub notes: Vec<String>,
    /// Ratios to the peer's time beside this configuration (`peer_ms`; None without the
    /// peer).
    pub wta_vs_peer: Option<f64>,
    pub sgm_vs_peer: Option<f64>,
    /// The peer's median ms timed just before and just after this configuration, averaged:
    /// the ratios' denominator, so a machine whose load moves during the bench (shared
    /// machines: 2x within minutes) moves both sides of a ratio alike.
    pub peer_ms: Option<f64>,
    /// Per-stage median ms of the winner-take-all runs (`--json` only).
    pub wta_stage_ms: serde_json::Map<String, serde_json::Value>,
    /// Per-stage median ms of the SGM runs (GPU timestamps or the CPU clock).
    pub sgm_stage_ms: serde_json::Map<String, serde_json::Value>,
    /// The WGSL engine's host work per frame set (None for the CPU engine).
    pub wta_host: Option<HostWork>,
    pub sgm_host: Option<HostWork>,
    pub runs: usize,
}

/// The WGSL engine's host side of one frame set (`sweep::gpu::SetCounts`): the median host ms
/// (wall time less the waits for the GPU) of the timed runs, and the last run's counts.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct HostWork {
    pub host_ms: f64,
    /// Median ms blocked waiting for the GPU.
    pub wait_ms: f64,
    /// Median ms in `Queue::submit`.
    pub submit_ms: f64,
    /// Plans run: levels of coarse to fine times references.
    pub levels: u32,
    pub submissions: u32,
    /// SGM's dispatches, every level's (each one direction, or several side by side).
    pub sgm_dispatches: u32,
    /// The sweep's dispatches (cost, row sums, aggregate), every level's.
    pub sweep_dispatches: u32,
    pub readbacks: u32,
    pub readback_bytes: u64,
    /// Bytes of the caller's images written up (a set of several references: each once).
    pub image_bytes: u64,
    pub waits: u32,
    /// The most submissions not read back yet at once (a set's references: all of them).
    pub most_in_flight: u32,
    /// Staging buffers made for uploads (0 once the engine's own is made).
    pub staging_buffers: u32,
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(|a, b| a.total_cmp(b));
    match values.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => values[n / 2],
        n => 0.5 * (values[n / 2 - 1] + values[n / 2]),
    }
}

fn round3(v: f64) -> f64 {
    (v * 1000.0).round() / 1000.0
}

/// The paper's benchmark settings: the colour SSD, best half-sequence with the shiftable 2x2
/// window, and the
/// given optimizer (the options apply to every configuration, all but the optimizer).
pub fn bench_params(
    config: &BenchConfig,
    overrides: &EngineOptions,
    optimizer: Optimizer,
) -> SweepParams {
    let mut params = SweepParams {
        min_depth_m: 1.0,
        max_depth_m: 6.0,
        num_planes: config.planes,
        ..SweepParams::default()
    };
    if config.workload == Workload::Paper {
        // The paper's colour SSD on the images as they are.
        params.prefilter = Prefilter::None;
        params.cost = Cost::Tssd;
        params.scoring = Scoring::BestHalfSequence;
        params.window_width = 2;
        params.window_height = 2;
        params.window_mode = WindowMode::Shiftable;
    }
    params.max_neighbours = config.max_neighbours;
    overrides.apply(&mut params);
    params.num_planes = config.planes;
    params.optimizer = optimizer;
    params
}

/// The rig, images and base parameters of a configuration.
fn workload(config: &BenchConfig) -> anyhow::Result<(Rig, Vec<Rgba8Image>, Option<SweepParams>)> {
    if config.workload == Workload::Demo {
        let dir = std::env::temp_dir().join(format!("sweepdepth-bench-{}", std::process::id()));
        let input = super::demo::extract_sample(&dir)?;
        let dataset = crate::datasets::load_dataset(&input);
        let _ = std::fs::remove_dir_all(&dir);
        let dataset = dataset?;
        return Ok((dataset.rig, dataset.images, Some(dataset.params)));
    }
    let mut model = CameraModel::pinhole(synthetic::intrinsics(config.width, config.height));
    let reference = (config.cameras - 1) / 2;
    let rig = match config.workload {
        Workload::Ring { distorted } => {
            if distorted {
                model.distortion = synthetic::plumb_bob_barrel();
            }
            // 6 degrees apart around a point 4 m ahead: 0.4 m between neighbours.
            synthetic::arc_rig(config.cameras, 0.105, 4.0, model, reference)?
        }
        Workload::Pair { distorted } => {
            if distorted {
                model.distortion = synthetic::plumb_bob_barrel();
                // A slight toe-in: the views are near-rectified, not rectified.
                synthetic::arc_rig(2, 0.1 / 4.0, 4.0, model, 0)?
            } else {
                synthetic::row_rig(2, 0.1, model, 0)?
            }
        }
        Workload::Dome => synthetic::dome_rig(config.cameras, 35f64.to_radians(), 4.0, model, 0)?,
        _ => synthetic::row_rig(config.cameras, 0.1, model, reference)?,
    };
    let scene = Scene::wall_and_box(4.0, Some((2.0, 0.4)), model.intrinsics.fx_px);
    let images = synthetic::render_rig(&scene, &rig);
    Ok((rig, images, None))
}

/// The median ms per frame set, the per-stage medians, and the WGSL engine's host work.
type Timed = (
    f64,
    serde_json::Map<String, serde_json::Value>,
    Option<HostWork>,
);

/// How long the WGSL engine runs untimed before a configuration's timed runs.
const GPU_WARM_UP: std::time::Duration = std::time::Duration::from_millis(400);

/// Median frame time of `repeats` timed runs after a warm-up, and the per-stage medians.
fn time_runs(
    engine: &mut Engine,
    rig: &Rig,
    images: &[Rgba8Image],
    params: &SweepParams,
    references: &[usize],
    (repeats, ahead): (usize, usize),
) -> Result<Timed, crate::sweep::SweepError> {
    let run = |engine: &mut Engine| -> Result<(), crate::sweep::SweepError> {
        if references.is_empty() {
            engine.run_views(rig, images, params).map(|_| ())
        } else {
            engine
                .run_references(&rig.cameras, images, references, params)
                .into_iter()
                .try_for_each(|r| r.map(|_| ()))
        }
    };
    let first = Instant::now();
    run(engine)?;
    let first = first.elapsed();
    // A hardware GPU idles down between configurations (the peer runs on the CPU): stage
    // times moved 2-4x between runs on an H200 (docs/speed.md "The first GPU figures"). The
    // WGSL engine warms up for GPU_WARM_UP (at most 100 sets) before the timed runs, where a
    // set is short enough for that to matter (not on lavapipe, seconds per set). It did not
    // remove the spread (one build: sxga wta 18.3 and 41.1 ms in two runs); report ranges.
    if engine.take_gpu_counts().is_some() && first * 4 < GPU_WARM_UP {
        let warm_from = Instant::now();
        let mut sets = 0;
        while warm_from.elapsed() < GPU_WARM_UP && sets < 100 {
            run(engine)?;
            sets += 1;
        }
    }
    let mut frame_ms = Vec::with_capacity(repeats);
    let mut stage_ms: Vec<(String, Vec<f64>)> = Vec::new();
    let mut add_stages = |stages: &[(String, f64)]| {
        for (name, ms) in stages {
            match stage_ms.iter_mut().find(|(n, _)| n == name) {
                Some((_, v)) => v.push(*ms),
                None => stage_ms.push((name.clone(), vec![*ms])),
            }
        }
    };
    let (mut host_ms, mut wait_ms, mut submit_ms) = (Vec::new(), Vec::new(), Vec::new());
    let mut last_counts = None;
    let stream = match ahead {
        0 => None,
        _ => streamed::run_stream(engine, rig, images, params, references, repeats, ahead)?,
    };
    if let Some(stream) = stream {
        frame_ms.push(stream.ms_per_set);
        if let Some(counts) = stream.counts {
            // The stream's work per set.
            let counts = streamed::per_set(counts, repeats.max(1));
            host_ms.push(counts.host_ms);
            wait_ms.push(counts.wait_ms);
            submit_ms.push(counts.submit_ms);
            last_counts = Some(counts);
        }
        stream.stages.iter().for_each(|s| add_stages(s));
    }
    let serial = if frame_ms.is_empty() {
        repeats.max(1)
    } else {
        0
    };
    for _ in 0..serial {
        engine.take_gpu_counts();
        let started = Instant::now();
        run(engine)?;
        frame_ms.push(started.elapsed().as_secs_f64() * 1e3);
        if let Some(counts) = engine.take_gpu_counts() {
            host_ms.push(counts.host_ms);
            wait_ms.push(counts.wait_ms);
            submit_ms.push(counts.submit_ms);
            last_counts = Some(counts);
        }
        add_stages(&engine.last_timings().stages);
    }
    let mut stages = serde_json::Map::new();
    for (name, values) in stage_ms {
        let ms = median(values);
        // Stages a mode does not run (box passes of small windows, SGM under WTA) are left out.
        if ms > 0.0 {
            stages.insert(name, serde_json::json!(round3(ms)));
        }
    }
    let host = last_counts.map(|c| HostWork {
        host_ms: round3(median(host_ms)),
        wait_ms: round3(median(wait_ms)),
        submit_ms: round3(median(submit_ms)),
        levels: c.levels,
        submissions: c.submissions,
        sgm_dispatches: c.sgm_dispatches,
        sweep_dispatches: c.sweep_dispatches,
        readbacks: c.readbacks,
        readback_bytes: c.readback_bytes,
        image_bytes: c.image_bytes,
        waits: c.waits,
        most_in_flight: c.most_in_flight,
        staging_buffers: c.staging_buffers,
    });
    Ok((median(frame_ms), stages, host))
}

/// `--repeats`: a whole number of at least 1.
fn at_least_one(text: &str) -> Result<usize, String> {
    match text.parse::<usize>() {
        Ok(n) if n >= 1 => Ok(n),
        _ => Err(format!("must be a whole number >= 1, got '{text}'")),
    }
}

/// The configurations `names` ask for (all, or with `quick` the paper's and the demo's), each
/// with `--planes`' planes where it is given (the engines' and the peer's disparities).
fn selected_configs(
    names: &[String],
    quick: bool,
    options: &EngineOptions,
) -> anyhow::Result<Vec<BenchConfig>> {
    if let Some(unknown) = names
        .iter()
        .find(|n| !CONFIGS.iter().any(|c| c.name == n.as_str()))
    {
        let known: Vec<&str> = CONFIGS.iter().map(|c| c.name).collect();
        anyhow::bail!(
            "unknown bench configuration '{unknown}' (known: {})",
            known.join(", ")
        );
    }
    let planes = planes_override(options);
    Ok(CONFIGS
        .iter()
        .filter(|c| !quick || matches!(c.name, "paper" | "demo"))
        .filter(|c| names.is_empty() || names.iter().any(|n| n == c.name))
        .map(|c| BenchConfig {
            planes: planes.unwrap_or(c.planes),
            ..*c
        })
        .collect())
}

/// The planes `--planes` asks for (None: each configuration's own).
fn planes_override(options: &EngineOptions) -> Option<u32> {
    options
        .values()
        .iter()
        .find_map(|(name, value)| match value {
            ParamValue::Int(n) if *name == "num_planes" => u32::try_from(*n).ok(),
            _ => None,
        })
}

/// Runs one configuration on one engine: winner-take-all, then SGM (the ratios to the peer
/// are left to the caller, which times the peer beside it).
pub fn run_config(
    engine: &mut Engine,
    config: &BenchConfig,
    overrides: &EngineOptions,
    (repeats, sets_ahead): (usize, usize),
) -> anyhow::Result<BenchResult> {
    let (rig, images, base) = workload(config)?;
    let params_for = |optimizer| match &base {
        Some(base) => {
            let mut p = base.clone();
            overrides.apply(&mut p);
            p.optimizer = optimizer;
            p
        }
        None => bench_params(config, overrides, optimizer),
    };
    let hypotheses = f64::from(config.width) * f64::from(config.height) * f64::from(config.planes);
    let mut notes = Vec::new();
    if sets_ahead > 0 && engine.starts_without_waiting() {
        notes.push(format!(
            "ms per set of {} sets back to back, {sets_ahead} ahead",
            repeats.max(1)
        ));
    }
    let mut column = |optimizer: Optimizer| -> anyhow::Result<_> {
        let params = params_for(optimizer);
        let runs = (repeats, sets_ahead);
        match time_runs(engine, &rig, &images, &params, config.references, runs) {
            Ok((ms, stages, host)) => Ok((Some(round3(ms)), stages, host)),
            // A volume too large for the adapter is a result, not a failure of the bench.
            Err(crate::sweep::SweepError::InvalidParams(reason)) => {
                notes.push(format!("{optimizer:?}: {reason}"));
                Ok((None, serde_json::Map::new(), None))
            }
            Err(other) => Err(other).with_context(|| format!("{optimizer:?} runs")),
        }
    };
    let (wta_ms, wta_stage_ms, wta_host) = column(Optimizer::Wta)?;
    let (sgm_ms, sgm_stage_ms, sgm_host) = column(Optimizer::Sgm)?;
    let params = params_for(Optimizer::Sgm);
    let settings = format!(
        "{}, {} {}x{}, {}",
        serde_json::to_value(params.scoring)?
            .as_str()
            .unwrap_or("?"),
        serde_json::to_value(params.window_mode)?
            .as_str()
            .unwrap_or("?"),
        params.window_width,
        params.window_height,
        serde_json::to_value(params.aggregation)?
            .as_str()
            .unwrap_or("?"),
    );
    let per_s = |ms: Option<f64>| ms.map(|ms| (hypotheses / (ms / 1e3)).round());
    Ok(BenchResult {
        config: config.name,
        engine: engine.label(),
        cameras: config.cameras,
        width: config.width,
        height: config.height,
        planes: config.planes,
        settings,
        wta_ms,
        wta_hypotheses_per_s: per_s(wta_ms),
        sgm_ms,
        sgm_hypotheses_per_s: per_s(sgm_ms),
        notes,
        wta_vs_peer: None,
        sgm_vs_peer: None,
        peer_ms: None,
        wta_stage_ms,
        sgm_stage_ms,
        wta_host,
        sgm_host,
        runs: repeats.max(1),
    })
}

/// Times the peer, or says why it is missing.
pub fn run_peer(explicit_python: Option<&Path>, repeats: usize) -> Result<PeerResult, String> {
    run_peer_for(explicit_python, repeats, None)
}

/// Times the peer of `config` (None: the Tsukuba peer), or says why it is missing.
pub fn run_peer_for(
    explicit_python: Option<&Path>,
    repeats: usize,
    config: Option<&BenchConfig>,
) -> Result<PeerResult, String> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/sgbm_baseline.py");
    let python = crate::eval::peer::cv2_python(explicit_python).ok_or_else(|| {
        "no Python with OpenCV (cv2) found: `pip install opencv-python-headless` into \
         target/test-venv or the system python3, or pass --python"
            .to_string()
    })?;
    let mut command = Command::new(&python);
    command
        .arg(&script)
        .args(["--time", "--json", "--repeats", &repeats.max(5).to_string()]);
    if let Some(BenchConfig {
        width,
        height,
        planes,
        peer: PeerKind::Pair { rectify },
        ..
    }) = config
    {
        command
            .args(["--size", &width.to_string(), &height.to_string()])
            .args(["--num-disp", &planes.to_string()]);
        if *rectify {
            command.arg("--rectify");
        }
    }
    let output = command
        .output()
        .map_err(|e| format!("running {}: {e}", python.display()))?;
    if !output.status.success() {
        return Err(format!(
            "{} {} --time failed: {}",
            python.display(),
            script.display(),
            String::from_utf8_lossy(&output.stderr).trim()
        ));
    }
    serde_json::from_slice(&output.stdout).map_err(|e| format!("the peer's output: {e}"))
}

pub fn run(args: &BenchArgs) -> anyhow::Result<()> {
    if args.fusion {
        return fusion::run(args);
    } else if args.maps_out {
        return maps_out::run(args);
    }
    let repeats = if args.quick { 3 } else { args.repeats };
    // Unknown names are refused before anything is timed.
    let configs = selected_configs(&args.configs, args.quick, &args.params)?;
    let peer = run_peer(args.python.as_deref(), 3 * repeats);
    // The peer is timed again after every configuration; each ratio divides by the mean of the
    // peer's times just before and just after it.
    let mut peer_before = peer.as_ref().ok().map(|p| p.ms_median);
    match (&peer, args.json) {
        (Ok(p), true) => println!("{}", serde_json::to_string(p)?),
        (Err(reason), true) => println!("{}", serde_json::json!({ "peer_missing": reason })),
        (Ok(p), false) => println!(
            "peer: {} (OpenCV {}, {} threads), {} {}x{}, {} disparities: {:.2} ms (median of {})",
            p.peer,
            p.opencv,
            p.threads,
            p.pair,
            p.width,
            p.height,
            p.num_disparities,
            p.ms_median,
            p.runs
        ),
        (Err(reason), false) => println!("peer: missing ({reason}); no ratios"),
    }
    // As the node runs it: the maps its outputs publish (issue 35; the CPU engine makes them
    // all, but brings back only these from a rectified pair).
    let wanted = if args.depth_only {
        crate::pipeline::Wanted::NONE.maps(true)
    } else {
        WantedMaps::OUTPUTS
    };
    let mut engines = Vec::new();
    if args.device != Device::Gpu {
        let mut engine = Engine::new(Device::Cpu)?;
        engine.set_wanted_maps(wanted);
        engines.push(engine);
    }
    if args.device != Device::Cpu {
        match Engine::new(Device::Gpu) {
            Ok(mut engine) => {
                engine.set_wanted_maps(wanted);
                args.gpu.apply(&mut engine);
                engines.push(engine)
            }
            Err(e) if args.device == Device::Auto => {
                println!("WGSL engine: not timed ({e})");
            }
            Err(e) => return Err(e.into()),
        }
    }
    if !args.json {
        println!(
            "{:<8} {:<44} {:>19} {:>30} {:>9} {:>9} {:>8} {:>8} {:>7} {:>15} {:>9}  SGM stages (ms)",
            "config",
            "engine",
            "size",
            "settings",
            "wta ms",
            "sgm ms",
            "wta/peer",
            "sgm/peer",
            "peer ms",
            "host ms wta/sgm",
            "sub/read",
        );
    }
    // Each engine's 9-camera set, for the decode line.
    let mut nine_camera: Vec<(String, Option<f64>, Option<f64>)> = Vec::new();
    for engine in &mut engines {
        for config in &configs {
            let mut result = run_config(engine, config, &args.params, (repeats, args.sets_ahead))
                .with_context(|| format!("{} on {}", config.name, engine.label()))?;
            if config.peer != PeerKind::Tsukuba {
                // Its own peer, just before (timed here, after the engine: the same machine
                // state within seconds) and after.
                let times: Vec<f64> = (0..2)
                    .filter_map(|_| {
                        run_peer_for(args.python.as_deref(), repeats, Some(config))
                            .ok()
                            .map(|p| p.ms_median)
                    })
                    .collect();
                if !times.is_empty() {
                    let beside = round3(times.iter().sum::<f64>() / times.len() as f64);
                    let ratio = |ms: Option<f64>| ms.map(|ms| round3(ms / beside));
                    result.wta_vs_peer = ratio(result.wta_ms);
                    result.sgm_vs_peer = ratio(result.sgm_ms);
                    result.peer_ms = Some(beside);
                    result.notes.push(format!(
                        "peer: StereoSGBM 3-way {}x{} {} disparities{}",
                        config.width,
                        config.height,
                        config.planes.div_ceil(16) * 16,
                        if config.peer == (PeerKind::Pair { rectify: true }) {
                            " after cv2.remap of both views"
                        } else {
                            ""
                        }
                    ));
                }
            } else if let Some(before) = peer_before {
                // A peer that fails now (it ran at the start) leaves the first time alone.
                let after =
                    run_peer(args.python.as_deref(), 3 * repeats).map_or(before, |p| p.ms_median);
                let beside = round3(0.5 * (before + after));
                let ratio = |ms: Option<f64>| ms.map(|ms| round3(ms / beside));
                result.wta_vs_peer = ratio(result.wta_ms);
                result.sgm_vs_peer = ratio(result.sgm_ms);
                result.peer_ms = Some(beside);
                peer_before = Some(after);
            }
            if result.config == "9-camera" {
                nine_camera.push((result.engine.clone(), result.wta_ms, result.sgm_ms));
            }
            if args.json {
                println!("{}", serde_json::to_string(&result)?);
                continue;
            }
            print_row(&result);
        }
    }
    decode_line(args.json, repeats, &nine_camera)
}

/// One configuration's row of the text table.
fn print_row(result: &BenchResult) {
    let ms = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{v:.1}"));
    let ratio = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.1}x"));
    let stages = result
        .sgm_stage_ms
        .iter()
        // The coarse levels' own stages (`coarse/sweep`, ...) only in the JSON.
        .filter(|(k, _)| !k.contains('/'))
        .map(|(k, v)| format!("{k} {:.1}", v.as_f64().unwrap_or(f64::NAN)))
        .collect::<Vec<String>>()
        .join(", ");
    // The WGSL engine's host share, and the SGM runs' submissions and readbacks per
    // frame set.
    let host = |h: Option<HostWork>| h.map_or("-".to_string(), |h| format!("{:.1}", h.host_ms));
    let host_ms = format!("{}/{}", host(result.wta_host), host(result.sgm_host));
    let per_set = result.sgm_host.map_or("-".to_string(), |h| {
        format!("{}/{}", h.submissions, h.readbacks)
    });
    println!(
        "{:<8} {:<44} {:>19} {:>30} {:>9} {:>9} {:>8} {:>8} {:>7} {:>15} {:>9}  {}{}",
        result.config,
        truncate(&result.engine, 44),
        format!(
            "{}x{}x{}x{}",
            result.cameras, result.width, result.height, result.planes
        ),
        truncate(&result.settings, 30),
        ms(result.wta_ms),
        ms(result.sgm_ms),
        ratio(result.wta_vs_peer),
        ratio(result.sgm_vs_peer),
        result
            .peer_ms
            .map_or("-".to_string(), |v| format!("{v:.2}")),
        host_ms,
        per_set,
        stages,
        if result.notes.is_empty() {
            String::new()
        } else {
            format!(" [{}]", result.notes.join("; "))
        }
    );
}

/// The decode line: a 9-camera 640x480 JPEG set decoded as the pipeline does, and its share of
/// each engine's 9-camera set (450x375, `9-camera` above) when that ran.
fn decode_line(
    json: bool,
    repeats: usize,
    nine_camera: &[(String, Option<f64>, Option<f64>)],
) -> anyhow::Result<()> {
    let result = decode::run(3 * repeats).context("the decode line")?;
    if json {
        println!("{}", serde_json::to_string(&result)?);
        let messages = messages::run(3 * repeats).context("the messages line")?;
        println!("{}", serde_json::to_string(&messages)?);
        return Ok(());
    }
    println!(
        "decode: {} x {}x{} JPEG (quality {}, {} KiB per set): {:.1} ms per set in parallel \
         across cameras ({} threads), {:.1} ms per image on one thread (median of {})",
        result.cameras,
        result.width,
        result.height,
        result.jpeg_quality,
        result.bytes_per_set / 1024,
        result.set_ms,
        result.threads,
        result.image_ms,
        result.runs
    );
    messages_line(repeats)?;
    for (engine, wta, sgm) in nine_camera {
        let share = |ms: Option<f64>| {
            ms.map_or("n/a".to_string(), |ms| {
                format!("{:.0} %", 100.0 * result.set_ms / ms)
            })
        };
        println!(
            "decode beside the 9-camera set (450x375x57) on {}: {} of its wta, {} of its sgm time",
            truncate(engine, 44),
            share(*wta),
            share(*sgm)
        );
    }
    Ok(())
}

/// The messages line: the node's own host work per set at 1 MP, besides the engine's.
fn messages_line(repeats: usize) -> anyhow::Result<()> {
    let result = messages::run(3 * repeats).context("the messages line")?;
    println!(
        "messages: {} x {}x{} rgb8 into the engine's images {:.1} ms per set ({} threads), \
         depth and confidence out as 32FC1 {:.1} ms (median of {}; the node's host work per \
         set besides the engine's host ms)",
        result.cameras,
        result.width,
        result.height,
        result.images_in_ms,
        result.threads,
        result.maps_out_ms,
        result.runs
    );
    Ok(())
}

fn truncate(s: &str, n: usize) -> String {
    if s.chars().count() <= n {
        s.to_string()
    } else {
        s.chars().take(n - 1).chain(std::iter::once('~')).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::{Args, Command, FromArgMatches};

    fn options(args: &[&str]) -> EngineOptions {
        let cmd = EngineOptions::augment_args(Command::new("t").no_binary_name(true));
        let matches = cmd.try_get_matches_from(args).expect("parses");
        EngineOptions::from_arg_matches(&matches).expect("options")
    }

    /// `--planes` is the planes of every configuration (it was overwritten by each
    /// configuration's own); other options leave them alone.
    #[test]
    fn the_planes_option_sets_the_configurations_planes() {
        assert_eq!(planes_override(&options(&["--planes", "8"])), Some(8));
        assert_eq!(planes_override(&options(&["--tau", "30"])), None);
        assert_eq!(planes_override(&options(&[])), None);
        let names = ["sxga".to_string(), "demo".to_string()];
        let eight = selected_configs(&names, false, &options(&["--planes", "8"])).expect("known");
        assert_eq!(eight.len(), 2);
        for config in &eight {
            assert_eq!(config.planes, 8, "{}", config.name);
            let params = bench_params(config, &options(&["--planes", "8"]), Optimizer::Wta);
            assert_eq!(params.num_planes, 8);
        }
        let own = selected_configs(&names, false, &options(&[])).expect("known");
        assert!(own.iter().all(|c| c.planes != 8));
        assert!(selected_configs(&["nope".into()], false, &options(&[])).is_err());
    }
}
