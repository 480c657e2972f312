//! One decision tree: growing by entropy-gain splits on the parametric WKS, and routing.
//!
//! Split search (per node, per candidate `(e, k̄)`): the candidate's values `p(m; e, k̄)` of the
//! node's samples are packed with their labels into `u64` keys (order-preserving `f32` bits in
//! the high half), sorted once, and swept left to right. The sweep keeps the left and right label
//! counts in two arrays of size `|L|` (reused, reset only at the node's labels) and the sums
//! `S = Σ_l c_l ln c_l` for both sides, updated in O(1) per moved sample from a table of
//! `c ln c`; the weighted child entropy is `(n_L ln n_L − S_L + n_R ln n_R − S_R) / n`, so every
//! threshold between distinct consecutive values is scored exactly, at the price of one sort.
//! Scoring every threshold (rather than a few random ones) finds the best τ of the candidate,
//! which matters with many labels where good splits are narrow; the sort costs about as much as
//! computing the values, so it is not the bottleneck.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use std::sync::Arc;

use super::params::RandomForestParams;
use crate::descriptor::{dot_f32, LocalDescriptor, ParametricWks};

/// A node: internal when `k_bar > 0`, a leaf otherwise (`left` is then the leaf index). An
/// internal node's `energy` is a feature index: below the energy grid's `levels`, the grid
/// level `e` of a WKS split (go right when `p(m; e, k̄) > threshold`); from `levels` on, bin
/// `energy − levels` of the local histogram (go right when that bin's value `> threshold`;
/// `k̄ = 1` then, unused).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub(crate) struct Node {
    pub(crate) energy: u32,
    pub(crate) k_bar: u16,
    pub(crate) threshold: f32,
    pub(crate) left: u32,
    pub(crate) right: u32,
}

/// A grown tree: nodes (root first; children always after their parent) and the leaves' sparse
/// label distributions as flat arrays (`leaf_offsets[i]..leaf_offsets[i+1]`, labels ascending).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub(crate) struct Tree {
    pub(crate) nodes: Vec<Node>,
    pub(crate) leaf_offsets: Vec<u32>,
    pub(crate) leaf_labels: Vec<u32>,
    pub(crate) leaf_probs: Vec<f32>,
    /// Position of this tree in the growth history (for seeding and retirement).
    pub(crate) index: u64,
}

impl Tree {
    /// The leaf reached by each vertex `v` in `vertices`, from `rows(v)` (its `φ²` row, read
    /// with the shape's weight table `table`, `levels × k`, and its local histogram, empty when
    /// the forest has none), into `out` (stride `stride`): with AVX where the CPU has it, the
    /// same leaves (the split values are the same bits, see [`crate::descriptor::dot_f32`]).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn leaves_into<'r>(
        &self,
        table: &[f32],
        k: usize,
        levels: u32,
        rows: impl Fn(usize) -> (&'r [f32], &'r [f32]),
        vertices: std::ops::Range<usize>,
        out: &mut [u32],
        stride: usize,
    ) {
        #[allow(clippy::too_many_arguments)]
        #[inline(always)]
        fn walk<'r>(
            tree: &Tree,
            table: &[f32],
            k: usize,
            levels: u32,
            rows: &impl Fn(usize) -> (&'r [f32], &'r [f32]),
            vertices: std::ops::Range<usize>,
            out: &mut [u32],
            stride: usize,
            dot: impl Fn(&[f32], &[f32]) -> f32,
        ) {
            let first = vertices.start;
            for v in vertices {
                let (row, local) = rows(v);
                let mut n = 0usize;
                let leaf = loop {
                    let node = &tree.nodes[n];
                    if node.k_bar == 0 {
                        break node.left;
                    }
                    let value = if node.energy < levels {
                        let kb = node.k_bar as usize;
                        let w = &table[node.energy as usize * k..node.energy as usize * k + kb];
                        dot(w, &row[..kb])
                    } else {
                        local[(node.energy - levels) as usize]
                    };
                    n = if value > node.threshold { node.right } else { node.left } as usize;
                };
                out[(v - first) * stride] = leaf;
            }
        }
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx")]
        #[allow(clippy::too_many_arguments)]
        unsafe fn with_avx<'r>(
            tree: &Tree,
            table: &[f32],
            k: usize,
            levels: u32,
            rows: &impl Fn(usize) -> (&'r [f32], &'r [f32]),
            vertices: std::ops::Range<usize>,
            out: &mut [u32],
            stride: usize,
        ) {
            // SAFETY: AVX is enabled in this function.
            walk(tree, table, k, levels, rows, vertices, out, stride, |a, b| unsafe {
                crate::descriptor::dot_f32_avx(a, b)
            });
        }
        #[cfg(target_arch = "x86_64")]
        if simd_dots() {
            // SAFETY: the CPU supports AVX (checked by `simd_dots`).
            unsafe { with_avx(self, table, k, levels, &rows, vertices, out, stride) };
            return;
        }
        walk(self, table, k, levels, &rows, vertices, out, stride, dot_f32);
    }

    /// Sparse distribution of leaf `i`.
    #[inline]
    pub(crate) fn leaf_distribution(&self, i: usize) -> (&[u32], &[f32]) {
        let (a, b) = (self.leaf_offsets[i] as usize, self.leaf_offsets[i + 1] as usize);
        (&self.leaf_labels[a..b], &self.leaf_probs[a..b])
    }

    pub(crate) fn n_leaves(&self) -> usize {
        self.leaf_offsets.len().saturating_sub(1)
    }
}

