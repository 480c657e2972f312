//! Left/right symmetry maps of a class, for the "symmetric flips allowed" figures of the
//! evaluation protocol ([`super::protocol`]).
//!
//! Two sources:
//!
//! - **Mirrored ground truth** (remeshed TOSCA, `NAME.sym.vts`): each shape lists, beside its
//!   ground-truth table `truth[k]`, the vertex `mirrored[k]` at the mirror image of `truth[k]`.
//!   [`label_symmetry_from_mirrored_truth`] turns that into a map of the labels.
//! - **Sparse symmetric feature points** (TOSCA/SCAPE `CLASS.sym.info`): a few pairs of vertices
//!   that mirror each other, and vertices on the symmetry plane. [`SymmetrySolver::derive`] extends them
//!   to a dense self-map of one shape with a self functional map (Ovsjanikov et al. 2012):
//!   the map `C` (pulling functions back along the symmetry `S`, as in [`crate::fmap`]) is
//!   fitted to
//!   1. the geodesic distance functions from the feature points, `d(·, q_j) ∘ S = d(·, p_j)`
//!      for every pair `S(p_j) = q_j` (both ways) and `d(·, p) ∘ S = d(·, p)` on the plane;
//!   2. the wave kernel signature, which an intrinsic symmetry keeps: `w ∘ S = w`;
//!   3. the orientation descriptors of [`crate::descriptor::orientation_descriptors`], which a
//!      mirror flips: `h ∘ S = −h` — the cue that tells the symmetry from the identity, which
//!      satisfies (2) as well;
//!   4. commutativity with the Laplacian, `C Λ = Λ C` (an isometry's map is block diagonal);
//!
//!   then refined by ZoomOut (Melzi et al. 2019) on a farthest-point subsample of the vertices
//!   and converted to a vertex map by nearest neighbours in the spectral embedding.
//!   [`SymmetrySolver::validate`] measures its accuracy honestly: cross-validation over the feature
//!   pairs, each fold fitted without the pairs it scores.
//!
//! Conventions: the spectrum is the unit-area one of [`crate::spectral`] (M-orthonormal
//! eigenvectors); distance functions are normalised by `√area`; errors are geodesic distances
//! divided by `√area`.

use faer::{linalg::matmul::matmul, Accum, Mat, MatRef, Par, Side};
use serde::{Deserialize, Serialize};

use super::EvalError;
use crate::{
    descriptor::{
        band_pass_functions, orientation_band_energies, orientation_descriptors, wave_kernel_signature,
        WksParams,
    },
    fmap::{nearest_rows, solve_rows_with_diagonal, spectral_coefficients},
    geodesic::{farthest_point_sampling_euclidean, HeatMethodSolver, HeatParams},
    mesh::Mesh,
    spectral::Spectrum,
};

/// One shape's ground truth with its mirror image (a remeshed shape with `.vts` and `.sym.vts`).
#[derive(Clone, Copy, Debug)]
pub struct MirroredTruth<'a> {
    /// The shape.
    pub mesh: &'a Mesh,
    /// `truth[k]`: the shape's vertex for label `k`.
    pub truth: &'a [usize],
    /// `mirrored[k]`: the vertex at the mirror image of `truth[k]`.
    pub mirrored: &'a [usize],
}

