//! Actors: the [`Source`], [`Stage`] and [`Sink`] traits a pipeline is made of, the loops that
//! run them over the edges a [`super::Transport`] makes, and per-stage metrics.
//!
//! Every actor is a tokio task that owns its state. The work of one job (`process`, `consume`)
//! runs on tokio's blocking pool (`spawn_blocking`), where it may use rayon; executor threads
//! only move envelopes. A panic while processing a job becomes that job's failure: the actor
//! keeps its state and goes on with the next job.

use std::{
    panic::AssertUnwindSafe,
    sync::{
        atomic::{AtomicU64, Ordering},
        Arc, Mutex,
    },
    time::{Duration, Instant},
};

use super::{
    error::Error,
    message::{Envelope, Failure, FailureKind, Job, JobId},
    shutdown::Shutdown,
    transport::{Output, Payload, Receiver},
};

/// Counters of one actor, updated as it runs.
#[derive(Debug, Default)]
pub struct StageMetrics {
    name: String,
    jobs: AtomicU64,
    failed: AtomicU64,
    passed_on: AtomicU64,
    busy_ns: AtomicU64,
    max_ns: AtomicU64,
    completed: AtomicU64,
    rejected: AtomicU64,
}

impl StageMetrics {
    /// Metrics for the actor `name`.
    pub fn new(name: impl Into<String>) -> Self {
        Self { name: name.into(), ..Default::default() }
    }

    fn record(&self, elapsed: Duration, ok: bool) {
        let ns = elapsed.as_nanos() as u64;
        self.jobs.fetch_add(1, Ordering::Relaxed);
        if !ok {
            self.failed.fetch_add(1, Ordering::Relaxed);
        }
        self.busy_ns.fetch_add(ns, Ordering::Relaxed);
        self.max_ns.fetch_max(ns, Ordering::Relaxed);
    }

    /// Adds work done outside a job (a trainer's update while idle).
    fn add_busy(&self, elapsed: Duration) {
        let ns = elapsed.as_nanos() as u64;
        self.busy_ns.fetch_add(ns, Ordering::Relaxed);
        self.max_ns.fetch_max(ns, Ordering::Relaxed);
    }

    /// A snapshot.
    pub fn summary(&self) -> StageSummary {
        let jobs = self.jobs.load(Ordering::Relaxed);
        let busy = self.busy_ns.load(Ordering::Relaxed) as f64 * 1e-9;
        StageSummary {
            name: self.name.clone(),
            jobs,
            failed: self.failed.load(Ordering::Relaxed),
            passed_on: self.passed_on.load(Ordering::Relaxed),
            busy_s: busy,
            mean_s: if jobs > 0 { busy / jobs as f64 } else { 0.0 },
            max_s: self.max_ns.load(Ordering::Relaxed) as f64 * 1e-9,
            completed: self.completed.load(Ordering::Relaxed),
            rejected: self.rejected.load(Ordering::Relaxed),
        }
    }
}

/// What one actor did.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct StageSummary {
    /// Actor name.
    pub name: String,
    /// Jobs processed (sources: emitted).
    pub jobs: u64,
    /// Of which failed here.
    pub failed: u64,
    /// Failures of earlier stages passed on unprocessed.
    pub passed_on: u64,
    /// Seconds spent working.
    pub busy_s: f64,
    /// Mean seconds per job.
    pub mean_s: f64,
    /// Longest job, seconds.
    pub max_s: f64,
    /// Sinks: jobs that arrived with a result and were consumed without error.
    pub completed: u64,
    /// Sinks: jobs that arrived failed (bad input, an internal error; not interrupted ones).
    pub rejected: u64,
}

/// A function run after each job of a stage or sink ([`super::RunOptions::after_job`]).
pub type AfterJob = fn();

/// Everything the actors of one pipeline share: job numbers, the shutdown flag and metrics.
#[derive(Clone)]
pub struct PipelineContext {
    /// The shutdown flag.
    pub shutdown: Shutdown,
    next_job: Arc<AtomicU64>,
    metrics: Arc<Mutex<Vec<Arc<StageMetrics>>>>,
    problems: Arc<Mutex<Vec<String>>>,
    summary: Arc<Mutex<Vec<String>>>,
    /// Called on the blocking pool after each job of a stage or sink (see
    /// [`super::RunOptions::after_job`]).
    after_job: Arc<Mutex<Option<AfterJob>>>,
}

impl Default for PipelineContext {
    fn default() -> Self {
        Self::new()
    }
}

