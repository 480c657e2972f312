//! Random forest over parametric wave kernel signatures (Rodolà, Rota Bulò, Windheuser, Vestner,
//! Cremers, "Dense non-rigid shape correspondence using random forests", CVPR 2014).
//!
//! **Problem.** Training shapes `M_1..M_n` each come with a (partial) map from their vertices to a
//! common label set `L = {0..|L|}` (e.g. the vertex indices of a reference shape). The forest
//! learns `vertex → label` from spectral features, and predicts for an unseen shape `N` a sparse
//! left-stochastic matrix `X ∈ [0,1]^{|L|×|N|}` with `X[l, m] = P(l | m)`.
//!
//! **Features.** The parametric WKS (Eq. 3 of the paper, see [`crate::descriptor`])
//! `p(m; e, k̄) = Σ_{k<k̄} f_e(λ_k)² φ_k(m)²`, `f_e(λ)² = exp(−(e − log λ)²/(2σ²))`, on the
//! unit-area spectrum (zero eigenvalues skipped). `e` is drawn from a grid of `energy_levels`
//! log-energies over `[e_min, e_max]` = [smallest `log λ_1`, largest `log λ_K`] of the training
//! shapes, `σ = 7 (e_max − e_min)/100` by default, and `k̄` uniformly from `[k_min, K]`. The range
//! and `K` are stored in the model so prediction uses the same descriptor.
//!
//! **Local histograms (for partial scans).** When every training shape carries
//! [`crate::descriptor::LocalDescriptor`]s ([`TrainingShape::with_local`]), a share
//! `local_share` of the split candidates are bins `b` of the histogram instead: `ψ(m) =
//! [h_b(m) > τ]` (default share 1: local bins only). The histograms see only a small ball around
//! each point, so they survive holes and missing halves that change every eigenfunction; the
//! forest stores their settings ([`RandomForest::local`], model format version 4) and predicts
//! from a shape's mesh and spectrum ([`RandomForest::predict_mesh`]).
//!
//! **Splits.** `ψ(m) = [p(m; e, k̄) > τ]` (true: right child). Each node draws
//! `candidates_per_node` pairs `(e, k̄)`; for each, every threshold between consecutive sorted
//! values is scored by the information gain `H(S) − |S_L|/|S| H(S_L) − |S_R|/|S| H(S_R)` with the
//! Shannon entropy `H` of the label histogram, using O(1) incremental updates of `Σ c ln c` (see
//! the `tree` module); the best candidate wins. A node becomes a leaf at `max_depth`, below
//! `min_samples_split` samples, with entropy ≤ `min_entropy`, or when no split gains. A leaf
//! stores its label distribution sparsely (sorted `(label, probability)`), never a dense `|L|`
//! vector. Each tree sees a random `bagging_fraction` of the samples (without replacement).
//!
//! **Prediction.** The posterior of a vertex is the average of the leaf distributions it reaches
//! in the trees ([`RandomForest::predict`] → [`Prediction`], with MAP labels, top-k and the Bayes
//! composition [`Prediction::compose`] of two predictions into a fuzzy correspondence).
//!
//! **Scale and memory.** Training memory is `O(samples · K)` for the per-shape `φ²` tables,
//! `O(samples)` per tree being grown (indices, sort keys, `candidates × node samples` values),
//! two `|L|` count arrays per worker and `O(nodes + leaf entries)` for the model. Trees grow in
//! parallel (rayon), and nodes larger than `parallel_node_size` score their candidates in
//! parallel. Everything is deterministic given the seed (each tree has its own seeded
//! `ChaCha8Rng`; parallel results are combined in a fixed order).
//!
//! **Incremental growth.** [`RandomForestValidParams::fit_with`]`(Some(&prev), &set)` grows
//! `trees_per_update` trees on the (enlarged) set and retires the oldest beyond `n_trees`; the
//! previous forest is immutable and keeps serving until the caller swaps in the new one.
//!
//! **Baseline.** [`WksKnn`]: nearest neighbours in WKS space, same output type.
//!
//! ```
//! use std::sync::Arc;
//! use shapeforest::forest::{labels_identity, RandomForest, TrainingSet, TrainingShape};
//! use shapeforest::{spectral::dense_spectrum, synth::icosphere};
//! let mesh = icosphere(1, 1.0);
//! let spectrum = Arc::new(dense_spectrum(&mesh, 12).unwrap());
//! let n = mesh.n_vertices();
//! let shape = TrainingShape::new("a", spectrum.clone(), labels_identity(n));
//! let set = TrainingSet::new(vec![shape], n).unwrap();
//! let forest = RandomForest::params().n_trees(3).seed(1).fit(&set).unwrap();
//! let pred = forest.predict(&spectrum).unwrap();
//! let (_, probs) = pred.posterior(0);
//! assert!((probs.iter().sum::<f32>() - 1.0).abs() < 1e-5);
//! ```

