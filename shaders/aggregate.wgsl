// Stage 4: shiftable-window aggregation of the cost slab, and the half-sequence decision.
// For a window of w x h texels the four placements with the pixel at a corner (up-left, up-right,
// down-left, down-right) are averaged over their valid texels; the best (smallest) mean wins.
// w = h = 2 is the paper's shiftable 2x2; w = h = 1 is no aggregation.
// One invocation per (reference pixel, plane of the batch). CPU twin: src/sweep/cpu/aggregate.rs.

override WINDOW_W: u32 = 2u;      // = params.window.x
override WINDOW_H: u32 = 2u;      // = params.window.y
override CHANNELS: u32 = 1u;      // = params.counts.z
override AGGREGATION: u32 = 0u;   // = params.modes.w

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> batch: Batch;
@group(0) @binding(2) var<storage, read> cost_slab: array<f32>;
@group(0) @binding(3) var<storage, read_write> agg_slab: array<vec2<f32>>;

fn window_min(sums: vec4<f32>, counts: vec4<f32>) -> f32 {
    var best = BIG;
    for (var i = 0; i < 4; i++) {
        if (counts[i] > 0.0) {
            best = min(best, sums[i] / counts[i]);
        }
    }
    return best;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let width = params.ref_size.x;
    let height = params.ref_size.y;
    if (gid.x >= width || gid.y >= height || gid.z >= batch.plane_count) {
        return;
    }
    let npix = params.ref_size.z;
    let channels = CHANNELS;
    let base = gid.z * channels * npix;
    let reach_x = i32(WINDOW_W) - 1;
    let reach_y = i32(WINDOW_H) - 1;

    // Stream 0: channel 0; stream 1: channel 1; stream 2: per-texel min of both channels.
    var sums: array<vec4<f32>, 3>;
    var counts: array<vec4<f32>, 3>;
    for (var dy = -reach_y; dy <= reach_y; dy++) {
        let y = i32(gid.y) + dy;
        if (y < 0 || y >= i32(height)) {
            continue;
        }
        for (var dx = -reach_x; dx <= reach_x; dx++) {
            let x = i32(gid.x) + dx;
            if (x < 0 || x >= i32(width)) {
                continue;
            }
            let mask = vec4<f32>(
                select(0.0, 1.0, dx <= 0 && dy <= 0),
                select(0.0, 1.0, dx >= 0 && dy <= 0),
                select(0.0, 1.0, dx <= 0 && dy >= 0),
                select(0.0, 1.0, dx >= 0 && dy >= 0),
            );
            let p = u32(y) * width + u32(x);
            let c0 = cost_slab[base + p];
            if (c0 >= 0.0) {
                sums[0] += c0 * mask;
                counts[0] += mask;
            }
            if (channels == 2u) {
                let c1 = cost_slab[base + npix + p];
                if (c1 >= 0.0) {
                    sums[1] += c1 * mask;
                    counts[1] += mask;
                }
                var m = c0;
                if (c0 < 0.0 || (c1 >= 0.0 && c1 < c0)) {
                    m = c1;
                }
                if (m >= 0.0) {
                    sums[2] += m * mask;
                    counts[2] += mask;
                }
            }
        }
    }

    let out_index = gid.z * npix + gid.y * width + gid.x;
    if (channels == 1u) {
        agg_slab[out_index] = vec2<f32>(window_min(sums[0], counts[0]), f32(SEL_NONE));
        return;
    }
    let left = window_min(sums[0], counts[0]);
    let right = window_min(sums[1], counts[1]);
    var score = min(left, right);
    if (AGGREGATION == AGG_SCORED) {
        score = window_min(sums[2], counts[2]);
    }
    let keep = 1.0 - params.thresholds.w;
    var sel = SEL_NONE;
    if (left < BIG && (right >= BIG || left < keep * right)) {
        sel = SEL_LEFT;
    } else if (right < BIG && (left >= BIG || right < keep * left)) {
        sel = SEL_RIGHT;
    }
    agg_slab[out_index] = vec2<f32>(score, f32(sel));
}
