//! Errors raised while building, reading or writing meshes.

use thiserror::Error;

/// A mesh could not be built, read or written.
#[derive(Debug, Error)]
pub enum MeshError {
    /// The mesh has no vertices or no faces.
    #[error("empty mesh: {vertices} vertices, {faces} faces")]
    Empty {
        /// Vertex count found.
        vertices: usize,
        /// Face count found.
        faces: usize,
    },
    /// A vertex coordinate is NaN or infinite.
    #[error("vertex {vertex} has a NaN or infinite coordinate")]
    NonFiniteVertex {
        /// 0-based vertex index.
        vertex: usize,
    },
    /// A face refers to a vertex that does not exist.
    #[error("face {face} refers to vertex {index}, but the mesh has {n_vertices} vertices")]
    FaceIndexOutOfRange {
        /// 0-based face index.
        face: usize,
        /// The offending 0-based vertex index.
        index: usize,
        /// Number of vertices in the mesh.
        n_vertices: usize,
    },
    /// A face uses the same vertex twice.
    #[error("face {face} repeats a vertex: {indices:?}")]
    RepeatedVertexInFace {
        /// 0-based face index.
        face: usize,
        /// The face's vertex indices.
        indices: [usize; 3],
    },
}
