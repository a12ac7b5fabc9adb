//! Incremental marching cubes (Lorensen & Cline, 1987) over the TSDF blocks, one mesh per
//! block, re-made only for blocks that changed (nvblox's `MeshIntegrator`).
//!
//! The cubes of a block are those whose lowest corner is one of its voxels; the cubes along
//! its upper faces reach into the neighbouring blocks (+x, +y, +z and their combinations),
//! whose voxels are looked up there. So a changed block re-meshes itself and the up to seven
//! blocks below it (-x, -y, -z and combinations) whose cubes reach into it. A cube with a
//! corner in a missing block or never observed (weight 0) makes no triangles.
//!
//! Vertices lie on cube edges at the zero crossing, linearly interpolated from the two
//! corners' TSDF (always from the lower corner to the upper one, so that an edge gives the
//! same bits whichever cube computes it), and are shared by the cubes of a block; blocks do
//! not share vertices (their borders' vertices are repeated). Triangles are wound counter-
//! clockwise seen from the free side (the TSDF's positive side, towards the cameras).

use rayon::prelude::*;

use super::blocks::{Block, BlockChanges, BlockIndex, BlockMap, BlockSet, Voxel, BLOCK_SIDE};
use super::tables::{CORNERS, EDGE_CORNERS, EDGE_TABLE, TRI_TABLE};
use super::VoxelBlockGrid;

/// The mesh of one block (or, from [`Mesh::collect`], of all), vertices in the world frame
/// in metres.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BlockMesh {
    pub vertices: Vec<[f32; 3]>,
    /// One per vertex.
    pub colours: Vec<[u8; 3]>,
    /// Indices into `vertices`.
    pub triangles: Vec<[u32; 3]>,
}

impl BlockMesh {
    pub fn is_empty(&self) -> bool {
        self.triangles.is_empty()
    }
}

/// What one [`Mesh::update`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MeshStats {
    /// Blocks whose mesh was made again.
    pub blocks_meshed: usize,
    /// Blocks with a non-empty mesh after the update.
    pub blocks_with_surface: usize,
    /// Triangles in the whole mesh after the update.
    pub triangles: usize,
    /// Vertices in the whole mesh after the update.
    pub vertices: usize,
    /// Meshes dropped because the grid dropped their blocks ([`Mesh::removed`]).
    pub blocks_removed: usize,
}

/// The surface of a [`VoxelBlockGrid`], one [`BlockMesh`] per block that has one.
#[derive(Debug, Clone, Default)]
pub struct Mesh {
    blocks: BlockMap<BlockMesh>,
    /// Blocks whose mesh was made again or dropped since the last [`Mesh::take_dirty`] (what
    /// a publisher of per-block meshes sends again or deletes).
    dirty: BlockSet,
    /// The blocks whose meshes the last [`Mesh::update`] dropped with their grid blocks.
    removed: Vec<BlockIndex>,
}

impl Mesh {
    pub fn new() -> Self {
        Self::default()
    }

    /// Re-meshes the blocks changed since the last update (and the blocks whose cubes reach
    /// into them), drops the meshes of blocks no longer in the grid, and clears the grid's
    /// changed set.
    pub fn update(&mut self, grid: &mut VoxelBlockGrid) -> MeshStats {
        let todo = self.take_changes(grid.take_changes(), |index| grid.contains(index));
        let meshes = mesh_on_cpu(grid, &todo);
        self.apply(meshes, todo.len())
    }

    /// [`Mesh::update`] with the blocks meshed by `mesh_blocks` (given the blocks to mesh, in
    /// index order; the GPU's [`crate::fusion::GpuTsdf::mesh_blocks`]), whose voxels `grid`
    /// holds a copy of. When it fails, the same blocks are meshed on the CPU from `grid`, and
    /// its error is returned beside the stats.
    pub fn update_with<E>(
        &mut self,
        grid: &mut VoxelBlockGrid,
        mesh_blocks: impl FnOnce(&[BlockIndex]) -> Result<Vec<(BlockIndex, BlockMesh)>, E>,
    ) -> (MeshStats, Option<E>) {
        let todo = self.take_changes(grid.take_changes(), |index| grid.contains(index));
        let (meshes, error) = match mesh_blocks(&todo) {
            Ok(meshes) => (meshes, None),
            Err(e) => (mesh_on_cpu(grid, &todo), Some(e)),
        };
        (self.apply(meshes, todo.len()), error)
    }

