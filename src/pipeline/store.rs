//! The daemon's data folder and the file moves that make it restart-safe.
//!
//! ```text
//! shapeforest-data/
//!   incoming/    scans to match (dropped by the user)
//!   labeled/     labelled shapes to learn from: NAME.off (or .obj/.ply/…) with NAME.labels
//!                (one 0-based label per vertex) or NAME.vts (line k = 1-based vertex of label k)
//!   matched/     one folder per matched scan: NAME.map.txt, NAME.colored.ply, NAME.report.json
//!                and the scan itself
//!   rejected/    inputs that could not be used, each with NAME.error.json
//!   models/      model-vNNNNNN.sfm with its manifest model-vNNNNNN.json (newest = live)
//!   training/    the labelled shapes the model has learnt from (as they arrived)
//!   cache/       spectra, keyed by mesh content
//!   .inflight/   inputs claimed by a running job
//! ```
//!
//! An input is always in exactly one place. A source claims a file by renaming it into
//! `.inflight/`; the sink writes a result into `matched/.partial-…/`, moves the input in beside
//! it and renames the folder to its final name — the commit. On start, [`DataDir::recover`]
//! commits partial results that hold their input, deletes those that do not, and returns
//! claimed inputs to `incoming/` and `labeled/`: nothing is lost and nothing is matched twice.

use std::{
    collections::HashMap,
    fs, io,
    path::{Path, PathBuf},
    sync::{Arc, Mutex},
    time::{Duration, Instant},
};

use serde::{Deserialize, Serialize};

use super::{
    error::Error,
    message::{Failure, FailureKind, Job},
};
use crate::{
    forest::RandomForest,
    limits::{escape_name, Limits},
};

/// The folder layout of a daemon (see the module documentation). Clones share the retry
/// schedule of inputs whose outputs could not be written ([`DataDir::defer`]).
#[derive(Clone, Debug)]
pub struct DataDir {
    root: PathBuf,
    retries: Arc<Mutex<HashMap<(InputKind, String), Retry>>>,
}

/// When a deferred input may be taken up again, and how often it was deferred.
#[derive(Clone, Copy, Debug)]
struct Retry {
    not_before: Instant,
    attempts: u32,
}

/// Which kind of input a file is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum InputKind {
    /// A scan to match.
    Scan,
    /// A labelled shape to learn from.
    Labeled,
}

impl InputKind {
    fn folder(self) -> &'static str {
        match self {
            InputKind::Scan => "scans",
            InputKind::Labeled => "labeled",
        }
    }
}

/// What [`DataDir::recover`] did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Recovery {
    /// Results whose commit was interrupted and is now done.
    pub committed: Vec<PathBuf>,
    /// Partial results without their input, deleted (the input is re-matched).
    pub discarded: Vec<PathBuf>,
    /// Claimed inputs returned to `incoming/` or `labeled/`.
    pub requeued: Vec<PathBuf>,
}

impl DataDir {
    /// The layout under `root` (nothing is created).
    pub fn new(root: impl Into<PathBuf>) -> Self {
        Self { root: root.into(), retries: Arc::default() }
    }

    /// Puts a claimed input back into its arrivals folder after its outputs could not be
    /// written (a full disk, a read-only folder): it stays queued, and the watcher takes it up
    /// again after a back-off (1 s, doubling, at most a minute). Returns the path it is back
    /// under and the delay.
    pub fn defer(
        &self,
        kind: InputKind,
        claimed: &Path,
        companions: &[PathBuf],
    ) -> io::Result<(PathBuf, Duration)> {
        let name = file_name(claimed);
        let target = unique_path(&self.arrivals(kind), &name);
        let stem = super::message::shape_stem(&target);
        // Label maps and TOSCA `.tri` files first: the watcher takes the mesh with them.
        for c in companions.iter().filter(|c| c.is_file()) {
            let ext = sidecar_suffix(c);
            move_file(c, &self.arrivals(kind).join(format!("{stem}{ext}")))?;
        }
        move_file(claimed, &target)?;
        let mut retries = self.retries.lock().unwrap_or_else(|p| p.into_inner());
        let entry = retries
            .entry((kind, file_name(&target)))
            .or_insert(Retry { not_before: Instant::now(), attempts: 0 });
        entry.attempts = entry.attempts.saturating_add(1);
        let delay =
            Duration::from_secs(1u64 << entry.attempts.saturating_sub(1).min(6)).min(Duration::from_secs(60));
        entry.not_before = Instant::now() + delay;
        Ok((target, delay))
    }

