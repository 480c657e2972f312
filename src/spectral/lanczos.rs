//! Restarted block Lanczos for the eigenvalues of largest magnitude of a symmetric operator.
//!
//! This is the engine behind [`super::LaplaceBeltramiSolver`]: the operator it sees is the
//! shift-inverted, mass-scaled Laplacian `C = (D⁻¹ L D⁻¹ − σ I)⁻¹` (with `D = M^{1/2}`), whose
//! eigenvalues `θ = 1/(λ − σ)` largest in magnitude belong to the Laplace eigenvalues `λ`
//! nearest to σ: the smallest ones for σ below the spectrum (`C` positive) or, for an interior
//! σ, those on both sides of it (`C` indefinite).
//!
//! The method is a block Krylov–Schur iteration (Stewart 2001; the block variant of
//! thick-restart Lanczos, Wu & Simon 2000):
//! - a block of `b` vectors is expanded one operator application at a time; every new block is
//!   orthogonalised against the whole basis with classical Gram–Schmidt done twice (full
//!   reorthogonalisation, so no spurious copies of converged Ritz values appear), and against a
//!   set of *locked* vectors (exact eigenvectors known beforehand, e.g. the constant vectors);
//! - when the basis is full, the projected matrix `H = VᵀCV` is diagonalised and the basis is
//!   compressed to the wanted Ritz vectors plus some extra ones (thick restart), followed by the
//!   last residual block;
//! - a Ritz pair `(θ, y)` is converged when `‖C y − θ y‖ ≤ tol · θ`, a residual read off the
//!   Krylov relation `C V = V H + Q B Eᵀ` without touching the operator.
//!
//! Blocks find eigenvalues of multiplicity up to `b` in step; larger exact multiplicities can
//! be missed by any Krylov method, which is why the caller locks the known null space and can
//! verify the result by counting eigenvalues (Sylvester inertia).
//!
//! The start is seeded and every parallel step splits its work at fixed points (row chunks,
//! column halves), never by the number of threads, so results are bit-for-bit reproducible on
//! any number of threads.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::evd::{self_adjoint_evd, self_adjoint_evd_scratch, ComputeEigenvectors};
use faer::linalg::matmul::matmul;
use faer::reborrow::{IntoConst, Reborrow, ReborrowMut};
use faer::{Accum, Mat, MatMut, MatRef, Par};
use rand::{Rng, SeedableRng};

use super::kernels::{nn_subtract, tn_product};
use rand_chacha::ChaCha8Rng;

/// Settings of one block Lanczos run (already validated by the caller).
#[derive(Clone, Debug)]
pub(crate) struct BlockLanczos {
    /// Number of wanted eigenpairs (largest in magnitude).
    pub nev: usize,
    /// Block size `b`.
    pub block: usize,
    /// Maximal basis size; must satisfy `nev + 2·block ≤ ncv ≤ n − locked`.
    pub ncv: usize,
    /// Relative residual tolerance `‖C y − θ y‖ ≤ tol·|θ|`.
    pub tol: f64,
    /// Maximal number of thick restarts.
    pub max_restarts: usize,
    /// Seed of the random start block.
    pub seed: u64,
}

/// Converged eigenpairs of the operator.
#[derive(Debug)]
pub(crate) struct LanczosOutput {
    /// The `nev` eigenvalues largest in magnitude, in descending magnitude.
    pub theta: Vec<f64>,
    /// Their orthonormal eigenvectors, `n × nev`.
    pub vectors: Mat<f64>,
    /// Restarts performed.
    pub restarts: usize,
    /// Block operator applications performed.
    pub applications: usize,
}

/// The iteration stopped before every wanted pair converged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum LanczosFailure {
    /// `found` of the `wanted` pairs had converged when the restart budget ran out.
    NotConverged { found: usize, wanted: usize },
    /// No direction orthogonal to the basis could be found (the space is exhausted).
    Exhausted,
}