/// Everything the trees of one fit share (read-only).
pub(crate) struct TrainData {
    pub(crate) shapes: Vec<ParametricWks>,
    /// Per shape, the weight table `levels × k`.
    pub(crate) tables: Vec<Vec<f32>>,
    pub(crate) k: usize,
    pub(crate) levels: u32,
    /// Bins of the local histograms (0 when the shapes carry none).
    pub(crate) local_dim: usize,
    /// Per shape, its local histograms (empty when the shapes carry none).
    pub(crate) local: Vec<Arc<LocalDescriptor>>,
    pub(crate) sample_shape: Vec<u16>,
    pub(crate) sample_vertex: Vec<u32>,
    pub(crate) sample_label: Vec<u32>,
    pub(crate) n_labels: usize,
    /// `c ln c` for `c = 0..=n_samples`.
    pub(crate) xlogx: Vec<f64>,
}

/// SplitMix64 step, used to derive independent per-tree seeds.
pub(crate) fn mix_seed(seed: u64, index: u64) -> u64 {
    let mut z = seed ^ index.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(0x632B_E59B_D9B4_E019);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[inline]
fn ord_bits(x: f32) -> u32 {
    let b = x.to_bits();
    if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    }
}

#[inline]
fn from_ord_bits(b: u32) -> f32 {
    if b & 0x8000_0000 != 0 {
        f32::from_bits(b & 0x7FFF_FFFF)
    } else {
        f32::from_bits(!b)
    }
}

/// Reusable per-thread buffers of the split search.
struct Scratch {
    counts_l: Vec<u32>,
    counts_r: Vec<u32>,
    keys: Vec<u64>,
    /// The radix sort's second buffer.
    spare: Vec<u64>,
}

impl Scratch {
    fn new(n_labels: usize) -> Self {
        Self { counts_l: vec![0; n_labels], counts_r: vec![0; n_labels], keys: Vec::new(), spare: Vec::new() }
    }
}

/// Below this many keys a comparison sort is faster than the radix sort.
const RADIX_MIN: usize = 512;

/// Sorts `keys` ascending: a least-significant-digit radix sort on bytes (skipping the bytes
/// that all keys share, e.g. the high bytes of the labels and of the values' exponents) for
/// large nodes, the standard unstable sort for small ones. Equal keys are identical, so the
/// result is the same either way. `spare` is reused scratch space. (Written here rather than
/// taken from a crate such as `radsort`, which allocates its buffer on every call: the split
/// search sorts thousands of times per tree.)
fn sort_keys(keys: &mut Vec<u64>, spare: &mut Vec<u64>) {
    let m = keys.len();
    if m < RADIX_MIN {
        keys.sort_unstable();
        return;
    }
    let mut hist = [[0u32; 256]; 8];
    for &x in keys.iter() {
        for (d, h) in hist.iter_mut().enumerate() {
            h[((x >> (8 * d)) & 0xFF) as usize] += 1;
        }
    }
    spare.clear();
    spare.resize(m, 0);
    for (d, h) in hist.iter().enumerate() {
        if h.iter().any(|&c| c as usize == m) {
            continue; // every key has the same byte here
        }
        let mut offsets = [0u32; 256];
        let mut acc = 0u32;
        for (o, &c) in offsets.iter_mut().zip(h) {
            *o = acc;
            acc += c;
        }
        for &x in keys.iter() {
            let b = ((x >> (8 * d)) & 0xFF) as usize;
            spare[offsets[b] as usize] = x;
            offsets[b] += 1;
        }
        std::mem::swap(keys, spare);
    }
}

