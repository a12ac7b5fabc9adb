//! Steps 0 and 2 of [`super::integrate_weighted`] for a pinhole camera, lane-wise (built
//! for AVX2 + FMA by `vectorised_fn!` where the CPU has them): the observation weights of a
//! row of pixels, and the update of a block a row of eight voxels at a time.

use super::*;
use crate::simd::floor_small;

impl View<'_> {
    /// Step 2 for one block of a pinhole camera, a row of eight voxels at a time: the
    /// projections, the pixel offsets and the choice between the bilinear and the nearest
    /// depth, and the running averages on the block's field arrays ([`Block::observe_row`])
    /// are lane-wise (vectorised under AVX2), only the gathers are per voxel. The same
    /// arithmetic as [`Self::update_block`], in the same order.
    #[inline(always)]
    pub(super) fn update_block_pinhole_lanes(&self, index: BlockIndex, block: &mut Block) -> usize {
        const LANES: usize = BLOCK_SIDE;
        let Projector::Pinhole { fx, fy, cx, cy } = self.projector else {
            return self.update_block(index, block);
        };
        let first = index.first_voxel();
        let origin_in_world = DVec3::new(first[0] as f64, first[1] as f64, first[2] as f64)
            * f64::from(self.voxel_size_m);
        let origin = (self.cam_from_world_rotation * origin_in_world
            + self.cam_from_world_translation)
            .as_vec3();
        let [step_x, step_y, step_z] = [
            self.voxel_steps_in_cam.x_axis,
            self.voxel_steps_in_cam.y_axis,
            self.voxel_steps_in_cam.z_axis,
        ];
        let (width, height) = (self.depth.width as usize, self.depth.height as usize);
        let (w, h) = (width as f32, height as f32);
        let samples = &self.samples[..];
        let depth_m = &self.depth_m[..];
        // The last top-left corner of a bilinear 2x2 (`lanes_fit`: at least 2x2 pixels).
        // In i32 (`lanes_fit`: fewer than 2^31 pixels), which AVX2 converts and multiplies
        // eight lanes at a time (usize lanes are converted one by one).
        let last_corner = (samples.len() - width - 2) as i32;
        let last_pixel = (samples.len() - 1) as i32;
        let (width_i, height_i) = (width as i32, height as i32);
        let trunc = self.truncation_m;
        let inv_trunc = 1.0 / trunc;
        let xs: [f32; LANES] = std::array::from_fn(|x| x as f32);
        let has_colour = self.colour.is_some();
        // A row whose nearest voxel lies more than the truncation distance behind every depth
        // the block can read takes no observation (`s >= -trunc` fails in every lane); the
        // margin covers the rounding of the bilinear depth and of `s` (far below it).
        let last_x = xs[LANES - 1];
        // The block's eight corner voxels.
        let corners: [Vec3; 8] = std::array::from_fn(|c| {
            let at = |bit: usize, step: Vec3| {
                if c & bit != 0 {
                    step * last_x
                } else {
                    Vec3::ZERO
                }
            };
            origin + at(1, step_x) + at(2, step_y) + at(4, step_z)
        });
        let behind = self.depth_bound(corners, [fx, fy, cx, cy]) + trunc + ROW_SKIP_MARGIN_M;
        let mut updated = 0;
        for z in 0..BLOCK_SIDE {
            for y in 0..BLOCK_SIDE {
                let row = origin + step_y * y as f32 + step_z * z as f32;
                // The lanes' z are `row.z + step_x.z * x`, monotonic in x (rounding is).
                if row.z.min(row.z + step_x.z * last_x) > behind {
                    continue;
                }
                let mut pz = [0.0f32; LANES];
                let mut inside = [false; LANES];
                let mut corner = [0i32; LANES];
                let mut nearest = [0i32; LANES];
                let mut bilinear = [false; LANES];
                let mut fu = [0.0f32; LANES];
                let mut fv = [0.0f32; LANES];
                for x in 0..LANES {
                    let (px, py) = (row.x + step_x.x * xs[x], row.y + step_x.y * xs[x]);
                    let zc = row.z + step_x.z * xs[x];
                    let inv_z = 1.0 / zc;
                    let u = fx * px * inv_z + cx;
                    let v = fy * py * inv_z + cy;
                    // NaN fails every comparison.
                    let ok = zc > 1e-6 && u >= -0.5 && v >= -0.5 && u < w - 0.5 && v < h - 0.5;
                    let (u, v) = if ok { (u, v) } else { (0.0, 0.0) };
                    // `as i32` of these values (at least 0, below 2^22: `lanes_fit`) by
                    // [`floor_small`], which the compiler keeps lane-wise (the saturating `as
                    // i32` was 40 % of the update's instructions: 379 M against 231 M).
                    let n = floor_small(v + 0.5).min(height_i - 1) * width_i
                        + floor_small(u + 0.5).min(width_i - 1);
                    let (u1, v1) = (floor_small(u + 1.0), floor_small(v + 1.0));
                    let bil = u1 >= 1 && v1 >= 1 && u1 < width_i && v1 < height_i;
                    let (u0, v0) = (u1.max(1) - 1, v1.max(1) - 1);
                    pz[x] = zc;
                    inside[x] = ok;
                    nearest[x] = n.min(last_pixel);
                    bilinear[x] = bil;
                    corner[x] = (v0 * width_i + u0).min(last_corner);
                    fu[x] = u - u0 as f32;
                    fv[x] = v - v0 as f32;
                }
                let mut d = [[0.0f32; LANES]; 4];
                let mut dn = [0.0f32; LANES];
                let mut weight = [0.0f32; LANES];
                let mut rgb = [0u32; LANES];
                for x in 0..LANES {
                    // The four corners from the dense depths (two cache lines), one bounds
                    // check for the four (not negative: u0, v0 >= 0).
                    let i = corner[x] as usize;
                    let quad = &depth_m[i..i + width + 2];
                    d[0][x] = quad[0];
                    d[1][x] = quad[1];
                    d[2][x] = quad[width];
                    d[3][x] = quad[width + 1];
                    // The nearest pixel's depth, weight and colour share a cache line.
                    let near = &samples[nearest[x] as usize];
                    dn[x] = near.depth_m;
                    weight[x] = near.weight;
                    rgb[x] = near.rgb;
                }
                // Unpacked lane-wise ([`Rgba8Image::pack`]: red in the low byte).
                let level = |shift: u32| rgb.map(|p| ((p >> shift) & 0xff) as f32);
                let mut observed = RowObservation {
                    tsdf: [0.0; LANES],
                    weight,
                    update: [0; LANES],
                    rgb: [level(0), level(8), level(16)],
                    update_colour: [0; LANES],
                };
                for x in 0..LANES {
                    let [d0, d1, d2, d3] = [d[0][x], d[1][x], d[2][x], d[3][x]];
                    // All four valid (a NaN makes the sum NaN) and agreeing.
                    let lo = d0.min(d1).min(d2.min(d3));
                    let hi = d0.max(d1).max(d2.max(d3));
                    let agree = bilinear[x] & !(d0 + d1 + d2 + d3).is_nan() & (hi - lo < trunc);
                    let top = d0 + (d1 - d0) * fu[x];
                    let bottom = d2 + (d3 - d2) * fu[x];
                    let seen = if agree {
                        top + (bottom - top) * fv[x]
                    } else {
                        dn[x]
                    };
                    let s = seen - pz[x];
                    // A NaN depth or weight fails (`&`, not `&&`: no branches).
                    let update = inside[x] & (s >= -trunc) & !weight[x].is_nan();
                    let update_colour = update & has_colour & (s.abs() < trunc);
                    observed.tsdf[x] = (s * inv_trunc).min(1.0);
                    observed.update[x] = u32::from(update).wrapping_neg();
                    observed.update_colour[x] = u16::from(update_colour).wrapping_neg();
                }
                updated += block.observe_row(y, z, &observed, self.max_weight);
            }
        }
        updated
    }
}

