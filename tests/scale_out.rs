//! The pipeline past one machine: real `nats-server` (JetStream, file storage), real worker
//! processes (`shapeforest worker`, `results`, `submit`) on the watch pipeline.
//!
//! Each test starts its own server on a free loopback port; without `nats-server` the tests
//! say SKIPPED (and fail under `CI=true`; see tests/common/nats.rs).

mod common;

use std::{
    ffi::OsStr,
    path::{Path, PathBuf},
    process::{Command, Stdio},
    thread,
    time::{Duration, Instant},
};

use common::{daemon::*, nats::NatsServer};
use shapeforest::{
    pipeline::nats::{model_sync, Nats, NatsSettings},
    synth::{creature_family, CreatureParams},
};

/// The watch pipeline for workers: a short ack wait (a dead worker's job comes back in 2 s)
/// and the given extra settings.
fn pipeline(dir: &Path, extra: &str) -> PathBuf {
    let p = pipeline_file(&dir.join("p"), |t| {
        t.replace("[settings]\n", &format!("[settings]\nnats_ack_wait_s = 2\n{extra}\n"))
    });
    assert!(std::fs::read_to_string(&p).unwrap().contains("nats_ack_wait_s = 2"));
    p
}

/// What every test starts from: a temporary folder, a running server, a data folder with a
/// trained model (not yet published) and the workers' pipeline file with `extra` settings.
/// `None` (the test skips, saying why) where no nats-server is installed outside CI.
struct Cluster {
    server: NatsServer,
    url: String,
    data: PathBuf,
    p: PathBuf,
    dir: tempfile::TempDir,
}

impl Cluster {
    fn start(extra: &str) -> Option<Cluster> {
        let dir = tempfile::tempdir().unwrap();
        let server = NatsServer::start(dir.path())?;
        let url = server.url();
        let data = trained_copy(dir.path());
        let p = pipeline(dir.path(), extra);
        Some(Cluster { server, url, data, p, dir })
    }
}

fn spawn(dir: &Path, name: &str, args: &[&OsStr]) -> Daemon {
    let log = dir.join(format!("{name}.log"));
    let out = std::fs::OpenOptions::new().create(true).append(true).open(&log).unwrap();
    let child = Command::new(bin())
        .args(args)
        .env("RUST_LOG", "info")
        .stdin(Stdio::null())
        .stdout(out.try_clone().unwrap())
        .stderr(out)
        .spawn()
        .unwrap();
    Daemon { child, log }
}

fn worker(dir: &Path, p: &Path, url: &str, name: &str, stages: Option<&str>) -> Daemon {
    let data = dir.join(name);
    let mut args: Vec<&OsStr> = vec![
        "worker".as_ref(),
        p.as_os_str(),
        "--nats".as_ref(),
        url.as_ref(),
        "--data-dir".as_ref(),
        data.as_os_str(),
    ];
    if let Some(s) = stages {
        args.extend(["--stages".as_ref(), OsStr::new(s)]);
    }
    spawn(dir, name, &args)
}

fn results(dir: &Path, p: &Path, url: &str, out: &Path) -> Daemon {
    let args: Vec<&OsStr> = vec![
        "results".as_ref(),
        "--pipeline".as_ref(),
        p.as_os_str(),
        "--nats".as_ref(),
        url.as_ref(),
        "--out".as_ref(),
        out.as_os_str(),
    ];
    spawn(dir, "results", &args)
}

fn submit(p: &Path, url: &str, extra: &[&OsStr]) -> String {
    let mut args: Vec<&OsStr> =
        vec!["submit".as_ref(), "--pipeline".as_ref(), p.as_os_str(), "--nats".as_ref(), url.as_ref()];
    args.extend_from_slice(extra);
    let (status, out, err) = run_cli(&args, timeout());
    assert!(status.success(), "submit failed: {out}\n{err}");
    out
}

fn submit_files(p: &Path, url: &str, files: &[PathBuf]) {
    let f: Vec<&OsStr> = files.iter().map(|f| f.as_os_str()).collect();
    let out = submit(p, url, &f);
    assert!(out.contains(&format!("submitted {} file(s)", files.len())), "{out}");
}

