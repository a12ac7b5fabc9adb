//! Marching cubes on the device (issue 56), the twin of [`crate::fusion::Mesh`]'s per-block
//! meshing: `shaders/tsdf_mesh.wgsl` meshes each listed block straight from the voxel pool
//! (one workgroup per block), so a map integrated on the GPU is meshed without reading its
//! voxels back; only the triangles come back. Each block's mesh is the CPU's, vertex for
//! vertex and triangle for triangle (the vertices' positions and colours to the device's
//! float rounding).

use bytemuck::{Pod, Zeroable};

use super::device::{compute_pipeline, dispatch_items, make_buffer, read_buffer, submit};
use super::{entry, GpuFusionError, GpuTsdf, Grown};
use crate::fusion::blocks::BlockIndex;
use crate::fusion::tables::{CORNERS, EDGE_CORNERS, EDGE_TABLE, TRI_TABLE};
use crate::fusion::{BlockMesh, Mesh, MeshStats};

/// The shader: the pool's voxel and the meshing.
const SHADER: &str = concat!(
    include_str!("../../../shaders/tsdf_voxel.wgsl"),
    "\n",
    include_str!("../../../shaders/tsdf_mesh.wgsl")
);

/// `tsdf_mesh.wgsl`'s `MESH_NO_SLOT`.
const NO_SLOT: u32 = u32::MAX;

/// WGSL `MeshParams`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct MeshUniform {
    voxel_size_m: f32,
    items: u32,
    vertex_room: u32,
    triangle_room: u32,
}

/// WGSL `MeshWork`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct MeshWork {
    first: [i32; 3],
    pad: u32,
    slots: [u32; 8],
}

/// WGSL `MeshVertex`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct MeshVertex {
    position: [f32; 3],
    rgb: u32,
}

/// WGSL `BlockOut`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct BlockOut {
    vertex_first: u32,
    vertices: u32,
    triangle_first: u32,
    triangles: u32,
}

/// The tables of `tables.rs` as the shader reads them: EDGE_TABLE, TRI_TABLE four bytes to a
/// word (-1 as 255), each edge's lower corner (bits x, y, z) and axis (bits 4-5), each
/// corner's offset (bits x, y, z).
fn table_words() -> Vec<u32> {
    let mut words: Vec<u32> = EDGE_TABLE.iter().map(|&e| u32::from(e)).collect();
    for row in &TRI_TABLE {
        for four in row.chunks_exact(4) {
            words.push(
                four.iter()
                    .enumerate()
                    .map(|(i, &e)| u32::from(e as u8) << (8 * i))
                    .sum(),
            );
        }
    }
    let bits = |c: [usize; 3]| (c[0] | (c[1] << 1) | (c[2] << 2)) as u32;
    for [a, b] in EDGE_CORNERS {
        let (lo, hi) = if CORNERS[a] < CORNERS[b] {
            (CORNERS[a], CORNERS[b])
        } else {
            (CORNERS[b], CORNERS[a])
        };
        let axis = (0..3).find(|&k| hi[k] != lo[k]).unwrap_or(0) as u32;
        words.push(bits(lo) | (axis << 4));
    }
    words.extend(CORNERS.map(bits));
    words
}

/// The meshing pipeline and its buffers, made at the first [`GpuTsdf::mesh_blocks`].
pub(super) struct Mesher {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    uniform: wgpu::Buffer,
    tables: wgpu::Buffer,
    work: Grown,
    vertices: Grown,
    triangles: Grown,
    blocks_out: Grown,
    totals: wgpu::Buffer,
}

impl Mesher {
    fn new(device: &wgpu::Device, queue: &wgpu::Queue) -> Result<Self, GpuFusionError> {
        use super::device::Binding::{Read, ReadWrite, Uniform};
        let (pipeline, layout) = compute_pipeline(
            device,
            "tsdf_mesh",
            SHADER,
            "mesh",
            &[
                Uniform, Read, Read, Read, ReadWrite, ReadWrite, ReadWrite, ReadWrite,
            ],
        )?;
        let words = table_words();
        let tables = make_buffer(
            device,
            "tsdf mesh tables",
            std::mem::size_of_val(words.as_slice()) as u64,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        );
        queue.write_buffer(&tables, 0, bytemuck::cast_slice(&words));
        let out = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC;
        Ok(Self {
            pipeline,
            layout,
            uniform: make_buffer(
                device,
                "tsdf mesh params",
                std::mem::size_of::<MeshUniform>() as u64,
                wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            ),
            tables,
            work: Grown::new(
                device,
                "tsdf mesh work",
                wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            ),
            vertices: Grown::new(device, "tsdf mesh vertices", out),
            triangles: Grown::new(device, "tsdf mesh triangles", out),
            blocks_out: Grown::new(device, "tsdf mesh blocks", out),
            totals: make_buffer(
                device,
                "tsdf mesh totals",
                8,
                out | wgpu::BufferUsages::COPY_DST,
            ),
        })
    }
}

/// What one dispatch made: per work item its vertices and triangles, or the room it needs.
enum Pass {
    Done(Vec<BlockMesh>),
    /// Vertices and triangles the outputs must hold.
    Needs(u64, u64),
}

