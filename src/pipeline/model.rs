//! The live model: the forest a pipeline predicts with, its reference shape, the atomic swap
//! that lets a trainer replace it while predictions go on, and loading the newest model of a
//! data folder that can serve (shared by the daemon's start-up and the trainer).
//!
//! Readers take a snapshot ([`LiveModel::current`], lock-free through `arc-swap`) and keep it for
//! the whole job; a trainer publishes a new [`ModelState`] with [`LiveModel::publish`]. Jobs that
//! arrive before any model exists wait for one ([`LiveModel::wait`]).

use std::{
    path::Path,
    sync::{Arc, Condvar, Mutex},
    time::Duration,
};

use arc_swap::ArcSwapOption;

use super::{
    error::Error,
    shutdown::Shutdown,
    store::{newest_model_that, read_labels, stored_shapes, DataDir, ModelManifest},
};
use crate::{
    forest::RandomForest,
    geodesic::HeatParams,
    mesh::{read_mesh_limited, Mesh},
    regularizer::PreparedShape,
    spectral::{spectrum_cached, Spectrum, SpectrumCache, SpectrumParams},
};

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

/// The reference table of a labelled shape: `table[label]` = the first vertex carrying it, or
/// the labels no vertex carries.
///
/// ```
/// use shapeforest::pipeline::label_table;
/// assert_eq!(label_table(&[Some(1), Some(0), None], 2), Ok(vec![1, 0]));
/// assert_eq!(label_table(&[Some(1), None], 3), Err(vec![0, 2]));
/// ```
pub fn label_table(labels: &[Option<u32>], n_labels: usize) -> Result<Vec<usize>, Vec<usize>> {
    let mut table = vec![usize::MAX; n_labels];
    for (v, l) in labels.iter().enumerate() {
        if let Some(l) = l {
            if let Some(slot) = table.get_mut(*l as usize) {
                if *slot == usize::MAX {
                    *slot = v;
                }
            }
        }
    }
    let missing: Vec<usize> = (0..n_labels).filter(|&l| table[l] == usize::MAX).collect();
    if missing.is_empty() {
        Ok(table)
    } else {
        Err(missing)
    }
}

/// A stored training shape read back: mesh, labels, spectrum.
pub(crate) type StoredParts = (Arc<Mesh>, Vec<Option<u32>>, Spectrum);

/// Reads a stored training shape back.
pub(crate) fn load_stored(
    dir: &Path,
    name: &str,
    params: &SpectrumParams,
    cache: Option<&SpectrumCache>,
    limits: &crate::limits::Limits,
) -> Result<StoredParts, Error> {
    let stored = stored_shapes(dir).into_iter().find(|s| s.name == name).ok_or_else(|| {
        Error::BadInput(format!("training shape `{name}` is missing from {}", dir.display()))
    })?;
    let (mesh, _) = read_mesh_limited(&stored.mesh, limits, false)?;
    let labels = read_labels(&stored.labels, mesh.n_vertices(), limits)?;
    let spectrum = spectrum_cached(&mesh, params, cache)
        .map_err(|e| Error::BadInput(format!("{}: {e}", stored.mesh.display())))?;
    Ok((Arc::new(mesh), labels, spectrum))
}

/// Reads the newest model of a data folder that loads, with its reference shape, ready to
/// serve; `Ok(None)` when there is none. Unreadable versions are skipped with a warning.
pub fn load_live_model(data: &DataDir, heat: HeatParams) -> Result<Option<ModelState>, Error> {
    load_live_model_for(data, heat, &ServeNeeds::default())
}

/// What a pipeline needs of a model to serve with it.
#[derive(Clone, Debug, Default)]
pub struct ServeNeeds {
    /// Limits every dimension of the model must respect.
    pub limits: crate::limits::Limits,
    /// Eigenpairs of the scans' spectra (the model's K must not exceed it).
    pub spectrum_k: Option<usize>,
    /// Versions not to use (quarantined after crashing the daemon).
    pub skip_versions: Vec<u64>,
}

/// Why a decoded model cannot serve a pipeline with `needs` (before its reference is read).
fn check_serves(manifest: &ModelManifest, forest: &RandomForest, needs: &ServeNeeds) -> Result<(), String> {
    if needs.skip_versions.contains(&manifest.version) {
        return Err("quarantined: it was in use when the daemon crashed twice".into());
    }
    if let Some(k) = needs.spectrum_k {
        if forest.k() > k {
            return Err(format!(
                "it uses K = {} eigenpairs, but this pipeline computes spectra with k = {k}",
                forest.k()
            ));
        }
    }
    if manifest.n_labels != forest.n_labels() || manifest.k != forest.k() {
        return Err(format!(
            "its manifest says {} labels and K = {}, the model file {} and {}",
            manifest.n_labels,
            manifest.k,
            forest.n_labels(),
            forest.k()
        ));
    }
    Ok(())
}

/// [`load_live_model`] for a pipeline with `needs`: the newest version that loads within the
/// limits and can serve (K no larger than the pipeline's spectra, a reference that carries
/// every label) is used; each newer one skipped is logged with the reason.
pub fn load_live_model_for(
    data: &DataDir,
    heat: HeatParams,
    needs: &ServeNeeds,
) -> Result<Option<ModelState>, Error> {
    let cache = SpectrumCache::new(data.cache()).ok();
    let (found, problems) = newest_model_that(&data.models(), &needs.limits, |manifest, forest| {
        check_serves(&manifest, &forest, needs)?;
        let params = SpectrumParams::new(forest.k());
        let (mesh, labels, spectrum) =
            load_stored(&data.training(), &manifest.reference, &params, cache.as_ref(), &needs.limits)
                .map_err(|e| format!("reference: {e}"))?;
        // The model's own table (format version 2) for its reference; older models had
        // references that carry every label.
        let table = match forest.reference().and_then(|r| r.table_for(&mesh)) {
            Some(t) => t,
            None => label_table(&labels, forest.n_labels()).map_err(|missing| {
                format!(
                    "its reference `{}` lacks {} of its {} labels",
                    manifest.reference,
                    missing.len(),
                    forest.n_labels()
                )
            })?,
        };
        let mut reference =
            PreparedShape::new(mesh, Arc::new(spectrum), heat).map_err(|e| e.to_string())?.serving_many();
        // A model that stores its reference's symmetry (trained from `.sym.vts`) repairs mirrored maps.
        if let Some(s) =
            forest.reference().filter(|r| r.is_mesh(&reference.mesh)).and_then(|r| r.symmetry_map())
        {
            reference = reference.with_symmetry(s.into()).map_err(|e| e.to_string())?;
        }
        Ok(ModelState {
            version: manifest.version,
            forest: Arc::new(forest),
            reference_name: manifest.reference,
            reference: Arc::new(reference),
            label_to_vertex: Arc::new(table),
            training_shapes: manifest.training_shapes,
        })
    });
    let fallback = found.is_some() && !problems.is_empty();
    for p in problems {
        tracing::warn!("skipping a model version: {p}");
    }
    if let (true, Some(m)) = (fallback, &found) {
        tracing::warn!("falling back to model v{}, the newest that can serve", m.version);
    }
    Ok(found)
}
