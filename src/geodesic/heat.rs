//! The heat method for geodesic distance (Crane, Weischedel, Wardetzky, "Geodesics in heat",
//! ACM TOG 2013): one backward-Euler heat step, normalised negative gradient, Poisson solve.

use std::sync::Arc;

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::cholesky::{LltRef, SymbolicCholesky};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Conj, Mat, MatMut, Par};
use rayon::prelude::*;

use crate::mesh::{cross, dot, norm, sub, Mesh};
use crate::spectral::cholesky::{
    fill_reducing_positions, numeric_llt, permuted, supernodal_symbolic_in_order,
};

use super::topology::{check_sources, edges_with_face_counts, vertex_components, vertex_on_boundary};
use super::{mean_edge_length, GeodesicError};

/// Boundary condition of the heat step on meshes with boundary (ignored on closed meshes).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum HeatBoundary {
    /// Zero normal derivative (insulated boundary): iso-lines meet the boundary at right angles.
    /// Accurate in the interior, iso-lines bend near the boundary.
    Neumann,
    /// Heat fixed to zero on the boundary: iso-lines run parallel to it near the boundary.
    /// A source on the boundary keeps its unit heat while the rest of the boundary is held at
    /// zero, which is inaccurate (34 % max relative error on a unit-square grid, against 3 %
    /// for `Neumann`/`Average`): prefer `Average` there.
    Dirichlet,
    /// The mean of the Neumann and Dirichlet heat solutions, the compromise the paper
    /// recommends (§3.2.3); it costs a second factorisation on meshes with boundary.
    #[default]
    Average,
}

/// Parameters of a [`HeatMethodSolver`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeatParams {
    /// The heat time is `t = time_factor · h²`, `h` the mean edge length. The paper's choice is
    /// 1; larger values smooth the distance (useful on noisy meshes), smaller ones sharpen it
    /// until the heat no longer reaches far vertices in floating point.
    pub time_factor: f64,
    /// Boundary condition of the heat step.
    pub boundary: HeatBoundary,
}

impl Default for HeatParams {
    fn default() -> Self {
        Self { time_factor: 1.0, boundary: HeatBoundary::Average }
    }
}

/// A sparse LLᵀ factor (faer supernodal Cholesky, AMD ordering) with explicit parallelism.
struct Cholesky {
    symbolic: Arc<SymbolicCholesky<usize>>,
    values: Vec<f64>,
}

impl Cholesky {
    /// Symbolic analysis of a matrix already in its fill-reducing order.
    fn symbolic(a: &SparseColMat<usize, f64>) -> Result<Arc<SymbolicCholesky<usize>>, GeodesicError> {
        supernodal_symbolic_in_order(a)
            .map(Arc::new)
            .map_err(|reason| GeodesicError::Factorization { matrix: "symbolic", reason })
    }

    fn numeric(
        symbolic: Arc<SymbolicCholesky<usize>>,
        a: &SparseColMat<usize, f64>,
        matrix: &'static str,
    ) -> Result<Self, GeodesicError> {
        let values =
            numeric_llt(&symbolic, a).map_err(|reason| GeodesicError::Factorization { matrix, reason })?;
        Ok(Self { symbolic, values })
    }

    /// Solves in place for a column-major `n × s` block; columns are split across the rayon
    /// pool (each chunk solved sequentially, which beats faer's internal parallelism here).
    fn solve_block(&self, buf: &mut [f64], n: usize) {
        if n == 0 {
            return;
        }
        let s = buf.len() / n;
        let threads = rayon::current_num_threads().max(1);
        let cols_per_chunk = s.div_ceil(threads).max(1);
        buf.par_chunks_mut(cols_per_chunk * n).for_each(|chunk| {
            let k = chunk.len() / n;
            let mut mem = MemBuffer::new(self.symbolic.solve_in_place_scratch::<f64>(k, Par::Seq));
            let rhs = MatMut::from_column_major_slice_mut(chunk, n, k);
            LltRef::new(&self.symbolic, &self.values).solve_in_place_with_conj(
                Conj::No,
                rhs,
                Par::Seq,
                MemStack::new(&mut mem),
            );
        });
    }
}

/// Per-face data of the discrete gradient and divergence.
#[derive(Clone, Copy, Debug, Default)]
struct FaceOperator {
    /// Gradient of the hat function of each corner (`N × e_i / 2A`, `e_i` the opposite edge).
    hat_gradient: [[f64; 3]; 3],
    /// Divergence weights: corner `i` receives `divergence_weight[i] · X` from a face field `X`
    /// (`½ (cot θ_k (p_j − p_i) + cot θ_j (p_k − p_i))`).
    divergence_weight: [[f64; 3]; 3],
}

impl FaceOperator {
    /// Gradient of the linear interpolant of the corner values `u` (the solver computes it lane
    /// by lane in [`divergence_of_normalised_gradient`]; the tests check both against this).
    #[cfg(test)]
    fn gradient(&self, u: [f64; 3]) -> [f64; 3] {
        let [a, b, c] = self.hat_gradient;
        [
            u[0] * a[0] + u[1] * b[0] + u[2] * c[0],
            u[0] * a[1] + u[1] * b[1] + u[2] * c[1],
            u[0] * a[2] + u[1] * b[2] + u[2] * c[2],
        ]
    }

