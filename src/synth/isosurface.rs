//! Mirror-symmetric polygonisation of an implicit surface: surface nets on a grid symmetric
//! about the `x = 0` plane, followed by Delaunay edge flips and tangential relaxation with
//! projection back onto the zero set.
//!
//! - The implicit function is always evaluated at `(|x|, y, z)`, so it is exactly symmetric.
//! - Grid nodes sit at `x = (i − nx/2 + ½)·h`: no node lies on the plane, the middle column of
//!   cells straddles it, and cell `i` mirrors to cell `nx − 2 − i`. Surface nets put one vertex
//!   in every cell whose corners change sign, so the vertex mirror map is read off the cells.
//! - Each grid edge with a sign change gives a quad joining the four cells around it, oriented
//!   so that normals point outwards (towards positive values), split along its shorter diagonal.
//! - Relaxation moves vertices only tangentially, re-projects them onto the zero set by Newton
//!   steps, and re-imposes exact mirror symmetry after every step.

use std::hash::{BuildHasherDefault, Hasher};

use rayon::prelude::*;

use super::SynthError;
use crate::mesh::{cross, dot, face_neighbour_lists, norm, sub};

/// Evaluates `f` on the mirror-folded point `(|x|, y, z)`.
#[inline]
fn eval<F: Fn([f64; 3]) -> f64>(f: &F, p: [f64; 3]) -> f64 {
    f([p[0].abs(), p[1], p[2]])
}

/// Forward-difference gradient of the folded function.
fn forward_gradient<F: Fn([f64; 3]) -> f64>(f: &F, p: [f64; 3], eps: f64) -> [f64; 3] {
    let f0 = eval(f, p);
    let mut g = [0.0; 3];
    for d in 0..3 {
        let mut a = p;
        a[d] += eps;
        g[d] = (eval(f, a) - f0) / eps;
    }
    g
}

/// A regular grid of samples, symmetric about `x = 0`.
struct Grid {
    nx: usize,
    ny: usize,
    nz: usize,
    h: f64,
    origin: [f64; 3],
    values: Vec<f64>,
}

impl Grid {
    /// Samples `f` on a grid of spacing `h` covering the box `[lo, hi]` (plus a margin); the
    /// x-extent is made symmetric.
    fn sample<F: Fn([f64; 3]) -> f64 + Sync>(f: &F, lo: [f64; 3], hi: [f64; 3], h: f64) -> Self {
        let half_x = lo[0].abs().max(hi[0].abs());
        let nx = 2 * ((half_x / h).ceil() as usize + 2);
        let ny = ((hi[1] - lo[1]) / h).ceil() as usize + 5;
        let nz = ((hi[2] - lo[2]) / h).ceil() as usize + 5;
        let origin = [
            -((nx / 2) as f64 - 0.5) * h,
            0.5 * (lo[1] + hi[1]) - 0.5 * (ny - 1) as f64 * h,
            0.5 * (lo[2] + hi[2]) - 0.5 * (nz - 1) as f64 * h,
        ];
        let mut values = vec![0.0; nx * ny * nz];
        values.par_chunks_mut(nx * ny).enumerate().for_each(|(k, slab)| {
            for j in 0..ny {
                for i in 0..nx {
                    let p = Self::position(origin, h, nx, i, j, k);
                    slab[i + nx * j] = eval(f, p);
                }
            }
        });
        Self { nx, ny, nz, h, origin, values }
    }

    #[inline]
    fn position(origin: [f64; 3], h: f64, nx: usize, i: usize, j: usize, k: usize) -> [f64; 3] {
        // x written as a multiple of h about 0 so that mirrored nodes are exact negations.
        [(i as f64 - (nx / 2) as f64 + 0.5) * h, origin[1] + j as f64 * h, origin[2] + k as f64 * h]
    }

    #[inline]
    fn node(&self, i: usize, j: usize, k: usize) -> [f64; 3] {
        Self::position(self.origin, self.h, self.nx, i, j, k)
    }