/// What [`View::update_block_pinhole_lanes`] adds to the truncation distance before it passes
/// over a row of voxels behind every depth its block can read (metres): far above the rounding
/// of a bilinear depth and of the projective distance.
const ROW_SKIP_MARGIN_M: f32 = 1e-3;

impl View<'_> {
    /// The greatest valid depth that step 2 can read for any voxel within the hull of
    /// `points` (camera frame; a block's corner voxels): the maximum of the depth tiles under
    /// the hull's projection (the hull of the points' projections, one pixel wider on each
    /// side for the bilinear neighbours and rounding, clamped into the image); -inf where no
    /// depth there is valid, +inf where a point is not in front of the camera.
    #[inline(always)]
    fn depth_bound<const N: usize>(&self, points: [Vec3; N], [fx, fy, cx, cy]: [f32; 4]) -> f32 {
        let (width, height) = (self.depth.width as usize, self.depth.height as usize);
        let tiles_x = width.div_ceil(DEPTH_TILE);
        if self.tile_max.len() != tiles_x * height.div_ceil(DEPTH_TILE) {
            return f32::INFINITY;
        }
        let (mut u_lo, mut u_hi) = (f32::INFINITY, f32::NEG_INFINITY);
        let (mut v_lo, mut v_hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for p in points {
            if p.z.is_nan() || p.z <= 1e-3 {
                return f32::INFINITY;
            }
            let (u, v) = (fx * p.x / p.z + cx, fy * p.y / p.z + cy);
            (u_lo, u_hi) = (u_lo.min(u), u_hi.max(u));
            (v_lo, v_hi) = (v_lo.min(v), v_hi.max(v));
        }
        // The tiles of the pixel columns (rows) a voxel projecting within [lo, hi] reads: the
        // nearest and the bilinear 2x2 lie within [floor(lo), floor(hi) + 1]; one more each
        // side; clamped into the image (a box beyond its edge takes the edge's tiles). The
        // casts floor: the values are within [0, n - 1].
        let span = |lo: f32, hi: f32, n: usize| {
            let last = (n - 1) as f32;
            let tile = |p: f32| p.clamp(0.0, last) as usize / DEPTH_TILE;
            (tile(lo - 1.0), tile(hi + 2.0))
        };
        let ((tx0, tx1), (ty0, ty1)) = (span(u_lo, u_hi, width), span(v_lo, v_hi, height));
        let mut bound = f32::NEG_INFINITY;
        for ty in ty0..=ty1 {
            for &m in &self.tile_max[ty * tiles_x + tx0..=ty * tiles_x + tx1] {
                bound = bound.max(m);
            }
        }
        bound
    }
}

