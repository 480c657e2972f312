//! The spatial regulariser of Rodolà et al. (§5 of the method): it turns the forest's fuzzy,
//! symmetry-confused posterior into a consistent dense point-to-point map.
//!
//! 1. `n_samples` (default 50) Euclidean farthest-point samples on the test shape;
//! 2. candidate matches: each sample with its `top_k` most probable reference points;
//! 3. geodesic distances among the samples (test) and among the candidate points (reference),
//!    by the heat method, normalised by √area;
//! 4. game-theoretic matching picks a sparse, geodesically consistent subset with weights ω;
//! 5. the regularised functional map (eq. 11.19) with the distance maps of the matched pairs;
//! 6. conversion to a point-to-point map: among each vertex's forest candidates, the one whose
//!    geodesic distances to the anchors agree best with the vertex's own (plus the nearest
//!    neighbour in the spectral embedding, reported separately);
//! 7. anchor growth (on by default): the game keeps only a handful of matches (often ~10 of
//!    50 samples), too few to place every vertex; a denser set of farthest-point samples is
//!    mapped through the current map, the pairs that agree with the others are kept as
//!    anchors, and every vertex is placed again with locality-weighted distances to them,
//!    a few rounds (see [`AnchorGrowthParams`]);
//! 8. an optional ZoomOut refinement, off by default and reported separately.
//!
//! Shapes are prepared once ([`PreparedShape`]: mesh, spectrum, heat-method factorisation), so a
//! reference serves many test shapes.

use std::{sync::Arc, time::Instant};

mod pair;

pub use pair::{invert_map, pair_posterior, regularize_onto, regularize_pair, PairMap, PairParams};

use faer::Mat;
use serde::{Deserialize, Serialize};

use crate::{
    descriptor::{orientation_descriptors, wks_filter_sq},
    fmap::{self, FmapParams, SoftCorrespondence},
    forest::Prediction,
    geodesic::{farthest_point_sampling_euclidean, HeatMethodSolver, HeatParams},
    matching::{game_theoretic_matching, Candidate, GameMatcherParams},
    mesh::Mesh,
    spectral::Spectrum,
    Error,
};

/// A shape ready for regularisation: mesh, spectrum and a heat-method factorisation.
pub struct PreparedShape {
    /// The mesh.
    pub mesh: Arc<Mesh>,
    /// Its unit-area spectrum.
    pub spectrum: Arc<Spectrum>,
    /// Heat-method geodesic solver (factorised once).
    pub heat: HeatMethodSolver,
}

impl PreparedShape {
    /// Prepares a shape: factorises the heat-method matrices.
    pub fn new(mesh: Arc<Mesh>, spectrum: Arc<Spectrum>, heat: HeatParams) -> Result<Self, Error> {
        if spectrum.n_vertices != mesh.n_vertices() {
            return Err(fmap::FmapError::SizeMismatch(format!(
                "spectrum of {} vertices for a mesh of {}",
                spectrum.n_vertices,
                mesh.n_vertices()
            ))
            .into());
        }
        let heat = HeatMethodSolver::new(&mesh, heat)?;
        Ok(Self { mesh, spectrum, heat })
    }

    /// `√area` of the mesh, the unit of normalised distances.
    pub fn sqrt_area(&self) -> f64 {
        self.spectrum.area.sqrt()
    }
}

/// ZoomOut refinement settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ZoomOutParams {
    /// Final basis size.
    pub k_final: usize,
    /// Basis functions added per iteration.
    pub step: usize,
}

/// Anchor growth: densifies the game's sparse matches into many geodesically consistent ones
/// before the final placement of every vertex.
///
/// Each round maps `samples` Euclidean farthest-point samples of the test shape through the
/// current map, scores each pair by the median disagreement of its distances to the other
/// pairs (`|d_M(s_i, s_j) − d_R(t_i, t_j)|`, in √area units), keeps the `keep` fraction that
/// agrees best, and re-places every test vertex among its forest candidates by
/// `Σ_j w_j(m) |d_M(m, s_j) − d_R(r, t_j)|` with `w_j(m) = exp(−d_M(m, s_j) / locality)`, so that
/// nearby anchors, least affected by non-isometric distortion, count most. The last placement
/// is smoothed: a vertex's choice also pays for landing far from where its mesh neighbours
/// land (`smoothness`), and a candidate whose orientation descriptor disagrees pays
/// `orientation`. A second run whose first round is placed by orientation (`reorient`) guards
/// against a mirrored set of game anchors; the better oriented of the two maps is kept.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AnchorGrowthParams {
    /// Farthest-point samples mapped per round. Default 200.
    pub samples: usize,
    /// Fraction of the most consistent sample pairs kept as anchors, in (0, 1]. Default 0.7.
    pub keep: f64,
    /// Locality scale of the anchor weights (√area units; 0: uniform weights). Default 0.2.
    pub locality: f64,
    /// Rounds. Default 3.
    pub rounds: usize,
    /// Weight of the smoothness term of the final placement: the mean distance (√area units)
    /// on the reference between a vertex's placement and its mesh neighbours' (0: off).
    /// Default 2.
    pub smoothness: f64,
    /// At most this many sweeps of the smoothing. Default 10.
    pub smoothing_rounds: usize,
    /// Weight of the orientation term of every placement: a candidate pays
    /// `orientation · (1 − cos)/2`, `cos` the agreement of the orientation descriptors
    /// `⟨n, ∇f × ∇g⟩` (which change sign under a mirror image) at the vertex and at the
    /// candidate. Default 0.01 (√area units, like the distance cost).
    pub orientation: f64,
    /// Orientation weight of the first round of a second growth run (0: no second run). The
    /// game's anchors may be a mirror image of the reference, whole or in part, which distances
    /// alone cannot tell from the true map on a symmetric shape; the second run first puts
    /// every vertex on the side its orientation descriptor says, then grows as usual, and of
    /// the two maps the one whose orientation descriptors agree best over all vertices is kept.
    /// Default 1.
    pub reorient: f64,
}

