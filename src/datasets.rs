//! Dataset loaders: a folder in, a rig + images + ground truth + sweep parameters out.
//!
//! The layout is detected from file names only (see [`Layout`]); any folder that follows one
//! of the layouts loads, not just the shipped copies in `shared/data`.
//!
//! Middlebury stereo sets (2001, 2003, 2005/2006) come without calibration: the views are
//! rectified and equally spaced along x, so a synthetic calibration is built. Every view gets
//! the same pinhole intrinsics (f = image width in pixels, principal point at the image centre),
//! identity rotation, and view `k` sits at x = k · B with B = [`MIDDLEBURY_BASELINE_M`]. A
//! reference pixel at x then appears at x − (k − r) · f B / z in view k (higher index = further
//! right), the sign convention verified in the `SOURCE.md` files. Disparities are reported in
//! "evaluation units": the disparity between the two views the ground truth is defined for
//! (adjacent views for 2001, four view steps for 2003 and 2005/2006), `d_eval = focal_baseline_eval / z`.

use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

use glam::{DMat3, DVec3};

use crate::geometry::{
    CameraModel, GeometryError, PinholeIntrinsics, Reference, Rig, RigCamera, RigidTransform,
};
use crate::image::{ImageF32, Rgba8Image};
use crate::io::{self, IoError};
use crate::sweep::SweepParams;

/// Baseline between adjacent views of the synthetic Middlebury calibration, metres.
pub const MIDDLEBURY_BASELINE_M: f64 = 0.1;
/// Planes swept for ICL-NUIM and the multi-view rings.
pub const CALIBRATED_NUM_PLANES: u32 = 96;
/// At most this many planes for the Middlebury sets (0.25 px steps otherwise).
pub const MAX_MIDDLEBURY_PLANES: u32 = 128;
/// Cameras used from a multi-view ring besides the reference.
pub const RING_NEIGHBOURS: usize = 4;

/// The folder layouts [`load_dataset`] knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Layout {
    /// `<prefix>.colN.<ext>` views + `truedisp.<...>.colR.<ext>` (value / 16 = adjacent-view px).
    Middlebury2001,
    /// `imN.<ext>` views + `dispN.<ext>` (value / 4 = disparity over 4 view steps).
    Middlebury2003,
    /// `viewN.<ext>` views + `dispN.<ext>` (ThirdSize: value / 3 = disparity over 4 view steps).
    Middlebury2005,
    /// POV-Ray frames `<stem>_NNNN.png` + `.depth` (ray distance, m) + `.txt` (camera).
    IclNuim,
    /// Middlebury multi-view stereo: `<name>_par.txt` (K, R, t per image) + images.
    MiddleburyMultiView,
}

impl Layout {
    pub const ALL: [Layout; 5] = [
        Layout::Middlebury2001,
        Layout::Middlebury2003,
        Layout::Middlebury2005,
        Layout::IclNuim,
        Layout::MiddleburyMultiView,
    ];

    pub fn name(&self) -> &'static str {
        match self {
            Layout::Middlebury2001 => "middlebury2001",
            Layout::Middlebury2003 => "middlebury2003",
            Layout::Middlebury2005 => "middlebury2005",
            Layout::IclNuim => "icl-nuim",
            Layout::MiddleburyMultiView => "middlebury-mview",
        }
    }

    /// What the files look like, for error messages.
    pub fn pattern(&self) -> &'static str {
        match self {
            Layout::Middlebury2001 => "<prefix>.colN.ppm|png + truedisp.<...>.colR.pgm|png",
            Layout::Middlebury2003 => "imN.ppm|png + dispN.pgm|png",
            Layout::Middlebury2005 => "viewN.png + dispN.png (2005/2006)",
            Layout::IclNuim => "<name>_NNNN.png + <name>_NNNN.depth + <name>_NNNN.txt",
            Layout::MiddleburyMultiView => "<name>_par.txt + the images it lists",
        }
    }

    fn known_list() -> String {
        Layout::ALL
            .iter()
            .map(|l| format!("{} ({})", l.name(), l.pattern()))
            .collect::<Vec<_>>()
            .join("; ")
    }
}

impl fmt::Display for Layout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Ground truth for the reference view.
#[derive(Debug, Clone, PartialEq)]
pub enum GroundTruth {
    /// Disparity in evaluation units (NaN = unknown); an estimated depth z maps to
    /// `focal_baseline_eval / z` in the same units. Pixels closer than `border_px` to the image
    /// edge are not evaluated.
    Disparity {
        disparity_eval_px: ImageF32,
        focal_baseline_eval: f64,
        border_px: u32,
    },
    /// z-depth along the reference optical axis, metres (NaN = unknown).
    Depth {
        depth_m: ImageF32,
    },
    None,
}

/// One loaded dataset.
#[derive(Debug, Clone)]
pub struct Dataset {
    /// The folder name.
    pub name: String,
    pub layout: Layout,
    pub rig: Rig,
    /// One per rig camera, in rig order.
    pub images: Vec<Rgba8Image>,
    pub ground_truth: GroundTruth,
    /// Disparity ground truth only, when the evaluation pair's other view has ground truth too
    /// (Middlebury 2003 Teddy disp2/disp6, 2005 disp1/disp5; not Tsukuba): true where the
    /// reference pixel is not occluded, by a left-right check of the two ground-truth maps (see
    /// [`nonocc_mask`]). `None` otherwise.
    pub nonocc_mask: Option<Vec<bool>>,
    /// `SweepParams::default()` with the dataset's depth range and plane count.
    pub params: SweepParams,
}

impl Dataset {
    /// The reference camera's index in `rig.cameras`.
    pub fn reference_index(&self) -> usize {
        self.rig.reference_index().unwrap_or(0)
    }

    pub fn reference_size(&self) -> (u32, u32) {
        let k = self.rig.reference_model().intrinsics;
        (k.width_px, k.height_px)
    }
}

/// Options for [`load_dataset_with`].
#[derive(Debug, Clone, Default)]
pub struct LoadOptions {
    /// Reference view by file name or file stem (multi-view rings and ICL-NUIM only; the
    /// Middlebury stereo sets take the view that has ground truth).
    pub reference: Option<String>,
}