/// Best threshold of candidate `c` (values `feats[i * n_cand + c]`): `(score, threshold)` where
/// the score `n_L ln n_L − S_L + n_R ln n_R − S_R` is to be minimised.
#[allow(clippy::too_many_arguments)]
fn sweep(
    feats: &[f32],
    n_cand: usize,
    c: usize,
    labels: &[u32],
    s_node: f64,
    xlogx: &[f64],
    min_leaf: usize,
    sc: &mut Scratch,
) -> Option<(f64, f32)> {
    let m = labels.len();
    sc.keys.clear();
    sc.keys.extend(
        labels.iter().enumerate().map(|(i, &y)| ((ord_bits(feats[i * n_cand + c]) as u64) << 32) | y as u64),
    );
    sort_keys(&mut sc.keys, &mut sc.spare);
    for &y in labels {
        sc.counts_r[y as usize] += 1;
    }
    let (mut s_l, mut s_r) = (0.0f64, s_node);
    let mut best: Option<(f64, usize)> = None;
    for j in 0..m - 1 {
        let y = sc.keys[j] as u32 as usize;
        let cl = sc.counts_l[y] as usize;
        sc.counts_l[y] = cl as u32 + 1;
        s_l += xlogx[cl + 1] - xlogx[cl];
        let cr = sc.counts_r[y] as usize;
        sc.counts_r[y] = cr as u32 - 1;
        s_r += xlogx[cr - 1] - xlogx[cr];
        let n_l = j + 1;
        let n_r = m - n_l;
        if n_l < min_leaf || n_r < min_leaf || (sc.keys[j] >> 32) == (sc.keys[j + 1] >> 32) {
            continue;
        }
        let score = xlogx[n_l] - s_l + xlogx[n_r] - s_r;
        if best.is_none_or(|(b, _)| score < b) {
            best = Some((score, j));
        }
    }
    for &y in labels {
        sc.counts_l[y as usize] = 0;
        sc.counts_r[y as usize] = 0;
    }
    best.map(|(score, j)| {
        let a = from_ord_bits((sc.keys[j] >> 32) as u32);
        let b = from_ord_bits((sc.keys[j + 1] >> 32) as u32);
        let mut t = a + 0.5 * (b - a);
        if !(t >= a && t < b) {
            t = a;
        }
        (score, t)
    })
}

