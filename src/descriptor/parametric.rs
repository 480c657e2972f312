//! The parametric wave kernel signature of Rodolà et al. (CVPR 2014, Eq. 3):
//! `p(m; e, k̄) = Σ_{k<k̄} f_e(λ_k)² φ_k(m)²`.

use serde::{Deserialize, Serialize};

use super::{check_spectrum, first_nonzero_eigenvalue, wks_filter_sq, DescriptorError, EnergyRange};
use crate::spectral::Spectrum;

/// Per-shape precomputation for fast evaluation of `p(m; e, k̄)`.
///
/// Stores `φ_k(m)²` as `f32`, **row-major per vertex** (`k` values per vertex contiguous), so
/// evaluating one vertex reads one short contiguous row, and the eigenvalues of this shape
/// (needed for the weights `w_k = f_e(λ_k)²`, which differ between shapes).
///
/// ```
/// use shapeforest::{descriptor::ParametricWks, spectral::dense_spectrum, synth::icosphere};
/// let s = dense_spectrum(&icosphere(1, 1.0), 10).unwrap();
/// let pw = ParametricWks::new(&s, 10).unwrap();
/// let mut w = vec![0.0f32; 10];
/// pw.weights(3.5, 0.3, &mut w);
/// assert_eq!(w[0], 0.0); // the zero eigenvalue is skipped
/// let p = pw.eval(0, &w, 10);
/// assert!(p > 0.0);
/// ```
#[derive(Clone, Debug)]
pub struct ParametricWks {
    n_vertices: usize,
    k: usize,
    phi_sq: Vec<f32>,
    eigenvalues: Vec<f64>,
}

impl ParametricWks {
    /// Precomputes `φ_k(m)²` for the first `k` eigenpairs of `spectrum`.
    /// Fails when `k` exceeds the spectrum's eigenpairs, `k < 2`, or the spectrum is malformed.
    pub fn new(spectrum: &Spectrum, k: usize) -> Result<Self, DescriptorError> {
        check_spectrum(spectrum)?;
        if k < 2 || k > spectrum.k() {
            return Err(DescriptorError::InvalidParameter {
                name: "k",
                reason: format!("must be between 2 and the spectrum's {} eigenpairs, got {k}", spectrum.k()),
            });
        }
        let n = spectrum.n_vertices;
        let mut phi_sq = vec![0.0f32; n * k];
        for kk in 0..k {
            let phi = spectrum.phi(kk);
            for (i, &v) in phi.iter().enumerate() {
                phi_sq[i * k + kk] = (v * v) as f32;
            }
        }
        let mut eigenvalues = spectrum.eigenvalues[..k].to_vec();
        // Zero eigenvalues get weight 0 (log 0 is undefined): mark them as exactly 0.
        let first = first_nonzero_eigenvalue(&eigenvalues).unwrap_or(k);
        for l in eigenvalues.iter_mut().take(first) {
            *l = 0.0;
        }
        Ok(Self { n_vertices: n, k, phi_sq, eigenvalues })
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.n_vertices
    }

    /// Number of eigenpairs `K` kept.
    pub fn k(&self) -> usize {
        self.k
    }

    /// The eigenvalues used (zero ones set to exactly 0).
    pub fn eigenvalues(&self) -> &[f64] {
        &self.eigenvalues
    }

    /// `φ_k(m)²` for `k < K` of vertex `m`.
    #[inline]
    pub fn row(&self, vertex: usize) -> &[f32] {
        &self.phi_sq[vertex * self.k..(vertex + 1) * self.k]
    }

    /// Writes the weights `w_k = f_e(λ_k)²` of this shape's eigenvalues into `out[..K]`
    /// (0 for zero eigenvalues). `out` must hold at least `K` values.
    pub fn weights(&self, e: f64, sigma: f64, out: &mut [f32]) {
        for (o, &l) in out[..self.k].iter_mut().zip(&self.eigenvalues) {
            *o = wks_filter_sq(e, l, sigma) as f32;
        }
    }

    /// `p(m; e, k̄)` for one vertex, given the weights of [`Self::weights`]; `k̄ ≤ K`.
    #[inline]
    pub fn eval(&self, vertex: usize, weights: &[f32], k_bar: usize) -> f32 {
        dot_f32(&weights[..k_bar], &self.row(vertex)[..k_bar])
    }

