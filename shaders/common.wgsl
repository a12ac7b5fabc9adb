// Shared structs and maths, prepended to every stage by build.rs (after camera.wgsl).
// Keep in sync with src/sweep/gpu_types.rs (GpuCamera, GpuParams, GpuBatch); a size test guards the layout.

const INVALID: f32 = -1.0;         // a cost slot with no visible pair
const BIG: f32 = 1.0e30;           // "infinite" cost in the selection state
const NO_CAMERA: u32 = 0xffffffffu;

const SCORING_SSSD: u32 = 0u;      // mean of pair TSSDs (pairs per pair_mode)
const SCORING_BEST_N: u32 = 1u;    // mean of the n smallest pair TSSDs
const SCORING_HALF: u32 = 2u;      // best half-sequence
const COST_TSSD: u32 = 0u;         // pair cost: truncated colour SSD
const COST_CENSUS: u32 = 1u;       // 5x5 census Hamming distance, tau / 24 per bit
const COST_AD_CENSUS: u32 = 2u;    // the mean of the two

const PAIRS_REFERENCE: u32 = 0u;   // reference-vs-other pairs
const PAIRS_ALL: u32 = 1u;         // all pairs among visible cameras

const AGG_SCORED: u32 = 0u;        // windows average the scored cost
const AGG_PER_HALF: u32 = 1u;      // windows average each half, then the min is taken
const AGG_PER_PAIR: u32 = 2u;      // windows average each pair's TSSD, then the score is taken
const MAX_PAIRS: u32 = 16u;        // pairs per hypothesis in per-pair aggregation

const WINDOW_SHIFTABLE: u32 = 0u;  // the four w x h windows with the pixel at a corner (the paper)
const WINDOW_CENTRED: u32 = 1u;    // one w x h window around the pixel

const SEL_NONE: u32 = 0u;          // no clear half (white)
const SEL_LEFT: u32 = 1u;          // left half >= 10 % better (red)
const SEL_RIGHT: u32 = 2u;         // right half >= 10 % better (green)
const SEL_INVALID: u32 = 3u;       // invalid pixel (black)
// A colour SSD of 25 (about 3 grey levels per channel): below it, half scores differ by noise.
const HALF_NOISE_FLOOR: f32 = 25.0;

const HALF_LEFT: u32 = 0u;
const HALF_RIGHT: u32 = 1u;
const HALF_REFERENCE: u32 = 2u;

const MAX_CAMERAS: u32 = 32u;      // all-pairs modes cache one colour per camera
const MAX_RIG_CAMERAS: u32 = 128u; // cameras travel in a uniform block (16 KiB)
const MAX_BEST_N: u32 = 8u;
const MAX_HALF_BEST_N: u32 = 4u;  // best half-sequence: the n best pairs of each half

// Pipeline-overridable constants: the engine specialises each pipeline to the mode at hand so
// the compiler drops the code of the other modes (named per stage in src/sweep/stages.rs, set
// by src/sweep/gpu/pipelines.rs; the values repeat fields of Params, which the CPU twin reads).
// DISTORTED is in camera.wgsl.


struct Params {
    // The reference image.
    width: u32,
    height: u32,
    pixel_count: u32,
    reference: u32,               // reference camera index, or NO_CAMERA (virtual reference)
    // Counts.
    cameras: u32,
    planes: u32,
    channels: u32,                // cost-slab channels per plane (pairs m in per-pair aggregation)
    half_best_n: u32,             // 0 = all pairs of a half
    // Modes (SCORING_*, PAIRS_*, AGG_*).
    scoring: u32,
    pair_mode: u32,
    best_n: u32,
    aggregation: u32,
    // Windows and post-processing switches.
    window_w: u32,                // 1 = no aggregation
    window_h: u32,
    subpixel: u32,                // 0 off, else the fit (+ 1: refine after it; + 4: a V, not a parabola)
    median: u32,                  // 0 or 1
    // Thresholds.
    tau: f32,
    max_cost: f32,
    occlusion_tolerance: f32,     // relative (and occlusion_inverse_depth)
    half_margin: f32,
    min_visible: u32,             // cameras, the reference counted
    window_mode: u32,             // WINDOW_*
    padded_w: u32,                // width + window_w - 1 (box-sum anchors)
    padded_h: u32,
    // SGM (optimizer sgm; sgm_paths = 0: winner-take-all).
    sgm_paths: u32,
    sgm_p1: u32,                  // volume levels
    sgm_p2: u32,                  // volume levels
    sgm_edge: u32,                // 1/16 grey levels, 0 = constant P2
    sgm_levels_per_unit: f32,     // SGM_COST_MAX / (tau + SGM_VOLUME_OFFSET)
    sgm_unit_per_level: f32,      // 1 / (paths x levels per unit): score units per summed level
    cost: u32,                    // COST_*
    census_offset: u32,           // word of camera 0's census in `images` (camera c: + size.z)
    uniqueness: f32,              // with SGM: uniqueness on the matching costs below which a pixel is invalid
    colour_in_alpha: u32,         // 1: images prefiltered, the cost's colour is the alpha byte
    ambiguity: f32,               // with SGM: uniqueness below which the confidence is scaled down
    uniqueness_radius: u32,       // with SGM: planes either side of the winner that are no rival
    keep_range_ends: u32,         // 1: a winner on the first or last plane keeps its depth; 0: invalid
    occlusion_inverse_depth: f32, // 1/m: an occluder is also nearer by this much (plan.rs)
    _pad1: u32,
    _pad2: u32,
}

