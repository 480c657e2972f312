//! `watch-folder`: the daemon's input. Watches `incoming/` (scans) or `labeled/` (labelled
//! shapes) of the data folder and claims each complete file into `.inflight/`.

use std::{
    collections::HashMap,
    fs,
    path::{Path, PathBuf},
    time::{Duration, SystemTime},
};

use serde::Deserialize;
// tokio's clock (the system clock outside tests): the settle logic can be tested with a paused
// clock.
use tokio::time::Instant;

use crate::{
    limits::escape_name,
    pipeline::{
        actor::{Emitter, Source},
        config::{parse_config, AnyPort, Builder, PortType, StageConfig, StageType},
        error::{Error, IoAt},
        message::{shape_stem, Envelope, Failure, InputFile, Job, LabelSpec},
        store::{
            is_mesh_file, is_symmetry_file, is_transient_file, label_sidecar, move_file, read_dir_sorted,
            sidecar_stem, sidecar_suffix, symmetry_sidecar, unique_path, DataDir, InputKind,
        },
    },
};

impl StageConfig for WatchConfig {
    const TYPE: StageType = StageType {
        name: "watch-folder",
        ports: (None, Some(PortType::File)),
        parse: parse_config::<WatchConfig>,
    };
    fn build(&self, b: &mut Builder<'_>, input: Option<AnyPort>) -> Result<Option<AnyPort>, Error> {
        if input.is_some() {
            return Err(b.wrong_input());
        }
        let name = b.stage.name.clone();
        let source = WatchSource::new(b.data.clone(), self.clone());
        Ok(Some(AnyPort::File(b.pipeline.source(&name, source))))
    }
}

/// Settings of a `watch-folder` source.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WatchConfig {
    /// What arrives: `scan` (in `incoming/`) or `labeled` (in `labeled/`, with label maps).
    #[serde(default = "default_kind")]
    pub kind: WatchKind,
    /// A file counts as complete once its size and modification time have not changed for
    /// this long (milliseconds) and no process holds it open for writing. Default 2000 (a
    /// writer that closes the file between pieces may pause that long).
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
    2000
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

/// Files a watcher leaves alone, each logged once (so nothing is ignored without a word).
#[derive(Default)]
struct Noted {
    first_seen: HashMap<PathBuf, Instant>,
    logged: std::collections::HashSet<PathBuf>,
}

impl Noted {
    /// Logs `why` about `path` once, after it has been there for `after`.
    fn note(&mut self, path: &Path, after: Duration, why: &str) {
        let since = *self.first_seen.entry(path.to_path_buf()).or_insert_with(Instant::now);
        if since.elapsed() >= after && self.logged.insert(path.to_path_buf()) {
            tracing::warn!(file = %escape_name(&path.display().to_string()), "left alone: {why}");
        }
    }

    fn retain(&mut self, present: &std::collections::HashSet<PathBuf>) {
        self.first_seen.retain(|p, _| present.contains(p));
        self.logged.retain(|p| present.contains(p));
    }
}

/// How long a file nobody will take is left before the watcher says so.
const NOTE_AFTER: Duration = Duration::from_secs(5);

