//! Scans as they really arrive: holes, single-view partial scans and fragmented meshes, on the
//! synthetic family (ground truth through the perturbation's vertex map), with asserted
//! accuracy floors; and the `perturb` command.

use std::{path::Path, process::Command, sync::Arc};

use shapeforest::{
    descriptor::LocalParams,
    eval::{
        protocol::{
            run_protocol, Method, ProtocolParams, ProtocolReport, ProtocolShape, DOUBT_VIEW_ORIENTATION,
        },
        PooledReport,
    },
    forest::{augmented_shape, RandomForest},
    geodesic::{HeatMethodSolver, HeatParams},
    mesh::{perturb, read_mesh, vertex_components, write_mesh, Perturbation},
    regularizer::{AnchorGrowthParams, PartialScanParams, RegularizerParams, ScanPart, ZoomOutParams},
    spectral::{compute_spectrum, Spectrum, SpectrumParams},
    synth::{creature_family, CreatureParams},
};

fn shapes_and_symmetry(n_vertices: usize, n_shapes: usize) -> (Vec<ProtocolShape>, Vec<usize>) {
    let fam = creature_family(
        &CreatureParams { target_vertices: n_vertices, seed: 2, ..Default::default() },
        n_shapes,
    )
    .expect("synthetic family");
    let shapes = fam
        .shapes
        .iter()
        .enumerate()
        .map(|(i, m)| ProtocolShape::identity(format!("creature{i}"), Arc::new(m.clone())))
        .collect();
    (shapes, fam.symmetry)
}

fn run(perturbations: Vec<Perturbation>, augment: Vec<Vec<Perturbation>>) -> ProtocolReport {
    run_with(perturbations, augment, RegularizerParams::default())
}

fn run_with(
    perturbations: Vec<Perturbation>,
    augment: Vec<Vec<Perturbation>>,
    regularizer: RegularizerParams,
) -> ProtocolReport {
    let (shapes, symmetry) = shapes_and_symmetry(3000, 7);
    let params = ProtocolParams {
        n_train: 5,
        max_tests: Some(2),
        train_once: true,
        eval_points: 500,
        forest: RandomForest::params().n_trees(10).seed(1),
        perturbations,
        skip_baseline: true,
        augment,
        augment_copies: 3,
        regularizer,
        ..ProtocolParams::default()
    };
    run_protocol(&shapes, Some(&symmetry), &params, None).expect("protocol")
}

fn within_005(report: &ProtocolReport) -> f64 {
    report.summary(Method::ForestRegularized).0.within_005
}

#[test]
fn small_holes_barely_change_the_accuracy_and_errors_are_measured_where_the_scan_has_points() {
    let clean = run(vec![], vec![]);
    let holed = run(vec![Perturbation::Holes { count: 5, radius: 0.03 }], vec![]);
    for t in &holed.tests {
        assert_eq!(t.perturbation, "holes5x0.03");
        assert!(t.area_fraction < 0.995 && t.area_fraction > 0.9, "area kept {}", t.area_fraction);
        assert!(t.present_points < 500 && t.present_points > 400, "{} points present", t.present_points);
        let m = t.errors(Method::ForestRegularized).unwrap();
        assert_eq!(m.strict.len(), t.present_points);
        assert_eq!(m.map.len(), t.scan_vertices);
        assert_eq!(t.evaluated.len(), t.present_points);
    }
    let (c, h) = (within_005(&clean), within_005(&holed));
    println!("clean {c:.3}, five holes {h:.3}");
    assert!(c > 0.9, "clean scans: {c}");
    assert!(h > 0.85, "five small holes: {h}");
}

