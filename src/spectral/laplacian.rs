//! Cotangent Laplacian and lumped mass matrix, and [`surface_operator`], which picks the
//! cotangent Laplacian for edge-manifold meshes and the tufted intrinsic-Delaunay Laplacian
//! ([`super::tufted`]) for non-manifold ones (and point clouds, whose meshes are).

use faer::sparse::{SparseColMat, Triplet};
use serde::{Deserialize, Serialize};

use super::tufted::{tufted_laplacian, TuftedParams};
use crate::mesh::{cross, dot, norm, sub, Mesh, POINT_CLOUD_COVER};

/// Which discrete Laplacian [`surface_operator`] chose.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum LaplacianKind {
    /// The cotangent Laplacian of the mesh itself ([`cotan_laplacian`], [`vertex_lumped_mass`]).
    Cotan,
    /// The tufted intrinsic-Delaunay Laplacian ([`tufted_laplacian`]), for meshes with an edge
    /// shared by more than two faces (non-manifold meshes, point-cloud surfaces).
    Tufted,
}

/// The Laplacian of a mesh as weights and lumped masses (see [`surface_operator`]).
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceOperator {
    /// Which Laplacian this is.
    pub kind: LaplacianKind,
    /// Edge weights `(i, j, w)` to be summed: `L_ij = −Σ w`, `L_ii = Σ_j Σ w`.
    pub weights: Vec<(usize, usize, f64)>,
    /// Lumped mass per vertex (0 on vertices in no face).
    pub mass: Vec<f64>,
}

impl SurfaceOperator {
    /// The stiffness matrix `L` as a sparse CSC matrix (both triangles stored).
    pub fn stiffness(&self) -> SparseColMat<usize, f64> {
        weights_matrix(self.mass.len(), &self.weights)
    }

    /// Total mass: the area the operator sees.
    pub fn total_mass(&self) -> f64 {
        self.mass.iter().sum()
    }
}

/// True when some edge of `mesh` is shared by more than two faces.
///
/// ```
/// use shapeforest::{mesh::Mesh, spectral::has_non_manifold_edge};
/// let v = vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]];
/// assert!(!has_non_manifold_edge(&Mesh::new(v.clone(), vec![[0, 1, 2], [1, 0, 3]]).unwrap()));
/// assert!(has_non_manifold_edge(&Mesh::new(v, vec![[0, 1, 2], [1, 0, 3], [0, 1, 4]]).unwrap()));
/// ```
pub fn has_non_manifold_edge(mesh: &Mesh) -> bool {
    let mut edges: Vec<(usize, usize)> = mesh
        .faces
        .iter()
        .flat_map(|f| (0..3).map(move |c| (f[c].min(f[(c + 1) % 3]), f[c].max(f[(c + 1) % 3]))))
        .collect();
    edges.sort_unstable();
    edges.windows(3).any(|w| w[0] == w[2])
}

/// The Laplacian the spectral and geodesic code use on `mesh`: the cotangent Laplacian when every
/// edge has at most two faces (the mesh is used as it is, as before), otherwise the tufted
/// intrinsic-Delaunay Laplacian of Sharp & Crane 2020 with its default mollification, whose
/// weights are non-negative and whose `M + tL` is positive definite whatever the soup.
///
/// ```
/// use shapeforest::{spectral::{surface_operator, LaplacianKind}, synth::icosphere};
/// let op = surface_operator(&icosphere(2, 1.0));
/// assert_eq!(op.kind, LaplacianKind::Cotan);
/// ```
pub fn surface_operator(mesh: &Mesh) -> SurfaceOperator {
    if let Some(multiplicity) = mesh.point_cloud_multiplicity() {
        // the paper's point-cloud Laplacian: every fan's triangle, so a face found in m fans
        // enters m times, and the result divided by the cover
        let soup: Vec<[usize; 3]> = mesh
            .faces
            .iter()
            .zip(multiplicity)
            .flat_map(|(f, &m)| std::iter::repeat_n(*f, m as usize))
            .collect();
        if let Ok(t) = tufted_laplacian(&mesh.vertices, &soup, TuftedParams::default()) {
            let s = 1.0 / POINT_CLOUD_COVER;
            return SurfaceOperator {
                kind: LaplacianKind::Tufted,
                weights: t.weights.into_iter().map(|(i, j, w)| (i, j, w * s)).collect(),
                mass: t.mass.into_iter().map(|m| m * s).collect(),
            };
        }
    }
    if has_non_manifold_edge(mesh) {
        // A valid Mesh can only fail here when every edge has length zero: then the cotan
        // operator (empty) lets the callers report the zero area.
        if let Ok(t) = tufted_laplacian(&mesh.vertices, &mesh.faces, TuftedParams::default()) {
            return SurfaceOperator { kind: LaplacianKind::Tufted, weights: t.weights, mass: t.mass };
        }
    }
    SurfaceOperator {
        kind: LaplacianKind::Cotan,
        weights: cotan_weights(mesh),
        mass: vertex_lumped_mass(mesh),
    }
}

