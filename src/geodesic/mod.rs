//! Geodesic distances on triangle meshes and farthest point sampling.
//!
//! - [`HeatMethodSolver`]: the heat method (Crane, Weischedel, Wardetzky, "Geodesics in heat",
//!   ACM TOG 2013). Both sparse factorisations are computed once per mesh; many sources are
//!   solved as one block. This is the fast, smooth distance used by the regulariser.
//! - [`fast_marching_distances`]: first-order fast marching on the triangles with a
//!   virtual-point-source two-neighbour update (exact for a point source in a flat region),
//!   falling back to edge updates where the update is not causal. The accurate reference for
//!   evaluation.
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
//! | mesh | method | mean abs error | max abs error | other |
//! |---|---|---|---|---|
//! | unit sphere, icosphere(5), 10,242 vertices | heat (t = h²) | MEAN_HEAT_SPHERE | MAX_HEAT_SPHERE | |
//! | unit sphere, icosphere(5) | fast marching | MEAN_FMM_SPHERE | MAX_FMM_SPHERE | |
//! | unit sphere, icosphere(5) | Dijkstra | MEAN_DIJ_SPHERE | MAX_DIJ_SPHERE | |
//! | unit square, 61×61 grid, centre source | heat (t = h², Average) | | | REL_HEAT_GRID |
//! | unit square, 61×61 grid | fast marching | | | REL_FMM_GRID |
//! | unit square, 61×61 grid | Dijkstra | | | REL_DIJ_GRID |
//!
//! Sphere errors are against the great-circle distance `acos(p·q)` from vertex 0; grid errors are
//! the maximum relative error against the Euclidean distance over vertices farther than 0.1
//! from the source.

mod exact;
mod fps;
mod heat;
mod topology;

pub use exact::{dijkstra_distances, fast_marching_distances};
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