/// What a scan of the watched folder found.
#[derive(Default)]
struct Scan {
    /// Regular files stable for the settle time, oldest observation first.
    ready: Vec<PathBuf>,
    /// Symbolic links, FIFOs, sockets, devices: refused without being opened.
    not_regular: Vec<(PathBuf, &'static str)>,
}

/// Whether a file name is the `.tri` half of a TOSCA pair (`NAME.tri`, `NAME.tri.gz`).
fn is_tosca_tri(path: &Path) -> bool {
    let name = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    name.strip_suffix(".gz").unwrap_or(&name).ends_with(".tri")
}

/// Whether a file name is the `.vert` half of a TOSCA pair.
fn is_tosca_vert(path: &Path) -> bool {
    let name = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    name.strip_suffix(".gz").unwrap_or(&name).ends_with(".vert")
}

/// The other half of a TOSCA pair (`a.vert` ↔ `a.tri`, keeping a `.gz`), if it exists.
fn tosca_sibling(path: &Path) -> Option<PathBuf> {
    let name = path.file_name()?.to_string_lossy().into_owned();
    let (base, gz) = match name.strip_suffix(".gz") {
        Some(b) => (b.to_string(), ".gz"),
        None => (name.clone(), ""),
    };
    let (stem, ext) = base.rsplit_once('.')?;
    let other = match ext.to_ascii_lowercase().as_str() {
        "vert" => "tri",
        "tri" => "vert",
        _ => return None,
    };
    let dir = path.parent()?;
    [format!("{stem}.{other}{gz}"), format!("{stem}.{other}")]
        .into_iter()
        .map(|n| dir.join(n))
        .find(|p| p.is_file())
}

/// The regular files among `candidates` that some process holds open for writing, found by
/// reading `/proc/*/fd` and `/proc/*/fdinfo` (Linux; elsewhere, or for processes whose `/proc`
/// entries are not readable, nothing is found and the settle time alone decides). A copier
/// that pauses longer than the settle time while keeping the file open is not read half-way.
pub fn open_for_writing(candidates: &[PathBuf]) -> std::collections::HashSet<PathBuf> {
    let mut found = std::collections::HashSet::new();
    if candidates.is_empty() {
        return found;
    }
    let canon: HashMap<PathBuf, &PathBuf> =
        candidates.iter().filter_map(|p| fs::canonicalize(p).ok().map(|c| (c, p))).collect();
    let Ok(procs) = fs::read_dir("/proc") else { return found };
    for pe in procs.flatten() {
        let pid = pe.file_name();
        if !pid.to_string_lossy().bytes().all(|b| b.is_ascii_digit()) {
            continue;
        }
        let Ok(fds) = fs::read_dir(pe.path().join("fd")) else { continue };
        for fd in fds.flatten() {
            let Ok(target) = fs::read_link(fd.path()) else { continue };
            let Some(orig) = canon.get(&target) else { continue };
            let info = fs::read_to_string(pe.path().join("fdinfo").join(fd.file_name())).unwrap_or_default();
            let flags = info
                .lines()
                .find_map(|l| l.strip_prefix("flags:"))
                .and_then(|f| u32::from_str_radix(f.trim(), 8).ok())
                .unwrap_or(0);
            if flags & 0o3 != 0 {
                found.insert((*orig).clone());
            }
        }
    }
    found
}

/// Watches a folder of the data directory (`notify` events, debounced, plus periodic rescans),
/// claims each complete file into `.inflight/` and emits it.
///
/// A file is complete once its size and modification time have not changed for `settle_ms`
/// and no process holds it open for writing. Copies in progress under a temporary name (a
/// dot-file, `*.part`, `*.tmp`, …, renamed when done) are left alone. Symbolic links, FIFOs and
/// devices are refused without being opened. A TOSCA `.vert` is taken with its `.tri`.
pub struct WatchSource {
    data: DataDir,
    config: WatchConfig,
    noted: Noted,
}

impl WatchSource {
    /// A watcher over `data`'s `incoming/` or `labeled/`.
    pub fn new(data: DataDir, config: WatchConfig) -> Self {
        Self { data, config, noted: Noted::default() }
    }

    fn kind(&self) -> InputKind {
        self.config.kind.into()
    }

    /// Moves `path` (and the files that travel with it) into `.inflight/`, keeping their stems
    /// equal to the claimed mesh's.
    fn claim(&self, path: &Path, with: &[PathBuf]) -> std::io::Result<(PathBuf, Vec<PathBuf>)> {
        let dir = self.data.inflight(self.kind());
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let target = unique_path(&dir, &name);
        let stem = shape_stem(&target);
        let mut moved = Vec::new();
        for w in with {
            let t = dir.join(format!("{stem}{}", sidecar_suffix(w)));
            move_file(w, &t)?;
            moved.push(t);
        }
        move_file(path, &target)?;
        Ok((target, moved))
    }

