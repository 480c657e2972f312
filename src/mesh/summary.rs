//! [`MeshSummary`]: counts, size and topology of a mesh at a glance.
//!
//! Topology is computed from the undirected edges of the faces: an edge used by one face is a
//! *boundary* edge, by two an interior (manifold) edge, by more than two a *non-manifold*
//! edge. Connected components are found by union-find over the faces' vertices; unreferenced
//! vertices belong to no component and are excluded from the Euler characteristic
//! `χ = V − E + F` (so a closed sphere-like surface has χ = 2 whatever stray points the file
//! holds).

use std::fmt;

use super::{norm, sub, Mesh, UnionFind};

/// Size of one connected component.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ComponentSize {
    /// Faces in the component.
    pub faces: usize,
    /// Vertices in the component.
    pub vertices: usize,
}

/// Counts, size and topology of a mesh. Build it with [`Mesh::summary`].
#[derive(Clone, Debug, PartialEq)]
pub struct MeshSummary {
    /// Number of vertices, including unreferenced ones.
    pub n_vertices: usize,
    /// Number of triangles.
    pub n_faces: usize,
    /// Number of distinct undirected edges.
    pub n_edges: usize,
    /// Total surface area.
    pub surface_area: f64,
    /// Axis-aligned bounding box `(min, max)` over all vertices.
    pub bounding_box: ([f64; 3], [f64; 3]),
    /// Connected components, largest (by faces) first.
    pub components: Vec<ComponentSize>,
    /// Edges used by exactly one face.
    pub n_boundary_edges: usize,
    /// Closed loops formed by the boundary edges (holes); a loop pinched at a vertex counts twice.
    pub n_boundary_loops: usize,
    /// Edges used by more than two faces.
    pub n_non_manifold_edges: usize,
    /// Vertices used by no face.
    pub n_unreferenced_vertices: usize,
    /// Faces whose area is zero up to rounding (see [`is_zero_area`]).
    pub n_zero_area_faces: usize,
    /// Faces with the same vertex set as an earlier face (in any order or orientation).
    pub n_duplicate_faces: usize,
    /// `V − E + F`, counting referenced vertices only.
    pub euler_characteristic: i64,
}

impl MeshSummary {
    /// Number of connected components.
    pub fn n_components(&self) -> usize {
        self.components.len()
    }

    /// True when every edge has exactly two faces (no boundary, no non-manifold edge).
    pub fn is_closed(&self) -> bool {
        self.n_boundary_edges == 0 && self.n_non_manifold_edges == 0
    }
}

