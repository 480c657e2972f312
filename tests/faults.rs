//! Fault injection: the daemon and the command-line tools driven as a hostile or unlucky user
//! drives them (issue 16). Each test pins one failure that used to corrupt, strand, leak or
//! blow up, through the real binary on a temporary data folder.

mod common;

use std::{
    ffi::OsStr,
    fs,
    io::Write,
    path::{Path, PathBuf},
    process::Command,
    sync::Arc,
    thread,
    time::{Duration, Instant},
};

use common::daemon::*;
use shapeforest::{
    forest::{fnv1a64, labels_identity, RandomForest, TrainingSet, TrainingShape},
    mesh::write_mesh,
    spectral::{compute_spectrum, SpectrumParams},
};

fn os(s: &str) -> &OsStr {
    OsStr::new(s)
}

fn reports(data: &Path) -> Vec<(String, serde_json::Value)> {
    files_in(&data.join("rejected"))
        .into_iter()
        .filter(|n| n.ends_with(".error.json"))
        .map(|n| {
            let v = read_json(&data.join("rejected").join(&n));
            (n, v)
        })
        .collect()
}

// ---- 1. training shapes are immutable ----------------------------------------------------

#[test]
fn a_labelled_shape_named_like_a_training_shape_is_rejected_not_swapped_in() {
    let tmp = tempfile::tempdir().unwrap();
    let data = trained_copy(tmp.path());
    let stored = data.join("training/creature0.off");
    let before = fs::read(&stored).unwrap();
    let versions = manifests(&data).len();
    let mut d = Daemon::start(&data, false);
    let fam = family(8);
    // Another pose under the reference's name.
    drop_labelled(&data, "creature0", &fam.shapes[7], &identity_labels(fam.template.n_vertices()));
    let report = data.join("rejected/creature0.error.json");
    wait_until(&mut d, "the same-name shape rejected", || report.is_file());
    let r = read_json(&report);
    assert!(r["error"].as_str().unwrap().contains("already stored"), "{r}");
    assert_eq!(fs::read(&stored).unwrap(), before, "the stored reference is untouched");
    assert!(
        data.join("rejected/creature0.off").is_file() && data.join("rejected/creature0.labels").is_file()
    );
    thread::sleep(Duration::from_millis(2500)); // past the trainer's quiet time
    assert_eq!(manifests(&data).len(), versions, "no model was made from it");
    d.stop();
    // The daemon still starts on the folder and serves with the original reference.
    let mut d = Daemon::start(&data, false);
    drop_mesh(&data.join("incoming"), "after.off", &fam.shapes[6]);
    wait_until(&mut d, "a result after restart", || result_dirs(&data).contains(&"after".to_string()));
    d.stop();
}

// ---- 2. a crash during the first training ------------------------------------------------

#[test]
fn a_kill_during_the_first_training_is_resumed_at_the_next_start() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let fam = family(7);
    let n = fam.template.n_vertices();
    // No model yet, a scan waiting: a SIGTERM must leave it queued, not reject it.
    let more_trees = |t: String| {
        assert!(t.contains("\ntrees = 0 "), "the pipeline's trainer sets `trees = 0`");
        t.replace("\ntrees = 0 ", "\ntrees = 60 ")
    };
    let mut d = Daemon::start_with(&data, false, more_trees, &[]);
    wait_until(&mut d, "the folders", || data.join("incoming").is_dir());
    drop_mesh(&data.join("incoming"), "waiting.off", &fam.shapes[6]);
    wait_until(&mut d, "the scan claimed", || files_in(&data.join("incoming")).is_empty());
    thread::sleep(Duration::from_millis(300));
    d.stop();
    assert!(reports(&data).is_empty(), "nothing rejected at a stop without a model: {:?}", reports(&data));
    // Six labelled shapes; kill -9 while the first model is being fitted.
    for i in 0..6 {
        drop_labelled(&data, &format!("creature{i}"), &fam.shapes[i], &identity_labels(n));
    }
    let mut d = Daemon::start_with(&data, false, more_trees, &[]);
    let stored = || files_in(&data.join("training")).iter().filter(|f| f.ends_with(".off")).count();
    wait_until(&mut d, "the shapes stored for training", || stored() == 6);
    assert!(manifests(&data).is_empty(), "killed before the first model was saved");
    d.kill();
    // The restart learns from training/ and then matches the waiting scan.
    let mut d = Daemon::start_with(&data, false, more_trees, &[]);
    wait_until(&mut d, "a model of the 6 stored shapes", || newest_training_count(&data) == 6);
    wait_until(&mut d, "the waiting scan matched", || result_dirs(&data).contains(&"waiting".to_string()));
    assert!(reports(&data).is_empty(), "{:?}", reports(&data));
    d.stop();
}

