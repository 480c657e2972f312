//! `shapeforest match`: dense correspondence of one mesh to a reference with a trained model.
//!
//! Forest prediction, then the regulariser against the reference. The model's labels must be
//! the reference's vertex indices (the common indexing of the training shapes). Writes into
//! `--out`:
//! - `SCAN.map.txt`: a header comment, then line `i` = the reference vertex (0-based) matched to
//!   scan vertex `i`;
//! - `REF.colored.ply` and `SCAN.colored.ply`: the reference coloured by a smooth function of
//!   its coordinates, and the scan coloured through the map (matching parts share colours);
//! - `SCAN.report.json`: timings, number of sparse matches, orientation score, mean forest
//!   confidence.

use std::{
    fmt::Write as _,
    path::{Path, PathBuf},
    sync::Arc,
    time::Instant,
};

use anyhow::{bail, Context, Result};
use clap::Args;
use shapeforest::{
    forest::RandomForest,
    mesh::{coordinate_colors, read_mesh, write_colored_ply, Mesh},
    regularizer::{regularize, PreparedShape, RegularizerParams},
    spectral::{compute_spectrum, Spectrum, SpectrumCache, SpectrumParams},
};

/// Arguments of `shapeforest match`.
#[derive(Debug, Args)]
pub struct MatchArgs {
    /// Model file written by `shapeforest train` (`RandomForest::save`).
    #[arg(long)]
    pub model: PathBuf,
    /// Reference mesh whose vertex indices are the model's labels.
    #[arg(long)]
    pub reference: PathBuf,
    /// Mesh to match.
    #[arg(long)]
    pub mesh: PathBuf,
    /// Output folder.
    #[arg(long, default_value = "shapeforest-match")]
    pub out: PathBuf,
    /// Spectrum cache folder (none by default).
    #[arg(long)]
    pub cache: Option<PathBuf>,
}

fn stem(p: &Path) -> String {
    p.file_stem().and_then(|s| s.to_str()).unwrap_or("mesh").to_string()
}

fn spectrum(
    mesh: &Mesh,
    params: &SpectrumParams,
    cache: Option<&SpectrumCache>,
    path: &Path,
) -> Result<Spectrum> {
    let r = match cache {
        Some(c) => c.get_or_compute(mesh, params),
        None => compute_spectrum(mesh, params),
    };
    r.with_context(|| format!("cannot compute the spectrum of {}", path.display()))
}

fn write_colored(path: &Path, mesh: &Mesh, colors: &[[u8; 3]]) -> Result<()> {
    write_colored_ply(path, mesh, colors).with_context(|| format!("cannot write {}", path.display()))
}