fn publish_model(p: &Path, url: &str, data: &Path) {
    let out = submit(p, url, &["--model-from".as_ref(), data.as_os_str()]);
    assert!(out.contains("current model: v"), "{out}");
}

/// Scans `first..first + n` of the test family, written into `dir`.
fn scans(dir: &Path, first: usize, n: usize) -> Vec<PathBuf> {
    scans_of(dir, first, n, VERTICES)
}

/// The same scans with about `vertices` vertices each.
fn scans_of(dir: &Path, first: usize, n: usize, vertices: usize) -> Vec<PathBuf> {
    std::fs::create_dir_all(dir).unwrap();
    let params = CreatureParams { target_vertices: vertices, seed: 1, ..Default::default() };
    let fam = creature_family(&params, first + n).unwrap();
    (first..first + n)
        .map(|i| {
            let p = dir.join(format!("scan-creature{i}.off"));
            shapeforest::mesh::write_mesh(&p, &fam.shapes[i]).unwrap();
            p
        })
        .collect()
}

fn client(url: &str) -> std::sync::Arc<Nats> {
    client_with(url, 64)
}

/// A client that creates edge consumers as workers with `max_ack_pending` would.
fn client_with(url: &str, max_ack_pending: usize) -> std::sync::Arc<Nats> {
    Nats::connect(NatsSettings {
        url: url.into(),
        prefix: "shapeforest".into(),
        ack_wait: Duration::from_secs(2),
        max_deliver: 5,
        max_ack_pending,
        max_object_bytes: 1 << 30,
    })
    .unwrap()
}

/// (waiting, delivered and unacknowledged) on an edge.
fn backlog(nats: &Nats, producer: &str, consumer: &str) -> (u64, usize) {
    nats.block_on(nats.edge_backlog(&nats.edge(producer, consumer))).unwrap()
}

fn wait_for(what: &str, procs: &mut [&mut Daemon], mut cond: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !cond() {
        for p in procs.iter_mut() {
            p.assert_running();
        }
        assert!(
            t0.elapsed() < timeout(),
            "timed out waiting for {what}:\n{}",
            procs.iter().map(|p| p.log()).collect::<Vec<_>>().join("\n----\n")
        );
        thread::sleep(Duration::from_millis(100));
    }
}

fn ledger(out: &Path) -> usize {
    files_in(&out.join(".nats/done/results")).len()
}

/// Jobs the worker's stage `stage` processed, from the table it prints when it stops.
fn jobs_of(log: &str, stage: &str) -> u64 {
    log.lines()
        .filter_map(|l| l.strip_prefix(stage))
        .filter_map(|rest| rest.split_whitespace().next()?.parse().ok())
        .next_back()
        .unwrap_or_else(|| panic!("no `{stage}` row in:\n{log}"))
}

fn rejected_reports(out: &Path) -> Vec<String> {
    files_in(&out.join("rejected")).into_iter().filter(|f| f.ends_with(".error.json")).collect()
}

#[test]
fn three_workers_match_each_scan_exactly_once_as_the_daemon_does() {
    let Some(Cluster { dir, server: _server, url, data, p }) = Cluster::start("") else { return };
    // Model v1 and the in-process daemon's results for scans 6 and 7.
    publish_model(&p, &url, &data);
    let mut inputs: Vec<PathBuf> =
        (6..8).map(|i| data.join(format!("matched/scan-creature{i}/scan-creature{i}.off"))).collect();
    inputs.extend(scans(&dir.path().join("in"), 8, 4));
    let out = dir.path().join("out");
    let mut ws: Vec<Daemon> = (0..3).map(|i| worker(dir.path(), &p, &url, &format!("w{i}"), None)).collect();
    let mut r = results(dir.path(), &p, &url, &out);
    submit_files(&p, &url, &inputs);
    {
        let mut procs: Vec<&mut Daemon> = ws.iter_mut().collect();
        procs.push(&mut r);
        wait_for("6 results", &mut procs, || result_dirs(&out).len() >= 6);
    }
    thread::sleep(Duration::from_secs(2));
    let names = result_dirs(&out);
    let mut want: Vec<String> = (6..12).map(|i| format!("scan-creature{i}")).collect();
    want.sort();
    assert_eq!(names, want, "each scan once, nothing twice");
    assert_eq!(ledger(&out), 6);
    assert!(rejected_reports(&out).is_empty(), "{:?}", rejected_reports(&out));
    for n in ["scan-creature6", "scan-creature7"] {
        let daemon = std::fs::read_to_string(data.join(format!("matched/{n}/{n}.map.txt"))).unwrap();
        let workers = std::fs::read_to_string(out.join(format!("matched/{n}/{n}.map.txt"))).unwrap();
        assert!(daemon == workers, "{n}: the workers' map differs from the in-process daemon's");
    }
    let nats = client(&url);
    assert_eq!(backlog(&nats, "scans", "read-scans"), (0, 0));
    assert_eq!(backlog(&nats, "fmap", "results"), (0, 0));
    let jobs: Vec<u64> = ws.drain(..).map(|w| jobs_of(&w.stop(), "read-scans")).collect();
    assert_eq!(jobs.iter().sum::<u64>(), 6, "every scan read once over the workers: {jobs:?}");
    assert!(jobs.iter().filter(|&&j| j > 0).count() >= 2, "the work was shared: {jobs:?}");
    r.stop();
}