impl Default for AnchorGrowthParams {
    fn default() -> Self {
        Self {
            samples: 200,
            keep: 0.7,
            locality: 0.2,
            rounds: 3,
            smoothness: 2.0,
            smoothing_rounds: 10,
            orientation: 0.01,
            reorient: 1.0,
        }
    }
}

impl AnchorGrowthParams {
    /// Checks the settings, naming the broken rule.
    pub fn check(&self) -> Result<(), String> {
        if self.samples < 3 {
            return Err(format!("growth_samples = {}: at least 3 are needed", self.samples));
        }
        if !(self.keep > 0.0 && self.keep <= 1.0) {
            return Err(format!("growth_keep = {}: must be in (0, 1]", self.keep));
        }
        if !(self.locality >= 0.0 && self.locality.is_finite()) {
            return Err(format!("growth_locality = {}: must be finite and ≥ 0", self.locality));
        }
        if !(self.smoothness >= 0.0 && self.smoothness.is_finite()) {
            return Err(format!("growth_smoothness = {}: must be finite and ≥ 0", self.smoothness));
        }
        for (name, v) in [("growth_orientation", self.orientation), ("growth_reorient", self.reorient)] {
            if !(v >= 0.0 && v.is_finite()) {
                return Err(format!("{name} = {v}: must be finite and ≥ 0"));
            }
        }
        if self.rounds == 0 {
            return Err("growth_rounds = 0: at least 1 (turn growth off with growth_samples = 0)".into());
        }
        Ok(())
    }
}

/// Parameters of the regulariser.
#[derive(Clone, Debug, PartialEq)]
pub struct RegularizerParams {
    /// Farthest-point samples on the test shape. Default 50 (the paper's choice).
    pub n_samples: usize,
    /// Candidate reference points per sample (most probable labels). Default 5.
    pub top_k: usize,
    /// Game-theoretic matcher settings.
    pub matcher: GameMatcherParams,
    /// Functional-map solve settings.
    pub fmap: FmapParams,
    /// Heat-method settings for the distance maps.
    pub heat: HeatParams,
    /// Anchor growth before the final placement (default on; `None`: the game's anchors only).
    pub growth: Option<AnchorGrowthParams>,
    /// Optional ZoomOut refinement after the solve. Default off.
    pub zoomout: Option<ZoomOutParams>,
}

impl Default for RegularizerParams {
    fn default() -> Self {
        Self {
            n_samples: 50,
            top_k: 5,
            matcher: GameMatcherParams::default(),
            fmap: FmapParams::default(),
            heat: HeatParams::default(),
            growth: Some(AnchorGrowthParams::default()),
            zoomout: None,
        }
    }
}

/// A matched pair of vertices with its confidence.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct VertexMatch {
    /// Vertex of the test shape.
    pub test: usize,
    /// Vertex of the reference shape.
    pub reference: usize,
    /// Confidence in (0, 1].
    pub weight: f64,
}

/// Seconds spent in each stage of the regulariser.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RegularizerTimings {
    /// Farthest point sampling and candidate selection.
    pub sampling_s: f64,
    /// Heat-method distance maps on both shapes.
    pub distances_s: f64,
    /// Game-theoretic matching.
    pub matching_s: f64,
    /// Functional-map assembly and solve.
    pub fmap_s: f64,
    /// Point-to-point conversion.
    pub point_map_s: f64,
    /// Anchor growth (0 when off).
    #[serde(default)]
    pub growth_s: f64,
    /// ZoomOut refinement (0 when off).
    pub zoomout_s: f64,
}

