//! Integration tests of the random forest through the public API, on small synthetic families
//! (a bumpy sphere under anisotropic stretches and bends, sharing vertex indexing).

mod common;

use std::sync::Arc;

use shapeforest::descriptor::WksParams;
use shapeforest::forest::{
    hit_ratio, labels_identity, read_label_map, ForestError, Prediction, RandomForest, TrainingSet,
    TrainingShape, WksKnn,
};
use shapeforest::mesh::Mesh;
use shapeforest::spectral::{dense_spectrum, Spectrum};

const K: usize = 30;

use common::bumpy::{bumpy_member as member, bumpy_sphere as base};

struct Family {
    base: Mesh,
    spectra: Vec<Arc<Spectrum>>,
}

fn family(n: usize) -> Family {
    let base = base();
    let spectra = (0..n).map(|i| Arc::new(dense_spectrum(&member(&base, i), K).unwrap())).collect();
    Family { base, spectra }
}

fn set_of(f: &Family, ids: &[usize]) -> TrainingSet {
    TrainingSet::same_indexing(ids.iter().map(|&i| (format!("member{i}"), f.spectra[i].clone()))).unwrap()
}

/// Fraction of vertices whose MAP label lies within `radius` (Euclidean, on the base shape) of
/// the true one.
fn within(base: &Mesh, pred: &Prediction, radius: f64) -> f64 {
    let map = pred.map_labels();
    let ok = map
        .iter()
        .enumerate()
        .filter(|(v, l)| {
            l.is_some_and(|l| {
                let (a, b) = (base.vertices[*v], base.vertices[l as usize]);
                ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt() <= radius
            })
        })
        .count();
    ok as f64 / map.len() as f64
}

#[test]
fn forest_beats_wks_knn_on_held_out_shape() {
    let f = family(6);
    let set = set_of(&f, &[0, 1, 2, 3, 4]);
    let forest = RandomForest::params().n_trees(10).seed(3).fit(&set).unwrap();
    let pred = forest.predict(&f.spectra[5]).unwrap();
    let support = pred.mean_support().round().max(1.0) as usize;
    let knn = WksKnn::fit(&set, &WksParams::default(), forest.energy_grid().range, forest.k()).unwrap();
    let base_pred = knn.predict(&f.spectra[5], support).unwrap();
    let truth = labels_identity(f.base.n_vertices());
    let (hf, hk) = (hit_ratio(&pred.map_labels(), &truth), hit_ratio(&base_pred.map_labels(), &truth));
    let (wf, wk) = (within(&f.base, &pred, 0.2), within(&f.base, &base_pred, 0.2));
    println!("support {support}: forest hit {hf:.3} within {wf:.3}; wks-knn hit {hk:.3} within {wk:.3}");
    assert!(hf > hk, "forest {hf} vs knn {hk}");
    assert!(wf > wk, "forest {wf} vs knn {wk}");
}

#[test]
fn wks_knn_tree_search_finds_the_brute_force_neighbours() {
    // The kd-tree on a projection must return exactly the exhaustive search's neighbours.
    let f = family(4);
    let set = set_of(&f, &[0, 1, 2]);
    let forest = RandomForest::params().n_trees(2).seed(1).fit(&set).unwrap();
    let knn = WksKnn::fit(&set, &WksParams::default(), forest.energy_grid().range, forest.k()).unwrap();
    for k in [1, 7] {
        let (tree, brute) =
            (knn.predict(&f.spectra[3], k).unwrap(), knn.predict_brute_force(&f.spectra[3], k).unwrap());
        assert_eq!(tree.n_vertices(), brute.n_vertices());
        let differ = (0..tree.n_vertices()).filter(|&v| tree.posterior(v) != brute.posterior(v)).count();
        // ties at round-off may order two equidistant neighbours differently: none expected here
        assert_eq!(differ, 0, "k = {k}: {differ} of {} vertices differ", tree.n_vertices());
    }
}

