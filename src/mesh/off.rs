//! OFF (Geomview Object File Format) reading and writing.
//!
//! Accepted input:
//! - a header keyword `OFF` with the optional prefixes of the Geomview spec (`ST`, `C`, `N`,
//!   e.g. `COFF`, `NOFF`, `CNOFF`); the keyword itself may be absent; the counts `V F [E]`
//!   may follow on the same line (`OFF 8 12 0`) or on the next;
//! - one vertex per line: the first three numbers are `x y z`, anything after them (normals,
//!   colours, texture coordinates) is ignored;
//! - one face per line: `n i1 … in`, 0-based, with anything after the indices (a face
//!   colour) ignored; polygons with `n > 3` are split into triangle fans `(i1, ik, ik+1)`;
//! - `#` comments anywhere and blank lines.
//!
//! Binary OFF and 4-D / n-D OFF are rejected with [`MeshError::Unsupported`].
//! The writer prints coordinates in Rust's shortest round-trip form, so a write-then-read
//! reproduces every coordinate bit for bit.

use std::io::Write;

use super::report::{check_vertex, push_fan, MeshFormat, MeshReport, MeshWarning, Parts};
use super::text::{capped_capacity, gunzip_if_needed, parse_usize, parse_xyz, show, tokens, Lines};
use super::{Mesh, MeshError};
use crate::limits::Limits;

/// Parses OFF data (plain or gzip-compressed) into a mesh and a report.
///
/// ```
/// use shapeforest::mesh::parse_off;
/// let (mesh, report) = parse_off(b"OFF\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n").unwrap();
/// assert_eq!(mesh.faces, vec![[0, 1, 2], [0, 2, 3]]);
/// assert_eq!(report.warnings.len(), 1); // the quad was triangulated
/// ```
pub fn parse_off(bytes: &[u8]) -> Result<(Mesh, MeshReport), MeshError> {
    off_parts(bytes)?.finish(&Limits::default())
}

