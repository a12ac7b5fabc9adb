//! The peer beside `eval` on a rectified pair: OpenCV StereoSGBM (3-way, the settings of
//! `tools/sgbm_baseline.py`, which runs it), scored with the same metrics in the same run, so
//! a table row of ours always has SGBM's beside it.

use std::path::{Path, PathBuf};
use std::process::Command;

use super::metrics::{disparity_metrics, Metrics};
use super::radiometry::Radiometry;
use super::EvalError;
use crate::datasets::{Dataset, GroundTruth, Layout};
use crate::image::ImageF32;
use crate::io;

/// `tools/sgbm_baseline.py`, built into the binary: `eval --peer` runs its `--pair` mode, which
/// reads only the paths it is given, so an installed binary needs no checkout.
const SGBM_SCRIPT: &str = include_str!("../../tools/sgbm_baseline.py");

/// The Pythons [`cv2_python`] tries: `explicit`, else the repo's test venv, then `python3`.
fn python_candidates(explicit: Option<&Path>) -> Vec<PathBuf> {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    match explicit {
        Some(p) => vec![p.to_path_buf()],
        None => vec![
            repo.join("target/test-venv/bin/python"),
            PathBuf::from("python3"),
        ],
    }
}

/// A Python that can import cv2: `explicit`, the repo's test venv, then `python3`.
pub fn cv2_python(explicit: Option<&Path>) -> Option<PathBuf> {
    python_candidates(explicit).into_iter().find(|python| {
        Command::new(python)
            .args(["-c", "import cv2"])
            .output()
            .map(|o| o.status.success())
            .unwrap_or(false)
    })
}

/// [`cv2_python`], or why there is none (the Pythons tried, by path).
pub fn require_cv2_python(explicit: Option<&Path>) -> Result<PathBuf, PeerError> {
    cv2_python(explicit).ok_or_else(|| {
        let tried: Vec<String> = python_candidates(explicit)
            .iter()
            .map(|p| p.display().to_string())
            .collect();
        PeerError::NoPython(tried.join(", "))
    })
}

/// Whether the peer can run on `dataset`: a rectified pair with disparity ground truth.
pub fn check_pair(dataset: &Dataset) -> Result<(), PeerError> {
    let is_pair = matches!(dataset.ground_truth, GroundTruth::Disparity { .. })
        && dataset.layout == Layout::Middlebury2014
        && dataset.rig.cameras.len() == 2;
    if is_pair {
        Ok(())
    } else {
        Err(PeerError::NotAPair(dataset.layout))
    }
}

