//! `shapeforest worker`, `shapeforest submit` and `shapeforest results`: a pipeline's stages
//! as worker processes on NATS JetStream (see `shapeforest::pipeline::nats`).

use std::{
    collections::HashSet,
    path::{Path, PathBuf},
    sync::Arc,
    time::Duration,
};

use anyhow::{anyhow, bail, Context, Result};
use clap::Args;
use shapeforest::pipeline::{
    build_with, check_selection, label_sidecar, load_live_model_for,
    nats::{model_sync, Nats, NatsSettings, NatsTransport},
    DataDir, DataLock, Dynamic, Envelope, InputFile, Job, LabelSpec, LiveModel, PipelineContext,
    PipelineSpec, ServeNeeds, Shutdown,
};

use super::run::on_signal;

/// The daemon's pipeline when none is given (its stages are the workers' default).
const DEFAULT_WATCH: &str = include_str!("../../pipelines/watch.toml");

fn read_spec(p: Option<&Path>) -> Result<PipelineSpec> {
    Ok(match p {
        Some(p) => PipelineSpec::from_file(p)?,
        None if Path::new("pipelines/watch.toml").is_file() => {
            PipelineSpec::from_file(Path::new("pipelines/watch.toml"))?
        }
        None => PipelineSpec::from_toml(DEFAULT_WATCH, "built-in watch.toml")?,
    })
}

/// Arguments of `shapeforest worker`.
#[derive(Debug, Args)]
pub struct WorkerArgs {
    /// Pipeline file (the same `pipelines/*.toml` the in-process daemon runs).
    pub pipeline: PathBuf,
    /// NATS server URL (overrides `nats_url` of the file's [settings]).
    #[arg(long)]
    pub nats: Option<String>,
    /// Stages to run, comma-separated (default: every stage that is neither a source nor a
    /// sink; `submit` feeds the sources, `results` runs the result sinks, and a trainer runs
    /// where it is named).
    #[arg(long, value_delimiter = ',')]
    pub stages: Vec<String>,
    /// This worker's own folder (received files, model versions, a trainer's models/).
    /// Default: `worker-PID` inside the pipeline's data folder.
    #[arg(long)]
    pub data_dir: Option<PathBuf>,
    /// Stop after this many seconds (otherwise: until Ctrl-C / SIGTERM).
    #[arg(long)]
    pub stop_after: Option<f64>,
}

/// Arguments of `shapeforest results`.
#[derive(Debug, Args)]
pub struct ResultsArgs {
    /// Pipeline file (default: pipelines/watch.toml, or the built-in copy).
    #[arg(long)]
    pub pipeline: Option<PathBuf>,
    /// NATS server URL.
    #[arg(long)]
    pub nats: Option<String>,
    /// Where results go: OUT/matched/NAME/ and OUT/rejected/, as the daemon writes them.
    #[arg(long)]
    pub out: PathBuf,
    /// Stop after this many seconds (otherwise: until Ctrl-C / SIGTERM).
    #[arg(long)]
    pub stop_after: Option<f64>,
}

/// Arguments of `shapeforest gc`.
#[derive(Debug, Args)]
pub struct GcArgs {
    /// Pipeline file (default: pipelines/watch.toml, or the built-in copy).
    #[arg(long)]
    pub pipeline: Option<PathBuf>,
    /// NATS server URL.
    #[arg(long)]
    pub nats: Option<String>,
    /// Model versions kept: the current one and those just before it (and any version a
    /// waiting job names).
    #[arg(long, default_value_t = 3)]
    pub keep_models: u64,
    /// Objects younger than this many seconds are kept (a stage stores its output before it
    /// publishes the message naming it).
    #[arg(long, default_value_t = 600.0)]
    pub grace_s: f64,
}

/// Arguments of `shapeforest submit`.
#[derive(Debug, Args)]
pub struct SubmitArgs {
    /// Mesh files to match (or, with --labelled, labelled shapes: NAME.off beside NAME.labels).
    pub files: Vec<PathBuf>,
    /// Pipeline file (default: pipelines/watch.toml, or the built-in copy).
    #[arg(long)]
    pub pipeline: Option<PathBuf>,
    /// NATS server URL.
    #[arg(long)]
    pub nats: Option<String>,
    /// The source stage the files enter at (default `scans`, with --labelled `labelled`).
    #[arg(long)]
    pub source: Option<String>,
    /// The files are labelled shapes for the trainer (each with its NAME.labels or NAME.vts).
    #[arg(long)]
    pub labelled: bool,
    /// Publish the newest model of this data folder (its models/ and training/) as the
    /// workers' current model, if it is newer than the one they use.
    #[arg(long)]
    pub model_from: Option<PathBuf>,
}

