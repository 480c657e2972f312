//! Game-theoretic sparse matching (Rodolà, Bronstein, Albarelli, Bergamasco, Torsello,
//! "A game-theoretic approach to deformable shape matching", CVPR 2012).
//!
//! Candidate matches `(m, r)` between sample points `m` of a test shape and points `r` of a
//! reference shape play a symmetric game whose payoff rewards pairs of matches that preserve
//! geodesic distance:
//!
//! `A_ab = exp(−|d_M(m_a, m_b) − d_R(r_a, r_b)| / σ)` for compatible matches (`m_a ≠ m_b` and
//! `r_a ≠ r_b`), and `0` for conflicting ones (same test point or same reference point — the
//! one-to-one constraint) and on the diagonal.
//!
//! The replicator dynamics `x ← x ⊙ (A x) / (xᵀ A x)` on the simplex converge to an
//! evolutionarily stable strategy; its support is a set of mutually consistent matches and the
//! population mass of each is its confidence. Distances should be normalised by √area (so that
//! σ is scale free); the default σ = 0.05 is 5 % of √area.
//!
//! The dynamics start from the candidates' prior scores (e.g. forest posteriors) so that, of two
//! equally consistent groups — a shape and its left/right mirror image — the one the prior
//! favours wins.

use rayon::prelude::*;
use thiserror::Error;

/// The matching problem was malformed.
#[derive(Debug, Error)]
pub enum MatchingError {
    /// A distance matrix does not have the announced size.
    #[error("{which} distance matrix has {len} entries, expected {n}×{n}")]
    DistanceMatrixSize {
        /// Which matrix.
        which: &'static str,
        /// Entries found.
        len: usize,
        /// Side length expected.
        n: usize,
    },
    /// A candidate refers to a point outside a distance matrix.
    #[error("candidate {index} refers to test point {test} / reference point {reference} outside the distance matrices")]
    CandidateOutOfRange {
        /// Candidate index.
        index: usize,
        /// Its test point.
        test: usize,
        /// Its reference point.
        reference: usize,
    },
    /// Too many candidates for the dense payoff matrix.
    #[error(
        "{0} candidate matches: at most {MAX_CANDIDATES} are supported (lower top-k or the sample count)"
    )]
    TooManyCandidates(usize),
    /// A parameter is invalid.
    #[error("invalid matching parameter `{name}`: {reason}")]
    InvalidParameter {
        /// Parameter name.
        name: &'static str,
        /// What is wrong with it.
        reason: String,
    },
}

/// A strategy whose mass falls below this fraction of the largest is extinct: it leaves the game
/// (its row and column of the payoff) once a quarter of the strategies are. Replicator dynamics
/// never revive such a strategy in practice (it would have to grow 10¹² times to reach the
/// support threshold), and the game then runs on its few living strategies: the 250-candidate
/// games of a 20K-vertex scan, which ran all 5,000 iterations on the whole matrix, cost a tenth.
const EXTINCT: f64 = 1e-15;

/// Largest candidate set accepted (the payoff matrix is dense, `f32`: 8,192² × 4 B = 256 MiB).
pub const MAX_CANDIDATES: usize = 8192;

/// A candidate match between test point `test` and reference point `reference`
/// (indices into the two distance matrices), with a prior score ≥ 0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// Index of the test point (row of the test distance matrix).
    pub test: usize,
    /// Index of the reference point (row of the reference distance matrix).
    pub reference: usize,
    /// Prior confidence, e.g. the forest posterior; only relative values matter.
    pub prior: f64,
}

/// A selected match with its confidence weight in `(0, 1]` (1 for the strongest match).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WeightedMatch {
    /// Index of the test point.
    pub test: usize,
    /// Index of the reference point.
    pub reference: usize,
    /// Confidence: population mass relative to the largest one.
    pub weight: f64,
}

/// Parameters of the replicator dynamics.
#[derive(Clone, Debug, PartialEq)]
pub struct GameMatcherParams {
    /// Distance-distortion scale σ of the payoff (same units as the distances). Default 0.05.
    pub sigma: f64,
    /// Iteration cap. Default 5,000.
    pub max_iterations: usize,
    /// Convergence threshold on the L1 change of the population. Default 1e-9.
    pub tolerance: f64,
    /// Matches whose mass is below this fraction of the largest are dropped. Default 1e-3.
    pub support_threshold: f64,
    /// Weight of the prior in the starting population (0 = barycentre, 1 = prior only). Default 0.9.
    pub prior_weight: f64,
}

