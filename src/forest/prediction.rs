//! [`Prediction`]: a sparse left-stochastic matrix `X` (labels × vertices), stored column by
//! column (one column per vertex) like a CSC matrix: `offsets[v]..offsets[v+1]` index the
//! vertex's `(label, probability)` pairs, labels ascending.

use rayon::prelude::*;

use super::ForestError;

/// Per-vertex sparse posteriors over a label set (a sparse left-stochastic matrix).
#[derive(Clone, Debug, PartialEq)]
pub struct Prediction {
    n_labels: usize,
    offsets: Vec<usize>,
    labels: Vec<u32>,
    probs: Vec<f32>,
}

/// A prediction whose labels are reference vertex indices (a shared-indexing class) as a soft
/// correspondence; for other label sets, read the labels through the reference's table first.
impl crate::fmap::SoftCorrespondence for Prediction {
    fn n_test_vertices(&self) -> usize {
        self.n_vertices()
    }
    fn for_each_entry(&self, m: usize, f: &mut dyn FnMut(usize, f64)) {
        let (labels, probs) = self.posterior(m);
        for (&l, &p) in labels.iter().zip(probs) {
            f(l as usize, p as f64);
        }
    }
}

impl Prediction {
    /// Builds a prediction from CSC-like arrays, checking that offsets are monotone and end at
    /// the array length, labels are `< n_labels` and strictly ascending within a vertex, and
    /// probabilities are finite and non-negative (they are not renormalised).
    ///
    /// ```
    /// use shapeforest::forest::Prediction;
    /// let p = Prediction::from_parts(3, vec![0, 2, 3], vec![0, 2, 1], vec![0.25, 0.75, 1.0]).unwrap();
    /// assert_eq!(p.map_labels(), vec![Some(2), Some(1)]);
    /// assert!(Prediction::from_parts(3, vec![0, 1], vec![5], vec![1.0]).is_err());
    /// ```
    pub fn from_parts(
        n_labels: usize,
        offsets: Vec<usize>,
        labels: Vec<u32>,
        probs: Vec<f32>,
    ) -> Result<Self, ForestError> {
        let bad = |r: &str| Err(ForestError::InvalidParameter { name: "prediction", reason: r.into() });
        if offsets.first() != Some(&0) || offsets.last() != Some(&labels.len()) || labels.len() != probs.len()
        {
            return bad("offsets must start at 0 and end at the number of entries");
        }
        for w in offsets.windows(2) {
            if w[0] > w[1] {
                return bad("offsets must not decrease");
            }
            let ls = &labels[w[0]..w[1]];
            if ls.windows(2).any(|x| x[0] >= x[1]) {
                return bad("labels must ascend strictly within a vertex");
            }
        }
        if labels.iter().any(|&l| l as usize >= n_labels) {
            return bad("labels must be below n_labels");
        }
        if probs.iter().any(|p| !p.is_finite() || *p < 0.0) {
            return bad("probabilities must be finite and non-negative");
        }
        Ok(Self { n_labels, offsets, labels, probs })
    }

    pub(crate) fn from_chunks(n_labels: usize, chunks: Vec<(Vec<u32>, Vec<u32>, Vec<f32>)>) -> Self {
        let n: usize = chunks.iter().map(|c| c.0.len()).sum();
        let nnz: usize = chunks.iter().map(|c| c.1.len()).sum();
        let mut offsets = Vec::with_capacity(n + 1);
        offsets.push(0);
        let mut labels = Vec::with_capacity(nnz);
        let mut probs = Vec::with_capacity(nnz);
        for (lens, l, p) in chunks {
            for len in lens {
                let last = *offsets.last().unwrap_or(&0);
                offsets.push(last + len as usize);
            }
            labels.extend(l);
            probs.extend(p);
        }
        Self { n_labels, offsets, labels, probs }
    }

    /// Number of vertices (columns of `X`).
    pub fn n_vertices(&self) -> usize {
        self.offsets.len() - 1
    }

    /// Size of the label set (rows of `X`).
    pub fn n_labels(&self) -> usize {
        self.n_labels
    }