    /// The blocks to mesh again after `changes` to a grid that holds the blocks `contains`
    /// says (each changed or dropped block and the blocks below it), in index order; drops
    /// the meshes of the dropped blocks. Their meshes then go to [`Mesh::apply`]. A map on a
    /// GPU keeps its changes on its own ([`crate::fusion::GpuTsdf::take_unmeshed`]) and
    /// meshes on the device, without a host copy of its voxels.
    pub fn take_changes(
        &mut self,
        changes: BlockChanges,
        contains: impl Fn(BlockIndex) -> bool,
    ) -> Vec<BlockIndex> {
        let BlockChanges { changed, removed } = changes;
        // Dropped blocks: their meshes go, and the blocks below them mesh again (their cubes
        // reached into them).
        let mut todo: Vec<BlockIndex> = changed
            .iter()
            .chain(removed.iter())
            .flat_map(|index| {
                (0..8).map(move |i| index.offset([-(i & 1), -((i >> 1) & 1), -((i >> 2) & 1)]))
            })
            .filter(|index| contains(*index))
            .collect();
        todo.sort_unstable();
        todo.dedup();
        self.removed.clear();
        for index in removed {
            // A block dropped and allocated again since is in `changed`.
            if !contains(index) && self.blocks.remove(&index).is_some() {
                self.dirty.insert(index);
                self.removed.push(index);
            }
        }
        self.removed.sort_unstable();
        todo
    }

    /// Keeps `meshes` (of the `meshed` blocks [`Mesh::take_changes`] named) and counts the
    /// mesh.
    pub fn apply(&mut self, meshes: Vec<(BlockIndex, BlockMesh)>, meshed: usize) -> MeshStats {
        let mut stats = self.keep(meshes, meshed);
        stats.blocks_removed = self.removed.len();
        stats
    }

    /// The blocks whose meshes the last [`Mesh::update`] dropped because the grid dropped them
    /// ([`crate::fusion::FusionParams::max_blocks`], [`VoxelBlockGrid::clear`]), in index
    /// order: a publisher of per-block meshes deletes them.
    pub fn removed(&self) -> &[BlockIndex] {
        &self.removed
    }

    /// Meshes every block from scratch (the grid's changed set is left as it is).
    pub fn rebuild(&mut self, grid: &VoxelBlockGrid) -> MeshStats {
        self.dirty.extend(self.blocks.keys().copied());
        self.blocks.clear();
        let all: Vec<BlockIndex> = grid.blocks().map(|(index, _)| *index).collect();
        self.remesh(grid, &all)
    }

    fn remesh(&mut self, grid: &VoxelBlockGrid, todo: &[BlockIndex]) -> MeshStats {
        self.keep(mesh_on_cpu(grid, todo), todo.len())
    }

    /// Keeps each block's new mesh (drops the empty ones) and counts the mesh.
    fn keep(&mut self, meshes: Vec<(BlockIndex, BlockMesh)>, meshed: usize) -> MeshStats {
        for (index, mesh) in meshes {
            self.dirty.insert(index);
            if mesh.is_empty() {
                self.blocks.remove(&index);
            } else {
                self.blocks.insert(index, mesh);
            }
        }
        MeshStats {
            blocks_meshed: meshed,
            blocks_with_surface: self.blocks.len(),
            triangles: self.triangle_count(),
            vertices: self.blocks.values().map(|m| m.vertices.len()).sum(),
            blocks_removed: 0,
        }
    }

    pub fn block(&self, index: BlockIndex) -> Option<&BlockMesh> {
        self.blocks.get(&index)
    }

    /// The blocks with a surface, in no particular order.
    pub fn blocks(&self) -> impl Iterator<Item = (&BlockIndex, &BlockMesh)> {
        self.blocks.iter()
    }

    pub fn triangle_count(&self) -> usize {
        self.blocks.values().map(|m| m.triangles.len()).sum()
    }

