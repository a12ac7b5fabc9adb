//! Twin of `shaders/cost.wgsl`, one reference row at a time: every camera's bilinear colour on
//! one plane, the pair TSSDs, and the channels the windows aggregate (one per pair, or the
//! scored cost). Rows are contiguous slices, so the loops vectorise.
//!
//! Fast paths: when a camera sees the reference grid on a plane through a pure translation
//! (undistorted cameras, same focal lengths, no rotation, fronto-parallel planes: Middlebury
//! rows, parallel rigs) its samples are contiguous shifted rows with constant bilinear
//! weights, no gathers. With any other pose, an undistorted reference's rays are linear in
//! the pixel, so along a row the camera's homogeneous coordinates are too (`Projective`): the
//! sample positions come from a few multiply-adds per pixel in a loop that vectorises, then
//! one gather loop reads the colours (and `census.rs` reuses the positions). A distorted
//! reference projects each pixel as the shader does (`General`).
// The `!(x > 0.0)` tests mirror the shaders and are NaN-safe on purpose.
#![expect(
    clippy::neg_cmp_op_on_partial_ord,
    reason = "`!(a > b)` on purpose: it is also true for NaN, as the shaders' tests are"
)]

use super::common::*;
use crate::sweep::gpu_types::*;
use crate::sweep::plan::SweepPlan;

/// How camera `c` sees the reference grid on one plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Mapping {
    /// Reference pixel (x, y) lands on (x + dx, y + dy) in the camera, for every pixel.
    Translation { dx: f64, dy: f64 },
    /// An undistorted reference (its rays `ray(x, y) = c + x ex + y ey`, z = 1) and any
    /// camera: on plane (n, d) the point of ray r is `r d / (n.r)`, in the camera
    /// `(d / (n.r)) (R r + t (n.r) / d)`, whose second factor `m` is linear in (x, y) as n.r
    /// is: `m = m0 + x mx + y my`, `n.r = q0 + x qx + y qy`. The pixel is then
    /// `lens(m.xy / m.z)` where the plane depth `d / (n.r)` and the camera depth
    /// `d / (n.r) m.z` are in front, as `project` decides per pixel.
    Projective {
        m0: [f64; 3],
        mx: [f64; 3],
        my: [f64; 3],
        q: [f64; 3],
        d: f64,
    },
    /// Anything else: project every pixel (`project` in common.wgsl).
    General,
    /// The sample positions are already in `coords` (`hypothesis_coords`: a depth per pixel,
    /// the refinement's hypotheses, `refine.rs`).
    Given,
    /// As `Given`, on a rectified pair (`refine::row_mapping`): the point of reference pixel
    /// (x, y) at inverse depth q (1 / the ray parameter) lands on `(x + x0 + per_q q, y + dy)`,
    /// the same camera row for every depth, so a sample reads two texels, not four
    /// (`gather::gather_row_along`).
    GivenRow { x0: f32, per_q: f32, dy: i32 },
}

/// The rays of an undistorted reference (`ray(x, y) = (ax + bx x, ay + by y, 1)`), read off the
/// plan's rays and checked on a 3x3 grid of pixels; None when they are not of that form (a
/// distorted reference, a pixel without a ray).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinearRays {
    ax: f64,
    bx: f64,
    ay: f64,
    by: f64,
}

impl LinearRays {
    pub fn of(plan: &SweepPlan) -> Option<Self> {
        let (w, h) = (plan.params.width as usize, plan.params.height as usize);
        if w < 2 || h < 2 {
            return None;
        }
        let ray = |x: usize, y: usize| plan.rays[y * w + x].map(f64::from);
        let (first, last_x, last_y) = (ray(0, 0), ray(w - 1, 0), ray(0, h - 1));
        let rays = Self {
            ax: first[0],
            bx: (last_x[0] - first[0]) / (w - 1) as f64,
            ay: first[1],
            by: (last_y[1] - first[1]) / (h - 1) as f64,
        };
        // 1e-6 on the z = 1 plane is a thousandth of a pixel at a focal length of 1000 px.
        const TOLERANCE: f64 = 1e-6;
        let linear = [0, w / 2, w - 1].iter().all(|&x| {
            [0, h / 2, h - 1].iter().all(|&y| {
                let r = ray(x, y);
                r[2] == 1.0
                    && (r[0] - (rays.ax + rays.bx * x as f64)).abs() <= TOLERANCE
                    && (r[1] - (rays.ay + rays.by * y as f64)).abs() <= TOLERANCE
            })
        });
        linear.then_some(rays)
    }

