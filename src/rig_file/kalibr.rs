//! Kalibr's `camchain.yaml`: `cam0`, `cam1`, ... chained by `T_cn_cnm1`, cam0's optical frame
//! the rig frame.

use std::collections::BTreeMap;

use glam::DVec3;
use serde::Deserialize;
use serde_yaml_ng::Value;

use super::checks::{check_intrinsics, distortion_from, pose_error, rows_to_mat3, CameraError};
use super::{value_kind, Ctx, RigFile, RigFileCamera, RigFileError, RigFileFormat};
use crate::geometry::{CameraModel, Distortion, PinholeIntrinsics, RigidTransform};

/// Tolerance on the last row of a Kalibr 4x4 homogeneous matrix being [0, 0, 0, 1].
const HOMOGENEOUS_ROW_TOLERANCE: f64 = 1e-6;

/// Per-camera keys of a Kalibr camchain (used or knowingly ignored).
const KALIBR_KEYS: &[&str] = &[
    "camera_model",
    "intrinsics",
    "distortion_model",
    "distortion_coeffs",
    "resolution",
    "rostopic",
    "T_cn_cnm1",
    "T_cam_imu",
    "cam_overlaps",
    "timeshift_cam_imu",
];

#[derive(Deserialize)]
struct RawKalibrCamera {
    camera_model: String,
    intrinsics: Vec<f64>,
    distortion_model: String,
    #[serde(default)]
    distortion_coeffs: Vec<f64>,
    resolution: Vec<u32>,
    #[serde(default)]
    rostopic: Option<String>,
    #[serde(default, rename = "T_cn_cnm1")]
    t_cn_cnm1: Option<Vec<Vec<f64>>>,
    #[serde(default, rename = "T_cam_imu")]
    t_cam_imu: Option<Vec<Vec<f64>>>,
    #[serde(default)]
    #[expect(
        dead_code,
        reason = "Kalibr writes it; read so that the file parses, not used"
    )]
    cam_overlaps: Option<Vec<i64>>,
    #[serde(default)]
    #[expect(
        dead_code,
        reason = "Kalibr writes it; read so that the file parses, not used"
    )]
    timeshift_cam_imu: Option<f64>,
}

/// `cam12` -> 12.
pub(super) fn kalibr_index(key: &str) -> Option<usize> {
    let digits = key.strip_prefix("cam")?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    if digits.len() > 1 && digits.starts_with('0') {
        return None;
    }
    digits.parse().ok()
}

pub(super) fn parse_kalibr(
    ctx: &Ctx<'_>,
    map: &serde_yaml_ng::Mapping,
) -> Result<RigFile, RigFileError> {
    let mut entries: BTreeMap<usize, (String, &Value)> = BTreeMap::new();
    for (key, value) in map {
        let Some(key) = key.as_str() else {
            return Err(ctx.format(format!(
                "Kalibr camchain: top-level keys must be `cam0`, `cam1`, ...; found {}",
                value_kind(key)
            )));
        };
        let Some(index) = kalibr_index(key) else {
            return Err(ctx.format(format!(
                "Kalibr camchain: unexpected top-level key `{key}` (expected `cam0`, `cam1`, ...)"
            )));
        };
        entries.insert(index, (key.to_string(), value));
    }
    for (expected, index) in entries.keys().enumerate() {
        if *index != expected {
            return Err(ctx.format(format!(
                "Kalibr camchain: cameras must be cam0, cam1, ... without gaps; `cam{expected}` \
                 is missing"
            )));
        }
    }
    let mut notes = Vec::new();
    let mut cameras: Vec<RigFileCamera> = Vec::with_capacity(entries.len());
    for (index, (name, value)) in entries {
        if let Value::Mapping(fields) = value {
            for key in fields.keys() {
                let key = key.as_str().unwrap_or("<non-string key>");
                if !KALIBR_KEYS.contains(&key) {
                    notes.push(format!(
                        "rig file '{}', camera '{name}': ignored Kalibr key `{key}`",
                        ctx.path.display()
                    ));
                }
            }
        }
        let raw: RawKalibrCamera =
            ctx.entry::<RawKalibrCamera, BTreeMap<String, RawKalibrCamera>>(&name, value)?;
        let previous = cameras.last().map(|c| c.cam_from_rig);
        let camera =
            convert_kalibr(&name, raw, previous, &mut notes).map_err(|e| ctx.camera(&name, e))?;
        debug_assert_eq!(cameras.len(), index);
        cameras.push(camera);
    }
    if cameras.is_empty() {
        return Err(ctx.format("Kalibr camchain has no cameras".to_string()));
    }
    Ok(RigFile {
        path: ctx.path.to_path_buf(),
        format: RigFileFormat::Kalibr,
        rig_frame: "cam0".to_string(),
        cameras,
        notes,
    })
}

