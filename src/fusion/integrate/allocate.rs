//! Step 1 of [`super::integrate_weighted`]: the blocks the truncation band of every valid
//! pixel crosses (a walk of each band's segment, block by block, Amanatides & Woo 1987),
//! and the rays of a distorted camera on a coarse grid ([`RayGrid`]).

use super::*;

impl View<'_> {
    /// Step 1: the blocks the truncation band of every valid pixel crosses, in no order, a block
    /// possibly more than once. Bands of rows walk their pixels' segments into a list (a block
    /// still in a small hash of the band's recently listed ones is not listed again).
    pub(super) fn band_blocks(&self, world_from_cam: &RigidTransform) -> Vec<BlockIndex> {
        const ROWS_PER_TASK: usize = 8;
        let (width, height) = (self.depth.width as usize, self.depth.height as usize);
        // Block coordinates: block `b` spans [b, b + 1) (voxel centres round, blocks floor).
        let inv_block = 1.0 / (f64::from(self.voxel_size_m) * BLOCK_SIDE as f64);
        let half_voxel_in_blocks = 0.5 / BLOCK_SIDE as f64;
        let centre =
            (world_from_cam.translation * inv_block + DVec3::splat(half_voxel_in_blocks)).as_vec3();
        // A ray with z = 1 in the camera frame, in blocks in the world frame.
        let rotation = (world_from_cam.rotation_matrix() * inv_block).as_mat3();
        let trunc = self.truncation_m;
        // A pinhole camera's ray x per column (z = 1), for the lane-wise fast path.
        let pinhole_xs: Option<Vec<f32>> = match self.projector {
            Projector::Pinhole { fx, cx, .. } => {
                Some((0..width).map(|col| (col as f32 - cx) / fx).collect())
            }
            Projector::Distorted(..) => None,
        };
        // A pinhole camera's tiles: per tile column, the ray's x part of each world axis at
        // the tile's first and last pixel column, least and greatest (`TileRays`).
        let tile_rays = pinhole_xs
            .as_ref()
            .map(|xs| TileRays::new(xs, rotation, width, centre, trunc));
        (0..height.div_ceil(ROWS_PER_TASK))
            .into_par_iter()
            .flat_map_iter(|task| {
                let rows = task * ROWS_PER_TASK..((task + 1) * ROWS_PER_TASK).min(height);
                let mut list = Vec::new();
                // Blocks listed lately, by a hash of their index (a repeat is listed once
                // unless another block took its slot; the caller deduplicates).
                let mut recent = [BlockIndex([i32::MIN; 3]); RECENT_SLOTS];
                let mut visit = |index: BlockIndex| {
                    let [x, y, z] = index.0.map(|c| c as u32);
                    let slot = (x.wrapping_mul(0x9E37_79B1)
                        ^ y.wrapping_mul(0x85EB_CA77)
                        ^ z.wrapping_mul(0xC2B2_AE3D))
                        >> (32 - RECENT_BITS);
                    let slot = &mut recent[slot as usize];
                    if *slot != index {
                        *slot = index;
                        list.push(index);
                    }
                };
                if let (Some(ray_xs), Some(tile_rays)) = (&pinhole_xs, &tile_rays) {
                    let Projector::Pinhole { fy, cy, .. } = self.projector else {
                        unreachable!("pinhole_xs is made for pinhole models only");
                    };
                    // Tiles of TILE x TILE pixels: the bands of a tile's pixels lie in the
                    // frustum between its corner pixels' rays from its least depth less the
                    // truncation distance to its greatest plus it, a convex solid whose
                    // corners bound it. Where that box (padded against rounding) holds at
                    // most `TILE_BOX_BLOCKS` blocks, all are listed (every band in the tile
                    // is in them; a few may be neighbours of the band); elsewhere each pixel's
                    // segment is taken exactly: its first and last blocks, the middle one of
                    // a two-step walk, the walk beyond (a pixel with the same blocks as the
                    // pixel before is skipped). The boxes of a row of tiles are made lane-wise
                    // (`tile_boxes`).
                    let ray_y = |row: usize| (row as f32 - cy) / fy;
                    let mut previous_tile = [i32::MIN; 6];
                    let mut state = PixelState::default();
                    let mut boxes = TileBoxes::new(tile_rays.tiles);
                    for row0 in rows.clone().step_by(TILE) {
                        let row1 = (row0 + TILE).min(rows.end);
                        let depths = &self.depth_m[row0 * width..row1 * width];
                        let (y0, y1) = (ray_y(row0), ray_y(row1 - 1));
                        tile_boxes(&mut boxes, tile_rays, width, depths, [y0, y1]);
                        for tile in 0..tile_rays.tiles {
                            let kind = boxes.kind[tile];
                            if kind == TileKind::Empty as u8 {
                                continue;
                            }
                            if kind == TileKind::Boxed as u8 {
                                let first = [0, 1, 2].map(|a| boxes.first[a][tile] as i32);
                                let last = [0, 1, 2].map(|a| boxes.last[a][tile] as i32);
                                let pair =
                                    [first[0], first[1], first[2], last[0], last[1], last[2]];
                                if pair != previous_tile {
                                    previous_tile = pair;
                                    for x in first[0]..=last[0] {
                                        for y in first[1]..=last[1] {
                                            for z in first[2]..=last[2] {
                                                visit(BlockIndex([x, y, z]));
                                            }
                                        }
                                    }
                                }
                                continue;
                            }
                            let col0 = tile * TILE;
                            let col1 = (col0 + TILE).min(width);
                            // Every other row and column (subsampled): a pixel's band lies
                            // between its neighbours' on a surface (they are a fraction of a
                            // block apart), so the four corners' walks cover the others'
                            // blocks; a tile whose sampled pixels are all invalid takes them
                            // all.
                            let sampled = (row0..row1).step_by(ALLOCATION_STRIDE).any(|row| {
                                (col0..col1)
                                    .step_by(ALLOCATION_STRIDE)
                                    .any(|col| !self.depth_m[row * width + col].is_nan())
                            });
                            let stride = if sampled { ALLOCATION_STRIDE } else { 1 };
                            for row in (row0..row1).step_by(stride) {
                                let y = ray_y(row);
                                let depths = &self.depth_m[row * width + col0..row * width + col1];
                                let xs = &ray_xs[col0..col1];
                                for (&d, &x) in depths.iter().zip(xs).step_by(stride) {
                                    if !d.is_nan() {
                                        let segment =
                                            band_segment(d, x, y, rotation, centre, trunc);
                                        state.visit_exact(segment, &mut visit);
                                    }
                                }
                            }
                        }
                    }
                    return list;
                }
                for row in rows {
                    for col in 0..width {
                        let d = self.depth_m[row * width + col];
                        if d.is_nan() {
                            continue;
                        }
                        let ray = match self.projector {
                            Projector::Pinhole { fx, fy, cx, cy } => {
                                Vec3::new((col as f32 - cx) / fx, (row as f32 - cy) / fy, 1.0)
                            }
                            Projector::Distorted(..) => match self.ray_z1(col, row) {
                                Some(ray) => ray.as_vec3(),
                                None => continue,
                            },
                        };
                        let ray = rotation * ray;
                        let near = centre + ray * (d - trunc).max(1e-3);
                        let far = centre + ray * (d + trunc);
                        walk_blocks(near, far, &mut visit);
                    }
                }
                list
            })
            .collect()
    }
}