#[test]
fn a_killed_workers_job_is_redelivered_and_finished_once() {
    let Some(Cluster { dir, server: _server, url, data, p }) = Cluster::start("") else { return };
    let out = dir.path().join("out");
    let nats = client(&url);
    // No model yet: the first worker reads the scan, computes its spectrum and holds the job
    // in its descriptor stage (waiting for a model).
    let mut a = worker(dir.path(), &p, &url, "a", None);
    let mut r = results(dir.path(), &p, &url, &out);
    submit_files(&p, &url, &scans(&dir.path().join("in"), 8, 1));
    wait_for("worker a to hold the job", &mut [&mut a, &mut r], || {
        backlog(&nats, "scan-spectra", "descriptor").1 == 1
    });
    thread::sleep(Duration::from_secs(3)); // beyond the ack wait: progress acks keep it with a
    assert_eq!(backlog(&nats, "scan-spectra", "descriptor"), (0, 1), "held by a, not redelivered");
    assert_eq!(backlog(&nats, "scans", "read-scans"), (0, 0), "the earlier edges are done with");
    a.kill();
    publish_model(&p, &url, &data);
    let mut b = worker(dir.path(), &p, &url, "b", None);
    wait_for("the result", &mut [&mut b, &mut r], || result_dirs(&out).len() == 1);
    thread::sleep(Duration::from_secs(3));
    assert_eq!(result_dirs(&out), vec!["scan-creature8".to_string()]);
    assert_eq!(ledger(&out), 1);
    assert_eq!(backlog(&nats, "scan-spectra", "descriptor"), (0, 0));
    let b_log = b.stop();
    assert_eq!(jobs_of(&b_log, "read-scans"), 0, "read once, by a");
    assert_eq!(jobs_of(&b_log, "descriptor"), 1, "the held job, redelivered to b");
    r.stop();
}

/// The watch pipeline's scan chain, edge by edge.
const SCAN_EDGES: [(&str, &str); 7] = [
    ("scans", "read-scans"),
    ("read-scans", "scan-spectra"),
    ("scan-spectra", "descriptor"),
    ("descriptor", "forest"),
    ("forest", "matcher"),
    ("matcher", "fmap"),
    ("fmap", "results"),
];

