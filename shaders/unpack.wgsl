// Stage 0a: the caller's images as their messages carry them (`rgb8`, `bgr8`, `mono8`: 3 or 1
// bytes per pixel, rows without padding, each camera's bytes from a word of `packed`) unpacked
// into the engine's RGBA words (r | g << 8 | b << 16 | 0xff << 24; grey in all three), camera
// by camera, into level 0 of the image pyramid (or the prefilter's `raw` images). One
// invocation per pixel, the camera in z. CPU twin: src/image.rs `PackedImage::to_rgba8` (bit
// for bit).

// The pass's format (1 rgb8, 2 bgr8, 3 mono8) in `count.y`, its cameras in `count.x`; per
// camera: width, height, the word of its first byte in `packed` and of its pixel (0, 0) in
// `unpacked`.
struct Unpacking {
    count: vec4<u32>,
    sizes: array<vec4<u32>, MAX_RIG_CAMERAS>,
}

@group(0) @binding(0) var<uniform> unpacking: Unpacking;
// Never read: common.wgsl's helpers name `params`, and this stage binds no shape's buffers
// (it runs on the engine's image pyramid, `src/sweep/gpu/pyramid.rs`).
var<private> params: Params;
@group(0) @binding(1) var<storage, read> packed: array<u32>;
@group(0) @binding(2) var<storage, read_write> unpacked: array<u32>;

// Byte `i` of the camera whose bytes begin at word `first`.
fn byte_at(first: u32, i: u32) -> u32 {
    return (packed[first + (i >> 2u)] >> ((i & 3u) * 8u)) & 0xffu;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.z >= unpacking.count.x) {
        return;
    }
    let size = unpacking.sizes[gid.z];
    if (gid.x >= size.x || gid.y >= size.y) {
        return;
    }
    let p = gid.y * size.x + gid.x;
    var rgb: vec3<u32>;
    switch unpacking.count.y {
        case 3u: {
            let v = byte_at(size.z, p);
            rgb = vec3<u32>(v, v, v);
        }
        case 2u: {
            rgb = vec3<u32>(byte_at(size.z, 3u * p + 2u), byte_at(size.z, 3u * p + 1u), byte_at(size.z, 3u * p));
        }
        default: {
            rgb = vec3<u32>(byte_at(size.z, 3u * p), byte_at(size.z, 3u * p + 1u), byte_at(size.z, 3u * p + 2u));
        }
    }
    unpacked[size.w + p] = rgb.x | (rgb.y << 8u) | (rgb.z << 16u) | 0xff000000u;
}