/// Slots of the hash of recently listed blocks in [`View::band_blocks`] (`2^RECENT_BITS`).
const RECENT_BITS: u32 = 8;
const RECENT_SLOTS: usize = 1 << RECENT_BITS;

/// The side of a pinhole camera's allocation tiles in pixels.
const TILE: usize = 4;

/// Per tile column of a pinhole camera: the x part (`ray_x * rotation.x_axis`) of each world
/// axis's ray component at the tile's first and last pixel column, the lesser and the
/// greater, with the z part (`rotation.z_axis`) added; in block units per metre of depth.
/// With what else [`tile_boxes`] needs of the camera: the y column of `rotation`, the camera
/// centre (block coordinates) and the truncation distance.
pub(super) struct TileRays {
    tiles: usize,
    /// `lo[a][tile]`, `hi[a][tile]`.
    lo: [Vec<f32>; 3],
    hi: [Vec<f32>; 3],
    y_column: [f32; 3],
    centre: [f32; 3],
    trunc: f32,
}

impl TileRays {
    fn new(ray_xs: &[f32], rotation: Mat3, width: usize, centre: Vec3, trunc: f32) -> Self {
        let tiles = width.div_ceil(TILE);
        let columns = rotation.to_cols_array_2d();
        let part = |a: usize, pick: fn(f32, f32) -> f32| -> Vec<f32> {
            (0..tiles)
                .map(|tile| {
                    let (c0, c1) = (tile * TILE, ((tile + 1) * TILE).min(width) - 1);
                    let (p0, p1) = (ray_xs[c0] * columns[0][a], ray_xs[c1] * columns[0][a]);
                    pick(p0, p1) + columns[2][a]
                })
                .collect()
        };
        Self {
            tiles,
            lo: [0, 1, 2].map(|a| part(a, f32::min)),
            hi: [0, 1, 2].map(|a| part(a, f32::max)),
            y_column: columns[1],
            centre: centre.to_array(),
            trunc,
        }
    }
}