impl Default for GameMatcherParams {
    fn default() -> Self {
        Self {
            sigma: 0.05,
            max_iterations: 5000,
            tolerance: 1e-9,
            support_threshold: 1e-3,
            prior_weight: 0.9,
        }
    }
}

impl GameMatcherParams {
    /// Checks the parameters, naming the rule that is broken.
    pub fn check(&self) -> Result<(), MatchingError> {
        let bad = |name, reason: &str| Err(MatchingError::InvalidParameter { name, reason: reason.into() });
        if !(self.sigma > 0.0 && self.sigma.is_finite()) {
            return bad("sigma", "must be a positive finite number");
        }
        if self.max_iterations == 0 {
            return bad("max_iterations", "must be at least 1");
        }
        if self.tolerance.is_nan() || self.tolerance < 0.0 {
            return bad("tolerance", "must be ≥ 0");
        }
        if !(0.0..1.0).contains(&self.support_threshold) {
            return bad("support_threshold", "must be in [0, 1)");
        }
        if !(0.0..=1.0).contains(&self.prior_weight) {
            return bad("prior_weight", "must be in [0, 1]");
        }
        Ok(())
    }
}

/// Outcome of the game: the selected matches and how the dynamics ended.
#[derive(Clone, Debug)]
pub struct GameMatching {
    /// Selected one-to-one matches, strongest first.
    pub matches: Vec<WeightedMatch>,
    /// Iterations run.
    pub iterations: usize,
    /// Whether the population converged within `max_iterations`.
    pub converged: bool,
    /// Average payoff `xᵀ A x` at the end (a consistency score in [0, 1]).
    pub payoff: f64,
}

