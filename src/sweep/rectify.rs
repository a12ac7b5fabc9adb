//! A pair of cameras whose images are not rectified (a driver's `image_raw`: lens distortion,
//! views turned slightly toward each other) swept as a rectified pair (`rectify_pairs`, the CPU
//! engine): both images are resampled once onto one rectified grid, as image_proc and
//! stereo_image_proc do before OpenCV's block matchers, so the sweep takes the shifted-row fast
//! path (`cpu/cost.rs`: no projection per pixel and plane, no gathers); the depth comes back
//! onto the reference's own pixels.
//!
//! The rectification (Fusiello, Trucco & Verri 2000): both rectified cameras look along the
//! mean of the two optical axes turned square to the baseline, their rows along the baseline,
//! with one pinhole model of the reference image's size whose focal length is the reference's,
//! shrunk just enough for the grid to hold every pixel of the reference's image (a barrel
//! widens the view: no depth is lost at the image's edges, and no more pixels are swept than
//! the image has). Everything that depends on the
//! rig alone (the two resampling maps and the way back) is made once and kept while the two
//! cameras' models and their relative pose stay the same (a moving stereo camera keeps them).
//!
//! The way back: the rectified reference's depth z' at the pixel where a reference pixel's ray
//! lands, bilinear where its four neighbours agree within 2 % (else the nearest), times the
//! ray's `z / z'`; the other maps take the nearest pixel's value. A pixel whose match would lie
//! where the other camera's image has no pixels is invalid, as the raw sweep finds no view of
//! it there.

use std::sync::Arc;

use glam::{DMat3, DQuat, DVec2, DVec3};
use rayon::prelude::*;

use super::gpu_types::MAX_SGM_PLANES;
use super::{selection, DepthMaps, Optimizer, SweepError, SweepParams, WantedMaps, MAX_PLANES};
use crate::geometry::{CameraModel, PinholeIntrinsics, Reference, Rig, RigCamera, RigidTransform};
use crate::image::{ImageF32, Rgba8Image};

/// The widest angle between the baseline and the reference's rows that is rectified (a pair
/// one above the other keeps the raw sweep).
pub const MAX_BASELINE_ANGLE_DEG: f64 = 30.0;
/// The widest turn of either camera onto the rectified axis.
pub const MAX_TURN_DEG: f64 = 20.0;
/// The least share of the reference's focal length the rectified grid keeps (it is the image's
/// size, so strong distortion or a wide turn would shrink the view too far).
pub const MIN_ZOOM: f64 = 0.75;
/// Neighbours within this share of each other are interpolated on the way back.
const AGREE: f32 = 0.02;

/// The rectified grids the CPU engine keeps (a rig's references each have their own).
const KEPT: usize = 16;
/// Relative poses this close are one (a moving rig's poses composed from its motion differ in
/// their last bits from set to set): translation relative to the baseline, rotation in the
/// quaternion's vector part (half the angle, radians).
const SAME_POSE: f64 = 1e-9;

impl Key {
    fn same(&self, other: &Key) -> bool {
        let (p, q) = (&self.other_from_reference, &other.other_from_reference);
        let turn = (p.rotation.inverse() * q.rotation).xyz().length();
        self.reference == other.reference
            && self.names == other.names
            && self.models == other.models
            && (p.translation - q.translation).length() <= SAME_POSE * p.translation.length()
            && turn <= SAME_POSE
    }
}

/// What a rectified pair is made from: the reference's index, the two cameras' names and
/// models (reference first), and where the other lies from the reference (not where the rig
/// is: a moving stereo camera keeps its rectification, whose rig keeps the first set's poses:
/// the sweep reads only the pair's relative pose).
#[derive(Debug, Clone)]
struct Key {
    reference: usize,
    names: [String; 2],
    models: [CameraModel; 2],
    other_from_reference: RigidTransform,
}

/// A pair's rectification: the rectified rig and the maps to it and back.
#[derive(Debug)]
pub struct Rectified {
    /// The two rectified cameras (pinhole, one model, rows along the baseline), in the
    /// original order, the reference the same index; named `NAME~rectified for REFERENCE`
    /// (the frame memo and the plan cache key on names).
    pub rig: Rig,
    /// The rig it rectifies.
    pub source: Rig,
    /// Per rectified pixel of each camera (indexed as the rig), where it samples its raw
    /// image.
    to_rectified: [Vec<Tap>; 2],
    /// Per reference pixel, where its ray lands on the grid (NaN: it has no ray, or lands
    /// outside), and `z / z'` from there: `scale . (x, y, 1)`.
    back: Vec<[f32; 2]>,
    scale: [f32; 3],
    /// The least and the greatest `z / z'` over the reference's pixels that land.
    scale_range: [f64; 2],
    /// Per row of the grid, the first and last column the other camera's image covers
    /// (`[1, 0]`: none).
    seen_columns: Vec<[f32; 2]>,
    /// `f * baseline` in rectified pixels times metres, and the sign of the other camera's
    /// shift (its column is `u - sign * disparity`).
    focal_baseline: f64,
    sign: f64,
    /// The raw reference's size.
    size: (u32, u32),
}

/// Where a rectified pixel samples a raw image: the top-left pixel of its 2x2 (`NONE`: no
/// pixel of the image sees it) and the weights of the right column and the lower row, in
/// 128ths (the bilinear of OpenCV's `remap`, in 32nds there).
#[derive(Debug, Clone, Copy)]
struct Tap {
    index: u32,
    fx: u8,
    fy: u8,
}

const NONE: u32 = u32::MAX;

/// The CPU engine's kept rectifications.
#[derive(Debug, Default)]
pub struct Rectifications {
    kept: Vec<(Key, Option<Arc<Rectified>>)>,
}