    /// Camera `cam`'s `Mapping::Projective` on `plane` (None when the plane passes through
    /// the reference's centre).
    fn projective(&self, cam: &GpuCamera, plane: [f64; 4]) -> Option<Mapping> {
        let d = plane[3];
        if d == 0.0 || !d.is_finite() {
            return None;
        }
        let rows = [cam.row0, cam.row1, cam.row2].map(|r| r.map(f64::from));
        let n = [plane[0], plane[1], plane[2]];
        let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        // m(v) = R v + t (n.v) / d for a vector v of the ray's form.
        let m = |v: [f64; 3]| -> [f64; 3] {
            let nv = dot(n, v) / d;
            std::array::from_fn(|i| {
                let r = rows[i];
                dot([r[0], r[1], r[2]], v) + r[3] * nv
            })
        };
        let (c, ex, ey) = (
            [self.ax, self.ay, 1.0],
            [self.bx, 0.0, 0.0],
            [0.0, self.by, 0.0],
        );
        Some(Mapping::Projective {
            m0: m(c),
            mx: m(ex),
            my: m(ey),
            q: [dot(n, c), dot(n, ex), dot(n, ey)],
            d,
        })
    }
}

/// Largest deviation (pixels) from one shift over the image corners that still counts as a
/// translation; the shader's own f32 projection is off by about 1e-5 px.
const TRANSLATION_TOLERANCE_PX: f64 = 1e-4;

/// The mapping of every camera (rig order) on plane `k`. The reference camera itself is never
/// sampled through it.
pub fn mappings(plan: &SweepPlan, k: usize, allow_fast: bool) -> Vec<Mapping> {
    let p = &plan.params;
    let reference = p.reference;
    // Rays of a real, undistorted reference are a pinhole's: the map is a homography, so
    // agreeing with one translation at the four corners means being that translation.
    let pinhole_reference =
        reference != NO_CAMERA && plan.cameras[reference as usize].size[3] == DIST_NONE;
    let plane = plan.planes[k].map(f64::from);
    let (w, h) = (p.width as usize, p.height as usize);
    let corners = [(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)];
    let linear_rays = if allow_fast {
        LinearRays::of(plan)
    } else {
        None
    };
    let projective = |cam: &GpuCamera| {
        linear_rays
            .and_then(|rays| rays.projective(cam, plane))
            .unwrap_or(Mapping::General)
    };
    plan.cameras
        .iter()
        .map(|cam| {
            if !allow_fast || !pinhole_reference || cam.size[3] != DIST_NONE {
                return projective(cam);
            }
            let mut shifts = Vec::with_capacity(4);
            for &(x, y) in &corners {
                let ray = plan.rays[y * w + x].map(f64::from);
                let denom = plane[0] * ray[0] + plane[1] * ray[1] + plane[2] * ray[2];
                if denom.abs() < 1e-12 {
                    return projective(cam);
                }
                let depth = plane[3] / denom;
                let point = [ray[0] * depth, ray[1] * depth, ray[2] * depth];
                let row = |r: [f32; 4]| {
                    f64::from(r[0]) * point[0]
                        + f64::from(r[1]) * point[1]
                        + f64::from(r[2]) * point[2]
                        + f64::from(r[3])
                };
                let cam_point = [row(cam.row0), row(cam.row1), row(cam.row2)];
                if !(depth > 0.0) || !(cam_point[2] > 1e-6) {
                    return projective(cam);
                }
                let k = cam.intrinsics.map(f64::from);
                let u = k[0] * cam_point[0] / cam_point[2] + k[2];
                let v = k[1] * cam_point[1] / cam_point[2] + k[3];
                shifts.push((u - x as f64, v - y as f64));
            }
            let (dx, dy) = shifts[0];
            let same = shifts.iter().all(|&(sx, sy)| {
                (sx - dx).abs() < TRANSLATION_TOLERANCE_PX
                    && (sy - dy).abs() < TRANSLATION_TOLERANCE_PX
            });
            // A shift within the tolerance of a whole pixel is that pixel (the f32 camera data
            // leave ~1e-7 px of noise: a row shifted by 7e-7 would lose the image's last row).
            let snap = |v: f64| {
                if (v - v.round()).abs() < TRANSLATION_TOLERANCE_PX {
                    v.round()
                } else {
                    v
                }
            };
            if same {
                Mapping::Translation {
                    dx: snap(dx),
                    dy: snap(dy),
                }
            } else {
                projective(cam)
            }
        })
        .collect()
}

/// One row of colours: R, G, B; NaN in R where the camera does not see the pixel.
pub type ColourRow = [Vec<f32>; 3];

