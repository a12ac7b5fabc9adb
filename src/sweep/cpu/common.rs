//! Twin of `shaders/common.wgsl`: projection and plane maths in f32, as the shaders do them.

use crate::sweep::gpu_types::*;

pub type Vec2 = [f32; 2];
pub type Vec3 = [f32; 3];

#[inline(always)]
pub fn dot3(a: Vec3, b: Vec3) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline(always)]
pub fn xyz(v: [f32; 4]) -> Vec3 {
    [v[0], v[1], v[2]]
}

/// Returns (pixel x, pixel y, depth in camera); depth <= 0 when behind.
#[inline(always)]
pub fn project(cam: &GpuCamera, point_in_ref: Vec3) -> Vec3 {
    let p = [
        dot3(xyz(cam.row0), point_in_ref) + cam.row0[3],
        dot3(xyz(cam.row1), point_in_ref) + cam.row1[3],
        dot3(xyz(cam.row2), point_in_ref) + cam.row2[3],
    ];
    if p[2] <= 1e-6 {
        return [0.0, 0.0, -1.0];
    }
    match lens(cam, [p[0] / p[2], p[1] / p[2]]) {
        Some(pixel) => [pixel[0], pixel[1], p[2]],
        None => [0.0, 0.0, -1.0],
    }
}

/// The second half of `project`: a point on the camera's z = 1 plane through its distortion
/// and intrinsics to a pixel; None past the distortion model's fold (where the point would
/// land back in the image: not seen).
#[inline(always)]
pub fn lens(cam: &GpuCamera, normalised: Vec2) -> Option<Vec2> {
    let mut n = normalised;
    if cam.size[3] != DIST_NONE && n[0] * n[0] + n[1] * n[1] > cam.dist_b[1] {
        return None;
    }
    if cam.size[3] == DIST_PLUMB_BOB {
        n = plumb_bob(cam, n);
    } else if cam.size[3] == DIST_EQUIDISTANT {
        let r = (n[0] * n[0] + n[1] * n[1]).sqrt();
        if r > 1e-12 {
            let theta = r.atan();
            let t2 = theta * theta;
            let [k1, k2, k3, k4] = cam.dist_a;
            let theta_d = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))));
            n = [n[0] * theta_d / r, n[1] * theta_d / r];
        }
    }
    Some([
        cam.intrinsics[0] * n[0] + cam.intrinsics[2],
        cam.intrinsics[1] * n[1] + cam.intrinsics[3],
    ])
}

/// `project` without its branches, for row loops that vectorise (the pinhole and plumb-bob
/// lenses; `distort` is `lens` less its fold test and intrinsics): the pixel, the depth in the
/// camera and whether `project` would have projected the point (in front, z > 1e-6, and not
/// past the distortion's fold). Every step is made for every point; where the last is false
/// the first two are not `project`'s and must not be used. The same floats where it is true.
#[inline(always)]
pub fn project_unbranched(
    cam: &GpuCamera,
    point: Vec3,
    distort: impl Fn(Vec2) -> Vec2,
) -> (Vec2, f32, bool) {
    let p = [
        dot3(xyz(cam.row0), point) + cam.row0[3],
        dot3(xyz(cam.row1), point) + cam.row1[3],
        dot3(xyz(cam.row2), point) + cam.row2[3],
    ];
    let n = [p[0] / p[2], p[1] / p[2]];
    let past_fold = (cam.size[3] != DIST_NONE) & (n[0] * n[0] + n[1] * n[1] > cam.dist_b[1]);
    let d = distort(n);
    let [fx, fy, cx, cy] = cam.intrinsics;
    let pixel = [fx * d[0] + cx, fy * d[1] + cy];
    (pixel, p[2], (p[2] > 1e-6) & !past_fold)
}

