//! The fitted [`RandomForest`]: training, incremental growth and prediction.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::params::{RandomForestParams, RandomForestValidParams};
use super::prediction::Prediction;
use super::reference::ModelReference;
use super::training::TrainingSet;
use super::tree::{grow_tree, TrainData, Tree};
use super::ForestError;
use crate::descriptor::{
    first_nonzero_eigenvalue, EnergyGrid, LocalDescriptor, LocalParams, ParametricWks, WksParams,
};
use crate::mesh::Mesh;
use crate::spectral::Spectrum;

/// The per-vertex descriptor a forest splits on ([`RandomForest::descriptor`]): the squared
/// eigenvector rows of the parametric WKS, the band-pass weights of the forest's energy grid
/// and, for a forest that splits on them too, the local histograms.
pub struct ForestDescriptor {
    wks: ParametricWks,
    table: Vec<f32>,
    k: usize,
    grid: EnergyGrid,
    local: Option<LocalDescriptor>,
}

impl ForestDescriptor {
    /// Vertices described.
    pub fn n_vertices(&self) -> usize {
        self.wks.n_vertices()
    }

    /// Bytes held (the `n × K` rows, the weight table and any local histograms).
    pub fn heap_bytes(&self) -> usize {
        4 * (self.wks.n_vertices() * self.k + self.table.len())
            + self.local.as_ref().map_or(0, |l| l.heap_bytes())
    }
}

/// A random forest mapping vertices to labels from the parametric WKS of their shape (and,
/// when trained on shapes that carry them, from local histograms: see [`Self::local`]).
///
/// Immutable once fitted: an incremental update ([`RandomForestValidParams::fit_with`]) returns a
/// new forest, so a server can keep answering with the old one (behind an `Arc`) and swap.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RandomForest {
    pub(crate) params: RandomForestParams,
    pub(crate) n_labels: usize,
    pub(crate) k: usize,
    pub(crate) grid: EnergyGrid,
    pub(crate) trees: Vec<Tree>,
    pub(crate) next_tree_index: u64,
    /// Where the labels lie on the reference shape (absent in models of a shared-indexing
    /// class, where label = reference vertex, and in files of format version 1).
    #[serde(default)]
    pub(crate) reference: Option<ModelReference>,
    /// The settings of the local histograms the trees also split on (absent for a WKS-only
    /// forest, and in files of format versions 1–3).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(crate) local: Option<LocalParams>,
}

impl RandomForest {
    /// Default hyper-parameters, to be adjusted with the chained setters.
    pub fn params() -> RandomForestParams {
        RandomForestParams::default()
    }

    /// The reference shape the labels are tabulated on, if the model carries one (see
    /// [`ModelReference`]).
    pub fn reference(&self) -> Option<&ModelReference> {
        self.reference.as_ref()
    }

    /// The same forest carrying `reference` (its table must have one entry per label).
    pub fn with_reference(mut self, reference: ModelReference) -> Result<Self, ForestError> {
        reference.validate(self.n_labels).map_err(ForestError::IncompatibleModel)?;
        self.reference = Some(reference);
        Ok(self)
    }

    /// The hyper-parameters this forest was (last) grown with.
    pub fn hyper_params(&self) -> &RandomForestParams {
        &self.params
    }

    /// The smallest leaf the trees were grown with (an automatic one resolved from the training
    /// set: [`RandomForestValidParams::resolved_for`]).
    pub fn min_samples_leaf(&self) -> usize {
        self.params.min_samples_leaf
    }

    /// Size of the label set.
    pub fn n_labels(&self) -> usize {
        self.n_labels
    }

    /// Number of eigenpairs `K` the splits use; a shape to predict needs at least this many.
    pub fn k(&self) -> usize {
        self.k
    }

    /// The log-energy grid (range and `σ`, from the training spectra) the splits draw `e` from.
    pub fn energy_grid(&self) -> EnergyGrid {
        self.grid
    }

    /// The settings of the local histograms ([`LocalDescriptor`]) the trees split on besides
    /// the parametric WKS, if the training shapes carried them. Such a forest predicts from a
    /// shape's mesh and spectrum ([`Self::predict_mesh`]), not from the spectrum alone.
    pub fn local(&self) -> Option<&LocalParams> {
        self.local.as_ref()
    }

    /// Number of trees.
    pub fn n_trees(&self) -> usize {
        self.trees.len()
    }

    /// Total number of nodes over all trees.
    pub fn n_nodes(&self) -> usize {
        self.trees.iter().map(|t| t.nodes.len()).sum()
    }

