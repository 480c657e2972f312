//! `trainer`: labelled shapes → a new model version, swapped into the live model.
//!
//! Accepted shapes are kept in the data folder's `training/` (a claimed input is moved there as
//! it arrived; a generated or unclaimed one is written as OFF with a `.labels` map). Each update
//! grows the forest on the enlarged set ([`crate::forest::RandomForestValidParams::fit_with`]:
//! `trees_per_update` new trees, the oldest retired), saves `models/model-vN.sfm` with its
//! manifest, and publishes the new model. Predictions use the old model meanwhile.
//!
//! In `incremental` mode (the daemon) an update runs whenever shapes have arrived and nothing
//! else is waiting; in `once` mode (batch training) one model is fitted when the input ends.
//! On start, training shapes missing from the newest model (a crash between storing a shape and
//! saving the model) trigger an update.

use std::{collections::HashMap, fs, path::Path, sync::Arc, time::Instant};

use serde::Deserialize;
use sha2::{Digest, Sha256};

use crate::{
    descriptor::LocalParams,
    forest::{
        augmented_copies, reference_table, Augmentation, ModelReference, RandomForest,
        RandomForestValidParams, TrainingSet, TrainingShape,
    },
    geodesic::HeatParams,
    mesh::{read_mesh_limited, write_mesh, Mesh, Perturbation},
    pipeline::{
        actor::Sink,
        config::{parse_config, AnyPort, Builder, PortType, StageConfig, StageType},
        error::{Error, IoAt},
        message::{shape_stem, Failure, Job, Shape, SpectralShape},
        model::{load_stored, LiveModel, ModelState},
        shutdown::Shutdown,
        store::{
            atomic_write, defer, is_claimed, is_symmetry_file, label_map_text, latest_manifest, move_file,
            natural_key, prune_models, read_labels, reject_or_defer, save_model_version, sidecar_suffix,
            stored_shapes, symmetry_sidecar, unix_now, DataDir, InputKind, ModelManifest,
        },
    },
    regularizer::{symmetry_from_pairs, PreparedShape, ScanPart},
    spectral::{SpectrumCache, SpectrumParams},
};

impl StageConfig for TrainerConfig {
    const TYPE: StageType = StageType {
        name: "trainer",
        ports: (Some(PortType::Spectrum), None),
        parse: parse_config::<TrainerConfig>,
    };
    fn check(&self) -> Result<(), String> {
        self.forest_params()?;
        self.augment_kinds().map(|_| ())
    }
    fn build(&self, b: &mut Builder<'_>, input: Option<AnyPort>) -> Result<Option<AnyPort>, Error> {
        let Some(AnyPort::Spectrum(i)) = input else { return Err(b.wrong_input()) };
        let upstream_k = b.upstream::<super::SpectralConfig>().map(|c| c.k);
        let mut t = TrainerSink::new(b.data.clone(), self.clone(), b.heat, b.live.clone())
            .map_err(|e| b.error(e))?
            .with_shutdown(b.pipeline.context().shutdown.clone())
            .with_limits(b.spec.settings.limits);
        if let Some(k) = upstream_k {
            t = t.with_spectrum_k(k);
        }
        let name = b.stage.name.clone();
        b.pipeline.sink(&name, i, t);
        Ok(None)
    }
}

/// When the trainer updates the model.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TrainMode {
    /// Whenever labelled shapes have arrived and no more are waiting (the daemon).
    #[default]
    Incremental,
    /// Once, when the input ends (batch training).
    Once,
}

