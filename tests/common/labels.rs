//! Labelled shapes in their own vertex order, with `.vts` maps (fixtures for the label-table,
//! pairwise and daemon tests).

use std::{fmt::Write as _, path::Path};

use shapeforest::{
    mesh::{write_mesh, Mesh},
    synth::{creature_family, shuffle_vertices, CreatureParams},
};

/// A labelled shape in its own vertex order: the mesh and `truth[label]` = its vertex.
pub struct Shuffled {
    /// The mesh.
    pub mesh: Mesh,
    /// `truth[label]` = its vertex.
    pub truth: Vec<usize>,
    /// `mirrored[label]` = the vertex at the mirror image of `truth[label]` (the family's exact
    /// left/right symmetry), as a `.sym.vts` lists it.
    pub mirrored: Vec<usize>,
}

/// Shapes of the synthetic family, each with its vertices shuffled; label `k` is template vertex
/// `k`, except that every 7th label sits on a neighbouring template vertex, so that several
/// labels share a vertex as in the remeshed sets' `.vts` files.
pub fn shuffled_family(n: usize) -> Vec<Shuffled> {
    let fam =
        creature_family(&CreatureParams { target_vertices: 1500, seed: 3, ..Default::default() }, n).unwrap();
    let n_v = fam.template.n_vertices();
    let mut site: Vec<usize> = (0..n_v).collect();
    for f in &fam.template.faces {
        if f[0] % 7 == 0 {
            site[f[0]] = f[1];
        }
    }
    fam.shapes
        .iter()
        .enumerate()
        .map(|(i, m)| {
            let (mesh, new_index) = shuffle_vertices(m, 100 + i as u64).unwrap();
            Shuffled {
                mesh,
                truth: site.iter().map(|&v| new_index[v]).collect(),
                mirrored: site.iter().map(|&v| new_index[fam.symmetry[v]]).collect(),
            }
        })
        .collect()
}

pub fn vts(truth: &[usize]) -> String {
    let mut s = String::new();
    for &v in truth {
        let _ = writeln!(s, "{}", v + 1);
    }
    s
}

pub fn write_shape(dir: &Path, name: &str, s: &Shuffled) {
    write_mesh(dir.join(format!("{name}.off")), &s.mesh).unwrap();
    std::fs::write(dir.join(format!("{name}.vts")), vts(&s.truth)).unwrap();
}

/// Fraction of labels whose source vertex lands within 0.05 √area (Euclidean, a lower bound of
/// the geodesic figure) of the label's vertex on the target, under `map` (source → target).
pub fn accuracy(map: &[usize], from: &Shuffled, to: &Shuffled) -> f64 {
    let scale = to.mesh.surface_area().sqrt();
    let good = from
        .truth
        .iter()
        .zip(&to.truth)
        .filter(|&(&a, &b)| {
            let (p, q) = (to.mesh.vertices[map[a]], to.mesh.vertices[b]);
            let d = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
            d / scale <= 0.05
        })
        .count();
    good as f64 / from.truth.len() as f64
}
