// Stage 1+2+3: hypotheses -> per-camera bilinear colour (and census) -> pair cost -> multi-camera
// score, into the cost slab. (Per-pair aggregation over reference pairs with window sums runs
// `cost_rows.wgsl` instead.) CPU twin: src/sweep/cpu/cost.rs.

override SCORING: u32 = 0u;       // = params.scoring
override PAIRS: u32 = 0u;         // = params.pair_mode
override BEST_N: u32 = 2u;        // = params.best_n
override AGGREGATION: u32 = 0u;   // = params.aggregation
override CHANNELS: u32 = 1u;      // = params.channels (pairs m in per-pair aggregation)

// (The bindings 0-4, 6 and 7 and the cost's functions: cost_common.wgsl.)
@group(0) @binding(5) var<storage, read_write> cost_slab: array<f32>;

// Running sums of one hypothesis's pair costs. Passed by value, with the n smallest costs in
// plain fields (no run-time-indexed arrays, which software rasterisers execute slowly).
struct Acc {
    sum: f32,
    count: u32,
    left_sum: f32,
    left_count: u32,
    right_sum: f32,
    right_count: u32,
    // The smallest pair costs in ascending order (BIG = empty), for best n of m.
    b0: f32,
    b1: f32,
    b2: f32,
    b3: f32,
    b4: f32,
    b5: f32,
    b6: f32,
    b7: f32,
}

fn empty_acc() -> Acc {
    return Acc(0.0, 0u, 0.0, 0u, 0.0, 0u, BIG, BIG, BIG, BIG, BIG, BIG, BIG, BIG);
}

