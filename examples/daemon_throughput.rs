//! Throughput, latency and memory of the watch-folder daemon, measured from outside as a user
//! sees it: the real `shapeforest watch` process on a fresh data folder.
//!
//! 1. writes `--train` labelled synthetic creatures into `labeled/` and waits for the model;
//! 2. resets the daemon's peak-memory counter (`/proc/PID/clear_refs`), then moves `--scans`
//!    further poses into `incoming/` at once (a burst queued on disk);
//! 3. waits for every result, sampling the daemon's resident memory;
//! 4. prints scans per minute, latency per scan (claim → result, from the reports; and
//!    drop → result) and peak memory while matching, then stops the daemon with SIGTERM.
//!
//! `cargo build --release && cargo run --release --example daemon_throughput -- \
//!     [--vertices 20000] [--scans 100] [--train 6] [--out DIR]`

use std::{
    fmt::Write as _,
    path::{Path, PathBuf},
    process::{Command, Stdio},
    thread,
    time::{Duration, Instant, SystemTime},
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

fn status_kb(pid: u32, key: &str) -> Option<u64> {
    let text = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = text.lines().find(|l| l.starts_with(key))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

fn count_results(matched: &Path) -> usize {
    std::fs::read_dir(matched)
        .map(|d| {
            d.filter_map(|e| e.ok())
                .filter(|e| e.path().is_dir() && !e.file_name().to_string_lossy().starts_with('.'))
                .count()
        })
        .unwrap_or(0)
}

fn main() -> Result<()> {
    let vertices: usize = arg("--vertices", 20_000);
    let n_scans: usize = arg("--scans", 100);
    let n_train: usize = arg("--train", 6);
    let out = PathBuf::from(arg("--out", "shapeforest-throughput".to_string()));
    let exe = std::env::current_exe()?
        .parent()
        .and_then(Path::parent)
        .map(|d| d.join("shapeforest"))
        .context("no exe dir")?;
    if !exe.is_file() {
        bail!("{} not found: run `cargo build --release` first", exe.display());
    }
    if out.exists() {
        std::fs::remove_dir_all(&out)?;
    }
    let staging = out.join("staging");
    std::fs::create_dir_all(&staging)?;
    println!(
        "daemon throughput: {n_train} labelled + {n_scans} scans of ~{vertices} vertices, in {}",
        out.display()
    );
    let t0 = Instant::now();
    let fam = creature_family(
        &CreatureParams { target_vertices: vertices, seed: 3, ..Default::default() },
        n_train + n_scans,
    )?;
    let n = fam.template.n_vertices();
    let mut labels = String::new();
    for v in 0..n {
        let _ = writeln!(labels, "{v}");
    }
    let data = out.join("data");
    for d in ["labeled", "incoming"] {
        std::fs::create_dir_all(data.join(d))?;
    }
    for (i, mesh) in fam.shapes.iter().enumerate() {
        if i < n_train {
            std::fs::write(data.join("labeled").join(format!("train{i}.labels")), &labels)?;
            write_mesh(data.join("labeled").join(format!("train{i}.off")), mesh)?;
        } else {
            write_mesh(staging.join(format!("scan{:03}.off", i - n_train)), mesh)?;
        }
    }
    drop(fam);
    println!("  shapes of {n} vertices written in {:.1} s", t0.elapsed().as_secs_f64());

    let log = std::fs::File::create(out.join("daemon.log"))?;
    let mut child = Command::new(&exe)
        .args(["watch", "--data-dir"])
        .arg(&data)
        .env("RUST_LOG", "info")
        .stdout(log.try_clone()?)
        .stderr(log)
        .stdin(Stdio::null())
        .spawn()?;
    let pid = child.id();
    let t0 = Instant::now();
    let models = data.join("models");
    loop {
        let done = std::fs::read_dir(&models)
            .map(|d| {
                d.filter_map(|e| e.ok()).any(|e| {
                    e.path().extension().is_some_and(|x| x == "json")
                        && std::fs::read_to_string(e.path())
                            .ok()
                            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
                            .and_then(|m| m["training_shapes"].as_array().map(Vec::len))
                            .is_some_and(|k| k >= n_train)
                })
            })
            .unwrap_or(false);
        if done {
            break;
        }
        if child.try_wait()?.is_some() {
            bail!("the daemon exited; see {}", out.join("daemon.log").display());
        }
        thread::sleep(Duration::from_millis(200));
    }
    let train_s = t0.elapsed().as_secs_f64();
    let train_peak = status_kb(pid, "VmHWM:").unwrap_or(0);
    println!(
        "  model on {n_train} shapes ready after {train_s:.1} s (daemon peak RSS so far {:.0} MB)",
        train_peak as f64 / 1024.0
    );

    // Reset the peak counter, then the burst.
    let _ = std::fs::write(format!("/proc/{pid}/clear_refs"), "5");
    let base = status_kb(pid, "VmRSS:").unwrap_or(0);
    let dropped = SystemTime::now();
    let t0 = Instant::now();
    let mut names: Vec<PathBuf> =
        std::fs::read_dir(&staging)?.filter_map(|e| e.ok().map(|e| e.path())).collect();
    names.sort();
    for p in &names {
        std::fs::rename(p, data.join("incoming").join(p.file_name().context("name")?))?;
    }
    let matched = data.join("matched");
    let mut peak_rss = base;
    let mut first_result = None;
    while count_results(&matched) < n_scans {
        if child.try_wait()?.is_some() {
            bail!("the daemon exited; see {}", out.join("daemon.log").display());
        }
        peak_rss = peak_rss.max(status_kb(pid, "VmRSS:").unwrap_or(0));
        if first_result.is_none() && count_results(&matched) > 0 {
            first_result = Some(t0.elapsed().as_secs_f64());
        }
        thread::sleep(Duration::from_millis(100));
    }
    let total_s = t0.elapsed().as_secs_f64();
    let hwm = status_kb(pid, "VmHWM:").unwrap_or(0).max(peak_rss);
    let _ = Command::new("kill").args(["-TERM", &pid.to_string()]).status();
    let status = child.wait()?;

    // Latencies from the reports (claim → commit) and from the files (drop → result).
    let mut claim_latency = Vec::new();
    let mut drop_latency = Vec::new();
    let mut work = Vec::new();
    let mut per_stage: Vec<(String, f64)> = Vec::new();
    for e in std::fs::read_dir(&matched)?.filter_map(|e| e.ok()).filter(|e| e.path().is_dir()) {
        let name = e.file_name().to_string_lossy().into_owned();
        let report = e.path().join(format!("{name}.report.json"));
        let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&report)?)?;
        claim_latency.push(v["latency_s"].as_f64().unwrap_or(f64::NAN));
        if let Some(stages) = v["stage_seconds"].as_object() {
            work.push(stages.values().filter_map(|t| t.as_f64()).sum::<f64>());
            for (k, t) in stages {
                if let Some(t) = t.as_f64() {
                    match per_stage.iter_mut().find(|(n, _)| n == k) {
                        Some((_, acc)) => *acc += t,
                        None => per_stage.push((k.clone(), t)),
                    }
                }
            }
        }
        let done = std::fs::metadata(&report)?.modified()?;
        drop_latency.push(done.duration_since(dropped).map_or(0.0, |d| d.as_secs_f64()));
    }
    let stats = |v: &mut Vec<f64>| {
        v.sort_by(|a, b| a.total_cmp(b));
        let mean = v.iter().sum::<f64>() / v.len().max(1) as f64;
        (mean, v[v.len() / 2], v[v.len() - 1])
    };
    let (cm, cmed, cmax) = stats(&mut claim_latency);
    let (dm, dmed, dmax) = stats(&mut drop_latency);
    println!(
        "  {n_scans} scans matched in {total_s:.1} s: {:.1} scans/min (first result after {:.1} s)",
        60.0 * n_scans as f64 / total_s,
        first_result.unwrap_or(total_s)
    );
    println!("  latency claim → result: mean {cm:.2} s, median {cmed:.2} s, max {cmax:.2} s");
    println!(
        "  latency drop → result (includes the queue): mean {dm:.1} s, median {dmed:.1} s, max {dmax:.1} s"
    );
    let (wm, wmed, wmax) = stats(&mut work);
    println!("  work per scan (sum of its stage times): mean {wm:.2} s, median {wmed:.2} s, max {wmax:.2} s");
    let per: Vec<String> =
        per_stage.iter().map(|(k, t)| format!("{k} {:.2} s", t / n_scans as f64)).collect();
    println!("  mean per stage: {}", per.join(", "));
    println!(
        "  daemon memory with {n_scans} scans queued: RSS before the burst {:.0} MB, peak while matching {:.0} MB (peak during training {:.0} MB)",
        base as f64 / 1024.0,
        hwm as f64 / 1024.0,
        train_peak as f64 / 1024.0
    );
    println!("  daemon exit after SIGTERM: {status}");
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!("  load average at the end: {}", load.split_whitespace().take(3).collect::<Vec<_>>().join(" "));
    Ok(())
}
