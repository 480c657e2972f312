//! Point clouds: a surface for a set of points without faces, from local Delaunay
//! triangulations in the tangent planes.
//!
//! This is the point-cloud construction of Sharp & Crane 2020, "A Laplacian for Nonmanifold
//! Triangle Meshes" (§5, as in their `robust_laplacian` package):
//!
//! 1. the `k` nearest neighbours of every point (a kd-tree, [`kiddo`]);
//! 2. a normal per point, the direction of least variance of its neighbourhood (PCA);
//! 3. the neighbours projected into the tangent plane and the triangles of their 2-D Delaunay
//!    triangulation that touch the point: a fan of triangles around it;
//! 4. the union of all fans, a non-manifold triangle soup that covers the sampled surface about
//!    three times (each triangle is, in the limit of sampling, in the fans of its three corners).
//!
//! [`LocalTriangulation`] holds the fans with their multiplicity (what the paper's Laplacian
//! is built on, see [`crate::spectral::point_cloud_laplacian`]); [`point_cloud_mesh`] turns
//! them into a [`Mesh`] whose faces are the distinct triangles, each once, so that everything
//! that works on a mesh (descriptors, geodesics, sampling, pictures) works on a point cloud.
//! Its spectrum uses the tufted intrinsic-Delaunay Laplacian, as for any non-manifold mesh.
//!
//! Conventions beyond the paper: normals are oriented consistently by propagation over the
//! neighbour graph (Hoppe et al. 1992: a maximum spanning tree of `|nᵢ·nⱼ|`), outward on
//! balance on each connected piece (`Σ nᵢ·(pᵢ − centroid) > 0`), and every triangle is oriented
//! counter-clockwise about the normals of its corners, so orientation-sensitive descriptors see
//! the same handedness as on an outward-oriented mesh. Vertex order is the point order.

use std::collections::{BinaryHeap, HashMap};
use std::num::NonZero;

use faer::{Mat, Side};
use kiddo::immutable::float::kdtree::ImmutableKdTree;
use kiddo::SquaredEuclidean;
use rayon::prelude::*;

use super::{cross, dot, norm, sub, Mesh, MeshError};

/// Default neighbourhood size `k` of the readers, as in `robust_laplacian`.
///
/// Two departures from `robust_laplacian` keep 30 usable on shapes of a few thousand points
/// with thin parts (legs, tails, fingers), where 30 neighbours reach across to the other side
/// of a limb: the normal comes from the nearest `PCA_NEIGHBOURS` (10) only, and neighbours whose
/// oriented normal faces away are left out of the fan. Measured on the 2,000-vertex synthetic
/// creature (held-out pose, forest trained on meshes), within 0.05: 59 % with plain k = 30
/// (λ₁ fell to 0.84 of the mesh's: the fans bridged the legs), 98 % with plain k = 12 (but on
/// 3,000 random points of a sphere k = 12 leaves 14 % excess area and λ 3–7 % high), 99 % with
/// both departures at k = 12, 20 and 30 (sphere: λ within 2 % at k = 30).
pub const DEFAULT_NEIGHBOURS: usize = 30;

/// How many times the union of the local fans covers the surface, in the limit of sampling.
pub const POINT_CLOUD_COVER: f64 = 3.0;

/// Fewest points a point cloud must have (a point and at least three neighbours).
pub const MIN_POINTS: usize = 4;

/// Points nearer the centre than this fraction of the neighbourhood radius are moved out to it,
/// so that (nearly) coincident points still give a fan.
const PERTURB: f64 = 1e-7;
/// Two neighbours whose directions from the centre are closer than this (radians, as the sine)
/// do not form a triangle with it.
const COLLINEAR: f64 = 1e-5;
/// Nearest neighbours whose spread gives the normal: fewer than the fan's `k`, so that on a thin
/// part (a leg, a tail) the plane is fitted to one side only.
const PCA_NEIGHBOURS: usize = 10;
/// Neighbours whose (oriented) normal is at more than 90° from the centre's are left out of its
/// fan: they lie on the other side of a thin part, and a triangle to them would bridge it.
const NORMAL_AGREEMENT: f64 = 0.0;
/// Neighbours over which normal orientation spreads.
const ORIENT_NEIGHBOURS: usize = 10;
/// Slack, relative to the neighbourhood radius, with which a circumcircle counts as empty.
const EMPTY_SLACK: f64 = 1e-4;

