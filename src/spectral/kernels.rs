//! Tall-skinny dense products for the Lanczos orthogonalisation.
//!
//! The basis `V` (`n × m`, column-major, `m ≤ a few hundred`) is multiplied with blocks of `b`
//! columns: `C = Vᵀ W` and `W ← W − V C`. General matrix-multiply kernels copy (pack) all of `V`
//! for every such product; these kernels stream `V` once instead, keep a row chunk of `W` in
//! cache, and accumulate in registers. They run in parallel (rayon) with a fixed order of
//! operations for every output entry, so results do not depend on the number of threads.

use faer::linalg::matmul::matmul;
use faer::reborrow::ReborrowMut;
use faer::{Accum, MatMut, MatRef, Par};
use rayon::prelude::*;

/// Rows per chunk: a chunk of a block of 8 columns (128 KiB) stays in L2.
const CHUNK: usize = 2048;

/// Multiply-adds below which a kernel runs on the calling thread: waking a sleeping worker costs
/// more than such a step saves (a 5K-vertex spectrum runs ~500 parallel steps, most of them
/// small: the locked vectors' projections, the block QR's Gram products and triangular solves).
const PARALLEL_MIN_WORK: usize = 1 << 20;

/// `with_min_len` for a parallel loop over `work` multiply-adds: the whole loop as one task
/// (on the calling thread, in the same order, so the same bits) when the work is small.
pub(crate) fn min_len_for(work: usize) -> usize {
    if work < PARALLEL_MIN_WORK {
        usize::MAX
    } else {
        1
    }
}

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

/// Rows per strip of [`matmul_tall`].
const TALL_STRIP: usize = 4096;

/// `dst = beta·dst + alpha · lhs · rhs` for a tall `lhs` (many rows, few columns), one strip of
/// [`TALL_STRIP`] rows at a time (in parallel over strips for `Par::Rayon`, each strip on one
/// thread). The same entries, bit for bit, as one `faer` product, but bounded packing: faer's
/// x86 kernel sizes its per-thread packing buffer from the L3 size that the CPU reports
/// (260 MiB on our VM), packs the whole of a tall `lhs` into it and keeps those pages resident
/// for the thread's lifetime: one product of a 52K × 240 basis left ~130 MB per thread.
pub(crate) fn matmul_tall<T: faer::traits::ComplexField>(
    dst: MatMut<'_, T>,
    beta: Accum,
    lhs: MatRef<'_, T>,
    rhs: MatRef<'_, T>,
    alpha: T,
    par: Par,
) {
    if lhs.nrows() <= TALL_STRIP {
        // One strip, on this thread (as every strip is), whatever `par` says.
        matmul(dst, beta, lhs, rhs, alpha, Par::Seq);
        return;
    }
    match par {
        Par::Seq => {
            let mut dst = dst;
            for r0 in (0..lhs.nrows()).step_by(TALL_STRIP) {
                let rows = TALL_STRIP.min(lhs.nrows() - r0);
                let d = dst.rb_mut().subrows_mut(r0, rows);
                matmul(d, beta, lhs.subrows(r0, rows), rhs, alpha.clone(), Par::Seq);
            }
        }
        _ => {
            dst.par_row_chunks_mut(TALL_STRIP).zip(lhs.par_row_chunks(TALL_STRIP)).for_each(|(d, l)| {
                matmul(d, beta, l, rhs, alpha.clone(), Par::Seq);
            });
        }
    }
}

