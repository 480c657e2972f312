//! A stage type of your own, in one file: this one.
//!
//! `confidence-colors` takes dense maps and passes them on unchanged, writing each shape
//! coloured by the forest's confidence (blue = sure, red = unsure) as a PLY on the way. Adding
//! it takes three things, all below: its settings (`ConfidenceColorsConfig`, serde), the running
//! stage (`ConfidenceColors`, a [`Stage`]), and its registration (`TYPE`, a [`StageType`], inside
//! the config's [`StageConfig`] impl).
//! The pipeline file then uses it like a built-in type, and the `fmap` output feeds two
//! consumers (fan-out): the new stage and the evaluation sink behind it, and a second
//! evaluation sink straight from `fmap`, so both see every job.
//!
//! The forest is trained on six synthetic creatures; two held-out ones are matched and scored.
//!
//! `cargo run --release --example custom_pipeline -- [OUT_DIR]` (default `shapeforest-custom`).
//!
//! The same stage can be wired in code instead: `p.stage("confidence", maps, ConfidenceColors
//! { dir })` on a [`shapeforest::pipeline::Pipeline`], with typed ports.

use std::{path::PathBuf, sync::Arc};

use anyhow::Result;
use serde::Deserialize;
use shapeforest::{
    mesh::write_colored_ply,
    pipeline::{
        self, build, parse_config, AnyPort, Builder, DataDir, Failure, FailureKind, Job, LiveModel,
        MatchedShape, PipelineContext, PipelineSpec, PortType, Registry, RunOptions, Stage, StageConfig,
        StageType,
    },
};

/// Settings of `confidence-colors`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ConfidenceColorsConfig {
    /// Where the PLY files go (relative: inside the data folder).
    folder: PathBuf,
}

impl StageConfig for ConfidenceColorsConfig {
    /// The type's registration: its name in pipeline files, what it consumes and emits, and how
    /// its settings are read (serde, then [`StageConfig::check`]).
    const TYPE: StageType = StageType {
        name: "confidence-colors",
        ports: (Some(PortType::Map), Some(PortType::Map)),
        parse: parse_config::<ConfidenceColorsConfig>,
    };
    fn check(&self) -> Result<(), String> {
        match self.folder.as_os_str().is_empty() {
            true => Err("folder must not be empty".into()),
            false => Ok(()),
        }
    }
    fn build(&self, b: &mut Builder<'_>, input: Option<AnyPort>) -> Result<Option<AnyPort>, pipeline::Error> {
        let Some(AnyPort::Map(maps)) = input else { return Err(b.wrong_input()) };
        let dir = b.resolve(&self.folder);
        std::fs::create_dir_all(&dir).map_err(|e| pipeline::Error::io(&dir, e))?;
        let name = b.name().to_string();
        Ok(Some(AnyPort::Map(b.pipeline.stage(&name, maps, ConfidenceColors { dir }))))
    }
}

/// Writes `NAME.confidence.ply`: each vertex coloured by the largest posterior probability.
struct ConfidenceColors {
    dir: PathBuf,
}

impl Stage for ConfidenceColors {
    type In = MatchedShape;
    type Out = MatchedShape;

    fn process(&mut self, job: &mut Job, m: MatchedShape) -> Result<MatchedShape, Failure> {
        let prediction = m.prediction();
        let colors: Vec<[u8; 3]> = (0..prediction.n_vertices())
            .map(|v| {
                let p = prediction.posterior(v).1.iter().fold(0.0f32, |a, &b| a.max(b)).clamp(0.0, 1.0);
                [(255.0 * (1.0 - p)) as u8, 40, (255.0 * p) as u8]
            })
            .collect();
        let path = self.dir.join(format!("{}.confidence.ply", job.name));
        write_colored_ply(&path, m.mesh(), &colors).map_err(|e| Failure {
            stage: "confidence".into(),
            kind: FailureKind::Internal,
            message: e.to_string(),
        })?;
        Ok(m)
    }
}

/// The evaluation pipeline with the new stage between `fmap` and a sink, and a second sink on
/// `fmap` itself.
const PIPELINE: &str = r#"
name = "custom"

[[stage]]
name = "train-shapes"
type = "synthetic"
vertices = 3000
seed = 7
count = 6

[[stage]]
name = "train-spectra"
type = "spectral"
input = "train-shapes"

[[stage]]
name = "trainer"
type = "trainer"
input = "train-spectra"
mode = "once"
fresh = true

[[stage]]
name = "test-shapes"
type = "synthetic"
vertices = 3000
seed = 7
first = 6
count = 2

[[stage]]
name = "test-spectra"
type = "spectral"
input = "test-shapes"

[[stage]]
name = "descriptor"
type = "descriptor"
input = "test-spectra"

[[stage]]
name = "forest"
type = "forest"
input = "descriptor"

[[stage]]
name = "matcher"
type = "matcher"
input = "forest"

[[stage]]
name = "fmap"
type = "fmap"
input = "matcher"

[[stage]]
name = "confidence"
type = "confidence-colors"
input = "fmap"
folder = "confidence"

[[stage]]
name = "score"
type = "eval-sink"
input = "confidence"
points = 500
folder = "eval"

[[stage]]
name = "score-again"
type = "eval-sink"
input = "fmap"
points = 500
folder = "eval-fmap"
"#;

fn main() -> Result<()> {
    let out = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "shapeforest-custom".into()));
    std::fs::create_dir_all(&out)?;
    let registry = Registry::builtin().with(ConfidenceColorsConfig::TYPE);
    let spec = PipelineSpec::from_toml_with(PIPELINE, "custom pipeline", &registry)?;
    let data = DataDir::new(&out);
    let live = Arc::new(LiveModel::new());
    let pipeline = build(&spec, &data, live, PipelineContext::new())?;
    let report = pipeline.run(RunOptions::default())?;
    for s in &report.summary {
        print!("{s}");
    }
    println!("{}", report.table());
    println!(
        "confidence-coloured meshes in {}, evaluations in eval/ and eval-fmap/",
        out.join("confidence").display()
    );
    Ok(())
}
