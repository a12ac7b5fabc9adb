// Stage 5a (optimizer sgm) in subgroups: the arithmetic of sgm.wgsl (read its header for L, P1,
// P2' and the u16 halves), laid out as fast GPU SGM is (Hernandez-Juarez et al. 2016, libSGM):
// one subgroup per path line, walking it pixel by pixel; each lane holds the path costs of a
// contiguous run of planes (SGM_LANE_WORDS words, two planes each) in registers, the planes
// next to its run come from the neighbouring lanes by one shuffle up and one shuffle down, and
// the previous pixel's minimum over all planes is one subgroup reduction. No workgroup memory,
// no barrier. A workgroup holds SGM_LINES subgroups, a line each (its `subgroup_id`), SGM_LANES
// lanes each: SGM_LANES is the adapter's smallest subgroup size, so every subgroup the adapter
// forms holds the whole line (with one line per workgroup, lanes beyond it are inactive and take
// part in no shuffle or reduction); several lines per workgroup only where the adapter's
// subgroups all have SGM_LANES lanes (more lines resident at once to hide each walk's latency). Needs `Features::SUBGROUP`; the engine uses it where the
// adapter has it, one band covering the image (banded runs use sgm.wgsl's line per invocation).
// The sums are integer and bit-identical to sgm.wgsl and to the CPU twin (src/sweep/cpu/sgm.rs).

override SGM_LANES: u32 = 32u;
// Words per lane: the plan's (planes + 1) / 2 words over SGM_LANES lanes, rounded up to a power
// of two (a handful of pipelines), at most MAX_LANE_WORDS. A constant trip count lets the
// shader compiler keep `prev0`/`prev1` in registers.
override SGM_LANE_WORDS: u32 = 1u;
// Path lines (subgroups) per workgroup.
override SGM_LINES: u32 = 1u;

// The most words a lane holds: MAX_SGM_PLANES over the smallest subgroup wgpu allows (4).
const MAX_LANE_WORDS: u32 = MAX_SGM_PLANES / 8u;

struct SgmPass {
    direction: vec4<i32>,   // dx, dy, path lines, index of the direction (0 = the first pass: write, not add)
}
// `direction.w` of a pass that walks directions `direction.y` .. paths - 1 in one dispatch
// (`direction.x` the paths, `direction.z` the lines of those directions together; each
// workgroup's line picks its direction): every direction, adding into sums the engine cleared
// before, or those after the first, which wrote the sums in a dispatch of its own. The walk of a
// line is latency-bound (one pixel after the other), so the directions run side by side, adding
// into the sums atomically (integer adds: the sums are the sequential passes' bit for bit,
// whatever the order).
const SGM_TOGETHER: i32 = -1;

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> sgm_pass: SgmPass;
@group(0) @binding(2) var<uniform> cameras: array<Camera, MAX_RIG_CAMERAS>;
@group(0) @binding(3) var<storage, read> images: array<u32>;
@group(0) @binding(4) var<storage, read> volume: array<u32>;
@group(0) @binding(5) var<storage, read_write> sums: array<atomic<u32>>;
// Unused here (sgm.wgsl's line-per-invocation scratch): the bindings are sgm.wgsl's, so both
// layouts share one bind group.
@group(0) @binding(6) var<storage, read_write> line_costs: array<u32>;
@group(0) @binding(7) var<uniform> band: Band;

// min(L(d), L(d-1) + P1, L(d+1) + P1, min + P2) - min; `below`/`above` are L(d-1)/L(d+1),
// ignored where that plane does not exist.
fn term(at: u32, below: u32, above: u32, d: u32, planes: u32, prev_min: u32, p1: u32, p2: u32) -> u32 {
    var best = min(at, prev_min + p2);
    if (d > 0u) {
        best = min(best, below + p1);
    }
    if (d + 1u < planes) {
        best = min(best, above + p1);
    }
    return best - prev_min;
}