pub fn colour_row(width: usize) -> ColourRow {
    [vec![0.0; width], vec![0.0; width], vec![0.0; width]]
}

/// Where reference row `y` lands in a camera on plane `k`: the pixel of every column of `cols`
/// in `coords` (x, y; x NaN where the camera does not see it: behind, past the distortion's
/// fold, or outside its image). Twin of the projection and `inside` of cost.wgsl, for the
/// mappings that are not translations.
#[inline(always)]
pub fn sample_coords(
    plan: &SweepPlan,
    cam: &GpuCamera,
    mapping: Mapping,
    k: usize,
    y: usize,
    cols: std::ops::Range<usize>,
    coords: &mut [Vec<f32>; 2],
) {
    let width = plan.params.width as usize;
    let [xs, ys] = coords;
    let (xs, ys) = (&mut xs[cols.clone()], &mut ys[cols.clone()]);
    let (w, h) = (cam.size[0] as f32 - 1.0, cam.size[1] as f32 - 1.0);
    match mapping {
        Mapping::Given | Mapping::GivenRow { .. } => {}
        Mapping::Projective { m0, mx, my, q, d } => {
            // The row's coefficients in f64, the pixels in f32 (as the shader's arithmetic).
            let yf = y as f64;
            let base: [f32; 3] = std::array::from_fn(|i| (m0[i] + yf * my[i]) as f32);
            let step: [f32; 3] = mx.map(|v| v as f32);
            let (q0, qx, d) = ((q[0] + yf * q[2]) as f32, q[1] as f32, d as f32);
            let distorted = cam.size[3] != DIST_NONE;
            let [fx, fy, cx, cy] = cam.intrinsics;
            // One loop per lens: without distortion it vectorises (the x as i32, whose
            // conversion to f32 has a vector instruction; the same floats as from usize).
            let pixels = xs.iter_mut().zip(ys.iter_mut()).zip(cols.start as i32..);
            if distorted {
                for ((xo, yo), x) in pixels {
                    let xf = x as f32;
                    let nr = q0 + xf * qx;
                    let depth = d / nr;
                    let m: [f32; 3] = std::array::from_fn(|i| base[i] + xf * step[i]);
                    let seen = nr.abs() >= 1e-12 && depth > 0.0 && depth * m[2] > 1e-6;
                    let pixel = lens(cam, [m[0] / m[2], m[1] / m[2]]).unwrap_or([f32::NAN; 2]);
                    // NaN fails every comparison: not inside.
                    let inside =
                        pixel[0] >= 0.0 && pixel[1] >= 0.0 && pixel[0] <= w && pixel[1] <= h;
                    *xo = if seen && inside { pixel[0] } else { f32::NAN };
                    *yo = pixel[1];
                }
            } else {
                for ((xo, yo), x) in pixels {
                    let xf = x as f32;
                    let nr = q0 + xf * qx;
                    let depth = d / nr;
                    let m: [f32; 3] = std::array::from_fn(|i| base[i] + xf * step[i]);
                    let seen = (nr.abs() >= 1e-12) & (depth > 0.0) & (depth * m[2] > 1e-6);
                    let pixel = [fx * (m[0] / m[2]) + cx, fy * (m[1] / m[2]) + cy];
                    let inside =
                        (pixel[0] >= 0.0) & (pixel[1] >= 0.0) & (pixel[0] <= w) & (pixel[1] <= h);
                    *xo = if seen & inside { pixel[0] } else { f32::NAN };
                    *yo = pixel[1];
                }
            }
        }
        Mapping::General | Mapping::Translation { .. } => {
            let plane = plan.planes[k];
            let rays = &plan.rays[y * width + cols.start..y * width + cols.end];
            // The pinhole and plumb-bob lenses in a loop that vectorises (`general_row`); the
            // equidistant one (an arctangent per pixel) as `project` does it.
            match cam.size[3] {
                DIST_NONE => general_row(cam, plane, rays, xs, ys, |n| n),
                DIST_PLUMB_BOB => general_row(cam, plane, rays, xs, ys, |n| plumb_bob(cam, n)),
                _ => {
                    for ((xo, yo), ray) in xs.iter_mut().zip(ys.iter_mut()).zip(rays) {
                        let ray = xyz(*ray);
                        [*xo, *yo] = ray_pixel(cam, ray, plane_depth(plane, ray));
                    }
                }
            }
        }
    }
}

