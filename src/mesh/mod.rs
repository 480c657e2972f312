//! Triangle meshes: the [`Mesh`] type, validation, geometric quantities and summaries, and
//! robust readers and writers.
//!
//! Conventions: vertices are `[x, y, z]` in `f64`, faces are 0-based vertex index triples with
//! counter-clockwise orientation. Loading never reorders vertices (ground-truth correspondence
//! is by vertex index) and never drops unreferenced vertices.
//!
//! # Reading
//! [`read_mesh`] / [`read_mesh_with_report`] read a file by extension: OFF (`.off`, with
//! `COFF`/`NOFF` variants, vertex colours and polygons), OBJ (`.obj`), PLY (`.ply`, ascii and
//! binary), TOSCA pairs (`.vert` + `.tri`), point clouds (`.xyz`), each optionally
//! gzip-compressed (`.gz`). The per-format functions [`parse_off`], [`parse_obj`], [`parse_ply`],
//! [`parse_tosca`], [`parse_xyz_cloud`] (and [`parse_mesh`], [`read_mesh_from`]) read from
//! memory or any reader. Polygons are split into triangle fans.
//!
//! Readers never panic, whatever the bytes: malformed data gives a [`MeshError`] naming the
//! file, the line (or PLY element) and what was expected, e.g.
//! `cat.off: line 17: expected 3 coordinates, found 2`. Counts in headers are never trusted
//! for allocation beyond what the data's size allows.
//!
//! # Point clouds
//! Data with vertices and no faces (`.xyz`, or an OFF/OBJ/PLY file without faces) is a point
//! cloud: the mesh read from it has the points as vertices, in file order, and the distinct
//! triangles of their local tangent-plane Delaunay triangulations as faces
//! ([`point_cloud_mesh`], Sharp & Crane 2020), a non-manifold surface on which the spectral
//! and geodesic code use the tufted intrinsic-Delaunay Laplacian. The report says so with
//! [`MeshWarning::PointCloud`]. [`Mesh::new`] itself still refuses vertices without faces
//! ([`MeshError::PointCloud`]).
//!
//! Problems that do not prevent use (zero-area faces, non-manifold edges, unreferenced
//! vertices, duplicate faces, triangulated polygons, skipped content) are returned as
//! [`MeshWarning`]s in a [`MeshReport`], which also carries the [`MeshSummary`].
//!
//! # Writing
//! [`write_mesh`] writes by extension; [`write_off`], [`write_obj`], [`write_ply`] (ascii or
//! binary, optional vertex colours) and [`write_tosca`] write to any `Write`. Text formats
//! print coordinates in shortest round-trip form, so write-then-read is bit-exact in every
//! format.

mod cloud;
mod error;
mod io;
mod obj;
mod off;
mod parts;
mod perturb;
mod ply;
mod report;
mod summary;
mod text;
mod topology;
mod tosca;
mod xyz;

pub(crate) use cloud::OrdF64;
pub use cloud::{
    local_triangulation, point_cloud_mesh, LocalTriangulation, DEFAULT_NEIGHBOURS, MIN_POINTS,
    POINT_CLOUD_COVER,
};
pub use error::{Location, MeshError};
pub use io::{
    parse_mesh, read_file_limited, read_mesh, read_mesh_from, read_mesh_limited, read_mesh_with_report,
    write_colored_ply, write_mesh,
};
pub use obj::{parse_obj, write_obj};
pub use off::{parse_off, write_off};
pub use parts::{
    boundary_loops, extend_map_by_nearest, fill_holes, largest_component, submesh, vertex_components,
};
pub use perturb::{perturb, perturbations_name, Perturbation, Perturbed};
pub use ply::{parse_ply, write_ply, PlyEncoding};
pub use report::{MeshFormat, MeshReport, MeshWarning};
pub use summary::{is_zero_area, ComponentSize, MeshSummary};
pub use text::MAX_DECOMPRESSED_BYTES;
pub use topology::{face_connectivity, UnionFind};
pub use tosca::{parse_tosca, parse_tri, parse_vert, write_tosca};
pub use xyz::{parse_xyz_cloud, write_xyz};

use serde::{Deserialize, Serialize};

