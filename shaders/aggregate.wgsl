// Stages 4c + 5a: window placement and scoring, then winner-take-all. For each window placement (shiftable: the four w x h
// windows with the pixel at a corner; centred: one window around it) the channel means are read
// from the row sums (summed over the window's rows here) and combined into one score; the best (smallest) placement wins.
// Channels by mode:
//   per-pair aggregation: one per camera pair (pair TSSD) -> SSSD / best n / half-sequence over
//     the window means of the pairs seen in the window (visibility normalisation);
//   best half-sequence, per-half: left mean, right mean -> min;
//   best half-sequence, scored: left mean, right mean, min(left, right) per texel -> window mean
//     of the per-texel min; the halves decide the selection;
//   otherwise: the score.
// One invocation per reference pixel; it walks the planes of the batch. CPU twins:
// src/sweep/cpu/aggregate.rs and src/sweep/cpu/select.rs.

override WINDOW_W: u32 = 2u;      // = params.window_w
override WINDOW_H: u32 = 2u;      // = params.window_h
override WINDOW_MODE: u32 = 0u;   // = params.window_mode
override CHANNELS: u32 = 1u;      // = params.channels
override AGGREGATION: u32 = 0u;   // = params.aggregation
override SCORING: u32 = 0u;       // = params.scoring
override BEST_N: u32 = 2u;        // = params.best_n
override HALF_BEST_LEFT: u32 = 1u;  // = SweepPlan::half_ranks()[0] (0 = all pairs of the half)
override HALF_BEST_RIGHT: u32 = 1u; // = SweepPlan::half_ranks()[1]
// Two horizontally adjacent pixels per invocation, sharing the loads of their 2x2 windows.
override PAIRED: bool = false;
// Optimizer sgm: also write every plane's score into the u16 cost volume (see common.wgsl);
// the winner-take-all state still gives validity and the selection image.
override VOLUME: bool = false;     // = params.sgm_paths != 0

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> batch: Batch;
// Horizontal window sums per row (`box_h.wgsl`; a placeholder without the box pass).
@group(0) @binding(2) var<storage, read> row_sums: array<vec2<f32>>;
@group(0) @binding(5) var<storage, read> cost_slab: array<f32>;
// Streaming winner-take-all state, per pixel 3 x vec4 (see the selection step in main):
//   [0] best cost, best plane, cost of plane best-1, cost of plane best+1
//   [1] best cost away from best +- 1, min over planes 0..k-1, min over planes 0..k-2, cost of plane k-1
//   [2] half-sequence selection at the best plane, 0, 0, 0
@group(0) @binding(3) var<storage, read_write> state: array<vec4<f32>>;
// Per pair: camera a, camera b, half (HALF_*), 0.
@group(0) @binding(4) var<uniform> pairs: array<vec4<u32>, MAX_PAIRS>;
// The u16 cost volume of this row band (optimizer sgm; a placeholder otherwise).
@group(0) @binding(6) var<storage, read_write> volume: array<u32>;
// The rows this dispatch covers (the whole image unless the volume is split into bands).
@group(0) @binding(7) var<uniform> band: Band;
// Per reference row and tile (SweepPlan::shader_plane_ranges): xy the planes its pixels sweep;
// outside them a plane scores BIG (coarse to fine).
@group(0) @binding(8) var<storage, read> plane_ranges: array<vec4<u32>>;

// Whether pixel (x, y) sweeps plane `k` (every pixel sweeps every hypothesis of the fine sweep).
fn sweeps(x: u32, y: u32, k: u32) -> bool {
    if (batch.refine != 0u) {
        return true;
    }
    let range = plane_ranges[range_index(params.width, x, y)].xy;
    return k >= range.x && k <= range.y;
}

// No hypothesis: the score of a plane outside the row's range.
fn no_hypothesis() -> vec2<f32> {
    return vec2<f32>(BIG, f32(SEL_INVALID));
}

