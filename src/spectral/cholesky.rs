//! The sparse Cholesky set-up shared by the eigensolver and the heat method: faer's
//! supernodal LLᵀ with AMD ordering, symbolic analysis once, numeric factorisation with
//! explicit scratch memory and sequential parallelism (fastest on this kind of machine).
//! Errors come back as text; each caller wraps them in its own error type.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, SymbolicCholesky, SymmetricOrdering,
};
use faer::sparse::linalg::{amd, SupernodalThreshold};
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

/// The AMD fill-reducing order of `a`'s pattern, as the position of each row in it: the order
/// [`supernodal_symbolic`] would use (faer's AMD, its default control, on the same pattern),
/// without the symbolic factorisation around it.
pub(crate) fn fill_reducing_positions(a: &SparseColMat<usize, f64>) -> Result<Vec<usize>, String> {
    let n = a.nrows();
    let (mut order, mut position) = (vec![0usize; n], vec![0usize; n]);
    let mut mem = MemBuffer::try_new(amd::order_maybe_unsorted_scratch::<usize>(n, a.compute_nnz()))
        .map_err(|e| format!("scratch memory: {e:?}"))?;
    amd::order_maybe_unsorted(
        &mut order,
        &mut position,
        a.symbolic(),
        CholeskySymbolicParams::default().amd_params,
        MemStack::new(&mut mem),
    )
    .map_err(|e| format!("fill-reducing order: {e:?}"))?;
    Ok(position)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fill_reducing_positions_are_the_symbolic_analysis_order() {
        // The Laplacian-like pattern of a 30 × 20 grid: AMD reorders it.
        let (w, h) = (30, 20);
        let id = |x: usize, y: usize| y * w + x;
        let mut t = Vec::new();
        for y in 0..h {
            for x in 0..w {
                t.push(Triplet::new(id(x, y), id(x, y), 4.0));
                for (nx, ny) in [(x + 1, y), (x, y + 1)] {
                    if nx < w && ny < h {
                        t.push(Triplet::new(id(x, y), id(nx, ny), -1.0));
                        t.push(Triplet::new(id(nx, ny), id(x, y), -1.0));
                    }
                }
            }
        }
        let a = SparseColMat::try_new_from_triplets(w * h, w * h, &t).unwrap();
        let position = fill_reducing_positions(&a).unwrap();
        let symbolic = supernodal_symbolic(&a).unwrap();
        let expected = symbolic.perm().expect("AMD gives a permutation").arrays().1.to_vec();
        assert_ne!(position, (0..w * h).collect::<Vec<_>>(), "a real reordering");
        assert_eq!(position, expected);
    }
}
