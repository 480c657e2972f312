//! Cotangent Laplacian and lumped mass matrix.

use faer::sparse::{SparseColMat, Triplet};

use crate::mesh::{cross, dot, norm, sub, Mesh};

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
    let n = mesh.n_vertices();
    let weights = cotan_weights(mesh);
    let mut triplets = Vec::with_capacity(weights.len() * 4);
    for &(i, j, w) in &weights {
        triplets.push(Triplet::new(i, j, -w));
        triplets.push(Triplet::new(j, i, -w));
        triplets.push(Triplet::new(i, i, w));
        triplets.push(Triplet::new(j, j, w));
    }
    SparseColMat::try_new_from_triplets(n, n, &triplets)
        .expect("cotan_laplacian: indices are validated by Mesh::new")
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
