// The matching cost's bindings and functions shared by `cost.wgsl` (the costs into the cost
// slab) and `cost_rows.wgsl` (the costs summed along rows in workgroup memory): build.rs
// prepends this file to both (the stage registry's `prelude`). CPU twin: src/sweep/cpu/cost.rs.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> batch: Batch;
@group(0) @binding(2) var<uniform> cameras: array<Camera, MAX_RIG_CAMERAS>;
@group(0) @binding(3) var<storage, read> images: array<u32>;
@group(0) @binding(4) var<storage, read> rays: array<vec4<f32>>;
// Per reference row and tile (SweepPlan::shader_plane_ranges; coarse to fine): xy the planes
// its pixels sweep, zw the planes the pixels whose windows reach it sweep. A pixel costs only
// its tile's zw planes; the slab texels it skips are read only by windows of pixels that do
// not sweep that plane, which aggregate.wgsl does not score.
@group(0) @binding(6) var<storage, read> plane_ranges: array<vec4<u32>>;
// The fine sweep's base surface per pixel (inverse depth, plane spacing; refine_base.wgsl),
// read in its batches (`batch.refine`) only.
@group(0) @binding(7) var<storage, read> hypotheses: array<vec2<f32>>;

// Ray parameter of hypothesis z of the batch at pixel `pix`: on the batch's plane, or in the
// fine sweep around the pixel's base surface.
fn hypothesis_depth(z: u32, ray: vec3<f32>, pix: u32) -> f32 {
    if (batch.refine != 0u) {
        return refine_depth(hypotheses[pix], batch.first_plane + z);
    }
    return plane_depth(batch.planes[z], ray);
}

// Whether plane k is costed at a pixel whose tile needs planes `needed` (every hypothesis of
// the fine sweep is).
fn costed(k: u32, needed: vec2<u32>) -> bool {
    return batch.refine != 0u || (k >= needed.x && k <= needed.y);
}

// The reference's colour as a camera's bilinear sample at `pixel` sees it, in the fine sweep
// (CPU twin `refine::MatchedReference`): smoothed along x by [v, 1 - 2v, v], v =
// PHASE_SMOOTHING fx (1 - fx), and along y alike; `across` and `along` are the reference's
// second differences at the pixel (edge texels repeated).
fn matched_colour(ref_colour: vec3<f32>, across: vec3<f32>, along: vec3<f32>, pixel: vec2<f32>) -> vec3<f32> {
    if (batch.refine == 0u) {
        return ref_colour;
    }
    let f = pixel - floor(pixel);
    return ref_colour + PHASE_SMOOTHING * (f.x * (1.0 - f.x) * across + f.y * (1.0 - f.y) * along);
}

// The four texels around a sample that `inside` accepted (row-major indices in the camera's
// image) and its weights (CPU twin: `Bilinear` in cpu/common.rs).
struct Bilinear {
    i00: u32,
    i10: u32,
    i01: u32,
    i11: u32,
    f: vec2<f32>,
}
fn bilinear_at(cam: Camera, pixel: vec2<f32>) -> Bilinear {
    let base = floor(pixel);
    let x0 = u32(base.x);
    let y0 = u32(base.y);
    let x1 = min(x0 + 1u, cam.size.x - 1u);
    let y1 = min(y0 + 1u, cam.size.y - 1u);
    let w = cam.size.x;
    return Bilinear(y0 * w + x0, y0 * w + x1, y1 * w + x0, y1 * w + x1, pixel - base);
}
fn texel_at(cam: Camera, i: u32) -> vec3<f32> {
    let texel = unpack4x8unorm(images[cam.size.z + i]);
    if (params.colour_in_alpha != 0u) {
        // Prefiltered images (sweep/prefilter.rs): the colour term compares the alpha byte.
        return vec3<f32>(texel.a * 255.0);
    }
    return texel.rgb * 255.0;
}
fn texel(cam: Camera, x: u32, y: u32) -> vec3<f32> {
    return texel_at(cam, y * cam.size.x + x);
}
fn sample_bilinear(cam: Camera, pixel: vec2<f32>) -> vec3<f32> {
    let b = bilinear_at(cam, pixel);
    let top = mix(texel_at(cam, b.i00), texel_at(cam, b.i10), b.f.x);
    let bottom = mix(texel_at(cam, b.i01), texel_at(cam, b.i11), b.f.x);
    return mix(top, bottom, b.f.y);
}

fn tssd(a: vec3<f32>, b: vec3<f32>) -> f32 {
    let d = a - b;
    return min(params.tau, dot(d, d));
}

