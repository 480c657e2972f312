//! Functional maps: the forest's soft correspondence expressed in truncated Laplace bases, its
//! regularisation by sparse geodesic-consistent matches, and conversion to a point-to-point map.
//!
//! Conventions. `C` is the `k_test × k_ref` matrix that **pulls functions back** from the
//! reference shape R to the test shape M in the spectral bases: if `g = Φ_R b` on R then
//! `g ∘ T ≈ Φ_M (C b)` on M, where `T: M → R` is the correspondence. With a soft map
//! `P(r | m)` (the forest's left-stochastic posterior), `C_pred = Φ_Mᵀ M_M Π Φ_R` with
//! `Π_mr = P(r | m)`. Bases are M-orthonormal and of the unit-area shapes; distances are
//! normalised by √area before projection.
//!
//! The regularised map (Rodolà et al., eq. 11.19) solves
//! `min_C ‖C − C_pred‖²_F + α Σ_j ω_j ‖C b_j − a_j‖² + μ ‖C Λ_R − Λ_M C‖²_F`
//! where `a_j`, `b_j` are the coefficients of the geodesic distance maps from the `j`-th
//! matched pair `(p_j, q_j)` on M and R, and `ω_j` its confidence. The problem separates by
//! rows of C into `k_test` small symmetric positive definite systems, solved exactly.
//!
//! Point-to-point: `T(m) = argmin_r ‖(Φ_M C)_m − (Φ_R)_r‖` (nearest neighbour in the spectral
//! embedding), by blocked brute force on matrix products (at ~30–100 dimensions it beats
//! kd-trees; see NOTES). [`zoomout`] refines a map by spectral upsampling (Melzi et al. 2019).

use faer::{linalg::matmul::matmul, Accum, Mat, MatRef, Par, Side};
use rayon::prelude::*;
use thiserror::Error;

use crate::spectral::Spectrum;

mod partial;
mod sampled;
pub use partial::{partial_basis_size, point_to_point_partial, zoomout_partial_on_samples};
pub use sampled::{
    nearest_in_cells, point_to_point_in_cells, zoomout_on_samples, CellBalls, SampleCells, ZoomOutSchedule,
};

/// A functional-map computation failed.
#[derive(Debug, Error)]
pub enum FmapError {
    /// More basis functions were asked for than the spectrum holds.
    #[error("asked for {wanted} basis functions, the {which} spectrum has {available}")]
    BasisTooSmall {
        /// Which shape.
        which: &'static str,
        /// Basis size asked for.
        wanted: usize,
        /// Eigenpairs available.
        available: usize,
    },
    /// Input sizes do not agree.
    #[error("size mismatch: {0}")]
    SizeMismatch(String),
    /// A parameter is invalid.
    #[error("invalid functional-map parameter `{name}`: {reason}")]
    InvalidParameter {
        /// Parameter name.
        name: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// The least-squares system could not be factorised.
    #[error("the regularised least-squares system is not positive definite")]
    NotPositiveDefinite,
}

/// A soft correspondence from test vertices to reference vertices: for each test vertex, a
/// sparse distribution `(reference vertex, probability)`.
pub trait SoftCorrespondence: Sync {
    /// Number of test vertices.
    fn n_test_vertices(&self) -> usize;
    /// Calls `f(reference_vertex, probability)` for every non-zero entry of test vertex `m`.
    fn for_each_entry(&self, m: usize, f: &mut dyn FnMut(usize, f64));
}

/// A plain point-to-point map viewed as a (hard) soft correspondence.
impl SoftCorrespondence for [usize] {
    fn n_test_vertices(&self) -> usize {
        self.len()
    }
    fn for_each_entry(&self, m: usize, f: &mut dyn FnMut(usize, f64)) {
        f(self[m], 1.0)
    }
}

fn check_basis(which: &'static str, s: &Spectrum, k: usize) -> Result<(), FmapError> {
    if k == 0 || k > s.k() {
        return Err(FmapError::BasisTooSmall { which, wanted: k, available: s.k() });
    }
    Ok(())
}

/// First `k` eigenvectors of a spectrum as an `n × k` view.
pub fn basis(s: &Spectrum, k: usize) -> MatRef<'_, f64> {
    s.vectors().subcols(0, k.min(s.k()))
}

/// Spectral coefficients `Φ[:, :k]ᵀ M F` of the columns of `functions` (`n × s`), → `k × s`.
///
/// ```
/// use shapeforest::{fmap::spectral_coefficients, spectral::dense_spectrum, synth::icosphere};
/// let s = dense_spectrum(&icosphere(2, 1.0), 9).unwrap();
/// // The coefficients of φ_3 are the unit vector e_3 (M-orthonormality).
/// let f = faer::Mat::from_fn(s.n_vertices, 1, |i, _| s.phi(3)[i]);
/// let c = spectral_coefficients(&s, 9, f.as_ref()).unwrap();
/// assert!((c[(3, 0)] - 1.0).abs() < 1e-9 && c[(0, 0)].abs() < 1e-9);
/// ```
pub fn spectral_coefficients(
    s: &Spectrum,
    k: usize,
    functions: MatRef<'_, f64>,
) -> Result<Mat<f64>, FmapError> {
    check_basis("given", s, k)?;
    if functions.nrows() != s.n_vertices {
        return Err(FmapError::SizeMismatch(format!(
            "functions have {} rows, the shape has {} vertices",
            functions.nrows(),
            s.n_vertices
        )));
    }
    let weighted = Mat::from_fn(functions.nrows(), functions.ncols(), |i, j| s.mass[i] * functions[(i, j)]);
    let mut out = Mat::zeros(k, functions.ncols());
    matmul(out.as_mut(), Accum::Replace, basis(s, k).transpose(), weighted.as_ref(), 1.0, Par::rayon(0));
    Ok(out)
}