/// What a row of tiles needs of [`View::band_blocks`]: no valid pixel, a box of at most
/// [`TILE_BOX_BLOCKS`] blocks, or the pixels' segments one by one.
#[repr(u8)]
enum TileKind {
    Empty = 0,
    Boxed = 1,
    Walk = 2,
}

/// [`tile_boxes`]' output for one row of tiles: each tile's kind and its box's first and last
/// block per axis (whole numbers, as f32).
struct TileBoxes {
    kind: Vec<u8>,
    first: [Vec<f32>; 3],
    last: [Vec<f32>; 3],
    /// Column minima and maxima of the tile row's depths (NaN left out), padded to whole tiles.
    column_lo: Vec<f32>,
    column_hi: Vec<f32>,
}

impl TileBoxes {
    fn new(tiles: usize) -> Self {
        let v = || vec![0.0f32; tiles];
        Self {
            kind: vec![0; tiles],
            first: [v(), v(), v()],
            last: [v(), v(), v()],
            column_lo: vec![0.0; tiles * TILE],
            column_hi: vec![0.0; tiles * TILE],
        }
    }
}

crate::simd::vectorised_fn! {
/// The boxes of one row of tiles (`depths`: its rows of valid depths, NaN elsewhere; `ys`:
/// the ray y of its first and last row), lane-wise: each tile's least and greatest depth, the
/// bounding box (in blocks, padded against rounding) of its corner pixels' rays between them
/// less and plus the truncation distance, and its kind. The box is separable: over the four
/// corner rays and the two depths `t > 0`, an axis's least value is
/// `centre + min(t_near * r_lo, t_far * r_lo)` with `r_lo` the least x part plus the least
/// y part plus the z part of the ray.
fn tile_boxes(
    out: &mut TileBoxes,
    rays: &TileRays,
    width: usize,
    depths: &[f32],
    ys: [f32; 2],
) {
    const PAD: f32 = 1e-4;
    let tiles = rays.tiles;
    let (column_lo, column_hi) = (&mut out.column_lo[..tiles * TILE], &mut out.column_hi[..tiles * TILE]);
    column_lo.fill(f32::INFINITY);
    column_hi.fill(f32::NEG_INFINITY);
    for row in depths.chunks_exact(width.max(1)) {
        for ((lo, hi), &d) in column_lo.iter_mut().zip(column_hi.iter_mut()).zip(row) {
            // NaN fails both.
            *lo = if d < *lo { d } else { *lo };
            *hi = if d > *hi { d } else { *hi };
        }
    }
    let (centre, trunc) = (rays.centre, rays.trunc);
    let y_part = |a: usize| {
        let (p0, p1) = (ys[0] * rays.y_column[a], ys[1] * rays.y_column[a]);
        (p0.min(p1), p0.max(p1))
    };
    let y_parts = [y_part(0), y_part(1), y_part(2)];
    let kind = &mut out.kind[..tiles];
    let [f0, f1, f2] = &mut out.first;
    let [l0, l1, l2] = &mut out.last;
    let (f0, f1, f2) = (&mut f0[..tiles], &mut f1[..tiles], &mut f2[..tiles]);
    let (l0, l1, l2) = (&mut l0[..tiles], &mut l1[..tiles], &mut l2[..tiles]);
    let (lo0, lo1, lo2) = (&rays.lo[0][..tiles], &rays.lo[1][..tiles], &rays.lo[2][..tiles]);
    let (hi0, hi1, hi2) = (&rays.hi[0][..tiles], &rays.hi[1][..tiles], &rays.hi[2][..tiles]);
    for t in 0..tiles {
        let c = &column_lo[t * TILE..t * TILE + TILE];
        let lo = c[0].min(c[1]).min(c[2].min(c[3]));
        let c = &column_hi[t * TILE..t * TILE + TILE];
        let hi = c[0].max(c[1]).max(c[2].max(c[3]));
        let valid = lo <= hi;
        let (t_near, t_far) = if valid {
            ((lo - trunc).max(1e-3), hi + trunc)
        } else {
            (1.0, 1.0)
        };
        let axis = |a: usize, r_lo: f32, r_hi: f32| {
            let (y_lo, y_hi) = y_parts[a];
            let (r_lo, r_hi) = (r_lo + y_lo, r_hi + y_hi);
            let low = centre[a] + (t_near * r_lo).min(t_far * r_lo) - PAD;
            let high = centre[a] + (t_near * r_hi).max(t_far * r_hi) + PAD;
            (low.floor(), high.floor())
        };
        let (a0, b0) = axis(0, lo0[t], hi0[t]);
        let (a1, b1) = axis(1, lo1[t], hi1[t]);
        let (a2, b2) = axis(2, lo2[t], hi2[t]);
        // Blocks in the box, each axis's count capped at 5 (so the product stays small).
        let count = |a: f32, b: f32| (b - a + 1.0).min(5.0);
        let boxed = count(a0, b0) * count(a1, b1) * count(a2, b2) <= TILE_BOX_BLOCKS as f32;
        kind[t] = if !valid {
            TileKind::Empty as u8
        } else if boxed {
            TileKind::Boxed as u8
        } else {
            TileKind::Walk as u8
        };
        (f0[t], f1[t], f2[t]) = (a0, a1, a2);
        (l0[t], l1[t], l2[t]) = (b0, b1, b2);
    }
}
}