    /// Forgets every block's mesh (and what was dirty: a publisher deletes everything).
    pub fn clear(&mut self) {
        self.blocks.clear();
        self.dirty.clear();
        self.removed.clear();
    }

    /// The blocks whose mesh was made again (possibly empty now) or dropped since the last
    /// call, in index order.
    pub fn take_dirty(&mut self) -> Vec<BlockIndex> {
        let mut dirty: Vec<BlockIndex> = self.dirty.drain().collect();
        dirty.sort_unstable();
        dirty
    }

    /// All blocks' meshes in one, blocks in index order (vertices of neighbouring blocks'
    /// shared borders appear once per block).
    pub fn collect(&self) -> BlockMesh {
        let mut indices: Vec<&BlockIndex> = self.blocks.keys().collect();
        indices.sort_unstable();
        let mut out = BlockMesh::default();
        for index in indices {
            let Some(mesh) = self.blocks.get(index) else {
                continue;
            };
            let base = out.vertices.len() as u32;
            out.vertices.extend_from_slice(&mesh.vertices);
            out.colours.extend_from_slice(&mesh.colours);
            out.triangles
                .extend(mesh.triangles.iter().map(|t| t.map(|i| i + base)));
        }
        out
    }

    /// Three vertices and three colours per triangle, blocks in index order (the layout of a
    /// `visualization_msgs/Marker` `TRIANGLE_LIST`).
    pub fn to_triangle_list(&self) -> (Vec<[f32; 3]>, Vec<[u8; 3]>) {
        let mesh = self.collect();
        let corners = mesh.triangles.iter().flatten().map(|&i| i as usize);
        corners
            .filter_map(|i| Some((*mesh.vertices.get(i)?, *mesh.colours.get(i)?)))
            .unzip()
    }
}

/// The voxels a block's cubes read: the block's own 8^3 and one more layer from the
/// neighbours above (`None` where that block is missing).
struct Neighbourhood<'a> {
    blocks: [Option<&'a Block>; 8],
}

const SIDE: usize = BLOCK_SIDE + 1;

impl<'a> Neighbourhood<'a> {
    fn new(grid: &'a VoxelBlockGrid, index: BlockIndex) -> Self {
        let blocks = std::array::from_fn(|i| {
            let i = i as i32;
            grid.block(index.offset([i & 1, (i >> 1) & 1, (i >> 2) & 1]))
        });
        Self { blocks }
    }

    /// Voxel `(x, y, z)` with each in `0..=8`, 8 being the neighbour's first layer.
    fn voxel(&self, x: usize, y: usize, z: usize) -> Option<Voxel> {
        let which = (x / BLOCK_SIDE) | ((y / BLOCK_SIDE) << 1) | ((z / BLOCK_SIDE) << 2);
        let block = self.blocks[which]?;
        Some(block.voxel(x % BLOCK_SIDE, y % BLOCK_SIDE, z % BLOCK_SIDE))
    }

    /// The TSDF of the 9x9x9 voxels a block's cubes read (x fastest, [`SIDE`] per axis), NaN
    /// where the voxel's block is missing or the voxel was never observed (an observed
    /// voxel's TSDF is never NaN: the integration averages finite values only): what the
    /// cubes' corners are tested on, a row of the block's field arrays at a time.
    #[inline(always)]
    fn observed_tsdf(&self) -> [f32; SIDE * SIDE * SIDE] {
        let mut out = [f32::NAN; SIDE * SIDE * SIDE];
        for (i, line) in out.chunks_exact_mut(SIDE).enumerate() {
            let (y, z) = (i % SIDE, i / SIDE);
            let which = ((y / BLOCK_SIDE) << 1) | ((z / BLOCK_SIDE) << 2);
            let (by, bz) = (y % BLOCK_SIDE, z % BLOCK_SIDE);
            if let Some(block) = self.blocks[which] {
                let (tsdf, weight) = block.tsdf_and_weight_row(by, bz);
                for x in 0..BLOCK_SIDE {
                    line[x] = if weight[x] > 0.0 { tsdf[x] } else { f32::NAN };
                }
            }
            if let Some(block) = self.blocks[which | 1] {
                let (tsdf, weight) = block.tsdf_and_weight_row(by, bz);
                line[BLOCK_SIDE] = if weight[0] > 0.0 { tsdf[0] } else { f32::NAN };
            }
        }
        out
    }
}