    /// Whether an arrived file is waiting out a back-off after a deferral.
    pub fn is_deferred(&self, kind: InputKind, name: &str) -> bool {
        let retries = self.retries.lock().unwrap_or_else(|p| p.into_inner());
        retries.get(&(kind, name.to_string())).is_some_and(|r| Instant::now() < r.not_before)
    }

    /// Forgets the back-off of an input whose outputs were written.
    pub fn clear_deferral(&self, kind: InputKind, name: &str) {
        let mut retries = self.retries.lock().unwrap_or_else(|p| p.into_inner());
        retries.remove(&(kind, name.to_string()));
    }

    /// The root folder.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// `incoming/`.
    pub fn incoming(&self) -> PathBuf {
        self.root.join("incoming")
    }

    /// `labeled/`.
    pub fn labeled(&self) -> PathBuf {
        self.root.join("labeled")
    }

    /// `matched/`.
    pub fn matched(&self) -> PathBuf {
        self.root.join("matched")
    }

    /// `rejected/`.
    pub fn rejected(&self) -> PathBuf {
        self.root.join("rejected")
    }

    /// `models/`.
    pub fn models(&self) -> PathBuf {
        self.root.join("models")
    }

    /// `training/`.
    pub fn training(&self) -> PathBuf {
        self.root.join("training")
    }

    /// `cache/`.
    pub fn cache(&self) -> PathBuf {
        self.root.join("cache")
    }

    /// `.inflight/scans` or `.inflight/labeled`.
    pub fn inflight(&self, kind: InputKind) -> PathBuf {
        self.root.join(".inflight").join(kind.folder())
    }

    /// `.inflight/running.json`: present while a daemon runs (see [`crate::pipeline::daemon`]).
    pub fn running_marker(&self) -> PathBuf {
        self.root.join(".inflight").join("running.json")
    }

    /// The folder a kind of input arrives in.
    pub fn arrivals(&self, kind: InputKind) -> PathBuf {
        match kind {
            InputKind::Scan => self.incoming(),
            InputKind::Labeled => self.labeled(),
        }
    }

    /// Creates every folder.
    pub fn create(&self) -> io::Result<()> {
        for d in [
            self.incoming(),
            self.labeled(),
            self.matched(),
            self.rejected(),
            self.models(),
            self.training(),
            self.cache(),
            self.inflight(InputKind::Scan),
            self.inflight(InputKind::Labeled),
        ] {
            fs::create_dir_all(&d).map_err(|e| with_path(e, &d))?;
        }
        Ok(())
    }