/// Runs `shapeforest match`.
pub fn run(args: MatchArgs) -> Result<()> {
    let t_all = Instant::now();
    let t0 = Instant::now();
    if !args.model.is_file() {
        bail!("model file {} does not exist", args.model.display());
    }
    let forest = RandomForest::load(&args.model)
        .with_context(|| format!("cannot load the model {}", args.model.display()))?;
    let reference = read_mesh(&args.reference)
        .with_context(|| format!("cannot read mesh {}", args.reference.display()))?;
    let scan = read_mesh(&args.mesh).with_context(|| format!("cannot read mesh {}", args.mesh.display()))?;
    let load_s = t0.elapsed().as_secs_f64();
    if forest.n_labels() != reference.n_vertices() {
        bail!(
            "the model {} has {} labels but the reference {} has {} vertices: the reference must be \
             a shape whose vertex indices are the model's labels (a shape of the training class)",
            args.model.display(),
            forest.n_labels(),
            args.reference.display(),
            reference.n_vertices()
        );
    }
    std::fs::create_dir_all(&args.out).with_context(|| format!("cannot create {}", args.out.display()))?;
    let cache = match &args.cache {
        Some(d) => {
            Some(SpectrumCache::new(d.clone()).with_context(|| format!("cannot use cache {}", d.display()))?)
        }
        None => None,
    };
    let reg = RegularizerParams::default();
    let k = forest.k().max(reg.fmap.k_test).max(reg.fmap.k_ref);
    let sp_params = SpectrumParams::new(k);
    let t0 = Instant::now();
    let scan_spectrum = Arc::new(spectrum(&scan, &sp_params, cache.as_ref(), &args.mesh)?);
    let spectrum_scan_s = t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    let ref_spectrum = Arc::new(spectrum(&reference, &sp_params, cache.as_ref(), &args.reference)?);
    let spectrum_ref_s = t0.elapsed().as_secs_f64();

    let t0 = Instant::now();
    let prediction = forest.predict(&scan_spectrum).context("forest prediction failed")?;
    let predict_s = t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    let scan = Arc::new(scan);
    let reference = Arc::new(reference);
    let test = PreparedShape::new(scan.clone(), scan_spectrum, reg.heat)?;
    let refp = PreparedShape::new(reference.clone(), ref_spectrum, reg.heat)?;
    let prepare_s = t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    let dense = regularize(&test, &refp, &prediction, None, &reg)?;
    let regularize_s = t0.elapsed().as_secs_f64();

    let t0 = Instant::now();
    let scan_name = stem(&args.mesh);
    let ref_name = stem(&args.reference);
    let mut text = format!(
        "# shapeforest match: line i (after this header) = vertex of {} (0-based) matched to vertex i of {}\n",
        args.reference.display(),
        args.mesh.display()
    );
    for &r in &dense.map {
        let _ = writeln!(text, "{r}");
    }
    let map_path = args.out.join(format!("{scan_name}.map.txt"));
    std::fs::write(&map_path, text).with_context(|| format!("cannot write {}", map_path.display()))?;
    let ref_colors = coordinate_colors(&reference);
    let scan_colors: Vec<[u8; 3]> = dense.map.iter().map(|&r| ref_colors[r]).collect();
    write_colored(&args.out.join(format!("{ref_name}.colored.ply")), &reference, &ref_colors)?;
    write_colored(&args.out.join(format!("{scan_name}.colored.ply")), &scan, &scan_colors)?;
    super::visual::write_snapshot(&args.out, &scan_name, &scan, &reference, &dense.map)?;
    let write_s = t0.elapsed().as_secs_f64();

    let confidence = prediction.mean_confidence();
    let tm = &dense.timings;
    let report = serde_json::json!({
        "mesh": args.mesh.display().to_string(),
        "reference": args.reference.display().to_string(),
        "model": args.model.display().to_string(),
        "mesh_vertices": scan.n_vertices(),
        "reference_vertices": reference.n_vertices(),
        "n_matches": dense.matches.len(),
        "orientation_score": dense.orientation_score,
        "mirror_rejected": dense.mirror_rejected,
        "grown_anchors": dense.grown_anchors,
        "dense_orientation_agreement": dense.dense_orientation,
        "reoriented": dense.reoriented,
        "mean_forest_confidence": confidence,
        "mean_forest_support": prediction.mean_support(),
        "timings_s": {
            "load": load_s,
            "spectrum_mesh": spectrum_scan_s,
            "spectrum_reference": spectrum_ref_s,
            "predict": predict_s,
            "prepare": prepare_s,
            "regularize": regularize_s,
            "regularize_sampling": tm.sampling_s,
            "regularize_distances": tm.distances_s,
            "regularize_matching": tm.matching_s,
            "regularize_fmap": tm.fmap_s,
            "regularize_point_map": tm.point_map_s,
            "regularize_growth": tm.growth_s,
            "write": write_s,
            "total": t_all.elapsed().as_secs_f64(),
        },
    });
    let json = serde_json::to_string_pretty(&report)? + "\n";
    let report_path = args.out.join(format!("{scan_name}.report.json"));
    std::fs::write(&report_path, json).with_context(|| format!("cannot write {}", report_path.display()))?;
    println!(
        "{} → {}: {} vertices matched, {} sparse matches, orientation {:.3}, mean confidence {:.3}; \
         predict {predict_s:.2} s, regularise {regularize_s:.2} s; wrote {}",
        args.mesh.display(),
        args.reference.display(),
        dense.map.len(),
        dense.matches.len(),
        dense.orientation_score,
        confidence,
        args.out.display()
    );
    Ok(())
}