#[test]
fn a_training_copy_with_small_holes_is_closed_as_a_scan_is_before_its_spectrum() {
    let (shapes, _) = shapes_and_symmetry(3000, 1);
    let mesh = &shapes[0].mesh;
    let labels: Vec<Option<u32>> = (0..mesh.n_vertices() as u32).map(Some).collect();
    let holes = [Perturbation::Holes { count: 5, radius: 0.03 }];
    let sp = SpectrumParams::new(30);
    let whole = compute_spectrum(mesh, &sp).expect("spectrum").renormalised(mesh.surface_area());
    let copy = |fill| augmented_shape("c", mesh, &labels, &holes, 7, fill, &sp, None, None).expect("copy");
    let (open, closed) = (copy(None), copy(Some(ScanPart::FILL_PERIMETER)));
    // The closed copy's spectrum lives on the copy's own vertices, labelled alike.
    assert_eq!(open.labels, closed.labels);
    assert_eq!(closed.spectrum.n_vertices, open.labels.len());
    assert!(open.labels.len() < mesh.n_vertices(), "the holes removed vertices");
    // Its eigenvalues are the whole shape's again, as a scan's are once its holes are closed.
    let gap = |s: &Spectrum| {
        (1..30).map(|k| (s.eigenvalues[k] / whole.eigenvalues[k] - 1.0).abs()).sum::<f64>() / 29.0
    };
    let (g_open, g_closed) = (gap(&open.spectrum), gap(&closed.spectrum));
    println!("mean relative eigenvalue gap to the whole shape: open {g_open:.4}, closed {g_closed:.4}");
    assert!(g_closed < 0.5 * g_open, "closing the copy's holes: {g_open} -> {g_closed}");
}

#[test]
fn a_single_view_scan_is_matched_once_the_forest_has_seen_single_views() {
    let view = vec![Perturbation::PARTIAL_VIEW];
    let plain = run(view.clone(), vec![]);
    let learned = run(view.clone(), vec![view]);
    for t in &learned.tests {
        assert!(t.area_fraction < 0.7, "a single view keeps part of the surface: {}", t.area_fraction);
        assert!(t.scale_ratio > 1.0, "a partial view is normalised by the reference's area");
        assert!(t.matched_part_vertices <= t.scan_vertices);
    }
    let (p, l) = (within_005(&plain), within_005(&learned));
    let flips = learned.summary(Method::ForestRegularized).1.unwrap().within_005;
    println!("single view: trained on complete shapes {p:.3}, with single-view copies {l:.3} (flips allowed {flips:.3})");
    assert!(l > p + 0.1, "augmentation must help on single views: {p} → {l}");
    assert!(flips > 0.25, "single view with augmentation, flips allowed: {flips}");
}

#[test]
fn a_single_view_is_left_as_grown_by_the_refinement() {
    let zoomout = RegularizerParams { zoomout: Some(ZoomOutParams::default()), ..Default::default() };
    let report = run_with(vec![Perturbation::PARTIAL_VIEW], vec![], zoomout);
    let mut small = 0;
    for t in &report.tests {
        let grown = &t.errors(Method::ForestRegularized).expect("regularised map").map;
        let refined = &t.errors(Method::ForestZoomOut).expect("refined map").map;
        // Under half of the body: the partial ZoomOut lost points there, so the map is kept.
        if t.area_fraction < 0.45 {
            small += 1;
            assert_eq!(
                grown, refined,
                "test {}: a part of {:.2} of the area is not refined",
                t.test, t.area_fraction
            );
        }
    }
    assert!(small > 0, "single views keep less than half of the surface");
}