/// `ray_pixel(cam, ray, plane_depth(plane, ray))` for every ray of a row, with `distort` the
/// camera's lens model (`lens` less its fold test and intrinsics): every step for every pixel
/// and the result selected, so the loop vectorises (the same floats where seen; NaN in both
/// coordinates elsewhere, as `ray_pixel`).
#[inline(always)]
fn general_row(
    cam: &GpuCamera,
    plane: [f32; 4],
    rays: &[[f32; 4]],
    xs: &mut [f32],
    ys: &mut [f32],
    distort: impl Fn(Vec2) -> Vec2,
) {
    let normal = xyz(plane);
    // `plane_depth`.
    let depth = |_: usize, ray: [f32; 3]| {
        let denom = dot3(normal, ray);
        if denom.abs() < 1e-12 {
            -1.0
        } else {
            plane[3] / denom
        }
    };
    projected_row(cam, rays, xs, ys, distort, depth);
}

/// `ray_pixel(cam, ray, depth(x, ray))` for every ray `x` of a row (the body of
/// `general_row`, whose depths lie on a plane; the fine sweep's are given per pixel).
#[inline(always)]
fn projected_row(
    cam: &GpuCamera,
    rays: &[[f32; 4]],
    xs: &mut [f32],
    ys: &mut [f32],
    distort: impl Fn(Vec2) -> Vec2,
    depth_of: impl Fn(usize, [f32; 3]) -> f32,
) {
    let (w, h) = (cam.size[0] as f32 - 1.0, cam.size[1] as f32 - 1.0);
    for (x, ((xo, yo), ray)) in xs.iter_mut().zip(ys.iter_mut()).zip(rays).enumerate() {
        let ray = xyz(*ray);
        // The depth, then `project` of the point `ray * depth`.
        let depth = depth_of(x, ray);
        let point = [ray[0] * depth, ray[1] * depth, ray[2] * depth];
        let (pixel, _, projected) = project_unbranched(cam, point, &distort);
        let inside = (pixel[0] >= 0.0) & (pixel[1] >= 0.0) & (pixel[0] <= w) & (pixel[1] <= h);
        let seen = (depth > 0.0) & projected & inside;
        *xo = if seen { pixel[0] } else { f32::NAN };
        *yo = if seen { pixel[1] } else { f32::NAN };
    }
}

/// Where the point `ray * depth` lands in camera `cam` (NaN: no depth, behind the camera or
/// outside its image).
#[inline(always)]
fn ray_pixel(cam: &GpuCamera, ray: [f32; 3], depth: f32) -> [f32; 2] {
    if depth > 0.0 {
        let projected = project(cam, [ray[0] * depth, ray[1] * depth, ray[2] * depth]);
        let p = [projected[0], projected[1]];
        if projected[2] > 0.0 && inside(cam, p) {
            return p;
        }
    }
    [f32::NAN; 2]
}

/// Where reference row `y` lands in a camera when each pixel has its own depth (ray parameter:
/// the point is `ray * depth`, as `plane_depth` gives on a plane; NaN = no hypothesis): the
/// general branch of `sample_coords` with `depths` for the plane's. For `Mapping::Given`.
#[inline(always)]
pub fn hypothesis_coords(
    plan: &SweepPlan,
    cam: &GpuCamera,
    mapping: Mapping,
    depths: &[f32],
    y: usize,
    coords: &mut [Vec<f32>; 2],
) {
    let width = plan.params.width as usize;
    let [xs, ys] = coords;
    let (xs, ys) = (&mut xs[..width], &mut ys[..width]);
    if let Mapping::GivenRow { x0, per_q, dy } = mapping {
        let v = y as i32 + dy;
        let row_inside = v >= 0 && v < cam.size[1] as i32;
        let w = cam.size[0] as f32 - 1.0;
        let depths = &depths[y * width..(y + 1) * width];
        for (x, (xo, &depth)) in xs.iter_mut().zip(depths).enumerate() {
            let u = (x as i32 as f32 + x0) + per_q * (1.0 / depth);
            let seen = row_inside & (depth > 0.0) & (u >= 0.0) & (u <= w);
            *xo = if seen { u } else { f32::NAN };
        }
        ys.fill(v as f32);
        return;
    }
    let rays = &plan.rays[y * width..(y + 1) * width];
    let depths = &depths[y * width..(y + 1) * width];
    let given = |x: usize, _: [f32; 3]| depths[x];
    // The pinhole and plumb-bob lenses in a loop that vectorises, as `general_row`.
    match cam.size[3] {
        DIST_NONE => projected_row(cam, rays, xs, ys, |n| n, given),
        DIST_PLUMB_BOB => projected_row(cam, rays, xs, ys, |n| plumb_bob(cam, n), given),
        _ => {
            for x in 0..width {
                [xs[x], ys[x]] = ray_pixel(cam, xyz(rays[x]), depths[x]);
            }
        }
    }
}

