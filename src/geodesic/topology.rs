//! Small combinatorial helpers shared by the geodesic algorithms: unique edges, boundary
//! vertices, connected components and the vertex adjacency graph.

use crate::mesh::{norm, sub, Mesh};

use super::GeodesicError;

/// Unique undirected edges `(i, j)` with `i < j`, each with the number of faces containing it.
pub(crate) fn edges_with_face_counts(mesh: &Mesh) -> Vec<(usize, usize, u32)> {
    let mut e: Vec<(usize, usize)> = Vec::with_capacity(mesh.n_faces() * 3);
    for f in &mesh.faces {
        for c in 0..3 {
            let (a, b) = (f[c], f[(c + 1) % 3]);
            e.push((a.min(b), a.max(b)));
        }
    }
    e.sort_unstable();
    let mut out: Vec<(usize, usize, u32)> = Vec::with_capacity(e.len() / 2 + 1);
    for (a, b) in e {
        match out.last_mut() {
            Some(last) if last.0 == a && last.1 == b => last.2 += 1,
            _ => out.push((a, b, 1)),
        }
    }
    out
}

/// Mean length of the unique edges (0 for a mesh without edges).
///
/// ```
/// use shapeforest::{geodesic::mean_edge_length, mesh::Mesh};
/// let m = Mesh::new(vec![[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [0.0, 4.0, 0.0]], vec![[0, 1, 2]]).unwrap();
/// assert!((mean_edge_length(&m) - 4.0).abs() < 1e-12); // (3 + 4 + 5) / 3
/// ```
pub fn mean_edge_length(mesh: &Mesh) -> f64 {
    let edges = edges_with_face_counts(mesh);
    if edges.is_empty() {
        return 0.0;
    }
    let total: f64 = edges.iter().map(|&(a, b, _)| norm(sub(mesh.vertices[a], mesh.vertices[b]))).sum();
    total / edges.len() as f64
}

/// `true` for every vertex on an edge that belongs to exactly one face.
pub(crate) fn vertex_on_boundary(mesh: &Mesh, edges: &[(usize, usize, u32)]) -> Vec<bool> {
    let mut on = vec![false; mesh.n_vertices()];
    for &(a, b, count) in edges {
        if count == 1 {
            on[a] = true;
            on[b] = true;
        }
    }
    on
}

/// Connected component label of every vertex (through faces). Unreferenced vertices get a
/// component of their own. Labels are `0..n_components`, numbered by lowest vertex.
pub(crate) fn vertex_components(mesh: &Mesh) -> Vec<usize> {
    crate::mesh::face_connectivity(mesh).labels().0
}

/// The edge graph in compressed (CSR) form: neighbours of `v` are
/// `targets[offsets[v]..offsets[v + 1]]`, with the edge lengths alongside.
pub(crate) struct EdgeGraph {
    pub(crate) offsets: Vec<usize>,
    pub(crate) targets: Vec<usize>,
    pub(crate) lengths: Vec<f64>,
}

impl EdgeGraph {
    pub(crate) fn new(mesh: &Mesh) -> Self {
        let n = mesh.n_vertices();
        let edges = edges_with_face_counts(mesh);
        let mut degree = vec![0usize; n + 1];
        for &(a, b, _) in &edges {
            degree[a] += 1;
            degree[b] += 1;
        }
        let mut offsets = vec![0usize; n + 1];
        for v in 0..n {
            offsets[v + 1] = offsets[v] + degree[v];
        }
        let mut fill = offsets.clone();
        let mut targets = vec![0usize; offsets[n]];
        let mut lengths = vec![0.0; offsets[n]];
        for &(a, b, _) in &edges {
            let l = norm(sub(mesh.vertices[a], mesh.vertices[b]));
            targets[fill[a]] = b;
            lengths[fill[a]] = l;
            fill[a] += 1;
            targets[fill[b]] = a;
            lengths[fill[b]] = l;
            fill[b] += 1;
        }
        Self { offsets, targets, lengths }
    }
}

/// Checks that `sources` is non-empty and every index is a vertex.
pub(crate) fn check_sources(sources: &[usize], n_vertices: usize) -> Result<(), GeodesicError> {
    if sources.is_empty() {
        return Err(GeodesicError::NoSources);
    }
    if let Some(&vertex) = sources.iter().find(|&&s| s >= n_vertices) {
        return Err(GeodesicError::SourceOutOfRange { vertex, n_vertices });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn square_has_boundary_and_one_component() {
        let m = crate::synth::grid_plane(3, 3, 1.0, 1.0);
        let edges = edges_with_face_counts(&m);
        // 3x3 grid: 12 axis edges + 4 diagonals
        assert_eq!(edges.len(), 16);
        let b = vertex_on_boundary(&m, &edges);
        assert_eq!(b.iter().filter(|&&x| x).count(), 8);
        assert!(!b[4]);
        assert!(vertex_components(&m).iter().all(|&c| c == 0));
    }

    #[test]
    fn sphere_has_no_boundary() {
        let m = crate::synth::icosphere(1, 1.0);
        let edges = edges_with_face_counts(&m);
        assert!(edges.iter().all(|e| e.2 == 2));
    }

    #[test]
    fn unreferenced_vertex_is_its_own_component() {
        let m = Mesh::new(vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [5.0, 5.0, 5.0]], vec![[0, 1, 2]])
            .unwrap();
        assert_eq!(vertex_components(&m), vec![0, 0, 0, 1]);
    }
}