/// The label symmetry `s` (`s[k]` = the label at the mirror image of label `k`) implied by
/// mirrored ground truth on one or more shapes.
///
/// On each shape, the labels voted for `k` are those whose vertex is `mirrored[k]` (several
/// labels may share a vertex on a remeshed shape) or, when no label sits there, those at the
/// labelled vertex nearest to it (Euclidean). Each shape gives one vote, split among its
/// candidates; the label with most votes wins (ties: the smallest). Shapes whose tables are
/// malformed are an error naming the shape's position.
///
/// ```
/// use shapeforest::{eval::symmetry::{label_symmetry_from_mirrored_truth, MirroredTruth}, mesh::Mesh};
/// // Four points mirrored about x = 0; labels 0..3 on vertices 0..3; vertex 0 ↔ 1, 2 ↔ 3.
/// let mesh = Mesh::new(
///     vec![[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [-1.0, 1.0, 0.0], [1.0, 1.0, 0.0]],
///     vec![[0, 1, 2], [1, 3, 2]],
/// ).unwrap();
/// let shape = MirroredTruth { mesh: &mesh, truth: &[0, 1, 2, 3], mirrored: &[1, 0, 3, 2] };
/// assert_eq!(label_symmetry_from_mirrored_truth(&[shape]).unwrap(), vec![1, 0, 3, 2]);
/// ```
pub fn label_symmetry_from_mirrored_truth(shapes: &[MirroredTruth<'_>]) -> Result<Vec<usize>, EvalError> {
    let first = shapes
        .first()
        .ok_or_else(|| EvalError::InvalidInput("no shape to derive a label symmetry from".into()))?;
    let n_labels = first.truth.len();
    let mut votes: Vec<Vec<(usize, f64)>> = vec![Vec::new(); n_labels];
    for (i, s) in shapes.iter().enumerate() {
        let n = s.mesh.n_vertices();
        if s.truth.len() != n_labels || s.mirrored.len() != n_labels {
            return Err(EvalError::SizeMismatch(format!(
                "shape {i}: {} ground-truth and {} mirrored entries, expected {n_labels} each",
                s.truth.len(),
                s.mirrored.len()
            )));
        }
        if let Some(&v) = s.truth.iter().chain(s.mirrored).find(|&&v| v >= n) {
            return Err(EvalError::InvalidInput(format!(
                "shape {i}: vertex {v} is outside its {n} vertices"
            )));
        }
        // Labels at each vertex.
        let mut start = vec![0usize; n + 1];
        for &v in s.truth {
            start[v + 1] += 1;
        }
        for v in 0..n {
            start[v + 1] += start[v];
        }
        let mut fill = start.clone();
        let mut rows = vec![0usize; n_labels];
        for (k, &v) in s.truth.iter().enumerate() {
            rows[fill[v]] = k;
            fill[v] += 1;
        }
        let labelled: Vec<usize> = (0..n).filter(|&v| start[v + 1] > start[v]).collect();
        for (votes_k, &target) in votes.iter_mut().zip(s.mirrored) {
            let v = if start[target + 1] > start[target] {
                target
            } else {
                let p = s.mesh.vertices[target];
                let d2 = |u: usize| {
                    let q = s.mesh.vertices[u];
                    (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)
                };
                labelled.iter().copied().min_by(|&a, &b| d2(a).total_cmp(&d2(b))).unwrap_or(target)
            };
            let cands = &rows[start[v]..start[v + 1]];
            let w = 1.0 / cands.len().max(1) as f64;
            for &c in cands {
                match votes_k.iter_mut().find(|(l, _)| *l == c) {
                    Some(e) => e.1 += w,
                    None => votes_k.push((c, w)),
                }
            }
        }
    }
    Ok(votes
        .into_iter()
        .enumerate()
        .map(|(k, v)| {
            v.into_iter().max_by(|a, b| a.1.total_cmp(&b.1).then(b.0.cmp(&a.0))).map_or(k, |(l, _)| l)
        })
        .collect())
}

/// Sparse left/right feature points of one shape: pairs `(p, q)` of vertices that mirror each
/// other, and vertices on the symmetry plane (their own mirror image).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SymmetricFeatures {
    /// Mirrored pairs `(p, q)`: `S(p) = q` and `S(q) = p`.
    pub pairs: Vec<(usize, usize)>,
    /// Vertices on the symmetry plane: `S(p) = p`.
    pub plane: Vec<usize>,
}

impl SymmetricFeatures {
    /// Every feature vertex with its mirror image: `(p, q)` and `(q, p)` for each pair, then
    /// `(p, p)` for each plane point.
    ///
    /// ```
    /// use shapeforest::eval::symmetry::SymmetricFeatures;
    /// let f = SymmetricFeatures { pairs: vec![(1, 2)], plane: vec![5] };
    /// assert_eq!(f.points(), vec![(1, 2), (2, 1), (5, 5)]);
    /// ```
    pub fn points(&self) -> Vec<(usize, usize)> {
        self.pairs
            .iter()
            .flat_map(|&(p, q)| [(p, q), (q, p)])
            .chain(self.plane.iter().map(|&p| (p, p)))
            .collect()
    }