/// The local triangulations of a point cloud.
#[derive(Clone, Debug, PartialEq)]
pub struct LocalTriangulation {
    /// Unit normal per point, consistently oriented (see the module documentation); `[0; 3]`
    /// where the neighbourhood is degenerate (all neighbours coincide with the point).
    pub normals: Vec<[f64; 3]>,
    /// Every fan triangle `[centre, a, b]`, counter-clockwise about the centre's normal, fans
    /// in point order. A triangle found in several fans appears once per fan.
    pub fans: Vec<[usize; 3]>,
}

/// Builds the local triangulations of `points` with `k` neighbours per point (`k` is capped at
/// `points.len() − 1`).
///
/// Errors: fewer than [`MIN_POINTS`] points, or a NaN/infinite coordinate
/// ([`MeshError::PointCloudTooSmall`], [`MeshError::NonFiniteVertex`]); and
/// [`MeshError::DegeneratePointCloud`] when no fan has a triangle (all points coincide or lie on
/// a line).
///
/// ```
/// use shapeforest::mesh::local_triangulation;
/// // a 5 × 5 grid in the plane z = 0
/// let pts: Vec<[f64; 3]> = (0..25).map(|i| [(i % 5) as f64, (i / 5) as f64, 0.0]).collect();
/// let lt = local_triangulation(&pts, 8).unwrap();
/// assert!(lt.normals.iter().all(|n| n[2].abs() > 0.999));
/// assert!(lt.fans.len() >= 3 * 2 * 16 - 12);
/// ```
pub fn local_triangulation(points: &[[f64; 3]], k: usize) -> Result<LocalTriangulation, MeshError> {
    if points.len() < MIN_POINTS {
        return Err(MeshError::PointCloudTooSmall { points: points.len(), min: MIN_POINTS });
    }
    if let Some(v) = points.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
        return Err(MeshError::NonFiniteVertex { vertex: v });
    }
    let k = k.clamp(3, points.len() - 1);
    let neighbours = nearest_neighbours(points, k);
    let mut normals: Vec<[f64; 3]> = (0..points.len())
        .into_par_iter()
        .map(|i| pca_normal(points, i, &neighbours[i][..neighbours[i].len().min(PCA_NEIGHBOURS)]))
        .collect();
    orient_normals(points, &neighbours, &mut normals);
    let fans: Vec<Vec<[usize; 3]>> = (0..points.len())
        .into_par_iter()
        .map(|i| {
            let same_side: Vec<usize> = neighbours[i]
                .iter()
                .copied()
                .filter(|&j| dot(normals[i], normals[j]) >= NORMAL_AGREEMENT)
                .collect();
            local_fan(points, i, &same_side, normals[i])
        })
        .collect();
    let fans: Vec<[usize; 3]> = fans.into_iter().flatten().collect();
    if fans.is_empty() {
        return Err(MeshError::DegeneratePointCloud {
            points: points.len(),
            reason: "no local triangle could be formed (the points coincide or lie on a line)".into(),
        });
    }
    Ok(LocalTriangulation { normals, fans })
}

/// A mesh for a point cloud: its vertices are the points (same order), its faces the distinct
/// triangles of the local triangulations (see the module documentation), each once, in the
/// order first found, oriented counter-clockwise about the summed normals of its corners.
///
/// The faces overlap and meet along non-manifold edges; the crate's spectral and geodesic code
/// use the tufted intrinsic-Delaunay Laplacian on such meshes
/// ([`crate::spectral::surface_operator`]).
///
/// ```
/// use shapeforest::mesh::point_cloud_mesh;
/// let pts: Vec<[f64; 3]> = (0..36).map(|i| [(i % 6) as f64, (i / 6) as f64, 0.1 * (i % 3) as f64]).collect();
/// let m = point_cloud_mesh(&pts, 10).unwrap();
/// assert_eq!(m.n_vertices(), 36);
/// assert!(m.n_faces() >= 2 * 25);
/// ```
pub fn point_cloud_mesh(points: &[[f64; 3]], k: usize) -> Result<Mesh, MeshError> {
    let lt = local_triangulation(points, k)?;
    let (faces, multiplicity) = distinct_oriented_faces(points, &lt);
    let mut mesh = Mesh::new(points.to_vec(), faces)?;
    mesh.face_multiplicity = multiplicity;
    Ok(mesh)
}