/// True when a triangle's area is zero up to floating-point rounding: at most
/// `f64::EPSILON` times the square of its longest edge (scale invariant; a triangle with
/// coincident or collinear vertices).
///
/// ```
/// use shapeforest::mesh::is_zero_area;
/// assert!(is_zero_area([0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]));
/// assert!(!is_zero_area([0.0; 3], [1.0, 0.0, 0.0], [0.0, 1e-6, 0.0]));
/// ```
pub fn is_zero_area(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> bool {
    let area = super::triangle_area(a, b, c);
    let longest = norm(sub(b, a)).max(norm(sub(c, b))).max(norm(sub(a, c)));
    area <= f64::EPSILON * longest * longest
}

/// Everything the summary and the read report need, with the first offender of each kind.
pub(crate) struct Analysis {
    pub(crate) summary: MeshSummary,
    pub(crate) first_zero_area: Option<usize>,
    pub(crate) first_duplicate: Option<usize>,
    pub(crate) first_unreferenced: Option<usize>,
}

impl Mesh {
    /// Counts, size and topology of the mesh.
    ///
    /// ```
    /// use shapeforest::synth::icosphere;
    /// let s = icosphere(2, 1.0).summary();
    /// assert_eq!(s.n_components(), 1);
    /// assert_eq!(s.euler_characteristic, 2);
    /// assert!(s.is_closed());
    /// ```
    pub fn summary(&self) -> MeshSummary {
        analyse(self).summary
    }
}

pub(crate) fn analyse(mesh: &Mesh) -> Analysis {
    let n = mesh.vertices.len();
    let faces = &mesh.faces;

    // Areas and degenerate faces.
    let mut surface_area = 0.0;
    let mut n_zero_area_faces = 0;
    let mut first_zero_area = None;
    for (i, f) in faces.iter().enumerate() {
        let (a, b, c) = (mesh.vertices[f[0]], mesh.vertices[f[1]], mesh.vertices[f[2]]);
        surface_area += super::triangle_area(a, b, c);
        if is_zero_area(a, b, c) {
            n_zero_area_faces += 1;
            first_zero_area.get_or_insert(i);
        }
    }

    // Duplicate faces: same sorted vertex triple.
    let mut sorted_faces: Vec<([usize; 3], usize)> = faces
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let mut s = *f;
            s.sort_unstable();
            (s, i)
        })
        .collect();
    sorted_faces.sort_unstable();
    let mut n_duplicate_faces = 0;
    let mut first_duplicate: Option<usize> = None;
    for w in sorted_faces.windows(2) {
        if w[0].0 == w[1].0 {
            n_duplicate_faces += 1;
            first_duplicate = Some(first_duplicate.map_or(w[1].1, |d| d.min(w[1].1)));
        }
    }
    drop(sorted_faces);

    // Edges with their face counts.
    let mut edges: Vec<(usize, usize)> = Vec::with_capacity(3 * faces.len());
    for f in faces {
        for k in 0..3 {
            let (a, b) = (f[k], f[(k + 1) % 3]);
            edges.push((a.min(b), a.max(b)));
        }
    }
    edges.sort_unstable();
    let mut n_edges = 0;
    let mut n_non_manifold_edges = 0;
    let mut boundary: Vec<(usize, usize)> = Vec::new();
    let mut i = 0;
    while i < edges.len() {
        let mut j = i + 1;
        while j < edges.len() && edges[j] == edges[i] {
            j += 1;
        }
        n_edges += 1;
        match j - i {
            1 => boundary.push(edges[i]),
            2 => {}
            _ => n_non_manifold_edges += 1,
        }
        i = j;
    }
    drop(edges);
    let n_boundary_loops = count_loops(n, &boundary);

    // Components by union-find over face vertices.
    let mut uf = UnionFind::new(n);
    let mut referenced = vec![false; n];
    for f in faces {
        uf.union(f[0], f[1]);
        uf.union(f[0], f[2]);
        for &v in f {
            referenced[v] = true;
        }
    }
    let mut comp_of_root = vec![usize::MAX; n];
    let mut components: Vec<ComponentSize> = Vec::new();
    for f in faces {
        let r = uf.find(f[0]);
        if comp_of_root[r] == usize::MAX {
            comp_of_root[r] = components.len();
            components.push(ComponentSize { faces: 0, vertices: 0 });
        }
        components[comp_of_root[r]].faces += 1;
    }
    let mut n_unreferenced_vertices = 0;
    let mut first_unreferenced = None;
    for (v, &is_ref) in referenced.iter().enumerate() {
        if is_ref {
            let r = uf.find(v);
            components[comp_of_root[r]].vertices += 1;
        } else {
            n_unreferenced_vertices += 1;
            first_unreferenced.get_or_insert(v);
        }
    }
    components.sort_by(|a, b| b.faces.cmp(&a.faces).then(b.vertices.cmp(&a.vertices)));

    let n_referenced = (n - n_unreferenced_vertices) as i64;
    let summary = MeshSummary {
        n_vertices: n,
        n_faces: faces.len(),
        n_edges,
        surface_area,
        bounding_box: mesh.bounding_box(),
        components,
        n_boundary_edges: boundary.len(),
        n_boundary_loops,
        n_non_manifold_edges,
        n_unreferenced_vertices,
        n_zero_area_faces,
        n_duplicate_faces,
        euler_characteristic: n_referenced - n_edges as i64 + faces.len() as i64,
    };
    Analysis { summary, first_zero_area, first_duplicate, first_unreferenced }
}

/// Decomposes the boundary-edge graph into simple closed loops and counts them. A vertex where
/// two holes touch (four boundary edges) splits them into two loops. Open chains, which only
/// arise around non-manifold configurations, are not counted.
fn count_loops(n_vertices: usize, boundary: &[(usize, usize)]) -> usize {
    if boundary.is_empty() {
        return 0;
    }
    // CSR incidence: vertex -> boundary edge ids.
    let mut start = vec![0usize; n_vertices + 1];
    for &(a, b) in boundary {
        start[a + 1] += 1;
        start[b + 1] += 1;
    }
    for v in 0..n_vertices {
        start[v + 1] += start[v];
    }
    let mut fill = start.clone();
    let mut incident = vec![0usize; 2 * boundary.len()];
    for (e, &(a, b)) in boundary.iter().enumerate() {
        incident[fill[a]] = e;
        fill[a] += 1;
        incident[fill[b]] = e;
        fill[b] += 1;
    }
    let mut next_slot = start[..n_vertices].to_vec();
    let mut used = vec![false; boundary.len()];
    let mut pos_in_path = vec![usize::MAX; n_vertices];
    let mut path: Vec<usize> = Vec::new();
    let mut loops = 0;

    for e0 in 0..boundary.len() {
        if used[e0] {
            continue;
        }
        used[e0] = true;
        let (a, b) = boundary[e0];
        path.clear();
        path.extend([a, b]);
        pos_in_path[a] = 0;
        pos_in_path[b] = 1;
        while let Some(&cur) = path.last() {
            // Next unused boundary edge at `cur`.
            let mut found = None;
            while next_slot[cur] < start[cur + 1] {
                let e = incident[next_slot[cur]];
                next_slot[cur] += 1;
                if !used[e] {
                    found = Some(e);
                    break;
                }
            }
            let Some(e) = found else { break };
            used[e] = true;
            let (x, y) = boundary[e];
            let other = if x == cur { y } else { x };
            let p = pos_in_path[other];
            if p != usize::MAX {
                loops += 1;
                for &v in &path[p + 1..] {
                    pos_in_path[v] = usize::MAX;
                }
                path.truncate(p + 1);
                if path.len() == 1 {
                    break;
                }
            } else {
                pos_in_path[other] = path.len();
                path.push(other);
            }
        }
        for &v in &path {
            pos_in_path[v] = usize::MAX;
        }
    }
    loops
}

