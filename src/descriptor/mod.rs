//! Spectral point descriptors: the heat kernel signature (HKS), the wave kernel signature (WKS)
//! and the parametric WKS `p(m; e, k̄)` that the random forest splits on.
//!
//! All three are functions of a [`Spectrum`](crate::spectral::Spectrum) `(λ_k, φ_k)` of the
//! **unit-area** mesh (so they are invariant to a global scaling of the shape), with eigenvalues
//! ascending and eigenvectors orthonormal in the mass inner product. They only use the squares
//! `φ_k(m)²`, so they are invariant to the sign of each eigenvector and, when a whole eigenspace
//! is summed, to any rotation within a repeated eigenvalue's eigenspace.
//!
//! - [`heat_kernel_signature`] (Sun, Ovsjanikov, Guibas 2009):
//!   `h(m, t) = Σ_k e^{-λ_k t} φ_k(m)²`, at `T` times log-spaced over
//!   `[4 ln 10 / λ_max, 4 ln 10 / λ_1]` (λ_1 the first nonzero eigenvalue).
//! - [`wave_kernel_signature`] (Aubry, Schlickewei, Cremers 2011):
//!   `w(m, e) = Σ_k f_e(λ_k)² φ_k(m)² / C_e` with the log-normal band-pass
//!   `f_e(λ)² = exp(-(e - log λ)² / (2σ²))` and `C_e = Σ_k f_e(λ_k)²`, at `N` log-energies
//!   evenly spaced over `[log λ_1, log λ_K]`, `σ = 7 (e_max - e_min) / N` (Aubry's defaults).
//! - [`ParametricWks`] (Rodolà et al. 2014, Eq. 3): the un-normalised, truncated WKS
//!   `p(m; e, k̄) = Σ_{k<k̄} f_e(λ_k)² φ_k(m)²`, where `k̄` counts eigenpairs from the first
//!   (index 0). Built for millions of evaluations: `φ_k(m)²` is precomputed per shape, row-major
//!   per vertex, and the weights `w_k = f_e(λ_k)²` are computed once per `(shape, e)`.
//!
//! - [`LocalDescriptor`]: not spectral: SHOT-like histograms of the surface in a small ball
//!   around each vertex ([`LocalParams`]), which survive holes and missing parts that change
//!   every eigenfunction; a forest can split on them besides the parametric WKS.
//!
//! Zero eigenvalues (the constant eigenvector, one per connected component) are skipped by
//! every descriptor: `log 0` is undefined and they carry no geometry. An eigenvalue is treated as
//! zero when it is at most `1e-8 · λ_max` (see [`first_nonzero_eigenvalue`]).

mod hks;
mod local;
mod orientation;
mod parametric;
mod wks;

pub use hks::{heat_kernel_signature, hks_times, HksParams};
pub use local::{LocalDescriptor, LocalParams, MAX_LOCAL_DIM, MIN_NEIGHBOURS};
pub use orientation::{band_pass_functions, orientation_band_energies, orientation_descriptors};
#[cfg(target_arch = "x86_64")]
pub(crate) use parametric::dot_f32_avx;
pub use parametric::{dot_f32, EnergyGrid, ParametricWks};
pub use wks::{wave_kernel_signature, wks_filter_sq, EnergyRange, WksParams};

use thiserror::Error;

/// Descriptor parameters were invalid.
#[derive(Debug, Error)]
pub enum DescriptorError {
    /// A parameter is out of its valid range.
    #[error("invalid descriptor parameter `{name}`: {reason}")]
    InvalidParameter {
        /// Parameter name.
        name: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// The spectrum has no nonzero eigenvalue (or too few eigenpairs) to build the descriptor.
    #[error("the spectrum has {k} eigenpairs and {nonzero} nonzero eigenvalues; the descriptor needs at least {needed} nonzero")]
    DegenerateSpectrum {
        /// Eigenpairs in the spectrum.
        k: usize,
        /// Nonzero eigenvalues among them.
        nonzero: usize,
        /// Nonzero eigenvalues needed.
        needed: usize,
    },
    /// The spectrum is malformed (eigenvector storage does not match `n_vertices × k`, or an
    /// eigenvalue is negative or not finite).
    #[error("malformed spectrum: {0}")]
    MalformedSpectrum(String),
}

/// Index of the first eigenvalue that is not (numerically) zero: the first `λ_k > 1e-8 · λ_max`.
/// Returns `None` when every eigenvalue is zero (or the list is empty).
///
/// ```
/// use shapeforest::descriptor::first_nonzero_eigenvalue;
/// assert_eq!(first_nonzero_eigenvalue(&[1e-13, 2.0, 6.0]), Some(1));
/// assert_eq!(first_nonzero_eigenvalue(&[0.0, 0.0, 3.0]), Some(2));
/// assert_eq!(first_nonzero_eigenvalue(&[0.0]), None);
/// ```
pub fn first_nonzero_eigenvalue(eigenvalues: &[f64]) -> Option<usize> {
    let max = eigenvalues.iter().cloned().fold(0.0_f64, f64::max);
    if max <= 0.0 {
        return None;
    }
    eigenvalues.iter().position(|&l| l > 1e-8 * max)
}

/// Checks that a spectrum's storage is consistent and its eigenvalues finite and non-negative
/// (tiny negative round-off above `-1e-8 · λ_max` is accepted).
pub(crate) fn check_spectrum(s: &crate::spectral::Spectrum) -> Result<(), DescriptorError> {
    if s.eigenvectors.len() != s.n_vertices * s.k() {
        return Err(DescriptorError::MalformedSpectrum(format!(
            "{} eigenvector entries for {} vertices × {} eigenpairs",
            s.eigenvectors.len(),
            s.n_vertices,
            s.k()
        )));
    }
    let max = s.eigenvalues.iter().cloned().fold(0.0_f64, f64::max);
    for (k, &l) in s.eigenvalues.iter().enumerate() {
        if !l.is_finite() || l < -1e-8 * max.max(1.0) {
            return Err(DescriptorError::MalformedSpectrum(format!("eigenvalue {k} is {l}")));
        }
    }
    Ok(())
}