impl Rectifications {
    /// The rectification of `rig`, made or kept; `None` where the rig is not a pair of cameras
    /// that rectification helps (see [`rectify`]).
    pub fn for_rig(&mut self, rig: &Rig) -> Option<Arc<Rectified>> {
        let reference = rig.reference_index()?;
        if rig.cameras.len() != 2 || reference > 1 {
            return None;
        }
        let (a, b) = (&rig.cameras[reference], &rig.cameras[1 - reference]);
        let key = Key {
            reference,
            names: [a.name.clone(), b.name.clone()],
            models: [a.model, b.model],
            other_from_reference: rig.cam_from_ref(1 - reference),
        };
        if let Some(i) = self.kept.iter().position(|(k, _)| k.same(&key)) {
            let kept = self.kept.remove(i);
            let made = kept.1.clone();
            self.kept.push(kept);
            return made;
        }
        let made = rectify(rig).map(Arc::new);
        if self.kept.len() >= KEPT {
            self.kept.remove(0);
        }
        self.kept.push((key, made.clone()));
        made
    }
}

/// Whether a pair's images already meet on shifted rows: both undistorted, the same focal
/// lengths and rows, no turn between them, the baseline along the rows.
fn already_rectified(a: &RigCamera, b: &RigCamera, b_from_a: &RigidTransform) -> bool {
    let (ka, kb) = (&a.model.intrinsics, &b.model.intrinsics);
    let t = b_from_a.translation;
    a.model.distortion.is_none()
        && b.model.distortion.is_none()
        && ka.fx_px == kb.fx_px
        && ka.fy_px == kb.fy_px
        && ka.cy_px == kb.cy_px
        && b_from_a.rotation.xyz().length() <= 1e-7
        && t.y.abs() <= 1e-7 * t.length()
        && t.z.abs() <= 1e-7 * t.length()
}

/// The rectification of a rig of two cameras whose reference is one of them; `None` (said at
/// debug level) where the images already meet on shifted rows, the baseline runs more than
/// [`MAX_BASELINE_ANGLE_DEG`] off the reference's rows, a camera would turn more than
/// [`MAX_TURN_DEG`], or the rectified grid would keep less than [`MIN_ZOOM`] of the focal
/// length.
pub fn rectify(rig: &Rig) -> Option<Rectified> {
    let reference = rig.reference_index()?;
    let small = |c: &RigCamera| c.model.intrinsics.width_px < 2 || c.model.intrinsics.height_px < 2;
    if rig.cameras.len() != 2 || reference > 1 || rig.cameras.iter().any(small) {
        return None;
    }
    let other = 1 - reference;
    let (a, b) = (&rig.cameras[reference], &rig.cameras[other]);
    let b_from_a = rig.cam_from_ref(other);
    if already_rectified(a, b, &b_from_a) {
        return None;
    }
    let skip = |why: String| {
        tracing::debug!("{}: the raw pair is swept as it is: {why}", a.name);
        None
    };
    let centre = b_from_a.inverse().translation;
    let (rect_from_a, sign) = match axes(centre, &b_from_a) {
        Ok(axes) => axes,
        Err(why) => return skip(why),
    };
    let k = &a.model.intrinsics;
    let focal = 0.5 * (k.fx_px + k.fy_px);
    let rays = reference_rays(&a.model);
    let (w, h) = (k.width_px as usize, k.height_px as usize);
    let landing = |ray: DVec3| {
        let r = rect_from_a * ray;
        (r.z > 1e-9).then(|| DVec2::new(focal * r.x / r.z, focal * r.y / r.z))
    };
    let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
    for ray in rays.iter().flatten() {
        let Some(p) = landing(*ray) else {
            return skip("a pixel's ray turns behind the rectified camera".into());
        };
        lo = lo.min(p);
        hi = hi.max(p);
    }
    // The grid holds every pixel's landing and is no larger than the image: the focal length
    // shrinks by the share the barrel (or the turn) widens the view.
    let (w1, h1) = ((w - 1) as f64, (h - 1) as f64);
    let span = hi - lo;
    let zoom = (w1 / span.x).min(h1 / span.y).min(1.0) * (1.0 - 1e-9);
    if zoom < MIN_ZOOM {
        return skip(format!(
            "its rectified view is {:.2} times the image's",
            1.0 / zoom
        ));
    }
    let (focal, lo) = (focal * zoom, lo * zoom);
    let (rw, rh) = ((span.x * zoom).ceil() + 1.0, (span.y * zoom).ceil() + 1.0);
    let landing = |ray: DVec3| landing(ray).map(|p| p * zoom);
    let intrinsics = PinholeIntrinsics {
        width_px: (rw as u32).min(w as u32),
        height_px: (rh as u32).min(h as u32),
        fx_px: focal,
        fy_px: focal,
        cx_px: -lo.x,
        cy_px: -lo.y,
    };
    let model = CameraModel::pinhole(intrinsics);
    let rotation = DQuat::from_mat3(&rect_from_a).normalize();
    let rect_from_rig = |camera: &RigCamera, from_a: DQuat| {
        // The rectified camera: the same centre, turned by rect_from_a from the reference's
        // orientation (`from_a`: this camera's own orientation relative to the reference's).
        let turn = rotation * from_a.inverse();
        RigidTransform {
            rotation: (turn * camera.cam_from_rig.rotation).normalize(),
            translation: turn * camera.cam_from_rig.translation,
        }
    };
    let name = |camera: &RigCamera| format!("{}~rectified for {}", camera.name, a.name);
    // The other's grid: the reference's rows, widened to the columns where the other camera's
    // own view lands (a toe-in turns it past the reference's edge).
    let other_grid = widened(
        &intrinsics,
        &b.model,
        rect_from_a * DMat3::from_quat(b_from_a.rotation.inverse()),
    );
    let mut cameras = vec![
        RigCamera {
            name: name(a),
            model,
            cam_from_rig: rect_from_rig(a, DQuat::IDENTITY),
        },
        RigCamera {
            name: name(b),
            model: CameraModel::pinhole(other_grid),
            cam_from_rig: rect_from_rig(b, b_from_a.rotation),
        },
    ];
    if reference == 1 {
        cameras.swap(0, 1);
    }
    let rectified_rig = Rig::new(cameras, Reference::Camera(reference)).ok()?;
    let grid = |grid: &PinholeIntrinsics, camera: &RigCamera, camera_from_a: DQuat| {
        resampling_map(grid, &camera.model, camera_from_a * rotation.inverse())
    };
    let mut to_rectified = [
        grid(&intrinsics, a, DQuat::IDENTITY),
        grid(&other_grid, b, b_from_a.rotation),
    ];
    if reference == 1 {
        to_rectified.swap(0, 1);
    }
    let (gw, gh) = (intrinsics.width_px as usize, intrinsics.height_px as usize);
    let back: Vec<[f32; 2]> = rays
        .par_iter()
        .map(|ray| match ray.and_then(landing).map(|p| p - lo) {
            Some(p) if nearest_pixel(p, gw, gh).is_some() => [p.x as f32, p.y as f32],
            _ => [f32::NAN; 2],
        })
        .collect();
    let Some((scale, scale_range)) = depth_scale(&rect_from_a, focal, &intrinsics, &back) else {
        return skip("no pixel of the reference lands on the rectified grid".into());
    };
    // In the reference grid's columns.
    let offset = (other_grid.cx_px - intrinsics.cx_px) as f32;
    let seen_columns = to_rectified[1 - reference]
        .chunks(other_grid.width_px as usize)
        .map(|row| {
            let covered = |t: &Tap| t.index != NONE;
            match (row.iter().position(covered), row.iter().rposition(covered)) {
                (Some(first), Some(last)) => [first as f32 - offset, last as f32 - offset],
                _ => [1.0, 0.0],
            }
        })
        .collect();
    tracing::debug!(
        "{}: the raw pair is swept rectified on a {}x{} grid",
        a.name,
        intrinsics.width_px,
        intrinsics.height_px
    );
    Some(Rectified {
        rig: rectified_rig,
        source: rig.clone(),
        to_rectified,
        back,
        scale: scale.map(|v| v as f32),
        scale_range,
        seen_columns,
        focal_baseline: focal * centre.length(),
        sign,
        size: (k.width_px, k.height_px),
    })
}

