//! "What to run": everything a sweep needs, packed once per rig + parameters into the exact
//! arrays the shaders read. Both engines consume a [`SweepPlan`], so the CPU twin reads the same
//! numbers the GPU does.

use bytemuck::Zeroable;
use glam::DVec2;

use super::gpu_types::*;
use super::{
    check_images, Aggregation, Cost, HypothesisGenerator, Optimizer, PairSet, Scoring, SweepError,
    SweepParams, WantedMaps, WindowMode,
};
use crate::geometry::{CameraModel, Distortion, Rig};
use crate::image::Rgba8Image;

/// Columns per tile of the plane ranges (coarse to fine narrows each row's planes per tile of
/// this many columns: docs/notes/speed-history.md, "How much plane ranges per tile would save").
pub const RANGE_TILE: u32 = 16;

/// Tiles of plane ranges across a reference `width` pixels wide.
pub fn range_tiles(width: u32) -> u32 {
    width.div_ceil(RANGE_TILE)
}

#[derive(Debug, Clone, PartialEq)]
pub struct SweepPlan {
    /// Unique per constructed plan; engines re-upload the arrays when it changes. Build a new
    /// plan rather than editing one in place.
    pub id: u64,
    pub params: GpuParams,
    pub cameras: Vec<GpuCamera>,
    /// Plane k as (normal_in_ref, offset_m).
    pub planes: Vec<[f32; 4]>,
    /// The camera pairs in the order the cost stage enumerates them: (camera a, camera b, half, 0).
    pub pairs: Vec<[u32; 4]>,
    /// The z = 1 ray of every reference pixel, in the reference frame (undistorted).
    pub rays: Vec<[f32; 4]>,
    /// The reference camera model `rays` were made from (they depend on it alone): the WGSL
    /// engine uploads them again only when it changes (several references of one rig share
    /// buffers and, with equal intrinsics, their rays).
    pub ray_model: crate::geometry::CameraModel,
    /// Per reference row and tile of [`RANGE_TILE`] columns (row-major: index
    /// `y * range_tiles(width) + x / RANGE_TILE`), the planes its pixels sweep (first, last;
    /// inclusive): a plane outside a pixel's range scores BIG there (no hypothesis), and the
    /// engines make no costs that no pixel's windows read. Every plane everywhere unless
    /// narrowed ([`SweepPlan::set_plane_ranges`], coarse to fine).
    pub plane_ranges: Vec<[u32; 2]>,
    /// The ranges as the shaders read them ([`SweepPlan::shader_plane_ranges`]), made when
    /// the ranges are set.
    tile_ranges: Vec<[u32; 4]>,
    /// Whether some tile sweeps fewer than every plane.
    narrowed: bool,
    /// Total pixels of all camera images (image buffer and z-buffer length).
    pub total_camera_pixels: usize,
    pub width: u32,
    pub height: u32,
}

/// A new plan's id.
fn next_plan_id() -> u64 {
    static NEXT_ID: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);
    NEXT_ID.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
}

/// Each camera of `rig` as the shaders read it (its pose relative to the reference,
/// intrinsics, distortion, half of the rig, where its pixels start in the images buffer), and
/// the pixels of every camera together.
fn gpu_cameras(rig: &Rig) -> Result<(Vec<GpuCamera>, u32), SweepError> {
    let split = rig.half_sequence_split();
    let reference = rig.reference_index();
    let mut offset = 0u32;
    let mut cameras = Vec::with_capacity(rig.cameras.len());
    for (i, camera) in rig.cameras.iter().enumerate() {
        let cam_from_ref = rig.cam_from_ref(i);
        let r = cam_from_ref.rotation_matrix();
        let t = cam_from_ref.translation;
        let k = &camera.model.intrinsics;
        // The end of the model's monotonic branch, as (x/z)² + (y/z)² (f32::MAX: none).
        let branch_r2 = {
            let r = camera.model.distortion.max_undistorted_radius();
            if r.is_finite() {
                (r * r) as f32
            } else {
                f32::MAX
            }
        };
        let (model, dist_a, dist_b) = match camera.model.distortion {
            Distortion::None => (DIST_NONE, [0.0; 4], [0.0, f32::MAX, 0.0, 0.0]),
            Distortion::PlumbBob { k1, k2, p1, p2, k3 } => (
                DIST_PLUMB_BOB,
                [k1 as f32, k2 as f32, p1 as f32, p2 as f32],
                [k3 as f32, branch_r2, 0.0, 0.0],
            ),
            Distortion::Equidistant { k1, k2, k3, k4 } => (
                DIST_EQUIDISTANT,
                [k1 as f32, k2 as f32, k3 as f32, k4 as f32],
                [0.0, branch_r2, 0.0, 0.0],
            ),
        };
        let half = match split[i] {
            None => HALF_REFERENCE,
            Some(false) => HALF_LEFT,
            Some(true) => HALF_RIGHT,
        };
        let row = |j: usize, tj: f64| {
            [
                r.row(j).x as f32,
                r.row(j).y as f32,
                r.row(j).z as f32,
                tj as f32,
            ]
        };
        cameras.push(GpuCamera {
            row0: row(0, t.x),
            row1: row(1, t.y),
            row2: row(2, t.z),
            intrinsics: [
                k.fx_px as f32,
                k.fy_px as f32,
                k.cx_px as f32,
                k.cy_px as f32,
            ],
            dist_a,
            dist_b,
            size: [k.width_px, k.height_px, offset, model],
            info: [half, u32::from(Some(i) == reference), 0, 0],
        });
        offset = offset
            .checked_add(k.width_px * k.height_px)
            .ok_or_else(|| SweepError::InvalidParams("camera images too large".into()))?;
    }
    Ok((cameras, offset))
}

