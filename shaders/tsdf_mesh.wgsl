// Marching cubes over TSDF blocks on the device, the GPU twin of src/fusion/mesh.rs
// (`mesh_block`): one workgroup per block, one invocation per row of eight cubes along x. The
// block's mesh is the CPU's, vertex for vertex and triangle for triangle: a vertex is made by
// the first cube (in z, y, x order) that reads its edge, in the order of that cube's edges, as
// the CPU's loop makes them; triangles come in the CPU's order too. The host
// (src/fusion/gpu/mesh.rs) lists the blocks with their neighbours' pool slots and uploads the
// tables of src/fusion/tables.rs.

struct MeshParams {
    voxel_size_m: f32,
    // Entries of `work`.
    items: u32,
    // Room in `vertices` and in `triangles` (triangles); what does not fit is counted only.
    vertex_room: u32,
    triangle_room: u32,
}

// A block to mesh: the global index of its voxel (0, 0, 0), and the pool slots of itself and
// of the seven blocks above it (+x, +y, +x+y, +z, +x+z, +y+z, +x+y+z), MESH_NO_SLOT where
// missing.
struct MeshWork {
    first: vec3<i32>,
    pad0: u32,
    slots: array<u32, 8>,
}

// A vertex: world position in metres, colour packed RGB8 (red low).
struct MeshVertex {
    position: vec3<f32>,
    rgb: u32,
}

// Where a block's vertices and triangles went, and how many.
struct BlockOut {
    vertex_first: u32,
    vertices: u32,
    triangle_first: u32,
    triangles: u32,
}

@group(0) @binding(0) var<uniform> mesh_params: MeshParams;
@group(0) @binding(1) var<storage, read> work: array<MeshWork>;
@group(0) @binding(2) var<storage, read> pool: array<PoolVoxel>;
// EDGE_TABLE (256 words), TRI_TABLE (256 x 16 bytes, four to a word, 255 ends a case), each
// edge's lower corner (bits x, y, z) and axis (bits 4-5), each corner's offset (bits x, y, z).
@group(0) @binding(3) var<storage, read> tables: array<u32>;
@group(0) @binding(4) var<storage, read_write> vertices: array<MeshVertex>;
@group(0) @binding(5) var<storage, read_write> triangles: array<u32>;
@group(0) @binding(6) var<storage, read_write> blocks_out: array<BlockOut>;
// Vertices and triangles handed out so far.
@group(0) @binding(7) var<storage, read_write> totals: array<atomic<u32>, 2>;

const MESH_NO_SLOT: u32 = 0xffffffffu;
const MESH_SIDE: u32 = 9u;
// A voxel never observed, or in a missing block (the CPU's NaN).
const MESH_UNSEEN: f32 = 3.0e38;
// A cube with a corner unseen (the CPU's case 0 for it; it makes nothing and owns nothing).
const MESH_MISSING: u32 = 256u;
const TRI_AT: u32 = 256u;
const EDGES_AT: u32 = 1280u;
const CORNERS_AT: u32 = 1292u;

// The 9x9x9 TSDF the block's cubes read (x fastest), MESH_UNSEEN where unseen.
var<workgroup> field: array<f32, 729>;
// Each cube's case (x fastest), MESH_MISSING where a corner is unseen.
var<workgroup> cases: array<u32, 512>;
// The block's vertex on each edge, by ((z * 9 + y) * 9 + x) * 3 + axis of its lower end.
var<workgroup> edge_vertex: array<u32, 2187>;
// Per row of cubes: its vertices and triangles, then where they begin in the block.
var<workgroup> row_vertices: array<u32, 64>;
var<workgroup> row_triangles: array<u32, 64>;
// The block's first vertex and triangle in the outputs.
var<workgroup> block_bases: vec2<u32>;

// The pool voxel at (x, y, z), each in 0..=8 (8: the first layer of the block above), of
// work item `item`; MESH_NO_SLOT's voxel where that block is missing.
fn voxel_index(item: u32, x: u32, y: u32, z: u32) -> u32 {
    let which = (x / 8u) | ((y / 8u) << 1u) | ((z / 8u) << 2u);
    let slot = work[item].slots[which];
    if (slot == MESH_NO_SLOT) {
        return MESH_NO_SLOT;
    }
    return slot * 512u + (x % 8u) + 8u * ((y % 8u) + 8u * (z % 8u));
}

fn field_at(x: u32, y: u32, z: u32) -> f32 {
    return field[x + MESH_SIDE * (y + MESH_SIDE * z)];
}

// The case of a cube (its lowest corner in the block), MESH_MISSING for one outside the block.
fn case_at(x: i32, y: i32, z: i32) -> u32 {
    if (x < 0 || y < 0 || z < 0 || x > 7 || y > 7 || z > 7) {
        return MESH_MISSING;
    }
    return cases[u32(x + 8 * (y + 8 * z))];
}

