//! The map, as nvblox's `Mapper`: the block TSDF grid, how depth maps are weighed, the
//! integration's per-pixel buffers (kept from one depth map to the next) and the mesh of the
//! surface. One sequence for everything that fuses depth: the node's and `bag`'s fusion thread
//! (`pipeline/fuser.rs`), `eval --fusion` and `bench --fusion`.

use super::gpu::{GpuFusionError, GpuTsdf};
use super::integrate::{integrate_into, IntegrationScratch};
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

/// The grid, its weighing, the integration's buffers and the mesh ([`Mapper::integrate`],
/// [`Mapper::update_mesh`], [`Mapper::clear`]). Made [`Mapper::on_gpu`], it integrates on a
/// wgpu device ([`GpuTsdf`]) and keeps `grid` as the device's copy (the blocks each depth map
/// changed read back), which the mesh and everything else read as on the CPU.
#[derive(Debug)]
pub struct Mapper {
    params: FusionParams,
    weighting: Weighting,
    grid: VoxelBlockGrid,
    scratch: IntegrationScratch,
    mesh: Mesh,
    gpu: Option<GpuTsdf>,
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
    /// is dropped, `grid` (its copy, synced after every integration that succeeded) keeps
    /// every block fused so far. A depth map whose GPU integration failed changed nothing
    /// here and can be integrated again. Returns whether the map was on a GPU.
    pub fn leave_gpu(&mut self) -> bool {
        self.gpu.take().is_some()
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
            gpu.sync_into(&mut self.grid).map_err(from_gpu)?;
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

    /// Meshes the blocks that changed since the last call: on the GPU for a map on a GPU
    /// (`GpuTsdf::mesh_blocks`, from the device's voxels; on the CPU from `grid`, its copy,
    /// if that fails), else on the CPU.
    pub fn update_mesh(&mut self) -> MeshStats {
        let Some(gpu) = self.gpu.as_mut() else {
            return self.mesh.update(&mut self.grid);
        };
        let (stats, error) = self
            .mesh
            .update_with(&mut self.grid, |todo| gpu.mesh_blocks(todo));
        if let Some(e) = error {
            tracing::warn!("meshing on the GPU failed ({e}); these blocks were meshed on the CPU");
        }
        stats
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
        let blocks = self.grid.block_count();
        if let Some(gpu) = &mut self.gpu {
            gpu.clear();
        }
        self.grid.clear();
        self.mesh.clear();
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
    }
}