/// The reference's ray through each pixel centre, z = 1 (padded to four floats).
fn reference_rays(ref_model: &CameraModel) -> Vec<[f32; 4]> {
    let (width, height) = (
        ref_model.intrinsics.width_px,
        ref_model.intrinsics.height_px,
    );
    // A pixel without a ray (a fisheye's beyond 90 degrees) gets the zero ray: no plane is
    // in front along it, so it stays invalid in every stage. (The model's rays are shared:
    // a moving rig makes a plan per pose.)
    let grid = ref_model.distorted_pixel_rays();
    let mut rays = Vec::with_capacity(width as usize * height as usize);
    for y in 0..height {
        for x in 0..width {
            let ray = match &grid {
                Some(grid) => grid.get(rays.len()).copied().flatten(),
                None => ref_model.unproject_z1(DVec2::new(f64::from(x), f64::from(y))),
            };
            rays.push(ray.map_or([0.0; 4], |r| [r.x as f32, r.y as f32, 1.0, 0.0]));
        }
    }
    rays
}

/// The camera pairs whose costs are made (`pairs`: those of the reference, or all), each
/// with the half of the rig it belongs to (`[a, b, half, 0]`).
fn pair_table(cameras: &[GpuCamera], reference: Option<usize>, pairs: u32) -> Vec<[u32; 4]> {
    let halves: Vec<u32> = cameras.iter().map(|c| c.info[0]).collect();
    let pair_half = |a: u32, b: u32| {
        if a == HALF_REFERENCE {
            b
        } else if b == HALF_REFERENCE || a == b {
            a
        } else {
            HALF_REFERENCE
        }
    };
    let mut pair_table = Vec::new();
    let n = cameras.len() as u32;
    if pairs == PAIRS_REFERENCE {
        let r = reference.map_or(NO_CAMERA, |i| i as u32);
        for i in (0..n).filter(|&i| i != r) {
            pair_table.push([r, i, halves[i as usize], 0]);
        }
    } else {
        for i in 0..n {
            for j in i + 1..n {
                pair_table.push([i, j, pair_half(halves[i as usize], halves[j as usize]), 0]);
            }
        }
    }
    pair_table
}

/// SGM's parameters in the units the shaders read (volume levels); at most
/// [`MAX_SGM_PLANES`] `planes`. A virtual reference (no `has_image`) keeps P2 constant.
fn set_sgm_params(
    gpu_params: &mut GpuParams,
    params: &SweepParams,
    has_image: bool,
    planes: usize,
) -> Result<(), SweepError> {
    if planes > MAX_SGM_PLANES as usize {
        return Err(SweepError::InvalidParams(format!(
            "optimizer sgm supports at most {MAX_SGM_PLANES} planes; the hypothesis generator gave {}",
            planes
        )));
    }
    // Scores run from -SGM_VOLUME_OFFSET (the half-sequence's smooth minimum) to tau.
    let levels_per_unit = SGM_COST_MAX as f32 / (params.tau + SGM_VOLUME_OFFSET);
    let level = |v: f32| (v * levels_per_unit + 0.5).floor() as u32;
    let p1 = level(params.sgm_p1);
    let p2 = level(params.sgm_p2).max(p1);
    // Virtual references have no image: P2 stays constant.
    let edge = if has_image {
        (params.sgm_edge * SGM_EDGE_UNITS + 0.5).floor() as u32
    } else {
        0
    };
    gpu_params.sgm_paths = params.sgm_paths;
    gpu_params.sgm_p1 = p1;
    gpu_params.sgm_p2 = p2;
    gpu_params.sgm_edge = edge;
    gpu_params.sgm_levels_per_unit = levels_per_unit;
    gpu_params.sgm_unit_per_level = 1.0 / (params.sgm_paths as f32 * levels_per_unit);
    Ok(())
}