// Adds one pair cost; `half` is HALF_LEFT, HALF_RIGHT or HALF_REFERENCE (= in no half).
fn add_pair(acc_in: Acc, cost: f32, half: u32) -> Acc {
    var acc = acc_in;
    acc.sum += cost;
    acc.count += 1u;
    if (half == HALF_LEFT) {
        acc.left_sum += cost;
        acc.left_count += 1u;
    } else if (half == HALF_RIGHT) {
        acc.right_sum += cost;
        acc.right_count += 1u;
    }
    if (SCORING == SCORING_BEST_N) {
        // Bubble the new cost through the sorted list.
        var v = cost;
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

// Mean of the min(BEST_N, pairs seen) smallest costs; INVALID when no pair was seen.
fn best_n_mean(acc: Acc) -> f32 {
    var s = 0.0;
    var k = 0u;
    let values = vec4<f32>(acc.b0, acc.b1, acc.b2, acc.b3);
    let more = vec4<f32>(acc.b4, acc.b5, acc.b6, acc.b7);
    for (var i = 0u; i < 4u; i++) {
        if (i < BEST_N && values[i] < BIG) {
            s += values[i];
            k += 1u;
        }
    }
    for (var i = 0u; i < 4u; i++) {
        if (i + 4u < BEST_N && more[i] < BIG) {
            s += more[i];
            k += 1u;
        }
    }
    return mean_or_invalid(s, k);
}

fn mean_or_invalid(sum: f32, count: u32) -> f32 {
    if (count == 0u) {
        return INVALID;
    }
    return sum / f32(count);
}

// The half a pair belongs to: both cameras in one half (the reference belongs to both).
fn pair_half(a: u32, b: u32) -> u32 {
    if (a == HALF_REFERENCE) {
        return b;
    }
    if (b == HALF_REFERENCE || a == b) {
        return a;
    }
    return HALF_REFERENCE;
}

// Scores plane `z` of the batch for pixel `pixel`; `ref_colour` is the reference texel.
fn score_plane(pixel: vec2<u32>, pix: u32, z: u32, ray: vec3<f32>, ref_colour: vec3<f32>, ref_word: u32, across: vec3<f32>, along: vec3<f32>) {
    let npix = params.pixel_count;
    let channels = CHANNELS;
    let slot = (z * channels) * npix + pix;
    let depth = hypothesis_depth(z, ray, pix);
    if (!(depth > 0.0)) {
        for (var ch = 0u; ch < channels; ch++) {
            cost_slab[slot + ch * npix] = INVALID;
        }
        return;
    }
    let point_in_ref = ray * depth;
    let ref_index = params.reference;
    let n_cameras = params.cameras;

    let per_pair = AGGREGATION == AGG_PER_PAIR;
    var acc = empty_acc();
    if (PAIRS == PAIRS_REFERENCE) {
        var p = 0u;
        for (var i = 0u; i < n_cameras; i++) {
            if (i == ref_index) {
                continue;
            }
            let cam = cameras[i];
            let projected = project(cam, point_in_ref);
            let visible = projected.z > 0.0 && inside(cam, projected.xy);
            if (per_pair) {
                var cost = INVALID;
                if (visible) {
                    let matched = matched_colour(ref_colour, across, along, projected.xy);
                    cost = reference_pair_cost(matched, ref_word, cam, projected.xy);
                }
                cost_slab[slot + p * npix] = cost;
                p += 1u;
            } else if (visible) {
                let matched = matched_colour(ref_colour, across, along, projected.xy);
                acc = add_pair(acc, reference_pair_cost(matched, ref_word, cam, projected.xy), cam.info.x);
            }
        }
        if (per_pair) {
            return;
        }
    } else {
        var colours: array<vec3<f32>, 32>;
        var visible: array<bool, 32>;
        // Census costs: the nearest texel's word, and where the camera saw the point (pairs
        // with the reference interpolate the distance there).
        var words: array<u32, 32>;
        var samples: array<vec2<f32>, 32>;
        let census = params.cost != COST_TSSD;
        for (var i = 0u; i < n_cameras; i++) {
            let cam = cameras[i];
            if (i == ref_index) {
                colours[i] = ref_colour;
                words[i] = ref_word;
                visible[i] = true;
                continue;
            }
            let projected = project(cam, point_in_ref);
            visible[i] = projected.z > 0.0 && inside(cam, projected.xy);
            if (visible[i]) {
                colours[i] = sample_bilinear(cam, projected.xy);
                samples[i] = projected.xy;
                if (census) {
                    words[i] = census_nearest(cam, projected.xy);
                }
            }
        }
        var p = 0u;
        for (var i = 0u; i < n_cameras; i++) {
            for (var j = i + 1u; j < n_cameras; j++) {
                let both = visible[i] && visible[j];
                var cost = INVALID;
                if (both) {
                    // Pairs with the reference compare the sample with the reference as the
                    // sample's phase smooths it (the fine sweep).
                    var a = colours[i];
                    var b = colours[j];
                    if (i == ref_index) {
                        a = matched_colour(ref_colour, across, along, samples[j]);
                    } else if (j == ref_index) {
                        b = matched_colour(ref_colour, across, along, samples[i]);
                    }
                    cost = tssd(a, b);
                    if (census) {
                        var bits = 0.0;
                        if (i == ref_index) {
                            bits = census_distance(cameras[j], samples[j], ref_word);
                        } else if (j == ref_index) {
                            bits = census_distance(cameras[i], samples[i], ref_word);
                        } else {
                            bits = f32(countOneBits(words[i] ^ words[j]));
                        }
                        cost = mixed_cost(cost, bits);
                    }
                }
                if (per_pair) {
                    cost_slab[slot + p * npix] = cost;
                    p += 1u;
                } else if (both) {
                    acc = add_pair(acc, cost, pair_half(cameras[i].info.x, cameras[j].info.x));
                }
            }
        }
        if (per_pair) {
            return;
        }
    }

    if (SCORING == SCORING_HALF) {
        let left = mean_or_invalid(acc.left_sum, acc.left_count);
        let right = mean_or_invalid(acc.right_sum, acc.right_count);
        cost_slab[slot] = left;
        cost_slab[slot + npix] = right;
        if (CHANNELS == 3u) {
            // Scored aggregation: the per-texel score min(left, right) over the visible halves.
            var m = left;
            if (left < 0.0 || (right >= 0.0 && right < left)) {
                m = right;
            }
            cost_slab[slot + 2u * npix] = m;
        }
    } else if (SCORING == SCORING_BEST_N) {
        cost_slab[slot] = best_n_mean(acc);
    } else {
        cost_slab[slot] = mean_or_invalid(acc.sum, acc.count);
    }
}

// One invocation per reference pixel; it walks the planes of the batch (the ray and the
// reference colour are loaded once).
@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let width = params.width;
    if (gid.x >= width || gid.y >= params.height) {
        return;
    }
    let pix = gid.y * width + gid.x;
    let ray = rays[pix].xyz;
    let ref_index = params.reference;
    let r = reference_pixel(gid.x, gid.y);
    let needed = plane_ranges[range_index(params.width, gid.x, gid.y)].zw;
    if (AGGREGATION == AGG_PER_PAIR && PAIRS == PAIRS_REFERENCE) {
        // Camera-outer order: each camera's parameters are loaded once for all planes.
        let npix = params.pixel_count;
        var p = 0u;
        for (var i = 0u; i < params.cameras; i++) {
            if (i == ref_index) {
                continue;
            }
            let cam = cameras[i];
            let in_cam = cam_ray(cam, ray);
            for (var z = 0u; z < batch.plane_count; z++) {
                if (costed(batch.first_plane + z, needed)) {
                    let cost = pair_cost_at(cam, z, ray, pix, in_cam, r);
                    cost_slab[(z * CHANNELS + p) * npix + pix] = cost;
                }
            }
            p += 1u;
        }
        return;
    }
    for (var z = 0u; z < batch.plane_count; z++) {
        let k = batch.first_plane + z;
        if (costed(k, needed)) {
            score_plane(gid.xy, pix, z, ray, r.colour, r.word, r.across, r.along);
        }
    }
}
