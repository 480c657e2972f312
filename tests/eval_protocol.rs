//! The evaluation protocol and the `eval` / `match` commands, end to end on small synthetic
//! data (and on the TOSCA wolf class when ../shared/data is present).

mod common;

use std::{path::Path, sync::Arc};

use shapeforest::{
    eval::{
        protocol::{run_protocol, Method, ProtocolParams, ProtocolShape},
        PooledReport,
    },
    forest::RandomForest,
    mesh::{read_mesh, write_mesh},
    spectral::SpectrumParams,
    synth::{creature_family, CreatureParams},
};

fn family(n_vertices: usize, n_shapes: usize) -> shapeforest::synth::ShapeFamily {
    creature_family(&CreatureParams { target_vertices: n_vertices, seed: 1, ..Default::default() }, n_shapes)
        .expect("synthetic family")
}

#[test]
fn protocol_on_a_small_family_beats_raw_wks_knn() {
    let fam = family(1500, 4);
    let shapes = common::protocol_shapes(&fam);
    let params = ProtocolParams {
        n_train: 2,
        max_tests: Some(2),
        eval_points: 300,
        forest: RandomForest::params().n_trees(4).seed(3),
        ..ProtocolParams::default()
    };
    let mut events = 0;
    let mut cb = |_: shapeforest::eval::protocol::ProtocolEvent<'_>| events += 1;
    let report = run_protocol(&shapes, Some(&fam.symmetry), &params, Some(&mut cb)).unwrap();
    assert!(events > 0);
    assert_eq!(report.tests.len(), 2);
    assert_eq!(report.eval_labels.len(), 300);
    for t in &report.tests {
        assert_eq!(t.training.len(), 2);
        assert!(!t.training.contains(&t.test), "a test shape must not be in its own training set");
        assert!(t.training.contains(&t.reference));
        assert_eq!(t.methods.len(), 4);
        for m in &t.methods {
            assert_eq!(m.strict.len(), 300);
            let sym = m.symmetric.as_ref().expect("symmetric errors with a symmetry map");
            // A mirrored match may count as correct, never the other way round.
            assert!(sym.iter().zip(&m.strict).all(|(y, s)| y <= s));
            assert!(m.strict.iter().all(|e| e.is_finite() && *e >= 0.0));
        }
        assert!(t.timings.predict_s > 0.0 && t.timings.regularize_s > 0.0);
    }
    let (reg, reg_sym) = report.summary(Method::ForestRegularized);
    let (knn_raw, _) = report.summary(Method::WksKnnRaw);
    println!("forest+reg {reg:?} sym {reg_sym:?}\nwks-knn raw {knn_raw:?}");
    assert!(
        reg.within_010 > knn_raw.within_010 || reg.mean < knn_raw.mean,
        "regularised forest ({reg:?}) does not beat raw WKS k-NN ({knn_raw:?})"
    );
    // Curves: one per method, strict and symmetric.
    assert_eq!(report.curves(50).len(), 8);
}

#[test]
fn a_zoomout_basis_beyond_the_descriptors_eigenpairs_is_computed_and_used() {
    // Descriptors on 30 eigenpairs; ZoomOut asked to refine up to 60. The protocol used to cap
    // ZoomOut at the descriptors' 30 without a word; now the reference and the scans get 60.
    let fam = family(1500, 4);
    let shapes = common::protocol_shapes(&fam);
    let cache = tempfile::tempdir().unwrap();
    let run = |k_final: usize| {
        let params = ProtocolParams {
            n_train: 2,
            max_tests: Some(1),
            train_once: true,
            eval_points: 300,
            skip_baseline: true,
            forest: RandomForest::params().n_trees(4).seed(3),
            spectrum: SpectrumParams::new(30),
            regularizer: shapeforest::regularizer::RegularizerParams {
                zoomout: Some(shapeforest::regularizer::ZoomOutParams {
                    k_start: 10,
                    k_final,
                    step: 5,
                    samples: 1500,
                    ..Default::default()
                }),
                ..Default::default()
            },
            cache_dir: Some(cache.path().to_path_buf()),
            // Onto the reference itself, so that its spectra are the ones counted below.
            relay: false,
            ..ProtocolParams::default()
        };
        run_protocol(&shapes, Some(&fam.symmetry), &params, None).unwrap()
    };
    let at_30 = run(30);
    let at_60 = run(60);
    let spectra_of = |k: usize| {
        std::fs::read_dir(cache.path())
            .unwrap()
            .filter(|e| {
                e.as_ref().unwrap().file_name().to_string_lossy().ends_with(&format!("-k{k}.spectrum"))
            })
            .count()
    };
    // The reference and the one scan, with 60 eigenpairs beside the descriptors' 30.
    assert_eq!(spectra_of(60), 2, "60-eigenpair spectra of the reference and the scan");
    let errors = |r: &shapeforest::eval::protocol::ProtocolReport| {
        let t = &r.tests[0];
        t.methods.iter().find(|m| m.method == Method::ForestZoomOut).unwrap().strict.clone()
    };
    assert_ne!(errors(&at_30), errors(&at_60), "ZoomOut to 60 gave the map of ZoomOut to 30");
    let (s30, _) = at_30.summary(Method::ForestZoomOut);
    let (s60, _) = at_60.summary(Method::ForestZoomOut);
    println!("ZoomOut to 30: {s30:?}\nZoomOut to 60: {s60:?}");
    assert!(s60.within_005 >= 0.5, "ZoomOut to 60 reaches only {s60:?}");
}