/// `z / z'` across the rectified grid, the reference's depth over the rectified camera's: the
/// coefficients of `scale . (x, y, 1)` at a landing (x, y), and its least and greatest over
/// the reference's pixels that land (`back`); `None` where none lands.
fn depth_scale(
    rect_from_a: &DMat3,
    focal: f64,
    grid: &PinholeIntrinsics,
    back: &[[f32; 2]],
) -> Option<([f64; 3], [f64; 2])> {
    // z / z' = 1 / (R r).z for the ray r (z = 1) = (R^T r').z for the rectified ray r'
    // (z' = 1) through the landing (x, y): linear in x and y.
    let m = rect_from_a.transpose().row(2) / focal;
    let scale = [m.x, m.y, m.z * focal - m.x * grid.cx_px - m.y * grid.cy_px];
    let range = back
        .iter()
        .filter(|[x, _]| !x.is_nan())
        .map(|&[x, y]| scale[0] * f64::from(x) + scale[1] * f64::from(y) + scale[2])
        .fold([f64::INFINITY, f64::NEG_INFINITY], |[lo, hi], s| {
            [lo.min(s), hi.max(s)]
        });
    (range[0] > 0.0 && range[1].is_finite()).then_some((scale, range))
}

/// The rectified cameras' axes in the reference's frame (`rect_from_a`, whose rows they are)
/// for the other camera at `centre` turned by `b_from_a`, and on which side of the reference it
/// lies along the rows (-1: left); why not where the pair is not for rectifying.
fn axes(centre: DVec3, b_from_a: &RigidTransform) -> Result<(DMat3, f64), String> {
    if centre.length().is_nan() || centre.length() <= 0.0 {
        return Err("the cameras share a centre".into());
    }
    let mut e1 = centre.normalize();
    let sign = if e1.x < 0.0 { -1.0 } else { 1.0 };
    e1 *= sign;
    if e1.x < MAX_BASELINE_ANGLE_DEG.to_radians().cos() {
        return Err(format!(
            "its baseline runs more than {MAX_BASELINE_ANGLE_DEG} degrees off its rows"
        ));
    }
    let axis_b = b_from_a.rotation.inverse() * DVec3::Z;
    let e2 = (DVec3::Z + axis_b).normalize().cross(e1).normalize();
    let e3 = e1.cross(e2);
    let turn = DVec3::Z.angle_between(e3).max(axis_b.angle_between(e3));
    if turn.is_nan() || turn > MAX_TURN_DEG.to_radians() {
        return Err(format!(
            "a camera would turn {:.1} degrees",
            turn.to_degrees()
        ));
    }
    Ok((DMat3::from_cols(e1, e2, e3).transpose(), sign))
}

/// `grid` widened to every column where `camera`'s image lands (`rect_from_camera` turns its
/// rays into the rectified frame), at most as wide again as the grid; its rows stay `grid`'s.
fn widened(
    grid: &PinholeIntrinsics,
    camera: &CameraModel,
    rect_from_camera: DMat3,
) -> PinholeIntrinsics {
    let k = &camera.intrinsics;
    let (w, h) = (k.width_px, k.height_px);
    let rows = (0..w).flat_map(|x| [(x, 0), (x, h - 1)]);
    let border = rows.chain((0..h).flat_map(|y| [(0, y), (w - 1, y)]));
    let (mut lo, mut hi) = (0.0f64, f64::from(grid.width_px - 1));
    for (x, y) in border {
        let Some(ray) = camera.unproject_z1(DVec2::new(f64::from(x), f64::from(y))) else {
            continue;
        };
        let r = rect_from_camera * ray;
        if r.z > 1e-9 {
            let x = grid.fx_px * r.x / r.z + grid.cx_px;
            lo = lo.min(x.floor());
            hi = hi.max(x.ceil());
        }
    }
    let extra = f64::from(grid.width_px);
    let (lo, hi) = (lo.max(-extra), hi.min(f64::from(grid.width_px - 1) + extra));
    PinholeIntrinsics {
        width_px: (hi - lo) as u32 + 1,
        cx_px: grid.cx_px - lo,
        ..*grid
    }
}