    /// Mean number of labels stored per leaf.
    pub fn mean_leaf_support(&self) -> f64 {
        let (l, n) =
            self.trees.iter().fold((0usize, 0usize), |(l, n), t| (l + t.leaf_labels.len(), n + t.n_leaves()));
        l as f64 / n.max(1) as f64
    }

    /// The forest posterior of every vertex of `spectrum` (a shape scaled to unit area, with at
    /// least [`Self::k`] eigenpairs): the average of the leaf distributions reached in each tree,
    /// as a sparse left-stochastic matrix (labels × vertices). Parallel over vertices.
    /// A forest that splits on local histograms ([`Self::local`]) needs the mesh too: see
    /// [`Self::predict_mesh`]; here it fails with [`ForestError::IncompatibleModel`].
    pub fn predict(&self, spectrum: &Spectrum) -> Result<Prediction, ForestError> {
        self.predict_descriptor(&self.descriptor(spectrum)?)
    }

    /// [`Self::predict`] for a shape given by its mesh and its spectrum (same vertices): works
    /// for every forest, computing the local histograms when the forest splits on them.
    pub fn predict_mesh(&self, mesh: &Mesh, spectrum: &Spectrum) -> Result<Prediction, ForestError> {
        crate::pool::on_pool(|| self.predict_descriptor(&self.descriptor_mesh(Some(mesh), spectrum)?))
    }

    /// The per-vertex descriptor the trees split on, for this forest's energy grid and `K`:
    /// the first half of [`Self::predict`], for pipelines that run it as its own stage.
    pub fn descriptor(&self, spectrum: &Spectrum) -> Result<ForestDescriptor, ForestError> {
        self.descriptor_mesh(None, spectrum)
    }

    /// [`Self::descriptor`] with the shape's mesh, from which the local histograms are computed
    /// when the forest splits on them (then the mesh is required; otherwise it is not read).
    pub fn descriptor_mesh(
        &self,
        mesh: Option<&Mesh>,
        spectrum: &Spectrum,
    ) -> Result<ForestDescriptor, ForestError> {
        if spectrum.k() < self.k {
            return Err(ForestError::SpectrumTooShort { needed: self.k, found: spectrum.k() });
        }
        let local =
            match (&self.local, mesh) {
                (None, _) => None,
                (Some(p), Some(m)) => Some(LocalDescriptor::new(m, spectrum, p)?),
                (Some(_), None) => return Err(ForestError::IncompatibleModel(
                    "this model also splits on local histograms of the surface: it needs the shape's mesh, \
                     not only its spectrum"
                        .into(),
                )),
            };
        let wks = ParametricWks::new(spectrum, self.k)?;
        let table = wks.weight_table(&self.grid);
        Ok(ForestDescriptor { wks, table, k: self.k, grid: self.grid, local })
    }

    /// The forest posterior from a descriptor made by [`Self::descriptor`] (of this forest or of
    /// one with the same `K` and energy grid).
    pub fn predict_descriptor(&self, descriptor: &ForestDescriptor) -> Result<Prediction, ForestError> {
        if descriptor.k != self.k || descriptor.grid != self.grid {
            return Err(ForestError::IncompatibleModel(format!(
                "descriptor made for K = {} and another energy grid; the model has K = {}",
                descriptor.k, self.k
            )));
        }
        if descriptor.local.as_ref().map(|l| l.params()) != self.local.as_ref() {
            return Err(ForestError::IncompatibleModel(
                "descriptor made with other local-histogram settings than the model's".into(),
            ));
        }
        let (pw, table) = (&descriptor.wks, &descriptor.table);
        let local = descriptor.local.as_ref();
        let local_row = |v: usize| local.map_or(&[][..], |l| l.row(v));
        let levels = self.grid.levels;
        let n = pw.n_vertices();
        let inv_trees = 1.0 / self.trees.len() as f64;
        // Vertices are processed in chunks, tree by tree within a chunk, so the upper levels of
        // each tree stay in cache while the chunk's vertices descend it.
        const CHUNK: usize = 256;
        let n_trees = self.trees.len();
        let chunks: Vec<(Vec<u32>, Vec<u32>, Vec<f32>)> = (0..n.div_ceil(CHUNK))
            .into_par_iter()
            .map(|ci| {
                let (a, b) = (ci * CHUNK, ((ci + 1) * CHUNK).min(n));
                let mut leaves = vec![0u32; (b - a) * n_trees];
                for (ti, t) in self.trees.iter().enumerate() {
                    let rows = |v: usize| (pw.row(v), local_row(v));
                    t.leaves_into(table, self.k, levels, rows, a..b, &mut leaves[ti..], n_trees);
                }
                let mut lens = Vec::with_capacity(b - a);
                let mut labels = Vec::new();
                let mut probs = Vec::new();
                let mut buf: Vec<(u32, f32)> = Vec::new();
                for v in a..b {
                    buf.clear();
                    for (ti, t) in self.trees.iter().enumerate() {
                        let (ls, ps) = t.leaf_distribution(leaves[(v - a) * n_trees + ti] as usize);
                        buf.extend(ls.iter().copied().zip(ps.iter().copied()));
                    }
                    buf.sort_unstable_by_key(|x| x.0);
                    let start = labels.len();
                    let mut total = 0.0f64;
                    let mut i = 0;
                    while i < buf.len() {
                        let mut s = 0.0f64;
                        let mut j = i;
                        while j < buf.len() && buf[j].0 == buf[i].0 {
                            s += buf[j].1 as f64;
                            j += 1;
                        }
                        labels.push(buf[i].0);
                        probs.push((s * inv_trees) as f32);
                        total += s * inv_trees;
                        i = j;
                    }
                    if total > 0.0 {
                        for q in &mut probs[start..] {
                            *q = (*q as f64 / total) as f32;
                        }
                    }
                    lens.push((labels.len() - start) as u32);
                }
                (lens, labels, probs)
            })
            .collect();
        Ok(Prediction::from_chunks(self.n_labels, chunks))
    }