/// The plumb-bob model of `lens` (camera `cam`'s coefficients) on a point of the z = 1 plane.
#[inline(always)]
pub fn plumb_bob(cam: &GpuCamera, n: Vec2) -> Vec2 {
    let [k1, k2, p1, p2] = cam.dist_a;
    let r2 = n[0] * n[0] + n[1] * n[1];
    let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * cam.dist_b[0]));
    let xy = n[0] * n[1];
    [
        n[0] * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * n[0] * n[0]),
        n[1] * radial + p1 * (r2 + 2.0 * n[1] * n[1]) + 2.0 * p2 * xy,
    ]
}

#[inline(always)]
pub fn inside(cam: &GpuCamera, pixel: Vec2) -> bool {
    let w = cam.size[0] as f32 - 1.0;
    let h = cam.size[1] as f32 - 1.0;
    pixel[0] >= 0.0 && pixel[1] >= 0.0 && pixel[0] <= w && pixel[1] <= h
}

#[inline(always)]
pub fn plane_depth(plane: [f32; 4], ray: Vec3) -> f32 {
    let denom = dot3(xyz(plane), ray);
    if denom.abs() < 1e-12 {
        return -1.0;
    }
    plane[3] / denom
}

/// One camera image as planar f32 channels (0..255, as the shaders' `texel`), so that rows
/// of samples are contiguous slices the compiler vectorises, and as interleaved texels for
/// samples at scattered positions (a bilinear sample is four 16-byte loads, not twelve).
#[derive(Debug, Default)]
pub struct PlanarImage {
    pub width: usize,
    pub height: usize,
    /// R, G, B planes, row-major.
    pub channels: [Vec<f32>; 3],
    /// The three channels hold the same values (a prefiltered image: its alpha byte in all
    /// three, `Params.colour_in_alpha`): the row loops sample and compare R alone.
    pub grey: bool,
    /// Per texel, row-major: its colour's bytes [R, G, B, 0] (little-endian in the first
    /// `u32`: `f32::from(byte)` is the channel's value, as `v / 255 * 255 == v` in f32 for every
    /// byte, `texel_bytes_are_the_channel_values`) and its census word (0 without census
    /// words), so one 8-byte load brings a scattered sample's colour and census word
    /// (`gather.rs`; 8 bytes rather than four f32 lanes: half the cache lines of the ring's
    /// gathers).
    pub texels: Vec<[u32; 2]>,
}

impl PlanarImage {
    /// Unpacks `pixels` (RGBA8 in a `u32`, red in the low byte) as `unpack4x8unorm(..) * 255`.
    pub fn from_packed(width: usize, height: usize, pixels: &[u32]) -> Self {
        let mut image = Self::default();
        image.fill_from_packed(width, height, pixels, false, true, None);
        image
    }

    /// [`Self::from_packed`] into this image's buffers (kept across frame sets); the
    /// interleaved texels only `with_texels` (samples at scattered positions: a camera that
    /// does not see the reference grid through a translation), with the image's census
    /// `words` when there are some.
    pub fn fill_from_packed(
        &mut self,
        width: usize,
        height: usize,
        pixels: &[u32],
        colour_in_alpha: bool,
        with_texels: bool,
        words: Option<&[u32]>,
    ) {
        self.width = width;
        self.height = height;
        self.grey = colour_in_alpha;
        // The colour the cost compares (`texel_at` in cost.wgsl): the RGB, or for prefiltered
        // images (`sweep/prefilter.rs`) the alpha byte in all three.
        let colour = |p: u32| {
            if colour_in_alpha {
                (p >> 24) * 0x0001_0101
            } else {
                p & 0x00ff_ffff
            }
        };
        for (c, channel) in self.channels.iter_mut().enumerate() {
            let shift = 8 * c as u32;
            channel.clear();
            channel.extend(
                pixels
                    .iter()
                    .map(|&p| f32::from(((colour(p) >> shift) & 0xff) as u8) / 255.0 * 255.0),
            );
        }
        self.texels.clear();
        if !with_texels {
            return;
        }
        let rgb = pixels.iter().map(|&p| colour(p));
        match words {
            Some(words) => self
                .texels
                .extend(rgb.zip(words).map(|(colour, &word)| [colour, word])),
            None => self.texels.extend(rgb.map(|colour| [colour, 0])),
        }
    }

