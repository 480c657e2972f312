//! `ingest`: mesh file (and label map) → [`Shape`].

use std::sync::Arc;

use serde::Deserialize;

use crate::{
    forest::labels_identity,
    mesh::read_mesh_limited,
    pipeline::{
        actor::Stage,
        config::{parse_config, AnyPort, Builder, PortType, StageConfig, StageType},
        error::Error,
        message::{Failure, InputFile, Job, LabelSpec, Shape},
        store::read_labels,
    },
};

impl StageConfig for IngestConfig {
    const TYPE: StageType = StageType {
        name: "ingest",
        ports: (Some(PortType::File), Some(PortType::Shape)),
        parse: parse_config::<IngestConfig>,
    };
    fn build(&self, b: &mut Builder<'_>, input: Option<AnyPort>) -> Result<Option<AnyPort>, Error> {
        let Some(AnyPort::File(i)) = input else { return Err(b.wrong_input()) };
        // Files dropped into a watched folder: links are not followed.
        let watched = b.upstream::<super::WatchConfig>().is_some();
        let stage =
            IngestStage::new(self.clone()).with_limits(b.spec.settings.limits).follow_symlinks(!watched);
        let name = b.stage.name.clone();
        Ok(Some(AnyPort::Shape(b.pipeline.stage(&name, i, stage))))
    }
}

/// Settings of `ingest`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IngestConfig {
    /// Meshes with fewer vertices are rejected (the spectrum needs more vertices than
    /// eigenpairs). Default 200.
    #[serde(default = "default_min")]
    pub min_vertices: usize,
    /// Meshes with more vertices are rejected (a guard against runaway memory). Default 2,000,000.
    #[serde(default = "default_max")]
    pub max_vertices: usize,
}

fn default_min() -> usize {
    200
}
fn default_max() -> usize {
    2_000_000
}

impl Default for IngestConfig {
    fn default() -> Self {
        Self { min_vertices: default_min(), max_vertices: default_max() }
    }
}

/// Reads meshes and their label maps.
pub struct IngestStage {
    config: IngestConfig,
    limits: crate::limits::Limits,
    follow_symlinks: bool,
}

impl IngestStage {
    /// An ingest stage (default limits; symbolic links are followed).
    pub fn new(config: IngestConfig) -> Self {
        Self { config, limits: crate::limits::Limits::default(), follow_symlinks: true }
    }

    /// Reads within `limits` (file size, vertices, faces, labels), checked before allocating.
    pub fn with_limits(mut self, limits: crate::limits::Limits) -> Self {
        self.limits = limits;
        self
    }

    /// Whether a symbolic link is followed (`false` for files dropped into a watched folder:
    /// a link there is refused unopened).
    pub fn follow_symlinks(mut self, follow: bool) -> Self {
        self.follow_symlinks = follow;
        self
    }
}

impl Stage for IngestStage {
    type In = InputFile;
    type Out = Shape;

    fn process(&mut self, job: &mut Job, input: InputFile) -> Result<Shape, Failure> {
        let bad = |m: String| Failure::bad_input("ingest", m);
        let (mesh, report) = read_mesh_limited(&input.path, &self.limits, self.follow_symlinks)
            .map_err(|e| bad(e.to_string()))?;
        for w in report.warnings.iter().take(5) {
            tracing::info!(job = job.id, file = %input.path.display(), "{w}");
        }
        let n = mesh.n_vertices();
        if n < self.config.min_vertices {
            return Err(bad(format!(
                "{}: {n} vertices, fewer than the {} this pipeline needs",
                input.path.display(),
                self.config.min_vertices
            )));
        }
        if n > self.config.max_vertices {
            return Err(bad(format!(
                "{}: {n} vertices, more than the limit of {} (ingest.max_vertices)",
                input.path.display(),
                self.config.max_vertices
            )));
        }
        let labels = match &input.labels {
            None => None,
            Some(LabelSpec::Identity) => Some(Arc::new(labels_identity(n))),
            Some(LabelSpec::File(f)) => {
                Some(Arc::new(read_labels(f, n, &self.limits).map_err(|e| bad(e.to_string()))?))
            }
        };
        Ok(Shape { mesh: Arc::new(mesh), labels })
    }
}
