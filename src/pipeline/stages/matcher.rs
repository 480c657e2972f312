//! `matcher`: [`PredictedShape`] → [`SparselyMatched`] (farthest-point samples, candidates,
//! geodesic distances, game-theoretic matching), and the regulariser settings shared with
//! `fmap`.

use std::sync::Arc;

use serde::Deserialize;

use super::fmap::FmapConfig;
use crate::{
    geodesic::HeatParams,
    pipeline::{
        actor::Stage,
        config::{parse_config, AnyPort, Builder, PortType, StageConfig, StageType},
        error::Error,
        message::{Failure, Job, PredictedShape, SparselyMatched},
    },
    regularizer::{sparse_matches, AnchorGrowthParams, PreparedShape, RegularizerParams, ZoomOutParams},
};

impl StageConfig for MatcherConfig {
    const TYPE: StageType = StageType {
        name: "matcher",
        ports: (Some(PortType::Prediction), Some(PortType::Matches)),
        parse: parse_config::<MatcherConfig>,
    };
    fn check(&self) -> Result<(), String> {
        check_regularizer(&regularizer_params(self, &FmapConfig::default()))
    }
    fn build(&self, b: &mut Builder<'_>, input: Option<AnyPort>) -> Result<Option<AnyPort>, Error> {
        let Some(AnyPort::Prediction(i)) = input else { return Err(b.wrong_input()) };
        let name = b.stage.name.clone();
        Ok(Some(AnyPort::Matches(b.pipeline.stage(&name, i, MatcherStage::new(self)))))
    }
}

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
    /// Candidate reference points per sample on a single-view scan (an open part of less than
    /// half the reference's area). Default 20.
    #[serde(default = "default_part_top_k")]
    pub part_top_k: usize,
    /// On a single-view scan, also play the game among `top_k` candidates and keep the
    /// completed map the forest's posterior supports best. Default true.
    #[serde(default = "default_part_alternative")]
    pub part_alternative: bool,
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
fn default_part_top_k() -> usize {
    RegularizerParams::default().part_top_k
}
fn default_part_alternative() -> bool {
    RegularizerParams::default().part_alternative
}
fn default_sigma() -> f64 {
    0.05
}

impl Default for MatcherConfig {
    fn default() -> Self {
        Self {
            samples: default_samples(),
            top_k: default_top_k(),
            part_top_k: default_part_top_k(),
            part_alternative: default_part_alternative(),
            sigma: default_sigma(),
        }
    }
}

/// The regulariser parameters of a matcher and an fmap configuration.
pub fn regularizer_params(m: &MatcherConfig, f: &FmapConfig) -> RegularizerParams {
    let mut p = RegularizerParams {
        n_samples: m.samples,
        top_k: m.top_k,
        part_top_k: m.part_top_k,
        part_alternative: m.part_alternative,
        ..Default::default()
    };
    p.matcher.sigma = m.sigma;
    p.fmap.k_test = f.basis;
    p.fmap.k_ref = f.basis;
    p.fmap.match_weight = f.match_weight;
    p.fmap.commutativity = f.commutativity;
    p.zoomout = (f.zoomout_to > 0).then_some(ZoomOutParams { k_final: f.zoomout_to, ..Default::default() });
    p.growth = (f.growth_samples > 0).then_some(AnchorGrowthParams {
        samples: f.growth_samples,
        keep: f.growth_keep,
        locality: f.growth_locality,
        rounds: f.growth_rounds,
        smoothness: f.growth_smoothness,
        orientation: f.growth_orientation,
        reorient: f.growth_reorient,
        part_prior: f.growth_part_prior,
        part_candidates: f.growth_part_candidates,
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
    if p.part_top_k == 0 {
        return Err("part_top_k = 0: at least one candidate per sample is needed".into());
    }
    p.matcher.check().map_err(|e| e.to_string())?;
    if let Some(g) = &p.growth {
        g.check()?;
    }
    p.fmap.check().map_err(|e| e.to_string())
}

pub(super) fn internal(stage: &str, job: &Job, e: impl std::fmt::Display) -> Failure {
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
        Ok(SparselyMatched {
            predicted: p,
            prepared: Arc::new(prepared),
            heat: self.heat,
            sparse: Arc::new(sparse),
        })
    }
}
