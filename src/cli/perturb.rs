//! `shapeforest perturb`: turn a clean mesh into a scan-like one (holes, a single view, a crop,
//! noise), with the vertex map that keeps its ground truth.

use std::{fmt::Write as _, path::PathBuf};

use anyhow::{Context, Result};
use clap::Args;
use shapeforest::mesh::{perturb, perturbations_name, read_mesh, write_mesh, Perturbation};

/// Arguments of `shapeforest perturb`.
#[derive(Debug, Args)]
pub struct PerturbArgs {
    /// The input mesh.
    #[arg(long)]
    pub mesh: PathBuf,
    /// The output mesh (format by extension). `OUT.kept.txt` beside it lists, per output vertex,
    /// the 0-based input vertex it is, so ground truth carries over.
    #[arg(long)]
    pub out: PathBuf,
    /// N holes of Euclidean radius R·√area around seeded random centres (`N:R`; repeatable).
    #[arg(long, value_name = "N:R", value_parser = super::eval::parse_holes)]
    pub holes: Vec<Perturbation>,
    /// Keep only the faces visible from a seeded random direction (a single-view scan).
    #[arg(long)]
    pub partial_view: bool,
    /// Keep only what lies within R·√area of a seeded point of the surface.
    #[arg(long, value_name = "R")]
    pub crop: Option<f64>,
    /// Gaussian vertex noise of S mean edge lengths.
    #[arg(long, value_name = "S")]
    pub noise: Option<f64>,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// Runs `shapeforest perturb`.
pub fn run(args: PerturbArgs) -> Result<()> {
    let mesh = read_mesh(&args.mesh).with_context(|| format!("cannot read {}", args.mesh.display()))?;
    let list = super::eval::perturbation_list(args.crop, args.partial_view, &args.holes, args.noise);
    let p = perturb(&mesh, &list, args.seed).with_context(|| format!("{}", args.mesh.display()))?;
    write_mesh(&args.out, &p.mesh).with_context(|| format!("cannot write {}", args.out.display()))?;
    let mut kept = String::with_capacity(8 * p.kept.len());
    for v in &p.kept {
        let _ = writeln!(kept, "{v}");
    }
    let kept_path = PathBuf::from(format!("{}.kept.txt", args.out.display()));
    std::fs::write(&kept_path, kept).with_context(|| format!("cannot write {}", kept_path.display()))?;
    let s = p.mesh.summary();
    println!(
        "{} → {}: {}; {} of {} vertices, {:.1} % of the surface, {} component(s), {} boundary loop(s); \
         vertex map in {}",
        args.mesh.display(),
        args.out.display(),
        perturbations_name(&list),
        p.mesh.n_vertices(),
        mesh.n_vertices(),
        100.0 * p.area_fraction(&mesh),
        s.n_components(),
        s.n_boundary_loops,
        kept_path.display()
    );
    Ok(())
}
