//! Parts of a mesh: connected components, sub-meshes with their vertex maps, and the extension
//! of a map computed on a part to the whole mesh.
//!
//! A real scan often comes in pieces: a single view breaks a body into one large piece and many
//! small ones (an ear, a strip of the side seen at a grazing angle). The spectral descriptors of
//! a piece of a few hundred vertices carry no usable information, and a spectrum shared by
//! dozens of components spends its eigenpairs on them, so the method is run on the largest
//! component, and the vertices of the other pieces take the match of their nearest vertex
//! (Euclidean) of the matched part.

use rayon::prelude::*;

use super::Mesh;

/// Connected components of the faces: `(label of each vertex, vertex count of each component)`;
/// labels follow the smallest vertex of each component, a vertex used by no face is a component
/// of its own.
pub fn vertex_components(mesh: &Mesh) -> (Vec<usize>, Vec<usize>) {
    let (labels, n_comp) = super::face_connectivity(mesh).labels();
    let mut sizes = vec![0usize; n_comp];
    for &l in &labels {
        sizes[l] += 1;
    }
    (labels, sizes)
}

/// The sub-mesh of the faces whose three vertices are kept, with `kept[new] = old` (vertices in
/// input order; vertices no kept face uses are dropped). `None` when no face is kept.
pub fn submesh(mesh: &Mesh, keep: &[bool]) -> Option<(Mesh, Vec<usize>)> {
    let inside = |f: &[usize; 3]| f.iter().all(|&v| keep[v]);
    // a point-cloud surface keeps its faces' fan multiplicities
    let multiplicity: Vec<u32> = mesh
        .point_cloud_multiplicity()
        .map(|m| mesh.faces.iter().zip(m).filter(|(f, _)| inside(f)).map(|(_, &k)| k).collect())
        .unwrap_or_default();
    let faces: Vec<[usize; 3]> = mesh.faces.iter().filter(|f| inside(f)).copied().collect();
    if faces.is_empty() {
        return None;
    }
    let mut used = vec![false; mesh.n_vertices()];
    for f in &faces {
        for &v in f {
            used[v] = true;
        }
    }
    let kept: Vec<usize> = (0..mesh.n_vertices()).filter(|&v| used[v]).collect();
    let mut index = vec![usize::MAX; mesh.n_vertices()];
    for (new, &old) in kept.iter().enumerate() {
        index[old] = new;
    }
    let vertices = kept.iter().map(|&v| mesh.vertices[v]).collect();
    let faces = faces.iter().map(|f| [index[f[0]], index[f[1]], index[f[2]]]).collect();
    let mut sub = Mesh::new(vertices, faces).ok()?;
    sub.face_multiplicity = multiplicity;
    Some((sub, kept))
}

/// The largest connected component (by vertex count) as a sub-mesh with its vertex map, or
/// `None` when the mesh is connected (one component holds every vertex).
///
/// ```
/// use shapeforest::mesh::{largest_component, Mesh};
/// // Two triangles that share no vertex, the second larger in vertex count with a quad.
/// let m = Mesh::new(
///     vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [5.0, 0.0, 0.0], [6.0, 0.0, 0.0], [5.0, 1.0, 0.0], [6.0, 1.0, 0.0]],
///     vec![[0, 1, 2], [3, 4, 5], [4, 6, 5]],
/// ).unwrap();
/// let (part, kept) = largest_component(&m).unwrap();
/// assert_eq!(kept, vec![3, 4, 5, 6]);
/// assert_eq!(part.n_faces(), 2);
/// ```
pub fn largest_component(mesh: &Mesh) -> Option<(Mesh, Vec<usize>)> {
    let (labels, sizes) = vertex_components(mesh);
    if sizes.len() <= 1 {
        return None;
    }
    let best = (0..sizes.len()).max_by_key(|&c| (sizes[c], usize::MAX - c))?;
    let keep: Vec<bool> = labels.iter().map(|&l| l == best).collect();
    submesh(mesh, &keep)
}

/// Extends a map computed on a part (`part_map[i]` for part vertex `i`, which is vertex
/// `kept[i]` of `full`) to every vertex of `full`: a vertex of the part keeps its match, any
/// other takes the match of the part vertex nearest to it in space.
pub fn extend_map_by_nearest(full: &Mesh, kept: &[usize], part_map: &[usize]) -> Vec<usize> {
    let mut map = vec![usize::MAX; full.n_vertices()];
    for (i, &v) in kept.iter().enumerate() {
        map[v] = part_map[i];
    }
    let part: Vec<[f64; 3]> = kept.iter().map(|&v| full.vertices[v]).collect();
    let missing: Vec<usize> = (0..full.n_vertices()).filter(|&v| map[v] == usize::MAX).collect();
    let nearest: Vec<usize> = missing
        .par_iter()
        .map(|&v| {
            let p = full.vertices[v];
            let mut best = (f64::INFINITY, 0usize);
            for (i, q) in part.iter().enumerate() {
                let d = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2);
                if d < best.0 {
                    best = (d, i);
                }
            }
            part_map.get(best.1).copied().unwrap_or(0)
        })
        .collect();
    for (&v, r) in missing.iter().zip(nearest) {
        map[v] = r;
    }
    map
}

