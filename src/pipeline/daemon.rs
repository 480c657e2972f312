//! Running a pipeline file on a data folder: the daemon's start-up (folders, crash recovery,
//! the newest model, a clear word when there is nothing to learn from, the optional synthetic
//! bootstrap), then the run.

use std::{fs, path::Path, sync::Arc};

use super::{
    actor::PipelineContext,
    config::{build, PipelineSpec},
    error::{Error, IoAt},
    graph::{PipelineReport, RunOptions},
    lock::DataLock,
    message::{Failure, FailureKind, Job},
    model::{load_live_model_for, LiveModel, ServeNeeds},
    shutdown::Shutdown,
    stages::{SpectralConfig, TrainerConfig},
    store::{atomic_write, label_map_text, read_dir_sorted, reject, stored_shapes, DataDir, InputKind},
};
use crate::{
    forest::labels_identity,
    geodesic::HeatParams,
    mesh::write_mesh,
    synth::{creature_family, CreatureParams},
};

/// What [`prepare`] found and did.
pub struct RunSetup {
    /// The data folder.
    pub data: DataDir,
    /// The live model (loaded from `models/` when one exists).
    pub live: Arc<LiveModel>,
    /// Lines for the user: recovery, the model in use.
    pub notes: Vec<String>,
    /// No model, no labelled shape waiting and none stored: nothing to learn from yet.
    pub nothing_to_learn: bool,
    /// For a daemon with nothing to learn from: what to drop where.
    pub waiting_hint: Option<String>,
    /// The exclusive lock on the data folder, held while this lives.
    pub lock: DataLock,
}

/// Writes `n_train` labelled shapes of the synthetic creature family into `labeled/` and
/// `n_scans` further poses into `incoming/` (`creatureN.off` with `creatureN.labels`;
/// `scan-creatureN.off`). Returns the number of vertices per shape.
pub fn bootstrap_synthetic(
    data: &DataDir,
    vertices: usize,
    n_train: usize,
    n_scans: usize,
    seed: u64,
) -> Result<usize, Error> {
    let fam = creature_family(
        &CreatureParams { target_vertices: vertices, seed, ..Default::default() },
        n_train + n_scans,
    )
    .map_err(|e| Error::BadInput(format!("synthetic family: {e}")))?;
    let n = fam.template.n_vertices();
    let labels = label_map_text(&labels_identity(n));
    // Scans first: a watcher sees complete files only (written aside, then renamed in).
    let stage = data.root().join(".bootstrap");
    fs::create_dir_all(&stage).at(&stage)?;
    for (i, mesh) in fam.shapes.iter().enumerate() {
        let (dir, name) = if i < n_train {
            (data.labeled(), format!("creature{i}"))
        } else {
            (data.incoming(), format!("scan-creature{i}"))
        };
        let tmp = stage.join(format!("{name}.off"));
        write_mesh(&tmp, mesh)?;
        if i < n_train {
            atomic_write(&dir.join(format!("{name}.labels")), labels.as_bytes())?;
        }
        fs::rename(&tmp, dir.join(format!("{name}.off"))).at(&dir)?;
    }
    let _ = fs::remove_dir(&stage);
    Ok(n)
}

