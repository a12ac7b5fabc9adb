//! `sweepdepth eval`: run the engine on datasets with ground truth and print error rates.
//!
//! Disparity ground truth (Middlebury): the estimated depth z becomes a disparity in the
//! dataset's evaluation units, `d = focal_baseline_eval / z`, and is compared with the ground
//! truth on every pixel that has ground truth and lies outside the border. Depth ground truth
//! (ICL-NUIM): relative depth errors. Datasets without ground truth (multi-view rings) only run.
//! `eval --fusion` ([`fusion`]): the fused model's accuracy beside the depth maps' (issue 28).

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::datasets::{self, Dataset, DatasetError, GroundTruth};
use crate::engine::{Engine, Sweeper};
use crate::io::{self, IoError};
use crate::sweep::{DepthMaps, SweepError};

pub mod fusion;
mod metrics;
pub mod peer;
pub mod radiometry;
mod table;

pub use metrics::{
    depth_metrics, depth_metrics_ranked, depth_to_disparity, disparity_metrics, metrics_for,
    ConfidenceRanking, DepthConfidenceRanking, DepthMetrics, DisparityMetrics, Metrics,
};
pub use table::{table_header, table_row, table_row_as};

/// Command-line arguments of `sweepdepth eval`.
#[derive(Debug, Clone, clap::Args)]
pub struct EvalArgs {
    /// Dataset folders (Middlebury 2001/2003/2005/2006, Middlebury 2014 and ETH3D two-view
    /// pairs in its layout, ICL-NUIM frames, Middlebury multi-view; with --fusion, ICL-NUIM
    /// frames only, and none is needed).
    #[arg(required_unless_present = "fusion", num_args = 1..)]
    pub dirs: Vec<PathBuf>,
    /// Write disparity/depth/confidence PFMs and PNGs to `OUT/<dataset folder name>/`
    /// (`<name>-2`, `<name>-3`, ... for a name an earlier folder of the same run has; with
    /// --fusion: each fused mesh as `OUT/<dataset>.ply`). OUT must be a folder or not exist.
    #[arg(long, value_name = "OUT")]
    pub save: Option<PathBuf>,
    /// The fused model's accuracy (issue 28) instead: a synthetic moving rig, then each folder
    /// (ICL-NUIM frames posed as one rig, every frame a reference), fused into a TSDF, ray-cast
    /// into every view and compared with the ground truth beside the depth maps
    /// (`eval::fusion`).
    #[arg(long)]
    pub fusion: bool,
    /// With --fusion: the voxel size in metres for every dataset (default: 0.02, chosen per
    /// dataset in `eval::fusion`).
    #[arg(long, value_name = "M", requires = "fusion")]
    pub voxel_size: Option<f32>,
    /// Pixels evaluated (disparity ground truth): all with ground truth, or only the
    /// non-occluded ones (a left-right check of the evaluation pair's two ground-truth maps;
    /// Middlebury 2003/2005 only, an error for the others).
    #[arg(long, value_enum, default_value_t = EvalMask::All)]
    pub mask: EvalMask,
    /// Which engine runs the sweep: a hardware GPU if there is one, else the CPU engine
    /// (auto); the WGSL engine on the wgpu adapter, lavapipe included (gpu); the CPU engine.
    #[arg(long, value_enum, default_value_t = crate::engine::Device::Auto)]
    pub device: crate::engine::Device,
    /// The right view of a Middlebury 2014 / ETH3D pair (default im1.png; the 2014 sets'
    /// im1E.png and im1L.png: the same view under another exposure or lighting).
    #[arg(long, value_name = "FILE")]
    pub right_view: Option<String>,
    /// Real cameras' radiometry given to every camera's image before the sweep (the peer's
    /// too): each camera its own exposure, a vignette, sensor noise, or all three
    /// (`eval::radiometry`): how much depth a setting keeps on a rig whose cameras differ.
    #[arg(long, value_enum, default_value_t = radiometry::Radiometry::None)]
    pub radiometry: radiometry::Radiometry,
    /// A peer run on the same pair in the same run, scored alike, printed as a row of its
    /// own under the dataset's (`sgbm`: OpenCV StereoSGBM 3-way through
    /// tools/sgbm_baseline.py; rectified pairs, the middlebury2014 layout).
    #[arg(long, value_enum)]
    pub peer: Option<EvalPeer>,
    /// Python with OpenCV for `--peer sgbm` (default: target/test-venv, then python3).
    #[arg(long, value_name = "PY")]
    pub python: Option<PathBuf>,
    #[command(flatten)]
    pub params: crate::params::EngineOptions,
}

