//! Extrinsic refinement of a refined map: the spectral embedding of ZoomOut's last step joined
//! by the shapes' coordinates, after a smooth deformation of the test shape onto the reference
//! through the map itself (the product space of Smooth Shells, Eisenberger et al. 2020, on top
//! of ZoomOut).
//!
//! ZoomOut's last point map is the nearest row of `Φ_R Cᵀ` to each row of `Φ_M` at the largest
//! basis, whose high frequencies agree only roughly between bodies of other builds: its images
//! are often one or two edges off. The coordinates tell a vertex's neighbours apart at once, but
//! only once the test shape is in the reference's pose and build. So each round
//!
//! 1. fits the functional map `C` of the current map (`k × k`, the ZoomOut basis);
//! 2. deforms the test shape: `X̃ = X_M + Φ_M[:, :k_d] Φ_M[:, :k_d]ᵀ M_M (X_R ∘ T − X_M)`, the
//!    displacement the map asks for, kept to its `k_d` smoothest components (so a wrong image
//!    moves its vertex by little, the pose and build are carried over, the test's own detail
//!    is kept);
//! 3. maps each test vertex to the reference vertex nearest in `[Φ_M, s X̃]` against
//!    `[Φ_R Cᵀ, s X_R]`, coordinates in units of each shape's `√area`, `s` so that one mean edge
//!    length counts as much as the mean spectral step between neighbouring test vertices,
//!    times `weight`.
//!
//! Step 3 is exact and cheap: the coordinates alone bound the search. The current image (or the
//! reference vertex nearest to `X̃` in space, whichever is nearer in the joint space) is at some
//! joint distance `d`; no vertex farther than `d / s` from `X̃` in space can be nearer, so only
//! the reference vertices in that ball (a kd-tree query) are compared: a few dozen per vertex
//! once the map is near its images, instead of every reference vertex (measured on SCAPE scans
//! with five holes, 12,500 vertices: 4–12 on average). With `weight` = 0 (no coordinates) the
//! search is spectral alone, among farthest-point samples of the reference first, then in the
//! cells around the best (as [`super::refine_zoomout`] reads its map back).
//!
//! [`settle_map`] is one more such round for a map that is final in every other respect (the
//! one the posterior chose, or one carried to the reference from a relay and voted), each image
//! moved no farther than a reach along the reference: it smooths the seams where the choice or
//! the vote switches between maps and the jitter of a map carried through the labels, and the
//! reach keeps a round driven by a wrong part from spreading it.

use std::sync::Arc;

use faer::{linalg::matmul::matmul, Accum, Mat, MatRef, Par};
use kiddo::{immutable::float::kdtree::ImmutableKdTree, SquaredEuclidean};
use serde::{Deserialize, Serialize};

use super::{PreparedShape, RegularizerError as Error};
use crate::{
    fmap::{basis, nearest_in_cells, nearest_rows, nearest_rows_single, squared_distance, SampleCells},
    mesh::{norm, sub, Mesh},
};

/// Settings of the extrinsic refinement (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ExtrinsicParams {
    /// Rounds (deformation, then point map). Default 3.
    pub rounds: usize,
    /// Basis functions of the test shape that carry the deformation (at most its ZoomOut
    /// basis). Default 200.
    pub deformation_k: usize,
    /// Weight of the coordinates against the spectral embedding (1: a mean edge length counts
    /// as much as the mean spectral step between neighbouring vertices). Default 1.
    pub weight: f64,
    /// With `weight` = 0 (a spectral search alone), the reference samples searched first on
    /// meshes with more vertices (every vertex below). Default 3000.
    pub samples: usize,
}

impl Default for ExtrinsicParams {
    fn default() -> Self {
        Self { rounds: 3, deformation_k: 200, weight: 1.0, samples: 3000 }
    }
}

impl ExtrinsicParams {
    /// Checks the settings, naming the broken rule.
    pub fn check(&self) -> Result<(), String> {
        if self.deformation_k == 0 {
            return Err("extrinsic deformation_k = 0: at least 1 (the translation)".into());
        }
        if !(self.weight >= 0.0 && self.weight.is_finite()) {
            return Err(format!("extrinsic weight = {}: must be finite and ≥ 0", self.weight));
        }
        if self.samples == 0 {
            return Err("extrinsic samples = 0: at least 1".into());
        }
        Ok(())
    }
}

/// Coordinates of `mesh` in units of `√area` (an `n × 3` matrix).
fn unit_coordinates(mesh: &Mesh) -> Mat<f64> {
    let s = 1.0 / mesh.surface_area().max(f64::MIN_POSITIVE).sqrt();
    Mat::from_fn(mesh.n_vertices(), 3, |v, d| mesh.vertices[v][d] * s)
}