impl GpuTsdf {
    /// Brings `mesh` up to date with this map: the blocks changed and dropped since the last
    /// call ([`GpuTsdf::take_unmeshed`], [`Mesh::take_changes`]) meshed here from the voxels
    /// where they are. When the device fails, the blocks it was to mesh come back with the
    /// error (the caller meshes them on the CPU: `Mapper::update_mesh`).
    pub fn update_mesh(
        &mut self,
        mesh: &mut Mesh,
    ) -> Result<MeshStats, (Vec<BlockIndex>, GpuFusionError)> {
        let todo = mesh.take_changes(self.take_unmeshed(), |index| self.contains(index));
        match self.mesh_blocks(&todo) {
            Ok(meshes) => Ok(mesh.apply(meshes, todo.len())),
            Err(e) => Err((todo, e)),
        }
    }

    /// Meshes `todo` on the device, each block as [`crate::fusion::Mesh`] meshes it on the CPU
    /// (its cubes reach into the blocks above it); a block not in the grid meshes empty. In
    /// `todo`'s order.
    pub fn mesh_blocks(
        &mut self,
        todo: &[BlockIndex],
    ) -> Result<Vec<(BlockIndex, BlockMesh)>, GpuFusionError> {
        if self.mesher.is_none() {
            self.mesher = Some(Mesher::new(&self.device, &self.queue)?);
        }
        let slot = |index: BlockIndex| self.slots.get(&index).copied();
        let mut listed: Vec<(usize, MeshWork)> = Vec::new();
        for (i, index) in todo.iter().enumerate() {
            if slot(*index).is_none() {
                continue;
            }
            let slots = std::array::from_fn(|n| {
                let n = n as i32;
                slot(index.offset([n & 1, (n >> 1) & 1, (n >> 2) & 1])).unwrap_or(NO_SLOT)
            });
            let first = index.first_voxel().map(|v| v as i32);
            listed.push((
                i,
                MeshWork {
                    first,
                    pad: 0,
                    slots,
                },
            ));
        }
        let mut out: Vec<(BlockIndex, BlockMesh)> = todo
            .iter()
            .map(|index| (*index, BlockMesh::default()))
            .collect();
        let work: Vec<MeshWork> = listed.iter().map(|(_, w)| *w).collect();
        let meshes = self.mesh_work(&work)?;
        for ((i, _), mesh) in listed.iter().zip(meshes) {
            out[*i].1 = mesh;
        }
        Ok(out)
    }

    /// The meshes of `work`, in pieces whose outputs fit the adapter's largest buffer.
    fn mesh_work(&mut self, work: &[MeshWork]) -> Result<Vec<BlockMesh>, GpuFusionError> {
        if work.is_empty() {
            return Ok(Vec::new());
        }
        let vertex_bytes = std::mem::size_of::<MeshVertex>() as u64;
        loop {
            match self.mesh_pass(work)? {
                Pass::Done(meshes) => return Ok(meshes),
                Pass::Needs(vertices, triangles) => {
                    let fits =
                        vertices * vertex_bytes <= self.limit && triangles * 12 <= self.limit;
                    if !fits && work.len() > 1 {
                        let (a, b) = work.split_at(work.len() / 2);
                        let mut meshes = self.mesh_work(a)?;
                        meshes.extend(self.mesh_work(b)?);
                        return Ok(meshes);
                    }
                    if !fits {
                        return Err(GpuFusionError::Gpu(format!(
                            "one block's mesh ({vertices} vertices) exceeds the adapter's \
                             largest buffer ({} bytes)",
                            self.limit
                        )));
                    }
                    let (device, limit) = (&self.device, self.limit);
                    let Some(mesher) = self.mesher.as_mut() else {
                        return Err(GpuFusionError::Gpu("internal: no mesher".into()));
                    };
                    mesher
                        .vertices
                        .reserve(device, vertices * vertex_bytes, limit);
                    mesher.triangles.reserve(device, triangles * 12, limit);
                }
            }
        }
    }