// Writes the level of plane `plane`'s score at pixel `pix`, each word once: an even plane's
// level waits in a register (returned) for the odd plane after it, which writes the word; an
// even plane that ends its batch writes its half alone (the high half 0, or filled by the next
// batch's first plane), and an odd plane that opens a batch keeps the low half written there.
fn store_level(
    pix: u32,
    plane: u32,
    score: f32,
    low: u32,
    first_in_batch: bool,
    last_in_batch: bool,
    swept: bool,
) -> u32 {
    // A plane outside the pixel's range is marked absent for SGM.
    var level = SGM_OUTSIDE_LEVEL;
    if (swept) {
        level = volume_level(score);
    }
    let word = (pix - band.first_pixel) * ((params.planes + 1u) / 2u) + plane / 2u;
    if ((plane & 1u) == 0u) {
        if (last_in_batch) {
            volume[word] = level;
        }
        return level;
    }
    if (first_in_batch) {
        volume[word] = (volume[word] & 0xffffu) | (level << 16u);
    } else {
        volume[word] = low | (level << 16u);
    }
    return 0u;
}

// Shiftable windows of at most 2x2 skip the box passes: the sums of the four placements come
// from the 3x3 texels around the pixel, each texel counted in the placements that contain it
// (the paper's four diagonal bilinear lookups).
fn direct_windows() -> bool {
    return WINDOW_MODE == WINDOW_SHIFTABLE && WINDOW_W <= 2u && WINDOW_H <= 2u;
}

// Mean of channel `ch` of plane `z` in the window anchored at (ax, ay) (its top-left texel):
// the row sums of its rows inside the image (`box_h.wgsl`) added top to bottom; BIG when
// nothing is valid. (A pass of its own wrote these vertical sums for every anchor and plane
// before: twice the memory of the row sums, read back once.)
fn box_mean(z: u32, ch: u32, ax: i32, ay: i32) -> f32 {
    let padded_w = params.padded_w;
    let height = i32(params.height);
    let px = u32(ax + i32(WINDOW_W) - 1);
    let y_first = max(ay, 0);
    let y_end = min(ay + i32(WINDOW_H), height);
    let base = (z * CHANNELS + ch) * params.height;
    var s = vec2<f32>(0.0);
    for (var y = y_first; y < y_end; y++) {
        s += row_sums[(base + u32(y)) * padded_w + px];
    }
    if (s.y <= 0.0) {
        return BIG;
    }
    return s.x / s.y;
}

// One texel of the cost slab as (cost, 1), or (0, 0) when invalid or outside the image.
fn slab_texel(base: u32, x: i32, y: i32) -> vec2<f32> {
    // Branch-free: the load is clamped into the image and weighs nothing outside it.
    let w = i32(params.width);
    let h = i32(params.height);
    let inside_image = x >= 0 && y >= 0 && x < w && y < h;
    let c = cost_slab[base + u32(clamp(y, 0, h - 1) * w + clamp(x, 0, w - 1))];
    return select(vec2<f32>(0.0), vec2<f32>(c, 1.0), inside_image && c >= 0.0);
}

// Means of the four 2x2 windows around the centre of 3 columns of (upper, lower) column sums.
fn means_2x2(u0: vec2<f32>, u1: vec2<f32>, u2: vec2<f32>, l0: vec2<f32>, l1: vec2<f32>, l2: vec2<f32>) -> vec4<f32> {
    let a = u0 + u1;
    let b = u1 + u2;
    let c = l0 + l1;
    let d = l1 + l2;
    let sum = vec4<f32>(a.x, b.x, c.x, d.x);
    let count = vec4<f32>(a.y, b.y, c.y, d.y);
    return select(vec4<f32>(BIG), sum / max(count, vec4<f32>(1.0)), count > vec4<f32>(0.0));
}

