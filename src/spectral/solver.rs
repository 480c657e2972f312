//! The sparse Laplace–Beltrami eigensolver: [`SpectrumParams`], [`LaplaceBeltramiSolver`] and
//! [`compute_spectrum`].
//!
//! The generalised problem `L φ = λ M φ` of the mesh scaled to unit area is solved as follows.
//!
//! 1. **Reduction.** Unreferenced vertices (no incident triangle of positive area) carry no mass
//!    and no stiffness: they are removed from the problem and every eigenvector is `0` there.
//!    The remaining masses are floored at `1e-12 / n` so that `M` is positive definite; the
//!    floored mass is what [`Spectrum::mass`] holds, so `Φᵀ M Φ = I` holds exactly with it.
//! 2. **Null space.** `L` is positive semi-definite with one zero eigenvalue per connected
//!    component, eigenvector the indicator of the component (`L 1 = 0`). These are computed
//!    exactly (eigenvalue exactly `0`, eigenvector constant and positive on its component,
//!    ordered by the smallest vertex index of the component) and *locked*, so any number of
//!    components is handled, not only as many as the block size.
//! 3. **Shift-invert block Lanczos** (the `lanczos` module) on the rest: with `D = M^{1/2}` and
//!    the symmetric `L̂ = D⁻¹ L D⁻¹`, the operator `(L̂ − σ I)⁻¹`, factorised once by a supernodal
//!    sparse factorisation, has the `λ` nearest to σ as its eigenvalues `θ = 1/(λ − σ)` largest
//!    in magnitude. σ is an *interior* shift between the wanted eigenvalues where that pays and
//!    can be trusted (`LDLᵀ`, indefinite; see `factorize_interior`: fewer Lanczos vectors to
//!    convergence), else [`SpectrumParams::shift`] below the spectrum (`LLᵀ`, SPD). Its
//!    eigenvectors `y` give `φ = D⁻¹ y`. Eigenvalues are then refined as Rayleigh quotients
//!    `λ = φᵀ L φ` (tiny negative round-off is clamped to `0`).
//! 4. **Verification** (on by default). The relative residuals
//!    `‖L φ − λ M φ‖_{M⁻¹} / max(λ, 1)` are computed for every pair; and the number of
//!    eigenvalues below `τ = λ_K (1 − 10⁻⁴)` is counted independently with Sylvester's law of
//!    inertia (negative pivots of an `LDLᵀ` factorisation of `L̂ − τ I`). A pair whose residual
//!    is too large, or an eigenvalue below `τ` that the iteration missed, is reported as an
//!    error instead of silently returning wrong pairs (after an interior shift, the problem is
//!    first solved again from below the spectrum).
//!
//! Small problems (`n ≤ dense_threshold`, or K too close to `n` for a Krylov basis) are solved
//! exactly with a dense eigendecomposition instead, with the same conventions.
//!
//! **Sign convention.** An eigenvector is only defined up to sign; to make results comparable
//! across runs and solvers every eigenvector is flipped so that its entry of largest magnitude
//! is positive (among entries within a relative `10⁻⁶` of the largest magnitude, the one with
//! the smallest vertex index decides, so that antisymmetric eigenvectors get a stable sign
//! too). Eigenvectors of a repeated eigenvalue are only defined up to a rotation within their
//! eigenspace: only the spanned subspace is meaningful there.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::ldlt::factor::LdltRegularization;
use faer::linalg::evd::{self_adjoint_evd, self_adjoint_evd_scratch, ComputeEigenvectors};
use faer::linalg::matmul::matmul;
use faer::sparse::linalg::cholesky::{
    supernodal::SupernodalLdltRef, LdltRef, LltRef, SymbolicCholesky, SymbolicCholeskyRaw,
};
use faer::sparse::linalg::matmul::sparse_dense_matmul;
use faer::sparse::{SparseColMat, Triplet};
use faer::{Accum, Conj, Mat, MatMut, MatRef, Par, Side};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

use super::cholesky::{numeric_llt, supernodal_symbolic};
use super::lanczos::{BlockLanczos, LanczosFailure};
use super::{surface_operator, LaplacianKind, SpectralError, Spectrum, SurfaceOperator};
use crate::mesh::{Mesh, UnionFind};

/// Version of the numerical method; part of the spectrum cache key, bump it when results change.
/// (2: meshes with non-manifold edges use the tufted Laplacian; 3: basis 240, Cholesky QR
/// blocks, solves split in two: the same pairs to round-off, other bits; 4: an interior shift,
/// likewise.)
pub const SOLVER_VERSION: u32 = 4;

/// Relative mass floor: active vertices get at least `MASS_FLOOR / n` of the unit total area.
const MASS_FLOOR: f64 = 1e-12;
/// Relative distance below `λ_K` at which the eigenvalue count is verified.
const COUNT_MARGIN: f64 = 1e-4;

/// Parameters of the Laplace–Beltrami eigensolver.
///
/// Build with [`SpectrumParams::new`] (defaults scaled to `k`) or [`Default`] (`k = 100`), adjust
/// fields, and let [`SpectrumParams::check`] (called by every solver entry point) validate.
///
/// ```
/// use shapeforest::spectral::SpectrumParams;
/// let p = SpectrumParams::new(30);
/// assert!(p.check().is_ok());
/// let bad = SpectrumParams { shift: 0.5, ..p };
/// assert!(bad.check().unwrap_err().to_string().contains("shift"));
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SpectrumParams {
    /// Number of eigenpairs K (smallest eigenvalues first). Default 100.
    pub k: usize,
    /// Spectral shift σ on the unit-area mesh; must be negative so that `L − σM` is positive
    /// definite. Eigenvalues near σ converge first. With `verify` on and a basis shorter than
    /// 4.5 K, the solver first takes an interior shift between the wanted eigenvalues (fewer
    /// iterations; see [`SpectrumReport::shift`]) and uses this one when that cannot be
    /// trusted. Default `-0.01`.
    pub shift: f64,
    /// Lanczos block size: eigenvalues of multiplicity up to this are found together.
    /// Default 8.
    pub block_size: usize,
    /// Maximal Krylov basis size; at least `k + 2·block_size`. Default `max(240, 2.4·k)`.
    pub max_basis: usize,
    /// Relative residual tolerance of the shift-inverted problem (`‖C y − θ y‖ ≤ tol·θ`).
    /// Default `1e-10`.
    pub tol: f64,
    /// Seed of the random start block; equal seeds give bit-identical results. Default 0.
    pub seed: u64,
    /// Maximal number of thick restarts before reporting [`SpectralError::NotConverged`].
    /// Default 100.
    pub max_restarts: usize,
    /// Problems with at most this many (referenced) vertices are solved densely. Default 600.
    pub dense_threshold: usize,
    /// Verify the result: residual bound and an independent eigenvalue count (one extra sparse
    /// `LDLᵀ` factorisation). The count is what lets the solver use an interior shift (a
    /// wrong eigenvalue set is caught and solved again from below the spectrum), so without it
    /// the solver keeps to `shift`. Default `true`.
    pub verify: bool,
}