    /// Checks the internal consistency of a forest (used after loading a model file): child
    /// indices after their parent and in range, leaf indices and labels in range, `k̄ ≤ K`,
    /// energies on the grid, local bins (feature indices past the grid) only in a forest with
    /// local histograms and within their bins.
    pub(crate) fn validate(&self) -> Result<(), String> {
        if self.trees.is_empty() {
            return Err("the forest has no trees".into());
        }
        if self.k < 2 || self.k > u16::MAX as usize {
            return Err(format!("K = {} is out of range", self.k));
        }
        if self.grid.levels < 2
            || !(self.grid.range.e_min.is_finite()
                && self.grid.range.e_max.is_finite()
                && self.grid.range.sigma.is_finite()
                && self.grid.range.sigma > 0.0)
        {
            return Err("the energy grid is invalid".into());
        }
        if let Some(r) = &self.reference {
            r.validate(self.n_labels)?;
        }
        if let Some(l) = &self.local {
            l.check().map_err(|e| e.to_string())?;
        }
        let features = self.grid.levels as usize + self.local.map_or(0, |l| l.dim());
        for (ti, t) in self.trees.iter().enumerate() {
            let nl = t.n_leaves();
            if t.nodes.is_empty() || t.leaf_offsets.first() != Some(&0) {
                return Err(format!("tree {ti} is empty"));
            }
            if t.leaf_offsets.windows(2).any(|w| w[0] > w[1])
                || t.leaf_offsets.last().map(|&x| x as usize) != Some(t.leaf_labels.len())
                || t.leaf_labels.len() != t.leaf_probs.len()
            {
                return Err(format!("tree {ti} has inconsistent leaf arrays"));
            }
            if t.leaf_labels.iter().any(|&l| l as usize >= self.n_labels)
                || t.leaf_probs.iter().any(|p| !p.is_finite() || *p < 0.0)
            {
                return Err(format!("tree {ti} has a leaf label or probability out of range"));
            }
            for (i, nd) in t.nodes.iter().enumerate() {
                if nd.k_bar == 0 {
                    if nd.left as usize >= nl {
                        return Err(format!("tree {ti} node {i} points to a missing leaf"));
                    }
                } else if nd.k_bar as usize > self.k
                    || nd.energy as usize >= features
                    || (nd.energy >= self.grid.levels && nd.k_bar != 1)
                    || nd.left as usize <= i
                    || nd.right as usize <= i
                    || nd.left as usize >= t.nodes.len()
                    || nd.right as usize >= t.nodes.len()
                    || nd.threshold.is_nan()
                {
                    return Err(format!("tree {ti} node {i} is malformed"));
                }
            }
        }
        Ok(())
    }
}

impl RandomForestParams {
    /// Checks the parameters, then fits a new forest (see [`RandomForestValidParams::fit`]).
    pub fn fit(self, set: &TrainingSet) -> Result<RandomForest, ForestError> {
        self.check()?.fit(set)
    }
}

