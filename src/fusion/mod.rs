//! Live 3D fusion (issue 28): depth maps into one coloured mesh, on the CPU.
//!
//! A truncated signed distance field (TSDF) in a sparse grid of 8x8x8-voxel blocks, filled by
//! projective integration of depth maps and meshed incrementally by marching cubes, as
//! nvblox does it (Millane et al., "nvblox: GPU-Accelerated Incremental Signed Distance Field
//! Mapping", 2024), itself after voxblox (Oleynikova et al., 2017) and KinectFusion's running
//! average (Newcombe et al., 2011; Curless & Levoy, 1996); the block hash and the band-only
//! allocation are those of Open3D's `VoxelBlockGrid` (Dong et al., 2021).
//!
//! - [`blocks`]: [`VoxelBlockGrid`]: blocks of [`Voxel`]s in a hash map by [`BlockIndex`], and
//!   the set of blocks changed since the last meshing.
//! - [`mod@integrate`]: [`integrate()`]: one depth map (and optionally its colour image) into the
//!   grid, [`IntegrationStats`]. Observations weigh the squared cosine between the viewing
//!   ray and the surface normal (nvblox weighs them equally), which keeps grazing views from
//!   pushing a curved surface outwards.
//! - [`gpu`]: [`GpuTsdf`]: the integration's twin on a wgpu device (the voxels in a device
//!   pool, the block hash and steps 0 and 1 on the host), read back into a grid for meshing.
//! - [`mesh`]: [`Mesh`]: marching cubes per block, re-meshing only the blocks that changed
//!   ([`Mesh::update`], [`MeshStats`]); [`Mesh::collect`] concatenates the blocks.
//! - [`ply`]: [`write_ply`]: the collected mesh as a binary PLY (MeshLab, Blender).
//! - [`raycast`]: [`raycast_depth`]: the fused surface's z-depth in a camera view (the first
//!   positive-to-negative crossing of the trilinear TSDF along each pixel's ray).
//! - [`accuracy`]: [`DepthAccuracy`]: the fused model against ground truth in the views that
//!   made it, beside the depth maps; [`vertex_accuracy`]: the mesh's vertices near the true
//!   surface (issue 28's accuracy bar).
//!
//! Conventions (those of [`crate::geometry`]):
//! - The grid lives in one world frame, in metres. Voxel `(i, j, k)` (global integer index)
//!   has its centre at `(i, j, k) * voxel_size_m`; block `(a, b, c)` holds the voxels
//!   `8a..8a + 8` (and so on per axis). Voxel centres are the samples of the field;
//!   marching cubes runs over the cubes between eight neighbouring centres.
//! - A camera's pose is `world_from_cam`, the pose of its ROS optical frame (x right, y down,
//!   z forward) in the world frame: `point_in_world = world_from_cam.transform_point(point_in_cam)`.
//! - Depth images are z along the optical axis in metres (32FC1), NaN (or any non-finite or
//!   non-positive value) where invalid; pixel centres at integer coordinates.
//! - The TSDF is positive in front of the surface (free space), negative behind it, scaled by
//!   the truncation distance to [-1, 1]; the surface is its zero crossing.

pub mod accuracy;
pub mod blocks;
pub mod gpu;
pub mod integrate;
pub mod mapper;
pub mod mesh;
pub mod ply;
pub mod raycast;
mod tables;
pub mod weights;

pub use accuracy::{vertex_accuracy, DepthAccuracy, DepthAccuracySummary, VertexAccuracy};
pub use blocks::{Block, BlockIndex, Voxel, VoxelBlockGrid, BLOCK_SIDE, VOXELS_PER_BLOCK};
pub use gpu::{GpuFusionError, GpuTsdf};
pub use integrate::{integrate, integrate_weighted, IntegrationStats};
pub use mapper::{DepthView, Mapper};
pub use mesh::{BlockMesh, Mesh, MeshStats};
pub use ply::{write_ply, write_ply_file};
pub use raycast::raycast_depth;
pub use weights::{observation_weights, rms_baseline_m, Weighting};

/// Parameters of the fusion (nvblox's `ProjectiveIntegrator` parameters, and its layer's voxel
/// size).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FusionParams {
    /// The side of a voxel in metres. Fixed for a grid ([`VoxelBlockGrid::new`]).
    pub voxel_size_m: f32,
    /// The truncation distance in voxels: the TSDF is updated from this far behind the observed
    /// surface, and saturates at this distance in front of it.
    pub truncation_voxels: f32,
    /// The cap on a voxel's weight (one per head-on observation, less for oblique ones: see
    /// [`integrate()`]): a running average over about this many observations at most, so that
    /// a surface that moves is followed.
    pub max_weight: f32,
    /// Depths beyond this are not integrated.
    pub max_depth_m: f32,
    /// Depths below this are not integrated.
    pub min_depth_m: f32,
    /// The most blocks the grid holds at any moment (0: no limit): before each integration
    /// allocates, the blocks farthest from that camera's centre beyond this many (held ones,
    /// and new ones of the depth map's band, which are then never made) are dropped
    /// ([`VoxelBlockGrid::drop_farthest`]; [`IntegrationStats::blocks_dropped`]), and the next
    /// [`Mesh::update`] drops their meshes ([`Mesh::removed`]). A block holds 8 KiB of voxels
    /// (plus about 40 bytes in the hash map): the default, 50 000 blocks, bounds the grid at
    /// about 400 MiB (at 5 cm voxels, 400 m³ of 40 cm blocks around the surface seen; at
    /// 2 cm, 25 m³).
    pub max_blocks: usize,
}