// ---- 3. one process per data folder -------------------------------------------------------

#[test]
fn a_second_daemon_on_the_same_folder_refuses_to_start_naming_the_first() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let mut first = Daemon::start(&data, false);
    wait_for_log(&mut first, "the first daemon watching", |l| l.contains("watching"));
    let second_data = data.clone();
    let second = Daemon::start(&second_data, false);
    let (status, _) = second.wait_exit(Duration::from_secs(60));
    assert!(!status.success());
    let log = fs::read_to_string(data.with_extension(format!("log{}", std::process::id()))).unwrap();
    assert!(log.contains(&format!("PID {}", first.pid())), "the holder is named:\n{log}");
    first.assert_running();
    first.stop();
}

// ---- 4. memory is bounded by limits, not by the input -------------------------------------

#[test]
fn oversized_inputs_are_refused_before_they_are_read() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let mut d = Daemon::start(&data, false);
    wait_until(&mut d, "the folders", || data.join("labeled").is_dir());
    // A 2 GB (sparse) mesh file: over the 1 GiB default limit.
    {
        let staging = data.join(".staging");
        fs::create_dir_all(&staging).unwrap();
        let p = staging.join("huge.off");
        let mut f = fs::File::create(&p).unwrap();
        f.write_all(b"OFF\n1000000 1000000 0\n").unwrap();
        f.set_len(2 << 30).unwrap();
        drop(f);
        fs::rename(&p, data.join("incoming/huge.off")).unwrap();
    }
    // One label value of 300,000,000: over the label limit.
    let fam = family(1);
    let n = fam.template.n_vertices();
    let mut labels = identity_labels(n);
    labels = labels.replacen("3\n", "300000000\n", 1);
    drop_labelled(&data, "bigl", &fam.shapes[0], &labels);
    let t0 = Instant::now();
    wait_until(&mut d, "both refused", || {
        data.join("rejected/huge.error.json").is_file() && data.join("rejected/bigl.error.json").is_file()
    });
    assert!(t0.elapsed() < Duration::from_secs(60));
    let huge = read_json(&data.join("rejected/huge.error.json"));
    let e = huge["error"].as_str().unwrap();
    assert!(e.contains("huge.off") && e.contains("max_file_bytes"), "{e}");
    let big = read_json(&data.join("rejected/bigl.error.json"));
    let e = big["error"].as_str().unwrap();
    assert!(e.contains("bigl.labels") && e.contains("line 4") && e.contains("max_labels"), "{e}");
    let peak = d.peak_rss().unwrap_or(0);
    assert!(peak < 400 << 20, "peak RSS {peak} bytes: the file was read");
    d.stop();
}

