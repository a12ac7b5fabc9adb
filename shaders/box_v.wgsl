// Stage 4b: vertical window sums of the row sums: for every anchor (ax, ay) the sum and count of
// the valid costs in the w x h window whose top-left texel is (ax, ay).
// One invocation per (padded column, padded row); it walks the planes x channels of the batch. CPU twin: src/sweep/cpu/boxes.rs.

override WINDOW_H: u32 = 2u;      // = params.window_h
override CHANNELS: u32 = 1u;      // = params.channels

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> batch: Batch;
@group(0) @binding(2) var<storage, read> row_sums: array<vec2<f32>>;
@group(0) @binding(3) var<storage, read_write> box_sums: array<vec2<f32>>;
// Per reference row and tile (SweepPlan::shader_plane_ranges; coarse to fine): xy the planes
// its pixels sweep.
@group(0) @binding(4) var<storage, read> plane_ranges: array<vec4<u32>>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let height = params.height;
    let padded_w = params.padded_w;
    let padded_h = params.padded_h;
    if (gid.x >= padded_w || gid.y >= padded_h) {
        return;
    }
    let ay = i32(gid.y) - i32(WINDOW_H) + 1;
    let y_first = max(ay, 0);
    let y_end = min(ay + i32(WINDOW_H), i32(height));
    // Only the pixels of this window read its sums: the planes none of them sweeps are
    // skipped.
    let width = params.width;
    let window_w = i32(params.window_w);
    let ax = i32(gid.x) - window_w + 1;
    let x_first = u32(max(ax, 0));
    let x_last = u32(min(ax + window_w, i32(width)) - 1);
    var needed = vec2<u32>(0u, batch.first_plane + batch.plane_count);
    if (y_first < y_end) {
        needed = vec2<u32>(NO_SPAN, 0u);
        for (var y = y_first; y < y_end; y++) {
            for (var t = x_first / RANGE_TILE; t <= x_last / RANGE_TILE; t++) {
                let range = plane_ranges[range_index(width, t * RANGE_TILE, u32(y))].xy;
                needed = vec2<u32>(min(needed.x, range.x), max(needed.y, range.y));
            }
        }
    }
    for (var zc = 0u; zc < batch.plane_count * CHANNELS; zc++) {
        let k = batch.first_plane + zc / CHANNELS;
        // Every hypothesis of the fine sweep is summed.
        if (batch.refine == 0u && (k < needed.x || k > needed.y)) {
            continue;
        }
        var acc = vec2<f32>(0.0);
        for (var y = y_first; y < y_end; y++) {
            acc += row_sums[(zc * height + u32(y)) * padded_w + gid.x];
        }
        box_sums[(zc * padded_h + gid.y) * padded_w + gid.x] = acc;
    }
}
