//! Tall-skinny dense products for the Lanczos orthogonalisation.
//!
//! The basis `V` (`n × m`, column-major, `m ≤ a few hundred`) is multiplied with blocks of `b`
//! columns: `C = Vᵀ W` and `W ← W − V C`. General matrix-multiply kernels copy (pack) all of `V`
//! for every such product; these kernels stream `V` once instead, keep a row chunk of `W` in
//! cache, and accumulate in registers. They run in parallel (rayon) with a fixed order of
//! operations for every output entry, so results do not depend on the number of threads.

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};
use rayon::prelude::*;

/// Rows per chunk: a chunk of a block of 8 columns (128 KiB) stays in L2.
const CHUNK: usize = 2048;

/// `c = basisᵀ w` (`c` is `m × b`).
pub(crate) fn tn_product(basis: MatRef<'_, f64>, w: MatRef<'_, f64>, c: MatMut<'_, f64>) {
    match w.ncols() {
        4 => tn_fixed::<4>(basis, w, c),
        8 => tn_fixed::<8>(basis, w, c),
        16 => tn_fixed::<16>(basis, w, c),
        _ => matmul(c, Accum::Replace, basis.transpose(), w, 1.0, Par::Seq),
    }
}

/// `w -= basis · c` (`c` is `m × b`).
pub(crate) fn nn_subtract(basis: MatRef<'_, f64>, c: MatRef<'_, f64>, w: MatMut<'_, f64>) {
    match w.ncols() {
        4 => nn_fixed::<4>(basis, c, w),
        8 => nn_fixed::<8>(basis, c, w),
        16 => nn_fixed::<16>(basis, c, w),
        _ => matmul(w, Accum::Add, basis, c, -1.0, Par::Seq),
    }
}

fn column(m: MatRef<'_, f64>, j: usize) -> &[f64] {
    m.col(j).try_as_col_major().expect("column-major storage").as_slice()
}

fn tn_fixed<const B: usize>(basis: MatRef<'_, f64>, w: MatRef<'_, f64>, mut c: MatMut<'_, f64>) {
    let (n, m) = (basis.nrows(), basis.ncols());
    let wc: [&[f64]; B] = std::array::from_fn(|j| column(w, j));
    let cols: Vec<&[f64]> = (0..m).map(|i| column(basis, i)).collect();
    let mut out = vec![[0.0f64; B]; m];
    // Each thread owns a range of basis columns and sweeps all row chunks for them.
    let per = m.div_ceil(rayon::current_num_threads().max(1) * 2).max(4);
    out.par_chunks_mut(per).zip(cols.par_chunks(per)).for_each(|(out, cols)| {
        let mut start = 0;
        while start < n {
            let end = (start + CHUNK).min(n);
            let wr: [&[f64]; B] = std::array::from_fn(|j| &wc[j][start..end]);
            accumulate_dots::<B>(out, cols, start, end, &wr);
            start = end;
        }
    });
    for (i, o) in out.iter().enumerate() {
        for j in 0..B {
            c[(i, j)] = o[j];
        }
    }
}

/// `out[i] += basis_i[start..end] · w` for every column `i` of the range.
fn accumulate_dots<const B: usize>(
    out: &mut [[f64; B]],
    cols: &[&[f64]],
    start: usize,
    end: usize,
    w: &[&[f64]; B],
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU supports AVX2 and FMA, checked just above.
        unsafe { accumulate_dots_avx2::<B>(out, cols, start, end, w) };
        return;
    }
    accumulate_dots_impl::<B, false>(out, cols, start, end, w);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn accumulate_dots_avx2<const B: usize>(
    out: &mut [[f64; B]],
    cols: &[&[f64]],
    start: usize,
    end: usize,
    w: &[&[f64]; B],
) {
    accumulate_dots_impl::<B, true>(out, cols, start, end, w);
}

#[inline(always)]
fn accumulate_dots_impl<const B: usize, const FMA: bool>(
    out: &mut [[f64; B]],
    cols: &[&[f64]],
    start: usize,
    end: usize,
    w: &[&[f64]; B],
) {
    for (o, v) in out.iter_mut().zip(cols) {
        let v = &v[start..end];
        for j in 0..B {
            o[j] += if FMA { dot_fma(v, w[j]) } else { dot_portable(v, w[j]) };
        }
    }
}

/// Dot product with eight independent lanes (fixed summation order).
#[inline(always)]
fn dot_portable(v: &[f64], w: &[f64]) -> f64 {
    let len = v.len().min(w.len());
    let full = len / 8 * 8;
    let mut acc = [0.0f64; 8];
    for (a, b) in v[..full].chunks_exact(8).zip(w[..full].chunks_exact(8)) {
        for l in 0..8 {
            acc[l] += a[l] * b[l];
        }
    }
    let mut s = ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]));
    for r in full..len {
        s += v[r] * w[r];
    }
    s
}