/// One row of a pinhole depth map and its neighbours for [`row_weights`] (NaN beyond the
/// image), with each column's ray x (z = 1) and the ray y of the rows above, here, below.
#[derive(Clone, Copy)]
pub(super) struct RowNeighbours<'a> {
    pub(super) here: &'a [f32],
    pub(super) left: &'a [f32],
    pub(super) right: &'a [f32],
    pub(super) up: &'a [f32],
    pub(super) down: &'a [f32],
    pub(super) xs: &'a [f32],
    pub(super) xs_left: &'a [f32],
    pub(super) xs_right: &'a [f32],
    pub(super) y: [f32; 3],
    pub(super) trunc: f32,
}

vectorised_fn! {
/// [`View::pixel_weight`] for every pixel of a row of a pinhole camera, lane-wise: the
/// normal from the neighbours' points (central differences, one-sided where a neighbour is
/// invalid or across a depth jump of at least the truncation distance), the squared cosine
/// to the pixel's ray, NaN where the pixel is invalid or a row or column has no neighbour.
pub(super) fn row_weights(n: RowNeighbours<'_>, weights: &mut [f32]) {
    let width = weights.len();
    let (here, left, right, up, down) = (
        &n.here[..width],
        &n.left[..width],
        &n.right[..width],
        &n.up[..width],
        &n.down[..width],
    );
    let (xs, xs_left, xs_right) = (&n.xs[..width], &n.xs_left[..width], &n.xs_right[..width]);
    let [y_up, y, y_down] = n.y;
    for c in 0..width {
        let d = here[c];
        let x = xs[c];
        // A neighbour's point where it is near (NaN fails), the centre's elsewhere.
        let pick = |dn: f32, xn: f32, yn: f32| {
            if (dn - d).abs() < n.trunc {
                Vec3::new(xn, yn, 1.0) * dn
            } else {
                Vec3::new(x, y, 1.0) * d
            }
        };
        let near = |dn: f32| (dn - d).abs() < n.trunc;
        let du = pick(right[c], xs_right[c], y) - pick(left[c], xs_left[c], y);
        let dv = pick(down[c], x, y_down) - pick(up[c], x, y_up);
        let has_both = (near(left[c]) || near(right[c])) && (near(up[c]) || near(down[c]));
        let cross = du.cross(dv);
        let rcp = 1.0 / cross.dot(cross).sqrt();
        let normal = cross * rcp;
        let ray = Vec3::new(x, y, 1.0);
        let cos = normal.dot(ray).abs() / ray.length();
        let ok = has_both && rcp.is_finite() && rcp > 0.0;
        weights[c] = if ok {
            (cos * cos).max(MIN_OBSERVATION_WEIGHT)
        } else {
            f32::NAN
        };
    }
}
}

