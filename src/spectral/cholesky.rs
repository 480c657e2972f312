//! The sparse Cholesky set-up shared by the eigensolver and the heat method: faer's
//! supernodal LLᵀ with AMD ordering, symbolic analysis once, numeric factorisation with
//! explicit scratch memory and sequential parallelism (fastest on this kind of machine).
//! Errors come back as text; each caller wraps them in its own error type.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, SymbolicCholesky, SymmetricOrdering,
};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::{SparseColMat, Triplet};
use faer::{Par, Side};

/// Symbolic analysis of the lower triangle of `a`, forced supernodal, AMD ordering.
pub(crate) fn supernodal_symbolic(a: &SparseColMat<usize, f64>) -> Result<SymbolicCholesky<usize>, String> {
    symbolic_with(a, SymmetricOrdering::Amd)
}

/// Symbolic analysis of the lower triangle of `a`, forced supernodal, in `a`'s own order (for
/// a matrix already permuted by [`fill_reducing_positions`] and [`permuted`]).
pub(crate) fn supernodal_symbolic_in_order(
    a: &SparseColMat<usize, f64>,
) -> Result<SymbolicCholesky<usize>, String> {
    symbolic_with(a, SymmetricOrdering::Identity)
}

fn symbolic_with(
    a: &SparseColMat<usize, f64>,
    ordering: SymmetricOrdering<'_, usize>,
) -> Result<SymbolicCholesky<usize>, String> {
    let params = CholeskySymbolicParams {
        supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
        ..Default::default()
    };
    factorize_symbolic_cholesky(a.symbolic(), Side::Lower, ordering, params)
        .map_err(|e| format!("symbolic analysis: {e:?}"))
}

/// The AMD fill-reducing order of `a`'s pattern (the one [`supernodal_symbolic`] uses), as
/// the position of each row in it.
pub(crate) fn fill_reducing_positions(a: &SparseColMat<usize, f64>) -> Result<Vec<usize>, String> {
    let symbolic = supernodal_symbolic(a)?;
    Ok(match symbolic.perm() {
        Some(perm) => perm.arrays().1.to_vec(),
        None => (0..a.nrows()).collect(),
    })
}

/// `P A Pᵀ` for the order `position` (row `i` of `a` becomes row `position[i]`).
pub(crate) fn permuted(
    a: &SparseColMat<usize, f64>,
    position: &[usize],
) -> Result<SparseColMat<usize, f64>, String> {
    let sym = a.symbolic();
    let mut triplets = Vec::with_capacity(a.compute_nnz());
    for j in 0..a.ncols() {
        let range = sym.col_range(j);
        for (&i, &v) in sym.row_idx()[range.clone()].iter().zip(&a.val()[range]) {
            triplets.push(Triplet::new(position[i], position[j], v));
        }
    }
    SparseColMat::try_new_from_triplets(a.nrows(), a.ncols(), &triplets).map_err(|e| format!("{e:?}"))
}

/// Numeric LLᵀ values of `a` for a symbolic analysis of its pattern. Fails (without
/// panicking) when scratch memory cannot be had or `a` is not numerically positive definite.
pub(crate) fn numeric_llt(
    symbolic: &SymbolicCholesky<usize>,
    a: &SparseColMat<usize, f64>,
) -> Result<Vec<f64>, String> {
    let par = Par::Seq;
    let mut values = vec![0.0; symbolic.len_val()];
    let mut mem = MemBuffer::try_new(symbolic.factorize_numeric_llt_scratch::<f64>(par, Default::default()))
        .map_err(|e| format!("scratch memory: {e:?}"))?;
    symbolic
        .factorize_numeric_llt(
            &mut values,
            a.as_ref(),
            Side::Lower,
            LltRegularization::default(),
            par,
            MemStack::new(&mut mem),
            Default::default(),
        )
        .map_err(|e| format!("{e:?}"))?;
    Ok(values)
}