/// Errors loading a dataset; every message names the folder or file.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error("{dir}: cannot list the folder: {source}")]
    ListDir {
        dir: PathBuf,
        source: std::io::Error,
    },
    #[error("{dir}: unknown dataset layout. Files seen: {files}. Known layouts: {known}")]
    UnknownLayout {
        dir: PathBuf,
        files: String,
        known: String,
    },
    #[error("{dir}: ambiguous {layout} folder: {reason}")]
    Ambiguous {
        dir: PathBuf,
        layout: Layout,
        reason: String,
    },
    #[error("{dir}: {layout} folder without ground truth: {reason}")]
    MissingGroundTruth {
        dir: PathBuf,
        layout: Layout,
        reason: String,
    },
    #[error("{dir}: {layout} folder: missing reference view: {reason}")]
    MissingReference {
        dir: PathBuf,
        layout: Layout,
        reason: String,
    },
    #[error("{path}: image is {got_w}x{got_h}, expected {want_w}x{want_h} ({what})")]
    SizeMismatch {
        path: PathBuf,
        got_w: u32,
        got_h: u32,
        want_w: u32,
        want_h: u32,
        what: String,
    },
    #[error("{path}:{line}: {reason}")]
    Parse {
        path: PathBuf,
        line: usize,
        reason: String,
    },
    #[error("{path}: {source}")]
    Geometry {
        path: PathBuf,
        source: GeometryError,
    },
    #[error("{path}: {reason}")]
    Invalid { path: PathBuf, reason: String },
    #[error(transparent)]
    Io(#[from] IoError),
}

// ---------------------------------------------------------------------------------------------
// Entry points

/// Loads the dataset in `dir`, detecting its layout from the file names.
pub fn load_dataset(dir: &Path) -> Result<Dataset, DatasetError> {
    load_dataset_with(dir, &LoadOptions::default())
}

/// [`load_dataset`] with options.
pub fn load_dataset_with(dir: &Path, options: &LoadOptions) -> Result<Dataset, DatasetError> {
    let names = list_files(dir)?;
    let layout = detect_layout_from_names(&names).ok_or_else(|| unknown_layout(dir, &names))?;
    if options.reference.is_some()
        && matches!(
            layout,
            Layout::Middlebury2001 | Layout::Middlebury2003 | Layout::Middlebury2005
        )
    {
        return Err(DatasetError::Invalid {
            path: dir.to_path_buf(),
            reason: format!(
                "a reference override is not supported for {layout}: the reference is the view with ground truth"
            ),
        });
    }
    match layout {
        Layout::Middlebury2001 | Layout::Middlebury2003 | Layout::Middlebury2005 => {
            load_middlebury(dir, &names, layout)
        }
        Layout::IclNuim => load_icl(dir, &names, options),
        Layout::MiddleburyMultiView => load_ring(dir, &names, options),
    }
}

/// The layout of `dir`, from its file names only.
pub fn detect_layout(dir: &Path) -> Result<Layout, DatasetError> {
    let names = list_files(dir)?;
    detect_layout_from_names(&names).ok_or_else(|| unknown_layout(dir, &names))
}

/// The layout a list of file names follows, if any. Checked in this order: multi-view ring
/// (`*_par.txt`), ICL-NUIM, Middlebury 2001, 2005/2006 (`viewN`), 2003 (`imN`).
pub fn detect_layout_from_names(names: &[String]) -> Option<Layout> {
    if names.iter().any(|n| n.ends_with("_par.txt")) {
        return Some(Layout::MiddleburyMultiView);
    }
    let icl = icl_frames(names);
    if icl.len() >= 2 && icl.values().any(|(_, f)| f.has_depth) {
        return Some(Layout::IclNuim);
    }
    let (groups, _) = middlebury2001_files(names);
    if !groups.is_empty() {
        return Some(Layout::Middlebury2001);
    }
    if numbered_images(names, "view").len() >= 2 {
        return Some(Layout::Middlebury2005);
    }
    if numbered_images(names, "im").len() >= 2 {
        return Some(Layout::Middlebury2003);
    }
    None
}

// ---------------------------------------------------------------------------------------------
// File names

fn list_files(dir: &Path) -> Result<Vec<String>, DatasetError> {
    let list_err = |source| DatasetError::ListDir {
        dir: dir.to_path_buf(),
        source,
    };
    let mut names = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(list_err)? {
        let entry = entry.map_err(list_err)?;
        let path = entry.path();
        if path.is_file() {
            names.push(entry.file_name().to_string_lossy().into_owned());
        }
    }
    names.sort();
    Ok(names)
}

fn unknown_layout(dir: &Path, names: &[String]) -> DatasetError {
    const SHOWN: usize = 40;
    let mut files = if names.is_empty() {
        "(none)".to_string()
    } else {
        names
            .iter()
            .take(SHOWN)
            .cloned()
            .collect::<Vec<_>>()
            .join(", ")
    };
    if names.len() > SHOWN {
        files.push_str(&format!(", ... and {} more", names.len() - SHOWN));
    }
    DatasetError::UnknownLayout {
        dir: dir.to_path_buf(),
        files,
        known: Layout::known_list(),
    }
}

fn is_image_ext(ext: &str) -> bool {
    matches!(
        ext.to_ascii_lowercase().as_str(),
        "png" | "ppm" | "pgm" | "pnm"
    )
}

/// `(stem, ext)` of a file name with an image extension.
fn split_image_name(name: &str) -> Option<(&str, &str)> {
    let (stem, ext) = name.rsplit_once('.')?;
    is_image_ext(ext).then_some((stem, ext))
}

/// `prefixN` → N.
fn number_after(stem: &str, prefix: &str) -> Option<u32> {
    let digits = stem.strip_prefix(prefix)?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) || digits.len() > 9 {
        return None;
    }
    digits.parse().ok()
}

/// `prefixN.<image ext>` files by N. With several files for one N (im2.ppm and im2.png) the
/// first in name order is kept.
fn numbered_images(names: &[String], prefix: &str) -> BTreeMap<u32, String> {
    let mut out = BTreeMap::new();
    for name in names {
        if let Some((stem, _)) = split_image_name(name) {
            if let Some(n) = number_after(stem, prefix) {
                out.entry(n).or_insert_with(|| name.clone());
            }
        }
    }
    out
}

