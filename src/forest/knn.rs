//! Baseline: k nearest neighbours in WKS descriptor space (the comparison of Rodolà et al.,
//! Fig. 8), producing the same [`Prediction`] type as the forest so hit ratios compare directly.
//!
//! Exact brute force: squared distances `|q|² + |t|² − 2 q·t` by blocked matrix products (faer)
//! over blocks of queries × training descriptors, keeping the `k` best per query. Each neighbour
//! votes `1/k` for its label.

use faer::Mat;
use rayon::prelude::*;

use super::{ForestError, Prediction, TrainingSet};
use crate::descriptor::{wave_kernel_signature, EnergyRange, WksParams};
use crate::spectral::Spectrum;

/// WKS descriptors of every labelled training vertex, for nearest-neighbour label transfer.
#[derive(Clone, Debug)]
pub struct WksKnn {
    params: WksParams,
    range: EnergyRange,
    k_eigen: usize,
    descriptors: Mat<f64>,
    sq_norms: Vec<f64>,
    labels: Vec<u32>,
    n_labels: usize,
}

impl WksKnn {
    /// Computes the WKS (with `params`, over the shared energy `range`, using the first
    /// `k_eigen` eigenpairs of each shape) of every labelled vertex of `set`.
    /// Use the forest's `energy_grid().range` and `k()` to compare like with like.
    pub fn fit(
        set: &TrainingSet,
        params: &WksParams,
        range: EnergyRange,
        k_eigen: usize,
    ) -> Result<Self, ForestError> {
        params.check()?;
        if k_eigen < 2 || k_eigen > set.k() {
            return Err(ForestError::InvalidParameter {
                name: "k_eigen",
                reason: format!("must be between 2 and the training set's K = {}, got {k_eigen}", set.k()),
            });
        }
        let t = params.n_energies;
        let mut rows: Vec<f64> = Vec::new();
        let mut labels = Vec::new();
        for s in set.shapes() {
            let sp = truncate(&s.spectrum, k_eigen);
            let w = wave_kernel_signature(&sp, params, Some(range))?;
            for (v, l) in s.labels.iter().enumerate() {
                if let Some(l) = l {
                    labels.push(*l);
                    rows.extend((0..t).map(|j| w[(v, j)]));
                }
            }
        }
        let n = labels.len();
        let descriptors = Mat::from_fn(n, t, |i, j| rows[i * t + j]);
        let sq_norms = (0..n).map(|i| (0..t).map(|j| rows[i * t + j].powi(2)).sum()).collect();
        Ok(Self {
            params: params.clone(),
            range,
            k_eigen,
            descriptors,
            sq_norms,
            labels,
            n_labels: set.n_labels(),
        })
    }

    /// Number of training descriptors.
    pub fn n_samples(&self) -> usize {
        self.labels.len()
    }

    /// For every vertex of `spectrum`, the labels of its `k` nearest training descriptors
    /// (Euclidean), each weighted `1/k` (duplicates summed). Parallel over query blocks.
    pub fn predict(&self, spectrum: &Spectrum, k: usize) -> Result<Prediction, ForestError> {
        if k == 0 {
            return Err(ForestError::InvalidParameter {
                name: "k",
                reason: "must be at least 1, got 0".into(),
            });
        }
        if spectrum.k() < self.k_eigen {
            return Err(ForestError::SpectrumTooShort { needed: self.k_eigen, found: spectrum.k() });
        }
        let sp = truncate(spectrum, self.k_eigen);
        let q = wave_kernel_signature(&sp, &self.params, Some(self.range))?;
        let nq = q.nrows();
        let nt = self.n_samples();
        let k = k.min(nt);
        const QB: usize = 256;
        const TB: usize = 4096;
        let chunks: Vec<(Vec<u32>, Vec<u32>, Vec<f32>)> = (0..nq.div_ceil(QB))
            .into_par_iter()
            .map(|bi| {
                let (a, b) = (bi * QB, ((bi + 1) * QB).min(nq));
                let qb = q.as_ref().subrows(a, b - a);
                let mut best: Vec<Vec<(f64, u32)>> = vec![Vec::with_capacity(k + 1); b - a];
                let mut g = Mat::<f64>::zeros(b - a, TB);
                for t0 in (0..nt).step_by(TB) {
                    let tl = TB.min(nt - t0);
                    let tb = self.descriptors.as_ref().subrows(t0, tl);
                    let mut gv = g.as_mut().subcols_mut(0, tl);
                    faer::linalg::matmul::matmul(
                        gv.as_mut(),
                        faer::Accum::Replace,
                        qb,
                        tb.transpose(),
                        1.0,
                        faer::Par::Seq,
                    );
                    for (r, list) in best.iter_mut().enumerate() {
                        for j in 0..tl {
                            let d = self.sq_norms[t0 + j] - 2.0 * gv[(r, j)];
                            if list.len() == k && d >= list[k - 1].0 {
                                continue;
                            }
                            let pos = list.partition_point(|x| x.0 <= d);
                            list.insert(pos, (d, (t0 + j) as u32));
                            list.truncate(k);
                        }
                    }
                }
                let (mut lens, mut ls, mut ps) = (Vec::new(), Vec::new(), Vec::new());
                let mut lab: Vec<u32> = Vec::with_capacity(k);
                for list in best {
                    lab.clear();
                    lab.extend(list.iter().map(|x| self.labels[x.1 as usize]));
                    lab.sort_unstable();
                    let start = ls.len();
                    let mut i = 0;
                    while i < lab.len() {
                        let mut j = i;
                        while j < lab.len() && lab[j] == lab[i] {
                            j += 1;
                        }
                        ls.push(lab[i]);
                        ps.push((j - i) as f32 / lab.len() as f32);
                        i = j;
                    }
                    lens.push((ls.len() - start) as u32);
                }
                (lens, ls, ps)
            })
            .collect();
        Ok(Prediction::from_chunks(self.n_labels, chunks))
    }
}

fn truncate(s: &Spectrum, k: usize) -> Spectrum {
    Spectrum {
        eigenvalues: s.eigenvalues[..k].to_vec(),
        eigenvectors: s.eigenvectors[..k * s.n_vertices].to_vec(),
        n_vertices: s.n_vertices,
        mass: s.mass.clone(),
        area: s.area,
    }
}
