//! The sweepdepth rig file (our own format): a `cameras:` list, each camera's pose as `rig_from_cam`
//! (translation + quaternion or rotation matrix), optional intrinsics and distortion.

use glam::{DMat3, DQuat};
use serde::Deserialize;
use serde_yaml_ng::Value;

use super::checks::{
    check_intrinsics, check_unique_names, distortion_from, pose_error, rows_to_mat3, vec3,
    CameraError,
};
use super::{Ctx, RigFile, RigFileCamera, RigFileError, RigFileFormat};
use crate::geometry::{CameraModel, Distortion, PinholeIntrinsics, RigidTransform};

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
#[expect(
    dead_code,
    reason = "only parsed for its error messages (deny_unknown_fields)"
)]
struct RawRigFile {
    #[serde(default)]
    rig_frame: Option<String>,
    cameras: Vec<RawCamera>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRigFileTop {
    #[serde(default)]
    rig_frame: Option<String>,
    cameras: Vec<Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCamera {
    name: String,
    translation: Vec<f64>,
    #[serde(default)]
    rotation: Option<Vec<f64>>,
    #[serde(default)]
    rotation_matrix: Option<Value>,
    #[serde(default)]
    intrinsics: Option<RawIntrinsics>,
    #[serde(default)]
    distortion: Option<RawDistortion>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawIntrinsics {
    width: u32,
    height: u32,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDistortion {
    model: String,
    #[serde(default)]
    coefficients: Vec<f64>,
}

pub(super) fn parse_sweepdepth(
    ctx: &Ctx<'_>,
    map: &serde_yaml_ng::Mapping,
) -> Result<RigFile, RigFileError> {
    let top = RawRigFileTop::deserialize(Value::Mapping(map.clone())).map_err(|e| {
        let message = match serde_yaml_ng::from_str::<RawRigFile>(ctx.text) {
            Err(whole) => whole.to_string(),
            Ok(_) => e.to_string(),
        };
        ctx.format(message)
    })?;
    let rig_frame = top.rig_frame.unwrap_or_else(|| "rig".to_string());
    if rig_frame.trim().is_empty() {
        return Err(ctx.format("`rig_frame` is empty".to_string()));
    }
    if top.cameras.is_empty() {
        return Err(ctx.format("`cameras` is empty; list at least one camera".to_string()));
    }
    let mut cameras = Vec::with_capacity(top.cameras.len());
    for (i, value) in top.cameras.iter().enumerate() {
        // Name the camera in messages by its `name` when it has one.
        let label = value
            .get("name")
            .and_then(Value::as_str)
            .filter(|n| !n.trim().is_empty())
            .map_or_else(|| format!("cameras[{i}]"), str::to_string);
        let raw: RawCamera = ctx.entry::<RawCamera, RawRigFile>(&label, value)?;
        let camera = convert_camera(raw).map_err(|e| ctx.camera(&label, e))?;
        cameras.push(camera);
    }
    check_unique_names(ctx, &cameras)?;
    Ok(RigFile {
        path: ctx.path.to_path_buf(),
        format: RigFileFormat::Sweepdepth,
        rig_frame,
        cameras,
        notes: Vec::new(),
    })
}

fn convert_camera(raw: RawCamera) -> Result<RigFileCamera, CameraError> {
    if raw.name.trim().is_empty() {
        return Err(CameraError::EmptyName);
    }
    let translation = vec3(&raw.translation, "translation")?;
    let rig_from_cam = match (&raw.rotation, &raw.rotation_matrix) {
        (Some(_), Some(_)) => return Err(CameraError::BothRotations),
        (None, None) => return Err(CameraError::NoRotation),
        (Some(q), None) => {
            if q.len() != 4 {
                return Err(CameraError::QuaternionLength(q.len()));
            }
            RigidTransform::from_quat_translation(
                "rotation",
                DQuat::from_xyzw(q[0], q[1], q[2], q[3]),
                translation,
            )
            .map_err(|e| pose_error("rotation", e))?
        }
        (None, Some(m)) => {
            let rotation = matrix3(m)?;
            RigidTransform::from_matrix_translation("rotation_matrix", rotation, translation)
                .map_err(|e| pose_error("rotation_matrix", e))?
        }
    };
    let model = match (raw.intrinsics, raw.distortion) {
        (None, Some(_)) => return Err(CameraError::DistortionWithoutIntrinsics),
        (None, None) => None,
        (Some(k), distortion) => {
            let intrinsics = PinholeIntrinsics {
                width_px: k.width,
                height_px: k.height,
                fx_px: k.fx,
                fy_px: k.fy,
                cx_px: k.cx,
                cy_px: k.cy,
            };
            check_intrinsics(&intrinsics)?;
            let distortion = match distortion {
                None => Distortion::None,
                Some(d) => distortion_from(&d.model, &d.coefficients)?,
            };
            Some(CameraModel {
                intrinsics,
                distortion,
            })
        }
    };
    Ok(RigFileCamera {
        name: raw.name,
        cam_from_rig: rig_from_cam.inverse(),
        model,
        rostopic: None,
        cam_from_imu: None,
    })
}

fn yaml_f64(value: &Value) -> Option<f64> {
    match value {
        Value::Number(n) => n.as_f64(),
        _ => None,
    }
}

/// A 3x3 matrix from 9 numbers or 3 rows of 3, row-major.
pub(super) fn matrix3(value: &Value) -> Result<DMat3, CameraError> {
    let shape_error = || CameraError::MatrixShape;
    let Value::Sequence(items) = value else {
        return Err(shape_error());
    };
    let mut entries = Vec::with_capacity(9);
    if items.len() == 9 {
        for item in items {
            entries.push(yaml_f64(item).ok_or_else(shape_error)?);
        }
    } else if items.len() == 3 {
        for row in items {
            let Value::Sequence(row) = row else {
                return Err(shape_error());
            };
            if row.len() != 3 {
                return Err(shape_error());
            }
            for item in row {
                entries.push(yaml_f64(item).ok_or_else(shape_error)?);
            }
        }
    } else {
        return Err(shape_error());
    }
    Ok(rows_to_mat3([
        [entries[0], entries[1], entries[2]],
        [entries[3], entries[4], entries[5]],
        [entries[6], entries[7], entries[8]],
    ]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig_file::parse_rig_file;
    use glam::DVec3;
    use std::path::Path;

    fn parse(text: &str) -> Result<RigFile, RigFileError> {
        parse_rig_file(text, Path::new("unit.yaml"))
    }

    #[test]
    fn pose_is_inverted_to_cam_from_rig() {
        // Camera at x = 0.5 in the rig, rotated 90 degrees about the rig's y axis.
        let text = "cameras:\n  - name: a\n    translation: [0.5, 0.0, 0.0]\n    rotation: [0.0, 0.7071067811865476, 0.0, 0.7071067811865476]\n";
        let rig = parse(text).unwrap();
        let cam = &rig.cameras[0];
        assert!((cam.centre_in_rig() - DVec3::new(0.5, 0.0, 0.0)).length() < 1e-12);
        // The camera's z axis is the rig's +x: a point 1 m further along rig x is at z = 1.
        let p = cam.cam_from_rig.transform_point(DVec3::new(1.5, 0.0, 0.0));
        assert!((p - DVec3::new(0.0, 0.0, 1.0)).length() < 1e-12, "{p:?}");
        assert_eq!(rig.rig_frame, "rig");
        assert_eq!(rig.format, RigFileFormat::Sweepdepth);
    }

    #[test]
    fn matrix_forms_agree_and_bad_shapes_fail() {
        let flat = serde_yaml_ng::from_str::<Value>("[0, -1, 0, 1, 0, 0, 0, 0, 1]").unwrap();
        let rows = serde_yaml_ng::from_str::<Value>("[[0, -1, 0], [1, 0, 0], [0, 0, 1]]").unwrap();
        let a = matrix3(&flat).unwrap();
        assert_eq!(a, matrix3(&rows).unwrap());
        // Row-major: the first row is (0, -1, 0), so R * x = (0, 1, 0).
        assert_eq!(a * DVec3::X, DVec3::Y);
        let bad = serde_yaml_ng::from_str::<Value>("[[1, 0], [0, 1]]").unwrap();
        assert!(matrix3(&bad).is_err());
    }
}
