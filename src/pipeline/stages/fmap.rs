//! `fmap`: [`SparselyMatched`] → [`MatchedShape`], the regularised functional map and the dense
//! point map.

use std::sync::Arc;

use serde::Deserialize;

use super::matcher::{check_regularizer, internal, regularizer_params, MatcherConfig};
use crate::{
    pipeline::{
        actor::Stage,
        config::{parse_config, AnyPort, Builder, PortType, StageConfig, StageType},
        error::Error,
        message::{Failure, Job, MatchedShape, SparselyMatched},
    },
    regularizer::{dense_map, AnchorGrowthParams, RegularizerParams},
};

impl StageConfig for FmapConfig {
    const TYPE: StageType = StageType {
        name: "fmap",
        ports: (Some(PortType::Matches), Some(PortType::Map)),
        parse: parse_config::<FmapConfig>,
    };
    fn check(&self) -> Result<(), String> {
        check_regularizer(&regularizer_params(&MatcherConfig::default(), self))
    }
    fn build(&self, b: &mut Builder<'_>, input: Option<AnyPort>) -> Result<Option<AnyPort>, Error> {
        let Some(AnyPort::Matches(i)) = input else { return Err(b.wrong_input()) };
        let name = b.stage.name.clone();
        Ok(Some(AnyPort::Map(b.pipeline.stage(&name, i, FmapStage::new(self)))))
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
    /// Anchor growth on a single-view scan: weight of the forest's posterior in every placement
    /// (`AnchorGrowthParams::part_prior`; 0: off). Default 0.02.
    #[serde(default = "default_growth_part_prior")]
    pub growth_part_prior: f64,
    /// Anchor growth on a single-view scan: each vertex's most probable posterior entries tried
    /// in a placement (`AnchorGrowthParams::part_candidates`; 0: all). Default 160.
    #[serde(default = "default_growth_part_candidates")]
    pub growth_part_candidates: usize,
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
fn default_growth_part_prior() -> f64 {
    AnchorGrowthParams::default().part_prior
}
fn default_growth_part_candidates() -> usize {
    AnchorGrowthParams::default().part_candidates
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
            growth_part_prior: default_growth_part_prior(),
            growth_part_candidates: default_growth_part_candidates(),
        }
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
        let mut dense = dense;
        if let Some(partial) = &p.shape.partial {
            // The part's map, extended to the whole scan (other pieces: nearest matched vertex).
            dense.map = partial.part.extend(&partial.scan, std::mem::take(&mut dense.map));
        }
        Ok(MatchedShape { predicted: s.predicted, dense: Arc::new(dense) })
    }
}