/// Columns whose norm after orthogonalisation fell below this fraction of their norm before
/// are re-orthogonalised once more.
const WEAK: f64 = 1e-8;
/// Columns that fell below this fraction are numerically in the span of the basis: they are
/// replaced by fresh random directions.
const BREAKDOWN: f64 = 1e-13;
/// Rows per strip of the thick restart's basis update: a strip of the basis (512 × 240) and its
/// update stay in cache, and the two strip buffers are 1 MB each instead of the 8 MB of 4096-row
/// strips, which a 5K-vertex solve paid for in fresh pages.
const RESTART_STRIP: usize = 512;
/// A cycle after one that converged at least this share of the wanted pairs checks for
/// convergence every [`PROBE_BLOCKS`] blocks instead of only when the basis is full, so that the
/// last cycle stops when its last pairs converge, not a basis later.
const PROBE_FRACTION: f64 = 0.9;
/// Blocks between two convergence checks of a probing cycle.
const PROBE_BLOCKS: usize = 2;
/// A check costs an eigendecomposition of the projected matrix (~3 ms at 240 × 240); below
/// this many rows a block step costs less than that, and cycles do not probe.
const PROBE_MIN_ROWS: usize = 10_000;
/// A reorthogonalisation pass that shrinks a column below this fraction is repeated.
const DGKS: f64 = 0.7;

impl BlockLanczos {
    /// Runs the iteration. `op(x, y)` must write `y = C x` for a block `x` of `b` columns;
    /// `locked` holds orthonormal exact eigenvectors to stay orthogonal to (may have 0 columns).
    pub fn run(
        &self,
        n: usize,
        locked: MatRef<'_, f64>,
        op: &mut dyn FnMut(MatRef<'_, f64>, MatMut<'_, f64>),
    ) -> Result<LanczosOutput, LanczosFailure> {
        let b = self.block;
        let ncv = self.ncv;
        assert!(b >= 1 && self.nev >= 1 && self.nev + 2 * b <= ncv, "invalid Lanczos sizes");
        assert!(ncv + locked.ncols() <= n, "basis larger than the space");
        assert_eq!(locked.nrows(), n);
        let par = Par::Seq;
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);

        // Basis with room for the residual block beyond ncv.
        let mut v = Mat::<f64>::zeros(n, ncv + b);
        let mut h = Mat::<f64>::zeros(ncv, ncv);
        let mut coef = Mat::<f64>::zeros(ncv + b, b);
        let mut coef2 = Mat::<f64>::zeros(ncv + b, b);
        let mut lcoef = Mat::<f64>::zeros(locked.ncols(), b);
        let mut r = Mat::<f64>::zeros(b, b);
        let mut evd_s = Mat::<f64>::zeros(ncv, 1);
        let mut evd_u = Mat::<f64>::zeros(ncv, ncv);
        // The Rayleigh–Ritz eigendecomposition runs on every thread (faer's divide and conquer
        // gives the same bits on one thread or several); the rest of the iteration splits its
        // work itself.
        let evd_par = Par::rayon(0);
        let mut evd_mem = MemBuffer::new(self_adjoint_evd_scratch::<f64>(
            ncv,
            ComputeEigenvectors::Yes,
            evd_par,
            Default::default(),
        ));
        // The thick restart `V[:, ..keep] ← V[:, ..m] S` is done a strip of rows at a time (row i
        // of the result only reads row i of V), so it needs a strip-sized buffer, not a second
        // n × ncv basis (100 MB at 52K vertices, K = 100).
        let mut restart_tmp = [(); 2].map(|_| Mat::<f64>::zeros(RESTART_STRIP.min(n), ncv));
        let mut norms = vec![0.0; b];
        let mut mid_norms = vec![0.0; b];
        // Basis size at which the current expansion started (right after a (re)start).
        let mut fresh = 0usize;

        // Random start block, orthonormal and orthogonal to the locked vectors.
        for j in 0..b {
            for x in col_mut(v.as_mut(), j) {
                *x = rng.random_range(-1.0..1.0);
            }
        }
        {
            let (basis, mut w) = v.as_mut().split_at_col_mut(0);
            let w = w.rb_mut().subcols_mut(0, b);
            for (j, nrm) in norms.iter_mut().enumerate() {
                *nrm = norm(col(w.rb(), j));
            }
            orthonormalize_block(locked, basis.rb(), w, r.as_mut(), &norms, lcoef.as_mut(), &mut rng, par)?;
        }

