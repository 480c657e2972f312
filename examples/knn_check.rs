//! The WKS k-NN baseline on a real class: fit time, the kd-tree search's time and, with
//! `--brute-force`, the exhaustive search's time and the number of vertices whose neighbour
//! labels differ between the two (0 expected, up to ties at round-off).
//!
//! `cargo run --release --example knn_check -- [DATA_DIR] [CLASS] [N_TRAIN] [TEST] [K] [--brute-force]`
//! (defaults: ../shared/data/tosca, cat, 6, cat10, 10): the first N_TRAIN shapes CLASSn of the
//! folder in name order, TEST left out. Spectra are cached in the system's
//! temporary folder (`shapeforest-spectra`).

use std::{path::PathBuf, sync::Arc, time::Instant};

use anyhow::{Context, Result};
use shapeforest::{
    descriptor::WksParams,
    forest::{RandomForest, TrainingSet, WksKnn},
    mesh::read_mesh,
    spectral::{SpectrumCache, SpectrumParams},
};

fn main() -> Result<()> {
    let all: Vec<String> = std::env::args().skip(1).collect();
    let brute = all.iter().any(|a| a == "--brute-force");
    let args: Vec<&String> = all.iter().filter(|a| !a.starts_with("--")).collect();
    let dir = PathBuf::from(args.first().map(|s| s.as_str()).unwrap_or("../shared/data/tosca"));
    let class = args.get(1).map(|s| s.as_str()).unwrap_or("cat");
    let n_train: usize = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(6);
    let test_name = args.get(3).map(|s| s.to_string()).unwrap_or_else(|| format!("{class}10"));
    let k: usize = args.get(4).map(|s| s.parse()).transpose()?.unwrap_or(10);
    if !dir.exists() {
        println!("SKIPPED: no data at {} (pass the data folder as the first argument)", dir.display());
        return Ok(());
    }
    let cache = SpectrumCache::new(std::env::temp_dir().join("shapeforest-spectra"))?;
    let params = SpectrumParams::new(100);
    let load = |name: &str| -> Result<_> {
        let path = dir.join(format!("{name}.off"));
        let mesh = read_mesh(&path).with_context(|| format!("reading {}", path.display()))?;
        Ok((mesh.n_vertices(), Arc::new(cache.get_or_compute(&mesh, &params)?)))
    };
    // The first N_TRAIN shapes of the class in name order, the test shape left out.
    let mut names: Vec<String> = std::fs::read_dir(&dir)?
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter_map(|f| f.strip_suffix(".off").map(str::to_string))
        .filter(|f| {
            f.starts_with(class) && f[class.len()..].chars().all(|c| c.is_ascii_digit()) && *f != test_name
        })
        .collect();
    names.sort();
    let mut shapes = Vec::new();
    for name in names.into_iter().take(n_train) {
        shapes.push((name.clone(), load(&name)?.1));
    }
    let set = TrainingSet::same_indexing(shapes)?;
    let (n, test) = load(&test_name)?;
    // The energy range a forest on this set would use (one small tree is enough to get it).
    let forest = RandomForest::params().n_trees(1).max_depth(4).seed(0).check()?.fit(&set)?;
    let t0 = Instant::now();
    let knn = WksKnn::fit(&set, &WksParams::default(), forest.energy_grid().range, forest.k())?;
    let fit_s = t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    let tree = knn.predict(&test, k)?;
    let tree_s = t0.elapsed().as_secs_f64();
    println!(
        "{test_name}: {n} vertices against {} training descriptors, k = {k}: fit {fit_s:.2} s, kd-tree search {tree_s:.2} s",
        knn.n_samples()
    );
    if brute {
        let t0 = Instant::now();
        let reference = knn.predict_brute_force(&test, k)?;
        let brute_s = t0.elapsed().as_secs_f64();
        let differ = (0..n).filter(|&v| tree.posterior(v) != reference.posterior(v)).count();
        println!(
            "brute force {brute_s:.2} s ({:.1}× the tree); vertices whose neighbour labels differ: {differ}",
            brute_s / tree_s
        );
    }
    Ok(())
}