#[test]
fn stages_split_over_two_workers_give_the_daemons_maps() {
    let Some(Cluster { dir, server: _server, url, data, p }) = Cluster::start("") else { return };
    publish_model(&p, &url, &data);
    let inputs: Vec<PathBuf> =
        (6..8).map(|i| data.join(format!("matched/scan-creature{i}/scan-creature{i}.off"))).collect();
    let out = dir.path().join("out");
    // One worker reads scans and computes spectra, the other does the rest: every edge between
    // them travels (spectra, and the model as its version).
    let mut a = worker(dir.path(), &p, &url, "a", Some("read-scans,scan-spectra"));
    let mut b = worker(dir.path(), &p, &url, "b", Some("descriptor,forest,matcher,fmap"));
    let mut r = results(dir.path(), &p, &url, &out);
    submit_files(&p, &url, &inputs);
    wait_for("2 results", &mut [&mut a, &mut b, &mut r], || result_dirs(&out).len() >= 2);
    thread::sleep(Duration::from_secs(2));
    assert_eq!(result_dirs(&out), vec!["scan-creature6".to_string(), "scan-creature7".to_string()]);
    for n in ["scan-creature6", "scan-creature7"] {
        let daemon = std::fs::read_to_string(data.join(format!("matched/{n}/{n}.map.txt"))).unwrap();
        let workers = std::fs::read_to_string(out.join(format!("matched/{n}/{n}.map.txt"))).unwrap();
        assert!(daemon == workers, "{n}: the split workers' map differs from the in-process daemon's");
    }
    let nats = client(&url);
    for (from, to) in SCAN_EDGES {
        assert_eq!(backlog(&nats, from, to), (0, 0), "{from} → {to}");
    }
    let (a_log, b_log) = (a.stop(), b.stop());
    assert_eq!(jobs_of(&a_log, "scan-spectra"), 2, "{a_log}");
    assert_eq!(jobs_of(&b_log, "fmap"), 2, "{b_log}");
    assert!(!b_log.lines().any(|l| l.starts_with("scan-spectra")), "b ran no spectra:\n{b_log}");
    r.stop();
}

fn dead_letters(nats: &Nats) -> Vec<String> {
    nats.block_on(async {
        let mut s = nats.jetstream().get_stream("shapeforest_DEAD").await.unwrap();
        let n = s.info().await.unwrap().state.last_sequence;
        let mut errors = Vec::new();
        for seq in 1..=n {
            if let Ok(m) = s.get_raw_message(seq).await {
                errors.push(
                    m.headers.get("Shapeforest-Error").map(|v| v.as_str().to_string()).unwrap_or_default(),
                );
            }
        }
        errors
    })
}

#[test]
fn a_result_that_cannot_be_written_is_retried_then_dead_lettered_never_acknowledged() {
    let Some(Cluster { dir, server: _server, url, data, p }) = Cluster::start("nats_max_deliver = 3") else {
        return;
    };
    publish_model(&p, &url, &data);
    let out = dir.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    // `matched` is a file: no result folder can be made (as on a full or read-only disk).
    std::fs::write(out.join("matched"), "not a folder").unwrap();
    let mut w = worker(dir.path(), &p, &url, "w", None);
    let mut r = results(dir.path(), &p, &url, &out);
    submit_files(&p, &url, &scans(&dir.path().join("in"), 8, 1));
    wait_for_log(&mut r, "a failed write handed back", |l| l.contains("delivered again in"));
    // The disk is fixed: the next delivery writes the result, once.
    std::fs::remove_file(out.join("matched")).unwrap();
    wait_for("the result", &mut [&mut w, &mut r], || result_dirs(&out).len() == 1);
    thread::sleep(Duration::from_secs(2));
    assert_eq!(result_dirs(&out), vec!["scan-creature8".to_string()]);
    assert_eq!(ledger(&out), 1);
    let nats = client(&url);
    assert_eq!(backlog(&nats, "fmap", "results"), (0, 0));
    assert!(dead_letters(&nats).is_empty());
    // It stays broken: three deliveries, then the dead letters, with the error.
    std::fs::remove_dir_all(out.join("matched")).unwrap();
    std::fs::write(out.join("matched"), "not a folder").unwrap();
    submit_files(&p, &url, &scans(&dir.path().join("in2"), 9, 1));
    wait_for("the dead letter", &mut [&mut w, &mut r], || dead_letters(&nats).len() == 1);
    let why = &dead_letters(&nats)[0];
    assert!(why.contains("cannot write the result") && why.contains("3 deliveries"), "{why}");
    thread::sleep(Duration::from_secs(1));
    assert_eq!(backlog(&nats, "fmap", "results"), (0, 0), "not waiting, not held");
    assert_eq!(ledger(&out), 1, "the failed job is not recorded as done");
    w.stop();
    r.stop();
}

