//! Wavefront OBJ reading and writing.
//!
//! This reader is our own rather than `tobj`'s: `tobj` renumbers vertices in the order faces
//! first use them, drops unreferenced vertices, splits the file per `o`/`g` group and (with
//! its default features) parses coordinates as `f32`. Correspondence ground truth is by
//! vertex index, so the file's vertex order and exact `f64` coordinates must be kept.
//!
//! Accepted input:
//! - `v x y z [w] [r g b]`: the first three numbers are the position, the rest is ignored;
//! - `f a b c …` with `v`, `v/vt`, `v//vn` or `v/vt/vn` references, 1-based, or negative
//!   (relative to the vertices defined so far); polygons are split into triangle fans;
//! - all objects and groups are merged into one mesh over the one global vertex list;
//! - `vt`, `vn`, `vp`, `o`, `g`, `s`, `usemtl`, `mtllib` are skipped silently; `l`, `p` and
//!   unknown statements are skipped and counted in the report;
//! - `#` comments and `\` line continuations.

use std::io::Write;

use super::report::{check_face, check_vertex, push_fan, MeshFormat, MeshReport, MeshWarning, Parts};
use super::text::{gunzip_if_needed, parse_i64, parse_xyz, show, tokens, Lines};
use super::{Mesh, MeshError};
use crate::limits::Limits;

/// Parses OBJ data (plain or gzip-compressed) into a mesh and a report.
///
/// ```
/// use shapeforest::mesh::parse_obj;
/// let obj = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1/1/1 2/2/2 3/3/3 4/4/4\n";
/// let (mesh, _) = parse_obj(obj).unwrap();
/// assert_eq!(mesh.faces, vec![[0, 1, 2], [0, 2, 3]]);
/// ```
pub fn parse_obj(bytes: &[u8]) -> Result<(Mesh, MeshReport), MeshError> {
    obj_parts(bytes)?.finish(&Limits::default())
}

/// The vertices, faces and notes of OBJ data, before the mesh is built.
pub(crate) fn obj_parts(bytes: &[u8]) -> Result<Parts, MeshError> {
    let bytes = gunzip_if_needed(bytes)?;
    let bytes = &bytes[..];
    let joined;
    // Line continuations are rare: only rewrite the data when one is present.
    let data: &[u8] = if has_continuation(bytes) {
        joined = join_continuations(bytes);
        &joined
    } else {
        bytes
    };

    let mut vertices: Vec<[f64; 3]> = Vec::new();
    let mut faces: Vec<[usize; 3]> = Vec::new();
    let mut face_lines: Vec<usize> = Vec::new();
    let mut polygon: Vec<usize> = Vec::new();
    let (mut polygons, mut polygon_triangles) = (0, 0);
    let (mut points_lines, mut unknown) = (0, 0);

    for (line, text) in Lines::new(data) {
        let mut toks = tokens(text);
        let keyword = toks.next().unwrap_or_default();
        match keyword {
            b"v" => {
                let rest = &text[1..];
                let p = parse_xyz(line, rest)?;
                check_vertex(vertices.len(), p).map_err(|e| e.at_line(line))?;
                vertices.push(p);
            }
            b"f" => {
                polygon.clear();
                for tok in toks {
                    polygon.push(parse_reference(line, tok, vertices.len())?);
                }
                if polygon.len() < 3 {
                    return Err(MeshError::parse_at(
                        line,
                        "a face with at least 3 vertices",
                        format!("{} vertices", polygon.len()),
                    ));
                }
                // Indices may point forward to vertices defined later: check at the end.
                let added = push_fan(&mut faces, &polygon, None)?;
                face_lines.extend(std::iter::repeat_n(line, added));
                if polygon.len() > 3 {
                    polygons += 1;
                    polygon_triangles += added;
                }
            }
            b"l" | b"p" => points_lines += 1,
            b"vt" | b"vn" | b"vp" | b"o" | b"g" | b"s" | b"usemtl" | b"mtllib" => {}
            _ => unknown += 1,
        }
    }

    let n = vertices.len();
    for (i, (&tri, &line)) in faces.iter().zip(&face_lines).enumerate() {
        check_face(i, tri, n).map_err(|e| e.at_line(line))?;
    }

    let mut notes = Vec::new();
    if polygons > 0 {
        notes.push(MeshWarning::PolygonsTriangulated { polygons, triangles: polygon_triangles });
    }
    if points_lines > 0 {
        notes.push(MeshWarning::Ignored {
            what: "OBJ point/line statement(s) (`p`, `l`)".into(),
            count: points_lines,
        });
    }
    if unknown > 0 {
        notes.push(MeshWarning::Ignored {
            what: "OBJ statement(s) with unknown keywords".into(),
            count: unknown,
        });
    }
    Ok(Parts { vertices, faces, format: MeshFormat::Obj, notes })
}