#[test]
fn deterministic_given_seed_and_posteriors_sum_to_one() {
    let f = family(3);
    let set = set_of(&f, &[0, 1]);
    let p = RandomForest::params().n_trees(4).seed(11);
    let (a, b) = (p.clone().fit(&set).unwrap(), p.clone().fit(&set).unwrap());
    assert_eq!(a, b);
    // The by-value fit (it frees the spectra before growing) grows the very same trees.
    let owned = p.check().unwrap().fit_owned(set.clone(), &|_| {}).unwrap();
    assert_eq!(owned, a, "fit_owned differs from fit");
    let (pa, pb) = (a.predict(&f.spectra[2]).unwrap(), b.predict(&f.spectra[2]).unwrap());
    assert_eq!(pa, pb);
    let c = RandomForest::params().n_trees(4).seed(12).fit(&set).unwrap();
    assert_ne!(a, c, "another seed grows another forest");
    for v in 0..pa.n_vertices() {
        let (labels, probs) = pa.posterior(v);
        assert!(!labels.is_empty());
        assert!(labels.windows(2).all(|w| w[0] < w[1]));
        let s: f32 = probs.iter().sum();
        assert!((s - 1.0).abs() < 1e-5, "vertex {v} sums to {s}");
        let top = pa.top_k(v, 3);
        assert!(top.windows(2).all(|w| w[0].1 >= w[1].1));
        assert_eq!(Some(top[0].0), pa.map_labels()[v]);
    }
}

#[test]
fn params_check_messages_state_the_rule() {
    let msg = |p: shapeforest::forest::RandomForestParams| p.check().unwrap_err().to_string();
    let m = msg(RandomForest::params().max_depth(0));
    assert!(m.contains("`max_depth`") && m.contains("must be at least 1, got 0"), "{m}");
    let m = msg(RandomForest::params().bagging_fraction(1.5));
    assert!(m.contains("`bagging_fraction`") && m.contains("greater than 0 and at most 1, got 1.5"), "{m}");
    let m = msg(RandomForest::params().min_samples_split(1));
    assert!(m.contains("`min_samples_split`") && m.contains("at least 2"), "{m}");
    let m = msg(RandomForest::params().trees_per_update(0));
    assert!(m.contains("`trees_per_update`") && m.contains("at least 1, got 0"), "{m}");
    let m = msg(RandomForest::params().min_entropy(-1.0));
    assert!(m.contains("`min_entropy`") && m.contains("at least 0"), "{m}");
    let m = msg(RandomForest::params().k_min(1));
    assert!(m.contains("`k_min`") && m.contains("at least 2"), "{m}");
    assert!(RandomForest::params().check().is_ok());
    // k_min above K is caught at fit time.
    let f = family(1);
    let e = RandomForest::params().k_min(K + 1).fit(&set_of(&f, &[0])).unwrap_err().to_string();
    assert!(e.contains("`k_min`") && e.contains(&format!("at most the number of eigenpairs K = {K}")), "{e}");
}

#[test]
fn bad_shapes_are_rejected_and_the_rest_train() {
    let f = family(1);
    let n = f.base.n_vertices();
    let good = TrainingShape::new("good", f.spectra[0].clone(), labels_identity(n));
    let short = TrainingShape::new("short", f.spectra[0].clone(), labels_identity(n - 1));
    let mut out_of_range = labels_identity(n);
    out_of_range[7] = Some(n as u32 + 3);
    let oor = TrainingShape::new("oor", f.spectra[0].clone(), out_of_range);
    let (set, rejected) =
        TrainingSet::new_with_rejections(vec![short.clone(), good, oor.clone()], n).unwrap();
    assert_eq!(set.shapes().len(), 1);
    assert_eq!(rejected.len(), 2);
    let m0 = rejected[0].error.to_string();
    assert!(m0.contains("`short`") && m0.contains(&format!("{} entries", n - 1)), "{m0}");
    let m1 = rejected[1].error.to_string();
    assert!(m1.contains("`oor`") && m1.contains("vertex 7") && m1.contains("outside the label set"), "{m1}");
    assert!(RandomForest::params().n_trees(2).fit(&set).is_ok());
    let e = TrainingSet::new(vec![short, oor], n).unwrap_err();
    assert!(matches!(e, ForestError::EmptyTrainingSet { .. }), "{e}");
    // Unlabelled vertices are skipped.
    let mut partial = labels_identity(n);
    for l in partial.iter_mut().skip(n / 2) {
        *l = None;
    }
    let s = TrainingShape::new("half", f.spectra[0].clone(), partial);
    let set = TrainingSet::new(vec![s], n).unwrap();
    assert_eq!(set.n_samples(), n / 2);
    let pred = RandomForest::params().n_trees(2).fit(&set).unwrap().predict(&f.spectra[0]).unwrap();
    assert!(pred.map_labels().iter().flatten().all(|&l| (l as usize) < n / 2));
}