#[test]
fn a_result_written_before_its_acknowledgement_was_lost_is_not_written_again() {
    let Some(Cluster { dir, server: _server, url, data, p }) = Cluster::start("") else { return };
    publish_model(&p, &url, &data);
    let out = dir.path().join("out");
    let nats = client(&url);
    let mut w = worker(dir.path(), &p, &url, "w", None);
    submit_files(&p, &url, &scans(&dir.path().join("in"), 8, 1));
    wait_for("the map waiting for a sink", &mut [&mut w], || backlog(&nats, "fmap", "results").0 == 1);
    // A copy of the map message, as the server would deliver it again.
    let edge = nats.edge("fmap", "results");
    let raw = nats.block_on(async {
        let s = nats.jetstream().get_stream(&edge.stream).await.unwrap();
        s.get_last_raw_message_by_subject(&edge.subject).await.unwrap()
    });
    let mut r = results(dir.path(), &p, &url, &out);
    wait_for("the result", &mut [&mut w, &mut r], || result_dirs(&out).len() == 1 && ledger(&out) == 1);
    // The sink crashed after its result was in place and before the acknowledgement and the
    // ledger entry: the ledger is gone, and the job comes again.
    for f in files_in(&out.join(".nats/done/results")) {
        std::fs::remove_file(out.join(".nats/done/results").join(f)).unwrap();
    }
    nats.block_on(async {
        let mut h = async_nats::HeaderMap::new();
        for k in ["Shapeforest-Format", "Shapeforest-Version", "Shapeforest-Key", "Shapeforest-Name"] {
            h.insert(k, raw.headers.get(k).unwrap().as_str());
        }
        let ack = nats
            .jetstream()
            .publish_with_headers(edge.subject.clone(), h, raw.payload.clone())
            .await
            .unwrap();
        ack.await.unwrap();
    });
    wait_for_log(&mut r, "the second delivery skipped", |l| l.contains("already written as"));
    thread::sleep(Duration::from_secs(1));
    assert_eq!(result_dirs(&out), vec!["scan-creature8".to_string()], "written once");
    assert_eq!(backlog(&nats, "fmap", "results"), (0, 0));
    w.stop();
    r.stop();
}

#[test]
fn a_server_restart_in_a_burst_loses_nothing_and_doubles_nothing() {
    let Some(Cluster { dir, mut server, url, data, p }) = Cluster::start("") else { return };
    publish_model(&p, &url, &data);
    let out = dir.path().join("out");
    let mut w = worker(dir.path(), &p, &url, "w", None);
    let mut r = results(dir.path(), &p, &url, &out);
    submit_files(&p, &url, &scans(&dir.path().join("in"), 6, 6));
    wait_for("a first result", &mut [&mut w, &mut r], || !result_dirs(&out).is_empty());
    server.restart();
    wait_for("6 results after the restart", &mut [&mut w, &mut r], || result_dirs(&out).len() >= 6);
    thread::sleep(Duration::from_secs(3));
    let mut want: Vec<String> = (6..12).map(|i| format!("scan-creature{i}")).collect();
    want.sort();
    assert_eq!(result_dirs(&out), want, "{}", server.log_text());
    assert_eq!(ledger(&out), 6);
    w.stop();
    r.stop();
}

#[test]
fn jobs_in_flight_while_a_restarted_server_recovers_are_neither_rejected_nor_lost() {
    let Some(Cluster { dir, mut server, url, data, p }) = Cluster::start("") else { return };
    publish_model(&p, &url, &data);
    let out = dir.path().join("out");
    let mut w = worker(dir.path(), &p, &url, "w", None);
    let mut r = results(dir.path(), &p, &url, &out);
    // Scans large enough (12,000 vertices, most of a second each) that the worker is still
    // busy when the server restarts, at the first result, and answers without JetStream for
    // 3 s: the parts the worker stores, the messages it reads and the results' reads fail
    // meanwhile. They are tried again once the server is back, not counted as the job's
    // failures.
    submit_files(&p, &url, &scans_of(&dir.path().join("in"), 6, 4, 12_000));
    wait_for("a first result", &mut [&mut w, &mut r], || !result_dirs(&out).is_empty());
    server.restart_late(Duration::from_secs(3));
    wait_for("4 results or a rejection after the restart", &mut [&mut w, &mut r], || {
        result_dirs(&out).len() + rejected_reports(&out).len() >= 4
    });
    thread::sleep(Duration::from_secs(2));
    assert!(
        rejected_reports(&out).is_empty(),
        "rejected: {:?}\n{}\n----\n{}",
        rejected_reports(&out),
        w.log(),
        r.log()
    );
    let mut want: Vec<String> = (6..10).map(|i| format!("scan-creature{i}")).collect();
    want.sort();
    assert_eq!(result_dirs(&out), want);
    assert_eq!(ledger(&out), 4);
    w.stop();
    r.stop();
}