/// Every pixel's ray (z = 1) of the reference, row-major; `None` where it has none.
fn reference_rays(model: &CameraModel) -> Arc<Vec<Option<DVec3>>> {
    if let Some(rays) = model.distorted_pixel_rays() {
        return rays;
    }
    let k = &model.intrinsics;
    Arc::new(
        (0..k.height_px)
            .flat_map(|y| (0..k.width_px).map(move |x| (x, y)))
            .map(|(x, y)| Some(k.unproject_z1(DVec2::new(f64::from(x), f64::from(y)))))
            .collect(),
    )
}

/// The index of the pixel of a `w` x `h` grid nearest `p`; `None` outside it.
fn nearest_pixel(p: DVec2, w: usize, h: usize) -> Option<u32> {
    let (x, y) = ((p.x + 0.5).floor(), (p.y + 0.5).floor());
    let inside = |v: f64, n: usize| v >= 0.0 && v < n as f64;
    (inside(x, w) && inside(y, h)).then(|| (y as usize * w + x as usize) as u32)
}

/// For each pixel of the rectified grid, where it samples `camera`'s raw image
/// (`camera_from_rect` turns a rectified ray into the camera's frame).
fn resampling_map(
    grid: &PinholeIntrinsics,
    camera: &CameraModel,
    camera_from_rect: DQuat,
) -> Vec<Tap> {
    let (w, h) = (grid.width_px as usize, grid.height_px as usize);
    let k = &camera.intrinsics;
    let (iw, ih) = (k.width_px as usize, k.height_px as usize);
    let reach = camera.distortion.max_undistorted_radius();
    let none = Tap {
        index: NONE,
        fx: 0,
        fy: 0,
    };
    let mut map = vec![none; w * h];
    if iw < 2 || ih < 2 {
        return map;
    }
    map.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, out) in row.iter_mut().enumerate() {
            let ray = grid.unproject_z1(DVec2::new(x as f64, y as f64));
            let Some(p) = camera.project_within(camera_from_rect * ray, reach) else {
                continue;
            };
            if !camera.contains(p) {
                continue;
            }
            // The 2x2 lies inside: the last column and row sample with full weight.
            let px = p.x.clamp(0.0, (iw - 1) as f64);
            let py = p.y.clamp(0.0, (ih - 1) as f64);
            let (x0, y0) = (
                (px.floor() as usize).min(iw - 2),
                (py.floor() as usize).min(ih - 2),
            );
            let weight = |f: f64| (f * 128.0).round().clamp(0.0, 128.0) as u8;
            *out = Tap {
                index: (y0 * iw + x0) as u32,
                fx: weight(px - x0 as f64),
                fy: weight(py - y0 as f64),
            };
        }
    });
    map
}

/// The bilinear of four packed RGBA pixels, two channels at a time in 16-bit lanes (weights
/// in 128ths, rounded: a lane holds at most 255 x 128 + 64).
fn blend(p00: u32, p10: u32, p01: u32, p11: u32, fx: u32, fy: u32) -> u32 {
    const LOW: u32 = 0x00ff_00ff;
    let mix = |a: u32, b: u32, f: u32| {
        const HALF: u32 = 0x0040_0040;
        let lo = ((a & LOW) * (128 - f) + (b & LOW) * f + HALF) >> 7;
        let hi = (((a >> 8) & LOW) * (128 - f) + ((b >> 8) & LOW) * f + HALF) >> 7;
        (lo & LOW) | ((hi & LOW) << 8)
    };
    mix(mix(p00, p10, fx), mix(p01, p11, fx), fy) | 0xff00_0000
}

impl Rectified {
    /// The rig's two images resampled onto the rectified grid (bilinear, black where a camera
    /// has no pixel), in the rig's order, into `out` (its buffers kept from set to set).
    pub fn images_into(&self, images: &[Rgba8Image], out: &mut Vec<Rgba8Image>) {
        out.resize_with(images.len(), || Rgba8Image {
            width: 0,
            height: 0,
            pixels: Vec::new(),
        });
        let grids = self.rig.cameras.iter().map(|c| c.model.intrinsics);
        for (((image, map), out), grid) in images
            .iter()
            .zip(&self.to_rectified)
            .zip(out.iter_mut())
            .zip(grids)
        {
            let (w, h) = (grid.width_px, grid.height_px);
            out.width = w;
            out.height = h;
            out.pixels.resize(map.len(), 0);
            let iw = image.width as usize;
            let src = &image.pixels;
            out.pixels
                .par_chunks_mut(w as usize)
                .zip(map.par_chunks(w as usize))
                .for_each(|(row, taps)| {
                    for (out, tap) in row.iter_mut().zip(taps) {
                        let i = tap.index as usize;
                        let taps = (tap.index != NONE)
                            .then(|| src.get(i..i + iw + 2))
                            .flatten();
                        *out = match taps {
                            Some(q) => blend(
                                q[0],
                                q[1],
                                q[iw],
                                q[iw + 1],
                                u32::from(tap.fx),
                                u32::from(tap.fy),
                            ),
                            _ => 0xff00_0000,
                        };
                    }
                });
        }
    }

    /// The parameters the rectified pair is swept with: `params` with the depth range that
    /// brings every depth of the reference's `min_depth_m`..`max_depth_m` onto a plane (the
    /// rectified camera's depth is the reference's divided by `z / z'`, which differs across
    /// the image by the turn between them), and as many more planes as keep their step in
    /// inverse depth (up to the parameters' limit, SGM's 1024 or else 4096).
    pub fn swept_params(&self, params: &SweepParams) -> SweepParams {
        let [lo, hi] = self.scale_range;
        let (near, far) = (params.min_depth_m / hi, params.max_depth_m / lo);
        let span = |near: f64, far: f64| 1.0 / near - 1.0 / far;
        let widening = span(near, far) / span(params.min_depth_m, params.max_depth_m);
        let steps = f64::from(params.num_planes.max(2) - 1) * widening;
        let most = match params.optimizer {
            Optimizer::Sgm => MAX_SGM_PLANES,
            _ => MAX_PLANES,
        };
        let steps = ((steps - 1e-6).ceil() as u32).clamp(1, most.max(params.num_planes) - 1);
        SweepParams {
            min_depth_m: near,
            max_depth_m: far,
            num_planes: steps + 1,
            ..params.clone()
        }
    }

