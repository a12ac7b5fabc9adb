//! The rig: its cameras, the reference (one of them or a virtual camera) and the geometric
//! split into the paper's two half-sequences.

use glam::{DVec2, DVec3};

use super::{CameraModel, GeometryError, RigidTransform};

/// One physical camera of a rig.
#[derive(Debug, Clone, PartialEq)]
pub struct RigCamera {
    pub name: String,
    pub model: CameraModel,
    /// Maps points in the rig frame into this camera's optical frame.
    pub cam_from_rig: RigidTransform,
}

impl RigCamera {
    /// The camera centre in the rig frame, metres.
    pub fn centre_in_rig(&self) -> DVec3 {
        self.cam_from_rig.inverse().translation
    }
}

/// The camera depth is estimated for.
#[derive(Debug, Clone, PartialEq)]
pub enum Reference {
    /// One of the rig's cameras, by index.
    Camera(usize),
    /// A camera of our own choosing (size, intrinsics, pose) with no image of its own.
    Virtual {
        model: CameraModel,
        cam_from_rig: RigidTransform,
    },
}

/// The cameras plus the reference.
#[derive(Debug, Clone, PartialEq)]
pub struct Rig {
    pub cameras: Vec<RigCamera>,
    pub reference: Reference,
}

impl Rig {
    pub fn new(cameras: Vec<RigCamera>, reference: Reference) -> Result<Self, GeometryError> {
        if cameras.len() < 2 {
            return Err(GeometryError::InvalidRig(format!(
                "need at least 2 cameras, got {}",
                cameras.len()
            )));
        }
        for camera in &cameras {
            camera.model.validate(&camera.name)?;
        }
        match &reference {
            Reference::Camera(i) if *i >= cameras.len() => {
                return Err(GeometryError::InvalidRig(format!(
                    "reference camera index {i} out of range (rig has {} cameras)",
                    cameras.len()
                )));
            }
            Reference::Virtual { model, .. } => model.validate("virtual reference")?,
            _ => {}
        }
        Ok(Self { cameras, reference })
    }

    pub fn reference_index(&self) -> Option<usize> {
        match self.reference {
            Reference::Camera(i) => Some(i),
            Reference::Virtual { .. } => None,
        }
    }

    pub fn reference_model(&self) -> CameraModel {
        match &self.reference {
            Reference::Camera(i) => self.cameras[*i].model,
            Reference::Virtual { model, .. } => *model,
        }
    }

    pub fn ref_from_rig(&self) -> RigidTransform {
        match &self.reference {
            Reference::Camera(i) => self.cameras[*i].cam_from_rig,
            Reference::Virtual { cam_from_rig, .. } => *cam_from_rig,
        }
    }

    /// `cam_from_ref` for camera `i`.
    pub fn cam_from_ref(&self, i: usize) -> RigidTransform {
        self.cameras[i]
            .cam_from_rig
            .compose(&self.ref_from_rig().inverse())
    }

    /// The view whose image moves most from one plane to the next of `planes` planes even in
    /// inverse depth over `[min_depth_m, max_depth_m]` (they move evenly), measured along the
    /// reference's central ray, and by how many pixels; None without a view that sees that ray.
    pub fn widest_shift_per_plane(
        &self,
        min_depth_m: f64,
        max_depth_m: f64,
        planes: usize,
    ) -> Option<(usize, f64)> {
        let model = self.reference_model();
        let k = model.intrinsics;
        let ray = model.unproject_z1(DVec2::new(k.cx_px, k.cy_px))?;
        let steps = planes.saturating_sub(1).max(1) as f64;
        (0..self.cameras.len())
            .filter(|&i| self.reference_index() != Some(i))
            .filter_map(|i| {
                let cam_from_ref = self.cam_from_ref(i);
                let project = |depth: f64| {
                    let model = &self.cameras[i].model;
                    model.project(cam_from_ref.transform_point(ray * depth))
                };
                let (near, far) = (project(min_depth_m), project(max_depth_m));
                Some((i, near?.distance(far?) / steps))
            })
            .max_by(|a, b| a.1.total_cmp(&b.1))
    }

    /// Splits the non-reference cameras into the two halves of the paper's best half-sequence:
    /// left and right of the reference along the rig's main baseline direction.
    ///
    /// The baseline direction is the principal axis of the camera centres (the reference
    /// included), oriented to agree with the reference's +x axis. A camera is "left" when its
    /// centre lies on the negative side of the reference centre along that axis. Returns one
    /// entry per camera: `Some(false)` = left, `Some(true)` = right, `None` = the reference.
    pub fn half_sequence_split(&self) -> Vec<Option<bool>> {
        let ref_from_rig = self.ref_from_rig();
        let centres_in_ref: Vec<DVec3> = self
            .cameras
            .iter()
            .map(|c| ref_from_rig.transform_point(c.centre_in_rig()))
            .collect();
        let mut points = centres_in_ref.clone();
        if self.reference_index().is_none() {
            points.push(DVec3::ZERO);
        }
        let n = points.len() as f64;
        let mean = points.iter().copied().fold(DVec3::ZERO, |a, b| a + b) / n;
        let mut cov = nalgebra::Matrix3::<f64>::zeros();
        for p in &points {
            let d = nalgebra::Vector3::new(p.x - mean.x, p.y - mean.y, p.z - mean.z);
            cov += d * d.transpose();
        }
        let eigen = nalgebra::SymmetricEigen::new(cov);
        let mut best = 0;
        for i in 1..3 {
            if eigen.eigenvalues[i] > eigen.eigenvalues[best] {
                best = i;
            }
        }
        let v = eigen.eigenvectors.column(best);
        let mut axis = DVec3::new(v[0], v[1], v[2]);
        if axis.length_squared() < 1e-24 || !axis.is_finite() {
            axis = DVec3::X;
        }
        if axis.dot(DVec3::X) < 0.0 {
            axis = -axis;
        }
        let reference = self.reference_index();
        centres_in_ref
            .iter()
            .enumerate()
            .map(|(i, c)| {
                if Some(i) == reference {
                    None
                } else {
                    Some(c.dot(axis) > 0.0)
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::PinholeIntrinsics;
    use glam::DQuat;

    #[test]
    fn half_sequence_split_follows_geometry_not_order() {
        let model = CameraModel::pinhole(PinholeIntrinsics {
            width_px: 10,
            height_px: 10,
            fx_px: 10.0,
            fy_px: 10.0,
            cx_px: 4.5,
            cy_px: 4.5,
        });
        // Cameras listed out of order along x; the reference is at x = 0.
        let xs = [0.2, -0.1, 0.0, 0.1, -0.2];
        let cameras = xs
            .iter()
            .enumerate()
            .map(|(i, &x)| RigCamera {
                name: format!("c{i}"),
                model,
                cam_from_rig: RigidTransform {
                    rotation: DQuat::IDENTITY,
                    translation: DVec3::new(-x, 0.0, 0.0),
                },
            })
            .collect();
        let rig = Rig::new(cameras, Reference::Camera(2)).unwrap();
        assert_eq!(
            rig.half_sequence_split(),
            vec![Some(true), Some(false), None, Some(true), Some(false)]
        );
    }
}