impl RandomForestValidParams {
    /// Grows `n_trees` trees on `set`, in parallel across trees (and across split candidates in
    /// nodes of at least `parallel_node_size` samples). The energy range is taken from the
    /// training spectra: `e_min` the smallest `log λ_1` (first nonzero), `e_max` the largest
    /// `log λ_K`, `σ = wks_sigma_factor · (e_max − e_min) / wks_n_energies`; it is stored in the
    /// model. Deterministic given the seed.
    pub fn fit(&self, set: &TrainingSet) -> Result<RandomForest, ForestError> {
        self.fit_with(None, set)
    }

    /// Incremental growth. With `previous = None`, a fresh fit. With `Some(prev)`, the policy is:
    /// grow `min(trees_per_update, n_trees)` new trees on `set` (typically the enlarged training set) with
    /// `prev`'s label set, `K` and energy grid (so old and new trees agree on the descriptor),
    /// append them, and retire the **oldest** trees beyond `n_trees`. The new trees get seeds
    /// that continue `prev`'s sequence. `prev` is not modified and stays usable meanwhile.
    ///
    /// Fails when `set`'s label count differs from `prev`'s or its shapes have fewer than
    /// `prev.k()` eigenpairs.
    pub fn fit_with(
        &self,
        previous: Option<&RandomForest>,
        set: &TrainingSet,
    ) -> Result<RandomForest, ForestError> {
        self.fit_with_progress(previous, set, &|_| {})
    }

    /// [`fit_with`](Self::fit_with), calling `on_tree(index)` as each new tree is finished
    /// (from worker threads, in completion order) — for progress bars.
    pub fn fit_with_progress(
        &self,
        previous: Option<&RandomForest>,
        set: &TrainingSet,
        on_tree: &(dyn Fn(usize) + Sync),
    ) -> Result<RandomForest, ForestError> {
        let resolved = self.resolved_for(set);
        let plan = resolved.plan(previous, set)?;
        Ok(resolved.grow(plan, previous, on_tree))
    }

    /// A fresh fit ([`fit_with_progress`](Self::fit_with_progress) with no previous forest) that
    /// takes the training set by value and drops it, spectra included, once the descriptor
    /// tables the trees split on are built: the `f64` eigenvectors (`n × K × 8` bytes per
    /// shape, 252 MB for six shapes of 52K vertices) are then freed during tree growth, unless
    /// the caller still holds them (they are shared `Arc`s). Same trees as
    /// [`fit`](Self::fit) on the same set.
    pub fn fit_owned(
        &self,
        set: TrainingSet,
        on_tree: &(dyn Fn(usize) + Sync),
    ) -> Result<RandomForest, ForestError> {
        let resolved = self.resolved_for(&set);
        let plan = resolved.plan(None, &set)?;
        drop(set);
        Ok(resolved.grow(plan, None, on_tree))
    }

    /// Everything a fit needs from the training set (its descriptor tables and samples).
    fn plan(&self, previous: Option<&RandomForest>, set: &TrainingSet) -> Result<Plan, ForestError> {
        let p = &self.0;
        let (k, grid, n_new, first_index, trees) = match previous {
            None => {
                let k = set.k();
                let grid = energy_grid(set, k, p)?;
                (k, grid, p.n_trees, 0u64, Vec::new())
            }
            Some(prev) if prev.local != set.local_params() => {
                return Err(ForestError::IncompatibleModel(match (&prev.local, set.local_params()) {
                    (Some(_), None) => {
                        "the model splits on local histograms but the new shapes carry none".into()
                    }
                    (None, Some(_)) => {
                        "the new shapes carry local histograms but the model does not split on them".into()
                    }
                    _ => "the new shapes' local histograms have other settings than the model's".into(),
                }));
            }
            Some(prev) => {
                if prev.n_labels != set.n_labels() {
                    return Err(ForestError::IncompatibleModel(format!(
                        "the model has {} labels but the training set {}",
                        prev.n_labels,
                        set.n_labels()
                    )));
                }
                if set.k() < prev.k {
                    return Err(ForestError::SpectrumTooShort { needed: prev.k, found: set.k() });
                }
                (
                    prev.k,
                    prev.grid,
                    p.trees_per_update.min(p.n_trees),
                    prev.next_tree_index,
                    prev.trees.clone(),
                )
            }
        };
        if p.k_min > k {
            return Err(ForestError::InvalidParameter {
                name: "k_min",
                reason: format!("must be at most the number of eigenpairs K = {k}, got {}", p.k_min),
            });
        }
        let local_dim = set.local_params().map_or(0, |l| l.dim());
        if u64::from(grid.levels) + local_dim as u64 > u64::from(u32::MAX) {
            return Err(ForestError::InvalidParameter {
                name: "energy_levels",
                reason: format!(
                    "{} levels and {local_dim} local bins do not fit in 32-bit feature indices",
                    grid.levels
                ),
            });
        }
        let data = build_train_data(set, k, grid)?;
        Ok(Plan {
            k,
            grid,
            n_new,
            first_index,
            trees,
            data,
            n_labels: set.n_labels(),
            local: set.local_params(),
        })
    }