/// A model file with a valid checksum whose energy grid claims 2^28 levels (an attacker who
/// recomputes the checksum): refused at load by the limits, the previous version serves.
#[test]
fn a_forged_model_is_refused_by_the_limits_and_a_crashing_input_is_quarantined() {
    let tmp = tempfile::tempdir().unwrap();
    let data = trained_copy(tmp.path());
    let v1 = data.join("models/model-v000001.sfm");
    let forged = forge_levels(&fs::read(&v1).unwrap(), 1 << 28);
    fs::write(data.join("models/model-v000002.sfm"), forged).unwrap();
    let mut m = read_json(&data.join("models/model-v000001.json"));
    m["version"] = 2.into();
    m["model_file"] = "model-v000002.sfm".into();
    fs::write(data.join("models/model-v000002.json"), m.to_string()).unwrap();
    // The forged model on its own loads, checksum and all, but is outside the limits.
    assert!(RandomForest::load(data.join("models/model-v000002.sfm")).is_ok());
    let fam = family(9);
    drop_mesh(&data.join("incoming"), "poison.off", &fam.shapes[8]);
    // Poison: the input is in flight at two abnormal stops in a row.
    let mut claims = 0;
    for round in 0..2 {
        let mut d = Daemon::start(&data, false);
        // Claimed by this run (the log file is shared by the runs).
        wait_for_log(&mut d, "the scan claimed", |l| l.matches("claimed").count() > claims);
        claims = d.log().matches("claimed").count();
        if round == 0 {
            let log = d.log();
            assert!(log.contains("max_energy_levels") && log.contains("model v1"), "{log}");
        }
        d.kill();
    }
    let mut d = Daemon::start(&data, false);
    let report = data.join("rejected/poison.error.json");
    wait_until(&mut d, "the poison scan quarantined", || report.is_file());
    let r = read_json(&report);
    assert!(r["error"].as_str().unwrap().contains("quarantined"), "{r}");
    assert!(data.join("rejected/poison.off").is_file());
    // The daemon goes on serving.
    drop_mesh(&data.join("incoming"), "fine.off", &fam.shapes[7]);
    wait_until(&mut d, "a result", || result_dirs(&data).contains(&"fine".to_string()));
    let r = read_json(&data.join("matched/fine/fine.report.json"));
    assert_eq!(r["model_version"], 1);
    d.stop();
}

/// Re-encodes a model with its energy grid's level count replaced, the checksum recomputed.
fn forge_levels(bytes: &[u8], levels: u64) -> Vec<u8> {
    // Format version 2 (still read), whose MessagePack payload maps onto JSON values (version 3
    // holds the trees as byte strings).
    let bytes = &RandomForest::from_bytes(bytes).unwrap().to_bytes_version(2).unwrap();
    // Prefix: magic (8), version (4), payload length (8), checksum (8).
    let payload = &bytes[28..];
    let mut v: serde_json::Value = rmp_serde::from_slice(payload).unwrap();
    // Payload = [header, forest]; header = [params, n_labels, k, grid, n_trees] and forest =
    // [params, n_labels, k, grid, trees, …]; grid = [range, levels].
    for part in 0..2 {
        assert!(v[part][3][1].is_u64(), "the energy grid's levels: {}", v[part][3]);
        v[part][3][1] = levels.into();
    }
    let payload = rmp_serde::to_vec(&v).unwrap();
    let mut out = bytes[..12].to_vec();
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(&fnv1a64(&payload).to_le_bytes());
    out.extend_from_slice(&payload);
    out
}

// ---- 5 and 13. links, fake reports, inputs nobody takes -------------------------------------

#[test]
fn links_are_not_followed_and_their_targets_never_quoted() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let secret = tmp.path().join("secret.txt");
    fs::write(&secret, "TOPSECRET=hunter2\n").unwrap();
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        fs::set_permissions(&secret, fs::Permissions::from_mode(0o600)).unwrap();
    }
    let mut d = Daemon::start(&data, false);
    wait_until(&mut d, "the folders", || data.join("labeled").is_dir());
    let incoming = data.join("incoming");
    std::os::unix::fs::symlink(&secret, incoming.join("secret.off")).unwrap();
    std::os::unix::fs::symlink("/etc/passwd", incoming.join("passwd.off")).unwrap();
    std::os::unix::fs::symlink("/proc/self/environ", incoming.join("environ.off")).unwrap();
    std::os::unix::fs::symlink(tmp.path().join("nothing"), incoming.join("dangling.off")).unwrap();
    // A non-mesh file named like a report, inputs nobody takes.
    fs::write(incoming.join("scan-7.error.json"), "{\"error\": \"forged\"}").unwrap();
    fs::write(incoming.join("..off"), "OFF\n").unwrap();
    fs::create_dir(incoming.join("folder.off")).unwrap();
    fs::write(data.join("labeled/lonely.labels"), "0\n").unwrap();
    wait_until(&mut d, "five reports", || reports(&data).len() == 5);
    for name in ["secret", "passwd", "environ", "dangling"] {
        let r = read_json(&data.join("rejected").join(format!("{name}.error.json")));
        let text = r.to_string();
        assert!(r["error"].as_str().unwrap().contains("symbolic link"), "{text}");
        assert!(!text.contains("TOPSECRET") && !text.contains("root:"), "{text}");
    }
    assert_eq!(fs::read_to_string(&secret).unwrap(), "TOPSECRET=hunter2\n", "the target is untouched");
    // The fake report is rejected under a name that is not a report's.
    let names = files_in(&data.join("rejected"));
    assert!(names.contains(&"scan-7.error.json.input".to_string()), "{names:?}");
    assert!(!names.contains(&"scan-7.error.json".to_string()), "{names:?}");
    // Nothing is ignored without a word.
    wait_for_log(&mut d, "a log line for each input left alone", |log| {
        log.contains("..off") && log.contains("folder.off") && log.contains("lonely.labels")
    });
    d.stop();
}

