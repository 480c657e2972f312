//! # shapeforest
//!
//! Dense non-rigid 3D shape correspondence with random forests over wave kernel signatures,
//! after Rodolà et al., "Dense non-rigid shape correspondence using random forests" (CVPR 2014).
//!
//! The crate is a library first; the `shapeforest` binary is a thin command-line layer.
//! Numeric and geometric modules are synchronous and pure (no files, no channels); the
//! pipeline layer wraps them.
//!
//! Modules in dataflow order (a shape goes down the table):
//!
//! | module | computes |
//! |---|---|
//! | [`mesh`] | the [`mesh::Mesh`] type, validation, summaries, readers and writers (OBJ, OFF, PLY, TOSCA) |
//! | [`limits`] | bounds on input sizes, checked before allocating |
//! | [`spectral`] | cotangent Laplacian, lumped mass, the generalised eigenpairs [`spectral::Spectrum`], a spectrum cache |
//! | [`descriptor`] | heat and wave kernel signatures, the parametric WKS `p(m; e, k̄)` the forest splits on, orientation descriptors |
//! | [`forest`] | random forest over parametric WKS: training, prediction, model files |
//! | [`geodesic`] | heat-method geodesic distances, exact graph distances, farthest point sampling |
//! | [`matching`] | game-theoretic sparse matching (replicator dynamics) |
//! | [`fmap`] | functional maps: soft map in Laplace bases, regularised solve, point-to-point, ZoomOut |
//! | [`regularizer`] | forest posterior → consistent matches → regularised functional map → dense map |
//! | [`eval`] | geodesic error of maps, cumulative curves, CSV and SVG reports |
//! | [`viz`] | PNG snapshots (a software rasteriser) and the interactive `view.html` (three.js) of a correspondence |
//! | [`synth`] | deterministic synthetic shape families with known correspondence and test primitives |
//! | [`pipeline`] | the streaming actors that wrap the modules above, pipeline files, the watch-folder daemon |
//!
//! The pipeline's stage types (`pipelines/*.toml`), each a file of [`pipeline::stages`]:
//!
//! | type | consumes → emits | wraps |
//! |---|---|---|
//! | `folder`, `watch-folder` | — → file | the data folder ([`pipeline::store`]) |
//! | `synthetic` | — → shape | [`synth`] |
//! | `ingest` | file → shape | [`mesh`], label maps |
//! | `spectral` | shape → spectrum | [`spectral`] |
//! | `descriptor` | spectrum → descriptor | [`descriptor`] with the live model |
//! | `forest` | descriptor → prediction | [`forest`] |
//! | `matcher` | prediction → matches | [`regularizer`] (sparse step: [`geodesic`], [`matching`]) |
//! | `fmap` | matches → map | [`regularizer`] (dense step: [`fmap`]) |
//! | `match-sink`, `eval-sink` | map → — | result folders, [`eval`] |
//! | `trainer` | spectrum → — | [`forest`] (incremental fits), model versions |
//!
//! Conventions used throughout:
//! - vertex order is never changed; ground truth is by vertex index;
//! - spectra are those of the mesh scaled to **unit total area**; eigenvalues ascend and
//!   eigenvectors are orthonormal in the **mass (M) inner product**, not the plain dot product;
//! - geodesic errors are normalised by the square root of the target's surface area.

#![warn(missing_docs)]

pub mod descriptor;
pub mod error;
pub mod eval;
pub mod fmap;
pub mod forest;
mod fsutil;
pub mod geodesic;
pub mod limits;
pub mod matching;
pub mod mesh;
pub mod pipeline;
mod pool;
pub mod regularizer;
pub mod spectral;
pub mod synth;
pub mod viz;

pub use error::{Error, Result};
