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

use super::params::RandomForestParams;
use crate::descriptor::{dot_f32, ParametricWks};

/// A node: internal when `k_bar > 0` (go right when `p(m; e, k̄) > threshold`), a leaf otherwise
/// (`left` is then the leaf index).
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
    /// Leaf reached by a vertex whose `φ²` row is `row`, with the shape's weight table `table`
    /// (`levels × k`).
    #[inline]
    pub(crate) fn leaf(&self, table: &[f32], k: usize, row: &[f32]) -> usize {
        let mut n = 0usize;
        loop {
            let node = &self.nodes[n];
            if node.k_bar == 0 {
                return node.left as usize;
            }
            let kb = node.k_bar as usize;
            let w = &table[node.energy as usize * k..node.energy as usize * k + kb];
            let p = dot_f32(w, &row[..kb]);
            n = if p > node.threshold { node.right } else { node.left } as usize;
        }
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
}

impl Scratch {
    fn new(n_labels: usize) -> Self {
        Self { counts_l: vec![0; n_labels], counts_r: vec![0; n_labels], keys: Vec::new() }
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
    sc.keys.sort_unstable();
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
            for _ in 0..n_cand {
                let e = rng.random_range(0..data.levels);
                let kb = rng.random_range(k_min..=k) as u16;
                cands.push((e, kb));
            }
            feats.clear();
            feats.resize(m * n_cand, 0.0);
            let fill = |(chunk, s): (&mut [f32], &u32)| {
                let s = *s as usize;
                let sh = data.sample_shape[s] as usize;
                let row = data.shapes[sh].row(data.sample_vertex[s] as usize);
                let table = &data.tables[sh];
                for (f, &(e, kb)) in chunk.iter_mut().zip(&cands) {
                    let kb = kb as usize;
                    let w = &table[e as usize * k..e as usize * k + kb];
                    *f = dot_f32(w, &row[..kb]);
                }
            };
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