/// The distinct triangles of `lt.fans` (by vertex set), first-found order, oriented so that
/// the face normal agrees with the sum of its corners' normals, with the number of fans that
/// hold each.
fn distinct_oriented_faces(points: &[[f64; 3]], lt: &LocalTriangulation) -> (Vec<[usize; 3]>, Vec<u32>) {
    let mut seen: HashMap<[usize; 3], usize> = HashMap::with_capacity(lt.fans.len() / 2);
    let mut faces = Vec::with_capacity(lt.fans.len() / 2);
    let mut multiplicity: Vec<u32> = Vec::with_capacity(lt.fans.len() / 2);
    for &f in &lt.fans {
        let mut key = f;
        key.sort_unstable();
        if let Some(&at) = seen.get(&key) {
            multiplicity[at] += 1;
            continue;
        }
        seen.insert(key, faces.len());
        multiplicity.push(1);
        let n = cross(sub(points[f[1]], points[f[0]]), sub(points[f[2]], points[f[0]]));
        let m = lt.normals[f[0]];
        let s = [0, 1, 2].map(|c| m[c] + lt.normals[f[1]][c] + lt.normals[f[2]][c]);
        faces.push(if dot(n, s) < 0.0 { [f[0], f[2], f[1]] } else { f });
    }
    (faces, multiplicity)
}

/// The `k` nearest other points of every point, nearest first (ties by index).
fn nearest_neighbours(points: &[[f64; 3]], k: usize) -> Vec<Vec<usize>> {
    let tree: ImmutableKdTree<f64, u32, 3, 32> = ImmutableKdTree::new_from_slice(points);
    let want = NonZero::new(k + 1).expect("k + 1 > 0");
    (0..points.len())
        .into_par_iter()
        .map(|i| {
            let mut found: Vec<(f64, usize)> = tree
                .nearest_n::<SquaredEuclidean>(&points[i], want)
                .into_iter()
                .map(|n| (n.distance, n.item as usize))
                .filter(|&(_, j)| j != i)
                .collect();
            found.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            found.truncate(k);
            found.into_iter().map(|(_, j)| j).collect()
        })
        .collect()
}

/// Unit direction of least variance of the point and its neighbours, or `[0; 3]` when they all
/// coincide.
fn pca_normal(points: &[[f64; 3]], i: usize, nbrs: &[usize]) -> [f64; 3] {
    let all = || std::iter::once(i).chain(nbrs.iter().copied()).map(|j| points[j]);
    let count = (nbrs.len() + 1) as f64;
    let mut c = [0.0; 3];
    for p in all() {
        for d in 0..3 {
            c[d] += p[d] / count;
        }
    }
    let mut cov = [[0.0; 3]; 3];
    for p in all() {
        let q = sub(p, c);
        for a in 0..3 {
            for b in 0..3 {
                cov[a][b] += q[a] * q[b];
            }
        }
    }
    let trace = cov[0][0] + cov[1][1] + cov[2][2];
    if !(trace > 0.0 && trace.is_finite()) {
        return [0.0; 3];
    }
    let m = Mat::<f64>::from_fn(3, 3, |a, b| cov[a][b] / trace);
    match m.self_adjoint_eigen(Side::Lower) {
        Ok(evd) => {
            // eigenvalues ascend: the first eigenvector spans the least variance
            let u = evd.U();
            let n = [u[(0, 0)], u[(1, 0)], u[(2, 0)]];
            let l = norm(n);
            if l > 0.0 && l.is_finite() {
                n.map(|x| x / l)
            } else {
                [0.0; 3]
            }
        }
        Err(_) => [0.0; 3],
    }
}