    #[inline]
    fn value(&self, i: usize, j: usize, k: usize) -> f64 {
        self.values[i + self.nx * (j + self.ny * k)]
    }

    #[inline]
    fn inside(&self, i: usize, j: usize, k: usize) -> bool {
        self.value(i, j, k) < 0.0
    }

    /// Whether the cell with lower corner `(i, j, k)` has corners of both signs.
    #[inline]
    fn cell_is_mixed(&self, i: usize, j: usize, k: usize) -> bool {
        let first = self.inside(i, j, k);
        (1..8).any(|c| self.inside(i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1)) != first)
    }

    /// Number of cells crossed by the surface (= surface-nets vertex count).
    fn count_mixed_cells(&self) -> usize {
        (0..self.nz - 1)
            .into_par_iter()
            .map(|k| {
                let mut n = 0;
                for j in 0..self.ny - 1 {
                    for i in 0..self.nx - 1 {
                        n += self.cell_is_mixed(i, j, k) as usize;
                    }
                }
                n
            })
            .sum()
    }

    #[inline]
    fn cell_index(&self, i: usize, j: usize, k: usize) -> usize {
        i + (self.nx - 1) * (j + (self.ny - 1) * k)
    }
}

/// A polygonised mirror-symmetric surface.
pub(crate) struct SymmetricSurface {
    pub vertices: Vec<[f64; 3]>,
    pub faces: Vec<[usize; 3]>,
    pub symmetry: Vec<usize>,
}

/// Grid spacing for which surface nets give about `target` vertices on the zero set of `f`
/// inside `[lo, hi]`. The count scales as `h⁻²`, so it is extrapolated from two coarse grids
/// (probed at about 3 and 1.5 times the final spacing: together cheaper than the final grid).
fn calibrate_spacing<F: Fn([f64; 3]) -> f64 + Sync>(f: &F, lo: [f64; 3], hi: [f64; 3], target: usize) -> f64 {
    let diag = norm(sub(hi, lo));
    let mut probe = 3.0 * diag / (target as f64).sqrt();
    let mut h = probe;
    for _ in 0..2 {
        let n = Grid::sample(f, lo, hi, probe).count_mixed_cells().max(1) as f64;
        h = probe * (n / target as f64).sqrt();
        probe = 1.5 * h;
    }
    h
}

/// Polygonises the zero set of `f` (negative inside) within `[lo, hi]` with about `target`
/// vertices, mirror-symmetric about `x = 0`, then relaxes the triangulation.
///
/// Fails with [`SynthError::Extraction`] if no closed, connected genus-0 manifold results after
/// several slightly finer grids (a sign that features are thinner than the grid spacing).
pub(crate) fn polygonise_symmetric<F: Fn([f64; 3]) -> f64 + Sync>(
    f: &F,
    lo: [f64; 3],
    hi: [f64; 3],
    target: usize,
    relax_rounds: usize,
) -> Result<SymmetricSurface, SynthError> {
    let mut h = calibrate_spacing(f, lo, hi, target);
    let mut last_reason = String::new();
    const ATTEMPTS: usize = 6;
    for _ in 0..ATTEMPTS {
        let grid = Grid::sample(f, lo, hi, h);
        let mut surface = surface_nets(&grid);
        match check_closed_sphere(surface.vertices.len(), &surface.faces) {
            Ok(()) => {
                relax(f, &mut surface, h, relax_rounds);
                return Ok(surface);
            }
            Err(reason) => last_reason = reason,
        }
        h *= 0.97;
    }
    Err(SynthError::Extraction { attempts: ATTEMPTS, reason: last_reason })
}

