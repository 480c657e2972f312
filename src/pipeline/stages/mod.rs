//! The stage types: one file per `type` of a pipeline file, each holding its `…Config`
//! (settings, unknown keys rejected), the running `…Stage`, `…Source` or `…Sink`, and its
//! [`StageType`] registration.
//!
//! | type | file | consumes | emits |
//! |---|---|---|---|
//! | `folder` | `folder.rs` | — | file |
//! | `watch-folder` | `watch_folder.rs` | — | file |
//! | `synthetic` | `synthetic.rs` | — | shape |
//! | `ingest` | `ingest.rs` | file | shape |
//! | `spectral` | `spectral.rs` | shape | spectrum |
//! | `descriptor` | `descriptor.rs` | spectrum | descriptor |
//! | `forest` | `forest.rs` | descriptor | prediction |
//! | `matcher` | `matcher.rs` | prediction | matches |
//! | `fmap` | `fmap.rs` | matches | map |
//! | `match-sink` | `match_sink.rs` | map | — |
//! | `eval-sink` | `eval_sink.rs` | map | — |
//! | `trainer` | `trainer.rs` | spectrum | — |
//!
//! A new stage type is one new file (a config implementing [`StageConfig`], whose `TYPE`
//! names it) plus one line in [`builtin`] — or, outside the crate, one
//! [`super::config::Registry::with`] call (see `examples/custom_pipeline.rs`).

mod descriptor;
mod eval_sink;
mod fmap;
mod folder;
mod forest;
mod ingest;
mod match_sink;
mod matcher;
mod spectral;
mod synthetic;
mod trainer;
mod watch_folder;

pub use descriptor::{DescriptorConfig, DescriptorStage};
pub use eval_sink::{EvalSink, EvalSinkConfig, ShapeScore};
pub use fmap::{FmapConfig, FmapStage};
pub use folder::{FolderConfig, FolderSource, Labels};
pub use forest::{ForestConfig, ForestStage};
pub use ingest::{IngestConfig, IngestStage};
pub use match_sink::{MatchSink, MatchSinkConfig};
pub use matcher::{check_regularizer, regularizer_params, MatcherConfig, MatcherStage};
pub use spectral::{SpectralConfig, SpectralStage};
pub use synthetic::{SyntheticConfig, SyntheticSource};
pub use trainer::{TrainMode, TrainerConfig, TrainerSink};
pub use watch_folder::{open_for_writing, WatchConfig, WatchKind, WatchSource};

use super::config::{StageConfig, StageType};

/// The built-in stage types, as a [`super::config::Registry`] holds them.
pub fn builtin() -> Vec<StageType> {
    vec![
        FolderConfig::TYPE,
        WatchConfig::TYPE,
        SyntheticConfig::TYPE,
        IngestConfig::TYPE,
        SpectralConfig::TYPE,
        DescriptorConfig::TYPE,
        ForestConfig::TYPE,
        MatcherConfig::TYPE,
        FmapConfig::TYPE,
        MatchSinkConfig::TYPE,
        EvalSinkConfig::TYPE,
        TrainerConfig::TYPE,
    ]
}