    /// Lists the folder: files stable for the settle time (and not open for writing), and
    /// things that are not regular files.
    fn scan(&mut self, seen: &mut HashMap<PathBuf, Seen>) -> Scan {
        let settle = Duration::from_millis(self.config.settle_ms);
        let dir = self.data.arrivals(self.kind());
        let Ok(entries) = read_dir_sorted(&dir) else { return Scan::default() };
        let mut present = std::collections::HashSet::new();
        let mut out = Scan::default();
        let mut stable = Vec::new();
        for p in entries {
            present.insert(p.clone());
            let name = p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            if self.data.is_deferred(self.kind(), &name) {
                continue;
            }
            let Ok(lmeta) = fs::symlink_metadata(&p) else { continue };
            let ft = lmeta.file_type();
            if ft.is_dir() {
                self.noted.note(&p, Duration::ZERO, "a folder (drop files, not folders)");
                continue;
            }
            if !ft.is_file() {
                let what = if ft.is_symlink() { "a symbolic link" } else { "not a regular file" };
                out.not_regular.push((p, what));
                continue;
            }
            if is_transient_file(&p) {
                self.noted.note(
                    &p,
                    NOTE_AFTER,
                    "its name marks a copy in progress (a leading dot, or .part/.tmp/…); it is read once renamed",
                );
                continue;
            }
            let (size, modified) = (lmeta.len(), lmeta.modified().ok());
            let now = Instant::now();
            let e = seen.entry(p.clone()).or_insert(Seen { size, modified, since: now, warned: false });
            if e.size != size || e.modified != modified {
                *e = Seen { size, modified, since: now, warned: false };
                continue;
            }
            if now.duration_since(e.since) >= settle {
                stable.push(p);
            }
        }
        // Still open for writing: wait another settle period.
        let writing = open_for_writing(&stable);
        for p in &writing {
            if let Some(s) = seen.get_mut(p) {
                s.since = Instant::now();
            }
        }
        out.ready = stable.into_iter().filter(|p| !writing.contains(p)).collect();
        seen.retain(|p, _| present.contains(p));
        self.noted.retain(&present);
        out.ready.sort_by_key(|p| seen.get(p).map(|s| s.since));
        out
    }
}

impl Source for WatchSource {
    type Out = InputFile;