mod augment;
mod compact;
mod io;
mod knn;
mod model;
mod params;
mod prediction;
mod reference;
mod training;
mod tree;

pub use augment::{augmented_copies, augmented_shape, Augmentation};
pub use io::{fnv1a64, ModelHeader, MODEL_FORMAT_VERSION, MODEL_MAGIC};
pub use knn::WksKnn;
pub use model::{ForestDescriptor, RandomForest};
pub use params::{
    RandomForestParams, RandomForestValidParams, AUTO_LEAF_SHARE, AUTO_TREES_MIXED, AUTO_TREES_PURE,
};
pub use prediction::{hit_ratio, Prediction};
pub use reference::{read_per_label_rows, reference_table, LabelTable, ModelReference};
pub use training::{
    labels_identity, per_vertex_labels, read_label_map, read_per_label_map, RejectedShape, TrainingSet,
    TrainingShape,
};

use thiserror::Error;

/// Training, predicting with, or storing a forest failed.
#[derive(Debug, Error)]
pub enum ForestError {
    /// A hyper-parameter is invalid.
    #[error("invalid forest parameter `{name}`: {reason}")]
    InvalidParameter {
        /// Parameter name.
        name: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// A training shape does not fit (wrong label count, labels out of range, bad spectrum).
    #[error("training shape `{name}` rejected: {reason}")]
    BadShape {
        /// The shape's name.
        name: String,
        /// What is wrong with it.
        reason: String,
    },
    /// No training shape was accepted.
    #[error("no usable training shape: {rejected}")]
    EmptyTrainingSet {
        /// The rejections, joined.
        rejected: String,
    },
    /// A label map file has a bad line.
    #[error("label map line {line}: {reason}")]
    LabelMap {
        /// 1-based line number.
        line: usize,
        /// What is wrong with it.
        reason: String,
    },
    /// A spectrum has fewer eigenpairs than the model needs.
    #[error("the spectrum has {found} eigenpairs but the forest needs {needed}")]
    SpectrumTooShort {
        /// Eigenpairs needed.
        needed: usize,
        /// Eigenpairs found.
        found: usize,
    },
    /// A model and data (or two predictions) disagree.
    #[error("incompatible model: {0}")]
    IncompatibleModel(String),
    /// Descriptor computation failed.
    #[error(transparent)]
    Descriptor(#[from] crate::descriptor::DescriptorError),
    /// A perturbed copy of a training shape could not be made (augmentation).
    #[error(transparent)]
    Mesh(#[from] crate::mesh::MeshError),
    /// A training shape's spectrum could not be computed (augmentation).
    #[error(transparent)]
    Spectral(#[from] crate::spectral::SpectralError),
    /// Reading or writing a file failed. (The cause is in the message and deliberately not a
    /// `source`, so that an error chain prints it once.)
    #[error("{}: {error}", path.display())]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// The underlying error.
        error: std::io::Error,
    },
    /// A model file could not be decoded. (The cause is in the message, not a `source`.)
    #[error("{}: {inner}", path.display())]
    InFile {
        /// The file.
        path: std::path::PathBuf,
        /// What is wrong with it.
        inner: Box<ForestError>,
    },
    /// The file does not start with the model magic bytes.
    #[error("not a shapeforest model file (bad magic bytes)")]
    NotAModel,
    /// The file's format version is not supported.
    #[error(
        "model format version {found} is not supported (this build reads versions {oldest} to {supported})"
    )]
    UnsupportedVersion {
        /// Version in the file.
        found: u32,
        /// Oldest version this build reads.
        oldest: u32,
        /// Version this build reads.
        supported: u32,
    },
    /// The file is shorter than its header says.
    #[error("model file truncated: expected {expected} bytes, found {found}")]
    Truncated {
        /// Bytes expected.
        expected: usize,
        /// Bytes present.
        found: usize,
    },
    /// The payload checksum does not match.
    #[error("model file corrupted: checksum {found:#018x} does not match the header's {expected:#018x}")]
    ChecksumMismatch {
        /// Checksum in the header.
        expected: u64,
        /// Checksum of the payload read.
        found: u64,
    },
    /// The payload could not be decoded or is inconsistent.
    #[error("model file corrupted: {0}")]
    CorruptModel(String),
}
