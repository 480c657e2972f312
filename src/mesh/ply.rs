//! PLY (Stanford polygon format) reading, via `ply-rs-bw`, and writing.
//!
//! Reading accepts ascii, binary little-endian and binary big-endian files. Only two elements
//! matter: `vertex`, whose scalar properties `x`, `y`, `z` (any numeric type) are the
//! position, and `face`, whose integer list `vertex_indices` (or `vertex_index`) holds
//! 0-based polygons, split into triangle fans. Every other property (normals, colours,
//! confidence, …) and every other element is parsed past and ignored.
//!
//! Before any payload is read, the counts in the header are checked against the number of
//! bytes that follow it, so a forged header (`element vertex 999999999999`) is reported as a
//! truncated file instead of driving a long loop or a large allocation.
//!
//! The writer emits `double` coordinates (bit-exact in binary and, through shortest
//! round-trip formatting, in ascii), `list uchar int vertex_indices` faces, and optionally
//! per-vertex `red`, `green`, `blue` (`uchar`).

use std::io::Write;

use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{
    ElementDef, Encoding, Property, PropertyAccess, PropertyAccessResult, PropertyType, ScalarType,
};

use super::error::Location;
use super::report::{check_face, check_vertex, push_fan, MeshFormat, MeshReport, MeshWarning, Parts};
use super::text::gunzip_if_needed;
use super::{Mesh, MeshError};
use crate::limits::Limits;

/// How a PLY file is encoded when written.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PlyEncoding {
    /// Human-readable text.
    Ascii,
    /// Binary, little-endian (compact and exact; the default).
    #[default]
    BinaryLittleEndian,
}

/// The face list property names this reader understands.
const FACE_LISTS: [&str; 2] = ["vertex_indices", "vertex_index"];

/// A `vertex` element: only the position is kept.
#[derive(Default)]
struct PlyVertex {
    p: [f64; 3],
}

impl PropertyAccess for PlyVertex {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        let k = match name {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            _ => return PropertyAccessResult::Ignored,
        };
        let v = match property {
            Property::Char(v) => f64::from(v),
            Property::UChar(v) => f64::from(v),
            Property::Short(v) => f64::from(v),
            Property::UShort(v) => f64::from(v),
            Property::Int(v) => f64::from(v),
            Property::UInt(v) => f64::from(v),
            Property::Float(v) => f64::from(v),
            Property::Double(v) => v,
            _ => return PropertyAccessResult::UnsupportedType,
        };
        self.p[k] = v;
        PropertyAccessResult::Set
    }
}

/// A `face` element: only the vertex list is kept.
#[derive(Default)]
struct PlyFace {
    indices: Vec<i64>,
}

impl PropertyAccess for PlyFace {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        if !FACE_LISTS.contains(&name) {
            return PropertyAccessResult::Ignored;
        }
        self.indices = match property {
            Property::ListChar(v) => v.into_iter().map(i64::from).collect(),
            Property::ListUChar(v) => v.into_iter().map(i64::from).collect(),
            Property::ListShort(v) => v.into_iter().map(i64::from).collect(),
            Property::ListUShort(v) => v.into_iter().map(i64::from).collect(),
            Property::ListInt(v) => v.into_iter().map(i64::from).collect(),
            Property::ListUInt(v) => v.into_iter().map(i64::from).collect(),
            _ => return PropertyAccessResult::UnsupportedType,
        };
        PropertyAccessResult::Set
    }
}

/// Any other element: parsed past, nothing stored (a zero-sized type, so a `Vec` of them
/// never allocates).
struct Skip;

impl PropertyAccess for Skip {
    fn new() -> Self {
        Skip
    }
}

fn scalar_size(t: &ScalarType) -> usize {
    match t {
        ScalarType::Char | ScalarType::UChar => 1,
        ScalarType::Short | ScalarType::UShort => 2,
        ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
        ScalarType::Double => 8,
    }
}

