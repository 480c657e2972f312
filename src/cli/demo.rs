//! `shapeforest demo`: the whole method end to end on the built-in synthetic creature family —
//! spectra, forest training, prediction on held-out poses, regularisation, evaluation against
//! the known ground truth, and outputs a person can open.

use std::{fmt::Write as _, path::PathBuf, sync::Arc, time::Instant};

use anyhow::{Context, Result};
use clap::Args;
use shapeforest::{
    descriptor::WksParams,
    eval::{geodesic_errors, ErrorSummary},
    forest::{labels_identity, RandomForest, TrainingSet, TrainingShape, WksKnn},
    geodesic::HeatParams,
    mesh::write_mesh,
    regularizer::{regularize, PreparedShape, RegularizerParams},
    synth::{creature_family, CreatureParams},
};

use super::common::{progress, spectra};

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Vertices per synthetic shape.
    #[arg(long, default_value_t = 5000)]
    pub vertices: usize,
    /// Training shapes (the paper uses 6).
    #[arg(long, default_value_t = 6)]
    pub train: usize,
    /// Held-out shapes to match.
    #[arg(long, default_value_t = 2)]
    pub test: usize,
    /// Trees in the forest.
    #[arg(long, default_value_t = 15)]
    pub trees: usize,
    /// Seed of the shape family and the forest.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Where to write the model, the shapes and the maps.
    #[arg(long, default_value = "shapeforest-demo")]
    pub out: PathBuf,
}

/// One row of the accuracy table.
struct Row {
    method: &'static str,
    strict: ErrorSummary,
    symmetric: ErrorSummary,
}

