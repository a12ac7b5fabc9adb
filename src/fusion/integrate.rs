//! Projective TSDF integration of one depth map (nvblox's `ProjectiveTsdfIntegrator`,
//! voxblox's projective integrator; the band-only allocation of Open3D's `VoxelBlockGrid`).
//!
//! 1. Allocation: every block that the truncation band `[d - trunc, d + trunc]` (along the
//!    optical axis) of a valid pixel's ray crosses, found by walking the ray's segment block
//!    by block (Amanatides & Woo, 1987), so no block along it is skipped. Free space in front
//!    of the band allocates nothing (unlike nvblox, which allocates along the whole ray).
//!    Shortcuts (pinhole cameras): a 4x4-pixel tile whose bands' bounding box holds at most
//!    four blocks lists them (`TILE_BOX_BLOCKS`: a few neighbours of the band more than the
//!    walk; on ICL-NUIM 1.3 % more blocks; the boxes of a row of tiles are made lane-wise,
//!    `allocate::tile_boxes`); a
//!    segment one or two face steps long lists its ends (and the middle block the walk would
//!    take) without walking; the per-pixel segments are those of every other row and column
//!    (`ALLOCATION_STRIDE`: neighbours' bands cross the same blocks; on ICL-NUIM 1502 of the
//!    1525 blocks every pixel's walk finds, the rest touched by a skipped pixel's band only).
//! 2. Update: every voxel of the blocks of step 1 and of the blocks already allocated inside
//!    the camera's view (so that a surface that moved away is carved out) is projected into
//!    the image; the depth there (bilinear when the four pixels around are valid and agree
//!    within the truncation distance, else the nearest pixel) gives nvblox's projective
//!    distance `sdf = depth - z_voxel`; voxels more than `trunc` behind the surface are left
//!    alone, the others take `clamp(sdf / trunc, -1, 1)` into a running average whose weight
//!    is capped at `max_weight`; near the surface (`|sdf| < trunc`) the colour of the nearest
//!    pixel is averaged the same way, one count per observation. A pinhole camera's update
//!    passes over the rows of a block that lie more than `trunc` behind every depth the
//!    block's projection can read (a depth maximum per 8x8-pixel tile, made in step 0): the
//!    same voxels are updated.
//!
//! One departure from nvblox's constant weight: an observation weighs the squared cosine
//! between the viewing ray and the surface normal at its pixel (from the depth map's
//! neighbours), as KinectFusion-style systems weigh by angle. Projective distances from
//! grazing views are stretched, and on a curved surface they reach the voxels outside it
//! (the ray misses: no observation) and inside it (a large negative one) unevenly, which
//! pulls the zero crossing outwards: on a 0.5 m sphere seen from six sides at 4 cm voxels,
//! constant weights put vertices up to 1.03 voxel off the surface, cos² weights 0.15.

use glam::{DMat3, DVec2, DVec3, Mat3, Vec3};
use rayon::prelude::*;

use crate::geometry::{CameraModel, Distortion, RigidTransform};
use crate::image::{ImageF32, Rgba8Image};
use crate::simd::vectorised_fn;

mod allocate;
mod pinhole;

use allocate::RayGrid;
use pinhole::{pinhole_samples, update_block_pinhole, PinholeSamples, DEPTH_TILE};

use super::blocks::{
    bound_allocation, Block, BlockIndex, BlockMap, BlockSet, RowObservation, BLOCK_SIDE,
};
use super::{FusionError, FusionParams, VoxelBlockGrid};

/// The least weight of one observation (a view at 84 degrees to the surface or more).
pub const MIN_OBSERVATION_WEIGHT: f32 = 0.01;

/// What one [`integrate`] call did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct IntegrationStats {
    /// Pixels with a depth within `[min_depth_m, max_depth_m]`.
    pub pixels_valid: usize,
    /// Blocks newly allocated around the observed surface.
    pub blocks_allocated: usize,
    /// Blocks visited: the new ones and those already allocated inside the view.
    pub blocks_in_view: usize,
    /// Blocks where at least one voxel was updated (marked changed for meshing).
    pub blocks_updated: usize,
    pub voxels_updated: usize,
    /// Blocks dropped to keep the grid within [`FusionParams::max_blocks`]: the farthest from
    /// this camera's centre, held ones and new ones of this map never allocated (the bound is
    /// settled before allocation, so the grid never holds more, even during one map).
    pub blocks_dropped: usize,
    /// The most blocks the grid held during this map: once the blocks the bound drops are
    /// gone and the new ones made (at most [`FusionParams::max_blocks`] when it bounds).
    pub blocks_peak: usize,
}

/// Integrates one depth map (z along the optical axis in metres, invalid pixels NaN, zero or
/// out of range) seen by `model` at `world_from_cam` into `grid`, with the colour of `colour`
/// (same size as the depth) near the surface. Distorted models are supported (each voxel goes
/// through [`CameraModel::project`], each pixel's ray through [`CameraModel::unproject_z1`]);
/// a pinhole model takes a faster path.
pub fn integrate(
    grid: &mut VoxelBlockGrid,
    params: &FusionParams,
    depth: &ImageF32,
    colour: Option<&Rgba8Image>,
    model: &CameraModel,
    world_from_cam: &RigidTransform,
) -> Result<IntegrationStats, FusionError> {
    integrate_weighted(grid, params, depth, None, colour, model, world_from_cam)
}

/// [`integrate()`] with a weight per pixel (`weights`, the depth's size): each observation's
/// weight is multiplied by its pixel's (e.g. the inverse variance of the depth, from the
/// engine's confidence and the reference's baselines); a pixel whose weight is not positive
/// and finite adds no observation. `None`: every pixel 1, as [`integrate()`]. Its per-pixel
/// buffers are made for the call; [`super::Mapper`] keeps its own from one depth map to the
/// next.
pub fn integrate_weighted(
    grid: &mut VoxelBlockGrid,
    params: &FusionParams,
    depth: &ImageF32,
    weights: Option<&ImageF32>,
    colour: Option<&Rgba8Image>,
    model: &CameraModel,
    world_from_cam: &RigidTransform,
) -> Result<IntegrationStats, FusionError> {
    let mut scratch = IntegrationScratch::default();
    integrate_into(
        grid,
        &mut scratch,
        params,
        depth,
        weights,
        colour,
        model,
        world_from_cam,
    )
}