/// Planes either side of a winner that are not its rivals on the matching costs
/// ([`GpuParams::uniqueness_radius`]): [`UNIQUENESS_RADIUS_PX`] of shift in the view that shifts
/// most per plane, measured along the reference's central ray over the depth range (planes
/// even in inverse depth shift evenly), at least 1.
/// Plane steps by which a surface in another camera's z-buffer must be nearer than a reference
/// pixel's own depth, besides `occlusion_tolerance`, to hide it: neighbouring reference pixels
/// whose depths differ by less than a plane (the depth's own noise, a slanted surface) land on
/// one texel of a camera, and the farther is no more occluded than the nearer. With the relative
/// tolerance alone real slanted ground in a pair had holes a pixel wide all over it (ETH3D
/// playground: 3.9 % of its pixels invalid, 2.7 % with two plane steps; docs/quality.md).
pub const OCCLUSION_PLANES: f64 = 2.0;

/// [`OCCLUSION_PLANES`] steps of `planes` planes spread evenly in inverse depth over the
/// depth range, in 1/m (the plane families spread their planes so; the step is the family's
/// mean where it does not).
fn occlusion_inverse_depth(params: &SweepParams, planes: usize) -> f32 {
    let span = 1.0 / params.min_depth_m - 1.0 / params.max_depth_m;
    (OCCLUSION_PLANES * span.abs() / planes.saturating_sub(1).max(1) as f64) as f32
}

fn uniqueness_radius(rig: &Rig, params: &SweepParams, planes: usize) -> u32 {
    match rig.widest_shift_per_plane(params.min_depth_m, params.max_depth_m, planes) {
        Some((_, per_plane)) if per_plane > 0.0 => {
            ((UNIQUENESS_RADIUS_PX / per_plane).ceil() as u32).clamp(1, planes as u32)
        }
        _ => 1,
    }
}

impl SweepPlan {
    /// Plans a sweep with the default hypotheses of `params` (uniform inverse depth).
    pub fn new(rig: &Rig, params: &SweepParams) -> Result<Self, SweepError> {
        Self::with_hypotheses(rig, params, &params.hypotheses())
    }

    pub fn with_hypotheses(
        rig: &Rig,
        params: &SweepParams,
        hypotheses: &dyn HypothesisGenerator,
    ) -> Result<Self, SweepError> {
        params.validate(rig)?;
        let planes: Vec<[f32; 4]> = hypotheses.planes().iter().map(|p| p.to_gpu()).collect();
        if planes.len() < 2 {
            return Err(SweepError::InvalidParams(format!(
                "the hypothesis generator gave {} planes; at least 2 are needed",
                planes.len()
            )));
        }
        let reference = rig.reference_index();
        let (cameras, offset) = gpu_cameras(rig)?;

        let ref_model = rig.reference_model();
        let width = ref_model.intrinsics.width_px;
        let height = ref_model.intrinsics.height_px;
        let rays = reference_rays(&ref_model);

        let scoring = match params.scoring {
            Scoring::Sssd | Scoring::AllPairs => SCORING_SSSD,
            Scoring::BestNOfM => SCORING_BEST_N,
            Scoring::BestHalfSequence => SCORING_HALF,
        };
        let pairs = match params.effective_pairs() {
            PairSet::Reference => PAIRS_REFERENCE,
            PairSet::All => PAIRS_ALL,
        };
        let pair_table = pair_table(&cameras, reference, pairs);
        // The halves score only the pairs on one side of the reference. A virtual reference
        // beside the last camera of its side has no pair on that side: that half is empty and
        // the pairs that straddle the virtual camera (in neither half) would go unused, so the
        // half-sequence scores best n of m over all pairs there (docs/engine.md, Virtual
        // references).
        let half_empty = |side: u32| !pair_table.iter().any(|p| p[2] == side);
        let straddling = pair_table.iter().any(|p| p[2] == HALF_REFERENCE);
        let scoring = if scoring == SCORING_HALF
            && straddling
            && (half_empty(HALF_LEFT) || half_empty(HALF_RIGHT))
        {
            SCORING_BEST_N
        } else {
            scoring
        };
        let aggregation = match params.aggregation {
            Aggregation::Scored => AGG_SCORED,
            Aggregation::PerHalf => AGG_PER_HALF,
            Aggregation::PerPair => AGG_PER_PAIR,
        };
        let channels = if aggregation == AGG_PER_PAIR {
            pair_table.len() as u32
        } else if scoring == SCORING_HALF && aggregation == AGG_SCORED {
            3
        } else if scoring == SCORING_HALF {
            2
        } else {
            1
        };
        let mut gpu_params = GpuParams {
            width,
            height,
            pixel_count: width * height,
            reference: reference.map_or(NO_CAMERA, |i| i as u32),
            cameras: rig.cameras.len() as u32,
            planes: planes.len() as u32,
            channels,
            half_best_n: params.half_best_n,
            scoring,
            pair_mode: pairs,
            best_n: params
                .best_n
                .clamp(1, MAX_BEST_N)
                .min(pair_table.len().max(1) as u32),
            aggregation,
            window_w: params.window_width,
            window_h: params.window_height,
            subpixel: match (params.subpixel, params.subpixel_refine) {
                (false, _) => SUBPIXEL_OFF,
                (true, false) => SUBPIXEL_PARABOLA,
                (true, true) => SUBPIXEL_REFINE,
            } | if params.subpixel && params.subpixel_v_fit {
                SUBPIXEL_V_FIT
            } else {
                0
            },
            median: u32::from(params.median),
            tau: params.tau,
            max_cost: params.max_cost,
            occlusion_tolerance: params.occlusion_tolerance,
            occlusion_inverse_depth: occlusion_inverse_depth(params, planes.len()),
            half_margin: params.half_margin,
            min_visible: params.min_visible_cameras,
            window_mode: match params.window_mode {
                WindowMode::Shiftable => WINDOW_SHIFTABLE,
                WindowMode::Centred => WINDOW_CENTRED,
            },
            padded_w: width + params.window_width - 1,
            padded_h: height + params.window_height - 1,
            cost: match params.cost {
                Cost::Tssd => COST_TSSD,
                Cost::Census => COST_CENSUS,
                Cost::AdCensus => COST_AD_CENSUS,
            },
            census_offset: if params.cost == Cost::Tssd { 0 } else { offset },
            uniqueness: params.uniqueness,
            ambiguity: params.ambiguity,
            uniqueness_radius: uniqueness_radius(rig, params, planes.len()),
            keep_range_ends: u32::from(params.keep_range_ends),
            colour_in_alpha: u32::from(params.prefilter.applies(rig.cameras.len())),
            ..GpuParams::zeroed()
        };
        if params.optimizer == Optimizer::Sgm {
            set_sgm_params(&mut gpu_params, params, reference.is_some(), planes.len())?;
        }
        let last_plane = planes.len() as u32 - 1;
        let tiles = (range_tiles(width) * height) as usize;
        Ok(Self {
            id: next_plan_id(),
            params: gpu_params,
            cameras,
            planes,
            pairs: pair_table,
            rays,
            ray_model: ref_model,
            total_camera_pixels: offset as usize,
            plane_ranges: vec![[0, last_plane]; tiles],
            tile_ranges: vec![[0, last_plane, 0, last_plane]; tiles],
            narrowed: false,
            width,
            height,
        })
    }

