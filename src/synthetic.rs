//! Synthetic rigs and textured scenes with exact ground truth, rendered by ray casting through
//! the same camera models the engine uses. Used by the tests, `bench` and `demo`.

use glam::{DQuat, DVec2, DVec3};

use crate::geometry::{
    CameraModel, Distortion, GeometryError, PinholeIntrinsics, Reference, Rig, RigCamera,
    RigidTransform,
};
use crate::image::{ImageF32, Rgba8Image};

/// A textured planar patch in the world (rig) frame: points `origin + a u_axis + b v_axis` with
/// |a| <= half_extent.x and |b| <= half_extent.y (infinite when `half_extent` is `None`).
#[derive(Debug, Clone, PartialEq)]
pub struct TexturedQuad {
    pub origin_in_world: DVec3,
    pub u_axis: DVec3,
    pub v_axis: DVec3,
    pub half_extent_m: Option<DVec2>,
    /// Size of one texture feature, metres.
    pub feature_m: f64,
    pub seed: u32,
    /// What is painted on it.
    pub pattern: Pattern,
}

/// The paint of a [`TexturedQuad`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Pattern {
    /// Value noise, features `feature_m` wide (matches at one depth only).
    #[default]
    Noise,
    /// A checkerboard of squares `feature_m` wide (smooth: sin x sin): a repeating pattern,
    /// which matches equally well one period off.
    Checkerboard,
}

impl TexturedQuad {
    /// A fronto-parallel (normal = world z) quad at depth `z_m`.
    pub fn fronto_parallel(
        z_m: f64,
        centre_xy: DVec2,
        half_extent_m: Option<DVec2>,
        feature_m: f64,
        seed: u32,
    ) -> Self {
        Self {
            origin_in_world: DVec3::new(centre_xy.x, centre_xy.y, z_m),
            u_axis: DVec3::X,
            v_axis: DVec3::Y,
            half_extent_m,
            feature_m,
            seed,
            pattern: Pattern::Noise,
        }
    }

    /// Ray parameter t of the hit of `origin + t dir`, if it hits inside the extent.
    fn hit(&self, origin: DVec3, dir: DVec3) -> Option<(f64, DVec2)> {
        let normal = self.u_axis.cross(self.v_axis);
        let denom = dir.dot(normal);
        if denom.abs() < 1e-12 {
            return None;
        }
        let t = (self.origin_in_world - origin).dot(normal) / denom;
        if t <= 1e-9 {
            return None;
        }
        let local = origin + dir * t - self.origin_in_world;
        let ab = DVec2::new(local.dot(self.u_axis), local.dot(self.v_axis));
        if let Some(h) = self.half_extent_m {
            if ab.x.abs() > h.x || ab.y.abs() > h.y {
                return None;
            }
        }
        Some((t, ab))
    }

    fn colour(&self, ab: DVec2) -> [f64; 3] {
        match self.pattern {
            Pattern::Noise => texture(ab, self.feature_m, self.seed),
            Pattern::Checkerboard => {
                // sin x sin: dark and light squares of `feature_m`, band-limited, so that every
                // view samples it alike (a hard-edged board aliases differently in each view,
                // which makes one false period match better than the truth).
                let p = ab * (std::f64::consts::PI / self.feature_m);
                [0.5 + 0.4 * p.x.sin() * p.y.sin(); 3]
            }
        }
    }
}

/// The texture at surface coordinates `ab` (metres): two octaves of value noise per channel.
fn texture(ab: DVec2, feature_m: f64, seed: u32) -> [f64; 3] {
    let p = ab / feature_m;
    let mut rgb = [0.0; 3];
    for (c, value) in rgb.iter_mut().enumerate() {
        let s = seed.wrapping_mul(3).wrapping_add(c as u32);
        *value =
            0.65 * value_noise(p, s) + 0.35 * value_noise(p * 2.7 + DVec2::splat(17.0), s ^ 0x5bd1);
    }
    rgb
}

fn hash(x: i64, y: i64, seed: u32) -> f64 {
    let mut h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ u64::from(seed).wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^= h >> 29;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 32;
    (h & 0xFFFF) as f64 / 65535.0
}

/// Smooth value noise in [0, 1].
fn value_noise(p: DVec2, seed: u32) -> f64 {
    let i = p.floor();
    let f = p - i;
    let s = f * f * (DVec2::splat(3.0) - 2.0 * f);
    let (x, y) = (i.x as i64, i.y as i64);
    let a = hash(x, y, seed);
    let b = hash(x + 1, y, seed);
    let c = hash(x, y + 1, seed);
    let d = hash(x + 1, y + 1, seed);
    let top = a + (b - a) * s.x;
    let bottom = c + (d - c) * s.x;
    top + (bottom - top) * s.y
}

