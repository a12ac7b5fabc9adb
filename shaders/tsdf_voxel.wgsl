// The voxel pool's entries, shared by tsdf_integrate.wgsl and tsdf_mesh.wgsl (the host,
// src/fusion/gpu.rs, prepends this file to both): a voxel as `Voxel` keeps it, the colour in
// 8.8 fixed point, red and green in `rg` (red low), blue and the colour count in `b_count`
// (blue low).
struct PoolVoxel {
    tsdf: f32,
    weight: f32,
    rg: u32,
    b_count: u32,
}
