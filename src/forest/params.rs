//! Hyper-parameters of the random forest, linfa style: [`RandomForestParams`] is built with
//! chained setters, [`RandomForestParams::check`] validates it into [`RandomForestValidParams`],
//! which fits models.

use serde::{Deserialize, Serialize};

use super::{ForestError, TrainingSet};

/// Unchecked hyper-parameters of a [`RandomForest`](super::RandomForest); see each setter for
/// the meaning and the default. Obtain one with [`RandomForest::params`](super::RandomForest::params).
///
/// ```
/// use shapeforest::forest::RandomForest;
/// let p = RandomForest::params().n_trees(5).max_depth(12).seed(7).check().unwrap();
/// assert_eq!(p.n_trees(), 5);
/// let e = RandomForest::params().max_depth(0).check().unwrap_err();
/// assert!(e.to_string().contains("at least 1"));
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RandomForestParams {
    pub(crate) n_trees: usize,
    pub(crate) max_depth: usize,
    pub(crate) min_samples_split: usize,
    pub(crate) min_samples_leaf: usize,
    pub(crate) candidates_per_node: usize,
    pub(crate) min_entropy: f64,
    pub(crate) bagging_fraction: f64,
    pub(crate) k_min: usize,
    pub(crate) energy_levels: u32,
    pub(crate) wks_n_energies: usize,
    pub(crate) wks_sigma_factor: f64,
    pub(crate) trees_per_update: usize,
    pub(crate) parallel_node_size: usize,
    pub(crate) seed: u64,
    /// Absent in models written before it existed (their default), and not written at the
    /// default (a forest without local histograms stores the default): a WKS-only forest's file
    /// is then the one older builds read.
    #[serde(default = "default_local_share", skip_serializing_if = "is_default_local_share")]
    pub(crate) local_share: f64,
}

pub(crate) fn default_local_share() -> f64 {
    1.0
}

fn is_default_local_share(share: &f64) -> bool {
    share.to_bits() == default_local_share().to_bits()
}

/// The share of a label's training samples a leaf holds at least when the smallest leaf is
/// automatic (see [`RandomForestValidParams::resolved_for`]). Measured on single views of SCAPE
/// (six shapes with 15 single-view copies each: 38 samples per label; local histograms, both
/// games), the largest pieces within 0.05: pure leaves 68.7 %, leaves of 4 76.7 %, of 5
/// **78.6 %** (README "Leaves sized by the training set"); with one game, leaves of 3, 5 and 12:
/// 58.5, 60.6 and 57.4 % of all points. On complete FAUST_r scans (six shapes, six samples per
/// label) leaves of 2 lost 1.7 points and leaves of 5 18: an eighth keeps their leaves pure.
pub const AUTO_LEAF_SHARE: f64 = 0.125;

/// Trees of an automatic forest (`n_trees = 0`, see [`RandomForestValidParams::resolved_for`])
/// whose leaves are pure: the paper's forests, and complete scans matched at 93–99 %.
pub const AUTO_TREES_PURE: usize = 15;

/// Trees of an automatic forest whose leaves hold several training samples (a set with
/// perturbed copies, whose automatic leaf is 3–5 samples): each tree's posterior is then a
/// mixture of a few neighbouring labels, and averaging more trees sharpens it. Measured on
/// single views of SCAPE (six shapes with 15 single-view copies each, local histograms; README
/// "More trees for views"), the largest pieces within 0.05 over 68 views: 15 trees 78.7 %, 30
/// 81.4 %, 60 **84.9 %** (the raw forest 23.1 → 36.6 %).
pub const AUTO_TREES_MIXED: usize = 60;

/// Hyper-parameters that passed [`RandomForestParams::check`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RandomForestValidParams(pub(crate) RandomForestParams);

impl Default for RandomForestParams {
    fn default() -> Self {
        Self {
            n_trees: 0,
            max_depth: 25,
            min_samples_split: 2,
            min_samples_leaf: 0,
            candidates_per_node: 20,
            min_entropy: 0.0,
            bagging_fraction: 0.7,
            k_min: 5,
            energy_levels: 256,
            wks_n_energies: 100,
            wks_sigma_factor: 7.0,
            trees_per_update: 5,
            parallel_node_size: 20_000,
            seed: 0,
            local_share: default_local_share(),
        }
    }
}

