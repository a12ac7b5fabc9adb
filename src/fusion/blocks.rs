//! The sparse voxel grid: blocks of 8x8x8 voxels in a hash map by block index (nvblox's
//! `VoxelBlockLayer`, Open3D's `VoxelBlockGrid`), allocated only where a surface was seen.

use std::collections::{HashMap, HashSet};
use std::hash::{BuildHasherDefault, Hash, Hasher};

use glam::DVec3;

use super::FusionError;

/// Voxels along each side of a block.
pub const BLOCK_SIDE: usize = 8;
/// Voxels in a block.
pub const VOXELS_PER_BLOCK: usize = BLOCK_SIDE * BLOCK_SIDE * BLOCK_SIDE;

/// The integer index of a block: it holds the voxels with global indices
/// `8 * index .. 8 * index + 8` along each axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct BlockIndex(pub [i32; 3]);

impl BlockIndex {
    /// The block holding a voxel of the given global index.
    pub fn of_voxel(voxel: [i64; 3]) -> Self {
        let side = BLOCK_SIDE as i64;
        Self(voxel.map(|v| v.div_euclid(side) as i32))
    }

    /// The global index of this block's voxel `(0, 0, 0)`.
    pub fn first_voxel(&self) -> [i64; 3] {
        self.0.map(|b| i64::from(b) * BLOCK_SIDE as i64)
    }

    /// This index moved by `offset` blocks.
    pub fn offset(&self, offset: [i32; 3]) -> Self {
        Self([
            self.0[0].wrapping_add(offset[0]),
            self.0[1].wrapping_add(offset[1]),
            self.0[2].wrapping_add(offset[2]),
        ])
    }
}

impl Hash for BlockIndex {
    fn hash<H: Hasher>(&self, state: &mut H) {
        // One word per index (exact for |index| < 2^21, i.e. 670 km of 5 cm voxels; beyond it
        // distinct indices may share a word, which a hash map tolerates).
        let [x, y, z] = self.0.map(|v| u64::from(v as u32) & 0x1f_ffff);
        state.write_u64(x | (y << 21) | (z << 42));
    }
}

/// A fast hasher for [`BlockIndex`] keys (splitmix64's finaliser over the one word they
/// write): the integration looks up every block a pixel's ray crosses, and SipHash's
/// resistance to chosen keys buys nothing for grid coordinates.
#[derive(Debug, Default, Clone, Copy)]
pub struct BlockHasher(u64);

impl Hasher for BlockHasher {
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }

    fn write_u64(&mut self, word: u64) {
        self.0 = (self.0.rotate_left(5) ^ word).wrapping_mul(0x9e37_79b9_7f4a_7c15);
    }

    fn finish(&self) -> u64 {
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
}

/// A hash map keyed by block index.
pub type BlockMap<V> = HashMap<BlockIndex, V, BuildHasherDefault<BlockHasher>>;
/// A set of block indices.
pub type BlockSet = HashSet<BlockIndex, BuildHasherDefault<BlockHasher>>;

/// One voxel: the truncated signed distance at its centre (in units of the truncation
/// distance, [-1, 1]), its weight (observations, capped), and its colour with its own weight
/// (colour is only averaged near the surface). 16 bytes; a [`Block`] keeps each field in an
/// array of its own and hands voxels out by value.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Voxel {
    pub tsdf: f32,
    /// Zero: never observed.
    pub weight: f32,
    /// Red, green, blue in 8.8 fixed point (value x 256), so that a running average over up
    /// to [`u16::MAX`] observations keeps moving by fractions of a level.
    colour_fixed: [u16; 3],
    colour_weight: u16,
}

impl Voxel {
    pub const EMPTY: Self = Self {
        tsdf: 0.0,
        weight: 0.0,
        colour_fixed: [0; 3],
        colour_weight: 0,
    };

    /// A voxel from its stored fields (the colour in 8.8 fixed point), as the GPU's pool
    /// (`super::gpu`) keeps them.
    pub(super) fn from_fields(
        tsdf: f32,
        weight: f32,
        colour_fixed: [u16; 3],
        colour_weight: u16,
    ) -> Self {
        Self {
            tsdf,
            weight,
            colour_fixed,
            colour_weight,
        }
    }