    /// Fold `fold` of `n_folds`: the features dealt round-robin (pairs and plane points
    /// separately) as `(held_out, kept)`.
    ///
    /// ```
    /// use shapeforest::eval::symmetry::SymmetricFeatures;
    /// let f = SymmetricFeatures { pairs: vec![(1, 2), (3, 4), (5, 6)], plane: vec![7, 8] };
    /// let (out, kept) = f.fold(0, 2);
    /// assert_eq!(out.pairs, vec![(1, 2), (5, 6)]);
    /// assert_eq!(kept.pairs, vec![(3, 4)]);
    /// assert_eq!((out.plane, kept.plane), (vec![8], vec![7]));
    /// ```
    pub fn fold(&self, fold: usize, n_folds: usize) -> (SymmetricFeatures, SymmetricFeatures) {
        let n_folds = n_folds.max(1);
        let mut out = SymmetricFeatures::default();
        let mut kept = SymmetricFeatures::default();
        for (i, &p) in self.pairs.iter().enumerate() {
            if i % n_folds == fold {
                out.pairs.push(p)
            } else {
                kept.pairs.push(p)
            }
        }
        for (i, &p) in self.plane.iter().enumerate() {
            // Offset so that the plane points of a fold are not always those of fold 0.
            if (i + self.pairs.len()) % n_folds == fold {
                out.plane.push(p)
            } else {
                kept.plane.push(p)
            }
        }
        (out, kept)
    }

    fn check(&self, n_vertices: usize) -> Result<(), EvalError> {
        if self.pairs.is_empty() {
            return Err(EvalError::InvalidInput(
                "a symmetry needs at least one mirrored feature pair".into(),
            ));
        }
        if let Some((p, _)) = self.points().into_iter().find(|&(p, _)| p >= n_vertices) {
            return Err(EvalError::InvalidInput(format!(
                "feature vertex {p} is outside the shape's {n_vertices} vertices"
            )));
        }
        Ok(())
    }
}

/// Settings of [`SymmetrySolver`].
#[derive(Clone, Debug, PartialEq)]
pub struct SymmetryParams {
    /// Basis size of the initial fit. Default 20.
    pub k_initial: usize,
    /// Basis size after ZoomOut (at most the spectrum's). Default 80.
    pub k_final: usize,
    /// Basis functions added per ZoomOut iteration. Default 4.
    pub zoomout_step: usize,
    /// Farthest-point samples ZoomOut runs on (all vertices when the shape has fewer). Default
    /// 3000.
    pub zoomout_samples: usize,
    /// WKS energies used as symmetric descriptors. Default 30.
    pub wks_energies: usize,
    /// Total weight of the feature-point distance functions. Default 4.
    pub feature_weight: f64,
    /// Total weight of the WKS descriptors (`w ∘ S = w`). Default 1.
    pub wks_weight: f64,
    /// Total weight of the orientation descriptors (`h ∘ S = −h`). Default 1.
    pub orientation_weight: f64,
    /// Weight of the Laplacian commutativity (eigenvalues normalised by the largest used).
    /// Default 1.
    pub commutativity: f64,
    /// Ridge added to every normal-equation system (keeps them positive definite). Default 1e-6.
    pub ridge: f64,
}

impl Default for SymmetryParams {
    fn default() -> Self {
        Self {
            k_initial: 20,
            k_final: 80,
            zoomout_step: 4,
            zoomout_samples: 3000,
            wks_energies: 30,
            feature_weight: 4.0,
            wks_weight: 1.0,
            orientation_weight: 1.0,
            commutativity: 1.0,
            ridge: 1e-6,
        }
    }
}

