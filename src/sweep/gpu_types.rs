//! Structs shared by Rust and WGSL. Keep in sync with `shaders/camera.wgsl` (`Camera`) and
//! `shaders/common.wgsl` (`Params`, `Batch`); the size test below guards the layout.

use bytemuck::{Pod, Zeroable};

pub const NO_CAMERA: u32 = u32::MAX;
pub const MAX_CAMERAS: u32 = 32;
/// Cameras per rig: they travel in a uniform block of 16 KiB (the downlevel limit).
pub const MAX_RIG_CAMERAS: u32 = 128;
pub const MAX_BEST_N: u32 = 8;
pub const MAX_HALF_BEST_N: u32 = 4;

pub const SCORING_SSSD: u32 = 0;
pub const SCORING_BEST_N: u32 = 1;
pub const SCORING_HALF: u32 = 2;
pub const PAIRS_REFERENCE: u32 = 0;
pub const PAIRS_ALL: u32 = 1;
pub const COST_TSSD: u32 = 0;
pub const COST_CENSUS: u32 = 1;
pub const COST_AD_CENSUS: u32 = 2;
pub const AGG_SCORED: u32 = 0;
pub const AGG_PER_HALF: u32 = 1;
pub const AGG_PER_PAIR: u32 = 2;
pub const MAX_PAIRS: u32 = 16;
pub const WINDOW_SHIFTABLE: u32 = 0;
pub const WINDOW_CENTRED: u32 = 1;
pub const DIST_NONE: u32 = 0;
pub const DIST_PLUMB_BOB: u32 = 1;
pub const DIST_EQUIDISTANT: u32 = 2;
pub const HALF_LEFT: u32 = 0;
pub const HALF_RIGHT: u32 = 1;
pub const HALF_REFERENCE: u32 = 2;

/// SGM: a scored cost of `tau` (or no valid pair) is this many levels in the u16 cost volume.
pub const SGM_COST_MAX: u32 = 1023;
/// Coarse to fine: the volume level (common.wgsl) of a plane outside the pixel's range, absent
/// from SGM; its path cost is SGM_PATH_PAD (the CPU's `sgm::PAD`).
pub const SGM_OUTSIDE_LEVEL: u32 = 0xffff;
pub const SGM_PATH_PAD: u32 = 0x7fff;
/// SGM: planes per pixel (the previous path costs live in workgroup memory).
pub const MAX_SGM_PLANES: u32 = 1024;
/// SGM: the colour step of `sgm_edge` in 1/16 grey levels (integer maths on both sides).
pub const SGM_EDGE_UNITS: f32 = 16.0;

/// `GpuParams::subpixel`, its low two bits: no refinement; the fit through the winner's and its
/// neighbours' scores (`cpu::finalize::subpixel_offset`); that fit, then the fine local sweep
/// around it (`subpixel_refine`, the refine stage). [`SUBPIXEL_MODE`] masks them.
pub const SUBPIXEL_OFF: u32 = 0;
pub const SUBPIXEL_PARABOLA: u32 = 1;
pub const SUBPIXEL_REFINE: u32 = 2;
pub const SUBPIXEL_MODE: u32 = 3;
/// `GpuParams::subpixel`'s flag: the fit is a V (equiangular line), not a parabola
/// (`subpixel_v_fit`).
pub const SUBPIXEL_V_FIT: u32 = 4;

pub const INVALID: f32 = -1.0;
/// `HALF_NOISE_FLOOR` in common.wgsl.
pub const HALF_NOISE_FLOOR: f32 = 25.0;
/// `SGM_VOLUME_OFFSET` in common.wgsl: how far a score is raised on its way into the SGM cost
/// volume, whose u16 levels start at 0. The smooth minimum of the two halves (`half_min`) goes
/// down to HALF_NOISE_FLOOR / 4 below the smaller half, so the best matches of a half-sequence
/// score are negative; without the offset they were all cut to level 0, and SGM saw a flat
/// floor where the data term had its sharpest minimum (ICL-NUIM mean error 0.0331 -> 0.0273 with
/// it). The same offset is taken off again when the sums are read back (`sgm_select`).
pub const SGM_VOLUME_OFFSET: f32 = HALF_NOISE_FLOOR / 4.0;
pub const BIG: f32 = 1.0e30;

/// Sections of the `maps` buffer (`MAP_*` in common.wgsl).
pub const MAP_DEPTH_RAW: usize = 0;
pub const MAP_DEPTH_MEDIAN: usize = 1;
pub const MAP_DEPTH: usize = 2;
pub const MAP_CONFIDENCE: usize = 3;
pub const MAP_COST: usize = 4;
pub const MAP_SELECTION: usize = 5;
pub const MAP_VISIBLE: usize = 6;
pub const MAP_COUNT: usize = 7;

/// WGSL `Camera`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, PartialEq)]
pub struct GpuCamera {
    pub row0: [f32; 4],
    pub row1: [f32; 4],
    pub row2: [f32; 4],
    pub intrinsics: [f32; 4],
    pub dist_a: [f32; 4],
    /// plumb_bob: k3 in \[0\]; both models: \[1\] = the largest (x/z)² + (y/z)² of the monotonic
    /// branch (points farther off axis are not seen; `f32::MAX` when the model never folds).
    pub dist_b: [f32; 4],
    /// width, height, offset of pixel (0, 0) in the image buffer, distortion model.
    pub size: [u32; 4],
    /// half, is_reference, 0, 0.
    pub info: [u32; 4],
}