vectorised_fn! {
/// [`View::update_block_pinhole_lanes`], compiled for AVX2 + FMA where the CPU has them.
pub(super) fn update_block_pinhole(view: &View<'_>, index: BlockIndex, block: &mut Block) -> usize {
    view.update_block_pinhole_lanes(index, block)
}
}

/// What [`pinhole_samples`] reads and writes.
pub(super) struct PinholeSamples<'a> {
    pub(super) depth: &'a ImageF32,
    pub(super) colour: Option<&'a Rgba8Image>,
    pub(super) fx: f32,
    pub(super) fy: f32,
    pub(super) cx: f32,
    pub(super) cy: f32,
    pub(super) trunc: f32,
    pub(super) limits: DepthLimits,
    pub(super) depth_m: &'a mut [f32],
    pub(super) samples: &'a mut [PixelSample],
    /// The greatest valid depth of each [`DEPTH_TILE`]-square tile (row by row; -inf where
    /// none is valid).
    pub(super) tile_max: &'a mut [f32],
}

/// Step 0 for a pinhole camera in one parallel pass over bands of rows: the rows' valid
/// depths into `depth_m`, their pixels' weights a row at a time, lane-wise ([`row_weights`]:
/// the neighbours' depths and ray x side by side, NaN beyond the image's edges, the rows just
/// above and below a band validated again locally) and their samples. Returns the number of
/// valid pixels.
pub(super) fn pinhole_samples(p: PinholeSamples<'_>) -> usize {
    let (width, height) = (p.depth.width as usize, p.depth.height as usize);
    let (fx, fy, cx, cy, trunc) = (p.fx, p.fy, p.cx, p.cy, p.trunc);
    let xs: Vec<f32> = (0..width).map(|col| (col as f32 - cx) / fx).collect();
    // `to` holds `from` shifted by one column (left: to[i] = from[i - 1]), NaN at the edge.
    let shift_into = |to: &mut [f32], from: &[f32], left: bool| {
        to.fill(f32::NAN);
        if width > 1 {
            if left {
                to[1..].copy_from_slice(&from[..width - 1]);
            } else {
                to[..width - 1].copy_from_slice(&from[1..]);
            }
        }
    };
    let (mut xs_left, mut xs_right) = (vec![0.0; width], vec![0.0; width]);
    shift_into(&mut xs_left, &xs, true);
    shift_into(&mut xs_right, &xs, false);
    let input = |r: usize| &p.depth.data[r * width..(r + 1) * width];
    let validate = |out: &mut [f32], input: &[f32]| p.limits.validate(out, input);
    let colour = p.colour;
    // Bands of rows: a band's own rows validated once into `depth_m`, the rows just above
    // and below it again locally; a band is a row of depth tiles.
    const BAND: usize = DEPTH_TILE;
    let tiles_x = width.div_ceil(DEPTH_TILE);
    p.depth_m
        .par_chunks_mut(width * BAND)
        .zip(p.samples.par_chunks_mut(width * BAND))
        .zip(p.tile_max.par_chunks_mut(tiles_x))
        .enumerate()
        .map_init(
            || {
                let row = || vec![0.0f32; width];
                // A row with one NaN beyond each end: its left neighbours are
                // `padded[..width]`, its right ones `padded[2..]`.
                (row(), row(), vec![f32::NAN; width + 2], row(), row())
            },
            |(above, below, padded, weights, column_max),
             (band, ((band_depths, band_out), tile_max))| {
                let first_row = band * BAND;
                let band_rows = band_depths.len() / width;
                let mut valid = 0;
                column_max.fill(f32::NEG_INFINITY);
                for (r, here) in band_depths.chunks_exact_mut(width).enumerate() {
                    valid += validate(here, input(first_row + r));
                    column_maxima(column_max, here);
                }
                for (tile, columns) in tile_max.iter_mut().zip(column_max.chunks(DEPTH_TILE)) {
                    *tile = columns.iter().fold(f32::NEG_INFINITY, |m, &d| m.max(d));
                }
                if first_row > 0 {
                    validate(above, input(first_row - 1));
                } else {
                    above.fill(f32::NAN);
                }
                if first_row + band_rows < height {
                    validate(below, input(first_row + band_rows));
                } else {
                    below.fill(f32::NAN);
                }
                let band_depths = &*band_depths;
                let line = |r: usize| &band_depths[r * width..(r + 1) * width];
                for (r, out) in band_out.chunks_exact_mut(width).enumerate() {
                    let row = first_row + r;
                    let here = line(r);
                    let up = if r > 0 { line(r - 1) } else { &above[..] };
                    let down = if r + 1 < band_rows {
                        line(r + 1)
                    } else {
                        &below[..]
                    };
                    padded[1..=width].copy_from_slice(here);
                    let (left, right) = (&padded[..width], &padded[2..]);
                    let ray_y = |r: usize| (r as f32 - cy) / fy;
                    let y = [ray_y(row.max(1) - 1), ray_y(row), ray_y(row + 1)];
                    row_weights(
                        RowNeighbours {
                            here,
                            left,
                            right,
                            up,
                            down,
                            xs: &xs,
                            xs_left: &xs_left,
                            xs_right: &xs_right,
                            y,
                            trunc,
                        },
                        weights,
                    );
                    let colours = colour.map(|c| &c.pixels[row * width..(row + 1) * width]);
                    fill_samples(out, here, weights, colours);
                }
                valid
            },
        )
        .sum()
}

