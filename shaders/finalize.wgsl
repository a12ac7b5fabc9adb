// Stage 5b: winner -> depth (sub-pixel parabola or V in inverse depth), max_cost and range-end invalidation, confidence.
// One invocation per reference pixel. CPU twin: src/sweep/cpu/finalize.rs.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> rays: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> planes: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> state: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> maps: array<f32>;

fn inverse_depth(k: u32, ray: vec3<f32>) -> f32 {
    let plane = planes[k];
    return dot(plane.xyz, ray) / plane.w;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let width = params.width;
    if (gid.x >= width || gid.y >= params.height) {
        return;
    }
    let npix = params.pixel_count;
    let pix = gid.y * width + gid.x;
    let s0 = state[3u * pix];
    let s1 = state[3u * pix + 1u];
    let s2 = state[3u * pix + 2u];
    let best = s0.x;
    let n_planes = params.planes;
    let max_cost = params.max_cost;

    if (!(best < 0.5 * BIG) || best > max_cost || s0.y < 0.0) {
        maps[MAP_DEPTH_RAW * npix + pix] = nan();
        maps[MAP_CONFIDENCE * npix + pix] = 0.0;
        maps[MAP_COST * npix + pix] = nan();
        maps[MAP_SELECTION * npix + pix] = f32(SEL_INVALID);
        return;
    }
    let k = u32(s0.y);
    if (params.keep_range_ends == 0u && (k == 0u || k + 1u == n_planes)) {
        // At the range's end: the surface is likely nearer or farther than the range.
        maps[MAP_DEPTH_RAW * npix + pix] = nan();
        maps[MAP_CONFIDENCE * npix + pix] = 0.0;
        maps[MAP_COST * npix + pix] = best;
        maps[MAP_SELECTION * npix + pix] = f32(SEL_INVALID);
        return;
    }
    let ray = rays[pix].xyz;
    var q = inverse_depth(k, ray);
    if (params.subpixel != 0u && k > 0u && k + 1u < n_planes && s0.z < 0.5 * BIG && s0.w < 0.5 * BIG) {
        let curvature = s0.z - 2.0 * best + s0.w;
        if (curvature > 0.0) {
            // The parabola's second difference, or the V's slope (subpixel_v_fit: its steeper
            // side's rise); CPU twin `subpixel_offset`.
            var denominator = curvature;
            if ((params.subpixel & SUBPIXEL_V_FIT) != 0u) {
                denominator = max(s0.z, s0.w) - best;
            }
            let offset = clamp(0.5 * (s0.z - s0.w) / denominator, -0.5, 0.5);
            if (offset > 0.0) {
                q += offset * (inverse_depth(k + 1u, ray) - q);
            } else {
                q += -offset * (inverse_depth(k - 1u, ray) - q);
            }
        }
    }
    // Confidence: how clearly the winner beats the best rival away from its neighbours.
    let sgm_conf = confidence(best, s1.x);
    // Uniqueness on the matching costs themselves (sgm_select.wgsl keeps it in s2.y): SGM's
    // sums make one of several equally good depths win along every path.
    var local = sgm_conf;
    var conf = sgm_conf;
    if (params.sgm_paths > 0u) {
        local = s2.y;
        if (params.ambiguity > 0.0) {
            conf = sgm_conf * min(local / params.ambiguity, 1.0);
        }
    }
    if (local < params.uniqueness) {
        // Ambiguous: a rival away from the winner nearly as good (CPU twin: finalize.rs).
        maps[MAP_DEPTH_RAW * npix + pix] = nan();
        maps[MAP_CONFIDENCE * npix + pix] = conf;
        maps[MAP_COST * npix + pix] = best;
        maps[MAP_SELECTION * npix + pix] = f32(SEL_INVALID);
        return;
    }
    maps[MAP_DEPTH_RAW * npix + pix] = 1.0 / q;
    maps[MAP_CONFIDENCE * npix + pix] = conf;
    maps[MAP_COST * npix + pix] = best;
    maps[MAP_SELECTION * npix + pix] = s2.x;
}