// The 2x2 window means of channel `ch` for pixels (x, y) and (x + 1, y) from one 4x3 block of
// texels (12 loads for two pixels instead of 18).
fn pair_means_2x2(z: u32, ch: u32, x: i32, y: i32) -> array<vec4<f32>, 2> {
    let base = (z * CHANNELS + ch) * params.pixel_count;
    let c0 = slab_texel(base, x - 1, y - 1);
    let c1 = slab_texel(base, x, y - 1);
    let c2 = slab_texel(base, x + 1, y - 1);
    let c3 = slab_texel(base, x + 2, y - 1);
    let d0 = slab_texel(base, x - 1, y);
    let d1 = slab_texel(base, x, y);
    let d2 = slab_texel(base, x + 1, y);
    let d3 = slab_texel(base, x + 2, y);
    let e0 = slab_texel(base, x - 1, y + 1);
    let e1 = slab_texel(base, x, y + 1);
    let e2 = slab_texel(base, x + 1, y + 1);
    let e3 = slab_texel(base, x + 2, y + 1);
    let u0 = c0 + d0;
    let u1 = c1 + d1;
    let u2 = c2 + d2;
    let u3 = c3 + d3;
    let l0 = d0 + e0;
    let l1 = d1 + e1;
    let l2 = d2 + e2;
    let l3 = d3 + e3;
    return array<vec4<f32>, 2>(means_2x2(u0, u1, u2, l0, l1, l2), means_2x2(u1, u2, u3, l1, l2, l3));
}

// The window means of channel `ch` of plane `z` for the four placements, one per lane:
// 0 up-left, 1 up-right, 2 down-left, 3 down-right of the pixel (centred: the same in all lanes).
// BIG where a window holds no valid texel. Everything below works on these lanes, without
// arrays indexed at run time (which software rasterisers execute slowly).
fn channel_means(z: u32, ch: u32, x: i32, y: i32) -> vec4<f32> {
    let w = i32(WINDOW_W);
    let h = i32(WINDOW_H);
    if (direct_windows() && WINDOW_W == 2u && WINDOW_H == 2u) {
        // The paper's shiftable 2x2: the four windows from column sums of the 3x3 texels.
        let base = (z * CHANNELS + ch) * params.pixel_count;
        let c00 = slab_texel(base, x - 1, y - 1);
        let c01 = slab_texel(base, x, y - 1);
        let c02 = slab_texel(base, x + 1, y - 1);
        let c10 = slab_texel(base, x - 1, y);
        let c11 = slab_texel(base, x, y);
        let c12 = slab_texel(base, x + 1, y);
        let c20 = slab_texel(base, x - 1, y + 1);
        let c21 = slab_texel(base, x, y + 1);
        let c22 = slab_texel(base, x + 1, y + 1);
        // Upper (rows -1, 0) and lower (rows 0, +1) column sums; .x value, .y count.
        return means_2x2(c00 + c10, c01 + c11, c02 + c12, c10 + c20, c11 + c21, c12 + c22);
    }
    if (direct_windows()) {
        let width = i32(params.width);
        let height = i32(params.height);
        let base = (z * CHANNELS + ch) * params.pixel_count;
        var sum = vec4<f32>(0.0);
        var count = vec4<f32>(0.0);
        for (var dy = 1 - h; dy <= h - 1; dy++) {
            let ty = y + dy;
            if (ty < 0 || ty >= height) {
                continue;
            }
            for (var dx = 1 - w; dx <= w - 1; dx++) {
                let tx = x + dx;
                if (tx < 0 || tx >= width) {
                    continue;
                }
                let c = cost_slab[base + u32(ty * width + tx)];
                if (c >= 0.0) {
                    let mask = vec4<f32>(
                        select(0.0, 1.0, dx <= 0 && dy <= 0),
                        select(0.0, 1.0, dx >= 0 && dy <= 0),
                        select(0.0, 1.0, dx <= 0 && dy >= 0),
                        select(0.0, 1.0, dx >= 0 && dy >= 0),
                    );
                    sum += c * mask;
                    count += mask;
                }
            }
        }
        return select(vec4<f32>(BIG), sum / max(count, vec4<f32>(1.0)), count > vec4<f32>(0.0));
    }
    if (WINDOW_MODE == WINDOW_CENTRED) {
        return vec4<f32>(box_mean(z, ch, x - (w - 1) / 2, y - (h - 1) / 2));
    }
    return vec4<f32>(
        box_mean(z, ch, x - w + 1, y - h + 1),
        box_mean(z, ch, x, y - h + 1),
        box_mean(z, ch, x - w + 1, y),
        box_mean(z, ch, x, y),
    );
}

