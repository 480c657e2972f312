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

    /// The same eigenpairs normalised for a surface of area `area` instead of the mesh's own
    /// (`L` is scale-free and `M` scales with area, so `λ' = λ · area / own`,
    /// `φ' = φ · √(area / own)`, `mass' = mass · own / area`). A partial scan is normalised by
    /// the area of the whole body it comes from, so its eigenvalues and descriptors sit where
    /// a complete shape's do; see [`crate::regularizer::normalising_area`].
    pub fn renormalised(&self, area: f64) -> Spectrum {
        let r = if area > 0.0 && self.area > 0.0 { area / self.area } else { 1.0 };
        let s = r.sqrt();
        Spectrum {
            eigenvalues: self.eigenvalues.iter().map(|l| l * r).collect(),
            eigenvectors: self.eigenvectors.iter().map(|x| x * s).collect(),
            n_vertices: self.n_vertices,
            mass: self.mass.iter().map(|m| m / r).collect(),
            area: if r == 1.0 { self.area } else { area },
        }
    }

    /// The first `k` eigenpairs (all of them when there are fewer): the spectrum of a smaller
    /// solve read off a larger one, so that a shape needing both (descriptors and ZoomOut) is
    /// solved once.
    ///
    /// ```
    /// use shapeforest::spectral::Spectrum;
    /// let s = Spectrum { eigenvalues: vec![0.0, 1.0, 2.0], eigenvectors: (0..6).map(f64::from).collect(),
    ///     n_vertices: 2, mass: vec![0.5, 0.5], area: 1.0 };
    /// let t = s.leading(2);
    /// assert_eq!((t.eigenvalues.as_slice(), t.eigenvectors.as_slice()), (&[0.0, 1.0][..], &[0.0, 1.0, 2.0, 3.0][..]));
    /// ```
    pub fn leading(&self, k: usize) -> Spectrum {
        let k = k.min(self.k());
        Spectrum {
            eigenvalues: self.eigenvalues[..k].to_vec(),
            eigenvectors: self.eigenvectors[..k * self.n_vertices].to_vec(),
            n_vertices: self.n_vertices,
            mass: self.mass.clone(),
            area: self.area,
        }
    }

    /// The eigenpairs restricted to the first `n` vertices (rows): the spectrum of a mesh with
    /// vertices appended (holes closed, see [`crate::mesh::fill_holes`]) read on the original
    /// vertices. The eigenvalues and the area are unchanged.
    pub fn restricted(&self, n: usize) -> Spectrum {
        let n = n.min(self.n_vertices);
        let mut eigenvectors = Vec::with_capacity(n * self.k());
        for j in 0..self.k() {
            eigenvectors.extend_from_slice(&self.phi(j)[..n]);
        }
        Spectrum {
            eigenvalues: self.eigenvalues.clone(),
            eigenvectors,
            n_vertices: n,
            mass: self.mass[..n].to_vec(),
            area: self.area,
        }
    }
}