/// Camera `cam`'s colours along reference row `y` on plane `k` (twin of the projection,
/// `inside` and `sample_bilinear` of cost.wgsl), in the columns of `spans` (NaN, not seen,
/// elsewhere; translations fill the whole row). Mappings other than translations leave the
/// sample positions in `coords` (`sample_coords`) for the census costs, and, given the
/// reference row's census words (`census`: the words, the distances out), make the census
/// distances of the samples too (`census::distance_row`'s arithmetic), from the same texel
/// loads (`PlanarImage::sample_with_words`). Returns whether they did.
#[expect(
    clippy::too_many_arguments,
    reason = "each argument is an input of its own (the shader twin's buffers, or slices kept apart so that the loop vectorises); a struct would only rename them"
)]
#[inline(always)]
pub fn sample_row(
    plan: &SweepPlan,
    image: &PlanarImage,
    cam: &GpuCamera,
    mapping: Mapping,
    k: usize,
    y: usize,
    spans: &[std::ops::Range<usize>],
    coords: &mut [Vec<f32>; 2],
    out: &mut ColourRow,
    mut census: Option<(&[u32], &mut [f32])>,
) -> bool {
    let width = plan.params.width as usize;
    if let Mapping::Translation { dx, dy } = mapping {
        sample_row_shifted(image, dx, dy, y, width, out);
        return false;
    }
    if !matches!(spans, [whole] if *whole == (0..width)) {
        out[0][..width].fill(f32::NAN);
    }
    for span in spans {
        let span = span.clone();
        sample_coords(plan, cam, mapping, k, y, span.clone(), coords);
        let [xs, ys] = &*coords;
        let [r, g, b] = out;
        let colours = [
            &mut r[span.clone()],
            &mut g[span.clone()],
            &mut b[span.clone()],
        ];
        let census = census
            .as_mut()
            .map(|(words, distances)| (&words[span.clone()], &mut distances[span.clone()]));
        match mapping {
            Mapping::GivenRow { dy, .. } => {
                // `hypothesis_coords` left the whole row unseen when camera row y + dy is
                // outside the image.
                let y0 = (y as i32 + dy).clamp(0, image.height as i32 - 1) as usize;
                super::gather::gather_row_along(image, &xs[span], y0, colours, census);
            }
            _ => {
                super::gather::gather_row(image, &xs[span.clone()], &ys[span], colours, census);
            }
        }
    }
    census.is_some()
}

/// Where reference row `y` lands in a camera image of `cw` x `ch` texels that sees it shifted by
/// (dx, dy): the reference columns `x_lo .. x_lo + count` whose samples are inside (`inside`:
/// 0 <= x + dx <= cw - 1), starting at camera column `first` of row `y0`, with the constant
/// bilinear weights `fx`, `fy`. `None` when no sample of the row is inside.
#[derive(Debug, Clone, Copy)]
pub struct ShiftedSpan {
    pub x_lo: usize,
    pub count: usize,
    pub first: usize,
    pub y0: usize,
    pub fx: f32,
    pub fy: f32,
}

impl ShiftedSpan {
    #[inline(always)]
    pub fn of(cw: usize, ch: usize, dx: f64, dy: f64, y: usize, width: usize) -> Option<Self> {
        let (cw, ch) = (cw as f64, ch as f64);
        let v = y as f64 + dy;
        let x_lo = (-dx).ceil().max(0.0);
        let x_hi = (cw - 1.0 - dx).floor().min(width as f64 - 1.0);
        if !(v >= 0.0 && v <= ch - 1.0) || x_hi < x_lo {
            return None;
        }
        let ix = dx.floor();
        let y0 = v.floor();
        Some(Self {
            x_lo: x_lo as usize,
            count: (x_hi - x_lo) as usize + 1,
            first: (x_lo + ix) as usize,
            y0: y0 as usize,
            fx: (dx - ix) as f32,
            fy: (v - y0) as f32,
        })
    }
}