/// Settings of `trainer`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainerConfig {
    /// When to update. Default `incremental`.
    #[serde(default)]
    pub mode: TrainMode,
    /// Trees in the forest. Default 0: automatic, 15 where the leaves are pure and 60 where
    /// they hold several samples (with `augment` copies; [`RandomForestValidParams::resolved_for`]).
    #[serde(default)]
    pub trees: usize,
    /// New trees per incremental update (the oldest are retired). Default 5.
    #[serde(default = "default_per_update")]
    pub trees_per_update: usize,
    /// Maximum tree depth. Default 25.
    #[serde(default = "default_depth")]
    pub max_depth: usize,
    /// Smallest leaf, in training samples. Default 0: automatic, an eighth of the training set's
    /// samples per label, at least 1 (pure leaves for six complete shapes, 3–5 with 15
    /// single-view copies of each; [`RandomForestValidParams::resolved_for`]).
    #[serde(default)]
    pub min_samples_leaf: usize,
    /// Split candidates per node. Default 20.
    #[serde(default = "default_candidates")]
    pub candidates_per_node: usize,
    /// Seed. Default 0.
    #[serde(default)]
    pub seed: u64,
    /// The reference shape (a training shape's name); default: the first, in name order, that
    /// carries every label.
    #[serde(default)]
    pub reference: Option<String>,
    /// Model versions kept in `models/`. Default 5.
    #[serde(default = "default_keep")]
    pub keep_models: usize,
    /// Start from no model even if `models/` has one (evaluation runs). Default false.
    #[serde(default)]
    pub fresh: bool,
    /// Incremental mode: update once no labelled shape has arrived for this long
    /// (milliseconds), so shapes dropped together make one update. Default 2000.
    #[serde(default = "default_quiet")]
    pub quiet_ms: u64,
    /// Learn partiality from examples (as `train --augment`): every training shape is also
    /// presented as `augment_copies` seeded perturbed copies of each of these kinds
    /// (`partial-view`, `holes:N:R`, `crop:R`), each prepared as a scan is (largest piece, small
    /// holes closed). Default: none.
    #[serde(default)]
    pub augment: Vec<String>,
    /// Perturbed copies per training shape and `augment` kind. Default 15.
    #[serde(default = "default_augment_copies")]
    pub augment_copies: usize,
    /// A first model also splits on local histograms of the surface (as `train
    /// --local-descriptors`; for partial scans). Later updates follow the current model:
    /// a model that splits on them keeps doing so, one that does not never starts. Default
    /// false.
    #[serde(default)]
    pub local_descriptors: bool,
}

fn default_augment_copies() -> usize {
    15
}

fn default_quiet() -> u64 {
    2000
}

fn default_per_update() -> usize {
    5
}
fn default_depth() -> usize {
    25
}
fn default_candidates() -> usize {
    20
}
fn default_keep() -> usize {
    5
}

impl Default for TrainerConfig {
    fn default() -> Self {
        Self {
            mode: TrainMode::Incremental,
            trees: 0,
            trees_per_update: default_per_update(),
            max_depth: default_depth(),
            min_samples_leaf: 0,
            candidates_per_node: default_candidates(),
            seed: 0,
            reference: None,
            keep_models: default_keep(),
            fresh: false,
            quiet_ms: default_quiet(),
            augment: Vec::new(),
            augment_copies: default_augment_copies(),
            local_descriptors: false,
        }
    }
}

impl TrainerConfig {
    /// The forest hyper-parameters, checked (the error names the parameter).
    pub fn forest_params(&self) -> Result<RandomForestValidParams, String> {
        RandomForest::params()
            .n_trees(self.trees)
            .trees_per_update(self.trees_per_update)
            .max_depth(self.max_depth)
            .min_samples_leaf(self.min_samples_leaf)
            .candidates_per_node(self.candidates_per_node)
            .seed(self.seed)
            .check()
            .map_err(|e| e.to_string())
    }

    /// The `augment` kinds, parsed; the first bad one named.
    pub fn augment_kinds(&self) -> Result<Vec<Perturbation>, String> {
        self.augment
            .iter()
            .map(|k| Perturbation::parse_kind(k).map_err(|e| format!("augment `{k}`: {e}")))
            .collect()
    }
}

/// The per-label rows of a job's `.vts` label file (`None` for other label files, or when it
/// cannot be read again: the per-vertex labels read at ingest are then all there is).
fn label_rows(job: &Job, n_vertices: usize) -> Option<Vec<Option<u32>>> {
    let path = job.labels_file.as_ref()?;
    if !path.extension().is_some_and(|e| e.eq_ignore_ascii_case("vts")) {
        return None;
    }
    let file = fs::File::open(path).ok()?;
    crate::forest::read_per_label_rows(std::io::BufReader::new(file), true, n_vertices).ok()
}

