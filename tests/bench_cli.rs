//! `shapeforest bench` through the binary: `--out` writes meshes that read back, a manifest the
//! peer script can follow and our timings; `--report` joins them with a peer's results.

mod common;

use std::path::Path;
use std::process::Output;

use serde_json::{json, Value};
use shapeforest::mesh::read_mesh;

fn shapeforest(args: &[&str]) -> Output {
    common::bin().args(args).output().expect("running the shapeforest binary")
}

fn read_json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).expect("reading JSON")).expect("parsing JSON")
}

/// Runs `bench --out` on one ~1000-vertex creature; returns the folder.
fn bench_out() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let out = shapeforest(&["bench", "--out", dir.path().to_str().unwrap(), "--sizes", "1000", "--no-data"]);
    assert!(out.status.success(), "bench --out failed: {}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stderr).contains("TOSCA meshes skipped"));
    dir
}

#[test]
fn bench_out_writes_manifest_meshes_and_timings() {
    let dir = bench_out();
    let manifest = read_json(&dir.path().join("manifest.json"));
    assert_eq!(manifest["k"], 100);
    assert_eq!(manifest["shift"], -0.01);
    let meshes = manifest["meshes"].as_array().unwrap();
    assert_eq!(meshes.len(), 1);
    let m = &meshes[0];
    assert_eq!(m["name"], "creature-1000");
    let mesh = read_mesh(m["path"].as_str().unwrap()).expect("benchmark OFF file reads back");
    let n = mesh.n_vertices();
    assert_eq!(m["vertices"].as_u64().unwrap() as usize, n);
    assert!((900..=1100).contains(&n), "{n} vertices for a ~1000 target");
    let mut sources: Vec<usize> =
        m["sources"].as_array().unwrap().iter().map(|s| s.as_u64().unwrap() as usize).collect();
    assert_eq!(sources.len(), 50);
    sources.sort_unstable();
    sources.dedup();
    assert_eq!(sources.len(), 50, "sources are distinct");
    assert!(sources.iter().all(|&s| s < n));

    let ours = read_json(&dir.path().join("shapeforest.json"));
    let r = &ours["meshes"][0];
    assert_eq!(r["name"], "creature-1000");
    let lambda: Vec<f64> = r["eigenvalues"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
    assert_eq!(lambda.len(), 100);
    assert!(lambda.windows(2).all(|w| w[0] <= w[1]), "eigenvalues ascending");
    // Unit-area closed surface: λ_0 = 0, and Weyl's law λ_k ≈ 4πk.
    assert!(lambda[0].abs() < 1e-8, "λ_0 = {}", lambda[0]);
    assert!(
        lambda[99] > 4.0 * std::f64::consts::PI * 99.0 * 0.5
            && lambda[99] < 4.0 * std::f64::consts::PI * 99.0 * 2.0
    );
    for key in ["eigen_s", "heat_setup_s", "heat_solve_s", "wks_s"] {
        assert!(r[key].as_f64().unwrap() > 0.0, "{key} timed");
    }
}

#[test]
fn bench_report_prints_ratios_and_eigenvalue_agreement() {
    let dir = bench_out();
    let ours = read_json(&dir.path().join("shapeforest.json"));
    let r = &ours["meshes"][0];
    let eigen_s = r["eigen_s"].as_f64().unwrap();
    let heat_s = r["heat_setup_s"].as_f64().unwrap() + r["heat_solve_s"].as_f64().unwrap();
    // A peer 4× slower on the eigenproblem, 2× slower on the heat method, and one eigenvalue off
    // by a relative 1e-3.
    let mut lambda: Vec<f64> =
        r["eigenvalues"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
    lambda[50] *= 1.001;
    let peer = json!({
        "peer": {"scipy": "9.9.9", "potpourri3d": "1.2.3"},
        "meshes": [{
            "name": "creature-1000",
            "vertices": r["vertices"],
            "eigsh_s": 4.0 * eigen_s,
            "eigenvalues": lambda,
            "heat_setup_s": heat_s,
            "heat_solve_s": heat_s,
        }],
    });
    std::fs::write(dir.path().join("peer.json"), peer.to_string()).unwrap();
    let out = shapeforest(&["bench", "--report", dir.path().to_str().unwrap()]);
    assert!(out.status.success(), "bench --report failed: {}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("scipy 9.9.9") && text.contains("potpourri3d 1.2.3"), "{text}");
    let row = text
        .lines()
        .find(|l| l.starts_with("| creature-1000 |"))
        .unwrap_or_else(|| panic!("no row in {text}"));
    let cells: Vec<&str> = row.split('|').map(str::trim).collect();
    // cells[0] is empty (leading '|'): mesh, vertices, eigen, eigsh, ratio, heat, peer heat, ratio, Δλ.
    assert_eq!(cells[5], "0.25", "{row}");
    assert_eq!(cells[8], "0.50", "{row}");
    let dl: f64 = cells[9].parse().unwrap();
    assert!((dl - 1e-3).abs() < 1e-5, "{row}");
}

#[test]
fn bench_report_without_peer_results_names_the_missing_file() {
    let dir = bench_out();
    let out = shapeforest(&["bench", "--report", dir.path().to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("peer.json"));
}

#[test]
fn bench_with_missing_data_folder_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nowhere");
    let out = shapeforest(&[
        "bench",
        "--out",
        dir.path().to_str().unwrap(),
        "--sizes",
        "1000",
        "--data",
        missing.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no tosca/ folder"));
}