/// Parses one face reference `v[/vt][/vn]` into a 0-based vertex index.
fn parse_reference(line: usize, tok: &[u8], n_defined: usize) -> Result<usize, MeshError> {
    let v = tok.split(|&b| b == b'/').next().unwrap_or_default();
    let Some(i) = parse_i64(v) else {
        return Err(MeshError::parse_at(line, "a vertex reference such as `7`, `7/2` or `7//3`", show(tok)));
    };
    if i > 0 {
        usize::try_from(i - 1).map_err(|_| MeshError::parse_at(line, "a vertex index", show(tok)))
    } else if i < 0 {
        let back = i.unsigned_abs();
        if back > n_defined as u64 {
            return Err(MeshError::parse_at(
                line,
                format!("a relative vertex index within the {n_defined} vertices defined so far"),
                show(tok),
            ));
        }
        Ok(n_defined - back as usize)
    } else {
        Err(MeshError::parse_at(line, "a 1-based vertex index", show(tok)))
    }
}

fn has_continuation(bytes: &[u8]) -> bool {
    bytes.windows(2).any(|w| w == b"\\\n") || bytes.windows(3).any(|w| w == b"\\\r\n")
}

/// Joins `\`-continued lines, keeping a newline for each removed one at the end of the joined
/// line so later line numbers stay right (the joined statement reports its first line).
fn join_continuations(bytes: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(bytes.len());
    let mut pending_newlines = 0;
    let mut i = 0;
    while i < bytes.len() {
        let b = bytes[i];
        if b == b'\\' {
            let rest = &bytes[i + 1..];
            let skip = if rest.starts_with(b"\n") {
                Some(1)
            } else if rest.starts_with(b"\r\n") {
                Some(2)
            } else {
                None
            };
            if let Some(skip) = skip {
                out.push(b' ');
                pending_newlines += 1;
                i += 1 + skip;
                continue;
            }
        }
        out.push(b);
        if b == b'\n' {
            out.extend(std::iter::repeat_n(b'\n', pending_newlines));
            pending_newlines = 0;
        }
        i += 1;
    }
    out
}

/// Writes `mesh` as OBJ (`v` and `f` lines, 1-based). Coordinates use the shortest
/// representation that reads back to the same `f64`.
///
/// ```
/// use shapeforest::mesh::{parse_obj, write_obj, Mesh};
/// let m = Mesh::new(vec![[0.1, 0.2, 0.3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], vec![[0, 1, 2]]).unwrap();
/// let mut out = Vec::new();
/// write_obj(&m, &mut out).unwrap();
/// assert_eq!(parse_obj(&out).unwrap().0, m);
/// ```
pub fn write_obj<W: Write>(mesh: &Mesh, mut w: W) -> Result<(), MeshError> {
    writeln!(w, "# {} vertices, {} faces", mesh.vertices.len(), mesh.faces.len())?;
    for p in &mesh.vertices {
        writeln!(w, "v {:?} {:?} {:?}", p[0], p[1], p[2])?;
    }
    for f in &mesh.faces {
        writeln!(w, "f {} {} {}", f[0] + 1, f[1] + 1, f[2] + 1)?;
    }
    w.flush()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn err(text: &str) -> String {
        parse_obj(text.as_bytes()).unwrap_err().to_string()
    }

    #[test]
    fn vertex_order_is_kept_and_unreferenced_vertices_stay() {
        // Faces use vertices in the order 3, 1, 2; vertex 0 is unused. tobj would renumber.
        let text = "v 9 9 9\nv 0 0 0\nv 1 0 0\nv 0 1 0\ng part\nf 4 2 3\n";
        let (m, report) = parse_obj(text.as_bytes()).unwrap();
        assert_eq!(m.vertices[0], [9.0, 9.0, 9.0]);
        assert_eq!(m.faces, vec![[3, 1, 2]]);
        assert_eq!(report.warnings, vec![MeshWarning::UnreferencedVertices { count: 1, first: 0 }]);
    }

    #[test]
    fn relative_indices_and_continuations() {
        let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 \\\n -2 -1\nv 5 5 5\nf 1 2 x\n";
        let e = err(text);
        assert_eq!(e, "line 7: expected a vertex reference such as `7`, `7/2` or `7//3`, found \"x\"");
        let (m, _) = parse_obj(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 \\\r\n -2 -1\n").unwrap();
        assert_eq!(m.faces, vec![[0, 1, 2]]);
    }

    #[test]
    fn messages_name_the_line() {
        assert_eq!(err("v 0 0\n"), "line 1: expected 3 coordinates, found 2");
        assert_eq!(
            err("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n"),
            "line 4: face 0 refers to vertex 8, but the mesh has 3 vertices"
        );
        assert_eq!(err("v 0 0 0\nf 1 0 1\n"), "line 2: expected a 1-based vertex index, found \"0\"");
        assert_eq!(
            err("v 0 0 0\nf -2 1 1\n"),
            "line 2: expected a relative vertex index within the 1 vertices defined so far, found \"-2\""
        );
        assert_eq!(err("v 0 0 0\nv inf 0 0\n"), "line 2: vertex 1 has a NaN or infinite coordinate");
        assert_eq!(err("v 0 0 0\nv 1 1 1\np 1\n"), "a point cloud needs at least 4 points, this one has 2");
        assert_eq!(err("# nothing\n"), "empty mesh: 0 vertices, 0 faces");
    }

    #[test]
    fn points_lines_and_unknown_statements_are_reported() {
        let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nl 1 2\np 3\ncstype bezier\nf 1//1 2//1 3//1\n";
        let (_, report) = parse_obj(text.as_bytes()).unwrap();
        assert_eq!(report.warnings.len(), 2, "{:?}", report.warnings);
    }
}