/// [`integrate_weighted`] with the per-pixel buffers `scratch` (kept by the caller).
#[expect(
    clippy::too_many_arguments,
    reason = "the depth map, its weights, colour, camera and pose are each an input of their own, as in integrate_weighted; Mapper gathers them in a DepthView"
)]
pub(super) fn integrate_into(
    grid: &mut VoxelBlockGrid,
    scratch: &mut IntegrationScratch,
    params: &FusionParams,
    depth: &ImageF32,
    weights: Option<&ImageF32>,
    colour: Option<&Rgba8Image>,
    model: &CameraModel,
    world_from_cam: &RigidTransform,
) -> Result<IntegrationStats, FusionError> {
    let frame = FrameInput {
        depth,
        weights,
        colour,
        model,
        world_from_cam,
        samples_on_device: false,
    };
    let (view, world_from_cam) = prepare(grid.voxel_size_m(), scratch, params, &frame)?;
    let pixels_valid = view.pixels_valid;
    // Step 1: allocation.
    let (mut in_view, mut new) = blocks_to_update(&view, grid.blocks_map(), &world_from_cam);
    // The memory bound settled before anything is allocated.
    let bound = bound_allocation(
        grid.blocks_map(),
        &mut in_view,
        &mut new,
        params.max_blocks,
        grid.voxel_size_m(),
        world_from_cam.translation,
    );
    for index in &bound.held {
        grid.remove_block(*index);
    }
    let map = grid.blocks_map_mut();
    // The new blocks made on the pool's threads: a block's zeroed voxels are 6 KiB of fresh
    // pages to fault in, a first frame's ~1500 of them 9 MB.
    let made: Vec<Block> = new.par_iter().map(|_| Block::default()).collect();
    let blocks_allocated = new.len();
    map.extend(new.into_iter().zip(made));
    let blocks_peak = map.len();
    let mut work: Vec<(BlockIndex, Block)> = in_view
        .iter()
        .filter_map(|index| map.remove(index).map(|block| (*index, block)))
        .collect();
    // In index order: neighbouring blocks one after another read neighbouring pixels.
    work.sort_unstable_by_key(|(index, _)| *index);
    // Step 2: update, a block per task.
    let updated: Vec<usize> = work
        .par_iter_mut()
        .map(|(index, block)| match view.projector {
            Projector::Pinhole { .. } if view.lanes_fit => {
                update_block_pinhole(&view, *index, block)
            }
            _ => view.update_block(*index, block),
        })
        .collect();
    let mut stats = IntegrationStats {
        pixels_valid,
        blocks_allocated,
        blocks_in_view: work.len(),
        blocks_peak,
        ..IntegrationStats::default()
    };
    let mut changed = Vec::new();
    for ((index, block), voxels) in work.into_iter().zip(updated) {
        map.insert(index, block);
        if voxels > 0 {
            stats.blocks_updated += 1;
            stats.voxels_updated += voxels;
            changed.push(index);
        }
    }
    for index in changed {
        grid.mark_changed(index);
    }
    *scratch = view.into_scratch();
    // Step 3: the memory bound (settled before step 1; this drops nothing more).
    stats.blocks_dropped = bound.held.len()
        + bound.skipped
        + grid.drop_farthest(params.max_blocks, world_from_cam.translation);
    Ok(stats)
}

/// One depth map with what goes with it, as [`integrate_weighted`] takes them.
pub(super) struct FrameInput<'a> {
    pub depth: &'a ImageF32,
    pub weights: Option<&'a ImageF32>,
    pub colour: Option<&'a Rgba8Image>,
    pub model: &'a CameraModel,
    pub world_from_cam: &'a RigidTransform,
    /// Whether a pinhole camera's samples are made on the device (the GPU integration's
    /// `gpu/samples.rs`): step 0 then validates the depths only, and `View::samples` is empty.
    pub samples_on_device: bool,
}

/// The checks of a frame and step 0 (each pixel's depth, weight and colour), shared by the CPU
/// update and the GPU's (`super::gpu`): the view, with the buffers of `scratch` (hand them back
/// with [`View::into_scratch`]), and the pose with its rotation normalised.
pub(super) fn prepare<'a>(
    voxel_size_m: f32,
    scratch: &mut IntegrationScratch,
    params: &FusionParams,
    frame: &FrameInput<'a>,
) -> Result<(View<'a>, RigidTransform), FusionError> {
    let FrameInput {
        depth,
        weights,
        colour,
        model,
        world_from_cam,
        samples_on_device,
    } = *frame;
    let world_from_cam =
        super::check_view(voxel_size_m, params, model, world_from_cam, "fusion camera")?;
    let (width, height) = (model.intrinsics.width_px, model.intrinsics.height_px);
    let size_error = |what, got_width, got_height| FusionError::ImageSize {
        what,
        got_width,
        got_height,
        width,
        height,
    };
    if depth.width != width || depth.height != height {
        return Err(size_error("depth image", depth.width, depth.height));
    }
    let pixels = width as usize * height as usize;
    if depth.data.len() != pixels {
        return Err(FusionError::Camera(format!(
            "depth image of {width}x{height} holds {} values",
            depth.data.len()
        )));
    }
    if let Some(w) = weights {
        if w.width != width || w.height != height || w.data.len() != pixels {
            return Err(size_error("weight image", w.width, w.height));
        }
    }
    if let Some(c) = colour {
        if c.width != width || c.height != height {
            return Err(size_error("colour image", c.width, c.height));
        }
        if c.pixels.len() != pixels {
            return Err(FusionError::Camera(format!(
                "colour image of {width}x{height} holds {} pixels",
                c.pixels.len()
            )));
        }
    }
    // Step 0: the valid depths and each pixel's observation weight, once per frame.
    let taken = std::mem::take(scratch);
    let mut view = View::new(
        voxel_size_m,
        params,
        depth,
        colour,
        model,
        &world_from_cam,
        taken,
        samples_on_device,
    );
    if let Some(w) = weights {
        for (sample, &w) in view.samples.iter_mut().zip(&w.data) {
            let keep = w.is_finite() && w > 0.0;
            sample.weight = if keep { sample.weight * w } else { f32::NAN };
        }
    }
    Ok((view, world_from_cam))
}

/// Step 1 over the blocks allocated so far (`allocated`: the CPU's grid, the GPU's slots): the
/// blocks the view updates (those allocated inside the view and the band's new ones) and the
/// new ones among them, sorted.
pub(super) fn blocks_to_update<V: Sync>(
    view: &View<'_>,
    allocated: &BlockMap<V>,
    world_from_cam: &RigidTransform,
) -> (BlockSet, Vec<BlockIndex>) {
    let mut in_view: BlockSet = allocated
        .par_iter()
        .filter(|(index, _)| view.block_in_view(**index))
        .map(|(index, _)| *index)
        .collect::<Vec<_>>()
        .into_iter()
        .collect();
    // `band` may list a block more than once: `in_view` keeps one of each.
    let mut new = Vec::new();
    for index in view.band_blocks(world_from_cam) {
        if in_view.insert(index) && !allocated.contains_key(&index) {
            new.push(index);
        }
    }
    new.sort_unstable();
    (in_view, new)
}

/// The depths a frame integrates: finite, positive and within `[min_m, max_m]`.
#[derive(Clone, Copy)]
struct DepthLimits {
    min_m: f32,
    max_m: f32,
}

