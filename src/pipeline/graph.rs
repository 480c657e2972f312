//! Composing actors into a running pipeline, in code ([`Pipeline`]: typed [`Port`]s make a
//! mis-wired graph a compile error) or from a `pipelines/*.toml` file (see [`super::config`]).

use std::{
    sync::{Arc, Mutex},
    time::{Duration, Instant},
};

use super::{
    actor::{run_sink, run_source, run_stage, PipelineContext, Sink, Source, Stage, StageSummary},
    error::Error,
    model::LiveModel,
    store::DataDir,
    transport::{Dynamic, Output, Payload, Sender, Transport},
};

/// The output of an actor. Every actor given it as input gets every envelope (fan-out: clone
/// the port to attach a second consumer, a viewer or a metrics exporter beside a sink).
pub struct Port<T> {
    consumers: Arc<Mutex<Vec<Arc<dyn Sender<T>>>>>,
    /// Name of the producing actor.
    pub producer: String,
}

impl<T> Clone for Port<T> {
    fn clone(&self) -> Self {
        Self { consumers: self.consumers.clone(), producer: self.producer.clone() }
    }
}

impl<T: Payload> Port<T> {
    pub(crate) fn new(producer: &str) -> Self {
        Self { consumers: Arc::default(), producer: producer.to_string() }
    }

    /// The output to the consumers attached so far (taken when the producer starts).
    pub fn output(&self) -> Output<T> {
        let consumers = self.consumers.lock().map(|mut c| std::mem::take(&mut *c)).unwrap_or_default();
        Output::new(consumers)
    }

    pub(crate) fn attach(&self, sender: Arc<dyn Sender<T>>) {
        if let Ok(mut c) = self.consumers.lock() {
            c.push(sender);
        }
    }
}

type Spawn = Box<dyn FnOnce() -> tokio::task::JoinHandle<()> + Send>;

/// A pipeline under construction: actors connected by bounded channels.
///
/// ```no_run
/// use std::sync::Arc;
/// use shapeforest::pipeline::{stages::*, DataDir, LiveModel, Pipeline, RunOptions};
///
/// let data = DataDir::new("shapeforest-data");
/// let live = Arc::new(LiveModel::new());
/// let mut p = Pipeline::new(data.clone(), live.clone());
/// let shapes = p.source("train-shapes", SyntheticSource::new(SyntheticConfig { vertices: 3000, seed: 1, first: 0, count: 6 }));
/// let spectra = p.stage("spectral", shapes, SpectralStage::new(&SpectralConfig::default(), None).unwrap());
/// let trainer = TrainerSink::new(data, TrainerConfig { mode: TrainMode::Once, ..Default::default() }, Default::default(), live).unwrap();
/// p.sink("trainer", spectra, trainer);
/// let report = p.run(RunOptions::default()).unwrap();
/// println!("{}", report.table());
/// ```
pub struct Pipeline<X: Transport = Dynamic> {
    ctx: PipelineContext,
    data: DataDir,
    live: Arc<LiveModel>,
    capacity: usize,
    spawns: Vec<Spawn>,
    transport: X,
}

/// What [`RunOptions::on_signal`] is told.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SignalEvent {
    /// The first Ctrl-C / SIGTERM: the pipeline finishes the jobs in flight and stops.
    ShuttingDown,
    /// Another signal while shutting down: the caller may exit at once (the data folder's
    /// running marker is already removed, so the next start is not taken for a crash; claimed
    /// inputs are taken up again then).
    Again,
}

/// How [`Pipeline::run`] behaves.
#[derive(Clone, Copy, Debug, Default)]
pub struct RunOptions {
    /// Shut down gracefully on Ctrl-C or SIGTERM. Default false (the command-line tool sets it).
    pub handle_signals: bool,
    /// Called on each signal when `handle_signals` is set (the command-line tool prints a line,
    /// and exits at [`SignalEvent::Again`]); the library itself never prints or exits.
    pub on_signal: Option<fn(SignalEvent)>,
    /// Worker threads of the async runtime that moves envelopes (CPU work runs on its blocking
    /// pool and rayon). Default 2.
    pub worker_threads: Option<usize>,
    /// Shut down after this long (for benchmarks and tests).
    pub stop_after: Option<Duration>,
    /// Log every actor's metrics at this interval (`tracing` info; the daemon uses a minute).
    pub metrics_every: Option<Duration>,
    /// Called on the blocking pool after each job of a stage or sink, on the thread that ran
    /// it. The command-line daemon hands the memory the job freed back to the system there
    /// (glibc's `malloc_trim`): a burst of scans otherwise leaves freed blocks resident in the
    /// allocator's arenas. The library itself does not tune the process's allocator.
    pub after_job: Option<fn()>,
}