#[test]
fn a_scan_missing_a_fifth_of_its_surface_is_refined_by_the_partial_zoomout() {
    let holes = vec![Perturbation::Holes { count: 3, radius: 0.15 }];
    let zoomout = RegularizerParams { zoomout: Some(ZoomOutParams::default()), ..Default::default() };
    let partial = run_with(holes.clone(), vec![], zoomout.clone());
    let square = run_with(holes, vec![], RegularizerParams { partial_zoomout: false, ..zoomout });
    for t in &partial.tests {
        assert!(t.area_fraction < 0.9, "three big holes take a part of the surface: {}", t.area_fraction);
    }
    let score = |r: &ProtocolReport| r.summary(Method::ForestZoomOut).0.within_005;
    let (grown, p, s) = (within_005(&partial), score(&partial), score(&square));
    println!("three big holes: regularised {grown:.3}, + square ZoomOut {s:.3}, + partial ZoomOut {p:.3}");
    // Measured 2026-12-02: regularised 24.4 %, square ZoomOut 36.6 %, partial ZoomOut 50.1 %.
    assert!(p > s, "the partial ZoomOut must beat the square one on an open part: {p} against {s}");
    assert!(p > 0.4, "three big holes, partial ZoomOut: {p}");
}

#[test]
fn the_diagnosis_says_where_the_wrong_points_of_a_holed_scan_come_from() {
    let holes = vec![Perturbation::Holes { count: 3, radius: 0.15 }];
    let base = RegularizerParams::default();
    let free = RegularizerParams {
        partial_scan: PartialScanParams { free_candidates: 500, ..Default::default() },
        ..base.clone()
    };
    let (shapes, symmetry) = shapes_and_symmetry(3000, 7);
    let params = ProtocolParams {
        n_train: 5,
        max_tests: Some(2),
        train_once: true,
        eval_points: 500,
        forest: RandomForest::params().n_trees(10).seed(1),
        perturbations: holes,
        skip_baseline: true,
        regularizer: base,
        diagnose: Some(vec![("free".to_string(), free)]),
        ..ProtocolParams::default()
    };
    let report = run_protocol(&shapes, Some(&symmetry), &params, None).expect("protocol");
    let mut pooled = [0.0; 2];
    for t in &report.tests {
        let d = t.diagnosis.as_ref().expect("a diagnosis was asked for");
        assert_eq!(d.matches, t.n_matches, "every game match is judged (identity ground truth)");
        assert!(d.points > 0 && d.points <= t.present_points, "{} of {}", d.points, t.present_points);
        let row = |name: &str| {
            d.rows.iter().find(|r| r.0 == name).map(|r| (r.1, r.2)).unwrap_or_else(|| panic!("no row {name}"))
        };
        for (name, strict, sym) in &d.rows {
            println!("{}: {name:<20} {strict:.3} / {sym:.3}", report.shape_names[t.test]);
            assert!((0.0..=1.0).contains(strict) && *strict <= *sym + 1e-12, "{name}: {strict} / {sym}");
        }
        // The forest's own choice is one of its candidates, and the top 5 are some of them.
        let (all, top, raw) = (row("candidates"), row("top-5 candidates"), row("forest-raw"));
        assert!(all.0 >= top.0 && top.0 >= raw.0, "candidates {all:?}, top-5 {top:?}, raw {raw:?}");
        assert!(all.1 >= top.1 && top.1 >= raw.1);
        // The diagnosed "grown" map is the reported regularised one.
        let reported = t.errors(Method::ForestRegularized).unwrap();
        let in_part = t.in_matched_part.iter().filter(|&&b| b).count();
        assert_eq!(in_part, d.points);
        let reported_in_part = reported
            .strict
            .iter()
            .zip(&t.in_matched_part)
            .filter(|(e, &inside)| inside && **e <= 0.05)
            .count() as f64
            / in_part as f64;
        assert!((reported_in_part - row("grown").0).abs() < 1e-9, "{reported_in_part} vs {:?}", row("grown"));
        pooled[0] += row("grown").0 / report.tests.len() as f64;
        pooled[1] += row("free grown").0 / report.tests.len() as f64;
    }
    // Measured 2026-12-02: grown 47.2 % and 6.2 %, with 500 reference samples as extra
    // candidates 96.8 % and 5.9 % (the second test's game matches are all mirrored: nothing
    // after them repairs that). Where the anchors are right, the extra candidates lift the
    // placement past the forest's candidates (52.6 % of the points have a right one).
    let [grown, free] = pooled;
    assert!(free > grown + 0.1 && free > 0.4, "extra candidates in growth: {grown:.3} → {free:.3}");
}

