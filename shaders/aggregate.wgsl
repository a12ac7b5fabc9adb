// Stage 4c: window placement and scoring. For each window placement (shiftable: the four w x h
// windows with the pixel at a corner; centred: one window around it) the channel means are read
// from the box sums and combined into one score; the best (smallest) placement wins.
// Channels by mode:
//   per-pair aggregation: one per camera pair (pair TSSD) -> SSSD / best n / half-sequence over
//     the window means of the pairs seen in the window (visibility normalisation);
//   best half-sequence, per-half: left mean, right mean -> min;
//   best half-sequence, scored: left mean, right mean, min(left, right) per texel -> window mean
//     of the per-texel min; the halves decide the selection;
//   otherwise: the score.
// One invocation per (reference pixel, plane of the batch). CPU twin: src/sweep/cpu/aggregate.rs.

override WINDOW_W: u32 = 2u;      // = params.window.x
override WINDOW_H: u32 = 2u;      // = params.window.y
override WINDOW_MODE: u32 = 0u;   // = params.extra.y
override CHANNELS: u32 = 1u;      // = params.counts.z
override AGGREGATION: u32 = 0u;   // = params.modes.w
override SCORING: u32 = 0u;       // = params.modes.x
override BEST_N: u32 = 2u;        // = params.modes.z

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> batch: Batch;
@group(0) @binding(2) var<storage, read> box_sums: array<vec2<f32>>;
@group(0) @binding(3) var<storage, read_write> agg_slab: array<vec2<f32>>;
// Per pair: camera a, camera b, half (HALF_*), 0.
@group(0) @binding(4) var<storage, read> pairs: array<vec4<u32>>;

fn half_decision(left: f32, right: f32) -> u32 {
    let keep = 1.0 - params.thresholds.w;
    if (left < BIG && (right >= BIG || left < keep * right)) {
        return SEL_LEFT;
    }
    if (right < BIG && (left >= BIG || right < keep * left)) {
        return SEL_RIGHT;
    }
    return SEL_NONE;
}

// Mean of channel `ch` of plane `z` in the window anchored at (ax, ay); BIG when nothing is valid.
fn window_mean(z: u32, ch: u32, ax: i32, ay: i32) -> f32 {
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

// (score, selection) of one window placement.
fn score_window(z: u32, ax: i32, ay: i32) -> vec2<f32> {
    if (AGGREGATION == AGG_PER_PAIR) {
        var sum = 0.0;
        var count = 0u;
        var left_sum = 0.0;
        var left_count = 0u;
        var right_sum = 0.0;
        var right_count = 0u;
        var smallest: array<f32, 8>;
        var kept = 0u;
        for (var p = 0u; p < CHANNELS; p++) {
            let a = window_mean(z, p, ax, ay);
            if (a >= BIG) {
                continue;
            }
            sum += a;
            count += 1u;
            let half = pairs[p].z;
            if (half == HALF_LEFT) {
                left_sum += a;
                left_count += 1u;
            } else if (half == HALF_RIGHT) {
                right_sum += a;
                right_count += 1u;
            }
            if (SCORING == SCORING_BEST_N && (kept < BEST_N || a < smallest[BEST_N - 1u])) {
                var i = min(kept, BEST_N - 1u);
                loop {
                    if (i == 0u || smallest[i - 1u] <= a) {
                        break;
                    }
                    smallest[i] = smallest[i - 1u];
                    i -= 1u;
                }
                smallest[i] = a;
                kept = min(kept + 1u, BEST_N);
            }
        }
        if (SCORING == SCORING_HALF) {
            var left = BIG;
            var right = BIG;
            if (left_count > 0u) {
                left = left_sum / f32(left_count);
            }
            if (right_count > 0u) {
                right = right_sum / f32(right_count);
            }
            return vec2<f32>(min(left, right), f32(half_decision(left, right)));
        }
        if (SCORING == SCORING_BEST_N) {
            if (kept == 0u) {
                return vec2<f32>(BIG, f32(SEL_NONE));
            }
            var s = 0.0;
            for (var k = 0u; k < kept; k++) {
                s += smallest[k];
            }
            return vec2<f32>(s / f32(kept), f32(SEL_NONE));
        }
        if (count == 0u) {
            return vec2<f32>(BIG, f32(SEL_NONE));
        }
        return vec2<f32>(sum / f32(count), f32(SEL_NONE));
    }
    if (SCORING == SCORING_HALF) {
        let left = window_mean(z, 0u, ax, ay);
        let right = window_mean(z, 1u, ax, ay);
        var score = min(left, right);
        if (AGGREGATION == AGG_SCORED) {
            score = window_mean(z, 2u, ax, ay);
        }
        return vec2<f32>(score, f32(half_decision(left, right)));
    }
    return vec2<f32>(window_mean(z, 0u, ax, ay), f32(SEL_NONE));
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let width = params.ref_size.x;
    if (gid.x >= width || gid.y >= params.ref_size.y || gid.z >= batch.plane_count) {
        return;
    }
    let x = i32(gid.x);
    let y = i32(gid.y);
    let w = i32(WINDOW_W);
    let h = i32(WINDOW_H);
    var best = vec2<f32>(BIG, f32(SEL_NONE));
    if (WINDOW_MODE == WINDOW_CENTRED || (w == 1 && h == 1)) {
        best = score_window(gid.z, x - (w - 1) / 2, y - (h - 1) / 2);
    } else {
        for (var corner = 0; corner < 4; corner++) {
            let ax = select(x, x - w + 1, (corner & 1) == 0);
            let ay = select(y, y - h + 1, (corner & 2) == 0);
            let s = score_window(gid.z, ax, ay);
            if (s.x < best.x) {
                best = s;
            }
        }
    }
    agg_slab[gid.z * params.ref_size.z + gid.y * width + gid.x] = best;
}
