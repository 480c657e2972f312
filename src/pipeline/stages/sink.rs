//! `match-sink`: writes each matched scan's outputs, commits claimed inputs beside them, and
//! rejects failed inputs with a report. Also the rejection helper other sinks share.

use std::{fmt::Write as _, fs, path::PathBuf};

use serde::Deserialize;

use crate::{
    mesh::{coordinate_colors, write_colored_ply},
    pipeline::{
        actor::Sink,
        message::{Failure, FailureKind, Job, MatchedShape},
        store::{atomic_write, move_file, unique_path, DataDir, InputKind},
    },
};

/// Settings of `match-sink`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MatchSinkConfig {
    /// Output folder (relative paths are taken from the data folder). Default `matched`.
    #[serde(default = "default_folder")]
    pub folder: PathBuf,
    /// Write the scan coloured through the map (and the reference once). Default true.
    #[serde(default = "default_true")]
    pub colored: bool,
}

fn default_folder() -> PathBuf {
    PathBuf::from("matched")
}
fn default_true() -> bool {
    true
}

/// Whether a job's input was claimed into the data folder's `.inflight/` (by a watcher).
pub fn is_claimed(data: &DataDir, job: &Job) -> bool {
    job.source.as_ref().is_some_and(|s| {
        s.starts_with(data.inflight(InputKind::Scan)) || s.starts_with(data.inflight(InputKind::Labeled))
    })
}

/// Handles a failed job: an interrupted one is left claimed (it is taken up again at the next
/// start); any other has its report written to `rejected/NAME.error.json`, and a claimed input
/// (with its label map) moves to `rejected/` beside it. Returns the report's path.
pub fn reject(data: &DataDir, job: &Job, failure: &Failure) -> Result<Option<PathBuf>, String> {
    if failure.kind == FailureKind::Interrupted {
        tracing::info!(job = job.id, shape = %job.name, "interrupted; the input is taken up again at the next start");
        return Ok(None);
    }
    let dir = data.rejected();
    fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let mut moved = Vec::new();
    if is_claimed(data, job) {
        for f in job.source.iter().chain(job.labels_file.iter()) {
            if !f.is_file() {
                continue;
            }
            let name = f.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            let target = unique_path(&dir, &name);
            move_file(f, &target).map_err(|e| e.to_string())?;
            moved.push(target.display().to_string());
        }
    }
    let report = serde_json::json!({
        "job": job.id,
        "input": job.arrived_as.clone().unwrap_or_else(|| job.display_source()),
        "stage": failure.stage,
        "kind": format!("{:?}", failure.kind),
        "error": failure.message,
        "moved_to": moved,
        "rejected_unix": unix_now(),
    });
    let path = unique_path(&dir, &format!("{}.error.json", job.name));
    let text = serde_json::to_string_pretty(&report).map_err(|e| e.to_string())? + "\n";
    atomic_write(&path, text.as_bytes()).map_err(|e| e.to_string())?;
    tracing::warn!(job = job.id, shape = %job.name, report = %path.display(), "rejected: {failure}");
    Ok(Some(path))
}

/// Seconds since the Unix epoch.
pub fn unix_now() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs())
}

/// Writes matched scans into a folder, one sub-folder per scan.
pub struct MatchSink {
    data: DataDir,
    config: MatchSinkConfig,
    written: Vec<PathBuf>,
}

impl MatchSink {
    /// A sink writing into `config.folder` (already resolved).
    pub fn new(data: DataDir, config: MatchSinkConfig) -> Self {
        Self { data, config, written: Vec::new() }
    }

    /// Result folders written so far.
    pub fn written(&self) -> &[PathBuf] {
        &self.written
    }