        let mut size = 0usize; // basis vectors whose column of H is known
        let mut restarts = 0usize;
        let mut applications = 0usize;
        // Whether this cycle stops every PROBE_BLOCKS blocks for a Rayleigh–Ritz check.
        let mut probing = false;
        loop {
            let target = if probing { (size + PROBE_BLOCKS * b).min(ncv) } else { ncv };
            // Expand: the block at [size, size + b) is orthonormal; produce the next one.
            while size + b <= target {
                let (head, mut tail) = v.as_mut().split_at_col_mut(size + b);
                let input = head.rb().subcols(size, b);
                let mut w = tail.rb_mut().subcols_mut(0, b);
                op(input, w.rb_mut());
                applications += 1;
                for (j, nrm) in norms.iter_mut().enumerate() {
                    *nrm = norm(col(w.rb(), j));
                }
                let basis = head.rb();
                let m = size + b;
                // Locked vectors: C keeps their complement invariant, this only removes drift.
                project_out(locked, w.rb_mut(), lcoef.as_mut(), par);
                project_out(locked, w.rb_mut(), lcoef.as_mut(), par);
                // First pass: the three-term recurrence (the previous and current blocks), or
                // the whole basis for the first block after a restart, which couples to every
                // kept Ritz vector. Second pass: full reorthogonalisation against the basis;
                // a third one only if the second removed much (DGKS criterion).
                let lo = if size == fresh { 0 } else { size - b };
                let mut c1 = coef.as_mut().subrows_mut(0, m);
                c1.fill(0.0);
                project_out(basis.subcols(lo, m - lo), w.rb_mut(), c1.rb_mut().subrows_mut(lo, m - lo), par);
                for (j, nrm) in mid_norms.iter_mut().enumerate() {
                    *nrm = norm(col(w.rb(), j));
                }
                let mut passes = 1;
                loop {
                    let mut c2 = coef2.as_mut().subrows_mut(0, m);
                    project_out(basis, w.rb_mut(), c2.rb_mut(), par);
                    for jj in 0..b {
                        for ii in 0..m {
                            c1[(ii, jj)] += c2[(ii, jj)];
                        }
                    }
                    passes += 1;
                    let mut worst = f64::INFINITY;
                    for (j, before) in mid_norms.iter_mut().enumerate() {
                        let after = norm(col(w.rb(), j));
                        worst = worst.min(after / before.max(f64::MIN_POSITIVE));
                        *before = after;
                    }
                    if worst > DGKS || passes >= 4 {
                        break;
                    }
                }
                // Column block [size, size+b) of H and its mirror.
                for jj in 0..b {
                    for ii in 0..m {
                        let val = c1[(ii, jj)];
                        h[(ii, size + jj)] = val;
                        h[(size + jj, ii)] = val;
                    }
                }
                for jj in 0..b {
                    for ii in 0..jj {
                        let s = 0.5 * (h[(size + ii, size + jj)] + h[(size + jj, size + ii)]);
                        h[(size + ii, size + jj)] = s;
                        h[(size + jj, size + ii)] = s;
                    }
                }
                orthonormalize_block(locked, basis, w, r.as_mut(), &norms, lcoef.as_mut(), &mut rng, par)?;
                size += b;
            }

            // Rayleigh–Ritz on the projected matrix.
            let m = size;
            {
                let mut s = evd_s.as_mut().subrows_mut(0, m);
                let s_diag = s.rb_mut().col_mut(0).as_diagonal_mut();
                let u = evd_u.as_mut().submatrix_mut(0, 0, m, m);
                self_adjoint_evd(
                    h.as_ref().submatrix(0, 0, m, m),
                    s_diag,
                    Some(u),
                    evd_par,
                    MemStack::new(&mut evd_mem),
                    Default::default(),
                )
                .map_err(|_| LanczosFailure::NotConverged { found: 0, wanted: self.nev })?;
            }
            // Ritz pair i is column `column[i]`: descending in magnitude (for a positive
            // operator, column m-1-i), equal magnitudes in descending column order.
            let mut column: Vec<usize> = (0..m).rev().collect();
            column.sort_by(|&a, &b| evd_s[(b, 0)].abs().total_cmp(&evd_s[(a, 0)].abs()));
            let theta: Vec<f64> = column.iter().map(|&c| evd_s[(c, 0)]).collect();
            let residual = |i: usize| -> f64 {
                let c = column[i];
                let mut acc = 0.0;
                for row in 0..b {
                    let mut x = 0.0;
                    for k in row..b {
                        x += r[(row, k)] * evd_u[(m - b + k, c)];
                    }
                    acc += x * x;
                }
                acc.sqrt()
            };
            let converged: Vec<bool> = (0..m).map(|i| residual(i) <= self.tol * theta[i].abs()).collect();
            let nconv = converged[..self.nev].iter().filter(|&&c| c).count();
            tracing::debug!(
                restart = restarts,
                basis = m,
                converged = nconv,
                wanted = self.nev,
                "block Lanczos cycle"
            );

            let done = nconv == self.nev;
            let full = size + b > ncv;
            if done || (full && restarts >= self.max_restarts) {
                if !done {
                    return Err(LanczosFailure::NotConverged { found: nconv, wanted: self.nev });
                }
                let mut vectors = Mat::<f64>::zeros(n, self.nev);
                let s_sel = Mat::<f64>::from_fn(m, self.nev, |i, j| evd_u[(i, column[j])]);
                super::kernels::matmul_tall(
                    vectors.as_mut(),
                    Accum::Replace,
                    v.as_ref().subcols(0, m),
                    s_sel.as_ref(),
                    1.0,
                    Par::rayon(0),
                );
                return Ok(LanczosOutput {
                    theta: theta[..self.nev].to_vec(),
                    vectors,
                    restarts,
                    applications,
                });
            }

            if !full {
                // A probe within the cycle: not converged yet, expand further.
                continue;
            }
            probing = n >= PROBE_MIN_ROWS && nconv as f64 >= PROBE_FRACTION * self.nev as f64;

            // Thick restart: keep the wanted Ritz vectors plus extra ones, then the residual block.
            let keep = (self.nev + nconv.min((m - self.nev) / 2)).min(ncv - 2 * b);
            let s_keep = Mat::<f64>::from_fn(m, keep, |i, j| evd_u[(i, column[j])]);
            // The strips are split into two halves updated side by side, one buffer each.
            let strips = n.div_ceil(RESTART_STRIP);
            let split = strips.div_ceil(2) * RESTART_STRIP;
            let (top, bottom) = v.as_mut().subcols_mut(0, m).split_at_row_mut(split.min(n));
            let [tmp0, tmp1] = &mut restart_tmp;
            rayon::join(
                || restart_rows(top, s_keep.as_ref(), tmp0.as_mut()),
                || restart_rows(bottom, s_keep.as_ref(), tmp1.as_mut()),
            );
            for j in 0..b {
                let (left, right) = v.as_mut().split_at_col_mut(m);
                let mut left = left;
                left.rb_mut().col_mut(keep + j).copy_from(right.rb().col(j));
            }
            h.fill(0.0);
            for (i, &t) in theta.iter().enumerate().take(keep) {
                h[(i, i)] = t;
            }
            size = keep;
            fresh = keep;
            restarts += 1;
        }
    }
}