/// The vertices, faces and notes of OFF data, before the mesh is built.
pub(crate) fn off_parts(bytes: &[u8]) -> Result<Parts, MeshError> {
    let bytes = gunzip_if_needed(bytes)?;
    let bytes = &bytes[..];
    let mut lines = Lines::new(bytes);

    // Header keyword, maybe followed by the counts.
    let Some((header_line, header)) = lines.next() else {
        return Err(MeshError::Truncated { expected: "an OFF header".into(), found: "an empty file".into() });
    };
    let mut header_tokens = tokens(header).peekable();
    let first = header_tokens.peek().copied().unwrap_or_default();
    let mut count_tokens: Vec<&[u8]> = Vec::new();
    let counts_line;
    if first.ends_with(b"OFF") {
        check_keyword(header_line, first)?;
        header_tokens.next();
        if let Some(&next) = header_tokens.peek() {
            if next.eq_ignore_ascii_case(b"BINARY") {
                return Err(MeshError::Unsupported { what: "binary OFF".into() }.at_line(header_line));
            }
        }
        count_tokens.extend(header_tokens);
        if count_tokens.is_empty() {
            let Some((line, counts)) = lines.next() else {
                return Err(MeshError::Truncated {
                    expected: "the counts line `V F E`".into(),
                    found: "the end of the file".into(),
                });
            };
            count_tokens.extend(tokens(counts));
            counts_line = line;
        } else {
            counts_line = header_line;
        }
    } else if parse_usize(first).is_some() {
        // The keyword is optional in the Geomview spec.
        count_tokens.extend(header_tokens);
        counts_line = header_line;
    } else {
        return Err(MeshError::parse_at(header_line, "an OFF header such as `OFF` or `COFF`", show(first)));
    }
    let (n_vertices, n_faces) = match (count_tokens.first(), count_tokens.get(1)) {
        (Some(v), Some(f)) => match (parse_usize(v), parse_usize(f)) {
            (Some(v), Some(f)) => (v, f),
            _ => {
                let found = String::from_utf8_lossy(&count_tokens.join(&b' ')).into_owned();
                return Err(MeshError::parse_at(
                    counts_line,
                    "vertex and face counts `V F E`",
                    show(found.as_bytes()),
                ));
            }
        },
        _ => {
            return Err(MeshError::parse_at(
                counts_line,
                "vertex and face counts `V F E`",
                format!("{} number(s)", count_tokens.len()),
            ))
        }
    };

    // "0 0 0\n" is the shortest vertex line, "3 0 1 2\n" the shortest face line.
    let mut vertices = Vec::with_capacity(capped_capacity(n_vertices, bytes.len(), 6));
    for i in 0..n_vertices {
        let Some((line, text)) = lines.next() else {
            return Err(MeshError::Truncated {
                expected: format!("{n_vertices} vertices"),
                found: i.to_string(),
            });
        };
        let p = parse_xyz(line, text)?;
        check_vertex(i, p).map_err(|e| e.at_line(line))?;
        vertices.push(p);
    }

    let mut faces = Vec::with_capacity(capped_capacity(n_faces, bytes.len(), 8));
    let mut polygon: Vec<usize> = Vec::new();
    let (mut polygons, mut polygon_triangles) = (0, 0);
    for i in 0..n_faces {
        let Some((line, text)) = lines.next() else {
            return Err(MeshError::Truncated { expected: format!("{n_faces} faces"), found: i.to_string() });
        };
        let mut toks = tokens(text);
        let n_tok = toks.next().unwrap_or_default();
        let n = parse_usize(n_tok)
            .ok_or_else(|| MeshError::parse_at(line, "a face's vertex count", show(n_tok)))?;
        if n < 3 {
            return Err(MeshError::parse_at(
                line,
                "a face with at least 3 vertices",
                format!("{n} vertices"),
            ));
        }
        polygon.clear();
        for tok in toks.by_ref().take(n) {
            let index =
                parse_usize(tok).ok_or_else(|| MeshError::parse_at(line, "a vertex index", show(tok)))?;
            polygon.push(index);
        }
        if polygon.len() < n {
            return Err(MeshError::parse_at(line, format!("{n} vertex indices"), polygon.len().to_string()));
        }
        let added = push_fan(&mut faces, &polygon, Some(n_vertices)).map_err(|e| e.at_line(line))?;
        if n > 3 {
            polygons += 1;
            polygon_triangles += added;
        }
    }

    let mut notes = Vec::new();
    if polygons > 0 {
        notes.push(MeshWarning::PolygonsTriangulated { polygons, triangles: polygon_triangles });
    }
    Ok(Parts { vertices, faces, format: MeshFormat::Off, notes })
}

/// Accepts `[ST][C][N]OFF`; rejects 4-D and n-D variants by name.
fn check_keyword(line: usize, keyword: &[u8]) -> Result<(), MeshError> {
    let mut prefix = &keyword[..keyword.len() - 3];
    if prefix.contains(&b'4') || prefix.contains(&b'n') {
        return Err(
            MeshError::Unsupported { what: format!("{} (4-D or n-D OFF)", show(keyword)) }.at_line(line)
        );
    }
    for opt in [&b"ST"[..], b"C", b"N"] {
        if let Some(rest) = prefix.strip_prefix(opt) {
            prefix = rest;
        }
    }
    if prefix.is_empty() {
        Ok(())
    } else {
        Err(MeshError::parse_at(line, "an OFF header such as `OFF` or `COFF`", show(keyword)))
    }
}

