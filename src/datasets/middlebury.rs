//! Middlebury stereo sets (2001, 2003, 2005/2006): rectified views equally spaced along x,
//! with the synthetic calibration of the module docs; disparity ground truth in each
//! edition's encoding.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::DVec3;

use super::{
    folder_name, number_after, numbered_images, split_image_name, Dataset, DatasetError,
    GroundTruth, Layout, MAX_MIDDLEBURY_PLANES, MIDDLEBURY_BASELINE_M,
};
use crate::geometry::{CameraModel, PinholeIntrinsics, Reference, Rig, RigCamera, RigidTransform};
use crate::image::{ImageF32, Rgba8Image};
use crate::io::{self};
use crate::sweep::SweepParams;

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

pub(super) fn load_middlebury(
    dir: &Path,
    names: &[String],
    layout: Layout,
) -> Result<Dataset, DatasetError> {
    // view number -> image file; ground-truth view number -> GT file.
    let (views, truth): (BTreeMap<u32, String>, BTreeMap<u32, String>) = match layout {
        Layout::Middlebury2001 => middlebury2001_views(dir, names)?,
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

    let (images, view_numbers, width, height) = load_views(dir, &views, layout)?;
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
        doffs_px: 0.0,
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

/// Middlebury 2001: the view sequence whose prefix matches the ground truth's middle part
/// (row3 of `truedisp.row3.col3`), as view number -> image file and view number -> GT file.
#[expect(
    clippy::type_complexity,
    reason = "the two maps load_middlebury reads, as the other layouts make them"
)]
fn middlebury2001_views(
    dir: &Path,
    names: &[String],
) -> Result<(BTreeMap<u32, String>, BTreeMap<u32, String>), DatasetError> {
    let layout = Layout::Middlebury2001;
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
                mid.is_empty() || prefix.as_str() == mid || prefix.ends_with(&format!(".{mid}"))
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
    Ok((views.clone(), truth))
}

/// The views' images in view order, their numbers, and their one size (all must share it).
fn load_views(
    dir: &Path,
    views: &BTreeMap<u32, String>,
    layout: Layout,
) -> Result<(Vec<Rgba8Image>, Vec<u32>, u32, u32), DatasetError> {
    let mut images = Vec::with_capacity(views.len());
    let mut view_numbers = Vec::with_capacity(views.len());
    let mut first: Option<(PathBuf, u32, u32)> = None;
    for (&n, name) in views {
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
    Ok((images, view_numbers, width, height))
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

/// Middlebury 2001: views `<prefix>.colN.<ext>` grouped by prefix, and ground truth
/// `truedisp.<mid>.colR.<ext>` as (mid, R, name).
#[expect(
    clippy::type_complexity,
    reason = "the (prefix, column, name) lists are read once, right below"
)]
pub(super) fn middlebury2001_files(
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