    /// The colour at texel (x, y).
    pub fn texel(&self, x: usize, y: usize) -> Vec3 {
        let i = y * self.width + x;
        [
            self.channels[0][i],
            self.channels[1][i],
            self.channels[2][i],
        ]
    }

    /// Twin of `sample_bilinear` (cost.wgsl) for a pixel that `inside` accepted.
    #[inline(always)]
    pub fn sample_bilinear(&self, pixel: Vec2) -> Vec3 {
        self.sample_with_words(pixel).0
    }

    /// [`Self::sample_bilinear`], and the census words of the four texels around the sample
    /// (00, 10, 01, 11) with the sample's weights (fx, fy): the scalar form of `gather.rs`.
    #[inline(always)]
    pub fn sample_with_words(&self, pixel: Vec2) -> (Vec3, [u32; 4], [f32; 2]) {
        let b = Bilinear::at(self.width, self.height, pixel);
        let colour = std::array::from_fn(|c| b.mix(|i| self.channels[c][i]));
        let words = [b.i00, b.i10, b.i01, b.i11].map(|i| self.texels[i][1]);
        (colour, words, [b.fx, b.fy])
    }
}

/// Twin of `Bilinear` (cost.wgsl): the four texels around a sample that `inside` accepted
/// (row-major indices into an image of `width` x `height`) and its weights.
#[derive(Debug, Clone, Copy)]
pub struct Bilinear {
    i00: usize,
    i10: usize,
    i01: usize,
    i11: usize,
    fx: f32,
    fy: f32,
}

impl Bilinear {
    #[inline(always)]
    pub fn at(width: usize, height: usize, pixel: Vec2) -> Self {
        let bx = pixel[0].floor();
        let by = pixel[1].floor();
        let (x0, y0) = (bx as usize, by as usize);
        let x1 = (x0 + 1).min(width - 1);
        let y1 = (y0 + 1).min(height - 1);
        Self {
            i00: y0 * width + x0,
            i10: y0 * width + x1,
            i01: y1 * width + x0,
            i11: y1 * width + x1,
            fx: pixel[0] - bx,
            fy: pixel[1] - by,
        }
    }

    /// `value` (of a texel index) interpolated at the sample.
    #[inline(always)]
    pub fn mix(&self, value: impl Fn(usize) -> f32) -> f32 {
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        let top = lerp(value(self.i00), value(self.i10), self.fx);
        let bottom = lerp(value(self.i01), value(self.i11), self.fx);
        lerp(top, bottom, self.fy)
    }
}

/// The WGSL `min` of two non-NaN values (`f32::min`: an unconditional select, which keeps the
/// compiler from turning `x = min(x, v)` into slow masked stores).
#[inline(always)]
pub fn fmin(a: f32, b: f32) -> f32 {
    a.min(b)
}

// The run-time dispatch to an AVX2 + FMA build of a loop, shared with `fusion/`: `crate::simd`.
pub use crate::simd::has_avx2_fma;
pub(crate) use crate::simd::vectorised_fn;

