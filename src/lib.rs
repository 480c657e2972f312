//! # shapeforest
//!
//! Dense non-rigid 3D shape correspondence with random forests over wave kernel signatures,
//! after Rodolà et al., "Dense non-rigid shape correspondence using random forests" (CVPR 2014).
//!
//! The crate is a library first; the `shapeforest` binary is a thin command-line layer.
//! Numeric and geometric modules are synchronous and pure (no files, no channels); the
//! pipeline layer wraps them.
//!
//! | module | computes |
//! |---|---|
//! | [`mesh`] | the [`mesh::Mesh`] type, validation, summaries, readers and writers (OBJ, OFF, PLY, TOSCA) |
//! | [`spectral`] | cotangent Laplacian, lumped mass, the generalised eigenpairs [`spectral::Spectrum`], a spectrum cache |
//! | [`descriptor`] | heat and wave kernel signatures, and the parametric WKS `p(m; e, k̄)` the forest splits on |
//! | [`geodesic`] | heat-method geodesic distances, exact graph distances, farthest point sampling |
//! | [`forest`] | random forest over parametric WKS: training, prediction, model files |
//! | [`matching`] | game-theoretic sparse matching (replicator dynamics) |
//! | [`fmap`] | functional maps: soft map in Laplace bases, regularised solve, point-to-point, ZoomOut |
//! | [`eval`] | geodesic error of maps, cumulative curves, CSV and SVG reports |
//! | [`regularizer`] | forest posterior → consistent matches → regularised functional map → dense map |
//! | [`viz`] | PNG snapshots (a software rasteriser) and the interactive `view.html` (three.js) of a correspondence |
//! | [`synth`] | deterministic synthetic shape families with known correspondence and test primitives |
//!
//! Conventions used throughout:
//! - vertex order is never changed; ground truth is by vertex index;
//! - spectra are those of the mesh scaled to **unit total area**; eigenvalues ascend and
//!   eigenvectors are orthonormal in the **mass (M) inner product**, not the plain dot product;
//! - geodesic errors are normalised by the square root of the target's surface area.

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
pub mod regularizer;
pub mod spectral;
pub mod synth;
pub mod viz;

pub use error::{Error, Result};