/// The truncation band's segment of the ray `(ray_x, ray_y, 1)` (camera frame) at depth `d`,
/// in block coordinates (`rotation`: world from camera over the block size; `centre`: the
/// camera centre), as [`View::band_blocks`] walks it.
#[inline(always)]
pub(super) fn band_segment(
    d: f32,
    ray_x: f32,
    ray_y: f32,
    rotation: Mat3,
    centre: Vec3,
    trunc: f32,
) -> (Vec3, Vec3) {
    let ray = rotation * Vec3::new(ray_x, ray_y, 1.0);
    (
        centre + ray * (d - trunc).max(1e-3),
        centre + ray * (d + trunc),
    )
}

/// What the exact per-pixel allocation of [`View::band_blocks`] remembers of the pixel before.
pub(super) struct PixelState {
    previous: [i32; 6],
    previous_middle: Option<[i32; 3]>,
}

impl Default for PixelState {
    fn default() -> Self {
        Self {
            previous: [i32::MIN; 6],
            previous_middle: None,
        }
    }
}

impl PixelState {
    /// Visits the blocks of one pixel's band segment (`(near, far)` in block coordinates), as
    /// [`walk_blocks`] would, unless the pixel before visited the same ones.
    #[inline(always)]
    pub(super) fn visit_exact(
        &mut self,
        (near, far): (Vec3, Vec3),
        visit: &mut impl FnMut(BlockIndex),
    ) {
        let first = near.to_array().map(floor_i32);
        let last = far.to_array().map(floor_i32);
        let pair = [first[0], first[1], first[2], last[0], last[1], last[2]];
        let steps: i64 = (0..3)
            .map(|a| (i64::from(last[a]) - i64::from(first[a])).abs())
            .sum();
        if steps <= 1 {
            // (Longer walks between the same ends may take other paths.)
            if pair == self.previous && self.previous_middle.is_none() {
                return;
            }
            self.previous = pair;
            self.previous_middle = None;
            visit(BlockIndex(first));
            visit(BlockIndex(last));
        } else if steps == 2 {
            // Three blocks: the middle one is the walk's, by which boundary the segment meets
            // first.
            let middle = two_step_middle(near, far, first, last);
            if pair == self.previous && self.previous_middle == Some(middle) {
                return;
            }
            self.previous = pair;
            self.previous_middle = Some(middle);
            visit(BlockIndex(first));
            visit(BlockIndex(middle));
            visit(BlockIndex(last));
        } else {
            self.previous = [i32::MIN; 6];
            walk_blocks(near, far, visit);
        }
    }
}