/// The functional map `C = Φ_M[:, :k_test]ᵀ M_M Π Φ_R[:, :k_ref]` of a soft correspondence
/// `Π` from the test shape to the reference shape (see the module conventions).
pub fn pullback_fmap<S: SoftCorrespondence + ?Sized>(
    test: &Spectrum,
    reference: &Spectrum,
    k_test: usize,
    k_ref: usize,
    soft: &S,
) -> Result<Mat<f64>, FmapError> {
    check_basis("test", test, k_test)?;
    check_basis("reference", reference, k_ref)?;
    if soft.n_test_vertices() != test.n_vertices {
        return Err(FmapError::SizeMismatch(format!(
            "the correspondence covers {} test vertices, the test shape has {}",
            soft.n_test_vertices(),
            test.n_vertices
        )));
    }
    let n = test.n_vertices;
    let phi_r = reference.vectors();
    // Rows of Π Φ_R, then C = Φ_Mᵀ diag(mass) (Π Φ_R). Φ_R is read by rows (a soft
    // correspondence names many reference vertices per test vertex): copied row-major first.
    let n_ref = reference.n_vertices;
    let rows: Vec<f64> = (0..n_ref).flat_map(|r| (0..k_ref).map(move |j| phi_r[(r, j)])).collect();
    let mut pulled_rows = vec![0.0; n * k_ref];
    let bad = pulled_rows
        .par_chunks_mut(k_ref.max(1))
        .enumerate()
        .filter_map(|(m, row)| {
            let mut bad = None;
            soft.for_each_entry(m, &mut |r, p| {
                if r >= n_ref {
                    bad = Some(r);
                    return;
                }
                for (x, &phi) in row.iter_mut().zip(&rows[r * k_ref..(r + 1) * k_ref]) {
                    *x += p * phi;
                }
            });
            row.iter_mut().for_each(|x| *x *= test.mass[m]);
            bad
        })
        .min();
    if let Some(r) = bad {
        return Err(FmapError::SizeMismatch(format!(
            "the correspondence names reference vertex {r}, the reference has {}",
            reference.n_vertices
        )));
    }
    let pulled = Mat::from_fn(n, k_ref, |m, j| pulled_rows[m * k_ref + j]);
    let mut c = Mat::zeros(k_test, k_ref);
    matmul(c.as_mut(), Accum::Replace, basis(test, k_test).transpose(), pulled.as_ref(), 1.0, Par::rayon(0));
    Ok(c)
}

/// Weights of the regularised functional-map problem.
#[derive(Clone, Debug, PartialEq)]
pub struct FmapParams {
    /// Basis size on the test shape. Default 40.
    pub k_test: usize,
    /// Basis size on the reference shape. Default 40.
    pub k_ref: usize,
    /// Weight α of the distance-map term. Default 1.
    pub match_weight: f64,
    /// Weight μ of the Laplacian commutativity term (eigenvalues normalised by the largest one
    /// used). Default 0 (off), as in the paper's main experiments.
    pub commutativity: f64,
}

impl Default for FmapParams {
    fn default() -> Self {
        Self { k_test: 40, k_ref: 40, match_weight: 1.0, commutativity: 0.0 }
    }
}

impl FmapParams {
    /// Checks the parameters, naming the rule that is broken.
    pub fn check(&self) -> Result<(), FmapError> {
        let bad = |name, reason: &str| Err(FmapError::InvalidParameter { name, reason: reason.into() });
        if self.k_test == 0 || self.k_ref == 0 {
            return bad("k_test/k_ref", "basis sizes must be at least 1");
        }
        if !(self.match_weight >= 0.0 && self.match_weight.is_finite()) {
            return bad("match_weight", "must be a finite number ≥ 0");
        }
        if !(self.commutativity >= 0.0 && self.commutativity.is_finite()) {
            return bad("commutativity", "must be a finite number ≥ 0");
        }
        Ok(())
    }
}

