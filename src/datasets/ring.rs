//! Middlebury multi-view rings: `<name>_par.txt` (K, R, t per image) and the images; a
//! reference view and its nearest neighbours on the ring.

use std::path::Path;

use glam::{DMat3, DVec3};

use super::{
    folder_name, Dataset, DatasetError, GroundTruth, Layout, LoadOptions, CALIBRATED_NUM_PLANES,
    RING_NEIGHBOURS,
};
use crate::geometry::{CameraModel, PinholeIntrinsics, Reference, Rig, RigCamera, RigidTransform};
use crate::image::Rgba8Image;
use crate::io::{self, IoError};
use crate::sweep::SweepParams;

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

pub(super) fn load_ring(
    dir: &Path,
    names: &[String],
    options: &LoadOptions,
) -> Result<Dataset, DatasetError> {
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
        cameras.push(view_camera(view, &image, &par_path)?);
        images.push(image);
    }
    let rig = Rig::new(cameras, Reference::Camera(0)).map_err(|source| DatasetError::Geometry {
        path: par_path.clone(),
        source,
    })?;

    let (min_depth_m, max_depth_m) = depth_range(dir, names, &views, &rig, &par_path)?;
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

/// The camera of one view of a `_par.txt` (K with no skew and a last row (0 0 k33), the pose
/// from R and t), sized as its image.
fn view_camera(
    view: &ParView,
    image: &Rgba8Image,
    par_path: &Path,
) -> Result<RigCamera, DatasetError> {
    let k = view.k;
    let k33 = k.z_axis.z;
    let invalid = |reason: String| DatasetError::Invalid {
        path: par_path.to_path_buf(),
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
            path: par_path.to_path_buf(),
            source,
        })?;
    Ok(RigCamera {
        name: view
            .image
            .rsplit_once('.')
            .map_or(view.image.as_str(), |(s, _)| s)
            .to_string(),
        model: CameraModel::pinhole(intrinsics),
        cam_from_rig: cam_from_world,
    })
}

/// The depth range swept: the README's bounding box seen from the reference (camera 0 of
/// `rig`), else around the point nearest all optical axes.
fn depth_range(
    dir: &Path,
    names: &[String],
    views: &[ParView],
    rig: &Rig,
    par_path: &Path,
) -> Result<(f64, f64), DatasetError> {
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
    match from_box {
        Some(range) => Ok(range),
        None => {
            let z = nearest_point_to_axes(views)
                .map(|p| ref_from_world.transform_point(p).z)
                .filter(|z| *z > 0.0 && z.is_finite())
                .ok_or_else(|| DatasetError::Invalid {
                    path: par_path.to_path_buf(),
                    reason: "no README bounding box and the optical axes do not meet in front of the reference: cannot choose a depth range".into(),
                })?;
            Ok((0.5 * z, 1.5 * z))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn readme_bounding_box() {
        let t = "The (tight) bounding box for the dino model is\n(-0.061897 -0.018874 -0.057845)\n(0.010897 0.068227 0.015495)\n\nmore";
        let (lo, hi) = parse_readme_bounding_box(t).unwrap();
        assert_eq!(lo, DVec3::new(-0.061897, -0.018874, -0.057845));
        assert_eq!(hi, DVec3::new(0.010897, 0.068227, 0.015495));
        assert!(parse_readme_bounding_box("nothing here").is_none());
    }
}
