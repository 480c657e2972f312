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
//! On large meshes step 3 searches among farthest-point samples of the reference first, then
//! in the cells around the best (as [`super::refine_zoomout`] reads its map back).
//!
//! [`settle_map`] is one more such round for a map that is final in every other respect (the
//! one the posterior chose, or one carried to the reference from a relay and voted), each image
//! moved no farther than a reach along the reference: it smooths the seams where the choice or
//! the vote switches between maps and the jitter of a map carried through the labels, and the
//! reach keeps a round driven by a wrong part from spreading it.

use faer::{linalg::matmul::matmul, Accum, Mat, MatRef, Par};
use serde::{Deserialize, Serialize};

use super::{PreparedShape, RegularizerError as Error};
use crate::{
    fmap::{basis, nearest_in_cells, nearest_rows, nearest_rows_single, pullback_fmap},
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
    /// Reference samples searched first on meshes with more vertices (every vertex below).
    /// Default 3000.
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

/// Mean over the mesh's edges of `‖row_u − row_v‖` of `rows` (`n × d`).
fn mean_edge_step(mesh: &Mesh, rows: MatRef<'_, f64>) -> f64 {
    let (mut sum, mut count) = (0.0, 0usize);
    for f in &mesh.faces {
        for (a, b) in [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])] {
            if a < b {
                sum += (0..rows.ncols()).map(|j| (rows[(a, j)] - rows[(b, j)]).powi(2)).sum::<f64>().sqrt();
                count += 1;
            }
        }
    }
    if count > 0 {
        sum / count as f64
    } else {
        0.0
    }
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
    let x_r = unit_coordinates(&reference.mesh);
    let phi_t = basis(tb, k);
    let phi_r = basis(rb, k);
    let edge = mean_edge_step(&test.mesh, x_t.as_ref());
    let scale = if edge > 0.0 { params.weight * mean_edge_step(&test.mesh, phi_t) / edge } else { 0.0 };
    let cells = if n_r > params.samples { Some(reference.sample_cells(params.samples)?) } else { None };
    // The deformation basis, weighted by the test shape's mass for the projections.
    let phi_d = basis(tb, kd);
    let weighted_d = Mat::from_fn(n_t, kd, |v, j| tb.mass[v] * phi_d[(v, j)]);
    let mut current = map.to_vec();
    for _ in 0..params.rounds {
        let c = pullback_fmap(tb, rb, k, k, current.as_slice())?;
        // The displacement the map asks for, kept to its smooth part.
        let residual = Mat::from_fn(n_t, 3, |v, d| x_r[(current[v], d)] - x_t[(v, d)]);
        let mut coeffs = Mat::<f64>::zeros(kd, 3);
        matmul(
            coeffs.as_mut(),
            Accum::Replace,
            weighted_d.transpose(),
            residual.as_ref(),
            1.0,
            Par::rayon(0),
        );
        let mut deformed = x_t.clone();
        crate::spectral::matmul_tall(
            deformed.as_mut(),
            Accum::Add,
            phi_d,
            coeffs.as_ref(),
            1.0,
            Par::rayon(0),
        );
        // Queries [Φ_M, s X̃] against points [Φ_R Cᵀ, s X_R].
        let queries =
            Mat::from_fn(n_t, k + 3, |v, j| if j < k { phi_t[(v, j)] } else { scale * deformed[(v, j - k)] });
        let mut points = Mat::<f64>::zeros(n_r, k + 3);
        crate::spectral::matmul_tall(
            points.as_mut().subcols_mut(0, k),
            Accum::Replace,
            phi_r,
            c.transpose(),
            1.0,
            Par::rayon(0),
        );
        for r in 0..n_r {
            for d in 0..3 {
                points[(r, k + d)] = scale * x_r[(r, d)];
            }
        }
        current = match &cells {
            None => nearest_rows(queries.as_ref(), points.as_ref()),
            Some(cells) => {
                let sample_points =
                    Mat::from_fn(cells.samples.len(), k + 3, |i, j| points[(cells.samples[i], j)]);
                let coarse = nearest_rows_single(queries.as_ref(), sample_points.as_ref());
                nearest_in_cells(queries.as_ref(), points.as_ref(), cells, &coarse)
            }
        };
    }
    Ok(current)
}
