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

//!
//! One file per format: [`middlebury`] (2001, 2003, 2005/2006 stereo sets), [`icl_nuim`]
//! (POV-Ray frames) and [`ring`] (Middlebury multi-view rings).

pub mod icl_nuim;
pub mod middlebury;
pub mod middlebury2014;
pub mod ring;

use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

use crate::geometry::{GeometryError, Rig};
use crate::image::{ImageF32, Rgba8Image};
use crate::io::IoError;
use crate::sweep::SweepParams;

pub use icl_nuim::{parse_povray_camera, povray_camera_model, read_icl_depth, PovRayCamera};
pub use middlebury::{nonocc_mask, NONOCC_TOLERANCE_PX};
pub use ring::{parse_par_file, parse_readme_bounding_box, select_ring_views, ParView};

use icl_nuim::{icl_frames, load_icl};
use middlebury::{load_middlebury, middlebury2001_files};
use middlebury2014::{is_middlebury2014, load_middlebury2014};
use ring::load_ring;

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
    /// A rectified pair with its calibration: `im0.png` + `im1.png` + `calib.txt` +
    /// `disp0GT.pfm` / `disp0.pfm` (Middlebury 2014, ETH3D two-view).
    Middlebury2014,
    /// POV-Ray frames `<stem>_NNNN.png` + `.depth` (ray distance, m) + `.txt` (camera).
    IclNuim,
    /// Middlebury multi-view stereo: `<name>_par.txt` (K, R, t per image) + images.
    MiddleburyMultiView,
}

impl Layout {
    pub const ALL: [Layout; 6] = [
        Layout::Middlebury2001,
        Layout::Middlebury2003,
        Layout::Middlebury2005,
        Layout::Middlebury2014,
        Layout::IclNuim,
        Layout::MiddleburyMultiView,
    ];

    pub fn name(&self) -> &'static str {
        match self {
            Layout::Middlebury2001 => "middlebury2001",
            Layout::Middlebury2003 => "middlebury2003",
            Layout::Middlebury2005 => "middlebury2005",
            Layout::Middlebury2014 => "middlebury2014",
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
            Layout::Middlebury2014 => {
                "im0.png + im1.png + calib.txt + disp0GT.pfm|disp0.pfm (2014, ETH3D)"
            }
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
        /// What the set's own disparity files hold is `disparity_eval - doffs_px`: Middlebury
        /// 2014's and ETH3D's `doffs` (the right camera's principal point less the left's, their
        /// files' d meaning depth `f B / (d + doffs)`), 0 for the other layouts. `eval --save`
        /// writes the estimate in the files' units, comparable with them pixel by pixel.
        doffs_px: f64,
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
    /// The right view of a Middlebury 2014 / ETH3D pair (default `im1.png`; the 2014 sets'
    /// `im1E.png` and `im1L.png` are the same view under another exposure or lighting).
    pub right_view: Option<String>,
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
            Layout::Middlebury2001
                | Layout::Middlebury2003
                | Layout::Middlebury2005
                | Layout::Middlebury2014
        )
    {
        return Err(DatasetError::Invalid {
            path: dir.to_path_buf(),
            reason: format!(
                "a reference override is not supported for {layout}: the reference is the view with ground truth"
            ),
        });
    }
    if let (Some(right), false) = (&options.right_view, layout == Layout::Middlebury2014) {
        tracing::warn!(
            "{}: right view '{right}' not used: a {layout} set has no variants of its views \
             (--right-view picks one of a Middlebury 2014 or ETH3D pair's)",
            dir.display()
        );
    }
    match layout {
        Layout::Middlebury2001 | Layout::Middlebury2003 | Layout::Middlebury2005 => {
            load_middlebury(dir, &names, layout)
        }
        Layout::Middlebury2014 => load_middlebury2014(dir, &names, options.right_view.as_deref()),
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
/// (`*_par.txt`), ICL-NUIM, Middlebury 2014 (`calib.txt`), 2001, 2005/2006 (`viewN`), 2003
/// (`imN`).
pub fn detect_layout_from_names(names: &[String]) -> Option<Layout> {
    if names.iter().any(|n| n.ends_with("_par.txt")) {
        return Some(Layout::MiddleburyMultiView);
    }
    let icl = icl_frames(names);
    if icl.len() >= 2 && icl.values().any(|(_, f)| f.has_depth) {
        return Some(Layout::IclNuim);
    }
    if is_middlebury2014(names) {
        return Some(Layout::Middlebury2014);
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

pub(super) fn list_files(dir: &Path) -> Result<Vec<String>, DatasetError> {
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

pub(super) fn unknown_layout(dir: &Path, names: &[String]) -> DatasetError {
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

pub(super) fn is_image_ext(ext: &str) -> bool {
    matches!(
        ext.to_ascii_lowercase().as_str(),
        "png" | "ppm" | "pgm" | "pnm"
    )
}

/// `(stem, ext)` of a file name with an image extension.
pub(super) fn split_image_name(name: &str) -> Option<(&str, &str)> {
    let (stem, ext) = name.rsplit_once('.')?;
    is_image_ext(ext).then_some((stem, ext))
}

/// `prefixN` → N.
pub(super) fn number_after(stem: &str, prefix: &str) -> Option<u32> {
    let digits = stem.strip_prefix(prefix)?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) || digits.len() > 9 {
        return None;
    }
    digits.parse().ok()
}

/// `prefixN.<image ext>` files by N. With several files for one N (im2.ppm and im2.png) the
/// first in name order is kept.
pub(super) fn numbered_images(names: &[String], prefix: &str) -> BTreeMap<u32, String> {
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

/// The dataset's name: its folder's.
pub(super) fn folder_name(dir: &Path) -> String {
    let canonical = dir.canonicalize().unwrap_or_else(|_| dir.to_path_buf());
    canonical
        .file_name()
        .or_else(|| dir.file_name())
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "dataset".to_string())
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
            detect_layout_from_names(&names(&["calib.txt", "im0.png", "im1.png", "disp0GT.pfm"])),
            Some(Layout::Middlebury2014)
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
}