/// Dot product with AVX2 + FMA, lanes laid out as in [`dot_portable`].
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn dot_fma(v: &[f64], w: &[f64]) -> f64 {
    use std::arch::x86_64::*;
    let len = v.len().min(w.len());
    let full = len / 8 * 8;
    // SAFETY: only reached from functions compiled with `avx2,fma` after runtime detection;
    // every load reads 4 in-bounds elements (k + 8 <= full <= len for both slices).
    unsafe {
        let mut a0 = _mm256_setzero_pd();
        let mut a1 = _mm256_setzero_pd();
        let (pv, pw) = (v.as_ptr(), w.as_ptr());
        let mut k = 0;
        while k < full {
            a0 = _mm256_fmadd_pd(_mm256_loadu_pd(pv.add(k)), _mm256_loadu_pd(pw.add(k)), a0);
            a1 = _mm256_fmadd_pd(_mm256_loadu_pd(pv.add(k + 4)), _mm256_loadu_pd(pw.add(k + 4)), a1);
            k += 8;
        }
        let mut l0 = [0.0f64; 4];
        let mut l1 = [0.0f64; 4];
        _mm256_storeu_pd(l0.as_mut_ptr(), a0);
        _mm256_storeu_pd(l1.as_mut_ptr(), a1);
        let mut s = ((l0[0] + l1[0]) + (l0[1] + l1[1])) + ((l0[2] + l1[2]) + (l0[3] + l1[3]));
        for r in full..len {
            s = v[r].mul_add(w[r], s);
        }
        s
    }
}

#[cfg(not(target_arch = "x86_64"))]
#[inline(always)]
fn dot_fma(v: &[f64], w: &[f64]) -> f64 {
    dot_portable(v, w)
}

#[inline(always)]
fn fmadd<const FMA: bool>(a: f64, b: f64, c: f64) -> f64 {
    if FMA {
        a.mul_add(b, c)
    } else {
        a * b + c
    }
}

fn nn_fixed<const B: usize>(basis: MatRef<'_, f64>, c: MatRef<'_, f64>, w: MatMut<'_, f64>) {
    let (n, m) = (basis.nrows(), basis.ncols());
    let cols: Vec<&[f64]> = (0..m).map(|i| column(basis, i)).collect();
    let h: Vec<[f64; B]> = (0..m).map(|i| std::array::from_fn(|j| c[(i, j)])).collect();
    // Split the B columns of w into row chunks, one task per chunk.
    let mut rest = w;
    let mut col_slices: Vec<&mut [f64]> = Vec::with_capacity(B);
    for _ in 0..B {
        let (first, tail) = rest.split_at_col_mut(1);
        col_slices
            .push(first.col_mut(0).try_as_col_major_mut().expect("column-major storage").as_slice_mut());
        rest = tail;
    }
    let mut chunks: Vec<Vec<&mut [f64]>> = (0..n.div_ceil(CHUNK)).map(|_| Vec::with_capacity(B)).collect();
    for s in col_slices {
        for (q, part) in s.chunks_mut(CHUNK).enumerate() {
            chunks[q].push(part);
        }
    }
    chunks.par_iter_mut().enumerate().for_each(|(q, parts)| subtract_chunk::<B>(&cols, &h, q * CHUNK, parts));
}

/// `parts[j][r] -= Σ_i basis_i[start + r] · h[i][j]` for the rows of one chunk.
fn subtract_chunk<const B: usize>(cols: &[&[f64]], h: &[[f64; B]], start: usize, parts: &mut [&mut [f64]]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU supports AVX2 and FMA, checked just above.
        unsafe { subtract_chunk_avx2::<B>(cols, h, start, parts) };
        return;
    }
    subtract_chunk_impl::<B, false>(cols, h, start, parts);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn subtract_chunk_avx2<const B: usize>(
    cols: &[&[f64]],
    h: &[[f64; B]],
    start: usize,
    parts: &mut [&mut [f64]],
) {
    subtract_chunk_impl::<B, true>(cols, h, start, parts);
}

#[inline(always)]
fn subtract_chunk_impl<const B: usize, const FMA: bool>(
    cols: &[&[f64]],
    h: &[[f64; B]],
    start: usize,
    parts: &mut [&mut [f64]],
) {
    // Sub-chunks small enough for the rows of `w` to stay in L1 while every basis column is
    // streamed through once (basis column outer, rows inner: sequential access).
    const SUB: usize = 256;
    assert_eq!(parts.len(), B);
    let len = parts[0].len();
    for p in parts.iter() {
        assert_eq!(p.len(), len);
    }
    let mut lo = 0;
    while lo < len {
        let hi = (lo + SUB).min(len);
        let w: [&mut [f64]; B] = {
            let mut it = parts.iter_mut();
            std::array::from_fn(|_| {
                let p = it.next().expect("B parts");
                &mut p[lo..hi]
            })
        };
        let rows = hi - lo;
        for (v, hv) in cols.iter().zip(h) {
            let v = &v[start + lo..start + hi];
            for j in 0..B {
                let coef = -hv[j];
                let wj = &mut *w[j];
                for (x, &y) in wj[..rows].iter_mut().zip(&v[..rows]) {
                    *x = fmadd::<FMA>(y, coef, *x);
                }
            }
        }
        lo = hi;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::Mat;

    fn reference_check(b: usize) {
        let (n, m) = (CHUNK * 2 + 7, 13);
        let v = Mat::<f64>::from_fn(n, m, |i, j| ((i * 7 + j * 13) % 17) as f64 / 17.0 - 0.4);
        let w = Mat::<f64>::from_fn(n, b, |i, j| ((i * 3 + j * 5) % 11) as f64 / 11.0 - 0.5);
        let mut c = Mat::<f64>::zeros(m, b);
        tn_product(v.as_ref(), w.as_ref(), c.as_mut());
        let c_ref = v.transpose() * &w;
        assert!((&c - &c_ref).norm_max() < 1e-9);
        let mut w2 = w.clone();
        nn_subtract(v.as_ref(), c.as_ref(), w2.as_mut());
        let w_ref = &w - &v * &c;
        assert!((&w2 - &w_ref).norm_max() < 1e-9);
    }

    #[test]
    fn kernels_match_matmul() {
        for b in [1, 3, 4, 8, 16] {
            reference_check(b);
        }
    }
}