/// The rows of a job's `NAME.sym.vts` (row `k`: the vertex at the mirror image of row `k` of
/// its `NAME.vts`), checked against the `.vts` rows: `Ok(None)` without one, `Err` (the reason,
/// naming the file) when it cannot be read, is too large, or has another row count.
fn mirror_rows(
    job: &Job,
    rows: Option<&Vec<Option<u32>>>,
    n_vertices: usize,
    limits: &crate::limits::Limits,
) -> Result<Option<Vec<Option<u32>>>, String> {
    let Some(path) = job.companions.iter().find(|c| is_symmetry_file(c)) else { return Ok(None) };
    let shown = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let Some(rows) = rows else {
        return Err(format!(
            "{shown}: a .sym.vts mirrors the rows of a NAME.vts label map, but this shape's labels are not a .vts"
        ));
    };
    let bytes = crate::mesh::read_file_limited(path, limits.max_file_bytes, false)
        .map_err(|e| format!("{shown}: {e}"))?;
    let mirror = crate::forest::read_per_label_rows(bytes.as_slice(), true, n_vertices)
        .map_err(|e| format!("{shown}: {e}"))?;
    if mirror.len() != rows.len() {
        return Err(format!(
            "{shown} has {} rows but {}.vts has {}: a .sym.vts lists the mirror of every row",
            mirror.len(),
            job.name,
            rows.len()
        ));
    }
    Ok(Some(mirror))
}

/// A reference chosen for a first model: name, prepared shape (with its left/right symmetry
/// when its `.sym.vts` gave one), label → vertex table.
type ChosenReference = (String, Arc<PreparedShape>, Arc<Vec<usize>>);

/// Learns from labelled shapes and publishes new model versions.
pub struct TrainerSink {
    data: DataDir,
    config: TrainerConfig,
    params: RandomForestValidParams,
    heat: HeatParams,
    live: Arc<LiveModel>,
    cache: Option<SpectrumCache>,
    /// Arrived, not yet in a model.
    pending: Vec<(Job, SpectralShape)>,
    /// Shapes already learnt, loaded on the first update.
    known: HashMap<String, TrainingShape>,
    /// The `augment` kinds (each one perturbation).
    augment: Vec<Vec<Perturbation>>,
    /// The perturbed copies of each training shape (by name), made once.
    copies: HashMap<String, Vec<TrainingShape>>,
    /// When the last shape arrived.
    last_arrival: Instant,
    /// Eigenpairs of the spectra it receives (for shapes it reads back from `training/`).
    spectrum_k: usize,
    /// The pipeline's shutdown flag: at shutdown, waiting scans are left queued, not rejected.
    shutdown: Option<Shutdown>,
    /// Limits on label maps read back from `training/`.
    limits: crate::limits::Limits,
}

impl TrainerSink {
    /// A trainer over `data`, publishing into `live`.
    pub fn new(
        data: DataDir,
        config: TrainerConfig,
        heat: HeatParams,
        live: Arc<LiveModel>,
    ) -> Result<Self, Error> {
        let params = config.forest_params().map_err(Error::Training)?;
        let augment = config.augment_kinds().map_err(Error::Training)?.into_iter().map(|p| vec![p]).collect();
        let cache = SpectrumCache::new(data.cache()).ok();
        Ok(Self {
            data,
            config,
            params,
            heat,
            live,
            cache,
            pending: Vec::new(),
            known: HashMap::new(),
            augment,
            copies: HashMap::new(),
            last_arrival: Instant::now(),
            spectrum_k: SpectrumParams::default().k,
            shutdown: None,
            limits: crate::limits::Limits::default(),
        })
    }

    /// The eigenpairs of the spectra this trainer receives (the upstream `spectral` stage's K),
    /// used for shapes read back from `training/` when there is no model yet.
    pub fn with_spectrum_k(mut self, k: usize) -> Self {
        self.spectrum_k = k;
        self
    }

    /// The pipeline's shutdown flag: a trainer stopped by it does not tell waiting scans that no
    /// model will come (they stay queued for the next start).
    pub fn with_shutdown(mut self, shutdown: Shutdown) -> Self {
        self.shutdown = Some(shutdown);
        self
    }