// Census words (sweep/census.rs): after every camera's pixels in `images`.
const CENSUS_BITS: f32 = 24.0;
fn census_word(cam: Camera, i: u32) -> u32 {
    return images[params.census_offset + cam.size.z + i];
}
// The word of the texel nearest to a sample.
fn census_nearest(cam: Camera, pixel: vec2<f32>) -> u32 {
    let x = min(u32(floor(pixel.x + 0.5)), cam.size.x - 1u);
    let y = min(u32(floor(pixel.y + 0.5)), cam.size.y - 1u);
    return census_word(cam, y * cam.size.x + x);
}
// Hamming distance of `word` to the words around a sample, interpolated bilinearly as the
// colours are (so the cost changes smoothly from plane to plane).
fn census_distance(cam: Camera, pixel: vec2<f32>, word: u32) -> f32 {
    let b = bilinear_at(cam, pixel);
    let h00 = f32(countOneBits(census_word(cam, b.i00) ^ word));
    let h10 = f32(countOneBits(census_word(cam, b.i10) ^ word));
    let h01 = f32(countOneBits(census_word(cam, b.i01) ^ word));
    let h11 = f32(countOneBits(census_word(cam, b.i11) ^ word));
    let top = h00 + (h10 - h00) * b.f.x;
    let bottom = h01 + (h11 - h01) * b.f.x;
    return top + (bottom - top) * b.f.y;
}
// The cost (COST_*) of a census distance and a colour pair's TSSD.
fn mixed_cost(tssd_cost: f32, census_bits: f32) -> f32 {
    let census_cost = census_bits * (params.tau / CENSUS_BITS);
    if (params.cost == COST_CENSUS) {
        return census_cost;
    }
    return 0.5 * (tssd_cost + census_cost);
}
// The cost of the reference pixel (colour, census word) against camera `cam` at `pixel`.
fn reference_pair_cost(ref_colour: vec3<f32>, ref_word: u32, cam: Camera, pixel: vec2<f32>) -> f32 {
    let t = tssd(ref_colour, sample_bilinear(cam, pixel));
    if (params.cost == COST_TSSD) {
        return t;
    }
    return mixed_cost(t, census_distance(cam, pixel, ref_word));
}

// The reference pixel's colour, census word and (the fine sweep's matched reference) second
// differences along and across rows; zeros with a virtual reference.
struct RefPixel {
    colour: vec3<f32>,
    word: u32,
    across: vec3<f32>,
    along: vec3<f32>,
}
fn reference_pixel(x: u32, y: u32) -> RefPixel {
    var r = RefPixel(vec3<f32>(0.0), 0u, vec3<f32>(0.0), vec3<f32>(0.0));
    let ref_index = params.reference;
    if (ref_index == NO_CAMERA) {
        return r;
    }
    let ref_cam = cameras[ref_index];
    r.colour = texel(ref_cam, x, y);
    if (batch.refine != 0u) {
        let last = ref_cam.size.xy - vec2<u32>(1u);
        let left = texel(ref_cam, max(x, 1u) - 1u, y);
        let right = texel(ref_cam, min(x + 1u, last.x), y);
        let up = texel(ref_cam, x, max(y, 1u) - 1u);
        let down = texel(ref_cam, x, min(y + 1u, last.y));
        r.across = left + right - 2.0 * r.colour;
        r.along = up + down - 2.0 * r.colour;
    }
    if (params.cost != COST_TSSD) {
        r.word = census_word(ref_cam, y * ref_cam.size.x + x);
    }
    return r;
}

// A reference pixel's ray in a camera's frame and the reference's centre there: a point at
// depth d on the ray is `ray * d + offset`, three multiply-adds per plane.
struct CamRay {
    ray: vec3<f32>,
    offset: vec3<f32>,
}
fn cam_ray(cam: Camera, ray: vec3<f32>) -> CamRay {
    let in_cam = vec3<f32>(dot(cam.row0.xyz, ray), dot(cam.row1.xyz, ray), dot(cam.row2.xyz, ray));
    return CamRay(in_cam, vec3<f32>(cam.row0.w, cam.row1.w, cam.row2.w));
}

// The cost of reference pair (reference, `cam`) at hypothesis `z` of the batch for the pixel
// `pix` on `ray` (`in_cam`: the same in the camera's frame); INVALID where the camera does not
// see the point.
fn pair_cost_at(cam: Camera, z: u32, ray: vec3<f32>, pix: u32, in_cam: CamRay, r: RefPixel) -> f32 {
    let depth = hypothesis_depth(z, ray, pix);
    if (depth > 0.0) {
        let projected = project_in_cam(cam, in_cam.ray * depth + in_cam.offset);
        if (projected.z > 0.0 && inside(cam, projected.xy)) {
            let matched = matched_colour(r.colour, r.across, r.along, projected.xy);
            return reference_pair_cost(matched, r.word, cam, projected.xy);
        }
    }
    return INVALID;
}