/// Solves the regularised problem of the module documentation exactly.
///
/// `c_pred`: `k_test × k_ref`; `a`: `k_test × s` test distance-map coefficients; `b`:
/// `k_ref × s` reference ones; `weights`: `s` confidences; `lambda_test`/`lambda_ref`: the
/// eigenvalues (at least `k_test` / `k_ref` of them).
///
/// ```
/// use faer::Mat;
/// use shapeforest::fmap::{solve_regularised_fmap, FmapParams};
/// // Without constraints the solution is the prediction itself.
/// let c_pred = Mat::from_fn(3, 3, |i, j| (i * 3 + j) as f64);
/// let p = FmapParams { k_test: 3, k_ref: 3, ..Default::default() };
/// let c = solve_regularised_fmap(c_pred.as_ref(), Mat::zeros(3, 0).as_ref(), Mat::zeros(3, 0).as_ref(), &[], &[0.0, 1.0, 2.0], &[0.0, 1.0, 2.0], &p).unwrap();
/// assert!((&c - &c_pred).norm_l2() < 1e-12);
/// ```
pub fn solve_regularised_fmap(
    c_pred: MatRef<'_, f64>,
    a: MatRef<'_, f64>,
    b: MatRef<'_, f64>,
    weights: &[f64],
    lambda_test: &[f64],
    lambda_ref: &[f64],
    params: &FmapParams,
) -> Result<Mat<f64>, FmapError> {
    params.check()?;
    let (kt, kr) = (c_pred.nrows(), c_pred.ncols());
    let s = weights.len();
    if a.nrows() != kt || b.nrows() != kr || a.ncols() != s || b.ncols() != s {
        return Err(FmapError::SizeMismatch(format!(
            "C_pred {kt}×{kr}, A {}×{}, B {}×{}, {s} weights",
            a.nrows(),
            a.ncols(),
            b.nrows(),
            b.ncols()
        )));
    }
    if lambda_test.len() < kt || lambda_ref.len() < kr {
        return Err(FmapError::SizeMismatch("fewer eigenvalues than basis functions".into()));
    }
    // G = α Σ ω_j b_j b_jᵀ ; R = α Σ ω_j a_j b_jᵀ (row i of R is the right-hand side addition).
    let bw = Mat::from_fn(kr, s, |i, j| params.match_weight * weights[j] * b[(i, j)]);
    let mut g = Mat::zeros(kr, kr);
    matmul(g.as_mut(), Accum::Replace, bw.as_ref(), b.transpose(), 1.0, Par::Seq);
    let mut rhs_add = Mat::zeros(kt, kr);
    matmul(rhs_add.as_mut(), Accum::Replace, a, bw.transpose(), 1.0, Par::Seq);
    let scale =
        lambda_test[..kt].iter().chain(&lambda_ref[..kr]).fold(0f64, |m, &l| m.max(l.abs())).max(1e-300);
    let rhs = Mat::from_fn(kt, kr, |i, j| c_pred[(i, j)] + rhs_add[(i, j)]);
    solve_rows_with_diagonal(g.as_ref(), rhs.as_ref(), |i, j| {
        let d = (lambda_ref[j] - lambda_test[i]) / scale;
        1.0 + params.commutativity * d * d
    })
}

/// Solves `x_i (G + diag(d_i)) = r_i` for every row `i` of `rhs` (`m × k`), `G` symmetric
/// positive semi-definite `k × k`, `d_i[j] = diagonal(i, j)` (a ridge, a commutativity
/// penalty): the row-separable least squares behind every regularised functional map. Fails
/// when a system is not positive definite.
///
/// ```
/// use faer::Mat;
/// let g = Mat::<f64>::zeros(2, 2);
/// let rhs = Mat::from_fn(1, 2, |_, j| 2.0 * (j + 1) as f64);
/// let x = shapeforest::fmap::solve_rows_with_diagonal(g.as_ref(), rhs.as_ref(), |_, _| 2.0).unwrap();
/// assert!((x[(0, 0)] - 1.0).abs() < 1e-12 && (x[(0, 1)] - 2.0).abs() < 1e-12);
/// ```
pub fn solve_rows_with_diagonal(
    g: MatRef<'_, f64>,
    rhs: MatRef<'_, f64>,
    diagonal: impl Fn(usize, usize) -> f64,
) -> Result<Mat<f64>, FmapError> {
    let (m, k) = (rhs.nrows(), rhs.ncols());
    if g.nrows() != k || g.ncols() != k {
        return Err(FmapError::SizeMismatch(format!("a {}×{} system for rows of {k}", g.nrows(), g.ncols())));
    }
    let mut c = Mat::zeros(m, k);
    for i in 0..m {
        let mut sys = g.to_owned();
        for j in 0..k {
            sys[(j, j)] += diagonal(i, j);
        }
        let llt = sys.llt(Side::Lower).map_err(|_| FmapError::NotPositiveDefinite)?;
        let r = Mat::from_fn(k, 1, |j, _| rhs[(i, j)]);
        let sol = faer::linalg::solvers::Solve::solve(&llt, r.as_ref());
        for j in 0..k {
            c[(i, j)] = sol[(j, 0)];
        }
    }
    Ok(c)
}

/// A matrix copied row by row into one contiguous buffer, for searches that read whole rows at
/// random (a column-major matrix puts a row's entries one column length apart).
pub(crate) struct RowMajor<T = f64> {
    data: Vec<T>,
    ncols: usize,
}

impl<T: Real> RowMajor<T> {
    pub(crate) fn new(m: MatRef<'_, T>) -> Self {
        let ncols = m.ncols();
        let mut data = vec![T::default(); m.nrows() * ncols];
        for j in 0..ncols {
            for (i, &x) in m.col(j).iter().enumerate() {
                data[i * ncols + j] = x;
            }
        }
        Self { data, ncols }
    }

