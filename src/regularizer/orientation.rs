//! Orientation cues for the regulariser: the agreement of test and reference orientation
//! descriptors, which tells a map from its mirror image.

use super::*;
use crate::descriptor::{band_pass_functions, orientation_band_energies, orientation_descriptors};

/// The orientation descriptors of a test and a reference shape, from the same band-pass
/// energies (chosen on the reference spectrum).
pub(super) struct Orientation {
    test: Arc<OrientationSide>,
    reference: Arc<OrientationSide>,
    width: usize,
}

/// One shape's orientation descriptors at some band energies, as a row-major `n × width`
/// table, and the squared norm of each vertex's descriptor (0 for an empty one).
pub(super) struct OrientationSide {
    descriptors: Vec<f64>,
    norms: Vec<f64>,
}

impl OrientationSide {
    /// `shape`'s descriptors at `energies`, made once per shape and energies
    /// ([`PreparedShape`] keeps them).
    fn of(shape: &PreparedShape, energies: &[f64]) -> Arc<Self> {
        shape.kept.orientation.get_or_insert_with(shape, energies.to_vec(), || {
            let n = shape.mesh.n_vertices();
            let descriptors =
                orientation_descriptors(&shape.mesh, band_pass_functions(&shape.spectrum, energies).as_ref());
            // One norm per vertex, also when the descriptors are empty (a spectrum too short for
            // two bands: width 0, every agreement 0).
            let width = descriptors.len() / n.max(1);
            let norms = (0..n)
                .map(|v| descriptors[v * width..(v + 1) * width].iter().fold(0.0, |s, x| s + x * x))
                .collect();
            Self { descriptors, norms }
        })
    }
}

impl Orientation {
    pub(super) fn of(test: &PreparedShape, reference: &PreparedShape) -> Self {
        // Five bands over the reference's low spectrum, used on both shapes.
        let energies = orientation_band_energies(&reference.spectrum, 5);
        let (test_side, reference_side) = rayon::join(
            || OrientationSide::of(test, &energies),
            || OrientationSide::of(reference, &energies),
        );
        let width = test_side.descriptors.len() / test.mesh.n_vertices().max(1);
        Self { test: test_side, reference: reference_side, width }
    }

    /// Agreement (cosine, in [−1, 1]) of test vertex `m`'s descriptor with reference vertex `r`'s:
    /// positive where matching `m` to `r` preserves orientation.
    pub(super) fn agreement(&self, m: usize, r: usize) -> f64 {
        let w = self.width;
        let (a, b) =
            (&self.test.descriptors[m * w..(m + 1) * w], &self.reference.descriptors[r * w..(r + 1) * w]);
        let ab = a.iter().zip(b).fold(0.0, |s, (x, y)| s + x * y);
        let (aa, bb) = (self.test.norms[m], self.reference.norms[r]);
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