/// Middlebury 2001: views `<prefix>.colN.<ext>` grouped by prefix, and ground truth
/// `truedisp.<mid>.colR.<ext>` as (mid, R, name).
#[allow(clippy::type_complexity)]
fn middlebury2001_files(
    names: &[String],
) -> (
    BTreeMap<String, BTreeMap<u32, String>>,
    Vec<(String, u32, String)>,
) {
    let mut views: BTreeMap<String, BTreeMap<u32, String>> = BTreeMap::new();
    let mut truth = Vec::new();
    for name in names {
        let Some((stem, _)) = split_image_name(name) else {
            continue;
        };
        let Some((prefix, col)) = stem.rsplit_once('.') else {
            continue;
        };
        let Some(n) = number_after(col, "col") else {
            continue;
        };
        if prefix == "truedisp" || prefix.starts_with("truedisp.") {
            let mid = prefix
                .trim_start_matches("truedisp")
                .trim_start_matches('.');
            truth.push((mid.to_string(), n, name.clone()));
        } else {
            views
                .entry(prefix.to_string())
                .or_default()
                .entry(n)
                .or_insert_with(|| name.clone());
        }
    }
    views.retain(|_, v| v.len() >= 2);
    (views, truth)
}

#[derive(Debug, Default, Clone)]
struct IclFrame {
    png: Option<String>,
    txt: Option<String>,
    has_depth: bool,
}