impl PipelineContext {
    /// A fresh context.
    pub fn new() -> Self {
        Self::with_shutdown(Shutdown::new())
    }

    /// A fresh context whose shutdown flag is `shutdown` (held by the caller, to stop the
    /// pipeline from outside).
    pub fn with_shutdown(shutdown: Shutdown) -> Self {
        Self {
            shutdown,
            next_job: Arc::new(AtomicU64::new(1)),
            metrics: Arc::new(Mutex::new(Vec::new())),
            problems: Arc::default(),
            summary: Arc::default(),
            after_job: Arc::default(),
        }
    }

    /// Sets the function called on the blocking pool after each job of a stage or sink
    /// (`None`: nothing); [`super::Pipeline::run`] sets it from
    /// [`super::RunOptions::after_job`].
    pub fn set_after_job(&self, hook: Option<AfterJob>) {
        if let Ok(mut h) = self.after_job.lock() {
            *h = hook;
        }
    }

    /// The function called after each job, if any.
    pub fn after_job(&self) -> Option<AfterJob> {
        self.after_job.lock().ok().and_then(|h| *h)
    }

    /// A new job number.
    pub fn next_job_id(&self) -> JobId {
        self.next_job.fetch_add(1, Ordering::Relaxed)
    }

    /// Registers metrics for an actor.
    pub fn metrics_for(&self, name: &str) -> Arc<StageMetrics> {
        let m = Arc::new(StageMetrics::new(name));
        if let Ok(mut all) = self.metrics.lock() {
            all.push(m.clone());
        }
        m
    }

    /// Records a failure of an actor itself (a source that stopped with an error, a sink whose
    /// start or finish failed), as opposed to a failed job.
    pub fn record_problem(&self, problem: impl Into<String>) {
        if let Ok(mut p) = self.problems.lock() {
            p.push(problem.into());
        }
    }

    /// Adds a result for the caller to show (an evaluation sink's table): the library does not
    /// print; [`super::PipelineReport::summary`] carries these.
    pub fn add_summary(&self, text: impl Into<String>) {
        if let Ok(mut s) = self.summary.lock() {
            s.push(text.into());
        }
    }

    /// The summaries added so far.
    pub fn summary(&self) -> Vec<String> {
        self.summary.lock().map(|s| s.clone()).unwrap_or_default()
    }

    /// The problems recorded so far.
    pub fn problems(&self) -> Vec<String> {
        self.problems.lock().map(|p| p.clone()).unwrap_or_default()
    }

    /// Snapshots of every actor's metrics, in creation order.
    pub fn summaries(&self) -> Vec<StageSummary> {
        match self.metrics.lock() {
            Ok(all) => all.iter().map(|m| m.summary()).collect(),
            Err(_) => Vec::new(),
        }
    }
}

/// Where a source puts what it finds. Sending blocks while the channel is full (back-pressure)
/// and gives up when the pipeline shuts down.
pub struct Emitter<T> {
    out: Mutex<Output<T>>,
    ctx: PipelineContext,
    metrics: Arc<StageMetrics>,
}

impl<T: Payload> Emitter<T> {
    /// An emitter writing to `out` (for running a source outside a [`super::Pipeline`], e.g.
    /// in a test with in-memory ports).
    pub fn new(out: Output<T>, ctx: PipelineContext, metrics: Arc<StageMetrics>) -> Self {
        Self { out: Mutex::new(out), ctx, metrics }
    }

    /// A new job number.
    pub fn next_job_id(&self) -> JobId {
        self.ctx.next_job_id()
    }

    /// The shutdown flag.
    pub fn shutdown(&self) -> &Shutdown {
        &self.ctx.shutdown
    }

    /// Sends one job downstream, waiting while the channel is full. Returns `false` when the
    /// job was not sent because the pipeline is shutting down or nothing consumes the output.
    pub fn emit(&self, envelope: Envelope<T>) -> bool {
        let ok = envelope.body.is_ok();
        let Ok(mut out) = self.out.lock() else { return false };
        let shutdown = &self.ctx.shutdown;
        let sent = out.send_blocking(envelope, Duration::from_millis(100), || shutdown.is_triggered());
        if sent {
            self.metrics.record(Duration::ZERO, ok);
        }
        sent
    }
}

/// A source of jobs (a folder, a watched folder, a generator). It runs on a blocking thread
/// until it has nothing more to give or the pipeline shuts down.
pub trait Source: Send + 'static {
    /// What it emits.
    type Out: Payload;
    /// Runs the source. An error ends it (and is logged); jobs already emitted go on.
    fn run(&mut self, out: &Emitter<Self::Out>) -> Result<(), Error>;
}