    pub(crate) fn nrows(&self) -> usize {
        self.data.len().checked_div(self.ncols).unwrap_or(0)
    }

    pub(crate) fn row(&self, i: usize) -> &[T] {
        &self.data[i * self.ncols..(i + 1) * self.ncols]
    }
}

/// `Σ_j (a_j − b_j)²` over the shorter of the two, in `f64` or `f32`. Short rows (coordinates)
/// are summed in order of `j`; rows of [`DISTANCE_LANES`] entries or more (spectral rows: the
/// inner loop of every point-map search) in that many interleaved partial sums added up in a
/// fixed order, compiled for the widest vector unit the CPU has: the same operations in the same
/// order on every path, so the same bits. One running sum would wait on each addition before
/// the next.
#[inline]
pub(crate) fn squared_distance<T: Real>(a: &[T], b: &[T]) -> T {
    if a.len().min(b.len()) < DISTANCE_LANES {
        return a.iter().zip(b).map(|(&x, &y)| (x - y) * (x - y)).sum();
    }
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F, checked just above.
            return unsafe { squared_distance_avx512(a, b) };
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, checked just above.
            return unsafe { squared_distance_avx2(a, b) };
        }
    }
    squared_distance_lanes(a, b)
}

/// The floating-point types [`squared_distance`] sums.
pub(crate) trait Real:
    Copy
    + Default
    + PartialOrd
    + Send
    + Sync
    + std::ops::Add<Output = Self>
    + std::ops::Sub<Output = Self>
    + std::ops::Mul<Output = Self>
    + std::iter::Sum
{
    /// Positive infinity.
    const INFINITY: Self;
}

impl Real for f64 {
    const INFINITY: Self = f64::INFINITY;
}

impl Real for f32 {
    const INFINITY: Self = f32::INFINITY;
}

/// Partial sums of [`squared_distance`] on long rows.
const DISTANCE_LANES: usize = 8;

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn squared_distance_avx512<T: Real>(a: &[T], b: &[T]) -> T {
    squared_distance_lanes(a, b)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn squared_distance_avx2<T: Real>(a: &[T], b: &[T]) -> T {
    squared_distance_lanes(a, b)
}

#[inline(always)]
fn squared_distance_lanes<T: Real>(a: &[T], b: &[T]) -> T {
    let n = a.len().min(b.len());
    let (ac, bc) = (a[..n].chunks_exact(DISTANCE_LANES), b[..n].chunks_exact(DISTANCE_LANES));
    let tail: T = ac.remainder().iter().zip(bc.remainder()).map(|(&x, &y)| (x - y) * (x - y)).sum();
    let mut acc = [T::default(); DISTANCE_LANES];
    for (xs, ys) in ac.zip(bc) {
        for l in 0..DISTANCE_LANES {
            let d = xs[l] - ys[l];
            acc[l] = acc[l] + d * d;
        }
    }
    ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7])) + tail
}

/// For each row of `queries` (`q × d`), the index of the nearest row of `points` (`p × d`) in
/// Euclidean distance. Blocked brute force on matrix products, parallel over query blocks.
///
/// ```
/// use faer::mat;
/// let pts = mat![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]];
/// let q = mat![[0.9, 0.2], [0.1, 0.8], [0.0, 0.1]];
/// assert_eq!(shapeforest::fmap::nearest_rows(q.as_ref(), pts.as_ref()), vec![1, 2, 0]);
/// ```
pub fn nearest_rows(queries: MatRef<'_, f64>, points: MatRef<'_, f64>) -> Vec<usize> {
    nearest_rows_in(queries, points)
}

/// [`nearest_rows`] with the products in single precision: twice the throughput of the vector
/// units, for searches whose result is only used as a starting point or a least-squares target
/// (ZoomOut's iterations, the coarse step of a search refined in double precision afterwards).
/// The row returned is the nearest up to single-precision rounding: where two points' squared
/// distances differ by less than about `1e-6` of the squared norms involved, either may be
/// returned.
///
/// ```
/// use faer::mat;
/// let pts = mat![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]];
/// let q = mat![[0.9, 0.2], [0.1, 0.8], [0.0, 0.1]];
/// assert_eq!(shapeforest::fmap::nearest_rows_single(q.as_ref(), pts.as_ref()), vec![1, 2, 0]);
/// ```
pub fn nearest_rows_single(queries: MatRef<'_, f64>, points: MatRef<'_, f64>) -> Vec<usize> {
    nearest_rows_in(single(queries).as_ref(), single(points).as_ref())
}

/// `m` rounded to single precision.
pub(crate) fn single(m: MatRef<'_, f64>) -> Mat<f32> {
    Mat::from_fn(m.nrows(), m.ncols(), |i, j| m[(i, j)] as f32)
}

/// The scalars [`nearest_rows_in`] runs on: [`Real`]s that faer multiplies.
pub(crate) trait SearchScalar: Real + faer::traits::ComplexField {
    const ONE: Self;
    const TWO: Self;
}

impl SearchScalar for f64 {
    const ONE: Self = 1.0;
    const TWO: Self = 2.0;
}

impl SearchScalar for f32 {
    const ONE: Self = 1.0;
    const TWO: Self = 2.0;
}

