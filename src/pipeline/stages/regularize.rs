//! `matcher` ([`PredictedShape`] → [`SparselyMatched`]: farthest-point samples, candidates,
//! geodesic distances, game-theoretic matching) and `fmap` ([`SparselyMatched`] →
//! [`MatchedShape`]: the regularised functional map and the dense point map).

use std::sync::Arc;

use serde::Deserialize;

use crate::{
    geodesic::HeatParams,
    pipeline::{
        actor::Stage,
        message::{Failure, Job, MatchedShape, PredictedShape, SparselyMatched},
    },
    regularizer::{
        dense_map, sparse_matches, AnchorGrowthParams, PreparedShape, RegularizerParams, ZoomOutParams,
    },
};

/// Settings of `matcher`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MatcherConfig {
    /// Farthest-point samples on the scan. Default 50.
    #[serde(default = "default_samples")]
    pub samples: usize,
    /// Candidate reference points per sample. Default 5.
    #[serde(default = "default_top_k")]
    pub top_k: usize,
    /// Distance-distortion scale σ of the game's payoff (distances / √area). Default 0.05.
    #[serde(default = "default_sigma")]
    pub sigma: f64,
}

fn default_samples() -> usize {
    50
}
fn default_top_k() -> usize {
    5
}
fn default_sigma() -> f64 {
    0.05
}

impl Default for MatcherConfig {
    fn default() -> Self {
        Self { samples: default_samples(), top_k: default_top_k(), sigma: default_sigma() }
    }
}

/// Settings of `fmap`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FmapConfig {
    /// Laplace basis size on each shape. Default 40.
    #[serde(default = "default_basis")]
    pub basis: usize,
    /// Weight of the distance-map term. Default 1.
    #[serde(default = "default_one")]
    pub match_weight: f64,
    /// Weight of the Laplacian commutativity term. Default 0 (off).
    #[serde(default)]
    pub commutativity: f64,
    /// ZoomOut refinement to this basis size (0: off). Default 0.
    #[serde(default)]
    pub zoomout_to: usize,
    /// Anchor growth: farthest-point samples mapped per round (0: off, the game's anchors
    /// only). Default 200.
    #[serde(default = "default_growth_samples")]
    pub growth_samples: usize,
    /// Anchor growth: fraction of the most consistent pairs kept. Default 0.7.
    #[serde(default = "default_growth_keep")]
    pub growth_keep: f64,
    /// Anchor growth: locality of the anchor weights (√area units, 0: uniform). Default 0.2.
    #[serde(default = "default_growth_locality")]
    pub growth_locality: f64,
    /// Anchor growth: rounds. Default 3.
    #[serde(default = "default_growth_rounds")]
    pub growth_rounds: usize,
    /// Anchor growth: weight of the neighbour-smoothness term of the final placement (0: off).
    /// Default 2.
    #[serde(default = "default_growth_smoothness")]
    pub growth_smoothness: f64,
    /// Anchor growth: weight of the orientation term of every placement. Default 0.01.
    #[serde(default = "default_growth_orientation")]
    pub growth_orientation: f64,
    /// Anchor growth: orientation weight of the first round of the second, re-orienting run
    /// (0: no second run). Default 1.
    #[serde(default = "default_growth_reorient")]
    pub growth_reorient: f64,
}

fn default_growth_samples() -> usize {
    AnchorGrowthParams::default().samples
}
fn default_growth_keep() -> f64 {
    AnchorGrowthParams::default().keep
}
fn default_growth_locality() -> f64 {
    AnchorGrowthParams::default().locality
}
fn default_growth_rounds() -> usize {
    AnchorGrowthParams::default().rounds
}
fn default_growth_smoothness() -> f64 {
    AnchorGrowthParams::default().smoothness
}
fn default_growth_orientation() -> f64 {
    AnchorGrowthParams::default().orientation
}
fn default_growth_reorient() -> f64 {
    AnchorGrowthParams::default().reorient
}

fn default_basis() -> usize {
    40
}
fn default_one() -> f64 {
    1.0
}