/// WGSL `Params`: named scalars, 40 x 4 bytes (the size test below and naga's layout of the
/// WGSL struct agree).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, PartialEq)]
pub struct GpuParams {
    /// The reference image, pixels.
    pub width: u32,
    pub height: u32,
    pub pixel_count: u32,
    /// Reference camera index, or [`NO_CAMERA`] (virtual reference).
    pub reference: u32,
    pub cameras: u32,
    pub planes: u32,
    /// Cost-slab channels per plane (the pairs m in per-pair aggregation).
    pub channels: u32,
    /// Best half-sequence with per-pair aggregation: the n best pairs of each half (0 = all).
    pub half_best_n: u32,
    /// `SCORING_*`.
    pub scoring: u32,
    /// `PAIRS_*`.
    pub pair_mode: u32,
    pub best_n: u32,
    /// `AGG_*`.
    pub aggregation: u32,
    /// Window size, pixels (1 = no aggregation).
    pub window_w: u32,
    pub window_h: u32,
    /// `SUBPIXEL_*`.
    pub subpixel: u32,
    /// 0 or 1.
    pub median: u32,
    /// TSSD truncation (sum over RGB of squared 0..255 differences).
    pub tau: f32,
    pub max_cost: f32,
    /// Relative depth tolerance of the occlusion z-test.
    pub occlusion_tolerance: f32,
    pub half_margin: f32,
    /// Cameras that must see a pixel, the reference counted.
    pub min_visible: u32,
    /// `WINDOW_*`.
    pub window_mode: u32,
    /// Box-sum image size: width + window_w - 1, height + window_h - 1.
    pub padded_w: u32,
    pub padded_h: u32,
    /// SGM path directions (0 = winner-take-all, no cost volume).
    pub sgm_paths: u32,
    /// SGM penalties in cost-volume levels.
    pub sgm_p1: u32,
    pub sgm_p2: u32,
    /// The colour step that halves P2, in 1/16 grey levels (0 = constant P2).
    pub sgm_edge: u32,
    /// Cost-volume levels per score unit (SGM_COST_MAX / (tau + SGM_VOLUME_OFFSET)).
    pub sgm_levels_per_unit: f32,
    /// Score units per summed level: 1 / (paths x levels per unit).
    pub sgm_unit_per_level: f32,
    /// `COST_*`.
    pub cost: u32,
    /// Word of the first camera's census in the `images` buffer (after every camera's pixels;
    /// camera `c`'s census starts at `census_offset + size.z`). 0 with `COST_TSSD`.
    pub census_offset: u32,
    /// With SGM: pixels whose winner is not unique on the matching costs (`(rival - best) /
    /// (rival + 1)`, the rival the best plane more than `uniqueness_radius` planes away) by
    /// this share are invalid.
    pub uniqueness: f32,
    /// 1: the images are prefiltered (`prefilter.rs`): the cost's colour term compares their
    /// alpha byte (in all three channels); 0: the RGB.
    pub colour_in_alpha: u32,
    /// With SGM: below this uniqueness on the matching costs, the confidence is scaled by
    /// `uniqueness / ambiguity` (0: SGM's confidence as it is).
    pub ambiguity: f32,
    /// With SGM: planes either side of the winner that are not its rivals on the matching
    /// costs (about [`UNIQUENESS_RADIUS_PX`] of shift in the widest view), at least 1.
    pub uniqueness_radius: u32,
    /// 1: a winner on the first or last plane keeps its depth; 0: it is invalid.
    pub keep_range_ends: u32,
    /// Inverse depth (1/m) by which an occluder must also be nearer: `OCCLUSION_PLANES` steps
    /// of the planes (`plan::occlusion_inverse_depth`).
    pub occlusion_inverse_depth: f32,
    pub _pad1: u32,
    pub _pad2: u32,
}

/// How far (pixels of shift in the widest view) a rival on the matching costs lies from the
/// winner at least: nearer planes are the same match, sampled between texels.
pub const UNIQUENESS_RADIUS_PX: f64 = 1.5;

/// `direction.w` of an SGM pass that walks directions `direction.y` .. paths - 1 in one
/// dispatch (`SGM_TOGETHER` in `sgm_subgroup.wgsl`).
pub const SGM_TOGETHER: i32 = -1;

/// WGSL `SgmPass`: one direction of the semi-global optimiser.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, PartialEq)]
pub struct GpuSgmPass {
    /// dx, dy (each -1, 0 or 1), number of path lines, index of the direction (0: the first
    /// pass, which writes the sums; the others add).
    pub direction: [i32; 4],
}

/// WGSL `Band`: one row band of the SGM cost volume and path sums.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, PartialEq)]
pub struct GpuBand {
    pub first_row: u32,
    pub rows: u32,
    /// `first_row * width`: the band's buffers start at this pixel.
    pub first_pixel: u32,
    pub _pad: u32,
}