/// A textured sphere in the world (rig) frame: the texture is laid on longitude and latitude
/// (arc lengths in metres), its seam on the far side from a camera looking down world +z.
#[derive(Debug, Clone, PartialEq)]
pub struct TexturedSphere {
    pub centre_in_world: DVec3,
    pub radius_m: f64,
    /// Size of one texture feature, metres.
    pub feature_m: f64,
    pub seed: u32,
}

impl TexturedSphere {
    /// Ray parameter t of the nearest hit of `origin + t dir` in front of the origin, and the
    /// texture coordinates there.
    fn hit(&self, origin: DVec3, dir: DVec3) -> Option<(f64, DVec2)> {
        let oc = origin - self.centre_in_world;
        let a = dir.length_squared();
        let half_b = oc.dot(dir);
        let c = oc.length_squared() - self.radius_m * self.radius_m;
        let disc = half_b * half_b - a * c;
        if disc < 0.0 || a < 1e-24 {
            return None;
        }
        let root = disc.sqrt();
        let t = [(-half_b - root) / a, (-half_b + root) / a]
            .into_iter()
            .find(|&t| t > 1e-9)?;
        let p = (origin + dir * t - self.centre_in_world) / self.radius_m;
        let longitude = p.x.atan2(-p.z);
        let latitude = p.y.clamp(-1.0, 1.0).asin();
        Some((t, DVec2::new(longitude, latitude) * self.radius_m))
    }

    fn colour(&self, ab: DVec2) -> [f64; 3] {
        texture(ab, self.feature_m, self.seed)
    }
}

/// A set of quads and spheres; the nearest hit along a ray wins.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Scene {
    pub quads: Vec<TexturedQuad>,
    pub spheres: Vec<TexturedSphere>,
}

impl Scene {
    /// A textured wall at `wall_z_m` and, optionally, a textured box face (square of side
    /// `2 half_m`) at `front_z_m` centred on the optical axis of the world frame. Texture
    /// features are about 2.5 pixels wide for a camera of focal length `focal_px`, so the
    /// renders are not aliased.
    pub fn wall_and_box(wall_z_m: f64, front: Option<(f64, f64)>, focal_px: f64) -> Self {
        let feature = |z: f64| 2.5 * z / focal_px;
        let mut quads = vec![TexturedQuad::fronto_parallel(
            wall_z_m,
            DVec2::ZERO,
            None,
            feature(wall_z_m),
            1,
        )];
        if let Some((front_z_m, half_m)) = front {
            quads.push(TexturedQuad::fronto_parallel(
                front_z_m,
                DVec2::ZERO,
                Some(DVec2::splat(half_m)),
                feature(front_z_m),
                7,
            ));
        }
        Self {
            quads,
            spheres: Vec::new(),
        }
    }

    /// Casts a ray in the world frame; returns (t, colour in 0..1).
    fn cast(&self, origin: DVec3, dir: DVec3) -> Option<(f64, [f64; 3])> {
        let mut best: Option<(f64, [f64; 3])> = None;
        for quad in &self.quads {
            if let Some((t, ab)) = quad.hit(origin, dir) {
                if best.is_none_or(|(bt, _)| t < bt) {
                    best = Some((t, quad.colour(ab)));
                }
            }
        }
        for sphere in &self.spheres {
            if let Some((t, ab)) = sphere.hit(origin, dir) {
                if best.is_none_or(|(bt, _)| t < bt) {
                    best = Some((t, sphere.colour(ab)));
                }
            }
        }
        best
    }

    /// Renders camera `camera` (2x2 supersampled); background where nothing is hit is mid grey.
    pub fn render(&self, camera: &RigCamera) -> Rgba8Image {
        let k = camera.model.intrinsics;
        let rig_from_cam = camera.cam_from_rig.inverse();
        let centre = rig_from_cam.translation;
        let mut pixels = Vec::with_capacity((k.width_px * k.height_px) as usize);
        for y in 0..k.height_px {
            for x in 0..k.width_px {
                let mut sum = [0.0; 3];
                for (sx, sy) in [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)] {
                    let pixel = DVec2::new(f64::from(x) + sx, f64::from(y) + sy);
                    let rgb = camera
                        .model
                        .unproject_z1(pixel)
                        .and_then(|ray| self.cast(centre, rig_from_cam.transform_vector(ray)))
                        .map_or([0.5; 3], |(_, c)| c);
                    for c in 0..3 {
                        sum[c] += rgb[c] * 0.25;
                    }
                }
                let q = |v: f64| (v * 255.0).round().clamp(0.0, 255.0) as u8;
                pixels.push(Rgba8Image::pack(q(sum[0]), q(sum[1]), q(sum[2])));
            }
        }
        Rgba8Image {
            width: k.width_px,
            height: k.height_px,
            pixels,
        }
    }

    /// Ground-truth z-depth (metres) of every pixel centre of `model` at pose `cam_from_rig`.
    pub fn depth(&self, model: &CameraModel, cam_from_rig: &RigidTransform) -> ImageF32 {
        let k = model.intrinsics;
        let rig_from_cam = cam_from_rig.inverse();
        let mut data = Vec::with_capacity((k.width_px * k.height_px) as usize);
        for y in 0..k.height_px {
            for x in 0..k.width_px {
                // The ray has z = 1 in the camera frame, so t is the z-depth.
                let hit = model
                    .unproject_z1(DVec2::new(f64::from(x), f64::from(y)))
                    .and_then(|ray| {
                        self.cast(rig_from_cam.translation, rig_from_cam.transform_vector(ray))
                    });
                data.push(hit.map_or(f32::NAN, |(t, _)| t as f32));
            }
        }
        ImageF32 {
            width: k.width_px,
            height: k.height_px,
            data,
        }
    }
}

