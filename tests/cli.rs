//! The command-line tool through its binary: the commands a user runs, and their errors.

mod common;

use shapeforest::{mesh::write_mesh, synth::icosphere};

use common::bin;

/// `train` on three small synthetic creatures, three trees, 30 eigenpairs.
const SMALL_SYNTHETIC_TRAINING: [&str; 10] =
    ["train", "--synthetic", "--vertices", "1000", "--n-synthetic", "3", "--trees", "3", "-k", "30"];

#[test]
fn info_summarises_a_mesh_and_names_a_bad_file() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("sphere.off");
    write_mesh(&good, &icosphere(2, 1.0)).unwrap();
    let out = bin().arg("info").arg(&good).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("162"), "vertex count missing: {text}");

    let bad = dir.path().join("broken.off");
    std::fs::write(&bad, "OFF\n3 1 0\n0 0 0\n1 0\n").unwrap();
    let out = bin().arg("info").arg(&bad).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("broken.off"), "error does not name the file: {err}");
}

#[test]
fn train_then_predict_labels_every_vertex() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("m.sfm");
    let out = bin().args(SMALL_SYNTHETIC_TRAINING).arg("--out").arg(&model).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(model.exists());

    // A new pose of the same creature family (same vertex count, different seed stream).
    let fam = shapeforest::synth::creature_family(
        &shapeforest::synth::CreatureParams { target_vertices: 1000, seed: 9, ..Default::default() },
        2,
    )
    .unwrap();
    let mesh = dir.path().join("scan.ply");
    write_mesh(&mesh, &fam.shapes[1]).unwrap();
    let labels = dir.path().join("labels.txt");
    let out = bin()
        .args(["predict", "--top-k", "3", "--model"])
        .arg(&model)
        .arg("--mesh")
        .arg(&mesh)
        .arg("--out")
        .arg(&labels)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = std::fs::read_to_string(&labels).unwrap();
    let rows: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).collect();
    assert_eq!(rows.len(), fam.shapes[1].n_vertices());
    // Every vertex gets a label, and the top-k probabilities are listed.
    assert!(rows.iter().all(|r| r.split_whitespace().nth(1).is_some_and(|l| l != "-")));
    assert!(rows[0].contains(':'));
}

#[test]
fn predict_with_a_missing_model_says_which_file() {
    let out =
        bin().args(["predict", "--model", "/nonexistent/model.sfm", "--mesh", "x.off"]).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("model.sfm"), "{err}");
}

#[test]
fn train_without_input_explains_what_to_give() {
    let out = bin().arg("train").output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--class") && err.contains("--synthetic"), "{err}");
}

#[test]
fn train_reads_vts_style_label_maps() {
    // Two poses of a remeshed-style shape: the .vts files list, per label, a vertex (1-based).
    let dir = tempfile::tempdir().unwrap();
    let fam = shapeforest::synth::creature_family(
        &shapeforest::synth::CreatureParams { target_vertices: 1000, seed: 3, ..Default::default() },
        2,
    )
    .unwrap();
    let n = fam.template.n_vertices();
    let mut cmd = bin();
    cmd.args(["train", "--trees", "2", "-k", "30", "--one-based"]);
    for (i, mesh) in fam.shapes.iter().enumerate() {
        let m = dir.path().join(format!("s{i}.off"));
        write_mesh(&m, mesh).unwrap();
        // Labels are every second vertex, in reverse order: label k ↔ vertex n-1-2k.
        let rows: String = (0..n / 2).map(|k| format!("{}\n", n - 2 * k)).collect();
        let vts = dir.path().join(format!("s{i}.vts"));
        std::fs::write(&vts, rows).unwrap();
        cmd.arg("--shape").arg(&m).arg("--labels").arg(&vts);
    }
    let model = dir.path().join("m.sfm");
    let out = cmd.arg("--out").arg(&model).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let forest = shapeforest::forest::RandomForest::load(&model).unwrap();
    assert_eq!(forest.n_labels(), n / 2, "label set = rows of the .vts files");

    // An index beyond the mesh is an error naming the file and line.
    let bad = dir.path().join("bad.vts");
    std::fs::write(&bad, format!("1\n{}\n", n + 5)).unwrap();
    let out = bin()
        .args(["train", "--one-based", "--shape"])
        .arg(dir.path().join("s0.off"))
        .arg("--labels")
        .arg(&bad)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.vts") && err.contains("line 2"), "{err}");
}