crate::simd::vectorised_fn! {
/// `maxima[i] = max(maxima[i], depths[i])` where `depths[i]` is valid (NaN is not), lane-wise.
fn column_maxima(maxima: &mut [f32], depths: &[f32]) {
    for (m, &d) in maxima.iter_mut().zip(depths) {
        *m = if d > *m { d } else { *m };
    }
}
}

/// The side in pixels of the square tiles whose greatest depth step 0 keeps for step 2
/// (`View::tile_max`): a block of voxels whose nearest row lies more than the truncation
/// distance behind every depth its projection can read is passed over row by row.
pub(super) const DEPTH_TILE: usize = 8;

crate::simd::vectorised_fn! {
/// A row's [`PixelSample`]s from its depths, weights and colours (0 without).
fn fill_samples(out: &mut [PixelSample], depths: &[f32], weights: &[f32], colours: Option<&[u32]>) {
    let n = out.len().min(depths.len()).min(weights.len());
    let (out, depths, weights) = (&mut out[..n], &depths[..n], &weights[..n]);
    match colours {
        Some(colours) => {
            let colours = &colours[..n];
            for i in 0..n {
                out[i] = PixelSample {
                    depth_m: depths[i],
                    weight: weights[i],
                    rgb: colours[i],
                };
            }
        }
        None => {
            for i in 0..n {
                out[i] = PixelSample {
                    depth_m: depths[i],
                    weight: weights[i],
                    rgb: 0,
                };
            }
        }
    }
}
}