/// ICL-NUIM frames `<stem>_NNNN` that have both a `.png` and a `.txt`, by number.
fn icl_frames(names: &[String]) -> BTreeMap<u64, (String, IclFrame)> {
    let mut by_stem: BTreeMap<String, IclFrame> = BTreeMap::new();
    for name in names {
        let Some((stem, ext)) = name.rsplit_once('.') else {
            continue;
        };
        let entry = by_stem.entry(stem.to_string()).or_default();
        match ext {
            "png" => entry.png = Some(name.clone()),
            "txt" => entry.txt = Some(name.clone()),
            "depth" => entry.has_depth = true,
            _ => {}
        }
    }
    let mut out = BTreeMap::new();
    for (stem, frame) in by_stem {
        if frame.png.is_none() || frame.txt.is_none() {
            continue;
        }
        let Some((_, digits)) = stem.rsplit_once('_') else {
            continue;
        };
        if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) || digits.len() > 18 {
            continue;
        }
        if let Ok(n) = digits.parse::<u64>() {
            out.entry(n).or_insert((stem, frame));
        }
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Middlebury stereo (2001, 2003, 2005/2006)

/// How one Middlebury edition encodes its ground truth.
struct MiddleburyEncoding {
    /// View steps between the two views the evaluation disparity is defined for.
    steps_eval: f64,
    /// Ground-truth value / this = disparity in evaluation units.
    divisor: f64,
    /// Published search range: max disparity between adjacent views, px.
    max_adjacent_px: f64,
    border_px: u32,
}

fn middlebury_encoding(layout: Layout, width: u32) -> MiddleburyEncoding {
    let w = f64::from(width);
    match layout {
        // Tsukuba: value / 16 = adjacent-view disparity (verified); search range 0..16 at 384 px.
        Layout::Middlebury2001 => MiddleburyEncoding {
            steps_eval: 1.0,
            divisor: 16.0,
            max_adjacent_px: 16.0 * w / 384.0,
            border_px: 18,
        },
        // value / 4 = disparity between views 2 and 6 (verified on quarter size, 450 px).
        Layout::Middlebury2003 => MiddleburyEncoding {
            steps_eval: 4.0,
            divisor: 4.0,
            max_adjacent_px: w * 16.0 / 450.0,
            border_px: 10,
        },
        // The stored values are in full-resolution (~1390 px wide) pixels of the 4-step pair.
        // Only ThirdSize (value / 3) was verified (shared/data SOURCE.md); HalfSize (/ 2) and
        // FullSize (/ 1) follow from round(full width / width) and were NOT verified.
        _ => {
            let divisor = if width < 600 {
                3.0
            } else if width < 1000 {
                2.0
            } else {
                1.0
            };
            MiddleburyEncoding {
                steps_eval: 4.0,
                divisor,
                max_adjacent_px: w * 20.0 / 447.0,
                border_px: 10,
            }
        }
    }
}

fn load_middlebury(dir: &Path, names: &[String], layout: Layout) -> Result<Dataset, DatasetError> {
    // view number -> image file; ground-truth view number -> GT file.
    let (views, truth): (BTreeMap<u32, String>, BTreeMap<u32, String>) = match layout {
        Layout::Middlebury2001 => {
            let (groups, truth) = middlebury2001_files(names);
            if truth.is_empty() {
                return Err(DatasetError::MissingGroundTruth {
                    dir: dir.to_path_buf(),
                    layout,
                    reason: "no truedisp.<...>.colR.pgm|png file".into(),
                });
            }
            // Views whose prefix ends with the ground truth's middle part (row3 of truedisp.row3.col3).
            let matching: Vec<(&String, &BTreeMap<u32, String>)> = groups
                .iter()
                .filter(|(prefix, _)| {
                    truth.iter().any(|(mid, _, _)| {
                        mid.is_empty()
                            || prefix.as_str() == mid
                            || prefix.ends_with(&format!(".{mid}"))
                    })
                })
                .collect();
            let (prefix, views) = match matching.as_slice() {
                [one] => *one,
                [] => {
                    return Err(DatasetError::MissingReference {
                        dir: dir.to_path_buf(),
                        layout,
                        reason: format!(
                            "no view sequence matches the ground truth file(s) {}",
                            truth
                                .iter()
                                .map(|t| t.2.as_str())
                                .collect::<Vec<_>>()
                                .join(", ")
                        ),
                    })
                }
                many => {
                    return Err(DatasetError::Ambiguous {
                        dir: dir.to_path_buf(),
                        layout,
                        reason: format!(
                            "several view sequences match the ground truth: {}",
                            many.iter()
                                .map(|(p, _)| p.as_str())
                                .collect::<Vec<_>>()
                                .join(", ")
                        ),
                    })
                }
            };
            let truth = truth
                .iter()
                .filter(|(mid, _, _)| {
                    mid.is_empty() || prefix == mid || prefix.ends_with(&format!(".{mid}"))
                })
                .map(|(_, n, name)| (*n, name.clone()))
                .collect();
            (views.clone(), truth)
        }
        Layout::Middlebury2003 => (numbered_images(names, "im"), numbered_images(names, "disp")),
        _ => (
            numbered_images(names, "view"),
            numbered_images(names, "disp"),
        ),
    };
    if truth.is_empty() {
        return Err(DatasetError::MissingGroundTruth {
            dir: dir.to_path_buf(),
            layout,
            reason: format!("no ground-truth file (expected {})", layout.pattern()),
        });
    }
    // Reference: the lowest-numbered view that has both ground truth and an image.
    let Some((&reference_view, truth_name)) = truth.iter().find(|(n, _)| views.contains_key(n))
    else {
        return Err(DatasetError::MissingReference {
            dir: dir.to_path_buf(),
            layout,
            reason: format!(
                "ground truth exists for view(s) {} but there is no image for any of them (views: {})",
                truth.keys().map(|n| n.to_string()).collect::<Vec<_>>().join(", "),
                views.keys().map(|n| n.to_string()).collect::<Vec<_>>().join(", ")
            ),
        });
    };
    let truth_path = dir.join(truth_name);

    let mut images = Vec::with_capacity(views.len());
    let mut view_numbers = Vec::with_capacity(views.len());
    let mut first: Option<(PathBuf, u32, u32)> = None;
    for (&n, name) in &views {
        let path = dir.join(name);
        let image = io::load_rgba8(&path)?;
        match &first {
            None => first = Some((path.clone(), image.width, image.height)),
            Some((first_path, w, h)) => {
                if (image.width, image.height) != (*w, *h) {
                    return Err(DatasetError::SizeMismatch {
                        path,
                        got_w: image.width,
                        got_h: image.height,
                        want_w: *w,
                        want_h: *h,
                        what: format!("the size of {}", first_path.display()),
                    });
                }
            }
        }
        images.push(image);
        view_numbers.push(n);
    }
    let Some((_, width, height)) = first else {
        return Err(DatasetError::MissingReference {
            dir: dir.to_path_buf(),
            layout,
            reason: "no views".into(),
        });
    };
    let Some(reference) = view_numbers.iter().position(|&n| n == reference_view) else {
        return Err(DatasetError::MissingReference {
            dir: dir.to_path_buf(),
            layout,
            reason: format!("view {reference_view} not loaded"),
        });
    };

    // Synthetic rectified calibration.
    let f = f64::from(width);
    let intrinsics = PinholeIntrinsics {
        width_px: width,
        height_px: height,
        fx_px: f,
        fy_px: f,
        cx_px: (f64::from(width) - 1.0) / 2.0,
        cy_px: (f64::from(height) - 1.0) / 2.0,
    };
    let cameras: Vec<RigCamera> = views
        .iter()
        .zip(&view_numbers)
        .map(|((_, name), &n)| RigCamera {
            name: name
                .rsplit_once('.')
                .map_or(name.as_str(), |(stem, _)| stem)
                .to_string(),
            model: CameraModel::pinhole(intrinsics),
            cam_from_rig: RigidTransform {
                rotation: glam::DQuat::IDENTITY,
                translation: DVec3::new(-f64::from(n) * MIDDLEBURY_BASELINE_M, 0.0, 0.0),
            },
        })
        .collect();
    let rig = Rig::new(cameras, Reference::Camera(reference)).map_err(|source| {
        DatasetError::Geometry {
            path: dir.to_path_buf(),
            source,
        }
    })?;

    // Ground truth.
    let encoding = middlebury_encoding(layout, width);
    let gt = io::load_gray_u8(&truth_path)?;
    if gt.dimensions() != (width, height) {
        return Err(DatasetError::SizeMismatch {
            path: truth_path,
            got_w: gt.width(),
            got_h: gt.height(),
            want_w: width,
            want_h: height,
            what: "the size of the views".into(),
        });
    }
    let disparity_eval_px = gt_disparity_image(&gt, encoding.divisor);
    // The evaluation pair's other view (steps_eval views to the right) with ground truth of its own.
    let partner_view = reference_view + encoding.steps_eval as u32;
    let nonocc_mask = match truth.get(&partner_view) {
        Some(partner_name) if views.contains_key(&partner_view) => {
            let partner_path = dir.join(partner_name);
            let partner = io::load_gray_u8(&partner_path)?;
            if partner.dimensions() != (width, height) {
                return Err(DatasetError::SizeMismatch {
                    path: partner_path,
                    got_w: partner.width(),
                    got_h: partner.height(),
                    want_w: width,
                    want_h: height,
                    what: "the size of the views".into(),
                });
            }
            let partner_eval_px = gt_disparity_image(&partner, encoding.divisor);
            Some(nonocc_mask(&disparity_eval_px, &partner_eval_px))
        }
        _ => None,
    };
    let focal_baseline = f * MIDDLEBURY_BASELINE_M;
    let ground_truth = GroundTruth::Disparity {
        disparity_eval_px,
        focal_baseline_eval: encoding.steps_eval * focal_baseline,
        border_px: encoding.border_px,
    };

    // Published search range [0.5, max] adjacent-view px, 0.5 eval-px steps (sub-pixel
    // refinement does the rest), at most MAX_MIDDLEBURY_PLANES planes.
    let min_adjacent_px = 0.5;
    let max_adjacent_px = encoding.max_adjacent_px.max(min_adjacent_px + 0.25);
    let range_eval_px = (max_adjacent_px - min_adjacent_px) * encoding.steps_eval;
    let num_planes = ((range_eval_px * 2.0).ceil() as u32 + 1).min(MAX_MIDDLEBURY_PLANES);
    let params = SweepParams {
        min_depth_m: focal_baseline / max_adjacent_px,
        max_depth_m: focal_baseline / min_adjacent_px,
        num_planes,
        ..SweepParams::default()
    };

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

/// A Middlebury ground-truth map in evaluation units (value / divisor; 0 = unknown = NaN).
fn gt_disparity_image(gt: &image::GrayImage, divisor: f64) -> ImageF32 {
    ImageF32 {
        width: gt.width(),
        height: gt.height(),
        data: gt
            .as_raw()
            .iter()
            .map(|&v| {
                if v == 0 {
                    f32::NAN
                } else {
                    (f64::from(v) / divisor) as f32
                }
            })
            .collect(),
    }
}

/// Largest disagreement (evaluation px) of the left-right check in [`nonocc_mask`].
pub const NONOCC_TOLERANCE_PX: f32 = 1.0;

/// Non-occluded pixels of the left view of a rectified pair from the ground truth of both views
/// (same units; NaN = unknown): left pixel x with disparity d is non-occluded when the right
/// view's ground truth at round(x − d) is known and within [`NONOCC_TOLERANCE_PX`] of d. A left
/// pixel without ground truth, or one that falls outside the right image, is not.
pub fn nonocc_mask(left: &ImageF32, right: &ImageF32) -> Vec<bool> {
    let (w, h) = (left.width as usize, left.height as usize);
    let mut mask = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let d = left.data[y * w + x];
            if !d.is_finite() {
                continue;
            }
            let xr = (x as f32 - d).round();
            if xr < 0.0 || xr >= w as f32 {
                continue;
            }
            let dr = right.data[y * w + xr as usize];
            mask[y * w + x] = dr.is_finite() && (d - dr).abs() <= NONOCC_TOLERANCE_PX;
        }
    }
    mask
}