/// The result of regularising one prediction.
pub struct DenseMap {
    /// Test vertex → reference vertex (the regulariser's output): [`DenseMap::anchor_map`]
    /// after anchor growth (the same map when growth is off).
    pub map: Vec<usize>,
    /// Test vertex → reference vertex placed by the game's anchors alone: among the forest's
    /// candidates of each vertex, the one whose geodesic distances to the matched anchors agree
    /// best with the vertex's own (`Σ_j ω_j |d_M(m, p_j) − d_R(r, q_j)|`, the pointwise form of
    /// the distance-map term of eq. 11.19); vertices without candidates take the functional
    /// map's.
    pub anchor_map: Vec<usize>,
    /// Anchors used in the last round of growth (0 when growth is off).
    pub grown_anchors: usize,
    /// Mean orientation agreement (in [−1, 1]) of the grown map over all test vertices
    /// (`None` when growth is off); negative for a mirror image.
    pub dense_orientation: Option<f64>,
    /// Whether growth found a mirror image and the strongly oriented second run replaced it.
    pub reoriented: bool,
    /// Test vertex → reference vertex: among the forest's candidates, the one nearest to the
    /// regularised functional map's spectral embedding.
    pub spectral_map: Vec<usize>,
    /// Test vertex → reference vertex from the regularised functional map alone
    /// (unrestricted nearest neighbour in the spectral embedding).
    pub fmap_map: Vec<usize>,
    /// The ZoomOut-refined map, when refinement was asked for.
    pub refined_map: Option<Vec<usize>>,
    /// The forest's own maximum-a-posteriori map (test vertex → reference vertex), for
    /// comparison; `None` where the forest gave no label.
    pub forest_map: Vec<Option<usize>>,
    /// The functional map of the raw prediction (`k_test × k_ref`).
    pub fmap_predicted: Mat<f64>,
    /// The regularised functional map.
    pub fmap: Mat<f64>,
    /// The sparse consistent matches chosen by the game.
    pub matches: Vec<VertexMatch>,
    /// Weighted mean agreement (in [−1, 1]) of the orientation descriptors at the matches:
    /// positive for an orientation-preserving match set, negative for a mirror image.
    pub orientation_score: f64,
    /// Whether the first equilibrium of the game was a mirror image and was replaced by the
    /// orientation-preserving one.
    pub mirror_rejected: bool,
    /// Time per stage.
    pub timings: RegularizerTimings,
}

/// A forest prediction read through a label → reference-vertex table.
struct LabelledPosterior<'a> {
    prediction: &'a Prediction,
    label_to_vertex: Option<&'a [usize]>,
}

impl LabelledPosterior<'_> {
    fn vertex(&self, label: u32) -> usize {
        match self.label_to_vertex {
            Some(t) => t[label as usize],
            None => label as usize,
        }
    }
}

impl SoftCorrespondence for LabelledPosterior<'_> {
    fn n_test_vertices(&self) -> usize {
        self.prediction.n_vertices()
    }
    fn for_each_entry(&self, m: usize, f: &mut dyn FnMut(usize, f64)) {
        let (labels, probs) = self.prediction.posterior(m);
        for (&l, &p) in labels.iter().zip(probs) {
            f(self.vertex(l), p as f64);
        }
    }
}

/// Symmetrised, normalised distance matrix among `points` from their fields (`n × points`).
fn pairwise(fields: &Mat<f64>, points: &[usize], scale: f64) -> Vec<f64> {
    let s = points.len();
    let mut d = vec![0.0; s * s];
    for i in 0..s {
        for j in 0..s {
            d[i * s + j] = 0.5 * (fields[(points[j], i)] + fields[(points[i], j)]) / scale;
        }
    }
    d
}

/// The sparse, geodesically consistent matches of a prediction (steps 1–4 of the regulariser),
/// with the distance fields the dense step reuses.
pub struct SparseMatches {
    /// Farthest-point samples on the test shape.
    pub samples: Vec<usize>,
    /// Reference vertices that are candidates of some sample.
    pub ref_points: Vec<usize>,
    /// Distances (divided by √area) from the test vertex of each match (`n_test × matches`):
    /// the distance maps `d_p` of eq. 11.19. Only the matched columns are kept, so a job
    /// waiting for the dense step holds little.
    pub test_fields: Mat<f64>,
    /// Distances (divided by √area) from the reference vertex of each match (`n_ref × matches`).
    pub ref_fields: Mat<f64>,
    /// The game's equilibrium: indices into `samples` and `ref_points`, with weights.
    pub game: crate::matching::GameMatching,
    /// The matches in vertex indices.
    pub matches: Vec<VertexMatch>,
    /// Orientation agreement of the match set (see [`DenseMap::orientation_score`]).
    pub orientation_score: f64,
    /// Whether a mirror-image equilibrium was replaced.
    pub mirror_rejected: bool,
    /// Time of sampling, distances and matching.
    pub timings: RegularizerTimings,
}