    /// Limits on what it reads back.
    pub fn with_limits(mut self, limits: crate::limits::Limits) -> Self {
        self.limits = limits;
        self
    }

    /// Whether `job` brings a shape under the name of one already in `training/` (learnt, or
    /// stored and about to be). An identical copy (same mesh, same labels: a re-delivery) is
    /// `Ok(true)` and is consumed; a different one is refused: training shapes are immutable once
    /// stored, so a new shape under an old name would silently change what every later map is
    /// computed against.
    fn same_name_as_stored(&self, job: &Job, shape: &SpectralShape) -> Result<bool, String> {
        let dir = self.data.training();
        if job.source.as_ref().is_some_and(|s| s.starts_with(&dir)) {
            return Ok(false); // read back from training/ itself
        }
        let Some(stored) = stored_shapes(&dir).into_iter().find(|s| s.name == job.name) else {
            return Ok(false);
        };
        let same = read_mesh_limited(&stored.mesh, &self.limits, false).ok().is_some_and(|(m, _)| {
            m == *shape.shape.mesh
                && read_labels(&stored.labels, m.n_vertices(), &self.limits)
                    .ok()
                    .is_some_and(|l| Some(&l) == shape.shape.labels.as_deref())
        });
        if same {
            return Ok(true);
        }
        Err(format!(
            "a different training shape named `{}` is already stored ({}); training shapes are \
             immutable once learnt, so this one is not used: give it another name to add it",
            job.name,
            stored.mesh.display()
        ))
    }

    /// Stores a pending shape in `training/` (moves a claimed input, writes anything else).
    fn store(&self, job: &Job, shape: &SpectralShape) -> Result<(), Error> {
        let dir = self.data.training();
        fs::create_dir_all(&dir).at(&dir)?;
        if job.source.as_ref().is_some_and(|s| s.starts_with(&dir)) {
            return Ok(()); // already stored
        }
        // Never replace a stored shape (see `same_name_as_stored`, checked before this).
        if let Some(old) = stored_shapes(&dir).into_iter().find(|s| s.name == job.name) {
            return Err(Error::BadInput(format!(
                "{}: a training shape of this name is already stored",
                old.mesh.display()
            )));
        }
        match (&job.source, &job.labels_file) {
            (Some(src), Some(lab)) if is_claimed(&self.data, job) => {
                let name =
                    |p: &Path| p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
                let mesh_name = name(src).replacen(&shape_stem(src), &job.name, 1);
                let lab_ext = lab.extension().map(|e| e.to_string_lossy().into_owned()).unwrap_or_default();
                move_file(lab, &dir.join(format!("{}.{lab_ext}", job.name)))?;
                for c in &job.companions {
                    let n = format!("{}{}", job.name, sidecar_suffix(c));
                    move_file(c, &dir.join(n))?;
                }
                move_file(src, &dir.join(mesh_name))?;
            }
            _ => {
                let labels = shape.shape.labels.as_deref().map(Vec::as_slice).unwrap_or(&[]);
                let text = label_map_text(labels);
                let lab = dir.join(format!("{}.labels", job.name));
                atomic_write(&lab, text.as_bytes())?;
                write_mesh(dir.join(format!("{}.off", job.name)), &shape.shape.mesh)?;
                // A claimed input without a label file (identity labels) is consumed.
                if is_claimed(&self.data, job) {
                    if let Some(src) = &job.source {
                        let _ = fs::remove_file(src);
                    }
                }
            }
        }
        Ok(())
    }

    /// Loads the stored shapes the current model has learnt (once).
    fn load_known(&mut self, k: usize) -> Result<(), Error> {
        let Some(model) = self.live.current() else { return Ok(()) };
        let params = SpectrumParams::new(k);
        for name in &model.training_shapes {
            if self.known.contains_key(name) {
                continue;
            }
            let (mesh, labels, spectrum) =
                load_stored(&self.data.training(), name, &params, self.cache.as_ref(), &self.limits)?;
            self.make_copies(name, &mesh, &labels, k);
            let shape =
                self.with_local(TrainingShape::new(name.clone(), Arc::new(spectrum), labels), &mesh)?;
            self.known.insert(name.clone(), shape);
        }
        Ok(())
    }

