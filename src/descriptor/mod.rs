//! Spectral point descriptors: heat kernel signature (HKS), wave kernel signature (WKS) and the
//! parametric WKS `p(m; e, k̄)` that the forest splits on.

use thiserror::Error;

/// Descriptor parameters were invalid.
#[derive(Debug, Error)]
pub enum DescriptorError {
    /// A parameter is out of its valid range.
    #[error("invalid descriptor parameter `{name}`: {reason}")]
    InvalidParameter {
        /// Parameter name.
        name: &'static str,
        /// What is wrong with it.
        reason: String,
    },
}
