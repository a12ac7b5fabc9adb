// TSDF integration, the GPU twin of step 2 of src/fusion/integrate.rs (`View::update_block`):
// one workgroup per 8x8x8 block, one invocation per row of eight voxels along x. Step 0 (each
// pixel's valid depth, cos² observation weight and colour, `samples`) comes from
// tsdf_samples.wgsl before it for a pinhole camera, from the host for a distorted one; the host
// (src/fusion/gpu.rs) makes step 1 (the blocks to update and their pool slots, `work`) with the
// CPU's own code; camera.wgsl (prepended) projects with the camera's distortion.

struct TsdfParams {
    // The depth map's camera: rows unused (voxels arrive in its frame), size.xy its pixels.
    camera: Camera,
    // The camera-frame step of one voxel along the world's x, y and z (xyz).
    step_x: vec4<f32>,
    step_y: vec4<f32>,
    step_z: vec4<f32>,
    truncation_m: f32,
    inv_truncation: f32,
    max_weight: f32,
    // 1 when the frame has a colour image.
    colour: u32,
    // Entries of `work`.
    items: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

// One pixel as step 0 made it (the CPU integrator's `PixelSample`, uploaded as it is): the
// depth and the observation weight as bits, NaN where invalid or none (WGSL may assume floats
// are never NaN, so they are tested as integers: `finite_or`), the colour packed RGBA8.
struct Sample {
    depth_bits: u32,
    weight_bits: u32,
    rgb: u32,
}

// The float of `bits`, or `fallback` where they are a NaN or an infinity.
fn finite_or(bits: u32, fallback: f32) -> f32 {
    if ((bits & 0x7fffffffu) >= 0x7f800000u) {
        return fallback;
    }
    return bitcast<f32>(bits);
}

// Pixel i's depth, 0 where invalid.
fn depth_of(i: u32) -> f32 {
    return finite_or(samples[i].depth_bits, 0.0);
}

// A block to update: its voxel (0, 0, 0) in the camera frame (made in f64 on the host, as the
// CPU does), and its slot in the pool.
struct Work {
    origin: vec3<f32>,
    slot: u32,
}

@group(0) @binding(0) var<uniform> tsdf: TsdfParams;
@group(0) @binding(1) var<storage, read> samples: array<Sample>;
@group(0) @binding(2) var<storage, read> work: array<Work>;
@group(0) @binding(3) var<storage, read_write> pool: array<PoolVoxel>;
@group(0) @binding(4) var<storage, read_write> updated: array<u32>;

const TSDF_BLOCK_SIDE: u32 = 8u;
const TSDF_BLOCK_VOXELS: u32 = 512u;
const TSDF_NO_PIXEL: u32 = 0xffffffffu;

var<workgroup> block_updates: atomic<u32>;

// What `sample_depth` found: a depth and the nearest pixel, TSDF_NO_PIXEL where none.
struct DepthSample {
    depth_m: f32,
    pixel: u32,
}

// `View::sample_depth`: the depth at a pixel position (bilinear where the four pixels around
// are valid and agree within the truncation distance, else the nearest pixel's) and the
// nearest pixel's index; none outside the image or where the nearest pixel is invalid.
fn sample_depth(u: f32, v: f32) -> DepthSample {
    let none = DepthSample(0.0, TSDF_NO_PIXEL);
    let width = tsdf.camera.size.x;
    let height = tsdf.camera.size.y;
    let w = f32(width);
    let h = f32(height);
    if (!(u >= -0.5 && v >= -0.5 && u < w - 0.5 && v < h - 0.5)) {
        return none;
    }
    let nearest = min(u32(v + 0.5), height - 1u) * width + min(u32(u + 0.5), width - 1u);
    // The pixel up and left: floor(u) + 1 for u > -1, as the CPU's cast.
    let u1 = u32(u + 1.0);
    let v1 = u32(v + 1.0);
    if (u1 >= 1u && v1 >= 1u && u1 < width && v1 < height) {
        let i = (v1 - 1u) * width + (u1 - 1u);
        let d0 = depth_of(i);
        let d1 = depth_of(i + 1u);
        let d2 = depth_of(i + width);
        let d3 = depth_of(i + width + 1u);
        let lo = min(min(d0, d1), min(d2, d3));
        let hi = max(max(d0, d1), max(d2, d3));
        if (lo > 0.0 && hi - lo < tsdf.truncation_m) {
            let fu = u - f32(u1 - 1u);
            let fv = v - f32(v1 - 1u);
            let top = d0 + (d1 - d0) * fu;
            let bottom = d2 + (d3 - d2) * fu;
            return DepthSample(top + (bottom - top) * fv, nearest);
        }
    }
    let d = depth_of(nearest);
    if (d > 0.0) {
        return DepthSample(d, nearest);
    }
    return none;
}

// `running_colour` of src/fusion/blocks.rs for one channel: the rounded 8.8 mean.
fn colour_mean(fixed: u32, count: f32, rcp: f32, observed: u32) -> u32 {
    return min(u32((f32(fixed) * count + f32(observed) * 256.0) * rcp + 0.5), 65535u);
}

// One observation of a voxel: the capped running averages of `Voxel::observe_tsdf` and,
// near the surface, `Voxel::observe_colour`.
fn observe(index: u32, sdf: f32, sample: Sample, weight: f32) {
    var voxel = pool[index];
    let observed = min(sdf * tsdf.inv_truncation, 1.0);
    let total = voxel.weight + weight;
    voxel.tsdf = (voxel.tsdf * voxel.weight + observed * weight) / total;
    voxel.weight = min(total, tsdf.max_weight);
    if (tsdf.colour != 0u && abs(sdf) < tsdf.truncation_m) {
        let count = f32(voxel.b_count >> 16u);
        let rcp = 1.0 / (count + 1.0);
        let r = colour_mean(voxel.rg & 0xffffu, count, rcp, sample.rgb & 0xffu);
        let g = colour_mean(voxel.rg >> 16u, count, rcp, (sample.rgb >> 8u) & 0xffu);
        let b = colour_mean(voxel.b_count & 0xffffu, count, rcp, (sample.rgb >> 16u) & 0xffu);
        let cap = clamp(tsdf.max_weight, 1.0, 65535.0);
        let counted = u32(min(count + 1.0, cap));
        voxel.rg = r | (g << 16u);
        voxel.b_count = b | (counted << 16u);
    }
    pool[index] = voxel;
}

@compute @workgroup_size(64)
fn integrate(
    @builtin(workgroup_id) group: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) lane: u32,
) {
    // Blocks beyond 65535 continue along y (the dispatch's x is capped).
    let item = group.x + group.y * groups.x;
    if (item >= tsdf.items) {
        return;
    }
    let block = work[item];
    let y = lane % TSDF_BLOCK_SIDE;
    let z = lane / TSDF_BLOCK_SIDE;
    // The CPU's order of operations, so that lavapipe's f32 arithmetic gives its points.
    let row = block.origin + tsdf.step_y.xyz * f32(y) + tsdf.step_z.xyz * f32(z);
    let first = block.slot * TSDF_BLOCK_VOXELS + TSDF_BLOCK_SIDE * (y + TSDF_BLOCK_SIDE * z);
    var count = 0u;
    for (var x = 0u; x < TSDF_BLOCK_SIDE; x++) {
        let point = row + tsdf.step_x.xyz * f32(x);
        let projected = project_in_cam(tsdf.camera, point);
        if (projected.z <= 0.0) {
            continue;
        }
        let seen = sample_depth(projected.x, projected.y);
        if (seen.pixel == TSDF_NO_PIXEL) {
            continue;
        }
        let sdf = seen.depth_m - point.z;
        if (sdf < -tsdf.truncation_m) {
            continue;
        }
        let sample = samples[seen.pixel];
        let weight = finite_or(sample.weight_bits, -1.0);
        if (!(weight > 0.0)) {
            continue;
        }
        observe(first + x, sdf, sample, weight);
        count += 1u;
    }
    atomicAdd(&block_updates, count);
    workgroupBarrier();
    if (lane == 0u) {
        updated[item] = atomicLoad(&block_updates);
    }
}