/// The fast path: row `y` shifted by (dx, dy), constant bilinear weights, contiguous loads.
#[inline(always)]
fn sample_row_shifted(
    image: &PlanarImage,
    dx: f64,
    dy: f64,
    y: usize,
    width: usize,
    out: &mut ColourRow,
) {
    let Some(ShiftedSpan {
        x_lo,
        count,
        first,
        y0,
        fx,
        fy,
    }) = ShiftedSpan::of(image.width, image.height, dx, dy, y, width)
    else {
        out[0].fill(f32::NAN);
        return;
    };
    out[0][..x_lo].fill(f32::NAN);
    out[0][x_lo + count..].fill(f32::NAN);
    let mix = |a: f32, b: f32, t: f32| a + (b - a) * t;
    let channels = if image.grey { 1 } else { 3 };
    for (plane, row_out) in image.channels.iter().zip(out.iter_mut()).take(channels) {
        let dst = &mut row_out[x_lo..x_lo + count];
        let row = |yy: usize| &plane[yy * image.width + first..];
        let top = row(y0);
        if fx == 0.0 {
            dst.copy_from_slice(&top[..count]);
        } else {
            for ((d, &a), &b) in dst.iter_mut().zip(&top[..count]).zip(&top[1..=count]) {
                *d = mix(a, b, fx);
            }
        }
        if fy != 0.0 {
            let bottom = row(y0 + 1);
            if fx == 0.0 {
                for (d, &b) in dst.iter_mut().zip(&bottom[..count]) {
                    *d = mix(*d, b, fy);
                }
            } else {
                for ((d, &a), &b) in dst.iter_mut().zip(&bottom[..count]).zip(&bottom[1..=count]) {
                    *d = mix(*d, mix(a, b, fx), fy);
                }
            }
        }
    }
}

/// Pair TSSD along a row: `min(tau, |a - b|^2)`, INVALID where either colour is missing.
/// `grey`: the three channels of both are equal (`PlanarImage::grey`) and R alone is read:
/// the same floats from a third of the loads (`(x + x) + x` is the sum of three equal
/// squares as the colour loop adds them).
#[inline(always)]
pub fn pair_cost_row(tau: f32, a: [&[f32]; 3], b: [&[f32]; 3], out: &mut [f32], grey: bool) {
    let n = out.len();
    if grey {
        let (a, b) = (&a[0][..n], &b[0][..n]);
        for x in 0..n {
            let d = a[x] - b[x];
            let square = d * d;
            let ssd = square + square + square;
            out[x] = if ssd >= 0.0 { fmin(tau, ssd) } else { INVALID };
        }
        return;
    }
    let (ar, ag, ab) = (&a[0][..n], &a[1][..n], &a[2][..n]);
    let (br, bg, bb) = (&b[0][..n], &b[1][..n], &b[2][..n]);
    for x in 0..n {
        let (dr, dg, db) = (ar[x] - br[x], ag[x] - bg[x], ab[x] - bb[x]);
        let ssd = dr * dr + dg * dg + db * db;
        // NaN (a missing colour) fails the test.
        out[x] = if ssd >= 0.0 { fmin(tau, ssd) } else { INVALID };
    }
}

/// Per-pixel accumulation of the visible pair costs for the scored channels (`Acc` of
/// cost.wgsl), one slice per field.
pub struct ScoreAcc {
    sum: Vec<f32>,
    count: Vec<f32>,
    left_sum: Vec<f32>,
    left_count: Vec<f32>,
    right_sum: Vec<f32>,
    right_count: Vec<f32>,
    /// The best_n smallest costs, ascending (BIG = none).
    best: Vec<Vec<f32>>,
}

impl ScoreAcc {
    pub fn new(width: usize, best_n: usize) -> Self {
        let v = || vec![0.0; width];
        Self {
            sum: v(),
            count: v(),
            left_sum: v(),
            left_count: v(),
            right_sum: v(),
            right_count: v(),
            best: (0..best_n).map(|_| vec![BIG; width]).collect(),
        }
    }

    /// Zeros (and BIG in `best`) in the columns `cols`.
    fn clear(&mut self, cols: std::ops::Range<usize>) {
        for v in [
            &mut self.sum,
            &mut self.count,
            &mut self.left_sum,
            &mut self.left_count,
            &mut self.right_sum,
            &mut self.right_count,
        ] {
            v[cols.clone()].fill(0.0);
        }
        for b in &mut self.best {
            b[cols.clone()].fill(BIG);
        }
    }
}

