//! `match-sink`: writes each matched scan's outputs, commits claimed inputs beside them, and
//! rejects failed inputs with a report. Also the rejection helper other sinks share.

use std::{fmt::Write as _, fs, path::PathBuf};

use serde::Deserialize;

use crate::{
    limits::escape_name,
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
/// start); any other has its report written to `rejected/NAME.error.json` first, then its
/// claimed files (input, label map, companions) move to `rejected/` beside it — so an input is
/// never in `rejected/` without its report. An input named like a report (`*.error.json`)
/// gets `.input` appended, so that it cannot pass for one. Returns the report's path.
pub fn reject(data: &DataDir, job: &Job, failure: &Failure) -> Result<Option<PathBuf>, String> {
    if failure.kind == FailureKind::Interrupted {
        tracing::info!(job = job.id, shape = %escape_name(&job.name), "interrupted; the input is taken up again at the next start");
        return Ok(None);
    }
    let dir = data.rejected();
    fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let mut moves = Vec::new();
    if is_claimed(data, job) {
        for f in job.files() {
            if fs::symlink_metadata(f).is_err() {
                continue;
            }
            let mut name = f.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            if name.to_ascii_lowercase().ends_with(".error.json") {
                name.push_str(".input");
            }
            let target = unique_path(&dir, &name);
            moves.push((f.clone(), target));
        }
    }
    let report = serde_json::json!({
        "job": job.id,
        "input": job.arrived_as.clone().unwrap_or_else(|| job.display_source()),
        "stage": failure.stage,
        "kind": format!("{:?}", failure.kind),
        "error": failure.message,
        "moved_to": moves.iter().map(|m| m.1.display().to_string()).collect::<Vec<_>>(),
        "rejected_unix": unix_now(),
    });
    let path = unique_path(&dir, &format!("{}.error.json", job.name));
    let text = serde_json::to_string_pretty(&report).map_err(|e| e.to_string())? + "\n";
    atomic_write(&path, text.as_bytes()).map_err(|e| e.to_string())?;
    for (from, to) in &moves {
        move_file(from, to).map_err(|e| e.to_string())?;
    }
    tracing::warn!(job = job.id, shape = %escape_name(&job.name), report = %path.display(), "rejected: {failure}");
    Ok(Some(path))
}

/// [`reject`], and when the report cannot be written (a full disk, a read-only folder) the
/// input is deferred instead: it goes back to its arrivals folder and is retried after a
/// back-off. Bad input is never lost because the disk was full.
pub fn reject_or_defer(data: &DataDir, job: &Job, failure: &Failure) -> Result<(), String> {
    match reject(data, job, failure) {
        Ok(_) => Ok(()),
        Err(e) => defer(data, job, &format!("cannot write its rejection report: {e}")),
    }
}

/// Puts a claimed job's input back into its arrivals folder for a later retry (see
/// [`DataDir::defer`]), logging the cause. Unclaimed inputs (batch runs read in place) are left
/// where they are.
pub fn defer(data: &DataDir, job: &Job, cause: &str) -> Result<(), String> {
    let Some(src) = job.source.as_ref().filter(|_| is_claimed(data, job)) else {
        return Err(cause.to_string());
    };
    let kind =
        if src.starts_with(data.inflight(InputKind::Scan)) { InputKind::Scan } else { InputKind::Labeled };
    let companions: Vec<PathBuf> = job.labels_file.iter().chain(job.companions.iter()).cloned().collect();
    match data.defer(kind, src, &companions) {
        Ok((back, delay)) => {
            tracing::warn!(
                job = job.id,
                shape = %escape_name(&job.name),
                "{cause}; the input stays queued as {} and is retried in {} s",
                back.display(),
                delay.as_secs()
            );
            Ok(())
        }
        Err(e) => {
            Err(format!("{cause}; and it could not be put back ({e}): it is taken up at the next start"))
        }
    }
}

/// A documented test hook for output failures: while the file named by the environment
/// variable `SHAPEFOREST_FAULT_FILE` exists, writing a result fails with the error that file
/// names (`ENOSPC`: no space left; `EROFS`: read-only file system). Used by the fault-injection
/// tests where a small file system cannot be mounted; it does nothing when the variable is
/// unset.
fn injected_fault() -> Option<std::io::Error> {
    let path = std::env::var_os("SHAPEFOREST_FAULT_FILE")?;
    let what = fs::read_to_string(path).ok()?;
    let code = if what.trim() == "EROFS" { libc::EROFS } else { libc::ENOSPC };
    Some(std::io::Error::from_raw_os_error(code))
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

    /// Writes a result, and on failure leaves nothing behind: the partial folder is removed and
    /// a claimed input that had moved into it goes back to `.inflight/`.
    fn write(&mut self, job: &Job, m: &MatchedShape) -> Result<PathBuf, String> {
        let partial = self.config.folder.join(format!(".partial-{}-{}", job.name, job.id));
        let r = self.write_parts(job, m, &partial);
        if r.is_err() {
            if let (Some(src), Some(arrived)) = (&job.source, &job.arrived_as) {
                let inside = partial.join(arrived);
                if is_claimed(&self.data, job) && inside.is_file() && !src.exists() {
                    let _ = move_file(&inside, src);
                }
            }
            let _ = fs::remove_dir_all(&partial);
        }
        r
    }

    fn write_parts(
        &mut self,
        job: &Job,
        m: &MatchedShape,
        partial: &std::path::Path,
    ) -> Result<PathBuf, String> {
        let root = &self.config.folder;
        if let Some(e) = injected_fault() {
            return Err(format!("{}: {e} (SHAPEFOREST_FAULT_FILE)", root.display()));
        }
        fs::create_dir_all(root).map_err(|e| format!("{}: {e}", root.display()))?;
        let name = &job.name;
        let partial = partial.to_path_buf();
        if partial.exists() {
            fs::remove_dir_all(&partial).map_err(|e| format!("{}: {e}", partial.display()))?;
        }
        fs::create_dir_all(&partial).map_err(|e| format!("{}: {e}", partial.display()))?;
        let model = &m.predicted.model;
        let dense = &m.dense;
        let mesh = &m.predicted.shape.shape.mesh;

        let mut text = format!(
            "# shapeforest: line i (after this header) = vertex of reference `{}` (model v{}) matched to vertex i of {}\n",
            escape_name(&model.reference_name),
            model.version,
            escape_name(job.arrived_as.as_deref().unwrap_or(name))
        );
        for &r in &dense.map {
            let _ = writeln!(text, "{r}");
        }
        let map_file = format!("{name}.map.txt");
        fs::write(partial.join(&map_file), text)
            .map_err(|e| format!("{}: {e}", partial.join(&map_file).display()))?;
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
        let report_path = partial.join(format!("{name}.report.json"));
        fs::write(&report_path, text).map_err(|e| format!("{}: {e}", report_path.display()))?;
        // Commit: the claimed input moves in beside its result, then the folder gets its name.
        if is_claimed(&self.data, job) {
            if let (Some(src), Some(arrived)) = (&job.source, &job.arrived_as) {
                let marker = partial.join(".input");
                fs::write(&marker, arrived).map_err(|e| format!("{}: {e}", marker.display()))?;
                for c in &job.companions {
                    if let Some(n) = c.file_name() {
                        move_file(c, &partial.join(n)).map_err(|e| e.to_string())?;
                    }
                }
                move_file(src, &partial.join(arrived)).map_err(|e| e.to_string())?;
            }
        }
        let target = unique_path(root, name);
        fs::rename(&partial, &target).map_err(|e| format!("{}: {e}", target.display()))?;
        if let Some(arrived) = &job.arrived_as {
            self.data.clear_deferral(InputKind::Scan, arrived);
        }
        tracing::info!(
            job = job.id,
            shape = %escape_name(name),
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
                // The input is good; the output could not be written (a full disk, a read-only
                // folder): keep it queued and retry, never reject it.
                Err(e) => defer(&self.data, &job, &format!("cannot write the result: {e}")),
            },
            Err(f) => reject_or_defer(&self.data, &job, &f),
        }
    }
}
