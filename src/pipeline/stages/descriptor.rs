//! `descriptor`: [`SpectralShape`] → [`DescribedShape`], the live model's parametric WKS.
//!
//! The stage takes the model snapshot the job will use to the end. With no model yet it waits
//! for one (a daemon without labelled data), until shutdown.

use std::sync::Arc;

use serde::Deserialize;

use crate::pipeline::{
    actor::Stage,
    config::{AnyPort, AnyStageConfig, Builder, PortType, StageConfig, StageType},
    error::Error,
    message::{DescribedShape, Failure, FailureKind, Job, SpectralShape},
    model::{LiveModel, NoModel},
    shutdown::Shutdown,
};

/// Settings of `descriptor` (none yet: the model fixes K and the energies).
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DescriptorConfig {}

/// Parses the settings of a stage type that takes none.
fn parse(rest: toml::Table) -> Result<Arc<dyn AnyStageConfig>, String> {
    match rest.keys().next() {
        Some(k) => Err(format!("unknown key `{k}` (this stage type takes no settings)")),
        None => Ok(Arc::new(DescriptorConfig::default())),
    }
}

impl StageConfig for DescriptorConfig {
    const TYPE: StageType = StageType {
        name: "descriptor",
        ports: (Some(PortType::Spectrum), Some(PortType::Descriptor)),
        parse,
    };
    fn build(&self, b: &mut Builder<'_>, input: Option<AnyPort>) -> Result<Option<AnyPort>, Error> {
        let Some(AnyPort::Spectrum(i)) = input else { return Err(b.wrong_input()) };
        let stage = DescriptorStage::new(b.live.clone(), b.pipeline.context().shutdown.clone());
        let name = b.stage.name.clone();
        Ok(Some(AnyPort::Descriptor(b.pipeline.stage(&name, i, stage))))
    }
}

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
            .descriptor_mesh(Some(&shape.shape.mesh), &shape.spectrum)
            .map_err(|e| Failure::bad_input("descriptor", format!("{}: {e}", job.display_source())))?;
        Ok(DescribedShape { shape, model, descriptor: Arc::new(descriptor) })
    }
}
