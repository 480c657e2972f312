//! `descriptor` ([`SpectralShape`] → [`DescribedShape`]: the live model's parametric WKS) and
//! `forest` ([`DescribedShape`] → [`PredictedShape`]: the forest posterior).
//!
//! The descriptor stage takes the model snapshot the job will use to the end. With no model yet
//! it waits for one (a daemon without labelled data), until shutdown.

use std::sync::Arc;

use serde::Deserialize;

use crate::pipeline::{
    actor::{Shutdown, Stage},
    message::{DescribedShape, Failure, FailureKind, Job, PredictedShape, SpectralShape},
    model::{LiveModel, NoModel},
};

/// Settings of `descriptor` and `forest` (none yet; the model fixes K and the energies).
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoConfig {}

/// Makes the forest's descriptor with the live model.
pub struct DescriptorStage {
    live: Arc<LiveModel>,
    shutdown: Shutdown,
}

impl DescriptorStage {
    /// A descriptor stage over `live`.
    pub fn new(live: Arc<LiveModel>, shutdown: Shutdown) -> Self {
        Self { live, shutdown }
    }
}

impl Stage for DescriptorStage {
    type In = SpectralShape;
    type Out = DescribedShape;

    fn process(&mut self, job: &mut Job, shape: SpectralShape) -> Result<DescribedShape, Failure> {
        if self.live.current().is_none() {
            tracing::warn!(job = job.id, "no model yet: waiting for labelled shapes to learn from");
        }
        let model = self.live.wait(&self.shutdown).map_err(|e| match e {
            NoModel::ShuttingDown => Failure::interrupted("descriptor"),
            NoModel::Closed(reason) => Failure {
                stage: "descriptor".into(),
                kind: FailureKind::Internal,
                message: format!("no model to match with: {reason}"),
            },
        })?;
        let descriptor = model
            .forest
            .descriptor(&shape.spectrum)
            .map_err(|e| Failure::bad_input("descriptor", format!("{}: {e}", job.display_source())))?;
        Ok(DescribedShape { shape, model, descriptor: Arc::new(descriptor) })
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
