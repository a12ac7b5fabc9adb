// Stage 6a: 3x3 median of the depth over valid neighbours; invalid pixels stay invalid.
// With the median disabled (params.median == 0) the depth is copied.
// One invocation per reference pixel. CPU twin: src/sweep/cpu/median.rs.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read_write> maps: array<f32>;

// Depth of the neighbour at (dx, dy), BIG when outside the image or invalid.
fn neighbour(gid: vec3<u32>, dx: i32, dy: i32) -> f32 {
    let x = i32(gid.x) + dx;
    let y = i32(gid.y) + dy;
    if (x < 0 || y < 0 || x >= i32(params.width) || y >= i32(params.height)) {
        return BIG;
    }
    let d = maps[MAP_DEPTH_RAW * params.pixel_count + u32(y) * params.width + u32(x)];
    return select(d, BIG, is_invalid(d));
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let width = params.width;
    let height = params.height;
    if (gid.x >= width || gid.y >= height) {
        return;
    }
    let npix = params.pixel_count;
    let pix = gid.y * width + gid.x;
    let centre = maps[MAP_DEPTH_RAW * npix + pix];
    if (is_invalid(centre) || params.median == 0u) {
        maps[MAP_DEPTH_MEDIAN * npix + pix] = centre;
        return;
    }
    // Invalid neighbours (and those outside the image) become +BIG and sort last; a 25-comparator
    // sorting network on plain variables (no data-dependent indexing) orders the nine values.
    var v0 = neighbour(gid, -1, -1);
    var v1 = neighbour(gid, 0, -1);
    var v2 = neighbour(gid, 1, -1);
    var v3 = neighbour(gid, -1, 0);
    var v4 = neighbour(gid, 0, 0);
    var v5 = neighbour(gid, 1, 0);
    var v6 = neighbour(gid, -1, 1);
    var v7 = neighbour(gid, 0, 1);
    var v8 = neighbour(gid, 1, 1);
    var count = 0u;
    count += select(0u, 1u, v0 < BIG);
    count += select(0u, 1u, v1 < BIG);
    count += select(0u, 1u, v2 < BIG);
    count += select(0u, 1u, v3 < BIG);
    count += select(0u, 1u, v4 < BIG);
    count += select(0u, 1u, v5 < BIG);
    count += select(0u, 1u, v6 < BIG);
    count += select(0u, 1u, v7 < BIG);
    count += select(0u, 1u, v8 < BIG);
    var t = 0.0;
    t = min(v0, v1); v1 = max(v0, v1); v0 = t;
    t = min(v3, v4); v4 = max(v3, v4); v3 = t;
    t = min(v6, v7); v7 = max(v6, v7); v6 = t;
    t = min(v1, v2); v2 = max(v1, v2); v1 = t;
    t = min(v4, v5); v5 = max(v4, v5); v4 = t;
    t = min(v7, v8); v8 = max(v7, v8); v7 = t;
    t = min(v0, v1); v1 = max(v0, v1); v0 = t;
    t = min(v3, v4); v4 = max(v3, v4); v3 = t;
    t = min(v6, v7); v7 = max(v6, v7); v6 = t;
    t = min(v0, v3); v3 = max(v0, v3); v0 = t;
    t = min(v3, v6); v6 = max(v3, v6); v3 = t;
    t = min(v0, v3); v3 = max(v0, v3); v0 = t;
    t = min(v1, v4); v4 = max(v1, v4); v1 = t;
    t = min(v4, v7); v7 = max(v4, v7); v4 = t;
    t = min(v1, v4); v4 = max(v1, v4); v1 = t;
    t = min(v2, v5); v5 = max(v2, v5); v2 = t;
    t = min(v5, v8); v8 = max(v5, v8); v5 = t;
    t = min(v2, v5); v5 = max(v2, v5); v2 = t;
    t = min(v1, v3); v3 = max(v1, v3); v1 = t;
    t = min(v5, v7); v7 = max(v5, v7); v5 = t;
    t = min(v2, v6); v6 = max(v2, v6); v2 = t;
    t = min(v4, v6); v6 = max(v4, v6); v4 = t;
    t = min(v2, v4); v4 = max(v2, v4); v2 = t;
    t = min(v2, v3); v3 = max(v2, v3); v2 = t;
    t = min(v5, v6); v6 = max(v5, v6); v5 = t;
    // Lower median of the valid values: at most 9 valid, so index (count - 1) / 2 <= 4.
    let median_index = (count - 1u) / 2u;
    var median = v0;
    median = select(median, v1, median_index == 1u);
    median = select(median, v2, median_index == 2u);
    median = select(median, v3, median_index == 3u);
    median = select(median, v4, median_index == 4u);
    maps[MAP_DEPTH_MEDIAN * npix + pix] = median;
}
