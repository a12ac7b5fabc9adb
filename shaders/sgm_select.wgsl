// Stage 5a' (optimizer sgm): winner-take-all over the summed path costs of sgm.wgsl, in score
// units (sum / (paths x levels per score unit)), into the same selection state the streaming
// winner-take-all of aggregate.wgsl fills (winner, its neighbours for the sub-pixel parabola,
// the best rival away from them for the confidence), so finalize.wgsl reads either. Pixels
// with no valid hypothesis stay invalid, and the half-sequence selection of the local winner is
// kept. One invocation per reference pixel. CPU twin: src/sweep/cpu/sgm.rs (`select`).

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> sums: array<u32>;
@group(0) @binding(2) var<storage, read_write> state: array<vec4<f32>>;
// The rows of this dispatch; `sums` holds only theirs.
@group(0) @binding(3) var<uniform> band: Band;

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
    // The local winner's confidence, before SGM's takes its place (`uniqueness`, finalize).
    let local_confidence = confidence(local.x, state[3u * pix + 1u].x);
    var st = Wta(vec4<f32>(BIG, -1.0, BIG, BIG), vec4<f32>(BIG), vec4<f32>(selection, local_confidence, 0.0, 0.0));
    for (var j = 0u; j < words; j++) {
        let word = sums[local_pix * words + j];
        let d = 2u * j;
        // Summed levels back to score units, less the offset every volume level carries.
        st = select_plane(st, f32(d), vec2<f32>(f32(word & 0xffffu) * unit - SGM_VOLUME_OFFSET, selection));
        if (d + 1u < planes) {
            st = select_plane(st, f32(d + 1u), vec2<f32>(f32(word >> 16u) * unit - SGM_VOLUME_OFFSET, selection));
        }
    }
    state[3u * pix] = st.s0;
    state[3u * pix + 1u] = st.s1;
    state[3u * pix + 2u] = st.s2;
}