impl SymmetryParams {
    /// Checks the settings, naming the first one out of range.
    ///
    /// ```
    /// use shapeforest::eval::symmetry::SymmetryParams;
    /// assert!(SymmetryParams::default().check().is_ok());
    /// let bad = SymmetryParams { k_initial: 0, ..Default::default() };
    /// assert!(bad.check().unwrap_err().to_string().contains("k_initial"));
    /// ```
    pub fn check(&self) -> Result<(), EvalError> {
        let bad = |what: &str| Err(EvalError::InvalidInput(format!("symmetry parameter {what}")));
        if self.k_initial < 2 {
            return bad("k_initial must be at least 2");
        }
        if self.k_final < self.k_initial {
            return bad("k_final must be at least k_initial");
        }
        if self.zoomout_step == 0 {
            return bad("zoomout_step must be at least 1");
        }
        if self.zoomout_samples < 2 * self.k_final {
            return bad("zoomout_samples must be at least 2 × k_final");
        }
        let weights =
            [self.feature_weight, self.wks_weight, self.orientation_weight, self.commutativity, self.ridge];
        if weights.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
            return bad("weights (feature, wks, orientation, commutativity, ridge) must be finite and ≥ 0");
        }
        if self.ridge <= 0.0 {
            return bad("ridge must be greater than 0");
        }
        Ok(())
    }
}

/// A dense left/right self-map of a shape.
#[derive(Clone, Debug)]
pub struct SymmetryMap {
    /// `map[v]`: the vertex at the mirror image of `v`.
    pub map: Vec<usize>,
    /// The refined functional map (`k × k`, pulling functions back along the symmetry).
    pub fmap: Mat<f64>,
}

/// The error of a derived symmetry at one feature point.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FeatureError {
    /// The feature vertex `p`.
    pub vertex: usize,
    /// Its known mirror image.
    pub expected: usize,
    /// The derived symmetry's image of `p`.
    pub mapped: usize,
    /// `d(mapped, expected) / √area`.
    pub error: f64,
}

/// Accuracy of a derived symmetry.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SymmetryValidation {
    /// Number of cross-validation folds.
    pub folds: usize,
    /// Errors at every feature point, each from the fold that held it out.
    pub held_out: Vec<FeatureError>,
    /// Fraction of held-out feature points within 0.05.
    pub within_005: f64,
    /// Mean held-out error.
    pub mean: f64,
    /// Largest held-out error.
    pub max: f64,
    /// Fraction of sampled vertices `v` of the final map with `d(S(S(v)), v) ≤ 0.05` (a map
    /// that is not close to an involution cannot be a symmetry).
    pub involution_within_005: f64,
}

/// Derives dense symmetries of one shape from sparse feature points (see the module
/// documentation). Holds what all fits share: the spectrum, a heat-method factorisation, the
/// descriptor coefficients and the ZoomOut samples.
pub struct SymmetrySolver {
    spectrum: std::sync::Arc<Spectrum>,
    heat: HeatMethodSolver,
    sqrt_area: f64,
    params: SymmetryParams,
    /// Symmetric descriptor coefficients (`k_initial × d`), unit columns.
    wks: Mat<f64>,
    /// Orientation descriptor coefficients (`k_initial × o`), unit columns.
    orientation: Mat<f64>,
    /// ZoomOut samples and their basis rows (`samples × k_final`).
    samples: Vec<usize>,
    phi_samples: Mat<f64>,
}

