// Stage 6c: occlusion consistency. A reference pixel is seen by camera i when its depth there is
// not behind that camera's z-buffer by more than the relative tolerance, or not by more than
// occlusion_inverse_depth in inverse depth (two plane steps: neighbours a fraction of a plane
// apart that land on one texel do not hide each other). Pixels seen by fewer than
// min_visible_cameras (the reference counted) become invalid.
// One invocation per reference pixel. CPU twin: src/sweep/cpu/occlusion.rs.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> cameras: array<Camera, MAX_RIG_CAMERAS>;
@group(0) @binding(2) var<storage, read> rays: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> zbuffer: array<u32>;
@group(0) @binding(4) var<storage, read_write> maps: array<f32>;

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
        maps[MAP_DEPTH * npix + pix] = depth;
        maps[MAP_VISIBLE * npix + pix] = 0.0;
        return;
    }
    let point_in_ref = rays[pix].xyz * depth;
    let tolerance = params.occlusion_tolerance;
    var seen = 0u;
    if (params.reference != NO_CAMERA) {
        seen = 1u;
    }
    for (var i = 0u; i < params.cameras; i++) {
        if (i == params.reference) {
            continue;
        }
        let projected = project(cameras[i], point_in_ref);
        let index = nearest_texel_index(cameras[i], projected);
        if (index == NO_CAMERA) {
            continue;
        }
        let stored = zbuffer[index];
        let nearest = bitcast<f32>(~stored);
        let z = projected.z;
        // Not behind the nearest surface by more than the relative tolerance, or by more than
        // occlusion_inverse_depth in inverse depth (1 / nearest - 1 / z, multiplied out).
        if (stored == 0u || z <= nearest * (1.0 + tolerance)
            || z - nearest <= params.occlusion_inverse_depth * (z * nearest)) {
            seen += 1u;
        }
    }
    maps[MAP_VISIBLE * npix + pix] = f32(seen);
    if (seen < params.min_visible) {
        maps[MAP_DEPTH * npix + pix] = nan();
        maps[MAP_CONFIDENCE * npix + pix] = 0.0;
        maps[MAP_SELECTION * npix + pix] = f32(SEL_INVALID);
    } else {
        maps[MAP_DEPTH * npix + pix] = depth;
    }
}