/// Surface nets: one vertex per mixed cell (at the mean of its edge crossings), one quad per
/// grid edge with a sign change.
fn surface_nets(grid: &Grid) -> SymmetricSurface {
    let (nx, ny, nz) = (grid.nx, grid.ny, grid.nz);
    let n_cells = (nx - 1) * (ny - 1) * (nz - 1);
    let mut cell_vertex = vec![u32::MAX; n_cells];
    let mut vertices: Vec<[f64; 3]> = Vec::new();
    let mut cells: Vec<[usize; 3]> = Vec::new();
    const EDGES: [(usize, usize); 12] =
        [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6), (3, 7)];
    for k in 0..nz - 1 {
        for j in 0..ny - 1 {
            for i in 0..nx - 1 {
                if !grid.cell_is_mixed(i, j, k) {
                    continue;
                }
                let corner = |c: usize| (i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1));
                let mut sum = [0.0; 3];
                let mut count = 0.0;
                for &(a, b) in &EDGES {
                    let (ia, ja, ka) = corner(a);
                    let (ib, jb, kb) = corner(b);
                    let (fa, fb) = (grid.value(ia, ja, ka), grid.value(ib, jb, kb));
                    if (fa < 0.0) == (fb < 0.0) {
                        continue;
                    }
                    let t = fa / (fa - fb);
                    let (pa, pb) = (grid.node(ia, ja, ka), grid.node(ib, jb, kb));
                    for d in 0..3 {
                        sum[d] += pa[d] + t * (pb[d] - pa[d]);
                    }
                    count += 1.0;
                }
                cell_vertex[grid.cell_index(i, j, k)] = vertices.len() as u32;
                vertices.push([sum[0] / count, sum[1] / count, sum[2] / count]);
                cells.push([i, j, k]);
            }
        }
    }
    let symmetry: Vec<usize> =
        cells.iter().map(|&[i, j, k]| cell_vertex[grid.cell_index(nx - 2 - i, j, k)] as usize).collect();

    let mut faces: Vec<[usize; 3]> = Vec::with_capacity(2 * vertices.len());
    let cv = |i: usize, j: usize, k: usize| cell_vertex[grid.cell_index(i, j, k)] as usize;
    let mut emit = |q: [usize; 4], outward_positive: bool, vertices: &[[f64; 3]]| {
        let q = if outward_positive { q } else { [q[0], q[3], q[2], q[1]] };
        let d02 = norm(sub(vertices[q[0]], vertices[q[2]]));
        let d13 = norm(sub(vertices[q[1]], vertices[q[3]]));
        if d02 <= d13 {
            faces.push([q[0], q[1], q[2]]);
            faces.push([q[0], q[2], q[3]]);
        } else {
            faces.push([q[0], q[1], q[3]]);
            faces.push([q[1], q[2], q[3]]);
        }
    };
    // The margin of the grid guarantees that sign changes never touch its border.
    for k in 1..nz - 1 {
        for j in 1..ny - 1 {
            for i in 1..nx - 1 {
                let here = grid.inside(i, j, k);
                // x-edge (i,j,k)-(i+1,j,k); cells around it in the (y, z) plane, y × z = x.
                if i + 1 < nx && grid.inside(i + 1, j, k) != here {
                    let q = [cv(i, j - 1, k - 1), cv(i, j, k - 1), cv(i, j, k), cv(i, j - 1, k)];
                    emit(q, here, &vertices);
                }
                // y-edge; cells in the (z, x) plane, z × x = y.
                if j + 1 < ny && grid.inside(i, j + 1, k) != here {
                    let q = [cv(i - 1, j, k - 1), cv(i - 1, j, k), cv(i, j, k), cv(i, j, k - 1)];
                    emit(q, here, &vertices);
                }
                // z-edge; cells in the (x, y) plane, x × y = z.
                if k + 1 < nz && grid.inside(i, j, k + 1) != here {
                    let q = [cv(i - 1, j - 1, k), cv(i, j - 1, k), cv(i, j, k), cv(i - 1, j, k)];
                    emit(q, here, &vertices);
                }
            }
        }
    }
    SymmetricSurface { vertices, faces, symmetry }
}

