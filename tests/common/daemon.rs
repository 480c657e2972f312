//! Driving the real `shapeforest` binary on a temporary data folder, as a user (or a hostile
//! one) would: start, drop files, wait, signal, kill.

use std::{
    fmt::Write as _,
    path::{Path, PathBuf},
    process::{Child, Command, Stdio},
    sync::OnceLock,
    thread,
    time::{Duration, Instant},
};

use shapeforest::{
    mesh::{write_mesh, Mesh},
    synth::{creature_family, CreatureParams, ShapeFamily},
};

pub const VERTICES: usize = 1500;
/// How long a test waits for something to happen (`SHAPEFOREST_TEST_TIMEOUT_S`, default 240).
pub fn timeout() -> Duration {
    let s = std::env::var("SHAPEFOREST_TEST_TIMEOUT_S").ok().and_then(|s| s.parse().ok()).unwrap_or(240);
    Duration::from_secs(s)
}

pub use super::bin_path as bin;

pub fn family(n: usize) -> ShapeFamily {
    creature_family(&CreatureParams { target_vertices: VERTICES, seed: 1, ..Default::default() }, n).unwrap()
}

pub struct Daemon {
    pub child: Child,
    pub log: PathBuf,
}

/// The watch pipeline with a short settle time, edited by `edit`.
pub fn pipeline_file(data: &Path, edit: impl Fn(String) -> String) -> PathBuf {
    let pipeline = data.with_extension(format!("watch{}.toml", std::process::id()));
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/pipelines/watch.toml"))
        .unwrap()
        .replace("settle_ms = 2000", "settle_ms = 200");
    std::fs::write(&pipeline, edit(text)).unwrap();
    pipeline
}

impl Daemon {
    pub fn start(data: &Path, bootstrap: bool) -> Daemon {
        Self::start_with(data, bootstrap, |t| t, &[])
    }

    pub fn start_with(
        data: &Path,
        bootstrap: bool,
        edit: impl Fn(String) -> String,
        env: &[(&str, &str)],
    ) -> Daemon {
        let log = data.with_extension(format!("log{}", std::process::id()));
        let out = std::fs::OpenOptions::new().create(true).append(true).open(&log).unwrap();
        let mut cmd = Command::new(bin());
        cmd.args(["watch", "--data-dir"]).arg(data).args(["--vertices", &VERTICES.to_string()]);
        if bootstrap {
            cmd.arg("--bootstrap-synthetic");
        }
        cmd.arg("--pipeline").arg(pipeline_file(data, edit));
        for (k, v) in env {
            cmd.env(k, v);
        }
        let child = cmd
            .env("RUST_LOG", "info")
            .stdout(out.try_clone().unwrap())
            .stderr(out)
            .stdin(Stdio::null())
            .spawn()
            .unwrap();
        Daemon { child, log }
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    pub fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    pub fn assert_running(&mut self) {
        if let Some(status) = self.child.try_wait().unwrap() {
            panic!("daemon exited with {status}:\n{}", self.log());
        }
    }

    /// SIGTERM, then wait for a clean exit.
    pub fn stop(mut self) -> String {
        let pid = self.child.id().to_string();
        let ok = Command::new("kill").args(["-TERM", &pid]).status().unwrap().success();
        assert!(ok, "kill -TERM failed");
        let t0 = Instant::now();
        loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                assert!(status.success(), "daemon exited with {status} after SIGTERM:\n{}", self.log());
                return self.log();
            }
            assert!(t0.elapsed() < timeout(), "daemon did not stop after SIGTERM:\n{}", self.log());
            thread::sleep(Duration::from_millis(50));
        }
    }

    /// `kill -9`.
    pub fn kill(mut self) {
        self.child.kill().unwrap();
        self.child.wait().unwrap();
    }

    /// Waits for the process to exit by itself; its status and log.
    pub fn wait_exit(mut self, within: Duration) -> (std::process::ExitStatus, String) {
        let t0 = Instant::now();
        loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                return (status, self.log());
            }
            assert!(t0.elapsed() < within, "still running after {within:?}:\n{}", self.log());
            thread::sleep(Duration::from_millis(50));
        }
    }

    /// Peak resident memory of the process so far, in bytes (Linux `VmHWM`).
    pub fn peak_rss(&self) -> Option<u64> {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.child.id())).ok()?;
        let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
        let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
        Some(kb * 1024)
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

pub fn wait_until(daemon: &mut Daemon, what: &str, mut cond: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !cond() {
        daemon.assert_running();
        assert!(t0.elapsed() < timeout(), "timed out waiting for {what}:\n{}", daemon.log());
        thread::sleep(Duration::from_millis(50));
    }
}

