//! Sources: a folder listed once (`folder`), a watched folder (`watch-folder`, the daemon's
//! input) and the built-in synthetic class (`synthetic`).

use std::{
    collections::HashMap,
    fs,
    path::{Path, PathBuf},
    sync::Arc,
    time::{Duration, Instant, SystemTime},
};

use serde::Deserialize;

use crate::{
    forest::labels_identity,
    pipeline::{
        actor::{Emitter, Source},
        message::{shape_stem, Envelope, Failure, InputFile, Job, Shape},
        store::{
            is_mesh_file, is_transient_file, label_sidecar, move_file, read_dir_sorted, unique_path, DataDir,
            InputKind,
        },
    },
    synth::{creature_family, CreatureParams},
};

/// How a folder source finds the labels of its shapes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Labels {
    /// Scans: no labels.
    #[default]
    None,
    /// A sidecar per mesh: `NAME.labels` (per vertex) or `NAME.vts` (per label, 1-based).
    Sidecar,
    /// Label = vertex index (classes sharing one vertex indexing, e.g. TOSCA, SCAPE).
    Identity,
}

/// Settings of a `folder` source.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FolderConfig {
    /// The folder (relative paths are taken from the pipeline's data folder).
    pub folder: PathBuf,
    /// Only meshes whose name starts with this.
    #[serde(default)]
    pub prefix: Option<String>,
    /// Only these shapes (file stems), in this order.
    #[serde(default)]
    pub names: Option<Vec<String>>,
    /// Skip this many meshes (after sorting by name, numbers in names compared as numbers).
    #[serde(default)]
    pub skip: usize,
    /// At most this many meshes.
    #[serde(default)]
    pub take: Option<usize>,
    /// Where the labels come from.
    #[serde(default)]
    pub labels: Labels,
}

/// `a2` < `a10`: names compared with their digit runs as numbers.
pub fn natural_key(name: &str) -> Vec<(String, u64)> {
    let mut out = Vec::new();
    let mut text = String::new();
    let mut chars = name.chars().peekable();
    while let Some(&c) = chars.peek() {
        if c.is_ascii_digit() {
            let mut n = 0u64;
            while let Some(&d) = chars.peek() {
                let Some(v) = d.to_digit(10) else { break };
                n = n.saturating_mul(10).saturating_add(v as u64);
                chars.next();
            }
            out.push((std::mem::take(&mut text), n));
        } else {
            text.push(c);
            chars.next();
        }
    }
    out.push((text, u64::MAX));
    out
}

/// Lists a folder once and emits its meshes.
pub struct FolderSource {
    config: FolderConfig,
}

impl FolderSource {
    /// A folder source; `config.folder` must already be resolved.
    pub fn new(config: FolderConfig) -> Self {
        Self { config }
    }

    /// The meshes it will emit, in order.
    pub fn files(&self) -> Result<Vec<PathBuf>, String> {
        let c = &self.config;
        let entries = read_dir_sorted(&c.folder).map_err(|e| format!("cannot list the folder: {e}"))?;
        let mut files: Vec<PathBuf> = entries
            .into_iter()
            .filter(|p| p.is_file() && is_mesh_file(p))
            .filter(|p| c.prefix.as_ref().is_none_or(|pre| shape_stem(p).starts_with(pre.as_str())))
            .collect();
        files.sort_by_key(|p| natural_key(&shape_stem(p)));
        if let Some(names) = &c.names {
            let mut chosen = Vec::new();
            for n in names {
                match files.iter().find(|p| &shape_stem(p) == n) {
                    Some(p) => chosen.push(p.clone()),
                    None => return Err(format!("no mesh named `{n}` in {}", c.folder.display())),
                }
            }
            files = chosen;
        }
        let files: Vec<PathBuf> = files.into_iter().skip(c.skip).take(c.take.unwrap_or(usize::MAX)).collect();
        if files.is_empty() {
            return Err(format!(
                "no mesh files (.off .obj .ply .vert, optionally .gz) in {}",
                c.folder.display()
            ));
        }
        Ok(files)
    }
}

impl Source for FolderSource {
    type Out = InputFile;

    fn run(&mut self, out: &Emitter<InputFile>) -> Result<(), String> {
        for path in self.files()? {
            let labels = match self.config.labels {
                Labels::None => None,
                Labels::Identity => Some(LabelSpec::Identity),
                Labels::Sidecar => label_sidecar(&path).map(LabelSpec::File),
            };
            let mut job = Job::for_file(out.next_job_id(), &path, None);
            let body = match (&self.config.labels, labels) {
                (Labels::Sidecar, None) => Err(Failure::bad_input(
                    "source",
                    format!("{}: no label map beside it (NAME.labels or NAME.vts)", path.display()),
                )),
                (_, labels) => {
                    if let Some(LabelSpec::File(f)) = &labels {
                        job.labels_file = Some(f.clone());
                    }
                    Ok(InputFile { path, labels })
                }
            };
            if !out.emit(Envelope { job, body }) {
                break;
            }
        }
        Ok(())
    }
}

