//! The Laplace–Beltrami spectrum of a triangle mesh.
//!
//! - [`cotan_laplacian`]: the symmetric positive semi-definite cotangent stiffness matrix `L`
//!   (`L_ij = -(cot α_ij + cot β_ij)/2`, rows summing to zero);
//! - [`vertex_lumped_mass`]: the lumped (barycentric) mass, a third of the incident triangle areas;
//! - [`Spectrum`]: the first K eigenpairs of `L φ = λ M φ`.
//!
//! Conventions: the spectrum is that of the mesh **scaled to unit total area** (so eigenvalues
//! are scale-invariant and comparable across shapes; divide by the original area to get them in
//! mesh units). Eigenvalues ascend. Eigenvectors are orthonormal in the M inner product
//! (`Φᵀ M Φ = I`), not under the plain dot product.

mod dense;
mod laplacian;
mod spectrum;

pub use dense::dense_spectrum;
pub use laplacian::{cotan_laplacian, cotan_weights, vertex_lumped_mass};
pub use spectrum::Spectrum;

use thiserror::Error;

/// The Laplace eigenproblem could not be set up or solved.
#[derive(Debug, Error)]
pub enum SpectralError {
    /// More eigenpairs were asked for than the mesh has vertices.
    #[error("asked for {wanted} eigenpairs but the mesh has only {n_vertices} vertices")]
    TooManyEigenpairs {
        /// Eigenpairs asked for.
        wanted: usize,
        /// Vertices in the mesh.
        n_vertices: usize,
    },
    /// The dense reference eigendecomposition did not converge.
    #[error("dense eigendecomposition did not converge")]
    DenseEigenFailed,
}