fn nearest_rows_in<T: SearchScalar>(queries: MatRef<'_, T>, points: MatRef<'_, T>) -> Vec<usize> {
    assert_eq!(queries.ncols(), points.ncols(), "nearest_rows: dimensions differ");
    const QB: usize = 256;
    const PB: usize = 2048;
    let (nq, np) = (queries.nrows(), points.nrows());
    if np == 0 {
        return vec![0; nq];
    }
    let point_sq: Vec<T> = (0..np)
        .map(|r| (0..points.ncols()).fold(T::default(), |acc, c| acc + points[(r, c)] * points[(r, c)]))
        .collect();
    let mut out = vec![0usize; nq];
    // One product buffer per worker, not per block (no zeroing: the product overwrites it).
    let buffer = || (Mat::<T>::zeros(QB, PB.min(np)), vec![T::INFINITY; QB]);
    out.par_chunks_mut(QB).enumerate().for_each_init(buffer, |(prod, best), (blk, chunk)| {
        let q0 = blk * QB;
        let qb = chunk.len();
        let qs = queries.subrows(q0, qb);
        let best = &mut best[..qb];
        best.fill(T::INFINITY);
        let mut p0 = 0;
        while p0 < np {
            let pb = PB.min(np - p0);
            matmul(
                prod.as_mut().subrows_mut(0, qb).subcols_mut(0, pb),
                Accum::Replace,
                qs,
                points.subrows(p0, pb).transpose(),
                T::ONE,
                Par::Seq,
            );
            for j in 0..pb {
                let col = prod.col(j).try_as_col_major().expect("a Mat's columns are contiguous").as_slice();
                closer_of_column(&col[..qb], point_sq[p0 + j], p0 + j, best, chunk);
            }
            p0 += pb;
        }
    });
    out
}

/// For every query `i`, `d = point_sq − 2 · dots[i]` (its squared distance to point `p` less
/// `‖q_i‖²`): where `d < best[i]`, `best[i] = d` and `nearest[i] = p` (the first point stays
/// on ties). Branch-free, on the widest vector unit the CPU has (same results on every one).
fn closer_of_column<T: SearchScalar>(
    dots: &[T],
    point_sq: T,
    p: usize,
    best: &mut [T],
    nearest: &mut [usize],
) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has AVX-512F (checked above).
            return unsafe { closer_of_column_avx512(dots, point_sq, p, best, nearest) };
        }
    }
    closer_of_column_generic(dots, point_sq, p, best, nearest)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn closer_of_column_avx512<T: SearchScalar>(
    dots: &[T],
    point_sq: T,
    p: usize,
    best: &mut [T],
    nearest: &mut [usize],
) {
    closer_of_column_generic(dots, point_sq, p, best, nearest)
}

#[inline(always)]
fn closer_of_column_generic<T: SearchScalar>(
    dots: &[T],
    point_sq: T,
    p: usize,
    best: &mut [T],
    nearest: &mut [usize],
) {
    for ((&dot, b), n) in dots.iter().zip(best.iter_mut()).zip(nearest.iter_mut()) {
        // ‖q − p‖² − ‖q‖² = ‖p‖² − 2 q·p
        let d = point_sq - T::TWO * dot;
        let closer = d < *b;
        *b = if closer { d } else { *b };
        *n = if closer { p } else { *n };
    }
}

/// ZoomOut (Melzi et al. 2019) started from a point map instead of a functional map: the
/// functional map of `map` (test vertex → reference vertex) in the first `k_start` eigenpairs,
/// then alternately a point map from the current functional map and a functional map one
/// `step` larger from that point map, up to `k_final`. Returns the last functional map and
/// point map. Refines a map that is right in the large but noisy in the small.
pub fn zoomout_from_map(
    test: &Spectrum,
    reference: &Spectrum,
    map: &[usize],
    k_start: usize,
    k_final: usize,
    step: usize,
) -> Result<(Mat<f64>, Vec<usize>), FmapError> {
    if step == 0 || k_start == 0 || k_start > k_final {
        return Err(FmapError::InvalidParameter {
            name: "zoomout",
            reason: format!("needs 1 ≤ k_start ≤ k_final and step ≥ 1, got {k_start}, {k_final}, {step}"),
        });
    }
    let c = pullback_fmap(test, reference, k_start, k_start, map)?;
    zoomout(test, reference, c.as_ref(), k_final, step)
}

/// Point-to-point map `T: M → R` (test vertex → reference vertex) of a functional map `C`
/// (`k_test × k_ref`, pulling back from R to M).
pub fn point_to_point(
    test: &Spectrum,
    reference: &Spectrum,
    c: MatRef<'_, f64>,
) -> Result<Vec<usize>, FmapError> {
    let emb = pulled_back_embedding(test, reference, c)?;
    Ok(nearest_rows(emb.as_ref(), basis(reference, c.ncols())))
}