    /// The rectified reference's maps on the reference's own pixels: depth and confidence,
    /// and those of the others `wanted` asks for (empty otherwise). `range` is the sweep's
    /// depth range (metres): a depth brought back outside it (the rectified camera's depth
    /// differs from the reference's by the turn between them) is none.
    pub fn maps_back(
        &self,
        rectified: &DepthMaps,
        wanted: WantedMaps,
        range: [f32; 2],
    ) -> Result<DepthMaps, SweepError> {
        let (w, h) = self.size;
        let (rw, rh) = (rectified.width() as usize, rectified.height() as usize);
        let grid = rw * rh;
        let n = self.back.len();
        let image = |data: Vec<f32>| ImageF32 {
            width: w,
            height: h,
            data,
        };
        let empty = || ImageF32 {
            width: 0,
            height: 0,
            data: Vec::new(),
        };
        if rectified.depth_m.data.len() != grid
            || rectified.confidence.data.len() != grid
            || rh != self.seen_columns.len()
            || n != (w * h) as usize
        {
            return Err(SweepError::InvalidParams(format!(
                "internal: a rectified pair's maps are {rw}x{rh}, not its grid's"
            )));
        }
        let (depth, confidence) = self.depth_back(
            &rectified.depth_m.data,
            &rectified.confidence.data,
            [rw, rh],
            range,
        );
        // The other maps: the value of the pixel nearest the landing (where the depth holds,
        // for the selection).
        let nearest = |i: usize| {
            let [x, y] = self.back[i];
            (!x.is_nan()).then(|| (y + 0.5) as usize * rw + (x + 0.5) as usize)
        };
        let take = |map: &[f32], wanted: bool| match wanted && map.len() == grid {
            true => image(
                (0..n)
                    .into_par_iter()
                    .map(|i| nearest(i).map_or(f32::NAN, |j| map[j]))
                    .collect(),
            ),
            false => empty(),
        };
        let take_u8 =
            |map: &[u8], wanted: bool, none: u8, valid: bool| match wanted && map.len() == grid {
                true => (0..n)
                    .into_par_iter()
                    .map(|i| match nearest(i) {
                        Some(j) if !valid || !depth[i].is_nan() => map[j],
                        _ => none,
                    })
                    .collect(),
                false => Vec::new(),
            };
        let mut depth_raw_m = take(&rectified.depth_raw_m.data, wanted.diagnostics);
        for (i, z) in depth_raw_m.data.iter_mut().enumerate() {
            let [x, y] = self.back[i];
            *z *= self.scale[0] * x + self.scale[1] * y + self.scale[2];
        }
        Ok(DepthMaps {
            cost: take(&rectified.cost.data, wanted.cost),
            selection: take_u8(
                &rectified.selection,
                wanted.selection,
                selection::INVALID,
                true,
            ),
            visible_cameras: take_u8(&rectified.visible_cameras, wanted.diagnostics, 0, false),
            depth_raw_m,
            depth_m: image(depth),
            confidence: image(confidence),
        })
    }