macro_rules! setter {
    ($(#[$m:meta])* $name:ident: $t:ty) => {
        $(#[$m])*
        pub fn $name(mut self, value: $t) -> Self {
            self.$name = value;
            self
        }
    };
}

impl RandomForestParams {
    setter!(
        /// Number of trees kept in the forest. Default 0: chosen when fitting from the smallest
        /// leaf, [`AUTO_TREES_PURE`] (15) where the leaves are pure and [`AUTO_TREES_MIXED`]
        /// (60) where they hold several samples
        /// ([`RandomForestValidParams::resolved_for`]). The fitted forest has the number used.
        n_trees: usize);
    setter!(
        /// Maximum depth of a tree; the root has depth 0 (default 25, at least 1).
        max_depth: usize);
    setter!(
        /// A node with fewer samples becomes a leaf (default 2, at least 2).
        min_samples_split: usize);
    setter!(
        /// Each child of a split keeps at least this many samples. Default 0: chosen from the
        /// training set when fitting, [`AUTO_LEAF_SHARE`] (an eighth) of its mean number of
        /// samples per label, at least 1 ([`RandomForestValidParams::resolved_for`]): pure
        /// leaves for six complete shapes, leaves of 3–5 with 15 single-view copies of each.
        /// The fitted forest stores the number used.
        min_samples_leaf: usize);
    setter!(
        /// Random split candidates `(e, k̄)` tried per node (default 20, at least 1). For each,
        /// every threshold between consecutive sorted values is scored.
        candidates_per_node: usize);
    setter!(
        /// A node whose label entropy (nats) is at most this becomes a leaf (default 0: only
        /// pure nodes stop on entropy; must be finite and ≥ 0).
        min_entropy: f64);
    setter!(
        /// Fraction of the training samples each tree sees, drawn without replacement
        /// (default 0.7; must be in (0, 1]).
        bagging_fraction: f64);
    setter!(
        /// Smallest truncation `k̄` drawn (default 5; at least 2 and at most the number of
        /// eigenpairs `K` of the training set, checked at fit time).
        k_min: usize);
    setter!(
        /// Number of points of the log-energy grid `e` is drawn from (default 256, at least 2).
        energy_levels: u32);
    setter!(
        /// `N` in the WKS band-pass width `σ = wks_sigma_factor · (e_max − e_min) / N`
        /// (default 100, at least 1).
        wks_n_energies: usize);
    setter!(
        /// Factor in `σ` (default 7, Aubry's; finite and > 0).
        wks_sigma_factor: f64);
    setter!(
        /// Trees grown by an incremental update [`RandomForestValidParams::fit_with`]
        /// (default 5, at least 1; capped at `n_trees`).
        trees_per_update: usize);
    setter!(
        /// Nodes with at least this many samples evaluate their candidates in parallel
        /// (default 20,000; at least 1). Does not change results.
        parallel_node_size: usize);
    setter!(
        /// Seed of all random choices: the same seed and data give the same forest.
        seed: u64);
    setter!(
        /// When the training shapes carry local histograms, the share of split candidates drawn
        /// from their bins, the rest from the parametric WKS (default 1: local bins only; in
        /// `[0, 1]`). Without histograms every candidate is a WKS one.
        local_share: f64);

    /// Validates every hyper-parameter; the error names the parameter and states the rule.
    pub fn check(self) -> Result<RandomForestValidParams, ForestError> {
        let bad = |name: &'static str, reason: String| Err(ForestError::InvalidParameter { name, reason });
        if self.max_depth < 1 {
            return bad("max_depth", format!("must be at least 1, got {}", self.max_depth));
        }
        if self.min_samples_split < 2 {
            return bad("min_samples_split", format!("must be at least 2, got {}", self.min_samples_split));
        }
        if self.candidates_per_node < 1 {
            return bad(
                "candidates_per_node",
                format!("must be at least 1, got {}", self.candidates_per_node),
            );
        }
        if !(self.min_entropy.is_finite() && self.min_entropy >= 0.0) {
            return bad("min_entropy", format!("must be finite and at least 0, got {}", self.min_entropy));
        }
        if !(self.bagging_fraction > 0.0 && self.bagging_fraction <= 1.0) {
            return bad(
                "bagging_fraction",
                format!("must be greater than 0 and at most 1, got {}", self.bagging_fraction),
            );
        }
        if self.k_min < 2 {
            return bad("k_min", format!("must be at least 2, got {}", self.k_min));
        }
        if self.energy_levels < 2 {
            return bad("energy_levels", format!("must be at least 2, got {}", self.energy_levels));
        }
        if self.wks_n_energies < 1 {
            return bad("wks_n_energies", format!("must be at least 1, got {}", self.wks_n_energies));
        }
        if !(self.wks_sigma_factor.is_finite() && self.wks_sigma_factor > 0.0) {
            return bad(
                "wks_sigma_factor",
                format!("must be finite and greater than 0, got {}", self.wks_sigma_factor),
            );
        }
        if self.trees_per_update < 1 {
            return bad("trees_per_update", format!("must be at least 1, got {}", self.trees_per_update));
        }
        if !(0.0..=1.0).contains(&self.local_share) {
            return bad("local_share", format!("must be between 0 and 1, got {}", self.local_share));
        }
        if self.parallel_node_size < 1 {
            return bad("parallel_node_size", format!("must be at least 1, got {}", self.parallel_node_size));
        }
        Ok(RandomForestValidParams(self))
    }
}

impl RandomForestValidParams {
    /// The validated parameters.
    pub fn params(&self) -> &RandomForestParams {
        &self.0
    }
    /// The smallest leaf (0: chosen from the training set, see [`Self::resolved_for`]).
    pub fn min_samples_leaf(&self) -> usize {
        self.0.min_samples_leaf
    }
    /// These parameters with an automatic smallest leaf (`min_samples_leaf = 0`) replaced by
    /// the one `set` asks for: [`AUTO_LEAF_SHARE`] of its mean number of samples per label
    /// ([`TrainingSet::samples_per_label`]), rounded, at least 1. A leaf then holds the same
    /// share of a label's examples however many copies the training set carries: six complete
    /// shapes (six samples per label) keep pure leaves, six SCAPE shapes with 15 single-view
    /// copies each (38 per label) get leaves of 5 (TOSCA's cat, 4; victoria, 3). Then an
    /// automatic number of trees (`n_trees = 0`): [`AUTO_TREES_PURE`] with pure leaves,
    /// [`AUTO_TREES_MIXED`] with larger ones. Fitting resolves both, so a forest stores the
    /// numbers it used; a caller that shows progress reads the count here first.
    ///
    /// ```
    /// use shapeforest::forest::RandomForest;
    /// let p = RandomForest::params().check().unwrap();
    /// assert_eq!((p.min_samples_leaf(), p.n_trees()), (0, 0)); // automatic
    /// let fixed = RandomForest::params().min_samples_leaf(3).n_trees(7).check().unwrap();
    /// assert_eq!((fixed.min_samples_leaf(), fixed.n_trees()), (3, 7));
    /// ```
    pub fn resolved_for(&self, set: &TrainingSet) -> RandomForestValidParams {
        let mut p = self.0.clone();
        if p.min_samples_leaf == 0 {
            p.min_samples_leaf = ((AUTO_LEAF_SHARE * set.samples_per_label()).round() as usize).max(1);
        }
        if p.n_trees == 0 {
            p.n_trees = if p.min_samples_leaf > 1 { AUTO_TREES_MIXED } else { AUTO_TREES_PURE };
        }
        RandomForestValidParams(p)
    }
    /// Number of trees (0: chosen from the training set, see [`Self::resolved_for`]).
    pub fn n_trees(&self) -> usize {
        self.0.n_trees
    }
    /// Seed.
    pub fn seed(&self) -> u64 {
        self.0.seed
    }
}
