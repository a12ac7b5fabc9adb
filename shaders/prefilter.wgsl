// Stage 0 (a pair of real cameras, `Params.colour_in_alpha`): the matching images of issue 52
// made on the device. Each pixel of the caller's images (`raw`, level 0's packing) is written to
// `filtered` with its RGB kept and, in the alpha byte, its grey's horizontal Sobel derivative
// `128 + clamp(scale * d, -127, 127)` rounded (`scale` = prefilter::SCALE / 256 for the integer
// grey 77 R + 150 G + 29 B); edge texels repeat. One invocation per texel, the camera in z:
// reading `raw` and writing `filtered` (two buffers), no invocation reads what another writes.
// CPU twin: src/sweep/prefilter.rs `gradient` (bit for bit: every step is exact in f32).

// Per camera: width, height, its word of pixel (0, 0) in `raw` and in `filtered`.
struct PrefilterCameras {
    count: vec4<u32>,    // cameras in x, the bits of the f32 scale in y
    sizes: array<vec4<u32>, MAX_RIG_CAMERAS>,
}

@group(0) @binding(0) var<uniform> prefilter: PrefilterCameras;
// Never read: common.wgsl's helpers name `params`, and this stage binds no shape's buffers
// (it runs on the engine's image pyramid, `src/sweep/gpu/pyramid.rs`).
var<private> params: Params;
@group(0) @binding(1) var<storage, read> raw: array<u32>;
@group(0) @binding(2) var<storage, read_write> filtered: array<u32>;

// The vertical [1, 2, 1] sum of the greys of column `x` around rows `up`, `mid`, `down` (their
// first words).
fn column_sum(up: u32, mid: u32, down: u32, x: u32) -> i32 {
    return i32(census_luma(raw[up + x]) + 2u * census_luma(raw[mid + x]) + census_luma(raw[down + x]));
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.z >= prefilter.count.x) {
        return;
    }
    let size = prefilter.sizes[gid.z];
    let w = size.x;
    let h = size.y;
    if (gid.x >= w || gid.y >= h) {
        return;
    }
    let mid = size.z + gid.y * w;
    let up = size.z + (max(gid.y, 1u) - 1u) * w;
    let down = size.z + min(gid.y + 1u, h - 1u) * w;
    let left = max(gid.x, 1u) - 1u;
    let right = min(gid.x + 1u, w - 1u);
    let d = column_sum(up, mid, down, right) - column_sum(up, mid, down, left);
    let scale = bitcast<f32>(prefilter.count.y);
    let v = 128.0 + clamp(f32(d) * scale, -127.0, 127.0);
    let byte = u32(floor(v + 0.5));
    filtered[size.w + gid.y * w + gid.x] = (raw[mid + gid.x] & 0x00ffffffu) | (byte << 24u);
}
