// Stage 5a' (optimizer sgm): winner-take-all over the summed path costs of sgm.wgsl, in score
// units (sum / (paths x levels per score unit)), into the same selection state the streaming
// winner-take-all of aggregate.wgsl fills (winner, its neighbours for the sub-pixel parabola,
// the best rival away from them for the confidence), so finalize.wgsl reads either. Pixels
// with no valid hypothesis stay invalid, and the half-sequence selection of the local winner is
// kept; where `uniqueness` or `ambiguity` reads it, the winner's uniqueness on the matching costs
// of the volume (in s2.y). One invocation per reference pixel, SELECT_PIXELS of one row to a
// workgroup. A pixel's sums and costs are a run of words: read in place, an invocation's loads
// lie a pixel's words from its neighbours'; with SELECT_CHUNKED (GPUs) the group copies them
// into workgroup memory a chunk of words at a time, neighbouring invocations reading
// neighbouring words. CPU twin: src/sweep/cpu/sgm_select.rs (`select`, `uniqueness_on_costs`).

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> sums: array<u32>;
@group(0) @binding(2) var<storage, read_write> state: array<vec4<f32>>;
// The rows of this dispatch; `sums` holds only theirs.
@group(0) @binding(3) var<uniform> band: Band;
// The matching costs of this band's rows, as SGM read them.
@group(0) @binding(4) var<storage, read> volume: array<u32>;

// Pixels per workgroup (a run of one row), and words per pixel in one chunk of workgroup
// memory; a chunk's rows lie SELECT_STRIDE words apart (odd: the invocations reading one word
// of their pixels hit different banks). Two chunks of 64 x 31 words: 15872 bytes, within
// WebGPU's 16352 (the engine asks for the downlevel limits).
const SELECT_PIXELS: u32 = 64u;
const SELECT_CHUNK: u32 = 30u;
const SELECT_STRIDE: u32 = 31u;
// Through workgroup memory (GPUs) or in place (CPU adapters, where each barrier costs a
// coroutine switch: lavapipe's selection 3x slower chunked).
override SELECT_CHUNKED: bool = true;
var<workgroup> chunk_sums: array<u32, 1984>;
var<workgroup> chunk_costs: array<u32, 1984>;

// Copies words [j0, j0 + n) of the group's `pixels` pixels (the first at band-local index
// `row_pix`) of `volume`, and of `sums` where `with_sums`, into the chunks.
fn load_chunk(lid: u32, row_pix: u32, pixels: u32, words: u32, j0: u32, n: u32, with_sums: bool) {
    workgroupBarrier();
    for (var i = lid; i < pixels * n; i += SELECT_PIXELS) {
        let p = i / n;
        let k = i - p * n;
        let at = (row_pix + p) * words + j0 + k;
        if (with_sums) {
            chunk_sums[p * SELECT_STRIDE + k] = sums[at];
        }
        chunk_costs[p * SELECT_STRIDE + k] = volume[at];
    }
    workgroupBarrier();
}

// A volume level back to score units (CPU twin: `level_score`).
fn level_score(level: u32) -> f32 {
    return f32(level) / params.sgm_levels_per_unit - SGM_VOLUME_OFFSET;
}

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let width = params.width;
    let y = band.first_row + wid.y;
    // Whole groups only (uniform): the barriers below need every invocation of the group.
    if (y >= min(params.height, band.first_row + band.rows)) {
        return;
    }
    let x0 = wid.x * SELECT_PIXELS;
    let pixels = min(SELECT_PIXELS, width - x0);
    let row_pix = y * width + x0 - band.first_pixel;
    let pix = y * width + x0 + lid;
    var selecting = false;
    var selection = 0.0;
    if (lid < pixels) {
        let local = state[3u * pix];
        selecting = local.x < 0.5 * BIG && local.y >= 0.0;
        selection = state[3u * pix + 2u].x;
    }
    let planes = params.planes;
    let words = (planes + 1u) / 2u;
    let unit = params.sgm_unit_per_level;
    let at = lid * SELECT_STRIDE;
    var st = Wta(vec4<f32>(BIG, -1.0, BIG, BIG), vec4<f32>(BIG), vec4<f32>(selection, 1.0, 0.0, 0.0));
    for (var j0 = 0u; j0 < words; j0 += SELECT_CHUNK) {
        let n = min(SELECT_CHUNK, words - j0);
        if (SELECT_CHUNKED) {
            load_chunk(lid, row_pix, pixels, words, j0, n, true);
        }
        if (!selecting) {
            continue;
        }
        let own = (row_pix + lid) * words + j0;
        for (var k = 0u; k < n; k++) {
            var word: u32;
            var costs: u32;
            if (SELECT_CHUNKED) {
                word = chunk_sums[at + k];
                costs = chunk_costs[at + k];
            } else {
                word = sums[own + k];
                costs = volume[own + k];
            }
            let d = 2u * (j0 + k);
            // Summed levels back to score units, less the offset every volume level carries;
            // BIG for a plane outside the pixel's range (coarse to fine: it is absent, never
            // the winner, its neighbour or a rival).
            var score = vec2<f32>(f32(word & 0xffffu), f32(word >> 16u)) * unit - SGM_VOLUME_OFFSET;
            score = select(score, vec2<f32>(BIG), vec2<u32>(costs & 0xffffu, costs >> 16u) == vec2<u32>(SGM_OUTSIDE_LEVEL));
            st = select_plane(st, f32(d), vec2<f32>(score.x, selection));
            if (d + 1u < planes) {
                st = select_plane(st, f32(d + 1u), vec2<f32>(score.y, selection));
            }
        }
    }
    // How clearly the winner is the best match on the matching costs: its cost against the
    // lowest more than `uniqueness_radius` planes away (a repeated pattern matches as well one
    // period away; SGM's paths make one of them win clearly).
    if (params.uniqueness > 0.0 || params.ambiguity > 0.0) {
        let best = u32(st.s0.y);
        let radius = max(params.uniqueness_radius, 1u);
        var rival = 0xffffu;
        var best_level = 0xffffu;
        for (var j0 = 0u; j0 < words; j0 += SELECT_CHUNK) {
            let n = min(SELECT_CHUNK, words - j0);
            if (SELECT_CHUNKED) {
                load_chunk(lid, row_pix, pixels, words, j0, n, false);
            }
            if (!selecting) {
                continue;
            }
            let own = (row_pix + lid) * words + j0;
            for (var k = 0u; k < n; k++) {
                var word: u32;
                if (SELECT_CHUNKED) {
                    word = chunk_costs[at + k];
                } else {
                    word = volume[own + k];
                }
                for (var h = 0u; h < 2u; h++) {
                    let d = 2u * (j0 + k) + h;
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
        }
        if (rival != 0xffffu) {
            st.s2.y = confidence(level_score(best_level), level_score(rival));
        } else {
            st.s2.y = 1.0;
        }
    }
    if (selecting) {
        state[3u * pix] = st.s0;
        state[3u * pix + 1u] = st.s1;
        state[3u * pix + 2u] = st.s2;
    }
}