    /// Finishes what a crash interrupted (see the module documentation).
    pub fn recover(&self) -> io::Result<Recovery> {
        let mut rec = Recovery::default();
        let matched = self.matched();
        if matched.is_dir() {
            for entry in read_dir_sorted(&matched)? {
                let name = file_name(&entry);
                let Some(partial) = name.strip_prefix(".partial-") else { continue };
                // `.partial-NAME-JOB`: the sink appends the job number.
                let final_name = match partial.rsplit_once('-') {
                    Some((n, id)) if !n.is_empty() && id.bytes().all(|b| b.is_ascii_digit()) => n,
                    _ => partial,
                };
                let input = fs::read_to_string(entry.join(".input")).ok().map(|s| s.trim().to_string());
                match input.filter(|i| !i.is_empty() && entry.join(i).is_file()) {
                    Some(_) => {
                        let target = unique_path(&matched, final_name);
                        fs::rename(&entry, &target).map_err(|e| with_path(e, &entry))?;
                        rec.committed.push(target);
                    }
                    None => {
                        fs::remove_dir_all(&entry).map_err(|e| with_path(e, &entry))?;
                        rec.discarded.push(entry);
                    }
                }
            }
        }
        for kind in [InputKind::Scan, InputKind::Labeled] {
            let dir = self.inflight(kind);
            if !dir.is_dir() {
                continue;
            }
            for entry in read_dir_sorted(&dir)? {
                // Files and links (a link is moved, never followed); not folders.
                if fs::symlink_metadata(&entry).map_or(true, |m| m.is_dir()) {
                    continue;
                }
                let target = unique_path(&self.arrivals(kind), &file_name(&entry));
                move_file(&entry, &target)?;
                rec.requeued.push(target);
            }
        }
        Ok(rec)
    }
}

fn with_path(e: io::Error, path: &Path) -> io::Error {
    io::Error::new(e.kind(), format!("{}: {e}", path.display()))
}

fn file_name(p: &Path) -> String {
    p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
}

/// The entries of a folder, sorted by name.
pub fn read_dir_sorted(dir: &Path) -> io::Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> =
        fs::read_dir(dir).map_err(|e| with_path(e, dir))?.filter_map(|e| e.ok().map(|e| e.path())).collect();
    v.sort();
    Ok(v)
}

/// Whether a file name looks like a mesh shapeforest reads (`.off .obj .ply .vert`, point clouds
/// `.xyz`, also `.gz`).
///
/// ```
/// use std::path::Path;
/// use shapeforest::pipeline::is_mesh_file;
/// assert!(is_mesh_file(Path::new("a/cat0.off")));
/// assert!(is_mesh_file(Path::new("b.PLY")));
/// assert!(is_mesh_file(Path::new("c.off.gz")));
/// assert!(is_mesh_file(Path::new("scan.xyz")));
/// assert!(!is_mesh_file(Path::new("cat0.labels")));
/// assert!(!is_mesh_file(Path::new(".cat0.off.part")));
/// ```
pub fn is_mesh_file(path: &Path) -> bool {
    let name = file_name(path).to_ascii_lowercase();
    if name.starts_with('.') {
        return false;
    }
    let name = name.strip_suffix(".gz").unwrap_or(&name);
    [".off", ".obj", ".ply", ".vert", ".xyz"].iter().any(|e| name.ends_with(e))
}

/// Whether a file is something being written or an editor's or copier's own (hidden dot-files
/// such as rsync's `.NAME.XXXXXX`, `*.part`, `*.partial`, `*.tmp`, `*.crdownload`, `*~`): a
/// watcher leaves it alone until it is renamed to its final name.
///
/// ```
/// use std::path::Path;
/// use shapeforest::pipeline::is_transient_file;
/// assert!(is_transient_file(Path::new("in/.scan.off.Xa81Z")));
/// assert!(is_transient_file(Path::new("in/scan.off.part")));
/// assert!(!is_transient_file(Path::new("in/scan.off")));
/// ```
pub fn is_transient_file(path: &Path) -> bool {
    let name = file_name(path).to_ascii_lowercase();
    name.starts_with('.')
        || name.ends_with('~')
        || [".part", ".partial", ".tmp", ".crdownload", ".download", ".swp"].iter().any(|e| name.ends_with(e))
}

/// Whether a file is a `NAME.sym.vts` (any case): the left/right mirror of every row of
/// `NAME.vts` (row `k`: the 1-based vertex at the mirror image of row `k`'s), which travels with
/// the mesh `NAME` and its `NAME.vts` and gives a reference its symmetry.
///
/// ```
/// use std::path::Path;
/// use shapeforest::pipeline::is_symmetry_file;
/// assert!(is_symmetry_file(Path::new("labeled/cat0.sym.vts")));
/// assert!(!is_symmetry_file(Path::new("labeled/cat0.vts")));
/// ```
pub fn is_symmetry_file(path: &Path) -> bool {
    file_name(path).to_ascii_lowercase().ends_with(".sym.vts")
}

