//! Dense reference solver for small meshes: exact generalised eigenpairs through a dense
//! symmetric eigendecomposition of `M^{-1/2} L M^{-1/2}`. O(n³): for small meshes and checks.

use super::{LaplaceBeltramiSolver, SpectralError, Spectrum, SpectrumParams};
use crate::mesh::Mesh;

/// All-in-memory reference spectrum (first `k` eigenpairs) of a small mesh, unit-area scaled.
/// Meant for meshes of at most a few thousand vertices.
///
/// It follows the conventions of [`super::compute_spectrum`] (unreferenced vertices excluded,
/// exact null space, sign convention), only the eigensolver differs: a full dense
/// eigendecomposition, exact to round-off.
///
/// ```
/// use shapeforest::{spectral::dense_spectrum, synth::icosphere};
/// let s = dense_spectrum(&icosphere(1, 1.0), 4).unwrap();
/// assert!(s.eigenvalues[0].abs() < 1e-9);
/// // l = 1 has multiplicity 3
/// assert!((s.eigenvalues[1] - s.eigenvalues[3]).abs() < 1e-9);
/// ```
pub fn dense_spectrum(mesh: &Mesh, k: usize) -> Result<Spectrum, SpectralError> {
    let params = SpectrumParams { dense_threshold: usize::MAX, ..SpectrumParams::new(k) };
    LaplaceBeltramiSolver::new(mesh, &params)?.solve()
}