    fn new(p: [[f64; 3]; 3]) -> Self {
        let n = cross(sub(p[1], p[0]), sub(p[2], p[0]));
        let double_area = norm(n);
        let scale = dot(sub(p[1], p[0]), sub(p[1], p[0])).max(dot(sub(p[2], p[0]), sub(p[2], p[0])));
        if !(double_area > 1e-14 * scale) || !double_area.is_finite() {
            return Self::default(); // degenerate face: contributes nothing
        }
        let unit = [n[0] / double_area, n[1] / double_area, n[2] / double_area];
        let mut op = Self::default();
        for i in 0..3 {
            let (j, k) = ((i + 1) % 3, (i + 2) % 3);
            let e = sub(p[k], p[j]);
            let g = cross(unit, e);
            op.hat_gradient[i] = [g[0] / double_area, g[1] / double_area, g[2] / double_area];
            // cot of the angle at corner c between edges to a and b = (u·v)/|u×v|, |u×v| = 2A
            let cot_at = |c: usize, a: usize, b: usize| dot(sub(p[a], p[c]), sub(p[b], p[c])) / double_area;
            let cot_k = cot_at(k, i, j);
            let cot_j = cot_at(j, k, i);
            let eij = sub(p[j], p[i]);
            let eik = sub(p[k], p[i]);
            op.divergence_weight[i] = [
                0.5 * (cot_k * eij[0] + cot_j * eik[0]),
                0.5 * (cot_k * eij[1] + cot_j * eik[1]),
                0.5 * (cot_k * eij[2] + cot_j * eik[2]),
            ];
        }
        op
    }
}

/// Dirichlet part of the solver: the heat operator restricted to interior vertices.
struct DirichletSystem {
    /// Interior index of each vertex (`usize::MAX` on the boundary).
    interior_index: Vec<usize>,
    /// Interior vertices in order.
    interior: Vec<usize>,
    /// Factor of `(M + tL)_II` (absent when every vertex lies on the boundary).
    factor: Option<Cholesky>,
    /// The full heat operator `M + tL`, to move boundary data to the right-hand side.
    heat_operator: SparseColMat<usize, f64>,
}

/// Geodesic distances by the heat method, with both factorisations cached.
///
/// Built once per mesh ([`HeatMethodSolver::new`]: the heat operator `M + tL` and the Poisson
/// operator `L + εM` are factorised with faer's supernodal sparse Cholesky, sharing one
/// symbolic analysis), then queried for any number of sources; several sources are solved as
/// one block of right-hand sides ([`HeatMethodSolver::distances_from_many`]), which is several
/// times faster than one at a time.
///
/// Conventions: `L` is the positive semi-definite cotangent stiffness matrix and `M` the
/// lumped mass ([`crate::spectral`]); distances are in mesh units, shifted to be exactly 0 at
/// the source and clamped below at 0 (the raw heat-method field may dip a hair below the
/// source value next to it); vertices in another connected component than the source get
/// `f64::INFINITY`.
///
/// ```
/// use shapeforest::geodesic::{HeatMethodSolver, HeatParams};
/// let sphere = shapeforest::synth::icosphere(4, 1.0);
/// let solver = HeatMethodSolver::new(&sphere, HeatParams::default()).unwrap();
/// let d = solver.distances_from(0).unwrap();
/// assert_eq!(d[0], 0.0);
/// // the antipode of vertex 0 is at great-circle distance π
/// let far = d.iter().cloned().fold(0.0, f64::max);
/// assert!((far - std::f64::consts::PI).abs() < 0.05);
/// ```
pub struct HeatMethodSolver {
    n_vertices: usize,
    /// Faces, with their corners' positions in the solver's order.
    faces: Vec<[usize; 3]>,
    face_operators: Vec<FaceOperator>,
    /// Connected component of each position.
    components: Vec<usize>,
    /// Position of each vertex in the solver's (fill-reducing) order.
    position: Vec<usize>,
    time: f64,
    boundary: HeatBoundary,
    heat_neumann: Cholesky,
    dirichlet: Option<DirichletSystem>,
    poisson: Cholesky,
    /// Heat put at a source (a power of two, see [`source_heat`]).
    source_heat: f64,
}

impl std::fmt::Debug for HeatMethodSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HeatMethodSolver")
            .field("n_vertices", &self.n_vertices)
            .field("time", &self.time)
            .field("boundary", &self.boundary)
            .field("has_boundary", &self.dirichlet.is_some())
            .finish_non_exhaustive()
    }
}

/// `a + c·b` for two matrices given as triplets over the same vertex set, with a unit diagonal
/// on vertices that touch no face (so the operators stay positive definite).
fn combine(
    n: usize,
    stiffness: &SparseColMat<usize, f64>,
    stiffness_factor: f64,
    mass: &[f64],
    mass_factor: f64,
) -> Result<SparseColMat<usize, f64>, GeodesicError> {
    let sym = stiffness.symbolic();
    let vals = stiffness.val();
    // Fast path: every column holds its diagonal, so the sum keeps the pattern of `stiffness`.
    let mut values = Vec::with_capacity(vals.len());
    let mut all_diagonals = true;
    for (j, &mass_j) in mass.iter().enumerate() {
        let range = sym.col_range(j);
        let mut found = false;
        for (&i, &v) in sym.row_idx()[range.clone()].iter().zip(&vals[range]) {
            let mut x = stiffness_factor * v;
            if i == j {
                found = true;
                x += if mass_j > 0.0 { mass_factor * mass_j } else { 1.0 };
            }
            values.push(x);
        }
        all_diagonals &= found;
    }
    if all_diagonals {
        return Ok(SparseColMat::new(sym.to_owned().map_err(assembly_error)?, values));
    }
    let mut triplets = Vec::with_capacity(stiffness.compute_nnz() + n);
    for j in 0..n {
        let range = sym.col_range(j);
        for (&i, &v) in sym.row_idx()[range.clone()].iter().zip(&vals[range]) {
            triplets.push(Triplet::new(i, j, stiffness_factor * v));
        }
    }
    for (v, &m) in mass.iter().enumerate() {
        let d = if m > 0.0 { mass_factor * m } else { 1.0 };
        triplets.push(Triplet::new(v, v, d));
    }
    SparseColMat::try_new_from_triplets(n, n, &triplets).map_err(assembly_error)
}