/// The stem of the shape a sidecar file belongs to: `NAME` for `NAME.sym.vts`, else
/// [`shape_stem`](super::message::shape_stem) (`NAME` for `NAME.vts`, `NAME.tri`, …).
pub fn sidecar_stem(path: &Path) -> String {
    let name = file_name(path);
    if is_symmetry_file(path) {
        return name[..name.len() - ".sym.vts".len()].to_string();
    }
    super::message::shape_stem(path)
}

/// The part of a sidecar's file name after its shape's stem (`.vts`, `.labels`, `.tri`,
/// `.sym.vts`): the name it takes beside a renamed mesh is the new stem followed by it.
pub fn sidecar_suffix(path: &Path) -> String {
    let name = file_name(path);
    name.strip_prefix(&sidecar_stem(path)).unwrap_or("").to_string()
}

/// The `NAME.sym.vts` beside a mesh `NAME.*`, if there is one.
pub fn symmetry_sidecar(mesh: &Path) -> Option<PathBuf> {
    let dir = mesh.parent().unwrap_or(Path::new("."));
    let p = dir.join(format!("{}.sym.vts", super::message::shape_stem(mesh)));
    p.is_file().then_some(p)
}

/// The label map that goes with a mesh: `NAME.labels` (per vertex) or `NAME.vts` (per label),
/// next to it.
pub fn label_sidecar(mesh: &Path) -> Option<PathBuf> {
    let dir = mesh.parent().unwrap_or(Path::new("."));
    let stem = super::message::shape_stem(mesh);
    ["labels", "vts"].iter().map(|ext| dir.join(format!("{stem}.{ext}"))).find(|p| p.is_file())
}

/// Reads a label map for a mesh of `n_vertices`: `.vts` files are per-label and 1-based (line
/// `k` = the vertex carrying label `k`); anything else is per-vertex and 0-based (line `i` = the
/// label of vertex `i`; `-1` or `none` for an unlabelled vertex). The file must be a regular
/// file (links are not followed) within `limits.max_file_bytes`, and every label below
/// `limits.max_labels`. Errors name the file and line.
pub fn read_labels(path: &Path, n_vertices: usize, limits: &Limits) -> Result<Vec<Option<u32>>, Error> {
    let bytes = crate::mesh::read_file_limited(path, limits.max_file_bytes, false)?;
    let per_label = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("vts"));
    let max_labels = limits.max_labels.min(u32::MAX as usize);
    let labels = if per_label {
        crate::forest::read_per_label_map(bytes.as_slice(), true, n_vertices)
    } else {
        crate::forest::read_label_map(bytes.as_slice(), false, max_labels)
    }
    .map_err(|e| {
        Error::BadInput(match e {
            crate::forest::ForestError::LabelMap { line, reason }
                if reason.contains("outside the label set") =>
            {
                format!("{}: line {line}: {reason} (limits.max_labels)", path.display())
            }
            e => format!("{}: {e}", path.display()),
        })
    })?;
    if labels.len() != n_vertices {
        return Err(Error::BadInput(format!(
            "{}: {} labels for a mesh of {n_vertices} vertices (one line per vertex expected)",
            path.display(),
            labels.len()
        )));
    }
    let labelled = labels.iter().flatten().count();
    if labelled == 0 {
        return Err(Error::BadInput(format!("{}: no vertex has a label", path.display())));
    }
    if let Some(&top) = labels.iter().flatten().max() {
        if top as usize >= max_labels {
            return Err(Error::BadInput(format!(
                "{}: label {top} is outside the label set of {max_labels} (limits.max_labels)",
                path.display()
            )));
        }
        if per_label && labelled * 2 < top as usize + 1 {
            tracing::warn!(
                file = %path.display(),
                "{} of {} labels landed on a vertex of their own (several labels name one vertex)",
                labelled,
                top + 1
            );
        }
    }
    Ok(labels)
}