// Whether the cube at (x, y, z) makes the vertex of its edge `edge`: no cube before it in the
// CPU's order (z, y, x) holds that edge with every corner seen. The cubes holding an edge lie
// below its lower end along the two other axes; of them, the one below along both comes
// first, then the one below along the later axis, then along the earlier one.
fn owns(x: u32, y: u32, z: u32, edge: u32) -> bool {
    let info = tables[EDGES_AT + edge];
    let axis = info >> 4u;
    let low = vec3<i32>(i32(x + (info & 1u)), i32(y + ((info >> 1u) & 1u)), i32(z + ((info >> 2u) & 1u)));
    // The two other axes, earlier first, as unit steps.
    var early = vec3<i32>(1, 0, 0);
    var late = vec3<i32>(0, 0, 1);
    if (axis == 0u) {
        early = vec3<i32>(0, 1, 0);
    } else if (axis == 2u) {
        late = vec3<i32>(0, 1, 0);
    }
    let mine = vec3<i32>(i32(x), i32(y), i32(z));
    // Unrolled (a local array indexed in a loop is slow on some drivers).
    let c0 = low - early - late;
    if (all(c0 == mine)) {
        return true;
    }
    if (case_at(c0.x, c0.y, c0.z) < MESH_MISSING) {
        return false;
    }
    let c1 = low - late;
    if (all(c1 == mine)) {
        return true;
    }
    if (case_at(c1.x, c1.y, c1.z) < MESH_MISSING) {
        return false;
    }
    let c2 = low - early;
    if (all(c2 == mine)) {
        return true;
    }
    return case_at(c2.x, c2.y, c2.z) >= MESH_MISSING;
}

// TRI_TABLE[case][k], 255 for the CPU's -1.
fn tri_entry(case_index: u32, k: u32) -> u32 {
    let at = case_index * 16u + k;
    return (tables[TRI_AT + at / 4u] >> (8u * (at % 4u))) & 0xffu;
}

fn triangle_count(case_index: u32) -> u32 {
    var n = 0u;
    for (var k = 0u; k < 5u; k += 1u) {
        if (tri_entry(case_index, 3u * k) == 255u) {
            break;
        }
        n += 1u;
    }
    return n;
}

// The slot of the vertex on `edge` of the cube at (x, y, z): its lower end and axis.
fn edge_key(x: u32, y: u32, z: u32, edge: u32) -> u32 {
    let info = tables[EDGES_AT + edge];
    let lx = x + (info & 1u);
    let ly = y + ((info >> 1u) & 1u);
    let lz = z + ((info >> 2u) & 1u);
    return ((lz * MESH_SIDE + ly) * MESH_SIDE + lx) * 3u + (info >> 4u);
}

// `round_level` of mesh.rs: x rounded half up, for x >= 0.
fn round_level(x: f32) -> f32 {
    let whole = f32(u32(max(x, 0.0)));
    return select(whole, whole + 1.0, x - whole >= 0.5);
}

// One colour channel (8.8 fixed point, `shift` bits up in the word) of two voxels mixed at t.
fn mix_channel(lo: u32, hi: u32, shift: u32, t: f32) -> u32 {
    let c_lo = f32((lo >> shift) & 0xffffu) / 256.0;
    let c_hi = f32((hi >> shift) & 0xffffu) / 256.0;
    return u32(clamp(round_level(c_lo + (c_hi - c_lo) * t), 0.0, 255.0));
}

// The vertex on `edge` of the cube at (x, y, z) of work item `item`.
fn make_vertex(item: u32, x: u32, y: u32, z: u32, edge: u32) -> MeshVertex {
    let info = tables[EDGES_AT + edge];
    let axis = info >> 4u;
    let low = vec3<u32>(x + (info & 1u), y + ((info >> 1u) & 1u), z + ((info >> 2u) & 1u));
    let along_axis = vec3<bool>(axis == 0u, axis == 1u, axis == 2u);
    let high = low + select(vec3<u32>(0u), vec3<u32>(1u), along_axis);
    let t_lo = field_at(low.x, low.y, low.z);
    let t_hi = field_at(high.x, high.y, high.z);
    let t = clamp(t_lo / (t_lo - t_hi), 0.0, 1.0);
    let along = select(vec3<f32>(0.0), vec3<f32>(t), along_axis);
    let position = (vec3<f32>(work[item].first + vec3<i32>(low)) + along) * mesh_params.voxel_size_m;
    let v_lo = pool[voxel_index(item, low.x, low.y, low.z)];
    let v_hi = pool[voxel_index(item, high.x, high.y, high.z)];
    let r = mix_channel(v_lo.rg, v_hi.rg, 0u, t);
    let g = mix_channel(v_lo.rg, v_hi.rg, 16u, t);
    let b = mix_channel(v_lo.b_count, v_hi.b_count, 0u, t);
    return MeshVertex(position, r | (g << 8u) | (b << 16u));
}