fn options(stop_after: Option<f64>) -> shapeforest::pipeline::RunOptions {
    shapeforest::pipeline::RunOptions {
        handle_signals: true,
        on_signal: Some(on_signal),
        worker_threads: None,
        stop_after: stop_after.map(|s| Duration::from_secs_f64(s.max(0.0))),
        metrics_every: Some(Duration::from_secs(60)),
        after_job: super::run::long_running_allocator(),
    }
}

/// Runs the stages `only` of `spec` as a worker over `data`.
fn run_worker(
    spec: &PipelineSpec,
    url: Option<&str>,
    only: HashSet<String>,
    data: DataDir,
    stop_after: Option<f64>,
) -> Result<()> {
    check_selection(spec, &only, NatsTransport::carries)?;
    let settings = NatsSettings::from_spec(spec, url)?;
    std::fs::create_dir_all(data.root())
        .with_context(|| format!("cannot create {}", data.root().display()))?;
    let _lock = DataLock::acquire(data.root())?;
    let nats = Nats::connect(settings)?;
    let shutdown = Shutdown::new();
    let needs = ServeNeeds { limits: spec.settings.limits, ..Default::default() };
    let live = Arc::new(match load_live_model_for(&data, Default::default(), &needs)? {
        Some(m) => LiveModel::with(m),
        None => LiveModel::new(),
    });
    let trains = spec.stages.iter().any(|s| only.contains(&s.name) && s.type_name() == "trainer");
    if trains {
        let holder = format!("{}-{}", hostname(), std::process::id());
        eprintln!("shapeforest: waiting for the trainer lease (one trainer at a time)");
        if !nats.block_on(model_sync::acquire_lease(&nats, &holder, &shutdown)) {
            return Ok(());
        }
        eprintln!("shapeforest: holding the trainer lease as {holder}");
        model_sync::keep_lease(nats.clone(), holder, shutdown.clone());
    }
    model_sync::follow(
        nats.clone(),
        data.clone(),
        live.clone(),
        needs,
        shutdown.clone(),
        Duration::from_millis(500),
    );
    let transport = NatsTransport::new(nats.clone(), spec, data.clone(), live.clone(), shutdown.clone());
    let ctx = PipelineContext::with_shutdown(shutdown.clone());
    let pipeline =
        build_with(spec, &data, live.clone(), ctx, Dynamic::new(Arc::new(transport)), Some(&only))?;
    let mut names: Vec<&String> = only.iter().collect();
    names.sort();
    eprintln!(
        "shapeforest: worker {} of pipeline `{}` on {}: stages {}",
        std::process::id(),
        spec.name,
        nats.settings.url,
        names.iter().map(|n| n.as_str()).collect::<Vec<_>>().join(", ")
    );
    let report = pipeline.run(options(stop_after))?;
    shutdown.trigger();
    // Let the last acknowledgements go out before the connection closes.
    std::thread::sleep(Duration::from_millis(300));
    println!("{}", report.table());
    println!("worker stopped after {:.1} s; model version {}", report.elapsed_s, report.model_version);
    if !report.problems.is_empty() {
        bail!("worker failed:\n  {}", report.problems.join("\n  "));
    }
    Ok(())
}

fn hostname() -> String {
    std::fs::read_to_string("/etc/hostname").map(|h| h.trim().to_string()).unwrap_or_else(|_| "host".into())
}

/// The stages a worker runs by default: every stage that is neither a source nor a sink
/// (less any whose output could only travel in process to a stage left out; today every edge
/// travels, so none is cut: the labelled shapes' spectra, too, are computed by any worker and
/// queued for the trainer).
fn default_stages(spec: &PipelineSpec) -> HashSet<String> {
    let mut only: HashSet<String> = spec
        .stages
        .iter()
        .filter(|s| {
            let (i, o) = s.config.ports();
            i.is_some() && o.is_some()
        })
        .map(|s| s.name.clone())
        .collect();
    loop {
        let cut: Vec<String> = spec
            .stages
            .iter()
            .filter(|s| only.contains(&s.name))
            .filter(|s| {
                let carried = s.config.ports().1.is_some_and(NatsTransport::carries);
                !carried
                    && spec
                        .stages
                        .iter()
                        .any(|c| c.input.as_deref() == Some(s.name.as_str()) && !only.contains(&c.name))
            })
            .map(|s| s.name.clone())
            .collect();
        if cut.is_empty() {
            return only;
        }
        for c in cut {
            only.remove(&c);
        }
    }
}

/// Runs `shapeforest worker`.
pub fn worker(args: WorkerArgs) -> Result<()> {
    let spec = PipelineSpec::from_file(&args.pipeline)?;
    let only: HashSet<String> = if args.stages.is_empty() {
        default_stages(&spec)
    } else {
        args.stages.iter().map(|s| s.trim().to_string()).filter(|s| !s.is_empty()).collect()
    };
    let data = DataDir::new(
        args.data_dir
            .unwrap_or_else(|| spec.settings.data_dir.join(format!("worker-{}", std::process::id()))),
    );
    run_worker(&spec, args.nats.as_deref(), only, data, args.stop_after)
}