/// Runs the replicator dynamics over `candidates`.
///
/// `test_distances` is the row-major `n_test × n_test` distance matrix between test points,
/// `reference_distances` the `n_ref × n_ref` one between reference points.
///
/// ```
/// use shapeforest::matching::{game_theoretic_matching, Candidate, GameMatcherParams};
/// // Three points on a line, the same on the reference; candidates: identity and a wrong one.
/// let d = vec![0.0, 1.0, 2.0, 1.0, 0.0, 1.0, 2.0, 1.0, 0.0];
/// let c = |t, r| Candidate { test: t, reference: r, prior: 1.0 };
/// let cands = [c(0, 0), c(1, 1), c(2, 2), c(0, 1)];
/// let out = game_theoretic_matching(&cands, &d, 3, &d, 3, &GameMatcherParams { sigma: 0.2, ..Default::default() }).unwrap();
/// let mut got: Vec<_> = out.matches.iter().map(|m| (m.test, m.reference)).collect();
/// got.sort();
/// assert_eq!(got, vec![(0, 0), (1, 1), (2, 2)]);
/// ```
pub fn game_theoretic_matching(
    candidates: &[Candidate],
    test_distances: &[f64],
    n_test: usize,
    reference_distances: &[f64],
    n_reference: usize,
    params: &GameMatcherParams,
) -> Result<GameMatching, MatchingError> {
    params.check()?;
    if test_distances.len() != n_test * n_test {
        return Err(MatchingError::DistanceMatrixSize {
            which: "test",
            len: test_distances.len(),
            n: n_test,
        });
    }
    if reference_distances.len() != n_reference * n_reference {
        return Err(MatchingError::DistanceMatrixSize {
            which: "reference",
            len: reference_distances.len(),
            n: n_reference,
        });
    }
    if candidates.len() > MAX_CANDIDATES {
        return Err(MatchingError::TooManyCandidates(candidates.len()));
    }
    for (index, c) in candidates.iter().enumerate() {
        if c.test >= n_test || c.reference >= n_reference || !(c.prior >= 0.0 && c.prior.is_finite()) {
            return Err(MatchingError::CandidateOutOfRange { index, test: c.test, reference: c.reference });
        }
    }
    let n = candidates.len();
    if n == 0 {
        return Ok(GameMatching { matches: vec![], iterations: 0, converged: true, payoff: 0.0 });
    }
    let payoff =
        payoff_matrix(candidates, test_distances, n_test, reference_distances, n_reference, params.sigma);

    // Starting population: a mix of the prior and the barycentre (every strategy alive).
    let prior_sum: f64 = candidates.iter().map(|c| c.prior).sum();
    let x: Vec<f64> = candidates
        .iter()
        .map(|c| {
            let p = if prior_sum > 0.0 { c.prior / prior_sum } else { 1.0 / n as f64 };
            params.prior_weight * p + (1.0 - params.prior_weight) / n as f64
        })
        .collect();
    let mut ax = vec![0.0; n];
    let mut iterations = 0;
    let mut converged = false;
    let mut mean_payoff = 0.0;
    // The living strategies (indices into `candidates`), their masses and the payoff among
    // them; extinct ones are dropped from the game when the matrix is compacted.
    let mut alive: Vec<usize> = (0..n).collect();
    let mut a = payoff;
    let mut xa = x;
    while iterations < params.max_iterations {
        iterations += 1;
        let m = alive.len();
        mat_vec(&a, m, &xa, &mut ax[..m]);
        mean_payoff = xa.iter().zip(&ax).map(|(a, b)| a * b).sum::<f64>();
        if mean_payoff <= 0.0 {
            // No two candidates are compatible: keep the single best prior.
            break;
        }
        let mut change = 0.0;
        let mut largest = 0.0f64;
        for (xi, &ai) in xa.iter_mut().zip(&ax) {
            let next = *xi * ai / mean_payoff;
            change += (next - *xi).abs();
            *xi = next;
            largest = largest.max(next);
        }
        if change < params.tolerance {
            converged = true;
            break;
        }
        let cut = EXTINCT * largest;
        let living = xa.iter().filter(|&&v| v >= cut).count();
        if living * 4 <= m * 3 {
            let keep: Vec<usize> = (0..m).filter(|&i| xa[i] >= cut).collect();
            let mut compact = vec![0f32; living * living];
            for (row, &i) in compact.chunks_exact_mut(living).zip(&keep) {
                for (dst, &j) in row.iter_mut().zip(&keep) {
                    *dst = a[i * m + j];
                }
            }
            a = compact;
            xa = keep.iter().map(|&i| xa[i]).collect();
            alive = keep.iter().map(|&i| alive[i]).collect();
        }
    }
    let mut x = vec![0.0; n];
    for (&i, &v) in alive.iter().zip(&xa) {
        x[i] = v;
    }

    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| x[b].total_cmp(&x[a]).then(a.cmp(&b)));
    let best = x[order[0]];
    let mut used_test = std::collections::HashSet::new();
    let mut used_ref = std::collections::HashSet::new();
    let mut matches = Vec::new();
    for &a in &order {
        if best <= 0.0 || x[a] < params.support_threshold * best {
            break;
        }
        let c = candidates[a];
        // The payoff of conflicting matches is zero, so an equilibrium rarely holds two; enforce it.
        if used_test.insert(c.test) && used_ref.insert(c.reference) {
            matches.push(WeightedMatch { test: c.test, reference: c.reference, weight: x[a] / best });
        }
        if mean_payoff <= 0.0 {
            break;
        }
    }
    Ok(GameMatching { matches, iterations, converged, payoff: mean_payoff })
}

/// Dense `f32` payoff matrix, row-major.
fn payoff_matrix(
    candidates: &[Candidate],
    test_distances: &[f64],
    n_test: usize,
    reference_distances: &[f64],
    n_reference: usize,
    sigma: f64,
) -> Vec<f32> {
    let n = candidates.len();
    let mut a = vec![0f32; n * n];
    a.par_chunks_mut(n).enumerate().for_each(|(i, row)| {
        let ci = candidates[i];
        for (j, cj) in candidates.iter().enumerate() {
            if ci.test == cj.test || ci.reference == cj.reference {
                continue;
            }
            let dm = test_distances[ci.test * n_test + cj.test];
            let dr = reference_distances[ci.reference * n_reference + cj.reference];
            row[j] = (-(dm - dr).abs() / sigma).exp() as f32;
        }
    });
    a
}

/// `out = A x` for the row-major `n × n` payoff `A`, four rows at a time. Each row's sum runs in
/// [`LANES`] interleaved partial sums (entry `j` into partial sum `j mod LANES`, the remainder
/// past the last full group added to the combined sum left to right), combined in a fixed tree:
/// the order is the same on every machine, every instruction set and every thread count (plain
/// multiplies and adds, never fused), so the game's result does not depend on where it runs,
/// while the independent partial sums let the compiler use the vector units (the game runs up
/// to thousands of these products on a few hundred candidates: a fifth of the regulariser's
/// time at 5K vertices with one sequential sum per row). Small games stay on one thread, where
/// handing each product to the pool costs more than it saves; large games go parallel.
fn mat_vec(a: &[f32], n: usize, x: &[f64], out: &mut [f64]) {
    mat_vec_by(a, n, x, out, rows_block)
}

