//! The pipeline layer in-process: pipeline files and their validation, actors that survive
//! bad jobs, back-pressure, the live model, crash recovery of the data folder, and the
//! evaluation pipeline end to end on synthetic data.

use std::{
    path::Path,
    sync::{
        atomic::{AtomicUsize, Ordering},
        Arc, Mutex,
    },
    thread,
    time::Duration,
};

use shapeforest::pipeline::{
    self, daemon::run_spec, DataDir, Emitter, Envelope, Failure, FailureKind, Job, LiveModel, NoModel,
    Pipeline, PipelineSpec, RunOptions, Shutdown, Sink, Source, Stage,
};

#[test]
fn shipped_pipelines_are_valid() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines");
    let mut names = Vec::new();
    for entry in std::fs::read_dir(&dir).unwrap() {
        let p = entry.unwrap().path();
        if p.extension().is_some_and(|e| e == "toml") {
            let spec = PipelineSpec::from_file(&p).unwrap_or_else(|e| panic!("{e}"));
            names.push(spec.name);
        }
    }
    names.sort();
    assert_eq!(names, ["eval", "match", "train", "watch"]);
    let watch = PipelineSpec::from_file(&dir.join("watch.toml")).unwrap();
    assert!(watch.is_daemon());
    // The single-view candidate count is checked like the other one.
    let text = std::fs::read_to_string(dir.join("watch.toml")).unwrap();
    assert!(text.contains("part_top_k = 20"));
    let err = PipelineSpec::from_toml(&text.replace("part_top_k = 20", "part_top_k = 0"), "watch.toml")
        .unwrap_err();
    assert!(err.to_string().contains("stage `matcher` (matcher): part_top_k = 0"), "{err}");
}

#[test]
fn a_bad_pipeline_file_lists_every_problem_by_stage_and_key() {
    let text = r#"
name = "broken"
[settings]
channel_capacity = 2
colour = "blue"

[[stage]]
name = "in"
type = "folder"
folder = "incoming"

[[stage]]
name = "read"
type = "ingest"
input = "in"

[[stage]]
name = "spectra"
type = "spectral"
input = "read"
kk = 50

[[stage]]
name = "forest"
type = "forest"
input = "read"

[[stage]]
name = "match"
type = "matcher"
input = "nowhere"
top_k = 0

[[stage]]
name = "dense"
type = "fmap"
input = "match"
growth_keep = 1.5

[[stage]]
name = "learn"
type = "trainer"
input = "spectra"
augment = ["partial-view", "holes:3"]

[[stage]]
name = "read"
type = "teleport"
input = "in"
"#;
    let err = PipelineSpec::from_toml(text, "broken.toml").unwrap_err();
    let msg = err.to_string();
    for needle in [
        "broken.toml",
        "[settings]: unknown field `colour`",
        "stage `spectra` (spectral): unknown field `kk`",
        "stage `forest`: takes descriptor but `read` emits shape",
        "stage `match` (matcher): top_k = 0",
        "stage `dense` (fmap): growth_keep = 1.5: must be in (0, 1]",
        "stage `learn` (trainer): augment `holes:3`: expected N:R",
        "unknown stage type `teleport`",
        "stage `read`: the name is used twice",
    ] {
        assert!(msg.contains(needle), "missing `{needle}` in:\n{msg}");
    }
    // One problem per line, all reported at once.
    assert!(err.problems.len() >= 6, "{msg}");
}

#[test]
fn a_pipeline_without_a_source_or_with_a_dangling_output_is_refused() {
    let text = r#"
name = "x"
[[stage]]
name = "a"
type = "spectral"
input = "b"
[[stage]]
name = "b"
type = "spectral"
input = "a"
"#;
    let msg = PipelineSpec::from_toml(text, "x.toml").unwrap_err().to_string();
    assert!(msg.contains("no source stage"), "{msg}");
    assert!(msg.contains("takes shape but `b` emits spectrum"), "{msg}");
    let text = r#"
name = "y"
[[stage]]
name = "in"
type = "folder"
folder = "x"
[[stage]]
name = "read"
type = "ingest"
input = "in"
"#;
    let msg = PipelineSpec::from_toml(text, "y.toml").unwrap_err().to_string();
    assert!(msg.contains("stage `read`: its output (shape) goes nowhere"), "{msg}");
}

/// Emits `n` numbered jobs, counting how many exist (emitted, not yet consumed).
struct Numbers {
    n: usize,
    alive: Arc<AtomicUsize>,
    peak: Arc<AtomicUsize>,
}

