//! `sweepdepth bench`: hypotheses per second and per-stage GPU times on synthetic rigs.

use std::time::Instant;

use anyhow::Context;
use serde::Serialize;

use crate::geometry::CameraModel;
use crate::gpu_context::GpuContext;
use crate::params::EngineOptions;
use crate::sweep::gpu::{GpuEngine, STAGES};
use crate::sweep::{Optimizer, Scoring, SweepParams, WindowMode};
use crate::synthetic::{self, Scene};

#[derive(Debug, clap::Args)]
pub struct BenchArgs {
    /// One JSON object per line and configuration.
    #[arg(long)]
    pub json: bool,
    /// Timed runs per configuration (after one warm-up run); the median is reported.
    #[arg(long, default_value_t = 7)]
    pub repeats: usize,
    /// Only the paper's configuration (4 cameras, 320x240, 20 planes).
    #[arg(long)]
    pub quick: bool,
    /// Engine options applied to every configuration (window, scoring, ...).
    #[command(flatten)]
    pub params: EngineOptions,
}

/// One benchmark configuration.
#[derive(Debug, Clone, Copy)]
pub struct BenchConfig {
    pub cameras: usize,
    pub width: u32,
    pub height: u32,
    pub planes: u32,
}

/// The three configurations: the paper's, then 640x480x64 and 1280x960x128.
pub const CONFIGS: [BenchConfig; 3] = [
    BenchConfig {
        cameras: 4,
        width: 320,
        height: 240,
        planes: 20,
    },
    BenchConfig {
        cameras: 4,
        width: 640,
        height: 480,
        planes: 64,
    },
    BenchConfig {
        cameras: 4,
        width: 1280,
        height: 960,
        planes: 128,
    },
];

#[derive(Debug, Serialize)]
pub struct BenchResult {
    pub cameras: usize,
    pub width: u32,
    pub height: u32,
    pub planes: u32,
    pub scoring: String,
    pub window: String,
    pub pairs: String,
    pub aggregation: String,
    /// The paper's local winner-take-all.
    pub ms_per_frame: f64,
    pub hypotheses_per_s: f64,
    pub stage_ms: serde_json::Map<String, serde_json::Value>,
    /// The same configuration with `optimizer: sgm` (`sgm_paths` directions); `None` with
    /// `sgm_error` when the cost volume does not fit this adapter.
    pub sgm_ms_per_frame: Option<f64>,
    pub sgm_paths: u32,
    pub sgm_stage_ms: serde_json::Map<String, serde_json::Value>,
    pub sgm_error: Option<String>,
    pub stage_timer: &'static str,
    pub runs: usize,
    pub adapter: String,
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(|a, b| a.total_cmp(b));
    match values.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => values[n / 2],
        n => 0.5 * (values[n / 2 - 1] + values[n / 2]),
    }
}

/// The benchmark's engine settings: best half-sequence with the paper's shiftable 2x2 window,
/// and the given optimizer (the options apply to both columns, all but the optimizer).
pub fn bench_params(
    config: &BenchConfig,
    overrides: &EngineOptions,
    optimizer: Optimizer,
) -> SweepParams {
    let mut params = SweepParams {
        min_depth_m: 1.0,
        max_depth_m: 6.0,
        num_planes: config.planes,
        scoring: Scoring::BestHalfSequence,
        window_width: 2,
        window_height: 2,
        window_mode: WindowMode::Shiftable,
        ..SweepParams::default()
    };
    overrides.apply(&mut params);
    params.num_planes = config.planes;
    params.optimizer = optimizer;
    params
}

/// Median frame time and per-stage medians of `repeats` timed runs after a warm-up.
fn time_runs(
    engine: &mut GpuEngine,
    rig: &crate::geometry::Rig,
    images: &[crate::image::Rgba8Image],
    params: &SweepParams,
    repeats: usize,
) -> Result<(f64, serde_json::Map<String, serde_json::Value>, bool), crate::sweep::SweepError> {
    engine.run(rig, images, params)?;
    let mut frame_ms = Vec::with_capacity(repeats);
    let mut stage_ms: Vec<Vec<f64>> = vec![Vec::new(); STAGES.len()];
    let mut gpu_timestamps = false;
    for _ in 0..repeats.max(1) {
        let started = Instant::now();
        engine.run(rig, images, params)?;
        frame_ms.push(started.elapsed().as_secs_f64() * 1e3);
        let timings = engine.last_timings();
        gpu_timestamps = timings.gpu_timestamps;
        if timings.gpu_timestamps {
            for (i, (_, ms)) in timings.stages.iter().enumerate().take(STAGES.len()) {
                stage_ms[i].push(*ms);
            }
        }
    }
    let mut stages = serde_json::Map::new();
    if gpu_timestamps {
        for (name, values) in STAGES.iter().zip(stage_ms) {
            let ms = median(values);
            // Stages a mode does not run (box passes of small windows, SGM under WTA) are left out.
            if ms > 0.0 {
                stages.insert(
                    name.to_string(),
                    serde_json::json!((ms * 1000.0).round() / 1000.0),
                );
            }
        }
    }
    Ok((median(frame_ms), stages, gpu_timestamps))
}

