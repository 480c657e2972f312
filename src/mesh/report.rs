//! [`MeshReport`]: what a reader noticed about a mesh it accepted.
//!
//! Errors stop a read (see [`MeshError`]); the problems here do not: a mesh with zero-area
//! faces, non-manifold edges, unreferenced vertices or duplicate faces is still returned,
//! unchanged (vertex order and count are never modified), and the report says what was found.

use std::fmt;

use super::cloud::{point_cloud_mesh, DEFAULT_NEIGHBOURS};
use super::summary::{analyse, MeshSummary};
use super::{Mesh, MeshError};
use crate::limits::Limits;

/// A mesh file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MeshFormat {
    /// Geomview Object File Format (`.off`, also `COFF`, `NOFF`, … variants).
    Off,
    /// Wavefront OBJ (`.obj`).
    Obj,
    /// Stanford polygon format (`.ply`), ascii or binary.
    Ply,
    /// TOSCA pair: `NAME.vert` (one `x y z` per line) and `NAME.tri` (1-based `i j k`).
    Tosca,
    /// Point cloud as text (`.xyz`): one `x y z` per line, extra columns ignored.
    Xyz,
}

impl fmt::Display for MeshFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            MeshFormat::Off => "OFF",
            MeshFormat::Obj => "OBJ",
            MeshFormat::Ply => "PLY",
            MeshFormat::Tosca => "TOSCA vert/tri",
            MeshFormat::Xyz => "XYZ point cloud",
        })
    }
}

/// Something worth knowing about a mesh that was read successfully.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum MeshWarning {
    /// Faces with zero area up to rounding (see [`super::is_zero_area`]).
    ZeroAreaFaces {
        /// How many.
        count: usize,
        /// 0-based index of the first.
        first: usize,
    },
    /// Edges shared by more than two faces.
    NonManifoldEdges {
        /// How many.
        count: usize,
    },
    /// Vertices that no face uses (kept, so vertex indices stay as in the file).
    UnreferencedVertices {
        /// How many.
        count: usize,
        /// 0-based index of the first.
        first: usize,
    },
    /// Faces with the same vertices as an earlier face.
    DuplicateFaces {
        /// How many (not counting the first occurrence).
        count: usize,
        /// 0-based index of the first duplicate.
        first: usize,
    },
    /// Polygons with more than three vertices were split into triangle fans.
    PolygonsTriangulated {
        /// Polygons in the file that had more than three vertices.
        polygons: usize,
        /// Triangles they became.
        triangles: usize,
    },
    /// The file holds points without faces: a surface was built from local triangulations of
    /// the points (see [`super::point_cloud_mesh`]).
    PointCloud {
        /// Points in the file (the mesh's vertices, in file order).
        points: usize,
        /// Neighbours per point of the local triangulations.
        neighbours: usize,
        /// Distinct triangles of the local triangulations (the mesh's faces).
        triangles: usize,
    },
    /// Parts of the file that carry no surface were skipped (OBJ points and lines,
    /// PLY elements other than `vertex` and `face`, unknown OBJ statements).
    Ignored {
        /// What was skipped.
        what: String,
        /// How many.
        count: usize,
    },
}

impl fmt::Display for MeshWarning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MeshWarning::ZeroAreaFaces { count, first } => {
                write!(f, "{count} zero-area face(s), the first is face {first}")
            }
            MeshWarning::NonManifoldEdges { count } => {
                write!(f, "{count} non-manifold edge(s) shared by more than two faces")
            }
            MeshWarning::UnreferencedVertices { count, first } => {
                write!(f, "{count} vertex(es) used by no face (kept), the first is vertex {first}")
            }
            MeshWarning::DuplicateFaces { count, first } => {
                write!(f, "{count} duplicate face(s), the first is face {first}")
            }
            MeshWarning::PolygonsTriangulated { polygons, triangles } => {
                write!(f, "{polygons} polygon(s) with more than 3 vertices split into {triangles} triangles")
            }
            MeshWarning::Ignored { what, count } => write!(f, "ignored {count} {what}"),
            MeshWarning::PointCloud { points, neighbours, triangles } => write!(
                f,
                "point cloud of {points} points without faces: surface built from local triangulations \
                 ({neighbours} neighbours, {triangles} distinct triangles, non-manifold; the tufted \
                 Laplacian is used)"
            ),
        }
    }
}

/// What a reader found in a mesh it accepted: the format, a [`MeshSummary`], and warnings.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshReport {
    /// The format that was read.
    pub format: MeshFormat,
    /// Counts and topology of the mesh.
    pub summary: MeshSummary,
    /// Problems that did not stop the read, in a stable order.
    pub warnings: Vec<MeshWarning>,
}

