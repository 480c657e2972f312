//! Reference distances: Dijkstra on the edge graph and first-order fast marching on the
//! triangles.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use crate::mesh::{dot, norm, sub, Mesh};

use super::topology::{check_sources, EdgeGraph};
use super::GeodesicError;

/// A heap entry ordered by smallest distance first (ties by vertex, for determinism).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Entry {
    dist: f64,
    vertex: usize,
}

impl Eq for Entry {}

impl Ord for Entry {
    fn cmp(&self, other: &Self) -> Ordering {
        other.dist.total_cmp(&self.dist).then_with(|| other.vertex.cmp(&self.vertex))
    }
}

impl PartialOrd for Entry {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// Shortest-path distance along mesh edges from the nearest of `sources` to every vertex
/// (`f64::INFINITY` where no path exists).
///
/// This is an upper bound of the geodesic distance: paths are restricted to edges, so on a
/// regular grid the error grows with the angle to the grid axes (up to ~8 % on a grid with
/// diagonals) and does not shrink under refinement.
///
/// ```
/// use shapeforest::{geodesic::dijkstra_distances, mesh::Mesh};
/// let m = Mesh::new(vec![[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [3.0, 4.0, 0.0]], vec![[0, 1, 2]]).unwrap();
/// let d = dijkstra_distances(&m, &[0]).unwrap();
/// assert_eq!(d, vec![0.0, 3.0, 5.0]);
/// ```
pub fn dijkstra_distances(mesh: &Mesh, sources: &[usize]) -> Result<Vec<f64>, GeodesicError> {
    check_sources(sources, mesh.n_vertices())?;
    let graph = EdgeGraph::new(mesh);
    let mut dist = vec![f64::INFINITY; mesh.n_vertices()];
    let mut heap = BinaryHeap::new();
    for &s in sources {
        dist[s] = 0.0;
        heap.push(Entry { dist: 0.0, vertex: s });
    }
    dijkstra_relax(&graph, &mut dist, &mut heap, None);
    Ok(dist)
}

/// Multi-source Dijkstra along mesh edges that also says which source is nearest: returns
/// `(dist, nearest)` with `nearest[v]` the index into `sources` of the source closest to `v`
/// (`usize::MAX` where no source is reachable, with `dist[v] = ∞`). Ties go to the earlier
/// vertex popped, so the result is deterministic.
///
/// ```
/// use shapeforest::{geodesic::dijkstra_nearest_source, mesh::Mesh};
/// let m = Mesh::new(vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [5.0, 0.0, 0.0]], vec![[0, 1, 2]]).unwrap();
/// let (d, near) = dijkstra_nearest_source(&m, &[0, 2]).unwrap();
/// assert_eq!(near, vec![0, 0, 1]);
/// assert_eq!(d[1], 1.0);
/// ```
pub fn dijkstra_nearest_source(
    mesh: &Mesh,
    sources: &[usize],
) -> Result<(Vec<f64>, Vec<usize>), GeodesicError> {
    check_sources(sources, mesh.n_vertices())?;
    let graph = EdgeGraph::new(mesh);
    let n = mesh.n_vertices();
    let mut dist = vec![f64::INFINITY; n];
    let mut nearest = vec![usize::MAX; n];
    let mut heap = BinaryHeap::new();
    for (i, &s) in sources.iter().enumerate() {
        if dist[s] > 0.0 {
            dist[s] = 0.0;
            nearest[s] = i;
            heap.push(Entry { dist: 0.0, vertex: s });
        }
    }
    dijkstra_relax(&graph, &mut dist, &mut heap, Some(&mut nearest));
    Ok((dist, nearest))
}

/// Runs Dijkstra from the entries in `heap`, lowering `dist` wherever a shorter path is found.
/// With `dist` holding an existing field and the heap one new source at 0, this is the
/// incremental min-update used by farthest point sampling: it only visits vertices that
/// become closer to the new source.
/// With `nearest`, a vertex reached through `v` also takes `nearest[v]` (the nearest source).
fn dijkstra_relax(
    graph: &EdgeGraph,
    dist: &mut [f64],
    heap: &mut BinaryHeap<Entry>,
    mut nearest: Option<&mut [usize]>,
) {
    while let Some(Entry { dist: d, vertex: v }) = heap.pop() {
        if d > dist[v] {
            continue;
        }
        for k in graph.offsets[v]..graph.offsets[v + 1] {
            let w = graph.targets[k];
            let nd = d + graph.lengths[k];
            if nd < dist[w] {
                dist[w] = nd;
                if let Some(n) = nearest.as_deref_mut() {
                    n[w] = n[v];
                }
                heap.push(Entry { dist: nd, vertex: w });
            }
        }
    }
}

/// Lowers `dist` by Dijkstra from a new source vertex (see [`dijkstra_relax`]).
pub(crate) fn dijkstra_min_update(graph: &EdgeGraph, dist: &mut [f64], source: usize) {
    dist[source] = 0.0;
    let mut heap = BinaryHeap::new();
    heap.push(Entry { dist: 0.0, vertex: source });
    dijkstra_relax(graph, dist, &mut heap, None);
}

/// First-order fast marching with its per-mesh precomputation cached (incident faces of every
/// vertex, the unfolded vertex of every obtuse corner): build once, query many sources. See
/// [`fast_marching_distances`] for the method.
///
/// ```
/// use shapeforest::geodesic::FastMarchingSolver;
/// let grid = shapeforest::synth::grid_plane(11, 11, 1.0, 1.0);
/// let solver = FastMarchingSolver::new(&grid);
/// let d = solver.distances_from(&[0]).unwrap();
/// assert!((d[120] - 2f64.sqrt()).abs() < 1e-9);
/// ```
pub struct FastMarchingSolver<'a> {
    mesh: &'a Mesh,
    offsets: Vec<usize>,
    faces: Vec<usize>,
    /// For each obtuse corner `3·face + corner`: the vertex found by unfolding the triangles
    /// beyond the opposite edge into the corner's plane, and its unfolded position.
    virtual_vertex: Vec<Option<(usize, [f64; 3])>>,
    /// Corners (`3·face + corner`) for which each vertex is the virtual vertex (CSR).
    virtual_offsets: Vec<usize>,
    virtual_corners: Vec<usize>,
}

