//! The mesh as a binary little-endian PLY (Turk, 1994): vertices `x y z` (float) with
//! `red green blue` (uchar), faces as `list uchar int`, as MeshLab, Blender and Open3D read it.

use std::io::{self, Write};
use std::path::Path;

use super::BlockMesh;

/// Writes `mesh` (from [`super::Mesh::collect`]) as a binary PLY. Vertices without a colour
/// are written grey; a mesh of more than `i32::MAX` vertices or with an index past its
/// vertices is refused (`InvalidInput`).
pub fn write_ply<W: Write>(mesh: &BlockMesh, out: W) -> io::Result<()> {
    let vertices = mesh.vertices.len();
    if i32::try_from(vertices).is_err() {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("{vertices} vertices do not fit PLY's int indices"),
        ));
    }
    if let Some(bad) = mesh
        .triangles
        .iter()
        .flatten()
        .find(|&&i| i as usize >= vertices)
    {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("a triangle refers to vertex {bad} of {vertices}"),
        ));
    }
    let mut out = io::BufWriter::new(out);
    write!(
        out,
        "ply\nformat binary_little_endian 1.0\ncomment sweepdepth fusion mesh\n\
         element vertex {vertices}\nproperty float x\nproperty float y\nproperty float z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\n\
         element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.triangles.len()
    )?;
    for (i, p) in mesh.vertices.iter().enumerate() {
        for c in p {
            out.write_all(&c.to_le_bytes())?;
        }
        out.write_all(&mesh.colours.get(i).copied().unwrap_or([128; 3]))?;
    }
    for t in &mesh.triangles {
        out.write_all(&[3])?;
        for &i in t {
            out.write_all(&(i as i32).to_le_bytes())?;
        }
    }
    out.flush()
}

/// [`write_ply`] into a file at `path`, whole or not at all: written beside it as
/// `<path>.partial` and moved into place when complete (a full disk leaves the file that was
/// there, and no half-written mesh).
pub fn write_ply_file(mesh: &BlockMesh, path: &Path) -> io::Result<()> {
    let mut partial = path.as_os_str().to_os_string();
    partial.push(".partial");
    let partial = std::path::PathBuf::from(partial);
    let written = std::fs::File::create(&partial)
        .and_then(|file| {
            let mut out = io::BufWriter::new(file);
            write_ply(mesh, &mut out)?;
            out.into_inner().map_err(|e| e.into_error())?.sync_all()
        })
        .and_then(|()| std::fs::rename(&partial, path));
    if written.is_err() {
        let _ = std::fs::remove_file(&partial);
    }
    written
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(bytes: &[u8]) -> (Vec<String>, &[u8]) {
        let marker = b"end_header\n";
        let end = bytes
            .windows(marker.len())
            .position(|w| w == marker)
            .unwrap()
            + marker.len();
        let header = std::str::from_utf8(&bytes[..end])
            .unwrap()
            .lines()
            .map(str::to_string)
            .collect();
        (header, &bytes[end..])
    }

    #[test]
    fn binary_ply_header_counts_and_bytes_match_the_mesh() {
        let mesh = BlockMesh {
            vertices: vec![
                [0.0, 0.0, 1.0],
                [1.0, 0.0, 1.0],
                [0.0, 1.0, 1.0],
                [1.0, 1.0, 1.5],
            ],
            colours: vec![[255, 0, 0], [0, 255, 0], [0, 0, 255], [9, 8, 7]],
            triangles: vec![[0, 1, 2], [1, 3, 2]],
        };
        let mut bytes = Vec::new();
        write_ply(&mesh, &mut bytes).unwrap();
        let (header, body) = parse(&bytes);
        assert_eq!(header[0], "ply");
        assert_eq!(header[1], "format binary_little_endian 1.0");
        assert!(header.contains(&"element vertex 4".to_string()));
        assert!(header.contains(&"element face 2".to_string()));
        assert!(header.contains(&"property list uchar int vertex_indices".to_string()));
        assert_eq!(body.len(), 4 * (3 * 4 + 3) + 2 * (1 + 3 * 4));
        // The fourth vertex, then the second face, read back.
        let v3 = &body[3 * 15..4 * 15];
        let z = f32::from_le_bytes(v3[8..12].try_into().unwrap());
        assert_eq!(z, 1.5);
        assert_eq!(&v3[12..15], &[9, 8, 7]);
        let f1 = &body[4 * 15 + 13..];
        assert_eq!(f1[0], 3);
        let idx: Vec<i32> = f1[1..]
            .chunks_exact(4)
            .map(|c| i32::from_le_bytes(c.try_into().unwrap()))
            .collect();
        assert_eq!(idx, vec![1, 3, 2]);
    }

    #[test]
    fn a_triangle_past_the_vertices_is_refused() {
        let mesh = BlockMesh {
            vertices: vec![[0.0; 3]; 2],
            colours: vec![[0; 3]; 2],
            triangles: vec![[0, 1, 2]],
        };
        let err = write_ply(&mesh, Vec::new()).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::InvalidInput);
    }
}