    /// Grows the planned trees and assembles the forest.
    fn grow(
        &self,
        plan: Plan,
        previous: Option<&RandomForest>,
        on_tree: &(dyn Fn(usize) + Sync),
    ) -> RandomForest {
        let p = &self.0;
        let Plan { k, grid, n_new, first_index, mut trees, data, n_labels, local } = plan;
        let span = tracing::info_span!("forest_fit", trees = n_new, samples = data.sample_label.len());
        let _g = span.enter();
        let new_trees: Vec<Tree> = (0..n_new as u64)
            .into_par_iter()
            .map(|t| {
                let tree = grow_tree(&data, p, first_index + t);
                on_tree(t as usize);
                tree
            })
            .collect();
        drop(data);
        trees.extend(new_trees);
        if trees.len() > p.n_trees {
            let drop = trees.len() - p.n_trees;
            trees.drain(..drop);
        }
        // Without local histograms their share means nothing: the default is stored, so the
        // file is the one older builds read.
        let params = match local {
            Some(_) => p.clone(),
            None => RandomForestParams { local_share: super::params::default_local_share(), ..p.clone() },
        };
        RandomForest {
            params,
            n_labels,
            k,
            grid,
            trees,
            next_tree_index: first_index + n_new as u64,
            reference: previous.and_then(|p| p.reference.clone()),
            local,
        }
    }
}

/// A fit's inputs, taken from the training set ([`RandomForestValidParams::plan`]).
struct Plan {
    k: usize,
    grid: EnergyGrid,
    n_new: usize,
    first_index: u64,
    trees: Vec<Tree>,
    data: TrainData,
    n_labels: usize,
    local: Option<LocalParams>,
}

fn energy_grid(set: &TrainingSet, k: usize, p: &RandomForestParams) -> Result<EnergyGrid, ForestError> {
    let (mut e_min, mut e_max) = (f64::INFINITY, f64::NEG_INFINITY);
    for s in set.shapes() {
        let ev = &s.spectrum.eigenvalues[..k];
        if let Some(f) = first_nonzero_eigenvalue(ev) {
            e_min = e_min.min(ev[f].ln());
            e_max = e_max.max(ev[k - 1].ln());
        }
    }
    let wks = WksParams { n_energies: p.wks_n_energies, sigma_factor: p.wks_sigma_factor };
    let range = wks.range_from(e_min, e_max)?;
    Ok(EnergyGrid { range, levels: p.energy_levels })
}

fn build_train_data(set: &TrainingSet, k: usize, grid: EnergyGrid) -> Result<TrainData, ForestError> {
    let mut shapes = Vec::with_capacity(set.shapes().len());
    let mut tables = Vec::with_capacity(set.shapes().len());
    let mut local = Vec::new();
    let (mut sample_shape, mut sample_vertex, mut sample_label) = (Vec::new(), Vec::new(), Vec::new());
    for (si, s) in set.shapes().iter().enumerate() {
        let pw = ParametricWks::new(&s.spectrum, k)?;
        tables.push(pw.weight_table(&grid));
        shapes.push(pw);
        local.extend(s.local.clone());
        for (v, l) in s.labels.iter().enumerate() {
            if let Some(l) = l {
                sample_shape.push(si as u16);
                sample_vertex.push(v as u32);
                sample_label.push(*l);
            }
        }
    }
    if sample_label.len() > u32::MAX as usize {
        return Err(ForestError::InvalidParameter {
            name: "training set",
            reason: format!("at most 2^32 - 1 samples, got {}", sample_label.len()),
        });
    }
    let xlogx =
        (0..=sample_label.len()).map(|c| if c == 0 { 0.0 } else { c as f64 * (c as f64).ln() }).collect();
    Ok(TrainData {
        shapes,
        tables,
        k,
        levels: grid.levels,
        local_dim: set.local_params().map_or(0, |l| l.dim()),
        local,
        sample_shape,
        sample_vertex,
        sample_label,
        n_labels: set.n_labels(),
        xlogx,
    })
}
