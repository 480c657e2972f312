//! Orientation cues for the regulariser: the agreement of test and reference orientation
//! descriptors, which tells a map from its mirror image.

use super::*;
use crate::descriptor::{band_pass_functions, orientation_band_energies, orientation_descriptors};

/// The orientation descriptors of a test and a reference shape, from the same band-pass
/// energies (chosen on the reference spectrum), as row-major `n × width` tables.
pub(super) struct Orientation {
    test: Vec<f64>,
    reference: Vec<f64>,
    width: usize,
    /// Squared norm of each test and reference vertex's descriptor (0 for an empty one).
    test_norms: Vec<f64>,
    reference_norms: Vec<f64>,
}

impl Orientation {
    pub(super) fn of(test: &PreparedShape, reference: &PreparedShape) -> Self {
        // Five bands over the reference's low spectrum, used on both shapes.
        let energies = orientation_band_energies(&reference.spectrum, 5);
        let o_test =
            orientation_descriptors(&test.mesh, band_pass_functions(&test.spectrum, &energies).as_ref());
        let o_ref = orientation_descriptors(
            &reference.mesh,
            band_pass_functions(&reference.spectrum, &energies).as_ref(),
        );
        let width = o_test.len() / test.mesh.n_vertices().max(1);
        // One norm per vertex, also when the descriptors are empty (a spectrum too short for two
        // bands: width 0, every agreement 0).
        let norms = |o: &[f64], n: usize| -> Vec<f64> {
            (0..n).map(|v| o[v * width..(v + 1) * width].iter().fold(0.0, |s, x| s + x * x)).collect()
        };
        let test_norms = norms(&o_test, test.mesh.n_vertices());
        let reference_norms = norms(&o_ref, reference.mesh.n_vertices());
        Self { test: o_test, reference: o_ref, width, test_norms, reference_norms }
    }

    /// Agreement (cosine, in [−1, 1]) of test vertex `m`'s descriptor with reference vertex `r`'s:
    /// positive where matching `m` to `r` preserves orientation.
    pub(super) fn agreement(&self, m: usize, r: usize) -> f64 {
        let w = self.width;
        let (a, b) = (&self.test[m * w..(m + 1) * w], &self.reference[r * w..(r + 1) * w]);
        let ab = a.iter().zip(b).fold(0.0, |s, (x, y)| s + x * y);
        let (aa, bb) = (self.test_norms[m], self.reference_norms[r]);
        if aa > 0.0 && bb > 0.0 {
            ab / (aa * bb).sqrt()
        } else {
            0.0
        }
    }

    /// Mean agreement along a map (test vertex → reference vertex).
    pub(super) fn mean_agreement(&self, map: &[usize]) -> f64 {
        map.iter().enumerate().map(|(m, &r)| self.agreement(m, r)).sum::<f64>() / map.len().max(1) as f64
    }
}