/// The diagonal of a sparse matrix (0 where a column has none).
fn diagonal_of(a: &SparseColMat<usize, f64>) -> Vec<f64> {
    let sym = a.symbolic();
    (0..a.ncols())
        .map(|j| {
            let range = sym.col_range(j);
            sym.row_idx()[range.clone()]
                .iter()
                .zip(&a.val()[range])
                .find(|(&i, _)| i == j)
                .map_or(0.0, |(_, &v)| v)
        })
        .collect()
}

fn assembly_error(e: impl std::fmt::Debug) -> GeodesicError {
    GeodesicError::Factorization { matrix: "assembly", reason: format!("{e:?}") }
}

/// The heat put at a source: a power of two that makes the largest heat value about 2^600.
///
/// With a unit source, the heat `(M + tL)⁻¹ δ` decays exponentially away from the source: some
/// 850 edge lengths away it underflows to zero, and faces without heat have no gradient, so the
/// distance field beyond is wrong (on a strip 1,100 edges long it collapsed to 0). On the TOSCA
/// meshes (28K–53K vertices) the heat never leaves the normal range, and the scaled source
/// gives the same distances bit for bit, in the same time. The heat step and the Poisson
/// right-hand side are linear and scale-free respectively (the gradient is normalised), so a
/// power-of-two source changes no normal value by a single bit; it only moves the underflow
/// some 180 decades farther out. The largest heat is at most `source / min M` (the heat
/// operator is diagonally dominant with row sums `M`), so `2^600 · min M` leaves ~2^420 of room
/// below overflow.
fn source_heat(mass: &[f64]) -> f64 {
    let min_mass = mass.iter().copied().filter(|&m| m > 0.0 && m.is_finite()).fold(f64::INFINITY, f64::min);
    if !min_mass.is_finite() {
        return 1.0;
    }
    let exponent = (600.0 + min_mass.log2()).floor().clamp(-1000.0, 1000.0) as i32;
    2f64.powi(exponent)
}

/// Sources solved together by [`HeatMethodSolver`]: a block large enough that each solve reads
/// the factors for many columns, small enough that its work buffer (`n ×` this many values,
/// 53 MB at 52K vertices) is reused across batches rather than a few hundred columns' worth
/// of fresh pages (each first touch a page fault; on a virtual machine ~2.4 µs per 4 KiB).
const BATCH_COLUMNS: usize = 128;

/// Columns processed side by side in the gradient and divergence step.
const COLUMN_GROUP: usize = 8;

/// Vertex-indexed `values` in the solver's order (the value of vertex `v` at `position[v]`).
fn in_solver_order<T: Copy + Default>(values: &[T], position: &[usize]) -> Vec<T> {
    let mut out = vec![T::default(); values.len()];
    for (&p, &x) in position.iter().zip(values) {
        out[p] = x;
    }
    out
}

/// The work buffers of a call (`n × b` values each, `b` ≤ [`BATCH_COLUMNS`], the solver's
/// order), reused by each of its batches: the heat, then in place the Poisson right-hand side
/// and the distances; on meshes with boundary also the interior right-hand side of the
/// Dirichlet heat. (Keeping them in the solver between calls as well saved no time and cost a
/// 52K-vertex match 170 MB of peak memory.)
#[derive(Default)]
struct Work {
    heat: Vec<f64>,
    interior: Vec<f64>,
}

/// `buf` as `len` zeros: rewritten in place where it has room, else fresh [`written_zeros`].
fn zeroed(buf: &mut Vec<f64>, len: usize) -> &mut [f64] {
    if buf.capacity() < len {
        *buf = written_zeros(len);
    } else {
        buf.resize(len, 0.0); // within capacity: no new pages
        buf.par_iter_mut().for_each(|x| *x = 0.0);
    }
    &mut buf[..]
}

/// A vector of `len` zeros whose pages have been written (in parallel), not only mapped.
/// A large `vec![0.0; len]` gets fresh pages that the kernel maps to its shared zero page on
/// the first read; a solve that reads a mostly-zero right-hand side before writing it then
/// takes a copy-on-write fault per page, each with a TLB flush on every core (measured: 12 % of
/// the samples of a 28K-vertex scan's `match`, all in the heat method's block solves). Written
/// zeros cost one plain fault per page instead.
fn written_zeros(len: usize) -> Vec<f64> {
    let mut v = Vec::with_capacity(len);
    v.par_extend(rayon::iter::repeat_n(0.0, len));
    v
}