    /// Narrows each (row, tile) to its range in `ranges` (first, last plane, inclusive; the
    /// layout of [`SweepPlan::plane_ranges`]). The ranges are not part of the plan's id: the
    /// engines read them on every run (a coarse-to-fine sweep sets new ones on the same plan
    /// every frame set).
    pub fn set_plane_ranges(&mut self, ranges: Vec<[u32; 2]>) -> Result<(), SweepError> {
        let planes = self.num_planes();
        let tiles = range_tiles(self.width) as usize;
        if ranges.len() != self.height as usize * tiles {
            return Err(SweepError::InvalidParams(format!(
                "{} plane ranges; a {}x{} reference has {} (rows x tiles of {RANGE_TILE} columns)",
                ranges.len(),
                self.width,
                self.height,
                self.height as usize * tiles
            )));
        }
        if let Some((i, r)) = ranges
            .iter()
            .enumerate()
            .find(|(_, r)| r[0] > r[1] || r[1] >= planes)
        {
            return Err(SweepError::InvalidParams(format!(
                "row {}, tile {}: plane range {}..={} is not within 0..{planes}",
                i / tiles,
                i % tiles,
                r[0],
                r[1]
            )));
        }
        self.tile_ranges = tile_hulls(&ranges, tiles, &self.params);
        self.narrowed = ranges.iter().any(|r| *r != [0, planes - 1]);
        self.plane_ranges = ranges;
        Ok(())
    }

    /// A copy of the plan (a new id) sweeping only `ranges` ([`SweepPlan::set_plane_ranges`]).
    pub fn narrow_planes(&self, ranges: Vec<[u32; 2]>) -> Result<Self, SweepError> {
        let mut narrowed = self.clone();
        narrowed.id = next_plan_id();
        narrowed.set_plane_ranges(ranges)?;
        Ok(narrowed)
    }

    /// The ranges as the shaders read them, per (row, tile) in the layout of
    /// [`SweepPlan::plane_ranges`]: its own range (aggregate.wgsl) and the hull of
    /// the ranges of the tiles whose pixels' windows reach its pixels, the planes whose costs
    /// and row sums it must have (cost.wgsl, box_h.wgsl; window_h - 1 rows and window_w - 1
    /// columns either way cover centred and shiftable windows).
    pub fn shader_plane_ranges(&self) -> &[[u32; 4]] {
        &self.tile_ranges
    }