    /// Its stored fields, as [`Voxel::from_fields`] takes them.
    pub(super) fn fields(&self) -> (f32, f32, [u16; 3], u16) {
        (
            self.tsdf,
            self.weight,
            self.colour_fixed,
            self.colour_weight,
        )
    }

    /// The averaged colour (black before any colour was seen).
    pub fn colour(&self) -> [u8; 3] {
        self.colour_fixed
            .map(|c| ((u32::from(c) + 128) >> 8).min(255) as u8)
    }

    /// The averaged colour as f32 levels (0..=255), for interpolation.
    pub fn colour_f32(&self) -> [f32; 3] {
        self.colour_fixed.map(|c| f32::from(c) / 256.0)
    }

    /// How many colour observations the colour averages (capped like the weight).
    pub fn colour_weight(&self) -> u16 {
        self.colour_weight
    }

    /// Whether the voxel was ever observed.
    pub fn is_observed(&self) -> bool {
        self.weight > 0.0
    }

    /// One observation of the TSDF (already truncated to [-1, 1]) with weight `weight`: the
    /// running average whose total weight is capped at `max_weight`.
    #[inline(always)]
    pub(super) fn observe_tsdf(&mut self, tsdf: f32, weight: f32, max_weight: f32) {
        (self.tsdf, self.weight) = running_tsdf(self.tsdf, self.weight, tsdf, weight, max_weight);
    }

    /// One observation of the colour with weight 1, averaged like the TSDF.
    #[inline(always)]
    pub(super) fn observe_colour(&mut self, rgb: [u8; 3], max_weight: f32) {
        let rgb = rgb.map(f32::from);
        let (colour, weight) =
            running_colour(self.colour_fixed, self.colour_weight, rgb, max_weight);
        self.colour_fixed = colour;
        self.colour_weight = weight;
    }
}

/// The TSDF's running average: `(tsdf, weight)` after one observation `observed` of weight
/// `observed_weight`, the total weight capped at `max_weight`.
#[inline(always)]
fn running_tsdf(
    tsdf: f32,
    weight: f32,
    observed: f32,
    observed_weight: f32,
    max_weight: f32,
) -> (f32, f32) {
    let total = weight + observed_weight;
    (
        (tsdf * weight + observed * observed_weight) / total,
        total.min(max_weight),
    )
}

/// The colour's running average (8.8 fixed point, rounded): the colour and its count after
/// one observation `rgb` (levels 0..=255 as f32) of weight 1, the count capped at `max_weight`
/// (and `u16::MAX`). One reciprocal for the three channels.
#[inline(always)]
fn running_colour(colour: [u16; 3], count: u16, rgb: [f32; 3], max_weight: f32) -> ([u16; 3], u16) {
    let w = f32::from(count);
    let rcp = 1.0 / (w + 1.0);
    // Rounded (the mean is not negative; the cast saturates at u16::MAX).
    let mean = |c: u16, o: f32| ((f32::from(c) * w + o * 256.0) * rcp + 0.5) as u16;
    let cap = max_weight.clamp(1.0, f32::from(u16::MAX));
    (
        [
            mean(colour[0], rgb[0]),
            mean(colour[1], rgb[1]),
            mean(colour[2], rgb[2]),
        ],
        (w + 1.0).min(cap) as u16,
    )
}

/// A row of [`BLOCK_SIDE`] voxels along x.
type Row<T> = [T; BLOCK_SIDE];
/// Rows in a block.
const ROWS: usize = BLOCK_SIDE * BLOCK_SIDE;

/// What step 2 of the integration observed along one row of a block
/// ([`Block::observe_row`]), lane per voxel.
pub(super) struct RowObservation {
    /// The truncated TSDF observed, in units of the truncation distance.
    pub tsdf: Row<f32>,
    pub weight: Row<f32>,
    /// Which voxels take the TSDF observation: all bits set, or none.
    pub update: Row<u32>,
    /// The colour observed (levels 0..=255).
    pub rgb: [Row<f32>; 3],
    /// Which voxels take the colour observation (a subset of `update`): all bits or none.
    pub update_colour: Row<u16>,
}

