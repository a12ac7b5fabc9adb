// Coarse to fine on the device, step 2 of 2: each full-resolution row's plane range from the
// spans of its own and the neighbouring half-resolution rows (`plane_spans.wgsl`), widened by
// MARGIN_PLANES (every plane where those rows hold no depth), and the hull of the ranges of
// the rows within a window height of it: the `plane_ranges` buffer the sweep's stages read, as
// `SweepPlan::shader_plane_ranges` makes it on the host. One invocation per row. CPU twin:
// src/sweep/coarse.rs `plane_ranges` and src/sweep/plan.rs `shader_plane_ranges`.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> spans: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read_write> plane_ranges: array<vec4<u32>>;

// Row y's own range: the spans of half-resolution rows cy - NEIGHBOUR_ROWS ..= cy +
// NEIGHBOUR_ROWS, widened by MARGIN_PLANES.
fn own_range(y: u32) -> vec2<u32> {
    let ch = params.height / 2u;
    let cy = min(y / 2u, ch - 1u);
    var lo = NO_SPAN;
    var hi = 0u;
    for (var r = cy - min(cy, NEIGHBOUR_ROWS); r <= min(cy + NEIGHBOUR_ROWS, ch - 1u); r++) {
        let span = spans[r];
        if (span.x != NO_SPAN) {
            lo = min(lo, span.x);
            hi = max(hi, span.y);
        }
    }
    if (lo == NO_SPAN) {
        return vec2<u32>(0u, params.planes - 1u);
    }
    return vec2<u32>(lo - min(lo, MARGIN_PLANES), min(hi + MARGIN_PLANES, params.planes - 1u));
}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let y = gid.x;
    if (y >= params.height) {
        return;
    }
    let reach = params.window_h - min(params.window_h, 1u);
    let own = own_range(y);
    var lo = own.x;
    var hi = own.y;
    for (var r = y - min(y, reach); r <= min(y + reach, params.height - 1u); r++) {
        let near = own_range(r);
        lo = min(lo, near.x);
        hi = max(hi, near.y);
    }
    plane_ranges[y] = vec4<u32>(own.x, own.y, lo, hi);
}