impl Default for SpectrumParams {
    fn default() -> Self {
        Self::new(100)
    }
}

impl SpectrumParams {
    /// Defaults for `k` eigenpairs (the basis size grows with `k`).
    ///
    /// ```
    /// let p = shapeforest::spectral::SpectrumParams::new(200);
    /// assert_eq!(p.k, 200);
    /// assert!(p.max_basis >= 200 + 2 * p.block_size);
    /// ```
    pub fn new(k: usize) -> Self {
        Self {
            k,
            shift: -0.01,
            block_size: 8,
            max_basis: 240.max(k * 12 / 5),
            tol: 1e-10,
            seed: 0,
            max_restarts: 100,
            dense_threshold: 600,
            verify: true,
        }
    }

    /// The same settings for `k` eigenpairs (a larger ZoomOut basis computed with the
    /// descriptors' settings); where `max_basis` is too small for `k` (below `k + 2·block_size`),
    /// it becomes [`SpectrumParams::new`]'s for `k`.
    ///
    /// ```
    /// use shapeforest::spectral::SpectrumParams;
    /// let p = SpectrumParams { tol: 1e-9, ..SpectrumParams::new(100) }.with_k(300);
    /// assert_eq!((p.k, p.tol), (300, 1e-9));
    /// assert!(p.check().is_ok());
    /// ```
    pub fn with_k(&self, k: usize) -> Self {
        let fits = self.max_basis >= k + 2 * self.block_size;
        let max_basis = if fits { self.max_basis } else { self.max_basis.max(Self::new(k).max_basis) };
        Self { k, max_basis, ..self.clone() }
    }

    /// Checks every field, naming the first offending one.
    pub fn check(&self) -> Result<(), SpectralError> {
        let invalid =
            |field: &'static str, reason: String| Err(SpectralError::InvalidParams { field, reason });
        if self.k == 0 {
            return invalid("k", "at least one eigenpair must be requested".into());
        }
        if !(self.shift.is_finite() && self.shift < 0.0) {
            return invalid(
                "shift",
                format!("must be finite and negative (L − σM must be positive definite), got {}", self.shift),
            );
        }
        if self.block_size == 0 {
            return invalid("block_size", "must be at least 1".into());
        }
        if self.max_basis < self.k + 2 * self.block_size {
            return invalid(
                "max_basis",
                format!(
                    "must be at least k + 2·block_size = {} (got {}); SpectrumParams::new(k) picks a suitable value",
                    self.k + 2 * self.block_size,
                    self.max_basis
                ),
            );
        }
        if !(self.tol.is_finite() && self.tol > 0.0 && self.tol < 1e-2) {
            return invalid("tol", format!("must be in (0, 0.01), got {}", self.tol));
        }
        if self.max_restarts == 0 {
            return invalid("max_restarts", "must be at least 1".into());
        }
        Ok(())
    }
}

/// Which method produced a spectrum.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum SpectrumMethod {
    /// Exact dense eigendecomposition (small problems).
    Dense,
    /// Only the null space was needed (K ≤ number of connected components).
    NullSpace,
    /// Shift-inverted block Lanczos.
    Lanczos,
}

/// Diagnostics of one solve.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SpectrumReport {
    /// The method used.
    pub method: SpectrumMethod,
    /// Connected components (= zero eigenvalues) of the referenced part of the mesh.
    pub n_components: usize,
    /// Vertices without area, excluded from the problem (eigenvectors are 0 there).
    pub n_unreferenced: usize,
    /// Thick restarts of the Lanczos iteration.
    pub restarts: usize,
    /// Block applications of the shift-inverted operator (each one sparse block solve).
    pub block_solves: usize,
    /// Largest relative residual `‖Lφ − λMφ‖_{M⁻¹} / max(λ, 1)` over the returned pairs.
    pub max_relative_residual: f64,
    /// The threshold below which the eigenvalue count was verified, if it was.
    pub count_verified_below: Option<f64>,
    /// The shift σ of the factorised `L − σM` (Lanczos method only): an interior one (positive,
    /// [`LaplaceBeltramiSolver`] chooses it) or [`SpectrumParams::shift`].
    #[serde(default)]
    pub shift: Option<f64>,
}

/// A Laplace–Beltrami eigensolver for one mesh: the reduced, mass-scaled problem and (for
/// large meshes) the sparse Cholesky factorisation of the shifted operator, built once.
///
/// ```
/// use shapeforest::spectral::{LaplaceBeltramiSolver, SpectrumParams};
/// use shapeforest::synth::icosphere;
/// let solver = LaplaceBeltramiSolver::new(&icosphere(2, 1.0), &SpectrumParams::new(4)).unwrap();
/// let (s, report) = solver.solve_with_report().unwrap();
/// assert_eq!(s.eigenvalues[0], 0.0);
/// assert!(report.max_relative_residual < 1e-8);
/// ```
#[derive(Debug)]
pub struct LaplaceBeltramiSolver {
    params: SpectrumParams,
    n_vertices: usize,
    area: f64,
    /// Unit-area mass, floored on active vertices, 0 on unreferenced ones (full length).
    mass: Vec<f64>,
    /// Reduced index → vertex index.
    active: Vec<usize>,
    /// `sqrt(mass)` on the reduced problem.
    sqrt_mass: Vec<f64>,
    /// `L̂ = D⁻¹ L D⁻¹` on the reduced problem, both triangles, every diagonal entry stored.
    lhat: SparseColMat<usize, f64>,
    /// Position of each diagonal entry in `lhat`'s values.
    diag_pos: Vec<usize>,
    /// Component label of each reduced vertex (labels ordered by smallest vertex index).
    component: Vec<usize>,
    n_components: usize,
    /// Cholesky factorisation of `L̂ − σ I` (sparse path only).
    factor: Option<Factorization>,
}