impl Default for FusionParams {
    fn default() -> Self {
        Self {
            voxel_size_m: 0.05,
            truncation_voxels: 4.0,
            max_weight: 64.0,
            max_depth_m: 10.0,
            min_depth_m: 0.1,
            max_blocks: 50_000,
        }
    }
}

impl FusionParams {
    /// The truncation distance in metres.
    pub fn truncation_m(&self) -> f32 {
        self.truncation_voxels * self.voxel_size_m
    }

    /// Checks every field: finite, positive where it must be, `min_depth_m < max_depth_m`.
    pub fn validate(&self) -> Result<(), FusionError> {
        let bad = |reason: String| Err(FusionError::InvalidParams(reason));
        for (name, v) in [
            ("voxel_size_m", self.voxel_size_m),
            ("truncation_voxels", self.truncation_voxels),
            ("max_weight", self.max_weight),
            ("max_depth_m", self.max_depth_m),
            ("min_depth_m", self.min_depth_m),
        ] {
            if !v.is_finite() {
                return bad(format!("{name} is {v}"));
            }
        }
        if self.voxel_size_m <= 0.0 {
            return bad(format!(
                "voxel_size_m must be positive, not {}",
                self.voxel_size_m
            ));
        }
        if self.truncation_voxels < 1.0 {
            return bad(format!(
                "truncation_voxels must be at least 1 (marching cubes needs a sign change \
                 between neighbouring voxels), not {}",
                self.truncation_voxels
            ));
        }
        if self.max_weight < 1.0 {
            return bad(format!(
                "max_weight must be at least 1, not {}",
                self.max_weight
            ));
        }
        if self.min_depth_m < 0.0 || self.min_depth_m >= self.max_depth_m {
            return bad(format!(
                "depth range [{}, {}] m is empty or negative",
                self.min_depth_m, self.max_depth_m
            ));
        }
        Ok(())
    }
}

/// The checks [`integrate()`] and [`raycast_depth`] make of a view before using it: the
/// parameters, the grid's voxel size (`voxel_size_m`), the camera (`what` names it in the error) and its pose;
/// returns the pose with its rotation normalised (tf2's tolerance).
pub(crate) fn check_view(
    voxel_size_m: f32,
    params: &FusionParams,
    model: &crate::geometry::CameraModel,
    world_from_cam: &crate::geometry::RigidTransform,
    what: &str,
) -> Result<crate::geometry::RigidTransform, FusionError> {
    params.validate()?;
    if (params.voxel_size_m - voxel_size_m).abs() > 1e-6 * voxel_size_m {
        return Err(FusionError::VoxelSizeMismatch {
            params_m: params.voxel_size_m,
            grid_m: voxel_size_m,
        });
    }
    model
        .validate(what)
        .map_err(|e| FusionError::Camera(e.to_string()))?;
    let rotation = crate::geometry::pose::unit_quaternion(world_from_cam.rotation)
        .map_err(|e| FusionError::Pose(format!("rotation: {e}")))?;
    if !world_from_cam.translation.is_finite() {
        return Err(FusionError::Pose(format!(
            "translation {} is not finite",
            world_from_cam.translation
        )));
    }
    Ok(crate::geometry::RigidTransform {
        rotation,
        translation: world_from_cam.translation,
    })
}

/// Why a fusion step refused its input.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FusionError {
    #[error("fusion parameters: {0}")]
    InvalidParams(String),
    #[error(
        "voxel size {params_m} m of the parameters differs from the grid's {grid_m} m (a grid's \
         voxel size is fixed when it is made)"
    )]
    VoxelSizeMismatch { params_m: f32, grid_m: f32 },
    #[error("{what} is {got_width}x{got_height} but the camera model is {width}x{height}")]
    ImageSize {
        what: &'static str,
        got_width: u32,
        got_height: u32,
        width: u32,
        height: u32,
    },
    #[error("camera model: {0}")]
    Camera(String),
    #[error("camera pose: {0}")]
    Pose(String),
    /// The device refused or failed the integration ([`GpuFusionError`] beyond bad input).
    #[error("{0}")]
    Gpu(String),
}

#[cfg(test)]
pub(crate) mod test_scenes;

/// Where [`GpuTsdf::integrate`]'s last frame spent its time (`bench --fusion --device gpu`
/// prints it): the host's steps, then the wait for the device.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct GpuIntegrationTimes {
    /// Step 0: each pixel's valid depth, observation weight and colour.
    pub samples: std::time::Duration,
    /// Step 1: the blocks in view and the truncation band's new ones, given slots.
    pub blocks: std::time::Duration,
    /// The work list (each block's origin and slot, in index order).
    pub work: std::time::Duration,
    /// Uploads, recording and submission (the device's run less its wait).
    pub submit: std::time::Duration,
    /// The wait for the device: its work and the readback of the voxels updated per block.
    pub wait: std::time::Duration,
}

impl GpuIntegrationTimes {
    /// From the instants a frame started, ended step 0, step 1 and the work list, and ended
    /// (`marks`), with its `wait` for the device.
    fn from_marks(marks: [std::time::Instant; 5], wait: std::time::Duration) -> Self {
        let part = |i: usize| marks[i + 1].saturating_duration_since(marks[i]);
        Self {
            samples: part(0),
            blocks: part(1),
            work: part(2),
            submit: part(3).saturating_sub(wait),
            wait,
        }
    }
}