@compute @workgroup_size(SGM_LANES * SGM_LINES, 1, 1)
fn main(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(subgroup_id) subgroup: u32,
    @builtin(subgroup_invocation_id) lane: u32,
) {
    var line = i32(wid.x * SGM_LINES + subgroup);
    // Uniform over the subgroup: every lane of the line leaves together (the shuffles below
    // need all).
    if (line >= sgm_pass.direction.z) {
        return;
    }
    let w = i32(params.width);
    let h = i32(params.height);
    var dx = sgm_pass.direction.x;
    var dy = sgm_pass.direction.y;
    var first_pass = sgm_pass.direction.w == 0;
    let together = sgm_pass.direction.w == SGM_TOGETHER;
    if (together) {
        // schedule.rs's SGM_DIRECTIONS; the lines of direction r as `sgm_lines` counts them.
        var directions = array<vec2<i32>, 8>(
            vec2<i32>(1, 0), vec2<i32>(-1, 0), vec2<i32>(0, 1), vec2<i32>(0, -1),
            vec2<i32>(1, 1), vec2<i32>(-1, -1), vec2<i32>(1, -1), vec2<i32>(-1, 1),
        );
        let paths = min(u32(sgm_pass.direction.x), 8u);
        var r = u32(sgm_pass.direction.y);
        loop {
            if (r >= paths) {
                return;
            }
            let d = directions[r];
            var lines = w + h - 1;
            if (d.y == 0) {
                lines = h;
            } else if (d.x == 0) {
                lines = w;
            }
            if (line < lines) {
                dx = d.x;
                dy = d.y;
                break;
            }
            line -= lines;
            r += 1u;
        }
        first_pass = false;
    }
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
    // This lane's words: first_word .. first_word + SGM_LANE_WORDS (those below `words`).
    let first_word = lane * SGM_LANE_WORDS;
    // L of the previous pixel at planes 2j and 2j + 1 of this lane's word j = first_word + i.
    var prev0: array<u32, MAX_LANE_WORDS>;
    var prev1: array<u32, MAX_LANE_WORDS>;
    var p = line_start(line, dx, dy, w, h);
    // This pixel's volume words and colour, loaded one step ahead: a step's loads do not depend
    // on the step before, so each word of the next pixel is loaded as this pixel's word is taken
    // and is not waited for until the next step: the walk waits on the arithmetic and the
    // subgroup's exchanges rather than on a memory load every pixel.
    var cost: array<u32, MAX_LANE_WORDS>;
    var colour = 0u;
    if (p.x >= 0 && p.y >= 0 && p.x < w && p.y < h) {
        let pix = u32(p.y * w + p.x);
        for (var i = 0u; i < SGM_LANE_WORDS; i++) {
            let j = first_word + i;
            if (j < words) {
                cost[i] = volume[(pix - band.first_pixel) * words + j];
            }
        }
        if (edge > 0u) {
            colour = images[image_offset + pix];
        }
    }
    var step = 0u;
    var previous_colour = 0u;
    var prev_min = 0u;
    loop {
        if (p.x < 0 || p.y < 0 || p.x >= w || p.y >= h) {
            break;
        }
        let pix = u32(p.y * w + p.x);
        let at_pixel = (pix - band.first_pixel) * words;
        let colour_here = colour;
        // The next pixel of the line (`at_next`: its first word), or none at the line's end.
        let q = p + vec2<i32>(dx, dy);
        let has_next = q.x >= 0 && q.y >= 0 && q.x < w && q.y < h;
        var at_next = 0u;
        if (has_next) {
            let next = u32(q.y * w + q.x);
            at_next = (next - band.first_pixel) * words;
            if (edge > 0u) {
                colour = images[image_offset + next];
            }
        }
        var penalty2 = p2;
        if (edge > 0u && step > 0u) {
            penalty2 = max(p1, p2 * edge / (edge + 16u * colour_step(colour_here, previous_colour)));
        }
        // The previous L of the planes just outside this lane's run: the last plane of the lane
        // below, the first of the lane above.
        let below_run = subgroupShuffleUp(prev1[SGM_LANE_WORDS - 1u], 1u);
        let above_run = subgroupShuffleDown(prev0[0], 1u);
        var local_min = 0xffffffffu;
        var below = below_run;
        for (var i = 0u; i < SGM_LANE_WORDS; i++) {
            let j = first_word + i;
            if (j < words) {
                let at = at_pixel + j;
                let c = cost[i];
                if (has_next) {
                    cost[i] = volume[at_next + j];
                }
                let d = 2u * j;
                var l0 = c & 0xffffu;
                var l1 = c >> 16u;
                if (step > 0u) {
                    var above = above_run;
                    if (i + 1u < SGM_LANE_WORDS) {
                        above = prev0[i + 1u];
                    }
                    l0 += term(prev0[i], below, prev1[i], d, planes, prev_min, p1, penalty2);
                    if (d + 1u < planes) {
                        l1 += term(prev1[i], prev0[i], above, d + 1u, planes, prev_min, p1, penalty2);
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
                // The next word's `below` is this word's previous L1 (read before it is replaced).
                below = prev1[i];
                prev0[i] = l0;
                prev1[i] = l1;
                let packed = sgm_sum_word(c, vec2<u32>(l0, l1));
                if (first_pass) {
                    atomicStore(&sums[at], packed);
                } else if (together) {
                    atomicAdd(&sums[at], packed);
                } else {
                    // One direction at a time: a plain load and store (no read-modify-write).
                    atomicStore(&sums[at], atomicLoad(&sums[at]) + packed);
                }
            }
        }
        prev_min = subgroupMin(local_min);
        previous_colour = colour_here;
        p += vec2<i32>(dx, dy);
        step += 1u;
    }
}
