//! TSDF integration on a wgpu device (issue 56), the twin of [`super::integrate_weighted`]:
//! the same checks; step 0 (each pixel's valid depth, cos² observation weight and colour) on
//! the device for a pinhole camera (`gpu/samples.rs`, `shaders/tsdf_samples.wgsl`; the host
//! validates the depths only, which step 1 reads), with the CPU's code for a distorted one;
//! step 1 (the blocks the truncation band crosses, and those allocated inside the view) on the
//! host with the CPU's own code; step 2, the projective update of every voxel of those blocks,
//! in `shaders/tsdf_integrate.wgsl`, one workgroup per block.
//!
//! The voxels live on the device in a pool of slots of [`VOXELS_PER_BLOCK`] voxels (16 bytes
//! each, as [`Voxel`] keeps them), grown by doubling up to the adapter's largest storage
//! buffer; the block hash stays on the host (a map from [`BlockIndex`] to slot): step 1 reads
//! it, and a frame uploads its depth map (colour, weights) or samples and the list of (block
//! origin, slot) to update.
//! [`GpuTsdf::sync_into`] copies the blocks changed since the last call into a
//! [`VoxelBlockGrid`] (the map's host copy), [`GpuTsdf::read_grid`] all of them;
//! [`GpuTsdf::mesh_blocks`] (`gpu/mesh.rs`) meshes blocks on the device.

use bytemuck::{Pod, Zeroable};

use self::camera::{gpu_camera, GpuCamera};
use self::device::{compute_pipeline, dispatch_items, make_buffer, read_buffer, submit, Grown};
use self::samples::Samples;
use super::blocks::{
    bound_allocation, farthest_blocks, Block, BlockChanges, BlockIndex, BlockMap, BlockSet, Voxel,
};
use super::integrate::{
    blocks_to_update, prepare, FrameInput, IntegrationScratch, PixelSample, Projector,
};
use super::{
    DepthView, FusionError, FusionParams, GpuIntegrationTimes, IntegrationStats, VoxelBlockGrid,
    VOXELS_PER_BLOCK,
};
use crate::image::ImageF32;

/// The shader: `camera.wgsl` (the camera struct and its projection with distortion, as the
/// sweep's stages use it), the pool's voxel and the integration.
const SHADER: &str = concat!(
    include_str!("../../shaders/camera.wgsl"),
    "\n",
    include_str!("../../shaders/tsdf_voxel.wgsl"),
    "\n",
    include_str!("../../shaders/tsdf_integrate.wgsl")
);

/// Bytes of one voxel in the pool.
const VOXEL_BYTES: u64 = std::mem::size_of::<PoolVoxel>() as u64;
/// Bytes of one slot.
const SLOT_BYTES: u64 = VOXEL_BYTES * VOXELS_PER_BLOCK as u64;
/// The pool's first size, in slots (grown by doubling).
const FIRST_SLOTS: u32 = 1024;

/// WGSL `TsdfParams`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct TsdfUniform {
    camera: GpuCamera,
    step_x: [f32; 4],
    step_y: [f32; 4],
    step_z: [f32; 4],
    truncation_m: f32,
    inv_truncation: f32,
    max_weight: f32,
    colour: u32,
    items: u32,
    pad: [u32; 3],
}

/// WGSL `Work`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct GpuWork {
    origin: [f32; 3],
    slot: u32,
}

/// WGSL `PoolVoxel`: a [`Voxel`]'s fields, the colour's 16-bit halves in pairs.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct PoolVoxel {
    tsdf: f32,
    weight: f32,
    rg: u32,
    b_count: u32,
}

impl PoolVoxel {
    fn from_voxel(voxel: Voxel) -> Self {
        let (tsdf, weight, [r, g, b], count) = voxel.fields();
        Self {
            tsdf,
            weight,
            rg: u32::from(r) | (u32::from(g) << 16),
            b_count: u32::from(b) | (u32::from(count) << 16),
        }
    }

    fn voxel(&self) -> Voxel {
        let low = |w: u32| (w & 0xffff) as u16;
        let high = |w: u32| (w >> 16) as u16;
        Voxel::from_fields(
            self.tsdf,
            self.weight,
            [low(self.rg), high(self.rg), low(self.b_count)],
            high(self.b_count),
        )
    }
}