impl Default for FmapConfig {
    fn default() -> Self {
        Self {
            basis: default_basis(),
            match_weight: 1.0,
            commutativity: 0.0,
            zoomout_to: 0,
            growth_samples: default_growth_samples(),
            growth_keep: default_growth_keep(),
            growth_locality: default_growth_locality(),
            growth_rounds: default_growth_rounds(),
            growth_smoothness: default_growth_smoothness(),
            growth_orientation: default_growth_orientation(),
            growth_reorient: default_growth_reorient(),
        }
    }
}

/// The regulariser parameters of a matcher and an fmap configuration.
pub fn regularizer_params(m: &MatcherConfig, f: &FmapConfig) -> RegularizerParams {
    let mut p = RegularizerParams { n_samples: m.samples, top_k: m.top_k, ..Default::default() };
    p.matcher.sigma = m.sigma;
    p.fmap.k_test = f.basis;
    p.fmap.k_ref = f.basis;
    p.fmap.match_weight = f.match_weight;
    p.fmap.commutativity = f.commutativity;
    p.zoomout = (f.zoomout_to > 0).then_some(ZoomOutParams { k_final: f.zoomout_to, step: 5 });
    p.growth = (f.growth_samples > 0).then_some(AnchorGrowthParams {
        samples: f.growth_samples,
        keep: f.growth_keep,
        locality: f.growth_locality,
        rounds: f.growth_rounds,
        smoothness: f.growth_smoothness,
        orientation: f.growth_orientation,
        reorient: f.growth_reorient,
        ..Default::default()
    });
    p
}

/// Checks regulariser settings, naming the broken rule.
pub fn check_regularizer(p: &RegularizerParams) -> Result<(), String> {
    if p.n_samples < 3 {
        return Err(format!("samples = {}: at least 3 are needed", p.n_samples));
    }
    if p.top_k == 0 {
        return Err("top_k = 0: at least one candidate per sample is needed".into());
    }
    p.matcher.check().map_err(|e| e.to_string())?;
    if let Some(g) = &p.growth {
        g.check()?;
    }
    p.fmap.check().map_err(|e| e.to_string())
}

fn internal(stage: &str, job: &Job, e: impl std::fmt::Display) -> Failure {
    Failure {
        stage: stage.into(),
        kind: crate::pipeline::message::FailureKind::Internal,
        message: format!("{}: {e}", job.display_source()),
    }
}

/// Sparse matching against the job model's reference.
pub struct MatcherStage {
    params: RegularizerParams,
    heat: HeatParams,
}

impl MatcherStage {
    /// A matcher stage.
    pub fn new(config: &MatcherConfig) -> Self {
        let params = regularizer_params(config, &FmapConfig::default());
        Self { heat: params.heat, params }
    }
}

impl Stage for MatcherStage {
    type In = PredictedShape;
    type Out = SparselyMatched;

    fn process(&mut self, job: &mut Job, p: PredictedShape) -> Result<SparselyMatched, Failure> {
        let prepared = PreparedShape::new(p.shape.shape.mesh.clone(), p.shape.spectrum.clone(), self.heat)
            .map_err(|e| Failure::bad_input("matcher", format!("{}: {e}", job.display_source())))?;
        let sparse = sparse_matches(
            &prepared,
            &p.model.reference,
            &p.prediction,
            Some(&p.model.label_to_vertex),
            &self.params,
        )
        .map_err(|e| internal("matcher", job, e))?;
        Ok(SparselyMatched { predicted: p, prepared: Arc::new(prepared), sparse: Arc::new(sparse) })
    }
}

/// The regularised functional map and the dense point map.
pub struct FmapStage {
    params: RegularizerParams,
}

impl FmapStage {
    /// An fmap stage.
    pub fn new(config: &FmapConfig) -> Self {
        Self { params: regularizer_params(&MatcherConfig::default(), config) }
    }
}

impl Stage for FmapStage {
    type In = SparselyMatched;
    type Out = MatchedShape;

    fn process(&mut self, job: &mut Job, s: SparselyMatched) -> Result<MatchedShape, Failure> {
        let p = &s.predicted;
        let dense = dense_map(
            &s.prepared,
            &p.model.reference,
            &p.prediction,
            Some(&p.model.label_to_vertex),
            &s.sparse,
            &self.params,
        )
        .map_err(|e| internal("fmap", job, e))?;
        Ok(MatchedShape { predicted: s.predicted, dense: Arc::new(dense) })
    }
}