    /// `p(m; e, k̄)` for many vertices with one weight vector, into `out` (same length as
    /// `vertices`).
    pub fn eval_many(&self, vertices: &[u32], weights: &[f32], k_bar: usize, out: &mut [f32]) {
        let w = &weights[..k_bar];
        for (o, &v) in out.iter_mut().zip(vertices) {
            *o = dot_f32(w, &self.row(v as usize)[..k_bar]);
        }
    }

    /// The weight table of an [`EnergyGrid`] for this shape: `levels × K` values,
    /// row `i` holding `f_{e_i}(λ_k)²`.
    pub fn weight_table(&self, grid: &EnergyGrid) -> Vec<f32> {
        let mut t = vec![0.0f32; grid.levels as usize * self.k];
        for (i, row) in t.chunks_exact_mut(self.k).enumerate() {
            self.weights(grid.energy(i), grid.range.sigma, row);
        }
        t
    }
}

/// A discrete grid of `levels` log-energies evenly spaced over an [`EnergyRange`].
///
/// The forest draws `e` from this grid rather than from the continuum so that the weights
/// `f_e(λ_k)²` of a shape can be tabulated once (`levels × K`) and looked up at every node. With
/// the forest's default of 256 levels and `σ = 7 (e_max − e_min)/100`, the grid step is under
/// 1/17 of `σ`, well below what a split can resolve, and the table of a shape with K = 100 takes
/// 100 KiB (it stays in cache during prediction).
///
/// ```
/// use shapeforest::descriptor::{EnergyGrid, EnergyRange};
/// let g = EnergyGrid { range: EnergyRange { e_min: 1.0, e_max: 3.0, sigma: 0.1 }, levels: 5 };
/// assert_eq!(g.energy(0), 1.0);
/// assert_eq!(g.energy(4), 3.0);
/// assert_eq!(g.energy(2), 2.0);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct EnergyGrid {
    /// Range and band-pass width.
    pub range: EnergyRange,
    /// Number of grid points (≥ 1).
    pub levels: u32,
}

impl EnergyGrid {
    /// Log-energy of grid point `i`.
    pub fn energy(&self, i: usize) -> f64 {
        if self.levels <= 1 {
            return 0.5 * (self.range.e_min + self.range.e_max);
        }
        let f = i as f64 / (self.levels - 1) as f64;
        self.range.e_min + f * (self.range.e_max - self.range.e_min)
    }
}

/// Dot product of two equal-length `f32` slices with eight independent accumulators (so the
/// compiler vectorises it). The summation order is fixed, so results are deterministic.
///
/// ```
/// use shapeforest::descriptor::dot_f32;
/// let a: Vec<f32> = (0..19).map(|i| i as f32).collect();
/// assert_eq!(dot_f32(&a, &vec![1.0; 19]), 171.0);
/// ```
#[inline]
pub fn dot_f32(a: &[f32], b: &[f32]) -> f32 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0f32; 8];
    let ca = a.chunks_exact(8);
    let cb = b.chunks_exact(8);
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for j in 0..8 {
            acc[j] += x[j] * y[j];
        }
    }
    let mut tail = 0.0f32;
    for (x, y) in ra.iter().zip(rb) {
        tail += x * y;
    }
    ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7])) + tail
}

/// [`dot_f32`] with AVX: the same eight lanes, the same products and sums in the same order,
/// so the same bits (the portable version compiles to 4-wide SSE with shuffles).
///
/// # Safety
/// The CPU must support AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
#[inline]
pub(crate) unsafe fn dot_f32_avx(a: &[f32], b: &[f32]) -> f32 {
    use std::arch::x86_64::*;
    let n = a.len().min(b.len());
    let full = n / 8 * 8;
    let mut l = [0.0f32; 8];
    // SAFETY: AVX is enabled; each load reads elements k..k+8 with k + 8 <= full <= n, in
    // bounds of both slices, and `l` holds 8 values.
    unsafe {
        let mut acc = _mm256_setzero_ps();
        let mut k = 0;
        while k < full {
            let p = _mm256_mul_ps(_mm256_loadu_ps(a.as_ptr().add(k)), _mm256_loadu_ps(b.as_ptr().add(k)));
            acc = _mm256_add_ps(acc, p);
            k += 8;
        }
        _mm256_storeu_ps(l.as_mut_ptr(), acc);
    }
    let mut tail = 0.0f32;
    for (x, y) in a[full..n].iter().zip(&b[full..n]) {
        tail += x * y;
    }
    ((l[0] + l[4]) + (l[1] + l[5])) + ((l[2] + l[6]) + (l[3] + l[7])) + tail
}
