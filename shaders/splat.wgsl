// Stage 6b: splat the reference depth map into every other camera as a z-buffer (the paper's
// shadow mapping). Each texel keeps the nearest depth (metres, in that camera), stored as the
// bitwise NOT of the f32 bits so that a cleared (zero) buffer means "empty" and atomicMax keeps
// the minimum positive depth. Offsets per camera are those of the image buffer.
// One invocation per reference pixel. CPU twin: src/sweep/cpu/occlusion.rs.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> cameras: array<Camera, MAX_RIG_CAMERAS>;
@group(0) @binding(2) var<storage, read> rays: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> maps: array<f32>;
@group(0) @binding(4) var<storage, read_write> zbuffer: array<atomic<u32>>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let width = params.width;
    if (gid.x >= width || gid.y >= params.height) {
        return;
    }
    let npix = params.pixel_count;
    let pix = gid.y * width + gid.x;
    let depth = maps[MAP_DEPTH_MEDIAN * npix + pix];
    if (is_invalid(depth)) {
        return;
    }
    let point_in_ref = rays[pix].xyz * depth;
    for (var i = 0u; i < params.cameras; i++) {
        if (i == params.reference) {
            continue;
        }
        let projected = project(cameras[i], point_in_ref);
        let index = nearest_texel_index(cameras[i], projected);
        if (index != NO_CAMERA) {
            atomicMax(&zbuffer[index], ~bitcast<u32>(projected.z));
        }
    }
}
