//! Composing a pipeline in Rust, with a stage of your own.
//!
//! The built-in stages are wired with typed ports (a mis-wired graph does not compile), and a
//! custom [`Stage`] is inserted between the functional-map solver and the evaluation sink: it
//! writes each shape coloured by the forest's confidence (blue = sure, red = unsure) as a PLY,
//! and passes the job on unchanged. The forest is trained on six synthetic creatures and two
//! held-out ones are matched and scored.
//!
//! `cargo run --release --example custom_pipeline -- [OUT_DIR]` (default `shapeforest-custom`).

use std::{path::PathBuf, sync::Arc};

use anyhow::{anyhow, Result};
use shapeforest::{
    geodesic::HeatParams,
    mesh::write_colored_ply,
    pipeline::{
        stages::{
            DescriptorStage, EvalSink, EvalSinkConfig, FmapConfig, FmapStage, ForestStage, MatcherConfig,
            MatcherStage, SpectralConfig, SpectralStage, SyntheticConfig, SyntheticSource, TrainMode,
            TrainerConfig, TrainerSink,
        },
        DataDir, Failure, FailureKind, Job, LiveModel, MatchedShape, Pipeline, RunOptions, Stage,
    },
};

/// Writes `NAME.confidence.ply`: each vertex coloured by the largest posterior probability.
struct ConfidenceColors {
    dir: PathBuf,
}

impl Stage for ConfidenceColors {
    type In = MatchedShape;
    type Out = MatchedShape;

    fn process(&mut self, job: &mut Job, m: MatchedShape) -> Result<MatchedShape, Failure> {
        let prediction = &m.predicted.prediction;
        let colors: Vec<[u8; 3]> = (0..prediction.n_vertices())
            .map(|v| {
                let p = prediction.posterior(v).1.iter().fold(0.0f32, |a, &b| a.max(b)).clamp(0.0, 1.0);
                [(255.0 * (1.0 - p)) as u8, 40, (255.0 * p) as u8]
            })
            .collect();
        let path = self.dir.join(format!("{}.confidence.ply", job.name));
        write_colored_ply(&path, &m.predicted.shape.shape.mesh, &colors).map_err(|e| Failure {
            stage: "confidence".into(),
            kind: FailureKind::Internal,
            message: e.to_string(),
        })?;
        Ok(m)
    }
}

fn main() -> Result<()> {
    let out = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "shapeforest-custom".into()));
    std::fs::create_dir_all(&out)?;
    let data = DataDir::new(&out);
    let live = Arc::new(LiveModel::new());
    let mut p = Pipeline::new(data.clone(), live.clone());
    let shutdown = p.context().shutdown.clone();

    // Training branch: synthetic labelled shapes → spectra → one model when the input ends.
    let family = |first, count| SyntheticConfig { vertices: 3000, seed: 7, first, count };
    let train = p.source("train-shapes", SyntheticSource::new(family(0, 6)));
    let train = p.stage(
        "train-spectra",
        train,
        SpectralStage::new(&SpectralConfig::default(), Some(data.cache())).map_err(|e| anyhow!(e))?,
    );
    let trainer = TrainerConfig { mode: TrainMode::Once, fresh: true, ..Default::default() };
    p.sink(
        "trainer",
        train,
        TrainerSink::new(data.clone(), trainer, HeatParams::default(), live.clone())
            .map_err(|e| anyhow!(e))?,
    );

    // Matching branch: held-out shapes wait for the model, then go through the regulariser,
    // our stage, and the evaluation sink.
    let test = p.source("test-shapes", SyntheticSource::new(family(6, 2)));
    let test = p.stage(
        "test-spectra",
        test,
        SpectralStage::new(&SpectralConfig::default(), Some(data.cache())).map_err(|e| anyhow!(e))?,
    );
    let test = p.stage("descriptor", test, DescriptorStage::new(live, shutdown));
    let test = p.stage("forest", test, ForestStage);
    let test = p.stage("matcher", test, MatcherStage::new(&MatcherConfig::default()));
    let test = p.stage("fmap", test, FmapStage::new(&FmapConfig::default()));
    let test = p.stage("confidence", test, ConfidenceColors { dir: out.clone() });
    p.sink("score", test, EvalSink::new(data, EvalSinkConfig { points: 500, folder: out.join("eval") }));

    let report = p.run(RunOptions::default())?;
    println!("{}", report.table());
    println!("confidence-coloured meshes and eval/ in {}", out.display());
    Ok(())
}