impl Source for Numbers {
    type Out = usize;
    fn run(&mut self, out: &Emitter<usize>) -> Result<(), pipeline::Error> {
        for i in 0..self.n {
            let now = self.alive.fetch_add(1, Ordering::SeqCst) + 1;
            self.peak.fetch_max(now, Ordering::SeqCst);
            let job = Job::generated(out.next_job_id(), format!("n{i}"));
            if !out.emit(Envelope { job, body: Ok(i) }) {
                break;
            }
        }
        Ok(())
    }
}

/// Panics on multiples of 3, otherwise squares (slowly).
struct Fragile;

impl Stage for Fragile {
    type In = usize;
    type Out = usize;
    fn process(&mut self, _job: &mut Job, i: usize) -> Result<usize, Failure> {
        thread::sleep(Duration::from_millis(5));
        if i.is_multiple_of(3) {
            panic!("cannot square {i}");
        }
        Ok(i * i)
    }
}

struct Collect {
    alive: Arc<AtomicUsize>,
    got: Arc<Mutex<Vec<Result<usize, Failure>>>>,
}

impl Sink for Collect {
    type In = usize;
    fn consume(&mut self, _job: Job, body: Result<usize, Failure>) -> Result<(), pipeline::Error> {
        self.alive.fetch_sub(1, Ordering::SeqCst);
        self.got.lock().unwrap().push(body);
        Ok(())
    }
}

/// With 1 and with 2 worker threads (timely repeats its tests across worker counts).
#[test]
fn a_panicking_job_fails_alone_and_bounded_channels_hold_back_the_source() {
    for workers in [1, 2] {
        panicking_job_fails_alone(workers);
    }
}

fn panicking_job_fails_alone(workers: usize) {
    let tmp = tempfile::tempdir().unwrap();
    let alive = Arc::new(AtomicUsize::new(0));
    let peak = Arc::new(AtomicUsize::new(0));
    let got = Arc::new(Mutex::new(Vec::new()));
    let mut p = Pipeline::new(DataDir::new(tmp.path()), Arc::new(LiveModel::new())).with_capacity(1);
    let nums = p.source("numbers", Numbers { n: 60, alive: alive.clone(), peak: peak.clone() });
    let squares = p.stage("square", nums, Fragile);
    p.sink("collect", squares, Collect { alive, got: got.clone() });
    let report = p.run(RunOptions { worker_threads: Some(workers), ..Default::default() }).unwrap();
    let got = got.lock().unwrap();
    assert_eq!(got.len(), 60, "every job reaches the sink");
    let failures: Vec<&Failure> = got.iter().filter_map(|r| r.as_ref().err()).collect();
    assert_eq!(failures.len(), 20);
    assert!(failures
        .iter()
        .all(|f| f.kind == FailureKind::Internal && f.message.contains("panic: cannot square")));
    assert!(failures.iter().all(|f| f.stage == "square"));
    assert_eq!(got.iter().filter(|r| r.is_ok()).count(), 40);
    // Capacity 1 on two edges, one job in each actor: never more than a handful alive.
    assert!(peak.load(Ordering::SeqCst) <= 6, "peak {} jobs in memory", peak.load(Ordering::SeqCst));
    let square = report.stages.iter().find(|s| s.name == "square").unwrap();
    assert_eq!((square.jobs, square.failed), (60, 20));
    assert!(!report.interrupted);
}

/// Jobs counted by [`count_job`] (the hook is a plain `fn()`, so the count is a static).
static AFTER_JOB_CALLS: AtomicUsize = AtomicUsize::new(0);

fn count_job() {
    AFTER_JOB_CALLS.fetch_add(1, Ordering::SeqCst);
}

#[test]
fn the_after_job_hook_runs_once_per_job_of_every_stage_and_sink() {
    // The daemon returns freed memory to the system there; here it only counts.
    let tmp = tempfile::tempdir().unwrap();
    let (alive, peak) = (Arc::new(AtomicUsize::new(0)), Arc::new(AtomicUsize::new(0)));
    let got = Arc::new(Mutex::new(Vec::new()));
    let mut p = Pipeline::new(DataDir::new(tmp.path()), Arc::new(LiveModel::new())).with_capacity(1);
    let nums = p.source("numbers", Numbers { n: 9, alive: alive.clone(), peak });
    let squares = p.stage("square", nums, Fragile);
    p.sink("collect", squares, Collect { alive, got: got.clone() });
    AFTER_JOB_CALLS.store(0, Ordering::SeqCst);
    p.run(RunOptions { after_job: Some(count_job), ..Default::default() }).unwrap();
    assert_eq!(got.lock().unwrap().len(), 9);
    // 9 jobs through `square` (3 of them panic: the hook still runs) and 9 into the sink
    assert_eq!(AFTER_JOB_CALLS.load(Ordering::SeqCst), 18);
}

