// Step 0 of the TSDF integration on the device for a pinhole camera, the twin of
// `pinhole_samples` and `row_weights` in src/fusion/integrate/pinhole.rs (src/fusion/gpu/
// samples.rs records it before tsdf_integrate.wgsl, which reads what it writes): each pixel's
// valid depth (finite, positive, within the depth range), its observation weight and colour.
// The weight is the squared cosine between the pixel's ray and the surface normal from its
// 4-neighbours' points (central differences, one-sided where a neighbour is invalid or across a
// depth step of at least the truncation distance), at least `min_weight`, times the caller's
// weight of the pixel where given (none where that is not finite and positive). Floats arrive
// and leave as bits (WGSL may assume floats are never NaN): NaN marks an invalid depth and a
// pixel without weight, as the host's samples do.

struct SampleParams {
    width: u32,
    height: u32,
    // 1 when `colour` holds the frame's colour image (RGBA8 packed), else 0.
    has_colour: u32,
    // 1 when `weights` holds the caller's weight of each pixel, else 0.
    has_weights: u32,
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
    truncation_m: f32,
    min_depth_m: f32,
    max_depth_m: f32,
    min_weight: f32,
}

// The CPU integrator's `PixelSample`, as tsdf_integrate.wgsl's `Sample` reads it.
struct OutSample {
    depth_bits: u32,
    weight_bits: u32,
    rgb: u32,
}

@group(0) @binding(0) var<uniform> params: SampleParams;
@group(0) @binding(1) var<storage, read> depth: array<u32>;
@group(0) @binding(2) var<storage, read> colour: array<u32>;
@group(0) @binding(3) var<storage, read> weights: array<u32>;
@group(0) @binding(4) var<storage, read_write> samples: array<OutSample>;

const NAN_BITS: u32 = 0x7fc00000u;

fn finite_bits(bits: u32) -> bool {
    return (bits & 0x7fffffffu) < 0x7f800000u;
}

// The depth of pixel (col, row) where it is valid, -1 where not or outside the image.
fn valid_depth(col: i32, row: i32) -> f32 {
    if (col < 0 || row < 0 || col >= i32(params.width) || row >= i32(params.height)) {
        return -1.0;
    }
    let bits = depth[u32(row) * params.width + u32(col)];
    if (!finite_bits(bits)) {
        return -1.0;
    }
    let d = bitcast<f32>(bits);
    if (d > 0.0 && d >= params.min_depth_m && d <= params.max_depth_m) {
        return d;
    }
    return -1.0;
}

// Whether a neighbour's depth `n` is valid and within the truncation distance of `d`.
fn near(n: f32, d: f32) -> bool {
    return n > 0.0 && abs(n - d) < params.truncation_m;
}

@compute @workgroup_size(64)
fn make_samples(
    @builtin(workgroup_id) group: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) lane: u32,
) {
    let i = (group.x + group.y * groups.x) * 64u + lane;
    if (i >= params.width * params.height) {
        return;
    }
    let col = i32(i % params.width);
    let row = i32(i / params.width);
    var out: OutSample;
    out.depth_bits = NAN_BITS;
    out.weight_bits = NAN_BITS;
    out.rgb = 0u;
    if (params.has_colour != 0u) {
        out.rgb = colour[i];
    }
    let d = valid_depth(col, row);
    if (d <= 0.0) {
        samples[i] = out;
        return;
    }
    out.depth_bits = bitcast<u32>(d);
    // The rays (z = 1) of the pixel and its neighbours, as the host makes them.
    let x = (f32(col) - params.cx) / params.fx;
    let y = (f32(row) - params.cy) / params.fy;
    let x_left = (f32(col - 1) - params.cx) / params.fx;
    let x_right = (f32(col + 1) - params.cx) / params.fx;
    let y_up = (f32(row - 1) - params.cy) / params.fy;
    let y_down = (f32(row + 1) - params.cy) / params.fy;
    let left = valid_depth(col - 1, row);
    let right = valid_depth(col + 1, row);
    let up = valid_depth(col, row - 1);
    let down = valid_depth(col, row + 1);
    // A neighbour's point where it is near, the pixel's own elsewhere.
    let centre = vec3<f32>(x, y, 1.0) * d;
    let p_left = select(centre, vec3<f32>(x_left, y, 1.0) * left, near(left, d));
    let p_right = select(centre, vec3<f32>(x_right, y, 1.0) * right, near(right, d));
    let p_up = select(centre, vec3<f32>(x, y_up, 1.0) * up, near(up, d));
    let p_down = select(centre, vec3<f32>(x, y_down, 1.0) * down, near(down, d));
    let has_both = (near(left, d) || near(right, d)) && (near(up, d) || near(down, d));
    let normal_dir = cross(p_right - p_left, p_down - p_up);
    let length2 = dot(normal_dir, normal_dir);
    if (!has_both || !(length2 > 0.0) || !finite_bits(bitcast<u32>(length2))) {
        samples[i] = out;
        return;
    }
    let normal = normal_dir * (1.0 / sqrt(length2));
    let ray = vec3<f32>(x, y, 1.0);
    let cosine = abs(dot(normal, ray)) / length(ray);
    var weight = max(cosine * cosine, params.min_weight);
    if (params.has_weights != 0u) {
        let bits = weights[i];
        let given = bitcast<f32>(bits);
        if (!finite_bits(bits) || !(given > 0.0)) {
            samples[i] = out;
            return;
        }
        weight = weight * given;
    }
    out.weight_bits = bitcast<u32>(weight);
    samples[i] = out;
}
