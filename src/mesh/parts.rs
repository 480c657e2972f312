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
    // The boundary edges in a fixed order (the set's own order changes from one set to the
    // next), so that where several loops meet at a vertex they are traced the same way every time.
    let mut boundary: Vec<(usize, usize)> =
        directed.iter().copied().filter(|&(a, b)| !directed.contains(&(b, a))).collect();
    boundary.sort_unstable();
    let mut next: HashMap<usize, Vec<usize>> = HashMap::new();
    for (a, b) in boundary {
        next.entry(a).or_default().push(b);
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
/// `max_perimeter` is covered by a patch of rings that shrink towards its centroid, spaced about
/// one boundary edge apart (a hole a few edges wide gets a plain centroid fan), then relaxed
/// towards a membrane with the boundary held; the patch is oriented like the surrounding faces.
/// Well-shaped patch triangles keep the cotangent weights and the lumped mass of the patch
/// like the rest of the surface's (a fan over a wide hole is a spray of slivers whose centre
/// carries the whole hole's mass). The input's vertices keep their indices; the added ones
/// follow them. Returns the filled mesh and the number of loops closed.
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
        let points: Vec<[f64; 3]> = chain.iter().map(|&v| mesh.vertices[v]).collect();
        let perimeter: f64 = (0..points.len()).map(|i| dist(points[i], points[(i + 1) % points.len()])).sum();
        if perimeter > max_perimeter {
            continue;
        }
        fill_loop(&chain, &points, perimeter, &mut vertices, &mut faces);
        closed += 1;
    }
    match Mesh::new(vertices, faces) {
        Ok(m) => (m, closed),
        Err(_) => (mesh.clone(), 0),
    }
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Appends the patch of one boundary loop (`chain`, at `points`) to `vertices` / `faces`.
fn fill_loop(
    chain: &[usize],
    points: &[[f64; 3]],
    perimeter: f64,
    vertices: &mut Vec<[f64; 3]>,
    faces: &mut Vec<[usize; 3]>,
) {
    let n = chain.len();
    let mut centre = [0.0; 3];
    for p in points {
        for (c, x) in centre.iter_mut().zip(p) {
            *c += x / n as f64;
        }
    }
    let edge = perimeter / n as f64;
    let radius = points.iter().map(|&p| dist(p, centre)).sum::<f64>() / n as f64;
    let rings = ((radius / edge).floor() as usize).saturating_sub(1).min(64);
    // Arc-length parameter of each loop vertex, for placing the rings' vertices.
    let mut arc = Vec::with_capacity(n + 1);
    arc.push(0.0);
    for i in 0..n {
        arc.push(arc[i] + dist(points[i], points[(i + 1) % n]) / perimeter.max(f64::MIN_POSITIVE));
    }
    let on_loop = |u: f64| -> [f64; 3] {
        let i = arc.partition_point(|&a| a <= u).saturating_sub(1).min(n - 1);
        let span = (arc[i + 1] - arc[i]).max(f64::MIN_POSITIVE);
        let t = ((u - arc[i]) / span).clamp(0.0, 1.0);
        let (a, b) = (points[i], points[(i + 1) % n]);
        [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), a[2] + t * (b[2] - a[2])]
    };
    let first_new = vertices.len();
    // The outer ring is the loop itself; each inner ring has fewer vertices, in proportion.
    let mut outer: Vec<usize> = chain.to_vec();
    let mut outer_u: Vec<f64> = arc[..n].to_vec();
    for r in 1..=rings {
        let t = r as f64 / (rings + 1) as f64;
        let count = ((n as f64 * (1.0 - t)).round() as usize).max(3);
        let inner: Vec<usize> = (vertices.len()..vertices.len() + count).collect();
        let inner_u: Vec<f64> = (0..count).map(|j| j as f64 / count as f64).collect();
        for &u in &inner_u {
            let q = on_loop(u);
            vertices.push([
                q[0] + t * (centre[0] - q[0]),
                q[1] + t * (centre[1] - q[1]),
                q[2] + t * (centre[2] - q[2]),
            ]);
        }
        zip_rings(&outer, &outer_u, &inner, &inner_u, faces);
        outer = inner;
        outer_u = inner_u;
    }
    let c = vertices.len();
    vertices.push(centre);
    let m = outer.len();
    for i in 0..m {
        faces.push([outer[(i + 1) % m], outer[i], c]);
    }
    relax(first_new, vertices, &faces[faces.len() - patch_faces(n, rings)..]);
}

/// Triangles of a patch over a loop of `n` vertices with `rings` inner rings.
fn patch_faces(n: usize, rings: usize) -> usize {
    let mut total = 0;
    let mut outer = n;
    for r in 1..=rings {
        let t = r as f64 / (rings + 1) as f64;
        let count = ((n as f64 * (1.0 - t)).round() as usize).max(3);
        total += outer + count;
        outer = count;
    }
    total + outer
}

/// Triangulates the band between ring `outer` (oriented like the loop: the surface lies to the
/// left of `outer[i] → outer[i+1]`) and the smaller ring `inner`, by advancing along whichever
/// ring's next parameter comes first.
fn zip_rings(
    outer: &[usize],
    outer_u: &[f64],
    inner: &[usize],
    inner_u: &[f64],
    faces: &mut Vec<[usize; 3]>,
) {
    let (m, k) = (outer.len(), inner.len());
    let next = |u: &[f64], i: usize| if i + 1 < u.len() { u[i + 1] } else { 1.0 };
    let (mut i, mut j) = (0, 0);
    while i < m || j < k {
        let advance_outer = j == k || (i < m && next(outer_u, i) <= next(inner_u, j));
        if advance_outer {
            faces.push([outer[(i + 1) % m], outer[i], inner[j % k]]);
            i += 1;
        } else {
            faces.push([outer[i % m], inner[j], inner[(j + 1) % k]]);
            j += 1;
        }
    }
}