/// [`CORNERS`] as offsets into [`Neighbourhood::observed_tsdf`].
const CORNER_OFFSETS: [usize; 8] = {
    let mut offsets = [0; 8];
    let mut i = 0;
    while i < 8 {
        let [x, y, z] = CORNERS[i];
        offsets[i] = x + SIDE * (y + SIDE * z);
        i += 1;
    }
    offsets
};

/// `x.round()` (half away from zero) wherever the result is then clamped to 0..=255: for
/// `x >= 0` the integer part plus one where the fraction (exact) is at least a half; NaN
/// and negative values give 0, as the rounded value clamped would. `f32::round` is a libm
/// call on the baseline x86-64 (`roundf`), three per vertex.
#[inline(always)]
fn round_level(x: f32) -> f32 {
    let whole = x as u32 as f32;
    if x - whole >= 0.5 {
        whole + 1.0
    } else {
        whole
    }
}

/// The marching-cubes case of each of the eight cubes along x of a row (`base`: the offset of
/// the first cube's lowest corner in [`Neighbourhood::observed_tsdf`]), lane-wise: bit `i`
/// set where corner `i` is inside (TSDF < 0); 0 (no triangles) where a corner is NaN.
#[inline(always)]
fn row_cases(observed: &[f32; SIDE * SIDE * SIDE], base: usize) -> [u32; BLOCK_SIDE] {
    let mut case = [0u32; BLOCK_SIDE];
    let mut missing = [false; BLOCK_SIDE];
    for (i, &o) in CORNER_OFFSETS.iter().enumerate() {
        let corners = &observed[base + o..base + o + BLOCK_SIDE];
        for x in 0..BLOCK_SIDE {
            case[x] |= u32::from(corners[x] < 0.0) << i;
            missing[x] |= corners[x].is_nan();
        }
    }
    for x in 0..BLOCK_SIDE {
        case[x] = if missing[x] { 0 } else { case[x] };
    }
    case
}

/// Each of `todo`'s meshes, on rayon's threads.
pub(crate) fn mesh_on_cpu(
    grid: &VoxelBlockGrid,
    todo: &[BlockIndex],
) -> Vec<(BlockIndex, BlockMesh)> {
    todo.par_iter()
        .map(|index| (*index, mesh_block(grid, *index)))
        .collect()
}

crate::simd::vectorised_fn! {
/// Marching cubes over one block's cubes (AVX2 where the CPU has it: the cases of a row of
/// cubes are found lane-wise).
fn mesh_block(grid: &VoxelBlockGrid, index: BlockIndex) -> BlockMesh {
    mesh_block_body(grid, index)
}
}

