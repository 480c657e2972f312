//! Geodesic distances on triangle meshes and farthest point sampling.
//!
//! - [`HeatMethodSolver`]: the heat method (Crane, Weischedel, Wardetzky, "Geodesics in heat",
//!   ACM TOG 2013). Both sparse factorisations are computed once per mesh; many sources are
//!   solved as one block. This is the fast, smooth distance used by the regulariser.
//! - [`fast_marching_distances`]: first-order fast marching on the triangles with a
//!   virtual-point-source two-neighbour update (exact for a point source in a flat region),
//!   obtuse corners split by unfolding (Kimmel–Sethian), edge updates where no causal update
//!   exists. The accurate reference for evaluation; [`FastMarchingSolver`] caches the per-mesh
//!   precomputation for many queries.
//! - [`dijkstra_distances`]: shortest paths along edges, an upper bound.
//! - [`farthest_point_sampling_euclidean`], [`farthest_point_sampling_geodesic`]:
//!   deterministic greedy farthest point sampling.
//!
//! Conventions: distances are in mesh units (callers normalise, e.g. by `√area`), `≥ 0`, exactly
//! 0 at the sources, and `f64::INFINITY` for vertices not connected to any source.
//! Multi-source functions return the distance to the *nearest* source, except
//! [`HeatMethodSolver::distances_from_many`], which returns one column per source.
//!
//! # Measured accuracy
//!
//! Release build, errors in mesh units (`tests/geodesic.rs` asserts bounds slightly above these):
//!
//! | mesh | method | mean abs error | max abs error | max relative error (r > 0.1) |
//! |---|---|---|---|---|
//! | unit sphere, `icosphere(5, 1.0)`, 10,242 vertices | heat, t = h² | 8.7e-3 | 1.9e-2 | |
//! | same | fast marching | 2.9e-3 | 2.3e-2 | |
//! | same | Dijkstra | 1.2e-1 | 2.0e-1 | |
//! | unit square, `grid_plane(61, 61, 1.0, 1.0)`, centre source | heat, t = h², `Average` | | | 3.1 % |
//! | same | heat, `Neumann` | | | 3.1 % |
//! | same | heat, `Dirichlet` | | | 5.7 % |
//! | same grid, source mid-way along one side | heat, `Average` / `Neumann` | | | 3.3 % |
//! | same | heat, `Dirichlet` | | | 34 % |
//! | same | fast marching | | | 5e-16 (exact in the plane) |
//! | same | Dijkstra | | | 8.2 % |
//! | same grid, interior vertices jittered ±0.35 h (obtuse triangles) | fast marching | | | 3.1 % (mean 0.01 %) |
//! | same | heat, `Average` | | | 4.3 % |
//! | same | Dijkstra | | | 14 % |
//!
//! On TOSCA `wolf0` (4,344 vertices) heat and fast marching differ by 0.9–1.4 % of `√area` on
//! average (max 2.6–6.5 %) over four sources.
//!
//! potpourri3d's `MeshHeatMethodDistanceSolver(V, F, t_coef=1.0)` on the same icosphere:
//! mean 8.9e-3, max 1.9e-2 (`use_robust=True`).
//!
//! # Speed
//!
//! `benches/geodesic.rs`, tori of 5,000 / 20,000 / 49,928 vertices, release, on a shared 2-core
//! machine under heavy load (absolute times noisy; ratios from back-to-back runs): setup
//! 48 / 233 / 800 ms and 50 sources as one block 62 / 365 / 948 ms, against potpourri3d's
//! setup 103 / 414 / 1726 ms and 50 `compute_distance` calls 286 / 881 / 2612 ms, i.e. about
//! 2× faster setup and 2.4–4.6× faster queries. Solving the 50 sources one at a time costs
//! 1.7–2.5× more than one block.
//!
//! Sphere errors are against the great-circle distance `acos(p·q)` from vertex 0; grid errors are
//! the maximum relative error against the Euclidean distance over vertices farther than 0.1
//! from the source.

// Negated float comparisons (`!(x > 0.0)`) are deliberate throughout: they treat NaN as failure.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

mod exact;
mod fps;
mod heat;
pub(crate) mod topology;

pub use exact::{dijkstra_distances, dijkstra_nearest_source, fast_marching_distances, FastMarchingSolver};
pub use fps::{
    farthest_from_centroid, farthest_point_sampling_euclidean, farthest_point_sampling_geodesic,
    SamplingMetric,
};
pub use heat::{HeatBoundary, HeatMethodSolver, HeatParams};
pub use topology::mean_edge_length;

use thiserror::Error;

/// A geodesic computation failed.
#[derive(Debug, Error)]
pub enum GeodesicError {
    /// A source vertex does not exist.
    #[error("source vertex {vertex} is out of range for a mesh of {n_vertices} vertices")]
    SourceOutOfRange {
        /// The vertex asked for.
        vertex: usize,
        /// Vertices in the mesh.
        n_vertices: usize,
    },
    /// An empty list of sources was given.
    #[error("no source vertices were given")]
    NoSources,
    /// More samples were asked for than the mesh has vertices.
    #[error("asked for {wanted} samples but the mesh has only {n_vertices} vertices")]
    TooManySamples {
        /// Samples asked for.
        wanted: usize,
        /// Vertices in the mesh.
        n_vertices: usize,
    },
    /// The heat time factor must be finite and positive.
    #[error("heat time factor must be finite and positive, got {time_factor}")]
    InvalidTimeFactor {
        /// The value given.
        time_factor: f64,
    },
    /// The mesh has zero total area or zero mean edge length.
    #[error("the mesh is degenerate (zero area or zero edge length): no geodesic distance is defined")]
    DegenerateMesh,
    /// A sparse Cholesky factorisation failed.
    #[error("sparse Cholesky factorisation of the {matrix} failed: {reason}")]
    Factorization {
        /// Which matrix.
        matrix: &'static str,
        /// faer's error.
        reason: String,
    },
}