/// `V[:, ..keep] ← V S` for the rows of `v` (`S` is `m × keep`), a strip of rows at a time
/// through `tmp` (row `i` of the result only reads row `i` of `V`).
fn restart_rows(mut v: MatMut<'_, f64>, s: MatRef<'_, f64>, mut tmp: MatMut<'_, f64>) {
    let (n, keep) = (v.nrows(), s.ncols());
    for r0 in (0..n).step_by(RESTART_STRIP) {
        let rows = RESTART_STRIP.min(n - r0);
        let mut t = tmp.rb_mut().submatrix_mut(0, 0, rows, keep);
        matmul(t.rb_mut(), Accum::Replace, v.rb().subrows(r0, rows), s, 1.0, Par::Seq);
        v.rb_mut().submatrix_mut(r0, 0, rows, keep).copy_from(t.rb());
    }
}

/// `w -= basis (basisᵀ w)`, storing the coefficients `basisᵀ w` in `c`.
fn project_out(basis: MatRef<'_, f64>, mut w: MatMut<'_, f64>, mut c: MatMut<'_, f64>, par: Par) {
    if basis.ncols() == 0 {
        return;
    }
    let _ = par;
    tn_product(basis, w.rb(), c.rb_mut());
    nn_subtract(basis, c.rb(), w.rb_mut());
}

