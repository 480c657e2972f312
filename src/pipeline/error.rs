//! The pipeline layer's error type. Job failures are not errors of the pipeline: they travel to
//! the sinks as [`super::Failure`] values. An [`enum@Error`] is what stops an actor, a start-up or a
//! build: a file that cannot be written, an invalid pipeline file, a model that cannot be loaded.

use std::path::PathBuf;

use thiserror::Error;

/// Why an actor, a build or a daemon start-up failed.
#[derive(Debug, Error)]
pub enum Error {
    /// Reading, writing or moving a file failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// What the operating system said.
        #[source]
        source: std::io::Error,
    },
    /// An I/O error whose message already names its file (from the data folder's helpers).
    #[error(transparent)]
    File(#[from] std::io::Error),
    /// A pipeline file is invalid (every problem at once).
    #[error(transparent)]
    Config(#[from] super::ConfigError),
    /// A stage's settings cannot be used (found while building it).
    #[error("stage `{stage}`: {message}")]
    Stage {
        /// The stage's name.
        stage: String,
        /// The setting at fault, when one is.
        key: Option<&'static str>,
        /// What is wrong.
        message: String,
    },
    /// A model cannot be loaded, stored or served.
    #[error("{0}")]
    Model(String),
    /// Training a new model version failed.
    #[error("training failed: {0}")]
    Training(String),
    /// An input (a folder, a label map, a stored shape) is unusable.
    #[error("{0}")]
    BadInput(String),
    /// The async runtime could not be started.
    #[error("cannot start the runtime: {0}")]
    Runtime(#[source] std::io::Error),
    /// The data folder's lock cannot be taken (another process holds it) or written.
    #[error("{0}")]
    Lock(String),
    /// The pipeline is shutting down.
    #[error("the pipeline is shutting down")]
    Shutdown,
    /// An actor panicked outside a job (in its start or finish).
    #[error("panic: {0}")]
    Panic(String),
    /// A core computation failed (reading a mesh, a spectrum, the forest, the regulariser, an
    /// evaluation, a synthetic family): the library's own error, unchanged.
    #[error(transparent)]
    Core(#[from] crate::Error),
    /// A report could not be encoded.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
}

/// Each core module's error converts through [`crate::Error`], so `?` works on them directly.
macro_rules! through_core {
    ($($t:ty),*) => {$(
        impl From<$t> for Error {
            fn from(e: $t) -> Self {
                Self::Core(e.into())
            }
        }
    )*};
}
through_core!(
    crate::mesh::MeshError,
    crate::spectral::SpectralError,
    crate::descriptor::DescriptorError,
    crate::geodesic::GeodesicError,
    crate::forest::ForestError,
    crate::matching::MatchingError,
    crate::fmap::FmapError,
    crate::regularizer::RegularizerError,
    crate::eval::EvalError,
    crate::synth::SynthError
);

impl Error {
    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io { path: path.into(), source }
    }

    /// A problem with stage `stage`'s settings.
    pub fn stage(stage: &str, message: impl Into<String>) -> Self {
        Self::Stage { stage: stage.to_string(), key: None, message: message.into() }
    }
}

/// An I/O result with its path attached: `fs::write(&p, x).at(&p)?`.
pub(crate) trait IoAt<T> {
    fn at(self, path: &std::path::Path) -> Result<T, Error>;
}

impl<T> IoAt<T> for std::io::Result<T> {
    fn at(self, path: &std::path::Path) -> Result<T, Error> {
        self.map_err(|e| Error::io(path, e))
    }
}