    /// Whether some tile sweeps fewer than every plane (coarse to fine).
    pub fn narrowed(&self) -> bool {
        self.narrowed
    }

    /// Whether some pixel of row `y` sweeps plane `k`.
    pub fn sweeps(&self, y: usize, k: u32) -> bool {
        let tiles = range_tiles(self.width) as usize;
        self.plane_ranges
            .get(y * tiles..(y + 1) * tiles)
            .is_none_or(|row| row.iter().any(|r| r[0] <= k && k <= r[1]))
    }

    /// The column spans of row `y` whose costs on plane `k` some pixel's windows read (the
    /// tiles whose window hull holds `k`, neighbours merged), into `spans`.
    pub fn cost_spans(&self, y: usize, k: u32, spans: &mut Vec<std::ops::Range<usize>>) {
        if !self.tile_spans(y, |r| r[2] <= k && k <= r[3], spans) {
            spans.push(0..self.width as usize);
        }
    }

    /// The column spans of row `y` whose pixels do not sweep plane `k` (they score BIG on it),
    /// into `spans`.
    pub fn idle_spans(&self, y: usize, k: u32, spans: &mut Vec<std::ops::Range<usize>>) {
        self.tile_spans(y, |r| !(r[0] <= k && k <= r[1]), spans);
    }

    /// The columns of the tiles of row `y` whose shader ranges ([`SweepPlan::shader_plane_ranges`])
    /// `keep` accepts, neighbours merged, into `spans` (cleared first). False, with no span,
    /// when the plan is not narrowed (or has no row `y`).
    fn tile_spans(
        &self,
        y: usize,
        keep: impl Fn(&[u32; 4]) -> bool,
        spans: &mut Vec<std::ops::Range<usize>>,
    ) -> bool {
        spans.clear();
        let tiles = range_tiles(self.width) as usize;
        let (tile, width) = (RANGE_TILE as usize, self.width as usize);
        let row = self.tile_ranges.get(y * tiles..(y + 1) * tiles);
        let Some(row) = row.filter(|_| self.narrowed) else {
            return false;
        };
        for (t, r) in row.iter().enumerate() {
            if keep(r) {
                let (lo, hi) = (t * tile, ((t + 1) * tile).min(width));
                match spans.last_mut() {
                    Some(last) if last.end == lo => last.end = hi,
                    _ => spans.push(lo..hi),
                }
            }
        }
        true
    }

    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    pub fn channels(&self) -> usize {
        self.params.channels as usize
    }

    /// Width and height of the box-sum images (window anchors from -(w-1)).
    pub fn padded_size(&self) -> (u32, u32) {
        (self.params.padded_w, self.params.padded_h)
    }

    pub fn num_planes(&self) -> u32 {
        self.params.planes
    }

    /// Window sums need the separable box passes: shiftable windows of at most 2x2 are summed
    /// straight from the cost slab instead.
    pub fn box_passes(&self) -> bool {
        let p = &self.params;
        !(p.window_mode == WINDOW_SHIFTABLE && p.window_w <= 2 && p.window_h <= 2)
    }

    /// The WGSL engine costs and sums along rows in one stage (`cost_rows.wgsl`, no cost slab):
    /// window sums of per-pair aggregation over the reference's pairs (the defaults).
    pub fn cost_rows(&self) -> bool {
        let p = &self.params;
        self.box_passes() && p.aggregation == AGG_PER_PAIR && p.pair_mode == PAIRS_REFERENCE
    }

    /// SGM path directions; 0 = winner-take-all (no cost volume).
    pub fn sgm_paths(&self) -> u32 {
        self.params.sgm_paths
    }

    /// u32 words per pixel of the u16 cost volume (two planes per word).
    pub fn volume_words(&self) -> usize {
        self.num_planes().div_ceil(2) as usize
    }

    /// Best half-sequence with per-pair aggregation: how many of its best pairs each half
    /// (left, right) scores. Each half keeps at most the better half of its pairs (rounded up)
    /// and at most `half_best_n` of them, so a half of two pairs scores its better pair: the
    /// occlusion assumption of the halves applied once more within a half (docs/engine.md,
    /// Scoring).
    /// 0 = all pairs of the half (the paper's rule, `half_best_n` 0).
    pub fn half_ranks(&self) -> [u32; 2] {
        let n = self.params.half_best_n;
        [HALF_LEFT, HALF_RIGHT].map(|side| {
            let pairs = self.pairs.iter().filter(|p| p[2] == side).count() as u32;
            n.min(pairs.div_ceil(2))
        })
    }

    /// The cost compares census words (`sweep/census.rs`).
    pub fn uses_census(&self) -> bool {
        self.params.cost != COST_TSSD
    }

    /// Words of the `images` buffer: every camera's pixels, then (census costs) their census
    /// words in the same layout.
    pub fn image_words(&self) -> usize {
        self.total_camera_pixels * if self.uses_census() { 2 } else { 1 }
    }

