//! TOSCA `.vert` / `.tri` pairs (the original TOSCA distribution's format).
//!
//! `NAME.vert` holds one vertex per line, `x y z`; `NAME.tri` one triangle per line, three
//! **1-based** vertex indices. Both are whitespace-separated text; indices written as
//! integral floats (`1.0000000e+00`, as MATLAB writes them) are accepted. Either file may be
//! gzip-compressed.

use std::io::Write;

use super::report::{check_face, check_vertex, MeshFormat, MeshReport, Parts};
use super::text::{
    capped_capacity, gunzip_if_needed, parse_f64, parse_usize, parse_xyz, show, tokens, Lines,
};
use super::{Mesh, MeshError};

/// Parses the vertices of a `.vert` file (plain or gzip-compressed).
///
/// ```
/// use shapeforest::mesh::parse_vert;
/// assert_eq!(parse_vert(b"0 0 0\n1 2 3\n").unwrap(), vec![[0.0; 3], [1.0, 2.0, 3.0]]);
/// ```
pub fn parse_vert(bytes: &[u8]) -> Result<Vec<[f64; 3]>, MeshError> {
    let bytes = gunzip_if_needed(bytes)?;
    let mut vertices = Vec::with_capacity(capped_capacity(usize::MAX, bytes.len(), 6));
    for (line, text) in Lines::new(&bytes) {
        let p = parse_xyz(line, text)?;
        check_vertex(vertices.len(), p).map_err(|e| e.at_line(line))?;
        vertices.push(p);
    }
    Ok(vertices)
}

/// Parses the triangles of a `.tri` file (1-based, plain or gzip-compressed) into 0-based
/// triangles, checking them against `n_vertices`.
///
/// ```
/// use shapeforest::mesh::parse_tri;
/// assert_eq!(parse_tri(b"1 2 3\n", 3).unwrap(), vec![[0, 1, 2]]);
/// assert!(parse_tri(b"1 2 4\n", 3).is_err());
/// ```
pub fn parse_tri(bytes: &[u8], n_vertices: usize) -> Result<Vec<[usize; 3]>, MeshError> {
    let bytes = gunzip_if_needed(bytes)?;
    let mut faces = Vec::with_capacity(capped_capacity(usize::MAX, bytes.len(), 6));
    for (line, text) in Lines::new(&bytes) {
        let mut tri = [0usize; 3];
        let mut found = 0;
        for tok in tokens(text).take(3) {
            tri[found] = parse_one_based(tok)
                .ok_or_else(|| MeshError::parse_at(line, "a 1-based vertex index", show(tok)))?;
            found += 1;
        }
        if found < 3 {
            return Err(MeshError::parse_at(line, "3 vertex indices", found.to_string()));
        }
        check_face(faces.len(), tri, n_vertices).map_err(|e| e.at_line(line))?;
        faces.push(tri);
    }
    Ok(faces)
}

/// A 1-based index token (integer or integral float) as a 0-based index.
fn parse_one_based(tok: &[u8]) -> Option<usize> {
    let i = match parse_usize(tok) {
        Some(i) => i,
        None => {
            let x = parse_f64(tok)?;
            if x.fract() != 0.0 || !(1.0..9.007_199_254_740_992e15).contains(&x) {
                return None;
            }
            x as usize
        }
    };
    i.checked_sub(1)
}

/// Parses a TOSCA pair from memory. Errors name the part they come from as `<vert data>` or
/// `<tri data>` (reading from files names the files themselves).
///
/// ```
/// use shapeforest::mesh::parse_tosca;
/// let (mesh, _) = parse_tosca(b"0 0 0\n1 0 0\n0 1 0\n", b"1 2 3\n").unwrap();
/// assert_eq!(mesh.faces, vec![[0, 1, 2]]);
/// ```
pub fn parse_tosca(vert: &[u8], tri: &[u8]) -> Result<(Mesh, MeshReport), MeshError> {
    let vertices = parse_vert(vert).map_err(|e| e.in_file("<vert data>".as_ref()))?;
    let faces = parse_tri(tri, vertices.len()).map_err(|e| e.in_file("<tri data>".as_ref()))?;
    Parts { vertices, faces, format: MeshFormat::Tosca, notes: Vec::new() }
        .finish(&crate::limits::Limits::default())
}

/// Writes `mesh` as a TOSCA pair: vertices to `vert`, 1-based triangles to `tri`.
/// Coordinates use the shortest representation that reads back to the same `f64`.
///
/// ```
/// use shapeforest::mesh::{parse_tosca, write_tosca, Mesh};
/// let m = Mesh::new(vec![[0.5, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], vec![[0, 1, 2]]).unwrap();
/// let (mut vert, mut tri) = (Vec::new(), Vec::new());
/// write_tosca(&m, &mut vert, &mut tri).unwrap();
/// assert_eq!(parse_tosca(&vert, &tri).unwrap().0, m);
/// ```
pub fn write_tosca<V: Write, T: Write>(mesh: &Mesh, mut vert: V, mut tri: T) -> Result<(), MeshError> {
    for p in &mesh.vertices {
        writeln!(vert, "{:?} {:?} {:?}", p[0], p[1], p[2])?;
    }
    for f in &mesh.faces {
        writeln!(tri, "{} {} {}", f[0] + 1, f[1] + 1, f[2] + 1)?;
    }
    vert.flush()?;
    tri.flush()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matlab_style_indices_are_accepted() {
        let f = parse_tri(b"1.0000000e+00 2.0000000e+00 3.0000000e+00\n", 3).unwrap();
        assert_eq!(f, vec![[0, 1, 2]]);
        assert!(parse_tri(b"1.5 2 3\n", 3).is_err());
    }

    #[test]
    fn errors_name_the_part_and_line() {
        let e = parse_tosca(b"0 0 0\n1 0 0\n0 1 0\n", b"1 2 3\n0 1 2\n").unwrap_err();
        assert_eq!(e.to_string(), "<tri data>: line 2: expected a 1-based vertex index, found \"0\"");
        let e = parse_tosca(b"0 0 0\n1 0\n", b"1 2 3\n").unwrap_err();
        assert_eq!(e.to_string(), "<vert data>: line 2: expected 3 coordinates, found 2");
        let e = parse_tosca(b"0 0 0\n1 0 0\n0 1 0\n", b"").unwrap_err();
        assert_eq!(e.to_string(), "a point cloud needs at least 4 points, this one has 3");
    }
}