impl fmt::Display for MeshSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (lo, hi) = self.bounding_box;
        writeln!(
            f,
            "vertices             {} ({} unreferenced)",
            self.n_vertices, self.n_unreferenced_vertices
        )?;
        writeln!(
            f,
            "faces                {} ({} zero-area, {} duplicate)",
            self.n_faces, self.n_zero_area_faces, self.n_duplicate_faces
        )?;
        writeln!(
            f,
            "edges                {} ({} boundary, {} non-manifold)",
            self.n_edges, self.n_boundary_edges, self.n_non_manifold_edges
        )?;
        writeln!(f, "surface area         {:.6e}", self.surface_area)?;
        writeln!(
            f,
            "bounding box         [{:.4e}, {:.4e}, {:.4e}] .. [{:.4e}, {:.4e}, {:.4e}]",
            lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]
        )?;
        write!(f, "components           {}", self.components.len())?;
        if self.components.len() > 1 {
            let shown: Vec<String> = self.components.iter().take(5).map(|c| c.faces.to_string()).collect();
            let more = if self.components.len() > 5 { ", …" } else { "" };
            write!(f, " (faces: {}{more})", shown.join(", "))?;
        }
        writeln!(f)?;
        writeln!(f, "boundary loops       {}", self.n_boundary_loops)?;
        write!(f, "Euler characteristic {}", self.euler_characteristic)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::{grid_plane, icosphere, torus};

    #[test]
    fn closed_surfaces_have_the_right_euler_characteristic() {
        let s = icosphere(1, 1.0).summary();
        assert_eq!((s.euler_characteristic, s.n_boundary_loops, s.n_components()), (2, 0, 1));
        let t = torus(16, 8, 2.0, 0.5).summary();
        assert_eq!((t.euler_characteristic, t.n_boundary_loops), (0, 0));
        assert!(t.is_closed());
    }

    #[test]
    fn a_plane_has_one_boundary_loop_and_disc_topology() {
        let s = grid_plane(5, 4, 1.0, 1.0).summary();
        assert_eq!(s.n_boundary_loops, 1);
        assert_eq!(s.euler_characteristic, 1);
        assert!((s.surface_area - 1.0).abs() < 1e-12);
    }

    #[test]
    fn two_squares_touching_at_a_corner_have_two_loops_and_one_component() {
        // Two unit squares sharing only vertex 2: a bow-tie with two holes' worth of boundary.
        let v = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
            [2.0, 1.0, 0.0],
            [2.0, 2.0, 0.0],
            [1.0, 2.0, 0.0],
        ];
        let f = vec![[0, 1, 2], [0, 2, 3], [2, 4, 5], [2, 5, 6]];
        let s = Mesh::new(v, f).unwrap().summary();
        assert_eq!(s.n_components(), 1);
        assert_eq!(s.n_boundary_loops, 2);
        assert_eq!(s.n_boundary_edges, 8);
    }

    #[test]
    fn defects_are_counted() {
        // A fan of three triangles on edge (0,1) (non-manifold), a duplicate face,
        // a degenerate face and an unreferenced vertex.
        let v = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0, 0.0, 1.0],
            [2.0, 0.0, 0.0],
            [9.0, 9.0, 9.0],
        ];
        let f = vec![[0, 1, 2], [1, 0, 3], [0, 1, 4], [2, 1, 0], [0, 1, 5]];
        let s = Mesh::new(v, f).unwrap().summary();
        assert_eq!(s.n_unreferenced_vertices, 1);
        assert_eq!(s.n_duplicate_faces, 1);
        assert_eq!(s.n_zero_area_faces, 1);
        assert_eq!(s.n_non_manifold_edges, 1);
        assert_eq!(s.components, vec![ComponentSize { faces: 5, vertices: 6 }]);
    }

    #[test]
    fn components_are_sorted_largest_first() {
        let a = icosphere(0, 1.0);
        let b = icosphere(1, 1.0);
        let offset = a.vertices.len();
        let mut v = a.vertices.clone();
        v.extend(b.vertices.iter().map(|p| [p[0] + 5.0, p[1], p[2]]));
        let mut f = a.faces.clone();
        f.extend(b.faces.iter().map(|t| [t[0] + offset, t[1] + offset, t[2] + offset]));
        let s = Mesh::new(v, f).unwrap().summary();
        assert_eq!(s.n_components(), 2);
        assert_eq!(s.components[0], ComponentSize { faces: 80, vertices: 42 });
        assert_eq!(s.components[1], ComponentSize { faces: 20, vertices: 12 });
        assert_eq!(s.euler_characteristic, 4);
        let text = s.to_string();
        assert!(text.contains("components           2 (faces: 80, 20)"), "{text}");
    }
}