/// `aᵀ b` for two tall matrices with the same rows: the top and bottom halves of the rows
/// (split at a fixed row, whatever the number of threads) multiplied side by side and added.
pub(crate) fn tall_inner_product(a: MatRef<'_, f64>, b: MatRef<'_, f64>) -> faer::Mat<f64> {
    assert_eq!(a.nrows(), b.nrows());
    let split = a.nrows() / 2;
    let half = |r0: usize, rows: usize| {
        let mut out = faer::Mat::<f64>::zeros(a.ncols(), b.ncols());
        matmul(
            out.as_mut(),
            Accum::Replace,
            a.subrows(r0, rows).transpose(),
            b.subrows(r0, rows),
            1.0,
            Par::Seq,
        );
        out
    };
    let (top, bottom) = rayon::join(|| half(0, split), || half(split, a.nrows() - split));
    top + bottom
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
    out.par_chunks_mut(per).zip(cols.par_chunks(per)).with_min_len(min_len_for(n * m * B)).for_each(
        |(out, cols)| {
            let mut start = 0;
            while start < n {
                let end = (start + CHUNK).min(n);
                let wr: [&[f64]; B] = std::array::from_fn(|j| &wc[j][start..end]);
                accumulate_dots::<B>(out, cols, start, end, &wr);
                start = end;
            }
        },
    );
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
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F, checked just above.
            unsafe { avx512::accumulate_dots::<B>(out, cols, start, end, w) };
            return;
        }
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
            // SAFETY: the CPU supports AVX2 and FMA, checked just above.
            unsafe { accumulate_dots_avx2::<B>(out, cols, start, end, w) };
            return;
        }
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
    chunks
        .par_iter_mut()
        .enumerate()
        .with_min_len(min_len_for(n * m * B))
        .for_each(|(q, parts)| subtract_chunk::<B>(&cols, &h, q * CHUNK, parts));
}

/// `parts[j][r] -= Σ_i basis_i[start + r] · h[i][j]` for the rows of one chunk.
fn subtract_chunk<const B: usize>(cols: &[&[f64]], h: &[[f64; B]], start: usize, parts: &mut [&mut [f64]]) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F, checked just above.
            unsafe { avx512::subtract_chunk::<B>(cols, h, start, parts) };
            return;
        }
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
            // SAFETY: the CPU supports AVX2 and FMA, checked just above.
            unsafe { subtract_chunk_avx2::<B>(cols, h, start, parts) };
            return;
        }
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

/// AVX-512 versions of the two kernels, register-blocked (several basis columns and several
/// columns of `w` per pass over a row range, so that each load feeds several FMAs), with the
/// same operations in the same order for every output entry as the AVX2 kernels:
/// - `accumulate_dots`: per entry and row chunk, eight lanes (rows `r ≡ 0..8 mod 8`, lanes 0–3
///   and 4–7 being [`dot_fma`]'s two accumulators), reduced as `dot_fma` reduces them, the
///   chunk's tail rows added one by one, then added to the entry;
/// - `subtract_chunk`: per entry, one FMA per basis column in ascending column order.
///
/// So their results are bit for bit those of the AVX2 kernels.
#[cfg(target_arch = "x86_64")]
mod avx512 {
    use std::arch::x86_64::*;

    /// Basis columns per block of `accumulate_dots` (with up to 8 columns of `w`: 24
    /// accumulators of the 32 registers).
    const DOT_COLS: usize = 3;
    /// Basis columns and `w` columns per block of `subtract_chunk`.
    const SUB_COLS: usize = 4;
    const SUB_W: usize = 4;
    /// Rows of `w` kept in L1 while the basis columns stream through `subtract_chunk`.
    const SUB_ROWS: usize = 256;

    /// Sum of the eight lanes in [`super::dot_fma`]'s order (lane `p` and `p + 4` first).
    #[inline(always)]
    unsafe fn reduce(a: __m512d) -> f64 {
        let mut l = [0.0f64; 8];
        // SAFETY: `l` holds 8 doubles.
        unsafe { _mm512_storeu_pd(l.as_mut_ptr(), a) };
        ((l[0] + l[4]) + (l[1] + l[5])) + ((l[2] + l[6]) + (l[3] + l[7]))
    }