/// Pinhole intrinsics with a horizontal field of view of about 60 degrees.
pub fn intrinsics(width_px: u32, height_px: u32) -> PinholeIntrinsics {
    let f = 0.87 * f64::from(width_px);
    PinholeIntrinsics {
        width_px,
        height_px,
        fx_px: f,
        fy_px: f,
        cx_px: (f64::from(width_px) - 1.0) / 2.0,
        cy_px: (f64::from(height_px) - 1.0) / 2.0,
    }
}

/// `n` cameras in a row along world x, `baseline_m` apart, looking down world +z; the reference is
/// camera `reference`.
pub fn row_rig(
    n: usize,
    baseline_m: f64,
    model: CameraModel,
    reference: usize,
) -> Result<Rig, GeometryError> {
    let cameras = (0..n)
        .map(|i| {
            let x = (i as f64 - reference as f64) * baseline_m;
            RigCamera {
                name: format!("cam{i}"),
                model,
                cam_from_rig: RigidTransform {
                    rotation: DQuat::IDENTITY,
                    translation: DVec3::new(-x, 0.0, 0.0),
                },
            }
        })
        .collect();
    Rig::new(cameras, Reference::Camera(reference))
}

/// A rig for general-pose tests: cameras on a horizontal arc around a point `distance_m` ahead,
/// each turned to look at it (converging views), with optional distortion.
pub fn arc_rig(
    n: usize,
    step_rad: f64,
    distance_m: f64,
    model: CameraModel,
    reference: usize,
) -> Result<Rig, GeometryError> {
    let target = DVec3::new(0.0, 0.0, distance_m);
    let cameras = (0..n)
        .map(|i| {
            let angle = (i as f64 - reference as f64) * step_rad;
            // Rotate the reference pose about the target by `angle` around world y.
            let rig_from_cam_rot = DQuat::from_rotation_y(-angle);
            let centre = target + rig_from_cam_rot * DVec3::new(0.0, 0.0, -distance_m);
            let rig_from_cam = RigidTransform {
                rotation: rig_from_cam_rot,
                translation: centre,
            };
            RigCamera {
                name: format!("cam{i}"),
                model,
                cam_from_rig: rig_from_cam.inverse(),
            }
        })
        .collect();
    Rig::new(cameras, Reference::Camera(reference))
}

/// `n` cameras on a spherical cap of half-angle `cap_rad` around the point `distance_m` ahead
/// of camera 0 (at the cap's pole), each looking at it: a capture dome's cameras over a scene.
/// The others lie on a golden-angle spiral, evenly over the cap.
pub fn dome_rig(
    n: usize,
    cap_rad: f64,
    distance_m: f64,
    model: CameraModel,
    reference: usize,
) -> Result<Rig, GeometryError> {
    let target = DVec3::new(0.0, 0.0, distance_m);
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let cameras = (0..n)
        .map(|i| {
            let polar = cap_rad * (i as f64 / (n.max(2) - 1) as f64).sqrt();
            let azimuth = i as f64 * golden;
            // Tilt by `polar` about the axis at `azimuth` in the x-y plane: "up" stays up.
            let rotation = DQuat::from_rotation_z(azimuth)
                * DQuat::from_rotation_y(polar)
                * DQuat::from_rotation_z(-azimuth);
            let rig_from_cam = RigidTransform {
                rotation,
                translation: target + rotation * DVec3::new(0.0, 0.0, -distance_m),
            };
            RigCamera {
                name: format!("cam{i}"),
                model,
                cam_from_rig: rig_from_cam.inverse(),
            }
        })
        .collect();
    Rig::new(cameras, Reference::Camera(reference))
}

/// Renders every camera of the rig.
pub fn render_rig(scene: &Scene, rig: &Rig) -> Vec<Rgba8Image> {
    rig.cameras.iter().map(|c| scene.render(c)).collect()
}

/// Ground-truth depth for the rig's reference camera.
pub fn reference_depth(scene: &Scene, rig: &Rig) -> ImageF32 {
    scene.depth(&rig.reference_model(), &rig.ref_from_rig())
}

/// A mild barrel distortion for tests.
pub fn plumb_bob_barrel() -> Distortion {
    Distortion::PlumbBob {
        k1: -0.12,
        k2: 0.02,
        p1: 0.0005,
        p2: -0.0003,
        k3: 0.0,
    }
}
