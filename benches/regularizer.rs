//! The regulariser's stages on a ladder of synthetic creatures (~5K and ~20K vertices; ~50K
//! with `SHAPEFOREST_BENCH_LARGE=1`), seeded and deterministic: a 15-tree forest trained on
//! three poses predicts a fourth, which is regularised against the first pose.
//!
//! - `regularize`: the whole regulariser (samples, heat distances, game, functional map, point
//!   maps, anchor growth and smoothing), the scan side of `shapeforest match` after prediction;
//! - `sparse_matches`: steps 1–4 (samples, candidates, heat distances, the game);
//! - `matcher`: the game-theoretic matching alone, on the candidates and distance matrices of
//!   those steps;
//! - `fmap_solve`: the regularised functional-map solve (eq. 11.19) from the prediction and the
//!   game's distance maps, with the pull-back of the prediction and the spectral coefficients.

use std::hint::black_box;
use std::sync::Arc;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use shapeforest::fmap::{pullback_fmap, solve_regularised_fmap, spectral_coefficients, FmapParams};
use shapeforest::forest::{Prediction, RandomForest, TrainingSet};
use shapeforest::geodesic::{farthest_point_sampling_euclidean, HeatParams};
use shapeforest::matching::{game_theoretic_matching, Candidate, GameMatcherParams};
use shapeforest::regularizer::{regularize, sparse_matches, PreparedShape, RegularizerParams};
use shapeforest::spectral::{compute_spectrum, SpectrumParams};
use shapeforest::synth::{creature_family, CreatureParams};

/// One size of the ladder: the prepared test and reference poses and the test's prediction.
struct Case {
    test: PreparedShape,
    reference: PreparedShape,
    prediction: Prediction,
}

fn case(vertices: usize) -> Case {
    let fam =
        creature_family(&CreatureParams { target_vertices: vertices, seed: 7, ..Default::default() }, 4)
            .expect("creature family");
    let spectra: Vec<_> = fam
        .shapes
        .iter()
        .map(|m| Arc::new(compute_spectrum(m, &SpectrumParams::new(100)).expect("spectrum")))
        .collect();
    let set = TrainingSet::same_indexing((0..3).map(|i| (format!("pose{i}"), spectra[i].clone())))
        .expect("training set");
    let forest =
        RandomForest::params().n_trees(15).seed(0).check().expect("params").fit(&set).expect("forest");
    let prediction = forest.predict(&spectra[3]).expect("prediction");
    let prepare = |i: usize| {
        PreparedShape::new(Arc::new(fam.shapes[i].clone()), spectra[i].clone(), HeatParams::default())
            .expect("prepared shape")
    };
    Case { test: prepare(3), reference: prepare(0), prediction }
}

fn sizes() -> Vec<usize> {
    let mut s = vec![5_000, 20_000];
    if std::env::var_os("SHAPEFOREST_BENCH_LARGE").is_some() {
        s.push(50_000);
    }
    s
}

/// The game's inputs as [`sparse_matches`] builds them: 50 farthest-point samples, their top-5
/// candidates, and the normalised heat distances among samples and among candidates.
fn game_inputs(c: &Case, params: &RegularizerParams) -> (Vec<Candidate>, Vec<f64>, usize, Vec<f64>, usize) {
    let samples = farthest_point_sampling_euclidean(&c.test.mesh, params.n_samples, None).expect("samples");
    let mut refs: Vec<usize> = Vec::new();
    let mut candidates = Vec::new();
    for (i, &m) in samples.iter().enumerate() {
        for (label, p) in c.prediction.top_k(m, params.top_k) {
            let r = label as usize;
            let idx = refs.iter().position(|&x| x == r).unwrap_or_else(|| {
                refs.push(r);
                refs.len() - 1
            });
            candidates.push(Candidate { test: i, reference: idx, prior: p as f64 });
        }
    }
    let pairwise = |shape: &PreparedShape, points: &[usize]| {
        let f = shape.heat.distances_from_many(points).expect("distances");
        let s = points.len();
        let scale = shape.sqrt_area();
        let mut d = vec![0.0; s * s];
        for i in 0..s {
            for j in 0..s {
                d[i * s + j] = 0.5 * (f[(points[j], i)] + f[(points[i], j)]) / scale;
            }
        }
        d
    };
    let (d_test, d_ref) = (pairwise(&c.test, &samples), pairwise(&c.reference, &refs));
    (candidates, d_test, samples.len(), d_ref, refs.len())
}