/// [`point_to_point`] for the test vertices `rows` only: entry `i` is the reference vertex
/// matched to test vertex `rows[i]`. The search costs `rows.len()` queries instead of one per
/// test vertex, for callers that need the spectral map only where nothing else places a vertex.
///
/// ```
/// use shapeforest::{fmap::{point_to_point, point_to_point_rows}, spectral::dense_spectrum, synth::icosphere};
/// let s = dense_spectrum(&icosphere(2, 1.0), 9).unwrap();
/// let c = faer::Mat::<f64>::identity(9, 9);
/// let all = point_to_point(&s, &s, c.as_ref()).unwrap();
/// assert_eq!(point_to_point_rows(&s, &s, c.as_ref(), &[3, 17]).unwrap(), vec![all[3], all[17]]);
/// ```
pub fn point_to_point_rows(
    test: &Spectrum,
    reference: &Spectrum,
    c: MatRef<'_, f64>,
    rows: &[usize],
) -> Result<Vec<usize>, FmapError> {
    let (kt, kr) = (c.nrows(), c.ncols());
    check_basis("test", test, kt)?;
    check_basis("reference", reference, kr)?;
    if let Some(&bad) = rows.iter().find(|&&m| m >= test.n_vertices) {
        return Err(FmapError::SizeMismatch(format!(
            "test vertex {bad} asked for, the test shape has {}",
            test.n_vertices
        )));
    }
    if rows.is_empty() {
        return Ok(Vec::new());
    }
    let phi = basis(test, kt);
    let sub = Mat::from_fn(rows.len(), kt, |i, j| phi[(rows[i], j)]);
    let mut emb = Mat::zeros(rows.len(), kr);
    crate::spectral::matmul_tall(emb.as_mut(), Accum::Replace, sub.as_ref(), c, 1.0, Par::Seq);
    Ok(nearest_rows(emb.as_ref(), basis(reference, kr)))
}

/// The reference rows mapped into the test basis, `Φ_R Cᵀ` (`phi_r.nrows() × c.nrows()`; `phi_r`
/// holds the first `c.ncols()` reference basis functions): the points that test rows of `Φ_M`
/// are searched among. In row strips, see [`crate::spectral::matmul_tall`]; in either precision.
pub(crate) fn mapped_reference_rows<T: SearchScalar>(phi_r: MatRef<'_, T>, c: MatRef<'_, T>) -> Mat<T> {
    let mut points = Mat::<T>::zeros(phi_r.nrows(), c.nrows());
    crate::spectral::matmul_tall(
        points.as_mut(),
        Accum::Replace,
        phi_r,
        c.transpose(),
        T::ONE,
        Par::rayon(0),
    );
    points
}

/// The test shape's spectral embedding mapped into the reference basis, `Φ_M[:, :k_test] C`
/// (`n_test × k_ref`), after checking the basis sizes.
fn pulled_back_embedding(
    test: &Spectrum,
    reference: &Spectrum,
    c: MatRef<'_, f64>,
) -> Result<Mat<f64>, FmapError> {
    let (kt, kr) = (c.nrows(), c.ncols());
    check_basis("test", test, kt)?;
    check_basis("reference", reference, kr)?;
    let mut emb = Mat::zeros(test.n_vertices, kr);
    crate::spectral::matmul_tall(emb.as_mut(), Accum::Replace, basis(test, kt), c, 1.0, Par::rayon(0));
    Ok(emb)
}

/// Point-to-point map in the other direction, `R → M` (reference vertex → test vertex), of the
/// same functional map `C`: nearest neighbours of the rows of `Φ_R` among those of `Φ_M C`.
pub fn point_to_point_reverse(
    test: &Spectrum,
    reference: &Spectrum,
    c: MatRef<'_, f64>,
) -> Result<Vec<usize>, FmapError> {
    let emb = pulled_back_embedding(test, reference, c)?;
    Ok(nearest_rows(basis(reference, c.ncols()), emb.as_ref()))
}

/// Point-to-point map `T: M → R` restricted to candidates: each test vertex goes to the
/// candidate reference vertex (from `soft`, e.g. the forest's posterior support) nearest to
/// its row of `Φ_M C` in the spectral embedding; vertices without candidates fall back to the
/// unrestricted nearest neighbour. This keeps the precision of the candidates and the global
/// consistency (e.g. the left/right orientation) of the functional map.
pub fn point_to_point_restricted<S: SoftCorrespondence + ?Sized>(
    test: &Spectrum,
    reference: &Spectrum,
    c: MatRef<'_, f64>,
    soft: &S,
) -> Result<Vec<usize>, FmapError> {
    if soft.n_test_vertices() != test.n_vertices {
        return Err(FmapError::SizeMismatch(format!(
            "the candidates cover {} test vertices, the test shape has {}",
            soft.n_test_vertices(),
            test.n_vertices
        )));
    }
    let kr = c.ncols();
    let emb = pulled_back_embedding(test, reference, c)?;
    let phi_r = basis(reference, kr);
    let (emb_rows, phi_rows) = (RowMajor::new(emb.as_ref()), RowMajor::new(phi_r));
    let mut out: Vec<Option<usize>> = vec![None; test.n_vertices];
    out.par_iter_mut().enumerate().for_each(|(m, slot)| {
        let mut best = f64::INFINITY;
        let q = emb_rows.row(m);
        soft.for_each_entry(m, &mut |r, _| {
            if r < reference.n_vertices {
                let d = squared_distance(q, phi_rows.row(r));
                if d < best {
                    best = d;
                    *slot = Some(r);
                }
            }
        });
    });
    let missing: Vec<usize> = (0..test.n_vertices).filter(|&m| out[m].is_none()).collect();
    if !missing.is_empty() {
        let queries = Mat::from_fn(missing.len(), kr, |i, j| emb[(missing[i], j)]);
        for (i, r) in nearest_rows(queries.as_ref(), phi_r).into_iter().enumerate() {
            out[missing[i]] = Some(r);
        }
    }
    Ok(out.into_iter().map(|r| r.unwrap_or(0)).collect())
}