    /// Concatenates the camera images in rig order, then with a census cost their census words
    /// (the layout of the `images` buffer).
    pub fn pack_images(
        &self,
        rig: &Rig,
        images: &[Rgba8Image],
        out: &mut Vec<u32>,
        memo: &mut crate::sweep::frame_memo::FrameMemo,
    ) -> Result<(), SweepError> {
        check_images(rig, images)?;
        out.clear();
        out.reserve(self.image_words());
        for image in images {
            out.extend_from_slice(&image.pixels);
        }
        if self.uses_census() {
            for (image, camera) in images.iter().zip(&rig.cameras) {
                memo.census_into(&camera.name, image, out);
            }
        }
        Ok(())
    }
}

impl SweepPlan {
    /// `DepthMaps` with `depth_raw_m` alone (the first section of the `maps` buffer, all a
    /// coarse-to-fine level below the full resolution is read for); the other maps empty.
    pub fn depth_raw_maps(&self, depth_raw: Vec<f32>) -> crate::sweep::DepthMaps {
        use crate::image::ImageF32;
        let empty = || ImageF32 {
            width: 0,
            height: 0,
            data: Vec::new(),
        };
        crate::sweep::DepthMaps {
            depth_m: empty(),
            depth_raw_m: ImageF32 {
                width: self.width,
                height: self.height,
                data: depth_raw,
            },
            confidence: empty(),
            cost: empty(),
            selection: Vec::new(),
            visible_cameras: Vec::new(),
        }
    }

    /// Unpacks the `maps` buffer into the public outputs.
    pub fn depth_maps(&self, maps: &[f32]) -> crate::sweep::DepthMaps {
        self.unpack_map_sections(maps, 0, WantedMaps::ALL, false)
    }

    /// The sections of `maps` that [`Self::unpack_map_sections`] reads for `wanted`: the WGSL
    /// engine reads back only these (the median filter's input never; the raw depth and the
    /// visible cameras with diagnostics; the cost and selection when wanted). Depth and
    /// confidence come first, so what is wanted is one range.
    pub fn unpacked_sections(wanted: WantedMaps) -> std::ops::Range<usize> {
        if wanted.diagnostics {
            MAP_DEPTH_RAW..MAP_COUNT
        } else if wanted.selection {
            MAP_DEPTH..MAP_VISIBLE
        } else if wanted.cost {
            MAP_DEPTH..MAP_SELECTION
        } else {
            MAP_DEPTH..MAP_COST
        }
    }

    /// The maps `wanted` of `maps`, a readback of [`Self::unpacked_sections`] that begins at
    /// section `first` (the others left empty), copied on rayon's threads with `split`
    /// (`gpu::HostCopies`).
    pub fn unpack_map_sections(
        &self,
        maps: &[f32],
        first: usize,
        wanted: WantedMaps,
        split: bool,
    ) -> crate::sweep::DepthMaps {
        unpack_sections((self.width, self.height), maps, first, wanted, split)
    }
}

/// [`SweepPlan::unpack_map_sections`] of a plan whose maps are `width` x `height`.
pub fn unpack_sections(
    (width, height): (u32, u32),
    maps: &[f32],
    first: usize,
    wanted: WantedMaps,
    split: bool,
) -> crate::sweep::DepthMaps {
    use super::gpu::copies;
    use crate::image::ImageF32;
    let npix = width as usize * height as usize;
    let of = |s: usize| &maps[(s - first) * npix..(s - first + 1) * npix];
    let section = |s: usize| ImageF32 {
        width,
        height,
        data: copies::to_vec(of(s), split),
    };
    let empty = || ImageF32 {
        width: 0,
        height: 0,
        data: Vec::new(),
    };
    let bytes = |s: usize, nan: u8| bytes_of_floats(of(s), nan, split);
    let diagnostics = wanted.diagnostics;
    crate::sweep::DepthMaps {
        depth_m: section(MAP_DEPTH),
        depth_raw_m: if diagnostics {
            section(MAP_DEPTH_RAW)
        } else {
            empty()
        },
        confidence: section(MAP_CONFIDENCE),
        cost: if wanted.cost || diagnostics {
            section(MAP_COST)
        } else {
            empty()
        },
        // `v as u8`.
        selection: if wanted.selection || diagnostics {
            bytes(MAP_SELECTION, 0)
        } else {
            Vec::new()
        },
        // `v.min(255.0) as u8`: `v as u8`, but a NaN 255.
        visible_cameras: if diagnostics {
            bytes(MAP_VISIBLE, 255)
        } else {
            Vec::new()
        },
    }
}