#[test]
fn an_output_feeds_every_consumer_attached_to_it() {
    for workers in [1, 2] {
        let tmp = tempfile::tempdir().unwrap();
        let (alive, peak) = (Arc::new(AtomicUsize::new(0)), Arc::new(AtomicUsize::new(0)));
        let (a, b) = (Arc::new(Mutex::new(Vec::new())), Arc::new(Mutex::new(Vec::new())));
        let mut p = Pipeline::new(DataDir::new(tmp.path()), Arc::new(LiveModel::new())).with_capacity(1);
        let nums = p.source("numbers", Numbers { n: 12, alive: Arc::new(AtomicUsize::new(0)), peak });
        p.sink("first", nums.clone(), Collect { alive: alive.clone(), got: a.clone() });
        p.sink("second", nums, Collect { alive: Arc::new(AtomicUsize::new(100)), got: b.clone() });
        let report = p.run(RunOptions { worker_threads: Some(workers), ..Default::default() }).unwrap();
        let ok = |v: &Arc<Mutex<Vec<Result<usize, Failure>>>>| {
            v.lock().unwrap().iter().map(|r| *r.as_ref().unwrap()).collect::<Vec<_>>()
        };
        assert_eq!(ok(&a), (0..12).collect::<Vec<_>>(), "{workers} workers");
        assert_eq!(ok(&b), (0..12).collect::<Vec<_>>(), "{workers} workers");
        assert_eq!(report.completed(), 24);
    }
}

#[test]
fn a_pipeline_file_may_fan_an_output_out_to_several_stages() {
    // `spectra` feeds the trainer and the descriptor; `fmap` feeds two sinks.
    let text = r#"
name = "fan-out"
stage = [
    { name = "shapes", type = "synthetic" },
    { name = "spectra", type = "spectral", input = "shapes" },
    { name = "trainer", type = "trainer", input = "spectra" },
    { name = "descriptor", type = "descriptor", input = "spectra" },
    { name = "forest", type = "forest", input = "descriptor" },
    { name = "matcher", type = "matcher", input = "forest" },
    { name = "fmap", type = "fmap", input = "matcher" },
    { name = "results", type = "match-sink", input = "fmap" },
    { name = "scores", type = "eval-sink", input = "fmap" },
]
"#;
    let spec = PipelineSpec::from_toml(text, "fan-out.toml").unwrap();
    assert_eq!(spec.stages.len(), 9);
    assert!(spec.has_type("trainer") && spec.has_type("descriptor"));
}

#[test]
fn a_stage_type_of_ones_own_is_one_registration() {
    use shapeforest::pipeline::{parse_config, stages::SpectralConfig, Registry, StageType};
    // The built-in `spectral` under another name: registered, it parses like any type.
    const ALIAS: StageType = StageType {
        name: "eigen",
        ports: (Some(pipeline::PortType::Shape), Some(pipeline::PortType::Spectrum)),
        parse: parse_config::<SpectralConfig>,
    };
    let text = "name = \"x\"\n[[stage]]\nname = \"s\"\ntype = \"synthetic\"\n[[stage]]\nname = \"e\"\ntype = \"eigen\"\ninput = \"s\"\nk = 30\n[[stage]]\nname = \"t\"\ntype = \"trainer\"\ninput = \"e\"\n";
    let e = PipelineSpec::from_toml(text, "x.toml").unwrap_err().to_string();
    assert!(e.contains("unknown stage type `eigen`") && e.contains("spectral"), "{e}");
    let spec = PipelineSpec::from_toml_with(text, "x.toml", &Registry::builtin().with(ALIAS)).unwrap();
    assert_eq!(spec.stage("e").and_then(|s| s.config::<SpectralConfig>()).map(|c| c.k), Some(30));
}

/// Every message, model and stage type can cross threads and live as long as the pipeline.
#[test]
fn messages_models_and_stages_are_send_sync_and_static() {
    fn check<T: Send + Sync + 'static>() {}
    use shapeforest::pipeline::{stages::*, *};
    check::<Envelope<InputFile>>();
    check::<Envelope<Shape>>();
    check::<Envelope<SpectralShape>>();
    check::<Envelope<DescribedShape>>();
    check::<Envelope<PredictedShape>>();
    check::<Envelope<SparselyMatched>>();
    check::<Envelope<MatchedShape>>();
    check::<Failure>();
    check::<ModelState>();
    check::<LiveModel>();
    check::<PipelineSpec>();
    check::<pipeline::Error>();
    fn check_send<T: Send + 'static>() {}
    check_send::<FolderSource>();
    check_send::<WatchSource>();
    check_send::<SyntheticSource>();
    check_send::<IngestStage>();
    check_send::<SpectralStage>();
    check_send::<DescriptorStage>();
    check_send::<ForestStage>();
    check_send::<MatcherStage>();
    check_send::<FmapStage>();
    check_send::<MatchSink>();
    check_send::<EvalSink>();
    check_send::<TrainerSink>();
}

