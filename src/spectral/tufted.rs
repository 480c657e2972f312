//! The tufted intrinsic-Delaunay Laplacian of Sharp & Crane 2020, "A Laplacian for Nonmanifold
//! Triangle Meshes" (SGP 2020; the method of their `robust_laplacian` package), for
//! non-manifold meshes, triangle soups and point clouds.
//!
//! The cotangent Laplacian is only well behaved on manifold meshes with Delaunay triangles: on
//! a non-manifold edge, or a soup of overlapping triangles, its weights can be negative and
//! `M + tL` indefinite. The construction here, from edge lengths alone:
//!
//! 1. **Mollification** (§4.5): every edge length grows by the same `ε`, the least that makes
//!    each triangle satisfy its triangle inequalities with slack `δ = mollify_factor ·
//!    mean edge length`, so degenerate (zero-area, needle) triangles get a usable geometry.
//! 2. **Tufted cover** (§4.2): every face is doubled into a front and a back copy; around each
//!    edge the incident faces are sorted by angle and each one's back is glued to the next one's
//!    front. The result is a closed, oriented, edge-manifold intrinsic triangulation (a boundary
//!    edge glues a face's two copies), covering the input twice.
//! 3. **Intrinsic Delaunay flips** (§4.3): edges whose opposite angles sum to more than π are
//!    flipped (new length from the 2-D layout of the two triangles) until none is left, so every
//!    cotangent weight is non-negative and `L` is an M-matrix.
//! 4. The cotangent stiffness and lumped mass of the cover, halved for the double cover; for a
//!    point cloud ([`point_cloud_laplacian`], §5) the input is the union of the local fans, which
//!    covers the surface three times, so both are further divided by three.
//!
//! Conventions: as [`super::cotan_laplacian`]: `L` symmetric positive semi-definite with rows
//! summing to zero (`L_ij = −w_ij`), weights as `(i, j, w)` triplets to be summed, mass per
//! vertex (a third of the incident cover areas); vertices in no face get no weight and zero
//! mass. Everything is in the units of the input.

use faer::sparse::{SparseColMat, Triplet};
use thiserror::Error;

use crate::mesh::{local_triangulation, norm, sub, MeshError};

/// Parameters of the tufted Laplacian.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TuftedParams {
    /// Relative mollification `δ / mean edge length`; 0 disables it. Default `1e-5`, as in
    /// `robust_laplacian`.
    pub mollify_factor: f64,
}

impl Default for TuftedParams {
    fn default() -> Self {
        Self { mollify_factor: 1e-5 }
    }
}

/// The tufted Laplacian could not be built.
#[derive(Debug, Error)]
pub enum TuftedError {
    /// A parameter is out of range.
    #[error("invalid mollify_factor {0}: must be finite and non-negative")]
    InvalidMollifyFactor(f64),
    /// A face refers to a vertex that does not exist, or repeats one.
    #[error("face {face} {problem}")]
    BadFace {
        /// 0-based face index.
        face: usize,
        /// What is wrong.
        problem: String,
    },
    /// A coordinate is NaN or infinite.
    #[error("vertex {0} has a NaN or infinite coordinate")]
    NonFinite(usize),
    /// There is nothing to build on: no faces, or every edge has length zero.
    #[error("no face with positive edge lengths")]
    Degenerate,
    /// The point cloud's local triangulation failed.
    #[error("point cloud: {0}")]
    PointCloud(#[from] MeshError),
}

/// A Laplacian as weights and lumped masses, with what the construction did.
#[derive(Clone, Debug, PartialEq)]
pub struct IntrinsicLaplacian {
    /// Number of vertices.
    pub n_vertices: usize,
    /// Edge weights `(i, j, w)`, `i ≠ j`, one per halfedge of the cover (to be summed):
    /// `L_ij = −Σ w`, `L_ii = Σ_j Σ w`.
    pub weights: Vec<(usize, usize, f64)>,
    /// Lumped mass per vertex.
    pub mass: Vec<f64>,
    /// The `ε` added to every edge length by mollification.
    pub mollify_epsilon: f64,
    /// Intrinsic edge flips performed.
    pub n_flips: usize,
}

impl IntrinsicLaplacian {
    /// The stiffness matrix `L` as a sparse CSC matrix (both triangles stored).
    pub fn stiffness(&self) -> SparseColMat<usize, f64> {
        let n = self.n_vertices;
        let mut triplets = Vec::with_capacity(self.weights.len() * 4);
        for &(i, j, w) in &self.weights {
            triplets.push(Triplet::new(i, j, -w));
            triplets.push(Triplet::new(j, i, -w));
            triplets.push(Triplet::new(i, i, w));
            triplets.push(Triplet::new(j, j, w));
        }
        SparseColMat::try_new_from_triplets(n, n, &triplets)
            .expect("tufted Laplacian indices are checked on construction")
    }