/// The face across each face edge: entry `3·f + c` is the face sharing edge
/// `(f[c], f[c + 1])` with `f`, or `usize::MAX` on the boundary (on non-manifold edges, the
/// faces are paired arbitrarily but deterministically).
fn face_neighbours(mesh: &Mesh) -> Vec<usize> {
    let mut half: Vec<(usize, usize, usize)> = Vec::with_capacity(mesh.n_faces() * 3);
    for (fi, f) in mesh.faces.iter().enumerate() {
        for c in 0..3 {
            let (a, b) = (f[c], f[(c + 1) % 3]);
            half.push((a.min(b), a.max(b), 3 * fi + c));
        }
    }
    half.sort_unstable();
    let mut out = vec![usize::MAX; mesh.n_faces() * 3];
    for w in half.chunk_by(|x, y| x.0 == y.0 && x.1 == y.1) {
        for pair in w.chunks(2) {
            if let [x, y] = pair {
                out[x.2] = y.2 / 3;
                out[y.2] = x.2 / 3;
            }
        }
    }
    out
}

/// Unfolding steps tried per obtuse corner before giving up (then edge updates are used).
const MAX_UNFOLD_STEPS: usize = 12;

/// Splits an obtuse corner the Kimmel–Sethian way: unfolds the strip of triangles beyond the
/// opposite edge into the corner's plane until a vertex falls strictly inside the corner's
/// angular sector. Returns that vertex and its unfolded 3D position (in the corner's plane).
fn unfold_obtuse_corner(
    mesh: &Mesh,
    neighbours: &[usize],
    face: usize,
    corner: usize,
) -> Option<(usize, [f64; 3])> {
    let f = mesh.faces[face];
    let (ci, ai, bi) = (f[corner], f[(corner + 1) % 3], f[(corner + 2) % 3]);
    let pc = mesh.vertices[ci];
    let ca = sub(mesh.vertices[ai], pc);
    let cb = sub(mesh.vertices[bi], pc);
    if dot(ca, cb) >= 0.0 {
        return None; // not obtuse
    }
    // 2D frame at c: e1 along ca, e2 in the face plane
    let la = norm(ca);
    let e1 = [ca[0] / la, ca[1] / la, ca[2] / la];
    let x = dot(cb, e1);
    let perp = [cb[0] - x * e1[0], cb[1] - x * e1[1], cb[2] - x * e1[2]];
    let lp = norm(perp);
    if !(lp > 0.0 && la > 0.0) {
        return None;
    }
    let e2 = [perp[0] / lp, perp[1] / lp, perp[2] / lp];
    let a2 = [la, 0.0];
    let b2 = [x, lp];
    let cross2 = |u: [f64; 2], v: [f64; 2]| u[0] * v[1] - u[1] * v[0];
    // the strip: current edge (p, q) with unfolded positions, and the face we came from
    let (mut p, mut p2, mut q, mut q2, mut from) = (ai, a2, bi, b2, face);
    for _ in 0..MAX_UNFOLD_STEPS {
        let ff = mesh.faces[from];
        let local = (0..3).find(|&c| {
            let (a, b) = (ff[c], ff[(c + 1) % 3]);
            (a == p && b == q) || (a == q && b == p)
        })?;
        let next = neighbours[3 * from + local];
        if next == usize::MAX {
            return None; // boundary edge
        }
        let nf = mesh.faces[next];
        let r = *nf.iter().find(|&&v| v != p && v != q)?;
        // unfold r across (p, q), onto the side away from c (the origin)
        let lpr = norm(sub(mesh.vertices[r], mesh.vertices[p]));
        let lqr = norm(sub(mesh.vertices[r], mesh.vertices[q]));
        let pq = [q2[0] - p2[0], q2[1] - p2[1]];
        let d = (pq[0] * pq[0] + pq[1] * pq[1]).sqrt();
        if !(d > 0.0) {
            return None;
        }
        let ex = [pq[0] / d, pq[1] / d];
        let mut ey = [-ex[1], ex[0]];
        if ey[0] * (-p2[0]) + ey[1] * (-p2[1]) > 0.0 {
            ey = [-ey[0], -ey[1]];
        }
        let rx = (lpr * lpr - lqr * lqr + d * d) / (2.0 * d);
        let ry = (lpr * lpr - rx * rx).max(0.0).sqrt();
        let r2 = [p2[0] + rx * ex[0] + ry * ey[0], p2[1] + rx * ex[1] + ry * ey[1]];
        let side_a = cross2(a2, r2); // > 0: r is past a towards b
        let side_b = cross2(r2, b2); // > 0: r is before b
        if side_a > 0.0 && side_b > 0.0 {
            let pos = [
                pc[0] + r2[0] * e1[0] + r2[1] * e2[0],
                pc[1] + r2[0] * e1[1] + r2[1] * e2[1],
                pc[2] + r2[0] * e1[2] + r2[1] * e2[2],
            ];
            return Some((r, pos));
        }
        // continue through the edge of the new triangle that the sector crosses
        if side_a <= 0.0 {
            // r lies outside, beyond a: the sector crosses edge (r, q)
            (p, p2) = (r, r2);
        } else {
            (q, q2) = (r, r2);
        }
        from = next;
    }
    None
}