#[test]
fn a_labelled_shape_updates_the_model_on_every_worker() {
    let Some(Cluster { dir, server: _server, url, data, p }) = Cluster::start("") else { return };
    publish_model(&p, &url, &data);
    let out = dir.path().join("out");
    let training = "read-labelled,labelled-spectra,trainer";
    // The trainer's folder starts from the same model and training shapes.
    let t_data = dir.path().join("t");
    copy_tree(&data, &t_data);
    let mut t = worker(dir.path(), &p, &url, "t", Some(training));
    wait_for_log(&mut t, "the trainer lease", |l| l.contains("holding the trainer lease"));
    let mut t2 = worker(dir.path(), &p, &url, "t2", Some(training));
    let mut ws: Vec<Daemon> = (0..2).map(|i| worker(dir.path(), &p, &url, &format!("w{i}"), None)).collect();
    let mut r = results(dir.path(), &p, &url, &out);
    let input = dir.path().join("in");
    submit_files(&p, &url, &scans(&input, 9, 1));
    wait_for("the first result", &mut [&mut r], || result_dirs(&out).len() == 1);
    let first = read_json(&out.join("matched/scan-creature9/scan-creature9.report.json"));
    assert_eq!(first["model_version"], 1);
    // A labelled shape: one model update, every worker switches.
    let fam = family(9);
    let shape = input.join("creature8.off");
    shapeforest::mesh::write_mesh(&shape, &fam.shapes[8]).unwrap();
    std::fs::write(input.join("creature8.labels"), identity_labels(fam.shapes[8].n_vertices())).unwrap();
    let out_text = submit(&p, &url, &["--labelled".as_ref(), shape.as_os_str()]);
    assert!(out_text.contains("submitted 1 file(s) to `labelled`"), "{out_text}");
    let nats = client(&url);
    wait_for("model v2 in the bucket", &mut [&mut t], || {
        nats.block_on(model_sync::current_version(&nats)).unwrap().0 == 2
    });
    for w in ws.iter_mut() {
        wait_for_log(w, "the switch to v2", |l| l.contains("switching to model v2"));
    }
    let t2_log = t2.log();
    assert!(t2_log.contains("waiting for the trainer lease") && !t2_log.contains("holding"), "{t2_log}");
    assert_eq!(
        manifests(&t_data).iter().map(|m| m["version"].as_u64().unwrap()).collect::<Vec<_>>(),
        vec![1, 2]
    );
    submit_files(&p, &url, &scans(&input, 10, 1));
    wait_for("the second result", &mut [&mut r], || result_dirs(&out).len() == 2);
    let second = read_json(&out.join("matched/scan-creature10/scan-creature10.report.json"));
    assert_eq!(second["model_version"], 2, "the job records the version it used");
    let map = std::fs::read_to_string(out.join("matched/scan-creature10/scan-creature10.map.txt")).unwrap();
    assert!(map.lines().next().unwrap().contains("(model v2)"), "{}", map.lines().next().unwrap());
    // The first trainer dies: the second takes the lease over.
    t.kill();
    wait_for_log(&mut t2, "the lease taken over", |l| l.contains("holding the trainer lease"));
    for w in ws.drain(..) {
        w.stop();
    }
    r.stop();
}