    /// Number of stored nonzeros.
    pub fn nnz(&self) -> usize {
        self.labels.len()
    }

    /// Mean number of labels with nonzero probability per vertex.
    pub fn mean_support(&self) -> f64 {
        self.nnz() as f64 / self.n_vertices().max(1) as f64
    }

    /// Mean over vertices of the largest posterior probability (0 for no vertex): how sure the
    /// prediction is, in reports.
    pub fn mean_confidence(&self) -> f64 {
        let n = self.n_vertices();
        if n == 0 {
            return 0.0;
        }
        (0..n).map(|v| self.posterior(v).1.iter().fold(0.0f32, |a, &b| a.max(b)) as f64).sum::<f64>()
            / n as f64
    }

    /// The posterior of vertex `v`: labels (ascending) and their probabilities.
    pub fn posterior(&self, v: usize) -> (&[u32], &[f32]) {
        let (a, b) = (self.offsets[v], self.offsets[v + 1]);
        (&self.labels[a..b], &self.probs[a..b])
    }

    /// The CSC-like arrays `(offsets, labels, probabilities)`.
    pub fn as_parts(&self) -> (&[usize], &[u32], &[f32]) {
        (&self.offsets, &self.labels, &self.probs)
    }

    /// The most probable label of each vertex (ties go to the smallest label); `None` for a
    /// vertex with an empty posterior.
    pub fn map_labels(&self) -> Vec<Option<u32>> {
        (0..self.n_vertices())
            .map(|v| {
                let (l, p) = self.posterior(v);
                let mut best: Option<(u32, f32)> = None;
                for (&l, &p) in l.iter().zip(p) {
                    if best.is_none_or(|(_, bp)| p > bp) {
                        best = Some((l, p));
                    }
                }
                best.map(|b| b.0)
            })
            .collect()
    }

    /// The `k` most probable labels of vertex `v`, most probable first (ties: smaller label).
    pub fn top_k(&self, v: usize, k: usize) -> Vec<(u32, f32)> {
        let (l, p) = self.posterior(v);
        let mut all: Vec<(u32, f32)> = l.iter().copied().zip(p.iter().copied()).collect();
        all.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        all.truncate(k);
        all
    }

    /// Keeps the `k` most probable labels of each vertex and renormalises them to sum to 1.
    pub fn pruned(&self, k: usize) -> Prediction {
        let chunks = vec![(0..self.n_vertices()).fold(
            (Vec::new(), Vec::new(), Vec::new()),
            |(mut lens, mut ls, mut ps): (Vec<u32>, Vec<u32>, Vec<f32>), v| {
                let mut top = self.top_k(v, k);
                top.sort_unstable_by_key(|x| x.0);
                let s: f64 = top.iter().map(|x| x.1 as f64).sum();
                lens.push(top.len() as u32);
                for (l, p) in top {
                    ls.push(l);
                    ps.push(if s > 0.0 { (p as f64 / s) as f32 } else { p });
                }
                (lens, ls, ps)
            },
        )];
        Prediction::from_chunks(self.n_labels, chunks)
    }

