//! Forest figures on a real class: training time, model size, prediction time, and the exact
//! hit ratio (MAP label = ground-truth vertex) of the forest against the WKS k-NN baseline at
//! equal support, for 1, 5, 10 and 15 trees (the paper's Fig. 11.8, left).
//!
//! `cargo run --release --example forest_report -- [DATA_DIR] [CLASS] [N_TRAIN] [TEST]`
//! (defaults: ../shared/data/tosca, cat, 6, cat10). Peak memory: run it under `/usr/bin/time -v`.

use std::{path::PathBuf, sync::Arc, time::Instant};

use anyhow::{Context, Result};
use shapeforest::{
    descriptor::WksParams,
    forest::{hit_ratio, labels_identity, RandomForest, TrainingSet, WksKnn},
    mesh::read_mesh,
    spectral::{SpectrumCache, SpectrumParams},
};

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dir = PathBuf::from(args.first().map(String::as_str).unwrap_or("../shared/data/tosca"));
    let class = args.get(1).map(String::as_str).unwrap_or("cat");
    let n_train: usize = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(6);
    let test_name = args.get(3).cloned().unwrap_or_else(|| format!("{class}10"));
    if !dir.exists() {
        println!("SKIPPED: no data at {} (pass the data folder as the first argument)", dir.display());
        return Ok(());
    }
    let cache = SpectrumCache::new(std::env::temp_dir().join("shapeforest-spectra"))?;
    let params = SpectrumParams::new(100);
    let load = |name: &str| -> Result<_> {
        let path = dir.join(format!("{name}.off"));
        let mesh = read_mesh(&path).with_context(|| format!("reading {}", path.display()))?;
        let t0 = Instant::now();
        let s = Arc::new(cache.get_or_compute(&mesh, &params)?);
        Ok((mesh, s, t0.elapsed().as_secs_f64()))
    };
    let mut shapes = Vec::new();
    for i in 0..n_train {
        let name = format!("{class}{i}");
        let (mesh, spectrum, t) = load(&name)?;
        println!("{name}: {} vertices, spectrum {t:.2} s (cached after the first run)", mesh.n_vertices());
        shapes.push((name, spectrum));
    }
    let set = TrainingSet::same_indexing(shapes)?;
    let (test_mesh, test_spectrum, _) = load(&test_name)?;
    let truth = labels_identity(test_mesh.n_vertices());

    println!("\n| trees | train (s) | forest hit ratio | mean support | WKS k-NN hit ratio |");
    println!("|---|---|---|---|---|");
    let mut last = None;
    for trees in [1usize, 5, 10, 15] {
        let t0 = Instant::now();
        let forest = RandomForest::params().n_trees(trees).seed(0).check()?.fit(&set)?;
        let t_train = t0.elapsed().as_secs_f64();
        let prediction = forest.predict(&test_spectrum)?;
        let support = prediction.mean_support();
        let knn = WksKnn::fit(&set, &WksParams::default(), forest.energy_grid().range, forest.k())?;
        let knn_pred = knn.predict(&test_spectrum, support.round().max(1.0) as usize)?;
        println!(
            "| {trees} | {t_train:.1} | {:.3} | {support:.1} | {:.3} |",
            hit_ratio(&prediction.map_labels(), &truth),
            hit_ratio(&knn_pred.map_labels(), &truth)
        );
        last = Some(forest);
    }
    let forest = last.context("no forest")?;
    let t0 = Instant::now();
    let _ = forest.predict(&test_spectrum)?;
    println!(
        "\nprediction of {test_name} ({} vertices, 15 trees): {:.2} s",
        test_mesh.n_vertices(),
        t0.elapsed().as_secs_f64()
    );
    let path = std::env::temp_dir().join("shapeforest-report.sfm");
    forest.save(&path)?;
    println!(
        "model file: {:.1} MiB, {} nodes",
        std::fs::metadata(&path)?.len() as f64 / 1048576.0,
        forest.n_nodes()
    );
    Ok(())
}