fn mean_or_big(sum: vec4<f32>, count: vec4<f32>) -> vec4<f32> {
    return select(vec4<f32>(BIG), sum / max(count, vec4<f32>(1.0)), count > vec4<f32>(0.0));
}

// Mean of the first min(n, valid) of four sorted lanes-wise values (BIG = no value).
fn best_mean(v0: vec4<f32>, v1: vec4<f32>, v2: vec4<f32>, v3: vec4<f32>, n: u32) -> vec4<f32> {
    let big = vec4<f32>(BIG);
    let zero = vec4<f32>(0.0);
    let one = vec4<f32>(1.0);
    var sum = select(zero, v0, v0 < big);
    var count = select(zero, one, v0 < big);
    sum += select(zero, v1, v1 < big & vec4<bool>(n > 1u));
    count += select(zero, one, v1 < big & vec4<bool>(n > 1u));
    sum += select(zero, v2, v2 < big & vec4<bool>(n > 2u));
    count += select(zero, one, v2 < big & vec4<bool>(n > 2u));
    sum += select(zero, v3, v3 < big & vec4<bool>(n > 3u));
    count += select(zero, one, v3 < big & vec4<bool>(n > 3u));
    return mean_or_big(sum, count);
}

// Which half is clearly better: by at least `half_margin` of the worse score, and never by less
// than `half_margin` of HALF_NOISE_FLOOR (near-zero costs differ by sensor noise alone).
fn half_decisions(left: vec4<f32>, right: vec4<f32>) -> vec4<f32> {
    let margin = params.half_margin;
    let floor_cost = vec4<f32>(HALF_NOISE_FLOOR);
    let big = vec4<f32>(BIG);
    let is_left = left < big & (right >= big | (right - left) > margin * max(right, floor_cost));
    let is_right = right < big & (left >= big | (left - right) > margin * max(left, floor_cost));
    return select(select(vec4<f32>(f32(SEL_NONE)), vec4<f32>(f32(SEL_RIGHT)), is_right), vec4<f32>(f32(SEL_LEFT)), is_left);
}

// The smaller half's score, blended with the other where the two are within HALF_NOISE_FLOOR
// of each other (a quadratic smooth minimum): where no occlusion hits either side the score follows both
// halves, not whichever is lower at each plane. CPU twin: half_min in cpu/aggregate.rs.
fn half_min(left: vec4<f32>, right: vec4<f32>) -> vec4<f32> {
    let h = HALF_NOISE_FLOOR;
    let m = min(left, right);
    let t = max(vec4<f32>(h) - abs(left - right), vec4<f32>(0.0));
    let big = vec4<f32>(BIG);
    return select(m, m - t * t / (4.0 * h), left < big & right < big);
}

// Running sums over the pairs of one pixel and plane, per window placement (lanes). By value,
// no arrays (software rasterisers run run-time-indexed arrays slowly).
struct Acc {
    sum: vec4<f32>,
    count: vec4<f32>,
    left_sum: vec4<f32>,
    left_count: vec4<f32>,
    right_sum: vec4<f32>,
    right_count: vec4<f32>,
    // The n smallest pair means, ascending (BIG = none), for best n of m.
    b0: vec4<f32>,
    b1: vec4<f32>,
    b2: vec4<f32>,
    b3: vec4<f32>,
    b4: vec4<f32>,
    b5: vec4<f32>,
    b6: vec4<f32>,
    b7: vec4<f32>,
    // The HALF_BEST_LEFT / HALF_BEST_RIGHT smallest pair means of each half, likewise.
    l0: vec4<f32>,
    l1: vec4<f32>,
    l2: vec4<f32>,
    l3: vec4<f32>,
    r0: vec4<f32>,
    r1: vec4<f32>,
    r2: vec4<f32>,
    r3: vec4<f32>,
}