impl DepthLimits {
    /// Writes `input`'s valid depths into `out` (NaN elsewhere); returns how many are valid.
    fn validate(self, out: &mut [f32], input: &[f32]) -> usize {
        validate_depths(self, out, input)
    }
}

crate::simd::vectorised_fn! {
/// [`DepthLimits::validate`], lane-wise (AVX2 where the CPU has it): counted in 32-bit lanes
/// (a `usize` count kept the loop scalar: ~10 instructions a pixel).
fn validate_depths(limits: DepthLimits, out: &mut [f32], input: &[f32]) -> usize {
    let mut valid_here = 0u32;
    for (o, &d) in out.iter_mut().zip(input) {
        // `&`, not `&&`: no branches, so the loop is lane-wise.
        let valid = (d.abs() < f32::INFINITY) & (d > 0.0) & (d >= limits.min_m) & (d <= limits.max_m);
        valid_here += u32::from(valid);
        *o = if valid { d } else { f32::NAN };
    }
    valid_here as usize
}
}

/// Camera frame to pixel.
pub(super) enum Projector {
    Pinhole {
        fx: f32,
        fy: f32,
        cx: f32,
        cy: f32,
    },
    /// The model and its largest undistorted radius (`CameraModel::project_within`).
    Distorted(CameraModel, f64),
}

impl Projector {
    fn project(&self, point_in_cam: Vec3) -> Option<(f32, f32)> {
        match self {
            Projector::Pinhole { fx, fy, cx, cy } => {
                if point_in_cam.z.is_nan() || point_in_cam.z <= 1e-6 {
                    return None;
                }
                let inv_z = 1.0 / point_in_cam.z;
                Some((
                    fx * point_in_cam.x * inv_z + cx,
                    fy * point_in_cam.y * inv_z + cy,
                ))
            }
            Projector::Distorted(model, max_radius) => model
                .project_within(point_in_cam.as_dvec3(), *max_radius)
                .map(|p| (p.x as f32, p.y as f32)),
        }
    }
}

/// One pixel as step 2 reads it: a voxel's four bilinear neighbours, its weight and colour
/// in one or two cache lines.
/// The GPU integrator uploads them as they are (`tsdf_integrate.wgsl`'s `Sample`).
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct PixelSample {
    /// The depth where valid, NaN elsewhere.
    pub(super) depth_m: f32,
    /// The observation weight ([`View::pixel_weight`]), NaN where there is none.
    pub(super) weight: f32,
    /// The colour ([`Rgba8Image::pack`]), 0 without a colour image.
    pub(super) rgb: u32,
}

/// The per-pixel buffers of [`View`], kept by [`super::Mapper`] from one frame to the next: a fresh
/// 640x480 frame's 4.9 MB would be new pages to fault in every time (on this project's
/// 2-core VMs 0.3-0.5 ms of the validity pass alone).
#[derive(Default, Clone)]
pub(super) struct IntegrationScratch {
    depth_m: Vec<f32>,
    samples: Vec<PixelSample>,
    tile_max: Vec<f32>,
}

impl std::fmt::Debug for IntegrationScratch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "IntegrationScratch({} pixels)", self.samples.capacity())
    }
}

/// One depth map with its camera, as the integration reads it.
pub(super) struct View<'a> {
    depth: &'a ImageF32,
    /// The depth where valid (finite, within the depth limits), NaN elsewhere.
    depth_m: Vec<f32>,
    pub(super) pixels_valid: usize,
    /// What step 2 reads of each pixel, side by side.
    pub(super) samples: Vec<PixelSample>,
    /// A pinhole camera's greatest valid depth per [`DEPTH_TILE`]-square tile (row by row,
    /// `width.div_ceil(DEPTH_TILE)` a row; -inf where none is valid); empty for a distorted
    /// camera.
    tile_max: Vec<f32>,
    pub(super) colour: Option<&'a Rgba8Image>,
    pub(super) model: CameraModel,
    pub(super) projector: Projector,
    /// A distorted model's rays for step 1.
    ray_grid: Option<RayGrid>,
    cam_from_world_rotation: DMat3,
    cam_from_world_translation: DVec3,
    /// `cam_from_world_rotation` times the voxel size, column per axis (f32).
    pub(super) voxel_steps_in_cam: Mat3,
    voxel_size_m: f32,
    pub(super) truncation_m: f32,
    max_depth_m: f32,
    pub(super) max_weight: f32,
    /// Whether the image has at least 2x2 pixels (step 2's lanes clamp their offsets into it),
    /// fewer than 2^31 (they are i32) and sides below 2^22 (`pinhole::floor_small`).
    lanes_fit: bool,
}

