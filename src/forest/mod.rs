//! Random forest over parametric wave kernel signatures.

use thiserror::Error;

/// Training, predicting with, or storing a forest failed.
#[derive(Debug, Error)]
pub enum ForestError {
    /// A hyper-parameter is invalid.
    #[error("invalid forest parameter `{name}`: {reason}")]
    InvalidParameter {
        /// Parameter name.
        name: &'static str,
        /// What is wrong with it.
        reason: String,
    },
}
