//! Rectified stereo pairs in the Middlebury 2014 layout, which ETH3D's two-view benchmark uses
//! too: `im0.png` (the reference, left), `im1.png` (right), `calib.txt` (both cameras'
//! intrinsics, `doffs`, `baseline` in mm, `ndisp`, optionally `vmin` / `vmax`), the left view's
//! disparity `disp0GT.pfm` (ETH3D) or `disp0.pfm` (Middlebury 2014; `inf` = unknown) and, when
//! present, `mask0nocc.png` (255 = non-occluded). Unlike the older Middlebury sets these carry
//! a real calibration: the rig is built from it, so depth is in metres.
//!
//! A variant of the right view (`im1E.png`: another exposure, `im1L.png`: other lighting, as
//! the 2014 sets ship them) is chosen with [`super::LoadOptions::right_view`].

use std::path::Path;

use glam::DVec3;

use super::{folder_name, Dataset, DatasetError, GroundTruth, Layout, MAX_MIDDLEBURY_PLANES};
use crate::geometry::{CameraModel, PinholeIntrinsics, Reference, Rig, RigCamera, RigidTransform};
use crate::image::{ImageF32, Rgba8Image};
use crate::io;
use crate::sweep::SweepParams;

/// Whether a folder's file names are a Middlebury 2014 / ETH3D pair.
pub(super) fn is_middlebury2014(names: &[String]) -> bool {
    let has = |n: &str| names.iter().any(|m| m == n);
    has("calib.txt") && has("im0.png") && has("im1.png")
}

/// What `calib.txt` says.
#[derive(Debug, Clone, PartialEq)]
pub struct StereoCalib {
    /// Left and right camera matrices `[f 0 cx; 0 f cy; 0 0 1]` as (fx, fy, cx, cy).
    pub cam0: [f64; 4],
    pub cam1: [f64; 4],
    /// cx1 - cx0: a disparity d means depth `baseline f / (d + doffs)`.
    pub doffs: f64,
    /// Metres (the file's millimetres / 1000).
    pub baseline_m: f64,
    pub width: u32,
    pub height: u32,
    /// Upper bound on the disparity, px.
    pub ndisp: f64,
    /// Tight disparity bounds, when given.
    pub vmin: Option<f64>,
    pub vmax: Option<f64>,
}

