//! `eval-sink`: scores matched shapes that carry ground-truth labels (the evaluation pipeline):
//! the normalised geodesic error on the model's reference between each evaluated vertex's
//! match and the reference vertex of its true label, for the regularised map and the raw forest.
//! Writes `eval.csv` (per shape and method) and `curves.csv`/`curves.svg` into its folder and
//! logs a summary table.

use std::{fmt::Write as _, fs, path::PathBuf};

use serde::Deserialize;

use crate::{
    eval::{cumulative_curve, geodesic_errors, plot_curves_svg, write_curves_csv, CurveSeries, ErrorSummary},
    pipeline::{
        actor::{PipelineContext, Sink},
        config::{parse_config, AnyPort, Builder, PortType, StageConfig, StageType},
        error::{Error, IoAt},
        message::{Failure, Job, MatchedShape},
        store::{reject, DataDir},
    },
};

impl StageConfig for EvalSinkConfig {
    const TYPE: StageType = StageType {
        name: "eval-sink",
        ports: (Some(PortType::Map), None),
        parse: parse_config::<EvalSinkConfig>,
    };
    fn build(&self, b: &mut Builder<'_>, input: Option<AnyPort>) -> Result<Option<AnyPort>, Error> {
        let Some(AnyPort::Map(i)) = input else { return Err(b.wrong_input()) };
        let mut c = self.clone();
        c.folder = b.resolve(&c.folder);
        let name = b.stage.name.clone();
        let sink = EvalSink::new(b.data.clone(), c).with_context(b.pipeline.context().clone());
        b.pipeline.sink(&name, i, sink);
        Ok(None)
    }
}

/// Settings of `eval-sink`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EvalSinkConfig {
    /// Evaluated vertices per shape (evenly spread over the vertex indices). Default 1000.
    #[serde(default = "default_points")]
    pub points: usize,
    /// Output folder (relative paths are taken from the data folder). Default `eval`.
    #[serde(default = "default_folder")]
    pub folder: PathBuf,
}

fn default_points() -> usize {
    1000
}
fn default_folder() -> PathBuf {
    PathBuf::from("eval")
}

/// Errors of one shape.
#[derive(Clone, Debug)]
pub struct ShapeScore {
    /// Shape name.
    pub name: String,
    /// Errors of the regularised map.
    pub regularized: Vec<f64>,
    /// Errors of the raw forest map.
    pub raw: Vec<f64>,
}

/// Scores matched shapes against their labels.
pub struct EvalSink {
    data: DataDir,
    config: EvalSinkConfig,
    scores: Vec<ShapeScore>,
    failures: usize,
    ctx: Option<PipelineContext>,
}

impl EvalSink {
    /// An evaluation sink writing into `config.folder` (already resolved).
    pub fn new(data: DataDir, config: EvalSinkConfig) -> Self {
        Self { data, config, scores: Vec::new(), failures: 0, ctx: None }
    }

    /// Puts the summary (shapes scored, the table) into the pipeline's report
    /// ([`crate::pipeline::PipelineReport::summary`]) when it finishes.
    pub fn with_context(mut self, ctx: PipelineContext) -> Self {
        self.ctx = Some(ctx);
        self
    }

    fn score(&self, job: &Job, m: &MatchedShape) -> Result<ShapeScore, String> {
        let labels = m.labels().ok_or("the shape has no ground-truth labels")?;
        let model = m.model();
        let n = labels.len();
        let step = (n / self.config.points.max(1)).max(1);
        let (mut evaluated, mut targets) = (Vec::new(), Vec::new());
        for v in (0..n).step_by(step) {
            if let Some(&t) = labels[v].and_then(|l| model.label_to_vertex.get(l as usize)) {
                evaluated.push(v);
                targets.push(t);
            }
        }
        if evaluated.is_empty() {
            return Err("no evaluated vertex has a label of the model".into());
        }
        let fields = model.reference.heat.distances_from_many(&targets).map_err(|e| e.to_string())?;
        let area = model.reference.mesh.surface_area();
        let (regularized, _) = geodesic_errors(&m.dense.map, &evaluated, fields.as_ref(), None, area)
            .map_err(|e| e.to_string())?;
        let raw_map: Vec<usize> = m.dense.forest_map.iter().map(|r| r.unwrap_or(0)).collect();
        let (raw, _) =
            geodesic_errors(&raw_map, &evaluated, fields.as_ref(), None, area).map_err(|e| e.to_string())?;
        let s = ErrorSummary::of(&regularized);
        tracing::info!(
            job = job.id,
            shape = %job.name,
            "≤0.05: {:.1} %, ≤0.1: {:.1} %, mean {:.3} (raw forest ≤0.05: {:.1} %)",
            100.0 * s.within_005,
            100.0 * s.within_010,
            s.mean,
            100.0 * ErrorSummary::of(&raw).within_005
        );
        Ok(ShapeScore { name: job.name.clone(), regularized, raw })
    }