#[test]
fn heat_distances_work_on_a_scan_in_many_pieces() {
    let (shapes, _) = shapes_and_symmetry(3000, 2);
    let scan = perturb(&shapes[0].mesh, &[Perturbation::PARTIAL_VIEW], 4).unwrap().mesh;
    let (labels, sizes) = vertex_components(&scan);
    assert!(sizes.len() > 1, "the single view should be in pieces");
    let solver = HeatMethodSolver::new(&scan, HeatParams::default()).expect("factorises a fragmented scan");
    let d = solver.distances_from(0).unwrap();
    for (v, &x) in d.iter().enumerate() {
        if labels[v] == labels[0] {
            assert!(x.is_finite() && x >= 0.0, "vertex {v}: {x}");
        } else {
            assert!(x.is_infinite(), "vertex {v} is in another piece: {x}");
        }
    }
}

#[test]
fn the_perturb_command_writes_a_scan_and_its_vertex_map() {
    let dir = tempfile::tempdir().unwrap();
    let (shapes, _) = shapes_and_symmetry(2000, 1);
    let input = dir.path().join("clean.off");
    write_mesh(&input, &shapes[0].mesh).unwrap();
    let out = dir.path().join("holed.ply");
    let o = Command::new(env!("CARGO_BIN_EXE_shapeforest"))
        .args(["perturb", "--mesh"])
        .arg(&input)
        .arg("--out")
        .arg(&out)
        .args(["--holes", "4:0.05", "--seed", "3"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("holes4x0.05") && text.contains("boundary loop"), "{text}");
    let scan = read_mesh(&out).unwrap();
    let kept: Vec<usize> = std::fs::read_to_string(Path::new(&format!("{}.kept.txt", out.display())))
        .unwrap()
        .lines()
        .map(|l| l.parse().unwrap())
        .collect();
    assert_eq!(kept.len(), scan.n_vertices());
    assert!(scan.n_vertices() < shapes[0].mesh.n_vertices());
    for (v, &old) in kept.iter().enumerate() {
        assert_eq!(scan.vertices[v], shapes[0].mesh.vertices[old]);
    }
    let bad = Command::new(env!("CARGO_BIN_EXE_shapeforest"))
        .args(["perturb", "--mesh"])
        .arg(&input)
        .arg("--out")
        .arg(&out)
        .args(["--holes", "4"])
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("expected N:R"));
}

#[test]
fn eval_point_errors_say_which_points_lie_in_the_matched_piece() {
    // A single view with a hole cut through it is in pieces: `points.csv` marks each evaluated
    // point, and per method the marked ones are those `results.csv` counts as the matched part.
    let dir = tempfile::tempdir().unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_shapeforest"))
        .args(["eval", "--synthetic", "--quiet", "--no-cache", "--vertices", "1500", "--tests", "1"])
        .args([
            "--trees",
            "2",
            "--partial-view",
            "--holes",
            "1:0.1",
            "--point-errors",
            "--no-baseline",
            "--out",
        ])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let read = |name: &str| std::fs::read_to_string(dir.path().join(name)).unwrap();
    let column = |header: &str, name: &str| header.split(',').position(|c| c == name).unwrap();
    let points = read("points.csv");
    let mut lines = points.lines();
    let header = lines.next().unwrap();
    let (method, in_part) = (column(header, "method"), column(header, "in_part"));
    let mut counts = std::collections::HashMap::<String, (usize, usize)>::new();
    for line in lines {
        let cells: Vec<&str> = line.split(',').collect();
        let count = counts.entry(cells[method].to_string()).or_default();
        match cells[in_part] {
            "1" => count.0 += 1,
            "0" => count.1 += 1,
            other => panic!("in_part must be 0 or 1, not {other:?}"),
        }
    }
    let results = read("results.csv");
    let mut lines = results.lines();
    let header = lines.next().unwrap();
    let (method, part_n) = (column(header, "method"), column(header, "part_n"));
    let mut rows = 0;
    for line in lines {
        let cells: Vec<&str> = line.split(',').collect();
        let (inside, outside) = counts[cells[method]];
        assert_eq!(inside, cells[part_n].parse::<usize>().unwrap(), "{line}");
        assert!(outside > 0, "the view's other pieces hold evaluated points too: {line}");
        rows += 1;
    }
    assert!(rows >= 2, "{results}");
}