    /// `out[i][j] += Σ_r basis_i[r] w_j[r - start]` over `start..end` (see the module's
    /// `accumulate_dots`).
    ///
    /// # Safety
    /// The CPU must support AVX-512F.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn accumulate_dots<const B: usize>(
        out: &mut [[f64; B]],
        cols: &[&[f64]],
        start: usize,
        end: usize,
        w: &[&[f64]; B],
    ) {
        let len = end - start;
        let full = len / 8 * 8;
        let w: [&[f64]; B] = std::array::from_fn(|j| &w[j][..len]);
        let mut i = 0;
        while i < cols.len() {
            let ib = DOT_COLS.min(cols.len() - i);
            let mut j = 0;
            while j < B {
                let jb = 8.min(B - j);
                // SAFETY: AVX-512F is enabled; every slice read has at least `len` elements.
                unsafe {
                    match (ib, jb) {
                        (3, 8) => block_dots::<3, 8, B>(out, cols, i, j, start, len, full, &w),
                        (3, 4) => block_dots::<3, 4, B>(out, cols, i, j, start, len, full, &w),
                        (2, 8) => block_dots::<2, 8, B>(out, cols, i, j, start, len, full, &w),
                        (2, 4) => block_dots::<2, 4, B>(out, cols, i, j, start, len, full, &w),
                        (1, 8) => block_dots::<1, 8, B>(out, cols, i, j, start, len, full, &w),
                        (1, 4) => block_dots::<1, 4, B>(out, cols, i, j, start, len, full, &w),
                        _ => {
                            for ii in i..i + ib {
                                for jj in j..j + jb {
                                    out[ii][jj] += super::dot_fma(&cols[ii][start..end], w[jj]);
                                }
                            }
                        }
                    }
                }
                j += jb;
            }
            i += ib;
        }
    }

    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    unsafe fn block_dots<const IB: usize, const JB: usize, const B: usize>(
        out: &mut [[f64; B]],
        cols: &[&[f64]],
        i0: usize,
        j0: usize,
        start: usize,
        len: usize,
        full: usize,
        w: &[&[f64]; B],
    ) {
        let v: [&[f64]; IB] = std::array::from_fn(|a| &cols[i0 + a][start..start + len]);
        let wb: [&[f64]; JB] = std::array::from_fn(|b| w[j0 + b]);
        // SAFETY (whole block): AVX-512F is enabled by the caller; loads read rows k..k+8 with
        // k + 8 <= full <= len, in bounds of every slice.
        unsafe {
            let mut acc = [[_mm512_setzero_pd(); JB]; IB];
            let mut k = 0;
            while k < full {
                let vv: [__m512d; IB] = std::array::from_fn(|a| _mm512_loadu_pd(v[a].as_ptr().add(k)));
                for b in 0..JB {
                    let x = _mm512_loadu_pd(wb[b].as_ptr().add(k));
                    for a in 0..IB {
                        acc[a][b] = _mm512_fmadd_pd(vv[a], x, acc[a][b]);
                    }
                }
                k += 8;
            }
            for a in 0..IB {
                for b in 0..JB {
                    let mut s = reduce(acc[a][b]);
                    for r in full..len {
                        s = v[a][r].mul_add(wb[b][r], s);
                    }
                    out[i0 + a][j0 + b] += s;
                }
            }
        }
    }

    /// `parts[j][r] -= Σ_i basis_i[start + r] · h[i][j]` (see the module's `subtract_chunk`).
    ///
    /// # Safety
    /// The CPU must support AVX-512F.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn subtract_chunk<const B: usize>(
        cols: &[&[f64]],
        h: &[[f64; B]],
        start: usize,
        parts: &mut [&mut [f64]],
    ) {
        assert_eq!(parts.len(), B);
        let len = parts[0].len();
        for p in parts.iter() {
            assert_eq!(p.len(), len);
        }
        let m = cols.len();
        let wp: Vec<*mut f64> = parts.iter_mut().map(|p| p.as_mut_ptr()).collect();
        let mut lo = 0;
        while lo < len {
            let hi = (lo + SUB_ROWS).min(len);
            let rows = hi - lo;
            let full = rows / 8 * 8;
            let mut i = 0;
            while i < m {
                let ib = SUB_COLS.min(m - i);
                let mut j = 0;
                while j < B {
                    let jb = SUB_W.min(B - j);
                    // SAFETY: AVX-512F is enabled; every pointer offset stays below `lo + rows`
                    // (≤ len) in `parts` and below `start + hi` in the basis columns, and the
                    // `parts` slices are distinct.
                    unsafe {
                        if ib == SUB_COLS && jb == SUB_W {
                            block_subtract::<B>(cols, h, i, j, start + lo, lo, full, &wp);
                        } else {
                            for b in j..j + jb {
                                for a in i..i + ib {
                                    let c = _mm512_set1_pd(-h[a][b]);
                                    let v = cols[a].as_ptr().add(start + lo);
                                    let w = wp[b].add(lo);
                                    let mut k = 0;
                                    while k < full {
                                        let x = _mm512_fmadd_pd(
                                            _mm512_loadu_pd(v.add(k)),
                                            c,
                                            _mm512_loadu_pd(w.add(k)),
                                        );
                                        _mm512_storeu_pd(w.add(k), x);
                                        k += 8;
                                    }
                                }
                            }
                        }
                    }
                    // The rows after the last multiple of 8, column by column in order.
                    for b in j..j + jb {
                        let wj = &mut parts[b][lo..hi];
                        for r in full..rows {
                            let mut x = wj[r];
                            for a in i..i + ib {
                                x = cols[a][start + lo + r].mul_add(-h[a][b], x);
                            }
                            wj[r] = x;
                        }
                    }
                    j += jb;
                }
                i += ib;
            }
            lo = hi;
        }
    }

    /// Rows `0..full` (from basis row `vrow` and `w` row `wrow`) of a block of `SUB_COLS`
    /// basis columns from `i0` and `SUB_W` columns of `w` from `j0`: each 8-row load of a basis
    /// column feeds `SUB_W` FMAs.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    unsafe fn block_subtract<const B: usize>(
        cols: &[&[f64]],
        h: &[[f64; B]],
        i0: usize,
        j0: usize,
        vrow: usize,
        wrow: usize,
        full: usize,
        wp: &[*mut f64],
    ) {
        // SAFETY: see the caller.
        unsafe {
            let c: [[__m512d; SUB_COLS]; SUB_W] =
                std::array::from_fn(|b| std::array::from_fn(|a| _mm512_set1_pd(-h[i0 + a][j0 + b])));
            let v: [*const f64; SUB_COLS] = std::array::from_fn(|a| cols[i0 + a].as_ptr().add(vrow));
            let w: [*mut f64; SUB_W] = std::array::from_fn(|b| wp[j0 + b].add(wrow));
            let mut k = 0;
            while k < full {
                let vv: [__m512d; SUB_COLS] = std::array::from_fn(|a| _mm512_loadu_pd(v[a].add(k)));
                for b in 0..SUB_W {
                    let mut x = _mm512_loadu_pd(w[b].add(k));
                    for a in 0..SUB_COLS {
                        x = _mm512_fmadd_pd(vv[a], c[b][a], x);
                    }
                    _mm512_storeu_pd(w[b].add(k), x);
                }
                k += 8;
            }
        }
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

    /// The strip-by-strip product is the one-piece product bit for bit (sequential and in
    /// parallel, with accumulation, a strided `lhs` and a last strip shorter than the others).
    #[test]
    fn tall_products_in_strips_equal_one_product_bit_for_bit() {
        let (n, k, m) = (3 * TALL_STRIP + 123, 37, 23);
        let big = Mat::<f64>::from_fn(n, k + 5, |i, j| {
            ((i * 31 + j * 17) % 101) as f64 / 7.0 - 6.5 + 1e-3 * j as f64
        });
        let lhs = big.as_ref().subcols(3, k);
        let rhs = Mat::<f64>::from_fn(k, m, |i, j| ((i * 5 + j * 11) % 13) as f64 / 3.0 - 2.0);
        let start = Mat::<f64>::from_fn(n, m, |i, j| (i + j) as f64 * 0.25);
        for beta in [Accum::Replace, Accum::Add] {
            let mut want = start.clone();
            matmul(want.as_mut(), beta, lhs, rhs.as_ref(), 0.75, Par::Seq);
            for par in [Par::Seq, Par::rayon(2)] {
                let mut got = start.clone();
                matmul_tall(got.as_mut(), beta, lhs, rhs.as_ref(), 0.75, par);
                let same = (0..m).all(|j| (0..n).all(|i| got[(i, j)].to_bits() == want[(i, j)].to_bits()));
                assert!(same, "{beta:?} {par:?}");
            }
        }
    }

    /// The AVX-512 kernels give the AVX2 kernels' results bit for bit (so the spectrum does not
    /// depend on which one the CPU runs), on row ranges with a tail and column counts that are
    /// not multiples of the blocks.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx512_kernels_equal_the_avx2_ones_bit_for_bit() {
        let has = |f: &str| match f {
            "avx512f" => std::arch::is_x86_feature_detected!("avx512f"),
            _ => std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma"),
        };
        if !has("avx512f") || !has("avx2") {
            eprintln!("this CPU lacks AVX-512F or AVX2/FMA: nothing to compare");
            return;
        }
        fn check<const B: usize>() {
            let (n, m) = (1000 + 13, 11);
            let cols_data: Vec<Vec<f64>> = (0..m)
                .map(|i| (0..n).map(|r| (((r * 7 + i * 13) % 29) as f64 / 7.0 - 1.9).sin()).collect())
                .collect();
            let cols: Vec<&[f64]> = cols_data.iter().map(|c| &c[..]).collect();
            let (start, end) = (5, n - 3);
            let w_data: Vec<Vec<f64>> = (0..B)
                .map(|j| (0..end - start).map(|r| ((r * 3 + j * 5) as f64 * 0.37).cos()).collect())
                .collect();
            let w: [&[f64]; B] = std::array::from_fn(|j| &w_data[j][..]);
            let mut a = vec![[0.25f64; B]; m];
            let mut b = a.clone();
            // SAFETY: both features were detected above.
            unsafe {
                accumulate_dots_avx2::<B>(&mut a, &cols, start, end, &w);
                avx512::accumulate_dots::<B>(&mut b, &cols, start, end, &w);
            }
            for (x, y) in a.iter().flatten().zip(b.iter().flatten()) {
                assert_eq!(x.to_bits(), y.to_bits(), "dots: {x} vs {y}");
            }
            let h: Vec<[f64; B]> =
                (0..m).map(|i| std::array::from_fn(|j| ((i * B + j) as f64).sin())).collect();
            let mut p1 = w_data.clone();
            let mut p2 = w_data.clone();
            let mut s1: Vec<&mut [f64]> = p1.iter_mut().map(|v| &mut v[..]).collect();
            let mut s2: Vec<&mut [f64]> = p2.iter_mut().map(|v| &mut v[..]).collect();
            // SAFETY: both features were detected above.
            unsafe {
                subtract_chunk_avx2::<B>(&cols, &h, start, &mut s1);
                avx512::subtract_chunk::<B>(&cols, &h, start, &mut s2);
            }
            for (x, y) in p1.iter().flatten().zip(p2.iter().flatten()) {
                assert_eq!(x.to_bits(), y.to_bits(), "subtract: {x} vs {y}");
            }
        }
        check::<4>();
        check::<8>();
        check::<16>();
    }

    #[test]
    fn kernels_match_matmul() {
        for b in [1, 3, 4, 8, 16] {
            reference_check(b);
        }
    }
}
