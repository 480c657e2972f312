//! Point clouds as text (`.xyz`): one point per line, `x y z` separated by whitespace; extra
//! columns (normals, colours, intensities) are ignored, `#` starts a comment, blank lines are
//! skipped. The file has no faces: the mesh read from it is the point cloud's surface of local
//! triangulations ([`super::point_cloud_mesh`]).

use std::io::Write;

use super::report::{MeshFormat, MeshReport, Parts};
use super::{Mesh, MeshError};
use crate::limits::Limits;

/// Parses `.xyz` data (plain or gzip-compressed) into a point-cloud mesh.
///
/// ```
/// use shapeforest::mesh::{parse_xyz_cloud, MeshWarning};
/// let text: String = (0..64).map(|i| format!("{} {} {} 0.5 0.5\n", i % 8, i / 8, ((i % 8) as f64 * 0.3).sin())).collect();
/// let (mesh, report) = parse_xyz_cloud(text.as_bytes()).unwrap();
/// assert_eq!(mesh.n_vertices(), 64);
/// assert!(matches!(report.warnings[0], MeshWarning::PointCloud { points: 64, .. }));
/// assert!(parse_xyz_cloud(b"0 0 0\n1 0\n").unwrap_err().to_string().contains("line 2"));
/// ```
pub fn parse_xyz_cloud(bytes: &[u8]) -> Result<(Mesh, MeshReport), MeshError> {
    xyz_parts(bytes)?.finish(&Limits::default())
}

/// The points of `.xyz` data, before the mesh is built.
pub(crate) fn xyz_parts(bytes: &[u8]) -> Result<Parts, MeshError> {
    // One point per line, as in a TOSCA `.vert` file: the same reader.
    let vertices = super::parse_vert(bytes)?;
    if vertices.is_empty() {
        return Err(MeshError::Empty { vertices: 0, faces: 0 });
    }
    Ok(Parts { vertices, faces: Vec::new(), format: MeshFormat::Xyz, notes: Vec::new() })
}

/// Writes the vertices of `mesh` as `.xyz` text (faces are dropped), in shortest round-trip
/// form.
pub fn write_xyz<W: Write>(mesh: &Mesh, mut w: W) -> Result<(), MeshError> {
    for p in &mesh.vertices {
        writeln!(w, "{:?} {:?} {:?}", p[0], p[1], p[2])?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{MeshWarning, DEFAULT_NEIGHBOURS};

    fn sphere_text() -> String {
        crate::synth::icosphere(2, 1.0)
            .vertices
            .iter()
            .map(|p| format!("{} {} {}\n", p[0], p[1], p[2]))
            .collect()
    }

    #[test]
    fn comments_blank_lines_and_extra_columns() {
        let mut text = String::from("# scanner output\n\n");
        for (i, line) in sphere_text().lines().enumerate() {
            text.push_str(&format!("{line} 0.1 0.2 0.3 {i} # point {i}\n"));
        }
        let (mesh, report) = parse_xyz_cloud(text.as_bytes()).unwrap();
        assert_eq!(mesh.n_vertices(), 162);
        assert_eq!(report.format, MeshFormat::Xyz);
        match &report.warnings[0] {
            MeshWarning::PointCloud { points, neighbours, triangles } => {
                assert_eq!((*points, *neighbours), (162, DEFAULT_NEIGHBOURS));
                assert_eq!(*triangles, mesh.n_faces());
            }
            w => panic!("unexpected first warning {w}"),
        }
    }

    #[test]
    fn errors_name_the_line() {
        let e = parse_xyz_cloud(b"0 0 0\n1 0 0\n1 x 0\n").unwrap_err();
        assert_eq!(e.to_string(), "line 3: expected a number, found \"x\"");
        let e = parse_xyz_cloud(b"# nothing\n").unwrap_err();
        assert!(matches!(e, MeshError::Empty { .. }), "{e}");
        let e = parse_xyz_cloud(b"0 0 0\n1 0 0\n0 1 0\n").unwrap_err();
        assert!(e.to_string().contains("at least 4 points"), "{e}");
        let e = parse_xyz_cloud(b"0 0 0\n1 0 0\n0 1 0\n0 0 inf\n").unwrap_err();
        assert!(e.to_string().starts_with("line 4: vertex 3 has a NaN"), "{e}");
    }

    #[test]
    fn write_then_read_keeps_the_points() {
        let sphere = crate::synth::icosphere(2, 1.0);
        let mut out = Vec::new();
        write_xyz(&sphere, &mut out).unwrap();
        let (back, _) = parse_xyz_cloud(&out).unwrap();
        assert_eq!(back.vertices, sphere.vertices);
    }
}