#[test]
fn label_maps_parse_both_bases_and_unlabelled_markers() {
    let zero = read_label_map("2\n\n-1\n0  \nnone\n".as_bytes(), false, 3).unwrap();
    assert_eq!(zero, vec![Some(2), None, None, Some(0), None]);
    // Signs of a corrupt map are errors naming the line: two values on a line, a negative
    // label other than -1, one label on every vertex.
    let e = read_label_map("1\n100 200\n".as_bytes(), false, 300).unwrap_err().to_string();
    assert!(e.contains("line 2") && e.contains("2 values"), "{e}");
    let e = read_label_map("1\n-5\n".as_bytes(), false, 3).unwrap_err().to_string();
    assert!(e.contains("line 2") && e.contains("negative"), "{e}");
    let e = read_label_map("2\n2\n2\n".as_bytes(), false, 3).unwrap_err().to_string();
    assert!(e.contains("all 3 labelled vertices carry label 2"), "{e}");
    let one = read_label_map("3\n1\n0\n".as_bytes(), true, 3).unwrap();
    assert_eq!(one, vec![Some(2), Some(0), None]);
    let e = read_label_map("1\nx\n".as_bytes(), false, 3).unwrap_err().to_string();
    assert!(e.contains("line 2") && e.contains("\"x\""), "{e}");
    let e = read_label_map("3\n".as_bytes(), false, 3).unwrap_err().to_string();
    assert!(e.contains("line 1") && e.contains("outside the label set of 3"), "{e}");
}

#[test]
fn model_round_trip_and_bad_files() {
    let f = family(2);
    let set = set_of(&f, &[0]);
    let forest = RandomForest::params().n_trees(3).seed(5).fit(&set).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("model.sfm");
    forest.save(&path).unwrap();
    let loaded = RandomForest::load(&path).unwrap();
    assert_eq!(loaded, forest);
    assert_eq!(loaded.predict(&f.spectra[1]).unwrap(), forest.predict(&f.spectra[1]).unwrap());
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1, "no temporary file left behind");

    let bytes = std::fs::read(&path).unwrap();
    assert!(matches!(RandomForest::from_bytes(b"OFF\n3 1 0\n"), Err(ForestError::NotAModel)));
    assert!(matches!(RandomForest::load(dir.path().join("missing")), Err(ForestError::Io { .. })));
    let mut v5 = bytes.clone();
    v5[8] = 5;
    let e = RandomForest::from_bytes(&v5).unwrap_err();
    assert!(matches!(e, ForestError::UnsupportedVersion { found: 5, oldest: 1, supported: 4 }), "{e}");
    let mut flipped = bytes.clone();
    let mid = bytes.len() / 2;
    flipped[mid] ^= 0x40;
    assert!(matches!(RandomForest::from_bytes(&flipped), Err(ForestError::ChecksumMismatch { .. })));
    // Every truncation (sampled with a fixed stride plus the first bytes) is an error, not a panic.
    let mut cuts: Vec<usize> = (0..40).collect();
    cuts.extend((40..bytes.len()).step_by(bytes.len() / 97 + 1));
    cuts.push(bytes.len() - 1);
    for cut in cuts {
        let e = RandomForest::from_bytes(&bytes[..cut]);
        assert!(
            matches!(e, Err(ForestError::NotAModel) | Err(ForestError::Truncated { .. })),
            "cut at {cut}: {e:?}"
        );
    }
    // A consistent checksum over a garbage payload is still rejected (decode or validation).
    let mut forged = bytes[..28].to_vec();
    let garbage: Vec<u8> = (0..200u32).map(|i| (i * 37 % 251) as u8).collect();
    forged[12..20].copy_from_slice(&(garbage.len() as u64).to_le_bytes());
    forged[20..28].copy_from_slice(&shapeforest::forest::fnv1a64(&garbage).to_le_bytes());
    forged.extend_from_slice(&garbage);
    assert!(matches!(RandomForest::from_bytes(&forged), Err(ForestError::CorruptModel(_))));
}