/// Prepares the data folder of a pipeline: creates the folders of a daemon and recovers from a
/// crash, then loads the newest model. Fails when the pipeline needs a model and nothing can
/// produce one.
pub fn prepare(spec: &PipelineSpec, data: DataDir) -> Result<RunSetup, Error> {
    let mut notes = Vec::new();
    // Before anything moves: a second process on this folder would recover (move back) the
    // first one's in-flight inputs.
    let lock = DataLock::acquire(data.root())?;
    let mut skip_versions = Vec::new();
    if spec.is_daemon() {
        data.create().map_err(|e| Error::BadInput(format!("cannot create the data folder: {e}")))?;
        let crash = account_for_a_crash(&data, &mut notes)?;
        skip_versions = crash.quarantined_models.clone();
        let rec = data.recover().map_err(|e| Error::BadInput(format!("recovery failed: {e}")))?;
        for p in &rec.committed {
            notes.push(format!("recovered: finished committing {}", p.display()));
        }
        if !rec.requeued.is_empty() {
            notes.push(format!(
                "recovered: {} input(s) in flight at the last stop are queued again",
                rec.requeued.len()
            ));
        }
        if !rec.discarded.is_empty() {
            notes.push(format!(
                "recovered: {} partial result(s) discarded (their scans are matched again)",
                rec.discarded.len()
            ));
        }
    }
    let fresh = spec.configs::<TrainerConfig>().any(|c| c.fresh);
    let needs = ServeNeeds { limits: spec.settings.limits, spectrum_k: scan_spectrum_k(spec), skip_versions };
    let loaded = if fresh { None } else { load_live_model_for(&data, HeatParams::default(), &needs)? };
    let live = match loaded {
        Some(m) => {
            notes.push(format!(
                "model v{} ({} trees, {} training shapes, reference `{}`)",
                m.version,
                m.forest.n_trees(),
                m.training_shapes.len(),
                m.reference_name
            ));
            Arc::new(LiveModel::with(m))
        }
        None => Arc::new(LiveModel::new()),
    };
    let needs_model = spec.has_type("descriptor");
    let has_trainer = spec.configs::<TrainerConfig>().next().is_some();
    if live.current().is_none() && needs_model && !has_trainer {
        return Err(Error::Model(format!(
            "no model in {}: this pipeline matches but does not train; run one that trains first \
             (e.g. `shapeforest run pipelines/train.toml`)",
            data.models().display()
        )));
    }
    let labelled = fs::read_dir(data.labeled()).map(|d| d.count()).unwrap_or(0);
    let nothing_to_learn =
        live.current().is_none() && labelled == 0 && stored_shapes(&data.training()).is_empty();
    let waiting_hint = (nothing_to_learn && needs_model && spec.is_daemon()).then(|| {
        format!(
            "no model and no labelled shapes yet: scans wait in {} until a labelled shape \
             (NAME.off with NAME.labels, one label per vertex) arrives in {} \
             — or start with --bootstrap-synthetic to see it work on built-in data",
            data.incoming().display(),
            data.labeled().display()
        )
    });
    if spec.is_daemon() {
        let marker = Running { pid: std::process::id(), model_version: live.version() };
        let text = serde_json::to_string(&marker)?;
        atomic_write(&data.running_marker(), text.as_bytes())?;
    }
    Ok(RunSetup { data, live, notes, nothing_to_learn, waiting_hint, lock })
}

/// The K of the spectra that feed the descriptor stage (the scans'), if the pipeline has one.
fn scan_spectrum_k(spec: &PipelineSpec) -> Option<usize> {
    spec.stages
        .iter()
        .filter(|s| s.type_name() == "descriptor")
        .filter_map(|d| d.input.as_deref().and_then(|i| spec.stage(i)))
        .filter_map(|u| u.config::<SpectralConfig>().map(|c| c.k))
        .min()
}

/// Written to `.inflight/running.json` while a daemon runs; removed when it stops cleanly (or
/// on a second signal). Found at start, it means the last run crashed (a panic that killed the
/// process, an abort, an OOM kill, `kill -9`).
#[derive(serde::Serialize, serde::Deserialize)]
struct Running {
    pid: u32,
    model_version: u64,
}

/// How often inputs and model versions were in flight when the daemon crashed
/// (`.inflight/crashes.json`).
#[derive(Default, serde::Serialize, serde::Deserialize)]
struct CrashLog {
    /// Claimed inputs (`scans/NAME`, `labeled/NAME`) → consecutive crashes while in flight.
    inputs: std::collections::BTreeMap<String, u32>,
    /// Model version in use → consecutive crashes.
    models: std::collections::BTreeMap<u64, u32>,
    /// Versions not to load again.
    quarantined_models: Vec<u64>,
}

/// Crashes after which an input or a model is quarantined instead of being tried again.
const POISON_CRASHES: u32 = 2;