#[test]
fn train_learns_from_perturbed_copies_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("aug.sfm");
    let o = Command::new(env!("CARGO_BIN_EXE_shapeforest"))
        .args(["train", "--synthetic", "--vertices", "1500", "--trees", "2", "--augment", "partial-view"])
        .args(["--augment", "holes:2:0.05", "--augment-copies", "2", "--out"])
        .arg(&model)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    // 6 shapes + 6 × 2 kinds × 2 copies.
    assert!(err.contains("24 perturbed copies") && err.contains("on 30 shapes"), "{err}");
    assert!(model.is_file());
    let bad = Command::new(env!("CARGO_BIN_EXE_shapeforest"))
        .args(["train", "--synthetic", "--augment", "holes:3"])
        .arg("--out")
        .arg(dir.path().join("x.sfm"))
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("expected N:R"));
}

/// The synthetic family's single-view protocol: five training shapes with three single-view
/// copies each, two test views, a ten-tree forest.
fn single_views() -> ProtocolParams {
    let view = vec![Perturbation::PARTIAL_VIEW];
    ProtocolParams {
        n_train: 5,
        max_tests: Some(2),
        train_once: true,
        eval_points: 500,
        forest: RandomForest::params().n_trees(10).seed(1),
        perturbations: view.clone(),
        skip_baseline: true,
        augment: vec![view],
        augment_copies: 3,
        ..ProtocolParams::default()
    }
}

#[test]
fn local_histograms_match_single_views_of_the_synthetic_family() {
    let (shapes, symmetry) = shapes_and_symmetry(3000, 7);
    let params = |local: Option<LocalParams>| ProtocolParams { local, ..single_views() };
    let spectral = run_protocol(&shapes, Some(&symmetry), &params(None), None).expect("protocol");
    let local = run_protocol(&shapes, Some(&symmetry), &params(Some(LocalParams::default())), None)
        .expect("protocol");
    let (s, l) = (within_005(&spectral), within_005(&local));
    let flips = local.summary(Method::ForestRegularized).1.unwrap().within_005;
    println!("single views: WKS forest {s:.3}, local histograms {l:.3} (flips allowed {flips:.3})");
    // Measured: 0.319 → 0.524 (flips allowed 0.591); 0.341 → 0.416 (0.502) before the forest's
    // posterior weighed in a view's placement (`AnchorGrowthParams::part_prior`).
    assert!(l > s + 0.05, "local histograms must beat the WKS forest on single views: {s} → {l}");
    assert!(l > 0.38 && flips > 0.45, "single views with local histograms: {l} (flips allowed {flips})");
}