/// The middle block of a segment whose first and last blocks ([`floor_i32`] of `start` and
/// `end`) are two face steps apart, as [`walk_blocks`] finds it: along the axis whose
/// boundary the segment meets first (the lower axis on a tie).
#[inline(always)]
pub(super) fn two_step_middle(start: Vec3, end: Vec3, first: [i32; 3], last: [i32; 3]) -> [i32; 3] {
    let (s, d) = (start.to_array(), (end - start).to_array());
    let mut best: Option<(usize, f32)> = None;
    for a in 0..3 {
        if first[a] == last[a] {
            continue;
        }
        let t = if d[a] > 0.0 {
            (first[a] as f32 + 1.0 - s[a]) / d[a]
        } else if d[a] < 0.0 {
            (s[a] - first[a] as f32) / -d[a]
        } else {
            f32::INFINITY
        };
        if best.is_none_or(|(_, t_best)| t < t_best) {
            best = Some((a, t));
        }
    }
    let mut middle = first;
    if let Some((a, _)) = best {
        middle[a] += (last[a] - first[a]).signum();
    }
    middle
}

/// A pinhole camera's tile whose bands' bounding box holds at most this many blocks lists
/// them all instead of walking its pixels' segments. On ICL-NUIM (`bench --fusion`, 2 cm
/// voxels): 2 (the two blocks of a segment that crosses one face) -> 4 takes 73 % of the tiles
/// instead of 28 % and cut the per-pixel segments from 55.7 k to 21.1 k for 1.3 % more blocks
/// (1502 -> 1521; 8 would list 5 % more).
pub(super) const TILE_BOX_BLOCKS: i64 = 4;

/// A pinhole camera's exact per-pixel allocation walks every `ALLOCATION_STRIDE`-th row and
/// column of a tile (Open3D and nvblox walk every pixel; neighbouring pixels' bands cross the
/// same blocks).
pub(super) const ALLOCATION_STRIDE: usize = 2;

/// `floor(v)` as an integer (a cast truncates towards zero; `floor` is a libm call on
/// baseline x86-64).
#[inline(always)]
pub(super) fn floor_i32(v: f32) -> i32 {
    let t = v as i32;
    t - i32::from(t as f32 > v)
}

/// Pixels between the points of a [`RayGrid`].
pub(super) const RAY_GRID_STEP: usize = 8;

/// A distorted camera's rays at every [`RAY_GRID_STEP`]-th pixel (and the last row and
/// column), each an exact [`CameraModel::unproject_z1`] (an iterative inverse, too slow for
/// every pixel of every frame), interpolated bilinearly in between for step 1's allocation:
/// the interpolation is off by a small fraction of a pixel, far inside the truncation band.
pub(super) struct RayGrid {
    xs: Vec<usize>,
    ys: Vec<usize>,
    rays: Vec<Option<DVec3>>,
}

impl RayGrid {
    pub(super) fn new(model: &CameraModel) -> Self {
        let points = |n: u32| {
            let last = (n as usize).saturating_sub(1);
            let mut v: Vec<usize> = (0..=last).step_by(RAY_GRID_STEP).collect();
            if v.last() != Some(&last) {
                v.push(last);
            }
            v
        };
        let (xs, ys) = (
            points(model.intrinsics.width_px),
            points(model.intrinsics.height_px),
        );
        let rays = ys
            .par_iter()
            .flat_map_iter(|&y| {
                xs.iter()
                    .map(move |&x| model.unproject_z1(DVec2::new(x as f64, y as f64)))
            })
            .collect();
        Self { xs, ys, rays }
    }

    /// The interpolated ray; `None` where a grid point around has no ray.
    pub(super) fn ray(&self, col: usize, row: usize) -> Option<DVec3> {
        let cell = |points: &[usize], p: usize| {
            let i = (p / RAY_GRID_STEP).min(points.len().saturating_sub(2));
            let (a, b) = (points[i], points[(i + 1).min(points.len() - 1)]);
            let t = if b > a {
                (p - a) as f64 / (b - a) as f64
            } else {
                0.0
            };
            (i, (i + 1).min(points.len() - 1), t)
        };
        let (i0, i1, tx) = cell(&self.xs, col);
        let (j0, j1, ty) = cell(&self.ys, row);
        let at = |i: usize, j: usize| self.rays[j * self.xs.len() + i];
        let top = at(i0, j0)?.lerp(at(i1, j0)?, tx);
        let bottom = at(i0, j1)?.lerp(at(i1, j1)?, tx);
        Some(top.lerp(bottom, ty))
    }
}