/// Writes `mesh` as ascii OFF. Coordinates use the shortest representation that reads back
/// to the same `f64`.
///
/// ```
/// use shapeforest::mesh::{parse_off, write_off, Mesh};
/// let m = Mesh::new(vec![[0.1, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 1e-300]], vec![[0, 1, 2]]).unwrap();
/// let mut out = Vec::new();
/// write_off(&m, &mut out).unwrap();
/// assert_eq!(parse_off(&out).unwrap().0, m);
/// ```
pub fn write_off<W: Write>(mesh: &Mesh, mut w: W) -> Result<(), MeshError> {
    writeln!(w, "OFF")?;
    writeln!(w, "{} {} 0", mesh.vertices.len(), mesh.faces.len())?;
    for p in &mesh.vertices {
        writeln!(w, "{:?} {:?} {:?}", p[0], p[1], p[2])?;
    }
    for f in &mesh.faces {
        writeln!(w, "3 {} {} {}", f[0], f[1], f[2])?;
    }
    w.flush()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn err(text: &str) -> MeshError {
        parse_off(text.as_bytes()).unwrap_err()
    }

    #[test]
    fn header_variants() {
        let body = "3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
        for header in ["OFF\n", "COFF\n", "NOFF\n", "CNOFF\n", "STOFF\n", "# c\nOFF # x\n", ""] {
            let (m, _) = parse_off(format!("{header}{body}").as_bytes()).unwrap();
            assert_eq!(m.faces, vec![[0, 1, 2]], "header {header:?}");
        }
        let (m, _) = parse_off(b"OFF 3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n").unwrap();
        assert_eq!(m.n_vertices(), 3);
        let (m, _) = parse_off(b"OFF\n3 1\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n").unwrap();
        assert_eq!(m.n_faces(), 1);
    }

    #[test]
    fn colours_and_extra_columns_are_ignored() {
        let text =
            "COFF\n3 1 0\n0 0 0 255 0 0 255\n1 0 0 0 255 0 255\n0 1 0 0 0 255 255\n3 0 1 2 0.5 0.5 0.5\n";
        let (m, _) = parse_off(text.as_bytes()).unwrap();
        assert_eq!(m.vertices, vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    }

    #[test]
    fn messages_name_the_line_and_the_problem() {
        assert_eq!(
            err("OFF\n2 1 0\n0 0 0\n1 0\n3 0 1 0\n").to_string(),
            "line 4: expected 3 coordinates, found 2"
        );
        assert_eq!(err("OFF\n1 0 0\n0 0 x\n").to_string(), "line 3: expected a number, found \"x\"");
        assert_eq!(
            err("OFF\n2 1 0\n0 0 0\n1 0 nan\n").to_string(),
            "line 4: vertex 1 has a NaN or infinite coordinate"
        );
        assert_eq!(
            err("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n").to_string(),
            "line 6: face 0 refers to vertex 7, but the mesh has 3 vertices"
        );
        assert_eq!(
            err("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 1\n").to_string(),
            "line 6: face 0 repeats a vertex: [0, 1, 1]"
        );
        assert_eq!(
            err("OFF\n3 2 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n").to_string(),
            "the file ends early: expected 2 faces, found 1"
        );
        assert_eq!(
            err("OFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n").to_string(),
            "a point cloud needs at least 4 points, this one has 3"
        );
        assert_eq!(
            err("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n2 0 1\n").to_string(),
            "line 6: expected a face with at least 3 vertices, found 2 vertices"
        );
        assert_eq!(
            err("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n4 0 1 2\n").to_string(),
            "line 6: expected 4 vertex indices, found 3"
        );
        assert_eq!(err("OFF BINARY\n").to_string(), "line 1: binary OFF is not supported");
        assert!(err("4OFF\n").to_string().contains("not supported"));
        assert_eq!(
            err("PLY\n").to_string(),
            "line 1: expected an OFF header such as `OFF` or `COFF`, found \"PLY\""
        );
        assert_eq!(err("").to_string(), "the file ends early: expected an OFF header, found an empty file");
        assert_eq!(err("OFF\n0 0 0\n").to_string(), "empty mesh: 0 vertices, 0 faces");
    }

    #[test]
    fn huge_declared_counts_fail_fast_without_allocating() {
        let e = err("OFF\n999999999999 1 0\n");
        assert_eq!(e.to_string(), "the file ends early: expected 999999999999 vertices, found 0");
        let e = err("OFF\n3 999999999999999 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
        assert!(matches!(e, MeshError::Truncated { .. }), "{e}");
        let e = err("OFF\n99999999999999999999999 1 0\n");
        assert!(matches!(e.root(), MeshError::Parse { .. }), "{e}");
    }

    #[test]
    fn polygons_are_fan_triangulated() {
        let text = "OFF\n5 1 0\n0 0 0\n1 0 0\n2 1 0\n1 2 0\n0 1 0\n5 0 1 2 3 4\n";
        let (m, report) = parse_off(text.as_bytes()).unwrap();
        assert_eq!(m.faces, vec![[0, 1, 2], [0, 2, 3], [0, 3, 4]]);
        assert_eq!(report.warnings, vec![MeshWarning::PolygonsTriangulated { polygons: 1, triangles: 3 }]);
    }
}
