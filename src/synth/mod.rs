//! Deterministic synthetic shapes: families with known correspondence (built-in data for the
//! demo and tests), and simple primitives with known analytic answers (spheres, planes, tori).
//!
//! - [`creature_template`] / [`creature_family`]: a four-legged creature with head, neck and
//!   tail, mirror-symmetric about `x = 0`, and posed / locally rescaled copies sharing its
//!   vertex indexing (vertex `i` of every shape corresponds). See [`creature`] for conventions.
//! - [`icosphere`], [`grid_plane`], [`torus`]: primitives with analytic areas and spectra.
//! - [`sdf`]: the signed distance functions the creature is built from.

pub mod creature;
mod isosurface;
pub mod primitives;
pub mod sdf;
mod skinning;

pub use creature::{creature_family, creature_template, Creature, CreatureParams, ShapeFamily, PART_NAMES};
pub use primitives::{grid_plane, icosphere, shuffle_vertices, torus};

use thiserror::Error;

/// A synthetic shape could not be generated.
#[derive(Debug, Error)]
pub enum SynthError {
    /// A parameter is out of its valid range.
    #[error("invalid synthetic-shape parameter `{name}` = {value}: expected {expected}")]
    InvalidParameter {
        /// Parameter name.
        name: &'static str,
        /// The value given, as text.
        value: String,
        /// The valid range or rule.
        expected: &'static str,
    },
    /// Polygonisation did not give a closed, connected genus-0 manifold.
    #[error("surface extraction failed after {attempts} grids: {reason}")]
    Extraction {
        /// Grids tried.
        attempts: usize,
        /// The last defect found.
        reason: String,
    },
    /// The generated mesh failed validation.
    #[error(transparent)]
    Mesh(#[from] crate::mesh::MeshError),
}