/// Why the GPU integration refused its input or failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GpuFusionError {
    #[error(transparent)]
    Fusion(#[from] FusionError),
    #[error(
        "the GPU's voxel pool cannot hold {blocks} blocks ({bytes} bytes): the adapter's largest \
         storage buffer is {limit} bytes (lower FusionParams::max_blocks or raise the voxel size)"
    )]
    PoolFull {
        blocks: usize,
        bytes: u64,
        limit: u64,
    },
    #[error(
        "the {what} of a {width}x{height} depth map ({bytes} bytes) exceeds the adapter's largest \
         storage buffer ({limit} bytes)"
    )]
    TooLarge {
        what: &'static str,
        width: u32,
        height: u32,
        bytes: u64,
        limit: u64,
    },
    #[error("GPU fusion: {0}")]
    Gpu(String),
}

/// The blocks of a TSDF grid on a wgpu device, integrated by `shaders/tsdf_integrate.wgsl`:
/// [`GpuTsdf::integrate`] is [`super::integrate_weighted`] with the voxels on the device
/// (the same blocks, the same arithmetic; on a CPU adapter the same values to float rounding).
pub struct GpuTsdf {
    device: wgpu::Device,
    queue: wgpu::Queue,
    params: FusionParams,
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    uniform: wgpu::Buffer,
    /// The voxels, [`SLOT_BYTES`] per slot.
    pool: wgpu::Buffer,
    samples: Grown,
    /// Step 0 on the device (pinhole cameras).
    sample_stage: samples::SampleStage,
    work: Grown,
    /// Voxels updated per work item, and its copy for the host.
    counts: Grown,
    counts_readback: Grown,
    /// The largest buffer the adapter binds, in bytes.
    limit: u64,
    /// Block to slot.
    slots: BlockMap<u32>,
    /// Slots of dropped blocks, to reuse (cleared first).
    free: Vec<u32>,
    /// Slots handed out so far (the pool's high-water mark).
    next_slot: u32,
    /// Changed and dropped since the last [`GpuTsdf::sync_into`].
    unsynced: BlockChanges,
    /// Allocated since the last [`GpuTsdf::sync_into`] (empty until updated).
    allocated: BlockSet,
    /// Changed and dropped since the last [`GpuTsdf::take_unmeshed`] (a mesh update's).
    unmeshed: BlockChanges,
    scratch: IntegrationScratch,
    /// The meshing pipeline (`gpu/mesh.rs`), made when first asked to mesh.
    mesher: Option<mesh::Mesher>,
    /// Where the last integration's time went.
    last_times: GpuIntegrationTimes,
}

impl std::fmt::Debug for GpuTsdf {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "GpuTsdf({} blocks, {} slots)",
            self.slots.len(),
            self.pool_slots()
        )
    }
}

