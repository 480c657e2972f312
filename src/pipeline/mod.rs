//! The streaming pipeline: independent actors (ingest, spectral, descriptor, forest, sparse
//! matcher, functional-map solver, sinks, trainer) connected by bounded, typed flume channels on
//! a tokio runtime, and the watch-folder daemon built from them.
//!
//! - [`actor`]: the [`Source`], [`Stage`] and [`Sink`] traits and their loops; CPU work runs on
//!   the blocking pool (and rayon), failures travel to the sink as values, panics become
//!   failures of one job, and per-actor metrics are kept.
//! - [`message`]: the [`Envelope`] on every edge (job id, source path, payload or failure).
//! - [`stages`]: the stage types and their settings.
//! - [`model`]: the live model, swapped atomically by the trainer while predictions go on.
//! - [`store`]: the daemon's data folder and the claim / commit / recover protocol that makes it
//!   restart-safe.
//! - [`lock`]: the exclusive lock on a data folder (one process at a time).
//! - [`config`]: `pipelines/*.toml` — parsing, validation naming stage and key, building.
//! - [`graph`]: [`Pipeline`], for composing actors in code with typed ports.
//! - [`daemon`]: preparing a data folder (recovery, model loading, the synthetic bootstrap) and
//!   running a pipeline file on it.
//!
//! Numeric work stays in the pure modules; actors only wrap it.

pub mod actor;
pub mod config;
pub mod daemon;
pub mod graph;
pub mod lock;
pub mod message;
pub mod model;
pub mod stages;
pub mod store;

pub use actor::{Emitter, PipelineContext, Shutdown, Sink, Source, Stage, StageMetrics, StageSummary};
pub use config::{build, ConfigError, PipelineSpec, PortType, Settings, StageKind, StageSpec};
pub use daemon::{bootstrap_synthetic, prepare, run_pipeline, run_spec, RunSetup};
pub use graph::{Pipeline, PipelineReport, Port, RunOptions};
pub use lock::DataLock;
pub use message::{
    shape_stem, DescribedShape, Envelope, Failure, FailureKind, InputFile, Job, JobId, LabelSpec,
    MatchedShape, PredictedShape, Shape, SparselyMatched, SpectralShape,
};
pub use model::{LiveModel, ModelState, NoModel};
pub use store::{
    atomic_write, is_mesh_file, is_transient_file, label_map_text, label_sidecar, latest_manifest,
    latest_model, move_file, read_labels, unique_path, DataDir, InputKind, ModelManifest, Recovery,
};
