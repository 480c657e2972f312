//! What each step of the regulariser contributes, on one test shape of a real class that shares
//! vertex indexing (TOSCA, SCAPE): a 15-tree forest on N other shapes, then the dense maps of
//! the variants below, scored at 1,000 seeded points strictly and with left/right flips allowed
//! (the symmetry derived from the class's symmetric feature points, as `shapeforest eval` does).
//!
//! - forest, raw MAP;
//! - the regularised functional map's point map (nearest neighbour in the spectral embedding);
//! - the same restricted to the forest's candidates;
//! - placement by the game's anchors alone (the regulariser before growth);
//! - anchor growth by distances alone, then with the smoothing of the final placement, then
//!   with the orientation term and the re-oriented second run (the default);
//! - the oracle: the best candidate in the forest's support, the bound of any placement that
//!   keeps to the candidates.
//!
//! `cargo run --release --example regularizer_ablation -- [DATA_DIR] [CLASS] [TEST] [N_TRAIN]`
//! (defaults: ../shared/data/tosca cat cat1 6; for SCAPE: ../shared/data/scape mesh mesh001 6).

use std::{
    path::{Path, PathBuf},
    sync::Arc,
    time::Instant,
};

use anyhow::{bail, Context, Result};
use shapeforest::{
    eval::{
        geodesic_errors,
        symmetry::{SymmetricFeatures, SymmetryParams, SymmetrySolver},
        ErrorSummary,
    },
    forest::{RandomForest, TrainingSet},
    geodesic::{HeatMethodSolver, HeatParams},
    mesh::read_mesh,
    regularizer::{regularize, AnchorGrowthParams, PreparedShape, RegularizerParams},
    spectral::{SpectrumCache, SpectrumParams},
};

/// `CLASS.sym.info` read through `CLASS.pid` (or SCAPE's `1.*`).
fn read_features(dir: &Path, class: &str) -> Result<SymmetricFeatures> {
    let stem = if dir.join(format!("{class}.pid")).is_file() { class.to_string() } else { "1".to_string() };
    let pid_path = dir.join(format!("{stem}.pid"));
    let pid: Vec<usize> = std::fs::read_to_string(&pid_path)
        .with_context(|| format!("cannot read {}", pid_path.display()))?
        .lines()
        .filter_map(|l| l.split_whitespace().next())
        .map(|t| t.parse().with_context(|| format!("{}: bad vertex {t:?}", pid_path.display())))
        .collect::<Result<_>>()?;
    let info = dir.join(format!("{stem}.sym.info"));
    let mut f = SymmetricFeatures::default();
    for line in
        std::fs::read_to_string(&info).with_context(|| format!("cannot read {}", info.display()))?.lines()
    {
        let ids: Vec<usize> = line
            .split_whitespace()
            .map(|t| t.parse().with_context(|| format!("{}: bad feature {t:?}", info.display())))
            .collect::<Result<_>>()?;
        let v =
            |k: usize| pid.get(k).copied().with_context(|| format!("{}: no feature {k}", pid_path.display()));
        match ids.as_slice() {
            [] => {}
            [a] => f.plane.push(v(*a)?),
            [a, b] => f.pairs.push((v(*a)?, v(*b)?)),
            _ => bail!("{}: a line holds more than two features", info.display()),
        }
    }
    Ok(f)
}

