//! `synthetic`: shapes of the built-in creature family, with their labels.

use std::sync::Arc;

use serde::Deserialize;

use crate::{
    forest::labels_identity,
    pipeline::{
        actor::{Emitter, Source},
        config::{parse_config, AnyPort, Builder, PortType, StageConfig, StageType},
        error::Error,
        message::{Envelope, Job, Shape},
    },
    synth::{creature_family, CreatureParams},
};

impl StageConfig for SyntheticConfig {
    const TYPE: StageType = StageType {
        name: "synthetic",
        ports: (None, Some(PortType::Shape)),
        parse: parse_config::<SyntheticConfig>,
    };
    fn build(&self, b: &mut Builder<'_>, input: Option<AnyPort>) -> Result<Option<AnyPort>, Error> {
        if input.is_some() {
            return Err(b.wrong_input());
        }
        let name = b.stage.name.clone();
        Ok(Some(AnyPort::Shape(b.pipeline.source(&name, SyntheticSource::new(self.clone())))))
    }
}

/// Settings of a `synthetic` source: shapes of the built-in creature family, with their labels
/// (label = vertex index of the family's template).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SyntheticConfig {
    /// Vertices per shape. Default 5000.
    #[serde(default = "default_vertices")]
    pub vertices: usize,
    /// Seed of the family. Default 1.
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// Index of the first shape emitted. Default 0.
    #[serde(default)]
    pub first: usize,
    /// Shapes emitted. Default 6.
    #[serde(default = "default_count")]
    pub count: usize,
}

fn default_vertices() -> usize {
    5000
}
fn default_seed() -> u64 {
    1
}
fn default_count() -> usize {
    6
}

/// Emits shapes of the synthetic creature family with their labels.
pub struct SyntheticSource {
    config: SyntheticConfig,
}

impl SyntheticSource {
    /// A synthetic source.
    pub fn new(config: SyntheticConfig) -> Self {
        Self { config }
    }
}

impl Source for SyntheticSource {
    type Out = Shape;

    fn run(&mut self, out: &Emitter<Shape>) -> Result<(), Error> {
        let c = &self.config;
        let fam = creature_family(
            &CreatureParams { target_vertices: c.vertices, seed: c.seed, ..Default::default() },
            c.first + c.count,
        )
        .map_err(|e| Error::BadInput(format!("cannot build the synthetic family: {e}")))?;
        let labels = Arc::new(labels_identity(fam.template.n_vertices()));
        for (i, mesh) in fam.shapes.into_iter().enumerate().skip(c.first) {
            let job = Job::generated(out.next_job_id(), format!("creature{i}"));
            let shape = Shape { mesh: Arc::new(mesh), labels: Some(labels.clone()) };
            if !out.emit(Envelope { job, body: Ok(shape) }) {
                break;
            }
        }
        Ok(())
    }
}