/// Visits every block a segment crosses, in order (Amanatides & Woo's traversal in block
/// coordinates, where block `b` spans `[b, b + 1)`): exactly `1 + sum |end - start|` blocks,
/// each a face neighbour of the one before.
pub(super) fn walk_blocks(start: Vec3, end: Vec3, mut visit: impl FnMut(BlockIndex)) {
    let cell_of = |p: Vec3| [p.x, p.y, p.z].map(floor_i32);
    let mut cell = cell_of(start);
    let last = cell_of(end);
    if cell == last {
        // The common case: the segment (twice the truncation distance) within one block.
        visit(BlockIndex(cell));
        return;
    }
    let dir = end - start;
    let (s, d) = ([start.x, start.y, start.z], [dir.x, dir.y, dir.z]);
    let mut t_max = [f32::INFINITY; 3];
    let mut t_delta = [f32::INFINITY; 3];
    for a in 0..3 {
        if d[a] > 0.0 {
            t_max[a] = (cell[a] as f32 + 1.0 - s[a]) / d[a];
            t_delta[a] = 1.0 / d[a];
        } else if d[a] < 0.0 {
            t_max[a] = (s[a] - cell[a] as f32) / -d[a];
            t_delta[a] = -1.0 / d[a];
        }
    }
    visit(BlockIndex(cell));
    let steps: i64 = (0..3)
        .map(|a| (i64::from(last[a]) - i64::from(cell[a])).abs())
        .sum();
    for _ in 0..steps {
        // The axis whose next boundary comes first, among those not yet at the end.
        let mut axis = None;
        for a in 0..3 {
            if cell[a] != last[a] && axis.is_none_or(|b: usize| t_max[a] < t_max[b]) {
                axis = Some(a);
            }
        }
        let Some(a) = axis else {
            break;
        };
        cell[a] += (last[a] - cell[a]).signum();
        t_max[a] += t_delta[a];
        visit(BlockIndex(cell));
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::*;
    use crate::fusion::blocks::BlockSet;
    use crate::fusion::test_scenes::{camera, look_at, sphere_before_slanted_wall};
    use crate::fusion::{integrate, FusionParams, VoxelBlockGrid};

    /// Step 1's shortcuts (tile boxes made lane-wise, every other pixel walked) against the
    /// exact walk of every valid pixel's band: a sphere before a slanted wall, seen from an
    /// oblique pose at 2 cm voxels. The blocks the exact walks find are allocated but for a
    /// few that only a skipped pixel's band touches, and few more are allocated.
    #[test]
    fn tiles_allocate_the_blocks_every_pixels_band_crosses() {
        let params = FusionParams {
            voxel_size_m: 0.02,
            ..FusionParams::default()
        };
        let model = camera(320, 240, 280.0);
        let pose = look_at(
            DVec3::new(0.7, -0.4, -0.2),
            DVec3::new(0.0, 0.0, 2.0),
            DVec3::new(0.1, -1.0, 0.2),
        );
        let depth = sphere_before_slanted_wall(&model, &pose);
        let mut grid = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
        let stats = integrate(&mut grid, &params, &depth, None, &model, &pose).unwrap();
        assert!(stats.pixels_valid > 300 * 200, "{stats:?}");

        // Every valid pixel's band segment walked exactly, in block coordinates.
        let inv_block = 1.0 / (f64::from(params.voxel_size_m) * BLOCK_SIDE as f64);
        let half_voxel = 0.5 / BLOCK_SIDE as f64;
        let centre = (pose.translation * inv_block + DVec3::splat(half_voxel)).as_vec3();
        let rotation = (pose.rotation_matrix() * inv_block).as_mat3();
        let trunc = params.truncation_m();
        let mut exact = BlockSet::default();
        for row in 0..240 {
            for col in 0..320 {
                let d = depth.data[row * 320 + col];
                if !(d.is_finite() && d >= params.min_depth_m && d <= params.max_depth_m) {
                    continue;
                }
                let ray = model
                    .intrinsics
                    .unproject_z1(glam::DVec2::new(col as f64, row as f64));
                let (near, far) =
                    band_segment(d, ray.x as f32, ray.y as f32, rotation, centre, trunc);
                walk_blocks(near, far, |index| {
                    exact.insert(index);
                });
            }
        }
        let missed = exact.iter().filter(|i| !grid.contains(**i)).count();
        let allocated = grid.block_count();
        assert!(
            missed * 100 <= exact.len() * 2,
            "{missed} of {} exact blocks not allocated",
            exact.len()
        );
        assert!(
            allocated * 100 <= exact.len() * 108,
            "{allocated} allocated for {} exact blocks",
            exact.len()
        );
        assert_eq!(allocated, stats.blocks_allocated);
    }
}