#[test]
fn run_refuses_a_bad_pipeline_file_naming_stage_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("mine.toml");
    std::fs::write(
        &file,
        "name = \"mine\"\n[[stage]]\nname = \"in\"\ntype = \"folder\"\nfolder = \"x\"\n\
         [[stage]]\nname = \"read\"\ntype = \"ingest\"\ninput = \"in\"\nmax_vertex = 5\n",
    )
    .unwrap();
    let out = bin().arg("run").arg(&file).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("mine.toml"), "{err}");
    assert!(err.contains("stage `read` (ingest): unknown field `max_vertex`"), "{err}");
    assert!(err.contains("its output (shape) goes nowhere"), "{err}");
}

#[test]
fn train_then_match_pipelines_on_a_data_folder() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let n = common::creatures_data_folder(&data, 2);
    let root = env!("CARGO_MANIFEST_DIR");
    for p in ["train", "match"] {
        let out = bin()
            .arg("run")
            .arg(format!("{root}/pipelines/{p}.toml"))
            .arg("--data-dir")
            .arg(&data)
            .output()
            .unwrap();
        assert!(out.status.success(), "{p}: {}", String::from_utf8_lossy(&out.stderr));
    }
    assert!(data.join("models/model-v000001.sfm").is_file());
    let map = std::fs::read_to_string(data.join("matched/scan/scan.map.txt")).unwrap();
    assert_eq!(map.lines().filter(|l| !l.starts_with('#')).count(), n);
    assert!(data.join("incoming/scan.off").is_file(), "batch matching reads inputs in place");
}

#[test]
fn a_model_with_local_histograms_is_trained_written_as_version_4_and_matches_a_single_view() {
    use shapeforest::mesh::{perturb, Perturbation};
    use shapeforest::synth::{creature_family, CreatureParams};
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("local.sfm");
    let out = bin()
        .args(SMALL_SYNTHETIC_TRAINING)
        .args(["--augment", "partial-view", "--augment-copies", "2", "--local-descriptors", "--out"])
        .arg(&model)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("splits on local histograms"), "{err}");
    // The smallest leaf was chosen from the training set, and a leaf of 0 samples is refused.
    assert!(err.contains("sample(s) (auto)"), "{err}");
    // A command line refused: it fails, and its message holds every one of `needles`.
    let refused = |args: &[&str], out: &str, needles: &[&str]| {
        let bad = bin().args(args).arg("--out").arg(dir.path().join(out)).output().unwrap();
        let bad_err = String::from_utf8_lossy(&bad.stderr);
        assert!(!bad.status.success() && needles.iter().all(|n| bad_err.contains(n)), "{bad_err}");
    };
    refused(
        &["train", "--synthetic", "--min-leaf", "0"],
        "x.sfm",
        &["expected `auto` or a number of samples of at least 1"],
    );
    // Nor is a forest of 0 trees (`auto` chooses the number).
    refused(
        &["train", "--synthetic", "--trees", "0"],
        "x.sfm",
        &["expected `auto` or a number of trees of at least 1"],
    );
    // A negative weight of the forest's word in a view's placement is refused by name.
    refused(&["eval", "--synthetic", "--part-prior=-1"], "e", &["--part-prior", "a finite weight ≥ 0"]);
    let bytes = std::fs::read(&model).unwrap();
    assert_eq!(u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]), 4, "format version");

    // The reference is the first training shape; the scan a single view of another pose.
    let fam = creature_family(&CreatureParams { target_vertices: 1000, ..Default::default() }, 4).unwrap();
    let reference = dir.path().join("ref.off");
    write_mesh(&reference, &fam.shapes[0]).unwrap();
    let view = perturb(&fam.shapes[3], &[Perturbation::PARTIAL_VIEW], 3).unwrap();
    let scan = dir.path().join("view.off");
    write_mesh(&scan, &view.mesh).unwrap();
    let out_dir = dir.path().join("out");
    let out = bin()
        .args(["match", "--model"])
        .arg(&model)
        .arg("--reference")
        .arg(&reference)
        .arg("--mesh")
        .arg(&scan)
        .arg("--out")
        .arg(&out_dir)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = std::fs::read_to_string(out_dir.join("view.map.txt")).unwrap();
    let map: Vec<usize> =
        text.lines().filter(|l| !l.starts_with('#')).map(|l| l.trim().parse().unwrap()).collect();
    assert_eq!(map.len(), view.mesh.n_vertices());
    assert!(map.iter().all(|&r| r < fam.shapes[0].n_vertices()));

    // A radius outside (0, 1] is refused before anything is read.
    let out = bin()
        .args(["train", "--synthetic", "--local-descriptors", "--local-radius", "0", "--out"])
        .arg(dir.path().join("x.sfm"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("radius"));
}