/// The voxels of a block, one array per field (structure of arrays), a row of 8 along x at
/// a time, so that the integration updates a row lane-wise.
#[derive(Debug, Clone, PartialEq)]
struct Voxels {
    tsdf: [Row<f32>; ROWS],
    weight: [Row<f32>; ROWS],
    colour: [[Row<u16>; ROWS]; 3],
    colour_weight: [Row<u16>; ROWS],
}

/// 8x8x8 voxels, x fastest, then y, then z ([`Block::voxel_offset`]), stored field by
/// field.
#[derive(Debug, Clone, PartialEq)]
pub struct Block {
    voxels: Box<Voxels>,
}

impl Default for Block {
    fn default() -> Self {
        Self {
            voxels: Box::new(Voxels {
                tsdf: [[0.0; BLOCK_SIDE]; ROWS],
                weight: [[0.0; BLOCK_SIDE]; ROWS],
                colour: [[[0; BLOCK_SIDE]; ROWS]; 3],
                colour_weight: [[0; BLOCK_SIDE]; ROWS],
            }),
        }
    }
}

impl Block {
    /// The place of voxel `(x, y, z)` (each `0..8`) in the block.
    pub const fn voxel_offset(x: usize, y: usize, z: usize) -> usize {
        x + BLOCK_SIDE * (y + BLOCK_SIDE * z)
    }

    /// Voxel `(x, y, z)` (each `0..8`).
    #[inline(always)]
    pub fn voxel(&self, x: usize, y: usize, z: usize) -> Voxel {
        self.voxel_at_offset(Self::voxel_offset(x, y, z))
    }

    /// The voxel at [`Block::voxel_offset`] `offset`.
    #[inline(always)]
    pub fn voxel_at_offset(&self, offset: usize) -> Voxel {
        let (row, x) = (offset / BLOCK_SIDE, offset % BLOCK_SIDE);
        let v = &self.voxels;
        Voxel {
            tsdf: v.tsdf[row][x],
            weight: v.weight[row][x],
            colour_fixed: [
                v.colour[0][row][x],
                v.colour[1][row][x],
                v.colour[2][row][x],
            ],
            colour_weight: v.colour_weight[row][x],
        }
    }

    /// The TSDF and the weight of the row of voxels `(0..8, y, z)`.
    #[inline(always)]
    pub(super) fn tsdf_and_weight_row(&self, y: usize, z: usize) -> (&Row<f32>, &Row<f32>) {
        let row = y + BLOCK_SIDE * z;
        (&self.voxels.tsdf[row], &self.voxels.weight[row])
    }

    /// Writes the voxel at [`Block::voxel_offset`] `offset`.
    #[inline(always)]
    pub(super) fn set_voxel_at_offset(&mut self, offset: usize, voxel: Voxel) {
        let (row, x) = (offset / BLOCK_SIDE, offset % BLOCK_SIDE);
        let v = &mut self.voxels;
        v.tsdf[row][x] = voxel.tsdf;
        v.weight[row][x] = voxel.weight;
        for (c, value) in voxel.colour_fixed.into_iter().enumerate() {
            v.colour[c][row][x] = value;
        }
        v.colour_weight[row][x] = voxel.colour_weight;
    }

    /// One observation of a row of voxels `(0..8, y, z)`, lane-wise: the running averages of
    /// [`Voxel::observe_tsdf`] and [`Voxel::observe_colour`] (the same arithmetic) made for
    /// every lane and kept where `observed.update` (and `observed.update_colour`) say, by
    /// bit masks rather than branches, so that the compiler vectorises them; returns how
    /// many voxels took the TSDF observation.
    #[inline(always)]
    pub(super) fn observe_row(
        &mut self,
        y: usize,
        z: usize,
        observed: &RowObservation,
        max_weight: f32,
    ) -> usize {
        let row = y + BLOCK_SIDE * z;
        let v = &mut *self.voxels;
        let (tsdf, weight) = (&mut v.tsdf[row], &mut v.weight[row]);
        let keep = |new: f32, old: f32, mask: u32| {
            f32::from_bits((new.to_bits() & mask) | (old.to_bits() & !mask))
        };
        for x in 0..BLOCK_SIDE {
            let (t, w) = running_tsdf(
                tsdf[x],
                weight[x],
                observed.tsdf[x],
                observed.weight[x],
                max_weight,
            );
            let mask = observed.update[x];
            tsdf[x] = keep(t, tsdf[x], mask);
            weight[x] = keep(w, weight[x], mask);
        }
        if observed.update_colour.iter().any(|m| *m != 0) {
            let [r, g, b] = &mut v.colour;
            observe_colour_row(
                [&mut r[row], &mut g[row], &mut b[row]],
                &mut v.colour_weight[row],
                observed,
                max_weight,
            );
        }
        observed.update.iter().map(|m| (m & 1) as usize).sum()
    }
}

