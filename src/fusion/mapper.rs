//! The map, as nvblox's `Mapper`: the block TSDF grid, how depth maps are weighed, the
//! integration's per-pixel buffers (kept from one depth map to the next) and the mesh of the
//! surface. One sequence for everything that fuses depth: the node's and `bag`'s fusion thread
//! (`pipeline/fuser.rs`), `eval --fusion` and `bench --fusion`.

use std::time::{Duration, Instant};

use super::gpu::{GpuFusionError, GpuTsdf};
use super::integrate::{integrate_into, IntegrationScratch};
use super::mesh::mesh_on_cpu;
use super::{
    observation_weights, BlockMesh, FusionError, FusionParams, IntegrationStats, Mesh, MeshStats,
    VoxelBlockGrid, Weighting,
};
use crate::geometry::{CameraModel, RigidTransform};
use crate::image::{ImageF32, Rgba8Image};

/// One depth map to fuse: its camera and pose in the map's frame, and what weighs its pixels.
#[derive(Debug, Clone, Copy)]
pub struct DepthView<'a> {
    /// z along the optical axis, metres, NaN invalid (REP 118).
    pub depth: &'a ImageF32,
    /// The engine's confidence per pixel (None: depth from elsewhere).
    pub confidence: Option<&'a ImageF32>,
    /// Its reference's baseline over the largest of its set's (None: not known).
    pub baseline_ratio: Option<f32>,
    /// The reference image, for the voxels' colour.
    pub colour: Option<&'a Rgba8Image>,
    pub model: &'a CameraModel,
    pub map_from_cam: &'a RigidTransform,
}

/// How often a map on a GPU copies the blocks it changed to the host ([`Mapper::grid`]) as it
/// integrates: what a lost device leaves the map (at most this much of depth maps is lost
/// with it). Reading the blocks back costs more than integrating them, so not every frame.
pub const MIRROR_PERIOD: Duration = Duration::from_secs(1);

/// The grid, its weighing, the integration's buffers and the mesh ([`Mapper::integrate`],
/// [`Mapper::update_mesh`], [`Mapper::clear`]). Made [`Mapper::on_gpu`], it integrates and
/// meshes on a wgpu device ([`GpuTsdf`]) and keeps `grid` as the device's copy, brought up to
/// date at the first depth map, every [`MIRROR_PERIOD`] after and on [`Mapper::sync_grid`]
/// (a mesh update reads the device's voxels where they are).
#[derive(Debug)]
pub struct Mapper {
    params: FusionParams,
    weighting: Weighting,
    grid: VoxelBlockGrid,
    scratch: IntegrationScratch,
    mesh: Mesh,
    gpu: Option<GpuTsdf>,
    /// Since `grid` was last brought up to date with the device (None: never).
    mirrored_at: Option<Instant>,
    mirror_period: Duration,
    /// Why the device's meshing or copy failed in the last [`Mapper::update_mesh`].
    gpu_error: Option<String>,
}

/// A GPU fusion error as the fusion's own: bad input as the CPU says it, the device's as
/// [`FusionError::Gpu`].
fn from_gpu(e: GpuFusionError) -> FusionError {
    match e {
        GpuFusionError::Fusion(e) => e,
        other => FusionError::Gpu(other.to_string()),
    }
}

impl Mapper {
    /// An empty map of `params` (checked), each depth map's pixels weighed by `weighting`.
    pub fn new(params: FusionParams, weighting: Weighting) -> Result<Self, FusionError> {
        params.validate()?;
        Ok(Self {
            grid: VoxelBlockGrid::new(params.voxel_size_m)?,
            params,
            weighting,
            scratch: IntegrationScratch::default(),
            mesh: Mesh::new(),
            gpu: None,
            mirrored_at: None,
            mirror_period: MIRROR_PERIOD,
            gpu_error: None,
        })
    }