fn is_integer(t: &ScalarType) -> bool {
    !matches!(t, ScalarType::Float | ScalarType::Double)
}

/// Smallest number of bytes one element can occupy.
fn min_element_bytes(def: &ElementDef, encoding: Encoding) -> usize {
    match encoding {
        Encoding::Ascii => (2 * def.properties.len()).max(1),
        Encoding::BinaryBigEndian | Encoding::BinaryLittleEndian => def
            .properties
            .values()
            .map(|p| match &p.data_type {
                PropertyType::Scalar(t) => scalar_size(t),
                PropertyType::List(count, _) => scalar_size(count),
            })
            .sum(),
    }
}

/// Converts a `ply-rs-bw` error into ours, with its line when the data is ascii.
fn ply_error(e: ply_rs_bw::parser::ParseError, ascii: bool, def: Option<&ElementDef>) -> MeshError {
    let text = e.to_string();
    let text = match e.line() {
        Some(n) => text.strip_prefix(&format!("Line {n}: ")).unwrap_or(&text).to_string(),
        None => text,
    };
    // ply-rs appends the PEG grammar's expectation sets after "Error:": keep the readable part.
    let text = text.replace("\n\t", "; ").replace('\n', " ");
    let text = text.split("; Error:").next().unwrap_or_default().trim();
    let mut message: String = text.chars().take(200).collect();
    if message.len() < text.len() {
        message.push('…');
    }
    let err = match (e.kind(), def) {
        (std::io::ErrorKind::UnexpectedEof, Some(def)) => MeshError::Truncated {
            expected: format!("{} '{}' elements", def.count, def.name),
            found: "the end of the file".into(),
        },
        _ => MeshError::Ply { message },
    };
    match e.line() {
        Some(line) if ascii => err.at_line(line),
        _ => err,
    }
}

/// Parses PLY data (ascii or binary, plain or gzip-compressed) into a mesh and a report.
///
/// ```
/// use shapeforest::mesh::parse_ply;
/// let ply = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
///             property float z\nproperty uchar red\nelement face 1\n\
///             property list uchar int vertex_indices\nend_header\n\
///             0 0 0 255\n1 0 0 0\n0 1 0 9\n3 0 1 2\n";
/// let (mesh, _) = parse_ply(ply).unwrap();
/// assert_eq!(mesh.vertices[1], [1.0, 0.0, 0.0]);
/// assert_eq!(mesh.faces, vec![[0, 1, 2]]);
/// ```
pub fn parse_ply(bytes: &[u8]) -> Result<(Mesh, MeshReport), MeshError> {
    ply_parts(bytes)?.finish(&Limits::default())
}