    /// The local histograms' settings of the next model: the current model's, or for a first
    /// model the default ones if the configuration asks for them.
    fn local_params(&self) -> Option<LocalParams> {
        match self.live.current() {
            Some(m) => m.forest.local().copied(),
            None => self.config.local_descriptors.then(LocalParams::default),
        }
    }

    /// `shape` with the local histograms of `mesh` when the next model splits on them.
    fn with_local(&self, shape: TrainingShape, mesh: &Mesh) -> Result<TrainingShape, Error> {
        shape.with_local(mesh, self.local_params().as_ref()).map_err(|e| Error::Training(e.to_string()))
    }

    /// The perturbed copies of a training shape (the `augment` kinds), made once per shape and
    /// seeded by its name, so every update and every restart learns the same copies. A copy
    /// that cannot be made (a view that leaves too little of the shape) is left out with a
    /// warning.
    fn make_copies(&mut self, name: &str, mesh: &Mesh, labels: &[Option<u32>], k: usize) {
        if self.augment.is_empty() || self.copies.contains_key(name) {
            return;
        }
        let params = SpectrumParams::new(k);
        let local = self.local_params();
        let digest = Sha256::digest(name.as_bytes());
        let base = self.config.seed ^ u64::from_le_bytes(digest[..8].try_into().unwrap_or_default());
        let augmentation = Augmentation {
            kinds: &self.augment,
            copies: self.config.augment_copies,
            fill_perimeter: Some(ScanPart::FILL_PERIMETER),
            spectrum: &params,
            cache: self.cache.as_ref(),
            local: local.as_ref(),
        };
        // The name's digest in the seed tells the shapes apart.
        let copies: Vec<TrainingShape> = augmented_copies(name, mesh, labels, &augmentation, base, 0)
            .into_iter()
            .filter_map(|copy| {
                copy.map_err(|e| tracing::warn!(shape = %name, "a perturbed copy left out: {e}")).ok()
            })
            .collect();
        self.copies.insert(name.to_string(), copies);
    }

    /// The reference of a first model among the accepted shapes: the configured one, else the
    /// one whose own labels (per-label rows for `.vts` maps) cover most of the label set; labels
    /// it lacks are placed through the other shapes ([`reference_table`]). Fails, with the
    /// reason for the report, when no shape can serve.
    fn choose_reference(
        &self,
        accepted: &[(Job, SpectralShape, TrainingShape)],
        rows: &HashMap<u64, Vec<Option<u32>>>,
        mirrors: &HashMap<u64, Vec<Option<u32>>>,
        n_labels: usize,
    ) -> Result<ChosenReference, String> {
        if n_labels == 0 {
            return Err("no vertex of these labelled shapes carries a label".to_string());
        }
        let candidates: Vec<usize> = match &self.config.reference {
            Some(r) => (0..accepted.len()).filter(|&i| &accepted[i].0.name == r).collect(),
            None => (0..accepted.len()).collect(),
        };
        let mut best: Option<(usize, crate::forest::LabelTable)> = None;
        for &i in &candidates {
            let (job, shape, ts) = &accepted[i];
            let donors: Vec<(&Mesh, &[Option<u32>])> = accepted
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .map(|(_, a)| (a.1.shape.mesh.as_ref(), &a.2.labels[..]))
                .collect();
            let own = rows.get(&job.id).map(Vec::as_slice);
            if let Ok(t) = reference_table(n_labels, &shape.shape.mesh, &ts.labels, own, &donors) {
                if best.as_ref().is_none_or(|(_, b)| t.exact > b.exact) {
                    best = Some((i, t));
                }
            }
        }
        let Some((i, t)) = best else {
            return Err(match &self.config.reference {
                Some(r) => {
                    format!("the reference `{r}` is not among these shapes or carries none of their labels")
                }
                None => "none of these labelled shapes carries labels that a reference can hold".to_string(),
            });
        };
        let (job, shape, ts) = &accepted[i];
        if t.filled > 0 || t.unused > 0 {
            tracing::info!(
                reference = %job.name,
                "reference `{}`: {} labels on its own vertices, {} placed through the other shapes, {} carried by none",
                job.name,
                t.exact,
                t.filled,
                t.unused
            );
        }
        let mut prepared = PreparedShape::new(shape.shape.mesh.clone(), ts.spectrum.clone(), self.heat)
            .map_err(|e| e.to_string())?
            .serving_many();
        // Its `.sym.vts` (checked on arrival) gives the reference its left/right symmetry, with
        // which the regulariser repairs mirrored maps.
        if let (Some(own), Some(mirror)) = (rows.get(&job.id), mirrors.get(&job.id)) {
            let pairs: Vec<(usize, usize)> =
                own.iter().zip(mirror).filter_map(|(a, b)| Some(((*a)? as usize, (*b)? as usize))).collect();
            let symmetry = symmetry_from_pairs(&shape.shape.mesh, &pairs)
                .map_err(|e| format!("{}.sym.vts: {e}", job.name))?;
            prepared = prepared.with_symmetry(symmetry.into()).map_err(|e| e.to_string())?;
            tracing::info!(
                reference = %job.name,
                "reference `{}`: left/right symmetry from its .sym.vts ({} mirror pairs)",
                job.name,
                pairs.len()
            );
        }
        Ok((job.name.clone(), Arc::new(prepared), Arc::new(t.table)))
    }