    /// An empty map of `params` that integrates on `device` ([`GpuTsdf`]).
    pub fn on_gpu(
        params: FusionParams,
        weighting: Weighting,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<Self, FusionError> {
        let gpu = GpuTsdf::new(device, queue, params).map_err(from_gpu)?;
        let mut mapper = Self::new(params, weighting)?;
        mapper.gpu = Some(gpu);
        Ok(mapper)
    }

    /// Whether the map integrates on a GPU ([`Mapper::on_gpu`]).
    pub fn is_on_gpu(&self) -> bool {
        self.gpu.is_some()
    }

    /// Integrates on the CPU from now on (a lost device, a GPU that failed): the device's map
    /// is dropped, `grid` (its copy, as of its last update: at most [`MIRROR_PERIOD`] old)
    /// goes on, and the mesh is made again from it (the device's mesh could be newer). A
    /// depth map whose GPU integration failed changed nothing here and can be integrated
    /// again. Returns whether the map was on a GPU.
    pub fn leave_gpu(&mut self) -> bool {
        if self.gpu.take().is_none() {
            return false;
        }
        self.mesh.rebuild(&self.grid);
        true
    }

    /// Integrates and meshes on `device` from now on, its blocks uploaded from `grid` (a map
    /// that left a lost device, going onto the new one); the mesh is first brought up to date
    /// with `grid` on the CPU. On a device still (the lost one, not yet noticed), the map
    /// leaves it first with what it still gives back ([`Mapper::sync_grid`]; nothing from a
    /// lost one). Returns whether it left one. The device refusing the map leaves it on the
    /// CPU.
    pub fn move_to_gpu(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<bool, FusionError> {
        let left = self.gpu.is_some();
        if left {
            if let Err(e) = self.sync_grid() {
                tracing::debug!("fusion: leaving a device that no longer answers: {e}");
            }
            self.leave_gpu();
        }
        self.mesh.update(&mut self.grid);
        let gpu = GpuTsdf::from_grid(device, queue, self.params, &self.grid).map_err(from_gpu)?;
        self.gpu = Some(gpu);
        self.mirrored_at = Some(Instant::now());
        Ok(left)
    }

    /// How often a map on a GPU brings `grid` up to date as it integrates ([`MIRROR_PERIOD`]
    /// unless set; zero: after every depth map).
    pub fn set_mirror_period(&mut self, period: Duration) {
        self.mirror_period = period;
    }

    /// Brings `grid` up to date with the device's voxels (a map on a GPU; on the CPU it is
    /// the map itself).
    pub fn sync_grid(&mut self) -> Result<&VoxelBlockGrid, FusionError> {
        if let Some(gpu) = &mut self.gpu {
            gpu.sync_into(&mut self.grid).map_err(from_gpu)?;
            self.mirrored_at = Some(Instant::now());
            // The device names what its mesh updates mesh (`GpuTsdf::take_unmeshed`); the
            // copy's own changes would only pile up.
            self.grid.take_changes();
        }
        Ok(&self.grid)
    }

    /// Blocks in the map (on a GPU: on the device, whatever `grid` holds yet).
    pub fn block_count(&self) -> usize {
        self.gpu
            .as_ref()
            .map_or(self.grid.block_count(), GpuTsdf::block_count)
    }

    /// Why the device failed in the last [`Mapper::update_mesh`] (then the mesh was made on
    /// the CPU from `grid`); taken once.
    pub fn take_gpu_error(&mut self) -> Option<String> {
        self.gpu_error.take()
    }

    pub fn params(&self) -> &FusionParams {
        &self.params
    }

    pub fn grid(&self) -> &VoxelBlockGrid {
        &self.grid
    }

    /// Integrates one depth map, its pixels weighed by the map's [`Weighting`]
    /// ([`observation_weights`]; none with [`Weighting::EQUAL`]).
    pub fn integrate(&mut self, view: &DepthView<'_>) -> Result<IntegrationStats, FusionError> {
        let weights = (!self.weighting.is_equal()).then(|| {
            observation_weights(
                view.depth,
                view.confidence,
                view.baseline_ratio,
                &self.weighting,
            )
        });
        self.integrate_weighted(view, weights.as_ref())
    }

    /// Integrates one depth map with its pixels' weights given (None: alike), whatever the
    /// map's [`Weighting`].
    pub fn integrate_weighted(
        &mut self,
        view: &DepthView<'_>,
        weights: Option<&ImageF32>,
    ) -> Result<IntegrationStats, FusionError> {
        if let Some(gpu) = &mut self.gpu {
            let stats = gpu.integrate(view, weights).map_err(from_gpu)?;
            let due = self
                .mirrored_at
                .is_none_or(|at| at.elapsed() >= self.mirror_period);
            if due {
                self.sync_grid()?;
            }
            return Ok(stats);
        }
        integrate_into(
            &mut self.grid,
            &mut self.scratch,
            &self.params,
            view.depth,
            weights,
            view.colour,
            view.model,
            view.map_from_cam,
        )
    }

    /// Meshes the blocks that changed since the last call: for a map on a GPU on the device
    /// from its voxels there (`GpuTsdf::mesh_blocks`; nothing is copied to the host; if the
    /// device fails, on the CPU from `grid` brought up to date as far as the device still
    /// answers, and [`Mapper::take_gpu_error`] says why), else on the CPU.
    pub fn update_mesh(&mut self) -> MeshStats {
        let Some(gpu) = self.gpu.as_mut() else {
            return self.mesh.update(&mut self.grid);
        };
        let (todo, e) = match gpu.update_mesh(&mut self.mesh) {
            Ok(stats) => return stats,
            Err(failed) => failed,
        };
        self.gpu_error = Some(e.to_string());
        if let Err(e) = self.sync_grid() {
            tracing::debug!("fusion: the host copy could not be brought up to date: {e}");
        }
        let meshes = mesh_on_cpu(&self.grid, &todo);
        self.mesh.apply(meshes, todo.len())
    }

    /// The mesh as last updated, per block ([`Mesh::take_dirty`] names the blocks whose
    /// surface changed since the last look).
    pub fn mesh(&self) -> &Mesh {
        &self.mesh
    }

    pub fn mesh_mut(&mut self) -> &mut Mesh {
        &mut self.mesh
    }

    /// The whole mesh, up to date, as one list of vertices and triangles.
    pub fn collect_mesh(&mut self) -> BlockMesh {
        self.update_mesh();
        self.mesh.collect()
    }

    /// Empties the map and its mesh; returns the blocks dropped.
    pub fn clear(&mut self) -> usize {
        let blocks = self.block_count();
        if let Some(gpu) = &mut self.gpu {
            gpu.clear();
        }
        self.grid.clear();
        self.mesh.clear();
        self.mirrored_at = None;
        blocks
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::test_scenes;

    /// The mapper's sequence is the free functions' (the same voxels), its weighing applies,
    /// and a cleared map takes depth again.
    #[test]
    fn the_mapper_integrates_weighs_meshes_and_clears() {
        let model = test_scenes::camera(64, 48, 50.0);
        let params = FusionParams {
            voxel_size_m: 0.05,
            ..FusionParams::default()
        };
        let pose = RigidTransform::IDENTITY;
        let depth = test_scenes::sphere_before_slanted_wall(&model, &pose);
        let view = DepthView {
            depth: &depth,
            confidence: None,
            baseline_ratio: None,
            colour: None,
            model: &model,
            map_from_cam: &pose,
        };
        let mut mapper = Mapper::new(params, Weighting::EQUAL).expect("params");
        let stats = mapper.integrate(&view).expect("integrates");
        assert!(stats.blocks_updated > 0);
        let mut grid = VoxelBlockGrid::new(params.voxel_size_m).expect("grid");
        super::super::integrate(&mut grid, &params, &depth, None, &model, &pose).expect("free");
        assert_eq!(grid.block_count(), mapper.grid().block_count());
        for (index, block) in grid.blocks() {
            let mine = mapper.grid().block(*index).expect("the same blocks");
            for offset in 0..crate::fusion::VOXELS_PER_BLOCK {
                assert_eq!(block.voxel_at_offset(offset), mine.voxel_at_offset(offset));
            }
        }
        let meshed = mapper.update_mesh();
        assert!(meshed.blocks_meshed > 0 && mapper.mesh().triangle_count() > 0);
        assert_eq!(mapper.clear(), grid.block_count());
        assert!(mapper.grid().is_empty() && mapper.mesh().triangle_count() == 0);
        mapper.integrate(&view).expect("integrates again");
        assert_eq!(mapper.grid().block_count(), grid.block_count());

        // On a GPU (lavapipe here): the grid is the device's copy, the same blocks and
        // voxels to float rounding, meshed as on the CPU; cleared, it takes depth again.
        let (gpu, _one_at_a_time) = crate::fusion::gpu::tests::gpu();
        let mut on_gpu =
            Mapper::on_gpu(params, Weighting::EQUAL, &gpu.device, &gpu.queue).expect("GPU mapper");
        assert!(on_gpu.is_on_gpu() && !mapper.is_on_gpu());
        let stats = on_gpu.integrate(&view).expect("integrates on the GPU");
        assert!(stats.blocks_updated > 0);
        assert_eq!(on_gpu.grid().block_count(), grid.block_count());
        // A few voxels whose point lands exactly on a pixel edge or the truncation limit go
        // either way with the last bit of a projection (`gpu/tests.rs` has the exact bounds).
        let (mut compared, mut differ) = (0, 0);
        for (index, block) in grid.blocks() {
            let mine = on_gpu.grid().block(*index).expect("the same blocks");
            for offset in 0..crate::fusion::VOXELS_PER_BLOCK {
                let (a, b) = (block.voxel_at_offset(offset), mine.voxel_at_offset(offset));
                if a.is_observed() || b.is_observed() {
                    compared += 1;
                    differ += usize::from(
                        a.is_observed() != b.is_observed() || (a.tsdf - b.tsdf).abs() > 1e-3,
                    );
                }
            }
        }
        assert!(compared > 1000, "{compared} voxels observed");
        assert!(
            differ * 100 <= compared,
            "{differ} of {compared} voxels differ"
        );
        assert!(on_gpu.update_mesh().blocks_meshed > 0 && on_gpu.mesh().triangle_count() > 0);
        assert_eq!(on_gpu.clear(), grid.block_count());
        assert!(on_gpu.grid().is_empty() && on_gpu.mesh().triangle_count() == 0);
        on_gpu
            .integrate(&view)
            .expect("integrates again on the GPU");
        assert_eq!(on_gpu.grid().block_count(), grid.block_count());

        // The device's copy: after every depth map with a zero period; with one that never
        // comes, not before `sync_grid` (nor at a mesh update).
        let weight = |m: &Mapper| -> f32 {
            let voxels = |b: &crate::fusion::Block| {
                (0..crate::fusion::VOXELS_PER_BLOCK)
                    .map(|o| b.voxel_at_offset(o).weight)
                    .sum::<f32>()
            };
            m.grid().blocks().map(|(_, b)| voxels(b)).sum()
        };
        on_gpu.set_mirror_period(Duration::ZERO);
        let before = weight(&on_gpu);
        on_gpu.integrate(&view).expect("integrates");
        let copied = weight(&on_gpu);
        assert!(copied > before, "{copied} after {before}");
        on_gpu.set_mirror_period(Duration::MAX);
        on_gpu.integrate(&view).expect("integrates");
        assert_eq!(weight(&on_gpu), copied, "copied before its period");
        on_gpu.sync_grid().expect("copies");
        let synced = weight(&on_gpu);
        assert!(synced > copied, "{synced} after {copied}");
        on_gpu.integrate(&view).expect("integrates");
        on_gpu.update_mesh();
        assert_eq!(weight(&on_gpu), synced, "a mesh update copied blocks back");
        assert_eq!(on_gpu.block_count(), on_gpu.grid().block_count());
    }
}