    /// Scores so far.
    pub fn scores(&self) -> &[ShapeScore] {
        &self.scores
    }

    /// The summary table, as printed at the end.
    pub fn table(&self) -> String {
        let mut t = format!("{:<24} {:>8} {:>8} {:>7}\n", "method", "≤ 0.05", "≤ 0.10", "mean");
        for (method, pick) in methods() {
            let all: Vec<f64> = self.scores.iter().flat_map(|s| pick(s).iter().copied()).collect();
            let s = ErrorSummary::of(&all);
            let _ = writeln!(
                t,
                "{method:<24} {:>7.1}% {:>7.1}% {:>7.3}",
                100.0 * s.within_005,
                100.0 * s.within_010,
                s.mean
            );
        }
        t
    }
}

type Pick = fn(&ShapeScore) -> &Vec<f64>;

fn methods() -> [(&'static str, Pick); 2] {
    [("forest + regulariser", |s| &s.regularized), ("forest, raw MAP", |s| &s.raw)]
}

impl Sink for EvalSink {
    type In = MatchedShape;

    fn consume(&mut self, job: Job, body: Result<MatchedShape, Failure>) -> Result<(), Error> {
        let r = match body {
            Ok(m) => self.score(&job, &m).map_err(|e| Failure::bad_input("eval-sink", e)),
            Err(f) => Err(f),
        };
        match r {
            Ok(s) => {
                self.scores.push(s);
                Ok(())
            }
            Err(f) => {
                self.failures += 1;
                reject(&self.data, &job, &f).map(|_| ())
            }
        }
    }

    fn finish(&mut self) -> Result<(), Error> {
        if self.scores.is_empty() {
            return Err(Error::BadInput(format!("no shape was scored ({} failed)", self.failures)));
        }
        let dir = &self.config.folder;
        fs::create_dir_all(dir).at(dir)?;
        let mut csv = String::from("shape,method,n,within_0.05,within_0.10,mean\n");
        for s in &self.scores {
            for (method, pick) in methods() {
                let e = ErrorSummary::of(pick(s));
                let _ = writeln!(
                    csv,
                    "{},{method},{},{:.6},{:.6},{:.6}",
                    s.name, e.n, e.within_005, e.within_010, e.mean
                );
            }
        }
        let csv_path = dir.join("eval.csv");
        fs::write(&csv_path, csv).at(&csv_path)?;
        let series: Vec<CurveSeries> = methods()
            .iter()
            .map(|(method, pick)| {
                let all: Vec<f64> = self.scores.iter().flat_map(|s| pick(s).iter().copied()).collect();
                CurveSeries { name: method.to_string(), curve: cumulative_curve(&all, 100) }
            })
            .collect();
        write_curves_csv(&dir.join("curves.csv"), &series)?;
        plot_curves_svg(&dir.join("curves.svg"), "shapeforest pipeline evaluation", &series)?;
        let summary = format!(
            "evaluation of {} shapes ({} failed); outputs in {}\n{}",
            self.scores.len(),
            self.failures,
            dir.display(),
            self.table()
        );
        tracing::info!("{summary}");
        if let Some(ctx) = &self.ctx {
            ctx.add_summary(summary);
        }
        Ok(())
    }
}