fn folder_name(dir: &Path) -> String {
    let canonical = dir.canonicalize().unwrap_or_else(|_| dir.to_path_buf());
    canonical
        .file_name()
        .or_else(|| dir.file_name())
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "dataset".to_string())
}

// ---------------------------------------------------------------------------------------------
// ICL-NUIM (POV-Ray frames)

/// A POV-Ray camera from an ICL-NUIM `.txt` file (MATLAB syntax).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PovRayCamera {
    pub pos: DVec3,
    pub dir: DVec3,
    pub up: DVec3,
    pub right: DVec3,
}

/// Parses `cam_pos = [x, y, z]';` style lines; `cam_pos`, `cam_dir`, `cam_up` and
/// `cam_right` are required, other fields are ignored.
pub fn parse_povray_camera(path: &Path, text: &str) -> Result<PovRayCamera, DatasetError> {
    let mut fields: BTreeMap<&str, DVec3> = BTreeMap::new();
    for (i, line) in text.lines().enumerate() {
        let parse_err = |reason: String| DatasetError::Parse {
            path: path.to_path_buf(),
            line: i + 1,
            reason,
        };
        let line = line.trim();
        if line.is_empty() || line.starts_with('%') {
            continue;
        }
        let Some((key, value)) = line.split_once('=') else {
            continue;
        };
        let key = key.trim();
        if !matches!(key, "cam_pos" | "cam_dir" | "cam_up" | "cam_right") {
            continue;
        }
        let value = value
            .trim()
            .trim_end_matches(';')
            .trim_end()
            .trim_end_matches('\'')
            .trim();
        let inner = value
            .strip_prefix('[')
            .and_then(|v| v.strip_suffix(']'))
            .ok_or_else(|| parse_err(format!("{key}: expected [x, y, z], got '{value}'")))?;
        let numbers: Vec<f64> = inner
            .split(|c: char| c == ',' || c == ';' || c.is_whitespace())
            .filter(|s| !s.is_empty())
            .map(|s| {
                s.parse::<f64>()
                    .map_err(|e| parse_err(format!("{key}: '{s}' is not a number ({e})")))
            })
            .collect::<Result<_, _>>()?;
        if numbers.len() != 3 || numbers.iter().any(|v| !v.is_finite()) {
            return Err(parse_err(format!(
                "{key}: expected 3 finite numbers, got {numbers:?}"
            )));
        }
        fields.insert(key, DVec3::new(numbers[0], numbers[1], numbers[2]));
    }
    let get = |key: &str| {
        fields.get(key).copied().ok_or_else(|| DatasetError::Parse {
            path: path.to_path_buf(),
            line: 0,
            reason: format!("field '{key}' is missing"),
        })
    };
    Ok(PovRayCamera {
        pos: get("cam_pos")?,
        dir: get("cam_dir")?,
        up: get("cam_up")?,
        right: get("cam_right")?,
    })
}

/// The camera model and `cam_from_world` of a POV-Ray camera rendering a `width` x `height`
/// image (ICL-NUIM SOURCE.md): fx = W|dir|/|right|, fy = −H|dir|/|up| (negative: the camera y
/// axis points up), cx = (W−1)/2, cy = (H−1)/2; z = dir/|dir|, x = normalize(up × z),
/// y = z × x, R_wc = [x y z], X_c = R_wcᵀ (X_w − C).
pub fn povray_camera_model(
    path: &Path,
    camera: &PovRayCamera,
    width: u32,
    height: u32,
) -> Result<(CameraModel, RigidTransform), DatasetError> {
    let invalid = |reason: &str| DatasetError::Invalid {
        path: path.to_path_buf(),
        reason: reason.to_string(),
    };
    let dir_len = camera.dir.length();
    let up_len = camera.up.length();
    let right_len = camera.right.length();
    if !(dir_len > 1e-12 && up_len > 1e-12 && right_len > 1e-12) {
        return Err(invalid("cam_dir, cam_up and cam_right must be non-zero"));
    }
    let (w, h) = (f64::from(width), f64::from(height));
    let intrinsics = PinholeIntrinsics {
        width_px: width,
        height_px: height,
        fx_px: w * dir_len / right_len,
        fy_px: -h * dir_len / up_len,
        cx_px: (w - 1.0) / 2.0,
        cy_px: (h - 1.0) / 2.0,
    };
    let z = camera.dir / dir_len;
    let x = camera.up.cross(z);
    if x.length() < 1e-9 {
        return Err(invalid("cam_up is parallel to cam_dir"));
    }
    let x = x.normalize();
    let y = z.cross(x);
    let r_wc = DMat3::from_cols(x, y, z);
    let r_cw = r_wc.transpose();
    let cam_from_world = RigidTransform::from_matrix_translation(
        &path.display().to_string(),
        r_cw,
        -(r_cw * camera.pos),
    )
    .map_err(|source| DatasetError::Geometry {
        path: path.to_path_buf(),
        source,
    })?;
    Ok((CameraModel::pinhole(intrinsics), cam_from_world))
}