// ---- 6. output failures keep the input queued ----------------------------------------------

/// Mounts a small tmpfs at `at` when the test may (root, and `mount` works here).
fn mount_tmpfs(at: &Path, size: &str) -> bool {
    fs::create_dir_all(at).unwrap();
    Command::new("mount")
        .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
        .arg(at)
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

fn umount(at: &Path) {
    let _ = Command::new("umount").arg("-l").arg(at).status();
}

/// Fills the file system of `dir` with one file until no space is left.
fn fill_disk(file: &Path) {
    let mut f = fs::File::create(file).unwrap();
    let chunk = vec![0u8; 1 << 16];
    while f.write_all(&chunk).is_ok() {}
    let _ = f.sync_all();
}

#[test]
fn a_full_disk_and_a_read_only_output_folder_keep_scans_queued_until_they_can_be_written() {
    let tmp = tempfile::tempdir().unwrap();
    let mount = tmp.path().join("fs");
    let real_fs = mount_tmpfs(&mount, "256m");
    let _unmount = Unmount(mount.clone(), real_fs);
    if !real_fs {
        eprintln!("note: cannot mount a tmpfs here; a full disk is injected through SHAPEFOREST_FAULT_FILE");
    }
    let root = if real_fs { mount.clone() } else { tmp.path().to_path_buf() };
    let data = trained_copy(&root);
    let fault = tmp.path().join("fault");
    let fault_s = fault.to_string_lossy().into_owned();
    let mut d = Daemon::start_with(&data, false, |t| t, &[("SHAPEFOREST_FAULT_FILE", &fault_s)]);
    wait_for_log(&mut d, "watching", |l| l.contains("watching"));
    let fam = family(10);
    let staging = data.join(".staging");
    fs::create_dir_all(&staging).unwrap();
    for (i, name) in ["full-a.off", "full-b.off"].iter().enumerate() {
        write_mesh(staging.join(name), &fam.shapes[8 + i]).unwrap();
    }
    // A full disk.
    let filler = data.join("filler.bin");
    if real_fs {
        fill_disk(&filler);
    } else {
        fs::write(&fault, "ENOSPC").unwrap();
    }
    for name in ["full-a.off", "full-b.off"] {
        fs::rename(staging.join(name), data.join("incoming").join(name)).unwrap();
    }
    wait_for_log(&mut d, "both results deferred", |l| l.matches("stays queued").count() >= 2);
    assert!(
        reports(&data).is_empty(),
        "nothing rejected for a full disk: {:?}",
        files_in(&data.join("rejected"))
    );
    assert!(!files_in(&data.join("matched")).iter().any(|f| f.starts_with(".partial")), "no partial left");
    assert!(!result_dirs(&data).iter().any(|r| r.starts_with("full-")));
    // Space again: both are matched.
    let _ = fs::remove_file(&filler);
    let _ = fs::remove_file(&fault);
    wait_until(&mut d, "both matched once space is back", || {
        let r = result_dirs(&data);
        r.contains(&"full-a".to_string()) && r.contains(&"full-b".to_string())
    });
    // A read-only matched/.
    let matched = data.join("matched");
    let ro = make_read_only(&matched, &fault);
    drop_mesh_via(&staging, &data.join("incoming"), "ro-a.off", &fam.shapes[7]);
    let deferred_before = d.log().matches("stays queued").count();
    wait_for_log(&mut d, "the result deferred", |l| l.matches("stays queued").count() > deferred_before);
    assert!(reports(&data).is_empty(), "nothing rejected for a read-only folder");
    undo_read_only(&matched, &fault, ro);
    wait_until(&mut d, "matched once writable", || result_dirs(&data).contains(&"ro-a".to_string()));
    assert!(reports(&data).is_empty());
    d.stop();
}

struct Unmount(PathBuf, bool);
impl Drop for Unmount {
    fn drop(&mut self) {
        if self.1 {
            umount(&self.0);
        }
    }
}

/// The effective user id (`id -u`; CI runs as root, where permissions do not stop writes).
fn euid() -> u32 {
    Command::new("id")
        .arg("-u")
        .output()
        .ok()
        .and_then(|o| String::from_utf8_lossy(&o.stdout).trim().parse().ok())
        .unwrap_or(u32::MAX)
}

#[derive(Clone, Copy)]
enum ReadOnly {
    Chmod,
    BindMount,
    Hook,
}

/// Makes `dir` read-only: `chmod` for a normal user, a read-only bind mount for root (who
/// ignores permissions), else the test hook.
fn make_read_only(dir: &Path, fault: &Path) -> ReadOnly {
    if euid() != 0 {
        use std::os::unix::fs::PermissionsExt;
        fs::set_permissions(dir, fs::Permissions::from_mode(0o555)).unwrap();
        return ReadOnly::Chmod;
    }
    let bind = Command::new("mount").arg("--bind").arg(dir).arg(dir).status().is_ok_and(|s| s.success());
    if bind {
        let ro = Command::new("mount")
            .args(["-o", "remount,bind,ro"])
            .arg(dir)
            .status()
            .is_ok_and(|s| s.success());
        if ro {
            return ReadOnly::BindMount;
        }
        umount(dir);
    }
    fs::write(fault, "EROFS").unwrap();
    ReadOnly::Hook
}

fn undo_read_only(dir: &Path, fault: &Path, how: ReadOnly) {
    match how {
        ReadOnly::Chmod => {
            use std::os::unix::fs::PermissionsExt;
            fs::set_permissions(dir, fs::Permissions::from_mode(0o755)).unwrap();
        }
        ReadOnly::BindMount => umount(dir),
        ReadOnly::Hook => fs::remove_file(fault).unwrap(),
    }
}

// ---- 7 and 13. a newest model that cannot serve -------------------------------------------

/// A one-tree model of the reference shape with `k` eigenpairs and `n_labels` labels, saved as
/// version `version` with a manifest whose `model_file` is `file`.
fn write_small_model(data: &Path, version: u64, k: usize, n_labels: usize, file: &str, at: &Path) {
    let fam = family(1);
    let mesh = &fam.shapes[0];
    let spectrum = Arc::new(compute_spectrum(mesh, &SpectrumParams::new(k)).unwrap());
    let shape = TrainingShape::new("creature0", spectrum, labels_identity(mesh.n_vertices()));
    let set = TrainingSet::new(vec![shape], n_labels).unwrap();
    let forest = RandomForest::params().n_trees(1).max_depth(4).fit(&set).unwrap();
    forest.save(at).unwrap();
    let mut m = read_json(&data.join("models/model-v000001.json"));
    m["version"] = version.into();
    m["model_file"] = file.into();
    m["k"] = k.into();
    m["n_labels"] = n_labels.into();
    m["n_trees"] = 1.into();
    fs::write(data.join(format!("models/model-v{version:06}.json")), m.to_string()).unwrap();
}

#[test]
fn newer_models_that_cannot_serve_fall_back_to_the_newest_that_can() {
    let tmp = tempfile::tempdir().unwrap();
    let data = trained_copy(tmp.path());
    let n = family(1).template.n_vertices();
    // v2: K = 120 under a k = 100 pipeline; v3: more labels than the reference carries;
    // v4: a manifest pointing outside models/.
    write_small_model(&data, 2, 120, n, "model-v000002.sfm", &data.join("models/model-v000002.sfm"));
    write_small_model(&data, 3, 100, n + 50, "model-v000003.sfm", &data.join("models/model-v000003.sfm"));
    write_small_model(&data, 4, 100, n, "../../outside.sfm", &tmp.path().join("outside.sfm"));
    let mut d = Daemon::start(&data, false);
    drop_mesh(&data.join("incoming"), "served.off", &family(9).shapes[8]);
    wait_until(&mut d, "a result", || result_dirs(&data).contains(&"served".to_string()));
    let r = read_json(&data.join("matched/served/served.report.json"));
    assert_eq!(r["model_version"], 1, "served by the newest model that can");
    let log = d.log();
    assert!(log.contains("model v2 cannot serve") && log.contains("k = 100"), "{log}");
    assert!(log.contains("model v3 cannot serve") && log.contains("lacks"), "{log}");
    assert!(log.contains("is not a file name inside"), "{log}");
    assert!(log.contains("falling back to model v1"), "{log}");
    d.stop();
}

// ---- 8. `run` says when it failed -------------------------------------------------------------

#[test]
fn run_exits_non_zero_when_its_source_fails_or_every_input_is_rejected() {
    let tmp = tempfile::tempdir().unwrap();
    let data = trained_copy(tmp.path());
    let pipeline = concat!(env!("CARGO_MANIFEST_DIR"), "/pipelines/match.toml");
    let args = |d: &Path| {
        vec![
            os("run").to_owned(),
            os(pipeline).to_owned(),
            os("--data-dir").to_owned(),
            d.as_os_str().to_owned(),
        ]
    };
    let a = args(&data);
    let a: Vec<&OsStr> = a.iter().map(|s| s.as_os_str()).collect();
    let (status, _, err) = run_cli(&a, Duration::from_secs(120));
    assert!(!status.success(), "no mesh files: {err}");
    assert!(err.contains("no mesh files"), "{err}");
    fs::write(data.join("incoming/broken.off"), "OFF\n3 1 0\n0 0 0\n").unwrap();
    let (status, out, err) = run_cli(&a, Duration::from_secs(120));
    assert!(!status.success(), "every input rejected: {out}{err}");
    assert!(err.contains("every input was rejected") && out.contains("0 done, 1 rejected"), "{out}{err}");
}

// ---- 9, 10, 11. slow writers, odd names, TOSCA pairs ------------------------------------------

#[test]
fn slow_writers_odd_names_and_tosca_pairs_are_matched_once() {
    let tmp = tempfile::tempdir().unwrap();
    let data = trained_copy(tmp.path());
    let mut d = Daemon::start(&data, false);
    wait_for_log(&mut d, "watching", |l| l.contains("watching"));
    let fam = family(10);
    let n = fam.template.n_vertices();
    let incoming = data.join("incoming");
    // A TOSCA pair, the .tri first.
    let staging = data.join(".staging");
    fs::create_dir_all(&staging).unwrap();
    write_mesh(staging.join("pair.vert"), &fam.shapes[7]).unwrap();
    fs::rename(staging.join("pair.tri"), incoming.join("pair.tri")).unwrap();
    thread::sleep(Duration::from_millis(500));
    fs::rename(staging.join("pair.vert"), incoming.join("pair.vert")).unwrap();
    // A name with a newline.
    drop_mesh(&incoming, "odd\nname.off", &fam.shapes[8]);
    // A copier that keeps the file open and pauses longer than the settle time.
    let bytes = {
        write_mesh(staging.join("slow.off"), &fam.shapes[9]).unwrap();
        fs::read(staging.join("slow.off")).unwrap()
    };
    {
        let mut f = fs::File::create(incoming.join("slow.off")).unwrap();
        for chunk in bytes.chunks(bytes.len() / 4 + 1) {
            f.write_all(chunk).unwrap();
            f.flush().unwrap();
            thread::sleep(Duration::from_millis(1500));
        }
    }
    wait_until(&mut d, "three results", || {
        let r = result_dirs(&data);
        ["pair", "odd\nname", "slow"].iter().all(|n| r.contains(&n.to_string()))
    });
    assert!(reports(&data).is_empty(), "nothing rejected: {:?}", files_in(&data.join("rejected")));
    assert!(data.join("matched/pair/pair.tri").is_file(), "the .tri travels with its .vert");
    let map = fs::read_to_string(data.join("matched/odd\nname/odd\nname.map.txt")).unwrap();
    let header: Vec<&str> = map.lines().filter(|l| l.starts_with('#')).collect();
    assert_eq!(header.len(), 1, "one header line");
    assert!(header[0].contains("odd\\nname.off"), "{}", header[0]);
    assert_eq!(map.lines().count(), n + 1, "one line per vertex after the header");
    assert!(files_in(&incoming).is_empty());
    d.stop();
}

// ---- 12. label maps with signs of corruption ------------------------------------------------

#[test]
fn corrupt_label_maps_are_rejected_naming_file_and_line() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let mut d = Daemon::start(&data, false);
    wait_until(&mut d, "the folders", || data.join("labeled").is_dir());
    let fam = family(1);
    let n = fam.template.n_vertices();
    let ok = identity_labels(n);
    drop_labelled(&data, "two", &fam.shapes[0], &ok.replacen("4\n", "4 200\n", 1));
    drop_labelled(&data, "negative", &fam.shapes[0], &ok.replacen("6\n", "-5\n", 1));
    let same: String = (0..n).map(|_| "7\n").collect();
    drop_labelled(&data, "same", &fam.shapes[0], &same);
    fs::write(data.join("labeled/onevertex.vts"), "7\n7\n7\n7\n").unwrap();
    drop_mesh(&data.join("labeled"), "onevertex.off", &fam.shapes[0]);
    wait_until(&mut d, "four rejections", || reports(&data).len() == 4);
    let error = |name: &str| {
        read_json(&data.join(format!("rejected/{name}.error.json")))["error"].as_str().unwrap().to_string()
    };
    let e = error("two");
    assert!(e.contains("two.labels") && e.contains("line 5") && e.contains("2 values"), "{e}");
    let e = error("negative");
    assert!(e.contains("negative.labels") && e.contains("line 7") && e.contains("negative"), "{e}");
    let e = error("same");
    assert!(e.contains("same.labels") && e.contains("carry label 7"), "{e}");
    let e = error("onevertex");
    assert!(e.contains("onevertex.vts") && e.contains("all 4 labels are on vertex 6"), "{e}");
    d.stop();
}