/// A small rig for the tests of the projection loops: three 48x36 cameras converging steeply
/// on an arc (the side ones see points far off their axes, past a barrel lens's fold), with
/// each lens in turn: a barrel (plumb-bob) and none. Its plan has the default parameters.
#[cfg(test)]
pub(crate) fn converging_test_plans() -> Vec<crate::sweep::plan::SweepPlan> {
    use crate::geometry::{CameraModel, Distortion, PinholeIntrinsics};
    let intrinsics = PinholeIntrinsics {
        width_px: 48,
        height_px: 36,
        fx_px: 80.0,
        fy_px: 84.0,
        cx_px: 23.5,
        cy_px: 17.25,
    };
    let barrel = Distortion::PlumbBob {
        k1: -0.3,
        k2: 0.0,
        p1: 0.001,
        p2: -0.002,
        k3: 0.0,
    };
    [barrel, Distortion::None]
        .into_iter()
        .map(|distortion| {
            let model = CameraModel {
                intrinsics,
                distortion,
            };
            let rig = crate::synthetic::arc_rig(3, 0.6, 2.0, model, 1).expect("rig");
            let params = crate::sweep::SweepParams::default();
            crate::sweep::plan::SweepPlan::new(&rig, &params).expect("plan")
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::RigidTransform;
    use crate::geometry::{CameraModel, Distortion, PinholeIntrinsics, Reference, Rig, RigCamera};
    use crate::sweep::plan::SweepPlan;
    use crate::sweep::SweepParams;
    use glam::DVec3;

    /// The texels' colour bytes are the channels' values (`PlanarImage::texels`; the gather
    /// reads the bytes, the rows the channels): `v / 255 * 255` is `v` in f32 for every byte.
    #[test]
    fn texel_bytes_are_the_channel_values() {
        let pixels: Vec<u32> = (0..=255u32)
            .map(|v| v | (255 - v) << 8 | (v * 7 % 256) << 16 | (v * 13 % 256) << 24)
            .collect();
        let image = PlanarImage::from_packed(256, 1, &pixels);
        for (i, texel) in image.texels.iter().enumerate() {
            for c in 0..3 {
                let byte = (texel[0] >> (8 * c)) & 0xff;
                assert_eq!(
                    f32::from(byte as u8).to_bits(),
                    image.channels[c][i].to_bits(),
                    "texel {i} channel {c}"
                );
            }
            assert_eq!(texel[0] >> 24, 0);
        }
    }

    /// The plan packs the end of each camera's monotonic branch, and the projection (here the
    /// CPU twin of the shader's) does not see points past it, which the model would fold back
    /// into the image.
    #[test]
    fn points_past_a_distortion_fold_are_not_seen() {
        let intrinsics = PinholeIntrinsics {
            width_px: 64,
            height_px: 48,
            fx_px: 80.0,
            fy_px: 80.0,
            cx_px: 31.5,
            cy_px: 23.5,
        };
        // Barrel k1 = -0.3: the fold is at r = 1/sqrt(0.9) = 1.054 (46.5 degrees).
        let barrel = CameraModel {
            intrinsics,
            distortion: Distortion::PlumbBob {
                k1: -0.3,
                k2: 0.0,
                p1: 0.0,
                p2: 0.0,
                k3: 0.0,
            },
        };
        let cameras = (0..2)
            .map(|i| RigCamera {
                name: format!("c{i}"),
                model: if i == 0 {
                    CameraModel::pinhole(intrinsics)
                } else {
                    barrel
                },
                cam_from_rig: RigidTransform {
                    rotation: glam::DQuat::IDENTITY,
                    translation: DVec3::new(-0.1 * i as f64, 0.0, 0.0),
                },
            })
            .collect();
        let rig = Rig::new(cameras, Reference::Camera(0)).unwrap();
        let plan = SweepPlan::new(&rig, &SweepParams::default()).unwrap();
        let cam = &plan.cameras[1];
        assert!(
            (f64::from(cam.dist_b[1]) - 1.0 / 0.9).abs() < 1e-6,
            "{:?}",
            cam.dist_b
        );
        assert_eq!(plan.cameras[0].dist_b[1], f32::MAX);
        // In the camera's frame (its row transform is a translation by -0.1 m along x).
        let at = |x_over_z: f32| [x_over_z * 2.0 + 0.1, 0.0, 2.0];
        // Inside the branch: projected where the model says.
        let inside = project(cam, at(0.9));
        let want = barrel.project(DVec3::new(0.9, 0.0, 1.0)).unwrap();
        assert!(inside[2] > 0.0 && (f64::from(inside[0]) - want.x).abs() < 1e-3);
        // Past the fold (r = 1.6: the model would put it at 0.371, inside the image): unseen.
        let distorted = barrel.distortion.distort(glam::DVec2::new(1.6, 0.0));
        assert!(
            distorted.x * 80.0 + 31.5 < 63.0,
            "the fold lands inside the image"
        );
        assert!(project(cam, at(1.6))[2] < 0.0);
    }
}
