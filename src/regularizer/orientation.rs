//! Orientation cues for the regulariser: band-pass functions of the reference spectrum and the
//! agreement of test and reference orientation descriptors (tells a map from its mirror image).

use super::*;
use crate::descriptor::{orientation_descriptors, wks_filter_sq};

/// The orientation descriptors of a test and a reference shape, from the same band-pass
/// energies (chosen on the reference spectrum), as row-major `n × width` tables.
pub(super) struct Orientation {
    test: Vec<f64>,
    reference: Vec<f64>,
    width: usize,
}

impl Orientation {
    pub(super) fn of(test: &PreparedShape, reference: &PreparedShape) -> Self {
        let energies = orientation_energies(&reference.spectrum);
        let o_test =
            orientation_descriptors(&test.mesh, orientation_functions(&test.spectrum, &energies).as_ref());
        let o_ref = orientation_descriptors(
            &reference.mesh,
            orientation_functions(&reference.spectrum, &energies).as_ref(),
        );
        let width = o_test.len() / test.mesh.n_vertices().max(1);
        Self { test: o_test, reference: o_ref, width }
    }

    /// Agreement (cosine, in [−1, 1]) of test vertex `m`'s descriptor with reference vertex `r`'s:
    /// positive where matching `m` to `r` preserves orientation.
    pub(super) fn agreement(&self, m: usize, r: usize) -> f64 {
        let w = self.width;
        cosine(&self.test[m * w..(m + 1) * w], &self.reference[r * w..(r + 1) * w])
    }

    /// Mean agreement along a map (test vertex → reference vertex).
    pub(super) fn mean_agreement(&self, map: &[usize]) -> f64 {
        map.iter().enumerate().map(|(m, &r)| self.agreement(m, r)).sum::<f64>() / map.len().max(1) as f64
    }
}

/// Log-energies of the band-pass functions behind the orientation descriptors: five, spread
/// over the low part of the reference spectrum (eigenvalues 1 to ~30), where descriptors are
/// smooth enough for stable gradients.
fn orientation_energies(reference: &Spectrum) -> Vec<f64> {
    let lam = &reference.eigenvalues;
    let first = lam.iter().position(|&l| l > 1e-9 * lam.last().copied().unwrap_or(1.0)).unwrap_or(0);
    let last = (first + 30).min(lam.len().saturating_sub(1));
    let (lo, hi) = (lam[first].max(1e-12).ln(), lam[last].max(1e-12).ln());
    (0..5).map(|i| lo + (hi - lo) * (i as f64 + 0.5) / 5.0).collect()
}

/// Band-pass (WKS-like) functions at the given log-energies, normalised per energy.
fn orientation_functions(spectrum: &Spectrum, energies: &[f64]) -> Mat<f64> {
    let sigma = if energies.len() > 1 {
        (energies[energies.len() - 1] - energies[0]) / (energies.len() - 1) as f64
    } else {
        1.0
    };
    let n = spectrum.n_vertices;
    let mut f = Mat::zeros(n, energies.len());
    for (c, &e) in energies.iter().enumerate() {
        let w: Vec<f64> = spectrum
            .eigenvalues
            .iter()
            .map(|&l| if l > 0.0 { wks_filter_sq(e, l, sigma) } else { 0.0 })
            .collect();
        let norm: f64 = w.iter().sum::<f64>().max(f64::MIN_POSITIVE);
        for (k, &wk) in w.iter().enumerate() {
            if wk > 1e-12 * norm {
                let phi = spectrum.phi(k);
                for v in 0..n {
                    f[(v, c)] += wk / norm * phi[v] * phi[v];
                }
            }
        }
    }
    f
}

fn cosine(a: &[f64], b: &[f64]) -> f64 {
    let (mut ab, mut aa, mut bb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        ab += x * y;
        aa += x * x;
        bb += y * y;
    }
    if aa > 0.0 && bb > 0.0 {
        ab / (aa * bb).sqrt()
    } else {
        0.0
    }
}