/// Parses `calib.txt` (`key=value` lines; matrices as `[a b c; d e f; g h i]`).
pub fn parse_calib(text: &str, path: &Path) -> Result<StereoCalib, DatasetError> {
    let mut values = std::collections::BTreeMap::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let Some((key, value)) = line.split_once('=') else {
            return Err(DatasetError::Parse {
                path: path.to_path_buf(),
                line: i + 1,
                reason: format!("expected key=value, got {line:?}"),
            });
        };
        values.insert(key.trim().to_string(), (i + 1, value.trim().to_string()));
    }
    let missing = |key: &str| DatasetError::Parse {
        path: path.to_path_buf(),
        line: 0,
        reason: format!("no {key}= line"),
    };
    let number = |key: &str| -> Result<Option<f64>, DatasetError> {
        let Some((line, v)) = values.get(key) else {
            return Ok(None);
        };
        v.parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .map(Some)
            .ok_or_else(|| DatasetError::Parse {
                path: path.to_path_buf(),
                line: *line,
                reason: format!("{key}: not a number: {v:?}"),
            })
    };
    let required = |key: &str| number(key)?.ok_or_else(|| missing(key));
    let matrix = |key: &str| -> Result<[f64; 4], DatasetError> {
        let (line, v) = values.get(key).ok_or_else(|| missing(key))?;
        let bad = |reason: String| DatasetError::Parse {
            path: path.to_path_buf(),
            line: *line,
            reason: format!("{key}: {reason}"),
        };
        let inner = v
            .trim()
            .strip_prefix('[')
            .and_then(|s| s.strip_suffix(']'))
            .ok_or_else(|| bad(format!("expected [f 0 cx; 0 f cy; 0 0 1], got {v:?}")))?;
        let m: Vec<f64> = inner
            .split(|c: char| c == ';' || c.is_whitespace())
            .filter(|s| !s.is_empty())
            .map(|s| s.parse::<f64>().map_err(|e| bad(format!("{s:?}: {e}"))))
            .collect::<Result<_, _>>()?;
        if m.len() != 9 || m.iter().any(|x| !x.is_finite()) {
            return Err(bad(format!("expected 9 finite numbers, got {}", m.len())));
        }
        if m[0] <= 0.0 || m[4] <= 0.0 {
            return Err(bad("focal lengths must be positive".into()));
        }
        Ok([m[0], m[4], m[2], m[5]])
    };
    let size = |key: &str| -> Result<u32, DatasetError> {
        let v = required(key)?;
        if !(1.0..=65535.0).contains(&v) || v.fract() != 0.0 {
            return Err(DatasetError::Parse {
                path: path.to_path_buf(),
                line: values.get(key).map_or(0, |(l, _)| *l),
                reason: format!("{key}: not an image size: {v}"),
            });
        }
        Ok(v as u32)
    };
    let baseline_mm = required("baseline")?;
    if baseline_mm <= 0.0 {
        return Err(DatasetError::Parse {
            path: path.to_path_buf(),
            line: values.get("baseline").map_or(0, |(l, _)| *l),
            reason: format!("baseline must be positive, got {baseline_mm}"),
        });
    }
    let ndisp = required("ndisp")?;
    if ndisp < 1.0 {
        return Err(DatasetError::Parse {
            path: path.to_path_buf(),
            line: values.get("ndisp").map_or(0, |(l, _)| *l),
            reason: format!("ndisp must be at least 1, got {ndisp}"),
        });
    }
    Ok(StereoCalib {
        cam0: matrix("cam0")?,
        cam1: matrix("cam1")?,
        doffs: number("doffs")?.unwrap_or(0.0),
        baseline_m: baseline_mm / 1000.0,
        width: size("width")?,
        height: size("height")?,
        ndisp,
        vmin: number("vmin")?,
        vmax: number("vmax")?,
    })
}

impl StereoCalib {
    /// The disparity range swept, px: `vmin..vmax` with a margin of 2 px where the file gives
    /// them; else the ground truth's own range (`gt`: its smallest and largest finite value)
    /// with that margin where `ndisp` is no bound (ETH3D writes the image width); else
    /// `0.5..ndisp`.
    /// An image of the pair (`path`, `width` x `height`) against calib.txt's size.
    fn check_size(&self, path: &Path, width: u32, height: u32) -> Result<(), DatasetError> {
        if (width, height) == (self.width, self.height) {
            return Ok(());
        }
        Err(DatasetError::SizeMismatch {
            path: path.to_path_buf(),
            got_w: width,
            got_h: height,
            want_w: self.width,
            want_h: self.height,
            what: "calib.txt's width and height".into(),
        })
    }

    pub fn disparity_range(&self, gt: Option<(f64, f64)>) -> (f64, f64) {
        match (self.vmin, self.vmax, gt) {
            (Some(lo), Some(hi), _) if hi > lo => ((lo - 2.0).max(0.5), hi + 2.0),
            (_, _, Some((lo, hi))) if self.ndisp >= f64::from(self.width) / 2.0 && hi >= lo => {
                ((lo - 2.0).max(0.5), hi + 2.0)
            }
            _ => (0.5, self.ndisp.max(1.0)),
        }
    }
}

