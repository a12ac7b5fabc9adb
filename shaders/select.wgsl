// Stage 5a: streaming winner-take-all over the planes of one batch.
// Keeps per pixel: the best cost and its plane, the costs of the planes just before and after it
// (for the sub-pixel parabola), and the best cost away from the winner's neighbours (for the
// confidence), exactly, without storing the whole cost volume.
// One invocation per reference pixel. CPU twin: src/sweep/cpu/select.rs.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> batch: Batch;
@group(0) @binding(2) var<storage, read> agg_slab: array<vec2<f32>>;
// Per pixel, 3 x vec4:
//   [0] best cost, best plane, cost of plane best-1, cost of plane best+1
//   [1] best cost away from best +- 1, min over planes 0..k-1, min over planes 0..k-2, cost of plane k-1
//   [2] half-sequence selection at the best plane, 0, 0, 0
@group(0) @binding(3) var<storage, read_write> state: array<vec4<f32>>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let width = params.ref_size.x;
    if (gid.x >= width || gid.y >= params.ref_size.y) {
        return;
    }
    let npix = params.ref_size.z;
    let pix = gid.y * width + gid.x;
    var s0 = vec4<f32>(BIG, -1.0, BIG, BIG);
    var s1 = vec4<f32>(BIG, BIG, BIG, BIG);
    var s2 = vec4<f32>(f32(SEL_INVALID), 0.0, 0.0, 0.0);
    if (batch.is_first == 0u) {
        s0 = state[3u * pix];
        s1 = state[3u * pix + 1u];
        s2 = state[3u * pix + 2u];
    }
    for (var z = 0u; z < batch.plane_count; z++) {
        let k = f32(batch.first_plane + z);
        let a = agg_slab[z * npix + pix];
        let c = a.x;
        if (c < s0.x) {
            s0 = vec4<f32>(c, k, s1.w, BIG);
            s1.x = s1.z;
            s2.x = a.y;
        } else if (k == s0.y + 1.0) {
            s0.w = c;
        } else {
            s1.x = min(s1.x, c);
        }
        s1.z = s1.y;
        s1.y = min(s1.y, c);
        s1.w = c;
    }
    state[3u * pix] = s0;
    state[3u * pix + 1u] = s1;
    state[3u * pix + 2u] = s2;
}
