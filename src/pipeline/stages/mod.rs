//! The stage types: one module per kind of actor. Each has a `…Config` (its settings, as read
//! from a pipeline file, unknown keys rejected) and a `…Stage`, `…Source` or `…Sink`.

mod eval;
mod forest;
mod ingest;
mod regularize;
mod sink;
mod source;
mod spectral;
mod trainer;

pub use eval::{EvalSink, EvalSinkConfig, ShapeScore};
pub use forest::{DescriptorStage, ForestStage, NoConfig};
pub use ingest::{IngestConfig, IngestStage};
pub use regularize::{
    check_regularizer, regularizer_params, FmapConfig, FmapStage, MatcherConfig, MatcherStage,
};
pub use sink::{defer, is_claimed, reject, reject_or_defer, MatchSink, MatchSinkConfig};
pub use source::{
    natural_key, FolderConfig, FolderSource, Labels, SyntheticConfig, SyntheticSource, WatchConfig,
    WatchKind, WatchSource,
};
pub use spectral::{SpectralConfig, SpectralStage};
pub use trainer::{
    label_table, load_live_model, load_live_model_for, ServeNeeds, TrainMode, TrainerConfig, TrainerSink,
};