fn check_inputs(
    test: &PreparedShape,
    reference: &PreparedShape,
    prediction: &Prediction,
    label_to_vertex: Option<&[usize]>,
    params: &RegularizerParams,
) -> Result<(), Error> {
    params.matcher.check()?;
    params.fmap.check()?;
    if let Some(g) = &params.growth {
        g.check().map_err(|reason| fmap::FmapError::InvalidParameter { name: "growth", reason })?;
    }
    let n_ref = reference.mesh.n_vertices();
    if prediction.n_vertices() != test.mesh.n_vertices() {
        return Err(fmap::FmapError::SizeMismatch(format!(
            "prediction for {} vertices, test shape has {}",
            prediction.n_vertices(),
            test.mesh.n_vertices()
        ))
        .into());
    }
    match label_to_vertex {
        Some(t) if t.len() != prediction.n_labels() || t.iter().any(|&v| v >= n_ref) => {
            Err(fmap::FmapError::SizeMismatch(format!(
                "label table of {} entries for {} labels and a reference of {n_ref} vertices",
                t.len(),
                prediction.n_labels()
            ))
            .into())
        }
        None if prediction.n_labels() > n_ref => Err(fmap::FmapError::SizeMismatch(format!(
            "{} labels but the reference has only {n_ref} vertices: give a label → vertex table",
            prediction.n_labels()
        ))
        .into()),
        _ => Ok(()),
    }
}

/// Regularises a forest prediction for `test` against `reference`: [`sparse_matches`] then
/// [`dense_map`].
///
/// `label_to_vertex` maps forest labels to reference vertices (`None`: label = vertex index).
pub fn regularize(
    test: &PreparedShape,
    reference: &PreparedShape,
    prediction: &Prediction,
    label_to_vertex: Option<&[usize]>,
    params: &RegularizerParams,
) -> Result<DenseMap, Error> {
    let sparse = sparse_matches(test, reference, prediction, label_to_vertex, params)?;
    dense_map(test, reference, prediction, label_to_vertex, &sparse, params)
}

/// Steps 1–4: farthest-point samples, their candidate matches, heat-method distances and the
/// game-theoretic selection of a consistent, orientation-preserving match set.
pub fn sparse_matches(
    test: &PreparedShape,
    reference: &PreparedShape,
    prediction: &Prediction,
    label_to_vertex: Option<&[usize]>,
    params: &RegularizerParams,
) -> Result<SparseMatches, Error> {
    check_inputs(test, reference, prediction, label_to_vertex, params)?;
    let posterior = LabelledPosterior { prediction, label_to_vertex };
    let mut timings = RegularizerTimings::default();
    // 1–2. Samples and candidates.
    let t0 = Instant::now();
    let n_samples = params.n_samples.min(test.mesh.n_vertices());
    let samples = farthest_point_sampling_euclidean(&test.mesh, n_samples, None)?;
    let mut ref_points: Vec<usize> = Vec::new();
    let mut ref_index = std::collections::HashMap::new();
    let mut candidates = Vec::new();
    for (i, &m) in samples.iter().enumerate() {
        for (label, p) in prediction.top_k(m, params.top_k) {
            let r = posterior.vertex(label);
            let idx = *ref_index.entry(r).or_insert_with(|| {
                ref_points.push(r);
                ref_points.len() - 1
            });
            candidates.push(Candidate { test: i, reference: idx, prior: p as f64 });
        }
    }
    timings.sampling_s = t0.elapsed().as_secs_f64();

    // 3. Distances.
    let t0 = Instant::now();
    let test_fields = test.heat.distances_from_many(&samples)?;
    let ref_fields = reference.heat.distances_from_many(&ref_points)?;
    let d_test = pairwise(&test_fields, &samples, test.sqrt_area());
    let d_ref = pairwise(&ref_fields, &ref_points, reference.sqrt_area());
    timings.distances_s = t0.elapsed().as_secs_f64();

    // 4. Game.
    let t0 = Instant::now();
    let orientation = Orientation::of(test, reference);
    let agreement = |m: usize, r: usize| orientation.agreement(m, r);
    let group_score = |g: &crate::matching::GameMatching| {
        let (mut num, mut den) = (0.0, 0.0);
        for m in &g.matches {
            num += m.weight * agreement(samples[m.test], ref_points[m.reference]);
            den += m.weight;
        }
        if den > 0.0 {
            num / den
        } else {
            0.0
        }
    };
    let play = |candidates: &[Candidate]| {
        game_theoretic_matching(candidates, &d_test, samples.len(), &d_ref, ref_points.len(), &params.matcher)
    };
    let mut game = play(&candidates)?;
    let mut orientation_score = group_score(&game);
    let mut mirror_rejected = false;
    if orientation_score < 0.0 {
        // The equilibrium is a mirror image: play again among orientation-preserving candidates.
        let kept: Vec<Candidate> = candidates
            .iter()
            .copied()
            .filter(|c| agreement(samples[c.test], ref_points[c.reference]) > 0.0)
            .collect();
        let second = play(&kept)?;
        let second_score = group_score(&second);
        if second_score > orientation_score && !second.matches.is_empty() {
            game = second;
            orientation_score = second_score;
            mirror_rejected = true;
        }
    }
    timings.matching_s = t0.elapsed().as_secs_f64();

    let matches = game
        .matches
        .iter()
        .map(|m| VertexMatch { test: samples[m.test], reference: ref_points[m.reference], weight: m.weight })
        .collect();
    let (ts, rs) = (test.sqrt_area(), reference.sqrt_area());
    let kept_test = Mat::from_fn(test.mesh.n_vertices(), game.matches.len(), |v, j| {
        test_fields[(v, game.matches[j].test)] / ts
    });
    let kept_ref = Mat::from_fn(reference.mesh.n_vertices(), game.matches.len(), |v, j| {
        ref_fields[(v, game.matches[j].reference)] / rs
    });
    Ok(SparseMatches {
        samples,
        ref_points,
        test_fields: kept_test,
        ref_fields: kept_ref,
        game,
        matches,
        orientation_score,
        mirror_rejected,
        timings,
    })
}