#[test]
fn incremental_growth_raises_accuracy_and_old_model_keeps_serving() {
    let f = family(6);
    let truth = labels_identity(f.base.n_vertices());
    let params = RandomForest::params().n_trees(8).trees_per_update(4).seed(2).check().unwrap();
    let small = params.fit(&set_of(&f, &[0])).unwrap();
    let before = small.predict(&f.spectra[5]).unwrap();
    let grown = params.fit_with(Some(&small), &set_of(&f, &[0, 1, 2, 3, 4])).unwrap();
    assert_eq!(grown.n_trees(), 8, "oldest trees retired beyond n_trees");
    let regrown = params.fit_with(Some(&grown), &set_of(&f, &[0, 1, 2, 3, 4])).unwrap();
    let after1 = grown.predict(&f.spectra[5]).unwrap();
    let after2 = regrown.predict(&f.spectra[5]).unwrap();
    let (h0, h1, h2) =
        (within(&f.base, &before, 0.2), within(&f.base, &after1, 0.2), within(&f.base, &after2, 0.2));
    println!("within 0.2: 1 shape {h0:.3}, +4 new trees {h1:.3}, +4 more {h2:.3}");
    assert!(h1 > h0 && h2 > h0, "{h0} {h1} {h2}");
    assert_eq!(small.predict(&f.spectra[5]).unwrap(), before, "the previous forest is unchanged");
    // Incompatible growth is refused.
    let n = f.base.n_vertices();
    let other =
        TrainingSet::new(vec![TrainingShape::new("x", f.spectra[0].clone(), labels_identity(n))], n + 1)
            .unwrap();
    assert!(matches!(params.fit_with(Some(&small), &other), Err(ForestError::IncompatibleModel(_))));
    let _ = hit_ratio(&after2.map_labels(), &truth);
}

#[test]
fn composition_transfers_correspondence_between_unseen_shapes() {
    let f = family(6);
    let forest = RandomForest::params().n_trees(8).seed(9).fit(&set_of(&f, &[0, 1, 2, 3])).unwrap();
    let (a, b) = (forest.predict(&f.spectra[4]).unwrap(), forest.predict(&f.spectra[5]).unwrap());
    let ab = a.compose(&b).unwrap();
    assert_eq!(ab.n_labels(), b.n_vertices());
    for v in 0..ab.n_vertices() {
        let s: f32 = ab.posterior(v).1.iter().sum();
        assert!(ab.posterior(v).0.is_empty() || (s - 1.0).abs() < 1e-4, "{s}");
    }
    let w = within(&f.base, &ab, 0.25);
    println!("composition within 0.25: {w:.3}");
    assert!(w > 0.5, "{w}");
}

#[test]
fn types_are_send_sync() {
    fn ok<T: Send + Sync + 'static>() {}
    ok::<RandomForest>();
    ok::<Prediction>();
    ok::<TrainingSet>();
    ok::<WksKnn>();
    ok::<ForestError>();
}

#[test]
fn local_histograms_must_be_carried_by_every_shape_or_none_and_an_update_keeps_them() {
    use shapeforest::descriptor::LocalParams;
    let f = family(3);
    let n = f.base.n_vertices();
    let local = LocalParams { radius: 0.15, ..Default::default() };
    let with = |i: usize| {
        TrainingShape::new(format!("member{i}"), f.spectra[i].clone(), labels_identity(n))
            .with_local(&member(&f.base, i), Some(&local))
            .unwrap()
    };
    let without =
        |i: usize| TrainingShape::new(format!("plain{i}"), f.spectra[i].clone(), labels_identity(n));
    // A set mixing shapes with and without histograms keeps the first kind and names the others.
    let set = TrainingSet::new(vec![with(0), without(1), with(2)], n).unwrap();
    assert_eq!(set.shapes().len(), 2);
    assert_eq!(set.local_params(), Some(local));
    let (name, why) = &set.rejected()[0];
    assert_eq!(name, "plain1");
    assert!(why.contains("no local histograms"), "{why}");
    // Histograms of another mesh (another vertex count) are refused by name.
    let other = shapeforest::synth::icosphere(2, 1.0);
    let wrong = TrainingShape::new("wrong", f.spectra[0].clone(), labels_identity(n));
    assert!(wrong.with_local(&other, Some(&local)).is_err());
    // An update must bring the same kind of shapes as the model was grown on.
    let params = RandomForest::params().n_trees(2).trees_per_update(1).seed(5).check().unwrap();
    let forest = params.fit(&set).unwrap();
    let plain = TrainingSet::new(vec![without(1)], n).unwrap();
    let e = params.fit_with(Some(&forest), &plain).unwrap_err();
    assert!(e.to_string().contains("local histograms"), "{e}");
    let grown = params.fit_with(Some(&forest), &TrainingSet::new(vec![with(1)], n).unwrap()).unwrap();
    assert_eq!(grown.local(), Some(&local));
    assert_eq!(grown.n_trees(), 2);
}