#[test]
fn protocol_rejects_inconsistent_truth_tables() {
    let mut shapes: Vec<ProtocolShape> = (0..2)
        .map(|i| ProtocolShape::identity(format!("s{i}"), Arc::new(shapeforest::synth::icosphere(2, 1.0))))
        .collect();
    shapes[1].truth.pop();
    let e = run_protocol(&shapes, None, &ProtocolParams::default(), None).expect_err("error");
    assert!(e.to_string().contains("s1"), "{e}");
    let e = run_protocol(&shapes[..1], None, &ProtocolParams::default(), None).expect_err("error");
    assert!(e.to_string().contains("at least 2"), "{e}");
}

use common::bin;

/// `shapeforest match` of `scan` onto `reference` with `model`, into `out`.
fn run_match(model: &Path, reference: &Path, scan: &Path, out: &Path) -> std::process::Output {
    bin()
        .args(["match", "--model"])
        .arg(model)
        .arg("--reference")
        .arg(reference)
        .arg("--mesh")
        .arg(scan)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

#[test]
fn match_writes_all_outputs_and_the_map_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    let fam = family(1000, 3);
    let n = fam.template.n_vertices();
    let model = dir.path().join("m.sfm");
    common::save_shared_indexing_model(&[&fam.shapes[0], &fam.shapes[1]], 3, &model);
    let reference = dir.path().join("ref.off");
    let scan = dir.path().join("scan.off");
    write_mesh(&reference, &fam.shapes[0]).unwrap();
    write_mesh(&scan, &fam.shapes[2]).unwrap();
    let out = dir.path().join("out");
    let o = run_match(&model, &reference, &scan, &out);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = std::fs::read_to_string(out.join("scan.map.txt")).unwrap();
    assert!(text.starts_with('#'));
    let map: Vec<usize> =
        text.lines().filter(|l| !l.starts_with('#')).map(|l| l.trim().parse().unwrap()).collect();
    assert_eq!(map.len(), n);
    assert!(map.iter().all(|&r| r < n));
    // The scan is a pose of the reference with the same indexing: most vertices land near home.
    let ref_mesh = &fam.shapes[0];
    let (lo, hi) = ref_mesh.bounding_box();
    let diag = ((0..3).map(|a| (hi[a] - lo[a]).powi(2)).sum::<f64>()).sqrt();
    let near = map
        .iter()
        .enumerate()
        .filter(|&(i, &r)| {
            let dist = |a: usize, b: usize| {
                let (p, q) = (ref_mesh.vertices[a], ref_mesh.vertices[b]);
                ((0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>()).sqrt()
            };
            // Near the ground truth, or near its mirror image (a symmetric flip).
            dist(i, r) < 0.1 * diag || dist(fam.symmetry[i], r) < 0.1 * diag
        })
        .count();
    assert!(near as f64 > 0.5 * n as f64, "only {near} of {n} vertices mapped near their ground truth");
    for f in ["scan.colored.ply", "ref.colored.ply"] {
        let m = read_mesh(out.join(f)).unwrap();
        assert!(m.n_vertices() == n, "{f}");
    }
    let json = std::fs::read_to_string(out.join("scan.report.json")).unwrap();
    for key in ["\"n_matches\"", "\"orientation_score\"", "\"mean_forest_confidence\"", "\"predict\""] {
        assert!(json.contains(key), "report lacks {key}: {json}");
    }

    // A reference whose vertex count differs from the model's labels is refused clearly.
    let other = dir.path().join("small.off");
    write_mesh(&other, &shapeforest::synth::icosphere(3, 1.0)).unwrap();
    let o = run_match(&model, &other, &scan, &out);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("labels") && err.contains("small.off"), "{err}");
}

#[test]
fn missing_files_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope.off");
    let o = bin()
        .args(["match", "--model"])
        .arg(dir.path().join("m.sfm"))
        .arg("--reference")
        .arg(&missing)
        .arg("--mesh")
        .arg(&missing)
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("m.sfm"));

    // eval on a class folder with one broken mesh names that mesh.
    let class = dir.path().join("class");
    std::fs::create_dir_all(&class).unwrap();
    write_mesh(class.join("wolf0.off"), &shapeforest::synth::icosphere(1, 1.0)).unwrap();
    std::fs::write(class.join("wolf1.off"), "OFF\n3 1 0\n0 0 0\n").unwrap();
    let o = bin()
        .args(["eval", "--quiet", "--no-cache", "--prefix", "wolf", "--class"])
        .arg(&class)
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("wolf1.off"), "{err}");
    let o = bin().args(["eval", "--quiet", "--class"]).arg(dir.path().join("absent")).output().unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("absent"));
}

#[test]
fn wolf_class_from_shared_data() {
    let Some(dir) = common::shared_data("tosca/wolf0.off").and_then(|p| p.parent().map(Path::to_path_buf))
    else {
        return;
    };
    let out = tempfile::tempdir().unwrap();
    let o = bin()
        .args(["eval", "--quiet", "--no-cache", "--no-symmetry", "--prefix", "wolf"])
        .args(["--train", "2", "--tests", "1"])
        .args(["--train-once", "--trees", "4", "--eval-points", "300", "--class"])
        .arg(&dir)
        .arg("--out")
        .arg(out.path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}\n{}", stdout, String::from_utf8_lossy(&o.stderr));
    println!("{stdout}");
    let csv = std::fs::read_to_string(out.path().join("results.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 4, "{csv}");
    let reg = csv.lines().find(|l| l.contains(",forest+reg,")).unwrap();
    let cols: Vec<&str> = reg.split(',').collect();
    let within_010: f64 = cols[5].parse().unwrap();
    assert!(within_010 > 0.3, "regularised forest reached only {within_010} within 0.1 on wolf: {reg}");
    for f in ["curves.csv", "curves.svg", "timings.csv", "peer/pairs.json"] {
        assert!(out.path().join(f).is_file(), "{f} missing");
    }
}