/// Mean over the mesh's edges of `‖row_u − row_v‖` of `rows` (`n × d`, column-major: summed a
/// column at a time over every edge, not an edge at a time across the columns).
fn mean_edge_step(mesh: &Mesh, rows: MatRef<'_, f64>) -> f64 {
    let edges: Vec<(usize, usize)> = mesh
        .faces
        .iter()
        .flat_map(|f| [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])])
        .filter(|(a, b)| a < b)
        .collect();
    if edges.is_empty() {
        return 0.0;
    }
    let mut squared = vec![0.0f64; edges.len()];
    for j in 0..rows.ncols() {
        for (s, &(a, b)) in squared.iter_mut().zip(&edges) {
            *s += (rows[(a, j)] - rows[(b, j)]).powi(2);
        }
    }
    squared.iter().map(|s| s.sqrt()).sum::<f64>() / edges.len() as f64
}

/// How far (× the reference's `√area`, Euclidean) [`settle_map`] may move an image by default.
/// Measured on tosca-r5k cat and david with relays (one settling round after the carry): 0.03
/// keeps about half of the gain on cat, 0.06 all of it, and no limit lets a mirrored part on one
/// david test spread (87.4 → 84.1 % within 0.05 there).
pub const SETTLE_REACH: f64 = 0.06;

/// One round of the extrinsic refinement (`params` with `rounds` = 1) from `map`, each image
/// moved only where it stays within `reach × √area` (Euclidean, on the reference) of the one it
/// replaces (see the module documentation).
pub fn settle_map(
    test: &PreparedShape,
    reference: &PreparedShape,
    map: &[usize],
    params: &ExtrinsicParams,
    reach: f64,
) -> Result<Vec<usize>, Error> {
    if !(reach >= 0.0 && reach.is_finite()) {
        return Err(Error::InvalidParameter {
            name: "settle",
            reason: format!("reach = {reach}: must be finite and ≥ 0"),
        });
    }
    let moved = refine_extrinsic(test, reference, map, &ExtrinsicParams { rounds: 1, ..*params })?;
    let limit = reach * reference.mesh.surface_area().sqrt();
    let pos = &reference.mesh.vertices;
    Ok(map
        .iter()
        .zip(moved)
        .map(|(&from, to)| if norm(sub(pos[from], pos[to])) <= limit { to } else { from })
        .collect())
}