/// Steps 5–6: the regularised functional map from the prediction and the sparse matches'
/// distance maps, and its conversion to point-to-point maps.
pub fn dense_map(
    test: &PreparedShape,
    reference: &PreparedShape,
    prediction: &Prediction,
    label_to_vertex: Option<&[usize]>,
    sparse: &SparseMatches,
    params: &RegularizerParams,
) -> Result<DenseMap, Error> {
    check_inputs(test, reference, prediction, label_to_vertex, params)?;
    let n_ref = reference.mesh.n_vertices();
    let posterior = LabelledPosterior { prediction, label_to_vertex };
    let mut timings = sparse.timings;
    let SparseMatches { test_fields, ref_fields, game, .. } = sparse;
    // 5. Functional maps.
    let t0 = Instant::now();
    let (kt, kr) = (params.fmap.k_test.min(test.spectrum.k()), params.fmap.k_ref.min(reference.spectrum.k()));
    let fmap_predicted = fmap::pullback_fmap(&test.spectrum, &reference.spectrum, kt, kr, &posterior)?;
    let (a_fields, b_fields) = (test_fields, ref_fields);
    if a_fields.ncols() != game.matches.len() || b_fields.nrows() != n_ref {
        return Err(fmap::FmapError::SizeMismatch("sparse matches of another shape pair".into()).into());
    }
    let a = fmap::spectral_coefficients(&test.spectrum, kt, a_fields.as_ref())?;
    let b = fmap::spectral_coefficients(&reference.spectrum, kr, b_fields.as_ref())?;
    let weights: Vec<f64> = game.matches.iter().map(|m| m.weight).collect();
    let fmap_params = FmapParams { k_test: kt, k_ref: kr, ..params.fmap.clone() };
    let c = fmap::solve_regularised_fmap(
        fmap_predicted.as_ref(),
        a.as_ref(),
        b.as_ref(),
        &weights,
        &test.spectrum.eigenvalues,
        &reference.spectrum.eigenvalues,
        &fmap_params,
    )?;
    timings.fmap_s = t0.elapsed().as_secs_f64();

    // 6. Point map, and optional refinement.
    let t0 = Instant::now();
    let fmap_map = fmap::point_to_point(&test.spectrum, &reference.spectrum, c.as_ref())?;
    let spectral_map =
        fmap::point_to_point_restricted(&test.spectrum, &reference.spectrum, c.as_ref(), &posterior)?;
    let anchor_map = anchor_consistent_map(a_fields, b_fields, &weights, &posterior, &fmap_map);
    timings.point_map_s = t0.elapsed().as_secs_f64();
    let grown = match &params.growth {
        Some(g) if !weights.is_empty() => {
            let t0 = Instant::now();
            let grown = grow_anchors(test, reference, &posterior, anchor_map.clone(), g)?;
            timings.growth_s = t0.elapsed().as_secs_f64();
            Some(grown)
        }
        _ => None,
    };
    let (map, grown_anchors, dense_orientation, reoriented) = match grown {
        Some(g) => (g.map, g.anchors, Some(g.orientation), g.reoriented),
        None => (anchor_map.clone(), 0, None, false),
    };
    let refined_map = match params.zoomout {
        Some(z) if kt == kr => {
            let t0 = Instant::now();
            let k_final = z.k_final.min(test.spectrum.k()).min(reference.spectrum.k());
            let (_, refined) =
                fmap::zoomout(&test.spectrum, &reference.spectrum, c.as_ref(), k_final, z.step)?;
            timings.zoomout_s = t0.elapsed().as_secs_f64();
            Some(refined)
        }
        _ => None,
    };

    let forest_map = prediction.map_labels().into_iter().map(|l| l.map(|l| posterior.vertex(l))).collect();
    Ok(DenseMap {
        map,
        anchor_map,
        grown_anchors,
        dense_orientation,
        reoriented,
        spectral_map,
        fmap_map,
        refined_map,
        forest_map,
        fmap_predicted,
        fmap: c,
        matches: sparse.matches.clone(),
        orientation_score: sparse.orientation_score,
        mirror_rejected: sparse.mirror_rejected,
        timings,
    })
}