    /// Total mass (the area the operator sees).
    pub fn total_mass(&self) -> f64 {
        self.mass.iter().sum()
    }

    fn scaled(mut self, factor: f64) -> Self {
        for w in &mut self.weights {
            w.2 *= factor;
        }
        for m in &mut self.mass {
            *m *= factor;
        }
        self
    }
}

/// The tufted intrinsic-Delaunay Laplacian of a triangle mesh or soup (any faces: non-manifold
/// edges and vertices, duplicates, zero-area triangles; see the module documentation).
///
/// ```
/// use shapeforest::spectral::{tufted_laplacian, TuftedParams};
/// // three triangles on one edge (0, 1): non-manifold
/// let v = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 1.0, 0.0], [0.5, -1.0, 0.0], [0.5, 0.0, 1.0]];
/// let f = [[0, 1, 2], [1, 0, 3], [0, 1, 4]];
/// let l = tufted_laplacian(&v, &f, TuftedParams::default()).unwrap();
/// assert!(l.weights.iter().all(|w| w.2 >= -1e-12)); // intrinsic Delaunay: no negative weight
/// assert!((l.total_mass() - 1.5).abs() < 1e-4); // three triangles of area 0.5
/// ```
pub fn tufted_laplacian(
    vertices: &[[f64; 3]],
    faces: &[[usize; 3]],
    params: TuftedParams,
) -> Result<IntrinsicLaplacian, TuftedError> {
    if !(params.mollify_factor.is_finite() && params.mollify_factor >= 0.0) {
        return Err(TuftedError::InvalidMollifyFactor(params.mollify_factor));
    }
    let n = vertices.len();
    for (f, tri) in faces.iter().enumerate() {
        if let Some(&i) = tri.iter().find(|&&i| i >= n) {
            return Err(TuftedError::BadFace { face: f, problem: format!("refers to vertex {i} of {n}") });
        }
        if tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2] {
            return Err(TuftedError::BadFace { face: f, problem: format!("repeats a vertex: {tri:?}") });
        }
    }
    for tri in faces {
        for &v in tri {
            if vertices[v].iter().any(|c| !c.is_finite()) {
                return Err(TuftedError::NonFinite(v));
            }
        }
    }
    let mut cover = Cover::build(vertices, faces);
    let epsilon = cover.mollify(params.mollify_factor)?;
    let n_flips = cover.flip_to_delaunay();
    let (weights, mass) = cover.cotan_and_mass(n);
    Ok(IntrinsicLaplacian { n_vertices: n, weights, mass, mollify_epsilon: epsilon, n_flips }.scaled(0.5))
}

/// The point-cloud Laplacian of Sharp & Crane 2020 (§5): the tufted Laplacian of the union of
/// the local triangulations of `points` with `k` neighbours each
/// ([`crate::mesh::local_triangulation`]), divided by three for the triple covering.
///
/// ```
/// use shapeforest::spectral::{point_cloud_laplacian, TuftedParams};
/// // a jittered 20 × 20 grid (exactly co-circular grid points make the fans ambiguous)
/// let pts: Vec<[f64; 3]> = (0..400)
///     .map(|i| [(i % 20) as f64 + 0.2 * (i as f64 * 1.7).sin(), (i / 20) as f64 + 0.2 * (i as f64 * 2.3).cos(), 0.0])
///     .collect();
/// let l = point_cloud_laplacian(&pts, 30, TuftedParams::default()).unwrap();
/// let area = l.total_mass();
/// assert!((area / 361.0 - 1.0).abs() < 0.05, "{area}"); // the 19 × 19 square, about once
/// ```
pub fn point_cloud_laplacian(
    points: &[[f64; 3]],
    k: usize,
    params: TuftedParams,
) -> Result<IntrinsicLaplacian, TuftedError> {
    let lt = local_triangulation(points, k)?;
    Ok(tufted_laplacian(points, &lt.fans, params)?.scaled(1.0 / 3.0))
}