impl SymmetrySolver {
    /// Prepares `mesh` with its unit-area `spectrum` (at least `params.k_initial` eigenpairs;
    /// `k_final` is capped at the spectrum's size).
    pub fn new(
        mesh: &Mesh,
        spectrum: std::sync::Arc<Spectrum>,
        params: SymmetryParams,
    ) -> Result<Self, EvalError> {
        params.check()?;
        if spectrum.k() < params.k_initial {
            return Err(EvalError::InvalidInput(format!(
                "the spectrum has {} eigenpairs, the symmetry fit needs {}",
                spectrum.k(),
                params.k_initial
            )));
        }
        let mut params = params;
        params.k_final = params.k_final.min(spectrum.k());
        if spectrum.n_vertices != mesh.n_vertices() {
            return Err(EvalError::SizeMismatch(format!(
                "spectrum of {} vertices for a mesh of {}",
                spectrum.n_vertices,
                mesh.n_vertices()
            )));
        }
        let heat = HeatMethodSolver::new(mesh, HeatParams::default())?;
        let sqrt_area = mesh.surface_area().sqrt();
        let k0 = params.k_initial;
        let wks_params = WksParams { n_energies: params.wks_energies.max(1), ..Default::default() };
        let wks = wave_kernel_signature(&spectrum, &wks_params, None)?;
        let wks = unit_columns(spectral_coefficients(&spectrum, k0, wks.as_ref())?);
        // Orientation descriptors from a few band-pass functions of the low spectrum.
        let bands = band_pass_functions(&spectrum, &orientation_band_energies(&spectrum, 5));
        let h = orientation_descriptors(mesh, bands.as_ref());
        let np = if bands.ncols() > 1 { h.len() / mesh.n_vertices() } else { 0 };
        let h = Mat::from_fn(mesh.n_vertices(), np, |v, j| h[v * np + j]);
        let orientation = unit_columns(spectral_coefficients(&spectrum, k0, h.as_ref())?);
        let n_samples = params.zoomout_samples.min(mesh.n_vertices());
        let samples = if n_samples == mesh.n_vertices() {
            (0..n_samples).collect()
        } else {
            farthest_point_sampling_euclidean(mesh, n_samples, None)?
        };
        let phi = spectrum.vectors();
        let phi_samples = Mat::from_fn(samples.len(), params.k_final, |i, j| phi[(samples[i], j)]);
        Ok(Self { spectrum, heat, sqrt_area, params, wks, orientation, samples, phi_samples })
    }

    /// Geodesic distance fields (normalised by √area) from `sources`.
    fn fields(&self, sources: &[usize]) -> Result<Mat<f64>, EvalError> {
        let mut f = self.heat.distances_from_many(sources)?;
        let s = 1.0 / self.sqrt_area.max(f64::MIN_POSITIVE);
        for j in 0..f.ncols() {
            for i in 0..f.nrows() {
                f[(i, j)] *= s;
            }
        }
        Ok(f)
    }

    /// Fits the refined functional map of the symmetry to `features` (`k_final × k_final`).
    pub fn fit(&self, features: &SymmetricFeatures) -> Result<Mat<f64>, EvalError> {
        let c0 = self.fit_initial(features)?;
        self.zoomout(c0)
    }

    /// The initial functional map (`k_initial × k_initial`) fitted to `features` and the
    /// descriptors, before ZoomOut.
    pub fn fit_initial(&self, features: &SymmetricFeatures) -> Result<Mat<f64>, EvalError> {
        features.check(self.spectrum.n_vertices)?;
        let points = features.points();
        let sources: Vec<usize> = points.iter().map(|&(p, _)| p).collect();
        let coef =
            spectral_coefficients(&self.spectrum, self.params.k_initial, self.fields(&sources)?.as_ref())?;
        let column = |v: usize| sources.iter().position(|&s| s == v).unwrap_or(0);
        // Constraint pairs C b = a, with a weight each.
        let k0 = self.params.k_initial;
        let n_c = 4 * points.len() + self.wks.ncols() + self.orientation.ncols();
        let mut a = Mat::<f64>::zeros(k0, n_c);
        let mut b = Mat::<f64>::zeros(k0, n_c);
        let mut w = Vec::with_capacity(n_c);
        let mut push =
            |col_b: MatRef<'_, f64>, col_a: MatRef<'_, f64>, sign: f64, weight: f64, w: &mut Vec<f64>| {
                let j = w.len();
                let norm = (0..k0).map(|i| col_b[(i, 0)].powi(2)).sum::<f64>().sqrt().max(f64::MIN_POSITIVE);
                for i in 0..k0 {
                    b[(i, j)] = col_b[(i, 0)] / norm;
                    a[(i, j)] = sign * col_a[(i, 0)] / norm;
                }
                w.push(weight);
            };
        // d(·, q) ∘ S = d(·, S⁻¹ q) = d(·, p) for S(p) = q.
        let fw = self.params.feature_weight / points.len() as f64;
        for &(p, q) in &points {
            push(coef.subcols(column(q), 1), coef.subcols(column(p), 1), 1.0, fw, &mut w);
        }
        // Heat kernels at the feature points, k_t(·, q) ∘ S = k_t(·, p): coefficients
        // e^{−λ t} φ(q) and e^{−λ t} φ(p), at a few scales from a delta (t = 0) to smooth bumps.
        let phi = self.spectrum.vectors();
        let lam_top = self.spectrum.eigenvalues[k0 - 1].max(f64::MIN_POSITIVE);
        let scales = [0.0, 1.0 / lam_top, 4.0 / lam_top];
        let hw = self.params.feature_weight / (points.len() * scales.len()) as f64;
        for &t in &scales {
            for &(p, q) in &points {
                let damp = |l: usize| (-self.spectrum.eigenvalues[l].max(0.0) * t).exp();
                let kq = Mat::from_fn(k0, 1, |l, _| damp(l) * phi[(q, l)]);
                let kp = Mat::from_fn(k0, 1, |l, _| damp(l) * phi[(p, l)]);
                push(kq.as_ref(), kp.as_ref(), 1.0, hw, &mut w);
            }
        }
        let ww = self.params.wks_weight / self.wks.ncols().max(1) as f64;
        for j in 0..self.wks.ncols() {
            push(self.wks.subcols(j, 1), self.wks.subcols(j, 1), 1.0, ww, &mut w);
        }
        let ow = self.params.orientation_weight / self.orientation.ncols().max(1) as f64;
        for j in 0..self.orientation.ncols() {
            push(self.orientation.subcols(j, 1), self.orientation.subcols(j, 1), -1.0, ow, &mut w);
        }
        solve_rows(a.as_ref(), b.as_ref(), &w, &self.spectrum.eigenvalues[..k0], &self.params)
    }