#[derive(Debug)]
struct Factorization {
    /// Shared with the fallback factorisation after a wrong interior shift (same pattern).
    symbolic: Arc<SymbolicCholesky<usize>>,
    values: Vec<f64>,
    /// The shift σ of the factorised `L̂ − σ I`.
    shift: f64,
    /// `LDLᵀ` of an indefinite `L̂ − σ I` (an interior shift) rather than `LLᵀ`.
    indefinite: bool,
}

impl Factorization {
    /// `y ← (L̂ − σ I)⁻¹ y` through `solver`.
    fn solve(&self, solver: &mut SplitSolve, y: MatMut<'_, f64>) {
        if self.indefinite {
            let ldlt = LdltRef::<usize, f64>::new(&self.symbolic, &self.values);
            solver.solve(|y, stack| ldlt.solve_in_place_with_conj(Conj::No, y, Par::Seq, stack), y);
        } else {
            let llt = LltRef::<usize, f64>::new(&self.symbolic, &self.values);
            solver.solve(|y, stack| llt.solve_in_place_with_conj(Conj::No, y, Par::Seq, stack), y);
        }
    }
}

impl LaplaceBeltramiSolver {
    /// Validates `params`, assembles the reduced problem and, when the sparse method will be
    /// used, factorises `L̂ − σ I`.
    pub fn new(mesh: &Mesh, params: &SpectrumParams) -> Result<Self, SpectralError> {
        params.check()?;
        let n = mesh.n_vertices();
        let operator = surface_operator(mesh);
        let area = match operator.kind {
            LaplacianKind::Cotan => mesh.surface_area(),
            LaplacianKind::Tufted => operator.total_mass(),
        };
        if !(area.is_finite() && area > 0.0) {
            return Err(SpectralError::ZeroArea);
        }
        let SurfaceOperator { weights, mass: raw_mass, .. } = operator;
        let mut has_stiffness = vec![false; n];
        for &(i, j, _) in &weights {
            has_stiffness[i] = true;
            has_stiffness[j] = true;
        }
        let active: Vec<usize> = (0..n).filter(|&i| raw_mass[i] > 0.0 || has_stiffness[i]).collect();
        let na = active.len();
        let floor = MASS_FLOOR / na.max(1) as f64;
        let mut mass = vec![0.0; n];
        for &i in &active {
            mass[i] = (raw_mass[i] / area).max(floor);
        }
        if params.k > na {
            return Err(SpectralError::TooManyEigenpairs { wanted: params.k, n_vertices: na });
        }
        let mut reduced = vec![usize::MAX; n];
        for (r, &i) in active.iter().enumerate() {
            reduced[i] = r;
        }
        let sqrt_mass: Vec<f64> = active.iter().map(|&i| mass[i].sqrt()).collect();

        // Assemble L̂ and the components of the stiffness graph.
        let mut uf = UnionFind::new(na);
        let mut triplets = Vec::with_capacity(4 * weights.len() + na);
        for r in 0..na {
            triplets.push(Triplet::new(r, r, 0.0));
        }
        for &(i, j, w) in &weights {
            let (ri, rj) = (reduced[i], reduced[j]);
            let (di, dj) = (sqrt_mass[ri], sqrt_mass[rj]);
            triplets.push(Triplet::new(ri, rj, -w / (di * dj)));
            triplets.push(Triplet::new(rj, ri, -w / (di * dj)));
            triplets.push(Triplet::new(ri, ri, w / (di * di)));
            triplets.push(Triplet::new(rj, rj, w / (dj * dj)));
            if w != 0.0 {
                uf.union(ri, rj);
            }
        }
        let lhat = SparseColMat::try_new_from_triplets(na, na, &triplets)
            .map_err(|e| SpectralError::Factorization(format!("assembling the Laplacian: {e:?}")))?;
        let mut diag_pos = Vec::with_capacity(na);
        for j in 0..na {
            let sym = lhat.symbolic();
            let (start, end) = (sym.col_ptr()[j], sym.col_ptr()[j + 1]);
            let off = sym.row_idx()[start..end]
                .iter()
                .position(|&i| i == j)
                .expect("diagonal entries are always assembled");
            diag_pos.push(start + off);
        }
        let (component, n_components) = uf.labels();

        let mut solver = Self {
            params: params.clone(),
            n_vertices: n,
            area,
            mass,
            active,
            sqrt_mass,
            lhat,
            diag_pos,
            component,
            n_components,
            factor: None,
        };
        if solver.method() == SpectrumMethod::Lanczos {
            // The interior shift relies on the final eigenvalue count to catch a wrong set, and
            // pays only where the basis is short enough to need restarts.
            let interior =
                params.verify && (params.max_basis as f64) < INTERIOR_BASIS_RATIO * params.k as f64;
            solver.factor = Some(if interior {
                solver.factorize_interior(INTERIOR_SHIFT, INTERIOR_MAX_BELOW)?
            } else {
                solver.factorize_shifted(None)?
            });
        }
        Ok(solver)
    }

    /// The parameters this solver was built with.
    pub fn params(&self) -> &SpectrumParams {
        &self.params
    }

    /// Number of vertices of the mesh (including unreferenced ones).
    pub fn n_vertices(&self) -> usize {
        self.n_vertices
    }

    /// Connected components of the mesh's referenced part: the multiplicity of eigenvalue 0.
    pub fn n_components(&self) -> usize {
        self.n_components
    }

    /// Surface area of the original mesh.
    pub fn area(&self) -> f64 {
        self.area
    }

    /// The method [`Self::solve`] will use.
    pub fn method(&self) -> SpectrumMethod {
        let na = self.active.len();
        let k = self.params.k;
        if k <= self.n_components {
            return SpectrumMethod::NullSpace;
        }
        let nev = k - self.n_components;
        let room = na - self.n_components;
        if na <= self.params.dense_threshold || nev + 2 * self.params.block_size > room {
            SpectrumMethod::Dense
        } else {
            SpectrumMethod::Lanczos
        }
    }

    /// Computes the first K eigenpairs (see the module documentation for conventions).
    pub fn solve(&self) -> Result<Spectrum, SpectralError> {
        self.solve_with_report().map(|(s, _)| s)
    }

    /// Like [`Self::solve`], also returning diagnostics.
    pub fn solve_with_report(&self) -> Result<(Spectrum, SpectrumReport), SpectralError> {
        let span = tracing::debug_span!("laplace_beltrami", n = self.n_vertices, k = self.params.k);
        let _guard = span.enter();
        let factor = self.factor.as_ref();
        match self.solve_using(factor) {
            // An interior shift whose K nearest eigenvalues were not the K smallest (or that did
            // not converge): solve again from below the spectrum.
            Err(e @ (SpectralError::NotConverged { .. } | SpectralError::MissedEigenvalues { .. }))
                if factor.is_some_and(|f| f.indefinite) =>
            {
                tracing::debug!(error = %e, "interior shift failed; solving again from below the spectrum");
                let symbolic = factor.map(|f| f.symbolic.clone());
                let fallback = self.factorize_shifted(symbolic)?;
                self.solve_using(Some(&fallback))
            }
            result => result,
        }
    }

