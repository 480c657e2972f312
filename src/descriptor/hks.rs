//! Heat kernel signature (Sun, Ovsjanikov, Guibas, "A concise and provably informative
//! multi-scale signature based on heat diffusion", SGP 2009).

use faer::Mat;

use super::{check_spectrum, first_nonzero_eigenvalue, DescriptorError};
use crate::spectral::Spectrum;

/// Parameters of the heat kernel signature.
#[derive(Clone, Debug, PartialEq)]
pub struct HksParams {
    /// Number of diffusion times `T` (default 100), log-spaced over
    /// `[4 ln 10 / λ_max, 4 ln 10 / λ_1]`.
    pub n_times: usize,
}

impl Default for HksParams {
    fn default() -> Self {
        Self { n_times: 100 }
    }
}

/// The diffusion times of Sun et al.: `n` values log-spaced from `4 ln 10 / λ_max` to
/// `4 ln 10 / λ_min`, ascending (`λ_min` the first nonzero eigenvalue).
///
/// ```
/// use shapeforest::descriptor::hks_times;
/// let t = hks_times(1.0, 100.0, 3).unwrap();
/// let l = 4.0 * 10f64.ln();
/// assert!((t[0] - l / 100.0).abs() < 1e-12 && (t[2] - l).abs() < 1e-12);
/// assert!((t[1] - l / 10.0).abs() < 1e-12);
/// ```
pub fn hks_times(lambda_min: f64, lambda_max: f64, n: usize) -> Result<Vec<f64>, DescriptorError> {
    if n == 0 {
        return Err(DescriptorError::InvalidParameter {
            name: "n_times",
            reason: "must be at least 1".into(),
        });
    }
    if !(lambda_min > 0.0 && lambda_max >= lambda_min && lambda_max.is_finite()) {
        return Err(DescriptorError::InvalidParameter {
            name: "eigenvalue range",
            reason: format!("need 0 < λ_min ≤ λ_max, got [{lambda_min}, {lambda_max}]"),
        });
    }
    let c = 4.0 * 10f64.ln();
    let (lo, hi) = ((c / lambda_max).ln(), (c / lambda_min).ln());
    Ok((0..n)
        .map(|i| {
            let f = if n == 1 { 0.0 } else { i as f64 / (n - 1) as f64 };
            (lo + f * (hi - lo)).exp()
        })
        .collect())
}

/// Heat kernel signature `h(m, t) = Σ_k e^{-λ_k t} φ_k(m)²` of every vertex, as an
/// `n_vertices × T` matrix (column `j` is time `t_j` of [`hks_times`], ascending). All eigenpairs
/// are summed; the times are set by the first nonzero and the largest eigenvalue.
///
/// Each entry is non-increasing in `t`.
pub fn heat_kernel_signature(spectrum: &Spectrum, params: &HksParams) -> Result<Mat<f64>, DescriptorError> {
    check_spectrum(spectrum)?;
    let first = first_nonzero_eigenvalue(&spectrum.eigenvalues)
        .ok_or(DescriptorError::DegenerateSpectrum { k: spectrum.k(), nonzero: 0, needed: 1 })?;
    let lmax = spectrum.eigenvalues[spectrum.k() - 1];
    let times = hks_times(spectrum.eigenvalues[first], lmax, params.n_times)?;
    let n = spectrum.n_vertices;
    let mut out = Mat::<f64>::zeros(n, times.len());
    for k in 0..spectrum.k() {
        let lambda = spectrum.eigenvalues[k].max(0.0);
        let phi = spectrum.phi(k);
        for (j, &t) in times.iter().enumerate() {
            let w = (-lambda * t).exp();
            let mut col = out.col_mut(j);
            for i in 0..n {
                col[i] += w * phi[i] * phi[i];
            }
        }
    }
    Ok(out)
}