impl MeshReport {
    /// True when nothing worth a warning was found.
    pub fn is_clean(&self) -> bool {
        self.warnings.is_empty()
    }
}

impl fmt::Display for MeshReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "format               {}", self.format)?;
        write!(f, "{}", self.summary)?;
        for w in &self.warnings {
            write!(f, "\nwarning: {w}")?;
        }
        Ok(())
    }
}

/// What a reader found, before the mesh is built by [`Parts::finish`].
pub(crate) struct Parts {
    pub(crate) vertices: Vec<[f64; 3]>,
    pub(crate) faces: Vec<[usize; 3]>,
    pub(crate) format: MeshFormat,
    pub(crate) notes: Vec<MeshWarning>,
}

impl Parts {
    /// Builds the mesh (with [`Mesh::new`]'s checks) and its report. Readers have already
    /// checked faces and coordinates with file positions; here only emptiness remains. Vertices
    /// without any face are a point cloud: its surface is built from local triangulations
    /// ([`super::point_cloud_mesh`]), after the vertex count is checked against `limits` (the
    /// construction allocates per point).
    pub(crate) fn finish(self, limits: &Limits) -> Result<(Mesh, MeshReport), MeshError> {
        let Parts { vertices, faces, format, mut notes } = self;
        if vertices.len() > limits.max_vertices {
            return Err(MeshError::OverLimit {
                what: "vertices",
                found: vertices.len(),
                limit: limits.max_vertices,
            });
        }
        let mesh = if faces.is_empty() && !vertices.is_empty() {
            let mesh = point_cloud_mesh(&vertices, DEFAULT_NEIGHBOURS)?;
            notes.insert(
                0,
                MeshWarning::PointCloud {
                    points: mesh.n_vertices(),
                    neighbours: DEFAULT_NEIGHBOURS.min(mesh.n_vertices() - 1),
                    triangles: mesh.n_faces(),
                },
            );
            mesh
        } else {
            Mesh::new(vertices, faces)?
        };
        finish_mesh(mesh, format, notes)
    }
}

fn finish_mesh(
    mesh: Mesh,
    format: MeshFormat,
    notes: Vec<MeshWarning>,
) -> Result<(Mesh, MeshReport), MeshError> {
    let point_cloud = notes.iter().any(|n| matches!(n, MeshWarning::PointCloud { .. }));
    let analysis = analyse(&mesh);
    let s = &analysis.summary;
    let mut warnings = Vec::new();
    if let Some(first) = analysis.first_zero_area {
        warnings.push(MeshWarning::ZeroAreaFaces { count: s.n_zero_area_faces, first });
    }
    // a point cloud's surface is non-manifold by construction: its note says so
    if s.n_non_manifold_edges > 0 && !point_cloud {
        warnings.push(MeshWarning::NonManifoldEdges { count: s.n_non_manifold_edges });
    }
    if let Some(first) = analysis.first_unreferenced {
        warnings.push(MeshWarning::UnreferencedVertices { count: s.n_unreferenced_vertices, first });
    }
    if let Some(first) = analysis.first_duplicate {
        warnings.push(MeshWarning::DuplicateFaces { count: s.n_duplicate_faces, first });
    }
    warnings.extend(notes);
    Ok((mesh, MeshReport { format, summary: analysis.summary, warnings }))
}

/// Checks one triangle against the vertex count, as [`Mesh::new`] does.
pub(crate) fn check_face(face: usize, tri: [usize; 3], n_vertices: usize) -> Result<(), MeshError> {
    if let Some(&index) = tri.iter().find(|&&i| i >= n_vertices) {
        return Err(MeshError::FaceIndexOutOfRange { face, index, n_vertices });
    }
    if tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2] {
        return Err(MeshError::RepeatedVertexInFace { face, indices: tri });
    }
    Ok(())
}

/// Checks one vertex's coordinates.
pub(crate) fn check_vertex(vertex: usize, p: [f64; 3]) -> Result<(), MeshError> {
    if p.iter().all(|c| c.is_finite()) {
        Ok(())
    } else {
        Err(MeshError::NonFiniteVertex { vertex })
    }
}

/// Fan-triangulates a polygon `(p0, p1, …, pn)` into `(p0, pk, pk+1)`, appending to `faces`
/// after checking each triangle. Returns the number of triangles added.
pub(crate) fn push_fan(
    faces: &mut Vec<[usize; 3]>,
    polygon: &[usize],
    n_vertices: Option<usize>,
) -> Result<usize, MeshError> {
    let mut added = 0;
    for k in 1..polygon.len().saturating_sub(1) {
        let tri = [polygon[0], polygon[k], polygon[k + 1]];
        if let Some(n) = n_vertices {
            check_face(faces.len(), tri, n)?;
        }
        faces.push(tri);
        added += 1;
    }
    Ok(added)
}
