// The fine sweep's base surface (`subpixel_refine`, first of its stages): per reference pixel,
// the plane spacing in inverse depth on its ray and the mean inverse depth of the window's
// pixels within REFINE_SAME_SURFACE spacings of its own raw depth (NaN where the raw depth is
// invalid). The fine sweep's hypotheses lie around it (`refine_depth` in common.wgsl): a
// window follows the smoothed surface, slanted where it is slanted. One invocation per pixel.
// CPU twin: `base_surface` in src/sweep/cpu/refine.rs.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> rays: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> planes: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> maps: array<f32>;
@group(0) @binding(4) var<storage, read_write> hypotheses: array<vec2<f32>>;

fn inverse_depth(k: u32, ray: vec3<f32>) -> f32 {
    let plane = planes[k];
    return dot(plane.xyz, ray) / plane.w;
}

// The raw depth's inverse at pixel `pix` (NaN where it is invalid).
fn raw_inverse(pix: u32) -> f32 {
    let t = maps[MAP_DEPTH_RAW * params.pixel_count + pix];
    if (is_invalid(t) || !(t > 0.0)) {
        return nan();
    }
    return 1.0 / t;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let width = params.width;
    let height = params.height;
    if (gid.x >= width || gid.y >= height) {
        return;
    }
    let pix = gid.y * width + gid.x;
    let ray = rays[pix].xyz;
    let spacing = abs(inverse_depth(1u, ray) - inverse_depth(0u, ray));
    let q = raw_inverse(pix);
    if (is_invalid(q)) {
        hypotheses[pix] = vec2<f32>(nan(), spacing);
        return;
    }
    let near = REFINE_SAME_SURFACE * spacing;
    let rx = (params.window_w - 1u) / 2u;
    let ry = (params.window_h - 1u) / 2u;
    var sum = 0.0;
    var count = 0.0;
    for (var y = max(gid.y, ry) - ry; y < min(gid.y + ry + 1u, height); y++) {
        for (var x = max(gid.x, rx) - rx; x < min(gid.x + rx + 1u, width); x++) {
            let n = raw_inverse(y * width + x);
            if (!is_invalid(n) && abs(n - q) <= near) {
                sum += n;
                count += 1.0;
            }
        }
    }
    hypotheses[pix] = vec2<f32>(sum / count, spacing);
}