    fn write(&mut self, job: &Job, m: &MatchedShape) -> Result<PathBuf, String> {
        let root = &self.config.folder;
        fs::create_dir_all(root).map_err(|e| format!("{}: {e}", root.display()))?;
        let name = &job.name;
        let partial = root.join(format!(".partial-{name}-{}", job.id));
        if partial.exists() {
            fs::remove_dir_all(&partial).map_err(|e| format!("{}: {e}", partial.display()))?;
        }
        fs::create_dir_all(&partial).map_err(|e| format!("{}: {e}", partial.display()))?;
        let model = &m.predicted.model;
        let dense = &m.dense;
        let mesh = &m.predicted.shape.shape.mesh;

        let mut text = format!(
            "# shapeforest: line i (after this header) = vertex of reference `{}` (model v{}) matched to vertex i of {}\n",
            model.reference_name,
            model.version,
            job.arrived_as.as_deref().unwrap_or(name)
        );
        for &r in &dense.map {
            let _ = writeln!(text, "{r}");
        }
        let map_file = format!("{name}.map.txt");
        fs::write(partial.join(&map_file), text).map_err(|e| format!("{map_file}: {e}"))?;
        if self.config.colored {
            let ref_mesh = &model.reference.mesh;
            let ref_colors = coordinate_colors(ref_mesh);
            let scan_colors: Vec<[u8; 3]> = dense.map.iter().map(|&r| ref_colors[r]).collect();
            write_colored_ply(partial.join(format!("{name}.colored.ply")), mesh, &scan_colors)
                .map_err(|e| e.to_string())?;
            crate::viz::write_snapshot(&partial.join(format!("{name}.png")), mesh, ref_mesh, &dense.map)?;
            let ref_path = root.join(format!("reference-{}.colored.ply", model.reference_name));
            if !ref_path.exists() {
                write_colored_ply(&ref_path, ref_mesh, &ref_colors).map_err(|e| e.to_string())?;
            }
        }
        let latency = job.started.elapsed().as_secs_f64();
        let stages: serde_json::Map<String, serde_json::Value> =
            job.stage_seconds.iter().map(|(s, t)| (s.clone(), serde_json::json!(t))).collect();
        let report = serde_json::json!({
            "job": job.id,
            "input": job.arrived_as.clone().unwrap_or_else(|| name.clone()),
            "vertices": mesh.n_vertices(),
            "model_version": model.version,
            "reference": model.reference_name,
            "reference_vertices": model.reference.mesh.n_vertices(),
            "map_file": map_file,
            "n_sparse_matches": dense.matches.len(),
            "orientation_score": dense.orientation_score,
            "mirror_rejected": dense.mirror_rejected,
            "grown_anchors": dense.grown_anchors,
            "dense_orientation_agreement": dense.dense_orientation,
            "reoriented": dense.reoriented,
            "mean_forest_confidence": m.predicted.prediction.mean_confidence(),
            "mean_forest_support": m.predicted.prediction.mean_support(),
            "stage_seconds": stages,
            "latency_s": latency,
            "finished_unix": unix_now(),
        });
        let text = serde_json::to_string_pretty(&report).map_err(|e| e.to_string())? + "\n";
        fs::write(partial.join(format!("{name}.report.json")), text).map_err(|e| e.to_string())?;
        // Commit: the claimed input moves in beside its result, then the folder gets its name.
        if is_claimed(&self.data, job) {
            if let (Some(src), Some(arrived)) = (&job.source, &job.arrived_as) {
                fs::write(partial.join(".input"), arrived).map_err(|e| e.to_string())?;
                move_file(src, &partial.join(arrived)).map_err(|e| e.to_string())?;
            }
        }
        let target = unique_path(root, name);
        fs::rename(&partial, &target).map_err(|e| format!("{}: {e}", target.display()))?;
        tracing::info!(
            job = job.id,
            shape = %name,
            model = model.version,
            "matched in {latency:.2} s → {}",
            target.display()
        );
        Ok(target)
    }
}

impl Sink for MatchSink {
    type In = MatchedShape;

    fn consume(&mut self, job: Job, body: Result<MatchedShape, Failure>) -> Result<(), String> {
        match body {
            Ok(m) => match self.write(&job, &m) {
                Ok(p) => {
                    self.written.push(p);
                    Ok(())
                }
                Err(e) => {
                    // The outputs could not be written: report it as the job's failure.
                    let f = Failure {
                        stage: "match-sink".into(),
                        kind: FailureKind::Internal,
                        message: e.clone(),
                    };
                    reject(&self.data, &job, &f)?;
                    Err(e)
                }
            },
            Err(f) => reject(&self.data, &job, &f).map(|_| ()),
        }
    }
}