impl<'a> View<'a> {
    #[expect(
        clippy::too_many_arguments,
        reason = "a frame's parts as prepare has them (the pose checked), its buffers and where its samples are made"
    )]
    fn new(
        voxel_size_m: f32,
        params: &FusionParams,
        depth: &'a ImageF32,
        colour: Option<&'a Rgba8Image>,
        model: &CameraModel,
        world_from_cam: &RigidTransform,
        scratch: IntegrationScratch,
        samples_on_device: bool,
    ) -> Self {
        let cam_from_world = world_from_cam.inverse();
        let rotation = cam_from_world.rotation_matrix();
        let k = &model.intrinsics;
        let projector = match model.distortion {
            Distortion::None => Projector::Pinhole {
                fx: k.fx_px as f32,
                fy: k.fy_px as f32,
                cx: k.cx_px as f32,
                cy: k.cy_px as f32,
            },
            _ => Projector::Distorted(*model, model.distortion.max_undistorted_radius()),
        };
        let (min_depth_m, max_depth_m) = (params.min_depth_m, params.max_depth_m);
        let trunc = params.truncation_m();
        // The buffers of the last frame (no fresh pages, no initialisation: every element is
        // written below).
        let IntegrationScratch {
            mut depth_m,
            mut samples,
            mut tile_max,
        } = scratch;
        let pixels = depth.data.len();
        let width = depth.width as usize;
        depth_m.resize(pixels, f32::NAN);
        if samples_on_device && matches!(projector, Projector::Pinhole { .. }) {
            samples.clear();
        } else {
            samples.resize(
                pixels,
                PixelSample {
                    depth_m: f32::NAN,
                    weight: f32::NAN,
                    rgb: 0,
                },
            );
        }
        // The depth where valid, NaN elsewhere; the number of valid pixels.
        let limits = DepthLimits {
            min_m: min_depth_m,
            max_m: max_depth_m,
        };
        tile_max.clear();
        let pixels_valid = match projector {
            // One pass over bands of rows: the rows' valid depths and their pixels' samples.
            Projector::Pinhole { fx, fy, cx, cy } if !samples_on_device => {
                let tiles =
                    width.div_ceil(DEPTH_TILE) * (pixels / width.max(1)).div_ceil(DEPTH_TILE);
                tile_max.resize(tiles, f32::NEG_INFINITY);
                pinhole_samples(PinholeSamples {
                    depth,
                    colour,
                    fx,
                    fy,
                    cx,
                    cy,
                    trunc,
                    limits,
                    depth_m: &mut depth_m,
                    samples: &mut samples,
                    tile_max: &mut tile_max,
                })
            }
            // The valid depths only (a distorted camera's samples follow below; a pinhole
            // camera's are made on the device).
            _ => depth_m
                .par_chunks_mut(4096)
                .zip(depth.data.par_chunks(4096))
                .map(|(out, input)| limits.validate(out, input))
                .sum(),
        };
        let mut view = Self {
            depth,
            depth_m,
            pixels_valid,
            samples: Vec::new(),
            tile_max,
            colour,
            model: *model,
            ray_grid: matches!(projector, Projector::Distorted(..)).then(|| RayGrid::new(model)),
            projector,
            cam_from_world_rotation: rotation,
            cam_from_world_translation: cam_from_world.translation,
            voxel_steps_in_cam: (rotation * f64::from(voxel_size_m)).as_mat3(),
            voxel_size_m,
            truncation_m: trunc,
            max_depth_m,
            max_weight: params.max_weight,
            lanes_fit: depth.width >= 2
                && depth.height >= 2
                && depth.width < 1 << 22
                && depth.height < 1 << 22
                && depth.data.len() < i32::MAX as usize,
        };
        if let Projector::Distorted(..) = view.projector {
            samples
                .par_chunks_mut(width)
                .enumerate()
                .for_each(|(row, out)| {
                    for (col, sample) in out.iter_mut().enumerate() {
                        let pixel = row * width + col;
                        *sample = PixelSample {
                            depth_m: view.depth_m[pixel],
                            weight: view.pixel_weight(col, row),
                            rgb: colour.map_or(0, |c| c.pixels[pixel]),
                        };
                    }
                });
        }
        view.samples = samples;
        view
    }

    /// Hands the per-pixel buffers back for the next frame.
    pub(super) fn into_scratch(self) -> IntegrationScratch {
        IntegrationScratch {
            depth_m: self.depth_m,
            samples: self.samples,
            tile_max: self.tile_max,
        }
    }

    fn ray_z1(&self, col: usize, row: usize) -> Option<DVec3> {
        let pixel = DVec2::new(col as f64, row as f64);
        match (&self.projector, &self.ray_grid) {
            (Projector::Distorted(..), Some(grid)) => grid
                .ray(col, row)
                .or_else(|| self.model.unproject_z1(pixel)),
            (Projector::Distorted(model, _), None) => model.unproject_z1(pixel),
            (Projector::Pinhole { .. }, _) => Some(self.model.intrinsics.unproject_z1(pixel)),
        }
    }

    /// Whether an allocated block may be seen (a conservative test on its bounding box).
    pub(super) fn block_in_view(&self, index: BlockIndex) -> bool {
        let first = index.first_voxel();
        let half = (BLOCK_SIDE as f64 - 1.0) / 2.0;
        let s = f64::from(self.voxel_size_m);
        let centre = DVec3::new(
            first[0] as f64 + half,
            first[1] as f64 + half,
            first[2] as f64 + half,
        ) * s;
        let p = self.cam_from_world_rotation * centre + self.cam_from_world_translation;
        let r = s * BLOCK_SIDE as f64 * 0.5 * 3f64.sqrt();
        if p.z + r <= 0.0 || p.z - r > f64::from(self.max_depth_m + self.truncation_m) {
            return false;
        }
        let Projector::Pinhole { fx, fy, cx, cy } = self.projector else {
            return true;
        };
        if p.z - r <= 1e-3 {
            return true;
        }
        // The range of x / z (and y / z) over the box of half-side r around p.
        let range = |a: f64| {
            let lo = if a - r >= 0.0 {
                (a - r) / (p.z + r)
            } else {
                (a - r) / (p.z - r)
            };
            let hi = if a + r >= 0.0 {
                (a + r) / (p.z - r)
            } else {
                (a + r) / (p.z + r)
            };
            (lo, hi)
        };
        let (x_lo, x_hi) = range(p.x);
        let (y_lo, y_hi) = range(p.y);
        let (w, h) = (f64::from(self.depth.width), f64::from(self.depth.height));
        let (fx, fy, cx, cy) = (f64::from(fx), f64::from(fy), f64::from(cx), f64::from(cy));
        // Either sign of the focal lengths (ICL-NUIM's fy is negative).
        let (u_a, u_b) = (fx * x_lo + cx, fx * x_hi + cx);
        let (v_a, v_b) = (fy * y_lo + cy, fy * y_hi + cy);
        u_a.max(u_b) >= -0.5
            && u_a.min(u_b) <= w - 0.5
            && v_a.max(v_b) >= -0.5
            && v_a.min(v_b) <= h - 0.5
    }

    /// The depth seen at a pixel position and the nearest pixel's offset; `None` outside the
    /// image or where the nearest pixel is invalid.
    fn sample_depth(&self, u: f32, v: f32) -> Option<(f32, usize)> {
        let (width, height) = (self.depth.width as usize, self.depth.height as usize);
        let (w, h) = (width as f32, height as f32);
        if !(u >= -0.5 && v >= -0.5 && u < w - 0.5 && v < h - 0.5) {
            return None;
        }
        let nearest =
            ((v + 0.5) as usize).min(height - 1) * width + ((u + 0.5) as usize).min(width - 1);
        let data = &self.samples;
        // The pixel up and left: `(u + 1) as usize` is floor(u) + 1 for u > -1 (a cast
        // truncates towards zero), cheaper than `floor` on the baseline x86-64.
        let (u1, v1) = ((u + 1.0) as usize, (v + 1.0) as usize);
        if u1 >= 1 && v1 >= 1 && u1 < width && v1 < height {
            let (u0, v0) = ((u1 - 1) as f32, (v1 - 1) as f32);
            let i = (v1 - 1) * width + (u1 - 1);
            let d = [i, i + 1, i + width, i + width + 1].map(|j| data[j].depth_m);
            // All four valid (a NaN makes the sum NaN) and agreeing.
            if !(d[0] + d[1] + d[2] + d[3]).is_nan() {
                let lo = d[0].min(d[1]).min(d[2].min(d[3]));
                let hi = d[0].max(d[1]).max(d[2].max(d[3]));
                if hi - lo < self.truncation_m {
                    let (fu, fv) = (u - u0, v - v0);
                    let top = d[0] + (d[1] - d[0]) * fu;
                    let bottom = d[2] + (d[3] - d[2]) * fu;
                    return Some((top + (bottom - top) * fv, nearest));
                }
            }
        }
        let d = data[nearest].depth_m;
        (!d.is_nan()).then_some((d, nearest))
    }

    /// The weight of one observation through pixel `(col, row)`: the squared cosine between
    /// the pixel's viewing ray and the surface normal there (at least
    /// [`MIN_OBSERVATION_WEIGHT`]), so that grazing views, whose projective distances are
    /// stretched and cut off unevenly on the two sides of a curved surface, count little;
    /// NaN where the pixel is invalid or has no normal (no valid neighbour along a row or
    /// column). Distorted models weigh every observation 1. Made once per pixel (step 0): a
    /// voxel takes the weight of the pixel nearest to its projection, whose ray is within half
    /// a pixel of the voxel's.
    fn pixel_weight(&self, col: usize, row: usize) -> f32 {
        let pixel = row * self.depth.width as usize + col;
        if self.depth_m[pixel].is_nan() {
            return f32::NAN;
        }
        let Projector::Pinhole { fx, fy, cx, cy } = self.projector else {
            return 1.0;
        };
        let Some(normal) = self.normal_at(pixel) else {
            return f32::NAN;
        };
        let ray = Vec3::new((col as f32 - cx) / fx, (row as f32 - cy) / fy, 1.0);
        let cos = normal.dot(ray).abs() / ray.length();
        (cos * cos).max(MIN_OBSERVATION_WEIGHT)
    }

    /// The unit surface normal (camera frame) at a pixel of a pinhole camera, from its
    /// neighbours' points (central differences, one-sided where a neighbour is invalid or
    /// across a depth jump of more than the truncation distance); `None` where a row or
    /// column has no neighbour.
    fn normal_at(&self, pixel: usize) -> Option<Vec3> {
        let width = self.depth.width as usize;
        let height = self.depth.height as usize;
        let (col, row) = (pixel % width, pixel / width);
        let data = &self.depth_m;
        let d = data[pixel];
        let Projector::Pinhole { fx, fy, cx, cy } = self.projector else {
            return None;
        };
        let point = |c: usize, r: usize, depth: f32| {
            Vec3::new((c as f32 - cx) / fx, (r as f32 - cy) / fy, 1.0) * depth
        };
        let near = |c: usize, r: usize| {
            let dn = data[r * width + c];
            // NaN (invalid) fails the comparison.
            ((dn - d).abs() < self.truncation_m).then(|| point(c, r, dn))
        };
        let centre = point(col, row, d);
        let diff = |a: Option<Vec3>, b: Option<Vec3>| match (a, b) {
            (Some(a), Some(b)) => Some(b - a),
            (Some(a), None) => Some(centre - a),
            (None, Some(b)) => Some(b - centre),
            (None, None) => None,
        };
        let du = diff(
            col.checked_sub(1).and_then(|c| near(c, row)),
            (col + 1 < width).then(|| near(col + 1, row)).flatten(),
        )?;
        let dv = diff(
            row.checked_sub(1).and_then(|r| near(col, r)),
            (row + 1 < height).then(|| near(col, row + 1)).flatten(),
        )?;
        du.cross(dv).try_normalize()
    }

    /// The centre of a block's voxel `(0, 0, 0)` in the camera frame (made in f64, so that far
    /// from the world's origin it keeps the precision of a voxel's offset in the block).
    pub(super) fn block_origin_in_cam(&self, index: BlockIndex) -> Vec3 {
        let first = index.first_voxel();
        let origin_in_world = DVec3::new(first[0] as f64, first[1] as f64, first[2] as f64)
            * f64::from(self.voxel_size_m);
        (self.cam_from_world_rotation * origin_in_world + self.cam_from_world_translation).as_vec3()
    }

    /// Step 2 for one block; returns how many voxels it updated.
    fn update_block(&self, index: BlockIndex, block: &mut Block) -> usize {
        let origin = self.block_origin_in_cam(index);
        let [step_x, step_y, step_z] = [
            self.voxel_steps_in_cam.x_axis,
            self.voxel_steps_in_cam.y_axis,
            self.voxel_steps_in_cam.z_axis,
        ];
        let trunc = self.truncation_m;
        let inv_trunc = 1.0 / trunc;
        let mut updated = 0;
        for z in 0..BLOCK_SIDE {
            for y in 0..BLOCK_SIDE {
                let row = origin + step_y * y as f32 + step_z * z as f32;
                for x in 0..BLOCK_SIDE {
                    let point_in_cam = row + step_x * x as f32;
                    let Some((u, v)) = self.projector.project(point_in_cam) else {
                        continue;
                    };
                    let Some((depth_m, pixel)) = self.sample_depth(u, v) else {
                        continue;
                    };
                    let sdf = depth_m - point_in_cam.z;
                    if sdf < -trunc {
                        continue;
                    }
                    let sample = &self.samples[pixel];
                    let weight = sample.weight;
                    if weight.is_nan() {
                        continue;
                    }
                    let offset = Block::voxel_offset(x, y, z);
                    let mut voxel = block.voxel_at_offset(offset);
                    voxel.observe_tsdf((sdf * inv_trunc).min(1.0), weight, self.max_weight);
                    if self.colour.is_some() && sdf.abs() < trunc {
                        let [r, g, b, _] = Rgba8Image::unpack(sample.rgb);
                        voxel.observe_colour([r, g, b], self.max_weight);
                    }
                    block.set_voxel_at_offset(offset, voxel);
                    updated += 1;
                }
            }
        }
        updated
    }
}