    /// [`Self::solve_with_report`] with `factor` (`Some` for the Lanczos method).
    fn solve_using(
        &self,
        factor: Option<&Factorization>,
    ) -> Result<(Spectrum, SpectrumReport), SpectralError> {
        let k = self.params.k;
        let na = self.active.len();
        let c = self.n_components.min(k);
        let method = self.method();
        // Reduced, mass-scaled eigenvectors y (φ = y / sqrt(m)) and eigenvalues.
        let mut y = Mat::<f64>::zeros(na, k);
        let mut lambda = vec![0.0; k];
        let null = self.null_vectors();
        y.as_mut().subcols_mut(0, c).copy_from(null.as_ref().subcols(0, c));
        let (mut restarts, mut block_solves) = (0, 0);
        match method {
            SpectrumMethod::NullSpace => {}
            SpectrumMethod::Dense => {
                let (vals, vecs) = self.dense_rest(k - c)?;
                lambda[c..].copy_from_slice(&vals);
                y.as_mut().subcols_mut(c, k - c).copy_from(vecs.as_ref());
            }
            SpectrumMethod::Lanczos => {
                let t0 = std::time::Instant::now();
                let factor = factor.expect("factorised for the Lanczos method");
                let out = self.lanczos_rest(factor, k - c, null.as_ref())?;
                let t_lanczos = t0.elapsed();
                restarts = out.restarts;
                block_solves = out.applications;
                let (vals, vecs) =
                    self.purify(factor, &out.theta, out.vectors, null.as_ref().subcols(0, c))?;
                lambda[c..].copy_from_slice(&vals);
                y.as_mut().subcols_mut(c, k - c).copy_from(vecs.as_ref());
                tracing::debug!(lanczos = ?t_lanczos, purify = ?(t0.elapsed() - t_lanczos), "Lanczos stages");
            }
        }

        // Rayleigh quotients and residuals in the scaled space:
        // ‖Lφ − λMφ‖_{M⁻¹} = ‖L̂y − λy‖ and φᵀLφ = yᵀL̂y for ‖y‖ = 1.
        let mut ly = Mat::<f64>::zeros(na, k);
        {
            let half = k.div_ceil(2);
            let (ly0, ly1) = ly.as_mut().split_at_col_mut(half);
            let (y0, y1) = y.as_ref().split_at_col(half);
            let lhat = self.lhat.as_ref();
            rayon::join(
                || sparse_dense_matmul(ly0, Accum::Replace, lhat, y0, 1.0, Par::Seq),
                || sparse_dense_matmul(ly1, Accum::Replace, lhat, y1, 1.0, Par::Seq),
            );
        }
        // Per pair: the Rayleigh quotient (the null space keeps λ = 0) and the residual.
        let pairs: Vec<(f64, f64)> = (0..k)
            .into_par_iter()
            .map(|j| {
                let (yj, lyj) = (y.col_as_slice(j), ly.col_as_slice(j));
                let lam = if j < c {
                    lambda[j]
                } else {
                    let rq: f64 = yj.iter().zip(lyj).map(|(a, b)| a * b).sum::<f64>();
                    let nn: f64 = yj.iter().map(|a| a * a).sum::<f64>();
                    (rq / nn).max(0.0)
                };
                let r: f64 = yj.iter().zip(lyj).map(|(a, b)| (b - lam * a).powi(2)).sum::<f64>().sqrt();
                (lam, r / lam.max(1.0))
            })
            .collect();
        let mut max_res = 0.0f64;
        let mut residuals = vec![0.0; k];
        for (j, &(lam, res)) in pairs.iter().enumerate() {
            lambda[j] = lam;
            residuals[j] = res;
            max_res = max_res.max(res);
        }
        // Not needed any more: freed before the verification's factorisation.
        drop(ly);
        // Rayleigh quotients may reorder pairs within round-off: sort (stable) by eigenvalue.
        let mut order: Vec<usize> = (0..k).collect();
        order.sort_by(|&a, &b| lambda[a].total_cmp(&lambda[b]));

        let mut count_verified_below = None;
        if method == SpectrumMethod::Lanczos && self.params.verify {
            let bound = (1e3 * self.params.tol).max(1e-8);
            if let Some(bad) = (c..k).find(|&j| residuals[j].is_nan() || residuals[j] > bound) {
                tracing::warn!(pair = bad, residual = residuals[bad], bound, "eigenpair residual too large");
                let found = (c..k).filter(|&j| residuals[j] <= bound).count() + c;
                return Err(SpectralError::NotConverged { found, wanted: k });
            }
            let last = lambda[order[k - 1]];
            if last > 0.0 {
                let tau = last * (1.0 - COUNT_MARGIN);
                let found = lambda.iter().filter(|&&l| l < tau).count();
                let factor = factor.expect("factorised for the Lanczos method");
                match self.count_below(factor, tau) {
                    Ok(counted) if counted == found => count_verified_below = Some(tau),
                    Ok(counted) => {
                        return Err(SpectralError::MissedEigenvalues { threshold: tau, counted, found });
                    }
                    Err(e) => tracing::warn!(error = %e, "eigenvalue count could not be verified"),
                }
            }
        }

        // Scatter to full vertex indexing, φ = y / sqrt(m), with the sign convention.
        let n = self.n_vertices;
        let mut eigenvectors = vec![0.0; n * k];
        let mut eigenvalues = vec![0.0; k];
        for (dst, &src) in order.iter().enumerate() {
            eigenvalues[dst] = lambda[src];
            let out = &mut eigenvectors[dst * n..(dst + 1) * n];
            let yj = y.col_as_slice(src);
            for (r, &i) in self.active.iter().enumerate() {
                out[i] = yj[r] / self.sqrt_mass[r];
            }
            apply_sign_convention(out);
        }
        let report = SpectrumReport {
            method,
            n_components: self.n_components,
            n_unreferenced: n - na,
            restarts,
            block_solves,
            max_relative_residual: max_res,
            count_verified_below,
            shift: factor.map(|f| f.shift),
        };
        tracing::debug!(?report, "spectrum computed");
        Ok((
            Spectrum { eigenvalues, eigenvectors, n_vertices: n, mass: self.mass.clone(), area: self.area },
            report,
        ))
    }