/// Flips normals for a consistent orientation: on each connected piece of the (symmetrised)
/// neighbour graph, orientation spreads from the point of largest `x` along a maximum spanning tree of `|nᵢ·nⱼ|` over
/// the [`ORIENT_NEIGHBOURS`] nearest neighbours (the most reliable links, and a cheaper tree);
/// then the whole piece is flipped if its normals point inward on balance.
fn orient_normals(points: &[[f64; 3]], neighbours: &[Vec<usize>], normals: &mut [[f64; 3]]) {
    let n = points.len();
    let mut adjacency: Vec<Vec<usize>> =
        neighbours.iter().map(|nb| nb[..nb.len().min(ORIENT_NEIGHBOURS)].to_vec()).collect();
    for (i, nb) in neighbours.iter().enumerate() {
        for &j in &nb[..nb.len().min(ORIENT_NEIGHBOURS)] {
            adjacency[j].push(i);
        }
    }
    let mut done = vec![false; n];
    let mut by_x: Vec<usize> = (0..n).collect();
    by_x.sort_by(|&a, &b| points[b][0].total_cmp(&points[a][0]).then(a.cmp(&b)));
    let mut heap: BinaryHeap<(OrdF64, usize, usize)> = BinaryHeap::new();
    for &seed in &by_x {
        if done[seed] {
            continue;
        }
        if normals[seed][0] < 0.0 {
            normals[seed] = normals[seed].map(|x| -x);
        }
        done[seed] = true;
        let mut piece = vec![seed];
        push_edges(seed, &adjacency, normals, &done, &mut heap);
        while let Some((_, from, to)) = heap.pop() {
            if done[to] {
                continue;
            }
            if dot(normals[from], normals[to]) < 0.0 {
                normals[to] = normals[to].map(|x| -x);
            }
            done[to] = true;
            piece.push(to);
            push_edges(to, &adjacency, normals, &done, &mut heap);
        }
        // Outward on the whole piece: the normals point away from its centroid on balance (the
        // flux of the position field, the enclosed volume's sign, rather than one extreme point).
        let count = piece.len() as f64;
        let mut c = [0.0; 3];
        for &v in &piece {
            for d in 0..3 {
                c[d] += points[v][d] / count;
            }
        }
        let flux: f64 = piece.iter().map(|&v| dot(normals[v], sub(points[v], c))).sum();
        if flux < 0.0 {
            for &v in &piece {
                normals[v] = normals[v].map(|x| -x);
            }
        }
    }
}

fn push_edges(
    from: usize,
    adjacency: &[Vec<usize>],
    normals: &[[f64; 3]],
    done: &[bool],
    heap: &mut BinaryHeap<(OrdF64, usize, usize)>,
) {
    for &to in &adjacency[from] {
        if !done[to] {
            heap.push((OrdF64(dot(normals[from], normals[to]).abs()), from, to));
        }
    }
}

/// An `f64` ordered by `total_cmp`, for binary heaps (here and in the regulariser's cell balls).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct OrdF64(pub(crate) f64);
impl Eq for OrdF64 {}
impl PartialOrd for OrdF64 {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for OrdF64 {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&other.0)
    }
}

