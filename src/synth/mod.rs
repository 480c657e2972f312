//! Deterministic synthetic shapes: families with known correspondence (built-in data for the
//! demo and tests), and simple primitives with known analytic answers (spheres, planes, tori).

pub mod primitives;

pub use primitives::{grid_plane, icosphere, torus};