/// `v as u8` (NaN to 0, saturating at 0 and 255, truncating toward zero) in operations that
/// vectorise: the scalar cast's fix-ups do not, and two such maps per frame set cost the WGSL
/// engine's host about 0.15 ms at 320x240 (issue 35). Equal to the cast for every `f32`
/// (checked over all 2^32 bit patterns once; the test checks the edge cases).
#[inline(always)]
fn float_to_u8(v: f32) -> u8 {
    // A NaN fails both comparisons: 0.
    let clamped = if v > 0.0 { v } else { 0.0 };
    let clamped = if clamped < 255.0 { clamped } else { 255.0 };
    crate::simd::floor_small(clamped) as u8
}

crate::simd::vectorised_fn! {
    /// [`float_to_u8`] of every value, a NaN `nan` (AVX2 where the CPU has it).
    fn floats_to_u8(values: &[f32], nan: u8, out: &mut [u8]) {
        let each = |v: f32| {
            if v.is_nan() {
                u32::from(nan)
            } else {
                u32::from(float_to_u8(v))
            }
        };
        // 32 at a time into words, then narrowed from whole vectors (3x the plain loop).
        let mut outs = out.chunks_exact_mut(32);
        let mut ins = values.chunks_exact(32);
        for (o, i) in (&mut outs).zip(&mut ins) {
            let mut words = [0u32; 32];
            for (w, &v) in words.iter_mut().zip(i) {
                *w = each(v);
            }
            for (o, w) in o.iter_mut().zip(words) {
                *o = w as u8;
            }
        }
        for (o, &v) in outs.into_remainder().iter_mut().zip(ins.remainder()) {
            *o = each(v) as u8;
        }
    }
}

/// A map of small integers held as floats, as bytes (`v as u8`; a NaN `nan`), on rayon's
/// threads with `split` (`gpu::HostCopies`).
fn bytes_of_floats(values: &[f32], nan: u8, split: bool) -> Vec<u8> {
    super::gpu::copies::to_bytes(values, split, |v, o| floats_to_u8(v, nan, o))
}

/// Per (row, tile) of `ranges` (`tiles` per row): its own range and the hull of the ranges of
/// the rows within window_h - 1 of it and the tiles holding a column within window_w - 1 of
/// its columns (`SweepPlan::shader_plane_ranges`; twin: shaders/plane_ranges.wgsl). The hull
/// across tiles first, then across rows (min and max: the order does not matter).
fn tile_hulls(ranges: &[[u32; 2]], tiles: usize, params: &GpuParams) -> Vec<[u32; 4]> {
    let reach_y = params.window_h.saturating_sub(1) as usize;
    let reach_x = params.window_w.saturating_sub(1) as usize;
    let (tile, width) = (RANGE_TILE as usize, params.width as usize);
    let rows = ranges.len() / tiles.max(1);
    let hull = |it: &mut dyn Iterator<Item = [u32; 2]>| {
        it.fold([u32::MAX, 0], |a, r| [a[0].min(r[0]), a[1].max(r[1])])
    };
    let across: Vec<[u32; 2]> = (0..rows * tiles)
        .map(|i| {
            let (y, t) = (i / tiles, i % tiles);
            let first = (t * tile).saturating_sub(reach_x) / tile;
            let last = (((t + 1) * tile).min(width).saturating_sub(1) + reach_x) / tile;
            hull(
                &mut ranges[y * tiles + first..=y * tiles + last.min(tiles - 1)]
                    .iter()
                    .copied(),
            )
        })
        .collect();
    (0..rows * tiles)
        .map(|i| {
            let (y, t) = (i / tiles, i % tiles);
            let near = y.saturating_sub(reach_y)..(y + reach_y + 1).min(rows);
            let [lo, hi] = hull(&mut near.map(|r| across[r * tiles + t]));
            [ranges[i][0], ranges[i][1], lo, hi]
        })
        .collect()
}

#[cfg(test)]
mod float_to_u8_tests {
    #[test]
    fn float_to_u8_is_the_cast() {
        let mut values = vec![
            f32::NAN,
            -f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            0.0,
            -0.0,
            f32::MIN_POSITIVE,
            -f32::MIN_POSITIVE,
            0.5,
            0.999_999_94,
            1.0,
            1.5,
            2.5,
            254.5,
            254.999_98,
            255.0,
            255.5,
            256.0,
            1e10,
            -1e10,
            -0.5,
            -1.0,
            f32::MAX,
            f32::MIN,
        ];
        values.extend((0..5000).map(|i| i as f32 * 0.0731 - 20.0));
        let expected: Vec<u8> = values.iter().map(|&v| v as u8).collect();
        for split in [false, true] {
            assert_eq!(super::bytes_of_floats(&values, 0, split), expected);
        }
        let each: Vec<u8> = values.iter().map(|&v| super::float_to_u8(v)).collect();
        assert_eq!(each, expected);
        let visible: Vec<u8> = values.iter().map(|&v| v.min(255.0) as u8).collect();
        assert_eq!(super::bytes_of_floats(&values, 255, true), visible);
    }
}