#[test]
fn an_automatic_leaf_holds_an_eighth_of_each_labels_samples() {
    let f = family(6);
    let n = f.base.n_vertices();
    let fit = |set: &TrainingSet, leaf: Option<usize>| {
        let p = RandomForest::params().n_trees(2).seed(1);
        match leaf {
            Some(l) => p.min_samples_leaf(l),
            None => p,
        }
        .fit(set)
        .unwrap()
    };
    // Six complete shapes: six examples of each label, so the default keeps pure leaves and
    // grows the very trees that `min_samples_leaf(1)` does.
    let complete = set_of(&f, &[0, 1, 2, 3, 4, 5]);
    assert_eq!(complete.samples_per_label(), 6.0);
    let auto = fit(&complete, None);
    assert_eq!(auto.min_samples_leaf(), 1);
    assert_eq!(auto.to_bytes().unwrap(), fit(&complete, Some(1)).to_bytes().unwrap());
    // Fifty copies, half of them labelled on one half of the vertices only (as single-view copies
    // are): 37.5 examples per label, leaves of 5; a number given is kept.
    let copies: Vec<TrainingShape> = (0..50)
        .map(|i| {
            let labels = labels_identity(n)
                .into_iter()
                .enumerate()
                .map(|(v, l)| l.filter(|_| i % 2 == 0 || v < n / 2));
            TrainingShape::new(format!("copy{i}"), f.spectra[i % 6].clone(), labels.collect())
        })
        .collect();
    let set = TrainingSet::new(copies, n).unwrap();
    assert!((set.samples_per_label() - 37.5).abs() < 0.1, "{}", set.samples_per_label());
    let auto = fit(&set, None);
    assert_eq!(auto.min_samples_leaf(), 5);
    assert_eq!(fit(&set, Some(2)).min_samples_leaf(), 2);
}

#[test]
fn an_automatic_forest_grows_more_trees_where_its_leaves_hold_several_samples() {
    use shapeforest::forest::{AUTO_TREES_MIXED, AUTO_TREES_PURE};
    let f = family(6);
    let n = f.base.n_vertices();
    // Six complete shapes: pure leaves, the paper's 15 trees (resolved before fitting, as a
    // progress bar reads it, and stored by the fit).
    let complete = set_of(&f, &[0, 1, 2, 3, 4, 5]);
    let auto = RandomForest::params().seed(1).check().unwrap();
    assert_eq!(auto.n_trees(), 0);
    assert_eq!(auto.resolved_for(&complete).n_trees(), AUTO_TREES_PURE);
    assert_eq!(AUTO_TREES_PURE, 15);
    // Thirty copies (five of each shape): 30 examples of each label, leaves of 4, whose
    // posteriors mix neighbouring labels, so more trees.
    let copies: Vec<TrainingShape> = (0..30)
        .map(|i| TrainingShape::new(format!("copy{i}"), f.spectra[i % 6].clone(), labels_identity(n)))
        .collect();
    let mixed = TrainingSet::new(copies, n).unwrap();
    let resolved = auto.resolved_for(&mixed);
    assert_eq!((resolved.min_samples_leaf(), resolved.n_trees()), (4, AUTO_TREES_MIXED));
    let forest = RandomForest::params().seed(1).max_depth(6).fit(&mixed).unwrap();
    assert_eq!(forest.n_trees(), AUTO_TREES_MIXED);
    // Pure leaves asked for on the same set: 15; a number given is kept.
    let pure = RandomForest::params().min_samples_leaf(1).check().unwrap().resolved_for(&mixed);
    assert_eq!(pure.n_trees(), AUTO_TREES_PURE);
    let fixed = RandomForest::params().n_trees(3).check().unwrap().resolved_for(&mixed);
    assert_eq!(fixed.n_trees(), 3);
}