#[inline(always)]
fn mesh_block_body(grid: &VoxelBlockGrid, index: BlockIndex) -> BlockMesh {
    let around = Neighbourhood::new(grid, index);
    let mut mesh = BlockMesh::default();
    if around.blocks[0].is_none() {
        return mesh;
    }
    // The vertex made on each edge, by (lower corner, axis); u16::MAX: none yet. u16: a
    // block has at most 3 * 9^3 edges, so vertices; half the table to fill per block (26 KiB
    // in u32, more than the rest of a block's meshing writes).
    let observed = around.observed_tsdf();
    // No observed voxel inside (TSDF < 0) or none outside: no cube is crossed (a block in
    // free space or behind the surface ends here).
    let (inside, outside) = observed
        .iter()
        .fold((false, false), |(inside, outside), t| {
            (inside | (*t < 0.0), outside | (*t >= 0.0))
        });
    if !(inside && outside) {
        return mesh;
    }
    // A block the surface crosses makes tens to a few hundred vertices: room for a typical
    // one up front rather than a dozen reallocations.
    mesh.vertices.reserve(96);
    mesh.colours.reserve(96);
    mesh.triangles.reserve(192);
    let mut edge_vertex = [u16::MAX; SIDE * SIDE * SIDE * 3];
    let first = index.first_voxel();
    let s = grid.voxel_size_m();
    for z in 0..BLOCK_SIDE {
        for y in 0..BLOCK_SIDE {
            // A cube with a corner missing or never observed (NaN) makes nothing (case 0).
            let cases = row_cases(&observed, SIDE * (y + SIDE * z));
            if cases.iter().all(|&c| c == 0 || c == 255) {
                continue;
            }
            for (x, &case) in cases.iter().enumerate() {
                let case = case as usize;
                let crossed = EDGE_TABLE[case];
                if crossed == 0 {
                    continue;
                }
                // The corners' voxels (colour and all), only for cubes that make triangles.
                let corner = |i: usize| {
                    let [dx, dy, dz] = CORNERS[i];
                    around.voxel(x + dx, y + dy, z + dz).unwrap_or(Voxel::EMPTY)
                };
                let mut cube_vertices = [0u32; 12];
                for (edge, pair) in EDGE_CORNERS.iter().enumerate() {
                    if crossed & (1 << edge) == 0 {
                        continue;
                    }
                    // Lower corner first: the corner offsets differ along one axis.
                    let (a, b) = (pair[0], pair[1]);
                    let (lo, hi) = if CORNERS[a] < CORNERS[b] {
                        (a, b)
                    } else {
                        (b, a)
                    };
                    let o = CORNERS[lo];
                    let axis = (0..3).find(|&k| CORNERS[hi][k] != o[k]).unwrap_or(0);
                    let key = (((z + o[2]) * SIDE + (y + o[1])) * SIDE + (x + o[0])) * 3 + axis;
                    if edge_vertex[key] == u16::MAX {
                        edge_vertex[key] = mesh.vertices.len() as u16;
                        let (v_lo, v_hi) = (corner(lo), corner(hi));
                        let t = (v_lo.tsdf / (v_lo.tsdf - v_hi.tsdf)).clamp(0.0, 1.0);
                        let mut p = [0.0f32; 3];
                        for k in 0..3 {
                            let voxel = [x, y, z][k] + o[k];
                            let along = if k == axis { t } else { 0.0 };
                            p[k] = ((first[k] + voxel as i64) as f32 + along) * s;
                        }
                        let (c_lo, c_hi) = (v_lo.colour_f32(), v_hi.colour_f32());
                        let colour = std::array::from_fn(|k| {
                            round_level(c_lo[k] + (c_hi[k] - c_lo[k]) * t).clamp(0.0, 255.0) as u8
                        });
                        mesh.vertices.push(p);
                        mesh.colours.push(colour);
                    }
                    cube_vertices[edge] = u32::from(edge_vertex[key]);
                }
                for triangle in TRI_TABLE[case].chunks_exact(3) {
                    if triangle[0] < 0 {
                        break;
                    }
                    // Bourke's table winds counter-clockwise seen from the inside (negative)
                    // corners' side in a right-handed frame; swap two to face the free side.
                    let [a, b, c] =
                        [triangle[0], triangle[1], triangle[2]].map(|e| cube_vertices[e as usize]);
                    mesh.triangles.push([a, c, b]);
                }
            }
        }
    }
    mesh
}

#[cfg(test)]
mod tests {
    use glam::{DVec3, Vec3};

    use super::*;
    use crate::fusion::test_scenes::{
        camera, look_at, red_left_blue_right, render_plane, render_sphere,
    };
    use crate::fusion::{integrate, FusionParams};
    use crate::geometry::RigidTransform;

    fn triangle_area_and_normal(mesh: &BlockMesh, t: &[u32; 3]) -> (f32, Vec3, Vec3) {
        let [a, b, c] = t.map(|i| Vec3::from(mesh.vertices[i as usize]));
        let n = (b - a).cross(c - a);
        (0.5 * n.length(), n, (a + b + c) / 3.0)
    }