/// The intrinsic tufted cover as a halfedge structure: face `f` has halfedges `3f..3f + 3`,
/// `next(h) = 3⌊h/3⌋ + (h + 1) mod 3`; `tail[h]` is the vertex `h` leaves, `twin[h]` the
/// halfedge glued to it (opposite direction), `len[h]` the intrinsic length of its edge.
struct Cover {
    tail: Vec<usize>,
    twin: Vec<usize>,
    len: Vec<f64>,
}

#[inline]
fn next(h: usize) -> usize {
    3 * (h / 3) + (h + 1) % 3
}

impl Cover {
    /// Front copies are faces `0..F` (the input orientation), back copies `F..2F` (reversed).
    fn build(vertices: &[[f64; 3]], faces: &[[usize; 3]]) -> Cover {
        let nf = faces.len();
        let mut tail = vec![0usize; 6 * nf];
        for (f, t) in faces.iter().enumerate() {
            // front: t0→t1, t1→t2, t2→t0; back (t0, t2, t1): t0→t2, t2→t1, t1→t0
            tail[3 * f..3 * f + 3].copy_from_slice(&[t[0], t[1], t[2]]);
            tail[3 * (nf + f)..3 * (nf + f) + 3].copy_from_slice(&[t[0], t[2], t[1]]);
        }
        let head = |tail: &[usize], h: usize| tail[next(h)];
        let len: Vec<f64> =
            (0..6 * nf).map(|h| norm(sub(vertices[head(&tail, h)], vertices[tail[h]]))).collect();
        // the back copy of front halfedge 3f + c runs the other way: it is 3(F + f) + (2 − c)
        let other_sheet = |h: usize| {
            if h < 3 * nf {
                3 * (nf + h / 3) + (2 - h % 3)
            } else {
                3 * ((h / 3) - nf) + (2 - h % 3)
            }
        };

        // Front halfedges grouped by undirected edge.
        let mut by_edge: Vec<(usize, usize, usize)> = (0..3 * nf)
            .map(|h| {
                let (a, b) = (tail[h], head(&tail, h));
                (a.min(b), a.max(b), h)
            })
            .collect();
        by_edge.sort_unstable();
        let mut twin = vec![usize::MAX; 6 * nf];
        let mut start = 0;
        while start < by_edge.len() {
            let (u, v, _) = by_edge[start];
            let mut end = start + 1;
            while end < by_edge.len() && (by_edge[end].0, by_edge[end].1) == (u, v) {
                end += 1;
            }
            let mut around: Vec<(f64, usize)> = by_edge[start..end]
                .iter()
                .map(|&(_, _, h)| (edge_angle(vertices, u, v, tail[next(next(h))]), h))
                .collect();
            // descending angle, ties by halfedge for determinism
            around.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
            // glue each face's copy running v→u to the next face's copy running u→v
            let runs_vu = |h: usize| tail[h] == v;
            let mut current = around[0].1;
            if !runs_vu(current) {
                current = other_sheet(current);
            }
            for i in 0..around.len() {
                let mut nxt = around[(i + 1) % around.len()].1;
                if runs_vu(nxt) {
                    nxt = other_sheet(nxt);
                }
                twin[current] = nxt;
                twin[nxt] = current;
                current = other_sheet(nxt);
            }
            start = end;
        }
        debug_assert!(twin.iter().all(|&t| t != usize::MAX));
        Cover { tail, twin, len }
    }

