// Stages 1-3 + 4a in one: per-pair aggregation over the reference's pairs with window sums (the
// defaults: centred 5x5). A workgroup takes ROW_LANES consecutive columns of one reference row;
// one camera pair and ROW_PLANES planes at a time, each lane costs its column (as cost.wgsl
// does) into workgroup memory, then each lane whose window lies within the group's columns adds the
// WINDOW_W costs that end at its column into `row_sums` (as box_h.wgsl does, in the same
// order). No cost slab is written or read: a batch's memory is its row sums alone. The first
// WINDOW_W - 1 lanes of a group only cost (the window's reach into the group before). CPU
// twin: src/sweep/cpu/plane.rs, which fuses cost and row sums alike.

override WINDOW_W: u32 = 2u;      // = params.window_w
override CHANNELS: u32 = 1u;      // = params.channels (camera pairs)

// (The bindings 0-4, 6 and 7 and the cost's functions: cost_common.wgsl.)
// Per channel (pair) and plane of the batch, row and padded column p: the sum and count of the
// valid costs in columns p - (WINDOW_W - 1) ..= p (box_h.wgsl's layout).
@group(0) @binding(5) var<storage, read_write> row_sums: array<vec2<f32>>;

const ROW_LANES: u32 = 64u;
// Planes costed between two barriers.
const ROW_PLANES: u32 = 8u;
// The lanes' costs of one pair and ROW_PLANES planes, two such blocks alternating so that one
// barrier per block keeps a block's reads apart from the next block's writes.
var<workgroup> row_costs: array<f32, 1024>;

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let width = params.width;
    let height = params.height;
    let padded_w = params.padded_w;
    let y = group.y;
    let reach = WINDOW_W - 1u;
    let anchors = ROW_LANES - reach;
    // This lane's column; for lanes from `reach` on also the padded column whose window ends
    // there (the same index).
    let column = i32(group.x * anchors + lane) - i32(reach);
    let in_image = column >= 0 && column < i32(width) && y < height;
    let sums = lane >= reach && column < i32(padded_w) && y < height;
    let x = u32(clamp(column, 0, i32(width) - 1));
    let row = min(y, height - 1u);
    let pix = row * width + x;
    let ray = rays[pix].xyz;
    let r = reference_pixel(x, row);
    let needed = plane_ranges[range_index(width, x, row)].zw;
    // The window of padded column p = column: columns p - reach ..= p inside the image; its
    // planes, those of its first column's tile (box_h.wgsl).
    let x_first = max(column - i32(reach), 0);
    let x_end = min(column + 1, i32(width));
    let window_needed = plane_ranges[range_index(width, u32(min(x_first, i32(width) - 1)), row)].zw;
    let ref_index = params.reference;
    var channel = 0u;
    var parity = 0u;
    for (var i = 0u; i < params.cameras; i++) {
        if (i == ref_index) {
            continue;
        }
        let cam = cameras[i];
        let in_cam = cam_ray(cam, ray);
        for (var z0 = 0u; z0 < batch.plane_count; z0 += ROW_PLANES) {
            let block = parity * ROW_PLANES * ROW_LANES;
            for (var j = 0u; j < ROW_PLANES; j++) {
                let z = z0 + j;
                var cost = INVALID;
                if (in_image && z < batch.plane_count && costed(batch.first_plane + z, needed)) {
                    cost = pair_cost_at(cam, z, ray, pix, in_cam, r);
                }
                row_costs[block + j * ROW_LANES + lane] = cost;
            }
            workgroupBarrier();
            for (var j = 0u; j < ROW_PLANES; j++) {
                let z = z0 + j;
                if (sums && z < batch.plane_count && costed(batch.first_plane + z, window_needed)) {
                    let at = block + j * ROW_LANES + lane;
                    var acc = vec2<f32>(0.0);
                    for (var c = x_first; c < x_end; c++) {
                        let v = row_costs[at - u32(column - c)];
                        if (v >= 0.0) {
                            acc += vec2<f32>(v, 1.0);
                        }
                    }
                    row_sums[((z * CHANNELS + channel) * height + y) * padded_w + u32(column)] = acc;
                }
            }
            parity = 1u - parity;
        }
        channel += 1u;
    }
}
