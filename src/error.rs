//! The crate-wide error type: one variant per core module, each wrapping that module's
//! own `thiserror` enum.

use thiserror::Error;

/// Any error raised by the shapeforest library.
#[derive(Debug, Error)]
pub enum Error {
    /// Reading, writing or validating a mesh failed.
    #[error(transparent)]
    Mesh(#[from] crate::mesh::MeshError),
    /// Building or solving the Laplace eigenproblem failed.
    #[error(transparent)]
    Spectral(#[from] crate::spectral::SpectralError),
    /// Descriptor parameters were invalid.
    #[error(transparent)]
    Descriptor(#[from] crate::descriptor::DescriptorError),
    /// Geodesic distance computation failed.
    #[error(transparent)]
    Geodesic(#[from] crate::geodesic::GeodesicError),
    /// Training, predicting with, or storing a random forest failed.
    #[error(transparent)]
    Forest(#[from] crate::forest::ForestError),
    /// Sparse matching failed.
    #[error(transparent)]
    Matching(#[from] crate::matching::MatchingError),
    /// A functional-map computation failed.
    #[error(transparent)]
    Fmap(#[from] crate::fmap::FmapError),
    /// The spatial regulariser failed.
    #[error(transparent)]
    Regularizer(#[from] crate::regularizer::RegularizerError),
    /// An evaluation could not be carried out.
    #[error(transparent)]
    Eval(#[from] crate::eval::EvalError),
    /// Generating a synthetic shape failed.
    #[error(transparent)]
    Synth(#[from] crate::synth::SynthError),
}

/// Result alias using the crate [`enum@Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;