/// ZoomOut refinement (Melzi et al., SIGGRAPH Asia 2019): starting from `c` (square, `k0 × k0`),
/// alternately convert to a point map and re-estimate the map with one more basis function
/// (every `step`), up to `k_final`. Returns the refined map and its point-to-point map.
pub fn zoomout(
    test: &Spectrum,
    reference: &Spectrum,
    c: MatRef<'_, f64>,
    k_final: usize,
    step: usize,
) -> Result<(Mat<f64>, Vec<usize>), FmapError> {
    if c.nrows() != c.ncols() {
        return Err(FmapError::SizeMismatch("zoomout starts from a square functional map".into()));
    }
    if step == 0 {
        return Err(FmapError::InvalidParameter { name: "step", reason: "must be at least 1".into() });
    }
    check_basis("test", test, k_final)?;
    check_basis("reference", reference, k_final)?;
    let mut current = c.to_owned();
    let mut k = c.nrows();
    let mut map = point_to_point_orthogonal(test, reference, current.as_ref())?;
    while k < k_final {
        k = (k + step).min(k_final);
        current = pullback_fmap(test, reference, k, k, map.as_slice())?;
        map = point_to_point_orthogonal(test, reference, current.as_ref())?;
    }
    Ok((current, map))
}

/// Point-to-point map `T: M → R` of a functional map `C` (`k_test × k_ref`, pulling back from R
/// to M) read as ZoomOut reads it: each row of `Φ_M` goes to the nearest row of `Φ_R Cᵀ`. For an
/// orthogonal `C` this is [`point_to_point`]; for the maps ZoomOut builds (pulled back from a
/// point map, so not quite orthogonal) it is the step of its alternating minimisation of
/// `‖Π Φ_R Cᵀ − Φ_M‖`, which keeps the rows at full length instead of shrinking them towards
/// the middle of the embedding.
pub fn point_to_point_orthogonal(
    test: &Spectrum,
    reference: &Spectrum,
    c: MatRef<'_, f64>,
) -> Result<Vec<usize>, FmapError> {
    let (kt, kr) = (c.nrows(), c.ncols());
    check_basis("test", test, kt)?;
    check_basis("reference", reference, kr)?;
    let points = mapped_reference_rows(basis(reference, kr), c);
    Ok(nearest_rows(basis(test, kt), points.as_ref()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{spectral::dense_spectrum, synth::icosphere};

    #[test]
    fn squared_distances_match_the_plain_sum_in_both_precisions_with_the_same_bits_on_every_path() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for n in [0, 1, 3, 7, 8, 15, 16, 17, 100, 200, 203] {
            let a: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
            let b: Vec<f64> = (0..n + 2).map(|_| rng.random_range(-1.0..1.0)).collect();
            let plain: f64 = a.iter().zip(&b).map(|(x, y)| (x - y).powi(2)).sum();
            let d = squared_distance(&a, &b);
            assert!((d - plain).abs() <= 1e-12 * plain.max(1.0), "{n}: {d} against {plain}");
            assert_eq!(
                squared_distance(&b, &a).to_bits(),
                d.to_bits(),
                "{n}: the shorter row sets the length"
            );
            if n >= DISTANCE_LANES {
                assert_eq!(squared_distance_lanes(&a, &b).to_bits(), d.to_bits(), "{n}: the portable path");
            }
            let single = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
            let (a32, b32) = (single(&a), single(&b));
            let d32 = squared_distance(&a32, &b32);
            assert!((f64::from(d32) - plain).abs() <= 1e-5 * plain.max(1.0), "{n}: {d32} against {plain}");
            if n >= DISTANCE_LANES {
                assert_eq!(squared_distance_lanes(&a32, &b32).to_bits(), d32.to_bits(), "{n}: f32, portable");
            }
        }
    }

    #[test]
    fn identity_map_gives_identity_fmap_and_back() {
        let s = dense_spectrum(&icosphere(2, 1.0), 16).unwrap();
        let id: Vec<usize> = (0..s.n_vertices).collect();
        let c = pullback_fmap(&s, &s, 16, 16, id.as_slice()).unwrap();
        let eye = Mat::<f64>::identity(16, 16);
        assert!((&c - &eye).norm_l2() < 1e-9);
        let back = point_to_point(&s, &s, c.as_ref()).unwrap();
        assert_eq!(back, id);
        assert_eq!(point_to_point_reverse(&s, &s, c.as_ref()).unwrap(), id);
    }

    #[test]
    fn distance_constraints_pull_the_solution() {
        // A single constraint C b = a with the prediction at zero: C moves towards a bᵀ/(1+|b|²).
        let c_pred = Mat::<f64>::zeros(2, 2);
        let a = faer::mat![[1.0], [0.0]];
        let b = faer::mat![[1.0], [0.0]];
        let p = FmapParams { k_test: 2, k_ref: 2, match_weight: 3.0, commutativity: 0.0 };
        let c = solve_regularised_fmap(
            c_pred.as_ref(),
            a.as_ref(),
            b.as_ref(),
            &[1.0],
            &[0.0, 1.0],
            &[0.0, 1.0],
            &p,
        )
        .unwrap();
        assert!((c[(0, 0)] - 0.75).abs() < 1e-12, "{c:?}");
        assert!(c[(1, 1)].abs() < 1e-12);
    }

    #[test]
    fn nearest_rows_matches_naive_search() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let q = Mat::from_fn(300, 7, |_, _| rng.random::<f64>());
        let p = Mat::from_fn(2500, 7, |_, _| rng.random::<f64>());
        let got = nearest_rows(q.as_ref(), p.as_ref());
        for i in 0..300 {
            let d = |j: usize| (0..7).map(|c| (q[(i, c)] - p[(j, c)]).powi(2)).sum::<f64>();
            let best = (0..2500).min_by(|&a, &b| d(a).total_cmp(&d(b))).unwrap();
            assert!((d(got[i]) - d(best)).abs() < 1e-12);
        }
        // Equal points, in different blocks: the first one wins, whatever the block boundaries.
        let dup = Mat::from_fn(4100, 7, |r, c| p[(r % 2, c)]);
        let got = nearest_rows(q.as_ref(), dup.as_ref());
        let d = |i: usize, j: usize| (0..7).map(|c| (q[(i, c)] - p[(j, c)]).powi(2)).sum::<f64>();
        for (i, &g) in got.iter().enumerate() {
            assert_eq!(g, if d(i, 1) < d(i, 0) { 1 } else { 0 }, "query {i}");
        }
    }

    #[test]
    fn nearest_rows_single_finds_the_nearest_up_to_single_rounding() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        // Spectral-embedding-like rows: 150 dimensions, values of a few units.
        let q = Mat::from_fn(700, 150, |_, _| rng.random::<f64>() * 4.0 - 2.0);
        let p = Mat::from_fn(3100, 150, |_, _| rng.random::<f64>() * 4.0 - 2.0);
        let exact = nearest_rows(q.as_ref(), p.as_ref());
        let single = nearest_rows_single(q.as_ref(), p.as_ref());
        let d = |i: usize, j: usize| (0..150).map(|c| (q[(i, c)] - p[(j, c)]).powi(2)).sum::<f64>();
        let mut same = 0;
        for i in 0..700 {
            let (de, ds) = (d(i, exact[i]), d(i, single[i]));
            assert!(ds - de <= 1e-5 * de, "query {i}: {ds} against the nearest {de}");
            same += usize::from(exact[i] == single[i]);
        }
        // Random points have no near-ties: the same rows almost everywhere.
        assert!(same >= 695, "{same} of 700 the same row");
    }

    #[test]
    fn zoomout_from_a_small_true_map_stays_correct() {
        let s = dense_spectrum(&icosphere(3, 1.0), 30).unwrap();
        // A rotation by 90° about z is an isometry; for the exact icosphere it permutes vertices
        // only approximately, so use the identity with a small noisy start instead.
        let id: Vec<usize> = (0..s.n_vertices).collect();
        let c0 = pullback_fmap(&s, &s, 9, 9, id.as_slice()).unwrap();
        let (c, map) = zoomout(&s, &s, c0.as_ref(), 30, 3).unwrap();
        assert_eq!(c.nrows(), 30);
        let correct = map.iter().enumerate().filter(|(i, &j)| *i == j).count();
        assert_eq!(correct, s.n_vertices);
    }

    #[test]
    fn the_point_map_read_in_cells_in_single_precision_is_the_exhaustive_search() {
        // A shape onto itself through a functional map near the identity: the cells' answer is
        // the nearest row of every reference vertex, up to single-precision ties.
        let mesh = icosphere(3, 1.0);
        let s = dense_spectrum(&mesh, 20).unwrap();
        let cells = crate::regularizer::sample_cells(&mesh, 60).unwrap();
        let c = Mat::from_fn(
            20,
            20,
            |i, j| if i == j { 1.0 } else { 0.02 * ((i * 7 + j * 3) % 5) as f64 - 0.04 },
        );
        let found = point_to_point_in_cells(&s, &s, &cells, None, c.as_ref()).unwrap();
        let points = mapped_reference_rows(basis(&s, 20), c.as_ref());
        let queries = basis(&s, 20);
        let d = |m: usize, r: usize| (0..20).map(|j| (queries[(m, j)] - points[(r, j)]).powi(2)).sum::<f64>();
        for (m, &r) in found.iter().enumerate() {
            let best = (0..s.n_vertices).map(|q| d(m, q)).fold(f64::INFINITY, f64::min);
            assert!(d(m, r) <= best + 1e-5 * (1.0 + best), "vertex {m}: {} against {best}", d(m, r));
        }
    }
}