    #[test]
    fn sphere_seen_from_six_poses_meshes_onto_its_surface() {
        let params = FusionParams {
            voxel_size_m: 0.04,
            ..FusionParams::default()
        };
        let (centre, radius) = (DVec3::new(0.0, 0.0, 2.0), 0.5);
        let model = camera(320, 240, 300.0);
        let mut grid = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
        let up = DVec3::new(0.0, -1.0, 0.0);
        let poses = [
            look_at(DVec3::ZERO, centre, up),
            look_at(centre + DVec3::new(2.0, 0.0, 0.0), centre, up),
            look_at(centre + DVec3::new(-2.0, 0.0, 0.0), centre, up),
            look_at(centre + DVec3::new(0.0, 0.0, 2.0), centre, up),
            look_at(centre + DVec3::new(0.0, -2.0, 0.1), centre, up),
            look_at(centre + DVec3::new(0.0, 2.0, 0.1), centre, up),
        ];
        for pose in &poses {
            let depth = render_sphere(&model, pose, centre, radius);
            let stats = integrate(&mut grid, &params, &depth, None, &model, pose).unwrap();
            assert!(stats.pixels_valid > 10_000, "{stats:?}");
            assert!(stats.voxels_updated > 0, "{stats:?}");
        }
        let mut mesh = Mesh::new();
        let stats = mesh.update(&mut grid);
        assert!(grid.changed_blocks().is_empty());
        let all = mesh.collect();
        assert_eq!(stats.triangles, all.triangles.len());
        let s = params.voxel_size_m;
        let centre32 = centre.as_vec3();
        let worst = all
            .vertices
            .iter()
            .map(|v| ((Vec3::from(*v) - centre32).length() - radius as f32).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 0.5 * s, "a vertex lies {worst} m off the sphere");
        // The whole sphere was seen: its area, and a vertex near every direction.
        let area: f32 = all
            .triangles
            .iter()
            .map(|t| triangle_area_and_normal(&all, t).0)
            .sum();
        let true_area = 4.0 * std::f32::consts::PI * (radius as f32).powi(2);
        assert!(
            (area / true_area - 1.0).abs() < 0.05,
            "area {area} of {true_area}"
        );
        let cells = true_area / (s * s);
        let n = all.triangles.len() as f32;
        assert!(
            n > cells && n < 4.0 * cells,
            "{n} triangles for {cells} voxel faces"
        );
        let directions: Vec<Vec3> = all
            .vertices
            .iter()
            .map(|v| (Vec3::from(*v) - centre32).normalize())
            .collect();
        for i in 0..200 {
            // A Fibonacci sphere of directions.
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / 200.0;
            let phi = i as f32 * 2.399_963;
            let r = (1.0 - z * z).sqrt();
            let d = Vec3::new(r * phi.cos(), r * phi.sin(), z);
            let best = directions.iter().map(|v| v.dot(d)).fold(-1.0f32, f32::max);
            assert!(best > 0.99, "no vertex towards {d} (best cosine {best})");
        }
        // Triangles face outwards, towards the cameras.
        let outward = all
            .triangles
            .iter()
            .filter(|t| {
                let (area, normal, centroid) = triangle_area_and_normal(&all, t);
                area < 1e-9 || normal.dot(centroid - centre32) > 0.0
            })
            .count();
        assert_eq!(outward, all.triangles.len());
    }

    /// A 320x240 camera at the origin looking along +z at the wall z = `z_m`.
    fn wall(z_m: f64) -> (crate::geometry::CameraModel, crate::image::ImageF32) {
        let model = camera(320, 240, 300.0);
        let depth = render_plane(&model, &RigidTransform::IDENTITY, DVec3::Z, z_m);
        (model, depth)
    }

