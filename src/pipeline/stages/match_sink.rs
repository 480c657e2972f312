//! `match-sink`: writes each matched scan's outputs, commits claimed inputs beside them, and
//! rejects failed inputs with a report.

use std::{fmt::Write as _, fs, path::PathBuf};

use serde::Deserialize;

use crate::{
    limits::escape_name,
    mesh::{coordinate_colors, write_colored_ply},
    pipeline::{
        actor::Sink,
        config::{parse_config, AnyPort, Builder, PortType, StageConfig, StageType},
        error::{Error, IoAt},
        message::{Failure, Job, MatchedShape},
        report::MatchReport,
        store::{defer, is_claimed, move_file, reject_or_defer, unique_path, unix_now, DataDir, InputKind},
    },
};

impl StageConfig for MatchSinkConfig {
    const TYPE: StageType = StageType {
        name: "match-sink",
        ports: (Some(PortType::Map), None),
        parse: parse_config::<MatchSinkConfig>,
    };
    fn build(&self, b: &mut Builder<'_>, input: Option<AnyPort>) -> Result<Option<AnyPort>, Error> {
        let Some(AnyPort::Map(i)) = input else { return Err(b.wrong_input()) };
        let mut c = self.clone();
        c.folder = b.resolve(&c.folder);
        let name = b.stage.name.clone();
        let sink = MatchSink::new(b.data.clone(), c);
        b.pipeline.sink(&name, i, sink);
        Ok(None)
    }
}

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

    /// Where a keyed job's result is recorded: `FOLDER/.keys/KEY` holds the name of its result
    /// folder, which holds the key in `.key` (see [`MatchSink::written_before`]).
    fn key_entry(&self, key: &str) -> PathBuf {
        let safe: String = key
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '_' { c } else { '_' })
            .collect();
        self.config.folder.join(".keys").join(safe)
    }

    /// The result folder of a keyed job written before (a job delivered again by a durable
    /// queue after its result was written but before that was acknowledged).
    fn written_before(&self, key: &str) -> Option<PathBuf> {
        let name = fs::read_to_string(self.key_entry(key)).ok()?;
        let dir = self.config.folder.join(name.trim());
        let theirs = fs::read_to_string(dir.join(".key")).ok()?;
        (theirs == key).then_some(dir)
    }

    /// Writes a result, and on failure leaves nothing behind: the partial folder is removed and
    /// a claimed input that had moved into it goes back to `.inflight/`. A job with a key (a
    /// durable queue's) whose result is already written is not written again.
    fn write(&mut self, job: &Job, m: &MatchedShape) -> Result<PathBuf, Error> {
        if let Some(dir) = job.key.as_deref().and_then(|k| self.written_before(k)) {
            tracing::info!(job = job.id, shape = %escape_name(&job.name), "already written as {}", dir.display());
            return Ok(dir);
        }
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
    ) -> Result<PathBuf, Error> {
        let root = &self.config.folder;
        if let Some(e) = injected_fault() {
            return Err(Error::BadInput(format!("{}: {e} (SHAPEFOREST_FAULT_FILE)", root.display())));
        }
        fs::create_dir_all(root).at(root)?;
        let name = &job.name;
        let partial = partial.to_path_buf();
        if partial.exists() {
            fs::remove_dir_all(&partial).at(&partial)?;
        }
        fs::create_dir_all(&partial).at(&partial)?;
        let model = &m.predicted.model;
        let dense = &m.dense;
        let mesh = m.scan();
        let part_of = m.predicted.shape.partial.as_deref();

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
        fs::write(partial.join(&map_file), text).at(&partial.join(&map_file))?;
        if self.config.colored {
            let ref_mesh = &model.reference.mesh;
            let ref_colors = coordinate_colors(ref_mesh);
            let scan_colors: Vec<[u8; 3]> = dense.map.iter().map(|&r| ref_colors[r]).collect();
            write_colored_ply(partial.join(format!("{name}.colored.ply")), mesh, &scan_colors)?;
            crate::viz::write_snapshot(&partial.join(format!("{name}.png")), mesh, ref_mesh, &dense.map)
                .map_err(Error::BadInput)?;
            let ref_path = root.join(format!("reference-{}.colored.ply", model.reference_name));
            if !ref_path.exists() {
                write_colored_ply(&ref_path, ref_mesh, &ref_colors)?;
            }
        }
        let latency = job.started.elapsed().as_secs_f64();
        let stages: serde_json::Map<String, serde_json::Value> =
            job.stage_seconds.iter().map(|(s, t)| (s.clone(), serde_json::json!(t))).collect();
        let details = serde_json::json!({
            "job": job.id,
            "input": job.arrived_as.clone().unwrap_or_else(|| name.clone()),
            "vertices": mesh.n_vertices(),
            "components": part_of.map_or(1, |p| p.part.components),
            "matched_part_vertices": m.mesh().n_vertices(),
            "holes_closed": part_of.map_or(0, |p| p.holes_closed),
            "normalising_area_ratio": part_of.map_or(1.0, |p| p.scale_ratio),
            "model_version": model.version,
            "reference": model.reference_name,
            "reference_vertices": model.reference.mesh.n_vertices(),
            "map_file": map_file,
            "n_sparse_matches": dense.matches.len(),
            "stage_seconds": stages,
            "latency_s": latency,
            "finished_unix": unix_now(),
        });
        let text = MatchReport::new(dense, &m.predicted.prediction, details).to_json()?;
        let report_path = partial.join(format!("{name}.report.json"));
        fs::write(&report_path, text).at(&report_path)?;
        // Commit: the claimed input moves in beside its result, then the folder gets its name.
        if is_claimed(&self.data, job) {
            if let (Some(src), Some(arrived)) = (&job.source, &job.arrived_as) {
                let marker = partial.join(".input");
                fs::write(&marker, arrived).at(&marker)?;
                for c in &job.companions {
                    if let Some(n) = c.file_name() {
                        move_file(c, &partial.join(n))?;
                    }
                }
                move_file(src, &partial.join(arrived))?;
            }
        }
        let target = unique_path(root, name);
        if let Some(key) = &job.key {
            // The key goes in first: a crash after the rename below leaves a result that a
            // redelivery finds (and does not write twice); one before it, an entry naming a
            // folder that is not there (so the result is written then).
            let marker = partial.join(".key");
            fs::write(&marker, key).at(&marker)?;
            let entry = self.key_entry(key);
            if let Some(d) = entry.parent() {
                fs::create_dir_all(d).at(d)?;
            }
            let target_name =
                target.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            crate::pipeline::atomic_write(&entry, target_name.as_bytes()).at(&entry)?;
        }
        fs::rename(&partial, &target).at(&target)?;
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

    fn consume(&mut self, job: Job, body: Result<MatchedShape, Failure>) -> Result<(), Error> {
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