/// Checks that `faces` over `n_vertices` vertices form a closed, consistently oriented,
/// connected 2-manifold of genus 0 using every vertex; returns the first problem found.
pub(crate) fn check_closed_sphere(n_vertices: usize, faces: &[[usize; 3]]) -> Result<(), String> {
    let n = n_vertices as u64;
    let mut directed: Vec<u64> = Vec::with_capacity(3 * faces.len());
    for f in faces {
        for e in 0..3 {
            directed.push(f[e] as u64 * n + f[(e + 1) % 3] as u64);
        }
    }
    directed.sort_unstable();
    if let Some(w) = directed.windows(2).find(|w| w[0] == w[1]) {
        return Err(format!("directed edge {}→{} used twice", w[0] / n, w[0] % n));
    }
    for &e in &directed {
        let (a, b) = (e / n, e % n);
        if directed.binary_search(&(b * n + a)).is_err() {
            return Err(format!("edge {a}–{b} has one face (boundary or inconsistent orientation)"));
        }
    }
    // Vertex links must be single cycles.
    // Each face at a vertex as its (next, previous) corners: the fan, walked below.
    let (offsets, corners) = crate::mesh::face_neighbour_lists(faces, n_vertices);
    if let Some(v) = (0..n_vertices).find(|&v| offsets[v + 1] == offsets[v]) {
        return Err(format!("vertex {v} is not used by any face"));
    }
    let fan: Vec<(usize, usize)> = corners.chunks_exact(2).map(|c| (c[0], c[1])).collect();
    let fan_start: Vec<usize> = offsets.iter().map(|&o| o / 2).collect();
    for v in 0..n_vertices {
        let list = &fan[fan_start[v]..fan_start[v + 1]];
        let mut cur = list[0].1;
        let mut steps = 1;
        while cur != list[0].0 {
            match list.iter().find(|&&(a, _)| a == cur) {
                Some(&(_, b)) => cur = b,
                None => return Err(format!("vertex {v} has a broken fan")),
            }
            steps += 1;
            if steps > list.len() {
                return Err(format!("vertex {v} has a broken fan"));
            }
        }
        if steps != list.len() {
            return Err(format!("vertex {v} is non-manifold ({} fans)", 1 + (steps < list.len()) as usize));
        }
    }
    // Connectivity.
    let mut uf = crate::mesh::UnionFind::new(n_vertices);
    for f in faces {
        uf.union(f[0], f[1]);
        uf.union(f[0], f[2]);
    }
    if uf.labels().1 > 1 {
        return Err("surface has several connected components".to_string());
    }
    let euler = n_vertices as i64 - (directed.len() / 2) as i64 + faces.len() as i64;
    if euler != 2 {
        return Err(format!("Euler characteristic {euler}, expected 2 (genus 0)"));
    }
    Ok(())
}

/// Alternates Delaunay edge flips with tangential smoothing and projection.
fn relax<F: Fn([f64; 3]) -> f64 + Sync>(f: &F, s: &mut SymmetricSurface, h: f64, rounds: usize) {
    let eps = 1e-4 * h;
    for _ in 0..rounds {
        delaunay_flips(&s.vertices, &mut s.faces);
        for _ in 0..3 {
            smooth_step(f, s, eps, 0.6);
        }
    }
    delaunay_flips(&s.vertices, &mut s.faces);
}

