//! ICL-NUIM (POV-Ray frames): `<stem>_NNNN.png` images, `.depth` ray distances in metres and
//! `.txt` POV-Ray cameras.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::{DMat3, DVec3};

use super::{
    folder_name, Dataset, DatasetError, GroundTruth, Layout, LoadOptions, CALIBRATED_NUM_PLANES,
};
use crate::geometry::{CameraModel, PinholeIntrinsics, Reference, Rig, RigCamera, RigidTransform};
use crate::image::ImageF32;
use crate::io::{self, IoError};
use crate::sweep::SweepParams;

#[derive(Debug, Default, Clone)]
pub(super) struct IclFrame {
    pub png: Option<String>,
    pub txt: Option<String>,
    pub has_depth: bool,
}

/// ICL-NUIM frames `<stem>_NNNN` that have both a `.png` and a `.txt`, by number.
pub(super) fn icl_frames(names: &[String]) -> BTreeMap<u64, (String, IclFrame)> {
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

pub(super) fn load_icl(
    dir: &Path,
    names: &[String],
    options: &LoadOptions,
) -> Result<Dataset, DatasetError> {
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