/// A processing stage: one input, one output per job.
pub trait Stage: Send + 'static {
    /// Input payload.
    type In: Payload;
    /// Output payload.
    type Out: Payload;
    /// Processes one job's payload; `job` may be annotated. An error is the job's failure.
    fn process(&mut self, job: &mut Job, input: Self::In) -> Result<Self::Out, Failure>;
}

/// The end of a chain: consumes every job, successful or failed.
pub trait Sink: Send + 'static {
    /// Input payload.
    type In: Payload;
    /// Called once before the first job (on a blocking thread).
    fn start(&mut self) -> Result<(), Error> {
        Ok(())
    }
    /// Consumes one job. An error is logged and counted; the sink goes on.
    fn consume(&mut self, job: Job, body: Result<Self::In, Failure>) -> Result<(), Error>;
    /// Called when nothing is waiting: after a job that left the input channel empty, and every
    /// [`Sink::tick`] while no job arrives (a trainer batches what has arrived and updates its
    /// model here).
    fn idle(&mut self) -> Result<(), Error> {
        Ok(())
    }
    /// How often [`Sink::idle`] is called while no job arrives (`None`: never).
    fn tick(&self) -> Option<Duration> {
        None
    }
    /// Called once when every input has arrived (the upstream closed).
    fn finish(&mut self) -> Result<(), Error> {
        Ok(())
    }
}

fn panic_message(p: Box<dyn std::any::Any + Send>) -> String {
    if let Some(s) = p.downcast_ref::<&str>() {
        s.to_string()
    } else if let Some(s) = p.downcast_ref::<String>() {
        s.clone()
    } else {
        "unknown panic".to_string()
    }
}

/// Runs `f` on `state` on the blocking pool and hands the state back with `f`'s result, or
/// with the panic message if `f` panicked (the state survives a panicking job). `None` when the
/// task was cancelled (the runtime is going down).
/// `after` runs on the same thread once `f` has returned (and dropped what it freed).
async fn on_blocking_pool<S, R>(
    mut state: S,
    f: impl FnOnce(&mut S) -> R + Send + 'static,
    after: Option<AfterJob>,
) -> Option<(S, Result<R, String>)>
where
    S: Send + 'static,
    R: Send + 'static,
{
    tokio::task::spawn_blocking(move || {
        let r = std::panic::catch_unwind(AssertUnwindSafe(|| f(&mut state)))
            .map_err(|p| format!("panic: {}", panic_message(p)));
        if let Some(after) = after {
            after();
        }
        (state, r)
    })
    .await
    .ok()
}

/// Runs a source to completion on the blocking pool.
pub async fn run_source<S: Source>(
    source: S,
    name: String,
    out: Output<S::Out>,
    ctx: PipelineContext,
    metrics: Arc<StageMetrics>,
) {
    let problems = ctx.clone();
    let emitter = Emitter::new(out, ctx, metrics);
    match on_blocking_pool(source, move |s| s.run(&emitter), None).await {
        Some((_, Ok(Ok(())))) => tracing::debug!(source = %name, "source finished"),
        Some((_, Ok(Err(e)))) => {
            tracing::error!(source = %name, "source stopped: {e}");
            problems.record_problem(format!("source `{name}` failed: {e}"));
        }
        Some((_, Err(e))) => {
            tracing::error!(source = %name, "source stopped: {e}");
            problems.record_problem(format!("source `{name}` failed: {e}"));
        }
        None => tracing::error!(source = %name, "source task was cancelled"),
    }
}