    /// Adds the mollification `ε` to every length; returns `ε`.
    fn mollify(&mut self, factor: f64) -> Result<f64, TuftedError> {
        let n_edges = self.len.len() / 2;
        if n_edges == 0 {
            return Err(TuftedError::Degenerate);
        }
        let mean = self.len.iter().sum::<f64>() / self.len.len() as f64;
        if !(mean > 0.0 && mean.is_finite()) {
            return Err(TuftedError::Degenerate);
        }
        let delta = factor * mean;
        let mut eps = 0.0f64;
        for h in 0..self.len.len() {
            let (a, b, c) = (self.len[h], self.len[next(h)], self.len[next(next(h))]);
            eps = eps.max(c - a - b + delta);
        }
        if eps > 0.0 {
            for l in &mut self.len {
                *l += eps;
            }
        }
        Ok(eps)
    }

    /// Half the cotangent weight of the corner opposite `h` in its face.
    fn half_cot(&self, h: usize) -> f64 {
        let (a, b, c) = (self.len[h], self.len[next(h)], self.len[next(next(h))]);
        let area = triangle_area(a, b, c);
        if area <= 0.0 {
            return 0.0;
        }
        (b * b + c * c - a * a) / (8.0 * area)
    }

    /// Flips non-Delaunay edges until none is left (or a generous cap is reached, which only
    /// rounding could cause); returns the number of flips.
    fn flip_to_delaunay(&mut self) -> usize {
        let nh = self.len.len();
        let mut queued = vec![true; nh];
        let mut stack: Vec<usize> = (0..nh).filter(|&h| h < self.twin[h]).collect();
        let cap = 100 * nh + 1000;
        let mut flips = 0;
        while let Some(h) = stack.pop() {
            queued[h] = false;
            let t = self.twin[h];
            queued[t] = false;
            // cotangent weights are scale-free: an absolute tolerance
            let weight = self.half_cot(h) + self.half_cot(t);
            if weight >= -1e-10 || flips >= cap {
                continue;
            }
            if self.flip(h) {
                flips += 1;
                for x in [next(h), next(next(h)), next(t), next(next(t))] {
                    let e = x.min(self.twin[x]);
                    if !queued[e] {
                        queued[e] = true;
                        queued[self.twin[e]] = true;
                        stack.push(e);
                    }
                }
            }
        }
        flips
    }

    /// Flips the edge of `h`; false (nothing changed) when the configuration does not allow it.
    fn flip(&mut self, h: usize) -> bool {
        let t = self.twin[h];
        if h / 3 == t / 3 {
            return false;
        }
        let (hn, hp, tn, tp) = (next(h), next(next(h)), next(t), next(next(t)));
        // a → b along h; c opposite in h's face, d opposite in t's face
        let (a, b, c, d) = (self.tail[h], self.tail[hn], self.tail[hp], self.tail[tp]);
        let (l_ab, l_bc, l_ca, l_ad, l_db) =
            (self.len[h], self.len[hn], self.len[hp], self.len[tn], self.len[tp]);
        // layout: a = (0, 0), b = (l_ab, 0), c above, d below
        let xc = (l_ab * l_ab + l_ca * l_ca - l_bc * l_bc) / (2.0 * l_ab);
        let yc = (l_ca * l_ca - xc * xc).max(0.0).sqrt();
        let xd = (l_ab * l_ab + l_ad * l_ad - l_db * l_db) / (2.0 * l_ab);
        let yd = -(l_ad * l_ad - xd * xd).max(0.0).sqrt();
        let l_cd = (xc - xd).hypot(yc - yd);
        if !(l_cd.is_finite() && l_cd > 0.0)
            || triangle_area(l_cd, l_ca, l_ad) <= 0.0
            || triangle_area(l_cd, l_db, l_bc) <= 0.0
        {
            return false;
        }
        // new faces: (h: d→c, hn: c→a, hp: a→d) and (t: c→d, tn: d→b, tp: b→c); the old
        // outer halfedges move: hp → hn, tn → hp, tp → tn, hn → tp. Their twins may be among
        // themselves (a vertex of degree 2, a doubled face): those move too.
        let moved = [(hp, hn), (tn, hp), (tp, tn), (hn, tp)];
        let new_slot = |x: usize| moved.iter().find(|m| m.0 == x).map_or(x, |m| m.1);
        let old_twins = moved.map(|(from, _)| self.twin[from]);
        self.tail[h] = d;
        self.tail[hn] = c;
        self.tail[hp] = a;
        self.tail[t] = c;
        self.tail[tn] = d;
        self.tail[tp] = b;
        self.len[h] = l_cd;
        self.len[t] = l_cd;
        self.len[hn] = l_ca;
        self.len[hp] = l_ad;
        self.len[tn] = l_db;
        self.len[tp] = l_bc;
        for ((_, slot), old_twin) in moved.iter().zip(old_twins) {
            let other = new_slot(old_twin);
            self.twin[*slot] = other;
            self.twin[other] = *slot;
        }
        true
    }

