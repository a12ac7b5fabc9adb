// Stage 5a (optimizer sgm): one direction of semi-global matching (Hirschmüller 2008) over the
// u16 cost volume that aggregate.wgsl wrote. For every path line in direction r = (dx, dy):
//   L(p, d) = C(p, d) + min(L(p-r, d), L(p-r, d±1) + P1, min_k L(p-r, k) + P2') - min_k L(p-r, k)
// with P2' = max(P1, P2 / (1 + step / edge)) where `step` is the largest RGB channel difference
// of the reference image between p - r and p (P2 constant when edge = 0). The first pass writes
// L into `sums`, the others add to it; L <= C + P2, so paths x (SGM_COST_MAX + P2) < 2^16 keeps
// both u16 halves of a word from carrying (checked by SweepParams::validate). A plane the volume
// marks SGM_OUTSIDE_LEVEL (coarse to fine: outside the pixel's range) is absent (`sgm_absent`).
// Two layouts of the same arithmetic (the engine picks one per adapter; results are identical):
// - GPUs (LINE_PER_INVOCATION = false): one workgroup per path line walks it pixel by pixel; its
//   lanes split the planes (two per u32 word), the previous pixel's L lives in workgroup memory
//   (double-buffered) and its minimum is an atomicMin in one of three rotating slots, so each
//   step needs a single barrier and no subgroup operations.
// - CPU adapters (lavapipe, LINE_PER_INVOCATION = true): one invocation per path line loops over
//   the planes itself, its previous L in `line_costs` (global scratch, one row per line): no
//   barriers, which a software rasteriser pays for with a coroutine switch per SIMD batch.
// Row bands (an adapter whose storage binding limit holds fewer rows of the volume than the
// image): each pass covers the rows of one band, and a line carries its state in `line_costs`
// (its previous L, double-buffered by step parity, and the minimum of that L) from one band to
// the next. The engine runs the directions going down (and the horizontal ones) band by band
// from the top, then the directions going up band by band from the bottom, so a line always
// finds the state its previous pixel left; a line's step count at a band's edge follows from
// its start. Banded runs use the LINE_PER_INVOCATION layout (workgroup memory does not outlive
// a dispatch); the result equals the untiled run bit for bit (integer sums).
// CPU twin: src/sweep/cpu/sgm.rs.

override SGM_LANES: u32 = 32u;
override LINE_PER_INVOCATION: bool = false;

