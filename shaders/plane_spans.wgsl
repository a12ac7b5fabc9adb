// Coarse to fine on the device, step 1 of 2: the span of planes of each half-resolution row
// under each range tile (the planes nearest its valid depths in the tile's half-resolution
// columns and NEIGHBOUR_COLS more each side, in inverse depth along the full-resolution ray of
// the pixel each stands for), and of the whole row, for the level that the half-resolution
// sweep narrows. One workgroup per half-resolution row, its lanes across the tiles, the
// row's span by workgroup atomics (min and max: the order does not matter). `spans` holds the
// tiles' spans row-major, then the rows' spans. `params`, `rays` and `planes` are the
// full-resolution level's; `coarse_depth` is the level below's raw depth (copied from its
// `maps`), half the width and height. CPU twin: src/sweep/coarse.rs `plane_ranges` (its
// `tile_spans` and `row_spans`) and `nearest_plane`, step for step in f32.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> rays: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> planes: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> coarse_depth: array<f32>;
@group(0) @binding(4) var<storage, read_write> spans: array<vec2<u32>>;

// Inverse depth of plane k along `ray` (coarse.rs `nearest_plane`'s `q_of`).
fn plane_q(k: u32, ray: vec4<f32>) -> f32 {
    let p = planes[k];
    return (p.x * ray.x + p.y * ray.y + p.z * ray.z) / p.w;
}

// The plane whose inverse depth along pixel `pix`'s ray is nearest 1 / `depth` (a binary
// search: the planes are in order of inverse depth).
fn nearest_plane(pix: u32, depth: f32) -> u32 {
    let ray = rays[pix];
    let q = 1.0 / depth;
    let n = params.planes;
    let rising = plane_q(n - 1u, ray) >= plane_q(0u, ray);
    var lo = 0u;
    var hi = n;
    while (lo < hi) {
        let mid = (lo + hi) / 2u;
        let qm = plane_q(mid, ray);
        let before = select(qm > q, qm < q, rising);
        if (before) {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    if (lo == 0u) {
        return 0u;
    }
    if (lo == n || abs(plane_q(lo - 1u, ray) - q) <= abs(plane_q(lo, ray) - q)) {
        return lo - 1u;
    }
    return lo;
}

const SPAN_LANES: u32 = 64u;

var<workgroup> span_lo: atomic<u32>;
var<workgroup> span_hi: atomic<u32>;

@compute @workgroup_size(64, 1, 1)
fn main(
    @builtin(workgroup_id) group: vec3<u32>,
    @builtin(local_invocation_index) lane: u32,
) {
    let cw = params.width / 2u;
    let ch = params.height / 2u;
    let tiles = (params.width + RANGE_TILE - 1u) / RANGE_TILE;
    let cy = group.x;
    if (lane == 0u) {
        atomicStore(&span_lo, NO_SPAN);
        atomicStore(&span_hi, 0u);
    }
    workgroupBarrier();
    let y = min(2u * cy, params.height - 1u);
    let half_tile = RANGE_TILE / 2u;
    var row_lo = NO_SPAN;
    var row_hi = 0u;
    for (var t = lane; t < tiles; t += SPAN_LANES) {
        let first = min(t * half_tile - min(t * half_tile, NEIGHBOUR_COLS), cw);
        let end = min((t + 1u) * half_tile + NEIGHBOUR_COLS, cw);
        var lo = NO_SPAN;
        var hi = 0u;
        for (var cx = first; cx < end; cx++) {
            let depth = coarse_depth[cy * cw + cx];
            // Finite and positive (NaN marks no depth).
            let finite = (bitcast<u32>(depth) & 0x7f800000u) != 0x7f800000u;
            if (finite && depth > 0.0) {
                let x = min(2u * cx, params.width - 1u);
                let k = nearest_plane(y * params.width + x, depth);
                lo = min(lo, k);
                hi = max(hi, k);
            }
        }
        spans[cy * tiles + t] = vec2<u32>(lo, hi);
        row_lo = min(row_lo, lo);
        row_hi = max(row_hi, hi);
    }
    atomicMin(&span_lo, row_lo);
    atomicMax(&span_hi, row_hi);
    workgroupBarrier();
    if (lane == 0u) {
        spans[ch * tiles + cy] = vec2<u32>(atomicLoad(&span_lo), atomicLoad(&span_hi));
    }
}
