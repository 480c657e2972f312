//! Running a pipeline file on a data folder: the daemon's start-up (folders, crash recovery,
//! the newest model, a clear word when there is nothing to learn from, the optional synthetic
//! bootstrap), then the run.

use std::{fs, path::Path, sync::Arc};

use super::{
    actor::{PipelineContext, Shutdown},
    config::{build, PipelineSpec, StageKind},
    graph::{PipelineReport, RunOptions},
    model::LiveModel,
    stages::load_live_model,
    store::{atomic_write, label_map_text, stored_shapes, DataDir},
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
) -> Result<usize, String> {
    let fam = creature_family(
        &CreatureParams { target_vertices: vertices, seed, ..Default::default() },
        n_train + n_scans,
    )
    .map_err(|e| format!("synthetic family: {e}"))?;
    let n = fam.template.n_vertices();
    let labels = label_map_text(&labels_identity(n));
    // Scans first: a watcher sees complete files only (written aside, then renamed in).
    let stage = data.root().join(".bootstrap");
    fs::create_dir_all(&stage).map_err(|e| format!("{}: {e}", stage.display()))?;
    for (i, mesh) in fam.shapes.iter().enumerate() {
        let (dir, name) = if i < n_train {
            (data.labeled(), format!("creature{i}"))
        } else {
            (data.incoming(), format!("scan-creature{i}"))
        };
        let tmp = stage.join(format!("{name}.off"));
        write_mesh(&tmp, mesh).map_err(|e| e.to_string())?;
        if i < n_train {
            atomic_write(&dir.join(format!("{name}.labels")), labels.as_bytes())
                .map_err(|e| e.to_string())?;
        }
        fs::rename(&tmp, dir.join(format!("{name}.off"))).map_err(|e| format!("{}: {e}", dir.display()))?;
    }
    let _ = fs::remove_dir(&stage);
    Ok(n)
}

/// Prepares the data folder of a pipeline: creates the folders of a daemon and recovers from a
/// crash, then loads the newest model. Fails when the pipeline needs a model and nothing can
/// produce one.
pub fn prepare(spec: &PipelineSpec, data: DataDir) -> Result<RunSetup, String> {
    let mut notes = Vec::new();
    if spec.is_daemon() {
        data.create().map_err(|e| format!("cannot create the data folder: {e}"))?;
        let rec = data.recover().map_err(|e| format!("recovery failed: {e}"))?;
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
    let fresh = spec.has(|k| matches!(k, StageKind::Trainer(c) if c.fresh));
    let loaded = if fresh { None } else { load_live_model(&data, HeatParams::default())? };
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
    let needs_model = spec.has(|k| matches!(k, StageKind::Descriptor));
    let has_trainer = spec.has(|k| matches!(k, StageKind::Trainer(_)));
    if live.current().is_none() && needs_model && !has_trainer {
        return Err(format!(
            "no model in {}: this pipeline matches but does not train; run one that trains first \
             (e.g. `shapeforest run pipelines/train.toml`)",
            data.models().display()
        ));
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
    Ok(RunSetup { data, live, notes, nothing_to_learn, waiting_hint })
}

/// Reads, prepares and runs a pipeline file (the `run` and `watch` commands). `data_dir`
/// overrides the file's `settings.data_dir`.
pub fn run_pipeline(
    path: &Path,
    data_dir: Option<&Path>,
    options: RunOptions,
) -> Result<PipelineReport, String> {
    let spec = PipelineSpec::from_file(path).map_err(|e| e.to_string())?;
    run_spec(&spec, data_dir, options, None, |_| Ok(()))
}

/// [`run_pipeline`] for a parsed spec, with an optional shutdown flag the caller holds and a
/// hook run after preparation (e.g. a bootstrap).
pub fn run_spec(
    spec: &PipelineSpec,
    data_dir: Option<&Path>,
    options: RunOptions,
    shutdown: Option<Shutdown>,
    before_run: impl FnOnce(&RunSetup) -> Result<(), String>,
) -> Result<PipelineReport, String> {
    let data =
        DataDir::new(data_dir.map(Path::to_path_buf).unwrap_or_else(|| spec.settings.data_dir.clone()));
    let setup = prepare(spec, data)?;
    before_run(&setup)?;
    let ctx = PipelineContext::with_shutdown(shutdown.unwrap_or_default());
    let pipeline = build(spec, &setup.data, setup.live.clone(), ctx)?;
    pipeline.run(options).map_err(|e| format!("cannot start the runtime: {e}"))
}