#[test]
fn a_poison_message_is_dead_lettered_and_rejected_while_the_rest_flow() {
    let Some(Cluster { dir, server: _server, url, data, p }) = Cluster::start("nats_max_deliver = 2") else {
        return;
    };
    publish_model(&p, &url, &data);
    let out = dir.path().join("out");
    let mut w = worker(dir.path(), &p, &url, "w", None);
    let mut r = results(dir.path(), &p, &url, &out);
    let nats = client(&url);
    // A message of a format version no worker knows.
    let edge = nats.edge("scans", "read-scans");
    nats.block_on(async {
        nats.ensure_stream(&edge).await.unwrap();
        let mut h = async_nats::HeaderMap::new();
        h.insert("Shapeforest-Format", "shapeforest.file");
        h.insert("Shapeforest-Version", "99");
        h.insert("Shapeforest-Key", "poison-0");
        h.insert("Shapeforest-Name", "poison.off");
        let ack = nats.jetstream().publish_with_headers(edge.subject.clone(), h, "??".into()).await.unwrap();
        ack.await.unwrap();
    });
    submit_files(&p, &url, &scans(&dir.path().join("in"), 8, 1));
    wait_for("the good result and the poison's report", &mut [&mut w, &mut r], || {
        result_dirs(&out).len() == 1 && rejected_reports(&out).len() == 1
    });
    assert_eq!(result_dirs(&out), vec!["scan-creature8".to_string()]);
    let report = read_json(&out.join("rejected/poison.error.json"));
    let error = report["error"].as_str().unwrap();
    assert!(
        error.contains("version 99") && error.contains("2 deliveries") && error.contains("dead"),
        "{error}"
    );
    let dead = nats.block_on(async {
        let mut s = nats.jetstream().get_stream("shapeforest_DEAD").await.unwrap();
        s.info().await.unwrap().state.messages
    });
    assert_eq!(dead, 1);
    assert_eq!(backlog(&nats, "scans", "read-scans"), (0, 0));
    w.stop();
    r.stop();
}

