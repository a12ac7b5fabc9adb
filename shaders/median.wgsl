// Stage 6a: 3x3 median of the depth over valid neighbours; invalid pixels stay invalid.
// With the median disabled (params.window.w == 0) the depth is copied.
// One invocation per reference pixel. CPU twin: src/sweep/cpu/median.rs.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read_write> maps: array<f32>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let width = params.ref_size.x;
    let height = params.ref_size.y;
    if (gid.x >= width || gid.y >= height) {
        return;
    }
    let npix = params.ref_size.z;
    let pix = gid.y * width + gid.x;
    let centre = maps[MAP_DEPTH_RAW * npix + pix];
    if (is_invalid(centre) || params.window.w == 0u) {
        maps[MAP_DEPTH_MEDIAN * npix + pix] = centre;
        return;
    }
    var values: array<f32, 9>;
    var count = 0u;
    for (var dy = -1; dy <= 1; dy++) {
        let y = i32(gid.y) + dy;
        if (y < 0 || y >= i32(height)) {
            continue;
        }
        for (var dx = -1; dx <= 1; dx++) {
            let x = i32(gid.x) + dx;
            if (x < 0 || x >= i32(width)) {
                continue;
            }
            let v = maps[MAP_DEPTH_RAW * npix + u32(y) * width + u32(x)];
            if (is_invalid(v)) {
                continue;
            }
            // Insertion sort as we go.
            var i = count;
            loop {
                if (i == 0u || values[i - 1u] <= v) {
                    break;
                }
                values[i] = values[i - 1u];
                i -= 1u;
            }
            values[i] = v;
            count += 1u;
        }
    }
    maps[MAP_DEPTH_MEDIAN * npix + pix] = values[(count - 1u) / 2u];
}