    /// ZoomOut on the samples, from a square functional map `c0` (at most `k_final²`) to
    /// `k_final × k_final`.
    pub fn zoomout(&self, c0: Mat<f64>) -> Result<Mat<f64>, EvalError> {
        let kf = self.params.k_final;
        if c0.nrows() != c0.ncols() || c0.nrows() > kf || c0.nrows() == 0 {
            return Err(EvalError::SizeMismatch(format!(
                "ZoomOut starts from a square map of at most {kf}², got {}×{}",
                c0.nrows(),
                c0.ncols()
            )));
        }
        let ns = self.samples.len();
        // Gram matrix of the sampled basis; its leading blocks serve every k.
        let mut gram = Mat::<f64>::zeros(kf, kf);
        matmul(
            gram.as_mut(),
            Accum::Replace,
            self.phi_samples.transpose(),
            self.phi_samples.as_ref(),
            1.0,
            Par::rayon(0),
        );
        let mut c = c0;
        let mut k = c.nrows();
        loop {
            let phi_k = self.phi_samples.subcols(0, k);
            let mut emb = Mat::<f64>::zeros(ns, k);
            crate::spectral::matmul_tall(emb.as_mut(), Accum::Replace, phi_k, c.as_ref(), 1.0, Par::rayon(0));
            let t = nearest_rows(emb.as_ref(), phi_k);
            if k == kf && c.nrows() == kf {
                // One more least-squares pass at the final size from the final point map.
                return self.least_squares(&gram, &t, kf);
            }
            k = (k + self.params.zoomout_step).min(kf);
            c = self.least_squares(&gram, &t, k)?;
        }
    }

    /// `argmin_C ‖Φ_s C − Φ_s[t]‖` over the samples, `k × k`.
    fn least_squares(&self, gram: &Mat<f64>, t: &[usize], k: usize) -> Result<Mat<f64>, EvalError> {
        let phi_k = self.phi_samples.subcols(0, k);
        let target = Mat::from_fn(t.len(), k, |i, j| self.phi_samples[(t[i], j)]);
        let mut rhs = Mat::<f64>::zeros(k, k);
        matmul(rhs.as_mut(), Accum::Replace, phi_k.transpose(), target.as_ref(), 1.0, Par::rayon(0));
        let g = Mat::from_fn(k, k, |i, j| gram[(i, j)] + if i == j { self.params.ridge } else { 0.0 });
        let llt = g.llt(Side::Lower).map_err(|_| {
            EvalError::InvalidInput("the sampled basis is rank-deficient (too few ZoomOut samples)".into())
        })?;
        Ok(faer::linalg::solvers::Solve::solve(&llt, rhs.as_ref()))
    }