pub fn run(args: DemoArgs) -> Result<()> {
    let started = Instant::now();
    std::fs::create_dir_all(&args.out).with_context(|| format!("cannot create {}", args.out.display()))?;
    println!(
        "shapeforest demo: {} training + {} held-out synthetic creatures of ~{} vertices",
        args.train, args.test, args.vertices
    );

    let t0 = Instant::now();
    let fam = creature_family(
        &CreatureParams { target_vertices: args.vertices, seed: args.seed, ..Default::default() },
        args.train + args.test,
    )?;
    let n = fam.template.n_vertices();
    println!(
        "  shapes: {} of {n} vertices, left/right symmetric, posed ({:.1} s)",
        fam.shapes.len(),
        t0.elapsed().as_secs_f64()
    );

    let t0 = Instant::now();
    let meshes: Vec<_> = fam.shapes.iter().collect();
    let spectra = spectra(&meshes, 100, None, "spectra")?;
    println!("  Laplace spectra, K = 100, all shapes: {:.1} s", t0.elapsed().as_secs_f64());

    let training: Vec<TrainingShape> = (0..args.train)
        .map(|i| TrainingShape {
            name: format!("creature{i}"),
            spectrum: spectra[i].clone(),
            labels: labels_identity(n),
        })
        .collect();
    let set = TrainingSet::new(training, n)?;
    let t0 = Instant::now();
    let bar = Arc::new(progress(args.trees as u64, "trees"));
    let b = bar.clone();
    let forest = RandomForest::params().n_trees(args.trees).seed(args.seed).check()?.fit_with_progress(
        None,
        &set,
        &move |_| b.inc(1),
    )?;
    bar.finish_and_clear();
    println!(
        "  forest: {} trees on {} samples, {:.1} s",
        forest.n_trees(),
        set.n_samples(),
        t0.elapsed().as_secs_f64()
    );
    let model_path = args.out.join("model.sfm");
    forest.save(&model_path)?;
    let knn = WksKnn::fit(&set, &WksParams::default(), forest.energy_grid().range, forest.k())?;

    let reference =
        PreparedShape::new(Arc::new(fam.shapes[0].clone()), spectra[0].clone(), HeatParams::default())?;
    write_mesh(args.out.join("reference.off"), &fam.shapes[0])?;
    // Evaluate on every 5th vertex: distance fields on the reference from their true matches.
    let evaluated: Vec<usize> = (0..n).step_by(5).collect();
    let fields = reference.heat.distances_from_many(&evaluated)?;
    let area = reference.mesh.surface_area();
    let score = |map: &[usize]| -> Result<(ErrorSummary, ErrorSummary)> {
        let (s, y) = geodesic_errors(map, &evaluated, fields.as_ref(), Some(&fam.symmetry), area)?;
        Ok((ErrorSummary::of(&s), ErrorSummary::of(&y.unwrap_or_default())))
    };

    let mut rows: Vec<Row> = Vec::new();
    let params = RegularizerParams::default();
    for (t, (shape, spectrum)) in fam.shapes.iter().zip(&spectra).enumerate().skip(args.train) {
        let t0 = Instant::now();
        let prediction = forest.predict(spectrum)?;
        let t_pred = t0.elapsed().as_secs_f64();
        let test =
            PreparedShape::new(Arc::new(fam.shapes[t].clone()), spectra[t].clone(), HeatParams::default())?;
        let t0 = Instant::now();
        let dense = regularize(&test, &reference, &prediction, None, &params)?;
        let t_reg = t0.elapsed().as_secs_f64();
        let raw: Vec<usize> = dense.forest_map.iter().map(|m| m.unwrap_or(0)).collect();
        let knn_pred = knn.predict(spectrum, prediction.mean_support().round().max(1.0) as usize)?;
        let knn_dense = regularize(&test, &reference, &knn_pred, None, &params)?;
        let knn_raw: Vec<usize> = knn_dense.forest_map.iter().map(|m| m.unwrap_or(0)).collect();
        for (method, map) in [
            ("forest, raw MAP", &raw),
            ("forest + regulariser", &dense.map),
            ("WKS k-NN, raw", &knn_raw),
            ("WKS k-NN + regulariser", &knn_dense.map),
        ] {
            let (strict, symmetric) = score(map)?;
            rows.push(Row { method, strict, symmetric });
        }
        let name = format!("creature{t}");
        write_mesh(args.out.join(format!("{name}.off")), shape)?;
        let mut text = format!("# {name} vertex -> reference vertex (0-based), shapeforest demo\n");
        for r in &dense.map {
            let _ = writeln!(text, "{r}");
        }
        std::fs::write(args.out.join(format!("{name}.map.txt")), text)?;
        println!(
            "  {name}: prediction {t_pred:.2} s, regulariser {t_reg:.2} s ({} consistent matches, orientation score {:+.2}{})",
            dense.matches.len(),
            dense.orientation_score,
            if dense.mirror_rejected { ", mirror image rejected" } else { "" }
        );
    }

    println!("\n  accuracy on the held-out shapes (geodesic error / √area; {} points each)", evaluated.len());
    println!("  {:<24} {:>9} {:>9} {:>7}   {:>14}", "method", "≤ 0.05", "≤ 0.10", "mean", "sym. ≤ 0.05");
    for method in ["forest, raw MAP", "forest + regulariser", "WKS k-NN, raw", "WKS k-NN + regulariser"] {
        let sel: Vec<&Row> = rows.iter().filter(|r| r.method == method).collect();
        let avg = |f: &dyn Fn(&Row) -> f64| sel.iter().map(|r| f(r)).sum::<f64>() / sel.len().max(1) as f64;
        println!(
            "  {:<24} {:>8.1}% {:>8.1}% {:>7.3}   {:>13.1}%",
            method,
            100.0 * avg(&|r| r.strict.within_005),
            100.0 * avg(&|r| r.strict.within_010),
            avg(&|r| r.strict.mean),
            100.0 * avg(&|r| r.symmetric.within_005)
        );
    }
    println!(
        "\n  outputs in {}: model.sfm, reference.off, creatureN.off and creatureN.map.txt (one reference vertex per line)",
        args.out.display()
    );
    println!("  total {:.1} s", started.elapsed().as_secs_f64());
    Ok(())
}
