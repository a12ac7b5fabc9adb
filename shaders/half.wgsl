// Stage 0b (coarse to fine): the half-size images of the level below, from one level's packed
// pixels (`finer`) to the next's (`coarser`), camera by camera: each 2 x 2 block's 8-bit
// channels averaged as (sum + 2) / 4 (integers: an odd last row or column is dropped). One
// invocation per half-size texel, the camera in z. CPU twin: src/sweep/coarse.rs
// `half_image` (bit for bit).

// Per camera: the source's width and height, the word of its pixel (0, 0) in `finer`, and
// that of the half-size image in `coarser`.
struct Halving {
    count: vec4<u32>,    // cameras in x
    sizes: array<vec4<u32>, MAX_RIG_CAMERAS>,
}

@group(0) @binding(0) var<uniform> halving: Halving;
// Never read: common.wgsl's helpers name `params`, and this stage binds no shape's buffers
// (it runs on the engine's image pyramid, `src/sweep/gpu/pyramid.rs`).
var<private> params: Params;
@group(0) @binding(1) var<storage, read> finer: array<u32>;
@group(0) @binding(2) var<storage, read_write> coarser: array<u32>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.z >= halving.count.x) {
        return;
    }
    let size = halving.sizes[gid.z];
    let width = size.x / 2u;
    if (gid.x >= width || gid.y >= size.y / 2u) {
        return;
    }
    let top = size.z + 2u * gid.y * size.x + 2u * gid.x;
    let quad = array<u32, 4>(finer[top], finer[top + 1u], finer[top + size.x], finer[top + size.x + 1u]);
    var packed = 0u;
    for (var shift = 0u; shift < 32u; shift += 8u) {
        var sum = 0u;
        for (var i = 0u; i < 4u; i++) {
            sum += (quad[i] >> shift) & 0xffu;
        }
        packed |= ((sum + 2u) / 4u) << shift;
    }
    coarser[size.w + gid.y * width + gid.x] = packed;
}