#[cfg(test)]
mod range_tile_tests {
    use super::*;
    use crate::geometry::CameraModel;

    /// Per tile ranges on a reference 70 pixels wide (a partial last tile): every pixel that a
    /// sweeping pixel's windows reach has its cost made on that plane (`cost_spans`), the
    /// pixels outside their tile's range are exactly the idle ones (`idle_spans`), and the
    /// shaders' hull holds the tile's own range; centred 5x5 and shiftable 2x2 windows.
    #[test]
    fn cost_spans_cover_every_window_of_a_sweeping_pixel() {
        let model = CameraModel::pinhole(crate::synthetic::intrinsics(70, 24));
        let rig = crate::synthetic::row_rig(3, 0.1, model, 1).expect("rig");
        let shiftable = SweepParams {
            window_mode: WindowMode::Shiftable,
            window_width: 2,
            window_height: 2,
            ..SweepParams::default()
        };
        for params in [SweepParams::default(), shiftable] {
            let mut plan = SweepPlan::new(&rig, &params).expect("plan");
            let planes = plan.num_planes();
            let tiles = range_tiles(plan.width) as usize;
            assert_eq!(tiles, 5);
            let (width, height) = (70usize, 24usize);
            // Not narrowed: every column of every row.
            let mut spans = Vec::new();
            plan.cost_spans(3, 7, &mut spans);
            assert_eq!(spans, vec![0..width]);
            let ranges: Vec<[u32; 2]> = (0..height * tiles)
                .map(|i| {
                    let (y, t) = (i / tiles, i % tiles);
                    let lo = ((y * 7 + t * 13) % 20) as u32;
                    [lo, (lo + (t as u32 % 3) * 4).min(planes - 1)]
                })
                .collect();
            plan.set_plane_ranges(ranges.clone()).expect("ranges");
            assert!(plan.narrowed());
            let (rw, rh) = (
                params.window_width as usize - 1,
                params.window_height as usize - 1,
            );
            let own = |x: usize, y: usize| ranges[y * tiles + x / RANGE_TILE as usize];
            let (mut needed_total, mut made_total) = (0, 0);
            for k in 0..planes {
                for y in 0..height {
                    plan.cost_spans(y, k, &mut spans);
                    let made = |x: usize| spans.iter().any(|s| s.contains(&x));
                    let mut idle = Vec::new();
                    plan.idle_spans(y, k, &mut idle);
                    for x in 0..width {
                        let r = own(x, y);
                        let sweeps = r[0] <= k && k <= r[1];
                        assert_eq!(
                            idle.iter().any(|s| s.contains(&x)),
                            !sweeps,
                            "({x}, {y}) {k}"
                        );
                        let needed = (y.saturating_sub(rh)..(y + rh + 1).min(height)).any(|v| {
                            (x.saturating_sub(rw)..(x + rw + 1).min(width)).any(|u| {
                                let r = own(u, v);
                                r[0] <= k && k <= r[1]
                            })
                        });
                        assert!(!needed || made(x), "({x}, {y}) plane {k} needed, not made");
                        needed_total += usize::from(needed);
                        made_total += usize::from(made(x));
                    }
                }
            }
            // Not every plane everywhere (the spans skip something).
            assert!(
                made_total < (planes as usize) * width * height,
                "{made_total}"
            );
            assert!(needed_total > 0);
            for (hull, r) in plan.shader_plane_ranges().iter().zip(&ranges) {
                assert_eq!([hull[0], hull[1]], *r);
                assert!(hull[2] <= r[0] && hull[3] >= r[1]);
            }
        }
    }
}

#[cfg(test)]
mod uniqueness_radius_tests {
    use super::*;
    use crate::geometry::CameraModel;
    use crate::synthetic;

    /// A pair 30 cm apart, f = 139 px, 1-6 m over 64 planes: 41.7 - 6.9 px of disparity, 0.55 px
    /// per plane, so 1.5 px is 3 planes; over 8 planes (5 px per plane) the radius is 1.
    #[test]
    fn the_radius_is_one_and_a_half_pixels_of_shift() {
        let model = CameraModel::pinhole(synthetic::intrinsics(160, 120));
        let rig = synthetic::row_rig(2, 0.3, model, 0).expect("rig");
        let params = |planes| SweepParams {
            min_depth_m: 1.0,
            max_depth_m: 6.0,
            num_planes: planes,
            ..SweepParams::default()
        };
        assert_eq!(uniqueness_radius(&rig, &params(64), 64), 3);
        assert_eq!(uniqueness_radius(&rig, &params(8), 8), 1);
        // The plan carries it to both engines.
        let plan = SweepPlan::new(&rig, &params(64)).expect("plan");
        assert_eq!(plan.params.uniqueness_radius, 3);
    }
}
