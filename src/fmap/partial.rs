//! ZoomOut for a partial test shape (a scan that covers part of the reference).
//!
//! [`super::zoomout_on_samples`] fits square `k × k` functional maps: the test shape's first `k`
//! eigenfunctions against the reference's first `k`. That assumes both shapes are the whole
//! surface. A part `M` of a surface `R` (area ratio `r < 1`, spectrum normalised by `R`'s area)
//! has sparser eigenvalues (Weyl's law: `λ_i ≈ 4πi / area`), so its `i`-th eigenfunction
//! resembles `R`'s around the `i/r`-th one, and the functional map of the part is a
//! `k_M × k_R` matrix whose non-zeros lie along a slanted diagonal of slope `r` and whose rank is
//! about `r·k_R` (Rodolà et al. 2017, "Partial functional correspondence"). Fitting a square map
//! forces the part's extra eigenfunctions onto reference functions that have no counterpart on
//! the part, which pulls the point map towards the missing region.
//!
//! Here each ZoomOut step takes `k_R` reference eigenfunctions and the `k_M` test eigenfunctions
//! whose eigenvalues are at most the `k_R`-th reference eigenvalue ([`partial_basis_size`]: the
//! slope read off the two spectra, which also accounts for the boundary), fits the rectangular
//! `k_M × k_R` map on samples of both shapes (area-weighted least squares, as the square
//! version), and reads the point map from the part into the whole reference only (every test
//! vertex looks for its nearest reference row; reference points outside the part's image are
//! simply never chosen). With `k_M = k_R` at every step this is the square ZoomOut.

use faer::{Mat, MatRef};

use super::{
    basis, check_basis, mapped_reference_rows, nearest_rows_single,
    sampled::{basis_rows, check_map, check_sizes, SampledFit},
    FmapError, SampleCells, ZoomOutSchedule,
};
use crate::spectral::Spectrum;

/// How many eigenfunctions of the part (`test`) go with the first `k_ref` eigenfunctions of the
/// reference: those whose eigenvalue is at most the reference's `k_ref`-th (at least 1, at most
/// `k_ref` and the part's `K`). Both spectra must be normalised by the same area (a partial scan
/// by the reference's, see `regularizer::normalising_area`).
///
/// ```
/// use shapeforest::{fmap::partial_basis_size, spectral::dense_spectrum, synth::icosphere};
/// let s = dense_spectrum(&icosphere(2, 1.0), 16).unwrap();
/// // A shape against itself: the square map.
/// assert_eq!(partial_basis_size(&s, &s, 16), 16);
/// ```
pub fn partial_basis_size(test: &Spectrum, reference: &Spectrum, k_ref: usize) -> usize {
    let k_ref = k_ref.min(reference.k()).max(1);
    let limit = reference.eigenvalues[k_ref - 1];
    let tol = 1e-9 * limit.abs().max(1.0);
    let n = test.eigenvalues.iter().take_while(|&&l| l <= limit + tol).count();
    n.clamp(1, k_ref.min(test.k()).max(1))
}

/// ZoomOut of the point map `map` (part vertex → reference vertex) with rectangular functional
/// maps sized by [`partial_basis_size`], run on the samples of `test_cells` and
/// `reference_cells` (see [`super::zoomout_on_samples`]; the schedule counts reference
/// eigenfunctions). Returns the final `k_M × k_R` map (pulling back from the reference); read it
/// back on every test vertex with [`point_to_point_partial`].
pub fn zoomout_partial_on_samples(
    test: &Spectrum,
    test_cells: &SampleCells,
    reference: &Spectrum,
    reference_cells: &SampleCells,
    map: &[usize],
    schedule: ZoomOutSchedule,
) -> Result<Mat<f64>, FmapError> {
    schedule.check_steps()?;
    let kf = schedule.k_final;
    check_basis("reference", reference, kf)?;
    let kmf = partial_basis_size(test, reference, kf);
    check_basis("test", test, kmf)?;
    check_sizes(test, test_cells, reference, reference_cells, map)?;
    check_map(map, reference, None, reference_cells)?;
    let phi_t = basis_rows(test, &test_cells.samples, kmf);
    let phi_r = basis_rows(reference, &reference_cells.samples, kf);
    // C (k_M × k_R) minimising Σ_i w_i |Φ_M[s_i, :k_M] C − Φ_R[t_i, :k_R]|².
    let fit = SampledFit::new(phi_t.as_ref(), &test_cells.cell_areas(&test.mass));
    let first: Vec<usize> = test_cells.samples.iter().map(|&s| map[s]).collect();
    let phi_ref = basis(reference, kf);
    let mut k = schedule.k_start;
    let mut km = partial_basis_size(test, reference, k);
    let mut c = fit.fit(km, k, &|i, j| phi_ref[(first[i], j)])?;
    loop {
        // Part samples onto reference samples: rows of Φ_M[:, :k_M] against Φ_R[:, :k_R] Cᵀ.
        let points = mapped_reference_rows(phi_r.subcols(0, k), c.as_ref());
        let t = nearest_rows_single(phi_t.subcols(0, km), points.as_ref());
        let last = k == kf;
        k = (k + schedule.step).min(kf);
        km = partial_basis_size(test, reference, k);
        c = fit.fit(km, k, &|i, j| phi_r[(t[i], j)])?;
        if last {
            return Ok(c);
        }
    }
}

/// The point map of a rectangular `c` (`k_M × k_R`, from [`zoomout_partial_on_samples`]) on
/// every test vertex: the row of `Φ_M[:, :k_M]` against the rows of `Φ_R[:, :k_R] Cᵀ`, searched
/// among the reference samples first and then among the vertices of the nearest sample's cell
/// and its neighbouring cells (as [`super::point_to_point_in_cells`]).
pub fn point_to_point_partial(
    test: &Spectrum,
    reference: &Spectrum,
    reference_cells: &SampleCells,
    c: MatRef<'_, f64>,
) -> Result<Vec<usize>, FmapError> {
    let (km, kr) = (c.nrows(), c.ncols());
    check_basis("test", test, km)?;
    check_basis("reference", reference, kr)?;
    if reference_cells.n_vertices() != reference.n_vertices {
        return Err(FmapError::SizeMismatch(format!(
            "cells of {} vertices for a reference of {}",
            reference_cells.n_vertices(),
            reference.n_vertices
        )));
    }
    let points = mapped_reference_rows(basis(reference, kr), c);
    let queries = basis(test, km);
    let sample_points =
        Mat::from_fn(reference_cells.samples.len(), km, |i, j| points[(reference_cells.samples[i], j)]);
    let coarse = nearest_rows_single(queries, sample_points.as_ref());
    Ok(super::sampled::nearest_in_cells(queries, points.as_ref(), reference_cells, &coarse))
}
