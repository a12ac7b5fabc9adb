//! Every reference's depth of every set into one mesh (`bag --mesh`; the node's live fusion
//! is the next step of issue 28): each output's depth, colour and camera, placed in the world
//! frame on a moving rig (`world_frame`) or in the rig frame of a rig that stands still.

use super::outputs::FrameOutputs;
use crate::fusion::{
    integrate, BlockMesh, FusionError, FusionParams, IntegrationStats, Mesh, MeshStats,
    VoxelBlockGrid,
};

/// The grid, its mesh and what went in.
#[derive(Debug)]
pub struct Fuser {
    params: FusionParams,
    grid: VoxelBlockGrid,
    mesh: Mesh,
    /// Depth maps integrated.
    pub integrated: u64,
}

impl Fuser {
    pub fn new(params: FusionParams) -> Result<Self, FusionError> {
        params.validate()?;
        Ok(Self {
            grid: VoxelBlockGrid::new(params.voxel_size_m)?,
            mesh: Mesh::new(),
            params,
            integrated: 0,
        })
    }

    /// Integrates one reference's depth at its pose (the world pose on a moving rig, else the
    /// pose in the rig frame).
    pub fn add(&mut self, out: &FrameOutputs) -> Result<IntegrationStats, FusionError> {
        let frame_pose = out.world_from_frame.unwrap_or(out.rig_from_frame);
        let world_from_cam = frame_pose.compose(&out.frame_from_cam);
        let stats = integrate(
            &mut self.grid,
            &self.params,
            &out.depth_m(),
            out.colour.as_deref(),
            &out.model,
            &world_from_cam,
        )?;
        self.integrated += 1;
        Ok(stats)
    }

    /// Meshes the blocks that changed since the last call.
    pub fn update_mesh(&mut self) -> MeshStats {
        self.mesh.update(&mut self.grid)
    }

    /// The whole mesh (after [`Self::update_mesh`]).
    pub fn mesh(&self) -> BlockMesh {
        self.mesh.collect()
    }

    /// Blocks allocated and their memory, for reports.
    pub fn blocks(&self) -> (usize, usize) {
        (self.grid.block_count(), self.grid.memory_bytes())
    }
}
