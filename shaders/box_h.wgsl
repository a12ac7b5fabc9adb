// Stage 4a: horizontal window sums. For every channel of the cost slab and every window anchor
// ax in [-(w-1), W-1], the sum and count of the valid (>= 0) costs in columns ax .. ax+w-1.
// One invocation per (padded column, row); it walks the planes x channels of the batch. CPU twin: src/sweep/cpu/boxes.rs.

override WINDOW_W: u32 = 2u;      // = params.window_w
override CHANNELS: u32 = 1u;      // = params.channels

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> batch: Batch;
@group(0) @binding(2) var<storage, read> cost_slab: array<f32>;
@group(0) @binding(3) var<storage, read_write> row_sums: array<vec2<f32>>;
// Per reference row and tile (SweepPlan::shader_plane_ranges; coarse to fine): xy the planes
// its pixels sweep, zw the planes the pixels whose windows reach it sweep; an anchor sums only
// the zw planes of its first column's tile (the pixels that read it lie within window_w - 1
// columns of that column).
@group(0) @binding(4) var<storage, read> plane_ranges: array<vec4<u32>>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let width = params.width;
    let height = params.height;
    let padded_w = params.padded_w;
    if (gid.x >= padded_w || gid.y >= height) {
        return;
    }
    let npix = params.pixel_count;
    let ax = i32(gid.x) - i32(WINDOW_W) + 1;
    // The columns of the window that lie inside the image.
    let x_first = max(ax, 0);
    let x_end = min(ax + i32(WINDOW_W), i32(width));
    let needed = plane_ranges[range_index(width, u32(x_first), gid.y)].zw;
    for (var zc = 0u; zc < batch.plane_count * CHANNELS; zc++) {
        let k = batch.first_plane + zc / CHANNELS;
        // Every hypothesis of the fine sweep is summed.
        if (batch.refine == 0u && (k < needed.x || k > needed.y)) {
            continue;
        }
        let row = zc * npix + gid.y * width;
        var acc = vec2<f32>(0.0);
        for (var x = x_first; x < x_end; x++) {
            let c = cost_slab[row + u32(x)];
            if (c >= 0.0) {
                acc += vec2<f32>(c, 1.0);
            }
        }
        row_sums[(zc * height + gid.y) * padded_w + gid.x] = acc;
    }
}