/// One pass of tangential uniform-Laplacian relaxation, Newton projection onto the zero set,
/// and exact re-symmetrisation.
fn smooth_step<F: Fn([f64; 3]) -> f64 + Sync>(f: &F, s: &mut SymmetricSurface, eps: f64, step: f64) {
    let n = s.vertices.len();
    let (start, nbr) = face_neighbour_lists(&s.faces, n);
    let old = &s.vertices;
    let moved: Vec<[f64; 3]> = (0..n)
        .into_par_iter()
        .map(|v| {
            let p = old[v];
            let ns = &nbr[start[v]..start[v + 1]];
            // Each neighbour appears twice (once per incident face), which is harmless.
            let mut c = [0.0; 3];
            for &u in ns {
                for d in 0..3 {
                    c[d] += old[u][d];
                }
            }
            let m = ns.len() as f64;
            let delta = [c[0] / m - p[0], c[1] / m - p[1], c[2] / m - p[2]];
            let g = forward_gradient(f, p, eps);
            let g2 = dot(g, g);
            if g2 <= 0.0 {
                return p;
            }
            let dn = dot(delta, g) / g2;
            let mut q = [0.0; 3];
            for d in 0..3 {
                q[d] = p[d] + step * (delta[d] - dn * g[d]);
            }
            // Newton steps along the (nearby) gradient: q ← q − f(q) ∇f / |∇f|².
            for _ in 0..2 {
                let value = eval(f, q);
                for d in 0..3 {
                    q[d] -= value * g[d] / g2;
                }
            }
            q
        })
        .collect();
    s.vertices = moved;
    symmetrise(&mut s.vertices, &s.symmetry);
}

/// Makes positions exactly mirror-symmetric: each pair is replaced by the average of one and
/// the mirror image of the other; self-mirrored vertices are put on the plane.
pub(crate) fn symmetrise(vertices: &mut [[f64; 3]], symmetry: &[usize]) {
    for v in 0..vertices.len() {
        let m = symmetry[v];
        if m == v {
            vertices[v][0] = 0.0;
        } else if m > v {
            let (p, q) = (vertices[v], vertices[m]);
            let avg = [0.5 * (p[0] - q[0]), 0.5 * (p[1] + q[1]), 0.5 * (p[2] + q[2])];
            vertices[v] = avg;
            vertices[m] = [-avg[0], avg[1], avg[2]];
        }
    }
}

