//! Step 1 of [`super::integrate_weighted`]: the blocks the truncation band of every valid
//! pixel crosses (a walk of each band's segment, block by block, Amanatides & Woo 1987),
//! and the rays of a distorted camera on a coarse grid ([`RayGrid`]).

use super::*;

impl View<'_> {
    /// Step 1: the blocks the truncation band of every valid pixel crosses, sorted, each once.
    /// Bands of rows walk their pixels' segments into a list (a block that one of the last few
    /// segments met is not listed again), sorted and deduplicated per band, then overall.
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
            Projector::Distorted(_) => None,
        };
        let mut blocks: Vec<BlockIndex> = (0..height.div_ceil(ROWS_PER_TASK))
            .into_par_iter()
            .flat_map_iter(|task| {
                let rows = task * ROWS_PER_TASK..((task + 1) * ROWS_PER_TASK).min(height);
                let mut list = Vec::new();
                let mut recent = [BlockIndex([i32::MIN; 3]); 8];
                let mut next = 0;
                let mut visit = |index: BlockIndex| {
                    if !recent.contains(&index) {
                        list.push(index);
                        recent[next] = index;
                        next = (next + 1) % recent.len();
                    }
                };
                if let Some(ray_xs) = &pinhole_xs {
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
                    // pixel before is skipped).
                    const TILE: usize = 4;
                    const PAD: f32 = 1e-4;
                    let ray_y = |row: usize| (row as f32 - cy) / fy;
                    let mut previous_tile = [i32::MIN; 6];
                    let mut state = PixelState::default();
                    for row0 in rows.clone().step_by(TILE) {
                        let row1 = (row0 + TILE).min(rows.end);
                        for col0 in (0..width).step_by(TILE) {
                            let col1 = (col0 + TILE).min(width);
                            let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
                            for row in row0..row1 {
                                for &d in &self.depth_m[row * width + col0..row * width + col1] {
                                    // NaN fails both.
                                    lo = if d < lo { d } else { lo };
                                    hi = if d > hi { d } else { hi };
                                }
                            }
                            if lo > hi {
                                continue;
                            }
                            let (t_near, t_far) = ((lo - trunc).max(1e-3), hi + trunc);
                            let (mut box_lo, mut box_hi) =
                                (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
                            for (c, r) in [
                                (col0, row0),
                                (col1 - 1, row0),
                                (col0, row1 - 1),
                                (col1 - 1, row1 - 1),
                            ] {
                                let ray = rotation * Vec3::new(ray_xs[c], ray_y(r), 1.0);
                                for t in [t_near, t_far] {
                                    let p = centre + ray * t;
                                    box_lo = box_lo.min(p);
                                    box_hi = box_hi.max(p);
                                }
                            }
                            let first = (box_lo - Vec3::splat(PAD)).to_array().map(floor_i32);
                            let last = (box_hi + Vec3::splat(PAD)).to_array().map(floor_i32);
                            let extent: [i64; 3] =
                                std::array::from_fn(|a| i64::from(last[a]) - i64::from(first[a]));
                            let boxed = extent.iter().all(|e| *e >= 0)
                                && extent.iter().map(|e| e + 1).product::<i64>() <= TILE_BOX_BLOCKS;
                            if boxed {
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
                    list.sort_unstable();
                    list.dedup();
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
                            Projector::Distorted(_) => match self.ray_z1(col, row) {
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
                list.sort_unstable();
                list.dedup();
                list
            })
            .collect();
        blocks.par_sort_unstable();
        blocks.dedup();
        blocks
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
