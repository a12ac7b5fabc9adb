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
// One invocation per reference pixel; it walks the planes of the batch. CPU twin: src/sweep/cpu/aggregate.rs.

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
@group(0) @binding(5) var<storage, read> cost_slab: array<f32>;
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

// (score, selection) of one window placement from the window means of its channels (BIG =
// nothing valid in the window).
fn score_means(means: ptr<function, array<f32, 16>>) -> vec2<f32> {
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
            let a = (*means)[p];
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
        let left = (*means)[0];
        let right = (*means)[1];
        var score = min(left, right);
        if (AGGREGATION == AGG_SCORED) {
            score = (*means)[2];
        }
        return vec2<f32>(score, f32(half_decision(left, right)));
    }
    return vec2<f32>((*means)[0], f32(SEL_NONE));
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let width = params.ref_size.x;
    let height = params.ref_size.y;
    if (gid.x >= width || gid.y >= height) {
        return;
    }
    let npix = params.ref_size.z;
    let x = i32(gid.x);
    let y = i32(gid.y);
    let w = i32(WINDOW_W);
    let h = i32(WINDOW_H);
    var means: array<f32, 16>;
    for (var z = 0u; z < batch.plane_count; z++) {
        var best = vec2<f32>(BIG, f32(SEL_NONE));
        if (direct_windows()) {
            var sums: array<vec4<f32>, 16>;
            var counts: array<vec4<f32>, 16>;
            let reach_x = w - 1;
            let reach_y = h - 1;
            for (var dy = -reach_y; dy <= reach_y; dy++) {
                let ty = y + dy;
                if (ty < 0 || ty >= i32(height)) {
                    continue;
                }
                for (var dx = -reach_x; dx <= reach_x; dx++) {
                    let tx = x + dx;
                    if (tx < 0 || tx >= i32(width)) {
                        continue;
                    }
                    // Placements: 0 up-left, 1 up-right, 2 down-left, 3 down-right of the pixel.
                    let mask = vec4<f32>(
                        select(0.0, 1.0, dx <= 0 && dy <= 0),
                        select(0.0, 1.0, dx >= 0 && dy <= 0),
                        select(0.0, 1.0, dx <= 0 && dy >= 0),
                        select(0.0, 1.0, dx >= 0 && dy >= 0),
                    );
                    let t = u32(ty * i32(width) + tx);
                    for (var ch = 0u; ch < CHANNELS; ch++) {
                        let c = cost_slab[(z * CHANNELS + ch) * npix + t];
                        if (c >= 0.0) {
                            sums[ch] += c * mask;
                            counts[ch] += mask;
                        }
                    }
                }
            }
            let placements = select(4, 1, w == 1 && h == 1);
            for (var corner = 0; corner < placements; corner++) {
                for (var ch = 0u; ch < CHANNELS; ch++) {
                    means[ch] = select(BIG, sums[ch][corner] / counts[ch][corner], counts[ch][corner] > 0.0);
                }
                let s = score_means(&means);
                if (s.x < best.x) {
                    best = s;
                }
            }
        } else if (WINDOW_MODE == WINDOW_CENTRED) {
            for (var ch = 0u; ch < CHANNELS; ch++) {
                means[ch] = box_mean(z, ch, x - (w - 1) / 2, y - (h - 1) / 2);
            }
            best = score_means(&means);
        } else {
            for (var corner = 0; corner < 4; corner++) {
                let ax = select(x, x - w + 1, (corner & 1) == 0);
                let ay = select(y, y - h + 1, (corner & 2) == 0);
                for (var ch = 0u; ch < CHANNELS; ch++) {
                    means[ch] = box_mean(z, ch, ax, ay);
                }
                let s = score_means(&means);
                if (s.x < best.x) {
                    best = s;
                }
            }
        }
        agg_slab[z * npix + gid.y * width + gid.x] = best;
    }
}
