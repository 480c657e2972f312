//! `shapeforest run PIPELINE.toml` and `shapeforest watch`: run a pipeline file on a data
//! folder until its inputs are done (batch pipelines) or until Ctrl-C / SIGTERM (the daemon).

use std::path::PathBuf;

use anyhow::{anyhow, Result};
use clap::Args;
use shapeforest::pipeline::{bootstrap_synthetic, daemon::run_spec, PipelineSpec, RunOptions, SignalEvent};

/// The daemon's pipeline when `pipelines/watch.toml` is not at hand (e.g. an installed binary).
const DEFAULT_WATCH: &str = include_str!("../../pipelines/watch.toml");

/// Arguments of `shapeforest run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// Pipeline file, e.g. pipelines/match.toml.
    pub pipeline: PathBuf,
    /// Data folder (overrides the file's `settings.data_dir`).
    #[arg(long)]
    pub data_dir: Option<PathBuf>,
    /// Stop after this many seconds (a daemon otherwise runs until Ctrl-C / SIGTERM).
    #[arg(long)]
    pub stop_after: Option<f64>,
}

/// Arguments of `shapeforest watch`.
#[derive(Debug, Args)]
pub struct WatchArgs {
    /// Pipeline file (default: pipelines/watch.toml, or the built-in copy of it).
    #[arg(long)]
    pub pipeline: Option<PathBuf>,
    /// Data folder with incoming/, labeled/, matched/, rejected/, models/.
    #[arg(long, default_value = "shapeforest-data")]
    pub data_dir: PathBuf,
    /// With no model and nothing to learn from, seed labeled/ with 6 shapes of the built-in
    /// synthetic class and incoming/ with 2 further poses to match.
    #[arg(long)]
    pub bootstrap_synthetic: bool,
    /// Vertices per synthetic shape for --bootstrap-synthetic.
    #[arg(long, default_value_t = 5000)]
    pub vertices: usize,
    /// Stop after this many seconds (otherwise: until Ctrl-C / SIGTERM).
    #[arg(long)]
    pub stop_after: Option<f64>,
}

/// What the binary does on Ctrl-C / SIGTERM: says what happens; a second signal exits at once
/// (status 130), leaving claimed inputs for the next start.
pub(super) fn on_signal(event: SignalEvent) {
    match event {
        SignalEvent::ShuttingDown => {
            eprintln!("shapeforest: shutting down — finishing jobs in flight (signal again to exit at once)")
        }
        SignalEvent::Again => {
            eprintln!("shapeforest: exiting now; claimed inputs are taken up at the next start");
            std::process::exit(130);
        }
    }
}

fn options(stop_after: Option<f64>) -> RunOptions {
    RunOptions {
        handle_signals: true,
        on_signal: Some(on_signal),
        worker_threads: None,
        stop_after: stop_after.map(|s| std::time::Duration::from_secs_f64(s.max(0.0))),
        metrics_every: Some(std::time::Duration::from_secs(60)),
        after_job: long_running_allocator(),
    }
}

/// Allocator settings for a long-running pipeline (the daemon, `run`, a worker), returning the
/// function to call after each job ([`RunOptions::after_job`]).
///
/// With glibc's defaults a burst of scans left far more memory resident than the jobs held:
/// each thread of the blocking pool gets an arena of its own, and freed blocks stay in them.
/// Measured with `examples/daemon_throughput.rs` (30 scans of 20K vertices, under load): peak
/// RSS 1.61 GB by default, 1.09–1.20 GB with at most 2 arenas, 0.90 GB with 2 arenas and
/// `malloc_trim` after each job (jemalloc as the allocator instead: 1.15 GB). So: at most 2
/// arenas (one per core of the machines this runs on; an explicit `MALLOC_ARENA_MAX` in the
/// environment is kept), and what a job freed goes back to the system when it ends.
pub(crate) fn long_running_allocator() -> Option<fn()> {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        if std::env::var_os("MALLOC_ARENA_MAX").is_none() {
            // SAFETY: mallopt only changes allocator tuning; 2 is a valid arena limit.
            unsafe {
                libc::mallopt(libc::M_ARENA_MAX, 2);
            }
        }
        fn trim() {
            // SAFETY: malloc_trim only returns free memory to the system; any pad is valid.
            unsafe {
                libc::malloc_trim(0);
            }
        }
        Some(trim)
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        None
    }
}

/// Runs `shapeforest run`.
pub fn run(args: RunArgs) -> Result<()> {
    let spec = PipelineSpec::from_file(&args.pipeline)?;
    eprintln!("shapeforest: running pipeline `{}` ({})", spec.name, args.pipeline.display());
    let report = run_spec(&spec, args.data_dir.as_deref(), options(args.stop_after), None, |setup| {
        for n in setup.notes.iter().chain(&setup.waiting_hint) {
            eprintln!("shapeforest: {n}");
        }
        Ok(())
    })?;
    for s in &report.summary {
        print!("{s}");
    }
    println!("{}", report.table());
    let (done, rejected) = (report.completed(), report.rejected());
    println!(
        "pipeline `{}` finished in {:.1} s{}; {done} done, {rejected} rejected; model version {}",
        spec.name,
        report.elapsed_s,
        if report.interrupted { " (shut down)" } else { "" },
        report.model_version
    );
    if !report.problems.is_empty() {
        return Err(anyhow!(
            "pipeline `{}` failed ({done} done, {rejected} rejected):\n  {}",
            spec.name,
            report.problems.join("\n  ")
        ));
    }
    if !report.interrupted && done == 0 && rejected > 0 {
        return Err(anyhow!(
            "pipeline `{}`: every input was rejected ({rejected} of {rejected}); the reports say why",
            spec.name
        ));
    }
    Ok(())
}

/// Runs `shapeforest watch`.
pub fn watch(args: WatchArgs) -> Result<()> {
    let spec = match &args.pipeline {
        Some(p) => PipelineSpec::from_file(p)?,
        None => {
            let default = PathBuf::from("pipelines/watch.toml");
            if default.is_file() {
                PipelineSpec::from_file(&default)?
            } else {
                PipelineSpec::from_toml(DEFAULT_WATCH, "built-in watch.toml")?
            }
        }
    };
    if !spec.is_daemon() {
        return Err(anyhow!("pipeline `{}` watches no folder; use `shapeforest run` for it", spec.name));
    }
    let data_dir = args.data_dir.clone();
    eprintln!(
        "shapeforest: watching {} (drop scans into incoming/, labelled shapes into labeled/; Ctrl-C to stop)",
        data_dir.display()
    );
    let report = run_spec(&spec, Some(&data_dir), options(args.stop_after), None, |setup| {
        let bootstrap = args.bootstrap_synthetic && setup.nothing_to_learn;
        let hint = setup.waiting_hint.iter().filter(|_| !bootstrap);
        for n in setup.notes.iter().chain(hint) {
            eprintln!("shapeforest: {n}");
        }
        if bootstrap {
            let n = bootstrap_synthetic(&setup.data, args.vertices, 6, 2, 1)?;
            eprintln!(
                "shapeforest: bootstrap: 6 labelled synthetic creatures ({n} vertices) in labeled/, 2 scans in incoming/"
            );
        }
        Ok(())
    })?;
    println!("{}", report.table());
    println!("stopped after {:.1} s; model version {}", report.elapsed_s, report.model_version);
    Ok(())
}