/// A triangle mesh: vertex positions and 0-based triangle indices.
///
/// A `Mesh` built through [`Mesh::new`] is guaranteed non-empty, with finite coordinates,
/// face indices in range and no face repeating a vertex.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Mesh {
    /// Vertex positions.
    pub vertices: Vec<[f64; 3]>,
    /// Triangles as 0-based vertex indices.
    pub faces: Vec<[usize; 3]>,
    /// Empty for an ordinary mesh. For the surface of a point cloud ([`point_cloud_mesh`]): how
    /// many of the local triangulations (fans) hold each face; they cover the surface
    /// [`POINT_CLOUD_COVER`] times, so face `f` stands for `face_multiplicity[f] / 3` of its area.
    /// Ignored (every face counts once) when its length is not the number of faces, e.g. after
    /// faces were added or removed by hand.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub face_multiplicity: Vec<u32>,
}

impl Mesh {
    /// Builds a mesh, checking the invariants every algorithm relies on: at least one vertex
    /// ([`MeshError::Empty`]) and one face ([`MeshError::PointCloud`]), finite coordinates,
    /// face indices in range, no face repeating a vertex.
    ///
    /// ```
    /// use shapeforest::mesh::Mesh;
    /// let m = Mesh::new(vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], vec![[0, 1, 2]]).unwrap();
    /// assert_eq!(m.n_faces(), 1);
    /// assert!(Mesh::new(vec![[0.0; 3]], vec![[0, 1, 2]]).is_err());
    /// ```
    pub fn new(vertices: Vec<[f64; 3]>, faces: Vec<[usize; 3]>) -> Result<Self, MeshError> {
        if vertices.is_empty() {
            return Err(MeshError::Empty { vertices: vertices.len(), faces: faces.len() });
        }
        if faces.is_empty() {
            return Err(MeshError::PointCloud { vertices: vertices.len() });
        }
        if let Some(v) = vertices.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
            return Err(MeshError::NonFiniteVertex { vertex: v });
        }
        let n = vertices.len();
        for (f, tri) in faces.iter().enumerate() {
            if let Some(&index) = tri.iter().find(|&&i| i >= n) {
                return Err(MeshError::FaceIndexOutOfRange { face: f, index, n_vertices: n });
            }
            if tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2] {
                return Err(MeshError::RepeatedVertexInFace { face: f, indices: *tri });
            }
        }
        Ok(Self { vertices, faces, face_multiplicity: Vec::new() })
    }

    /// The face multiplicities of a point-cloud surface (see [`Mesh::face_multiplicity`]), or
    /// `None` for an ordinary mesh.
    pub fn point_cloud_multiplicity(&self) -> Option<&[u32]> {
        (!self.face_multiplicity.is_empty() && self.face_multiplicity.len() == self.faces.len())
            .then_some(&self.face_multiplicity[..])
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.vertices.len()
    }

    /// Number of triangles.
    pub fn n_faces(&self) -> usize {
        self.faces.len()
    }

    /// Area of every triangle.
    ///
    /// ```
    /// use shapeforest::mesh::Mesh;
    /// let m = Mesh::new(vec![[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.0, 0.0]], vec![[0, 1, 2]]).unwrap();
    /// assert!((m.face_areas()[0] - 1.0).abs() < 1e-12);
    /// ```
    pub fn face_areas(&self) -> Vec<f64> {
        self.faces
            .iter()
            .map(|f| triangle_area(self.vertices[f[0]], self.vertices[f[1]], self.vertices[f[2]]))
            .collect()
    }

    /// Total surface area (of a point-cloud surface: each face weighted by its multiplicity
    /// over [`POINT_CLOUD_COVER`], the area the local triangulations cover).
    pub fn surface_area(&self) -> f64 {
        match self.point_cloud_multiplicity() {
            None => self.face_areas().iter().sum(),
            Some(m) => {
                self.face_areas().iter().zip(m).map(|(a, &k)| a * k as f64).sum::<f64>() / POINT_CLOUD_COVER
            }
        }
    }

    /// Axis-aligned bounding box `(min, max)`.
    pub fn bounding_box(&self) -> ([f64; 3], [f64; 3]) {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in &self.vertices {
            for d in 0..3 {
                lo[d] = lo[d].min(p[d]);
                hi[d] = hi[d].max(p[d]);
            }
        }
        (lo, hi)
    }

    /// A 64-bit FNV-1a hash of the exact vertex coordinates and faces: two meshes with the same
    /// hash are (with overwhelming probability) bit-identical. Used to key caches.
    pub fn content_hash(&self) -> u64 {
        let mut h = crate::fsutil::Fnv64::new();
        h.write_u64(self.vertices.len() as u64);
        h.write_u64(self.faces.len() as u64);
        for p in &self.vertices {
            for c in p {
                h.write_u64(c.to_bits());
            }
        }
        for f in &self.faces {
            for &i in f {
                h.write_u64(i as u64);
            }
        }
        for &m in &self.face_multiplicity {
            h.write_u64(m as u64);
        }
        h.finish()
    }

    /// A copy with every coordinate multiplied by `factor`.
    pub fn scaled(&self, factor: f64) -> Mesh {
        Mesh {
            vertices: self.vertices.iter().map(|p| [p[0] * factor, p[1] * factor, p[2] * factor]).collect(),
            faces: self.faces.clone(),
            face_multiplicity: self.face_multiplicity.clone(),
        }
    }
}

