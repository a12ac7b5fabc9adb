// Coarse to fine on the device, step 2 of 2: each full-resolution (row, tile)'s plane range
// from the spans of its tile and of the whole rows in its own and the neighbouring
// half-resolution rows (`plane_spans.wgsl`): the tile's widened by TILE_MARGIN_PLANES within
// the rows' widened by MARGIN_PLANES (the rows' where the tile holds no depth, every plane
// where the rows hold none), and the hull of the ranges of the tiles whose pixels' windows
// reach it (window_h - 1 rows and window_w - 1 columns either way): the `plane_ranges` buffer
// the sweep's stages read, as `SweepPlan::shader_plane_ranges` makes it on the host. One
// invocation per (tile, row). CPU twin: src/sweep/coarse.rs `plane_ranges` and
// src/sweep/plan.rs `tile_hulls`.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> spans: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read_write> plane_ranges: array<vec4<u32>>;

// Tile t of row y's own range (see the top).
fn own_range(t: u32, y: u32, tiles: u32) -> vec2<u32> {
    let ch = params.height / 2u;
    let cy = min(y / 2u, ch - 1u);
    var lo = NO_SPAN;
    var hi = 0u;
    var row_lo = NO_SPAN;
    var row_hi = 0u;
    for (var r = cy - min(cy, NEIGHBOUR_ROWS); r <= min(cy + NEIGHBOUR_ROWS, ch - 1u); r++) {
        let span = spans[r * tiles + t];
        if (span.x != NO_SPAN) {
            lo = min(lo, span.x);
            hi = max(hi, span.y);
        }
        let row = spans[ch * tiles + r];
        if (row.x != NO_SPAN) {
            row_lo = min(row_lo, row.x);
            row_hi = max(row_hi, row.y);
        }
    }
    let last = params.planes - 1u;
    if (row_lo == NO_SPAN) {
        return vec2<u32>(0u, last);
    }
    let row_range = vec2<u32>(row_lo - min(row_lo, MARGIN_PLANES), min(row_hi + MARGIN_PLANES, last));
    if (lo == NO_SPAN) {
        return row_range;
    }
    return vec2<u32>(
        max(lo - min(lo, TILE_MARGIN_PLANES), row_range.x),
        min(min(hi + TILE_MARGIN_PLANES, last), row_range.y),
    );
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let tiles = (params.width + RANGE_TILE - 1u) / RANGE_TILE;
    let t = gid.x;
    let y = gid.y;
    if (t >= tiles || y >= params.height) {
        return;
    }
    let reach_y = params.window_h - min(params.window_h, 1u);
    let reach_x = params.window_w - min(params.window_w, 1u);
    let first = (t * RANGE_TILE - min(t * RANGE_TILE, reach_x)) / RANGE_TILE;
    let last = min((min((t + 1u) * RANGE_TILE, params.width) - 1u + reach_x) / RANGE_TILE, tiles - 1u);
    let own = own_range(t, y, tiles);
    var lo = own.x;
    var hi = own.y;
    for (var r = y - min(y, reach_y); r <= min(y + reach_y, params.height - 1u); r++) {
        for (var u = first; u <= last; u++) {
            let near = own_range(u, r, tiles);
            lo = min(lo, near.x);
            hi = max(hi, near.y);
        }
    }
    plane_ranges[y * tiles + t] = vec4<u32>(own.x, own.y, lo, hi);
}