// Semi-global matching (optimizer sgm): the scored cost of every pixel and plane is stored as
// u16 levels, two planes per u32 word (even plane in the low half), pixel-major.
// Params.subpixel's flag: the sub-pixel fit is a V, not a parabola (SUBPIXEL_V_FIT).
const SUBPIXEL_V_FIT: u32 = 4u;

const SGM_COST_MAX: u32 = 1023u;   // the level of a cost of tau (raised by SGM_VOLUME_OFFSET), and of a hypothesis with no valid pair
// Coarse to fine: the level of a plane outside the pixel's range (aggregate.wgsl). SGM treats it
// as absent: its path cost is SGM_PATH_PAD (above any real one, so no path passes through it),
// it adds nothing to the sums, and the selection and the uniqueness skip it. CPU twin: the
// windows of src/sweep/cpu/sgm.rs.
const SGM_OUTSIDE_LEVEL: u32 = 65535u;
const SGM_PATH_PAD: u32 = 32767u;

// A volume word's two path costs `l` with the planes the word marks outside set to SGM_PATH_PAD.
fn sgm_absent(c: u32, l: vec2<u32>) -> vec2<u32> {
    return select(l, vec2<u32>(SGM_PATH_PAD), vec2<u32>(c & 0xffffu, c >> 16u) == vec2<u32>(SGM_OUTSIDE_LEVEL));
}

// The two path costs `l` of a volume word `c` packed for the sums (0 for a plane outside).
fn sgm_sum_word(c: u32, l: vec2<u32>) -> u32 {
    let counted = select(l, vec2<u32>(0u), vec2<u32>(c & 0xffffu, c >> 16u) == vec2<u32>(SGM_OUTSIDE_LEVEL));
    return counted.x | (counted.y << 16u);
}
const MAX_SGM_PLANES: u32 = 1024u; // planes per pixel (previous path costs in workgroup memory)

// One row band of the cost volume and the path sums (keep in sync with GpuBand): an adapter's
// storage binding limit may hold fewer rows than the image, so the volume and the sums are
// separate buffers of `rows` rows each, and the stages that touch them run once per band. Pixel
// `pix` of the image is word `(pix - first_pixel) * words + j` of its band's buffers.
// SGM (sgm.wgsl, sgm_subgroup.wgsl): the first pixel of path line `line`: rows enter through
// the left or right edge, columns through the top or bottom; diagonals first through the
// vertical edge (one per row), then through the horizontal one (the remaining columns).
fn line_start(line: i32, dx: i32, dy: i32, w: i32, h: i32) -> vec2<i32> {
    let x_edge = select(w - 1, 0, dx > 0);
    let y_edge = select(h - 1, 0, dy > 0);
    if (dy == 0) {
        return vec2<i32>(x_edge, line);
    }
    if (dx == 0) {
        return vec2<i32>(line, y_edge);
    }
    if (line < h) {
        return vec2<i32>(x_edge, line);
    }
    let i = line - h + 1;
    return vec2<i32>(select(w - 1 - i, i, dx > 0), y_edge);
}