fn group<'a>(
    c: &'a mut Criterion,
    name: &str,
    seconds: u64,
) -> criterion::BenchmarkGroup<'a, criterion::measurement::WallTime> {
    let mut g = c.benchmark_group(name);
    g.sample_size(10).measurement_time(Duration::from_secs(seconds)).warm_up_time(Duration::from_secs(1));
    g
}

fn bench(c: &mut Criterion) {
    let params = RegularizerParams::default();
    let cases: Vec<(usize, Case)> = sizes()
        .into_iter()
        .map(|n| {
            let case = case(n);
            (case.test.mesh.n_vertices(), case)
        })
        .collect();

    let mut g = group(c, "regularize", 20);
    for (n, case) in &cases {
        g.throughput(Throughput::Elements(*n as u64));
        g.bench_with_input(BenchmarkId::from_parameter(n), case, |b, case| {
            b.iter(|| {
                black_box(
                    regularize(&case.test, &case.reference, &case.prediction, None, &params).expect("map"),
                )
            })
        });
    }
    g.finish();

    let mut g = group(c, "sparse_matches", 8);
    for (n, case) in &cases {
        g.throughput(Throughput::Elements(*n as u64));
        g.bench_with_input(BenchmarkId::from_parameter(n), case, |b, case| {
            b.iter(|| {
                black_box(
                    sparse_matches(&case.test, &case.reference, &case.prediction, None, &params)
                        .expect("matches"),
                )
            })
        });
    }
    g.finish();

    let mut g = group(c, "matcher", 4);
    for (n, case) in &cases {
        let (candidates, d_test, n_test, d_ref, n_ref) = game_inputs(case, &params);
        g.bench_function(BenchmarkId::from_parameter(n), |b| {
            b.iter(|| {
                black_box(
                    game_theoretic_matching(
                        &candidates,
                        &d_test,
                        n_test,
                        &d_ref,
                        n_ref,
                        &GameMatcherParams::default(),
                    )
                    .expect("game"),
                )
            })
        });
    }
    g.finish();

    let mut g = group(c, "fmap_solve", 4);
    for (n, case) in &cases {
        let sparse =
            sparse_matches(&case.test, &case.reference, &case.prediction, None, &params).expect("matches");
        let weights: Vec<f64> = sparse.game.matches.iter().map(|m| m.weight).collect();
        let p = FmapParams::default();
        let (kt, kr) = (p.k_test, p.k_ref);
        g.throughput(Throughput::Elements(*n as u64));
        g.bench_function(BenchmarkId::from_parameter(n), |b| {
            b.iter(|| {
                let (t, r) = (&case.test.spectrum, &case.reference.spectrum);
                let c_pred = pullback_fmap(t, r, kt, kr, &case.prediction).expect("pull-back");
                let a = spectral_coefficients(t, kt, sparse.test_fields.as_ref()).expect("coefficients");
                let bb = spectral_coefficients(r, kr, sparse.ref_fields.as_ref()).expect("coefficients");
                black_box(
                    solve_regularised_fmap(
                        c_pred.as_ref(),
                        a.as_ref(),
                        bb.as_ref(),
                        &weights,
                        &t.eigenvalues,
                        &r.eigenvalues,
                        &p,
                    )
                    .expect("solve"),
                )
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