pub(super) fn load_middlebury2014(
    dir: &Path,
    names: &[String],
    right_view: Option<&str>,
) -> Result<Dataset, DatasetError> {
    let layout = Layout::Middlebury2014;
    let calib_path = dir.join("calib.txt");
    let text = std::fs::read_to_string(&calib_path).map_err(|source| {
        DatasetError::Io(io::IoError::Read {
            path: calib_path.clone(),
            source,
        })
    })?;
    let calib = parse_calib(&text, &calib_path)?;
    let right_name = right_view.unwrap_or("im1.png");
    if !names.iter().any(|n| n == right_name) {
        return Err(DatasetError::MissingReference {
            dir: dir.to_path_buf(),
            layout,
            reason: format!("no right view {right_name}"),
        });
    }
    let (images, rig) = pair(dir, &calib, &calib_path, right_name)?;

    let (gt, disparity_eval_px, nonocc_mask) = ground_truth(dir, names, &calib)?;
    let focal_baseline = calib.cam0[0] * calib.baseline_m;
    let ground_truth = GroundTruth::Disparity {
        disparity_eval_px,
        focal_baseline_eval: focal_baseline,
        border_px: 0,
        doffs_px: calib.doffs,
    };

    // One plane per pixel of disparity over the calibration's range (sub-pixel depth between
    // them), at most MAX_MIDDLEBURY_PLANES.
    let gt_range = gt.data.iter().filter(|d| d.is_finite() && **d > 0.0).fold(
        None,
        |r: Option<(f64, f64)>, &d| {
            let d = f64::from(d);
            Some(r.map_or((d, d), |(lo, hi)| (lo.min(d), hi.max(d))))
        },
    );
    let (lo, hi) = calib.disparity_range(gt_range);
    let num_planes = ((hi - lo).ceil() as u32 + 1).clamp(2, MAX_MIDDLEBURY_PLANES);
    let params = SweepParams {
        min_depth_m: focal_baseline / (hi + calib.doffs).max(1e-3),
        max_depth_m: focal_baseline / (lo + calib.doffs).max(1e-3),
        num_planes,
        ..SweepParams::default()
    };
    let ordered = params.min_depth_m < params.max_depth_m;
    if !ordered {
        return Err(DatasetError::Invalid {
            path: calib_path,
            reason: format!(
                "the disparity range {lo}..{hi} px with doffs {} gives no depth range",
                calib.doffs
            ),
        });
    }
    Ok(Dataset {
        name: folder_name(dir),
        layout,
        rig,
        images,
        ground_truth,
        nonocc_mask,
        params,
    })
}

/// The two views (`im0.png` and `right_name`) at calib.txt's size, and their rig: `im0` the
/// reference, the right camera `baseline` along +x.
fn pair(
    dir: &Path,
    calib: &StereoCalib,
    calib_path: &Path,
    right_name: &str,
) -> Result<(Vec<Rgba8Image>, Rig), DatasetError> {
    let mut images = Vec::with_capacity(2);
    for name in ["im0.png", right_name] {
        let path = dir.join(name);
        let image = io::load_rgba8(&path)?;
        calib.check_size(&path, image.width, image.height)?;
        images.push(image);
    }
    let camera = |name: &str, m: [f64; 4], x_m: f64| RigCamera {
        name: name.to_string(),
        model: CameraModel::pinhole(PinholeIntrinsics {
            width_px: calib.width,
            height_px: calib.height,
            fx_px: m[0],
            fy_px: m[1],
            cx_px: m[2],
            cy_px: m[3],
        }),
        cam_from_rig: RigidTransform {
            rotation: glam::DQuat::IDENTITY,
            translation: DVec3::new(-x_m, 0.0, 0.0),
        },
    };
    let right_stem = right_name.rsplit_once('.').map_or(right_name, |(s, _)| s);
    let rig = Rig::new(
        vec![
            camera("im0", calib.cam0, 0.0),
            camera(right_stem, calib.cam1, calib.baseline_m),
        ],
        Reference::Camera(0),
    )
    .map_err(|source| DatasetError::Geometry {
        path: calib_path.to_path_buf(),
        source,
    })?;

    Ok((images, rig))
}