impl GpuTsdf {
    /// An empty grid with `params` (checked) on `device`.
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        params: FusionParams,
    ) -> Result<Self, GpuFusionError> {
        params.validate()?;
        use self::device::Binding::{Read, ReadWrite, Uniform};
        let (pipeline, layout) = compute_pipeline(
            device,
            "tsdf_integrate",
            SHADER,
            "integrate",
            &[Uniform, Read, Read, ReadWrite, ReadWrite],
        )?;
        let limits = device.limits();
        let limit = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        let storage_usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        let first_slots = FIRST_SLOTS.min((limit / SLOT_BYTES).max(1) as u32);
        Ok(Self {
            device: device.clone(),
            queue: queue.clone(),
            params,
            pipeline,
            layout,
            uniform: make_buffer(
                device,
                "tsdf params",
                std::mem::size_of::<TsdfUniform>() as u64,
                wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            ),
            pool: make_buffer(
                device,
                "tsdf pool",
                pool_usage_size(first_slots),
                pool_usage(),
            ),
            samples: Grown::new(device, "tsdf samples", storage_usage),
            sample_stage: samples::SampleStage::new(device)?,
            work: Grown::new(device, "tsdf work", storage_usage),
            counts: Grown::new(
                device,
                "tsdf counts",
                wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            ),
            counts_readback: Grown::new(
                device,
                "tsdf counts readback",
                wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            ),
            limit,
            slots: BlockMap::default(),
            free: Vec::new(),
            next_slot: 0,
            unsynced: BlockChanges::default(),
            allocated: BlockSet::default(),
            unmeshed: BlockChanges::default(),
            scratch: IntegrationScratch::default(),
            mesher: None,
            last_times: GpuIntegrationTimes::default(),
        })
    }

    /// A map on `device` holding every block of `grid` (of `params`' voxel size), as if
    /// integrated there: a map that left a lost device for the CPU goes back onto a new one.
    /// Its record of changes starts empty (`grid`'s are its own).
    pub fn from_grid(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        params: FusionParams,
        grid: &VoxelBlockGrid,
    ) -> Result<Self, GpuFusionError> {
        let voxel_size_m = params.voxel_size_m;
        if (grid.voxel_size_m() - voxel_size_m).abs() > 1e-6 * voxel_size_m {
            return Err(FusionError::VoxelSizeMismatch {
                params_m: voxel_size_m,
                grid_m: grid.voxel_size_m(),
            }
            .into());
        }
        let mut tsdf = Self::new(device, queue, params)?;
        let blocks: Vec<(&BlockIndex, &Block)> = grid.blocks().collect();
        // The pool is empty: nothing of the old one to copy.
        tsdf.grow_for(blocks.len())?;
        // A few thousand blocks (8 KiB each) at a time.
        const PIECE: usize = 4096;
        for (piece, chunk) in blocks.chunks(PIECE).enumerate() {
            let first = piece * PIECE;
            let mut voxels = Vec::with_capacity(chunk.len() * VOXELS_PER_BLOCK);
            for (i, (index, block)) in chunk.iter().enumerate() {
                tsdf.slots.insert(**index, (first + i) as u32);
                voxels.extend(
                    (0..VOXELS_PER_BLOCK).map(|o| PoolVoxel::from_voxel(block.voxel_at_offset(o))),
                );
            }
            let at = first as u64 * SLOT_BYTES;
            queue.write_buffer(&tsdf.pool, at, bytemuck::cast_slice(&voxels));
        }
        tsdf.next_slot = blocks.len() as u32;
        {
            let _poll = crate::gpu_context::device_poll_lock();
            queue.submit([]);
        }
        Ok(tsdf)
    }

    pub fn params(&self) -> &FusionParams {
        &self.params
    }

    /// Blocks allocated.
    pub fn block_count(&self) -> usize {
        self.slots.len()
    }

    pub fn contains(&self, index: BlockIndex) -> bool {
        self.slots.contains_key(&index)
    }

    /// Every allocated block, in no particular order.
    pub fn block_indices(&self) -> impl Iterator<Item = &BlockIndex> {
        self.slots.keys()
    }

    /// The blocks changed since the last [`GpuTsdf::sync_into`].
    pub fn changed_blocks(&self) -> &BlockSet {
        &self.unsynced.changed
    }

    /// The blocks changed and dropped since the last call, whatever was copied to the host
    /// since: what a mesh update meshes again ([`crate::fusion::Mesh::take_changes`], then
    /// [`GpuTsdf::mesh_blocks`]).
    pub fn take_unmeshed(&mut self) -> BlockChanges {
        std::mem::take(&mut self.unmeshed)
    }

    /// Where the last [`Self::integrate`] spent its time: the host's steps and its wait for
    /// the device (its work and the readback of the voxels updated per block).
    pub fn last_times(&self) -> GpuIntegrationTimes {
        self.last_times
    }

    /// The device memory the voxel pool holds, in bytes.
    pub fn pool_bytes(&self) -> u64 {
        self.pool.size()
    }

    fn pool_slots(&self) -> u64 {
        self.pool.size() / SLOT_BYTES
    }

    /// [`super::Mapper::integrate_weighted`] on the device: one depth map with its colour
    /// (the view's confidence and baseline are not read) and its pixels' weights (None:
    /// alike). Refuses what the CPU refuses, and a frame whose blocks the pool cannot hold
    /// within the adapter's largest buffer (nothing changed then). Waits for the device (the
    /// stats count what the shader updated).
    pub fn integrate(
        &mut self,
        view: &DepthView<'_>,
        weights: Option<&ImageF32>,
    ) -> Result<IntegrationStats, GpuFusionError> {
        let (depth, model) = (view.depth, view.model);
        let frame = FrameInput {
            depth,
            weights,
            colour: view.colour,
            model,
            world_from_cam: view.map_from_cam,
            samples_on_device: true,
        };
        let started = std::time::Instant::now();
        let voxel_size_m = self.params.voxel_size_m;
        let (view, pose) = prepare(voxel_size_m, &mut self.scratch, &self.params, &frame)?;
        let (width, height) = (depth.width, depth.height);
        // A pinhole camera's samples made on the device (`gpu/samples.rs`), a distorted
        // one's by the CPU as they are (the shader reads their NaNs as bits).
        let samples = match view.projector {
            Projector::Pinhole { fx, fy, cx, cy } => Samples::Device(samples::SampleInput {
                depth,
                colour: view.colour,
                weights,
                intrinsics: [fx, fy, cx, cy],
                truncation_m: view.truncation_m,
                depth_range_m: [self.params.min_depth_m, self.params.max_depth_m],
            }),
            Projector::Distorted(..) => Samples::Host(view.samples.as_slice()),
        };
        let sample_bytes = (depth.data.len() * std::mem::size_of::<PixelSample>()) as u64;
        if sample_bytes > self.limit {
            return Err(GpuFusionError::TooLarge {
                what: "samples",
                width,
                height,
                bytes: sample_bytes,
                limit: self.limit,
            });
        }
        let samples_done = std::time::Instant::now();
        // Step 1 on the host map; the pool grown before anything is changed.
        let (mut in_view, mut new) = blocks_to_update(&view, &self.slots, &pose);
        // The memory bound settled before the pool grows, as the CPU's.
        let bound = bound_allocation(
            &self.slots,
            &mut in_view,
            &mut new,
            self.params.max_blocks,
            voxel_size_m,
            pose.translation,
        );
        for index in &bound.held {
            self.drop_block(*index);
        }
        let fresh = new.len().saturating_sub(self.free.len());
        let grown = self.grow_for(self.next_slot as usize + fresh)?;
        let mut reused = Vec::new();
        for index in &new {
            let slot = match self.free.pop() {
                Some(slot) => {
                    reused.push(slot);
                    slot
                }
                None => {
                    self.next_slot += 1;
                    self.next_slot - 1
                }
            };
            self.slots.insert(*index, slot);
            self.allocated.insert(*index);
        }
        let blocks_peak = self.slots.len();
        let blocks_done = std::time::Instant::now();
        let mut order: Vec<BlockIndex> = in_view.into_iter().collect();
        // In index order, as the CPU: neighbouring blocks read neighbouring pixels.
        order.sort_unstable();
        let work: Vec<GpuWork> = order
            .iter()
            .filter_map(|index| {
                let slot = *self.slots.get(index)?;
                Some(GpuWork {
                    origin: view.block_origin_in_cam(*index).to_array(),
                    slot,
                })
            })
            .collect();
        let uniform = TsdfUniform {
            camera: gpu_camera(&view.projector, model),
            step_x: extend(view.voxel_steps_in_cam.x_axis.to_array()),
            step_y: extend(view.voxel_steps_in_cam.y_axis.to_array()),
            step_z: extend(view.voxel_steps_in_cam.z_axis.to_array()),
            truncation_m: view.truncation_m,
            inv_truncation: 1.0 / view.truncation_m,
            max_weight: view.max_weight,
            colour: u32::from(view.colour.is_some()),
            items: work.len() as u32,
            pad: [0; 3],
        };
        let (pixels_valid, work_done) = (view.pixels_valid, std::time::Instant::now());
        let counts = self.run(&uniform, &samples, &work, &reused, grown);
        let marks = [
            started,
            samples_done,
            blocks_done,
            work_done,
            std::time::Instant::now(),
        ];
        self.last_times = GpuIntegrationTimes::from_marks(marks, self.last_times.wait);
        self.scratch = view.into_scratch();
        let counts = counts?;
        let mut stats = IntegrationStats {
            pixels_valid,
            blocks_allocated: new.len(),
            blocks_in_view: work.len(),
            blocks_peak,
            ..IntegrationStats::default()
        };
        for (index, &count) in order.iter().zip(&counts) {
            if count > 0 {
                stats.blocks_updated += 1;
                stats.voxels_updated += count as usize;
                self.unsynced.change(*index);
                self.unmeshed.change(*index);
            }
        }
        // The memory bound (settled above; this drops nothing more), as the CPU's.
        let dropped = farthest_blocks(
            &self.slots,
            self.params.max_blocks,
            voxel_size_m,
            pose.translation,
        );
        for index in &dropped {
            self.drop_block(*index);
        }
        stats.blocks_dropped = bound.held.len() + bound.skipped + dropped.len();
        Ok(stats)
    }

    /// Drops one block: its slot is free for the next, its changes forgotten.
    fn drop_block(&mut self, index: BlockIndex) {
        if let Some(slot) = self.slots.remove(&index) {
            self.free.push(slot);
        }
        self.allocated.remove(&index);
        self.unsynced.remove(index);
        self.unmeshed.remove(index);
    }

    /// Makes the pool hold `slots` slots (doubling), or says it cannot; returns the old pool
    /// when it was replaced (its contents still to be copied).
    fn grow_for(&mut self, slots: usize) -> Result<Option<wgpu::Buffer>, GpuFusionError> {
        let have = self.pool_slots();
        if slots as u64 <= have {
            return Ok(None);
        }
        let bytes = slots as u64 * SLOT_BYTES;
        let max_slots = self.limit / SLOT_BYTES;
        if slots as u64 > max_slots {
            return Err(GpuFusionError::PoolFull {
                blocks: slots,
                bytes,
                limit: self.limit,
            });
        }
        let mut size = have.max(1);
        while size < slots as u64 {
            size *= 2;
        }
        let size = size.min(max_slots) as u32;
        let bigger = make_buffer(
            &self.device,
            "tsdf pool",
            pool_usage_size(size),
            pool_usage(),
        );
        Ok(Some(std::mem::replace(&mut self.pool, bigger)))
    }

    /// Uploads a frame, copies the old pool into a grown one, clears reused slots, runs the
    /// shader and returns the voxels updated per work item.
    fn run(
        &mut self,
        uniform: &TsdfUniform,
        samples: &Samples<'_>,
        work: &[GpuWork],
        reused: &[u32],
        old_pool: Option<wgpu::Buffer>,
    ) -> Result<Vec<u32>, GpuFusionError> {
        self.last_times.wait = std::time::Duration::ZERO;
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let count_bytes = (work.len().max(1) * 4) as u64;
        let (device, limit) = (&self.device, self.limit);
        let pixels = match samples {
            Samples::Host(samples) => samples.len(),
            Samples::Device(input) => input.depth.data.len(),
        };
        self.samples.reserve(
            device,
            (pixels * std::mem::size_of::<PixelSample>()) as u64,
            limit,
        );
        let work_bytes = std::mem::size_of_val(work).max(16) as u64;
        self.work.reserve(device, work_bytes, limit);
        self.counts.reserve(device, count_bytes, limit);
        self.counts_readback.reserve(device, count_bytes, limit);
        self.queue
            .write_buffer(&self.uniform, 0, bytemuck::bytes_of(uniform));
        if !work.is_empty() {
            self.queue
                .write_buffer(&self.work.buffer, 0, bytemuck::cast_slice(work));
        }
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("tsdf integrate"),
            });
        match samples {
            Samples::Host(samples) => {
                let bytes = bytemuck::cast_slice(samples);
                self.queue.write_buffer(&self.samples.buffer, 0, bytes);
            }
            Samples::Device(input) => {
                let (stage, buffer) = (&mut self.sample_stage, &self.samples.buffer);
                stage.record(device, &self.queue, &mut encoder, input, buffer, limit);
            }
        }
        if let Some(old) = &old_pool {
            encoder.copy_buffer_to_buffer(old, 0, &self.pool, 0, old.size());
        }
        for &slot in reused {
            encoder.clear_buffer(&self.pool, u64::from(slot) * SLOT_BYTES, Some(SLOT_BYTES));
        }
        if !work.is_empty() {
            let bind_group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("tsdf integrate"),
                layout: &self.layout,
                entries: &[
                    entry(0, &self.uniform),
                    entry(1, &self.samples.buffer),
                    entry(2, &self.work.buffer),
                    entry(3, &self.pool),
                    entry(4, &self.counts.buffer),
                ],
            });
            let items = work.len() as u32;
            dispatch_items(
                &mut encoder,
                "tsdf integrate",
                &self.pipeline,
                &bind_group,
                items,
            );
            encoder.copy_buffer_to_buffer(
                &self.counts.buffer,
                0,
                &self.counts_readback.buffer,
                0,
                count_bytes,
            );
        }
        let submitted = submit(&self.queue, encoder.finish());
        if let Some(error) = futures::executor::block_on(scope.pop()) {
            return Err(GpuFusionError::Gpu(format!("integration: {error}")));
        }
        if work.is_empty() {
            return Ok(Vec::new());
        }
        let readback = &self.counts_readback.buffer;
        let started = std::time::Instant::now();
        let words = read_buffer(&self.device, submitted, readback, count_bytes);
        self.last_times.wait = started.elapsed();
        let words: Vec<u32> = words?;
        Ok(words.into_iter().take(work.len()).collect())
    }

    /// The voxels of `indices` (allocated blocks; others are skipped) from the device.
    fn read_blocks(
        &self,
        indices: &[BlockIndex],
    ) -> Result<Vec<(BlockIndex, Block)>, GpuFusionError> {
        let present: Vec<(BlockIndex, u32)> = indices
            .iter()
            .filter_map(|index| self.slots.get(index).map(|slot| (*index, *slot)))
            .collect();
        if present.is_empty() {
            return Ok(Vec::new());
        }
        // In pieces no larger than the largest buffer.
        let per_piece = (self.limit / SLOT_BYTES).max(1) as usize;
        let mut out = Vec::with_capacity(present.len());
        for piece in present.chunks(per_piece) {
            let bytes = piece.len() as u64 * SLOT_BYTES;
            let staging = make_buffer(
                &self.device,
                "tsdf readback",
                bytes,
                wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            );
            let mut encoder = self
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("tsdf readback"),
                });
            for (i, (_, slot)) in piece.iter().enumerate() {
                encoder.copy_buffer_to_buffer(
                    &self.pool,
                    u64::from(*slot) * SLOT_BYTES,
                    &staging,
                    i as u64 * SLOT_BYTES,
                    SLOT_BYTES,
                );
            }
            let submitted = submit(&self.queue, encoder.finish());
            let voxels: Vec<PoolVoxel> = read_buffer(&self.device, submitted, &staging, bytes)?;
            for ((index, _), slot) in piece.iter().zip(voxels.chunks_exact(VOXELS_PER_BLOCK)) {
                let mut block = Block::default();
                for (offset, voxel) in slot.iter().enumerate() {
                    block.set_voxel_at_offset(offset, voxel.voxel());
                }
                out.push((*index, block));
            }
        }
        Ok(out)
    }

    /// Brings `grid` (of the same voxel size) up to date: the blocks changed since the last
    /// call copied from the device (and marked changed in `grid`, for
    /// [`super::Mesh::update`]), those allocated and not updated added empty (as the CPU's
    /// integration leaves them), the blocks dropped since removed. Returns how many blocks
    /// were copied.
    pub fn sync_into(&mut self, grid: &mut VoxelBlockGrid) -> Result<usize, GpuFusionError> {
        let voxel_size_m = self.params.voxel_size_m;
        if (grid.voxel_size_m() - voxel_size_m).abs() > 1e-6 * voxel_size_m {
            return Err(FusionError::VoxelSizeMismatch {
                params_m: voxel_size_m,
                grid_m: grid.voxel_size_m(),
            }
            .into());
        }
        let mut changed: Vec<BlockIndex> = self.unsynced.changed.iter().copied().collect();
        changed.sort_unstable();
        let blocks = self.read_blocks(&changed)?;
        let copied = blocks.len();
        let BlockChanges { changed, removed } = std::mem::take(&mut self.unsynced);
        for index in removed {
            grid.remove_block(index);
        }
        for index in self.allocated.drain() {
            if !changed.contains(&index) {
                grid.insert_empty_block(index);
            }
        }
        for (index, block) in blocks {
            grid.insert_block(index, block);
        }
        Ok(copied)
    }

    /// Every block as a new [`VoxelBlockGrid`] (all marked changed).
    pub fn read_grid(&self) -> Result<VoxelBlockGrid, GpuFusionError> {
        let mut grid = VoxelBlockGrid::new(self.params.voxel_size_m)?;
        let mut all: Vec<BlockIndex> = self.slots.keys().copied().collect();
        all.sort_unstable();
        for (index, block) in self.read_blocks(&all)? {
            grid.insert_block(index, block);
        }
        Ok(grid)
    }

    /// Drops every block (the pool keeps its size; a later [`GpuTsdf::sync_into`] removes
    /// them from its grid).
    pub fn clear(&mut self) {
        for (index, slot) in self.slots.drain() {
            self.free.push(slot);
            self.unsynced.remove(index);
            self.unmeshed.remove(index);
        }
        self.allocated.clear();
    }
}

fn entry(binding: u32, buffer: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry {
        binding,
        resource: buffer.as_entire_binding(),
    }
}

fn pool_usage() -> wgpu::BufferUsages {
    wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST
}

fn pool_usage_size(slots: u32) -> u64 {
    u64::from(slots.max(1)) * SLOT_BYTES
}

fn extend(v: [f32; 3]) -> [f32; 4] {
    [v[0], v[1], v[2], 0.0]
}

mod camera;
mod device;
mod mesh;
mod samples;
#[cfg(test)]
pub(crate) mod tests;