#[test]
fn cli_train_fails_on_a_bad_shape_unless_told_to_skip_it_and_reads_vts_one_based() {
    let tmp = tempfile::tempdir().unwrap();
    let fam = family(2);
    let n = fam.template.n_vertices();
    let p = |f: &str| tmp.path().join(f);
    write_mesh(p("a.off"), &fam.shapes[0]).unwrap();
    write_mesh(p("b.off"), &fam.shapes[1]).unwrap();
    fs::write(p("a.labels"), identity_labels(n)).unwrap();
    fs::write(p("short.labels"), identity_labels(n - 10)).unwrap();
    // 1-based per-label map: line k holds vertex k (1-based), the last one is vertex n.
    let vts: String = (1..=n).map(|v| format!("{v}\n")).collect();
    fs::write(p("b.vts"), vts).unwrap();
    let base = |labels_b: &str, extra: &[&str]| {
        let mut v: Vec<std::ffi::OsString> = ["train", "--shape"].iter().map(|s| s.into()).collect();
        v.push(p("a.off").into());
        v.push("--labels".into());
        v.push(p("a.labels").into());
        v.push("--shape".into());
        v.push(p("b.off").into());
        v.push("--labels".into());
        v.push(p(labels_b).into());
        for s in ["--trees", "1", "--depth", "4", "--out"] {
            v.push(s.into());
        }
        v.push(p("m.sfm").into());
        v.extend(extra.iter().map(|s| s.into()));
        v
    };
    let run = |v: Vec<std::ffi::OsString>| {
        let a: Vec<&OsStr> = v.iter().map(|s| s.as_os_str()).collect();
        run_cli(&a, Duration::from_secs(120))
    };
    let (status, _, err) = run(base("short.labels", &[]));
    assert!(!status.success(), "a wrong-length map fails the run: {err}");
    assert!(err.contains("--skip-bad"), "{err}");
    let (status, _, err) = run(base("short.labels", &["--skip-bad"]));
    assert!(status.success(), "{err}");
    let (status, _, err) = run(base("b.vts", &[]));
    assert!(status.success(), ".vts read 1-based by default: {err}");
}