// Largest RGB channel difference of two packed reference colours.
fn colour_step(a: u32, b: u32) -> u32 {
    var step = 0u;
    for (var shift = 0u; shift < 24u; shift += 8u) {
        let ca = (a >> shift) & 0xffu;
        let cb = (b >> shift) & 0xffu;
        step = max(step, max(ca, cb) - min(ca, cb));
    }
    return step;
}

struct Band {
    first_row: u32,
    rows: u32,
    first_pixel: u32,
    _pad: u32,
}

// How far a score is raised into the SGM volume: the smooth minimum of the halves (half_min)
// goes down to HALF_NOISE_FLOOR / 4 below the smaller half, and the levels start at 0.
const SGM_VOLUME_OFFSET: f32 = 6.25;

// The volume level of a scored cost (BIG = no valid pair -> SGM_COST_MAX); floor(x + 0.5) as
// the CPU twin (WGSL's round() rounds halves to even). The score is raised by
// SGM_VOLUME_OFFSET first, so that every score keeps its own level (sgm_select takes it off).
fn volume_level(score: f32) -> u32 {
    if (score >= 0.5 * BIG) {
        return SGM_COST_MAX;
    }
    let raised = max(score + SGM_VOLUME_OFFSET, 0.0);
    return min(u32(floor(raised * params.sgm_levels_per_unit + 0.5)), SGM_COST_MAX);
}

// Window anchors (top-left texel of a window) run from -(w-1) to W-1 (and likewise in y), so the
// box-sum images are padded by w-1 columns and h-1 rows; anchor (ax, ay) is stored at
// (ax + w - 1, ay + h - 1).

const MAX_BATCH_PLANES: u32 = 256u;

// One batch of planes. The batch's planes travel in this uniform block: every invocation reads
// the same plane at the same time, which a uniform load serves far better than a storage load
// on a software rasteriser.
struct Batch {
    first_plane: u32,
    plane_count: u32,
    is_first: u32,
    // Non-zero: a batch of the fine sweep (`subpixel_refine`): hypothesis k = first_plane + z of
    // each pixel lies in its own `hypotheses` entry, not on a plane, and no plane range applies.
    refine: u32,
    planes: array<vec4<f32>, MAX_BATCH_PLANES>,
}

// The fine sweep (`subpixel_refine`; CPU twin src/sweep/cpu/refine.rs: REACH, STEP,
// SAME_SURFACE, PHASE_SMOOTHING): hypotheses on each side of a pixel's base surface, their
// spacing in plane spacings, the window's band of one surface, the reference's smoothing to a
// sample's bilinear phase.
const REFINE_REACH: u32 = 2u;
const REFINE_STEP: f32 = 0.25;
const REFINE_SAME_SURFACE: f32 = 1.5;
const PHASE_SMOOTHING: f32 = 0.75;

// Ray parameter of hypothesis k of a fine-sweep pixel whose base surface is (inverse depth,
// plane spacing) `base` (NaN: no hypothesis); CPU twin: the hypotheses of `refine::run`.
fn refine_depth(base: vec2<f32>, k: u32) -> f32 {
    let offset = (f32(k) - f32(REFINE_REACH)) * REFINE_STEP;
    let q = base.x + offset * base.y;
    if (q > 0.0) {
        return 1.0 / q;
    }
    return nan();
}

// Projects a point in the reference frame into camera `cam`; returns pixel (xy) and depth in
// that camera (z), or z <= 0 when the point is behind it.
fn project(cam: Camera, point_in_ref: vec3<f32>) -> vec3<f32> {
    let p = vec3<f32>(
        dot(cam.row0.xyz, point_in_ref) + cam.row0.w,
        dot(cam.row1.xyz, point_in_ref) + cam.row1.w,
        dot(cam.row2.xyz, point_in_ref) + cam.row2.w,
    );
    return project_in_cam(cam, p);
}


// A pixel position is sampleable when bilinear interpolation needs no texel outside the image.
fn inside(cam: Camera, pixel: vec2<f32>) -> bool {
    let w = f32(cam.size.x) - 1.0;
    let h = f32(cam.size.y) - 1.0;
    return pixel.x >= 0.0 && pixel.y >= 0.0 && pixel.x <= w && pixel.y <= h;
}

// Depth (z, metres) of the plane n.X = e along the z = 1 ray `ray`; <= 0 when not in front.
fn plane_depth(plane: vec4<f32>, ray: vec3<f32>) -> f32 {
    let denom = dot(plane.xyz, ray);
    if (abs(denom) < 1e-12) {
        return -1.0;
    }
    return plane.w / denom;
}

