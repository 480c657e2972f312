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
use faer::sparse::SparseColMat;
use faer::{Par, Side};

/// Symbolic analysis of the lower triangle of `a`, forced supernodal, AMD ordering.
pub(crate) fn supernodal_symbolic(a: &SparseColMat<usize, f64>) -> Result<SymbolicCholesky<usize>, String> {
    let params = CholeskySymbolicParams {
        supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
        ..Default::default()
    };
    factorize_symbolic_cholesky(a.symbolic(), Side::Lower, SymmetricOrdering::Amd, params)
        .map_err(|e| format!("symbolic analysis: {e:?}"))
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