/// For each test vertex, the candidate reference vertex whose normalised distances to the
/// anchors best match the vertex's own (weighted L1); `fallback` where there is no candidate
/// or no anchor.
fn anchor_consistent_map(
    test_fields: &Mat<f64>,
    ref_fields: &Mat<f64>,
    weights: &[f64],
    posterior: &LabelledPosterior<'_>,
    fallback: &[usize],
) -> Vec<usize> {
    use rayon::prelude::*;
    let s = weights.len();
    if s == 0 {
        return fallback.to_vec();
    }
    (0..fallback.len())
        .into_par_iter()
        .map(|m| {
            let mut best = (f64::INFINITY, fallback[m]);
            posterior.for_each_entry(m, &mut |r, _| {
                let cost: f64 =
                    (0..s).map(|j| weights[j] * (test_fields[(m, j)] - ref_fields[(r, j)]).abs()).sum();
                if cost < best.0 {
                    best = (cost, r);
                }
            });
            best.1
        })
        .collect()
}

/// Anchor growth (see [`AnchorGrowthParams`]): returns the final map and the number of anchors
/// of the last round.
fn grow_anchors(
    test: &PreparedShape,
    reference: &PreparedShape,
    posterior: &LabelledPosterior<'_>,
    start: Vec<usize>,
    p: &AnchorGrowthParams,
) -> Result<Grown, Error> {
    let orientation = Orientation::of(test, reference);
    // Shared by both runs: the samples, their test-side fields, and the reference fields of
    // the first round's targets (the same in both runs).
    let samples = farthest_point_sampling_euclidean(&test.mesh, p.samples.min(test.mesh.n_vertices()), None)?;
    if samples.len() < 3 {
        let score = orientation.mean_agreement(&start);
        return Ok(Grown { map: start, anchors: 0, orientation: score, reoriented: false });
    }
    let a_fields = test.heat.distances_from_many(&samples)?;
    let mut first: Vec<usize> = samples.iter().map(|&v| start[v]).collect();
    first.sort_unstable();
    first.dedup();
    let setup =
        GrowthSetup { first_cols: reference_columns(reference, &first)?, samples, a_fields, orientation };
    let (map, anchors) = grow_rounds(test, reference, posterior, start.clone(), p, p.orientation, &setup)?;
    let score = setup.orientation.mean_agreement(&map);
    if p.reorient <= 0.0 {
        return Ok(Grown { map, anchors, orientation: score, reoriented: false });
    }
    // The second hypothesis: a first round placed with a strong orientation term, which puts
    // every vertex on the side its orientation descriptor says (undoing a mirror image of the
    // game's anchors, whole or in part), then the ordinary rounds. The better oriented map wins.
    let (second, second_anchors) = grow_rounds(test, reference, posterior, start, p, p.reorient, &setup)?;
    let second_score = setup.orientation.mean_agreement(&second);
    if second_score > score {
        Ok(Grown { map: second, anchors: second_anchors, orientation: second_score, reoriented: true })
    } else {
        Ok(Grown { map, anchors, orientation: score, reoriented: false })
    }
}

/// What both growth runs share.
struct GrowthSetup {
    /// Farthest-point samples of the test shape.
    samples: Vec<usize>,
    /// Distances from the samples on the test shape (`n_test × samples`, not normalised).
    a_fields: Mat<f64>,
    /// Normalised reference distance columns of the first round's targets.
    first_cols: std::collections::HashMap<usize, Vec<f32>>,
    /// Orientation descriptors of the test and reference shapes.
    orientation: Orientation,
}

/// Normalised (÷ √area) reference distance columns from `targets`, as f32, one block solve.
fn reference_columns(
    reference: &PreparedShape,
    targets: &[usize],
) -> Result<std::collections::HashMap<usize, Vec<f32>>, Error> {
    let rs = 1.0 / reference.sqrt_area();
    let f = reference.heat.distances_from_many(targets)?;
    Ok(targets
        .iter()
        .enumerate()
        .map(|(j, &t)| (t, f.col(j).iter().map(|&d| (d * rs) as f32).collect()))
        .collect())
}

/// What anchor growth returns.
struct Grown {
    map: Vec<usize>,
    anchors: usize,
    /// Mean orientation agreement of the map over all test vertices.
    orientation: f64,
    /// Whether the map came from the second, strongly oriented run.
    reoriented: bool,
}