    /// Orthonormal (Euclidean, scaled space) indicator vectors of the components.
    fn null_vectors(&self) -> Mat<f64> {
        let na = self.active.len();
        let mut z = Mat::<f64>::zeros(na, self.n_components);
        let mut norm2 = vec![0.0; self.n_components];
        for r in 0..na {
            let c = self.component[r];
            z[(r, c)] = self.sqrt_mass[r];
            norm2[c] += self.sqrt_mass[r] * self.sqrt_mass[r];
        }
        for r in 0..na {
            let c = self.component[r];
            z[(r, c)] /= norm2[c].sqrt();
        }
        z
    }

    /// Dense solve of the `count` smallest nonzero eigenpairs (after the null space).
    fn dense_rest(&self, count: usize) -> Result<(Vec<f64>, Mat<f64>), SpectralError> {
        let (s, u) = dense_evd(self.lhat.to_dense().as_ref())?;
        // The first n_components eigenvectors span the null space, replaced by the exact
        // indicators; the others are orthogonal to it.
        let skip = self.n_components;
        let vals = (0..count).map(|j| s[skip + j].max(0.0)).collect();
        let vecs = u.as_ref().subcols(skip, count).to_owned();
        Ok((vals, vecs))
    }

    fn lanczos_rest(
        &self,
        factor: &Factorization,
        nev: usize,
        null: MatRef<'_, f64>,
    ) -> Result<super::lanczos::LanczosOutput, SpectralError> {
        let na = self.active.len();
        let b = self.params.block_size;
        let ncv = self.params.max_basis.min(na - self.n_components);
        let lanczos = BlockLanczos {
            nev,
            block: b,
            ncv,
            tol: self.params.tol,
            max_restarts: self.params.max_restarts,
            seed: self.params.seed,
        };
        let mut solver = SplitSolve::new(&factor.symbolic, b);
        let mut op = |x: MatRef<'_, f64>, mut y: MatMut<'_, f64>| {
            y.copy_from(x);
            factor.solve(&mut solver, y);
        };
        let k = self.params.k;
        let c = self.n_components;
        lanczos.run(na, null.subcols(0, c), &mut op).map_err(|e| match e {
            LanczosFailure::NotConverged { found, wanted: _ } => {
                SpectralError::NotConverged { found: found + c, wanted: k }
            }
            LanczosFailure::Exhausted => SpectralError::NotConverged { found: c, wanted: k },
        })
    }

    /// One step of inverse iteration followed by Rayleigh–Ritz: `Z = C Y Θ⁻¹`, then the best
    /// pairs of `L̂` in `span(Z)`. Lanczos Ritz vectors carry round-off components along the
    /// highest-frequency eigenvectors which `L̂` amplifies by up to `λ_max/λ`; applying the
    /// operator once damps them by the same factor. `Zᵀ L̂ Z = Zᵀ(Y Θ⁻¹ + σ Z)` needs no
    /// product with `L̂`.
    fn purify(
        &self,
        factor: &Factorization,
        theta: &[f64],
        y: Mat<f64>,
        null: MatRef<'_, f64>,
    ) -> Result<(Vec<f64>, Mat<f64>), SpectralError> {
        let (na, p) = (y.nrows(), y.ncols());
        let sigma = factor.shift;
        let mut z = y.clone();
        factor.solve(&mut SplitSolve::new(&factor.symbolic, p), z.as_mut());
        for (j, &t) in theta.iter().enumerate() {
            for x in z.col_as_slice_mut(j) {
                *x /= t;
            }
        }
        // The operator amplifies null-space round-off in Y by θ_null/θ (up to 10⁵): remove it.
        if null.ncols() > 0 {
            let mut nz = Mat::<f64>::zeros(null.ncols(), p);
            matmul(nz.as_mut(), Accum::Replace, null.transpose(), z.as_ref(), 1.0, Par::Seq);
            super::kernels::matmul_tall(z.as_mut(), Accum::Add, null, nz.as_ref(), -1.0, Par::rayon(0));
        }
        // Gram matrix G = ZᵀZ ≈ I and A = Zᵀ L̂ Z = Zᵀ Y Θ⁻¹ + σ G.
        let g = super::kernels::tall_inner_product(z.as_ref(), z.as_ref());
        let mut a = super::kernels::tall_inner_product(z.as_ref(), y.as_ref());
        // Y is not read again: freed before the n × p result is allocated.
        drop(y);
        for j in 0..p {
            for i in 0..p {
                a[(i, j)] = a[(i, j)] / theta[j] + sigma * g[(i, j)];
            }
        }
        let a = Mat::<f64>::from_fn(p, p, |i, j| 0.5 * (a[(i, j)] + a[(j, i)]));
        let g = Mat::<f64>::from_fn(p, p, |i, j| 0.5 * (g[(i, j)] + g[(j, i)]));
        // Orthonormalise span(Z) through G = U D Uᵀ, W = U D^{-1/2}, then diagonalise WᵀAW.
        let (d, u) = dense_evd(g.as_ref())?;
        if d[0] <= 1e-8 * d[p - 1] {
            return Err(SpectralError::NotConverged { found: 0, wanted: self.params.k });
        }
        let w = Mat::<f64>::from_fn(p, p, |i, j| u[(i, j)] / d[j].sqrt());
        let mut aw = Mat::<f64>::zeros(p, p);
        matmul(aw.as_mut(), Accum::Replace, a.as_ref(), w.as_ref(), 1.0, Par::Seq);
        let mut wtaw = Mat::<f64>::zeros(p, p);
        matmul(wtaw.as_mut(), Accum::Replace, w.transpose(), aw.as_ref(), 1.0, Par::Seq);
        let wtaw = Mat::<f64>::from_fn(p, p, |i, j| 0.5 * (wtaw[(i, j)] + wtaw[(j, i)]));
        let (vals, s) = dense_evd(wtaw.as_ref())?;
        let mut ws = Mat::<f64>::zeros(p, p);
        matmul(ws.as_mut(), Accum::Replace, w.as_ref(), s.as_ref(), 1.0, Par::Seq);
        let mut out = Mat::<f64>::zeros(na, p);
        super::kernels::matmul_tall(
            out.as_mut(),
            Accum::Replace,
            z.as_ref(),
            ws.as_ref(),
            1.0,
            Par::rayon(0),
        );
        Ok((vals.into_iter().map(|l| l.max(0.0)).collect(), out))
    }

