// The fine sweep's result (`subpixel_refine`, last of its stages): the best hypothesis of the
// streaming winner-take-all over the fine sweep's batches (`state`, as aggregate.wgsl leaves
// it) and the parabola through it and its neighbours give the raw depth; a best hypothesis at
// either end of the range, or none, keeps the finalized one. One invocation per pixel.
// CPU twin: the end of `run` in src/sweep/cpu/refine.rs.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> state: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> hypotheses: array<vec2<f32>>;
@group(0) @binding(3) var<storage, read_write> maps: array<f32>;

// The offset (in hypotheses, -0.5..0.5) of the parabola's minimum through three scores, 0
// where they do not curve up (`parabola` of the CPU twin).
fn parabola(before: f32, best: f32, after: f32) -> f32 {
    let curvature = before - 2.0 * best + after;
    if (curvature > 0.0) {
        return clamp(0.5 * (before - after) / curvature, -0.5, 0.5);
    }
    return 0.0;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let width = params.width;
    if (gid.x >= width || gid.y >= params.height) {
        return;
    }
    let pix = gid.y * width + gid.x;
    let base = hypotheses[pix];
    let s0 = state[3u * pix];
    let count = 2u * REFINE_REACH + 1u;
    // No valid hypothesis (the state's best plane stays -1), or the best at an end.
    if (is_invalid(base.x) || !(s0.x < 0.5 * BIG) || s0.y < 1.0 || s0.y + 2.0 > f32(count)) {
        return;
    }
    let j = u32(s0.y);
    var fit = 0.0;
    if (s0.z < 0.5 * BIG && s0.w < 0.5 * BIG) {
        fit = parabola(s0.z, s0.x, s0.w);
    }
    let offset = f32(j) - f32(REFINE_REACH) + fit;
    let refined = base.x + offset * REFINE_STEP * base.y;
    if (refined > 0.0) {
        maps[MAP_DEPTH_RAW * params.pixel_count + pix] = 1.0 / refined;
    }
}