fn empty_acc() -> Acc {
    let z = vec4<f32>(0.0);
    let b = vec4<f32>(BIG);
    return Acc(z, z, z, z, z, z, b, b, b, b, b, b, b, b, b, b, b, b, b, b, b, b);
}

// Adds the window means `a` (BIG = no valid texel) of one pair in half `half`.
fn accumulate(acc_in: Acc, a: vec4<f32>, half: u32) -> Acc {
    var acc = acc_in;
    let big = vec4<f32>(BIG);
    let seen = a < big;
    let a0 = select(vec4<f32>(0.0), a, seen);
    let n0 = select(vec4<f32>(0.0), vec4<f32>(1.0), seen);
    acc.sum += a0;
    acc.count += n0;
    // The halves also tell best n of m which side matched better (the selection image).
    if (SCORING == SCORING_HALF || SCORING == SCORING_BEST_N) {
        if (half == HALF_LEFT) {
            acc.left_sum += a0;
            acc.left_count += n0;
            var v = a;
            var t = min(acc.l0, v); v = max(acc.l0, v); acc.l0 = t;
            t = min(acc.l1, v); v = max(acc.l1, v); acc.l1 = t;
            t = min(acc.l2, v); v = max(acc.l2, v); acc.l2 = t;
            acc.l3 = min(acc.l3, v);
        } else if (half == HALF_RIGHT) {
            acc.right_sum += a0;
            acc.right_count += n0;
            var v = a;
            var t = min(acc.r0, v); v = max(acc.r0, v); acc.r0 = t;
            t = min(acc.r1, v); v = max(acc.r1, v); acc.r1 = t;
            t = min(acc.r2, v); v = max(acc.r2, v); acc.r2 = t;
            acc.r3 = min(acc.r3, v);
        }
    }
    if (SCORING == SCORING_BEST_N) {
        var v = a;
        var t = min(acc.b0, v); v = max(acc.b0, v); acc.b0 = t;
        t = min(acc.b1, v); v = max(acc.b1, v); acc.b1 = t;
        t = min(acc.b2, v); v = max(acc.b2, v); acc.b2 = t;
        t = min(acc.b3, v); v = max(acc.b3, v); acc.b3 = t;
        t = min(acc.b4, v); v = max(acc.b4, v); acc.b4 = t;
        t = min(acc.b5, v); v = max(acc.b5, v); acc.b5 = t;
        t = min(acc.b6, v); v = max(acc.b6, v); acc.b6 = t;
        acc.b7 = min(acc.b7, v);
    }
    return acc;
}

// The best placement (first lane on ties; centred and 1x1 windows fill all lanes alike) as
// (score, selection).
fn best_placement(score: vec4<f32>, sel: vec4<f32>) -> vec2<f32> {
    var best = vec2<f32>(score.x, sel.x);
    if (score.y < best.x) {
        best = vec2<f32>(score.y, sel.y);
    }
    if (score.z < best.x) {
        best = vec2<f32>(score.z, sel.z);
    }
    if (score.w < best.x) {
        best = vec2<f32>(score.w, sel.w);
    }
    return best;
}