/// QR of a block already orthogonalised against `locked` and `basis`: `w ← Q`, `r ← R`.
/// `norms[j]` is the norm of column `j` before any orthogonalisation, the reference for
/// detecting cancellation. Columns that vanish are replaced by random directions (their row of
/// `R` is zero, which keeps the Krylov relation exact up to the discarded remainder).
#[allow(clippy::too_many_arguments)]
fn orthonormalize_block(
    locked: MatRef<'_, f64>,
    basis: MatRef<'_, f64>,
    mut w: MatMut<'_, f64>,
    mut r: MatMut<'_, f64>,
    norms: &[f64],
    lcoef: MatMut<'_, f64>,
    rng: &mut ChaCha8Rng,
    par: Par,
) -> Result<(), LanczosFailure> {
    match cholesky_qr2(w.rb_mut(), r.rb_mut(), norms) {
        CholQr::Done => Ok(()),
        CholQr::Untouched => gram_schmidt_block(locked, basis, w, r, norms, lcoef, rng, par),
        CholQr::FirstPass(r1) => {
            // `w` holds W R₁⁻¹, orthonormal up to ε·cond(W)²: finish with Gram–Schmidt,
            // R = R_gs R₁.
            let b = w.ncols();
            let unit = vec![1.0; b];
            gram_schmidt_block(locked, basis, w, r.rb_mut(), &unit, lcoef, rng, par)?;
            let r_gs = r.to_owned();
            upper_product(r_gs.as_ref(), r1.as_ref(), r);
            Ok(())
        }
    }
}

/// The Gram–Schmidt path of [`orthonormalize_block`] (same contract).
#[allow(clippy::too_many_arguments)]
fn gram_schmidt_block(
    locked: MatRef<'_, f64>,
    basis: MatRef<'_, f64>,
    mut w: MatMut<'_, f64>,
    mut r: MatMut<'_, f64>,
    norms: &[f64],
    mut lcoef: MatMut<'_, f64>,
    rng: &mut ChaCha8Rng,
    par: Par,
) -> Result<(), LanczosFailure> {
    let b = w.ncols();
    r.fill(0.0);
    for j in 0..b {
        // Modified Gram–Schmidt against the earlier columns of the block, twice.
        for _ in 0..2 {
            for i in 0..j {
                let (qi, wj) = two_cols(w.rb_mut(), i, j);
                let c = dot(qi, wj);
                axpy(-c, qi, wj);
                r[(i, j)] += c;
            }
        }
        let mut nrm = norm(col(w.rb(), j));
        let reference = norms[j].max(f64::MIN_POSITIVE);
        if nrm <= BREAKDOWN * reference {
            // Numerically dependent: continue with a random direction instead.
            for i in 0..j {
                r[(i, j)] = 0.0;
            }
            let mut attempts = 0;
            loop {
                attempts += 1;
                if attempts > 5 {
                    return Err(LanczosFailure::Exhausted);
                }
                for x in col_mut(w.rb_mut(), j) {
                    *x = rng.random_range(-1.0..1.0);
                }
                let before = norm(col(w.rb(), j));
                reorthogonalize_column(locked, basis, w.rb_mut(), j, lcoef.rb_mut(), par);
                reorthogonalize_column(locked, basis, w.rb_mut(), j, lcoef.rb_mut(), par);
                nrm = norm(col(w.rb(), j));
                if nrm > 1e-6 * before {
                    break;
                }
            }
            scale(col_mut(w.rb_mut(), j), 1.0 / nrm);
            continue;
        }
        if nrm <= WEAK * reference {
            // Heavy cancellation: orthogonality to the basis may have degraded; restore it.
            scale(col_mut(w.rb_mut(), j), 1.0 / nrm);
            reorthogonalize_column(locked, basis, w.rb_mut(), j, lcoef.rb_mut(), par);
            let again = norm(col(w.rb(), j));
            scale(col_mut(w.rb_mut(), j), 1.0 / again);
            r[(j, j)] = nrm;
            continue;
        }
        r[(j, j)] = nrm;
        scale(col_mut(w.rb_mut(), j), 1.0 / nrm);
    }
    Ok(())
}

/// Relative pivot of the Cholesky QR below which a block is too ill-conditioned for it
/// (`cond(W)` of the column-scaled block above ~10⁵ would leave orthogonality errors above
/// `ε·cond²`); such blocks go through modified Gram–Schmidt.
const CHOLQR_PIVOT: f64 = 1e-5;

