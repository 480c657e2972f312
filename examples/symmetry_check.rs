//! How accurate are the dense symmetries derived from the sparse feature points of TOSCA?
//!
//! For each class, derives the symmetry of the hi-res `CLASS0.off` (or the shape named as
//! `CLASS:SHAPE`) from `CLASS.sym.info` + `CLASS.pid` (as `shapeforest eval` does), prints its
//! error at the feature points (leave-one-pair-out, at most 10 folds), and checks it densely against the remeshed TOSCA set (`tosca-r5k`), whose
//! `CLASS0.sym.vts` lists the mirror image of 5000 points of the same surface in the same
//! coordinates: each remeshed point is snapped to its nearest hi-res vertex.
//!
//! ```text
//! cargo run --release --example symmetry_check -- ../shared/data cat centaur david gorilla:gorilla1
//! ```

use std::{path::Path, sync::Arc, time::Instant};

use anyhow::{bail, Context, Result};
use shapeforest::{
    eval::symmetry::{SymmetricFeatures, SymmetryParams, SymmetrySolver},
    fmap::nearest_rows,
    geodesic::{HeatMethodSolver, HeatParams},
    mesh::{read_mesh, Mesh},
    spectral::{compute_spectrum, SpectrumParams},
};

fn numbers(path: &Path) -> Result<Vec<Vec<usize>>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    text.lines()
        .map(|l| {
            l.split_whitespace()
                .map(|t| t.parse().with_context(|| format!("{}: {t:?}", path.display())))
                .collect()
        })
        .collect()
}

fn features(tosca: &Path, class: &str) -> Result<SymmetricFeatures> {
    let pid: Vec<usize> =
        numbers(&tosca.join(format!("{class}.pid")))?.iter().filter_map(|r| r.first().copied()).collect();
    let mut f = SymmetricFeatures::default();
    for row in numbers(&tosca.join(format!("{class}.sym.info")))? {
        match row.as_slice() {
            [a, b] => f.pairs.push((pid[*a], pid[*b])),
            [a] => f.plane.push(pid[*a]),
            [] => {}
            _ => bail!("{class}.sym.info: a line with more than two features"),
        }
    }
    Ok(f)
}

/// Nearest vertex of `mesh` to each point.
fn snap(mesh: &Mesh, points: &[[f64; 3]]) -> Vec<usize> {
    let m = |v: &[[f64; 3]]| faer::Mat::from_fn(v.len(), 3, |i, j| v[i][j]);
    nearest_rows(m(points).as_ref(), m(&mesh.vertices).as_ref())
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some((data, classes)) = args.split_first() else {
        bail!("usage: symmetry_check DATA_DIR CLASS...");
    };
    let data = Path::new(data);
    let tosca = data.join("tosca");
    let r5k = data.join("tosca-r5k/TOSCA_Isometric/vtx_5k");
    println!("| shape | vertices | pairs + plane | held-out ≤ 0.05 | held-out mean | S∘S ≈ id | dense ≤ 0.05 | dense mean | time |");
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    for arg in classes {
        // CLASS, or CLASS:SHAPE for a class without a CLASS0 mesh (gorilla:gorilla1).
        let (class, shape) = match arg.split_once(':') {
            Some((c, s)) => (c.to_string(), s.to_string()),
            None => (arg.clone(), format!("{arg}0")),
        };
        let class = class.as_str();
        let t0 = Instant::now();
        let mesh = read_mesh(tosca.join(format!("{shape}.off")))?;
        let feats = features(&tosca, class)?;
        let spectrum = Arc::new(compute_spectrum(&mesh, &SpectrumParams::new(100))?);
        let solver = SymmetrySolver::new(&mesh, spectrum, SymmetryParams::default())?;
        let derived = solver.derive(&feats)?;
        let check = solver.validate(&feats, 10, &derived)?;
        let time = t0.elapsed().as_secs_f64();
        // Dense check against the remeshed set's mirrored ground truth.
        let (dense_within, dense_mean) = match read_mesh(r5k.join(format!("{shape}.off.gz"))) {
            Ok(low) => {
                let vts = numbers(&r5k.join(format!("corres/{shape}.vts")))?;
                let sym = numbers(&r5k.join(format!("corres/{shape}.sym.vts")))?;
                let rows: Vec<usize> = (0..vts.len()).step_by(5).collect();
                let at = |t: &Vec<Vec<usize>>| -> Vec<[f64; 3]> {
                    rows.iter().map(|&k| low.vertices[t[k][0] - 1]).collect()
                };
                let a = snap(&mesh, &at(&vts));
                let b = snap(&mesh, &at(&sym));
                let fields = HeatMethodSolver::new(&mesh, HeatParams::default())?.distances_from_many(&b)?;
                let norm = 1.0 / mesh.surface_area().sqrt();
                let e: Vec<f64> =
                    a.iter().enumerate().map(|(j, &v)| fields[(derived.map[v], j)] * norm).collect();
                let within = e.iter().filter(|&&x| x <= 0.05).count() as f64 / e.len() as f64;
                (format!("{:.1} %", 100.0 * within), format!("{:.4}", e.iter().sum::<f64>() / e.len() as f64))
            }
            Err(_) => ("–".into(), "–".into()),
        };
        println!(
            "| {shape} | {} | {} + {} | {:.1} % | {:.4} | {:.1} % | {dense_within} | {dense_mean} | {time:.1} s |",
            mesh.n_vertices(),
            feats.pairs.len(),
            feats.plane.len(),
            100.0 * check.within_005,
            check.mean,
            100.0 * check.involution_within_005
        );
    }
    Ok(())
}