fn convert_kalibr(
    name: &str,
    raw: RawKalibrCamera,
    previous_from_rig: Option<RigidTransform>,
    notes: &mut Vec<String>,
) -> Result<RigFileCamera, CameraError> {
    if raw.camera_model != "pinhole" {
        return Err(CameraError::KalibrModel(raw.camera_model));
    }
    if raw.intrinsics.len() != 4 {
        return Err(CameraError::KalibrIntrinsics(raw.intrinsics.len()));
    }
    if raw.resolution.len() != 2 {
        return Err(CameraError::KalibrResolution(raw.resolution.len()));
    }
    let intrinsics = PinholeIntrinsics {
        width_px: raw.resolution[0],
        height_px: raw.resolution[1],
        fx_px: raw.intrinsics[0],
        fy_px: raw.intrinsics[1],
        cx_px: raw.intrinsics[2],
        cy_px: raw.intrinsics[3],
    };
    check_intrinsics(&intrinsics)?;
    let d = &raw.distortion_coeffs;
    let distortion = match raw.distortion_model.as_str() {
        "radtan" => {
            if d.len() != 4 {
                return Err(CameraError::KalibrDistortionCount {
                    model: "radtan",
                    form: "[k1, k2, r1, r2]",
                    got: d.len(),
                });
            }
            distortion_from("plumb_bob", &[d[0], d[1], d[2], d[3], 0.0])?
        }
        "equidistant" => {
            if d.len() != 4 {
                return Err(CameraError::KalibrDistortionCount {
                    model: "equidistant",
                    form: "[k1, k2, k3, k4]",
                    got: d.len(),
                });
            }
            distortion_from("equidistant", d)?
        }
        "none" => {
            if d.iter().any(|&v| v != 0.0) {
                return Err(CameraError::KalibrNoneWithCoefficients);
            }
            Distortion::None
        }
        other => return Err(CameraError::KalibrDistortion(other.to_string())),
    };
    let cam_from_rig = match previous_from_rig {
        None => {
            if raw.t_cn_cnm1.is_some() {
                notes.push(format!(
                    "camera '{name}': `T_cn_cnm1` on the first camera ignored (cam0 is the rig \
                     frame)"
                ));
            }
            RigidTransform::IDENTITY
        }
        Some(previous_from_rig) => {
            let Some(m) = &raw.t_cn_cnm1 else {
                return Err(CameraError::MissingChain);
            };
            let cn_from_cnm1 = homogeneous(m, "T_cn_cnm1")?;
            cn_from_cnm1.compose(&previous_from_rig)
        }
    };
    let cam_from_imu = match &raw.t_cam_imu {
        Some(m) => Some(homogeneous(m, "T_cam_imu")?),
        None => None,
    };
    Ok(RigFileCamera {
        name: name.to_string(),
        cam_from_rig,
        model: Some(CameraModel {
            intrinsics,
            distortion,
        }),
        rostopic: raw.rostopic,
        cam_from_imu,
    })
}

/// A 4x4 row-major homogeneous rigid transform.
fn homogeneous(m: &[Vec<f64>], field: &'static str) -> Result<RigidTransform, CameraError> {
    if m.len() != 4 || m.iter().any(|row| row.len() != 4) {
        return Err(CameraError::HomogeneousShape(field));
    }
    if m.iter().flatten().any(|v| !v.is_finite()) {
        return Err(CameraError::HomogeneousNotFinite(field));
    }
    let last = &m[3];
    if (last[0].abs().max(last[1].abs()).max(last[2].abs())) > HOMOGENEOUS_ROW_TOLERANCE
        || (last[3] - 1.0).abs() > HOMOGENEOUS_ROW_TOLERANCE
    {
        return Err(CameraError::HomogeneousLastRow {
            field,
            last: last.clone(),
        });
    }
    let rotation = rows_to_mat3([
        [m[0][0], m[0][1], m[0][2]],
        [m[1][0], m[1][1], m[1][2]],
        [m[2][0], m[2][1], m[2][2]],
    ]);
    let translation = DVec3::new(m[0][3], m[1][3], m[2][3]);
    RigidTransform::from_matrix_translation(field, rotation, translation)
        .map_err(|e| pose_error(field, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kalibr_index_parses_only_cam_keys() {
        assert_eq!(kalibr_index("cam0"), Some(0));
        assert_eq!(kalibr_index("cam12"), Some(12));
        assert_eq!(kalibr_index("cam"), None);
        assert_eq!(kalibr_index("cam01"), None);
        assert_eq!(kalibr_index("camera0"), None);
        assert_eq!(kalibr_index("cameras"), None);
    }
}