/// Why the peer gave no row.
#[derive(Debug, thiserror::Error)]
pub enum PeerError {
    #[error("the SGBM peer runs on rectified pairs (middlebury2014 layout), not {0}")]
    NotAPair(Layout),
    #[error("no Python with OpenCV (cv2) found (tried {0}): run scripts/setup.sh, `pip install opencv-python-headless`, or pass --python")]
    NoPython(String),
    #[error("{0}")]
    Run(String),
    #[error(transparent)]
    Metrics(#[from] EvalError),
}

/// SGBM's result on a dataset: its metrics and the time of its compute call.
#[derive(Debug, Clone)]
pub struct PeerRow {
    pub metrics: Metrics,
    pub invalid: f64,
    pub ms: f64,
}

/// The two image files the peer reads: the set's own, or (`eval --radiometry`) the engine's
/// images as the radiometry made them, written to a scratch folder and removed on drop.
pub struct PairFiles {
    pub left: PathBuf,
    pub right: PathBuf,
    written: bool,
}

impl PairFiles {
    /// The pair loaded from `dir` (`right`: the right view's file name); with a radiometry,
    /// `dataset`'s two images written as PNGs into `scratch`.
    pub fn of(
        dir: &Path,
        right: &str,
        dataset: &Dataset,
        radiometry: Radiometry,
        scratch: &Path,
    ) -> Result<Self, PeerError> {
        if radiometry == Radiometry::None {
            return Ok(Self {
                left: dir.join("im0.png"),
                right: dir.join(right),
                written: false,
            });
        }
        let [left, right] = ["left", "right"]
            .map(|side| scratch.join(format!("sweepdepth-peer-{}-{side}.png", std::process::id())));
        let files = Self {
            left,
            right,
            written: true,
        };
        for (image, path) in dataset.images.iter().zip([&files.left, &files.right]) {
            io::save_image(path, &image.to_rgb_image())
                .map_err(|e| PeerError::Run(e.to_string()))?;
        }
        Ok(files)
    }
}

impl Drop for PairFiles {
    fn drop(&mut self) {
        if self.written {
            let _ = std::fs::remove_file(&self.left);
            let _ = std::fs::remove_file(&self.right);
        }
    }
}

/// Runs SGBM 3-way on the dataset's pair (`pair`: its two image files) and scores it against
/// the dataset's ground truth.
pub fn sgbm_row(
    python: &Path,
    pair: &PairFiles,
    dataset: &Dataset,
    scratch: &Path,
) -> Result<PeerRow, PeerError> {
    let GroundTruth::Disparity {
        disparity_eval_px,
        focal_baseline_eval,
        border_px,
        ..
    } = &dataset.ground_truth
    else {
        return Err(PeerError::NotAPair(dataset.layout));
    };
    if dataset.layout != Layout::Middlebury2014 || dataset.rig.cameras.len() != 2 {
        return Err(PeerError::NotAPair(dataset.layout));
    }
    let left = dataset.rig.cameras[0].model.intrinsics;
    let right_k = dataset.rig.cameras[1].model.intrinsics;
    // Evaluation units are d + doffs (`middlebury2014`); doffs = cx1 - cx0.
    let doffs = right_k.cx_px - left.cx_px;
    let max_disparity = *focal_baseline_eval / dataset.params.min_depth_m - doffs;
    let num_disp = (max_disparity.ceil() as i64).max(16);
    let out = scratch.join(format!("sgbm-{}.pfm", std::process::id()));
    let script = scratch.join(format!("sweepdepth-sgbm-{}.py", std::process::id()));
    std::fs::write(&script, SGBM_SCRIPT)
        .map_err(|e| PeerError::Run(format!("writing {}: {e}", script.display())))?;
    let output = Command::new(python)
        .arg(&script)
        .arg("--pair")
        .arg(&pair.left)
        .arg(&pair.right)
        .args([
            "--num-disp",
            &num_disp.to_string(),
            "--mode",
            "3WAY",
            "--out",
        ])
        .arg(&out)
        .output()
        .map_err(|e| PeerError::Run(format!("running {}: {e}", python.display())));
    let _ = std::fs::remove_file(&script);
    let output = output?;
    if !output.status.success() {
        return Err(PeerError::Run(format!(
            "{} --pair failed: {}",
            script.display(),
            String::from_utf8_lossy(&output.stderr).trim()
        )));
    }
    let ms = serde_json::from_slice::<serde_json::Value>(&output.stdout)
        .ok()
        .and_then(|v| v.get("ms").and_then(|m| m.as_f64()))
        .unwrap_or(f64::NAN);
    let disparity = io::read_pfm(&out).map_err(|e| PeerError::Run(e.to_string()))?;
    let _ = std::fs::remove_file(&out);
    // SGBM's disparity as the depth the metrics expect.
    let depth_m = ImageF32 {
        width: disparity.width,
        height: disparity.height,
        data: disparity
            .data
            .iter()
            .map(|&d| {
                let d = f64::from(d) + doffs;
                if d.is_finite() && d > 0.0 {
                    (*focal_baseline_eval / d) as f32
                } else {
                    f32::NAN
                }
            })
            .collect(),
    };
    let ones = ImageF32 {
        width: depth_m.width,
        height: depth_m.height,
        data: vec![1.0; depth_m.data.len()],
    };
    let mut metrics = disparity_metrics(
        &depth_m,
        &ones,
        disparity_eval_px,
        *focal_baseline_eval,
        *border_px,
    )?;
    // SGBM gives no confidence to rank by.
    metrics.confidence_ranking = None;
    let invalid = depth_m.data.iter().filter(|z| !z.is_finite()).count() as f64
        / depth_m.data.len().max(1) as f64;
    Ok(PeerRow {
        metrics: Metrics::Disparity(metrics),
        invalid,
        ms,
    })
}
