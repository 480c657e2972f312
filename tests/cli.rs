//! The command-line tool through its binary: the commands a user runs, and their errors.

use std::process::Command;

use shapeforest::{mesh::write_mesh, synth::icosphere};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_shapeforest"))
}

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
    let out = bin()
        .args([
            "train",
            "--synthetic",
            "--vertices",
            "1000",
            "--n-synthetic",
            "3",
            "--trees",
            "3",
            "-k",
            "30",
        ])
        .arg("--out")
        .arg(&model)
        .output()
        .unwrap();
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