struct SgmPass {
    direction: vec4<i32>,   // dx, dy, path lines, index of the direction (0 = the first pass: write, not add)
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> sgm_pass: SgmPass;
@group(0) @binding(2) var<uniform> cameras: array<Camera, MAX_RIG_CAMERAS>;
@group(0) @binding(3) var<storage, read> images: array<u32>;
// The volume and the sums of this pass's row band.
@group(0) @binding(4) var<storage, read> volume: array<u32>;
@group(0) @binding(5) var<storage, read_write> sums: array<u32>;
// LINE_PER_INVOCATION: per direction and line, the previous and the current pixel's L
// (4 x words), then the minimum of the previous L (carried from band to band).
@group(0) @binding(6) var<storage, read_write> line_costs: array<u32>;
@group(0) @binding(7) var<uniform> band: Band;

// L of the previous pixel of the line (one half) and of the current one (the other half).
var<workgroup> path_costs: array<u32, 2 * MAX_SGM_PLANES>;
var<workgroup> path_min: array<atomic<u32>, 3>;

// min(L(d), L(d±1) + P1, min + P2) - min over the previous pixel's costs at offset `prev`.
fn path_term(prev: u32, d: u32, planes: u32, prev_min: u32, p1: u32, p2: u32) -> u32 {
    var best = min(path_costs[prev + d], prev_min + p2);
    if (d > 0u) {
        best = min(best, path_costs[prev + d - 1u] + p1);
    }
    if (d + 1u < planes) {
        best = min(best, path_costs[prev + d + 1u] + p1);
    }
    return best - prev_min;
}

// `path_term` over the line's own scratch row in `line_costs`.
fn line_term(prev: u32, d: u32, planes: u32, prev_min: u32, p1: u32, p2: u32) -> u32 {
    var best = min(line_costs[prev + d], prev_min + p2);
    if (d > 0u) {
        best = min(best, line_costs[prev + d - 1u] + p1);
    }
    if (d + 1u < planes) {
        best = min(best, line_costs[prev + d + 1u] + p1);
    }
    return best - prev_min;
}

// LINE_PER_INVOCATION: the whole path line `line`, plane after plane, by one invocation.
fn walk_line(line: i32) {
    let w = i32(params.width);
    let h = i32(params.height);
    let dx = sgm_pass.direction.x;
    let dy = sgm_pass.direction.y;
    let first_pass = sgm_pass.direction.w == 0;
    let planes = params.planes;
    let words = (planes + 1u) / 2u;
    let p1 = params.sgm_p1;
    let p2 = params.sgm_p2;
    let edge = params.sgm_edge;
    let reference = params.reference;
    var image_offset = 0u;
    if (reference != NO_CAMERA) {
        image_offset = cameras[reference].size.z;
    }
    // Each direction has its own rows of scratch: in bands, directions interleave.
    let lines_max = u32(w + h);
    let base = (u32(sgm_pass.direction.w) * lines_max + u32(line)) * (4u * words + 1u);
    let top = i32(band.first_row);
    let bottom = min(h, top + i32(band.rows));
    var p = line_start(line, dx, dy, w, h);
    // Steps the line took before this band (its pixels in the bands before).
    var skipped = 0;
    if (dy > 0 && p.y < top) {
        skipped = top - p.y;
    } else if (dy < 0 && p.y >= bottom) {
        skipped = p.y - (bottom - 1);
    }
    p += skipped * vec2<i32>(dx, dy);
    var step = u32(skipped);
    var previous_colour = 0u;
    var prev_min = 0u;
    if (step > 0u && p.x >= 0 && p.x < w) {
        prev_min = line_costs[base + 4u * words];
        if (edge > 0u) {
            let q = p - vec2<i32>(dx, dy);
            previous_colour = images[image_offset + u32(q.y * w + q.x)];
        }
    }
    loop {
        if (p.x < 0 || p.y < top || p.x >= w || p.y >= bottom) {
            break;
        }
        let pix = u32(p.y * w + p.x);
        let local_pix = pix - band.first_pixel;
        var penalty2 = p2;
        var colour = 0u;
        if (edge > 0u) {
            colour = images[image_offset + pix];
            if (step > 0u) {
                penalty2 = max(p1, p2 * edge / (edge + 16u * colour_step(colour, previous_colour)));
            }
        }
        var local_min = 0xffffffffu;
        // Double-buffered like the workgroup layout: read the previous pixel's half, write the
        // other.
        let prev = base + (step & 1u) * 2u * words;
        let next = base + (1u - (step & 1u)) * 2u * words;
        for (var j = 0u; j < words; j++) {
            let at = local_pix * words + j;
            let c = volume[at];
            let d = 2u * j;
            var l0 = c & 0xffffu;
            var l1 = c >> 16u;
            if (step > 0u) {
                l0 += line_term(prev, d, planes, prev_min, p1, penalty2);
                if (d + 1u < planes) {
                    l1 += line_term(prev, d + 1u, planes, prev_min, p1, penalty2);
                }
            }
            let absent = sgm_absent(c, vec2<u32>(l0, l1));
            l0 = absent.x;
            l1 = absent.y;
            if (d + 1u >= planes) {
                l1 = 0u;
            } else {
                local_min = min(local_min, l1);
            }
            local_min = min(local_min, l0);
            line_costs[next + d] = l0;
            line_costs[next + d + 1u] = l1;
            let packed = sgm_sum_word(c, vec2<u32>(l0, l1));
            if (first_pass) {
                sums[at] = packed;
            } else {
                sums[at] = sums[at] + packed;
            }
        }
        prev_min = local_min;
        previous_colour = colour;
        p += vec2<i32>(dx, dy);
        step += 1u;
    }
    // For the next band (read there only by a line that went on).
    line_costs[base + 4u * words] = prev_min;
}

@compute @workgroup_size(SGM_LANES, 1, 1)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    if (LINE_PER_INVOCATION) {
        let line = i32(wid.x * SGM_LANES + lane);
        if (line < sgm_pass.direction.z) {
            walk_line(line);
        }
        return;
    }
    let line = i32(wid.x);
    if (line >= sgm_pass.direction.z) {
        return;
    }
    let w = i32(params.width);
    let h = i32(params.height);
    let dx = sgm_pass.direction.x;
    let dy = sgm_pass.direction.y;
    let first_pass = sgm_pass.direction.w == 0;
    let planes = params.planes;
    let words = (planes + 1u) / 2u;
    let p1 = params.sgm_p1;
    let p2 = params.sgm_p2;
    let edge = params.sgm_edge;
    let reference = params.reference;
    var image_offset = 0u;
    if (reference != NO_CAMERA) {
        image_offset = cameras[reference].size.z;
    }
    if (lane == 0u) {
        atomicStore(&path_min[0], 0xffffffffu);
        atomicStore(&path_min[1], 0xffffffffu);
        atomicStore(&path_min[2], 0xffffffffu);
    }
    workgroupBarrier();
    var p = line_start(line, dx, dy, w, h);
    var step = 0u;
    var previous_colour = 0u;
    loop {
        if (p.x < 0 || p.y < 0 || p.x >= w || p.y >= h) {
            break;
        }
        let pix = u32(p.y * w + p.x);
        let prev = (step & 1u) * MAX_SGM_PLANES;
        let next = MAX_SGM_PLANES - prev;
        var penalty2 = p2;
        var colour = 0u;
        if (edge > 0u) {
            colour = images[image_offset + pix];
            if (step > 0u) {
                penalty2 = max(p1, p2 * edge / (edge + 16u * colour_step(colour, previous_colour)));
            }
        }
        var prev_min = 0u;
        if (step > 0u) {
            prev_min = atomicLoad(&path_min[step % 3u]);
        }
        var local_min = 0xffffffffu;
        // One band covers the image in this layout (first_pixel = 0).
        for (var j = lane; j < words; j += SGM_LANES) {
            let at = (pix - band.first_pixel) * words + j;
            let c = volume[at];
            let d = 2u * j;
            var l0 = c & 0xffffu;
            var l1 = c >> 16u;
            if (step > 0u) {
                l0 += path_term(prev, d, planes, prev_min, p1, penalty2);
                if (d + 1u < planes) {
                    l1 += path_term(prev, d + 1u, planes, prev_min, p1, penalty2);
                }
            }
            let absent = sgm_absent(c, vec2<u32>(l0, l1));
            l0 = absent.x;
            l1 = absent.y;
            if (d + 1u >= planes) {
                l1 = 0u;
            } else {
                local_min = min(local_min, l1);
            }
            local_min = min(local_min, l0);
            path_costs[next + d] = l0;
            path_costs[next + d + 1u] = l1;
            let packed = sgm_sum_word(c, vec2<u32>(l0, l1));
            if (first_pass) {
                sums[at] = packed;
            } else {
                sums[at] = sums[at] + packed;
            }
        }
        atomicMin(&path_min[(step + 1u) % 3u], local_min);
        if (lane == 0u) {
            atomicStore(&path_min[(step + 2u) % 3u], 0xffffffffu);
        }
        workgroupBarrier();
        previous_colour = colour;
        p += vec2<i32>(dx, dy);
        step += 1u;
    }
}