/// The class's shapes `CLASS`, `CLASS0`, `CLASS1`, … (in that order) present in `dir`.
fn class_names(dir: &Path, class: &str) -> Vec<String> {
    let mut names: Vec<String> = std::iter::once(class.to_string())
        .chain((0..100).map(|i| format!("{class}{i}")))
        .chain((0..100).map(|i| format!("{class}{i:03}")))
        .filter(|n| dir.join(format!("{n}.off")).is_file())
        .collect();
    names.dedup();
    names
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dir = PathBuf::from(args.first().map(String::as_str).unwrap_or("../shared/data/tosca"));
    let class = args.get(1).map(String::as_str).unwrap_or("cat");
    let test_name = args.get(2).cloned().unwrap_or_else(|| format!("{class}1"));
    let n_train: usize = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(6);
    if !dir.exists() {
        println!("SKIPPED: no data at {} (pass the data folder as the first argument)", dir.display());
        return Ok(());
    }
    let names = class_names(&dir, class);
    let Some(test) = names.iter().position(|n| *n == test_name) else {
        bail!("no {test_name}.off in {} (class {class}: {names:?})", dir.display());
    };
    let train: Vec<usize> = (0..names.len()).filter(|&i| i != test).take(n_train).collect();
    if train.is_empty() {
        bail!("class {class} in {} has no other shape to train on", dir.display());
    }
    let cache = SpectrumCache::new(PathBuf::from("shapeforest-data/cache"))?;
    let sp = SpectrumParams::new(100);
    let load = |i: usize| -> Result<_> {
        let path = dir.join(format!("{}.off", names[i]));
        let mesh = Arc::new(read_mesh(&path).with_context(|| format!("cannot read {}", path.display()))?);
        let spectrum = Arc::new(cache.get_or_compute(&mesh, &sp)?);
        Ok((mesh, spectrum))
    };
    let mut set = Vec::new();
    for &i in &train {
        set.push((names[i].clone(), load(i)?.1));
    }
    let t0 = Instant::now();
    let forest =
        RandomForest::params().n_trees(15).seed(0).check()?.fit(&TrainingSet::same_indexing(set)?)?;
    println!(
        "test {test_name}, trained on {:?} in {:.1} s",
        train.iter().map(|&i| names[i].as_str()).collect::<Vec<_>>(),
        t0.elapsed().as_secs_f64()
    );
    let (ref_mesh, ref_spectrum) = load(train[0])?;
    let (test_mesh, test_spectrum) = load(test)?;
    if ref_mesh.n_vertices() != test_mesh.n_vertices() {
        bail!("{} and {test_name} do not share vertex indexing", names[train[0]]);
    }
    let reference = PreparedShape::new(ref_mesh.clone(), ref_spectrum.clone(), HeatParams::default())?;
    let test_shape = PreparedShape::new(test_mesh, test_spectrum.clone(), HeatParams::default())?;
    let prediction = forest.predict(&test_spectrum)?;

    // Evaluation: 1,000 seeded points; heat-method fields on the reference from the truth and
    // from its mirror image.
    let n = ref_mesh.n_vertices();
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let evaluated: Vec<usize> = (0..1000.min(n))
        .map(|_| {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 33) as usize) % n
        })
        .collect();
    let symmetry = SymmetrySolver::new(&ref_mesh, ref_spectrum.clone(), SymmetryParams::default())?
        .derive(&read_features(&dir, class)?)?
        .map;
    let solver = HeatMethodSolver::new(&ref_mesh, HeatParams::default())?;
    let fields = solver.distances_from_many(&evaluated)?;
    let mirrored: Vec<usize> = evaluated.iter().map(|&v| symmetry[v]).collect();
    let mirror_fields = solver.distances_from_many(&mirrored)?;
    let area = ref_mesh.surface_area();
    let row = |name: &str, map: &[usize], seconds: Option<f64>| -> Result<()> {
        let (strict, _) = geodesic_errors(map, &evaluated, fields.as_ref(), None, area)?;
        let (mirror, _) = geodesic_errors(map, &evaluated, mirror_fields.as_ref(), None, area)?;
        let flips: Vec<f64> = strict.iter().zip(&mirror).map(|(a, b)| a.min(*b)).collect();
        let (s, f) = (ErrorSummary::of(&strict), ErrorSummary::of(&flips));
        let t = seconds.map(|t| format!("{t:.2}")).unwrap_or_default();
        println!(
            "| {name} | {:.1} % | {:.1} % | {:.4} | {:.1} % | {t} |",
            100.0 * s.within_005,
            100.0 * s.within_010,
            s.mean,
            100.0 * f.within_005
        );
        Ok(())
    };

    let run = |params: &RegularizerParams| -> Result<_> {
        let t0 = Instant::now();
        let dense = regularize(&test_shape, &reference, &prediction, None, params)?;
        Ok((dense, t0.elapsed().as_secs_f64()))
    };
    let (plain, plain_s) =
        run(&RegularizerParams { growth: None, spectral_maps: true, ..Default::default() })?;
    let growth = |g: AnchorGrowthParams| RegularizerParams { growth: Some(g), ..Default::default() };
    let distances_only =
        AnchorGrowthParams { smoothness: 0.0, orientation: 0.0, reorient: 0.0, ..Default::default() };
    let (grown, grown_s) = run(&growth(distances_only))?;
    let (smoothed, smoothed_s) = run(&growth(AnchorGrowthParams { smoothness: 2.0, ..distances_only }))?;
    let (full, full_s) = run(&RegularizerParams::default())?;
    // Distances on the reference from the ground truth (same index) of each game anchor.
    let anchor_fields =
        solver.distances_from_many(&full.matches.iter().map(|m| m.test).collect::<Vec<_>>())?;
    println!(
        "{} game anchors ({} within 0.05 of the truth), {} grown anchors; mean forest support {:.1}; \
         dense orientation agreement {:.3}{}",
        full.matches.len(),
        full.matches
            .iter()
            .zip(anchor_fields.col_iter())
            .filter(|(m, d)| d[m.reference] / area.sqrt() <= 0.05)
            .count(),
        full.grown_anchors,
        prediction.mean_support(),
        full.dense_orientation.unwrap_or(f64::NAN),
        if full.reoriented { " (the re-oriented run won)" } else { "" }
    );
    println!("\n| map | ≤ 0.05 | ≤ 0.10 | mean | flips allowed ≤ 0.05 | regulariser (s) |");
    println!("|---|---:|---:|---:|---:|---:|");
    let raw: Vec<usize> = plain.forest_map.iter().map(|m| m.unwrap_or(0)).collect();
    row("forest, raw MAP", &raw, None)?;
    let fmap_map = plain.fmap_map.as_deref().expect("asked for with spectral_maps");
    let spectral_map = plain.spectral_map.as_deref().expect("asked for with spectral_maps");
    row("regularised fmap, spectral nearest neighbour", fmap_map, None)?;
    row("regularised fmap, among the forest's candidates", spectral_map, None)?;
    row("game anchors only", &plain.map, Some(plain_s))?;
    row("anchor growth, distances only", &grown.map, Some(grown_s))?;
    row("+ smoothing", &smoothed.map, Some(smoothed_s))?;
    row("+ orientation term and re-oriented run (default)", &full.map, Some(full_s))?;
    // Oracle: the candidate nearest to the truth.
    // Only the evaluated vertices are scored; the others keep the raw MAP.
    let mut oracle = raw.clone();
    for (j, &v) in evaluated.iter().enumerate() {
        let (labels, _) = prediction.posterior(v);
        if let Some(&best) =
            labels.iter().min_by(|&&a, &&b| fields[(a as usize, j)].total_cmp(&fields[(b as usize, j)]))
        {
            oracle[v] = best as usize;
        }
    }
    row("oracle: best forest candidate", &oracle, None)?;
    Ok(())
}