    /// One model update with the pending shapes.
    fn update(&mut self) -> Result<(), Error> {
        if self.pending.is_empty() {
            return Ok(());
        }
        let t0 = Instant::now();
        let current = self.live.current();
        if let Some(m) =
            current.as_ref().filter(|m| self.config.local_descriptors && m.forest.local().is_none())
        {
            tracing::warn!(
                "local_descriptors = true does not apply: model v{} was grown without local histograms and \
                 updates keep its descriptors (fresh = true grows a new model that splits on them)",
                m.version
            );
        }
        let pending = std::mem::take(&mut self.pending);
        // A shape under the name of a stored one: an identical re-delivery is consumed, a
        // different shape is rejected (never swapped in).
        let mut fresh = Vec::new();
        for (job, shape) in pending {
            match self.same_name_as_stored(&job, &shape) {
                Ok(false) => fresh.push((job, shape)),
                Ok(true) => {
                    tracing::info!(shape = %job.name, "an identical copy of a stored training shape: consumed");
                    if is_claimed(&self.data, &job) {
                        for f in job.files() {
                            let _ = fs::remove_file(f);
                        }
                    }
                }
                Err(why) => reject_or_defer(&self.data, &job, &Failure::bad_input("trainer", why))?,
            }
        }
        if fresh.is_empty() {
            return Ok(());
        }
        // Per-label rows of `.vts` label files (several labels may share a vertex, so the
        // per-vertex labels alone lose some): they size the label set and place the labels on
        // the reference.
        let rows: HashMap<u64, Vec<Option<u32>>> = fresh
            .iter()
            .filter_map(|(job, shape)| label_rows(job, shape.shape.mesh.n_vertices()).map(|r| (job.id, r)))
            .collect();
        let n_labels = match &current {
            Some(m) => m.forest.n_labels(),
            None => fresh
                .iter()
                .filter_map(|(_, s)| s.shape.labels.as_ref())
                .flat_map(|l| l.iter().flatten())
                .map(|&l| l as usize + 1)
                .chain(rows.values().map(Vec::len))
                .max()
                .unwrap_or(0),
        };
        // Validate each new shape alone, so one bad shape is rejected by name.
        let mut accepted = Vec::new();
        let mut mirrors: HashMap<u64, Vec<Option<u32>>> = HashMap::new();
        for (job, shape) in fresh {
            let ts = TrainingShape::new(
                job.name.clone(),
                shape.spectrum.clone(),
                shape.shape.labels.as_deref().cloned().unwrap_or_default(),
            );
            let (ts, local) = match self.with_local(ts.clone(), &shape.shape.mesh) {
                Ok(with) => (with, Ok(())),
                Err(e) => (ts, Err(e.to_string())),
            };
            let check = match current.as_ref() {
                _ if local.is_err() => local,
                Some(m) if shape.spectrum.k() < m.forest.k() => Err(format!(
                    "its spectrum has {} eigenpairs, the model needs {}",
                    shape.spectrum.k(),
                    m.forest.k()
                )),
                _ => TrainingSet::new(vec![ts.clone()], n_labels).map(|_| ()).map_err(|e| e.to_string()),
            };
            let check = check.and_then(|()| {
                let m = mirror_rows(&job, rows.get(&job.id), shape.shape.mesh.n_vertices(), &self.limits)?;
                if let Some(m) = m {
                    mirrors.insert(job.id, m);
                }
                Ok(())
            });
            match check {
                Ok(()) => accepted.push((job, shape, ts)),
                Err(e) => {
                    reject_or_defer(&self.data, &job, &Failure::bad_input("trainer", e))?;
                }
            }
        }
        if accepted.is_empty() {
            return Ok(());
        }
        // The reference: kept from the current model, else the new shape that carries the most
        // labels (or the configured one), with the labels it lacks placed through the others.
        let (reference_name, reference, table) = match &current {
            Some(m) => (m.reference_name.clone(), m.reference.clone(), m.label_to_vertex.clone()),
            None => match self.choose_reference(&accepted, &rows, &mirrors, n_labels) {
                Ok(chosen) => chosen,
                Err(why) => {
                    // Nothing can be learnt from this set: say so for every shape of it.
                    for (job, _, _) in &accepted {
                        reject_or_defer(&self.data, job, &Failure::bad_input("trainer", why.clone()))?;
                    }
                    return Ok(());
                }
            },
        };
        let k = current.as_ref().map_or(accepted[0].1.spectrum.k(), |m| m.forest.k());
        self.load_known(k)?;
        // Stored before the fit (a crash during it resumes from training/). A shape that cannot
        // be stored (a full disk) goes back to labeled/ and is retried later.
        let mut stored = Vec::with_capacity(accepted.len());
        for a in accepted {
            match self.store(&a.0, &a.1) {
                Ok(()) => {
                    if let Some(n) = &a.0.arrived_as {
                        self.data.clear_deferral(InputKind::Labeled, n);
                    }
                    stored.push(a);
                }
                Err(e) => defer(&self.data, &a.0, &format!("cannot store it in training/: {e}"))?,
            }
        }
        let accepted = stored;
        if accepted.is_empty() {
            return Ok(());
        }
        for (_, shape, ts) in &accepted {
            self.make_copies(&ts.name, &shape.shape.mesh, &ts.labels, k);
        }
        let mut shapes: Vec<TrainingShape> = self.known.values().cloned().collect();
        shapes.extend(accepted.iter().map(|a| a.2.clone()));
        shapes.sort_by_key(|a| natural_key(&a.name));
        let real: std::collections::HashSet<String> = shapes.iter().map(|s| s.name.clone()).collect();
        let copies: Vec<TrainingShape> =
            shapes.iter().flat_map(|s| self.copies.get(&s.name).into_iter().flatten().cloned()).collect();
        let n_copies = copies.len();
        shapes.extend(copies);
        let set = TrainingSet::new(shapes, n_labels)?;
        let mut forest = self
            .params
            .fit_with(current.as_ref().map(|m| m.forest.as_ref()), &set)
            .map_err(|e| Error::Training(e.to_string()))?;
        if forest.reference().is_none() {
            let table = crate::forest::LabelTable { table: table.to_vec(), exact: 0, filled: 0, unused: 0 };
            let mut r = ModelReference::new(&reference_name, &reference.mesh, &table);
            if let Some(s) = reference.symmetry.as_deref() {
                r = r.with_symmetry(s)?;
            }
            forest = forest.with_reference(r)?;
        }
        let on_disk = latest_manifest(&self.data.models()).map_or(0, |m| m.version);
        let version = current.as_ref().map_or(0, |m| m.version).max(on_disk) + 1;
        // The manifest names the training shapes, not their copies.
        let names: Vec<String> =
            set.shapes().iter().map(|s| s.name.clone()).filter(|n| real.contains(n)).collect();
        let manifest = ModelManifest {
            version,
            model_file: format!("model-v{version:06}.sfm"),
            created_unix: unix_now(),
            reference: reference_name.clone(),
            training_shapes: names.clone(),
            n_labels,
            n_trees: forest.n_trees(),
            k: forest.k(),
        };
        let path = save_model_version(&self.data.models(), &forest, &manifest)?;
        prune_models(&self.data.models(), self.config.keep_models.max(1));
        for (_, _, ts) in accepted {
            self.known.insert(ts.name.clone(), ts);
        }
        self.live.publish(Arc::new(ModelState {
            version,
            forest: Arc::new(forest),
            reference_name,
            reference,
            label_to_vertex: table,
            training_shapes: names.clone(),
        }));
        tracing::info!(
            version,
            shapes = names.len(),
            "model v{version} saved to {} ({} training shapes, {n_copies} perturbed copies, {:.1} s)",
            path.display(),
            names.len(),
            t0.elapsed().as_secs_f64()
        );
        Ok(())
    }
}