pub use crate::pipeline::message::LabelSpec;

/// Settings of a `watch-folder` source.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WatchConfig {
    /// What arrives: `scan` (in `incoming/`) or `labeled` (in `labeled/`, with label maps).
    #[serde(default = "default_kind")]
    pub kind: WatchKind,
    /// A file counts as complete once its size and modification time have not changed for
    /// this long (milliseconds). Default 500.
    #[serde(default = "default_settle")]
    pub settle_ms: u64,
    /// Full rescans of the folder, in milliseconds, behind the file-system events. Default 2000.
    #[serde(default = "default_rescan")]
    pub rescan_ms: u64,
    /// Stop once the folder is empty (for batch runs and tests). Default false.
    #[serde(default)]
    pub exit_when_empty: bool,
}

fn default_kind() -> WatchKind {
    WatchKind::Scan
}
fn default_settle() -> u64 {
    500
}
fn default_rescan() -> u64 {
    2000
}

/// What a watched folder receives.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum WatchKind {
    /// Scans, in `incoming/`.
    Scan,
    /// Labelled shapes, in `labeled/`.
    Labeled,
}

impl From<WatchKind> for InputKind {
    fn from(k: WatchKind) -> Self {
        match k {
            WatchKind::Scan => InputKind::Scan,
            WatchKind::Labeled => InputKind::Labeled,
        }
    }
}

/// What a watcher last saw of a file.
struct Seen {
    size: u64,
    modified: Option<SystemTime>,
    since: Instant,
    warned: bool,
}

/// Watches a folder of the data directory (`notify` events, debounced, plus periodic rescans),
/// claims each complete file into `.inflight/` and emits it.
pub struct WatchSource {
    data: DataDir,
    config: WatchConfig,
}

impl WatchSource {
    /// A watcher over `data`'s `incoming/` or `labeled/`.
    pub fn new(data: DataDir, config: WatchConfig) -> Self {
        Self { data, config }
    }

    fn kind(&self) -> InputKind {
        self.config.kind.into()
    }

    /// Moves `path` (and its label map) into `.inflight/`, keeping the pair's stems equal.
    fn claim(&self, path: &Path, labels: Option<&Path>) -> std::io::Result<(PathBuf, Option<PathBuf>)> {
        let dir = self.data.inflight(self.kind());
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let target = unique_path(&dir, &name);
        let labels_target = labels.map(|l| {
            let ext = l.extension().map(|e| e.to_string_lossy().into_owned()).unwrap_or_default();
            dir.join(format!("{}.{ext}", shape_stem(&target)))
        });
        if let (Some(l), Some(t)) = (labels, &labels_target) {
            move_file(l, t)?;
        }
        move_file(path, &target)?;
        Ok((target, labels_target))
    }

    /// Files of the folder that have been stable for the settle time, oldest observation first.
    fn ready(&self, seen: &mut HashMap<PathBuf, Seen>) -> Vec<PathBuf> {
        let settle = Duration::from_millis(self.config.settle_ms);
        let dir = self.data.arrivals(self.kind());
        let Ok(entries) = read_dir_sorted(&dir) else { return Vec::new() };
        let mut present = std::collections::HashSet::new();
        let mut ready = Vec::new();
        for p in entries {
            if is_transient_file(&p) {
                continue;
            }
            let Ok(meta) = fs::metadata(&p) else { continue };
            if !meta.is_file() {
                continue;
            }
            present.insert(p.clone());
            let (size, modified) = (meta.len(), meta.modified().ok());
            let now = Instant::now();
            let e = seen.entry(p.clone()).or_insert(Seen { size, modified, since: now, warned: false });
            if e.size != size || e.modified != modified {
                *e = Seen { size, modified, since: now, warned: false };
                continue;
            }
            if now.duration_since(e.since) >= settle {
                ready.push(p);
            }
        }
        seen.retain(|p, _| present.contains(p));
        ready.sort_by_key(|p| seen.get(p).map(|s| s.since));
        ready
    }
}

impl Source for WatchSource {
    type Out = InputFile;

    fn run(&mut self, out: &Emitter<InputFile>) -> Result<(), String> {
        use notify::RecursiveMode;
        let dir = self.data.arrivals(self.kind());
        fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        let (tx, rx) = flume::unbounded();
        let mut debouncer =
            notify_debouncer_full::new_debouncer(Duration::from_millis(200), None, move |ev| {
                let _ = tx.send(ev);
            })
            .map_err(|e| format!("cannot watch {}: {e}", dir.display()))?;
        debouncer
            .watch(&dir, RecursiveMode::NonRecursive)
            .map_err(|e| format!("cannot watch {}: {e}", dir.display()))?;
        tracing::info!(folder = %dir.display(), "watching");
        let mut seen: HashMap<PathBuf, Seen> = HashMap::new();
        let rescan = Duration::from_millis(self.config.rescan_ms.max(50));
        let tick = Duration::from_millis((self.config.settle_ms / 4).clamp(20, 250));
        let mut last_scan = Instant::now() - rescan;
        let mut dirty = true;
        loop {
            if out.shutdown().is_triggered() {
                return Ok(());
            }
            // Events only say "look again"; the folder listing is the truth.
            while let Ok(ev) = rx.try_recv() {
                if let Err(errs) = ev {
                    for e in errs {
                        tracing::warn!(folder = %dir.display(), "watch error: {e}");
                    }
                }
                dirty = true;
            }
            let pending = !seen.is_empty();
            if dirty || pending || last_scan.elapsed() >= rescan {
                last_scan = Instant::now();
                dirty = false;
                let ready = self.ready(&mut seen);
                for path in ready {
                    if out.shutdown().is_triggered() {
                        return Ok(());
                    }
                    if !self.offer(&path, &mut seen, out) {
                        return Ok(());
                    }
                }
                if self.config.exit_when_empty && seen.is_empty() {
                    return Ok(());
                }
            }
            if out.shutdown().sleep(tick) {
                return Ok(());
            }
        }
    }
}