/// The Delaunay triangles around point `i` of its neighbours projected into the tangent plane
/// of `normal`, as `[i, a, b]` counter-clockwise about `normal`.
///
/// The angular sweep of `robust_laplacian`: neighbours are sorted by angle around the centre,
/// and from each neighbour the sweep looks ahead for the first one that forms, with it and the
/// centre, a triangle whose circumcircle holds no other neighbour; the triangle is taken and the
/// sweep continues from its far corner. An angular gap of more than π marks a boundary, where
/// the sweep starts and stops. Not the exact Delaunay triangulation in degenerate cases, but
/// always some sane fan, which is all the Laplacian needs.
fn local_fan(points: &[[f64; 3]], i: usize, nbrs: &[usize], normal: [f64; 3]) -> Vec<[usize; 3]> {
    let m = nbrs.len();
    if m < 2 || norm(normal) == 0.0 {
        return Vec::new();
    }
    let (e1, e2) = tangent_basis(normal);
    let mut q: Vec<[f64; 2]> = nbrs
        .iter()
        .map(|&j| {
            let v = sub(points[j], points[i]);
            [dot(v, e1), dot(v, e2)]
        })
        .collect();
    let radius = q.iter().map(|p| p[0].hypot(p[1])).fold(0.0, f64::max);
    if !(radius > 0.0 && radius.is_finite()) {
        return Vec::new();
    }
    for (a, p) in q.iter_mut().enumerate() {
        let d = p[0].hypot(p[1]);
        if d < radius * PERTURB {
            let angle = if d > 0.0 { p[1].atan2(p[0]) } else { std::f64::consts::TAU * a as f64 / m as f64 };
            let len = (1.0 + a as f64 / m as f64) * radius * PERTURB * 10.0;
            *p = [len * angle.cos(), len * angle.sin()];
        }
    }
    let angles: Vec<f64> = q.iter().map(|p| p[1].atan2(p[0])).collect();
    let mut order: Vec<usize> = (0..m).collect();
    order.sort_by(|&a, &b| angles[a].total_cmp(&angles[b]).then(a.cmp(&b)));
    let (mut gap, mut gap_end) = (-1.0, 0);
    for s in 0..m {
        let t = (s + 1) % m;
        let g = if t == 0 {
            angles[order[0]] + std::f64::consts::TAU - angles[order[s]]
        } else {
            angles[order[t]] - angles[order[s]]
        };
        if g > gap {
            gap = g;
            gap_end = t;
        }
    }
    let boundary = gap > std::f64::consts::PI - COLLINEAR;
    let first = if boundary {
        gap_end
    } else {
        let closest = (0..m).min_by(|&a, &b| dist2(q[a]).total_cmp(&dist2(q[b]))).expect("m ≥ 2");
        order.iter().position(|&a| a == closest).expect("closest is in the order")
    };
    order.rotate_left(first);

    let search_end = m + usize::from(!boundary);
    let mut fan = Vec::new();
    let mut start = 0;
    while start < m {
        let s = order[start];
        let mut found = None;
        for end in start + 1..search_end {
            let e = order[end % m];
            if e == s {
                continue;
            }
            let (ps, pe) = (q[s], q[e]);
            let cr = ps[0] * pe[1] - ps[1] * pe[0];
            // counter-clockwise and not (nearly) collinear with the centre
            if cr <= COLLINEAR * dist2(ps).sqrt() * dist2(pe).sqrt() {
                continue;
            }
            let (ss, ee) = (dist2(ps), dist2(pe));
            let centre = [(pe[1] * ss - ps[1] * ee) / (2.0 * cr), (ps[0] * ee - pe[0] * ss) / (2.0 * cr)];
            let r = dist2(centre).sqrt();
            let strict = (r - radius * EMPTY_SLACK).max(0.0).powi(2);
            let mut nearest = f64::INFINITY;
            for (t, pt) in q.iter().enumerate() {
                if t == s || t == e {
                    continue;
                }
                nearest = nearest.min(dist2([centre[0] - pt[0], centre[1] - pt[1]]));
                if nearest < strict {
                    break;
                }
            }
            if nearest.sqrt() + radius * EMPTY_SLACK > r {
                found = Some(end);
                fan.push([i, nbrs[s], nbrs[e]]);
                break;
            }
        }
        start = found.unwrap_or(start + 1);
    }
    fan
}

#[inline]
fn dist2(p: [f64; 2]) -> f64 {
    p[0] * p[0] + p[1] * p[1]
}