/// The extrinsic refinement of `map` (test vertex → reference vertex), see the module
/// documentation. Uses the shapes' ZoomOut bases ([`PreparedShape::zoomout_basis`]).
pub fn refine_extrinsic(
    test: &PreparedShape,
    reference: &PreparedShape,
    map: &[usize],
    params: &ExtrinsicParams,
) -> Result<Vec<usize>, Error> {
    params.check().map_err(|reason| Error::InvalidParameter { name: "extrinsic", reason })?;
    let (tb, rb) = (test.zoomout_basis(), reference.zoomout_basis());
    super::check_map_onto(test, reference, map)?;
    let (n_t, n_r) = (test.mesh.n_vertices(), reference.mesh.n_vertices());
    let k = tb.k().min(rb.k());
    let kd = params.deformation_k.min(tb.k());
    let x_t = unit_coordinates(&test.mesh);
    let x_r = coordinate_tree(reference);
    let phi_t = basis(tb, k);
    let (edge, spectral_edge) = *test.kept.edge_steps.get_or_insert_with(test, k, || {
        (mean_edge_step(&test.mesh, x_t.as_ref()), mean_edge_step(&test.mesh, phi_t))
    });
    let scale = if edge > 0.0 { params.weight * spectral_edge / edge } else { 0.0 };
    // The test's spectral rows and the reference's as contiguous columns (`k × n`), in single
    // precision: the products of a round run in single precision (twice the throughput; what
    // they feed is a nearest-neighbour search and a smooth deformation).
    let phi_r_rows = basis_rows(reference, k);
    let search = if scale > 0.0 {
        Search::Joint(Box::new(Joint { reference: x_r.clone(), scale, test_rows: basis_rows(test, k) }))
    } else if n_r > params.samples {
        Search::Sampled(reference.sample_cells(params.samples)?)
    } else {
        Search::Spectral
    };
    // The test basis weighted by its mass (for the functional map and the deformation's
    // projection).
    let kw = k.max(kd);
    let weighted = test.kept.weighted.get_or_insert_with(test, kw, || {
        let phi_w = basis(tb, kw);
        Mat::from_fn(n_t, kw, |v, j| (tb.mass[v] * phi_w[(v, j)]) as f32)
    });
    let phi_d = basis(tb, kd);
    let mut reference_rows = Mat::<f32>::zeros(k, n_r);
    let mut current = map.to_vec();
    // The map of the last round and its product.
    let mut last: Option<(Vec<usize>, Mat<f32>)> = None;
    for _ in 0..params.rounds {
        // One product gives the map's functional map `C = Φ_Mᵀ M Φ_R[T]` (first `k` rows of
        // the gathered columns) and the projection of the displacement it asks for,
        // `X_R[T] − X_M` (last 3): a sum over test vertices, so after the first round only the
        // vertices whose image moved change it (when they are fewer than half).
        // Entry `j` of test vertex `v`'s column under `map`.
        let entry = |map: &[usize], v: usize, j: usize| {
            if j < k {
                phi_r_rows[(j, map[v])]
            } else {
                (x_r.coordinates[map[v]][j - k] - x_t[(v, j - k)]) as f32
            }
        };
        let changed: Option<Vec<usize>> = last.as_ref().and_then(|(before, _)| {
            let changed: Vec<usize> = (0..n_t).filter(|&v| current[v] != before[v]).collect();
            (2 * changed.len() < n_t).then_some(changed)
        });
        let product = match (changed, last.take()) {
            (Some(changed), Some((before, mut product))) => {
                let rows = Mat::from_fn(changed.len(), kw, |i, j| weighted[(changed[i], j)]);
                let change = Mat::from_fn(k + 3, changed.len(), |j, i| {
                    entry(&current, changed[i], j) - entry(&before, changed[i], j)
                });
                matmul(
                    product.as_mut(),
                    Accum::Add,
                    rows.transpose(),
                    change.transpose(),
                    1.0,
                    Par::rayon(0),
                );
                product
            }
            _ => {
                let gathered = Mat::from_fn(k + 3, n_t, |j, v| entry(&current, v, j));
                let mut product = Mat::<f32>::zeros(kw, k + 3);
                matmul(
                    product.as_mut(),
                    Accum::Replace,
                    weighted.transpose(),
                    gathered.transpose(),
                    1.0,
                    Par::rayon(0),
                );
                product
            }
        };
        let c = product.as_ref().subrows(0, k).subcols(0, k);
        // The displacement kept to its smooth part.
        let mut deformed = x_t.clone();
        let projection = Mat::from_fn(kd, 3, |i, d| f64::from(product[(i, k + d)]));
        crate::spectral::matmul_tall(
            deformed.as_mut(),
            Accum::Add,
            phi_d,
            projection.as_ref(),
            1.0,
            Par::rayon(0),
        );
        // The rows of Φ_R Cᵀ, as the columns of C Φ_Rᵀ.
        matmul(reference_rows.as_mut(), Accum::Replace, c, (*phi_r_rows).as_ref(), 1.0, Par::rayon(0));
        let next = match &search {
            Search::Joint(joint) => {
                let moved: Vec<[f64; 3]> =
                    (0..n_t).map(|v| [deformed[(v, 0)], deformed[(v, 1)], deformed[(v, 2)]]).collect();
                nearest_joint(joint, reference_rows.as_ref(), &moved, &current)
            }
            Search::Spectral => nearest_rows(phi_t, wide_rows(reference_rows.as_ref()).as_ref()),
            Search::Sampled(cells) => {
                let points = wide_rows(reference_rows.as_ref());
                let sample_points =
                    Mat::from_fn(cells.samples.len(), k, |i, j| points[(cells.samples[i], j)]);
                let coarse = nearest_rows_single(phi_t, sample_points.as_ref());
                nearest_in_cells(phi_t, points.as_ref(), cells, &coarse)
            }
        };
        last = Some((std::mem::replace(&mut current, next), product));
    }
    Ok(current)
}

/// The rows of `C Φ_Rᵀ`'s columns (`k × n_r`) in double precision, for the spectral searches.
fn wide_rows(columns: MatRef<'_, f32>) -> Mat<f64> {
    Mat::from_fn(columns.ncols(), columns.nrows(), |r, j| f64::from(columns[(j, r)]))
}

/// How step 3 searches: in the joint space, bounded by the coordinates (`weight` > 0); or, on
/// the spectral rows alone, among every reference vertex or samples first.
enum Search {
    Joint(Box<Joint>),
    Spectral,
    Sampled(Arc<SampleCells>),
}

/// What the joint search keeps across rounds: the reference's coordinates and their tree, their
/// weight `scale`, and the test shape's spectral rows (column `m`: vertex `m`, `k × n_t`).
struct Joint {
    reference: Arc<CoordinateTree>,
    scale: f64,
    test_rows: Arc<Mat<f32>>,
}

/// A shape's coordinates in units of `√area` and their kd-tree (the joint search's bound).
pub(super) struct CoordinateTree {
    coordinates: Vec<[f64; 3]>,
    tree: ImmutableKdTree<f64, u32, 3, 32>,
}

impl CoordinateTree {
    fn new(coordinates: Vec<[f64; 3]>) -> Self {
        Self { tree: ImmutableKdTree::new_from_slice(&coordinates), coordinates }
    }
}