/// Whether [`sample_features`] may use AVX (checked once per node).
fn simd_dots() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The values of sample `s` for every candidate `(e, k̄)` (`p(m; e, k̄)`, or a local bin for a
/// feature index past the grid), into `out` (the same
/// bits with `avx` as without: see [`crate::descriptor::dot_f32`]).
#[inline]
fn sample_features(data: &TrainData, cands: &[(u32, u16)], s: usize, out: &mut [f32], avx: bool) {
    #[inline(always)]
    fn body(
        data: &TrainData,
        cands: &[(u32, u16)],
        s: usize,
        out: &mut [f32],
        dot: impl Fn(&[f32], &[f32]) -> f32,
    ) {
        let k = data.k;
        let sh = data.sample_shape[s] as usize;
        let v = data.sample_vertex[s] as usize;
        let row = data.shapes[sh].row(v);
        let local = data.local.get(sh).map_or(&[][..], |l| l.row(v));
        let table = &data.tables[sh];
        for (f, &(e, kb)) in out.iter_mut().zip(cands) {
            *f = if e < data.levels {
                let kb = kb as usize;
                let w = &table[e as usize * k..e as usize * k + kb];
                dot(w, &row[..kb])
            } else {
                local[(e - data.levels) as usize]
            };
        }
    }
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    unsafe fn with_avx(data: &TrainData, cands: &[(u32, u16)], s: usize, out: &mut [f32]) {
        // SAFETY: AVX is enabled in this function.
        body(data, cands, s, out, |a, b| unsafe { crate::descriptor::dot_f32_avx(a, b) });
    }
    #[cfg(target_arch = "x86_64")]
    if avx {
        // SAFETY: the caller checked that the CPU supports AVX (`simd_dots`).
        unsafe { with_avx(data, cands, s, out) };
        return;
    }
    let _ = avx;
    body(data, cands, s, out, dot_f32);
}

/// Grows one tree on a bagged subset of `data`'s samples.
pub(crate) fn grow_tree(data: &TrainData, p: &RandomForestParams, index: u64) -> Tree {
    let mut rng = ChaCha8Rng::seed_from_u64(mix_seed(p.seed, index));
    let n = data.sample_label.len();
    let m_bag = ((p.bagging_fraction * n as f64).round() as usize).clamp(1, n);
    let mut idx: Vec<u32> = (0..n as u32).collect();
    if m_bag < n {
        for i in 0..m_bag {
            let j = rng.random_range(i..n);
            idx.swap(i, j);
        }
        idx.truncate(m_bag);
        idx.sort_unstable();
    }
    let k = data.k;
    let k_min = p.k_min.min(k);
    let n_cand = p.candidates_per_node;
    let mut sc = Scratch::new(data.n_labels);
    let mut feats: Vec<f32> = Vec::new();
    let mut labels: Vec<u32> = Vec::new();
    let mut best_vals: Vec<f32> = Vec::new();
    let mut part: Vec<u32> = Vec::new();
    let mut cands: Vec<(u32, u16)> = Vec::with_capacity(n_cand);
    let mut tree = Tree {
        nodes: vec![Node { energy: 0, k_bar: 0, threshold: 0.0, left: 0, right: 0 }],
        leaf_offsets: vec![0],
        leaf_labels: Vec::new(),
        leaf_probs: Vec::new(),
        index,
    };
    let mut stack: Vec<(usize, usize, usize, usize)> = vec![(0, 0, idx.len(), 0)];
    while let Some((id, lo, hi, depth)) = stack.pop() {
        let m = hi - lo;
        let samples = &mut idx[lo..hi];
        labels.clear();
        labels.extend(samples.iter().map(|&s| data.sample_label[s as usize]));
        // Node entropy H = ln m − S/m with S = Σ c ln c.
        let mut s_node = 0.0;
        for &y in &labels {
            let c = sc.counts_l[y as usize] as usize;
            s_node += data.xlogx[c + 1] - data.xlogx[c];
            sc.counts_l[y as usize] += 1;
        }
        for &y in &labels {
            sc.counts_l[y as usize] = 0;
        }
        let h = (m as f64).ln() - s_node / m as f64;
        let mut split: Option<(usize, f32)> = None;
        if depth < p.max_depth
            && m >= p.min_samples_split
            && m >= 2 * p.min_samples_leaf
            && h > p.min_entropy + 1e-12
        {
            cands.clear();
            // With local histograms, a share `local_share` of the candidates are local bins
            // (feature index past the grid); without them, the draws of a WKS-only forest.
            for _ in 0..n_cand {
                let local = data.local_dim > 0 && rng.random_bool(p.local_share);
                cands.push(if local {
                    (data.levels + rng.random_range(0..data.local_dim as u32), 1)
                } else {
                    (rng.random_range(0..data.levels), rng.random_range(k_min..=k) as u16)
                });
            }
            feats.clear();
            feats.resize(m * n_cand, 0.0);
            let avx = simd_dots();
            let cands = &cands[..];
            let fill = |(chunk, s): (&mut [f32], &u32)| sample_features(data, cands, *s as usize, chunk, avx);
            let large = m >= p.parallel_node_size;
            let results: Vec<Option<(f64, f32)>> = if large {
                feats.par_chunks_mut(n_cand).zip(samples.par_iter()).for_each(fill);
                let (feats, labels) = (&feats, &labels);
                (0..n_cand)
                    .into_par_iter()
                    .map_init(
                        || Scratch::new(data.n_labels),
                        |scr, c| {
                            sweep(feats, n_cand, c, labels, s_node, &data.xlogx, p.min_samples_leaf, scr)
                        },
                    )
                    .collect()
            } else {
                feats.chunks_mut(n_cand).zip(samples.iter()).for_each(fill);
                (0..n_cand)
                    .map(|c| {
                        sweep(&feats, n_cand, c, &labels, s_node, &data.xlogx, p.min_samples_leaf, &mut sc)
                    })
                    .collect()
            };
            let mut best: Option<(f64, usize, f32)> = None;
            for (c, r) in results.into_iter().enumerate() {
                if let Some((score, t)) = r {
                    if best.is_none_or(|(b, _, _)| score < b) {
                        best = Some((score, c, t));
                    }
                }
            }
            if let Some((score, c, t)) = best {
                let gain = h - score / m as f64;
                if gain > 1e-12 {
                    split = Some((c, t));
                }
            }
        }
        match split {
            Some((c, t)) => {
                best_vals.clear();
                best_vals.extend((0..m).map(|i| feats[i * n_cand + c]));
                part.clear();
                part.extend(samples.iter().zip(&best_vals).filter(|(_, &v)| v <= t).map(|(&s, _)| s));
                let n_left = part.len();
                part.extend(samples.iter().zip(&best_vals).filter(|(_, &v)| v > t).map(|(&s, _)| s));
                samples.copy_from_slice(&part);
                let left = tree.nodes.len();
                let right = left + 1;
                let blank = Node { energy: 0, k_bar: 0, threshold: 0.0, left: 0, right: 0 };
                tree.nodes.push(blank);
                tree.nodes.push(blank);
                let (e, kb) = cands[c];
                tree.nodes[id] =
                    Node { energy: e, k_bar: kb, threshold: t, left: left as u32, right: right as u32 };
                stack.push((right, lo + n_left, hi, depth + 1));
                stack.push((left, lo, lo + n_left, depth + 1));
            }
            None => {
                labels.sort_unstable();
                let leaf = tree.n_leaves();
                let inv = 1.0 / m as f64;
                let mut i = 0;
                while i < labels.len() {
                    let mut j = i + 1;
                    while j < labels.len() && labels[j] == labels[i] {
                        j += 1;
                    }
                    tree.leaf_labels.push(labels[i]);
                    tree.leaf_probs.push(((j - i) as f64 * inv) as f32);
                    i = j;
                }
                tree.leaf_offsets.push(tree.leaf_labels.len() as u32);
                tree.nodes[id] = Node { energy: 0, k_bar: 0, threshold: 0.0, left: leaf as u32, right: 0 };
            }
        }
    }
    tree
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ord_bits_preserve_order_and_round_trip() {
        let xs = [-3.5f32, -0.0, 0.0, 1e-30, 0.25, 7.0, 1e30];
        for w in xs.windows(2) {
            assert!(ord_bits(w[0]) <= ord_bits(w[1]));
        }
        for &x in &xs {
            assert_eq!(from_ord_bits(ord_bits(x)).to_bits(), x.to_bits());
        }
    }

    #[test]
    fn radix_sort_equals_the_standard_sort() {
        // Keys as the split search builds them: order-preserving value bits over a label, with
        // repeated values, negative and positive values and constant bytes.
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for m in [0, 1, 7, RADIX_MIN - 1, RADIX_MIN, 5000] {
            let keys: Vec<u64> = (0..m)
                .map(|_| {
                    let v: f32 = if rng.random_bool(0.2) { 0.5 } else { rng.random_range(-3.0..3.0) };
                    ((ord_bits(v) as u64) << 32) | rng.random_range(0..70_000u64)
                })
                .collect();
            let mut want = keys.clone();
            want.sort_unstable();
            let (mut got, mut spare) = (keys, Vec::new());
            sort_keys(&mut got, &mut spare);
            assert_eq!(got, want, "{m} keys");
        }
    }

    #[test]
    fn sweep_finds_the_pure_split() {
        // Values 0..6, labels 0,0,0,1,1,1: the best threshold separates 2 and 3.
        let feats: Vec<f32> = (0..6).map(|i| i as f32).collect();
        let labels = [0u32, 0, 0, 1, 1, 1];
        let xlogx: Vec<f64> =
            (0..=6).map(|c| if c == 0 { 0.0 } else { c as f64 * (c as f64).ln() }).collect();
        let s_node = 2.0 * xlogx[3];
        let mut sc = Scratch::new(2);
        let (score, t) = sweep(&feats, 1, 0, &labels, s_node, &xlogx, 1, &mut sc).unwrap();
        assert!(score.abs() < 1e-12, "pure children have zero entropy");
        assert_eq!(t, 2.5);
        assert!(sc.counts_l.iter().chain(&sc.counts_r).all(|&c| c == 0));
    }
}