    /// The mirror image of each of `vertices` under the functional map `c`.
    pub fn map_vertices(&self, c: MatRef<'_, f64>, vertices: &[usize]) -> Result<Vec<usize>, EvalError> {
        let k = c.nrows();
        if c.ncols() != k || k > self.spectrum.k() {
            return Err(EvalError::SizeMismatch(format!(
                "a {}×{} functional map for a spectrum of {} eigenpairs",
                c.nrows(),
                c.ncols(),
                self.spectrum.k()
            )));
        }
        let n = self.spectrum.n_vertices;
        if let Some(&v) = vertices.iter().find(|&&v| v >= n) {
            return Err(EvalError::InvalidInput(format!("vertex {v} is outside the shape's {n} vertices")));
        }
        let phi = self.spectrum.vectors().subcols(0, k);
        let rows = Mat::from_fn(vertices.len(), k, |i, j| phi[(vertices[i], j)]);
        let mut emb = Mat::<f64>::zeros(vertices.len(), k);
        crate::spectral::matmul_tall(emb.as_mut(), Accum::Replace, rows.as_ref(), c, 1.0, Par::rayon(0));
        Ok(nearest_rows(emb.as_ref(), phi))
    }

    /// The dense symmetry fitted to all of `features`.
    pub fn derive(&self, features: &SymmetricFeatures) -> Result<SymmetryMap, EvalError> {
        let fmap = self.fit(features)?;
        let all: Vec<usize> = (0..self.spectrum.n_vertices).collect();
        let map = self.map_vertices(fmap.as_ref(), &all)?;
        Ok(SymmetryMap { map, fmap })
    }

    /// Cross-validates the derivation over `n_folds` folds of the features (each feature point
    /// scored by a fit that did not see it), and checks that `derived` (the map fitted to all
    /// features) is close to an involution on up to 100 sampled vertices.
    pub fn validate(
        &self,
        features: &SymmetricFeatures,
        n_folds: usize,
        derived: &SymmetryMap,
    ) -> Result<SymmetryValidation, EvalError> {
        features.check(self.spectrum.n_vertices)?;
        let n = self.spectrum.n_vertices;
        if derived.map.len() != n || derived.map.iter().any(|&v| v >= n) {
            return Err(EvalError::SizeMismatch(format!(
                "a symmetry map of {} entries for a shape of {n} vertices",
                derived.map.len()
            )));
        }
        let folds = n_folds.clamp(2, features.pairs.len().max(2));
        let mut held_out = Vec::new();
        for f in 0..folds {
            let (out, kept) = features.fold(f, folds);
            if out.pairs.is_empty() && out.plane.is_empty() {
                continue;
            }
            if kept.pairs.is_empty() {
                return Err(EvalError::InvalidInput(
                    "too few feature pairs to hold some out (need at least 2)".into(),
                ));
            }
            let c = self.fit(&kept)?;
            let pts = out.points();
            let verts: Vec<usize> = pts.iter().map(|&(p, _)| p).collect();
            let mapped = self.map_vertices(c.as_ref(), &verts)?;
            let expected: Vec<usize> = pts.iter().map(|&(_, q)| q).collect();
            let fields = self.fields(&expected)?;
            for (j, (&(p, q), &m)) in pts.iter().zip(&mapped).enumerate() {
                held_out.push(FeatureError { vertex: p, expected: q, mapped: m, error: fields[(m, j)] });
            }
        }
        let errs: Vec<f64> = held_out.iter().map(|e| e.error).collect();
        let nh = errs.len().max(1) as f64;
        // Involution check on a spread of vertices.
        let step = (self.samples.len() / 100).max(1);
        let probe: Vec<usize> = self.samples.iter().step_by(step).take(100).copied().collect();
        let fields = self.fields(&probe)?;
        let back = probe
            .iter()
            .enumerate()
            .filter(|&(j, &v)| fields[(derived.map[derived.map[v]], j)] <= 0.05)
            .count();
        Ok(SymmetryValidation {
            folds,
            within_005: errs.iter().filter(|&&e| e <= 0.05).count() as f64 / nh,
            mean: errs.iter().sum::<f64>() / nh,
            max: errs.iter().copied().fold(0.0, f64::max),
            held_out,
            involution_within_005: back as f64 / probe.len().max(1) as f64,
        })
    }
}