/// A peer `eval` runs beside the engine.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum EvalPeer {
    /// OpenCV StereoSGBM, 3-way mode.
    Sgbm,
}

/// Which pixels with ground truth are evaluated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum EvalMask {
    /// Every pixel with ground truth (outside the border).
    All,
    /// Only pixels that pass a left-right check of the two ground-truth maps
    /// ([`datasets::nonocc_mask`]).
    Nonocc,
}

/// Errors of one evaluation.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error(transparent)]
    Sweep(#[from] SweepError),
    #[error(transparent)]
    Io(#[from] IoError),
    #[error(
        "{what} is {got_w}x{got_h} ({got_len} values) but the ground truth is {want_w}x{want_h}"
    )]
    Size {
        what: &'static str,
        got_w: u32,
        got_h: u32,
        got_len: usize,
        want_w: u32,
        want_h: u32,
    },
    #[error("{0}: no non-occluded mask (needs disparity ground truth for both views of the evaluation pair: Middlebury 2003/2005)")]
    NoNonoccMask(String),
    #[error("no pixel has ground truth{0}")]
    NoGroundTruthPixels(String),
    #[error("{path}: cannot create folder: {source}")]
    CreateDir {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// Restricts the dataset's disparity ground truth to its non-occluded pixels (the others become
/// unknown), so that every metric is over the non-occluded pixels only.
pub fn restrict_to_nonocc(dataset: &mut Dataset) -> Result<(), EvalError> {
    let (
        Some(mask),
        GroundTruth::Disparity {
            disparity_eval_px, ..
        },
    ) = (&dataset.nonocc_mask, &mut dataset.ground_truth)
    else {
        return Err(EvalError::NoNonoccMask(dataset.name.clone()));
    };
    for (d, &keep) in disparity_eval_px.data.iter_mut().zip(mask) {
        if !keep {
            *d = f32::NAN;
        }
    }
    Ok(())
}

/// Runs the engine on a dataset with its `params` and scores the result.
pub fn evaluate(
    engine: &mut impl Sweeper,
    dataset: &Dataset,
) -> Result<(DepthMaps, Option<Metrics>), EvalError> {
    let maps = engine.run_views(&dataset.rig, &dataset.images, &dataset.params)?;
    let metrics = metrics_for(dataset, &maps)?;
    Ok((maps, metrics))
}

/// Writes the outputs of one dataset into `dir` (created if needed): `disparity.pfm` (in the
/// units of the set's own ground-truth files, NaN invalid) for disparity ground truth,
/// `depth.pfm` (metres) for the others, and always `confidence.pfm`, `depth.png`,
/// `confidence.png`, `selection.png`.
pub fn save_outputs(dir: &Path, dataset: &Dataset, maps: &DepthMaps) -> Result<(), EvalError> {
    std::fs::create_dir_all(dir).map_err(|source| EvalError::CreateDir {
        path: dir.to_path_buf(),
        source,
    })?;
    match &dataset.ground_truth {
        GroundTruth::Disparity {
            focal_baseline_eval,
            doffs_px,
            ..
        } => {
            let mut disparity = depth_to_disparity(&maps.depth_m, *focal_baseline_eval);
            // The files' d, not the evaluation's d + doffs (NaN stays NaN).
            let doffs = *doffs_px as f32;
            disparity.data.iter_mut().for_each(|d| *d -= doffs);
            io::write_pfm(&dir.join("disparity.pfm"), &disparity)?;
        }
        GroundTruth::Depth { .. } | GroundTruth::None => {
            io::write_pfm(&dir.join("depth.pfm"), &maps.depth_m)?;
        }
    }
    io::write_pfm(&dir.join("confidence.pfm"), &maps.confidence)?;
    io::save_image(&dir.join("depth.png"), &io::depth_png(&maps.depth_m))?;
    io::save_image(
        &dir.join("confidence.png"),
        &io::confidence_png(&maps.confidence),
    )?;
    io::save_image(
        &dir.join("selection.png"),
        &io::selection_png(maps.width(), maps.height(), &maps.selection),
    )?;
    Ok(())
}

/// The name of a dataset called `name` in the table and under `--save`: `name` itself, or
/// `name-2`, `name-3`, ... where an earlier dataset of the run has it (ignoring ASCII case, as
/// a case-insensitive file system would); the name chosen is added to `taken`.
pub fn distinct_name(name: &str, taken: &mut Vec<String>) -> String {
    let free = |candidate: &str| !taken.iter().any(|t| t.eq_ignore_ascii_case(candidate));
    let chosen = if free(name) {
        name.to_string()
    } else {
        (2..)
            .map(|k| format!("{name}-{k}"))
            .find(|candidate| free(candidate))
            .unwrap_or_else(|| name.to_string())
    };
    taken.push(chosen.clone());
    chosen
}

/// Checks `--save OUT` before any dataset runs: OUT is a folder (made here where it does not
/// exist), not a file.
pub fn check_save_folder(out: &Path) -> Result<(), EvalRunError> {
    let refuse = |reason: String| EvalRunError::Save {
        path: out.to_path_buf(),
        reason,
    };
    if out.exists() && !out.is_dir() {
        return Err(refuse(
            "exists and is not a folder (give a folder, or a path that does not exist)".into(),
        ));
    }
    std::fs::create_dir_all(out).map_err(|e| refuse(format!("cannot create the folder: {e}")))
}

/// One dataset folder `dir` through the engine: its table row (and its peer's, with the Python
/// of `--peer sgbm` found before any dataset runs), its maps saved under `--save`. `taken`:
/// the names of the run's earlier datasets ([`distinct_name`]).
fn eval_one(
    engine: &mut Engine,
    dir: &Path,
    args: &EvalArgs,
    peer_python: Option<&Path>,
    progress: &str,
    taken: &mut Vec<String>,
) -> Result<String, EvalError> {
    let started = Instant::now();
    eprintln!("{progress} loading {}", dir.display());
    let options = datasets::LoadOptions {
        right_view: args.right_view.clone(),
        ..Default::default()
    };
    let mut dataset = datasets::load_dataset_with(dir, &options)?;
    args.params.apply(&mut dataset.params);
    args.radiometry.apply(&mut dataset.images);
    if args.mask == EvalMask::Nonocc {
        restrict_to_nonocc(&mut dataset)?;
    }
    let (w, h) = dataset.reference_size();
    eprintln!(
        "{progress} {} ({}, {} views, {w}x{h}, reference {}, depth {:.3}..{:.3} m, {} planes) loaded in {:.0} ms; running",
        dataset.name,
        dataset.layout,
        dataset.rig.cameras.len(),
        dataset.rig.cameras[dataset.reference_index()].name,
        dataset.params.min_depth_m,
        dataset.params.max_depth_m,
        dataset.params.num_planes,
        started.elapsed().as_secs_f64() * 1e3
    );
    let run_started = Instant::now();
    let maps = engine.run_views(&dataset.rig, &dataset.images, &dataset.params)?;
    let ms = run_started.elapsed().as_secs_f64() * 1e3;
    eprintln!("{progress} engine ran in {ms:.0} ms");
    let metrics = metrics_for(&dataset, &maps)?;
    let name = distinct_name(&dataset.name, taken);
    if let Some(out) = &args.save {
        let dir = out.join(&name);
        save_outputs(&dir, &dataset, &maps)?;
        let renamed = if name == dataset.name {
            String::new()
        } else {
            format!(
                " (as {name}: an earlier dataset of this run is named {} too)",
                dataset.name
            )
        };
        eprintln!("{progress} wrote {}{renamed}", dir.display());
    }
    let invalid = maps.invalid_fraction();
    let mut rows = table_row_as(&name, &dataset, metrics.as_ref(), invalid, ms);
    if let Some(python) = peer_python {
        // The engine's row stands whatever becomes of the peer's: a dataset it cannot run on
        // (not a rectified pair) or a failed run is a comment line of the table instead.
        let right = args.right_view.as_deref().unwrap_or("im1.png");
        let scratch = std::env::temp_dir();
        let row = peer::check_pair(&dataset).and_then(|()| {
            let pair = peer::PairFiles::of(dir, right, &dataset, args.radiometry, &scratch)?;
            peer::sgbm_row(python, &pair, &dataset, &scratch)
        });
        rows.push('\n');
        match row {
            Ok(row) => rows.push_str(&table_row_as(
                &format!("  sgbm-3way {name}"),
                &dataset,
                Some(&row.metrics),
                row.invalid,
                row.ms,
            )),
            Err(e) => {
                eprintln!("{progress} the SGBM peer did not run on {name}: {e}");
                rows.push_str(&format!("#  sgbm-3way {name}: not run: {e}"));
            }
        }
    }
    Ok(rows)
}

/// Why `sweepdepth eval` failed as a whole (a folder that fails is reported, and counted in
/// [`EvalRunError::Failed`]).
#[derive(Debug, thiserror::Error)]
pub enum EvalRunError {
    #[error(transparent)]
    Setup(#[from] crate::engine::EngineError),
    #[error(transparent)]
    Engine(#[from] SweepError),
    #[error("writing the table: {0}")]
    Stdout(#[from] std::io::Error),
    #[error("--peer sgbm: {0}")]
    Peer(#[from] peer::PeerError),
    #[error("--peer compares depth maps on rectified pairs; with --fusion there is none to compare (bench --fusion times fusion beside Open3D)")]
    PeerWithFusion,
    #[error("--radiometry changes the depth maps' images; --fusion measures fused models on the sets as they are (use --radiometry without --fusion)")]
    RadiometryWithFusion,
    #[error("--save {}: {reason}", path.display())]
    Save { path: PathBuf, reason: String },
    #[error("{} of {total} dataset(s) failed: {}", failed.len(), failed.join(", "))]
    Failed { failed: Vec<String>, total: usize },
}

/// `sweepdepth eval`: one engine (`--device`) for all folders; a folder that fails is reported and the
/// others still run; the command fails at the end if any did. `--save` is checked first.
pub fn run(args: &EvalArgs) -> Result<(), EvalRunError> {
    if let Some(out) = &args.save {
        check_save_folder(out)?;
    }
    if args.fusion {
        if args.peer.is_some() {
            return Err(EvalRunError::PeerWithFusion);
        }
        if args.radiometry != radiometry::Radiometry::None {
            return Err(EvalRunError::RadiometryWithFusion);
        }
        return fusion::run(args);
    }
    let peer_python = match args.peer {
        Some(EvalPeer::Sgbm) => Some(peer::require_cv2_python(args.python.as_deref())?),
        None => None,
    };
    let mut engine = Engine::new(args.device)?;
    let mut stdout = std::io::stdout();
    writeln!(stdout, "# engine: {}", engine.label())?;
    if args.mask == EvalMask::Nonocc {
        writeln!(
            stdout,
            "# mask: non-occluded pixels only (left-right check of the two ground-truth maps)"
        )?;
    }
    writeln!(stdout, "{}", table_header())?;
    stdout.flush()?;
    let mut failed = Vec::new();
    let mut taken = Vec::new();
    let total = args.dirs.len();
    for (i, dir) in args.dirs.iter().enumerate() {
        let progress = format!("[{}/{total}]", i + 1);
        let python = peer_python.as_deref();
        match eval_one(&mut engine, dir, args, python, &progress, &mut taken) {
            Ok(row) => {
                writeln!(stdout, "{row}")?;
                stdout.flush()?;
            }
            Err(error) => {
                eprintln!("{progress} error: {}: {error}", dir.display());
                failed.push(dir.display().to_string());
            }
        }
    }
    if !failed.is_empty() {
        return Err(EvalRunError::Failed { failed, total });
    }
    Ok(())
}