/// The rounds of anchor growth from `start`.
fn grow_rounds(
    test: &PreparedShape,
    reference: &PreparedShape,
    posterior: &LabelledPosterior<'_>,
    start: Vec<usize>,
    p: &AnchorGrowthParams,
    first_orientation: f64,
    setup: &GrowthSetup,
) -> Result<(Vec<usize>, usize), Error> {
    use rayon::prelude::*;
    let (n_t, n_r) = (test.mesh.n_vertices(), reference.mesh.n_vertices());
    let GrowthSetup { samples, a_fields, first_cols, orientation } = setup;
    let s = samples.len();
    let ts = 1.0 / test.sqrt_area();
    let a_col = |j: usize| a_fields.col(j);
    // Reference-side fields, computed once per distinct target and dropped when unused.
    let mut ref_cols = first_cols.clone();
    let mut map = start;
    let n_keep = ((s as f64 * p.keep).ceil() as usize).clamp(3, s);
    let mut used = 0;
    for round in 0..p.rounds {
        let targets: Vec<usize> = samples.iter().map(|&v| map[v]).collect();
        let mut missing: Vec<usize> = targets.iter().copied().filter(|t| !ref_cols.contains_key(t)).collect();
        missing.sort_unstable();
        missing.dedup();
        if !missing.is_empty() {
            ref_cols.extend(reference_columns(reference, &missing)?);
        }
        ref_cols.retain(|t, _| targets.contains(t));
        // Consistency of each pair with the others: median distance disagreement.
        let mut consistency: Vec<(f64, usize)> = (0..s)
            .into_par_iter()
            .map(|i| {
                let ci = &ref_cols[&targets[i]];
                let mut d: Vec<f64> = (0..s)
                    .filter(|&j| j != i)
                    .map(|j| (a_col(i)[samples[j]] * ts - ci[targets[j]] as f64).abs())
                    .collect();
                let mid = d.len() / 2;
                d.select_nth_unstable_by(mid, f64::total_cmp);
                (d[mid], i)
            })
            .collect();
        consistency.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let kept: Vec<usize> = consistency[..n_keep].iter().map(|c| c.1).collect();
        let k = kept.len();
        // Row-major tables: test distances and weights (n_t × k), reference distances (n_r × k).
        let mut a = vec![0f32; n_t * k];
        let mut w = vec![0f32; n_t * k];
        for (j, &i) in kept.iter().enumerate() {
            let col = a_col(i);
            for v in 0..n_t {
                let d = col[v] * ts;
                a[v * k + j] = d as f32;
                w[v * k + j] = if p.locality > 0.0 { (-d / p.locality).exp() as f32 } else { 1.0 };
            }
        }
        let mut b = vec![0f32; n_r * k];
        for (j, &i) in kept.iter().enumerate() {
            let col = &ref_cols[&targets[i]];
            for r in 0..n_r {
                b[r * k + j] = col[r];
            }
        }
        let last = round + 1 == p.rounds;
        let gamma = if round == 0 { first_orientation } else { p.orientation } as f32;
        // Each vertex's candidates with their cost (mean locality-weighted disagreement, in
        // √area units); the cheapest is the new placement. The last round keeps the table for
        // the smoothing below.
        let placed: Vec<(usize, Vec<(u32, f32)>)> = (0..n_t)
            .into_par_iter()
            .map(|m| {
                let (am, wm) = (&a[m * k..(m + 1) * k], &w[m * k..(m + 1) * k]);
                let norm = 1.0 / wm.iter().sum::<f32>().max(f32::MIN_POSITIVE);
                let mut best = (f32::INFINITY, map[m]);
                let mut table = Vec::new();
                posterior.for_each_entry(m, &mut |r, _| {
                    let br = &b[r * k..(r + 1) * k];
                    let mut cost: f32 =
                        am.iter().zip(wm).zip(br).map(|((x, w), y)| w * (x - y).abs()).sum::<f32>() * norm;
                    if gamma > 0.0 {
                        cost += gamma * (0.5 * (1.0 - orientation.agreement(m, r))) as f32;
                    }
                    if cost < best.0 {
                        best = (cost, r);
                    }
                    if last {
                        table.push((r as u32, cost));
                    }
                });
                (best.1, table)
            })
            .collect();
        map = placed.iter().map(|p| p.0).collect();
        if last && p.smoothness > 0.0 && p.smoothing_rounds > 0 {
            let table: Vec<Vec<(u32, f32)>> = placed.into_iter().map(|p| p.1).collect();
            map = smooth_placement(&test.mesh, &reference.mesh, reference.sqrt_area(), &table, map, p);
        }
        used = k;
    }
    Ok((map, used))
}