#[cfg(test)]
mod tests {
    use glam::{DQuat, DVec3};

    use super::*;
    use crate::fusion::test_scenes::{camera, red_left_blue_right, render_plane};
    use crate::fusion::Mesh;

    /// The pinhole lane path of step 2 (rows of eight voxels, rows behind every depth their
    /// block can read passed over) updates every block exactly as the per-voxel path does: a
    /// sphere before a slanted wall, integrated from one oblique pose, then a second pose's
    /// update of every block in view by both paths on copies of the blocks.
    #[test]
    fn the_lane_path_equals_the_per_voxel_path() {
        use crate::fusion::test_scenes::{look_at, sphere_before_slanted_wall};
        let params = FusionParams {
            voxel_size_m: 0.02,
            ..FusionParams::default()
        };
        let model = camera(320, 240, 280.0);
        let scene = |pose: &RigidTransform| sphere_before_slanted_wall(&model, pose);
        let up = DVec3::new(0.1, -1.0, 0.2);
        let target = DVec3::new(0.0, 0.0, 2.0);
        let first = look_at(DVec3::new(0.7, -0.4, -0.2), target, up);
        let second = look_at(DVec3::new(-0.3, 0.2, 0.1), target, up);
        let colour = red_left_blue_right(320, 240);
        let mut grid = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
        integrate(
            &mut grid,
            &params,
            &scene(&first),
            Some(&colour),
            &model,
            &first,
        )
        .unwrap();
        let depth = scene(&second);
        let scratch = IntegrationScratch::default();
        let view = View::new(
            grid.voxel_size_m(),
            &params,
            &depth,
            Some(&colour),
            &model,
            &second,
            scratch,
            false,
        );
        assert!(view.lanes_fit);
        let (mut blocks, mut voxels) = (0, 0);
        for (index, block) in grid.blocks() {
            if !view.block_in_view(*index) {
                continue;
            }
            let (mut lanes, mut each) = (block.clone(), block.clone());
            let updated = update_block_pinhole(&view, *index, &mut lanes);
            assert_eq!(updated, view.update_block(*index, &mut each), "{index:?}");
            assert!(lanes == each, "block {index:?} differs");
            blocks += 1;
            voxels += updated;
        }
        assert!(
            blocks > 300 && voxels > 50_000,
            "{blocks} blocks, {voxels} voxels"
        );
    }