    /// Cotangent weights (one per halfedge with distinct ends) and lumped masses of the cover.
    fn cotan_and_mass(&self, n: usize) -> (Vec<(usize, usize, f64)>, Vec<f64>) {
        let mut weights = Vec::with_capacity(self.len.len());
        let mut mass = vec![0.0; n];
        for h in 0..self.len.len() {
            let (i, j) = (self.tail[h], self.tail[next(h)]);
            if i != j {
                let w = self.half_cot(h);
                if w != 0.0 {
                    weights.push((i.min(j), i.max(j), w));
                }
            }
            if h % 3 == 0 {
                let area = triangle_area(self.len[h], self.len[h + 1], self.len[h + 2]);
                for c in 0..3 {
                    mass[self.tail[h + c]] += area / 3.0;
                }
            }
        }
        (weights, mass)
    }
}

/// Angle of the triangle `(u, v, o)` around the edge `u → v`, in a basis perpendicular to it.
fn edge_angle(vertices: &[[f64; 3]], u: usize, v: usize, o: usize) -> f64 {
    let e = sub(vertices[v], vertices[u]);
    let el = norm(e).max(f64::MIN_POSITIVE);
    let e = e.map(|x| x / el);
    let helper = if e[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let b1 = crate::mesh::cross(helper, e);
    let b1l = norm(b1);
    let b1 = b1.map(|x| x / b1l);
    let b2 = crate::mesh::cross(e, b1);
    let w = sub(vertices[o], vertices[u]);
    crate::mesh::dot(b2, w).atan2(crate::mesh::dot(b1, w))
}

/// Area from edge lengths (Heron, in the numerically stable ordering of Kahan); 0 when the
/// lengths violate the triangle inequality.
fn triangle_area(a: f64, b: f64, c: f64) -> f64 {
    let mut s = [a, b, c];
    s.sort_by(|x, y| y.total_cmp(x));
    let [a, b, c] = s;
    let q = (a + (b + c)) * (c - (a - b)) * (c + (a - b)) * (a + (b - c));
    if q > 0.0 {
        0.25 * q.sqrt()
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::Mesh;
    use crate::spectral::{cotan_weights, vertex_lumped_mass};
    use crate::synth::icosphere;

    fn dense(l: &IntrinsicLaplacian) -> Vec<Vec<f64>> {
        let n = l.n_vertices;
        let mut m = vec![vec![0.0; n]; n];
        for &(i, j, w) in &l.weights {
            m[i][j] -= w;
            m[j][i] -= w;
            m[i][i] += w;
            m[j][j] += w;
        }
        m
    }

    #[test]
    fn delaunay_manifold_mesh_gives_its_cotan_laplacian() {
        // the icosphere is Delaunay: no flip, and the tufted Laplacian is the cotan Laplacian
        let m = icosphere(2, 1.0);
        let l = tufted_laplacian(&m.vertices, &m.faces, TuftedParams { mollify_factor: 0.0 }).unwrap();
        assert_eq!(l.n_flips, 0);
        let mut reference = vec![vec![0.0; m.n_vertices()]; m.n_vertices()];
        for (i, j, w) in cotan_weights(&m) {
            reference[i][j] -= w;
            reference[j][i] -= w;
            reference[i][i] += w;
            reference[j][j] += w;
        }
        let got = dense(&l);
        for i in 0..m.n_vertices() {
            for j in 0..m.n_vertices() {
                assert!((got[i][j] - reference[i][j]).abs() < 1e-10, "({i}, {j})");
            }
        }
        for (a, b) in l.mass.iter().zip(vertex_lumped_mass(&m)) {
            assert!((a - b).abs() < 1e-12);
        }
    }

    #[test]
    fn non_delaunay_mesh_is_flipped_to_non_negative_weights() {
        // a flat quad split along its long diagonal: obtuse angles, a negative cotan weight
        let v = [[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [4.2, 1.0, 0.0], [-0.2, 1.0, 0.0]];
        let f = [[0, 1, 2], [0, 2, 3]];
        let m = Mesh::new(v.to_vec(), f.to_vec()).unwrap();
        let mut diagonal = 0.0;
        for (i, j, w) in cotan_weights(&m) {
            if (i, j) == (0, 2) {
                diagonal += w;
            }
        }
        assert!(diagonal < 0.0, "the fixture must be non-Delaunay, weight {diagonal}");
        let l = tufted_laplacian(&v, &f, TuftedParams::default()).unwrap();
        let d = dense(&l);
        for (i, row) in d.iter().enumerate() {
            assert!(row.iter().sum::<f64>().abs() < 1e-10);
            for (j, &x) in row.iter().enumerate() {
                assert!(i == j || x <= 1e-12, "L[{i}][{j}] = {x}");
            }
        }
        assert!((l.total_mass() - m.surface_area()).abs() < 1e-3);
    }

    #[test]
    fn non_manifold_fin_is_positive_semi_definite() {
        // a closed octahedron with a fin of three triangles hanging off one of its edges
        let mut oct = crate::synth::icosphere(0, 1.0);
        let (a, b) = (oct.faces[0][0], oct.faces[0][1]);
        let tip = oct.vertices.len();
        oct.vertices.push([0.0, 0.0, 3.0]);
        oct.faces.push([a, b, tip]);
        oct.faces.push([b, a, tip]);
        let l = tufted_laplacian(&oct.vertices, &oct.faces, TuftedParams::default()).unwrap();
        assert!(l.weights.iter().all(|w| w.2 >= -1e-12));
        let d = dense(&l);
        let n = d.len();
        let mat = faer::Mat::<f64>::from_fn(n, n, |i, j| d[i][j]);
        let eig = mat.self_adjoint_eigen(faer::Side::Lower).unwrap();
        let s = eig.S();
        assert!(s[0] > -1e-10, "smallest eigenvalue {}", s[0]);
        assert!(s[1] > 1e-6, "the surface is connected: one zero eigenvalue, got {}", s[1]);
    }

    #[test]
    fn mollification_handles_degenerate_triangles() {
        let v = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 1.0, 0.0]];
        let f = [[0, 1, 3], [1, 2, 3], [0, 2, 1]]; // the last is flat
        let l = tufted_laplacian(&v, &f, TuftedParams::default()).unwrap();
        assert!(l.mollify_epsilon > 0.0);
        assert!(l.weights.iter().all(|w| w.2.is_finite()));
        let l0 = tufted_laplacian(&v, &f, TuftedParams { mollify_factor: 0.0 }).unwrap();
        assert!(l0.weights.iter().all(|w| w.2.is_finite()));
    }

    #[test]
    fn bad_input_is_refused() {
        let v = [[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        assert!(matches!(
            tufted_laplacian(&v, &[[0, 1, 3]], TuftedParams::default()),
            Err(TuftedError::BadFace { .. })
        ));
        assert!(matches!(tufted_laplacian(&v, &[], TuftedParams::default()), Err(TuftedError::Degenerate)));
        assert!(matches!(
            tufted_laplacian(&v, &[[0, 1, 2]], TuftedParams { mollify_factor: -1.0 }),
            Err(TuftedError::InvalidMollifyFactor(_))
        ));
    }
}
