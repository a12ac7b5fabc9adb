// Stages 4c + 5a: window placement and scoring, then winner-take-all. For each window placement (shiftable: the four w x h
// windows with the pixel at a corner; centred: one window around it) the channel means are read
// from the box sums and combined into one score; the best (smallest) placement wins.
// Channels by mode:
//   per-pair aggregation: one per camera pair (pair TSSD) -> SSSD / best n / half-sequence over
//     the window means of the pairs seen in the window (visibility normalisation);
//   best half-sequence, per-half: left mean, right mean -> min;
//   best half-sequence, scored: left mean, right mean, min(left, right) per texel -> window mean
//     of the per-texel min; the halves decide the selection;
//   otherwise: the score.
// One invocation per reference pixel; it walks the planes of the batch. CPU twins:
// src/sweep/cpu/aggregate.rs and src/sweep/cpu/select.rs.

override WINDOW_W: u32 = 2u;      // = params.window.x
override WINDOW_H: u32 = 2u;      // = params.window.y
override WINDOW_MODE: u32 = 0u;   // = params.extra.y
override CHANNELS: u32 = 1u;      // = params.counts.z
override AGGREGATION: u32 = 0u;   // = params.modes.w
override SCORING: u32 = 0u;       // = params.modes.x
override BEST_N: u32 = 2u;        // = params.modes.z
override HALF_BEST_N: u32 = 2u;   // = params.counts.w

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> batch: Batch;
@group(0) @binding(2) var<storage, read> box_sums: array<vec2<f32>>;
@group(0) @binding(5) var<storage, read> cost_slab: array<f32>;
// Streaming winner-take-all state, per pixel 3 x vec4 (see the selection step in main):
//   [0] best cost, best plane, cost of plane best-1, cost of plane best+1
//   [1] best cost away from best +- 1, min over planes 0..k-1, min over planes 0..k-2, cost of plane k-1
//   [2] half-sequence selection at the best plane, 0, 0, 0
@group(0) @binding(3) var<storage, read_write> state: array<vec4<f32>>;
// Per pair: camera a, camera b, half (HALF_*), 0.
@group(0) @binding(4) var<uniform> pairs: array<vec4<u32>, MAX_PAIRS>;

// Shiftable windows of at most 2x2 skip the box passes: the sums of the four placements come
// from the 3x3 texels around the pixel, each texel counted in the placements that contain it
// (the paper's four diagonal bilinear lookups).
fn direct_windows() -> bool {
    return WINDOW_MODE == WINDOW_SHIFTABLE && WINDOW_W <= 2u && WINDOW_H <= 2u;
}

// Mean of channel `ch` of plane `z` in the window anchored at (ax, ay) from the box sums; BIG
// when nothing is valid.
fn box_mean(z: u32, ch: u32, ax: i32, ay: i32) -> f32 {
    let padded_w = params.extra.z;
    let padded_h = params.extra.w;
    let px = u32(ax + i32(WINDOW_W) - 1);
    let py = u32(ay + i32(WINDOW_H) - 1);
    let s = box_sums[((z * CHANNELS + ch) * padded_h + py) * padded_w + px];
    if (s.y <= 0.0) {
        return BIG;
    }
    return s.x / s.y;
}