    /// Fusion's vectorised builds (`simd::vectorised_fn!`: allocation, the voxel update, the
    /// mesher's sign scan) give the same grid and mesh as the portable one, as the sweep's do
    /// (`tests/engine/gpu_vs_cpu.rs`): three views of a sphere before a slanted wall, one
    /// through a distorted lens, with colour and per-pixel weights, integrated and meshed with
    /// the builds capped at each tier in turn; every voxel and every vertex compared bit for
    /// bit.
    #[test]
    fn fusion_builds_give_the_same_grid_and_mesh() {
        use crate::fusion::test_scenes::{look_at, sphere_before_slanted_wall};
        use crate::simd::{cap, Tier};
        let params = FusionParams {
            voxel_size_m: 0.02,
            ..FusionParams::default()
        };
        let pinhole = camera(320, 240, 280.0);
        let mut distorted = pinhole;
        distorted.distortion = Distortion::PlumbBob {
            k1: -0.1,
            k2: 0.01,
            p1: 0.0,
            p2: 0.0,
            k3: 0.0,
        };
        let up = DVec3::new(0.1, -1.0, 0.2);
        let target = DVec3::new(0.0, 0.0, 2.0);
        let views = [
            (pinhole, look_at(DVec3::new(0.7, -0.4, -0.2), target, up)),
            (pinhole, look_at(DVec3::new(-0.3, 0.2, 0.1), target, up)),
            (distorted, look_at(DVec3::new(0.2, 0.5, -0.3), target, up)),
        ];
        let colour = red_left_blue_right(320, 240);
        let run = |tier: Option<Tier>| {
            cap(tier);
            let mut grid = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
            for (i, (model, pose)) in views.iter().enumerate() {
                let depth = sphere_before_slanted_wall(model, pose);
                // Weights that vary across the image (and a band of invalid ones).
                let weights = ImageF32 {
                    width: depth.width,
                    height: depth.height,
                    data: (0..depth.data.len())
                        .map(|p| match (p + 37 * i) % 97 {
                            0 => f32::NAN,
                            k => 0.25 + k as f32 / 50.0,
                        })
                        .collect(),
                };
                integrate_weighted(
                    &mut grid,
                    &params,
                    &depth,
                    Some(&weights),
                    Some(&colour),
                    model,
                    pose,
                )
                .unwrap();
            }
            let mut mesh = Mesh::new();
            mesh.update(&mut grid);
            cap(None);
            let mut blocks: Vec<(BlockIndex, Block)> =
                grid.blocks().map(|(i, b)| (*i, b.clone())).collect();
            blocks.sort_unstable_by_key(|(i, _)| *i);
            (blocks, mesh.collect())
        };
        let (widest_blocks, widest_mesh) = run(None);
        assert!(widest_blocks.len() > 300, "{} blocks", widest_blocks.len());
        assert!(widest_mesh.vertices.len() > 10_000);
        for tier in [Tier::Avx2, Tier::Portable] {
            let (blocks, mesh) = run(Some(tier));
            assert_eq!(blocks.len(), widest_blocks.len(), "{tier:?}: blocks");
            let differing = blocks
                .iter()
                .zip(&widest_blocks)
                .filter(|(a, b)| a.0 != b.0 || a.1 != b.1)
                .count();
            assert_eq!(differing, 0, "{tier:?}: {differing} blocks differ");
            let bits = |m: &crate::fusion::mesh::BlockMesh| -> Vec<u32> {
                m.vertices.iter().flatten().map(|c| c.to_bits()).collect()
            };
            assert_eq!(bits(&mesh), bits(&widest_mesh), "{tier:?}: vertices");
            assert_eq!(mesh.triangles, widest_mesh.triangles, "{tier:?}: triangles");
            assert_eq!(mesh.colours, widest_mesh.colours, "{tier:?}: colours");
        }
    }

    fn wall(z_m: f64) -> (CameraModel, ImageF32) {
        let model = camera(320, 240, 300.0);
        let depth = render_plane(&model, &RigidTransform::IDENTITY, DVec3::Z, z_m);
        (model, depth)
    }

    /// Mesh vertices in the middle of the view (|x|, |y| < 0.5 m), by their z.
    fn middle_vertex_depths(mesh: &Mesh) -> Vec<f32> {
        let all = mesh.collect();
        all.vertices
            .iter()
            .filter(|v| v[0].abs() < 0.5 && v[1].abs() < 0.5)
            .map(|v| v[2])
            .collect()
    }

    #[test]
    fn bad_input_is_refused_without_touching_the_grid() {
        let params = FusionParams::default();
        let (model, depth) = wall(3.0);
        let mut grid = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
        let pose = RigidTransform::IDENTITY;
        let nan_translation = RigidTransform {
            translation: DVec3::new(0.0, f64::NAN, 0.0),
            ..pose
        };
        let nan_rotation = RigidTransform {
            rotation: DQuat::from_xyzw(f64::NAN, 0.0, 0.0, 1.0),
            ..pose
        };
        let scaled_rotation = RigidTransform {
            rotation: DQuat::from_xyzw(0.0, 0.0, 0.0, 2.0),
            ..pose
        };
        for bad in [nan_translation, nan_rotation, scaled_rotation] {
            let err = integrate(&mut grid, &params, &depth, None, &model, &bad).unwrap_err();
            assert!(matches!(err, FusionError::Pose(_)), "{err}");
        }
        let small_colour = red_left_blue_right(160, 120);
        let err = integrate(
            &mut grid,
            &params,
            &depth,
            Some(&small_colour),
            &model,
            &pose,
        )
        .unwrap_err();
        assert!(
            matches!(
                err,
                FusionError::ImageSize {
                    what: "colour image",
                    ..
                }
            ),
            "{err}"
        );
        let small_depth = ImageF32 {
            width: 10,
            height: 10,
            data: vec![1.0; 100],
        };
        let err = integrate(&mut grid, &params, &small_depth, None, &model, &pose).unwrap_err();
        assert!(matches!(err, FusionError::ImageSize { .. }), "{err}");
        let short = ImageF32 {
            data: vec![1.0; 5],
            ..depth.clone()
        };
        assert!(integrate(&mut grid, &params, &short, None, &model, &pose).is_err());
        for voxel_size_m in [0.0, -0.05, f32::NAN] {
            let bad = FusionParams {
                voxel_size_m,
                ..params
            };
            let err = integrate(&mut grid, &bad, &depth, None, &model, &pose).unwrap_err();
            assert!(matches!(err, FusionError::InvalidParams(_)), "{err}");
            assert!(VoxelBlockGrid::new(voxel_size_m).is_err());
        }
        let other_size = FusionParams {
            voxel_size_m: 0.1,
            ..params
        };
        let err = integrate(&mut grid, &other_size, &depth, None, &model, &pose).unwrap_err();
        assert!(
            matches!(err, FusionError::VoxelSizeMismatch { .. }),
            "{err}"
        );
        for bad in [
            FusionParams {
                truncation_voxels: 0.5,
                ..params
            },
            FusionParams {
                max_weight: 0.0,
                ..params
            },
            FusionParams {
                min_depth_m: 11.0,
                ..params
            },
        ] {
            assert!(bad.validate().is_err());
        }
        let mut no_focal = model;
        no_focal.intrinsics.fx_px = 0.0;
        let err = integrate(&mut grid, &params, &depth, None, &no_focal, &pose).unwrap_err();
        assert!(matches!(err, FusionError::Camera(_)), "{err}");
        assert!(grid.is_empty());
        assert!(grid.changed_blocks().is_empty());
    }