/// The left view's ground-truth disparity (as read), in evaluation units `d + doffs` (NaN
/// where unknown), and the non-occluded mask when the set has `mask0nocc.png`.
fn ground_truth(
    dir: &Path,
    names: &[String],
    calib: &StereoCalib,
) -> Result<(ImageF32, ImageF32, Option<Vec<bool>>), DatasetError> {
    let layout = Layout::Middlebury2014;
    // Ground truth: disparity d (px) of the left view; depth f B / (d + doffs). In evaluation
    // units d + doffs, so that an estimated depth z maps to f B / z.
    let gt_name = ["disp0GT.pfm", "disp0.pfm"]
        .into_iter()
        .find(|n| names.iter().any(|m| m == n))
        .ok_or_else(|| DatasetError::MissingGroundTruth {
            dir: dir.to_path_buf(),
            layout,
            reason: "no disp0GT.pfm or disp0.pfm".into(),
        })?;
    let gt_path = dir.join(gt_name);
    let gt = io::read_pfm(&gt_path)?;
    calib.check_size(&gt_path, gt.width, gt.height)?;
    let doffs = calib.doffs as f32;
    let disparity_eval_px = ImageF32 {
        width: gt.width,
        height: gt.height,
        data: gt
            .data
            .iter()
            .map(|&d| {
                if d.is_finite() && d > 0.0 {
                    d + doffs
                } else {
                    f32::NAN
                }
            })
            .collect(),
    };
    let nonocc_mask = if names.iter().any(|n| n == "mask0nocc.png") {
        let mask_path = dir.join("mask0nocc.png");
        let mask = io::load_gray_u8(&mask_path)?;
        calib.check_size(&mask_path, mask.width(), mask.height())?;
        Some(mask.as_raw().iter().map(|&v| v == 255).collect())
    } else {
        None
    };
    Ok((gt, disparity_eval_px, nonocc_mask))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_an_eth3d_and_a_middlebury_calib() {
        let eth3d = "cam0=[541.764 0 553.869; 0 541.764 232.396; 0 0 1]\n\
                     cam1=[541.764 0 553.869; 0 541.764 232.396; 0 0 1]\n\
                     doffs=0\nbaseline=59.9283\nwidth=942\nheight=489\nndisp=64\nisint=0\n\
                     vmin=8\nvmax=38\ndyavg=0\ndymax=0\n";
        let c = parse_calib(eth3d, Path::new("calib.txt")).unwrap();
        assert_eq!(c.cam0, [541.764, 541.764, 553.869, 232.396]);
        assert!((c.baseline_m - 0.0599283).abs() < 1e-12);
        assert_eq!((c.width, c.height), (942, 489));
        assert_eq!(c.disparity_range(None), (6.0, 40.0));
        let mid = "cam0=[1758.23 0 953.34; 0 1758.23 552.29; 0 0 1]\n\
                   cam1=[1758.23 0 953.34; 0 1758.23 552.29; 0 0 1]\n\
                   doffs=0\nbaseline=97.99\nwidth=1920\nheight=1080\nndisp=290\n";
        let c = parse_calib(mid, Path::new("calib.txt")).unwrap();
        assert_eq!(c.disparity_range(Some((10.0, 200.0))), (0.5, 290.0));
        // ETH3D as distributed: ndisp = the width, no vmin / vmax: the ground truth's range.
        let wide = mid.replace("ndisp=290", "ndisp=1920");
        let c = parse_calib(&wide, Path::new("calib.txt")).unwrap();
        assert_eq!(c.disparity_range(Some((10.0, 200.0))), (8.0, 202.0));
        assert!(parse_calib("cam0=[1 2]\n", Path::new("c")).is_err());
        assert!(parse_calib(
            &eth3d.replace("baseline=59.9283", "baseline=-1"),
            Path::new("c")
        )
        .is_err());
    }
}