    /// The rectified depth and confidence (`w` x `h`) on the reference's pixels: the depth
    /// bilinear where the four pixels around a landing are valid and agree within [`AGREE`],
    /// else the nearest pixel's; NaN (confidence 0) where the other camera has no pixel at the
    /// match or the depth falls outside `range`.
    fn depth_back(
        &self,
        depth: &[f32],
        confidence: &[f32],
        [w, h]: [usize; 2],
        [near, far]: [f32; 2],
    ) -> (Vec<f32>, Vec<f32>) {
        let shift = (self.sign * self.focal_baseline) as f32;
        let row = self.size.0 as usize;
        let mut out_depth = vec![f32::NAN; self.back.len()];
        let mut out_confidence = vec![0.0f32; self.back.len()];
        out_depth
            .par_chunks_mut(row)
            .zip(out_confidence.par_chunks_mut(row))
            .zip(self.back.par_chunks(row))
            .for_each(|((out_depth, out_confidence), back)| {
                let outs = out_depth.iter_mut().zip(out_confidence.iter_mut());
                for ((out_z, out_c), &[x, y]) in outs.zip(back) {
                    // NaN: no landing. Inside the grid, x and y are at least -0.5, so the
                    // truncations below floor them.
                    if x.is_nan() {
                        continue;
                    }
                    let (xn, yn) = ((x + 0.5) as usize, (y + 0.5) as usize);
                    let nearest = yn * w + xn;
                    let mut z = depth[nearest];
                    let (x0, y0) = (x as usize, y as usize);
                    if x >= 0.0 && y >= 0.0 && x0 + 1 < w && y0 + 1 < h {
                        let i = y0 * w + x0;
                        let q = [depth[i], depth[i + 1], depth[i + w], depth[i + w + 1]];
                        let lo = q[0].min(q[1]).min(q[2]).min(q[3]);
                        let hi = q[0].max(q[1]).max(q[2]).max(q[3]);
                        if q.iter().all(|z| *z > 0.0) && hi <= lo * (1.0 + AGREE) {
                            let (fx, fy) = (x - x0 as f32, y - y0 as f32);
                            let top = q[0] + (q[1] - q[0]) * fx;
                            let bottom = q[2] + (q[3] - q[2]) * fx;
                            z = top + (bottom - top) * fy;
                        }
                    }
                    if z.is_nan() || z <= 0.0 {
                        continue;
                    }
                    // Where the other camera would see this point: no pixel there, no depth.
                    let u = x - shift / z;
                    let [first, last] = self.seen_columns[yn];
                    let z = z * (self.scale[0] * x + self.scale[1] * y + self.scale[2]);
                    if u >= first - 0.5 && u < last + 0.5 && z >= near && z <= far {
                        *out_z = z;
                        *out_c = confidence[nearest];
                    }
                }
            });
        (out_depth, out_confidence)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::{self, Scene};

    /// The bench's raw pair (`stereo-raw`): a plumb-bob barrel and a slight toe-in.
    fn raw_pair(width: u32, height: u32, reference: usize) -> Rig {
        let mut model = CameraModel::pinhole(synthetic::intrinsics(width, height));
        model.distortion = synthetic::plumb_bob_barrel();
        synthetic::arc_rig(2, 0.1 / 4.0, 4.0, model, reference).unwrap()
    }

    fn scene(rig: &Rig) -> Scene {
        Scene::wall_and_box(4.0, Some((2.0, 0.4)), rig.cameras[0].model.intrinsics.fx_px)
    }

    #[test]
    fn a_rectified_pair_is_left_as_it_is() {
        let model = CameraModel::pinhole(synthetic::intrinsics(64, 48));
        let rig = synthetic::row_rig(2, 0.1, model, 0).unwrap();
        assert!(rectify(&rig).is_none());
        // Each way a pair can leave shifted rows, alone, is rectified.
        let mut turned = rig.clone();
        turned.cameras[1].cam_from_rig.rotation = DQuat::from_rotation_y(0.01);
        assert!(rectify(&turned).is_some());
        for camera in [0, 1] {
            let mut distorted = rig.clone();
            distorted.cameras[camera].model.distortion = synthetic::plumb_bob_barrel();
            assert!(rectify(&distorted).is_some(), "camera {camera} distorted");
        }
        for fy in [false, true] {
            let mut other_focal = rig.clone();
            let k = &mut other_focal.cameras[1].model.intrinsics;
            *(if fy { &mut k.fy_px } else { &mut k.fx_px }) *= 1.01;
            assert!(rectify(&other_focal).is_some(), "fy {fy}");
        }
        let mut ahead = rig.clone();
        ahead.cameras[1].cam_from_rig.translation.z += 0.001;
        assert!(
            rectify(&ahead).is_some(),
            "a baseline out of the image plane"
        );
        let mut other_row = rig.clone();
        other_row.cameras[1].model.intrinsics.cy_px += 1.0;
        assert!(rectify(&other_row).is_some(), "cy");
        let mut lifted = rig.clone();
        lifted.cameras[1].cam_from_rig.translation.y += 0.001;
        assert!(rectify(&lifted).is_some(), "a baseline off the rows");
        // One above the other: not rectified (the raw sweep takes it).
        let mut above = rig;
        above.cameras[1].cam_from_rig.translation = DVec3::new(0.0, -0.1, 0.0);
        above.cameras[1].model.distortion = synthetic::plumb_bob_barrel();
        assert!(rectify(&above).is_none());
    }

    /// The rectified rig is a pair on shifted rows: one pinhole model, no turn between them,
    /// the baseline along the rows, each camera at its own centre.
    #[test]
    fn the_rectified_rig_meets_on_rows() {
        for reference in [0, 1] {
            let rig = raw_pair(160, 120, reference);
            let r = rectify(&rig).unwrap();
            let (a, b) = (&r.rig.cameras[reference], &r.rig.cameras[1 - reference]);
            let (ka, kb) = (&a.model.intrinsics, &b.model.intrinsics);
            assert_eq!(
                (ka.fx_px, ka.fy_px, ka.cy_px),
                (kb.fx_px, kb.fy_px, kb.cy_px)
            );
            assert_eq!(ka.height_px, kb.height_px);
            // The toed-in other camera's view reaches past the reference's edge.
            assert!(kb.width_px > ka.width_px, "{kb:?}");
            assert!(a.model.distortion.is_none() && b.model.distortion.is_none());
            let b_from_a = r.rig.cam_from_ref(1 - reference);
            assert!(b_from_a.rotation.angle_between(DQuat::IDENTITY) < 1e-9);
            let t = b_from_a.translation;
            assert!(
                t.y.abs() < 1e-9 && t.z.abs() < 1e-9 && t.x.abs() > 0.09,
                "{t}"
            );
            for i in 0..2 {
                let d = r.rig.cameras[i].centre_in_rig() - rig.cameras[i].centre_in_rig();
                assert!(d.length() < 1e-9);
            }
            // The grid is the image's size; it holds the barrel-shaped view at a shorter focal
            // length.
            let k = &a.model.intrinsics;
            assert!(k.width_px <= 160 && k.height_px <= 120, "{k:?}");
            assert!(k.width_px >= 159 || k.height_px >= 119, "{k:?}");
            let f = rig.cameras[reference].model.intrinsics.fx_px;
            assert!(k.fx_px < f && k.fx_px > 0.85 * f, "{} against {f}", k.fx_px);
        }
    }

    /// A pair that moves keeps its rectification; one whose cameras move apart does not.
    #[test]
    fn a_moving_pair_keeps_its_rectification() {
        let rig = raw_pair(64, 48, 0);
        let mut kept = Rectifications::default();
        let first = kept.for_rig(&rig).unwrap();
        let mut moved = rig.clone();
        let motion = RigidTransform {
            rotation: DQuat::from_rotation_z(0.3),
            translation: DVec3::new(1.0, 2.0, 3.0),
        };
        for camera in &mut moved.cameras {
            camera.cam_from_rig = camera.cam_from_rig.compose(&motion);
        }
        assert!(Arc::ptr_eq(&first, &kept.for_rig(&moved).unwrap()));
        let mut apart = rig.clone();
        apart.cameras[1].cam_from_rig.translation.x -= 0.05;
        assert!(!Arc::ptr_eq(&first, &kept.for_rig(&apart).unwrap()));
        // A new calibration of either camera at the same names, sizes and poses (a
        // CameraInfo replaced at run time) is made anew, as is a turn alone.
        for camera in [0, 1] {
            let mut focal = rig.clone();
            focal.cameras[camera].model.intrinsics.fx_px *= 1.01;
            let mut lens = rig.clone();
            lens.cameras[camera].model.distortion = crate::geometry::Distortion::PlumbBob {
                k1: -0.13,
                k2: 0.02,
                p1: 0.0005,
                p2: -0.0003,
                k3: 0.0,
            };
            for changed in [focal, lens] {
                let made = kept.for_rig(&changed).unwrap();
                assert!(!Arc::ptr_eq(&first, &made), "camera {camera}");
                assert_eq!(
                    made.source.cameras[camera].model,
                    changed.cameras[camera].model
                );
            }
        }
        let mut turned = rig.clone();
        let r = &mut turned.cameras[1].cam_from_rig;
        r.rotation = (DQuat::from_rotation_x(0.1f64.to_radians()) * r.rotation).normalize();
        let (t0, t1) = (
            rig.cam_from_ref(1).translation,
            turned.cam_from_ref(1).translation,
        );
        assert!((t0 - t1).length() < 1e-12, "the turn alone: {t0} {t1}");
        assert!(
            !Arc::ptr_eq(&first, &kept.for_rig(&turned).unwrap()),
            "a turn"
        );
    }

    /// The bench's raw pair with camera 1 also pitched down by a degree (the rectified rows
    /// then tilt out of the reference's: `z / z'` varies along both axes).
    fn pitched_pair(width: u32, height: u32, reference: usize) -> Rig {
        let mut rig = raw_pair(width, height, reference);
        let pitch = DQuat::from_rotation_x(1f64.to_radians());
        let c = &mut rig.cameras[1].cam_from_rig;
        *c = RigidTransform {
            rotation: pitch * c.rotation,
            translation: pitch * c.translation,
        };
        rig
    }

    /// The depth of the rectified reference, brought back, is the raw reference's depth; its
    /// confidence comes with it; a pixel the other camera does not see has none.
    #[test]
    fn depth_comes_back_onto_the_references_pixels() {
        for reference in [0, 1] {
            let rig = pitched_pair(160, 120, reference);
            let scene = scene(&rig);
            let r = rectify(&rig).unwrap();
            let a = &r.rig.cameras[reference];
            let mut maps = DepthMaps::empty();
            maps.depth_m = scene.depth(&a.model, &a.cam_from_rig);
            maps.confidence = ImageF32 {
                data: vec![0.5; maps.depth_m.data.len()],
                ..maps.depth_m.clone()
            };
            // The raw depth is the depth too; the cost and the visible count are each
            // rectified pixel's index.
            maps.depth_raw_m = maps.depth_m.clone();
            let grid = maps.depth_m.data.len();
            maps.cost = ImageF32 {
                data: (0..grid).map(|i| i as f32).collect(),
                ..maps.depth_m.clone()
            };
            maps.visible_cameras = (0..grid).map(|i| (i % 251) as u8).collect();
            let back = r
                .maps_back(&maps, WantedMaps::ALL, [0.0, f32::MAX])
                .unwrap();
            // The raw depth comes back in the reference's depth, as the depth does (nearest
            // pixel against bilinear: within 0.2 % on this smooth scene), and the cost
            // and the count are the nearest rectified pixel's.
            let rw = r.rig.cameras[reference].model.intrinsics.width_px as usize;
            let mut compared = 0;
            for i in 0..back.depth_m.data.len() {
                let (z, raw) = (back.depth_m.data[i], back.depth_raw_m.data[i]);
                let [x, y] = r.back[i];
                if x.is_nan() {
                    assert!(back.cost.data[i].is_nan(), "pixel {i}");
                    continue;
                }
                let j = (y + 0.5) as usize * rw + (x + 0.5) as usize;
                assert_eq!(back.cost.data[i], j as f32, "pixel {i}");
                assert_eq!(back.visible_cameras[i], (j % 251) as u8, "pixel {i}");
                if !z.is_nan() && (raw - z).abs() <= 0.002 * z {
                    compared += 1;
                }
            }
            let valid = back.depth_m.data.iter().filter(|z| !z.is_nan()).count();
            assert!(
                compared * 100 >= valid * 99,
                "{compared} of {valid} raw depths agree"
            );
            let truth = synthetic::reference_depth(&scene, &rig);
            let total = truth.data.len();
            assert_eq!(back.depth_m.data.len(), total);
            // Where the other raw camera sees the true point.
            let (raw_a, raw_b) = (&rig.cameras[reference], &rig.cameras[1 - reference]);
            let w = raw_a.model.intrinsics.width_px as usize;
            let (mut close, mut valid, mut mismatched) = (0, 0, 0);
            for (i, (z, t)) in back.depth_m.data.iter().zip(&truth.data).enumerate() {
                let pixel = DVec2::new((i % w) as f64, (i / w) as f64);
                let ray = raw_a.model.unproject_z1(pixel).unwrap();
                let point = raw_a
                    .cam_from_rig
                    .inverse()
                    .transform_point(ray * f64::from(*t));
                let seen = raw_b
                    .model
                    .project(raw_b.cam_from_rig.transform_point(point))
                    .is_some_and(|p| raw_b.model.contains(p));
                mismatched += usize::from(seen == z.is_nan());
                let c = back.confidence.data[i];
                assert_eq!(c, if z.is_nan() { 0.0 } else { 0.5 }, "pixel {i}");
                if z.is_nan() {
                    continue;
                }
                valid += 1;
                close += usize::from((z - t).abs() <= 0.002 * t);
            }
            // The other camera sees all but a band at one side, and only the band's edge
            // columns differ.
            assert!(valid * 10 > total * 8, "{valid} of {total} valid");
            assert!(
                mismatched * 100 <= total,
                "{mismatched} of {total} seen wrongly"
            );
            assert!(close * 100 >= valid * 98, "{close} of {valid} within 0.2 %");
        }
    }

    /// The resampled images are what the rectified cameras see: closer to their renders than
    /// a pixel's shift along either axis, in every channel.
    #[test]
    fn the_images_are_what_the_rectified_cameras_see() {
        for reference in [0, 1] {
            let rig = pitched_pair(160, 120, reference);
            let scene = scene(&rig);
            let r = rectify(&rig).unwrap();
            let mut out = Vec::new();
            r.images_into(&synthetic::render_rig(&scene, &rig), &mut out);
            for (i, image) in out.iter().enumerate() {
                let truth = scene.render(&r.rig.cameras[i]);
                let w = image.width as usize;
                let diff = |dx: usize, dy: usize| {
                    let (mut sum, mut n) = (0u64, 0u64);
                    for (j, q) in truth.pixels.iter().enumerate() {
                        let (x, y) = (j % w, j / w);
                        let Some(&p) = image.pixels.get((y + dy) * w + x + dx) else {
                            continue;
                        };
                        // Inside both the raw image's view and the grid only (black outside).
                        if x + dx >= w || p == 0xff00_0000 || image.pixels[j] == 0xff00_0000 {
                            continue;
                        }
                        let (p, q) = (Rgba8Image::unpack(p), Rgba8Image::unpack(*q));
                        sum += (0..3).map(|c| u64::from(p[c].abs_diff(q[c]))).sum::<u64>();
                        n += 3;
                    }
                    sum as f64 / n.max(1) as f64
                };
                let same = diff(0, 0);
                for (dx, dy) in [(1, 0), (0, 1)] {
                    let shifted = diff(dx, dy);
                    assert!(
                        same * 2.0 < shifted,
                        "reference {reference}, camera {i}: {same:.1} against {shifted:.1} shifted by ({dx}, {dy})"
                    );
                }
            }
        }
    }

    /// The rectified sweep's range holds every depth of the reference's range on every pixel
    /// that lands, and no more; its planes keep their step in inverse depth.
    #[test]
    fn the_swept_range_holds_the_references_range() {
        let rig = pitched_pair(160, 120, 0);
        let r = rectify(&rig).unwrap();
        let params = SweepParams {
            min_depth_m: 1.5,
            max_depth_m: 6.0,
            num_planes: 48,
            ..SweepParams::default()
        };
        let swept = r.swept_params(&params);
        let (mut nearest, mut farthest) = (f64::INFINITY, 0.0f64);
        for &[x, y] in r.back.iter().filter(|p| !p[0].is_nan()) {
            let s = r.scale.map(f64::from);
            let s = s[0] * f64::from(x) + s[1] * f64::from(y) + s[2];
            nearest = nearest.min(params.min_depth_m / s);
            farthest = farthest.max(params.max_depth_m / s);
        }
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-5 * b;
        assert!(
            close(swept.min_depth_m, nearest) && close(swept.max_depth_m, farthest),
            "{}..{} against {nearest}..{farthest}",
            swept.min_depth_m,
            swept.max_depth_m
        );
        // The pitch widens it by more than a plane's step here.
        assert!(swept.min_depth_m < params.min_depth_m || swept.max_depth_m > params.max_depth_m);
        let step = |p: &SweepParams| {
            (1.0 / p.min_depth_m - 1.0 / p.max_depth_m) / f64::from(p.num_planes - 1)
        };
        assert!(swept.num_planes > params.num_planes);
        assert!(step(&swept) <= step(&params) * (1.0 + 1e-9));
        let fewer = SweepParams {
            num_planes: swept.num_planes - 1,
            ..swept.clone()
        };
        assert!(
            step(&fewer) > step(&params),
            "no more planes than the step needs"
        );
        // SGM's limit holds.
        let most = r.swept_params(&SweepParams {
            num_planes: MAX_SGM_PLANES,
            ..params.clone()
        });
        assert_eq!(most.num_planes, MAX_SGM_PLANES);
        assert_eq!(
            (most.cost, most.sgm_p2, most.coarse_to_fine),
            (params.cost, params.sgm_p2, params.coarse_to_fine)
        );
    }

    /// A depth brought back is inside the sweep's range, and one inside it comes back: the
    /// box (2 m) alone in 1-3 m, the wall (4 m) alone in 2.5-5 m.
    #[test]
    fn depth_comes_back_inside_the_range() {
        let rig = pitched_pair(160, 120, 0);
        let scene = scene(&rig);
        let r = rectify(&rig).unwrap();
        let a = &r.rig.cameras[0];
        let mut maps = DepthMaps::empty();
        maps.depth_m = scene.depth(&a.model, &a.cam_from_rig);
        maps.confidence = ImageF32 {
            data: vec![0.5; maps.depth_m.data.len()],
            ..maps.depth_m.clone()
        };
        let all = r.maps_back(&maps, WantedMaps::OUTPUTS, [0.0, f32::MAX]);
        let all = all.unwrap().depth_m.data;
        for [near, far] in [[1.0, 3.0], [2.5, 5.0]] {
            let back = r
                .maps_back(&maps, WantedMaps::OUTPUTS, [near, far])
                .unwrap();
            let (mut inside, mut kept) = (0, 0);
            for (z, z_all) in back.depth_m.data.iter().zip(&all) {
                assert!(
                    z.is_nan() || (near..=far).contains(z),
                    "{z} outside {near}..{far}"
                );
                if (near..=far).contains(z_all) {
                    inside += 1;
                    kept += usize::from(z == z_all);
                }
            }
            assert!(
                inside * 10 > all.len() && kept == inside,
                "{kept} of {inside} kept"
            );
        }
        // One rectified depth everywhere comes back within about 1 % of it (the turn between
        // the rectified and the raw camera): the range applies to the depth brought back.
        maps.depth_m.data.fill(4.0);
        let far = 4.0;
        let back = r.maps_back(&maps, WantedMaps::OUTPUTS, [0.0, far]).unwrap();
        let kept = back.depth_m.data.iter().filter(|z| !z.is_nan()).count();
        assert!(back.depth_m.data.iter().all(|z| z.is_nan() || *z <= far));
        let unlimited = r
            .maps_back(&maps, WantedMaps::OUTPUTS, [0.0, f32::MAX])
            .unwrap();
        let farther = unlimited.depth_m.data.iter().filter(|z| **z > far).count();
        assert!(
            kept > 0 && farther > 0,
            "{kept} kept, {farther} beyond {far} m"
        );
    }
}