/// The boundary loops of a mesh as closed vertex chains, each following its boundary edges in
/// the direction the faces give them (a face `[a, b, c]` whose edge `a → b` has no face on the
/// other side contributes `a → b`). A vertex where several loops touch is visited once per loop.
pub fn boundary_loops(mesh: &Mesh) -> Vec<Vec<usize>> {
    use std::collections::{HashMap, HashSet};
    let mut directed: HashSet<(usize, usize)> = HashSet::with_capacity(3 * mesh.n_faces());
    for f in &mesh.faces {
        for e in 0..3 {
            directed.insert((f[e], f[(e + 1) % 3]));
        }
    }
    let mut next: HashMap<usize, Vec<usize>> = HashMap::new();
    for &(a, b) in &directed {
        if !directed.contains(&(b, a)) {
            next.entry(a).or_default().push(b);
        }
    }
    let mut starts: Vec<usize> = next.keys().copied().collect();
    starts.sort_unstable();
    let mut loops = Vec::new();
    for start in starts {
        while let Some(b) = next.get_mut(&start).and_then(|v| v.pop()) {
            let mut chain = vec![start];
            let mut at = b;
            while at != start && chain.len() <= mesh.n_vertices() {
                chain.push(at);
                match next.get_mut(&at).and_then(|v| v.pop()) {
                    Some(n) => at = n,
                    None => break,
                }
            }
            if at == start && chain.len() >= 3 {
                loops.push(chain);
            }
        }
    }
    loops
}

/// The mesh with its small holes closed: every boundary loop whose perimeter is at most
/// `max_perimeter` gets a vertex at its centroid and a fan of triangles, oriented like the
/// surrounding faces. The input's vertices keep their indices; the added ones follow them.
/// Returns the filled mesh and the number of loops closed.
///
/// ```
/// use shapeforest::mesh::{fill_holes, Mesh};
/// // A square of two triangles: one boundary loop of perimeter 4.
/// let m = Mesh::new(vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]],
///                   vec![[0, 1, 2], [0, 2, 3]]).unwrap();
/// let (closed, n) = fill_holes(&m, 5.0);
/// assert_eq!((n, closed.n_vertices(), closed.n_faces()), (1, 5, 6));
/// assert!(closed.summary().is_closed());
/// assert_eq!(fill_holes(&m, 3.0).1, 0); // perimeter above the limit: left open
/// ```
pub fn fill_holes(mesh: &Mesh, max_perimeter: f64) -> (Mesh, usize) {
    // A point-cloud surface is a soup whose "holes" are gaps between inconsistent fans; its
    // Laplacian (the tufted cover) is closed already: it is left as it is.
    if mesh.point_cloud_multiplicity().is_some() {
        return (mesh.clone(), 0);
    }
    let mut vertices = mesh.vertices.clone();
    let mut faces = mesh.faces.clone();
    let mut closed = 0;
    for chain in boundary_loops(mesh) {
        let len = chain.len();
        let perimeter: f64 = (0..len)
            .map(|i| {
                let (a, b) = (mesh.vertices[chain[i]], mesh.vertices[chain[(i + 1) % len]]);
                ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
            })
            .sum();
        if perimeter > max_perimeter {
            continue;
        }
        let mut c = [0.0; 3];
        for &v in &chain {
            for (cd, x) in c.iter_mut().zip(mesh.vertices[v]) {
                *cd += x / len as f64;
            }
        }
        let centre = vertices.len();
        vertices.push(c);
        for i in 0..len {
            // Boundary edge a → b belongs to a face on its left; the fill triangle runs b → a.
            let (a, b) = (chain[i], chain[(i + 1) % len]);
            faces.push([b, a, centre]);
        }
        closed += 1;
    }
    match Mesh::new(vertices, faces) {
        Ok(m) => (m, closed),
        Err(_) => (mesh.clone(), 0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::icosphere;

    #[test]
    fn pieces_take_the_match_of_the_nearest_part_vertex() {
        // Two spheres far apart; the part is the first one, mapped to itself.
        let a = icosphere(2, 1.0);
        let n = a.n_vertices();
        let mut vertices = a.vertices.clone();
        vertices.extend(a.vertices.iter().map(|p| [p[0] + 10.0, p[1], p[2]]));
        let mut faces = a.faces.clone();
        faces.extend(a.faces.iter().map(|f| [f[0] + n, f[1] + n, f[2] + n]));
        let both = Mesh::new(vertices, faces).unwrap();
        let (labels, sizes) = vertex_components(&both);
        assert_eq!(sizes, vec![n, n]);
        assert!(labels[..n].iter().all(|&l| l == 0));
        let kept: Vec<usize> = (0..n).collect();
        let part_map: Vec<usize> = (0..n).map(|v| 1000 + v).collect();
        let map = extend_map_by_nearest(&both, &kept, &part_map);
        assert_eq!(&map[..n], &part_map[..]);
        // The far sphere's vertex v is nearest to the first sphere's vertex with the largest x
        // among... at least every far vertex maps into the first sphere's matches.
        assert!(map[n..].iter().all(|&r| (1000..1000 + n).contains(&r)));
    }
}