    /// Bayes composition through the label space: a fuzzy correspondence from the vertices of
    /// `self`'s shape A to the vertices of `other`'s shape B. With `X_A[l, a] = P(l | a)` and,
    /// assuming a uniform prior over B's vertices, `P(b | l) = X_B[l, b] / Σ_b' X_B[l, b']`,
    /// the result is `P(b | a) ∝ Σ_l P(b | l) P(l | a)`, returned as a [`Prediction`] whose
    /// "labels" are B's vertices (each column sums to 1; a vertex of A whose labels never
    /// appear on B gets an empty column). Parallel over A's vertices.
    ///
    /// ```
    /// use shapeforest::forest::Prediction;
    /// // A: vertex 0 is label 0, vertex 1 is label 1. B: vertex 0 is label 1, vertex 1 is label 0.
    /// let a = Prediction::from_parts(2, vec![0, 1, 2], vec![0, 1], vec![1.0, 1.0]).unwrap();
    /// let b = Prediction::from_parts(2, vec![0, 1, 2], vec![1, 0], vec![1.0, 1.0]).unwrap();
    /// let ab = a.compose(&b).unwrap();
    /// assert_eq!(ab.map_labels(), vec![Some(1), Some(0)]);
    /// ```
    pub fn compose(&self, other: &Prediction) -> Result<Prediction, ForestError> {
        if self.n_labels != other.n_labels {
            return Err(ForestError::IncompatibleModel(format!(
                "cannot compose predictions over {} and {} labels",
                self.n_labels, other.n_labels
            )));
        }
        // Transpose B: for each label, the (b, P(b | l)) list.
        let nl = self.n_labels;
        let nb = other.n_vertices();
        let mut row_start = vec![0usize; nl + 1];
        for &l in &other.labels {
            row_start[l as usize + 1] += 1;
        }
        for i in 0..nl {
            row_start[i + 1] += row_start[i];
        }
        let mut fill = row_start.clone();
        let mut t_vert = vec![0u32; other.nnz()];
        let mut t_prob = vec![0f64; other.nnz()];
        let mut row_sum = vec![0f64; nl];
        for b in 0..nb {
            let (ls, ps) = other.posterior(b);
            for (&l, &p) in ls.iter().zip(ps) {
                let pos = fill[l as usize];
                t_vert[pos] = b as u32;
                t_prob[pos] = p as f64;
                row_sum[l as usize] += p as f64;
                fill[l as usize] += 1;
            }
        }
        const CHUNK: usize = 256;
        let n = self.n_vertices();
        let chunks: Vec<(Vec<u32>, Vec<u32>, Vec<f32>)> = (0..n.div_ceil(CHUNK))
            .into_par_iter()
            .map(|ci| {
                let mut acc = vec![0f64; nb];
                let mut touched: Vec<u32> = Vec::new();
                let (mut lens, mut ls_out, mut ps_out) = (Vec::new(), Vec::new(), Vec::new());
                for a in ci * CHUNK..((ci + 1) * CHUNK).min(n) {
                    let (ls, ps) = self.posterior(a);
                    for (&l, &p) in ls.iter().zip(ps) {
                        let rs = row_sum[l as usize];
                        if rs <= 0.0 {
                            continue;
                        }
                        for pos in row_start[l as usize]..row_start[l as usize + 1] {
                            let b = t_vert[pos] as usize;
                            if acc[b] == 0.0 {
                                touched.push(b as u32);
                            }
                            acc[b] += p as f64 * t_prob[pos] / rs;
                        }
                    }
                    touched.sort_unstable();
                    let total: f64 = touched.iter().map(|&b| acc[b as usize]).sum();
                    let mut len = 0u32;
                    for &b in &touched {
                        let v = acc[b as usize];
                        acc[b as usize] = 0.0;
                        if v > 0.0 && total > 0.0 {
                            ls_out.push(b);
                            ps_out.push((v / total) as f32);
                            len += 1;
                        }
                    }
                    touched.clear();
                    lens.push(len);
                }
                (lens, ls_out, ps_out)
            })
            .collect();
        Ok(Prediction::from_chunks(nb, chunks))
    }
}

/// Fraction of labelled vertices whose predicted label equals the ground truth
/// (`truth[v] = None` vertices are ignored; a missing prediction counts as a miss).
///
/// ```
/// use shapeforest::forest::hit_ratio;
/// // vertex 0 hit, vertex 1 wrong, vertex 2 not predicted: 1 hit of 3 labelled vertices
/// let r = hit_ratio(&[Some(1), Some(2), None], &[Some(1), Some(3), Some(0)]);
/// assert!((r - 1.0 / 3.0).abs() < 1e-12);
/// assert_eq!(hit_ratio(&[Some(4), Some(0)], &[None, Some(0)]), 1.0);
/// ```
pub fn hit_ratio(predicted: &[Option<u32>], truth: &[Option<u32>]) -> f64 {
    let mut n = 0usize;
    let mut hits = 0usize;
    for (p, t) in predicted.iter().zip(truth) {
        if let Some(t) = t {
            n += 1;
            if *p == Some(*t) {
                hits += 1;
            }
        }
    }
    hits as f64 / n.max(1) as f64
}