crate::simd::vectorised_fn! {
/// The colour half of [`Block::observe_row`]: [`running_colour`] lane-wise on a row, where
/// `observed.update_colour` is set. A function of its own (not inlined into the voxel
/// update) so that the compiler vectorises it.
#[inline(never)]
fn observe_colour_row(
    colour: [&mut Row<u16>; 3],
    count: &mut Row<u16>,
    observed: &RowObservation,
    max_weight: f32,
) {
    // `t as u16` for 0 <= t < 2^16 without the saturating cast (which stays scalar).
    let to_u16 = |t: f32| crate::simd::floor_small(t) as u16;
    let cap = max_weight.clamp(1.0, f32::from(u16::MAX));
    let mut w = [0.0f32; BLOCK_SIDE];
    let mut rcp = [0.0f32; BLOCK_SIDE];
    for x in 0..BLOCK_SIDE {
        w[x] = f32::from(count[x]);
        rcp[x] = 1.0 / (w[x] + 1.0);
    }
    let mask = &observed.update_colour;
    for (c, o) in colour.into_iter().zip(&observed.rgb) {
        for x in 0..BLOCK_SIDE {
            // [`running_colour`]'s mean (at most 255 * 256 + 0.5).
            let mean = to_u16((f32::from(c[x]) * w[x] + o[x] * 256.0) * rcp[x] + 0.5);
            c[x] = (mean & mask[x]) | (c[x] & !mask[x]);
        }
    }
    for x in 0..BLOCK_SIDE {
        let n = to_u16((w[x] + 1.0).min(cap));
        count[x] = (n & mask[x]) | (count[x] & !mask[x]);
    }
}
}

/// The blocks of `blocks` beyond the `max_blocks` nearest to `centre_in_world` (0: no limit),
/// which [`VoxelBlockGrid::drop_farthest`] drops: the ones whose centres (blocks of voxels of
/// `voxel_size_m`) lie farthest from it, ties broken by index so that the choice is
/// repeatable. O(n) in the blocks held (a selection, not a sort), and only when over the limit.
pub(super) fn farthest_blocks<V>(
    blocks: &BlockMap<V>,
    max_blocks: usize,
    voxel_size_m: f32,
    centre_in_world: DVec3,
) -> Vec<BlockIndex> {
    if max_blocks == 0 || blocks.len() <= max_blocks {
        return Vec::new();
    }
    farthest_of(
        blocks.keys().copied(),
        max_blocks,
        voxel_size_m,
        centre_in_world,
    )
}