/// Runs `shapeforest results`.
pub fn results(args: ResultsArgs) -> Result<()> {
    let spec = read_spec(args.pipeline.as_deref())?;
    let only: HashSet<String> = spec
        .stages
        .iter()
        .filter(|s| matches!(s.type_name(), "match-sink" | "eval-sink"))
        .map(|s| s.name.clone())
        .collect();
    if only.is_empty() {
        bail!("pipeline `{}` has no match-sink or eval-sink stage to write results", spec.name);
    }
    eprintln!("shapeforest: writing results into {}", args.out.display());
    run_worker(&spec, args.nats.as_deref(), only, DataDir::new(args.out), args.stop_after)
}

/// Runs `shapeforest gc`.
pub fn gc(args: GcArgs) -> Result<()> {
    if args.keep_models == 0 {
        bail!("--keep-models 0: at least the current model is kept");
    }
    if !(args.grace_s.is_finite() && args.grace_s >= 0.0) {
        bail!("--grace-s {}: a number of seconds, 0 or more", args.grace_s);
    }
    let spec = read_spec(args.pipeline.as_deref())?;
    let nats = Nats::connect(NatsSettings::from_spec(&spec, args.nats.as_deref())?)?;
    let grace = Duration::from_secs_f64(args.grace_s);
    let r = nats
        .block_on(shapeforest::pipeline::nats::gc::collect(&nats, args.keep_models, grace))
        .map_err(|e| anyhow!(e))?;
    println!(
        "read {} waiting message(s) referring to {} object(s); deleted {} of {} object(s) ({:.1} MB) and model version(s) {:?}",
        r.messages,
        r.referenced,
        r.deleted,
        r.objects,
        r.deleted_bytes as f64 / 1e6,
        r.deleted_models
    );
    Ok(())
}

/// Runs `shapeforest submit`.
pub fn submit(args: SubmitArgs) -> Result<()> {
    let spec = read_spec(args.pipeline.as_deref())?;
    let settings = NatsSettings::from_spec(&spec, args.nats.as_deref())?;
    let nats = Nats::connect(settings)?;
    if let Some(dir) = &args.model_from {
        let v =
            nats.block_on(model_sync::publish_model(&nats, &DataDir::new(dir))).map_err(|e| anyhow!(e))?;
        println!("current model: v{v}");
    }
    if args.files.is_empty() {
        if args.model_from.is_none() {
            bail!("nothing to submit: give mesh files (or --model-from DIR)");
        }
        return Ok(());
    }
    let source =
        args.source.clone().unwrap_or_else(|| if args.labelled { "labelled" } else { "scans" }.into());
    let Some(src) = spec.stage(&source) else { bail!("pipeline `{}` has no stage `{source}`", spec.name) };
    if src.input.is_some() {
        bail!("stage `{source}` is not a source");
    }
    let consumers: Vec<String> = spec
        .stages
        .iter()
        .filter(|s| s.input.as_deref() == Some(source.as_str()))
        .map(|s| s.name.clone())
        .collect();
    let scratch =
        DataDir::new(std::env::temp_dir().join(format!("shapeforest-submit-{}", std::process::id())));
    let transport =
        NatsTransport::new(nats.clone(), &spec, scratch, Arc::new(LiveModel::new()), Shutdown::new());
    let senders =
        consumers.iter().map(|c| transport.file_sender(&source, c)).collect::<Result<Vec<_>, _>>()?;
    let mut n = 0;
    for f in &args.files {
        if !f.is_file() {
            bail!("{}: not a file", f.display());
        }
        let labels = if args.labelled {
            Some(
                label_sidecar(f)
                    .ok_or_else(|| anyhow!("{}: no NAME.labels or NAME.vts beside it", f.display()))?,
            )
        } else {
            None
        };
        let mut job = Job::for_file(u64::from(rand::random::<u32>()), f, labels.clone());
        if f.extension().is_some_and(|e| e.eq_ignore_ascii_case("vert")) {
            let tri = f.with_extension("tri");
            if !tri.is_file() {
                bail!("{}: a TOSCA .vert needs its .tri beside it", f.display());
            }
            job.companions.push(tri);
        }
        let body = Ok(InputFile { path: f.clone(), labels: labels.map(LabelSpec::File) });
        for tx in &senders {
            let env = Envelope { job: job.clone(), body: body.clone() };
            nats.block_on(tx.send(env)).map_err(|_| anyhow!("{}: could not be published", f.display()))?;
        }
        n += 1;
    }
    println!("submitted {n} file(s) to `{source}` ({})", consumers.join(", "));
    Ok(())
}