/// What a finished pipeline did.
#[derive(Clone, Debug)]
pub struct PipelineReport {
    /// Per-actor metrics, in creation order.
    pub stages: Vec<StageSummary>,
    /// Wall-clock seconds.
    pub elapsed_s: f64,
    /// Whether it stopped on a shutdown signal (rather than running out of input).
    pub interrupted: bool,
    /// The live model's version at the end (0: none).
    pub model_version: u64,
    /// Failures of actors themselves (a source that could not list its folder, a trainer
    /// whose training failed), as opposed to rejected jobs.
    pub problems: Vec<String>,
    /// Results for the caller to show, in the order the sinks finished (an evaluation's table).
    pub summary: Vec<String>,
}

impl PipelineReport {
    /// Jobs that reached a sink with a result.
    pub fn completed(&self) -> u64 {
        self.stages.iter().map(|s| s.completed).sum()
    }

    /// Jobs that reached a sink failed (bad input or an internal error; not interrupted).
    pub fn rejected(&self) -> u64 {
        self.stages.iter().map(|s| s.rejected).sum()
    }
}

impl PipelineReport {
    /// The metrics as a table, one line per actor.
    pub fn table(&self) -> String {
        use std::fmt::Write as _;
        let mut t = format!(
            "{:<18} {:>6} {:>7} {:>8} {:>9} {:>9}\n",
            "actor", "jobs", "failed", "skipped", "mean s", "max s"
        );
        for s in &self.stages {
            let _ = writeln!(
                t,
                "{:<18} {:>6} {:>7} {:>8} {:>9.3} {:>9.3}",
                s.name, s.jobs, s.failed, s.passed_on, s.mean_s, s.max_s
            );
        }
        t
    }
}

impl Pipeline {
    /// An empty pipeline over a data folder and a live model.
    pub fn new(data: DataDir, live: Arc<LiveModel>) -> Self {
        Self::with_context(data, live, PipelineContext::new())
    }

    /// An empty pipeline with a given context (e.g. one whose shutdown flag the caller holds).
    pub fn with_context(data: DataDir, live: Arc<LiveModel>, ctx: PipelineContext) -> Self {
        Self { ctx, data, live, capacity: 2, spawns: Vec::new(), transport: Dynamic::default() }
    }
}

impl<X: Transport> Pipeline<X> {
    /// The same pipeline, connecting the actors added from now on with `transport`.
    pub fn with_transport<Y: Transport>(self, transport: Y) -> Pipeline<Y> {
        let Self { ctx, data, live, capacity, spawns, .. } = self;
        Pipeline { ctx, data, live, capacity, spawns, transport }
    }

    /// Capacity of every channel created after this call (default 2: a burst of inputs waits
    /// on disk, not in memory).
    pub fn with_capacity(mut self, capacity: usize) -> Self {
        self.capacity = capacity.max(1);
        self
    }

    /// The same pipeline, connecting the actors added from now on with `transport`, keeping
    /// its type (a pipeline built from a file: see [`super::config::build_with`]).
    pub fn set_transport(&mut self, transport: X) {
        self.transport = transport;
    }

    /// The shared context (shutdown flag, metrics).
    pub fn context(&self) -> &PipelineContext {
        &self.ctx
    }

    /// The data folder.
    pub fn data(&self) -> &DataDir {
        &self.data
    }

    /// The live model.
    pub fn live_model(&self) -> &Arc<LiveModel> {
        &self.live
    }

    /// Connects an edge `producer → consumer` through the pipeline's transport.
    pub(crate) fn connect_edge<T: Payload>(
        &self,
        producer: &str,
        consumer: &str,
    ) -> (Arc<dyn Sender<T>>, Box<dyn super::transport::Receiver<T>>) {
        self.transport.connect(producer, consumer, self.capacity)
    }

    /// Adds a source.
    pub fn source<S: Source>(&mut self, name: &str, source: S) -> Port<S::Out> {
        let port = Port::new(name);
        let (ctx, n, out) = (self.ctx.clone(), name.to_string(), port.clone());
        let metrics = self.ctx.metrics_for(name);
        self.spawns.push(Box::new(move || tokio::spawn(run_source(source, n, out.output(), ctx, metrics))));
        port
    }

