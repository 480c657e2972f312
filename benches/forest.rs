//! Benchmarks of the random forest.
//!
//! - **One-shot, printed:** training 15 trees on 6 shapes of 28K vertices (K = 100) and the model
//!   file size; hit ratio of the forest (1, 5, 10, 15 trees) against WKS k-NN at equal support on a
//!   small real family (bumpy icosphere under stretches/bends, dense spectra, held-out shape).
//! - **Criterion:** prediction for a 50K-vertex shape; training 3 trees on a 6 × 5K ladder point.
//!
//! The 28K/50K spectra are **synthetic** (no fast eigensolver in this branch yet): a shared random
//! eigenvector matrix with per-shape noise (5 %), unit mass, eigenvalues growing like a surface's
//! (`λ_k ≈ 4πk`, jittered per shape). Such data time the kernels faithfully (same sizes, same
//! code paths, separable labels) but say nothing about accuracy; accuracy is measured on the
//! real (dense-spectrum) family. Run with `cargo bench --bench forest`.

use std::sync::Arc;
use std::time::Instant;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use shapeforest::descriptor::WksParams;
use shapeforest::forest::{hit_ratio, labels_identity, RandomForest, TrainingSet, WksKnn};
use shapeforest::spectral::{dense_spectrum, Spectrum};

const K: usize = 100;

fn synthetic_spectrum(base: &[f64], n: usize, shape: u64) -> Spectrum {
    let mut rng = ChaCha8Rng::seed_from_u64(1000 + shape);
    let s3 = 3f64.sqrt();
    let eigenvectors: Vec<f64> = (0..n * K)
        .map(|i| if i < n { 1.0 } else { base[i % base.len()] + 0.05 * rng.random_range(-s3..s3) })
        .collect();
    let eigenvalues =
        (0..K)
            .map(|k| {
                if k == 0 {
                    0.0
                } else {
                    4.0 * std::f64::consts::PI * k as f64 * rng.random_range(0.97..1.03)
                }
            })
            .collect();
    let mut ev: Vec<f64> = eigenvalues;
    ev.sort_by(f64::total_cmp);
    Spectrum { eigenvalues: ev, eigenvectors, n_vertices: n, mass: vec![1.0 / n as f64; n], area: 1.0 }
}

fn base_vectors(n: usize) -> Vec<f64> {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let s3 = 3f64.sqrt();
    (0..n * K).map(|_| rng.random_range(-s3..s3)).collect()
}

fn synthetic_set(n: usize, shapes: usize) -> TrainingSet {
    let base = base_vectors(n);
    TrainingSet::same_indexing(
        (0..shapes).map(|s| (format!("synthetic{s}"), Arc::new(synthetic_spectrum(&base, n, s as u64)))),
    )
    .expect("valid synthetic set")
}

#[path = "../tests/common/bumpy.rs"]
mod bumpy;

fn bumpy_family(n: usize) -> Vec<Arc<Spectrum>> {
    let base = bumpy::bumpy_sphere();
    (0..n).map(|i| Arc::new(dense_spectrum(&bumpy::bumpy_member(&base, i), 30).expect("spectrum"))).collect()
}

/// CPU seconds (user + system) used by this process so far, from `/proc/self/stat` (Linux);
/// 0 elsewhere. Reported beside wall time because the bench machine is shared.
fn cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else { return 0.0 };
    let Some(rest) = stat.rsplit(')').next() else { return 0.0 };
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|x| x.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}

fn one_shot_reports() {
    // Training at the scale.
    let set = synthetic_set(28_000, 6);
    let (t, c) = (Instant::now(), cpu_seconds());
    let forest = RandomForest::params().n_trees(15).seed(1).fit(&set).expect("fit");
    let train_s = t.elapsed().as_secs_f64();
    let train_cpu = cpu_seconds() - c;
    let bytes = forest.to_bytes().expect("encode");
    println!(
        "train 15 trees, 6 × 28K synthetic (K = {K}, {} samples): {train_s:.1} s wall, {train_cpu:.1} s CPU; {} nodes, mean leaf support {:.2}; model file {:.1} MiB",
        set.n_samples(),
        forest.n_nodes(),
        forest.mean_leaf_support(),
        bytes.len() as f64 / (1024.0 * 1024.0)
    );
    let q = synthetic_spectrum(&base_vectors(28_000), 28_000, 99);
    let pred = forest.predict(&q).expect("predict");
    let q50 = synthetic_spectrum(&base_vectors(50_000), 50_000, 77);
    let (t, c) = (Instant::now(), cpu_seconds());
    let p50 = forest.predict(&q50).expect("predict");
    println!(
        "predict 50K vertices, 15 trees: {:.2} s wall, {:.2} s CPU (mean support {:.1})",
        t.elapsed().as_secs_f64(),
        cpu_seconds() - c,
        p50.mean_support()
    );
    println!(
        "held-out synthetic shape: MAP hit ratio {:.3}, mean support {:.1}",
        hit_ratio(&pred.map_labels(), &labels_identity(28_000)),
        pred.mean_support()
    );

    // Hit ratio vs number of trees on a real (dense-spectrum) family.
    let fam = bumpy_family(6);
    let n = fam[0].n_vertices;
    let set = TrainingSet::same_indexing((0..5).map(|i| (format!("m{i}"), fam[i].clone()))).expect("set");
    let truth = labels_identity(n);
    let full = RandomForest::params().n_trees(15).seed(3).fit(&set).expect("fit");
    let knn = WksKnn::fit(&set, &WksParams::default(), full.energy_grid().range, full.k()).expect("knn");
    println!("trees | forest hit | support | WKS k-NN hit (k = support)");
    for trees in [1usize, 5, 10, 15] {
        let f = RandomForest::params().n_trees(trees).seed(3).fit(&set).expect("fit");
        let p = f.predict(&fam[5]).expect("predict");
        let k = p.mean_support().round().max(1.0) as usize;
        let b = knn.predict(&fam[5], k).expect("knn");
        println!(
            "{trees:5} | {:10.3} | {:7.1} | {:.3}",
            hit_ratio(&p.map_labels(), &truth),
            p.mean_support(),
            hit_ratio(&b.map_labels(), &truth)
        );
    }
}

fn benches(c: &mut Criterion) {
    if std::env::var_os("SHAPEFOREST_BENCH_SKIP_ONESHOT").is_none() {
        one_shot_reports();
    }
    let set = synthetic_set(5_000, 6);
    let mut g = c.benchmark_group("forest");
    g.sample_size(10);
    g.throughput(Throughput::Elements(set.n_samples() as u64));
    g.bench_function("train_3_trees_6x5k", |b| {
        b.iter(|| RandomForest::params().n_trees(3).seed(1).fit(&set).expect("fit"))
    });
    let big = synthetic_set(28_000, 6);
    let forest = RandomForest::params().n_trees(15).seed(1).fit(&big).expect("fit");
    let q = synthetic_spectrum(&base_vectors(50_000), 50_000, 77);
    g.throughput(Throughput::Elements(50_000));
    g.bench_function("predict_50k_15_trees", |b| b.iter(|| forest.predict(&q).expect("predict")));
    g.finish();
}

criterion_group!(forest_benches, benches);
criterion_main!(forest_benches);