    #[test]
    fn stats_count_what_was_done_and_invalid_pixels_add_nothing() {
        let params = FusionParams::default();
        let (model, depth) = wall(3.0);
        let pose = RigidTransform::IDENTITY;
        let mut grid = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
        let first = integrate(&mut grid, &params, &depth, None, &model, &pose).unwrap();
        assert_eq!(first.pixels_valid, 320 * 240);
        assert_eq!(first.blocks_allocated, grid.block_count());
        assert!(first.blocks_updated > 0 && first.blocks_updated <= first.blocks_in_view);
        assert!(first.voxels_updated > first.blocks_updated);
        assert_eq!(grid.changed_blocks().len(), first.blocks_updated);
        // The wall's voxel at the surface: tsdf ~ 0, one observation at the image centre.
        let at = grid.voxel_at(DVec3::new(0.0, 0.0, 3.0)).unwrap();
        assert!(
            at.tsdf.abs() < 1e-3 && (at.weight - 1.0).abs() < 1e-3,
            "{at:?}"
        );
        let behind = grid.voxel_at(DVec3::new(0.0, 0.0, 3.1)).unwrap();
        assert!((behind.tsdf + 0.5).abs() < 1e-3, "{behind:?}");
        // Again: nothing new to allocate. Then an all-invalid map and one beyond max_depth.
        let second = integrate(&mut grid, &params, &depth, None, &model, &pose).unwrap();
        assert_eq!(second.blocks_allocated, 0);
        assert_eq!(second.voxels_updated, first.voxels_updated);
        let nothing = ImageF32 {
            data: vec![f32::NAN; 320 * 240],
            ..depth.clone()
        };
        let (_, far) = wall(12.0);
        for empty in [&nothing, &far] {
            let stats = integrate(&mut grid, &params, empty, None, &model, &pose).unwrap();
            assert_eq!(
                (
                    stats.pixels_valid,
                    stats.blocks_allocated,
                    stats.voxels_updated
                ),
                (0, 0, 0)
            );
        }
    }

    #[test]
    fn a_wall_moving_away_is_followed_within_the_weight_cap() {
        // 10 frames of a wall at 2.5 m, then 5 at 3 m: with the cap at 4 observations the old
        // surface is carved away (its blocks are in view, in front of the new wall) and the
        // new one is meshed; with a cap of 64 the old one still outweighs the new frames.
        let run = |max_weight: f32| {
            let params = FusionParams {
                max_weight,
                ..FusionParams::default()
            };
            let pose = RigidTransform::IDENTITY;
            let mut grid = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
            let mut mesh = Mesh::new();
            let (model, near) = wall(2.5);
            let (_, far) = wall(3.0);
            for _ in 0..10 {
                integrate(&mut grid, &params, &near, None, &model, &pose).unwrap();
            }
            mesh.update(&mut grid);
            let before = middle_vertex_depths(&mesh);
            for _ in 0..5 {
                integrate(&mut grid, &params, &far, None, &model, &pose).unwrap();
            }
            mesh.update(&mut grid);
            (before, middle_vertex_depths(&mesh))
        };
        let near = |zs: &[f32], z: f32| zs.iter().filter(|v| (*v - z).abs() < 0.05).count();
        let (before, after) = run(4.0);
        assert!(near(&before, 2.5) > 100 && near(&before, 3.0) == 0);
        assert!(
            after.iter().all(|z| *z > 2.8),
            "the old wall is still there"
        );
        assert!(near(&after, 3.0) > 100);
        assert!(after.iter().all(|z| (z - 3.0).abs() < 0.0125));
        // With a cap of 64 the old wall's zero crossing has only begun to move (to 2.6 m).
        let (_, slow) = run(64.0);
        let old_wall = slow.iter().filter(|z| **z < 2.8).count();
        assert!(old_wall > 100, "the old wall went without the cap");
    }

    #[test]
    fn a_wall_moving_closer_appears_in_front_of_the_hidden_old_one() {
        // 10 frames at 3 m, then 2.5 m with a cap of 4: the new wall is meshed at once; the
        // old one, now hidden behind it (more than the truncation distance), is not seen and
        // stays, as in nvblox and voxblox.
        let params = FusionParams {
            max_weight: 4.0,
            ..FusionParams::default()
        };
        let pose = RigidTransform::IDENTITY;
        let mut grid = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
        let mut mesh = Mesh::new();
        let (model, far) = wall(3.0);
        let (_, near) = wall(2.5);
        for _ in 0..10 {
            integrate(&mut grid, &params, &far, None, &model, &pose).unwrap();
        }
        for _ in 0..5 {
            integrate(&mut grid, &params, &near, None, &model, &pose).unwrap();
        }
        mesh.update(&mut grid);
        let zs = middle_vertex_depths(&mesh);
        let count = |z: f32| zs.iter().filter(|v| (*v - z).abs() < 0.0125).count();
        assert!(count(2.5) > 100 && count(3.0) > 100);
        assert_eq!(count(2.5) + count(3.0), zs.len());
    }