/// The text of a per-vertex label map as [`read_labels`] reads it: line `v` holds vertex `v`'s
/// label, `-1` for an unlabelled vertex.
///
/// ```
/// use shapeforest::pipeline::label_map_text;
/// assert_eq!(label_map_text(&[Some(2), None, Some(0)]), "2\n-1\n0\n");
/// ```
pub fn label_map_text(labels: &[Option<u32>]) -> String {
    use std::fmt::Write as _;
    let mut text = String::with_capacity(labels.len() * 6);
    for l in labels {
        let _ = match l {
            Some(l) => writeln!(text, "{l}"),
            None => writeln!(text, "-1"),
        };
    }
    text
}

/// Writes a file atomically (a temporary file in the same folder, synced, then renamed); the
/// error names the file.
pub fn atomic_write(path: &Path, bytes: &[u8]) -> io::Result<()> {
    crate::fsutil::write_atomic(path, bytes).map_err(|e| with_path(e, path))
}

/// Moves a file (a rename; a copy and delete across file systems).
pub fn move_file(from: &Path, to: &Path) -> io::Result<()> {
    match fs::rename(from, to) {
        Ok(()) => Ok(()),
        Err(_) if from.is_file() => {
            fs::copy(from, to).map_err(|e| with_path(e, from))?;
            fs::remove_file(from).map_err(|e| with_path(e, from))
        }
        Err(e) => Err(with_path(e, from)),
    }
}

/// `dir/name`, or `dir/name-2`, `dir/name-3`, … (before the extensions) if taken.
///
/// ```
/// let d = tempfile::tempdir().unwrap();
/// std::fs::write(d.path().join("a.off"), "").unwrap();
/// let p = shapeforest::pipeline::unique_path(d.path(), "a.off");
/// assert_eq!(p.file_name().unwrap(), "a-2.off");
/// ```
pub fn unique_path(dir: &Path, name: &str) -> PathBuf {
    let first = dir.join(name);
    if !first.exists() {
        return first;
    }
    let (stem, ext) = match name.find('.') {
        Some(i) if i > 0 => (&name[..i], &name[i..]),
        _ => (name, ""),
    };
    (2..).map(|i| dir.join(format!("{stem}-{i}{ext}"))).find(|p| !p.exists()).unwrap_or(first)
}

/// What a model file was made from, written beside it as `model-vNNNNNN.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelManifest {
    /// Model version.
    pub version: u64,
    /// File name of the model, in the same folder.
    pub model_file: String,
    /// Seconds since the Unix epoch when it was saved.
    pub created_unix: u64,
    /// The reference shape (a name in `training/`).
    pub reference: String,
    /// Training shapes (names in `training/`).
    pub training_shapes: Vec<String>,
    /// Labels.
    pub n_labels: usize,
    /// Trees.
    pub n_trees: usize,
    /// Eigenpairs the forest uses.
    pub k: usize,
}

/// Saves a model version atomically: the model file, then its manifest (the manifest's presence
/// marks a complete version). Returns the model's path.
pub fn save_model_version(
    dir: &Path,
    forest: &RandomForest,
    manifest: &ModelManifest,
) -> Result<PathBuf, Error> {
    fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let path = dir.join(&manifest.model_file);
    forest.save(&path)?;
    let json = serde_json::to_string_pretty(manifest)? + "\n";
    let mpath = dir.join(format!("model-v{:06}.json", manifest.version));
    atomic_write(&mpath, json.as_bytes())?;
    Ok(path)
}