fn weights_matrix(n: usize, weights: &[(usize, usize, f64)]) -> SparseColMat<usize, f64> {
    let mut triplets = Vec::with_capacity(weights.len() * 4);
    for &(i, j, w) in weights {
        triplets.push(Triplet::new(i, j, -w));
        triplets.push(Triplet::new(j, i, -w));
        triplets.push(Triplet::new(i, i, w));
        triplets.push(Triplet::new(j, j, w));
    }
    SparseColMat::try_new_from_triplets(n, n, &triplets)
        .expect("Laplacian indices are validated by Mesh::new")
}

/// Cotangent of the angle between `u` and `v`, or `None` for a degenerate (zero-area) corner.
#[inline]
fn cot(u: [f64; 3], v: [f64; 3]) -> Option<f64> {
    let c = norm(cross(u, v));
    let scale = dot(u, u).max(dot(v, v));
    if c <= 1e-14 * scale || !c.is_finite() {
        None
    } else {
        Some(dot(u, v) / c)
    }
}

/// Per-edge cotangent weights `w_ij = (cot α_ij + cot β_ij)/2` as `(i, j, w)` with `i < j`,
/// one entry per (face, edge) incidence (entries of shared edges are to be summed).
///
/// Zero-area faces contribute nothing, so the Laplacian stays finite on degenerate input.
pub fn cotan_weights(mesh: &Mesh) -> Vec<(usize, usize, f64)> {
    let mut out = Vec::with_capacity(mesh.n_faces() * 3);
    for f in &mesh.faces {
        let p = [mesh.vertices[f[0]], mesh.vertices[f[1]], mesh.vertices[f[2]]];
        for c in 0..3 {
            // corner c is opposite edge (a, b)
            let a = (c + 1) % 3;
            let b = (c + 2) % 3;
            if let Some(ct) = cot(sub(p[a], p[c]), sub(p[b], p[c])) {
                let (i, j) = (f[a].min(f[b]), f[a].max(f[b]));
                out.push((i, j, 0.5 * ct));
            }
        }
    }
    out
}

/// The cotangent stiffness matrix `L` (symmetric, positive semi-definite for Delaunay meshes,
/// rows summing to zero), as a sparse CSC matrix with both triangles stored.
///
/// ```
/// use shapeforest::{mesh::Mesh, spectral::cotan_laplacian};
/// let m = Mesh::new(
///     vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
///     vec![[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]],
/// ).unwrap();
/// let l = cotan_laplacian(&m);
/// let dense = l.to_dense();
/// for i in 0..4 {
///     let row: f64 = (0..4).map(|j| dense[(i, j)]).sum();
///     assert!(row.abs() < 1e-12);
/// }
/// ```
pub fn cotan_laplacian(mesh: &Mesh) -> SparseColMat<usize, f64> {
    weights_matrix(mesh.n_vertices(), &cotan_weights(mesh))
}

/// Lumped (barycentric) vertex mass: a third of the area of each incident triangle.
/// Unreferenced vertices get mass zero.
///
/// ```
/// use shapeforest::{mesh::Mesh, spectral::vertex_lumped_mass};
/// let m = Mesh::new(vec![[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [0.0, 2.0, 0.0]], vec![[0, 1, 2]]).unwrap();
/// let mass = vertex_lumped_mass(&m);
/// assert!(mass.iter().all(|&a| (a - 1.0).abs() < 1e-12));
/// ```
pub fn vertex_lumped_mass(mesh: &Mesh) -> Vec<f64> {
    let mut mass = vec![0.0; mesh.n_vertices()];
    for (f, a) in mesh.faces.iter().zip(mesh.face_areas()) {
        for &v in f {
            mass[v] += a / 3.0;
        }
    }
    mass
}

#[cfg(test)]
mod tests {
    use super::*;

    fn octahedron() -> Mesh {
        let v = vec![
            [1.0, 0.0, 0.0],
            [-1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
        ];
        let f = vec![[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]];
        Mesh::new(v, f).unwrap()
    }

    #[test]
    fn laplacian_is_symmetric_with_zero_row_sums() {
        let l = cotan_laplacian(&octahedron()).to_dense();
        for i in 0..6 {
            let s: f64 = (0..6).map(|j| l[(i, j)]).sum();
            assert!(s.abs() < 1e-12, "row {i} sums to {s}");
            for j in 0..6 {
                assert!((l[(i, j)] - l[(j, i)]).abs() < 1e-12);
            }
            assert!(l[(i, i)] > 0.0);
        }
    }

    #[test]
    fn mass_sums_to_area() {
        let m = octahedron();
        let total: f64 = vertex_lumped_mass(&m).iter().sum();
        assert!((total - m.surface_area()).abs() < 1e-12);
    }

    #[test]
    fn degenerate_face_contributes_nothing() {
        let m = Mesh::new(vec![[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]], vec![[0, 1, 2]]).unwrap();
        assert!(cotan_weights(&m).is_empty());
    }
}