/// The vertex neighbours of a triangle list over `n` vertices, as compressed rows: those of `v`
/// are `neighbours[offsets[v]..offsets[v + 1]]`, the two other corners of each face at `v` in
/// face order (an interior edge's far end appears twice, once per face).
///
/// ```
/// use shapeforest::mesh::face_neighbour_lists;
/// let (offsets, neighbours) = face_neighbour_lists(&[[0, 1, 2], [0, 2, 3]], 4);
/// assert_eq!(&neighbours[offsets[0]..offsets[1]], &[1, 2, 2, 3]);
/// assert_eq!(&neighbours[offsets[3]..offsets[4]], &[0, 2]);
/// ```
pub fn face_neighbour_lists(faces: &[[usize; 3]], n: usize) -> (Vec<usize>, Vec<usize>) {
    let mut offsets = vec![0usize; n + 1];
    for face in faces {
        for &v in face {
            offsets[v + 1] += 2;
        }
    }
    for v in 0..n {
        offsets[v + 1] += offsets[v];
    }
    let mut fill = offsets.clone();
    let mut neighbours = vec![0usize; offsets[n]];
    for face in faces {
        for e in 0..3 {
            let v = face[e];
            neighbours[fill[v]] = face[(e + 1) % 3];
            neighbours[fill[v] + 1] = face[(e + 2) % 3];
            fill[v] += 2;
        }
    }
    (offsets, neighbours)
}

/// Area of the triangle `(a, b, c)`.
pub fn triangle_area(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> f64 {
    0.5 * norm(cross(sub(b, a), sub(c, a)))
}

/// Area-weighted vertex normals (not normalised: the sum of the incident faces' cross
/// products, each twice the face's area).
pub(crate) fn vertex_normals(mesh: &Mesh) -> Vec<[f64; 3]> {
    let mut normals = vec![[0.0; 3]; mesh.n_vertices()];
    for f in &mesh.faces {
        let p = mesh.vertices[f[0]];
        let n = cross(sub(mesh.vertices[f[1]], p), sub(mesh.vertices[f[2]], p));
        for &v in f {
            for d in 0..3 {
                normals[v][d] += n[d];
            }
        }
    }
    normals
}

#[inline]
pub(crate) fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline]
pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
pub(crate) fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

#[inline]
pub(crate) fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

/// A smooth colour per vertex from its coordinates normalised to the bounding box (red = x,
/// green = y, blue = z, each in 30..=255): transferred through a correspondence, matching parts
/// of two shapes share colours.
///
/// ```
/// use shapeforest::mesh::{coordinate_colors, Mesh};
/// let m = Mesh::new(vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 1.0]], vec![[0, 1, 2]]).unwrap();
/// let c = coordinate_colors(&m);
/// assert_eq!(c[0], [30, 30, 30]);
/// assert_eq!(c[1], [255, 30, 30]);
/// ```
pub fn coordinate_colors(mesh: &Mesh) -> Vec<[u8; 3]> {
    let (lo, hi) = mesh.bounding_box();
    mesh.vertices
        .iter()
        .map(|p| {
            let mut c = [0u8; 3];
            for a in 0..3 {
                let ext = (hi[a] - lo[a]).max(f64::MIN_POSITIVE);
                let t = ((p[a] - lo[a]) / ext).clamp(0.0, 1.0);
                c[a] = (30.0 + 225.0 * t).round() as u8;
            }
            c
        })
        .collect()
}