/// Reads an ICL-NUIM `.depth` file (row-major ray distances, metres) and converts it to
/// z-depth with `intrinsics`; non-positive or non-finite values become NaN.
pub fn read_icl_depth(
    path: &Path,
    intrinsics: &PinholeIntrinsics,
) -> Result<ImageF32, DatasetError> {
    let text = std::fs::read_to_string(path).map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let (w, h) = (intrinsics.width_px as usize, intrinsics.height_px as usize);
    let mut data = Vec::with_capacity(w * h);
    for (i, line) in text.lines().enumerate() {
        for token in line.split_ascii_whitespace() {
            let r: f64 = token.parse().map_err(|e| DatasetError::Parse {
                path: path.to_path_buf(),
                line: i + 1,
                reason: format!("'{token}' is not a number ({e})"),
            })?;
            if data.len() == w * h {
                return Err(DatasetError::Invalid {
                    path: path.to_path_buf(),
                    reason: format!("more than {w}x{h} = {} values", w * h),
                });
            }
            let idx = data.len();
            let (u, v) = ((idx % w) as f64, (idx / w) as f64);
            let a = (u - intrinsics.cx_px) / intrinsics.fx_px;
            let b = (v - intrinsics.cy_px) / intrinsics.fy_px;
            let z = r / (a * a + b * b + 1.0).sqrt();
            data.push(if z.is_finite() && z > 0.0 {
                z as f32
            } else {
                f32::NAN
            });
        }
    }
    if data.len() != w * h {
        return Err(DatasetError::Invalid {
            path: path.to_path_buf(),
            reason: format!(
                "has {} values, the {w}x{h} image needs {}",
                data.len(),
                w * h
            ),
        });
    }
    Ok(ImageF32 {
        width: intrinsics.width_px,
        height: intrinsics.height_px,
        data,
    })
}

fn load_icl(dir: &Path, names: &[String], options: &LoadOptions) -> Result<Dataset, DatasetError> {
    let layout = Layout::IclNuim;
    let frames: Vec<(String, IclFrame)> = icl_frames(names).into_values().collect();
    let reference = match &options.reference {
        None => frames.len() / 2,
        Some(wanted) => frames
            .iter()
            .position(|(stem, f)| stem == wanted || f.png.as_deref() == Some(wanted.as_str()))
            .ok_or_else(|| DatasetError::MissingReference {
                dir: dir.to_path_buf(),
                layout,
                reason: format!("no frame named '{wanted}'"),
            })?,
    };
    let mut cameras = Vec::with_capacity(frames.len());
    let mut images = Vec::with_capacity(frames.len());
    let mut size: Option<(PathBuf, u32, u32)> = None;
    for (stem, frame) in &frames {
        let (Some(png), Some(txt)) = (&frame.png, &frame.txt) else {
            continue;
        };
        let png_path = dir.join(png);
        let image = io::load_rgba8(&png_path)?;
        match &size {
            None => size = Some((png_path.clone(), image.width, image.height)),
            Some((p, w, h)) if (image.width, image.height) != (*w, *h) => {
                return Err(DatasetError::SizeMismatch {
                    path: png_path,
                    got_w: image.width,
                    got_h: image.height,
                    want_w: *w,
                    want_h: *h,
                    what: format!("the size of {}", p.display()),
                })
            }
            Some(_) => {}
        }
        let txt_path = dir.join(txt);
        let text = std::fs::read_to_string(&txt_path).map_err(|source| IoError::Read {
            path: txt_path.clone(),
            source,
        })?;
        let pov = parse_povray_camera(&txt_path, &text)?;
        let (model, cam_from_world) =
            povray_camera_model(&txt_path, &pov, image.width, image.height)?;
        cameras.push(RigCamera {
            name: stem.clone(),
            model,
            cam_from_rig: cam_from_world,
        });
        images.push(image);
    }
    let rig = Rig::new(cameras, Reference::Camera(reference)).map_err(|source| {
        DatasetError::Geometry {
            path: dir.to_path_buf(),
            source,
        }
    })?;
    let (ref_stem, ref_frame) = &frames[reference];
    let ground_truth = if ref_frame.has_depth {
        let depth_path = dir.join(format!("{ref_stem}.depth"));
        let intrinsics = rig.cameras[reference].model.intrinsics;
        GroundTruth::Depth {
            depth_m: read_icl_depth(&depth_path, &intrinsics)?,
        }
    } else {
        tracing::warn!(
            "{}: reference frame {ref_stem} has no .depth file; no ground truth",
            dir.display()
        );
        GroundTruth::None
    };
    let params = SweepParams {
        min_depth_m: 1.0,
        max_depth_m: 8.0,
        num_planes: CALIBRATED_NUM_PLANES,
        ..SweepParams::default()
    };
    Ok(Dataset {
        name: folder_name(dir),
        layout,
        rig,
        images,
        ground_truth,
        nonocc_mask: None,
        params,
    })
}

// ---------------------------------------------------------------------------------------------
// Middlebury multi-view rings

/// One view of a `*_par.txt` file: P = K [R | t].
#[derive(Debug, Clone, PartialEq)]
pub struct ParView {
    pub image: String,
    pub k: DMat3,
    pub r: DMat3,
    pub t: DVec3,
}

impl ParView {
    /// The camera centre in world coordinates, C = −Rᵀ t.
    pub fn centre(&self) -> DVec3 {
        -(self.r.transpose() * self.t)
    }

    /// The optical axis (+z) in world coordinates: the third row of R.
    pub fn axis(&self) -> DVec3 {
        self.r.row(2)
    }
}

/// Parses a Middlebury multi-view `*_par.txt`: the view count, then one line per view,
/// `imgname k11 .. k33 r11 .. r33 t1 t2 t3`.
pub fn parse_par_file(path: &Path, text: &str) -> Result<Vec<ParView>, DatasetError> {
    let parse_err = |line: usize, reason: String| DatasetError::Parse {
        path: path.to_path_buf(),
        line,
        reason,
    };
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty());
    let Some((count_line, count_text)) = lines.next() else {
        return Err(parse_err(
            1,
            "empty file (expected the number of views)".into(),
        ));
    };
    let count: usize = count_text.parse().map_err(|e| {
        parse_err(
            count_line,
            format!("expected the number of views, got '{count_text}' ({e})"),
        )
    })?;
    let mut views = Vec::with_capacity(count.min(10_000));
    for (line, text) in lines {
        let tokens: Vec<&str> = text.split_whitespace().collect();
        if tokens.len() != 22 {
            return Err(parse_err(
                line,
                format!(
                    "expected 'imgname' + 21 numbers (K, R, t), got {} fields",
                    tokens.len()
                ),
            ));
        }
        let mut v = [0f64; 21];
        for (slot, token) in v.iter_mut().zip(&tokens[1..]) {
            *slot = token
                .parse()
                .map_err(|e| parse_err(line, format!("'{token}' is not a number ({e})")))?;
            if !slot.is_finite() {
                return Err(parse_err(line, format!("'{token}' is not finite")));
            }
        }
        // Row-major in the file; glam matrices are built from columns.
        let rows = |o: usize| {
            DMat3::from_cols_array(&[
                v[o],
                v[o + 3],
                v[o + 6],
                v[o + 1],
                v[o + 4],
                v[o + 7],
                v[o + 2],
                v[o + 5],
                v[o + 8],
            ])
        };
        views.push(ParView {
            image: tokens[0].to_string(),
            k: rows(0),
            r: rows(9),
            t: DVec3::new(v[18], v[19], v[20]),
        });
    }
    if views.len() != count {
        return Err(parse_err(
            count_line,
            format!("says {count} views, the file lists {}", views.len()),
        ));
    }
    Ok(views)
}