    #[test]
    fn a_long_trajectory_stays_within_max_blocks_and_dropped_blocks_leave_the_mesh() {
        // A camera sliding 20 m along a wall 3 m away, 0.25 m per frame: about 100 blocks per
        // view, 120 kept at most (the wall's 4.8 m around the camera).
        let params = FusionParams {
            max_blocks: 120,
            ..FusionParams::default()
        };
        let model = camera(320, 240, 300.0);
        let mut grid = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
        let mut mesh = Mesh::new();
        let (mut dropped, mut removed) = (0, Vec::new());
        for i in 0..80 {
            let pose = RigidTransform {
                translation: DVec3::new(0.25 * f64::from(i), 0.0, 0.0),
                ..RigidTransform::IDENTITY
            };
            let depth = render_plane(&model, &pose, DVec3::Z, 3.0);
            let stats = integrate(&mut grid, &params, &depth, None, &model, &pose).unwrap();
            assert!(grid.block_count() <= params.max_blocks, "{stats:?}");
            dropped += stats.blocks_dropped;
            if i % 3 == 0 {
                let before: Vec<BlockIndex> = grid.removed_blocks().iter().copied().collect();
                let stats = mesh.update(&mut grid);
                assert!(grid.removed_blocks().is_empty());
                assert_eq!(stats.blocks_removed, mesh.removed().len());
                for index in mesh.removed() {
                    assert!(before.contains(index) && !grid.contains(*index));
                    assert!(mesh.block(*index).is_none());
                }
                removed.extend_from_slice(mesh.removed());
                // Every meshed block is still in the grid.
                assert!(mesh.blocks().all(|(index, _)| grid.contains(*index)));
            }
            // What is left is near the camera: nothing beyond the farthest block a view holds.
            let x = pose.translation.x as f32;
            for (index, _) in grid.blocks() {
                let bx = (index.0[0] as f32 + 0.5) * grid.block_size_m();
                assert!(
                    (bx - x).abs() < 4.0,
                    "block {index:?} at x {bx}, camera at {x}"
                );
            }
        }
        assert!(dropped > 1000, "{dropped} dropped");
        assert!(removed.len() > 100, "{} meshes removed", removed.len());
        // The incremental mesh is the mesh of what the grid holds.
        mesh.update(&mut grid);
        let mut scratch = Mesh::new();
        let full = scratch.rebuild(&grid);
        assert_eq!(mesh.triangle_count(), full.triangles);
        assert!(full.triangles > 1000);
        // Unbounded: everything stays.
        let unbounded = FusionParams {
            max_blocks: 0,
            ..params
        };
        let mut all = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
        for i in 0..20 {
            let pose = RigidTransform {
                translation: DVec3::new(0.5 * f64::from(i), 0.0, 0.0),
                ..RigidTransform::IDENTITY
            };
            let depth = render_plane(&model, &pose, DVec3::Z, 3.0);
            let stats = integrate(&mut all, &unbounded, &depth, None, &model, &pose).unwrap();
            assert_eq!(stats.blocks_dropped, 0);
        }
        assert!(all.block_count() > 250);
    }

    #[test]
    fn one_depth_map_never_allocates_past_max_blocks() {
        // A wall 3 m away seen by two poses a metre apart: the blocks one view's band crosses,
        // unbounded, then with a bound of half of them.
        let model = camera(320, 240, 300.0);
        let poses = [0.0, 1.0].map(|x| RigidTransform {
            translation: DVec3::new(x, 0.2, 0.0),
            ..RigidTransform::IDENTITY
        });
        let unbounded = FusionParams {
            max_blocks: 0,
            ..FusionParams::default()
        };
        let mut all = VoxelBlockGrid::new(unbounded.voxel_size_m).unwrap();
        let depth = render_plane(&model, &poses[0], DVec3::Z, 3.0);
        let n = integrate(&mut all, &unbounded, &depth, None, &model, &poses[0])
            .unwrap()
            .blocks_allocated;
        assert!(n > 60, "{n} blocks");
        let bound = FusionParams {
            max_blocks: n / 2,
            ..unbounded
        };
        let mut grid = VoxelBlockGrid::new(bound.voxel_size_m).unwrap();
        // What dropping the farthest after an unbounded update keeps, frame by frame.
        let mut reference = VoxelBlockGrid::new(bound.voxel_size_m).unwrap();
        let keys = |g: &VoxelBlockGrid| {
            let mut k: Vec<BlockIndex> = g.blocks().map(|(index, _)| *index).collect();
            k.sort_unstable();
            k
        };
        for (i, pose) in poses.iter().enumerate() {
            let depth = render_plane(&model, pose, DVec3::Z, 3.0);
            let stats = integrate(&mut grid, &bound, &depth, None, &model, pose).unwrap();
            // Never more blocks than the bound, even between dropping and allocating (the
            // second frame holds the first's blocks when it starts).
            assert!(
                stats.blocks_peak <= bound.max_blocks,
                "frame {i}: {stats:?}"
            );
            assert!(
                stats.blocks_peak >= stats.blocks_allocated,
                "frame {i}: {stats:?}"
            );
            assert_eq!(grid.block_count(), bound.max_blocks, "frame {i}");
            let all = integrate(&mut reference, &unbounded, &depth, None, &model, pose).unwrap();
            let gone = reference.drop_farthest(bound.max_blocks, pose.translation);
            assert_eq!(keys(&grid), keys(&reference), "frame {i}");
            assert_eq!(stats.blocks_dropped, gone, "frame {i}");
            // The new blocks dropping would remove at once were never made.
            assert!(
                stats.blocks_allocated < all.blocks_allocated,
                "frame {i}: {stats:?}"
            );
        }
        // The same voxels, so the same surface.
        let (mut a, mut b) = (Mesh::new(), Mesh::new());
        assert_eq!(a.rebuild(&grid).triangles, b.rebuild(&reference).triangles);
    }

    #[test]
    fn a_distorted_camera_integrates_through_its_model() {
        let params = FusionParams::default();
        let mut model = camera(160, 120, 150.0);
        model.distortion = Distortion::PlumbBob {
            k1: -0.1,
            k2: 0.01,
            p1: 0.0,
            p2: 0.0,
            k3: 0.0,
        };
        let pose = RigidTransform::IDENTITY;
        let depth = render_plane(&model, &pose, DVec3::Z, 3.0);
        let mut grid = VoxelBlockGrid::new(params.voxel_size_m).unwrap();
        let colour = red_left_blue_right(160, 120);
        integrate(&mut grid, &params, &depth, Some(&colour), &model, &pose).unwrap();
        let mut mesh = Mesh::new();
        mesh.update(&mut grid);
        let all = mesh.collect();
        assert!(all.triangles.len() > 1000);
        // The grid's interpolated rays agree with the exact ones.
        let rays = RayGrid::new(&model);
        for (col, row) in [(0, 0), (3, 5), (77, 61), (159, 119), (150, 4)] {
            let exact = model
                .unproject_z1(DVec2::new(col as f64, row as f64))
                .unwrap();
            let near = rays.ray(col, row).unwrap();
            assert!(
                (exact - near).length() < 1e-3,
                "{col} {row}: {exact} {near}"
            );
        }
        assert!(all.vertices.iter().all(|v| (v[2] - 3.0).abs() < 0.0125));
    }
}