/// Outcome of [`cholesky_qr2`].
enum CholQr {
    /// `w ← Q`, `r ← R`.
    Done,
    /// The block is too ill-conditioned; `w` and `r` are untouched.
    Untouched,
    /// Only the first pass was applied (`w ← W R₁⁻¹`, `r` untouched): the second Cholesky
    /// factorisation failed, which round-off alone should never cause.
    FirstPass(Mat<f64>),
}

/// QR of a block by Cholesky QR done twice (`G = WᵀW = R₁ᵀR₁`, `W ← W R₁⁻¹`, then again):
/// two passes over the block instead of Gram–Schmidt's one per pair of columns, each pass in
/// parallel over rows. Declines (leaving `w` untouched) when a column is nearly dependent on the
/// others (relative pivot below [`CHOLQR_PIVOT`]) or cancelled below [`WEAK`] of its norm before
/// orthogonalisation: Gram–Schmidt handles those.
fn cholesky_qr2(mut w: MatMut<'_, f64>, r: MatMut<'_, f64>, norms: &[f64]) -> CholQr {
    let b = w.ncols();
    let mut g = Mat::<f64>::zeros(b, b);
    tn_product(w.rb(), w.rb(), g.as_mut());
    let Some(r1) = upper_cholesky(g.as_ref()) else { return CholQr::Untouched };
    for j in 0..b {
        let colnorm = g[(j, j)].sqrt();
        if r1[(j, j)] <= CHOLQR_PIVOT * colnorm || r1[(j, j)] <= WEAK * norms[j].max(f64::MIN_POSITIVE) {
            return CholQr::Untouched;
        }
    }
    solve_right_upper(w.rb_mut(), r1.as_ref());
    tn_product(w.rb(), w.rb(), g.as_mut());
    let Some(r2) = upper_cholesky(g.as_ref()) else { return CholQr::FirstPass(r1) };
    solve_right_upper(w.rb_mut(), r2.as_ref());
    upper_product(r2.as_ref(), r1.as_ref(), r);
    CholQr::Done
}

/// `out = a b` for upper triangular `a` and `b`.
fn upper_product(a: MatRef<'_, f64>, b: MatRef<'_, f64>, mut out: MatMut<'_, f64>) {
    let n = a.nrows();
    out.fill(0.0);
    for j in 0..n {
        for i in 0..=j {
            out[(i, j)] = (i..=j).map(|k| a[(i, k)] * b[(k, j)]).sum();
        }
    }
}

/// Upper triangular `R` with `RᵀR = g` (faer's dense Cholesky factor, transposed), or `None`
/// when `g` is not numerically positive definite.
fn upper_cholesky(g: MatRef<'_, f64>) -> Option<Mat<f64>> {
    let llt = g.llt(faer::Side::Lower).ok()?;
    let r = llt.L().transpose().to_owned();
    (0..r.nrows()).all(|j| r[(j, j)].is_finite() && r[(j, j)] > 0.0).then_some(r)
}

/// `w ← w R⁻¹` for an upper triangular `R`, in parallel over row chunks (rows are independent,
/// so the result does not depend on the number of threads).
fn solve_right_upper(w: MatMut<'_, f64>, r: MatRef<'_, f64>) {
    use rayon::prelude::*;
    const ROWS: usize = 2048;
    let b = w.ncols();
    let inv_diag: Vec<f64> = (0..b).map(|j| 1.0 / r[(j, j)]).collect();
    let work = w.nrows() * b * b / 2;
    w.par_row_chunks_mut(ROWS).with_min_len(super::kernels::min_len_for(work)).for_each(|mut chunk| {
        for j in 0..b {
            for i in 0..j {
                let c = r[(i, j)];
                let (left, right) = chunk.rb_mut().split_at_col_mut(j);
                let qi = col(left.into_const(), i);
                axpy(-c, qi, col_mut(right, 0));
            }
            scale(col_mut(chunk.rb_mut(), j), inv_diag[j]);
        }
    });
}