/// The bounding box of a Middlebury multi-view README: a line containing "bounding box"
/// followed by two `(x y z)` lines.
pub fn parse_readme_bounding_box(text: &str) -> Option<(DVec3, DVec3)> {
    let lines: Vec<&str> = text.lines().collect();
    let start = lines
        .iter()
        .position(|l| l.to_ascii_lowercase().contains("bounding box"))?;
    let mut corners = Vec::new();
    for line in &lines[start + 1..] {
        let line = line.trim();
        if line.is_empty() {
            if corners.is_empty() {
                continue;
            }
            break;
        }
        let inner = line.strip_prefix('(')?.strip_suffix(')')?;
        let v: Vec<f64> = inner
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|s| !s.is_empty())
            .map(|s| s.parse::<f64>())
            .collect::<Result<_, _>>()
            .ok()?;
        if v.len() != 3 || v.iter().any(|x| !x.is_finite()) {
            return None;
        }
        corners.push(DVec3::new(v[0], v[1], v[2]));
        if corners.len() == 2 {
            return Some((corners[0].min(corners[1]), corners[0].max(corners[1])));
        }
    }
    None
}

/// Picks the reference plus up to `neighbours` other views with the smallest angle between
/// optical axes. Views whose centre is within 1 mm of the reference's, or of an already picked
/// view's, are skipped (the same viewpoint adds nothing; templeSR0001/0011). Returns indices,
/// the reference first.
pub fn select_ring_views(views: &[ParView], reference: usize, neighbours: usize) -> Vec<usize> {
    const SAME_CENTRE_M: f64 = 1e-3;
    let Some(ref_view) = views.get(reference) else {
        return Vec::new();
    };
    let ref_axis = ref_view.axis().normalize_or_zero();
    let mut candidates: Vec<(f64, usize)> = views
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != reference)
        .map(|(i, v)| {
            let cos = v.axis().normalize_or_zero().dot(ref_axis).clamp(-1.0, 1.0);
            (cos.acos(), i)
        })
        .collect();
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let mut picked = vec![reference];
    for (_, i) in candidates {
        if picked.len() > neighbours {
            break;
        }
        let c = views[i].centre();
        if picked
            .iter()
            .any(|&p| (views[p].centre() - c).length() < SAME_CENTRE_M)
        {
            continue;
        }
        picked.push(i);
    }
    picked
}

/// The point nearest (least squares) to all optical axes, if well defined.
fn nearest_point_to_axes(views: &[ParView]) -> Option<DVec3> {
    let mut a = DMat3::ZERO;
    let mut b = DVec3::ZERO;
    for v in views {
        let d = v.axis().normalize_or_zero();
        let m = DMat3::IDENTITY - DMat3::from_cols(d * d.x, d * d.y, d * d.z);
        a += m;
        b += m * v.centre();
    }
    if a.determinant().abs() < 1e-9 {
        return None;
    }
    let p = a.inverse() * b;
    p.is_finite().then_some(p)
}