@compute @workgroup_size(64)
fn mesh(
    @builtin(workgroup_id) group: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let item = group.x + group.y * groups.x;
    if (item >= mesh_params.items) {
        return;
    }
    // The field, 729 voxels by 64 invocations.
    for (var i = lid; i < 729u; i += 64u) {
        let x = i % MESH_SIDE;
        let y = (i / MESH_SIDE) % MESH_SIDE;
        let z = i / (MESH_SIDE * MESH_SIDE);
        let at = voxel_index(item, x, y, z);
        var t = MESH_UNSEEN;
        if (at != MESH_NO_SLOT) {
            let v = pool[at];
            if (v.weight > 0.0) {
                t = v.tsdf;
            }
        }
        field[i] = t;
    }
    workgroupBarrier();
    // This invocation's row of cubes: their cases.
    let y = lid % 8u;
    let z = lid / 8u;
    for (var x = 0u; x < 8u; x += 1u) {
        var c = 0u;
        var missing = false;
        for (var corner = 0u; corner < 8u; corner += 1u) {
            let o = tables[CORNERS_AT + corner];
            let t = field_at(x + (o & 1u), y + ((o >> 1u) & 1u), z + ((o >> 2u) & 1u));
            missing = missing || t == MESH_UNSEEN;
            c |= select(0u, 1u << corner, t < 0.0);
        }
        cases[lid * 8u + x] = select(c, MESH_MISSING, missing);
    }
    workgroupBarrier();
    // The row's vertices (the edges its cubes own) and triangles.
    var own_vertices = 0u;
    var own_triangles = 0u;
    for (var x = 0u; x < 8u; x += 1u) {
        let c = cases[lid * 8u + x];
        if (c >= MESH_MISSING) {
            continue;
        }
        let crossed = tables[c];
        if (crossed == 0u) {
            continue;
        }
        own_triangles += triangle_count(c);
        for (var edge = 0u; edge < 12u; edge += 1u) {
            if ((crossed & (1u << edge)) != 0u && owns(x, y, z, edge)) {
                own_vertices += 1u;
            }
        }
    }
    row_vertices[lid] = own_vertices;
    row_triangles[lid] = own_triangles;
    workgroupBarrier();
    // Where each row begins, and the block's room in the outputs.
    if (lid == 0u) {
        var v = 0u;
        var n = 0u;
        for (var r = 0u; r < 64u; r += 1u) {
            let rv = row_vertices[r];
            let rt = row_triangles[r];
            row_vertices[r] = v;
            row_triangles[r] = n;
            v += rv;
            n += rt;
        }
        var bases = vec2<u32>(0u, 0u);
        if (n > 0u) {
            bases = vec2<u32>(atomicAdd(&totals[0], v), atomicAdd(&totals[1], n));
        }
        block_bases = bases;
        blocks_out[item] = BlockOut(bases.x, v, bases.y, n);
    }
    workgroupBarrier();
    let bases = block_bases;
    // The row's vertices, in the CPU's order.
    var next_vertex = row_vertices[lid];
    for (var x = 0u; x < 8u; x += 1u) {
        let c = cases[lid * 8u + x];
        if (c >= MESH_MISSING) {
            continue;
        }
        let crossed = tables[c];
        for (var edge = 0u; edge < 12u; edge += 1u) {
            if ((crossed & (1u << edge)) != 0u && owns(x, y, z, edge)) {
                edge_vertex[edge_key(x, y, z, edge)] = next_vertex;
                let at = bases.x + next_vertex;
                if (at < mesh_params.vertex_room) {
                    vertices[at] = make_vertex(item, x, y, z, edge);
                }
                next_vertex += 1u;
            }
        }
    }
    workgroupBarrier();
    // The row's triangles, wound to face the free side as mesh.rs winds them.
    var next_triangle = row_triangles[lid];
    for (var x = 0u; x < 8u; x += 1u) {
        let c = cases[lid * 8u + x];
        if (c >= MESH_MISSING) {
            continue;
        }
        for (var k = 0u; k < 5u; k += 1u) {
            let e0 = tri_entry(c, 3u * k);
            if (e0 == 255u) {
                break;
            }
            let a = edge_vertex[edge_key(x, y, z, e0)];
            let b = edge_vertex[edge_key(x, y, z, tri_entry(c, 3u * k + 1u))];
            let d = edge_vertex[edge_key(x, y, z, tri_entry(c, 3u * k + 2u))];
            let at = bases.y + next_triangle;
            if (at < mesh_params.triangle_room) {
                triangles[3u * at] = a;
                triangles[3u * at + 1u] = d;
                triangles[3u * at + 2u] = b;
            }
            next_triangle += 1u;
        }
    }
}