/// Smoothing of the final placement (iterated conditional modes): each test vertex takes the
/// candidate minimising its anchor cost plus `smoothness` times the mean Euclidean distance
/// (√area units) on the reference to where its mesh neighbours are placed, all vertices at
/// once, until nothing changes or `smoothing_rounds` have run. It removes isolated
/// misplacements that the anchors alone cannot tell apart.
fn smooth_placement(
    test: &Mesh,
    reference: &Mesh,
    ref_sqrt_area: f64,
    table: &[Vec<(u32, f32)>],
    mut map: Vec<usize>,
    p: &AnchorGrowthParams,
) -> Vec<usize> {
    use rayon::prelude::*;
    let n = test.n_vertices();
    let (degree, nbrs) = crate::mesh::face_neighbour_lists(&test.faces, n);
    let pos = &reference.vertices;
    let scale = p.smoothness / ref_sqrt_area.max(f64::MIN_POSITIVE);
    for _ in 0..p.smoothing_rounds {
        let next: Vec<usize> = (0..n)
            .into_par_iter()
            .map(|m| {
                let nb = &nbrs[degree[m]..degree[m + 1]];
                if table[m].len() < 2 || nb.is_empty() {
                    return map[m];
                }
                let inv = scale / nb.len() as f64;
                let mut best = (f64::INFINITY, map[m]);
                for &(r, c) in &table[m] {
                    let x = pos[r as usize];
                    let spread: f64 = nb
                        .iter()
                        .map(|&q| {
                            let y = pos[map[q]];
                            ((x[0] - y[0]).powi(2) + (x[1] - y[1]).powi(2) + (x[2] - y[2]).powi(2)).sqrt()
                        })
                        .sum();
                    let total = c as f64 + inv * spread;
                    if total < best.0 {
                        best = (total, r as usize);
                    }
                }
                best.1
            })
            .collect();
        let changed = next.iter().zip(&map).any(|(a, b)| a != b);
        map = next;
        if !changed {
            break;
        }
    }
    map
}

/// The orientation descriptors of a test and a reference shape, from the same band-pass
/// energies (chosen on the reference spectrum), as row-major `n × width` tables.
struct Orientation {
    test: Vec<f64>,
    reference: Vec<f64>,
    width: usize,
}

impl Orientation {
    fn of(test: &PreparedShape, reference: &PreparedShape) -> Self {
        let energies = orientation_energies(&reference.spectrum);
        let o_test =
            orientation_descriptors(&test.mesh, orientation_functions(&test.spectrum, &energies).as_ref());
        let o_ref = orientation_descriptors(
            &reference.mesh,
            orientation_functions(&reference.spectrum, &energies).as_ref(),
        );
        let width = o_test.len() / test.mesh.n_vertices().max(1);
        Self { test: o_test, reference: o_ref, width }
    }

    /// Agreement (cosine, in [−1, 1]) of test vertex `m`'s descriptor with reference vertex `r`'s:
    /// positive where matching `m` to `r` preserves orientation.
    fn agreement(&self, m: usize, r: usize) -> f64 {
        let w = self.width;
        cosine(&self.test[m * w..(m + 1) * w], &self.reference[r * w..(r + 1) * w])
    }

    /// Mean agreement along a map (test vertex → reference vertex).
    fn mean_agreement(&self, map: &[usize]) -> f64 {
        map.iter().enumerate().map(|(m, &r)| self.agreement(m, r)).sum::<f64>() / map.len().max(1) as f64
    }
}

/// Log-energies of the band-pass functions behind the orientation descriptors: five, spread
/// over the low part of the reference spectrum (eigenvalues 1 to ~30), where descriptors are
/// smooth enough for stable gradients.
fn orientation_energies(reference: &Spectrum) -> Vec<f64> {
    let lam = &reference.eigenvalues;
    let first = lam.iter().position(|&l| l > 1e-9 * lam.last().copied().unwrap_or(1.0)).unwrap_or(0);
    let last = (first + 30).min(lam.len().saturating_sub(1));
    let (lo, hi) = (lam[first].max(1e-12).ln(), lam[last].max(1e-12).ln());
    (0..5).map(|i| lo + (hi - lo) * (i as f64 + 0.5) / 5.0).collect()
}

/// Band-pass (WKS-like) functions at the given log-energies, normalised per energy.
fn orientation_functions(spectrum: &Spectrum, energies: &[f64]) -> Mat<f64> {
    let sigma = if energies.len() > 1 {
        (energies[energies.len() - 1] - energies[0]) / (energies.len() - 1) as f64
    } else {
        1.0
    };
    let n = spectrum.n_vertices;
    let mut f = Mat::zeros(n, energies.len());
    for (c, &e) in energies.iter().enumerate() {
        let w: Vec<f64> = spectrum
            .eigenvalues
            .iter()
            .map(|&l| if l > 0.0 { wks_filter_sq(e, l, sigma) } else { 0.0 })
            .collect();
        let norm: f64 = w.iter().sum::<f64>().max(f64::MIN_POSITIVE);
        for (k, &wk) in w.iter().enumerate() {
            if wk > 1e-12 * norm {
                let phi = spectrum.phi(k);
                for v in 0..n {
                    f[(v, c)] += wk / norm * phi[v] * phi[v];
                }
            }
        }
    }
    f
}

fn cosine(a: &[f64], b: &[f64]) -> f64 {
    let (mut ab, mut aa, mut bb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        ab += x * y;
        aa += x * x;
        bb += y * y;
    }
    if aa > 0.0 && bb > 0.0 {
        ab / (aa * bb).sqrt()
    } else {
        0.0
    }
}