/// The vertices, faces and notes of PLY data, before the mesh is built.
pub(crate) fn ply_parts(bytes: &[u8]) -> Result<Parts, MeshError> {
    let bytes = gunzip_if_needed(bytes)?;
    let mut reader = Reader::new(&bytes[..]);
    let header = Parser::<Skip>::new().read_header(&mut reader).map_err(|e| ply_error(e, true, None))?;
    let ascii = header.encoding == Encoding::Ascii;
    // Once the header has been read, the line tracker stands on the first payload line.
    let first_payload_line = reader.line();

    // Header checks: the elements we need, with usable property types.
    let vertex_def = header.elements.get("vertex").ok_or_else(|| MeshError::Parse {
        expected: "a PLY `vertex` element".into(),
        found: format!("elements {:?}", header.elements.keys().collect::<Vec<_>>()),
    })?;
    for axis in ["x", "y", "z"] {
        match vertex_def.properties.get(axis).map(|p| &p.data_type) {
            Some(PropertyType::Scalar(_)) => {}
            Some(PropertyType::List(..)) => {
                return Err(MeshError::Parse {
                    expected: format!("a scalar vertex property `{axis}`"),
                    found: "a list".into(),
                })
            }
            None => {
                return Err(MeshError::Parse {
                    expected: format!("a vertex property `{axis}`"),
                    found: format!("properties {:?}", vertex_def.properties.keys().collect::<Vec<_>>()),
                })
            }
        }
    }
    let face_def = header.elements.get("face");
    if let Some(def) = face_def {
        let list = FACE_LISTS.iter().find_map(|n| def.properties.get(*n));
        match list.map(|p| &p.data_type) {
            Some(PropertyType::List(count, item)) if is_integer(count) && is_integer(item) => {}
            Some(t) => {
                return Err(MeshError::Parse {
                    expected: "a face property `vertex_indices` that is a list of integers".into(),
                    found: format!("{t:?}"),
                })
            }
            None => {
                return Err(MeshError::Parse {
                    expected: "a face property `vertex_indices` (or `vertex_index`)".into(),
                    found: format!("properties {:?}", def.properties.keys().collect::<Vec<_>>()),
                })
            }
        }
    } else if header.elements.contains_key("tristrips") && vertex_def.count > 0 {
        return Err(MeshError::Unsupported { what: "PLY triangle strips (a `tristrips` element)".into() });
    }

    // Counts against the bytes actually present.
    let remaining = reader.get_ref().len();
    let required = header.elements.values().fold(0usize, |acc, def| {
        acc.saturating_add(def.count.saturating_mul(min_element_bytes(def, header.encoding)))
    });
    let slack = usize::from(ascii); // the last ascii line may lack its newline
    if required > remaining.saturating_add(slack) {
        let declared: Vec<String> =
            header.elements.values().map(|d| format!("{} '{}'", d.count, d.name)).collect();
        return Err(MeshError::Truncated {
            expected: format!("{} elements (at least {required} bytes)", declared.join(", ")),
            found: format!("{remaining} bytes after the header"),
        });
    }

    // Payload, element by element in header order.
    let mut vertices: Vec<[f64; 3]> = Vec::new();
    let mut raw_faces: Vec<PlyFace> = Vec::new();
    let (mut vertex_line, mut face_line) = (0, 0);
    let mut line = first_payload_line;
    let mut ignored: usize = 0;
    for def in header.elements.values() {
        let start = line;
        line = line.saturating_add(def.count);
        match def.name.as_str() {
            "vertex" => {
                vertex_line = start;
                let parsed = Parser::<PlyVertex>::new()
                    .read_payload_for_element(&mut reader, def, &header)
                    .map_err(|e| ply_error(e, ascii, Some(def)))?;
                vertices = parsed.into_iter().map(|v| v.p).collect();
            }
            "face" => {
                face_line = start;
                raw_faces = Parser::<PlyFace>::new()
                    .read_payload_for_element(&mut reader, def, &header)
                    .map_err(|e| ply_error(e, ascii, Some(def)))?;
            }
            _ => {
                ignored = ignored.saturating_add(def.count);
                // A binary element without properties occupies no bytes: nothing to read.
                if ascii || !def.properties.is_empty() {
                    Parser::<Skip>::new()
                        .read_payload_for_element(&mut reader, def, &header)
                        .map_err(|e| ply_error(e, ascii, Some(def)))?;
                }
            }
        }
    }

    let locate = |name: &str, first_line: usize, index: usize| {
        if ascii {
            Location::Line(first_line + index)
        } else {
            Location::Element { element: name.to_string(), index }
        }
    };
    for (i, &p) in vertices.iter().enumerate() {
        check_vertex(i, p).map_err(|e| e.at(locate("vertex", vertex_line, i)))?;
    }
    let n = vertices.len();
    let mut faces = Vec::with_capacity(raw_faces.len());
    let mut polygon: Vec<usize> = Vec::new();
    let (mut polygons, mut polygon_triangles) = (0, 0);
    for (k, face) in raw_faces.iter().enumerate() {
        let at = || locate("face", face_line, k);
        if face.indices.len() < 3 {
            return Err(MeshError::Parse {
                expected: "a face with at least 3 vertices".into(),
                found: format!("{} vertices", face.indices.len()),
            }
            .at(at()));
        }
        polygon.clear();
        for &i in &face.indices {
            let index = usize::try_from(i).map_err(|_| {
                MeshError::Parse { expected: "a non-negative vertex index".into(), found: i.to_string() }
                    .at(at())
            })?;
            polygon.push(index);
        }
        let first_new = faces.len();
        let added = push_fan(&mut faces, &polygon, None)?;
        for (t, tri) in faces[first_new..].iter().enumerate() {
            check_face(first_new + t, *tri, n).map_err(|e| e.at(at()))?;
        }
        if polygon.len() > 3 {
            polygons += 1;
            polygon_triangles += added;
        }
    }
    drop(raw_faces);

    let mut notes = Vec::new();
    if polygons > 0 {
        notes.push(MeshWarning::PolygonsTriangulated { polygons, triangles: polygon_triangles });
    }
    if ignored > 0 {
        let names: Vec<&str> = header
            .elements
            .values()
            .filter(|d| d.name != "vertex" && d.name != "face" && d.count > 0)
            .map(|d| d.name.as_str())
            .collect();
        notes.push(MeshWarning::Ignored {
            what: format!("PLY element(s) of kind {}", names.join(", ")),
            count: ignored,
        });
    }
    Ok(Parts { vertices, faces, format: MeshFormat::Ply, notes })
}