#[test]
fn a_doubted_view_is_regularised_onto_the_next_poses_and_keeps_the_best_oriented_map() {
    let (shapes, symmetry) = shapes_and_symmetry(3000, 7);
    let params = |doubt_view: Option<f64>| ProtocolParams { doubt_view, ..single_views() };
    let run =
        |doubt_view| run_protocol(&shapes, Some(&symmetry), &params(doubt_view), None).expect("protocol");
    // On by default at the measured threshold; a threshold above every score doubts every view.
    assert_eq!(ProtocolParams::default().doubt_view, Some(DOUBT_VIEW_ORIENTATION));
    let (never, always) = (run(None), run(Some(1.0)));
    let mut doubted = 0;
    for (t, one) in always.tests.iter().zip(&never.tests) {
        assert!(one.tried.is_empty(), "view {}: tried other poses without doubt", one.test);
        let score = one.view_orientation.expect("a single view's map is read");
        assert!(score > 0.0 && score < 1.0, "view {}: orientation {score}", one.test);
        assert_eq!(t.view_orientation, one.view_orientation, "view {}: the first map is the same", one.test);
        // Three poses in all: the nearest, and two other training shapes (never the test).
        let nearest = one.relay.unwrap_or(one.reference);
        let kept = t.relay.unwrap_or(t.reference);
        let mut poses: Vec<usize> = t.tried.iter().copied().chain([kept]).collect();
        poses.sort_unstable();
        poses.dedup();
        assert_eq!(poses.len(), 3, "view {}: kept {kept}, tried {:?}", t.test, t.tried);
        assert!(poses.contains(&nearest) && poses.iter().all(|p| t.training.contains(p) && *p != t.test));
        doubted += 1;
        // The nearest pose's map is kept unless another reads better oriented: then the same map.
        let map =
            |r: &ProtocolReport, i: usize| r.tests[i].errors(Method::ForestRegularized).unwrap().map.clone();
        let i = always.tests.iter().position(|x| x.test == t.test).unwrap();
        if kept == nearest {
            assert!(
                map(&always, i) == map(&never, i),
                "view {}: kept the nearest pose's map, changed",
                t.test
            );
        }
    }
    assert!(doubted > 0);
    // The default threshold: a view whose map reads at least it is not doubted; one that reads
    // below tries the next poses one at a time, two at most.
    let default = run(Some(DOUBT_VIEW_ORIENTATION));
    for (t, one) in default.tests.iter().zip(&never.tests) {
        let score = one.view_orientation.unwrap();
        let regularised = t.tried.len() + 1;
        if score >= DOUBT_VIEW_ORIENTATION {
            assert!(t.tried.is_empty(), "view {}: reads {score}, tried {:?}", t.test, t.tried);
        } else {
            assert!((2..=3).contains(&regularised), "view {}: reads {score}, tried {:?}", t.test, t.tried);
        }
        println!("view {}: reads {score:.3}, regularised onto {regularised} pose(s)", t.test);
    }
    let (a, n) = (within_005(&always), within_005(&never));
    println!("single views, doubting every one: {n:.3} -> {a:.3}");
    assert!(a >= n - 0.02, "keeping the best oriented map lost accuracy: {n} -> {a}");
}