/// A small closed mesh (a tetrahedron) moved by `i`: 1,000 distinct files, each too small for
/// the pipeline's 100 eigenpairs, so each is read, rejected with a report, and acknowledged.
fn tiny_scan(dir: &Path, i: usize) -> PathBuf {
    let d = i as f64 * 1e-3;
    let text = format!("OFF\n4 4 0\n{d} 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n");
    let p = dir.join(format!("tiny{i:04}.off"));
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn a_burst_of_1000_scans_is_held_by_the_queue_not_by_the_worker() {
    let Some(Cluster { dir, server: _server, url, data, p }) = Cluster::start("nats_max_ack_pending = 4")
    else {
        return;
    };
    publish_model(&p, &url, &data);
    let input = dir.path().join("in");
    std::fs::create_dir_all(&input).unwrap();
    let files: Vec<PathBuf> = (0..1000).map(|i| tiny_scan(&input, i)).collect();
    submit_files(&p, &url, &files);
    let nats = client_with(&url, 4);
    assert_eq!(backlog(&nats, "scans", "read-scans").0, 1000, "the burst waits in the stream");
    let out = dir.path().join("out");
    let mut w = worker(dir.path(), &p, &url, "w", None);
    let mut r = results(dir.path(), &p, &url, &out);
    let mut most_in_flight = 0;
    wait_for("1000 reports", &mut [&mut w, &mut r], || {
        most_in_flight = most_in_flight.max(backlog(&nats, "scans", "read-scans").1);
        rejected_reports(&out).len() >= 1000
    });
    let peak = w.peak_rss().unwrap_or(0);
    assert!(most_in_flight <= 4, "{most_in_flight} jobs in flight, max_ack_pending is 4");
    assert!(peak < 250 << 20, "worker peak RSS {} MiB for a backlog of 1000", peak >> 20);
    println!("1000 tiny scans: at most {most_in_flight} in flight; worker peak RSS {} MiB", peak >> 20);
    thread::sleep(Duration::from_secs(2));
    assert_eq!(rejected_reports(&out).len(), 1000);
    assert_eq!(backlog(&nats, "scans", "read-scans"), (0, 0));
    let one = read_json(&out.join("rejected/tiny0000.error.json"));
    assert_eq!(one["kind"], "BadInput", "{one}");
    w.stop();
    r.stop();
}

/// `(deleted, objects before)` from `shapeforest gc`'s line.
fn gc(p: &Path, url: &str, extra: &[&str]) -> (usize, usize, String) {
    let mut args: Vec<&OsStr> =
        vec!["gc".as_ref(), "--pipeline".as_ref(), p.as_os_str(), "--nats".as_ref(), url.as_ref()];
    args.extend(extra.iter().map(OsStr::new));
    let (status, out, err) = run_cli(&args, timeout());
    assert!(status.success(), "gc failed: {out}\n{err}");
    let words: Vec<&str> = out.split_whitespace().collect();
    let at = words.iter().position(|w| *w == "deleted").unwrap_or_else(|| panic!("{out}"));
    (words[at + 1].parse().unwrap(), words[at + 3].parse().unwrap(), out)
}

#[test]
fn gc_deletes_the_objects_of_finished_jobs_and_keeps_what_waiting_jobs_need() {
    let Some(Cluster { dir, server: _server, url, data, p }) = Cluster::start("") else { return };
    publish_model(&p, &url, &data);
    let out = dir.path().join("out");
    let mut w = worker(dir.path(), &p, &url, "w", None);
    let mut r = results(dir.path(), &p, &url, &out);
    submit_files(&p, &url, &scans(&dir.path().join("in"), 8, 1));
    wait_for("the first result", &mut [&mut w, &mut r], || result_dirs(&out).len() == 1);
    thread::sleep(Duration::from_secs(1));
    w.stop();
    // A second scan waits in the queue (no worker runs): its file must survive a collection.
    submit_files(&p, &url, &scans(&dir.path().join("in2"), 9, 1));
    let (deleted, _, text) = gc(&p, &url, &[]);
    assert_eq!(deleted, 0, "everything is younger than the default grace: {text}");
    let (deleted, before, text) = gc(&p, &url, &["--grace-s", "0"]);
    assert!(deleted >= 5, "the finished job's mesh, spectrum, prediction, matches, map…: {text}");
    assert_eq!(before - deleted, 2, "kept: the waiting scan's file and the model bundle: {text}");
    assert!(text.contains("referring to 2 object(s)"), "{text}");
    // The waiting scan still goes through, with the model kept.
    let mut w = worker(dir.path(), &p, &url, "w2", None);
    wait_for("the second result", &mut [&mut w, &mut r], || result_dirs(&out).len() == 2);
    assert!(rejected_reports(&out).is_empty(), "{:?}", rejected_reports(&out));
    w.stop();
    r.stop();
}

#[test]
fn a_job_dead_lettered_for_its_deliveries_leaves_nothing_in_the_spool() {
    use shapeforest::pipeline::{
        nats::NatsTransport, DataDir, Envelope, ErasedTransport, InputFile, Job, LiveModel, PipelineSpec,
        Receiver, Sender, Shutdown,
    };
    use std::{any::TypeId, sync::Arc};
    let Some(Cluster { dir, server: _server, url, data: _, p }) = Cluster::start("nats_max_deliver = 1")
    else {
        return;
    };
    let spec = PipelineSpec::from_file(&p).unwrap();
    let mut settings = NatsSettings::from_spec(&spec, Some(&url)).unwrap();
    settings.ack_wait = Duration::from_secs(2);
    let nats = Nats::connect(settings).unwrap();
    let data = DataDir::new(dir.path().join("worker"));
    let t =
        NatsTransport::new(nats.clone(), &spec, data.clone(), Arc::new(LiveModel::new()), Shutdown::new());
    type Pair = (Arc<dyn Sender<InputFile>>, Box<dyn Receiver<InputFile>>);
    let (tx, rx) = *t
        .connect_erased("scans", "read-scans", 1, TypeId::of::<InputFile>())
        .unwrap()
        .downcast::<Pair>()
        .unwrap();
    let scan = scans(&dir.path().join("in"), 8, 1).remove(0);
    let body = Ok(InputFile { path: scan.clone(), labels: None });
    nats.block_on(tx.send(Envelope { job: Job::for_file(1, &scan, None), body })).unwrap();
    let spool = data.root().join(".nats/spool");
    // The first delivery is spooled, then lost (its worker "dies": the delivery is dropped).
    let first = nats.block_on(rx.recv()).unwrap();
    assert!(first.body.is_ok());
    assert_eq!(files_in(&spool).len(), 1, "spooled while held");
    drop(first);
    // Its second delivery is one more than max_deliver: dead-lettered, and its spool removed.
    let second = nats.block_on(rx.recv()).unwrap();
    let e = second.body.as_ref().unwrap_err();
    assert!(e.message.contains("no worker finished this job in 1 deliveries"), "{e}");
    assert!(files_in(&spool).is_empty(), "{:?}", files_in(&spool));
    drop(second);
    thread::sleep(Duration::from_millis(500));
    assert!(files_in(&spool).is_empty(), "{:?}", files_in(&spool));
    assert_eq!(dead_letters(&nats).len(), 1);
}
