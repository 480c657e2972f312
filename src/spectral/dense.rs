//! Dense reference solver for small meshes: exact generalised eigenpairs through a dense
//! symmetric eigendecomposition of `M^{-1/2} L M^{-1/2}`. O(n³): for tests and checks only.

use faer::{Mat, Side};

use super::{cotan_laplacian, vertex_lumped_mass, SpectralError, Spectrum};
use crate::mesh::Mesh;

/// All-in-memory reference spectrum (first `k` eigenpairs) of a small mesh, unit-area scaled.
/// Meant for meshes of at most a few thousand vertices.
///
/// ```
/// use shapeforest::{spectral::dense_spectrum, synth::icosphere};
/// let s = dense_spectrum(&icosphere(1, 1.0), 4).unwrap();
/// assert!(s.eigenvalues[0].abs() < 1e-9);
/// // l = 1 has multiplicity 3
/// assert!((s.eigenvalues[1] - s.eigenvalues[3]).abs() < 1e-9);
/// ```
pub fn dense_spectrum(mesh: &Mesh, k: usize) -> Result<Spectrum, SpectralError> {
    let n = mesh.n_vertices();
    if k > n {
        return Err(SpectralError::TooManyEigenpairs { wanted: k, n_vertices: n });
    }
    let area = mesh.surface_area();
    let mass: Vec<f64> = vertex_lumped_mass(mesh).iter().map(|m| m / area).collect();
    let l = cotan_laplacian(mesh).to_dense();
    // Vertices without mass (unreferenced) get a tiny one so M^{-1/2} exists.
    let floor = 1e-12 / n as f64;
    let inv_sqrt: Vec<f64> = mass.iter().map(|&m| 1.0 / m.max(floor).sqrt()).collect();
    let a = Mat::from_fn(n, n, |i, j| l[(i, j)] * inv_sqrt[i] * inv_sqrt[j]);
    let evd = a.self_adjoint_eigen(Side::Lower).map_err(|_| SpectralError::DenseEigenFailed)?;
    let (s, u) = (evd.S(), evd.U());
    let mut eigenvectors = Vec::with_capacity(n * k);
    for j in 0..k {
        for i in 0..n {
            eigenvectors.push(u[(i, j)] * inv_sqrt[i]);
        }
    }
    Ok(Spectrum {
        eigenvalues: (0..k).map(|j| s.column_vector()[j]).collect(),
        eigenvectors,
        n_vertices: n,
        mass,
        area,
    })
}
