//! Analytic scenes for the fusion tests: depth maps of a sphere and of planes, rendered by
//! ray casting through a pinhole (or distorted) camera, and poses looking at a point.

use glam::{DMat3, DVec2, DVec3};

use crate::geometry::{CameraModel, PinholeIntrinsics, RigidTransform};
use crate::image::{ImageF32, Rgba8Image};

pub fn camera(width: u32, height: u32, focal_px: f64) -> CameraModel {
    CameraModel::pinhole(PinholeIntrinsics {
        width_px: width,
        height_px: height,
        fx_px: focal_px,
        fy_px: focal_px,
        cx_px: (f64::from(width) - 1.0) / 2.0,
        cy_px: (f64::from(height) - 1.0) / 2.0,
    })
}

/// `world_from_cam` of an optical frame at `eye` looking at `target`, with the image's "up"
/// (-y) as close to `up` as it can be.
pub fn look_at(eye: DVec3, target: DVec3, up: DVec3) -> RigidTransform {
    let z = (target - eye).normalize();
    let x = z.cross(up).normalize();
    let y = z.cross(x);
    RigidTransform::from_matrix_translation("test", DMat3::from_cols(x, y, z), eye).unwrap()
}

/// Renders a depth map by casting each pixel's ray into `hit` (ray origin and direction in
/// the world frame, direction with z = 1 in the camera frame) which returns the ray's
/// parameter at the first hit; the parameter of a z = 1 ray is the depth.
fn render(
    model: &CameraModel,
    world_from_cam: &RigidTransform,
    hit: impl Fn(DVec3, DVec3) -> Option<f64>,
) -> ImageF32 {
    let (w, h) = (model.intrinsics.width_px, model.intrinsics.height_px);
    let mut data = Vec::with_capacity((w * h) as usize);
    for v in 0..h {
        for u in 0..w {
            let depth = model
                .unproject_z1(DVec2::new(f64::from(u), f64::from(v)))
                .and_then(|ray| {
                    hit(
                        world_from_cam.translation,
                        world_from_cam.transform_vector(ray),
                    )
                })
                .filter(|t| *t > 0.0);
            data.push(depth.map_or(f32::NAN, |d| d as f32));
        }
    }
    ImageF32 {
        width: w,
        height: h,
        data,
    }
}

pub fn render_sphere(
    model: &CameraModel,
    world_from_cam: &RigidTransform,
    centre: DVec3,
    radius: f64,
) -> ImageF32 {
    render(model, world_from_cam, |origin, dir| {
        let oc = origin - centre;
        let a = dir.dot(dir);
        let b = 2.0 * dir.dot(oc);
        let c = oc.dot(oc) - radius * radius;
        let disc = b * b - 4.0 * a * c;
        (disc >= 0.0).then(|| (-b - disc.sqrt()) / (2.0 * a))
    })
}

/// The plane `normal . p = offset` (world frame), seen where it is in front of the camera.
pub fn render_plane(
    model: &CameraModel,
    world_from_cam: &RigidTransform,
    normal: DVec3,
    offset: f64,
) -> ImageF32 {
    render(model, world_from_cam, |origin, dir| {
        let denom = normal.dot(dir);
        (denom.abs() > 1e-12).then(|| (offset - normal.dot(origin)) / denom)
    })
}

/// A sphere (0.35 m radius at (0.1, 0, 1.8)) before a slanted wall (normal (0.3, 0.1, 1),
/// 2.4 m from the origin): the nearer of the two at each pixel.
pub fn sphere_before_slanted_wall(
    model: &CameraModel,
    world_from_cam: &RigidTransform,
) -> ImageF32 {
    let sphere = render_sphere(model, world_from_cam, DVec3::new(0.1, 0.0, 1.8), 0.35);
    let normal = DVec3::new(0.3, 0.1, 1.0).normalize();
    let mut depth = render_plane(model, world_from_cam, normal, 2.4);
    for (d, s) in depth.data.iter_mut().zip(&sphere.data) {
        if s.is_finite() && (!d.is_finite() || s < d) {
            *d = *s;
        }
    }
    depth
}

/// A colour image: red on the left half, blue on the right.
pub fn red_left_blue_right(width: u32, height: u32) -> Rgba8Image {
    let pixels = (0..width * height)
        .map(|i| {
            if i % width < width / 2 {
                Rgba8Image::pack(255, 0, 0)
            } else {
                Rgba8Image::pack(0, 0, 255)
            }
        })
        .collect();
    Rgba8Image {
        width,
        height,
        pixels,
    }
}