// Per-pair aggregation: the score of each placement from the accumulated pair means.
fn finish_pairs(acc: Acc) -> vec2<f32> {
    let big = vec4<f32>(BIG);
    let zero = vec4<f32>(0.0);
    let one = vec4<f32>(1.0);
    var left = mean_or_big(acc.left_sum, acc.left_count);
    var right = mean_or_big(acc.right_sum, acc.right_count);
    if (HALF_BEST_LEFT > 0u) {
        left = best_mean(acc.l0, acc.l1, acc.l2, acc.l3, HALF_BEST_LEFT);
    }
    if (HALF_BEST_RIGHT > 0u) {
        right = best_mean(acc.r0, acc.r1, acc.r2, acc.r3, HALF_BEST_RIGHT);
    }
    if (SCORING == SCORING_HALF) {
        return best_placement(half_min(left, right), half_decisions(left, right));
    }
    let none = vec4<f32>(f32(SEL_NONE));
    if (SCORING == SCORING_BEST_N) {
        // Mean of the min(n, seen) smallest; BIG entries are unseen pairs.
        let n = BEST_N;
        var s = zero;
        var c = zero;
        s += select(zero, acc.b0, acc.b0 < big & vec4<bool>(n > 0u));
        c += select(zero, one, acc.b0 < big & vec4<bool>(n > 0u));
        s += select(zero, acc.b1, acc.b1 < big & vec4<bool>(n > 1u));
        c += select(zero, one, acc.b1 < big & vec4<bool>(n > 1u));
        s += select(zero, acc.b2, acc.b2 < big & vec4<bool>(n > 2u));
        c += select(zero, one, acc.b2 < big & vec4<bool>(n > 2u));
        s += select(zero, acc.b3, acc.b3 < big & vec4<bool>(n > 3u));
        c += select(zero, one, acc.b3 < big & vec4<bool>(n > 3u));
        s += select(zero, acc.b4, acc.b4 < big & vec4<bool>(n > 4u));
        c += select(zero, one, acc.b4 < big & vec4<bool>(n > 4u));
        s += select(zero, acc.b5, acc.b5 < big & vec4<bool>(n > 5u));
        c += select(zero, one, acc.b5 < big & vec4<bool>(n > 5u));
        s += select(zero, acc.b6, acc.b6 < big & vec4<bool>(n > 6u));
        c += select(zero, one, acc.b6 < big & vec4<bool>(n > 6u));
        s += select(zero, acc.b7, acc.b7 < big & vec4<bool>(n > 7u));
        c += select(zero, one, acc.b7 < big & vec4<bool>(n > 7u));
        return best_placement(mean_or_big(s, c), half_decisions(left, right));
    }
    return best_placement(mean_or_big(acc.sum, acc.count), none);
}

// Scored or per-half aggregation: the score from the channel means (m2 only when scored).
fn finish_channels(m0: vec4<f32>, m1: vec4<f32>, m2: vec4<f32>) -> vec2<f32> {
    if (SCORING == SCORING_HALF) {
        var score = min(m0, m1);
        if (AGGREGATION == AGG_SCORED) {
            score = m2;
        }
        return best_placement(score, half_decisions(m0, m1));
    }
    return best_placement(m0, vec4<f32>(f32(SEL_NONE)));
}

// (best score over the window placements, its selection) of plane `z` at pixel (x, y).
fn score_plane(z: u32, x: i32, y: i32) -> vec2<f32> {
    if (AGGREGATION == AGG_PER_PAIR) {
        var acc = empty_acc();
        for (var p = 0u; p < CHANNELS; p++) {
            acc = accumulate(acc, channel_means(z, p, x, y), pairs[p].z);
        }
        return finish_pairs(acc);
    }
    let m0 = channel_means(z, 0u, x, y);
    var m1 = m0;
    var m2 = m0;
    if (CHANNELS > 1u) {
        m1 = channel_means(z, 1u, x, y);
    }
    if (CHANNELS > 2u) {
        m2 = channel_means(z, 2u, x, y);
    }
    return finish_channels(m0, m1, m2);
}