    /// `L̂ − shift·I` (same pattern as `L̂`).
    fn shifted(&self, shift: f64) -> SparseColMat<usize, f64> {
        let mut a = self.lhat.clone();
        let vals = a.val_mut();
        for &p in &self.diag_pos {
            vals[p] -= shift;
        }
        a
    }

    /// `LLᵀ` of `L̂ − σ I` at the (negative) `params.shift`; `symbolic`: the pattern's analysis
    /// when already done.
    fn factorize_shifted(
        &self,
        symbolic: Option<Arc<SymbolicCholesky<usize>>>,
    ) -> Result<Factorization, SpectralError> {
        let a = self.shifted(self.params.shift);
        let symbolic = match symbolic {
            Some(s) => s,
            None => Arc::new(supernodal_symbolic(&a).map_err(SpectralError::Factorization)?),
        };
        let values = numeric_llt(&symbolic, &a).map_err(|e| {
            SpectralError::Factorization(format!(
                "L − σM (σ = {}) is not numerically positive definite ({e}); \
                 the mesh may have badly degenerate triangles",
                self.params.shift
            ))
        })?;
        Ok(Factorization { symbolic, values, shift: self.params.shift, indefinite: false })
    }

    /// `LDLᵀ` of `L̂ − σ I` at an interior shift, so that the wanted eigenvalues lie on both
    /// sides of σ and the nearest unwanted one is relatively farther from them than from a shift
    /// below the spectrum: fewer Lanczos vectors to convergence (38 block solves instead of ~49
    /// on most meshes). σ starts at `fraction` ([`INTERIOR_SHIFT`]) of Weyl's estimate of
    /// `λ_K` on the unit-area surface (`4πK`); the factorisation's inertia counts the
    /// eigenvalues below it, and the K smallest are the K nearest to σ when `λ_{K+1} ≥ 2σ`,
    /// which a count of at most `max_below`·K ([`INTERIOR_MAX_BELOW`]) makes likely
    /// (eigenvalues grow about linearly, or slower). A count above that (open meshes have more
    /// small eigenvalues) moves σ down once, to where `fraction`·K would lie below it; if the
    /// count is still too high, or a factorisation fails, this falls back to
    /// [`Self::factorize_shifted`]. The final eigenvalue count verifies the set either way.
    fn factorize_interior(&self, fraction: f64, max_below: f64) -> Result<Factorization, SpectralError> {
        let k = self.params.k as f64;
        let mut sigma = fraction * 4.0 * std::f64::consts::PI * k;
        let a = self.shifted(sigma);
        let symbolic = Arc::new(supernodal_symbolic(&a).map_err(SpectralError::Factorization)?);
        let mut a = Some(a);
        for _ in 0..2 {
            let shifted = a.take().unwrap_or_else(|| self.shifted(sigma));
            let inertia = ldlt_inertia(&symbolic, &shifted);
            tracing::debug!(sigma, below = ?inertia.as_ref().map(|r| r.1).ok(), "interior shift");
            match inertia {
                Ok((values, below)) if below as f64 <= max_below * k => {
                    return Ok(Factorization { symbolic, values, shift: sigma, indefinite: true });
                }
                Ok((_, below)) => sigma *= fraction * k / below as f64,
                Err(_) => break,
            }
        }
        self.factorize_shifted(Some(symbolic))
    }

    /// Number of eigenvalues below `tau` (Sylvester inertia of `L̂ − τ I`).
    fn count_below(&self, factor: &Factorization, tau: f64) -> Result<usize, SpectralError> {
        ldlt_inertia(&factor.symbolic, &self.shifted(tau)).map(|(_, below)| below)
    }
}

/// Fraction of Weyl's estimate of `λ_K` at which the interior shift is placed, and the share
/// of K eigenvalues aimed for below it when it is moved.
const INTERIOR_SHIFT: f64 = 0.42;
/// Largest share of K eigenvalues that may lie below the interior shift.
const INTERIOR_MAX_BELOW: f64 = 0.47;
/// The interior shift is taken when the basis is shorter than this many times K. A longer one
/// converges in its first cycle from below the spectrum too (K = 50 with the basis of 240: 30
/// block solves either way), and there the indefinite factorisation's solves only cost more
/// (TOSCA cat0: 0.35 against 0.31 s); from K = 60 the interior shift saves a restart (46 → 30).
const INTERIOR_BASIS_RATIO: f64 = 4.5;

/// `LDLᵀ` values of `a` (pattern `symbolic`) and the number of negative pivots: by Sylvester's
/// law of inertia, the number of negative eigenvalues of `a`.
fn ldlt_inertia(
    symbolic: &SymbolicCholesky<usize>,
    a: &SparseColMat<usize, f64>,
) -> Result<(Vec<f64>, usize), SpectralError> {
    let mut values = vec![0.0; symbolic.len_val()];
    let mut mem =
        MemBuffer::new(symbolic.factorize_numeric_ldlt_scratch::<f64>(Par::Seq, Default::default()));
    symbolic
        .factorize_numeric_ldlt(
            &mut values,
            a.as_ref(),
            Side::Lower,
            LdltRegularization::default(),
            Par::Seq,
            MemStack::new(&mut mem),
            Default::default(),
        )
        .map_err(|e| SpectralError::Factorization(format!("LDLᵀ of L − τM: {e:?}")))?;
    let SymbolicCholeskyRaw::Supernodal(sym) = symbolic.raw() else {
        return Err(SpectralError::Factorization("expected a supernodal factorisation".into()));
    };
    let ldlt = SupernodalLdltRef::<usize, f64>::new(sym, &values);
    let mut negative = 0;
    for s in 0..sym.n_supernodes() {
        let node = ldlt.supernode(s).val();
        for j in 0..node.ncols() {
            let d = node[(j, j)];
            if !d.is_finite() {
                return Err(SpectralError::Factorization(
                    "LDLᵀ of L − τM produced a non-finite pivot".into(),
                ));
            }
            if d < 0.0 {
                negative += 1;
            }
        }
    }
    Ok((values, negative))
}

/// Sparse triangular solves of a block of right-hand sides, its columns split in two halves
/// solved side by side (`rayon::join`). The split does not depend on the number of threads, so
/// results are the same bits on one thread or several.
struct SplitSolve {
    mem: [MemBuffer; 2],
}