impl<'a> FastMarchingSolver<'a> {
    /// Precomputes the adjacency and the obtuse-corner unfoldings of `mesh`.
    pub fn new(mesh: &'a Mesh) -> Self {
        let n = mesh.n_vertices();
        let mut offsets = vec![0usize; n + 1];
        for f in &mesh.faces {
            for &v in f {
                offsets[v + 1] += 1;
            }
        }
        for v in 0..n {
            offsets[v + 1] += offsets[v];
        }
        let mut fill = offsets.clone();
        let mut faces = vec![0usize; offsets[n]];
        for (fi, f) in mesh.faces.iter().enumerate() {
            for &v in f {
                faces[fill[v]] = fi;
                fill[v] += 1;
            }
        }
        let neighbours = face_neighbours(mesh);
        let virtual_vertex: Vec<Option<(usize, [f64; 3])>> =
            (0..mesh.n_faces() * 3).map(|k| unfold_obtuse_corner(mesh, &neighbours, k / 3, k % 3)).collect();
        let mut virtual_offsets = vec![0usize; n + 1];
        for (d, _) in virtual_vertex.iter().flatten() {
            virtual_offsets[d + 1] += 1;
        }
        for v in 0..n {
            virtual_offsets[v + 1] += virtual_offsets[v];
        }
        let mut fill = virtual_offsets.clone();
        let mut virtual_corners = vec![0usize; virtual_offsets[n]];
        for (k, vv) in virtual_vertex.iter().enumerate() {
            if let Some((d, _)) = vv {
                virtual_corners[fill[*d]] = k;
                fill[*d] += 1;
            }
        }
        Self { mesh, offsets, faces, virtual_vertex, virtual_offsets, virtual_corners }
    }