    /// Adds a stage reading `input` (which may feed other actors too).
    pub fn stage<S: Stage>(&mut self, name: &str, input: Port<S::In>, stage: S) -> Port<S::Out> {
        let (tx, rx) = self.transport.connect(&input.producer, name, self.capacity);
        input.attach(tx);
        let port = Port::new(name);
        let (ctx, n, out) = (self.ctx.clone(), name.to_string(), port.clone());
        let metrics = self.ctx.metrics_for(name);
        self.spawns.push(Box::new(move || tokio::spawn(run_stage(stage, n, rx, out.output(), ctx, metrics))));
        port
    }

    /// Adds a sink reading `input` (which may feed other actors too).
    pub fn sink<S: Sink>(&mut self, name: &str, input: Port<S::In>, sink: S) {
        let (tx, rx) = self.transport.connect(&input.producer, name, self.capacity);
        input.attach(tx);
        let n = name.to_string();
        let metrics = self.ctx.metrics_for(name);
        let ctx = self.ctx.clone();
        self.spawns.push(Box::new(move || tokio::spawn(run_sink(sink, n, rx, metrics, ctx))));
    }

    /// Runs every actor until the sources are exhausted and every job has reached its sink,
    /// or until shutdown (signal, [`RunOptions::stop_after`], or the context's flag).
    pub fn run(self, options: RunOptions) -> Result<PipelineReport, Error> {
        let t0 = Instant::now();
        self.ctx.set_after_job(options.after_job);
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(options.worker_threads.unwrap_or(2).max(1))
            .thread_name("shapeforest-actor")
            .enable_all()
            .build()
            .map_err(Error::Runtime)?;
        let ctx = self.ctx.clone();
        let live = self.live.clone();
        let run_ctx = self.ctx.clone();
        let marker = self.data.running_marker();
        rt.block_on(async move {
            let ctx = run_ctx;
            let handles: Vec<_> = self.spawns.into_iter().map(|s| s()).collect();
            let reporter = options.metrics_every.map(|every| {
                let ctx = ctx.clone();
                tokio::spawn(async move {
                    let mut tick = tokio::time::interval(every);
                    tick.tick().await;
                    loop {
                        tick.tick().await;
                        for s in ctx.summaries() {
                            tracing::info!(
                                actor = %s.name,
                                jobs = s.jobs,
                                failed = s.failed,
                                mean_s = s.mean_s,
                                max_s = s.max_s,
                                "metrics"
                            );
                        }
                    }
                })
            });
            let watcher = {
                let shutdown = ctx.shutdown.clone();
                tokio::spawn(async move {
                    let deadline = async {
                        match options.stop_after {
                            Some(d) => tokio::time::sleep(d).await,
                            None => std::future::pending::<()>().await,
                        }
                    };
                    tokio::select! {
                        _ = shutdown_signal(options.handle_signals) => {
                            shutdown.trigger();
                            if let Some(tell) = options.on_signal {
                                tell(SignalEvent::ShuttingDown);
                            }
                            tokio::spawn(async move {
                                loop {
                                    shutdown_signal(true).await;
                                    // Asked for, not a crash: in-flight inputs are not suspects.
                                    let _ = std::fs::remove_file(&marker);
                                    if let Some(tell) = options.on_signal {
                                        tell(SignalEvent::Again);
                                    }
                                }
                            });
                        }
                        _ = deadline => shutdown.trigger(),
                        _ = shutdown.triggered() => {}
                    }
                })
            };
            for h in handles {
                let _ = h.await;
            }
            watcher.abort();
            if let Some(r) = reporter {
                r.abort();
            }
        });
        rt.shutdown_timeout(Duration::from_secs(1));
        Ok(PipelineReport {
            stages: ctx.summaries(),
            elapsed_s: t0.elapsed().as_secs_f64(),
            interrupted: ctx.shutdown.is_triggered(),
            model_version: live.version(),
            problems: ctx.problems(),
            summary: ctx.summary(),
        })
    }
}

/// Resolves on Ctrl-C or SIGTERM when `enabled`, never otherwise.
async fn shutdown_signal(enabled: bool) {
    if !enabled {
        return std::future::pending().await;
    }
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        match signal(SignalKind::terminate()) {
            Ok(mut term) => {
                tokio::select! {
                    _ = tokio::signal::ctrl_c() => {}
                    _ = term.recv() => {}
                }
            }
            Err(_) => {
                let _ = tokio::signal::ctrl_c().await;
            }
        }
    }
    #[cfg(not(unix))]
    {
        let _ = tokio::signal::ctrl_c().await;
    }
}
