//! The transport's own cost per job: a pipeline of no-op stages (a source of N small input
//! files → a stage that passes them on → a counting sink), run in process and on NATS
//! JetStream in the same run. Prints jobs/s and the latency source → sink.
//!
//! ```sh
//! nats-server -js -sd /tmp/js -p 4222 &
//! cargo run --release --example transport_overhead -- nats://127.0.0.1:4222 2000
//! ```

use std::{
    collections::HashSet,
    path::{Path, PathBuf},
    sync::{Arc, Mutex},
    time::Instant,
};

use shapeforest::pipeline::{
    nats::{Nats, NatsSettings, NatsTransport},
    DataDir, Dynamic, Emitter, Envelope, Error, Failure, InputFile, Job, LiveModel, Pipeline,
    PipelineContext, RunOptions, ServeNeeds, Shutdown, Sink, Source, Stage,
};

struct Files {
    path: PathBuf,
    n: usize,
}

impl Source for Files {
    type Out = InputFile;
    fn run(&mut self, out: &Emitter<InputFile>) -> Result<(), Error> {
        for _ in 0..self.n {
            let job = Job::for_file(out.next_job_id(), &self.path, None);
            if !out.emit(Envelope { job, body: Ok(InputFile { path: self.path.clone(), labels: None }) }) {
                break;
            }
        }
        Ok(())
    }
}

struct PassOn;

impl Stage for PassOn {
    type In = InputFile;
    type Out = InputFile;
    fn process(&mut self, _: &mut Job, input: InputFile) -> Result<InputFile, Failure> {
        Ok(input)
    }
}

struct Count {
    n: usize,
    latencies: Arc<Mutex<Vec<f64>>>,
    done: Shutdown,
}

impl Sink for Count {
    type In = InputFile;
    fn consume(&mut self, job: Job, _: Result<InputFile, Failure>) -> Result<(), Error> {
        let mut l = self.latencies.lock().unwrap();
        l.push(job.started.elapsed().as_secs_f64());
        if l.len() >= self.n {
            self.done.trigger();
        }
        Ok(())
    }
}

fn run(label: &str, n: usize, file: &Path, data: &DataDir, nats: Option<Arc<Nats>>) -> anyhow::Result<()> {
    let done = Shutdown::new();
    let live = Arc::new(LiveModel::new());
    let ctx = PipelineContext::with_shutdown(done.clone());
    let mut p = Pipeline::with_context(data.clone(), live.clone(), ctx).with_capacity(2);
    if let Some(nats) = &nats {
        let sinks: HashSet<String> = ["count".to_string()].into();
        let t = NatsTransport::with_sinks(
            nats.clone(),
            sinks,
            ServeNeeds::default(),
            data.clone(),
            live,
            done.clone(),
        );
        p.set_transport(Dynamic::new(Arc::new(t)));
    }
    let latencies = Arc::new(Mutex::new(Vec::new()));
    let src = p.source("files", Files { path: file.to_path_buf(), n });
    let passed = p.stage("pass-on", src, PassOn);
    p.sink("count", passed, Count { n, latencies: latencies.clone(), done });
    let t0 = Instant::now();
    p.run(RunOptions::default())?;
    let dt = t0.elapsed().as_secs_f64();
    let mut l = latencies.lock().unwrap().clone();
    l.sort_by(f64::total_cmp);
    let pct = |q: f64| {
        l.get(((l.len() as f64 * q) as usize).min(l.len().saturating_sub(1))).copied().unwrap_or(0.0)
    };
    println!(
        "{label:<12} {:>6} jobs in {dt:>6.2} s: {:>8.0} jobs/s; latency median {:>7.2} ms, p95 {:>7.2} ms",
        l.len(),
        l.len() as f64 / dt,
        pct(0.5) * 1e3,
        pct(0.95) * 1e3
    );
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let url = args.get(1).cloned().unwrap_or_else(|| "nats://127.0.0.1:4222".into());
    let n: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(2000);
    let dir = std::env::temp_dir().join(format!("shapeforest-overhead-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let file = dir.join("scan.off");
    std::fs::write(&file, "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")?;
    let data = DataDir::new(dir.join("data"));
    run("in-process", n, &file, &data, None)?;
    let settings = NatsSettings {
        url,
        prefix: format!("overhead{}", std::process::id()),
        ack_wait: std::time::Duration::from_secs(30),
        max_deliver: 5,
        max_ack_pending: 64,
        max_object_bytes: 1 << 20,
    };
    let nats = Nats::connect(settings)?;
    run("nats", n, &file, &data, Some(nats.clone()))?;
    drop(nats);
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}
