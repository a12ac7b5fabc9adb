// Stage 5a' (optimizer sgm): winner-take-all over the summed path costs of sgm.wgsl, in score
// units (sum / (paths x levels per score unit)), into the same selection state the streaming
// winner-take-all of aggregate.wgsl fills (winner, its neighbours for the sub-pixel parabola,
// the best rival away from them for the confidence), so finalize.wgsl reads either. Pixels
// with no valid hypothesis stay invalid, and the half-sequence selection of the local winner is
// kept; where `uniqueness` or `ambiguity` reads it, the winner's uniqueness on the matching costs
// of the volume (in s2.y). One invocation per reference pixel. CPU twin: src/sweep/cpu/sgm.rs
// (`select`, `uniqueness_on_costs`).

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> sums: array<u32>;
@group(0) @binding(2) var<storage, read_write> state: array<vec4<f32>>;
// The rows of this dispatch; `sums` holds only theirs.
@group(0) @binding(3) var<uniform> band: Band;
// The matching costs of this band's rows, as SGM read them.
@group(0) @binding(4) var<storage, read> volume: array<u32>;

// A volume level back to score units (CPU twin: `level_score`).
fn level_score(level: u32) -> f32 {
    return f32(level) / params.sgm_levels_per_unit - SGM_VOLUME_OFFSET;
}

// How clearly plane `best` is the best match on the matching costs of pixel `local_pix` of the
// band: its cost against the lowest more than `uniqueness_radius` planes away (a repeated
// pattern matches as well one period away; SGM's paths make one of them win clearly).
fn uniqueness_on_costs(local_pix: u32, best: u32) -> f32 {
    let planes = params.planes;
    let words = (planes + 1u) / 2u;
    let radius = max(params.uniqueness_radius, 1u);
    var rival = 0xffffu;
    var best_level = 0xffffu;
    for (var j = 0u; j < words; j++) {
        let word = volume[local_pix * words + j];
        for (var h = 0u; h < 2u; h++) {
            let d = 2u * j + h;
            let level = (word >> (16u * h)) & 0xffffu;
            if (d >= planes) {
                break;
            }
            if (d == best) {
                best_level = level;
            }
            // A plane outside the pixel's range (SGM_OUTSIDE_LEVEL) is no rival.
            if ((d + radius < best || d > best + radius) && level != SGM_OUTSIDE_LEVEL) {
                rival = min(rival, level);
            }
        }
    }
    if (rival == 0xffffu) {
        return 1.0;
    }
    return confidence(level_score(best_level), level_score(rival));
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let width = params.width;
    let y = band.first_row + gid.y;
    if (gid.x >= width || y >= min(params.height, band.first_row + band.rows)) {
        return;
    }
    let pix = y * width + gid.x;
    let local_pix = pix - band.first_pixel;
    let local = state[3u * pix];
    if (!(local.x < 0.5 * BIG) || local.y < 0.0) {
        return;
    }
    let selection = state[3u * pix + 2u].x;
    let planes = params.planes;
    let words = (planes + 1u) / 2u;
    let unit = params.sgm_unit_per_level;
    var st = Wta(vec4<f32>(BIG, -1.0, BIG, BIG), vec4<f32>(BIG), vec4<f32>(selection, 1.0, 0.0, 0.0));
    for (var j = 0u; j < words; j++) {
        let word = sums[local_pix * words + j];
        let costs = volume[local_pix * words + j];
        let d = 2u * j;
        // Summed levels back to score units, less the offset every volume level carries; BIG for
        // a plane outside the pixel's range (coarse to fine: it is absent, never the winner, its
        // neighbour or a rival).
        var score = vec2<f32>(f32(word & 0xffffu), f32(word >> 16u)) * unit - SGM_VOLUME_OFFSET;
        score = select(score, vec2<f32>(BIG), vec2<u32>(costs & 0xffffu, costs >> 16u) == vec2<u32>(SGM_OUTSIDE_LEVEL));
        st = select_plane(st, f32(d), vec2<f32>(score.x, selection));
        if (d + 1u < planes) {
            st = select_plane(st, f32(d + 1u), vec2<f32>(score.y, selection));
        }
    }
    if (params.uniqueness > 0.0 || params.ambiguity > 0.0) {
        st.s2.y = uniqueness_on_costs(local_pix, u32(st.s0.y));
    }
    state[3u * pix] = st.s0;
    state[3u * pix + 1u] = st.s1;
    state[3u * pix + 2u] = st.s2;
}
