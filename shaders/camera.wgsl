// A camera and its projection with lens distortion, prepended (before common.wgsl) to every
// sweep stage by build.rs, and to fusion's tsdf_integrate.wgsl by src/fusion/gpu.rs.
// Keep `Camera` in sync with src/sweep/gpu_types.rs (GpuCamera) and src/fusion/gpu.rs.

const DIST_NONE: u32 = 0u;
const DIST_PLUMB_BOB: u32 = 1u;
const DIST_EQUIDISTANT: u32 = 2u;

// Overridable by a pipeline (src/sweep/stages.rs names the stages that set it): without
// distortion the compiler drops the distortion's code.
override DISTORTED: bool = true;      // some camera has lens distortion

struct Camera {
    // cam_from_ref: rows of the rotation in xyz, translation (metres) in w.
    row0: vec4<f32>,
    row1: vec4<f32>,
    row2: vec4<f32>,
    intrinsics: vec4<f32>,   // fx, fy, cx, cy (pixels)
    dist_a: vec4<f32>,       // plumb_bob: k1 k2 p1 p2; equidistant: k1 k2 k3 k4
    dist_b: vec4<f32>,       // plumb_bob: k3 in x; both: y = the largest (x/z)² + (y/z)² of the model's monotonic branch
    size: vec4<u32>,         // width, height, offset of pixel (0,0) in the image buffer, distortion model
    info: vec4<u32>,         // half (HALF_*), is_reference, 0, 0
}

// Projects a point in the camera's frame: pixel (xy) and depth (z), or z <= 0 when it is behind
// the camera or past the distortion model's fold (common.wgsl's `project` from the reference
// frame).
fn project_in_cam(cam: Camera, p: vec3<f32>) -> vec3<f32> {
    if (p.z <= 1e-6) {
        return vec3<f32>(0.0, 0.0, -1.0);
    }
    var n = p.xy / p.z;
    let model = select(DIST_NONE, cam.size.w, DISTORTED);
    // Past the distortion model's fold the point would land back in the image: not seen.
    if (model != DIST_NONE && dot(n, n) > cam.dist_b.y) {
        return vec3<f32>(0.0, 0.0, -1.0);
    }
    if (model == DIST_PLUMB_BOB) {
        let r2 = dot(n, n);
        let radial = 1.0 + r2 * (cam.dist_a.x + r2 * (cam.dist_a.y + r2 * cam.dist_b.x));
        let xy = n.x * n.y;
        n = vec2<f32>(
            n.x * radial + 2.0 * cam.dist_a.z * xy + cam.dist_a.w * (r2 + 2.0 * n.x * n.x),
            n.y * radial + cam.dist_a.z * (r2 + 2.0 * n.y * n.y) + 2.0 * cam.dist_a.w * xy,
        );
    } else if (model == DIST_EQUIDISTANT) {
        let r = length(n);
        if (r > 1e-12) {
            let theta = atan(r);
            let t2 = theta * theta;
            let theta_d = theta * (1.0 + t2 * (cam.dist_a.x + t2 * (cam.dist_a.y + t2 * (cam.dist_a.z + t2 * cam.dist_a.w))));
            n = n * (theta_d / r);
        }
    }
    return vec3<f32>(
        cam.intrinsics.x * n.x + cam.intrinsics.z,
        cam.intrinsics.y * n.y + cam.intrinsics.w,
        p.z,
    );
}