/// `shape`'s [`CoordinateTree`], made once ([`PreparedShape`] keeps it).
fn coordinate_tree(shape: &PreparedShape) -> Arc<CoordinateTree> {
    shape.kept.coordinates.get_or_insert_with(shape, (), || {
        let x = unit_coordinates(&shape.mesh);
        CoordinateTree::new((0..x.nrows()).map(|r| [x[(r, 0)], x[(r, 1)], x[(r, 2)]]).collect())
    })
}

/// The first `k` functions of `shape`'s ZoomOut basis as single-precision rows (`k × n`), made
/// once per `k` ([`PreparedShape`] keeps them).
fn basis_rows(shape: &PreparedShape, k: usize) -> Arc<Mat<f32>> {
    shape.kept.rows.get_or_insert_with(shape, k, || {
        let phi = basis(shape.zoomout_basis(), k);
        Mat::from_fn(k, phi.nrows(), |j, v| phi[(v, j)] as f32)
    })
}

/// Column `i` of an owned matrix as a slice.
fn column(m: MatRef<'_, f32>, i: usize) -> &[f32] {
    m.col(i).try_as_col_major().expect("an owned matrix's columns are contiguous").as_slice()
}

/// For each test vertex `m` (spectral row: column `m` of `joint.test_rows`; coordinates
/// `test_xyz[m]`), the reference vertex `r` (spectral row: column `r` of `reference_rows`,
/// `k × n_r`) nearest in `‖φ_m − φ_r‖² + scale² ‖x_m − x_r‖²`
/// (the lower index on ties), exactly: among the vertices whose coordinates alone are no farther
/// than the nearer of `hint[m]` and the vertex nearest in space (see the module documentation).
fn nearest_joint(
    joint: &Joint,
    reference_rows: MatRef<'_, f32>,
    test_xyz: &[[f64; 3]],
    hint: &[usize],
) -> Vec<usize> {
    use rayon::prelude::*;
    let (s2, test_rows, reference) =
        (joint.scale * joint.scale, (*joint.test_rows).as_ref(), &joint.reference);
    (0..test_rows.ncols())
        .into_par_iter()
        .map(|m| {
            let (q, y) = (column(test_rows, m), &test_xyz[m]);
            let distance =
                |r: usize, d2: f64| s2 * d2 + f64::from(squared_distance(q, column(reference_rows, r)));
            let p = reference.coordinates[hint[m]];
            let nearer =
                |a: (f64, usize), b: (f64, usize)| if b.0 < a.0 || (b.0 == a.0 && b.1 < a.1) { b } else { a };
            let mut best = (distance(hint[m], squared_distance(&p, y)), hint[m]);
            let near = reference.tree.nearest_one::<SquaredEuclidean>(y);
            best = nearer(best, (distance(near.item as usize, near.distance), near.item as usize));
            for n in reference.tree.within_unsorted::<SquaredEuclidean>(y, best.0 / s2) {
                best = nearer(best, (distance(n.item as usize, n.distance), n.item as usize));
            }
            best.1
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};

    use super::*;

    #[test]
    fn the_bounded_joint_search_finds_the_nearest_vertex_whatever_the_hint() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let (k, n_t, n_r, scale) = (12, 300, 700, 3.0);
        let mut uniform = |n: usize, m: usize| Mat::from_fn(n, m, |_, _| rng.random_range(-1.0..1.0));
        let single = |m: Mat<f64>| Mat::from_fn(m.nrows(), m.ncols(), |i, j| m[(i, j)] as f32);
        let (test_rows, reference_rows) = (single(uniform(k, n_t)), single(uniform(k, n_r)));
        let xyz =
            |m: &Mat<f64>| (0..m.nrows()).map(|i| [m[(i, 0)], m[(i, 1)], m[(i, 2)]]).collect::<Vec<_>>();
        let (test_xyz, reference_xyz) = (xyz(&uniform(n_t, 3)), xyz(&uniform(n_r, 3)));
        let joint = Joint {
            reference: Arc::new(CoordinateTree::new(reference_xyz.clone())),
            scale,
            test_rows: Arc::new(test_rows.clone()),
        };
        // Hints anywhere, most of them far from the answer.
        let hint: Vec<usize> = (0..n_t).map(|m| (m * 7919) % n_r).collect();
        let found = nearest_joint(&joint, reference_rows.as_ref(), &test_xyz, &hint);
        for m in 0..n_t {
            let d = |r: usize| {
                f64::from(squared_distance(column(test_rows.as_ref(), m), column(reference_rows.as_ref(), r)))
                    + scale * scale * squared_distance(&test_xyz[m], &reference_xyz[r])
            };
            let brute = (0..n_r).min_by(|&a, &b| d(a).total_cmp(&d(b))).unwrap();
            assert_eq!(found[m], brute, "test vertex {m}");
        }
    }
}