// The same for pixels (x, y) and (x + 1, y) with shiftable 2x2 windows (PAIRED).
fn score_plane_paired(z: u32, x: i32, y: i32) -> array<vec2<f32>, 2> {
    if (AGGREGATION == AGG_PER_PAIR) {
        var acc_a = empty_acc();
        var acc_b = empty_acc();
        for (var p = 0u; p < CHANNELS; p++) {
            let m = pair_means_2x2(z, p, x, y);
            let half = pairs[p].z;
            acc_a = accumulate(acc_a, m[0], half);
            acc_b = accumulate(acc_b, m[1], half);
        }
        return array<vec2<f32>, 2>(finish_pairs(acc_a), finish_pairs(acc_b));
    }
    let m0 = pair_means_2x2(z, 0u, x, y);
    var m1 = m0;
    var m2 = m0;
    if (CHANNELS > 1u) {
        m1 = pair_means_2x2(z, 1u, x, y);
    }
    if (CHANNELS > 2u) {
        m2 = pair_means_2x2(z, 2u, x, y);
    }
    return array<vec2<f32>, 2>(finish_channels(m0[0], m1[0], m2[0]), finish_channels(m0[1], m1[1], m2[1]));
}

// Stage 5a, selection: `select_plane` in common.wgsl (shared with sgm_select.wgsl).

fn load_state(pix: u32) -> Wta {
    if (batch.is_first != 0u) {
        return Wta(vec4<f32>(BIG, -1.0, BIG, BIG), vec4<f32>(BIG), vec4<f32>(f32(SEL_INVALID), 0.0, 0.0, 0.0));
    }
    return Wta(state[3u * pix], state[3u * pix + 1u], state[3u * pix + 2u]);
}

fn store_state(pix: u32, st: Wta) {
    state[3u * pix] = st.s0;
    state[3u * pix + 1u] = st.s1;
    state[3u * pix + 2u] = st.s2;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let width = params.width;
    let y = band.first_row + gid.y;
    let height = min(params.height, band.first_row + band.rows);
    if (PAIRED) {
        let x = 2u * gid.x;
        if (x >= width || y >= height) {
            return;
        }
        let has_b = x + 1u < width;
        let pix = y * width + x;
        var a = load_state(pix);
        var b = a;
        if (has_b) {
            b = load_state(pix + 1u);
        }
        var low_a = 0u;
        var low_b = 0u;
        for (var z = 0u; z < batch.plane_count; z++) {
            let k = f32(batch.first_plane + z);
            var best = array<vec2<f32>, 2>(no_hypothesis(), no_hypothesis());
            // x and x + 1 share a tile (RANGE_TILE is even).
            let swept = sweeps(x, y, batch.first_plane + z);
            if (swept) {
                best = score_plane_paired(z, i32(x), i32(y));
            }
            a = select_plane(a, k, best[0]);
            b = select_plane(b, k, best[1]);
            // The fine sweep writes no cost volume (SGM has run).
            if (VOLUME && batch.refine == 0u) {
                let last = z + 1u == batch.plane_count;
                low_a = store_level(pix, batch.first_plane + z, best[0].x, low_a, z == 0u, last, swept);
                if (has_b) {
                    low_b = store_level(pix + 1u, batch.first_plane + z, best[1].x, low_b, z == 0u, last, swept);
                }
            }
        }
        store_state(pix, a);
        if (has_b) {
            store_state(pix + 1u, b);
        }
        return;
    }
    if (gid.x >= width || y >= height) {
        return;
    }
    let pix = y * width + gid.x;
    var st = load_state(pix);
    var low = 0u;
    for (var z = 0u; z < batch.plane_count; z++) {
        var best = no_hypothesis();
        let swept = sweeps(gid.x, y, batch.first_plane + z);
        if (swept) {
            best = score_plane(z, i32(gid.x), i32(y));
        }
        st = select_plane(st, f32(batch.first_plane + z), best);
        if (VOLUME && batch.refine == 0u) {
            let last = z + 1u == batch.plane_count;
            low = store_level(pix, batch.first_plane + z, best.x, low, z == 0u, last, swept);
        }
    }
    store_state(pix, st);
}