/// Scales each column to unit Euclidean norm (zero columns stay zero).
fn unit_columns(mut m: Mat<f64>) -> Mat<f64> {
    for j in 0..m.ncols() {
        let norm = (0..m.nrows()).map(|i| m[(i, j)].powi(2)).sum::<f64>().sqrt();
        if norm > 0.0 {
            for i in 0..m.nrows() {
                m[(i, j)] /= norm;
            }
        }
    }
    m
}

/// Solves `min_C Σ_j w_j ‖C b_j − a_j‖² + μ ‖C Λ − Λ C‖² + ε ‖C‖²` row by row.
fn solve_rows(
    a: MatRef<'_, f64>,
    b: MatRef<'_, f64>,
    w: &[f64],
    lambda: &[f64],
    params: &SymmetryParams,
) -> Result<Mat<f64>, EvalError> {
    let k = b.nrows();
    let bw = Mat::from_fn(k, w.len(), |i, j| w[j] * b[(i, j)]);
    let mut g = Mat::<f64>::zeros(k, k);
    matmul(g.as_mut(), Accum::Replace, bw.as_ref(), b.transpose(), 1.0, Par::Seq);
    let mut rhs = Mat::<f64>::zeros(k, k);
    matmul(rhs.as_mut(), Accum::Replace, a, bw.transpose(), 1.0, Par::Seq);
    let scale = lambda.iter().fold(0f64, |m, &l| m.max(l.abs())).max(f64::MIN_POSITIVE);
    solve_rows_with_diagonal(g.as_ref(), rhs.as_ref(), |i, j| {
        let d = (lambda[j] - lambda[i]) / scale;
        params.commutativity * d * d + params.ridge
    })
    .map_err(|_| EvalError::InvalidInput("the symmetry least-squares system is not positive definite".into()))
}

/// The left/right self-map of one shape (`map[v]`: the vertex at the mirror image of `v`) from a
/// symmetry of the labels (`label_symmetry[k]`: the label at the mirror image of label `k`) and the
/// shape's label table (`truth[k]`: its vertex for label `k`). A vertex that carries no label takes
/// the mirror of its nearest labelled vertex (Euclidean). Inputs of mismatched lengths or out-of-range
/// entries are refused.
///
/// ```
/// use shapeforest::{eval::symmetry::vertex_symmetry, mesh::Mesh};
/// let v = vec![[-1.0, 0.0, 0.0], [-0.9, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
/// let mesh = Mesh::new(v, vec![[0, 2, 3], [0, 1, 3]]).unwrap();
/// // Labels 0 and 1 sit at x = −1 and x = 1 and mirror each other; vertex 1 carries no label.
/// let map = vertex_symmetry(&mesh, &[0, 2], &[1, 0]).unwrap();
/// assert_eq!(map[0], 2);
/// assert_eq!(map[2], 0);
/// assert_eq!(map[1], 2); // nearest labelled vertex is 0
/// ```
pub fn vertex_symmetry(
    mesh: &Mesh,
    truth: &[usize],
    label_symmetry: &[usize],
) -> Result<Vec<usize>, EvalError> {
    let n = mesh.n_vertices();
    if truth.len() != label_symmetry.len() {
        return Err(EvalError::SizeMismatch(format!(
            "a label symmetry of {} labels for a table of {}",
            label_symmetry.len(),
            truth.len()
        )));
    }
    if truth.iter().any(|&v| v >= n) || label_symmetry.iter().any(|&k| k >= truth.len()) {
        return Err(EvalError::InvalidInput("a label table or label symmetry entry is out of range".into()));
    }
    let pairs: Vec<(usize, usize)> =
        truth.iter().enumerate().map(|(k, &v)| (v, truth[label_symmetry[k]])).collect();
    crate::regularizer::symmetry_from_pairs(mesh, &pairs).map_err(|e| EvalError::InvalidInput(e.to_string()))
}