// One texel of the cost slab as (cost, 1), or (0, 0) when invalid or outside the image.
fn slab_texel(base: u32, x: i32, y: i32) -> vec2<f32> {
    // Branch-free: the load is clamped into the image and weighs nothing outside it.
    let w = i32(params.ref_size.x);
    let h = i32(params.ref_size.y);
    let inside_image = x >= 0 && y >= 0 && x < w && y < h;
    let c = cost_slab[base + u32(clamp(y, 0, h - 1) * w + clamp(x, 0, w - 1))];
    return select(vec2<f32>(0.0), vec2<f32>(c, 1.0), inside_image && c >= 0.0);
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
        let base = (z * CHANNELS + ch) * params.ref_size.z;
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
        let u0 = c00 + c10;
        let u1 = c01 + c11;
        let u2 = c02 + c12;
        let l0 = c10 + c20;
        let l1 = c11 + c21;
        let l2 = c12 + c22;
        let a = u0 + u1;
        let b = u1 + u2;
        let c = l0 + l1;
        let d = l1 + l2;
        let sum = vec4<f32>(a.x, b.x, c.x, d.x);
        let count = vec4<f32>(a.y, b.y, c.y, d.y);
        return select(vec4<f32>(BIG), sum / max(count, vec4<f32>(1.0)), count > vec4<f32>(0.0));
    }
    if (direct_windows()) {
        let width = i32(params.ref_size.x);
        let height = i32(params.ref_size.y);
        let base = (z * CHANNELS + ch) * params.ref_size.z;
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

fn half_decisions(left: vec4<f32>, right: vec4<f32>) -> vec4<f32> {
    let keep = 1.0 - params.thresholds.w;
    let big = vec4<f32>(BIG);
    let is_left = left < big & (right >= big | left < keep * right);
    let is_right = right < big & (left >= big | right < keep * left);
    return select(select(vec4<f32>(f32(SEL_NONE)), vec4<f32>(f32(SEL_RIGHT)), is_right), vec4<f32>(f32(SEL_LEFT)), is_left);
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let width = params.ref_size.x;
    let height = params.ref_size.y;
    if (gid.x >= width || gid.y >= height) {
        return;
    }
    let x = i32(gid.x);
    let y = i32(gid.y);
    let pix = gid.y * width + gid.x;
    var s0 = vec4<f32>(BIG, -1.0, BIG, BIG);
    var s1 = vec4<f32>(BIG, BIG, BIG, BIG);
    var s2 = vec4<f32>(f32(SEL_INVALID), 0.0, 0.0, 0.0);
    if (batch.is_first == 0u) {
        s0 = state[3u * pix];
        s1 = state[3u * pix + 1u];
        s2 = state[3u * pix + 2u];
    }
    let big = vec4<f32>(BIG);
    let zero = vec4<f32>(0.0);
    let one = vec4<f32>(1.0);
    for (var z = 0u; z < batch.plane_count; z++) {
        // Per placement (lane): score and half-sequence selection.
        var score = big;
        var sel = vec4<f32>(f32(SEL_NONE));
        if (AGGREGATION == AGG_PER_PAIR) {
            var sum = zero;
            var count = zero;
            var left_sum = zero;
            var left_count = zero;
            var right_sum = zero;
            var right_count = zero;
            // The n smallest pair means per lane, kept sorted by bubbling each new value through.
            var b0 = big;
            var b1 = big;
            var b2 = big;
            var b3 = big;
            var b4 = big;
            var b5 = big;
            var b6 = big;
            var b7 = big;
            // The HALF_BEST_N smallest pair means of each half, likewise.
            var l0 = big;
            var l1 = big;
            var l2 = big;
            var l3 = big;
            var r0 = big;
            var r1 = big;
            var r2 = big;
            var r3 = big;
            for (var p = 0u; p < CHANNELS; p++) {
                let a = channel_means(z, p, x, y);
                let seen = a < big;
                let a0 = select(zero, a, seen);
                let n0 = select(zero, one, seen);
                sum += a0;
                count += n0;
                let half = pairs[p].z;
                if (half == HALF_LEFT) {
                    left_sum += a0;
                    left_count += n0;
                    var v = a;
                    var t = min(l0, v); v = max(l0, v); l0 = t;
                    t = min(l1, v); v = max(l1, v); l1 = t;
                    t = min(l2, v); v = max(l2, v); l2 = t;
                    l3 = min(l3, v);
                } else if (half == HALF_RIGHT) {
                    right_sum += a0;
                    right_count += n0;
                    var v = a;
                    var t = min(r0, v); v = max(r0, v); r0 = t;
                    t = min(r1, v); v = max(r1, v); r1 = t;
                    t = min(r2, v); v = max(r2, v); r2 = t;
                    r3 = min(r3, v);
                }
                if (SCORING == SCORING_BEST_N) {
                    var v = a;
                    var t = min(b0, v); v = max(b0, v); b0 = t;
                    t = min(b1, v); v = max(b1, v); b1 = t;
                    t = min(b2, v); v = max(b2, v); b2 = t;
                    t = min(b3, v); v = max(b3, v); b3 = t;
                    t = min(b4, v); v = max(b4, v); b4 = t;
                    t = min(b5, v); v = max(b5, v); b5 = t;
                    t = min(b6, v); v = max(b6, v); b6 = t;
                    b7 = min(b7, v);
                }
            }
            if (SCORING == SCORING_HALF) {
                var left = mean_or_big(left_sum, left_count);
                var right = mean_or_big(right_sum, right_count);
                if (HALF_BEST_N > 0u) {
                    left = best_mean(l0, l1, l2, l3, HALF_BEST_N);
                    right = best_mean(r0, r1, r2, r3, HALF_BEST_N);
                }
                score = min(left, right);
                sel = half_decisions(left, right);
            } else if (SCORING == SCORING_BEST_N) {
                // Mean of the min(n, seen) smallest; BIG entries are unseen pairs.
                var best_sum = zero;
                var best_count = zero;
                let n = BEST_N;
                best_sum += select(zero, b0, b0 < big & vec4<bool>(n > 0u));
                best_count += select(zero, one, b0 < big & vec4<bool>(n > 0u));
                best_sum += select(zero, b1, b1 < big & vec4<bool>(n > 1u));
                best_count += select(zero, one, b1 < big & vec4<bool>(n > 1u));
                best_sum += select(zero, b2, b2 < big & vec4<bool>(n > 2u));
                best_count += select(zero, one, b2 < big & vec4<bool>(n > 2u));
                best_sum += select(zero, b3, b3 < big & vec4<bool>(n > 3u));
                best_count += select(zero, one, b3 < big & vec4<bool>(n > 3u));
                best_sum += select(zero, b4, b4 < big & vec4<bool>(n > 4u));
                best_count += select(zero, one, b4 < big & vec4<bool>(n > 4u));
                best_sum += select(zero, b5, b5 < big & vec4<bool>(n > 5u));
                best_count += select(zero, one, b5 < big & vec4<bool>(n > 5u));
                best_sum += select(zero, b6, b6 < big & vec4<bool>(n > 6u));
                best_count += select(zero, one, b6 < big & vec4<bool>(n > 6u));
                best_sum += select(zero, b7, b7 < big & vec4<bool>(n > 7u));
                best_count += select(zero, one, b7 < big & vec4<bool>(n > 7u));
                score = mean_or_big(best_sum, best_count);
            } else {
                score = mean_or_big(sum, count);
            }
        } else if (SCORING == SCORING_HALF) {
            let left = channel_means(z, 0u, x, y);
            let right = channel_means(z, 1u, x, y);
            score = min(left, right);
            if (AGGREGATION == AGG_SCORED) {
                score = channel_means(z, 2u, x, y);
            }
            sel = half_decisions(left, right);
        } else {
            score = channel_means(z, 0u, x, y);
        }
        // The best placement, the first lane on ties (centred and 1x1 windows fill all lanes alike).
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

        // Stage 5a, selection: streaming winner-take-all that keeps, exactly and without a cost
        // volume, the winner's neighbours (for the sub-pixel parabola) and the best rival away
        // from them (for the confidence).
        let k = f32(batch.first_plane + z);
        let c = best.x;
        if (c < s0.x) {
            s0 = vec4<f32>(c, k, s1.w, BIG);
            s1.x = s1.z;
            s2.x = best.y;
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