/// [`mat_vec`] with `block(a, n, x, i0, o)` filling `o` with the products of rows `i0..`.
fn mat_vec_by(
    a: &[f32],
    n: usize,
    x: &[f64],
    out: &mut [f64],
    block: fn(&[f32], usize, &[f64], usize, &mut [f64]),
) {
    let each = |(b, o): (usize, &mut [f64])| block(a, n, x, b * ROWS, o);
    if n < 1024 {
        out.chunks_mut(ROWS).enumerate().for_each(each);
    } else {
        out.par_chunks_mut(ROWS).enumerate().with_min_len(16).for_each(each);
    }
}

/// Rows per block of [`mat_vec`].
const ROWS: usize = 4;

/// Partial sums per row in [`mat_vec`].
const LANES: usize = 8;

/// The products of rows `i0..i0 + o.len()` (at most [`ROWS`]), on the widest vector unit the
/// CPU has (the same numbers on every one, see [`mat_vec`]).
fn rows_block(a: &[f32], n: usize, x: &[f64], i0: usize, o: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has AVX-512F (checked above).
            return unsafe { rows_block_avx512(a, n, x, i0, o) };
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked above).
            return unsafe { rows_block_avx2(a, n, x, i0, o) };
        }
    }
    rows_block_generic(a, n, x, i0, o)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn rows_block_avx512(a: &[f32], n: usize, x: &[f64], i0: usize, o: &mut [f64]) {
    rows_block_generic(a, n, x, i0, o)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn rows_block_avx2(a: &[f32], n: usize, x: &[f64], i0: usize, o: &mut [f64]) {
    rows_block_generic(a, n, x, i0, o)
}

#[inline(always)]
fn rows_block_generic(a: &[f32], n: usize, x: &[f64], i0: usize, o: &mut [f64]) {
    let r = |k: usize| &a[(i0 + k) * n..(i0 + k + 1) * n];
    if o.len() == ROWS {
        o.copy_from_slice(&row_dots([r(0), r(1), r(2), r(3)], x));
    } else {
        for (k, ok) in o.iter_mut().enumerate() {
            *ok = row_dots([r(k)], x)[0];
        }
    }
}

/// `rows[r] · x` for each row, in the order [`mat_vec`] documents.
#[inline(always)]
fn row_dots<const R: usize>(rows: [&[f32]; R], x: &[f64]) -> [f64; R] {
    let n = x.len();
    let full = n / LANES * LANES;
    let mut acc = [[0.0f64; LANES]; R];
    for (c, xs) in x[..full].chunks_exact(LANES).enumerate() {
        for (acc_r, row) in acc.iter_mut().zip(&rows) {
            let ar = &row[c * LANES..(c + 1) * LANES];
            for ((p, &aj), &xj) in acc_r.iter_mut().zip(ar).zip(xs) {
                *p += aj as f64 * xj;
            }
        }
    }
    let mut out = [0.0; R];
    for ((o, p), row) in out.iter_mut().zip(&acc).zip(&rows) {
        let mut s = ((p[0] + p[4]) + (p[2] + p[6])) + ((p[1] + p[5]) + (p[3] + p[7]));
        for (&aj, &xj) in row[full..n].iter().zip(&x[full..]) {
            s += aj as f64 * xj;
        }
        *o = s;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The documented order, written out plainly.
    fn lane_sum(row: &[f32], x: &[f64]) -> f64 {
        let full = x.len() / LANES * LANES;
        let mut p = [0.0f64; LANES];
        for (j, (&aj, &xj)) in row.iter().zip(x).take(full).enumerate() {
            p[j % LANES] += aj as f64 * xj;
        }
        let mut s = ((p[0] + p[4]) + (p[2] + p[6])) + ((p[1] + p[5]) + (p[3] + p[7]));
        for (&aj, &xj) in row.iter().zip(x).skip(full) {
            s += aj as f64 * xj;
        }
        s
    }

    #[test]
    fn mat_vec_sums_in_the_documented_order_bit_for_bit() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for n in [1, 5, 8, 13, 250, 1030] {
            let a: Vec<f32> = (0..n * n).map(|_| rng.random::<f32>()).collect();
            let x: Vec<f64> = (0..n).map(|_| rng.random::<f64>() * 1e-3).collect();
            let (mut out, mut generic) = (vec![0.0; n], vec![0.0; n]);
            mat_vec(&a, n, &x, &mut out);
            mat_vec_by(&a, n, &x, &mut generic, rows_block_generic);
            for i in 0..n {
                let row = &a[i * n..(i + 1) * n];
                assert_eq!(out[i].to_bits(), lane_sum(row, &x).to_bits(), "n = {n}, row {i}");
                assert_eq!(out[i].to_bits(), generic[i].to_bits(), "n = {n}, row {i}: dispatch vs generic");
                let exact: f64 = row.iter().zip(&x).map(|(&aij, &xj)| aij as f64 * xj).sum();
                assert!((out[i] - exact).abs() <= 1e-12 * exact.abs().max(1e-300), "n = {n}, row {i}");
            }
        }
    }

    /// Random points in the unit square; reference = same points (identity is the truth).
    fn planar_problem(n: usize, seed: u64) -> (Vec<[f64; 2]>, Vec<f64>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let p: Vec<[f64; 2]> = (0..n).map(|_| [rng.random::<f64>(), rng.random::<f64>()]).collect();
        let d = (0..n * n)
            .map(|k| {
                let (i, j) = (k / n, k % n);
                ((p[i][0] - p[j][0]).powi(2) + (p[i][1] - p[j][1]).powi(2)).sqrt()
            })
            .collect();
        (p, d)
    }

    #[test]
    fn recovers_identity_among_random_outliers() {
        let n = 40;
        let (_, d) = planar_problem(n, 7);
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut cands = Vec::new();
        for t in 0..n {
            cands.push(Candidate { test: t, reference: t, prior: 0.3 });
            for _ in 0..5 {
                let r = rng.random_range(0..n);
                if r != t {
                    cands.push(Candidate { test: t, reference: r, prior: rng.random::<f64>() * 0.5 });
                }
            }
        }
        let out = game_theoretic_matching(&cands, &d, n, &d, n, &GameMatcherParams::default()).unwrap();
        let correct = out.matches.iter().filter(|m| m.test == m.reference).count();
        assert!(correct >= 30, "only {correct} of {} matches correct", out.matches.len());
        assert!(
            correct as f64 >= 0.95 * out.matches.len() as f64,
            "{} wrong matches",
            out.matches.len() - correct
        );
    }

    #[test]
    fn prior_breaks_the_mirror_symmetry() {
        // Points symmetric about x = 0.5: identity and mirror are equally consistent.
        let half: Vec<[f64; 2]> = vec![[0.1, 0.2], [0.2, 0.7], [0.3, 0.4], [0.05, 0.9], [0.35, 0.1]];
        let mut pts = half.clone();
        pts.extend(half.iter().map(|p| [1.0 - p[0], p[1]]));
        let n = pts.len();
        let mirror = |i: usize| if i < 5 { i + 5 } else { i - 5 };
        let d: Vec<f64> = (0..n * n)
            .map(|k| {
                let (i, j) = (k / n, k % n);
                ((pts[i][0] - pts[j][0]).powi(2) + (pts[i][1] - pts[j][1]).powi(2)).sqrt()
            })
            .collect();
        let mut cands = Vec::new();
        for t in 0..n {
            cands.push(Candidate { test: t, reference: t, prior: 0.4 });
            cands.push(Candidate { test: t, reference: mirror(t), prior: 0.6 });
        }
        let out = game_theoretic_matching(&cands, &d, n, &d, n, &GameMatcherParams::default()).unwrap();
        assert_eq!(out.matches.len(), n);
        assert!(out.matches.iter().all(|m| m.reference == mirror(m.test)), "the mirror group should win");
    }

    #[test]
    fn one_to_one_is_enforced_and_weights_are_normalised() {
        let (_, d) = planar_problem(10, 3);
        let cands: Vec<Candidate> = (0..10)
            .flat_map(|t| (0..10).map(move |r| Candidate { test: t, reference: r, prior: 1.0 }))
            .collect();
        let out = game_theoretic_matching(&cands, &d, 10, &d, 10, &GameMatcherParams::default()).unwrap();
        let mut t: Vec<_> = out.matches.iter().map(|m| m.test).collect();
        let mut r: Vec<_> = out.matches.iter().map(|m| m.reference).collect();
        t.dedup();
        r.sort();
        r.dedup();
        assert_eq!(t.len(), out.matches.len());
        assert_eq!(r.len(), out.matches.len());
        assert!((out.matches[0].weight - 1.0).abs() < 1e-12);
        assert!(out.matches.iter().all(|m| m.weight > 0.0 && m.weight <= 1.0));
    }

    /// Dropping extinct strategies leaves the game's outcome as the plain replicator dynamics on
    /// the whole matrix give it: the same matches, the same weights to 1e-9, on games like the
    /// regulariser's (50 samples, 5 candidates each, a noisy copy of the test distances).
    #[test]
    fn extinct_strategies_leave_the_outcome_unchanged() {
        let (n, k) = (50, 5);
        for seed in 0..4 {
            let (_, d) = planar_problem(n, seed);
            let mut rng = ChaCha8Rng::seed_from_u64(100 + seed);
            let d_ref: Vec<f64> = d.iter().map(|&x| x * (1.0 + 0.05 * rng.random::<f64>())).collect();
            let mut cands = Vec::new();
            for t in 0..n {
                for c in 0..k {
                    let r = if c == 0 { t } else { rng.random_range(0..n) };
                    cands.push(Candidate { test: t, reference: r, prior: rng.random::<f64>() });
                }
            }
            let params = GameMatcherParams::default();
            let got = game_theoretic_matching(&cands, &d, n, &d_ref, n, &params).unwrap();
            // The plain dynamics, written out.
            let m = cands.len();
            let a = payoff_matrix(&cands, &d, n, &d_ref, n, params.sigma);
            let total: f64 = cands.iter().map(|c| c.prior).sum();
            let mut x: Vec<f64> = cands
                .iter()
                .map(|c| params.prior_weight * c.prior / total + (1.0 - params.prior_weight) / m as f64)
                .collect();
            let mut ax = vec![0.0; m];
            for _ in 0..params.max_iterations {
                mat_vec(&a, m, &x, &mut ax);
                let mean: f64 = x.iter().zip(&ax).map(|(p, q)| p * q).sum();
                let mut change = 0.0;
                for (xi, &ai) in x.iter_mut().zip(&ax) {
                    let next = *xi * ai / mean;
                    change += (next - *xi).abs();
                    *xi = next;
                }
                if change < params.tolerance {
                    break;
                }
            }
            let mut order: Vec<usize> = (0..m).collect();
            order.sort_by(|&i, &j| x[j].total_cmp(&x[i]).then(i.cmp(&j)));
            let best = x[order[0]];
            let (mut ut, mut ur) = (std::collections::HashSet::new(), std::collections::HashSet::new());
            let want: Vec<(usize, usize, f64)> = order
                .iter()
                .take_while(|&&i| x[i] >= params.support_threshold * best)
                .filter(|&&i| ut.insert(cands[i].test) & ur.insert(cands[i].reference))
                .map(|&i| (cands[i].test, cands[i].reference, x[i] / best))
                .collect();
            assert!(want.len() >= 10, "seed {seed}: a game with {} matches tests little", want.len());
            assert_eq!(got.matches.len(), want.len(), "seed {seed}");
            for (g, w) in got.matches.iter().zip(&want) {
                assert_eq!((g.test, g.reference), (w.0, w.1), "seed {seed}");
                assert!((g.weight - w.2).abs() <= 1e-9, "seed {seed}: weight {} vs {}", g.weight, w.2);
            }
        }
    }

    #[test]
    fn bad_input_is_an_error() {
        let d = vec![0.0; 4];
        let c = [Candidate { test: 5, reference: 0, prior: 1.0 }];
        assert!(matches!(
            game_theoretic_matching(&c, &d, 2, &d, 2, &GameMatcherParams::default()),
            Err(MatchingError::CandidateOutOfRange { .. })
        ));
        assert!(matches!(
            game_theoretic_matching(&[], &d, 3, &d, 2, &GameMatcherParams::default()),
            Err(MatchingError::DistanceMatrixSize { which: "test", .. })
        ));
        let p = GameMatcherParams { sigma: 0.0, ..Default::default() };
        let msg = p.check().unwrap_err().to_string();
        assert!(msg.contains("sigma") && msg.contains("positive"), "{msg}");
    }
}