/// Every face's share of `−div X` (see [`divergence_of_normalised_gradient`]), added into `rt`
/// in face order, compiled for the widest vector unit the CPU has (the eight lanes of a group
/// are one AVX-512 register): the same operations in the same order on every path, so the same
/// bits (no fused multiply-adds: Rust does not contract `a * b + c`).
fn divergence_pass(faces: &[[usize; 3]], ops: &[FaceOperator], ut: &[f64], rt: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F, checked just above.
            unsafe { divergence_pass_avx512(faces, ops, ut, rt) };
            return;
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, checked just above.
            unsafe { divergence_pass_avx2(faces, ops, ut, rt) };
            return;
        }
    }
    divergence_pass_impl(faces, ops, ut, rt);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn divergence_pass_avx512(faces: &[[usize; 3]], ops: &[FaceOperator], ut: &[f64], rt: &mut [f64]) {
    divergence_pass_impl(faces, ops, ut, rt);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn divergence_pass_avx2(faces: &[[usize; 3]], ops: &[FaceOperator], ut: &[f64], rt: &mut [f64]) {
    divergence_pass_impl(faces, ops, ut, rt);
}

#[inline(always)]
fn divergence_pass_impl(faces: &[[usize; 3]], ops: &[FaceOperator], ut: &[f64], rt: &mut [f64]) {
    for (f, op) in faces.iter().zip(ops) {
        divergence_of_normalised_gradient(op, f, ut, rt);
    }
}

/// One face's share of `−div X`, `X = −∇u/|∇u|`, for the `COLUMN_GROUP` interleaved columns of
/// `u` (`u[v · COLUMN_GROUP + c]`), added into `rhs` (same layout): `rhs_i += w_i · ∇u/|∇u|`,
/// with `∇u` scaled by `1/max|∇u_d|` first so that tiny far-field gradients do not underflow
/// when squared. A face where a column's gradient is zero or not finite adds nothing to it.
#[inline(always)]
fn divergence_of_normalised_gradient(op: &FaceOperator, f: &[usize; 3], u: &[f64], rhs: &mut [f64]) {
    const G: usize = COLUMN_GROUP;
    let [a, b, c] = op.hat_gradient;
    let (u0, u1, u2) = (&u[f[0] * G..f[0] * G + G], &u[f[1] * G..f[1] * G + G], &u[f[2] * G..f[2] * G + G]);
    let (mut g0, mut g1, mut g2, mut k) = ([0.0; G], [0.0; G], [0.0; G], [0.0; G]);
    let mut valid = [false; G];
    for l in 0..G {
        // FaceOperator::gradient, lane by lane
        g0[l] = u0[l] * a[0] + u1[l] * b[0] + u2[l] * c[0];
        g1[l] = u0[l] * a[1] + u1[l] * b[1] + u2[l] * c[1];
        g2[l] = u0[l] * a[2] + u1[l] * b[2] + u2[l] * c[2];
        let m = g0[l].abs().max(g1[l].abs()).max(g2[l].abs());
        valid[l] = m > 0.0 && m.is_finite();
        let inv_m = 1.0 / m;
        k[l] = inv_m / norm([g0[l] * inv_m, g1[l] * inv_m, g2[l] * inv_m]);
    }
    for (&v, w) in f.iter().zip(&op.divergence_weight) {
        let out = &mut rhs[v * G..v * G + G];
        for l in 0..G {
            if valid[l] {
                out[l] += dot(*w, [g0[l], g1[l], g2[l]]) * k[l];
            }
        }
    }
}

impl HeatMethodSolver {
    /// Builds the solver: assembles `L`, `M`, the heat operator `M + tL` (with
    /// `t = time_factor · h²`) and the Poisson operator `L + εM` (`ε = 1e-8 / area`, which
    /// removes the constant null space; the constant it leaves is cancelled by the shift to
    /// zero at the source), and factorises them. On meshes with boundary and
    /// [`HeatBoundary::Dirichlet`] or [`HeatBoundary::Average`], the interior block of the heat
    /// operator is factorised too.
    pub fn new(mesh: &Mesh, params: HeatParams) -> Result<Self, GeodesicError> {
        if !(params.time_factor.is_finite() && params.time_factor > 0.0) {
            return Err(GeodesicError::InvalidTimeFactor { time_factor: params.time_factor });
        }
        let n = mesh.n_vertices();
        let h = mean_edge_length(mesh);
        let area = mesh.surface_area();
        if !(h > 0.0 && area > 0.0) {
            return Err(GeodesicError::DegenerateMesh);
        }
        let time = params.time_factor * h * h;
        // the tufted Laplacian on non-manifold meshes and point clouds (positive definite M + tL)
        let operator = crate::spectral::surface_operator(mesh);
        let (l, mass) = (operator.stiffness(), operator.mass);

        let heat_op = combine(n, &l, time, &mass, 1.0)?;
        // Poisson: L + εM, and one vertex of every connected component pinned (its own
        // diagonal added once more). εM alone leaves a small component with a pivot of order
        // ε·area(component), below round-off on a fragmented scan; the pin keeps each block
        // well conditioned and changes nothing else: the divergence sums to zero over each
        // component, so the pinned solve differs from the exact one by a constant per
        // component, which the shift to zero at the source removes.
        let components = vertex_components(mesh);
        let diagonal = diagonal_of(&l);
        let mut seen = vec![false; n];
        let poisson_diag: Vec<f64> = (0..n)
            .map(|v| {
                let eps_m = 1e-8 / area * mass[v];
                let c = components[v];
                if c < n && !seen[c] && diagonal[v] > 0.0 {
                    seen[c] = true;
                    eps_m + diagonal[v]
                } else {
                    eps_m
                }
            })
            .collect();
        let poisson_op = combine(n, &l, 1.0, &poisson_diag, 1.0)?;
        // Both operators are factorised, and every vector of the solver lives, in one
        // fill-reducing order (AMD of the heat operator's pattern) fixed here: the block solves
        // then need no permutation of their right-hand sides (otherwise a gather and a scatter
        // of every column per solve, and an n × s scratch block). Columns go back to vertex
        // order once, when they leave the solver.
        let position = fill_reducing_positions(&heat_op)
            .map_err(|reason| GeodesicError::Factorization { matrix: "symbolic", reason })?;
        let reorder = |a: &SparseColMat<usize, f64>| permuted(a, &position).map_err(assembly_error);
        let (heat_op, poisson_op) = (reorder(&heat_op)?, reorder(&poisson_op)?);
        let symbolic = Cholesky::symbolic(&heat_op)?;
        // the two numeric factorisations are independent: run them side by side
        let (heat_neumann, poisson) = rayon::join(
            || Cholesky::numeric(symbolic.clone(), &heat_op, "heat operator M + tL"),
            || Cholesky::numeric(symbolic.clone(), &poisson_op, "Poisson operator L + εM"),
        );
        let (heat_neumann, poisson) = (heat_neumann?, poisson?);

        let edges = edges_with_face_counts(mesh);
        let on_boundary = in_solver_order(&vertex_on_boundary(mesh, &edges), &position);
        let dirichlet = if params.boundary != HeatBoundary::Neumann && on_boundary.iter().any(|&b| b) {
            Some(Self::dirichlet_system(&heat_op, &on_boundary)?)
        } else {
            None
        };

        let face_operators = mesh
            .faces
            .par_iter()
            .map(|f| FaceOperator::new([mesh.vertices[f[0]], mesh.vertices[f[1]], mesh.vertices[f[2]]]))
            .collect();

        let source_heat = source_heat(&mass);
        Ok(Self {
            n_vertices: n,
            faces: mesh.faces.iter().map(|f| f.map(|v| position[v])).collect(),
            face_operators,
            components: in_solver_order(&components, &position),
            position,
            time,
            boundary: params.boundary,
            heat_neumann,
            dirichlet,
            poisson,
            source_heat,
        })
    }

    fn dirichlet_system(
        heat_op: &SparseColMat<usize, f64>,
        on_boundary: &[bool],
    ) -> Result<DirichletSystem, GeodesicError> {
        let n = on_boundary.len();
        let mut interior_index = vec![usize::MAX; n];
        let mut interior = Vec::new();
        for v in 0..n {
            if !on_boundary[v] {
                interior_index[v] = interior.len();
                interior.push(v);
            }
        }
        let ni = interior.len();
        let factor = if ni == 0 {
            None
        } else {
            let sym = heat_op.symbolic();
            let vals = heat_op.val();
            let mut triplets = Vec::new();
            for &j in &interior {
                let range = sym.col_range(j);
                for (&i, &v) in sym.row_idx()[range.clone()].iter().zip(&vals[range]) {
                    if interior_index[i] != usize::MAX {
                        triplets.push(Triplet::new(interior_index[i], interior_index[j], v));
                    }
                }
            }
            let a = SparseColMat::try_new_from_triplets(ni, ni, &triplets)
                .map_err(|e| GeodesicError::Factorization { matrix: "assembly", reason: format!("{e:?}") })?;
            let symbolic = Cholesky::symbolic(&a)?;
            Some(Cholesky::numeric(symbolic, &a, "interior heat operator (M + tL)_II")?)
        };
        Ok(DirichletSystem { interior_index, interior, factor, heat_operator: heat_op.clone() })
    }

    /// Number of vertices of the mesh the solver was built for.
    pub fn n_vertices(&self) -> usize {
        self.n_vertices
    }

    /// The heat time `t = time_factor · h²` in squared mesh units.
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Geodesic distance from `source` to every vertex.
    pub fn distances_from(&self, source: usize) -> Result<Vec<f64>, GeodesicError> {
        check_sources(&[source], self.n_vertices)?;
        let mut out = Vec::new();
        self.solve_in_batches(&[source], |_, col| out = self.in_vertex_order(col).collect());
        Ok(out)
    }

    /// Geodesic distances from each source: an `n × s` matrix whose column `j` holds the
    /// distances from `sources[j]` to every vertex. All sources are solved as blocks of
    /// right-hand sides; gradient, divergence and shifts run in parallel across columns.
    pub fn distances_from_many(&self, sources: &[usize]) -> Result<Mat<f64>, GeodesicError> {
        check_sources(sources, self.n_vertices)?;
        let n = self.n_vertices;
        let mut out = Mat::zeros(n, sources.len());
        self.solve_in_batches(sources, |first, batch| {
            for (j, col) in batch.chunks(n).enumerate() {
                for (x, d) in out.col_mut(first + j).iter_mut().zip(self.in_vertex_order(col)) {
                    *x = d;
                }
            }
        });
        Ok(out)
    }

    /// Geodesic distances from each source, one shared column per source (as
    /// [`Self::distances_from_many`], without the intermediate matrix).
    pub fn distance_columns(&self, sources: &[usize]) -> Result<Vec<Arc<[f64]>>, GeodesicError> {
        self.columns_as(sources, |d| d)
    }

    /// As [`Self::distance_columns`], each distance rounded to `f32`: half the memory, for
    /// columns that are kept (the rounding, a relative 6·10⁻⁸, is far below the heat method's own
    /// error of a percent or more).
    pub fn distance_columns_f32(&self, sources: &[usize]) -> Result<Vec<Arc<[f32]>>, GeodesicError> {
        self.columns_as(sources, |d| d as f32)
    }

    /// One shared column per source, each distance converted by `convert`.
    fn columns_as<T: Send + Sync>(
        &self,
        sources: &[usize],
        convert: fn(f64) -> T,
    ) -> Result<Vec<Arc<[T]>>, GeodesicError> {
        check_sources(sources, self.n_vertices)?;
        let n = self.n_vertices;
        if n == 0 {
            return Ok(Vec::new());
        }
        let mut out = Vec::with_capacity(sources.len());
        self.solve_in_batches(sources, |_, batch| {
            out.par_extend(
                batch.par_chunks(n).map(|col| self.in_vertex_order(col).map(convert).collect::<Arc<[T]>>()),
            )
        });
        Ok(out)
    }

    /// A column of the solver's order, vertex by vertex.
    fn in_vertex_order<'a>(&'a self, col: &'a [f64]) -> impl Iterator<Item = f64> + 'a {
        self.position.iter().map(move |&p| col[p])
    }

    /// Solves `sources` (already checked) in batches of at most [`BATCH_COLUMNS`] and hands
    /// each batch to `emit` with the index of its first source: a column-major `n × b` block in
    /// the solver's order (row `position[v]` for vertex `v`). One work buffer serves every
    /// batch, so a few hundred sources cost the fresh pages of one batch, not of all.
    fn solve_in_batches(&self, sources: &[usize], mut emit: impl FnMut(usize, &[f64])) {
        let n = self.n_vertices;
        let rows: Vec<usize> = sources.iter().map(|&v| self.position[v]).collect();
        let mut work = Work::default();
        for (b, batch) in rows.chunks(BATCH_COLUMNS).enumerate() {
            self.solve_batch(batch, &mut work);
            emit(b * BATCH_COLUMNS, &work.heat[..n * batch.len()]);
        }
    }

    /// The whole pipeline for `sources` (positions in the solver's order), into `work.heat`
    /// (resized to `n × sources.len()`, column-major, the solver's order).
    fn solve_batch(&self, sources: &[usize], work: &mut Work) {
        let n = self.n_vertices;
        let heat = zeroed(&mut work.heat, n * sources.len());

        // 1. heat step
        let use_neumann = self.dirichlet.is_none() || self.boundary != HeatBoundary::Dirichlet;
        if use_neumann {
            for (j, &src) in sources.iter().enumerate() {
                heat[j * n + src] = self.source_heat;
            }
            self.heat_neumann.solve_block(heat, n);
        }
        if let Some(dir) = &self.dirichlet {
            // Dirichlet alone, or (Average) its mean with the Neumann heat already in `heat`
            self.dirichlet_heat(dir, sources, &mut work.interior, heat, use_neumann);
        }

        // 2. normalised gradient, 3. divergence (right-hand side of L φ = −div X), in groups of
        // COLUMN_GROUP columns interleaved vertex by vertex: each face's operator (144 bytes) is
        // read once per group instead of once per column, and the lanes of a group are
        // computed side by side (vectorisable). Every column's arithmetic, and the order in
        // which faces add into a vertex, are those of a one-column pass: the same numbers.
        // The right-hand side replaces the heat in place (a group's heat is copied out first),
        // with one pair of group buffers per rayon job rather than per group.
        let group = n * COLUMN_GROUP;
        heat.par_chunks_mut(group).for_each_init(
            || (written_zeros(group), written_zeros(group)),
            |(ut, rt), u| {
                let cols = u.len() / n;
                if cols < COLUMN_GROUP {
                    ut.fill(0.0); // padding lanes: zero heat, zero gradient
                }
                for c in 0..cols {
                    for (v, &x) in u[c * n..(c + 1) * n].iter().enumerate() {
                        ut[v * COLUMN_GROUP + c] = x;
                    }
                }
                rt.fill(0.0);
                divergence_pass(&self.faces, &self.face_operators, ut, rt);
                for c in 0..cols {
                    for (v, x) in u[c * n..(c + 1) * n].iter_mut().enumerate() {
                        *x = rt[v * COLUMN_GROUP + c];
                    }
                }
            },
        );
        let phi = heat;

        // 4. Poisson solve
        self.poisson.solve_block(phi, n);

        // 5. shift to zero at the source, clamp, mark other components unreachable
        phi.par_chunks_mut(n).zip(sources.par_iter()).for_each(|(col, &src)| {
            let at_source = col[src];
            let comp = self.components[src];
            for (v, x) in col.iter_mut().enumerate() {
                *x = if self.components[v] != comp { f64::INFINITY } else { (*x - at_source).max(0.0) };
            }
            col[src] = 0.0;
        });
    }

    /// Heat step with u = δ on the boundary and `(M + tL)_II u_I = δ_I − (M + tL)_IB δ_B`.
    /// Written into `heat` (`n × sources`), or averaged with what it holds when `average`.
    fn dirichlet_heat(
        &self,
        dir: &DirichletSystem,
        sources: &[usize],
        interior: &mut Vec<f64>,
        heat: &mut [f64],
        average: bool,
    ) {
        let n = self.n_vertices;
        let ni = dir.interior.len();
        let interior_rhs = zeroed(interior, ni * sources.len());
        let sym = dir.heat_operator.symbolic();
        let vals = dir.heat_operator.val();
        for (j, &src) in sources.iter().enumerate() {
            let col = &mut interior_rhs[j * ni..(j + 1) * ni];
            let k = dir.interior_index[src];
            if k != usize::MAX {
                col[k] = self.source_heat;
            } else {
                let range = sym.col_range(src);
                for (&i, &v) in sym.row_idx()[range.clone()].iter().zip(&vals[range]) {
                    let ii = dir.interior_index[i];
                    if ii != usize::MAX {
                        col[ii] -= v * self.source_heat;
                    }
                }
            }
        }
        if let Some(factor) = &dir.factor {
            factor.solve_block(interior_rhs, ni);
        }
        let interior_rhs = &*interior_rhs;
        heat.par_chunks_mut(n).zip(sources.par_iter()).enumerate().for_each(|(j, (col, &src))| {
            for (v, h) in col.iter_mut().enumerate() {
                let k = dir.interior_index[v];
                // on the boundary: zero, but at a source there
                let d = if k != usize::MAX {
                    interior_rhs[j * ni + k]
                } else if v == src {
                    self.source_heat
                } else {
                    0.0
                };
                *h = if average { 0.5 * (*h + d) } else { d };
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spectral::cotan_laplacian;

    #[test]
    fn face_operator_reproduces_linear_gradient() {
        let p = [[0.0, 0.0, 0.0], [2.0, 0.1, 0.0], [0.3, 1.5, 0.0]];
        let op = FaceOperator::new(p);
        // u = 3x − y
        let u = p.map(|q| 3.0 * q[0] - q[1]);
        let g = op.gradient(u);
        assert!((g[0] - 3.0).abs() < 1e-12 && (g[1] + 1.0).abs() < 1e-12 && g[2].abs() < 1e-12);
    }

    #[test]
    fn divergence_of_gradient_is_cotan_laplacian() {
        let m = crate::synth::icosphere(1, 1.0);
        let u: Vec<f64> = m.vertices.iter().map(|p| p[0] * p[0] + 0.3 * p[1] - p[2]).collect();
        let mut div = vec![0.0; m.n_vertices()];
        for f in &m.faces {
            let op = FaceOperator::new([m.vertices[f[0]], m.vertices[f[1]], m.vertices[f[2]]]);
            let g = op.gradient([u[f[0]], u[f[1]], u[f[2]]]);
            for (&v, w) in f.iter().zip(&op.divergence_weight) {
                div[v] += dot(*w, g);
            }
        }
        let l = cotan_laplacian(&m).to_dense();
        for i in 0..m.n_vertices() {
            let lu: f64 = (0..m.n_vertices()).map(|j| l[(i, j)] * u[j]).sum();
            // div ∇u = Lc u = −L u
            assert!((div[i] + lu).abs() < 1e-10, "vertex {i}: {} vs {}", div[i], -lu);
        }
    }

    #[test]
    fn grouped_divergence_equals_the_one_column_pass_bit_for_bit() {
        let m = crate::synth::icosphere(2, 1.0);
        let n = m.n_vertices();
        let ops: Vec<FaceOperator> = m
            .faces
            .iter()
            .map(|f| FaceOperator::new([m.vertices[f[0]], m.vertices[f[1]], m.vertices[f[2]]]))
            .collect();
        // 5 columns (3 lanes of padding), one of them constant (zero gradient everywhere)
        let cols: Vec<Vec<f64>> = (0..5)
            .map(|c| {
                m.vertices
                    .iter()
                    .map(|p| if c == 2 { 1.0 } else { (p[0] * (c + 1) as f64).exp() - p[1] * p[2] })
                    .collect()
            })
            .collect();
        let mut ut = vec![0.0; n * COLUMN_GROUP];
        for (c, col) in cols.iter().enumerate() {
            for v in 0..n {
                ut[v * COLUMN_GROUP + c] = col[v];
            }
        }
        // the dispatched pass (AVX-512 or AVX2 where the CPU has them) the solver runs
        let mut rt = vec![0.0; n * COLUMN_GROUP];
        divergence_pass(&m.faces, &ops, &ut, &mut rt);
        for (c, u) in cols.iter().enumerate() {
            let mut rhs = vec![0.0; n];
            for (f, op) in m.faces.iter().zip(&ops) {
                let g = op.gradient([u[f[0]], u[f[1]], u[f[2]]]);
                let mx = g[0].abs().max(g[1].abs()).max(g[2].abs());
                if !(mx > 0.0) || !mx.is_finite() {
                    continue;
                }
                let inv_m = 1.0 / mx;
                let k = inv_m / norm([g[0] * inv_m, g[1] * inv_m, g[2] * inv_m]);
                for (&v, w) in f.iter().zip(&op.divergence_weight) {
                    rhs[v] += dot(*w, g) * k;
                }
            }
            for v in 0..n {
                assert_eq!(rt[v * COLUMN_GROUP + c].to_bits(), rhs[v].to_bits(), "column {c}, vertex {v}");
            }
        }
        let padding = (0..n).flat_map(|v| (5..COLUMN_GROUP).map(move |c| v * COLUMN_GROUP + c));
        assert!(padding.map(|i| rt[i]).all(|x| x == 0.0), "padding lanes stay zero");
    }

    #[test]
    fn power_of_two_source_changes_nothing_where_the_heat_is_normal() {
        // On a sphere the unit-source heat stays far above the subnormal range: the scaled
        // source must give the same distances bit for bit.
        let m = crate::synth::icosphere(3, 1.0);
        let mut solver = HeatMethodSolver::new(&m, HeatParams::default()).unwrap();
        assert!(solver.source_heat > 1e100, "source heat {}", solver.source_heat);
        let scaled = solver.distances_from_many(&[0, 17, 100]).unwrap();
        solver.source_heat = 1.0;
        let unit = solver.distances_from_many(&[0, 17, 100]).unwrap();
        for j in 0..3 {
            for v in 0..m.n_vertices() {
                assert_eq!(scaled[(v, j)].to_bits(), unit[(v, j)].to_bits(), "source {j}, vertex {v}");
            }
        }
    }

    #[test]
    fn batched_sources_match_one_at_a_time_in_vertex_order() {
        // More sources than one batch, on an open mesh (the Average boundary condition: two
        // heat solves per batch), through both entry points. Each column must be the distance
        // from its own source in vertex order (the solver works in a fill-reducing order
        // inside): equal to a one-source solve up to round-off, and 0 at the source.
        let m = crate::synth::grid_plane(24, 20, 2.3, 1.9);
        let solver = HeatMethodSolver::new(&m, HeatParams::default()).unwrap();
        assert!(solver.dirichlet.is_some(), "an open mesh takes the Dirichlet path too");
        assert_ne!(solver.position, (0..m.n_vertices()).collect::<Vec<_>>(), "a real reordering");
        let sources: Vec<usize> = (0..BATCH_COLUMNS + 37).map(|i| (i * 7) % m.n_vertices()).collect();
        let first = solver.distance_columns(&sources).unwrap();
        let again = solver.distances_from_many(&sources).unwrap();
        let rounded = solver.distance_columns_f32(&sources).unwrap();
        assert_eq!(first.len(), sources.len());
        for (a, b) in first.iter().zip(&rounded) {
            assert!(a.iter().zip(b.iter()).all(|(&x, &y)| (x as f32).to_bits() == y.to_bits()));
        }
        for (j, &src) in sources.iter().enumerate() {
            let single = solver.distances_from(src).unwrap();
            assert_eq!(first[j][src], 0.0);
            for v in 0..m.n_vertices() {
                assert!(
                    (first[j][v] - single[v]).abs() <= 1e-9 * (1.0 + single[v]),
                    "source {src}, vertex {v}"
                );
                assert_eq!(
                    first[j][v].to_bits(),
                    again[(v, j)].to_bits(),
                    "both entry points give the same bits"
                );
            }
            // Euclidean distance on a flat plane is the geodesic one (the heat method is off by
            // up to ~12 % next to the boundary; a column in the wrong order is off by far more)
            let e = norm(sub(m.vertices[src], m.vertices[sources[(j + 1) % sources.len()]]));
            let d = first[j][sources[(j + 1) % sources.len()]];
            assert!((d - e).abs() < 0.2 * e.max(0.2), "source {src}: {d} against {e}");
        }
    }

    #[test]
    fn far_end_of_a_long_strip_gets_its_distance() {
        // Some 850 edge lengths from the source a unit heat underflows to zero (its far field
        // has no gradient, so the distance there is whatever the Poisson solve fills in); the
        // scaled source keeps the heat normal and the distance along the strip right.
        // a strip of unit squares, LEN long and 2 wide; vertex j · nx + i at (i, j)
        const LEN: usize = 1100;
        let nx = LEN + 1;
        let m = crate::synth::grid_plane(nx, 3, LEN as f64, 2.0);
        let mut solver = HeatMethodSolver::new(&m, HeatParams::default()).unwrap();
        let (source, far) = (nx, 2 * nx - 1); // both ends of the middle row
        let err = |d: &[f64]| (d[far] - LEN as f64).abs() / LEN as f64;
        let scaled = solver.distances_from(source).unwrap();
        assert!(err(&scaled) < 0.01, "scaled source: far end at {} ({LEN} expected)", scaled[far]);
        // the distance grows along the strip's middle row
        let mid = &scaled[nx..2 * nx];
        assert!(mid.windows(2).all(|w| w[1] > w[0]), "distance along the strip is monotone");
        solver.source_heat = 1.0;
        let unit = solver.distances_from(source).unwrap();
        let unit_mid = &unit[nx..2 * nx];
        assert!(
            !unit_mid.windows(2).all(|w| w[1] > w[0]) || err(&unit) > 0.01,
            "the unit source was expected to fail here (far end {}), so this test shows nothing",
            unit[far]
        );
    }

    #[test]
    fn rejects_bad_time_factor() {
        let m = crate::synth::icosphere(1, 1.0);
        for t in [0.0, -1.0, f64::NAN] {
            let err =
                HeatMethodSolver::new(&m, HeatParams { time_factor: t, ..Default::default() }).unwrap_err();
            assert!(matches!(err, GeodesicError::InvalidTimeFactor { .. }));
        }
    }
}