    /// One dispatch over `work`: its meshes, or the room they need when the outputs are too
    /// small (then nothing is read back).
    fn mesh_pass(&mut self, work: &[MeshWork]) -> Result<Pass, GpuFusionError> {
        let (device, limit) = (&self.device, self.limit);
        let Some(mesher) = self.mesher.as_mut() else {
            return Err(GpuFusionError::Gpu("internal: no mesher".into()));
        };
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let out_bytes = (work.len() * std::mem::size_of::<BlockOut>()) as u64;
        mesher
            .work
            .reserve(device, std::mem::size_of_val(work) as u64, limit);
        mesher.blocks_out.reserve(device, out_bytes, limit);
        let vertex_room = mesher.vertices.buffer.size() / std::mem::size_of::<MeshVertex>() as u64;
        let triangle_room = mesher.triangles.buffer.size() / 12;
        let uniform = MeshUniform {
            voxel_size_m: self.params.voxel_size_m,
            items: work.len() as u32,
            vertex_room: vertex_room.min(u64::from(u32::MAX)) as u32,
            triangle_room: triangle_room.min(u64::from(u32::MAX)) as u32,
        };
        self.queue
            .write_buffer(&mesher.uniform, 0, bytemuck::bytes_of(&uniform));
        self.queue
            .write_buffer(&mesher.work.buffer, 0, bytemuck::cast_slice(work));
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("tsdf mesh"),
            layout: &mesher.layout,
            entries: &[
                entry(0, &mesher.uniform),
                entry(1, &mesher.work.buffer),
                entry(2, &self.pool),
                entry(3, &mesher.tables),
                entry(4, &mesher.vertices.buffer),
                entry(5, &mesher.triangles.buffer),
                entry(6, &mesher.blocks_out.buffer),
                entry(7, &mesher.totals),
            ],
        });
        let readback = make_buffer(
            device,
            "tsdf mesh readback",
            8 + out_bytes,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        );
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("tsdf mesh"),
        });
        encoder.clear_buffer(&mesher.totals, 0, None);
        let items = work.len() as u32;
        dispatch_items(
            &mut encoder,
            "tsdf mesh",
            &mesher.pipeline,
            &bind_group,
            items,
        );
        encoder.copy_buffer_to_buffer(&mesher.totals, 0, &readback, 0, 8);
        encoder.copy_buffer_to_buffer(&mesher.blocks_out.buffer, 0, &readback, 8, out_bytes);
        let submitted = submit(&self.queue, encoder.finish());
        if let Some(error) = futures::executor::block_on(scope.pop()) {
            return Err(GpuFusionError::Gpu(format!("meshing: {error}")));
        }
        let words: Vec<u32> = read_buffer(device, submitted, &readback, 8 + out_bytes)?;
        let (totals, blocks) = words.split_at(2);
        let (vertices, triangles) = (u64::from(totals[0]), u64::from(totals[1]));
        if vertices > vertex_room || triangles > triangle_room {
            return Ok(Pass::Needs(vertices, triangles));
        }
        let blocks: &[BlockOut] = bytemuck::cast_slice(blocks);
        // The outputs, as far as they were filled.
        let vertex_bytes = vertices * std::mem::size_of::<MeshVertex>() as u64;
        let triangle_bytes = triangles * 12;
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("tsdf mesh readback"),
        });
        let outputs = make_buffer(
            device,
            "tsdf mesh outputs",
            (vertex_bytes + triangle_bytes).max(4),
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        );
        if vertex_bytes > 0 {
            encoder.copy_buffer_to_buffer(&mesher.vertices.buffer, 0, &outputs, 0, vertex_bytes);
        }
        if triangle_bytes > 0 {
            let (from, to) = (&mesher.triangles.buffer, vertex_bytes);
            encoder.copy_buffer_to_buffer(from, 0, &outputs, to, triangle_bytes);
        }
        let submitted = submit(&self.queue, encoder.finish());
        let bytes = (vertex_bytes + triangle_bytes).max(4);
        let words: Vec<u32> = read_buffer(device, submitted, &outputs, bytes)?;
        let (vertex_words, triangle_words) = words.split_at((vertex_bytes / 4) as usize);
        let all_vertices: &[MeshVertex] = bytemuck::cast_slice(vertex_words);
        let all_triangles: &[[u32; 3]] =
            bytemuck::cast_slice(&triangle_words[..(triangles * 3) as usize]);
        let meshes = blocks
            .iter()
            .map(|b| {
                let span = |first: u32, n: u32| first as usize..first as usize + n as usize;
                let (vs, ts) = (
                    span(b.vertex_first, b.vertices),
                    span(b.triangle_first, b.triangles),
                );
                let (Some(vs), Some(ts)) = (all_vertices.get(vs), all_triangles.get(ts)) else {
                    return BlockMesh::default();
                };
                BlockMesh {
                    vertices: vs.iter().map(|v| v.position).collect(),
                    colours: vs
                        .iter()
                        .map(|v| [v.rgb as u8, (v.rgb >> 8) as u8, (v.rgb >> 16) as u8])
                        .collect(),
                    triangles: ts.to_vec(),
                }
            })
            .collect();
        Ok(Pass::Done(meshes))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shader parses and validates (naga, as wgpu does), and its structs are laid out as
    /// the host's.
    #[test]
    fn the_meshing_shader_validates_with_the_hosts_layouts() {
        let module = super::super::tests::validated(SHADER, "shaders/tsdf_mesh.wgsl");
        let size = |name: &str| {
            let (_, t) = module
                .types
                .iter()
                .find(|(_, t)| t.name.as_deref() == Some(name))
                .unwrap_or_else(|| panic!("{name}"));
            t.inner.size(module.to_ctx()) as usize
        };
        assert_eq!(size("MeshParams"), std::mem::size_of::<MeshUniform>());
        assert_eq!(size("MeshWork"), std::mem::size_of::<MeshWork>());
        assert_eq!(size("MeshVertex"), std::mem::size_of::<MeshVertex>());
        assert_eq!(size("BlockOut"), std::mem::size_of::<BlockOut>());
        // The table offsets the shader reads at.
        assert_eq!(table_words().len(), 256 + 1024 + 12 + 8);
    }
}
