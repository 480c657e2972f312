//! `forest`: [`DescribedShape`] → [`PredictedShape`], the forest posterior with the job's model.

use std::sync::Arc;

use serde::Deserialize;

use crate::pipeline::{
    actor::Stage,
    config::{AnyPort, AnyStageConfig, Builder, PortType, StageConfig, StageType},
    error::Error,
    message::{DescribedShape, Failure, FailureKind, Job, PredictedShape},
};

/// Settings of `forest` (none yet).
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ForestConfig {}

/// Parses the settings of a stage type that takes none.
fn parse(rest: toml::Table) -> Result<Arc<dyn AnyStageConfig>, String> {
    match rest.keys().next() {
        Some(k) => Err(format!("unknown key `{k}` (this stage type takes no settings)")),
        None => Ok(Arc::new(ForestConfig::default())),
    }
}

impl StageConfig for ForestConfig {
    const TYPE: StageType =
        StageType { name: "forest", ports: (Some(PortType::Descriptor), Some(PortType::Prediction)), parse };
    fn build(&self, b: &mut Builder<'_>, input: Option<AnyPort>) -> Result<Option<AnyPort>, Error> {
        let Some(AnyPort::Descriptor(i)) = input else { return Err(b.wrong_input()) };
        let name = b.stage.name.clone();
        Ok(Some(AnyPort::Prediction(b.pipeline.stage(&name, i, ForestStage))))
    }
}

/// Predicts labels with the job's model.
#[derive(Default)]
pub struct ForestStage;

impl Stage for ForestStage {
    type In = DescribedShape;
    type Out = PredictedShape;

    fn process(&mut self, job: &mut Job, d: DescribedShape) -> Result<PredictedShape, Failure> {
        let prediction = d.model.forest.predict_descriptor(&d.descriptor).map_err(|e| Failure {
            stage: "forest".into(),
            kind: FailureKind::Internal,
            message: format!("{}: {e}", job.display_source()),
        })?;
        Ok(PredictedShape { shape: d.shape, model: d.model, prediction: Arc::new(prediction) })
    }
}