/// Waits until the daemon's log satisfies `cond`.
pub fn wait_for_log(daemon: &mut Daemon, what: &str, cond: impl Fn(&str) -> bool) {
    let t0 = Instant::now();
    while !cond(&daemon.log()) {
        daemon.assert_running();
        assert!(t0.elapsed() < timeout(), "timed out waiting for {what}:\n{}", daemon.log());
        thread::sleep(Duration::from_millis(50));
    }
}

/// Writes a file aside (in `staging`, on the same file system) and renames it into `dir`.
pub fn drop_mesh_via(staging: &Path, dir: &Path, name: &str, mesh: &Mesh) {
    std::fs::create_dir_all(staging).unwrap();
    let tmp = staging.join(name);
    write_mesh(&tmp, mesh).unwrap();
    std::fs::rename(&tmp, dir.join(name)).unwrap();
}

/// Writes a file aside and renames it into `dir`, as a careful copier does.
pub fn drop_mesh(dir: &Path, name: &str, mesh: &Mesh) {
    let staging = dir.parent().unwrap().join(".staging");
    drop_mesh_via(&staging, dir, name, mesh);
}

pub fn identity_labels(n: usize) -> String {
    let mut s = String::new();
    for v in 0..n {
        let _ = writeln!(s, "{v}");
    }
    s
}

/// A labelled shape in `labeled/`: the label map first, then the mesh.
pub fn drop_labelled(data: &Path, name: &str, mesh: &Mesh, labels: &str) {
    std::fs::write(data.join("labeled").join(format!("{name}.labels")), labels).unwrap();
    drop_mesh(&data.join("labeled"), &format!("{name}.off"), mesh);
}

pub fn manifests(data: &Path) -> Vec<serde_json::Value> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(data.join("models"))
        .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    v.retain(|p| p.extension().is_some_and(|e| e == "json"));
    v.sort();
    v.iter().filter_map(|p| serde_json::from_str(&std::fs::read_to_string(p).ok()?).ok()).collect()
}

pub fn newest_training_count(data: &Path) -> usize {
    manifests(data).last().and_then(|m| m["training_shapes"].as_array().map(Vec::len)).unwrap_or(0)
}

pub fn result_dirs(data: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(data.join("matched"))
        .map(|d| {
            d.filter_map(|e| e.ok())
                // `.partial-NAME-ID/` is a result being written, not a result.
                .filter(|e| e.path().is_dir() && !e.file_name().to_string_lossy().starts_with('.'))
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

pub fn files_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|d| d.filter_map(|e| e.ok()).map(|e| e.file_name().to_string_lossy().into_owned()).collect())
        .unwrap_or_default();
    v.sort();
    v
}

pub fn read_json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())))
        .unwrap()
}

/// Copies a folder tree (files, folders; links as links).
pub fn copy_tree(from: &Path, to: &Path) {
    let ok = Command::new("cp").arg("-a").arg(from).arg(to).status().unwrap().success();
    assert!(ok, "cp -a {} {}", from.display(), to.display());
}

/// A data folder whose daemon has learnt the bootstrap class (model v1, 6 shapes, reference
/// `creature0`) and matched its 2 scans, built once per test binary and copied by each test.
pub fn trained_template() -> &'static Path {
    static T: OnceLock<PathBuf> = OnceLock::new();
    T.get_or_init(|| {
        // Under the target folder, rebuilt by each run of the test binary (nothing accumulates).
        let root = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("faults-template");
        let _ = std::fs::remove_dir_all(&root);
        std::fs::create_dir_all(&root).unwrap();
        let data = root.join("data");
        let mut d = Daemon::start(&data, true);
        wait_until(&mut d, "the bootstrap model and results", || {
            newest_training_count(&data) == 6 && result_dirs(&data).len() == 2
        });
        d.stop();
        data
    })
}

/// A fresh copy of [`trained_template`] at `dir/data`.
pub fn trained_copy(dir: &Path) -> PathBuf {
    let data = dir.join("data");
    copy_tree(trained_template(), &data);
    data
}

/// Runs the binary with `args`; its status, stdout and stderr.
pub fn run_cli(args: &[&std::ffi::OsStr], within: Duration) -> (std::process::ExitStatus, String, String) {
    let mut child = Command::new(bin())
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    loop {
        if child.try_wait().unwrap().is_some() {
            let out = child.wait_with_output().unwrap();
            return (
                out.status,
                String::from_utf8_lossy(&out.stdout).into_owned(),
                String::from_utf8_lossy(&out.stderr).into_owned(),
            );
        }
        if t0.elapsed() > within {
            let _ = child.kill();
            let out = child.wait_with_output().unwrap();
            panic!(
                "`shapeforest {:?}` still running after {within:?}\n{}",
                args,
                String::from_utf8_lossy(&out.stderr)
            );
        }
        thread::sleep(Duration::from_millis(20));
    }
}