impl WatchSource {
    /// Claims and emits one stable file; returns `false` when the pipeline no longer takes jobs.
    fn offer(&self, path: &Path, seen: &mut HashMap<PathBuf, Seen>, out: &Emitter<InputFile>) -> bool {
        let kind = self.kind();
        let is_mesh = is_mesh_file(path);
        let labels = if kind == InputKind::Labeled && is_mesh { label_sidecar(path) } else { None };
        match (kind, is_mesh) {
            (InputKind::Labeled, false) => return true, // label maps travel with their mesh
            (InputKind::Labeled, true) if labels.is_none() => {
                if let Some(s) = seen.get_mut(path) {
                    if !s.warned && s.since.elapsed() > Duration::from_secs(5) {
                        tracing::warn!(file = %path.display(), "waiting for its label map (NAME.labels or NAME.vts)");
                        s.warned = true;
                    }
                }
                return true;
            }
            (InputKind::Labeled, true) => {
                // The label map must be complete too.
                if let Some(l) = &labels {
                    match seen.get(l) {
                        Some(s) if s.since.elapsed() >= Duration::from_millis(self.config.settle_ms) => {}
                        _ => return true,
                    }
                }
            }
            _ => {}
        }
        let claimed = match self.claim(path, labels.as_deref()) {
            Ok(c) => c,
            Err(e) => {
                // Gone meanwhile, or not ours to move: look again at the next scan.
                tracing::debug!(file = %path.display(), "cannot claim: {e}");
                return true;
            }
        };
        seen.remove(path);
        if let Some(l) = &labels {
            seen.remove(l);
        }
        let (claimed_path, claimed_labels) = claimed;
        let mut job = Job::for_file(out.next_job_id(), &claimed_path, claimed_labels.clone());
        job.arrived_as = path.file_name().map(|n| n.to_string_lossy().into_owned());
        job.name = shape_stem(&claimed_path);
        let body = if is_mesh {
            Ok(InputFile { path: claimed_path, labels: claimed_labels.map(LabelSpec::File) })
        } else {
            Err(Failure::bad_input(
                "source",
                format!(
                    "{} is not a mesh file shapeforest reads (.off .obj .ply .vert, optionally .gz)",
                    path.display()
                ),
            ))
        };
        tracing::info!(job = job.id, file = %path.display(), "claimed");
        out.emit(Envelope { job, body })
    }
}

/// Settings of a `synthetic` source: shapes of the built-in creature family, with their labels
/// (label = vertex index of the family's template).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SyntheticConfig {
    /// Vertices per shape. Default 5000.
    #[serde(default = "default_vertices")]
    pub vertices: usize,
    /// Seed of the family. Default 1.
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// Index of the first shape emitted. Default 0.
    #[serde(default)]
    pub first: usize,
    /// Shapes emitted. Default 6.
    #[serde(default = "default_count")]
    pub count: usize,
}

fn default_vertices() -> usize {
    5000
}
fn default_seed() -> u64 {
    1
}
fn default_count() -> usize {
    6
}

/// Emits shapes of the synthetic creature family with their labels.
pub struct SyntheticSource {
    config: SyntheticConfig,
}

impl SyntheticSource {
    /// A synthetic source.
    pub fn new(config: SyntheticConfig) -> Self {
        Self { config }
    }
}

impl Source for SyntheticSource {
    type Out = Shape;

    fn run(&mut self, out: &Emitter<Shape>) -> Result<(), String> {
        let c = &self.config;
        let fam = creature_family(
            &CreatureParams { target_vertices: c.vertices, seed: c.seed, ..Default::default() },
            c.first + c.count,
        )
        .map_err(|e| format!("cannot build the synthetic family: {e}"))?;
        let labels = Arc::new(labels_identity(fam.template.n_vertices()));
        for (i, mesh) in fam.shapes.into_iter().enumerate().skip(c.first) {
            let job = Job::generated(out.next_job_id(), format!("creature{i}"));
            let shape = Shape { mesh: Arc::new(mesh), labels: Some(labels.clone()) };
            if !out.emit(Envelope { job, body: Ok(shape) }) {
                break;
            }
        }
        Ok(())
    }
}