/// Planes per batch (they travel in the batch's uniform block).
pub const MAX_BATCH_PLANES: u32 = 256;

/// WGSL `Batch`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, PartialEq)]
pub struct GpuBatch {
    pub first_plane: u32,
    pub plane_count: u32,
    pub is_first: u32,
    /// Non-zero: a batch of the fine sweep's hypotheses (`subpixel_refine`).
    pub refine: u32,
    pub planes: [[f32; 4]; MAX_BATCH_PLANES as usize],
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layouts_match_wgsl() {
        assert_eq!(std::mem::size_of::<GpuCamera>(), 128);
        assert_eq!(std::mem::size_of::<GpuParams>(), 160);
        assert_eq!(std::mem::size_of::<GpuSgmPass>(), 16);
        assert_eq!(std::mem::size_of::<GpuBand>(), 16);
        assert_eq!(
            std::mem::size_of::<GpuBatch>(),
            16 + 16 * MAX_BATCH_PLANES as usize
        );
        // What build.rs prepends to every stage.
        let common = concat!(
            include_str!("../../shaders/camera.wgsl"),
            include_str!("../../shaders/common.wgsl")
        );
        // The WGSL `Params` names the same fields in the same order (all 4-byte scalars).
        let start = common
            .find("struct Params {")
            .expect("common.wgsl has Params");
        let body = &common[start..start + common[start..].find('}').expect("Params closes")];
        let wgsl_fields: Vec<&str> = body
            .lines()
            .skip(1)
            .filter_map(|l| l.trim().split_once(':').map(|(name, _)| name.trim()))
            .filter(|name| !name.starts_with("//"))
            .collect();
        let p = GpuParams::zeroed();
        let rust_fields = format!("{p:?}");
        let rust_fields: Vec<&str> = rust_fields
            .trim_start_matches("GpuParams {")
            .split(',')
            .filter_map(|f| f.split_once(':').map(|(name, _)| name.trim()))
            .collect();
        assert_eq!(wgsl_fields, rust_fields, "GpuParams and WGSL Params differ");
        for (name, value) in [
            ("MAX_CAMERAS", MAX_CAMERAS),
            ("MAX_RIG_CAMERAS", MAX_RIG_CAMERAS),
            ("MAX_BEST_N", MAX_BEST_N),
            ("SCORING_HALF", SCORING_HALF),
            ("COST_CENSUS", COST_CENSUS),
            ("COST_AD_CENSUS", COST_AD_CENSUS),
            ("AGG_PER_HALF", AGG_PER_HALF),
            ("AGG_PER_PAIR", AGG_PER_PAIR),
            ("MAX_PAIRS", MAX_PAIRS),
            ("WINDOW_CENTRED", WINDOW_CENTRED),
            ("MAX_HALF_BEST_N", MAX_HALF_BEST_N),
            ("DIST_EQUIDISTANT", DIST_EQUIDISTANT),
            ("HALF_REFERENCE", HALF_REFERENCE),
            ("MAP_COUNT", MAP_COUNT as u32),
            ("MAX_BATCH_PLANES", MAX_BATCH_PLANES),
            ("MAP_VISIBLE", MAP_VISIBLE as u32),
            ("SGM_COST_MAX", SGM_COST_MAX),
            ("SGM_OUTSIDE_LEVEL", SGM_OUTSIDE_LEVEL),
            ("SGM_PATH_PAD", SGM_PATH_PAD),
            ("SUBPIXEL_V_FIT", SUBPIXEL_V_FIT),
            ("MAX_SGM_PLANES", MAX_SGM_PLANES),
            ("MARGIN_PLANES", crate::sweep::coarse::MARGIN_PLANES),
            ("NEIGHBOUR_ROWS", crate::sweep::coarse::NEIGHBOUR_ROWS),
            (
                "TILE_MARGIN_PLANES",
                crate::sweep::coarse::TILE_MARGIN_PLANES,
            ),
            ("NEIGHBOUR_COLS", crate::sweep::coarse::NEIGHBOUR_COLS),
            ("RANGE_TILE", crate::sweep::plan::RANGE_TILE),
            ("REFINE_REACH", crate::sweep::cpu::refine::REACH as u32),
        ] {
            let needle = format!("const {name}: u32 = {value}u;");
            assert!(common.contains(&needle), "common.wgsl lacks `{needle}`");
        }
        for (name, value) in [
            ("HALF_NOISE_FLOOR", HALF_NOISE_FLOOR),
            ("SGM_VOLUME_OFFSET", SGM_VOLUME_OFFSET),
            ("REFINE_STEP", crate::sweep::cpu::refine::STEP),
            (
                "REFINE_SAME_SURFACE",
                crate::sweep::cpu::refine::SAME_SURFACE,
            ),
            (
                "PHASE_SMOOTHING",
                crate::sweep::cpu::matched::PHASE_SMOOTHING,
            ),
        ] {
            let needle = format!("const {name}: f32 = {value:?};");
            assert!(common.contains(&needle), "common.wgsl lacks `{needle}`");
        }
    }
}