/// [`farthest_blocks`] over any distinct block indices: those beyond the `max_blocks` nearest
/// to `centre_in_world` (0: no limit), in no particular order.
pub(super) fn farthest_of(
    indices: impl Iterator<Item = BlockIndex>,
    max_blocks: usize,
    voxel_size_m: f32,
    centre_in_world: DVec3,
) -> Vec<BlockIndex> {
    let block_m = f64::from(voxel_size_m) * BLOCK_SIDE as f64;
    let half = DVec3::splat(0.5 * block_m - 0.5 * f64::from(voxel_size_m));
    let mut by_distance: Vec<(f64, BlockIndex)> = indices
        .map(|index| {
            let [a, b, c] = index.0.map(f64::from);
            let centre = DVec3::new(a, b, c) * block_m + half;
            (centre.distance_squared(centre_in_world), index)
        })
        .collect();
    if max_blocks == 0 || by_distance.len() <= max_blocks {
        return Vec::new();
    }
    // The `max_blocks` nearest first.
    by_distance.select_nth_unstable_by(max_blocks, |a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    by_distance
        .drain(max_blocks..)
        .map(|(_, index)| index)
        .collect()
}

/// What [`bound_allocation`] settled: the blocks held to drop before allocating, and how many
/// new ones are not allocated.
pub(super) struct AllocationBound {
    pub held: Vec<BlockIndex>,
    pub skipped: usize,
}

/// The memory bound before step 1 allocates: when the blocks `allocated` and `new` together
/// pass `max_blocks` (0: no limit), the ones beyond the `max_blocks` nearest to
/// `centre_in_world` are settled now, as dropping the farthest after the update would settle
/// them ([`VoxelBlockGrid::drop_farthest`]): the new ones among them leave `new` and `in_view`
/// (never allocated), the held ones are returned for the caller to drop before it allocates.
/// So one depth map never makes the grid hold more than `max_blocks`, even for a moment.
pub(super) fn bound_allocation<V>(
    allocated: &BlockMap<V>,
    in_view: &mut BlockSet,
    new: &mut Vec<BlockIndex>,
    max_blocks: usize,
    voxel_size_m: f32,
    centre_in_world: DVec3,
) -> AllocationBound {
    let mut bound = AllocationBound {
        held: Vec::new(),
        skipped: 0,
    };
    if max_blocks == 0 || allocated.len() + new.len() <= max_blocks {
        return bound;
    }
    let all = allocated.keys().copied().chain(new.iter().copied());
    let mut skipped = BlockSet::default();
    for index in farthest_of(all, max_blocks, voxel_size_m, centre_in_world) {
        in_view.remove(&index);
        if allocated.contains_key(&index) {
            bound.held.push(index);
        } else {
            skipped.insert(index);
        }
    }
    new.retain(|index| !skipped.contains(index));
    bound.skipped = skipped.len();
    bound
}

/// The blocks changed and dropped since a consumer last took them (a mesh update:
/// [`super::Mesh::take_changes`]).
#[derive(Debug, Clone, Default)]
pub struct BlockChanges {
    pub changed: BlockSet,
    pub removed: BlockSet,
}

impl BlockChanges {
    /// `index` changed (or was allocated again after a drop).
    pub fn change(&mut self, index: BlockIndex) {
        self.removed.remove(&index);
        self.changed.insert(index);
    }

    /// `index` was dropped.
    pub fn remove(&mut self, index: BlockIndex) {
        self.changed.remove(&index);
        self.removed.insert(index);
    }

    pub fn is_empty(&self) -> bool {
        self.changed.is_empty() && self.removed.is_empty()
    }
}

/// The TSDF grid: blocks by index, the voxel size, and the blocks changed and removed since
/// the last meshing ([`super::Mesh::update`] takes both).
#[derive(Debug, Clone)]
pub struct VoxelBlockGrid {
    voxel_size_m: f32,
    blocks: BlockMap<Block>,
    /// Changed and dropped since the last meshing.
    changes: BlockChanges,
}

impl VoxelBlockGrid {
    /// An empty grid of voxels of `voxel_size_m` metres (finite, positive).
    pub fn new(voxel_size_m: f32) -> Result<Self, FusionError> {
        if !voxel_size_m.is_finite() || voxel_size_m <= 0.0 {
            return Err(FusionError::InvalidParams(format!(
                "voxel_size_m must be finite and positive, not {voxel_size_m}"
            )));
        }
        Ok(Self {
            voxel_size_m,
            blocks: BlockMap::default(),
            changes: BlockChanges::default(),
        })
    }

    pub fn voxel_size_m(&self) -> f32 {
        self.voxel_size_m
    }

    /// The side of a block in metres.
    pub fn block_size_m(&self) -> f32 {
        self.voxel_size_m * BLOCK_SIDE as f32
    }

    /// Number of allocated blocks.
    pub fn block_count(&self) -> usize {
        self.blocks.len()
    }

    pub fn is_empty(&self) -> bool {
        self.blocks.is_empty()
    }

    pub fn block(&self, index: BlockIndex) -> Option<&Block> {
        self.blocks.get(&index)
    }

    pub fn contains(&self, index: BlockIndex) -> bool {
        self.blocks.contains_key(&index)
    }

    /// Every block, in no particular order.
    pub fn blocks(&self) -> impl Iterator<Item = (&BlockIndex, &Block)> {
        self.blocks.iter()
    }

    /// The global index of the voxel whose centre is nearest to a world point.
    pub fn voxel_index_of(&self, point_in_world: DVec3) -> [i64; 3] {
        let scaled = point_in_world / f64::from(self.voxel_size_m);
        [scaled.x, scaled.y, scaled.z].map(|v| v.round() as i64)
    }

    /// The centre of a voxel in the world frame.
    pub fn voxel_centre(&self, voxel: [i64; 3]) -> DVec3 {
        let s = f64::from(self.voxel_size_m);
        DVec3::new(voxel[0] as f64, voxel[1] as f64, voxel[2] as f64) * s
    }

    /// The voxel of a global index, if its block is allocated.
    pub fn voxel(&self, voxel: [i64; 3]) -> Option<Voxel> {
        let block_index = BlockIndex::of_voxel(voxel);
        let block = self.blocks.get(&block_index)?;
        let first = block_index.first_voxel();
        let [x, y, z] = [0, 1, 2].map(|a| (voxel[a] - first[a]) as usize);
        Some(block.voxel(x, y, z))
    }

    /// The voxel whose centre is nearest to a world point, if its block is allocated.
    pub fn voxel_at(&self, point_in_world: DVec3) -> Option<Voxel> {
        self.voxel(self.voxel_index_of(point_in_world))
    }

    /// The memory the blocks hold, in bytes (voxels plus the hash map's entries; the
    /// allocator's own overhead is not counted).
    pub fn memory_bytes(&self) -> usize {
        let per_block = std::mem::size_of::<Voxels>();
        let per_entry = std::mem::size_of::<(BlockIndex, Block)>() + 1;
        self.blocks.len() * per_block
            + self.blocks.capacity() * per_entry
            + (self.changes.changed.capacity() + self.changes.removed.capacity())
                * (std::mem::size_of::<BlockIndex>() + 1)
    }

    /// Drops every block (a later [`super::Mesh::update`] drops their meshes).
    pub fn clear(&mut self) {
        for index in self.blocks.keys() {
            self.changes.remove(*index);
        }
        self.blocks.clear();
    }

    /// Keeps at most `max_blocks` blocks (0: no limit): when there are more, drops the ones
    /// whose centres lie farthest from `centre_in_world` (the latest camera centre), for good:
    /// what they held is forgotten, and a block seen again later starts empty. Returns how many
    /// were dropped; they join [`Self::removed_blocks`]. O(n) in the blocks held (a selection,
    /// not a sort), and only when over the limit.
    pub fn drop_farthest(&mut self, max_blocks: usize, centre_in_world: DVec3) -> usize {
        let dropped = farthest_blocks(&self.blocks, max_blocks, self.voxel_size_m, centre_in_world);
        for index in &dropped {
            self.remove_block(*index);
        }
        dropped.len()
    }

    /// Drops one block (it joins [`Self::removed_blocks`]).
    pub(super) fn remove_block(&mut self, index: BlockIndex) {
        self.blocks.remove(&index);
        self.changes.remove(index);
    }

    /// Allocates an empty block at `index` (as the integration allocates them, not marked
    /// changed).
    pub(super) fn insert_empty_block(&mut self, index: BlockIndex) {
        self.blocks.insert(index, Block::default());
        self.changes.removed.remove(&index);
    }

    /// Puts a block in (replacing the one at `index`) and marks it changed.
    pub(super) fn insert_block(&mut self, index: BlockIndex, block: Block) {
        self.blocks.insert(index, block);
        self.changes.change(index);
    }

    /// The blocks dropped ([`Self::drop_farthest`], [`Self::clear`]) since the last meshing.
    pub fn removed_blocks(&self) -> &BlockSet {
        &self.changes.removed
    }

    /// The blocks changed since the last meshing.
    pub fn changed_blocks(&self) -> &BlockSet {
        &self.changes.changed
    }

    /// Marks every block changed (the next [`super::Mesh::update`] re-meshes all).
    pub fn mark_all_changed(&mut self) {
        self.changes.changed = self.blocks.keys().copied().collect();
    }

    /// The blocks changed and removed since the last call (then none).
    pub(super) fn take_changes(&mut self) -> BlockChanges {
        std::mem::take(&mut self.changes)
    }

    pub(super) fn mark_changed(&mut self, index: BlockIndex) {
        self.changes.change(index);
    }

    pub(super) fn blocks_map(&self) -> &BlockMap<Block> {
        &self.blocks
    }

    pub(super) fn blocks_map_mut(&mut self) -> &mut BlockMap<Block> {
        &mut self.blocks
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn voxel_and_block_indices_round_to_the_nearest_centre_and_floor_to_blocks() {
        let grid = VoxelBlockGrid::new(0.05).unwrap();
        assert_eq!(
            grid.voxel_index_of(DVec3::new(0.024, -0.026, 0.4)),
            [0, -1, 8]
        );
        assert_eq!(BlockIndex::of_voxel([0, -1, 8]), BlockIndex([0, -1, 1]));
        assert_eq!(BlockIndex::of_voxel([-8, -9, 7]), BlockIndex([-1, -2, 0]));
        assert_eq!(BlockIndex([-1, 2, 0]).first_voxel(), [-8, 16, 0]);
        assert!(grid.voxel_at(DVec3::ZERO).is_none());
        assert!(VoxelBlockGrid::new(0.0).is_err());
        assert!(VoxelBlockGrid::new(f32::NAN).is_err());
    }

    #[test]
    fn running_averages_are_capped_and_keep_moving() {
        let mut v = Voxel::EMPTY;
        for _ in 0..100 {
            v.observe_tsdf(-1.0, 1.0, 4.0);
            v.observe_colour([200, 10, 0], 4.0);
        }
        assert_eq!(v.weight, 4.0);
        assert_eq!(v.colour_weight(), 4);
        assert!((v.tsdf + 1.0).abs() < 1e-6);
        assert_eq!(v.colour(), [200, 10, 0]);
        // Capped at 4: one new observation moves the mean by a fifth of the difference.
        v.observe_tsdf(1.0, 1.0, 4.0);
        assert!((v.tsdf - (-1.0 + 2.0 / 5.0)).abs() < 1e-6);
        // With a cap of 64, a level-1 difference still moves the 8.8 fixed-point colour.
        let mut c = Voxel::EMPTY;
        for _ in 0..64 {
            c.observe_colour([100, 100, 100], 64.0);
        }
        for _ in 0..200 {
            c.observe_colour([101, 101, 101], 64.0);
        }
        assert_eq!(c.colour(), [101, 101, 101]);
        assert_eq!(std::mem::size_of::<Voxel>(), 16);
    }

    #[test]
    fn clear_drops_blocks_and_memory_counts_them() {
        let mut grid = VoxelBlockGrid::new(0.05).unwrap();
        for i in 0..10 {
            grid.blocks_map_mut()
                .insert(BlockIndex([i, 0, 0]), Block::default());
            grid.mark_changed(BlockIndex([i, 0, 0]));
        }
        assert_eq!(grid.block_count(), 10);
        assert!(grid.memory_bytes() >= 10 * 512 * 16);
        assert!(grid.voxel([79, 7, 7]).is_some());
        assert!(grid.voxel([80, 0, 0]).is_none());
        grid.clear();
        assert!(grid.is_empty());
        assert!(grid.changed_blocks().is_empty());
        assert_eq!(grid.removed_blocks().len(), 10);
    }

    #[test]
    fn drop_farthest_keeps_the_nearest_blocks() {
        let mut grid = VoxelBlockGrid::new(0.05).unwrap();
        for i in -5..10 {
            grid.blocks_map_mut()
                .insert(BlockIndex([i, 0, 0]), Block::default());
            grid.mark_changed(BlockIndex([i, 0, 0]));
        }
        // Nothing to drop under the limit, or without one.
        assert_eq!(grid.drop_farthest(0, DVec3::ZERO), 0);
        assert_eq!(grid.drop_farthest(15, DVec3::ZERO), 0);
        // Around block 3 (x from 1.2 to 1.6 m): blocks 1..=5 are the five nearest.
        assert_eq!(grid.drop_farthest(5, DVec3::new(1.4, 0.2, 0.2)), 10);
        let mut kept: Vec<i32> = grid.blocks().map(|(index, _)| index.0[0]).collect();
        kept.sort_unstable();
        assert_eq!(kept, vec![1, 2, 3, 4, 5]);
        assert_eq!(grid.removed_blocks().len(), 10);
        assert!(grid.removed_blocks().iter().all(|i| !grid.contains(*i)));
        assert!(grid.changed_blocks().iter().all(|i| grid.contains(*i)));
        assert_eq!(grid.changed_blocks().len(), 5);
    }
}