/// Writes `mesh` as PLY, with optional per-vertex RGB colours (one per vertex).
///
/// ```
/// use shapeforest::mesh::{parse_ply, write_ply, Mesh, PlyEncoding};
/// let m = Mesh::new(vec![[0.1, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], vec![[0, 1, 2]]).unwrap();
/// let colours = [[255, 0, 0], [0, 255, 0], [0, 0, 255]];
/// for encoding in [PlyEncoding::Ascii, PlyEncoding::BinaryLittleEndian] {
///     let mut out = Vec::new();
///     write_ply(&m, &mut out, encoding, Some(&colours)).unwrap();
///     assert_eq!(parse_ply(&out).unwrap().0, m);
/// }
/// ```
pub fn write_ply<W: Write>(
    mesh: &Mesh,
    mut w: W,
    encoding: PlyEncoding,
    vertex_colors: Option<&[[u8; 3]]>,
) -> Result<(), MeshError> {
    if let Some(c) = vertex_colors {
        if c.len() != mesh.vertices.len() {
            return Err(MeshError::ColorCountMismatch { colors: c.len(), vertices: mesh.vertices.len() });
        }
    }
    if mesh.vertices.len() > i32::MAX as usize {
        return Err(MeshError::Unsupported { what: "writing more than 2^31 - 1 vertices to PLY".into() });
    }
    let format = match encoding {
        PlyEncoding::Ascii => "ascii",
        PlyEncoding::BinaryLittleEndian => "binary_little_endian",
    };
    writeln!(w, "ply\nformat {format} 1.0\ncomment written by shapeforest")?;
    writeln!(w, "element vertex {}", mesh.vertices.len())?;
    writeln!(w, "property double x\nproperty double y\nproperty double z")?;
    if vertex_colors.is_some() {
        writeln!(w, "property uchar red\nproperty uchar green\nproperty uchar blue")?;
    }
    writeln!(w, "element face {}", mesh.faces.len())?;
    writeln!(w, "property list uchar int vertex_indices\nend_header")?;
    match encoding {
        PlyEncoding::Ascii => {
            for (i, p) in mesh.vertices.iter().enumerate() {
                write!(w, "{:?} {:?} {:?}", p[0], p[1], p[2])?;
                if let Some(c) = vertex_colors {
                    write!(w, " {} {} {}", c[i][0], c[i][1], c[i][2])?;
                }
                writeln!(w)?;
            }
            for f in &mesh.faces {
                writeln!(w, "3 {} {} {}", f[0], f[1], f[2])?;
            }
        }
        PlyEncoding::BinaryLittleEndian => {
            let mut buf = Vec::with_capacity(27);
            for (i, p) in mesh.vertices.iter().enumerate() {
                buf.clear();
                for c in p {
                    buf.extend_from_slice(&c.to_le_bytes());
                }
                if let Some(c) = vertex_colors {
                    buf.extend_from_slice(&c[i]);
                }
                w.write_all(&buf)?;
            }
            for f in &mesh.faces {
                buf.clear();
                buf.push(3);
                for &i in f {
                    // In range: every index is below the vertex count, checked above.
                    buf.extend_from_slice(&(i as i32).to_le_bytes());
                }
                w.write_all(&buf)?;
            }
        }
    }
    w.flush()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEAD: &str =
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                        element face 1\nproperty list uchar int vertex_indices\nend_header\n";

    fn err(text: &str) -> String {
        parse_ply(text.as_bytes()).unwrap_err().to_string()
    }

    #[test]
    fn ascii_errors_carry_payload_line_numbers() {
        assert_eq!(
            err(&format!("{HEAD}0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n")),
            "line 13: face 0 refers to vertex 5, but the mesh has 3 vertices"
        );
        assert_eq!(
            err(&format!("{HEAD}0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n")),
            "line 13: expected a non-negative vertex index, found -1"
        );
        assert_eq!(
            err(&format!("{HEAD}0 0 0\n1 0 0\n0 1 0\n2 0 1\n")),
            "line 13: expected a face with at least 3 vertices, found 2 vertices"
        );
        let e = parse_ply(format!("{HEAD}0 0 0\n1 0 0\n0 x 0\n3 0 1 2\n").as_bytes()).unwrap_err();
        assert_eq!(e.line(), Some(12), "{e}");
        let msg = e.to_string();
        assert!(msg.starts_with("line 12: invalid PLY data: Couldn't read element line"), "{msg}");
        assert!(!msg.contains("expected one of"), "grammar noise kept: {msg}");
        assert_eq!(err("hello"), "line 1: invalid PLY data: Expected magic number 'ply'.; String: 'hello'");
    }

    #[test]
    fn forged_counts_are_truncation_errors() {
        let text = "ply\nformat binary_little_endian 1.0\nelement vertex 999999999999\nproperty float x\n\
                    property float y\nproperty float z\nend_header\n";
        let e = parse_ply(text.as_bytes()).unwrap_err();
        assert!(matches!(e, MeshError::Truncated { .. }), "{e}");
        // A property-less element with a huge count occupies no bytes: it must not loop.
        let text = "ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\n\
                    property float y\nproperty float z\nelement junk 999999999999999\nend_header\n";
        let e = parse_ply(text.as_bytes()).unwrap_err();
        assert!(matches!(e, MeshError::Empty { .. }), "{e}");
    }

    #[test]
    fn header_problems_are_named() {
        let text =
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n0 0\n";
        assert!(err(text).starts_with("expected a vertex property `z`"), "{}", err(text));
        let text = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n";
        assert_eq!(err(text), "a point cloud needs at least 4 points, this one has 3");
        let text =
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                    element face 1\nproperty list uchar float vertex_indices\nend_header\n";
        assert!(err(text).contains("list of integers"), "{}", err(text));
    }

    #[test]
    fn colours_normals_and_other_elements_are_ignored() {
        let text =
            "ply\nformat ascii 1.0\ncomment hi\nelement vertex 4\nproperty double x\nproperty double y\n\
                    property double z\nproperty float nx\nproperty uchar red\nelement face 1\n\
                    property uchar flags\nproperty list uchar uint vertex_index\nelement edge 1\n\
                    property int vertex1\nproperty int vertex2\nend_header\n\
                    0 0 0 1 2\n1 0 0 1 2\n1 1 0 1 2\n0 1 0 1 2\n7 4 0 1 2 3\n0 1\n";
        let (m, report) = parse_ply(text.as_bytes()).unwrap();
        assert_eq!(m.faces, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(report.warnings.len(), 2, "{:?}", report.warnings);
    }
}
