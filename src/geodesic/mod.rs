//! Geodesic distances on triangle meshes and farthest point sampling.

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
}
