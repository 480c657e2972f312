//! The field's pairwise protocol (`eval --pairs`, [`shapeforest::eval::pairs`]): maps between
//! pairs of unseen shapes, each in its own vertex order, scored on the target.

mod common;

use std::sync::Arc;

use shapeforest::{
    eval::{
        pairs::{run_pairs, PairMethod, PairsParams},
        protocol::ProtocolShape,
        PooledReport,
    },
    forest::RandomForest,
    regularizer::{PairParams, PairStart},
    spectral::SpectrumParams,
};

#[test]
fn pairs_of_unseen_shuffled_shapes_are_mapped_onto_each_other() {
    let family = common::labels::shuffled_family(7);
    let shapes: Vec<ProtocolShape> = family
        .into_iter()
        .enumerate()
        .map(|(i, s)| ProtocolShape { name: format!("s{i}"), mesh: Arc::new(s.mesh), truth: s.truth })
        .collect();
    let params = PairsParams {
        training: vec![0, 1, 2, 3],
        pairs: vec![(4, 5), (5, 6), (6, 4)],
        forest: RandomForest::params().n_trees(8),
        spectrum: SpectrumParams::new(50),
        ..PairsParams::default()
    };
    let mut events = 0;
    let mut on_event = |_: shapeforest::eval::pairs::PairsEvent<'_>| events += 1;
    let report = run_pairs(&shapes, None, &params, Some(&mut on_event)).unwrap();
    assert!(events > 0);
    assert_eq!(report.pairs.len(), 3);
    assert_eq!(report.points_per_pair, shapes[0].truth.len());
    assert!(!report.has_symmetry);
    for p in &report.pairs {
        for m in &p.methods {
            assert_eq!(m.strict.len(), shapes[0].truth.len(), "every corresponded point is scored");
            assert!(m.symmetric.is_none());
            // Each point's image is reported: a point mapped onto its true vertex has no error,
            // and one mapped elsewhere has some.
            assert_eq!(m.images.len(), m.strict.len(), "every corresponded point's image is reported");
            for (k, (&image, &e)) in m.images.iter().zip(&m.strict).enumerate() {
                let truth = shapes[p.b].truth[k];
                assert_eq!(image == truth, e == 0.0, "point {k}: image {image}, truth {truth}, error {e}");
            }
        }
    }
    let (pair, _) = report.summary(PairMethod::Pair);
    let (composed, _) = report.summary(PairMethod::Composed);
    assert!(pair.within_005 >= 0.8, "pair maps: {:.1} % within 0.05", 100.0 * pair.within_005);
    assert!(composed.within_005 >= 0.7, "composed maps: {:.1} % within 0.05", 100.0 * composed.within_005);
    assert!(pair.mean < 0.05, "pair maps: mean error {:.4}", pair.mean);
    // The method's pair map: the composed map refined against the target (the default route).
    let (refined, _) = report.summary(PairMethod::PairZoomOut);
    assert!(refined.within_005 >= 0.8, "refined pair maps: {:.1} % within 0.05", 100.0 * refined.within_005);

    // The other route (the pair's posterior regularised against the target, then refined)
    // meets the same floor.
    let regularised = PairsParams {
        pair: PairParams { start: PairStart::Regularised, ..PairParams::default() },
        ..params.clone()
    };
    let report = run_pairs(&shapes, None, &regularised, None).unwrap();
    let (refined, _) = report.summary(PairMethod::PairZoomOut);
    assert!(refined.within_005 >= 0.8, "regularised route: {:.1} % within 0.05", 100.0 * refined.within_005);

    // Bad settings and plans are refused with the reason.
    let bad = PairsParams { pair: PairParams { radius: -0.1, ..PairParams::default() }, ..params.clone() };
    let e = run_pairs(&shapes, None, &bad, None).err().unwrap().to_string();
    assert!(e.contains("pair radius") && e.contains("-0.1"), "{e}");
    let bad = PairsParams { pairs: vec![(4, 4)], ..params.clone() };
    let e = run_pairs(&shapes, None, &bad, None).err().unwrap().to_string();
    assert!(e.contains("with itself"), "{e}");
    let bad = PairsParams { pairs: vec![(4, 9)], ..params };
    let e = run_pairs(&shapes, None, &bad, None).err().unwrap().to_string();
    assert!(e.contains("outside"), "{e}");
}

#[test]
fn eval_pairs_file_names_the_line_of_an_unknown_shape() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (i, s) in common::labels::shuffled_family(3).iter().enumerate() {
        common::labels::write_shape(d, &format!("s{i}"), s);
    }
    std::fs::write(d.join("pairs.txt"), "# pairs\ns1 s2\ns1 nobody\n").unwrap();
    let out = common::bin()
        .args(["eval", "--class"])
        .arg(d)
        .arg("--pairs")
        .arg(d.join("pairs.txt"))
        .arg("--out")
        .arg(d.join("out"))
        .args(["--no-cache", "--quiet", "--no-symmetry"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("pairs.txt: line 3") && err.contains("nobody"), "{err}");
}