impl Sink for TrainerSink {
    type In = SpectralShape;

    fn start(&mut self) -> Result<(), Error> {
        // Stored shapes the newest model has not learnt (a crash before its save, or during the
        // first training, before any model existed): learn them now.
        let model = self.live.current();
        let learnt = |name: &str| model.as_ref().is_some_and(|m| m.training_shapes.iter().any(|n| n == name));
        let missing: Vec<_> =
            stored_shapes(&self.data.training()).into_iter().filter(|s| !learnt(&s.name)).collect();
        if missing.is_empty() {
            return Ok(());
        }
        let k = model.as_ref().map_or(self.spectrum_k, |m| m.forest.k());
        let params = SpectrumParams::new(k);
        for s in missing {
            match &model {
                Some(m) => {
                    tracing::info!(shape = %s.name, "stored training shape not in model v{}: learning it", m.version)
                }
                None => {
                    tracing::info!(shape = %s.name, "stored training shape and no model yet (training was interrupted): learning it")
                }
            }
            match load_stored(&self.data.training(), &s.name, &params, self.cache.as_ref(), &self.limits) {
                Ok((mesh, labels, spectrum)) => {
                    let mut job = Job::generated(0, &s.name);
                    job.source = Some(s.mesh.clone());
                    // Its `.vts` rows and `.sym.vts` as when it arrived, so that the reference
                    // and its symmetry come out the same.
                    job.labels_file = Some(s.labels.clone());
                    job.companions.extend(symmetry_sidecar(&s.mesh));
                    let shape = Shape { mesh, labels: Some(Arc::new(labels)) };
                    self.pending.push((job, SpectralShape::whole(shape, Arc::new(spectrum))));
                }
                Err(e) => tracing::warn!(shape = %s.name, "cannot read a stored training shape: {e}"),
            }
        }
        self.update()
    }

