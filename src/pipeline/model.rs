//! The live model: the forest a pipeline predicts with, its reference shape, and the atomic
//! swap that lets a trainer replace it while predictions go on.
//!
//! Readers take a snapshot ([`LiveModel::current`], lock-free through `arc-swap`) and keep it for
//! the whole job; a trainer publishes a new [`ModelState`] with [`LiveModel::publish`]. Jobs that
//! arrive before any model exists wait for one ([`LiveModel::wait`]).

use std::{
    sync::{Arc, Condvar, Mutex},
    time::Duration,
};

use arc_swap::ArcSwapOption;

use super::actor::Shutdown;
use crate::{forest::RandomForest, regularizer::PreparedShape};

/// One version of the model: a forest and the reference shape its labels live on.
pub struct ModelState {
    /// Version number (1, 2, …), increasing with every update; the model file's number.
    pub version: u64,
    /// The forest.
    pub forest: Arc<RandomForest>,
    /// Name of the reference shape (a training shape carrying every label).
    pub reference_name: String,
    /// The reference, prepared for the regulariser.
    pub reference: Arc<PreparedShape>,
    /// `label_to_vertex[label]` = the reference vertex of the label.
    pub label_to_vertex: Arc<Vec<usize>>,
    /// Names of the training shapes the forest has seen.
    pub training_shapes: Vec<String>,
}

/// Why [`LiveModel::wait`] returned without a model.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum NoModel {
    /// The pipeline is shutting down.
    ShuttingDown,
    /// No model will come (the trainer finished without one); the reason.
    Closed(String),
}

#[derive(Default)]
struct Waiting {
    closed: Option<String>,
}

/// The model shared by a pipeline's stages.
#[derive(Default)]
pub struct LiveModel {
    current: ArcSwapOption<ModelState>,
    state: Mutex<Waiting>,
    changed: Condvar,
}

impl LiveModel {
    /// No model yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// A live model starting from `state`.
    pub fn with(state: ModelState) -> Self {
        let m = Self::new();
        m.publish(Arc::new(state));
        m
    }

    /// The current model, if any.
    pub fn current(&self) -> Option<Arc<ModelState>> {
        self.current.load_full()
    }

    /// The current version (0 without a model).
    pub fn version(&self) -> u64 {
        self.current.load().as_ref().map_or(0, |m| m.version)
    }

    /// Swaps in a new model; jobs already holding the old one finish with it.
    pub fn publish(&self, state: Arc<ModelState>) {
        self.current.store(Some(state));
        if let Ok(_g) = self.state.lock() {
            self.changed.notify_all();
        }
    }

    /// Says that no model will come if none exists yet (waiters get [`NoModel::Closed`]).
    pub fn close(&self, reason: impl Into<String>) {
        if let Ok(mut g) = self.state.lock() {
            if g.closed.is_none() {
                g.closed = Some(reason.into());
            }
            self.changed.notify_all();
        }
    }

    /// Blocks until a model exists, the pipeline shuts down, or no model will come.
    pub fn wait(&self, shutdown: &Shutdown) -> Result<Arc<ModelState>, NoModel> {
        let mut g = self.state.lock().map_err(|_| NoModel::Closed("model lock poisoned".into()))?;
        loop {
            if let Some(m) = self.current() {
                return Ok(m);
            }
            if let Some(reason) = &g.closed {
                return Err(NoModel::Closed(reason.clone()));
            }
            if shutdown.is_triggered() {
                return Err(NoModel::ShuttingDown);
            }
            g = match self.changed.wait_timeout(g, Duration::from_millis(100)) {
                Ok((g, _)) => g,
                Err(_) => return Err(NoModel::Closed("model lock poisoned".into())),
            };
        }
    }
}