#[test]
fn single_views_gain_from_leaves_of_several_vertices_and_more_game_candidates() {
    let (shapes, symmetry) = shapes_and_symmetry(3000, 7);
    let params = |leaf: usize, part_top_k: usize, part_alternative: bool| ProtocolParams {
        forest: RandomForest::params().n_trees(10).seed(1).min_samples_leaf(leaf),
        local: Some(LocalParams::default()),
        regularizer: RegularizerParams { part_top_k, part_alternative, ..Default::default() },
        ..single_views()
    };
    let run = |leaf, k, alternative| {
        run_protocol(&shapes, Some(&symmetry), &params(leaf, k, alternative), None).expect("protocol")
    };
    let score =
        |r: &ProtocolReport| (within_005(r), r.summary(Method::ForestRegularized).1.unwrap().within_005);
    let k = RegularizerParams::default().part_top_k;
    let five = run(1, 5, true);
    let twenty = run(1, k, false);
    let both = run(1, k, true);
    let leaves = run(5, k, true);
    let (before, candidates, chosen, now) = (score(&five), score(&twenty), score(&both), score(&leaves));
    println!(
        "single views, local histograms: 5 game candidates {before:.3?}, 20 {candidates:.3?}, both games {chosen:.3?}, \
         leaves of 5 {now:.3?}"
    );
    // Both games: each view keeps the map of one of them, the one among 5 where it says so.
    let map =
        |r: &ProtocolReport, t: usize| r.tests[t].errors(Method::ForestRegularized).unwrap().map.clone();
    for (t, test) in both.tests.iter().enumerate() {
        let expected = if test.alternative_kept { map(&five, t) } else { map(&twenty, t) };
        assert!(
            map(&both, t) == expected,
            "view {t}: the map of neither game (alternative kept: {})",
            test.alternative_kept
        );
        assert!(!five.tests[t].alternative_kept && !twenty.tests[t].alternative_kept);
    }
    // Measured: 5 → 20 → both games (0.520, 0.593) → (0.524, 0.591) → (0.524, 0.591); leaves
    // of 5 with both games (0.690, 0.730) (before the posterior weighed in a view's placement:
    // (0.416, 0.502) → (0.420, 0.500) → (0.416, 0.502); (0.712, 0.757)). On SCAPE's views the game candidates weigh more (46.8
    // → 54.5 → 55.3 %); on these the larger leaves do most (they are not the default: on
    // FAUST_r's other people and triangulations they cost 18 points on complete scans; README
    // "Local histograms").
    assert!(
        candidates.0 >= before.0 - 0.02,
        "more game candidates on a single view: {before:?} → {candidates:?}"
    );
    assert!(
        chosen.0 >= candidates.0.min(before.0) - 1e-9,
        "both games: {before:?}, {candidates:?} → {chosen:?}"
    );
    assert!(now.0 > before.0 + 0.15 && now.0 > 0.6, "leaves of several vertices: {before:?} → {now:?}");
    assert!(now.1 > 0.65, "flips allowed: {now:?}");
}

#[test]
fn a_single_views_placement_heeds_the_forest_and_a_complete_scans_does_not() {
    let view = vec![Perturbation::PARTIAL_VIEW];
    let (shapes, symmetry) = shapes_and_symmetry(3000, 7);
    let params = |perturbations: Vec<Perturbation>, part_prior: f64| ProtocolParams {
        n_train: 5,
        max_tests: Some(2),
        train_once: true,
        eval_points: 500,
        forest: RandomForest::params().n_trees(10).seed(1),
        perturbations: perturbations.clone(),
        skip_baseline: true,
        augment: if perturbations.is_empty() { vec![] } else { vec![perturbations] },
        augment_copies: 3,
        local: Some(LocalParams::default()),
        regularizer: RegularizerParams {
            growth: Some(AnchorGrowthParams { part_prior, ..Default::default() }),
            ..Default::default()
        },
        // The prior alone: a doubted view's other poses would mix another choice into the
        // comparison (with the default doubt these two views measured 0.555 without the prior
        // and 0.509 with it).
        doubt_view: None,
        ..ProtocolParams::default()
    };
    let run = |p: Vec<Perturbation>, w: f64| {
        run_protocol(&shapes, Some(&symmetry), &params(p, w), None).expect("protocol")
    };
    let w = AnchorGrowthParams::default().part_prior;
    assert!(w > 0.0, "the prior is on by default");
    let (anchors, heeded) = (run(view.clone(), 0.0), run(view, w));
    let score =
        |r: &ProtocolReport| (within_005(r), r.summary(Method::ForestRegularized).1.unwrap().within_005);
    let (a, h) = (score(&anchors), score(&heeded));
    println!("single views (automatic leaves, local histograms): anchors alone {a:.3?}, with the forest's word {h:.3?}");
    // Measured: (0.416, 0.502) → (0.524, 0.591).
    assert!(h.0 > a.0 + 0.03, "the posterior in a view's placement: {a:?} → {h:?}");
    // A complete scan is placed by its anchors alone: the same maps.
    let (complete, complete_w) = (run(vec![], 0.0), run(vec![], w));
    for (x, y) in complete.tests.iter().zip(&complete_w.tests) {
        assert_eq!(
            x.errors(Method::ForestRegularized).unwrap().map,
            y.errors(Method::ForestRegularized).unwrap().map,
            "a complete scan's map changed"
        );
    }
}