    #[test]
    fn wall_meshes_flat_without_holes_and_with_its_colours() {
        let params = FusionParams::default();
        let (model, depth) = wall(3.0);
        let colour = red_left_blue_right(320, 240);
        let mut grid = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
        let stats = integrate(
            &mut grid,
            &params,
            &depth,
            Some(&colour),
            &model,
            &RigidTransform::IDENTITY,
        )
        .unwrap();
        assert_eq!(stats.pixels_valid, 320 * 240);
        let mut mesh = Mesh::new();
        mesh.update(&mut grid);
        let all = mesh.collect();
        let s = params.voxel_size_m;
        for v in &all.vertices {
            assert!((v[2] - 3.0).abs() < 0.25 * s, "vertex {v:?} off the wall");
        }
        // The wall spans |x| < 1.6 m, |y| < 1.2 m; inside |x|, |y| < 1 m, every 10 cm square
        // holds vertices and the triangles cover the area.
        let half = 1.0f32;
        let cells = (2.0 * half / 0.1) as usize;
        let mut count = vec![0usize; cells * cells];
        for v in &all.vertices {
            if v[0].abs() < half && v[1].abs() < half {
                let i = ((v[0] + half) / 0.1) as usize;
                let j = ((v[1] + half) / 0.1) as usize;
                count[j.min(cells - 1) * cells + i.min(cells - 1)] += 1;
            }
        }
        assert!(count.iter().all(|&c| c >= 1), "a hole: {count:?}");
        let area: f32 = all
            .triangles
            .iter()
            .map(|t| triangle_area_and_normal(&all, t))
            .filter(|(_, _, c)| c.x.abs() < half && c.y.abs() < half)
            .map(|(a, _, _)| a)
            .sum();
        assert!(
            (area / (4.0 * half * half) - 1.0).abs() < 0.03,
            "area {area}"
        );
        // Red on the left (x < 0 in the optical frame), blue on the right.
        for (v, c) in all.vertices.iter().zip(&all.colours) {
            if v[0] < -0.1 {
                assert_eq!(*c, [255, 0, 0], "at {v:?}");
            } else if v[0] > 0.1 {
                assert_eq!(*c, [0, 0, 255], "at {v:?}");
            }
        }
        // Triangles face the camera (-z).
        for t in &all.triangles {
            let (a, n, _) = triangle_area_and_normal(&all, t);
            assert!(a < 1e-9 || n.z < 0.0);
        }
    }

    #[test]
    fn only_changed_blocks_are_remeshed_and_match_a_full_remesh() {
        let params = FusionParams::default();
        let (model, depth) = wall(3.0);
        let mut grid = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
        let pose = RigidTransform::IDENTITY;
        integrate(&mut grid, &params, &depth, None, &model, &pose).unwrap();
        let mut mesh = Mesh::new();
        let first = mesh.update(&mut grid);
        assert!(first.blocks_meshed > 0 && first.blocks_meshed <= grid.block_count());
        // A box face at 2 m in a patch of the image, nothing seen elsewhere.
        let mut patch = render_plane(&model, &pose, DVec3::Z, 2.0);
        for (i, d) in patch.data.iter_mut().enumerate() {
            let (u, v) = (i % 320, i / 320);
            if !(100..180).contains(&u) || !(80..140).contains(&v) {
                *d = f32::NAN;
            }
        }
        let stats = integrate(&mut grid, &params, &patch, None, &model, &pose).unwrap();
        assert!(stats.blocks_allocated > 0);
        let second = mesh.update(&mut grid);
        assert!(second.blocks_meshed > 0);
        assert!(
            second.blocks_meshed < grid.block_count() / 2,
            "{second:?} of {} blocks",
            grid.block_count()
        );
        assert!(second.triangles > first.triangles);
        let mut scratch = Mesh::new();
        let full = scratch.rebuild(&grid);
        assert_eq!(full.triangles, second.triangles);
        assert_eq!(mesh.blocks.len(), scratch.blocks.len());
        for (index, block) in mesh.blocks() {
            let other = scratch.block(*index).unwrap();
            assert_eq!(block.triangles, other.triangles);
            assert_eq!(block.colours, other.colours);
            for (a, b) in block.vertices.iter().zip(&other.vertices) {
                for k in 0..3 {
                    assert!((a[k] - b[k]).abs() <= 1e-6);
                }
            }
        }
        // Nothing changed: nothing re-meshed; a cleared grid drops the mesh.
        assert_eq!(mesh.update(&mut grid).blocks_meshed, 0);
        grid.clear();
        let empty = mesh.update(&mut grid);
        assert_eq!((empty.triangles, empty.blocks_with_surface), (0, 0));
        let (points, colours) = scratch.to_triangle_list();
        assert_eq!(points.len(), 3 * full.triangles);
        assert_eq!(colours.len(), points.len());
    }
}