/// One classical Gram–Schmidt pass of column `j` of `w` against `locked`, `basis` and the
/// columns `0..j` of `w`.
fn reorthogonalize_column(
    locked: MatRef<'_, f64>,
    basis: MatRef<'_, f64>,
    mut w: MatMut<'_, f64>,
    j: usize,
    mut lcoef: MatMut<'_, f64>,
    par: Par,
) {
    let mut c = Mat::<f64>::zeros(basis.ncols().max(locked.ncols()), 1);
    let wj = w.rb_mut().subcols_mut(j, 1);
    let nl = locked.ncols();
    if nl > 0 {
        project_out(locked, wj, lcoef.rb_mut().subcols_mut(0, 1), par);
    }
    let wj = w.rb_mut().subcols_mut(j, 1);
    project_out(basis, wj, c.as_mut().subrows_mut(0, basis.ncols()), par);
    for i in 0..j {
        let (qi, wj) = two_cols(w.rb_mut(), i, j);
        let cc = dot(qi, wj);
        axpy(-cc, qi, wj);
    }
}

fn col<'a>(m: MatRef<'a, f64>, j: usize) -> &'a [f64] {
    m.col(j).try_as_col_major().expect("column-major storage").as_slice()
}

fn col_mut<'a>(m: MatMut<'a, f64>, j: usize) -> &'a mut [f64] {
    m.col_mut(j).try_as_col_major_mut().expect("column-major storage").as_slice_mut()
}

/// Column `i` (read) and column `j` (write) of the same matrix, `i < j`.
fn two_cols<'a>(m: MatMut<'a, f64>, i: usize, j: usize) -> (&'a [f64], &'a mut [f64]) {
    debug_assert!(i < j);
    let (left, right) = m.split_at_col_mut(j);
    (col(left.into_const(), i), col_mut(right, 0))
}

#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    // Four accumulators: lets the compiler vectorise while staying deterministic.
    let mut acc = [0.0f64; 4];
    let chunks = a.len() / 4;
    for c in 0..chunks {
        for l in 0..4 {
            acc[l] += a[4 * c + l] * b[4 * c + l];
        }
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for i in 4 * chunks..a.len() {
        s += a[i] * b[i];
    }
    s
}

#[inline]
fn norm(a: &[f64]) -> f64 {
    dot(a, a).sqrt()
}

#[inline]
fn axpy(alpha: f64, x: &[f64], y: &mut [f64]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi += alpha * xi;
    }
}