/// A real stage alone, between in-memory ports: send, receive, drop the sender, and the
/// output closes.
#[test]
fn the_spectral_stage_alone_between_in_memory_ports() {
    use shapeforest::pipeline::{
        actor::run_stage,
        stages::{SpectralConfig, SpectralStage},
        InProcess, Output, PipelineContext, Shape, Transport,
    };
    let ctx = PipelineContext::new();
    let (tx_in, rx_in) = InProcess.connect::<Shape>("test", "spectral", 2);
    let (tx_out, rx_out) = InProcess.connect("spectral", "test", 2);
    let stage = SpectralStage::new(&SpectralConfig { k: 20, cache: false }, None).unwrap();
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build().unwrap();
    rt.block_on(async {
        let metrics = ctx.metrics_for("spectral");
        let task =
            tokio::spawn(run_stage(stage, "spectral".into(), rx_in, Output::new(vec![tx_out]), ctx, metrics));
        let mesh = Arc::new(shapeforest::synth::icosphere(2, 1.0));
        let shape = Shape { mesh: mesh.clone(), labels: None };
        tx_in.send(Envelope { job: Job::generated(1, "ball"), body: Ok(shape) }).await.unwrap();
        let bad = Shape { mesh: Arc::new(shapeforest::synth::icosphere(0, 1.0)), labels: None };
        tx_in.send(Envelope { job: Job::generated(2, "tiny"), body: Ok(bad) }).await.unwrap();
        drop(tx_in);
        let first = rx_out.recv().await.expect("a result");
        let s = first.body.expect("a spectrum");
        assert_eq!((s.spectrum.k(), s.mesh().n_vertices()), (20, 162));
        assert_eq!(first.job.stage_seconds.len(), 1);
        let second = rx_out.recv().await.expect("the second job");
        let f = second.body.expect_err("12 vertices cannot give 20 eigenpairs");
        assert_eq!((f.stage.as_str(), f.kind), ("spectral", FailureKind::BadInput));
        assert!(rx_out.recv().await.is_none(), "the output closes once the input has");
        task.await.unwrap();
    });
}

#[test]
fn the_live_model_wait_ends_on_shutdown_or_close() {
    let live = Arc::new(LiveModel::new());
    let sd = Shutdown::new();
    let (l, s) = (live.clone(), sd.clone());
    let waiter = thread::spawn(move || l.wait(&s).err());
    thread::sleep(Duration::from_millis(150));
    assert!(!waiter.is_finished(), "waits while there is no model");
    sd.trigger();
    assert_eq!(waiter.join().unwrap(), Some(NoModel::ShuttingDown));
    let l = live.clone();
    let waiter = thread::spawn(move || l.wait(&Shutdown::new()).err());
    live.close("no labelled shape was accepted");
    assert_eq!(waiter.join().unwrap(), Some(NoModel::Closed("no labelled shape was accepted".into())));
    assert_eq!(live.version(), 0);
}

#[test]
fn recovery_commits_finished_results_and_requeues_claimed_inputs() {
    let tmp = tempfile::tempdir().unwrap();
    let data = DataDir::new(tmp.path());
    data.create().unwrap();
    // A result whose input had moved in: only the rename was missing.
    let done = data.matched().join(".partial-a-3");
    std::fs::create_dir_all(&done).unwrap();
    std::fs::write(done.join("a.map.txt"), "0\n").unwrap();
    std::fs::write(done.join(".input"), "a.off").unwrap();
    std::fs::write(done.join("a.off"), "OFF").unwrap();
    // A result written before its input moved: discarded, the input is re-matched.
    let half = data.matched().join(".partial-b-4");
    std::fs::create_dir_all(&half).unwrap();
    std::fs::write(half.join("b.map.txt"), "0\n").unwrap();
    std::fs::write(data.inflight(shapeforest::pipeline::InputKind::Scan).join("b.off"), "OFF").unwrap();
    std::fs::write(data.inflight(shapeforest::pipeline::InputKind::Labeled).join("c.off"), "OFF").unwrap();
    std::fs::write(data.inflight(shapeforest::pipeline::InputKind::Labeled).join("c.labels"), "0").unwrap();
    let rec = data.recover().unwrap();
    assert_eq!(rec.committed, vec![data.matched().join("a")]);
    assert!(data.matched().join("a").join("a.off").is_file());
    assert_eq!(rec.discarded.len(), 1);
    assert!(!half.exists());
    assert!(data.incoming().join("b.off").is_file());
    assert!(data.labeled().join("c.off").is_file() && data.labeled().join("c.labels").is_file());
    assert_eq!(rec.requeued.len(), 3);
    // Idempotent.
    assert_eq!(data.recover().unwrap(), Default::default());
}

