//! Wave kernel signature (Aubry, Schlickewei, Cremers, "The wave kernel signature: a quantum
//! mechanical approach to shape analysis", ICCV workshops 2011).

use faer::Mat;
use serde::{Deserialize, Serialize};

use super::{check_spectrum, first_nonzero_eigenvalue, DescriptorError};
use crate::spectral::Spectrum;

/// Parameters of the wave kernel signature.
#[derive(Clone, Debug, PartialEq)]
pub struct WksParams {
    /// Number of log-energies `N` (default 100).
    pub n_energies: usize,
    /// Band-pass width factor: `σ = sigma_factor · (e_max - e_min) / N` (default 7, Aubry's).
    pub sigma_factor: f64,
}

impl Default for WksParams {
    fn default() -> Self {
        Self { n_energies: 100, sigma_factor: 7.0 }
    }
}

impl WksParams {
    /// Checks `n_energies ≥ 1` and `sigma_factor > 0`.
    pub fn check(&self) -> Result<(), DescriptorError> {
        if self.n_energies == 0 {
            return Err(DescriptorError::InvalidParameter {
                name: "n_energies",
                reason: "must be at least 1".into(),
            });
        }
        if !(self.sigma_factor > 0.0 && self.sigma_factor.is_finite()) {
            return Err(DescriptorError::InvalidParameter {
                name: "sigma_factor",
                reason: format!("must be a finite number greater than 0, got {}", self.sigma_factor),
            });
        }
        Ok(())
    }

    /// The energy range of one spectrum: `e_min = log λ_1` (first nonzero),
    /// `e_max = log λ_K`, `σ = sigma_factor · (e_max - e_min) / N`.
    pub fn energy_range(&self, spectrum: &Spectrum) -> Result<EnergyRange, DescriptorError> {
        self.check()?;
        check_spectrum(spectrum)?;
        let ev = &spectrum.eigenvalues;
        let first = first_nonzero_eigenvalue(ev);
        let nonzero = first.map_or(0, |f| ev.len() - f);
        if nonzero < 2 {
            return Err(DescriptorError::DegenerateSpectrum { k: ev.len(), nonzero, needed: 2 });
        }
        let (e_min, e_max) = (ev[first.unwrap_or(0)].ln(), ev[ev.len() - 1].ln());
        self.range_from(e_min, e_max)
    }

    /// The energy range `[e_min, e_max]` with this parameter set's `σ`.
    pub fn range_from(&self, e_min: f64, e_max: f64) -> Result<EnergyRange, DescriptorError> {
        self.check()?;
        if !(e_min.is_finite() && e_max.is_finite() && e_max > e_min) {
            return Err(DescriptorError::InvalidParameter {
                name: "energy range",
                reason: format!("need finite e_min < e_max, got [{e_min}, {e_max}]"),
            });
        }
        let sigma = self.sigma_factor * (e_max - e_min) / self.n_energies as f64;
        Ok(EnergyRange { e_min, e_max, sigma })
    }
}

/// A log-energy interval and the band-pass width used on it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct EnergyRange {
    /// Smallest log-energy (`log λ` of the first nonzero eigenvalue).
    pub e_min: f64,
    /// Largest log-energy (`log λ_K`).
    pub e_max: f64,
    /// Width `σ` of the log-normal band-pass filter.
    pub sigma: f64,
}

impl EnergyRange {
    /// `n` log-energies evenly spaced over `[e_min, e_max]` (both ends included when `n ≥ 2`).
    ///
    /// ```
    /// use shapeforest::descriptor::EnergyRange;
    /// let r = EnergyRange { e_min: 0.0, e_max: 1.0, sigma: 0.1 };
    /// assert_eq!(r.energies(3), vec![0.0, 0.5, 1.0]);
    /// ```
    pub fn energies(&self, n: usize) -> Vec<f64> {
        (0..n)
            .map(|i| {
                let f = if n <= 1 { 0.5 } else { i as f64 / (n - 1) as f64 };
                self.e_min + f * (self.e_max - self.e_min)
            })
            .collect()
    }
}

/// The squared log-normal band-pass `f_e(λ)² = exp(-(e - log λ)² / (2σ²))` (as in Aubry's
/// reference code); 0 for `λ ≤ 0` (zero eigenvalues are skipped).
///
/// ```
/// use shapeforest::descriptor::wks_filter_sq;
/// assert!((wks_filter_sq(2.0f64.ln(), 2.0, 0.5) - 1.0).abs() < 1e-15);
/// assert!((wks_filter_sq(0.0, 1.0f64.exp(), 1.0) - (-0.5f64).exp()).abs() < 1e-15);
/// assert_eq!(wks_filter_sq(0.0, 0.0, 1.0), 0.0);
/// ```
pub fn wks_filter_sq(e: f64, lambda: f64, sigma: f64) -> f64 {
    if lambda <= 0.0 {
        return 0.0;
    }
    let d = e - lambda.ln();
    (-d * d / (2.0 * sigma * sigma)).exp()
}

/// Wave kernel signature of every vertex, as an `n_vertices × N` matrix:
/// `w(m, e_j) = Σ_k f_{e_j}(λ_k)² φ_k(m)² / C_{e_j}` with `C_e = Σ_k f_e(λ_k)²`, for the `N`
/// energies of `range.energies(N)`. Pass `range = None` to use the spectrum's own range
/// ([`WksParams::energy_range`]); pass a shared range to compare descriptors across shapes.
/// Zero eigenvalues are skipped. Entries are non-negative.
pub fn wave_kernel_signature(
    spectrum: &Spectrum,
    params: &WksParams,
    range: Option<EnergyRange>,
) -> Result<Mat<f64>, DescriptorError> {
    params.check()?;
    check_spectrum(spectrum)?;
    let range = match range {
        Some(r) => params.range_from(r.e_min, r.e_max).map(|_| r)?,
        None => params.energy_range(spectrum)?,
    };
    if !(range.sigma > 0.0 && range.sigma.is_finite()) {
        return Err(DescriptorError::InvalidParameter {
            name: "sigma",
            reason: format!("must be a finite number greater than 0, got {}", range.sigma),
        });
    }
    let energies = range.energies(params.n_energies);
    let n = spectrum.n_vertices;
    let k = spectrum.k();
    // Weight matrix W (k × N), normalised per column by C_e, then out = Φ² W.
    let mut w = Mat::<f64>::zeros(k, energies.len());
    for (j, &e) in energies.iter().enumerate() {
        let mut c = 0.0;
        for kk in 0..k {
            let f = wks_filter_sq(e, spectrum.eigenvalues[kk], range.sigma);
            w[(kk, j)] = f;
            c += f;
        }
        if c > 0.0 {
            for kk in 0..k {
                w[(kk, j)] /= c;
            }
        }
    }
    let phi_sq = Mat::<f64>::from_fn(n, k, |i, kk| {
        let v = spectrum.eigenvectors[kk * n + i];
        v * v
    });
    let mut out = Mat::<f64>::zeros(n, energies.len());
    crate::spectral::matmul_tall(
        out.as_mut(),
        faer::Accum::Replace,
        phi_sq.as_ref(),
        w.as_ref(),
        1.0,
        faer::Par::Seq,
    );
    Ok(out)
}