// ---- 13. the rest ---------------------------------------------------------------------------

#[test]
fn info_on_a_fifo_fails_at_once() {
    let tmp = tempfile::tempdir().unwrap();
    let fifo = tmp.path().join("pipe.off");
    assert!(Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let (status, _, err) = run_cli(&[os("info"), fifo.as_os_str()], Duration::from_secs(20));
    assert!(!status.success());
    assert!(err.contains("FIFO"), "{err}");
}

#[test]
fn model_errors_say_their_cause_once_and_predict_leaves_loose_vertices_unlabelled() {
    let tmp = tempfile::tempdir().unwrap();
    let fam = family(1);
    let mut mesh = fam.shapes[0].clone();
    mesh.vertices.push([5.0, 5.0, 5.0]); // in no face
    let mesh_path = tmp.path().join("loose.off");
    write_mesh(&mesh_path, &mesh).unwrap();
    // A corrupt model: one payload byte flipped.
    let model = tmp.path().join("m.sfm");
    let n = fam.template.n_vertices();
    let spectrum = Arc::new(compute_spectrum(&fam.shapes[0], &SpectrumParams::new(100)).unwrap());
    let set = TrainingSet::new(vec![TrainingShape::new("a", spectrum, labels_identity(n))], n).unwrap();
    RandomForest::params().n_trees(1).max_depth(6).fit(&set).unwrap().save(&model).unwrap();
    let mut bytes = fs::read(&model).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 0xff;
    let corrupt = tmp.path().join("corrupt.sfm");
    fs::write(&corrupt, bytes).unwrap();
    let (status, _, err) = run_cli(
        &[os("predict"), os("--model"), corrupt.as_os_str(), os("--mesh"), mesh_path.as_os_str()],
        Duration::from_secs(60),
    );
    assert!(!status.success());
    assert_eq!(err.matches("checksum").count(), 1, "the cause once: {err}");
    let out = tmp.path().join("labels.txt");
    let (status, _, err) = run_cli(
        &[
            os("predict"),
            os("--model"),
            model.as_os_str(),
            os("--mesh"),
            mesh_path.as_os_str(),
            os("--out"),
            out.as_os_str(),
        ],
        Duration::from_secs(60),
    );
    assert!(status.success(), "{err}");
    let text = fs::read_to_string(&out).unwrap();
    let last = text.lines().last().unwrap();
    assert_eq!(last.trim(), format!("{n} -"), "the loose vertex gets no label");
}

#[test]
fn pipeline_errors_do_not_cascade_and_a_cycle_is_called_one() {
    let tmp = tempfile::tempdir().unwrap();
    let watch = fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/pipelines/watch.toml")).unwrap();
    let bad_input = tmp.path().join("bad.toml");
    fs::write(&bad_input, watch.replacen("input = \"scans\"", "input = \"scnas\"", 1)).unwrap();
    let (status, _, err) = run_cli(&[os("run"), bad_input.as_os_str()], Duration::from_secs(30));
    assert!(!status.success());
    // The mistake and its one consequence (`scans` now feeds nothing); no cascade of "cycles".
    let problems: Vec<&str> = err.lines().filter(|l| l.trim_start().starts_with("- ")).collect();
    assert!(problems.len() <= 2 && problems.iter().any(|p| p.contains("`scnas`")), "{err}");
    assert!(!err.contains("cycle"), "{err}");
    let cycle = tmp.path().join("cycle.toml");
    fs::write(&cycle, watch.replacen("input = \"scans\"", "input = \"fmap\"", 1)).unwrap();
    let (status, _, err) = run_cli(&[os("run"), cycle.as_os_str()], Duration::from_secs(30));
    assert!(!status.success());
    assert!(err.contains("form a cycle"), "{err}");
    assert_eq!(err.matches("form a cycle").count(), 1, "{err}");
}
