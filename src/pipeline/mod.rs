//! The streaming pipeline: independent actors (ingest, spectral, descriptor, forest, sparse
//! matcher, functional-map solver, sinks, trainer) connected by bounded, typed flume channels on
//! a tokio runtime, and the watch-folder daemon built from them.
//!
//! - [`message`]: the [`Envelope`] on every edge (job id, source path, payload or failure).
//! - [`transport`]: the [`Sender`]/[`Receiver`] seam actors are written against, its in-process
//!   flume implementation, and the fan-out [`Output`] of an actor.
//! - [`shutdown`]: the [`Shutdown`] flag every actor holds.
//! - [`actor`]: the [`Source`], [`Stage`] and [`Sink`] traits and their loops; CPU work runs on
//!   the blocking pool (and rayon), failures travel to the sink as values, panics become
//!   failures of one job, and per-actor metrics are kept.
//! - [`stages`]: the stage types, one file per `type` of a pipeline file.
//! - [`model`]: the live model, swapped atomically by the trainer while predictions go on, and
//!   loading the newest model that can serve.
//! - [`store`]: the daemon's data folder, the claim / commit / reject / recover protocol that
//!   makes it restart-safe, model versions on disk.
//! - [`report`]: the [`MatchReport`] of a matched scan (shared with `shapeforest match`).
//! - [`lock`]: the exclusive lock on a data folder (one process at a time).
//! - [`config`]: `pipelines/*.toml` — the [`StageConfig`] trait and [`Registry`] of stage types,
//!   parsing, validation naming stage and key, building.
//! - [`graph`]: [`Pipeline`], for composing actors in code with typed ports (an output may
//!   feed several consumers).
//! - [`error`]: the layer's [`enum@Error`].
//! - [`nats`]: the edges on NATS JetStream (`transport = "nats"`): workers on any number of
//!   machines, payloads in the object store, the model followed through a key-value bucket.
//! - [`daemon`]: preparing a data folder (recovery, model loading, the synthetic bootstrap) and
//!   running a pipeline file on it.
//!
//! Numeric work stays in the pure modules; actors only wrap it.

pub mod actor;
pub mod config;
pub mod daemon;
pub mod error;
pub mod graph;
pub mod lock;
pub mod message;
pub mod model;
pub mod nats;
pub mod report;
pub mod shutdown;
pub mod stages;
pub mod store;
pub mod transport;

pub use actor::{Emitter, PipelineContext, Sink, Source, Stage, StageMetrics, StageSummary};
pub use config::{
    build, build_with, check_selection, parse_config, AnyPort, AnyStageConfig, Builder, ConfigError,
    PipelineSpec, PortType, Ports, Registry, Settings, StageConfig, StageSpec, StageType, TransportKind,
};
pub use daemon::{bootstrap_synthetic, prepare, run_pipeline, run_spec, RunSetup};
pub use error::Error;
pub use graph::{Pipeline, PipelineReport, Port, RunOptions, SignalEvent};
pub use lock::DataLock;
pub use message::{
    shape_stem, DescribedShape, Envelope, Failure, FailureKind, InputFile, Job, JobId, LabelSpec,
    MatchedShape, PartialScan, PredictedShape, Shape, SparselyMatched, SpectralShape,
};
pub use model::{
    label_table, load_live_model, load_live_model_for, LiveModel, ModelState, NoModel, ServeNeeds,
};
pub use report::{MapQuality, MatchReport};
pub use shutdown::Shutdown;
pub use store::{
    atomic_write, defer, is_claimed, is_mesh_file, is_symmetry_file, is_transient_file, label_map_text,
    label_sidecar, latest_manifest, latest_model, move_file, natural_key, read_labels, reject,
    reject_or_defer, sidecar_stem, sidecar_suffix, symmetry_sidecar, unique_path, DataDir, InputKind,
    ModelManifest, Recovery,
};
pub use transport::{
    Delivery, Dynamic, ErasedTransport, InProcess, Output, Payload, Receiver, Sender, Settle, Settled,
    Settling, Transport,
};