    fn run(&mut self, out: &Emitter<InputFile>) -> Result<(), Error> {
        use notify::RecursiveMode;
        let dir = self.data.arrivals(self.kind());
        fs::create_dir_all(&dir).at(&dir)?;
        let (tx, rx) = flume::unbounded();
        let mut debouncer =
            notify_debouncer_full::new_debouncer(Duration::from_millis(200), None, move |ev| {
                let _ = tx.send(ev);
            })
            .map_err(|e| Error::BadInput(format!("cannot watch {}: {e}", dir.display())))?;
        debouncer
            .watch(&dir, RecursiveMode::NonRecursive)
            .map_err(|e| Error::BadInput(format!("cannot watch {}: {e}", dir.display())))?;
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
                let scan = self.scan(&mut seen);
                for (path, what) in scan.not_regular {
                    if out.shutdown().is_triggered() {
                        return Ok(());
                    }
                    if !self.refuse(&path, what, out) {
                        return Ok(());
                    }
                }
                for path in scan.ready {
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
    /// Claims a symbolic link (or FIFO, device, …) without opening it, and emits it as a bad
    /// input: the report says what it is and quotes nothing of it.
    fn refuse(&mut self, path: &Path, what: &str, out: &Emitter<InputFile>) -> bool {
        let Ok((claimed, _)) = self.claim(path, &[]) else { return true };
        let mut job = Job::for_file(out.next_job_id(), &claimed, None);
        job.arrived_as = path.file_name().map(|n| n.to_string_lossy().into_owned());
        job.name = shape_stem(&claimed);
        let body = Err(Failure::bad_input(
            "source",
            format!(
                "{} is {what}; files dropped here are read only if they are regular files \
                 (links are not followed): copy or move the file itself in",
                path.display()
            ),
        ));
        tracing::info!(job = job.id, file = %escape_name(&path.display().to_string()), "claimed ({what})");
        out.emit(Envelope { job, body })
    }

    /// Claims and emits one stable file; returns `false` when the pipeline no longer takes jobs.
    fn offer(&mut self, path: &Path, seen: &mut HashMap<PathBuf, Seen>, out: &Emitter<InputFile>) -> bool {
        let kind = self.kind();
        let settled = |p: &Path, seen: &HashMap<PathBuf, Seen>| {
            seen.get(p).is_some_and(|s| s.since.elapsed() >= Duration::from_millis(self.config.settle_ms))
        };
        // The `.tri` of a TOSCA pair travels with its `.vert`.
        if is_tosca_tri(path) {
            if tosca_sibling(path).is_none() {
                self.noted.note(
                    path,
                    NOTE_AFTER,
                    "a TOSCA .tri without its .vert (NAME.vert); waiting for it",
                );
            }
            return true;
        }
        let is_label_map = |p: &Path| {
            p.extension().is_some_and(|e| e.eq_ignore_ascii_case("labels") || e.eq_ignore_ascii_case("vts"))
        };
        if kind == InputKind::Labeled && is_label_map(path) {
            // Label maps (and a `NAME.sym.vts` mirror table) travel with their mesh.
            let stem = sidecar_stem(path);
            let dir = path.parent().unwrap_or(Path::new("."));
            let has_mesh = read_dir_sorted(dir)
                .unwrap_or_default()
                .iter()
                .any(|p| is_mesh_file(p) && shape_stem(p) == stem);
            if !has_mesh {
                self.noted.note(
                    path,
                    NOTE_AFTER,
                    "a label map without its mesh (NAME.off, .obj, .ply or .vert)",
                );
            }
            return true;
        }
        let is_mesh = is_mesh_file(path);
        let mut with = Vec::new();
        if is_mesh && kind == InputKind::Labeled {
            match label_sidecar(path) {
                Some(l) if settled(&l, seen) => with.push(l),
                Some(_) => return true, // the label map must be complete too
                None => {
                    if let Some(s) = seen.get_mut(path) {
                        if !s.warned && s.since.elapsed() > NOTE_AFTER {
                            tracing::warn!(file = %escape_name(&path.display().to_string()), "waiting for its label map (NAME.labels or NAME.vts)");
                            s.warned = true;
                        }
                    }
                    return true;
                }
            }
            // The mirror table `NAME.sym.vts`, when there is one, goes with them (the trainer
            // checks it against `NAME.vts`).
            if let Some(sym) = symmetry_sidecar(path) {
                if !settled(&sym, seen) {
                    return true;
                }
                with.push(sym);
            }
        }
        if is_mesh && is_tosca_vert(path) {
            match tosca_sibling(path) {
                Some(t) if settled(&t, seen) => with.push(t),
                Some(_) => return true,
                None => {
                    self.noted.note(
                        path,
                        NOTE_AFTER,
                        "a TOSCA .vert without its .tri (NAME.tri); waiting for it",
                    );
                    return true;
                }
            }
        }
        let claimed = match self.claim(path, &with) {
            Ok(c) => c,
            Err(e) => {
                // Gone meanwhile, or not ours to move: look again at the next scan.
                tracing::debug!(file = %path.display(), "cannot claim: {e}");
                return true;
            }
        };
        seen.remove(path);
        for w in &with {
            seen.remove(w);
        }
        let (claimed_path, moved) = claimed;
        let (claimed_labels, companions): (Vec<PathBuf>, Vec<PathBuf>) =
            moved.into_iter().partition(|p| is_label_map(p) && !is_symmetry_file(p));
        let claimed_labels = claimed_labels.into_iter().next();
        let mut job = Job::for_file(out.next_job_id(), &claimed_path, claimed_labels.clone());
        job.companions = companions;
        job.arrived_as = path.file_name().map(|n| n.to_string_lossy().into_owned());
        job.name = shape_stem(&claimed_path);
        let body = if is_mesh {
            Ok(InputFile { path: claimed_path, labels: claimed_labels.map(LabelSpec::File) })
        } else {
            Err(Failure::bad_input(
                "source",
                format!(
                    "{} is not a mesh file shapeforest reads (.off .obj .ply, .vert with its .tri, optionally .gz)",
                    path.display()
                ),
            ))
        };
        tracing::info!(job = job.id, file = %escape_name(&path.display().to_string()), "claimed");
        out.emit(Envelope { job, body })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The settle rule on tokio's paused clock: a file is ready once its size and modification
    /// time have not changed for `settle_ms`; a change starts the wait again.
    #[tokio::test(start_paused = true)]
    async fn a_file_is_taken_once_unchanged_for_the_settle_time() {
        let tmp = tempfile::tempdir().unwrap();
        let data = DataDir::new(tmp.path());
        data.create().unwrap();
        let config =
            WatchConfig { kind: WatchKind::Scan, settle_ms: 2000, rescan_ms: 2000, exit_when_empty: false };
        let mut watcher = WatchSource::new(data.clone(), config);
        let file = data.incoming().join("a.off");
        fs::write(&file, "OFF\n").unwrap();
        let mut seen = HashMap::new();
        let step = |ms| tokio::time::advance(Duration::from_millis(ms));
        assert!(watcher.scan(&mut seen).ready.is_empty(), "first seen: not settled");
        step(1999).await;
        assert!(watcher.scan(&mut seen).ready.is_empty(), "1.999 s unchanged: not yet");
        fs::write(&file, "OFF\n3 1 0\n").unwrap();
        step(1500).await;
        assert!(watcher.scan(&mut seen).ready.is_empty(), "it grew: the wait starts again");
        step(1999).await;
        assert!(watcher.scan(&mut seen).ready.is_empty());
        step(2).await;
        assert_eq!(watcher.scan(&mut seen).ready, vec![file.clone()], "2 s unchanged: ready");
        // A copy in progress under a temporary name is never taken.
        fs::write(data.incoming().join("b.off.part"), "OFF\n").unwrap();
        step(60_000).await;
        assert_eq!(watcher.scan(&mut seen).ready, vec![file]);
    }
}