    /// Lowers `dist[c]` (pushing it on the heap) if `t` improves it.
    #[inline]
    fn offer(dist: &mut [f64], heap: &mut BinaryHeap<Entry>, c: usize, t: f64) {
        if t < dist[c] {
            dist[c] = t;
            heap.push(Entry { dist: t, vertex: c });
        }
    }

    /// Distance from the nearest of `sources` to every vertex (`f64::INFINITY` where the surface
    /// does not connect).
    pub fn distances_from(&self, sources: &[usize]) -> Result<Vec<f64>, GeodesicError> {
        check_sources(sources, self.mesh.n_vertices())?;
        Ok(self.run(sources))
    }

    /// Distances from the nearest source (sources already validated).
    pub(crate) fn run(&self, sources: &[usize]) -> Vec<f64> {
        let n = self.mesh.n_vertices();
        let p = &self.mesh.vertices;
        let mut dist = vec![f64::INFINITY; n];
        let mut accepted = vec![false; n];
        let mut heap = BinaryHeap::new();
        for &s in sources {
            dist[s] = 0.0;
            heap.push(Entry { dist: 0.0, vertex: s });
        }
        while let Some(Entry { dist: d, vertex: v }) = heap.pop() {
            if accepted[v] || d > dist[v] {
                continue;
            }
            accepted[v] = true;
            for &fi in &self.faces[self.offsets[v]..self.offsets[v + 1]] {
                let f = self.mesh.faces[fi];
                let k = f.iter().position(|&x| x == v).unwrap_or(0);
                let (a, b) = (f[(k + 1) % 3], f[(k + 2) % 3]);
                for (c, other) in [(a, b), (b, a)] {
                    if accepted[c] {
                        continue;
                    }
                    let mut best = d + norm(sub(p[c], p[v]));
                    if accepted[other] {
                        if let Some(t) = triangle_update(p[v], d, p[other], dist[other], p[c]) {
                            best = best.min(t);
                        }
                    }
                    // obtuse corner at c: the virtual triangle (c, v, unfolded vertex)
                    let corner = f.iter().position(|&x| x == c).unwrap_or(0);
                    if let Some((w, pw)) = self.virtual_vertex[3 * fi + corner] {
                        if accepted[w] {
                            if let Some(t) = triangle_update(p[v], d, pw, dist[w], p[c]) {
                                best = best.min(t);
                            }
                        }
                    }
                    Self::offer(&mut dist, &mut heap, c, best);
                }
            }
            // v as the unfolded vertex of obtuse corners elsewhere
            for &k in &self.virtual_corners[self.virtual_offsets[v]..self.virtual_offsets[v + 1]] {
                let f = self.mesh.faces[k / 3];
                let c = f[k % 3];
                let Some((_, pv)) = self.virtual_vertex[k] else { continue };
                if accepted[c] {
                    continue;
                }
                for x in [f[(k % 3 + 1) % 3], f[(k % 3 + 2) % 3]] {
                    if accepted[x] {
                        if let Some(t) = triangle_update(p[x], dist[x], pv, d, p[c]) {
                            Self::offer(&mut dist, &mut heap, c, t);
                        }
                    }
                }
            }
        }
        dist
    }
}

