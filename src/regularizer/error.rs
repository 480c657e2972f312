//! The regulariser's error type: its own input checks, and the errors of the core modules it
//! drives (geodesics, matching, functional maps), each kept whole.

use thiserror::Error;

/// Why a regularisation could not be carried out.
#[derive(Debug, Error)]
pub enum RegularizerError {
    /// Input sizes do not agree (a prediction, a spectrum or a label table of another shape).
    #[error("size mismatch: {0}")]
    SizeMismatch(String),
    /// An input is out of range or empty (e.g. a symmetry map naming a vertex the shape lacks).
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// A parameter is invalid.
    #[error("invalid regulariser parameter `{name}`: {reason}")]
    InvalidParameter {
        /// Parameter name.
        name: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// A geodesic computation failed.
    #[error(transparent)]
    Geodesic(#[from] crate::geodesic::GeodesicError),
    /// The sparse matcher failed.
    #[error(transparent)]
    Matching(#[from] crate::matching::MatchingError),
    /// A functional-map computation failed.
    #[error(transparent)]
    Fmap(#[from] crate::fmap::FmapError),
    /// A posterior could not be built.
    #[error(transparent)]
    Forest(#[from] crate::forest::ForestError),
}