/// After a crash (the running marker is still there), counts it against the inputs that were
/// in flight and the model in use. An input in flight at two crashes in a row is moved to
/// `rejected/` with a report (poison: it would crash the daemon at every restart); a model in
/// use at two crashes in a row, with no input to blame, is not loaded again (the next newest
/// is used).
fn account_for_a_crash(data: &DataDir, notes: &mut Vec<String>) -> Result<CrashLog, Error> {
    let log_path = data.root().join(".inflight").join("crashes.json");
    let mut log: CrashLog =
        fs::read_to_string(&log_path).ok().and_then(|t| serde_json::from_str(&t).ok()).unwrap_or_default();
    let marker = data.running_marker();
    let Some(running) = fs::read_to_string(&marker).ok() else { return Ok(log) };
    let running: Option<Running> = serde_json::from_str(&running).ok();
    let mut in_flight = Vec::new();
    for kind in [InputKind::Scan, InputKind::Labeled] {
        let dir = data.inflight(kind);
        for p in read_dir_sorted(&dir).unwrap_or_default() {
            if p.is_file() || p.is_symlink() {
                in_flight.push((kind, p));
            }
        }
    }
    let key = |kind: InputKind, p: &Path| {
        let folder = if kind == InputKind::Scan { "scans" } else { "labeled" };
        format!("{folder}/{}", p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default())
    };
    // Counts are of consecutive crashes: inputs no longer in flight are forgotten.
    let keys: Vec<String> = in_flight.iter().map(|(k, p)| key(*k, p)).collect();
    log.inputs.retain(|k, _| keys.contains(k));
    for k in &keys {
        *log.inputs.entry(k.clone()).or_insert(0) += 1;
    }
    let mut quarantined_inputs = 0;
    for (kind, p) in &in_flight {
        if log.inputs.get(&key(*kind, p)).copied().unwrap_or(0) < POISON_CRASHES {
            continue;
        }
        let mut job = Job::for_file(0, p, None);
        job.arrived_as = p.file_name().map(|n| n.to_string_lossy().into_owned());
        let why = format!(
            "quarantined: this input was being processed each of the last {POISON_CRASHES} times the \
             daemon stopped abnormally (a crash, an out-of-memory kill or kill -9), so it is not \
             retried; move it back to {}/ to try again",
            if *kind == InputKind::Scan { "incoming" } else { "labeled" }
        );
        reject(data, &job, &Failure { stage: "recovery".into(), kind: FailureKind::Internal, message: why })?;
        log.inputs.remove(&key(*kind, p));
        quarantined_inputs += 1;
        notes.push(format!("quarantined {} after {POISON_CRASHES} crashes (see rejected/)", p.display()));
    }
    if let Some(r) = running.as_ref().filter(|r| r.model_version > 0) {
        log.models.retain(|v, _| *v == r.model_version);
        let n = log.models.entry(r.model_version).or_insert(0);
        *n += 1;
        if *n >= POISON_CRASHES
            && quarantined_inputs == 0
            && !log.quarantined_models.contains(&r.model_version)
        {
            log.quarantined_models.push(r.model_version);
            log.models.remove(&r.model_version);
            notes.push(format!(
                "model v{} was in use at {POISON_CRASHES} crashes in a row: quarantined, not loaded again",
                r.model_version
            ));
        }
    }
    notes.push(format!(
        "the last run did not stop cleanly (pid {}); {} input(s) were in flight",
        running.as_ref().map_or("?".into(), |r| r.pid.to_string()),
        in_flight.len()
    ));
    let text = serde_json::to_string_pretty(&log)?;
    atomic_write(&log_path, text.as_bytes())?;
    let _ = fs::remove_file(&marker);
    Ok(log)
}

/// Reads, prepares and runs a pipeline file (the `run` and `watch` commands). `data_dir`
/// overrides the file's `settings.data_dir`.
pub fn run_pipeline(
    path: &Path,
    data_dir: Option<&Path>,
    options: RunOptions,
) -> Result<PipelineReport, Error> {
    let spec = PipelineSpec::from_file(path)?;
    run_spec(&spec, data_dir, options, None, |_| Ok(()))
}

/// [`run_pipeline`] for a parsed spec, with an optional shutdown flag the caller holds and a
/// hook run after preparation (e.g. a bootstrap).
pub fn run_spec(
    spec: &PipelineSpec,
    data_dir: Option<&Path>,
    options: RunOptions,
    shutdown: Option<Shutdown>,
    before_run: impl FnOnce(&RunSetup) -> Result<(), Error>,
) -> Result<PipelineReport, Error> {
    let data =
        DataDir::new(data_dir.map(Path::to_path_buf).unwrap_or_else(|| spec.settings.data_dir.clone()));
    let setup = prepare(spec, data)?;
    before_run(&setup)?;
    let ctx = PipelineContext::with_shutdown(shutdown.unwrap_or_default());
    let pipeline = build(spec, &setup.data, setup.live.clone(), ctx)?;
    let report = pipeline.run(options);
    // A clean stop: the next start is not a crash recovery.
    let _ = fs::remove_file(setup.data.running_marker());
    report
}