/// The manifests in `dir` that parse, newest first, with the problems met on the way.
fn manifests_newest_first(dir: &Path) -> (Vec<ModelManifest>, Vec<String>) {
    let mut problems = Vec::new();
    let Ok(entries) = read_dir_sorted(dir) else { return (Vec::new(), problems) };
    let mut found = Vec::new();
    for m in entries.iter().rev() {
        let n = file_name(m);
        if !(n.starts_with("model-v") && n.ends_with(".json")) {
            continue;
        }
        match fs::read_to_string(m)
            .map_err(|e| e.to_string())
            .and_then(|t| serde_json::from_str::<ModelManifest>(&t).map_err(|e| e.to_string()))
        {
            Ok(x) => found.push(x),
            Err(e) => problems.push(format!("{}: {e}", m.display())),
        }
    }
    (found, problems)
}

/// The newest model manifest in `dir` that parses (the model file itself is not read).
pub fn latest_manifest(dir: &Path) -> Option<ModelManifest> {
    manifests_newest_first(dir).0.into_iter().next()
}

/// The newest complete model version in `dir` that loads, with the problems met on the way
/// (unreadable manifests or models are skipped, newest first), under the default limits.
pub fn latest_model(dir: &Path) -> (Option<(ModelManifest, RandomForest)>, Vec<String>) {
    newest_model_that(dir, &Limits::default(), |m, f| Ok((m, f)))
}

/// Whether a manifest's `model_file` is a plain file name inside the models folder (no folder
/// part, no `..`, not hidden, ending in `.sfm`): a manifest never makes the daemon load a file
/// from elsewhere.
///
/// ```
/// use shapeforest::pipeline::store::is_model_file_name;
/// assert!(is_model_file_name("model-v000003.sfm"));
/// assert!(!is_model_file_name("../../../x.sfm"));
/// assert!(!is_model_file_name("/tmp/x.sfm"));
/// ```
pub fn is_model_file_name(name: &str) -> bool {
    !name.starts_with('.')
        && name.ends_with(".sfm")
        && !name.contains(['/', '\\', '\0'])
        && Path::new(name).file_name().is_some_and(|n| n == name)
}

/// The newest model version in `dir` that loads within `limits` and that `serve` accepts
/// (`serve` turns it into what the caller needs, or says why it cannot serve), with the
/// problems met on the way, newest first: unreadable manifests, a `model_file` outside the
/// folder, files over `limits.max_model_bytes`, corrupt files, dimensions over the limits, and
/// the reasons `serve` gave.
pub fn newest_model_that<T>(
    dir: &Path,
    limits: &Limits,
    mut serve: impl FnMut(ModelManifest, RandomForest) -> Result<T, String>,
) -> (Option<T>, Vec<String>) {
    let (manifests, mut problems) = manifests_newest_first(dir);
    for manifest in manifests {
        let mpath = dir.join(format!("model-v{:06}.json", manifest.version));
        if !is_model_file_name(&manifest.model_file) {
            problems.push(format!(
                "{}: model_file {:?} is not a file name inside {}",
                mpath.display(),
                crate::limits::escape_name(&manifest.model_file),
                dir.display()
            ));
            continue;
        }
        let path = dir.join(&manifest.model_file);
        match fs::symlink_metadata(&path) {
            Ok(m) if !m.is_file() => {
                problems.push(format!("{}: not a regular file", path.display()));
                continue;
            }
            Ok(m) if m.len() > limits.max_model_bytes => {
                problems.push(format!(
                    "{}: {} bytes, more than limits.max_model_bytes = {}",
                    path.display(),
                    m.len(),
                    limits.max_model_bytes
                ));
                continue;
            }
            _ => {}
        }
        let version = manifest.version;
        match RandomForest::load(&path) {
            Ok(f) => match limits.check_model(&f) {
                Ok(()) => match serve(manifest, f) {
                    Ok(t) => return (Some(t), problems),
                    Err(e) => problems.push(format!("model v{version} cannot serve: {e}")),
                },
                Err(e) => problems.push(format!("{}: {e}", path.display())),
            },
            Err(e) => problems.push(e.to_string()),
        }
    }
    (None, problems)
}