/// A few rounds of umbrella smoothing of the patch's own vertices (index ≥ `first_new`), the
/// loop held: the rings relax into a membrane spanning the hole.
fn relax(first_new: usize, vertices: &mut [[f64; 3]], patch: &[[usize; 3]]) {
    let added = vertices.len() - first_new;
    if added <= 1 {
        return;
    }
    for _ in 0..10 {
        let mut sum = vec![[0.0; 3]; added];
        let mut count = vec![0usize; added];
        for f in patch {
            for e in 0..3 {
                let (a, b) = (f[e], f[(e + 1) % 3]);
                for (x, y) in [(a, b), (b, a)] {
                    if x >= first_new {
                        let s = &mut sum[x - first_new];
                        for d in 0..3 {
                            s[d] += vertices[y][d];
                        }
                        count[x - first_new] += 1;
                    }
                }
            }
        }
        for (i, (s, c)) in sum.iter().zip(&count).enumerate() {
            if *c > 0 {
                vertices[first_new + i] = [s[0] / *c as f64, s[1] / *c as f64, s[2] / *c as f64];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::icosphere;

    #[test]
    fn a_wide_hole_gets_a_patch_of_well_shaped_triangles() {
        // A unit sphere without its cap above z = 0.8: one loop of radius ~0.6, ~10 edges wide.
        let sphere = icosphere(4, 1.0);
        let area_of = |m: &Mesh, f: &[usize; 3]| {
            crate::mesh::triangle_area(m.vertices[f[0]], m.vertices[f[1]], m.vertices[f[2]])
        };
        let keep: Vec<bool> = sphere.vertices.iter().map(|p| p[2] < 0.8).collect();
        let open = submesh(&sphere, &keep).unwrap().0;
        let (filled, closed) = fill_holes(&open, 10.0);
        assert_eq!(closed, 1);
        let s = filled.summary();
        assert!(s.is_closed() && s.n_non_manifold_edges == 0, "{s:?}");
        assert_eq!(s.n_vertices as i64 - s.n_edges as i64 + s.n_faces as i64, 2, "a sphere again");
        assert!(filled.n_vertices() > open.n_vertices() + 20, "rings, not a single centre vertex");
        // No sliver fan: the patch's largest triangle is like the surface's.
        let mut areas: Vec<f64> = open.faces.iter().map(|f| area_of(&open, f)).collect();
        areas.sort_by(f64::total_cmp);
        let median = areas[areas.len() / 2];
        let patch = &filled.faces[open.n_faces()..];
        let largest = patch.iter().map(|f| area_of(&filled, f)).fold(0.0, f64::max);
        assert!(largest < 4.0 * median, "patch triangle of area {largest}, surface median {median}");
        // A membrane across the hole: about the area of the flat disc the loop spans.
        let loops = boundary_loops(&open);
        let n = loops[0].len() as f64;
        let c = loops[0].iter().fold([0.0; 3], |c, &v| {
            let p = open.vertices[v];
            [c[0] + p[0] / n, c[1] + p[1] / n, c[2] + p[2] / n]
        });
        let r = loops[0].iter().map(|&v| dist(open.vertices[v], c)).sum::<f64>() / n;
        let patch_area: f64 = patch.iter().map(|f| area_of(&filled, f)).sum();
        let disc = std::f64::consts::PI * r * r;
        assert!((patch_area / disc - 1.0).abs() < 0.1, "patch {patch_area}, disc {disc}");
    }

    #[test]
    fn loops_meeting_at_a_vertex_are_traced_the_same_way_every_time() {
        // A sphere with two caps cut away that touch at one vertex (as a single-view scan's
        // holes often do): the boundary passes that vertex twice, and which outgoing edge is
        // followed first decides the loops. The same mesh must give the same loops (and so the
        // same filled mesh and spectrum) on every call; the hash set's order used to decide it.
        let sphere = icosphere(3, 1.0);
        let pinch = (0..sphere.n_vertices())
            .max_by(|&a, &b| sphere.vertices[a][0].total_cmp(&sphere.vertices[b][0]))
            .unwrap();
        let p = sphere.vertices[pinch];
        let neighbours: Vec<usize> = sphere
            .faces
            .iter()
            .filter(|f| f.contains(&pinch))
            .flat_map(|f| f.iter().copied())
            .filter(|&v| v != pinch)
            .collect();
        // Drop the faces around the pinch vertex above and below it (z), keeping the ones
        // beside it, so two holes share that one vertex.
        let faces: Vec<[usize; 3]> = sphere
            .faces
            .iter()
            .copied()
            .filter(|f| {
                if !f.contains(&pinch) {
                    return true;
                }
                let z = f.iter().map(|&v| sphere.vertices[v][2] - p[2]).sum::<f64>();
                z.abs() < 0.02
            })
            .collect();
        assert!(faces.len() + 2 <= sphere.n_faces() && !neighbours.is_empty());
        let open = Mesh::new(sphere.vertices.clone(), faces).unwrap();
        let first = boundary_loops(&open);
        let through: usize = first.iter().map(|l| l.iter().filter(|&&v| v == pinch).count()).sum();
        assert!(through >= 2, "the boundary passes the pinch vertex {through} times");
        for _ in 0..20 {
            assert_eq!(boundary_loops(&open), first);
            assert_eq!(fill_holes(&open, 10.0).0, fill_holes(&open, 10.0).0);
        }
    }

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
