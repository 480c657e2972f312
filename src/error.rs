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
    /// A pipeline file is invalid.
    #[error(transparent)]
    Config(#[from] crate::pipeline::ConfigError),
    /// A pipeline, a stage or the daemon failed (boxed: a pipeline error can carry a core one).
    #[error(transparent)]
    Pipeline(Box<crate::pipeline::Error>),
}

impl From<crate::pipeline::Error> for Error {
    /// A pipeline error; one that only wraps a core error becomes that error again.
    fn from(e: crate::pipeline::Error) -> Self {
        match e {
            crate::pipeline::Error::Core(core) => core,
            crate::pipeline::Error::Config(c) => Self::Config(c),
            other => Self::Pipeline(Box::new(other)),
        }
    }
}

/// Result alias using the crate [`enum@Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

#[cfg(test)]
mod tests {
    use super::Error;
    use crate::{mesh::MeshError, pipeline};

    #[test]
    fn a_core_error_through_the_pipeline_comes_back_as_itself() {
        let mesh = MeshError::Empty { vertices: 0, faces: 0 };
        let text = mesh.to_string();
        let through: pipeline::Error = mesh.into();
        assert_eq!(through.to_string(), text, "the pipeline adds nothing to a core error's message");
        assert!(matches!(Error::from(through), Error::Mesh(MeshError::Empty { .. })));
        let stage = pipeline::Error::Shutdown;
        assert!(matches!(Error::from(stage), Error::Pipeline(e) if matches!(*e, pipeline::Error::Shutdown)));
    }
}