fn load_ring(dir: &Path, names: &[String], options: &LoadOptions) -> Result<Dataset, DatasetError> {
    let layout = Layout::MiddleburyMultiView;
    let par_files: Vec<&String> = names.iter().filter(|n| n.ends_with("_par.txt")).collect();
    let par_name = match par_files.as_slice() {
        [one] => *one,
        many => {
            return Err(DatasetError::Ambiguous {
                dir: dir.to_path_buf(),
                layout,
                reason: format!(
                    "expected one *_par.txt, found {}",
                    many.iter()
                        .map(|s| s.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            })
        }
    };
    let par_path = dir.join(par_name);
    let text = std::fs::read_to_string(&par_path).map_err(|source| IoError::Read {
        path: par_path.clone(),
        source,
    })?;
    let views = parse_par_file(&par_path, &text)?;
    if views.len() < 2 {
        return Err(DatasetError::Invalid {
            path: par_path,
            reason: format!("needs at least 2 views, has {}", views.len()),
        });
    }
    let reference = match &options.reference {
        None => 0,
        Some(wanted) => views
            .iter()
            .position(|v| {
                v.image == *wanted
                    || v.image.rsplit_once('.').map(|(s, _)| s) == Some(wanted.as_str())
            })
            .ok_or_else(|| DatasetError::MissingReference {
                dir: dir.to_path_buf(),
                layout,
                reason: format!("{} lists no view named '{wanted}'", par_path.display()),
            })?,
    };
    let selected = select_ring_views(&views, reference, RING_NEIGHBOURS);

    let mut cameras = Vec::with_capacity(selected.len());
    let mut images = Vec::with_capacity(selected.len());
    for &i in &selected {
        let view = &views[i];
        let image_path = dir.join(&view.image);
        if !image_path.is_file() {
            return Err(if i == reference {
                DatasetError::MissingReference {
                    dir: dir.to_path_buf(),
                    layout,
                    reason: format!(
                        "{} lists {} but the file is not there",
                        par_path.display(),
                        view.image
                    ),
                }
            } else {
                DatasetError::Invalid {
                    path: par_path.clone(),
                    reason: format!("lists {} but the file is not there", view.image),
                }
            });
        }
        let image = io::load_rgba8(&image_path)?;
        let k = view.k;
        let k33 = k.z_axis.z;
        let invalid = |reason: String| DatasetError::Invalid {
            path: par_path.clone(),
            reason: format!("{}: {reason}", view.image),
        };
        if k33.abs() < 1e-12 || k.x_axis.z.abs() > 1e-9 || k.y_axis.z.abs() > 1e-9 {
            return Err(invalid(format!(
                "K's last row must be (0 0 k33) with k33 != 0, K = {k:?}"
            )));
        }
        let k = k * (1.0 / k33);
        // glam is column-major: k.y_axis.x is k12 (skew), k.x_axis.y is k21.
        if k.y_axis.x.abs() > 1e-6 * k.x_axis.x.abs().max(1.0) || k.x_axis.y.abs() > 1e-9 {
            return Err(invalid("K has a skew term; not supported".into()));
        }
        let intrinsics = PinholeIntrinsics {
            width_px: image.width,
            height_px: image.height,
            fx_px: k.x_axis.x,
            fy_px: k.y_axis.y,
            cx_px: k.z_axis.x,
            cy_px: k.z_axis.y,
        };
        let cam_from_world = RigidTransform::from_matrix_translation(&view.image, view.r, view.t)
            .map_err(|source| DatasetError::Geometry {
            path: par_path.clone(),
            source,
        })?;
        cameras.push(RigCamera {
            name: view
                .image
                .rsplit_once('.')
                .map_or(view.image.as_str(), |(s, _)| s)
                .to_string(),
            model: CameraModel::pinhole(intrinsics),
            cam_from_rig: cam_from_world,
        });
        images.push(image);
    }
    let rig = Rig::new(cameras, Reference::Camera(0)).map_err(|source| DatasetError::Geometry {
        path: par_path.clone(),
        source,
    })?;

    // Depth range: the README's bounding box seen from the reference, else around the point
    // nearest all optical axes.
    let ref_from_world = rig.cameras[0].cam_from_rig;
    let readme_box = names
        .iter()
        .filter(|n| n.to_ascii_lowercase().starts_with("readme"))
        .filter_map(|n| std::fs::read_to_string(dir.join(n)).ok())
        .find_map(|t| parse_readme_bounding_box(&t));
    let from_box = readme_box.and_then(|(lo, hi)| {
        let mut zmin = f64::INFINITY;
        let mut zmax = f64::NEG_INFINITY;
        for i in 0..8 {
            let corner = DVec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            );
            let z = ref_from_world.transform_point(corner).z;
            zmin = zmin.min(z);
            zmax = zmax.max(z);
        }
        (zmin > 0.0 && zmax > zmin).then_some((zmin * 0.9, zmax * 1.1))
    });
    let (min_depth_m, max_depth_m) = match from_box {
        Some(range) => range,
        None => {
            let z = nearest_point_to_axes(&views)
                .map(|p| ref_from_world.transform_point(p).z)
                .filter(|z| *z > 0.0 && z.is_finite())
                .ok_or_else(|| DatasetError::Invalid {
                    path: par_path.clone(),
                    reason: "no README bounding box and the optical axes do not meet in front of the reference: cannot choose a depth range".into(),
                })?;
            (0.5 * z, 1.5 * z)
        }
    };
    let params = SweepParams {
        min_depth_m,
        max_depth_m,
        num_planes: CALIBRATED_NUM_PLANES,
        ..SweepParams::default()
    };
    Ok(Dataset {
        name: folder_name(dir),
        layout,
        rig,
        images,
        ground_truth: GroundTruth::None,
        nonocc_mask: None,
        params,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn detects_layouts_from_names() {
        assert_eq!(
            detect_layout_from_names(&names(&[
                "scene1.row3.col1.ppm",
                "scene1.row3.col2.ppm",
                "truedisp.row3.col2.pgm"
            ])),
            Some(Layout::Middlebury2001)
        );
        assert_eq!(
            detect_layout_from_names(&names(&["im0.ppm", "im1.png", "disp1.pgm"])),
            Some(Layout::Middlebury2003)
        );
        assert_eq!(
            detect_layout_from_names(&names(&["view0.png", "view1.png", "disp1.png"])),
            Some(Layout::Middlebury2005)
        );
        assert_eq!(
            detect_layout_from_names(&names(&[
                "a_0001.png",
                "a_0001.txt",
                "a_0001.depth",
                "a_0002.png",
                "a_0002.txt"
            ])),
            Some(Layout::IclNuim)
        );
        assert_eq!(
            detect_layout_from_names(&names(&["x_par.txt", "x0001.png"])),
            Some(Layout::MiddleburyMultiView)
        );
        assert_eq!(detect_layout_from_names(&names(&["a.png", "b.png"])), None);
    }

    #[test]
    fn povray_camera_matches_source_md() {
        // Frame 0020 of ICL-NUIM living room traj2 (SOURCE.md: fx 481.203, fy -480.000).
        let text = "cam_pos      = [0.816903, 1.3002, 1.46265]';\n\
                    cam_dir      = [-0.0282699, 0.0062868, -0.999581]';\n\
                    cam_up       = [-0.00856271, 0.999942, 0.00653124]';\n\
                    cam_right    = [-1.32942, -0.0116292, 0.0375252]';\n\
                    cam_angle    = 90;\n";
        let p = Path::new("x.txt");
        let cam = parse_povray_camera(p, text).unwrap();
        let (model, cam_from_world) = povray_camera_model(p, &cam, 640, 480).unwrap();
        assert!((model.intrinsics.fx_px - 481.203).abs() < 0.01);
        assert!((model.intrinsics.fy_px + 480.0).abs() < 0.01);
        // The camera centre maps to the origin, a point ahead along cam_dir to +z.
        assert!(cam_from_world.transform_point(cam.pos).length() < 1e-9);
        let ahead = cam_from_world.transform_point(cam.pos + cam.dir * 2.0);
        assert!(ahead.z > 1.9 && ahead.x.abs() < 1e-6 && ahead.y.abs() < 1e-6);
        assert!(matches!(
            parse_povray_camera(p, "cam_pos = [1, x, 2]';"),
            Err(DatasetError::Parse { line: 1, .. })
        ));
    }

    #[test]
    fn readme_bounding_box() {
        let t = "The (tight) bounding box for the dino model is\n(-0.061897 -0.018874 -0.057845)\n(0.010897 0.068227 0.015495)\n\nmore";
        let (lo, hi) = parse_readme_bounding_box(t).unwrap();
        assert_eq!(lo, DVec3::new(-0.061897, -0.018874, -0.057845));
        assert_eq!(hi, DVec3::new(0.010897, 0.068227, 0.015495));
        assert!(parse_readme_bounding_box("nothing here").is_none());
    }
}