/// Runs a stage until its input closes.
pub async fn run_stage<S: Stage>(
    stage: S,
    name: String,
    rx: Box<dyn Receiver<S::In>>,
    mut out: Output<S::Out>,
    ctx: PipelineContext,
    metrics: Arc<StageMetrics>,
) {
    let mut stage = Some(stage);
    let after_job = ctx.after_job();
    while let Some(Envelope { job, body }) = rx.recv().await {
        let next = match body {
            Err(f) => {
                metrics.passed_on.fetch_add(1, Ordering::Relaxed);
                Envelope { job, body: Err(f) }
            }
            Ok(_) if ctx.shutdown.is_triggered() => {
                metrics.passed_on.fetch_add(1, Ordering::Relaxed);
                Envelope { job, body: Err(Failure::interrupted(&name)) }
            }
            Ok(input) => {
                let Some(s) = stage.take() else { break };
                let t0 = Instant::now();
                let Some(((s, mut job), r)) =
                    on_blocking_pool((s, job), move |(s, job)| s.process(job, input), after_job).await
                else {
                    tracing::error!(stage = %name, "stage task was cancelled");
                    break;
                };
                stage = Some(s);
                // Failures (and panics) are reported under the actor's name.
                let r = r
                    .unwrap_or_else(|panic| {
                        Err(Failure { stage: String::new(), kind: FailureKind::Internal, message: panic })
                    })
                    .map_err(|mut f| {
                        f.stage = name.clone();
                        f
                    });
                let dt = t0.elapsed();
                metrics.record(dt, r.is_ok());
                job.stage_seconds.push((name.clone(), dt.as_secs_f64()));
                match &r {
                    Ok(_) => {
                        tracing::debug!(stage = %name, job = job.id, shape = %job.name, "done in {:.3} s", dt.as_secs_f64())
                    }
                    Err(f) => {
                        tracing::warn!(stage = %name, job = job.id, shape = %job.name, "failed: {}", f.message)
                    }
                }
                Envelope { job, body: r }
            }
        };
        if !out.send(next).await {
            tracing::error!(stage = %name, "downstream closed; stopping");
            break;
        }
    }
}

/// Runs a sink until its input closes.
pub async fn run_sink<S: Sink>(
    sink: S,
    name: String,
    rx: Box<dyn Receiver<S::In>>,
    metrics: Arc<StageMetrics>,
    ctx: PipelineContext,
) {
    let rx: Arc<dyn Receiver<S::In>> = Arc::from(rx);
    let after_job = ctx.after_job();
    let log = |what: &str, r: Result<Result<(), Error>, String>| {
        if let Err(e) = r.map_err(Error::Panic).and_then(|r| r) {
            tracing::error!(sink = %name, "{what}{e}");
            if !what.is_empty() {
                ctx.record_problem(format!("sink `{name}`: {what}{e}"));
            }
        }
    };
    let Some((s, r)) = on_blocking_pool(sink, |s| s.start(), None).await else { return };
    log("start failed: ", r);
    let tick = s.tick();
    let mut sink = Some(s);
    loop {
        let received = match tick {
            None => rx.recv().await,
            Some(t) => match tokio::time::timeout(t, rx.recv()).await {
                Ok(r) => r,
                Err(_) => {
                    // Nothing arrived for a while: let the sink act on what it holds.
                    let Some(s) = sink.take() else { break };
                    let t0 = Instant::now();
                    let Some((s, r)) = on_blocking_pool(s, |s| s.idle(), None).await else { break };
                    if t0.elapsed() > Duration::from_millis(5) {
                        metrics.add_busy(t0.elapsed());
                    }
                    sink = Some(s);
                    log("", r);
                    continue;
                }
            },
        };
        let Some(Envelope { job, body }) = received else { break };
        match &body {
            Ok(_) => {}
            Err(f) if f.kind == FailureKind::Interrupted => {}
            Err(_) => {
                metrics.rejected.fetch_add(1, Ordering::Relaxed);
            }
        }
        let arrived_ok = body.is_ok();
        let Some(s) = sink.take() else { break };
        let t0 = Instant::now();
        let waiting = rx.clone();
        let consumed = on_blocking_pool(
            s,
            move |s| {
                let r = s.consume(job, body);
                // A durable queue acknowledges the job, or delivers it again, by this outcome.
                waiting.consumed(r.as_ref().map(|_| ()).map_err(|e| e.to_string()));
                // Let a batching sink act once nothing else is waiting.
                if waiting.is_empty() {
                    r.and_then(|_| s.idle())
                } else {
                    r
                }
            },
            after_job,
        )
        .await;
        let Some((s, r)) = consumed else {
            tracing::error!(sink = %name, "sink task was cancelled");
            break;
        };
        sink = Some(s);
        let ok = matches!(r, Ok(Ok(())));
        metrics.record(t0.elapsed(), ok);
        if arrived_ok && ok {
            metrics.completed.fetch_add(1, Ordering::Relaxed);
        }
        log("", r);
    }
    if let Some(s) = sink {
        let t0 = Instant::now();
        let finished = on_blocking_pool(s, |s| s.finish(), None).await;
        metrics.add_busy(t0.elapsed());
        if let Some((_, r)) = finished {
            log("finish failed: ", r);
        }
    }
}