/// Angle at `a` in the triangle `(a, b, c)`.
fn angle_at(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> f64 {
    let (u, v) = (sub(b, a), sub(c, a));
    norm(cross(u, v)).atan2(dot(u, v))
}

fn unit_normal(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> [f64; 3] {
    let n = cross(sub(b, a), sub(c, a));
    let l = norm(n);
    if l > 0.0 {
        [n[0] / l, n[1] / l, n[2] / l]
    } else {
        [0.0; 3]
    }
}

/// Sweeps of edge flips towards the (extrinsic) Delaunay condition: an interior edge `ab` with
/// opposite vertices `c`, `d` is flipped when the opposite angles sum beyond π, provided the
/// two faces are nearly coplanar, the new edge `cd` does not exist yet, neither `a` nor `b`
/// would drop below valence 3, and the new faces do not fold over.
fn delaunay_flips(vertices: &[[f64; 3]], faces: &mut [[usize; 3]]) {
    type HashMap<K, V> = std::collections::HashMap<K, V, BuildHasherDefault<EdgeHasher>>;
    let key = |a: usize, b: usize| (a.min(b), a.max(b));
    let n = vertices.len() as u64;
    // Half-edges sorted by undirected edge, the one running min→max first: pairs give every
    // edge with its two faces, in a deterministic order.
    let mut half: Vec<(u64, usize)> = Vec::with_capacity(3 * faces.len());
    for (fi, f) in faces.iter().enumerate() {
        for e in 0..3 {
            let (a, b) = (f[e], f[(e + 1) % 3]);
            let k = 2 * (a.min(b) as u64 * n + a.max(b) as u64) + (a > b) as u64;
            half.push((k, fi));
        }
    }
    half.sort_unstable();
    let mut edges: Vec<(usize, usize, usize, usize)> = Vec::with_capacity(half.len() / 2);
    let mut edge_faces: HashMap<(usize, usize), [usize; 2]> =
        HashMap::with_capacity_and_hasher(half.len() / 2, Default::default());
    let mut valence = vec![0usize; vertices.len()];
    for pair in half.chunks_exact(2) {
        // The surface is closed, so half-edges pair up exactly.
        let k = pair[0].0 / 2;
        let (a, b) = ((k / n) as usize, (k % n) as usize);
        edges.push((a, b, pair[0].1, pair[1].1));
        edge_faces.insert((a, b), [pair[0].1, pair[1].1]);
        valence[a] += 1;
        valence[b] += 1;
    }
    let has = |f: [usize; 3], a: usize, b: usize| (0..3).any(|e| f[e] == a && f[(e + 1) % 3] == b);
    for _sweep in 0..2 {
        let mut flipped = 0;
        for edge in edges.iter_mut() {
            let (a, b, mut f1, mut f2) = *edge;
            if !has(faces[f1], a, b) || !has(faces[f2], b, a) {
                // A neighbouring flip moved this edge to other faces.
                let Some(&[g1, g2]) = edge_faces.get(&(a, b)) else { continue };
                (f1, f2) = (g1, g2);
            }
            // f1 contains a→b, f2 contains b→a.
            let c = third(faces[f1], a, b);
            let d = third(faces[f2], a, b);
            if c == d || valence[a] <= 3 || valence[b] <= 3 {
                continue;
            }
            let (pa, pb, pc, pd) = (vertices[a], vertices[b], vertices[c], vertices[d]);
            let alpha = angle_at(pc, pa, pb);
            let beta = angle_at(pd, pa, pb);
            if alpha + beta <= std::f64::consts::PI + 1e-9 || edge_faces.contains_key(&key(c, d)) {
                continue;
            }
            let (n1, n2) = (unit_normal(pa, pb, pc), unit_normal(pb, pa, pd));
            if dot(n1, n2) < 0.2 {
                continue;
            }
            let (m1, m2) = (unit_normal(pa, pd, pc), unit_normal(pb, pc, pd));
            let avg = [n1[0] + n2[0], n1[1] + n2[1], n1[2] + n2[2]];
            if dot(m1, avg) <= 0.0 || dot(m2, avg) <= 0.0 || dot(m1, m2) < 0.2 {
                continue;
            }
            faces[f1] = [a, d, c];
            faces[f2] = [b, c, d];
            edge_faces.remove(&(a, b));
            // New edge c–d: f1 has d→c, f2 has c→d.
            let slot_f2 = (c > d) as usize;
            let mut pair = [usize::MAX; 2];
            pair[slot_f2] = f2;
            pair[1 - slot_f2] = f1;
            edge_faces.insert(key(c, d), pair);
            // Edge b–c moved from f1 to f2; edge a–d moved from f2 to f1.
            if let Some(p) = edge_faces.get_mut(&key(b, c)) {
                for s in p.iter_mut() {
                    if *s == f1 {
                        *s = f2;
                    }
                }
            }
            if let Some(p) = edge_faces.get_mut(&key(a, d)) {
                for s in p.iter_mut() {
                    if *s == f2 {
                        *s = f1;
                    }
                }
            }
            valence[a] -= 1;
            valence[b] -= 1;
            valence[c] += 1;
            valence[d] += 1;
            *edge = if c < d { (c, d, f2, f1) } else { (d, c, f1, f2) };
            flipped += 1;
        }
        if flipped == 0 {
            break;
        }
    }
}

/// A fast multiplicative hasher for small integer keys (edges); not DoS-resistant, which is
/// irrelevant for internally generated keys.
#[derive(Default)]
struct EdgeHasher(u64);

impl Hasher for EdgeHasher {
    fn finish(&self) -> u64 {
        // splitmix64 finaliser: every output bit depends on every input bit.
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(b as u64);
        }
    }
    fn write_u64(&mut self, x: u64) {
        self.0 = (self.0.rotate_left(5) ^ x).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    fn write_usize(&mut self, x: usize) {
        self.write_u64(x as u64);
    }
}

/// The vertex of `f` that is neither `a` nor `b`.
#[inline]
fn third(f: [usize; 3], a: usize, b: usize) -> usize {
    f.into_iter().find(|&v| v != a && v != b).unwrap_or(f[0])
}