    fn consume(&mut self, job: Job, body: Result<SpectralShape, Failure>) -> Result<(), Error> {
        match body {
            Err(f) => reject_or_defer(&self.data, &job, &f),
            Ok(shape) if shape.shape.labels.is_none() => reject_or_defer(
                &self.data,
                &job,
                &Failure::bad_input("trainer", "the shape has no labels to learn from"),
            )
            .map(|_| ()),
            Ok(shape) => {
                tracing::info!(shape = %job.name, "labelled shape received; the model is updated once no more arrive");
                self.pending.push((job, shape));
                self.last_arrival = Instant::now();
                Ok(())
            }
        }
    }

    fn idle(&mut self) -> Result<(), Error> {
        let quiet = std::time::Duration::from_millis(self.config.quiet_ms);
        match self.config.mode {
            TrainMode::Incremental if self.last_arrival.elapsed() >= quiet => self.update(),
            _ => Ok(()),
        }
    }

    fn tick(&self) -> Option<std::time::Duration> {
        match self.config.mode {
            TrainMode::Incremental => Some(std::time::Duration::from_millis(200)),
            TrainMode::Once => None,
        }
    }

    fn finish(&mut self) -> Result<(), Error> {
        let r = self.update();
        // At a shutdown, scans waiting for a model stay queued (they see the shutdown); only a
        // pipeline that ran out of input learns that no model will come.
        let stopping = self.shutdown.as_ref().is_some_and(|s| s.is_triggered());
        if self.live.current().is_none() && !stopping {
            self.live.close(match &r {
                Err(e) => format!("training failed: {e}"),
                Ok(()) => "no labelled shape was accepted for training".to_string(),
            });
        }
        r
    }
}