/// Deletes all but the newest `keep` model versions.
pub fn prune_models(dir: &Path, keep: usize) {
    let Ok(entries) = read_dir_sorted(dir) else { return };
    let mut versions: Vec<String> = entries
        .iter()
        .map(|p| file_name(p))
        .filter(|n| n.starts_with("model-v") && n.ends_with(".json"))
        .map(|n| n.trim_end_matches(".json").to_string())
        .collect();
    versions.sort();
    let n = versions.len().saturating_sub(keep);
    for stem in &versions[..n] {
        let _ = fs::remove_file(dir.join(format!("{stem}.json")));
        let _ = fs::remove_file(dir.join(format!("{stem}.sfm")));
    }
}

/// A training shape stored in `training/`: its mesh file and label map.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StoredShape {
    /// Name (the mesh file's stem).
    pub name: String,
    /// Mesh file.
    pub mesh: PathBuf,
    /// Label map.
    pub labels: PathBuf,
}

/// The shapes in a `training/` folder, by name.
pub fn stored_shapes(dir: &Path) -> Vec<StoredShape> {
    let Ok(entries) = read_dir_sorted(dir) else { return Vec::new() };
    entries
        .into_iter()
        .filter(|p| p.is_file() && is_mesh_file(p))
        .filter_map(|mesh| {
            let labels = label_sidecar(&mesh)?;
            Some(StoredShape { name: super::message::shape_stem(&mesh), mesh, labels })
        })
        .collect()
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

/// Seconds since the Unix epoch.
pub fn unix_now() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs())
}

/// Whether a job's input was claimed into the data folder's `.inflight/` (by a watcher).
pub fn is_claimed(data: &DataDir, job: &Job) -> bool {
    job.source.as_ref().is_some_and(|s| {
        s.starts_with(data.inflight(InputKind::Scan)) || s.starts_with(data.inflight(InputKind::Labeled))
    })
}

/// Handles a failed job (the rejection every sink shares): an interrupted one is left claimed (it is taken up again at the next
/// start); any other has its report written to `rejected/NAME.error.json` first, then its
/// claimed files (input, label map, companions) move to `rejected/` beside it — so an input is
/// never in `rejected/` without its report. An input named like a report (`*.error.json`)
/// gets `.input` appended, so that it cannot pass for one. Returns the report's path.
pub fn reject(data: &DataDir, job: &Job, failure: &Failure) -> Result<Option<PathBuf>, Error> {
    if failure.kind == FailureKind::Interrupted {
        tracing::info!(job = job.id, shape = %escape_name(&job.name), "interrupted; the input is taken up again at the next start");
        return Ok(None);
    }
    let dir = data.rejected();
    fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
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
    let text = serde_json::to_string_pretty(&report)? + "\n";
    atomic_write(&path, text.as_bytes())?;
    for (from, to) in &moves {
        move_file(from, to)?;
    }
    tracing::warn!(job = job.id, shape = %escape_name(&job.name), report = %path.display(), "rejected: {failure}");
    Ok(Some(path))
}

/// [`reject`], and when the report cannot be written (a full disk, a read-only folder) the
/// input is deferred instead: it goes back to its arrivals folder and is retried after a
/// back-off. Bad input is never lost because the disk was full.
pub fn reject_or_defer(data: &DataDir, job: &Job, failure: &Failure) -> Result<(), Error> {
    match reject(data, job, failure) {
        Ok(_) => Ok(()),
        Err(e) => defer(data, job, &format!("cannot write its rejection report: {e}")),
    }
}

/// Puts a claimed job's input back into its arrivals folder for a later retry (see
/// [`DataDir::defer`]), logging the cause. Unclaimed inputs (batch runs read in place) are left
/// where they are.
pub fn defer(data: &DataDir, job: &Job, cause: &str) -> Result<(), Error> {
    let Some(src) = job.source.as_ref().filter(|_| is_claimed(data, job)) else {
        return Err(Error::BadInput(cause.to_string()));
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
        Err(e) => Err(Error::BadInput(format!(
            "{cause}; and it could not be put back ({e}): it is taken up at the next start"
        ))),
    }
}