#[test]
fn the_evaluation_pipeline_scores_held_out_synthetic_shapes() {
    let tmp = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines/eval.toml"))
        .unwrap()
        .replace("vertices = 5000", "vertices = 2000");
    let spec = PipelineSpec::from_toml(&text, "eval.toml").unwrap();
    let report = run_spec(&spec, Some(tmp.path()), RunOptions::default(), None, |_| Ok(())).unwrap();
    assert_eq!(report.model_version, 1);
    let csv = std::fs::read_to_string(tmp.path().join("eval/eval.csv")).unwrap();
    let rows: Vec<Vec<&str>> = csv.lines().skip(1).map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 4, "2 shapes × 2 methods:\n{csv}");
    for r in rows.iter().filter(|r| r[1] == "forest + regulariser") {
        let within: f64 = r[3].parse().unwrap();
        assert!(within > 0.85, "{}: {within} within 0.05", r[0]);
    }
    assert!(tmp.path().join("eval/curves.svg").is_file());
    // No model → a clear error before anything runs.
    let text =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines/match.toml")).unwrap();
    let spec = PipelineSpec::from_toml(&text, "match.toml").unwrap();
    let empty = tempfile::tempdir().unwrap();
    let err =
        run_spec(&spec, Some(empty.path()), RunOptions::default(), None, |_| Ok(())).unwrap_err().to_string();
    assert!(err.contains("no model in") && err.contains("train.toml"), "{err}");
}

#[test]
fn failures_are_values_with_a_kind() {
    let f = Failure::bad_input("ingest", "x.off: line 3: bad vertex");
    assert_eq!(f.to_string(), "stage `ingest`: x.off: line 3: bad vertex");
    assert_eq!(Failure::interrupted("fmap").kind, FailureKind::Interrupted);
}

#[test]
fn the_newest_model_that_loads_is_used_and_bad_versions_are_named() {
    use shapeforest::{
        forest::{RandomForest, TrainingSet},
        pipeline::store::{latest_model, prune_models, save_model_version, ModelManifest},
        spectral::{compute_spectrum, SpectrumParams},
        synth::{creature_family, CreatureParams},
    };
    let fam =
        creature_family(&CreatureParams { target_vertices: 800, seed: 4, ..Default::default() }, 2).unwrap();
    let n = fam.template.n_vertices();
    let set =
        TrainingSet::same_indexing(fam.shapes.iter().enumerate().map(|(i, m)| {
            (format!("s{i}"), Arc::new(compute_spectrum(m, &SpectrumParams::new(30)).unwrap()))
        }))
        .unwrap();
    let forest = RandomForest::params().n_trees(2).check().unwrap().fit(&set).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let manifest = |v: u64| ModelManifest {
        version: v,
        model_file: format!("model-v{v:06}.sfm"),
        created_unix: 0,
        reference: "s0".into(),
        training_shapes: vec!["s0".into(), "s1".into()],
        n_labels: n,
        n_trees: 2,
        k: forest.k(),
    };
    for v in 1..=3 {
        save_model_version(tmp.path(), &forest, &manifest(v)).unwrap();
    }
    // Version 3's model is damaged, version 4 has no model file at all.
    let bytes = std::fs::read(tmp.path().join("model-v000003.sfm")).unwrap();
    std::fs::write(tmp.path().join("model-v000003.sfm"), &bytes[..bytes.len() / 2]).unwrap();
    std::fs::write(tmp.path().join("model-v000004.json"), serde_json::to_string(&manifest(4)).unwrap())
        .unwrap();
    let (found, problems) = latest_model(tmp.path());
    let (m, f) = found.unwrap();
    assert_eq!(m.version, 2);
    assert_eq!(f, forest);
    assert_eq!(problems.len(), 2, "{problems:?}");
    assert!(
        problems[0].contains("model-v000004.sfm") && problems[1].contains("model-v000003.sfm"),
        "{problems:?}"
    );
    prune_models(tmp.path(), 2);
    let left: Vec<String> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".json"))
        .collect();
    assert_eq!(left.len(), 2);
}