// Sections of the `maps` buffer, each one reference image of f32 (counts and codes stored as f32).
// Coarse to fine on the device (plane_spans.wgsl, plane_ranges.wgsl; src/sweep/coarse.rs).
const MARGIN_PLANES: u32 = 3u;     // planes added on each side of a row's span
const TILE_MARGIN_PLANES: u32 = 7u; // planes added on each side of a tile's span
const NEIGHBOUR_ROWS: u32 = 2u;    // half-resolution rows either side of a row's own
const NO_SPAN: u32 = 0xffffffffu;  // a half-resolution row with no depth
const NEIGHBOUR_COLS: u32 = 8u;    // half-resolution columns either side of a tile's own
const RANGE_TILE: u32 = 16u;       // columns per tile of the plane ranges (plan.rs RANGE_TILE)

// Index of pixel (x, y)'s tile in the `plane_ranges` buffer of a reference `width` wide
// (row-major tiles of RANGE_TILE columns: SweepPlan::plane_ranges).
fn range_index(width: u32, x: u32, y: u32) -> u32 {
    return y * ((width + RANGE_TILE - 1u) / RANGE_TILE) + x / RANGE_TILE;
}

const MAP_DEPTH_RAW: u32 = 0u;     // after selection (+ sub-pixel)
const MAP_DEPTH_MEDIAN: u32 = 1u;  // after the 3x3 median
const MAP_DEPTH: u32 = 2u;         // after the occlusion check: the output
const MAP_CONFIDENCE: u32 = 3u;
const MAP_COST: u32 = 4u;
const MAP_SELECTION: u32 = 5u;
const MAP_VISIBLE: u32 = 6u;
const MAP_COUNT: u32 = 7u;

fn nan() -> f32 {
    return bitcast<f32>(0x7fc00000u);
}

// NaN test on the bits, immune to fast-math assumptions.
fn is_invalid(v: f32) -> bool {
    return (bitcast<u32>(v) & 0x7f800000u) == 0x7f800000u;
}

// Index (in the image / z-buffer layout) of the texel of `cam` nearest to a projection from
// `project`, or NO_CAMERA when the point is behind the camera or outside its image.
fn nearest_texel_index(cam: Camera, projected: vec3<f32>) -> u32 {
    let texel = floor(projected.xy + 0.5);
    if (projected.z <= 0.0 || !inside(cam, texel)) {
        return NO_CAMERA;
    }
    return cam.size.z + u32(texel.y) * cam.size.x + u32(texel.x);
}

// Stage 5a, selection: streaming winner-take-all that keeps, exactly and without a cost volume,
// the winner's neighbours (for the sub-pixel parabola) and the best rival away from them (for
// the confidence). See `state` for the layout.
struct Wta {
    s0: vec4<f32>,
    s1: vec4<f32>,
    s2: vec4<f32>,
}

// How clearly a winner `best` beats the best `rival` away from its neighbouring planes, 0..1
// (1 without a rival). CPU twin: select.rs `confidence`.
fn confidence(best: f32, rival: f32) -> f32 {
    if (rival < 0.5 * BIG) {
        return clamp((rival - best) / (rival + 1.0), 0.0, 1.0);
    }
    return 1.0;
}

fn select_plane(st: Wta, k: f32, best: vec2<f32>) -> Wta {
    var s0 = st.s0;
    var s1 = st.s1;
    var s2 = st.s2;
    let c = best.x;
    if (c < s0.x) {
        s0 = vec4<f32>(c, k, s1.w, BIG);
        s1.x = s1.z;
        s2.x = best.y;
    } else if (k == s0.y + 1.0) {
        s0.w = c;
    } else {
        s1.x = min(s1.x, c);
    }
    s1.z = s1.y;
    s1.y = min(s1.y, c);
    s1.w = c;
    return Wta(s0, s1, s2);
}

// The integer grey of a packed RGBA texel, 77 R + 150 G + 29 B (the census and the prefilter;
// CPU twin: src/sweep/census.rs `luma`).
fn census_luma(pixel: u32) -> u32 {
    return (pixel & 0xffu) * 77u + ((pixel >> 8u) & 0xffu) * 150u + ((pixel >> 16u) & 0xffu) * 29u;
}
