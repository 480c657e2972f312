//! The Laplace–Beltrami spectrum of a triangle mesh.
//!
//! - [`cotan_laplacian`]: the symmetric positive semi-definite cotangent stiffness matrix `L`
//!   (`L_ij = -(cot α_ij + cot β_ij)/2`, rows summing to zero);
//! - [`vertex_lumped_mass`]: the lumped (barycentric) mass, a third of the incident triangle areas;
//! - [`tufted_laplacian`] / [`point_cloud_laplacian`]: the tufted intrinsic-Delaunay Laplacian of
//!   Sharp & Crane 2020 for non-manifold meshes, soups and point clouds ([`tufted`]);
//!   [`surface_operator`] picks it for meshes with non-manifold edges, the cotangent Laplacian
//!   otherwise, and is what the solver (and the heat method) use;
//! - [`Spectrum`]: the first K eigenpairs of `L φ = λ M φ`;
//! - [`compute_spectrum`] / [`LaplaceBeltramiSolver`]: the sparse eigensolver (block Lanczos
//!   shift-inverted at an interior shift, with exact null space and verification, see
//!   [`solver`]), with
//!   [`SpectrumParams`]; [`dense_spectrum`]: the exact dense reference for small meshes;
//! - [`SpectrumCache`]: spectra stored on disk, keyed by mesh content and parameters.
//!
//! Conventions: the spectrum is that of the mesh **scaled to unit total area** (so eigenvalues
//! are scale-invariant and comparable across shapes; divide by the original area to get them in
//! mesh units). Eigenvalues ascend. Eigenvectors are orthonormal in the M inner product
//! (`Φᵀ M Φ = I`), not under the plain dot product: to project a function `f` use `Φᵀ M f`.
//! Each eigenvector's sign is fixed so that its entry of largest magnitude is positive.

mod cache;
pub(crate) mod cholesky;
mod dense;
mod kernels;
pub(crate) use kernels::matmul_tall;
mod lanczos;
mod laplacian;
pub mod solver;
mod spectrum;
pub mod tufted;

pub use cache::{spectrum_cached, SpectrumCache};
pub use dense::dense_spectrum;
pub use laplacian::{
    cotan_laplacian, cotan_weights, has_non_manifold_edge, surface_operator, vertex_lumped_mass,
    LaplacianKind, SurfaceOperator,
};
pub use solver::{
    compute_spectrum, relative_residuals, LaplaceBeltramiSolver, SpectrumMethod, SpectrumParams,
    SpectrumReport, SOLVER_VERSION,
};
pub use spectrum::Spectrum;
pub use tufted::{point_cloud_laplacian, tufted_laplacian, IntrinsicLaplacian, TuftedError, TuftedParams};

use std::path::PathBuf;

use thiserror::Error;

/// The Laplace eigenproblem could not be set up or solved.
#[derive(Debug, Error)]
pub enum SpectralError {
    /// More eigenpairs were asked for than the mesh has vertices.
    #[error("asked for {wanted} eigenpairs but the mesh has only {n_vertices} vertices with area")]
    TooManyEigenpairs {
        /// Eigenpairs asked for.
        wanted: usize,
        /// Vertices of the mesh that carry area (unreferenced vertices do not count).
        n_vertices: usize,
    },
    /// The dense reference eigendecomposition did not converge.
    #[error("dense eigendecomposition did not converge")]
    DenseEigenFailed,
    /// A solver parameter is out of range.
    #[error("invalid spectrum parameter `{field}`: {reason}")]
    InvalidParams {
        /// The offending field of [`SpectrumParams`].
        field: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// Every triangle of the mesh has zero area.
    #[error("the mesh has zero surface area")]
    ZeroArea,
    /// A sparse factorisation failed.
    #[error("sparse factorisation failed: {0}")]
    Factorization(String),
    /// The iterative eigensolver did not reach the tolerance for every wanted pair.
    #[error(
        "eigensolver did not converge: {found} of {wanted} eigenpairs reached the tolerance \
         (raise max_restarts or max_basis, or loosen tol)"
    )]
    NotConverged {
        /// Eigenpairs that converged (counting from the smallest).
        found: usize,
        /// Eigenpairs asked for.
        wanted: usize,
    },
    /// The independent eigenvalue count disagrees with the computed eigenvalues: some
    /// eigenvalue was missed (typically a multiplicity above the block size).
    #[error(
        "{counted} eigenvalues lie below {threshold:.6e} but the solver found {found} \
         (increase block_size or max_basis)"
    )]
    MissedEigenvalues {
        /// Threshold of the count (unit-area eigenvalue).
        threshold: f64,
        /// Eigenvalues below the threshold according to Sylvester's law of inertia.
        counted: usize,
        /// Eigenvalues below the threshold returned by the solver.
        found: usize,
    },
    /// A spectrum and a mesh of different sizes were combined.
    #[error("spectrum has {spectrum} vertices but the mesh has {mesh}")]
    SizeMismatch {
        /// Vertices of the mesh.
        mesh: usize,
        /// Vertices of the spectrum.
        spectrum: usize,
    },
    /// Reading or writing a spectrum cache file failed.
    #[error("spectrum cache I/O on {}: {source}", path.display())]
    CacheIo {
        /// The file or directory.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A spectrum cache file is unusable (truncated, corrupted, other version or key).
    #[error("spectrum cache file {} is unusable: {reason}", path.display())]
    CacheInvalid {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
}
