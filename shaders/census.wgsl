// Stage 0a (a census cost, `cost = census | ad_census`): the census words of every camera's
// image, written after the pixels in `images` (camera c's at `census_offset + size.z`), one
// invocation per texel, the camera in z. A word holds one bit per neighbour of the 5 x 5
// window (the centre left out, row by row from the top left, the first neighbour in bit 23),
// set when the neighbour's integer grey (77 R + 150 G + 29 B) is below the centre's;
// neighbours past the border repeat the edge texel. CPU twin: src/sweep/census.rs (bit for
// bit).

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> cameras: array<Camera, MAX_RIG_CAMERAS>;
@group(0) @binding(2) var<storage, read_write> images: array<u32>;

const CENSUS_RADIUS: i32 = 2;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.z >= params.cameras) {
        return;
    }
    let size = cameras[gid.z].size;
    if (gid.x >= size.x || gid.y >= size.y) {
        return;
    }
    let base = size.z;
    let last_x = i32(size.x) - 1;
    let last_y = i32(size.y) - 1;
    let centre = census_luma(images[base + gid.y * size.x + gid.x]);
    var word = 0u;
    for (var dy = -CENSUS_RADIUS; dy <= CENSUS_RADIUS; dy++) {
        let row = base + u32(clamp(i32(gid.y) + dy, 0, last_y)) * size.x;
        for (var dx = -CENSUS_RADIUS; dx <= CENSUS_RADIUS; dx++) {
            if (dx == 0 && dy == 0) {
                continue;
            }
            let x = u32(clamp(i32(gid.x) + dx, 0, last_x));
            let below = census_luma(images[row + x]) < centre;
            word = (word << 1u) | select(0u, 1u, below);
        }
    }
    images[params.census_offset + base + gid.y * size.x + gid.x] = word;
}
