//! The bumpy-sphere family shared by the forest tests and benches (`benches/forest.rs` includes
//! this file by path): an asymmetric bumpy sphere (no isometries to confuse labels) and its
//! near-isometric members, all with the base's vertex order.

use shapeforest::{mesh::Mesh, synth::icosphere};

/// The asymmetric bumpy sphere (icosphere of 3 subdivisions, 642 vertices).
pub fn bumpy_sphere() -> Mesh {
    let m = icosphere(3, 1.0);
    let vertices = m
        .vertices
        .iter()
        .map(|&[x, y, z]| {
            let r = 1.0 + 0.3 * x + 0.15 * y * z + 0.2 * z * z * z + 0.1 * (3.0 * y).sin();
            [r * x, r * y, r * z]
        })
        .collect();
    Mesh::new(vertices, m.faces.clone()).expect("a valid mesh")
}

/// Member `i` of the family: an anisotropic stretch and a smooth bend of `base`.
pub fn bumpy_member(base: &Mesh, i: usize) -> Mesh {
    let t = i as f64;
    let (sx, sy, sz) =
        (1.0 + 0.04 * (t * 1.3).sin(), 1.0 + 0.04 * (t * 2.1).cos(), 1.0 - 0.03 * (t * 0.7).sin());
    let bend = 0.08 * (t * 1.7).sin();
    let vertices = base
        .vertices
        .iter()
        .map(|&[x, y, z]| {
            let (x, y, z) = (sx * x, sy * y, sz * z);
            let a = bend * z;
            [x * a.cos() - y * a.sin(), x * a.sin() + y * a.cos(), z + 0.05 * bend * x * x]
        })
        .collect();
    Mesh::new(vertices, base.faces.clone()).expect("a valid mesh")
}
