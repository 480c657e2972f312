//! The [`Spectrum`] type: eigenvalues, M-orthonormal eigenvectors and the mass they refer to.

use faer::MatRef;
use serde::{Deserialize, Serialize};

/// The first K eigenpairs of `L φ = λ M φ` for a mesh scaled to unit area.
///
/// Eigenvalues ascend; eigenvectors are stored column-major (`n_vertices × k`) and satisfy
/// `Φᵀ M Φ = I` with `M = diag(mass)`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Spectrum {
    /// Eigenvalues of the unit-area mesh, ascending.
    pub eigenvalues: Vec<f64>,
    /// Eigenvectors, column-major `n_vertices × k`.
    pub eigenvectors: Vec<f64>,
    /// Number of vertices (rows of the eigenvector matrix).
    pub n_vertices: usize,
    /// Lumped mass of the unit-area mesh (length `n_vertices`, sums to 1).
    pub mass: Vec<f64>,
    /// Surface area of the original mesh; eigenvalues in mesh units are `λ / area`.
    pub area: f64,
}

impl Spectrum {
    /// Number of eigenpairs.
    pub fn k(&self) -> usize {
        self.eigenvalues.len()
    }

    /// Eigenvector `j` as a slice over vertices.
    pub fn phi(&self, j: usize) -> &[f64] {
        &self.eigenvectors[j * self.n_vertices..(j + 1) * self.n_vertices]
    }

    /// The eigenvector matrix as a faer view (`n_vertices × k`).
    pub fn vectors(&self) -> MatRef<'_, f64> {
        MatRef::from_column_major_slice(&self.eigenvectors, self.n_vertices, self.k())
    }
}