impl SplitSolve {
    fn new(symbolic: &SymbolicCholesky<usize>, cols: usize) -> Self {
        let half = cols.div_ceil(2).max(1);
        let scratch = || MemBuffer::new(symbolic.solve_in_place_scratch::<f64>(half, Par::Seq));
        Self { mem: [scratch(), scratch()] }
    }

    /// `y ← A⁻¹ y`, `solve(y, stack)` solving in place for a block of columns.
    fn solve(&mut self, solve: impl Fn(MatMut<'_, f64>, &mut MemStack) + Sync, y: MatMut<'_, f64>) {
        let half = y.ncols().div_ceil(2);
        let (left, right) = y.split_at_col_mut(half);
        let [m0, m1] = &mut self.mem;
        rayon::join(
            || solve(left, MemStack::new(m0)),
            || {
                if right.ncols() > 0 {
                    solve(right, MemStack::new(m1));
                }
            },
        );
    }
}

/// Eigenvalues (ascending) and eigenvectors of a small dense symmetric matrix.
fn dense_evd(a: MatRef<'_, f64>) -> Result<(Vec<f64>, Mat<f64>), SpectralError> {
    let p = a.nrows();
    let mut s = Mat::<f64>::zeros(p, 1);
    let mut u = Mat::<f64>::zeros(p, p);
    let mut mem = MemBuffer::new(self_adjoint_evd_scratch::<f64>(
        p,
        ComputeEigenvectors::Yes,
        Par::Seq,
        Default::default(),
    ));
    self_adjoint_evd(
        a,
        s.as_mut().col_mut(0).as_diagonal_mut(),
        Some(u.as_mut()),
        Par::Seq,
        MemStack::new(&mut mem),
        Default::default(),
    )
    .map_err(|_| SpectralError::DenseEigenFailed)?;
    Ok(((0..p).map(|i| s[(i, 0)]).collect(), u))
}

/// The first K eigenpairs of `L φ = λ M φ` for `mesh` scaled to unit area, ascending and
/// M-orthonormal (see the [module documentation](self) for the method and conventions).
///
/// ```
/// use shapeforest::spectral::{compute_spectrum, SpectrumParams};
/// use shapeforest::synth::icosphere;
/// let s = compute_spectrum(&icosphere(3, 2.0), &SpectrumParams::new(4)).unwrap();
/// // Unit-area sphere: λ ≈ l(l+1)·4π, multiplicity 2l+1.
/// let l1 = 2.0 * 4.0 * std::f64::consts::PI;
/// assert_eq!(s.eigenvalues[0], 0.0);
/// assert!(s.eigenvalues[1..4].iter().all(|l| (l - l1).abs() / l1 < 0.01));
/// ```
pub fn compute_spectrum(mesh: &Mesh, params: &SpectrumParams) -> Result<Spectrum, SpectralError> {
    LaplaceBeltramiSolver::new(mesh, params)?.solve()
}

/// Relative residuals `‖L φ_j − λ_j M φ_j‖_{M⁻¹} / max(λ_j, 1)` of every pair of `spectrum`
/// against `mesh` (scaled to unit area), recomputed from scratch: an independent check of any
/// spectrum, wherever it came from. Vertices without mass are skipped when the residual is
/// zero there and make the result infinite otherwise.
///
/// ```
/// use shapeforest::spectral::{dense_spectrum, relative_residuals};
/// use shapeforest::synth::icosphere;
/// let m = icosphere(2, 1.0);
/// let s = dense_spectrum(&m, 5).unwrap();
/// assert!(relative_residuals(&m, &s).unwrap().iter().all(|&r| r < 1e-10));
/// ```
pub fn relative_residuals(mesh: &Mesh, spectrum: &Spectrum) -> Result<Vec<f64>, SpectralError> {
    let n = mesh.n_vertices();
    if spectrum.n_vertices != n || spectrum.mass.len() != n || spectrum.eigenvectors.len() != n * spectrum.k()
    {
        return Err(SpectralError::SizeMismatch { mesh: n, spectrum: spectrum.n_vertices });
    }
    let l = surface_operator(mesh).stiffness();
    let k = spectrum.k();
    let mut lphi = Mat::<f64>::zeros(n, k);
    sparse_dense_matmul(lphi.as_mut(), Accum::Replace, l.as_ref(), spectrum.vectors(), 1.0, Par::Seq);
    Ok((0..k)
        .map(|j| {
            let lam = spectrum.eigenvalues[j];
            let phi = spectrum.phi(j);
            let mut acc = 0.0;
            for i in 0..n {
                let r = lphi[(i, j)] - lam * spectrum.mass[i] * phi[i];
                if spectrum.mass[i] > 0.0 {
                    acc += r * r / spectrum.mass[i];
                } else if r != 0.0 {
                    acc = f64::INFINITY;
                }
            }
            acc.sqrt() / lam.max(1.0)
        })
        .collect())
}

/// Flips `v` so that its entry of largest magnitude is positive; among entries within a
/// relative 1e-6 of the largest magnitude the one with the smallest index decides.
fn apply_sign_convention(v: &mut [f64]) {
    let max = v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    if max == 0.0 {
        return;
    }
    if let Some(&lead) = v.iter().find(|x| x.abs() >= max * (1.0 - 1e-6)) {
        if lead < 0.0 {
            for x in v.iter_mut() {
                *x = -*x;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::{icosphere, torus};

    #[test]
    fn spectrum_bits_do_not_depend_on_the_number_of_threads() {
        // 5,000 vertices: several row chunks and strips in every parallel step of the solve.
        let mesh = torus(100, 50, 1.0, 0.3);
        let params = SpectrumParams::new(30);
        let solve = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| LaplaceBeltramiSolver::new(&mesh, &params).unwrap().solve_with_report().unwrap())
        };
        let (one, one_report) = solve(1);
        let (three, _) = solve(3);
        assert_eq!(one_report.method, SpectrumMethod::Lanczos);
        assert_eq!(one.eigenvalues, three.eigenvalues);
        assert_eq!(one.eigenvectors, three.eigenvectors);
    }

    /// Largest relative difference between two eigenvalue lists.
    fn max_relative_difference(a: &[f64], b: &[f64]) -> f64 {
        let scale = 1e-6 * a.last().copied().unwrap_or(1.0);
        a.iter().zip(b).map(|(x, y)| (x - y).abs() / x.abs().max(scale)).fold(0.0, f64::max)
    }

    #[test]
    fn interior_shift_finds_the_eigenvalues_a_shift_below_the_spectrum_finds() {
        // A torus with its symmetries broken (a deterministic bump), so that most eigenvalues are
        // simple and their eigenvectors comparable.
        let mut mesh = torus(100, 50, 1.0, 0.3);
        for v in &mut mesh.vertices {
            let s = 1.0 + 0.15 * (3.0 * v[0] + v[1]).sin() + 0.1 * (2.0 * v[1] - v[2]).cos();
            v[0] *= s;
            v[2] *= 1.0 + 0.2 * v[0];
        }
        let params = SpectrumParams::new(60);
        let (interior, report) =
            LaplaceBeltramiSolver::new(&mesh, &params).unwrap().solve_with_report().unwrap();
        let sigma = report.shift.expect("the Lanczos method reports its shift");
        assert!(sigma > interior.eigenvalues[10], "an interior shift was taken: σ = {sigma}");
        assert!(report.count_verified_below.is_some());
        let below = SpectrumParams { verify: false, ..params };
        let (reference, report) =
            LaplaceBeltramiSolver::new(&mesh, &below).unwrap().solve_with_report().unwrap();
        assert_eq!(report.shift, Some(below.shift), "without the count, the solver keeps below the spectrum");
        let few = SpectrumParams::new(40);
        let (_, report) = LaplaceBeltramiSolver::new(&mesh, &few).unwrap().solve_with_report().unwrap();
        assert_eq!(report.shift, Some(few.shift), "a basis of 6 K converges from below the spectrum");
        let diff = max_relative_difference(&reference.eigenvalues, &interior.eigenvalues);
        assert!(diff < 1e-9, "eigenvalues differ by {diff:e}");
        // The same eigenvectors up to sign, where the eigenvalue is simple (the last one's
        // multiplicity is unknown: its copies may lie beyond K).
        let n = mesh.n_vertices();
        let mut simple = 0;
        for j in 1..59 {
            let l = reference.eigenvalues[j];
            let gap = (l - reference.eigenvalues[j - 1]).min(reference.eigenvalues[j + 1] - l);
            if gap < 1e-3 * l {
                continue;
            }
            let dot: f64 = (0..n)
                .map(|i| {
                    reference.eigenvectors[j * n + i] * interior.eigenvectors[j * n + i] * reference.mass[i]
                })
                .sum();
            assert!((dot.abs() - 1.0).abs() < 1e-6, "pair {j}: |⟨φ, ψ⟩_M| = {}", dot.abs());
            simple += 1;
        }
        assert!(simple >= 5, "only {simple} simple eigenvalues compared");
    }

    #[test]
    fn wrong_interior_shift_is_caught_and_solved_again() {
        let mesh = torus(100, 50, 1.0, 0.3);
        let params = SpectrumParams::new(60);
        let reference =
            LaplaceBeltramiSolver::new(&mesh, &SpectrumParams { verify: false, ..params.clone() })
                .unwrap()
                .solve()
                .unwrap();
        // σ at 0.6 of λ_K: the K eigenvalues nearest to it are not the K smallest.
        let mut solver = LaplaceBeltramiSolver::new(&mesh, &params).unwrap();
        let wrong = solver.factorize_interior(0.6, 1.0).unwrap();
        assert!(wrong.indefinite && wrong.shift > 0.55 * reference.eigenvalues[59]);
        solver.factor = Some(wrong);
        let (spectrum, report) = solver.solve_with_report().unwrap();
        assert_eq!(report.shift, Some(params.shift), "solved again from below the spectrum");
        let diff = max_relative_difference(&reference.eigenvalues, &spectrum.eigenvalues);
        assert!(diff < 1e-9, "eigenvalues differ by {diff:e}");
    }

    #[test]
    fn sign_convention_makes_largest_entry_positive() {
        let mut v = vec![0.1, -0.9, 0.3];
        apply_sign_convention(&mut v);
        assert_eq!(v, vec![-0.1, 0.9, -0.3]);
        // Antisymmetric: first of the tied maxima decides.
        let mut w = vec![0.0, -0.5, 0.5, 0.2];
        apply_sign_convention(&mut w);
        assert_eq!(w, vec![0.0, 0.5, -0.5, -0.2]);
    }

    #[test]
    fn inertia_count_matches_dense_eigenvalues() {
        let mesh = torus(30, 20, 1.0, 0.4);
        let params = SpectrumParams { dense_threshold: 0, ..SpectrumParams::new(10) };
        let solver = LaplaceBeltramiSolver::new(&mesh, &params).unwrap();
        assert_eq!(solver.method(), SpectrumMethod::Lanczos);
        let dense = super::super::dense_spectrum(&mesh, 40).unwrap();
        for &tau in &[1.0, 50.0, 200.0] {
            let expect = dense.eigenvalues.iter().filter(|&&l| l < tau).count();
            assert!(expect < 40);
            let factor = solver.factor.as_ref().unwrap();
            assert_eq!(solver.count_below(factor, tau).unwrap(), expect, "tau = {tau}");
        }
    }

    #[test]
    fn check_names_each_bad_field() {
        let base = SpectrumParams::new(10);
        let cases: Vec<(SpectrumParams, &str)> = vec![
            (SpectrumParams { k: 0, ..base.clone() }, "k"),
            (SpectrumParams { shift: 0.0, ..base.clone() }, "shift"),
            (SpectrumParams { shift: f64::NAN, ..base.clone() }, "shift"),
            (SpectrumParams { block_size: 0, ..base.clone() }, "block_size"),
            (SpectrumParams { max_basis: 20, ..base.clone() }, "max_basis"),
            (SpectrumParams { tol: 0.0, ..base.clone() }, "tol"),
            (SpectrumParams { tol: 0.5, ..base.clone() }, "tol"),
            (SpectrumParams { max_restarts: 0, ..base.clone() }, "max_restarts"),
        ];
        for (p, field) in cases {
            match p.check() {
                Err(SpectralError::InvalidParams { field: f, reason }) => {
                    assert_eq!(f, field);
                    assert!(!reason.is_empty());
                }
                other => panic!("{field}: expected InvalidParams, got {other:?}"),
            }
        }
    }

    #[test]
    fn null_space_only_when_k_is_small() {
        let s = LaplaceBeltramiSolver::new(&icosphere(1, 1.0), &SpectrumParams::new(1)).unwrap();
        assert_eq!(s.method(), SpectrumMethod::NullSpace);
        let sp = s.solve().unwrap();
        assert_eq!(sp.eigenvalues, vec![0.0]);
        // Constant 1/sqrt(total mass) = 1 on the unit-area mesh.
        assert!(sp.phi(0).iter().all(|&x| (x - 1.0).abs() < 1e-12));
    }
}