/// First-order fast-marching geodesic distance from the nearest of `sources` to every vertex
/// (`f64::INFINITY` where the surface does not connect).
///
/// Vertices are accepted in increasing distance (as in Dijkstra); a vertex `c` of a triangle
/// whose other two vertices `a`, `b` are accepted is updated from both: the triangle is laid
/// in the plane, the virtual point source at distances `(T_a, T_b)` from `a` and `b` is
/// reconstructed on the far side of edge `ab`, and `T_c = |c − source|` is accepted when the
/// straight ray from that source to `c` crosses the edge `ab` (the update is causal) and
/// `T_c ≥ max(T_a, T_b)`. Otherwise the edge updates `T_a + |ac|`, `T_b + |bc|` are used, as
/// in Dijkstra. For a point source in a flat region this update is exact, so the error comes
/// from curvature and from the remaining fallbacks. Obtuse corners are split as in
/// Kimmel–Sethian: the triangles beyond the opposite edge are unfolded into the corner's plane
/// until a vertex falls inside the corner's sector (at most 12 steps), and that vertex forms
/// two virtual acute triangles with the corner's edges.
///
/// ```
/// use shapeforest::geodesic::fast_marching_distances;
/// let grid = shapeforest::synth::grid_plane(21, 21, 1.0, 1.0);
/// let d = fast_marching_distances(&grid, &[0]).unwrap();
/// // the far corner is at Euclidean distance √2 in the plane
/// assert!((d[21 * 21 - 1] - 2f64.sqrt()).abs() < 1e-9);
/// ```
pub fn fast_marching_distances(mesh: &Mesh, sources: &[usize]) -> Result<Vec<f64>, GeodesicError> {
    check_sources(sources, mesh.n_vertices())?;
    Ok(FastMarchingSolver::new(mesh).run(sources))
}

/// The two-neighbour update described in [`fast_marching_distances`]: `None` when the
/// virtual source does not exist or its ray to `pc` misses the edge `pa pb`.
fn triangle_update(pa: [f64; 3], ta: f64, pb: [f64; 3], tb: f64, pc: [f64; 3]) -> Option<f64> {
    let ab = sub(pb, pa);
    let c = norm(ab);
    if !(c > 0.0) {
        return None;
    }
    let ex = [ab[0] / c, ab[1] / c, ab[2] / c];
    let ac = sub(pc, pa);
    let cx = dot(ac, ex);
    let cy = (dot(ac, ac) - cx * cx).max(0.0).sqrt();
    if !(cy > 1e-12 * c) {
        return None;
    }
    let sx = (ta * ta - tb * tb + c * c) / (2.0 * c);
    let sy2 = ta * ta - sx * sx;
    if !(sy2 >= 0.0) {
        return None;
    }
    let sy = -sy2.sqrt();
    // where the ray from the virtual source to c crosses the line through a and b
    let cross_x = sx + (cx - sx) * (-sy) / (cy - sy);
    if !(cross_x >= 0.0 && cross_x <= c) {
        return None;
    }
    let t = ((cx - sx).powi(2) + (cy - sy).powi(2)).sqrt();
    if t >= ta.max(tb) {
        Some(t)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn triangle_update_recovers_planar_point_source() {
        let src = [0.3, -2.0, 0.0];
        let (pa, pb, pc) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.4, 0.9, 0.0]);
        let d = |p: [f64; 3]| norm(sub(p, src));
        let t = triangle_update(pa, d(pa), pb, d(pb), pc).unwrap();
        assert!((t - d(pc)).abs() < 1e-12);
    }

    #[test]
    fn triangle_update_rejects_non_causal() {
        // source far to the left: the ray to c does not cross ab
        let src = [-5.0, -0.1, 0.0];
        let (pa, pb, pc) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [-0.5, 1.0, 0.0]);
        let d = |p: [f64; 3]| norm(sub(p, src));
        assert!(triangle_update(pa, d(pa), pb, d(pb), pc).is_none());
    }

    #[test]
    fn empty_and_out_of_range_sources_are_errors() {
        let m = crate::synth::grid_plane(3, 3, 1.0, 1.0);
        assert!(matches!(dijkstra_distances(&m, &[]), Err(GeodesicError::NoSources)));
        assert!(matches!(
            fast_marching_distances(&m, &[9]),
            Err(GeodesicError::SourceOutOfRange { vertex: 9, n_vertices: 9 })
        ));
    }
}