/// Runs one configuration: a warm-up, then `repeats` timed frame sets, with the paper's
/// winner-take-all and then with SGM.
pub fn run_config(
    engine: &mut GpuEngine,
    adapter: &str,
    config: &BenchConfig,
    overrides: &EngineOptions,
    repeats: usize,
) -> anyhow::Result<BenchResult> {
    let model = CameraModel::pinhole(synthetic::intrinsics(config.width, config.height));
    let rig = synthetic::row_rig(config.cameras, 0.1, model, 1)?;
    let scene = Scene::wall_and_box(4.0, Some((2.0, 0.4)), model.intrinsics.fx_px);
    let images = synthetic::render_rig(&scene, &rig);
    let params = bench_params(config, overrides, Optimizer::Wta);
    let (ms, stages, gpu_timestamps) =
        time_runs(engine, &rig, &images, &params, repeats).context("winner-take-all runs")?;
    let sgm_params = bench_params(config, overrides, Optimizer::Sgm);
    let (sgm_ms_per_frame, sgm_stage_ms, sgm_error) =
        match time_runs(engine, &rig, &images, &sgm_params, repeats) {
            Ok((ms, stages, _)) => (Some((ms * 1000.0).round() / 1000.0), stages, None),
            // A volume too large for the adapter is a result, not a failure of the bench.
            Err(crate::sweep::SweepError::InvalidParams(reason)) => {
                (None, serde_json::Map::new(), Some(reason))
            }
            Err(other) => return Err(other).context("SGM runs"),
        };
    let hypotheses = f64::from(config.width) * f64::from(config.height) * f64::from(config.planes);
    Ok(BenchResult {
        cameras: config.cameras,
        width: config.width,
        height: config.height,
        planes: config.planes,
        scoring: serde_json::to_value(params.scoring)?
            .as_str()
            .unwrap_or("?")
            .to_string(),
        window: format!(
            "{} {}x{}",
            serde_json::to_value(params.window_mode)?
                .as_str()
                .unwrap_or("?"),
            params.window_width,
            params.window_height
        ),
        pairs: serde_json::to_value(params.effective_pairs())?
            .as_str()
            .unwrap_or("?")
            .to_string(),
        aggregation: serde_json::to_value(params.aggregation)?
            .as_str()
            .unwrap_or("?")
            .to_string(),
        ms_per_frame: (ms * 1000.0).round() / 1000.0,
        hypotheses_per_s: (hypotheses / (ms / 1e3)).round(),
        stage_ms: stages,
        sgm_ms_per_frame,
        sgm_paths: sgm_params.sgm_paths,
        sgm_stage_ms,
        sgm_error,
        stage_timer: if gpu_timestamps {
            "gpu timestamps"
        } else {
            "none (adapter has no timestamp queries)"
        },
        runs: repeats.max(1),
        adapter: adapter.to_string(),
    })
}

pub fn run(args: &BenchArgs) -> anyhow::Result<()> {
    let gpu = GpuContext::new()?;
    let adapter = gpu.adapter_label();
    let mut engine = GpuEngine::new(&gpu.device, &gpu.queue)?;
    if !args.json {
        println!("adapter: {adapter}");
        println!(
            "{:>4} {:>11} {:>6} {:>34} {:>10} {:>12} {:>10}  per-stage GPU ms (wta | sgm)",
            "cams", "size", "planes", "scoring/window", "wta ms", "Mhyp/s", "sgm ms"
        );
    }
    let configs: &[BenchConfig] = if args.quick { &CONFIGS[..1] } else { &CONFIGS };
    for config in configs {
        // Fewer repeats for the big frame on slow adapters keeps the run bounded.
        let result = run_config(&mut engine, &adapter, config, &args.params, args.repeats)
            .with_context(|| {
                format!(
                    "{}x{} with {} planes",
                    config.width, config.height, config.planes
                )
            })?;
        if args.json {
            println!("{}", serde_json::to_string(&result)?);
        } else {
            let list = |stages: &serde_json::Map<String, serde_json::Value>| {
                stages
                    .iter()
                    .map(|(k, v)| format!("{k} {:.2}", v.as_f64().unwrap_or(f64::NAN)))
                    .collect::<Vec<String>>()
                    .join(", ")
            };
            let stages = list(&result.stage_ms);
            let sgm_ms = match result.sgm_ms_per_frame {
                Some(ms) => format!("{ms:.2}"),
                None => "n/a".to_string(),
            };
            println!(
                "{:>4} {:>11} {:>6} {:>34} {:>10.2} {:>12.1} {:>10}  {} | {}",
                result.cameras,
                format!("{}x{}", result.width, result.height),
                result.planes,
                format!("{}/{}", result.scoring, result.window),
                result.ms_per_frame,
                result.hypotheses_per_s / 1e6,
                sgm_ms,
                if stages.is_empty() {
                    result.stage_timer.to_string()
                } else {
                    stages
                },
                match &result.sgm_error {
                    Some(reason) => reason.clone(),
                    None => list(&result.sgm_stage_ms),
                }
            );
        }
    }
    Ok(())
}