/// Two unit vectors `(e1, e2)` with `e1 × e2 = n` for a unit `n`.
fn tangent_basis(n: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let helper = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let e1 = cross(helper, n);
    let l = norm(e1);
    let e1 = e1.map(|x| x / l);
    let e2 = cross(n, e1);
    (e1, e2)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::icosphere;

    #[test]
    fn planar_grid_fans_are_the_delaunay_triangles() {
        // a jittered grid: each interior point's fan has ~6 triangles; every triangle is found by
        // its three corners (the triple cover)
        let mut pts = Vec::new();
        for y in 0..12 {
            for x in 0..12 {
                let j = ((x * 7 + y * 13) % 11) as f64 / 11.0 - 0.5;
                pts.push([x as f64 + 0.2 * j, y as f64 - 0.15 * j, 0.0]);
            }
        }
        let lt = local_triangulation(&pts, 20).unwrap();
        let mut count: HashMap<[usize; 3], usize> = HashMap::new();
        for f in &lt.fans {
            let mut key = *f;
            key.sort_unstable();
            *count.entry(key).or_default() += 1;
        }
        // Euler: a triangulated 12×12 square has 2·11·11 triangles
        let triple = count.values().filter(|&&c| c == 3).count();
        assert!(triple as f64 >= 0.9 * 242.0, "{triple} triangles in three fans, of {}", count.len());
        // counter-clockwise about +z (the normal points +x-ward or is flipped consistently)
        let nz = lt.normals[0][2].signum();
        assert!(lt.normals.iter().all(|n| n[2] * nz > 0.999));
        for f in &lt.fans {
            let c = cross(sub(pts[f[1]], pts[f[0]]), sub(pts[f[2]], pts[f[0]]));
            assert!(c[2] * nz > 0.0, "fan triangle {f:?} is clockwise");
        }
    }

    #[test]
    fn sphere_normals_point_outward_and_faces_agree() {
        let pts = icosphere(3, 1.0).vertices;
        let m = point_cloud_mesh(&pts, DEFAULT_NEIGHBOURS).unwrap();
        let lt = local_triangulation(&pts, DEFAULT_NEIGHBOURS).unwrap();
        for (p, n) in pts.iter().zip(&lt.normals) {
            assert!(dot(*p, *n) > 0.95, "normal {n:?} at {p:?} is not outward");
        }
        for f in &m.faces {
            let c = cross(sub(pts[f[1]], pts[f[0]]), sub(pts[f[2]], pts[f[0]]));
            assert!(dot(c, pts[f[0]]) > 0.0, "face {f:?} points inward");
        }
        // the distinct triangles cover the sphere about once
        let ratio = m.surface_area() / (4.0 * std::f64::consts::PI);
        assert!((0.95..1.3).contains(&ratio), "area ratio {ratio}");
    }

    #[test]
    fn bad_clouds_are_refused_with_reasons() {
        let e = local_triangulation(&[[0.0; 3]; 3], 30).unwrap_err();
        assert!(matches!(e, MeshError::PointCloudTooSmall { points: 3, .. }), "{e}");
        let e = local_triangulation(&[[0.0; 3]; 10], 30).unwrap_err();
        assert!(matches!(e, MeshError::DegeneratePointCloud { .. }), "{e}");
        let line: Vec<[f64; 3]> = (0..10).map(|i| [i as f64, 0.0, 0.0]).collect();
        assert!(matches!(local_triangulation(&line, 30), Err(MeshError::DegeneratePointCloud { .. })));
        let mut nan: Vec<[f64; 3]> = (0..10).map(|i| [i as f64, (i * i) as f64, 0.0]).collect();
        nan[4][1] = f64::NAN;
        assert!(matches!(local_triangulation(&nan, 30), Err(MeshError::NonFiniteVertex { vertex: 4 })));
    }

    #[test]
    fn duplicate_points_do_not_break_the_fans() {
        let mut pts = icosphere(2, 1.0).vertices;
        let copies: Vec<[f64; 3]> = pts.iter().take(20).copied().collect();
        pts.extend(copies);
        let m = point_cloud_mesh(&pts, 12).unwrap();
        assert_eq!(m.n_vertices(), pts.len());
        assert!(m.faces.iter().all(|f| f[0] != f[1] && f[1] != f[2] && f[0] != f[2]));
    }
}