/// The scored channels of one row (not per-pair aggregation) from the pair costs, as
/// `score_plane` of cost.wgsl: SSSD, best n, or the half means (and their min when scored), in
/// the columns `cols` (INVALID elsewhere).
#[inline(always)]
pub fn scored_channels(
    plan: &SweepPlan,
    pair_costs: &[Vec<f32>],
    cols: std::ops::Range<usize>,
    acc: &mut ScoreAcc,
    channels: &mut [Vec<f32>],
) {
    let p = &plan.params;
    for channel in channels.iter_mut() {
        channel[..cols.start].fill(INVALID);
        channel[cols.end..].fill(INVALID);
    }
    acc.clear(cols.clone());
    let best_n = p.scoring == SCORING_BEST_N;
    for (pair, costs) in plan.pairs.iter().zip(pair_costs) {
        let half = pair[2];
        for x in cols.clone() {
            let c = costs[x];
            let seen = c >= 0.0;
            let (v, one) = if seen { (c, 1.0) } else { (0.0, 0.0) };
            acc.sum[x] += v;
            acc.count[x] += one;
            if half == HALF_LEFT {
                acc.left_sum[x] += v;
                acc.left_count[x] += one;
            } else if half == HALF_RIGHT {
                acc.right_sum[x] += v;
                acc.right_count[x] += one;
            }
        }
        if best_n {
            // Bubble each visible cost through the sorted list (the n smallest are exact).
            for x in cols.clone() {
                let c = costs[x];
                let mut v = if c >= 0.0 { c } else { BIG };
                for b in acc.best.iter_mut() {
                    let t = fmin(b[x], v);
                    v = if b[x] < v { v } else { b[x] };
                    b[x] = t;
                }
            }
        }
    }
    let mean_or_invalid = |s: f32, c: f32| if c > 0.0 { s / c } else { INVALID };
    if p.scoring == SCORING_HALF {
        for x in cols.clone() {
            let left = mean_or_invalid(acc.left_sum[x], acc.left_count[x]);
            let right = mean_or_invalid(acc.right_sum[x], acc.right_count[x]);
            channels[0][x] = left;
            channels[1][x] = right;
            if channels.len() == 3 {
                channels[2][x] = if left < 0.0 || (right >= 0.0 && right < left) {
                    right
                } else {
                    left
                };
            }
        }
    } else if best_n {
        for x in cols.clone() {
            let (mut s, mut k) = (0.0f32, 0.0f32);
            for b in &acc.best {
                if b[x] < BIG {
                    s += b[x];
                    k += 1.0;
                }
            }
            channels[0][x] = mean_or_invalid(s, k);
        }
    } else {
        for x in cols.clone() {
            channels[0][x] = mean_or_invalid(acc.sum[x], acc.count[x]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Prefiltered (grey) images: R alone is sampled and compared, with the floats that the
    /// three equal channels give: shifted rows, scattered gathers and the pair cost, samples
    /// outside the image (NaN, INVALID) included.
    #[test]
    fn grey_images_sample_and_cost_as_their_three_equal_channels() {
        let (w, h, width) = (37usize, 9usize, 30usize);
        let pixels: Vec<u32> = (0..w * h)
            .map(|i| (i as u32).wrapping_mul(2_654_435_761))
            .collect();
        let mut grey = PlanarImage::default();
        grey.fill_from_packed(w, h, &pixels, true, true, None);
        let mut three = PlanarImage::default();
        three.fill_from_packed(w, h, &pixels, true, true, None);
        three.grey = false;
        assert!(grey.grey && grey.channels[0] == grey.channels[2]);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let shifted = |image: &PlanarImage, dx: f64, dy: f64, y: usize| {
            let mut out = colour_row(width);
            sample_row_shifted(image, dx, dy, y, width, &mut out);
            out
        };
        let reference = shifted(&three, 0.0, 0.0, 4);
        for (dx, dy, y) in [(2.25, 0.5, 3), (0.0, 0.0, 1), (9.75, -0.25, 6)] {
            let (g, t) = (shifted(&grey, dx, dy, y), shifted(&three, dx, dy, y));
            assert_eq!(bits(&g[0]), bits(&t[0]));
            assert!(t[0].iter().any(|v| v.is_nan()) || dx < 5.0);
            let cost = |a: &ColourRow, grey: bool| {
                let mut out = vec![0.0; width];
                fn rows(r: &ColourRow) -> [&[f32]; 3] {
                    std::array::from_fn(|c| r[c].as_slice())
                }
                pair_cost_row(60.0, rows(&reference), rows(a), &mut out, grey);
                bits(&out)
            };
            let want = cost(&t, false);
            assert_eq!(cost(&g, true), want, "shift ({dx}, {dy})");
            assert!(want.contains(&INVALID.to_bits()) || dx < 5.0);
        }
        // Scattered samples, every seventh not seen.
        let xs: Vec<f32> = (0..width)
            .map(|i| {
                if i % 7 == 3 {
                    f32::NAN
                } else {
                    (i as f32 * 1.13) % 36.0
                }
            })
            .collect();
        let ys: Vec<f32> = (0..width).map(|i| (i as f32 * 0.71) % 8.0).collect();
        let gathered = |image: &PlanarImage| {
            let mut out = colour_row(width);
            let [r, g, b] = &mut out;
            super::super::gather::gather_row(image, &xs, &ys, [r, g, b], None);
            out
        };
        let (g, t) = (gathered(&grey), gathered(&three));
        assert_eq!(bits(&g[0]), bits(&t[0]));
        assert_eq!(bits(&t[0]), bits(&t[1]));
    }

    /// The General mapping's row loop (`general_row`: pinhole and plumb-bob lenses, every step
    /// computed and selected) against `ray_pixel` per pixel, bit for bit, NaN where not seen:
    /// a barrel lens and cameras converging steeply (points past the fold, which the model
    /// would fold back into the image, and points outside it), planes behind the reference and through its centre.
    /// Whether the point of `ray` on `plane` is in front of `cam`, past its lens's fold, and
    /// the model would put it inside the image (what the fold test keeps out).
    fn folds_inside(cam: &GpuCamera, plane: [f32; 4], ray: Vec3) -> bool {
        let depth = plane_depth(plane, ray);
        let point = ray.map(|v| v * depth);
        let p = [cam.row0, cam.row1, cam.row2].map(|row| dot3(xyz(row), point) + row[3]);
        let n = [p[0] / p[2], p[1] / p[2]];
        let d = plumb_bob(cam, n);
        let [fx, fy, cx, cy] = cam.intrinsics;
        depth > 0.0
            && p[2] > 1e-6
            && n[0] * n[0] + n[1] * n[1] > cam.dist_b[1]
            && inside(cam, [fx * d[0] + cx, fy * d[1] + cy])
    }

    #[test]
    #[expect(
        clippy::needless_range_loop,
        reason = "x indexes the rays, the depths and both coordinate rows at once"
    )]
    fn general_row_and_hypothesis_coords_are_ray_pixel_bit_for_bit() {
        for mut plan in converging_test_plans() {
            // Through the centre, slanted, behind, and near enough for the side cameras to see
            // points 60 degrees off their axes (past the fold).
            plan.planes.extend([
                [0.0, 1.0, 0.0, 0.0],
                [0.0, 0.6, 0.8, 1.5],
                [0.0, 0.0, 1.0, -1.0],
                [0.0, 0.0, 1.0, 0.15],
                [0.0, 0.0, 1.0, 0.2],
                [0.0, 0.0, 1.0, 0.3],
            ]);
            let width = plan.params.width as usize;
            let mut coords = [vec![0.0; width], vec![0.0; width]];
            let (mut seen, mut unseen, mut folded_inside) = (0, 0, 0);
            let mut given = [vec![0.0; width], vec![0.0; width]];
            for k in 0..plan.planes.len() {
                // The fine sweep's per-pixel depths: the plane's, every seventh missing.
                let depths: Vec<f32> = (0..plan.rays.len())
                    .map(|i| match i % 7 {
                        3 => f32::NAN,
                        _ => plane_depth(plan.planes[k], xyz(plan.rays[i])),
                    })
                    .collect();
                for cam in &plan.cameras {
                    for y in 0..plan.params.height as usize {
                        hypothesis_coords(&plan, cam, Mapping::Given, &depths, y, &mut given);
                        for x in 0..width {
                            let ray = xyz(plan.rays[y * width + x]);
                            let want = ray_pixel(cam, ray, depths[y * width + x]);
                            let got = [given[0][x], given[1][x]];
                            assert_eq!(
                                got.map(f32::to_bits),
                                want.map(f32::to_bits),
                                "given depths, plane {k} row {y} column {x}"
                            );
                        }
                        sample_coords(&plan, cam, Mapping::General, k, y, 0..width, &mut coords);
                        for x in 0..width {
                            let ray = xyz(plan.rays[y * width + x]);
                            let want = ray_pixel(cam, ray, plane_depth(plan.planes[k], ray));
                            let got = [coords[0][x], coords[1][x]];
                            assert_eq!(
                                got.map(f32::to_bits),
                                want.map(f32::to_bits),
                                "plane {k} row {y} column {x}: {got:?} {want:?}"
                            );
                            folded_inside += usize::from(folds_inside(cam, plan.planes[k], ray));
                            if want[0].is_nan() {
                                unseen += 1;
                            } else {
                                seen += 1;
                            }
                        }
                    }
                }
            }
            assert!(seen > 1000 && unseen > 1000, "{seen} seen, {unseen} not");
            if plan.cameras.iter().any(|cam| cam.size[3] != DIST_NONE) {
                assert!(folded_inside > 0, "no point folded back into the image");
            }
        }
    }
}