#[inline]
fn scale(x: &mut [f64], alpha: f64) {
    for xi in x {
        *xi *= alpha;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Diagonal operator with known spectrum, including a triple eigenvalue.
    fn diagonal_op(d: Vec<f64>) -> impl FnMut(MatRef<'_, f64>, MatMut<'_, f64>) {
        move |x, mut y| {
            for j in 0..x.ncols() {
                for i in 0..x.nrows() {
                    y[(i, j)] = d[i] * x[(i, j)];
                }
            }
        }
    }

    #[test]
    fn finds_largest_eigenvalues_with_multiplicity() {
        let n = 400;
        let mut d: Vec<f64> = (0..n).map(|i| 1.0 / (1.0 + i as f64)).collect();
        d[1] = 0.5;
        d[2] = 0.5; // 0.5 three times (indices 1, 2, 3? d[1]=0.5 already), plus index 1
        d[3] = 0.5;
        let mut sorted = d.clone();
        sorted.sort_by(|a, b| b.total_cmp(a));
        let lz = BlockLanczos { nev: 10, block: 4, ncv: 40, tol: 1e-10, max_restarts: 200, seed: 7 };
        let locked = Mat::<f64>::zeros(n, 0);
        let out = lz.run(n, locked.as_ref(), &mut diagonal_op(d)).unwrap();
        for (t, e) in out.theta.iter().zip(&sorted) {
            assert!((t - e).abs() < 1e-9 * e, "{t} vs {e}");
        }
        // Orthonormal vectors.
        let g = out.vectors.transpose() * &out.vectors;
        for i in 0..10 {
            for j in 0..10 {
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((g[(i, j)] - want).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn indefinite_operator_gives_the_eigenvalues_largest_in_magnitude() {
        // Eigenvalues of both signs, as `(L̂ − σ I)⁻¹` has for an interior shift σ.
        let n = 300;
        let d: Vec<f64> = (0..n).map(|i| if i % 3 == 0 { -1.0 } else { 1.0 } / (1.0 + i as f64)).collect();
        let mut by_magnitude = d.clone();
        by_magnitude.sort_by(|a, b| b.abs().total_cmp(&a.abs()));
        let lz = BlockLanczos { nev: 12, block: 4, ncv: 40, tol: 1e-10, max_restarts: 200, seed: 3 };
        let out = lz.run(n, Mat::<f64>::zeros(n, 0).as_ref(), &mut diagonal_op(d)).unwrap();
        assert!(out.theta.iter().any(|&t| t < 0.0) && out.theta.iter().any(|&t| t > 0.0));
        for (t, e) in out.theta.iter().zip(&by_magnitude) {
            assert!((t - e).abs() < 1e-9 * e.abs(), "{t} vs {e}");
        }
    }

    #[test]
    fn locked_vectors_are_avoided() {
        let n = 200;
        let d: Vec<f64> = (0..n).map(|i| 1.0 / (1.0 + i as f64)).collect();
        // Lock e_0 (eigenvalue 1): the iteration must return 1/2, 1/3, ...
        let mut locked = Mat::<f64>::zeros(n, 1);
        locked[(0, 0)] = 1.0;
        let lz = BlockLanczos { nev: 5, block: 2, ncv: 30, tol: 1e-10, max_restarts: 200, seed: 1 };
        let out = lz.run(n, locked.as_ref(), &mut diagonal_op(d)).unwrap();
        for (i, t) in out.theta.iter().enumerate() {
            let e = 1.0 / (2.0 + i as f64);
            assert!((t - e).abs() < 1e-9, "{t} vs {e}");
        }
    }

    /// Block QR, by either path: `QᵀQ = I`, `QR = W`, `R` upper triangular.
    fn check_block_qr(w: &Mat<f64>) {
        let (n, b) = (w.nrows(), w.ncols());
        let mut q = w.clone();
        let mut r = Mat::<f64>::zeros(b, b);
        let norms: Vec<f64> = (0..b).map(|j| norm(col(w.as_ref(), j))).collect();
        let locked = Mat::<f64>::zeros(n, 0);
        let basis = Mat::<f64>::zeros(n, 0);
        let mut lcoef = Mat::<f64>::zeros(0, b);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        orthonormalize_block(
            locked.as_ref(),
            basis.as_ref(),
            q.as_mut(),
            r.as_mut(),
            &norms,
            lcoef.as_mut(),
            &mut rng,
            Par::Seq,
        )
        .unwrap();
        let gram = q.transpose() * &q;
        let recon = &q * &r;
        for i in 0..b {
            for j in 0..b {
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((gram[(i, j)] - want).abs() < 1e-13, "QᵀQ[{i},{j}] = {}", gram[(i, j)]);
                if i > j {
                    assert_eq!(r[(i, j)], 0.0);
                }
            }
        }
        let scale = w.norm_max();
        assert!((&recon - w).norm_max() < 1e-12 * scale, "QR differs from W");
    }

    #[test]
    fn block_qr_is_exact_for_well_and_ill_conditioned_blocks() {
        let n = 5000;
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let w = Mat::<f64>::from_fn(n, 8, |_, j| rng.random_range(-1.0..1.0) * (1.0 + j as f64));
        check_block_qr(&w); // Cholesky QR
        let mut bad = w.clone();
        for i in 0..n {
            // Column 5 nearly parallel to column 2: Cholesky QR declines, Gram–Schmidt runs.
            bad[(i, 5)] = bad[(i, 2)] + 1e-9 * bad[(i, 5)];
        }
        check_block_qr(&bad);
    }

    #[test]
    fn restart_budget_exhaustion_is_reported() {
        let n = 300;
        let d: Vec<f64> = (0..n).map(|i| 1.0 - 1e-4 * i as f64).collect();
        let lz = BlockLanczos { nev: 20, block: 2, ncv: 26, tol: 1e-14, max_restarts: 1, seed: 1 };
        let locked = Mat::<f64>::zeros(n, 0);
        match lz.run(n, locked.as_ref(), &mut diagonal_op(d)) {
            Err(LanczosFailure::NotConverged { found, wanted }) => {
                assert_eq!(wanted, 20);
                assert!(found < 20);
            }
            other => panic!("expected NotConverged, got {other:?}"),
        }
    }
}
