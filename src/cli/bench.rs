//! `shapeforest bench`: the side-by-side benchmark against scipy's `eigsh` and potpourri3d.
//!
//! Two halves, run by `scripts/bench-peers.sh` with the peer in between:
//! - `--out DIR` writes the benchmark meshes (a ladder of synthetic creatures, plus TOSCA shapes
//!   when the data folder exists) as OFF, times shapeforest on each (spectrum K = 100 on the
//!   unit-area mesh with shift σ, heat-method setup plus distances from 50 farthest-point
//!   sources, WKS of every vertex), and writes `manifest.json` (what the peer must run) and
//!   `shapeforest.json` (our timings and eigenvalues).
//! - `--report DIR` joins `shapeforest.json` with the peer's `peer.json` (written by
//!   `scripts/peer_bench.py`) and prints a Markdown table with the time ratios and the largest
//!   relative eigenvalue difference between the two solvers (both solve the same generalised
//!   problem `L φ = λ M φ` with lumped mass scaled to unit area, so they must agree).

use std::fmt::Write as _;
use std::fs;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::{ArgGroup, Args};
use serde::{Deserialize, Serialize};
use shapeforest::{
    descriptor::{wave_kernel_signature, WksParams},
    forest::{labels_identity, RandomForest, TrainingSet, TrainingShape},
    geodesic::{farthest_point_sampling_euclidean, HeatMethodSolver, HeatParams},
    mesh::{read_mesh, write_mesh, Mesh},
    spectral::{compute_spectrum, SpectrumParams},
    synth::{creature_family, CreatureParams},
};

/// TOSCA shapes benchmarked when the data folder is present (small to large).
const TOSCA_SHAPES: [&str; 4] = ["wolf0", "centaur0", "cat0", "david0"];

#[derive(Debug, Args)]
#[command(group(ArgGroup::new("mode").required(true).args(["out", "report"])))]
pub struct BenchArgs {
    /// Write the benchmark meshes, `manifest.json` and `shapeforest.json` into this folder.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Read `shapeforest.json` and `peer.json` from this folder and print the Markdown table.
    #[arg(long, value_name = "DIR")]
    pub report: Option<PathBuf>,
    /// Approximate vertex counts of the synthetic creature ladder (comma separated).
    #[arg(long, value_delimiter = ',', default_value = "5000,20000,50000")]
    pub sizes: Vec<usize>,
    /// Data folder holding `tosca/` (default: `$SHAPEFOREST_DATA`, else `../shared/data`).
    #[arg(long, value_name = "DIR")]
    pub data: Option<PathBuf>,
    /// Skip the TOSCA meshes even when the data folder exists.
    #[arg(long, conflicts_with = "data")]
    pub no_data: bool,
    /// Time each step this many times and keep the best.
    #[arg(long, default_value_t = 1)]
    pub repeat: usize,
    /// Number of eigenpairs K.
    #[arg(long, default_value_t = 100)]
    pub k: usize,
    /// Number of heat-method distance sources (farthest point sampling).
    #[arg(long, default_value_t = 50)]
    pub sources: usize,
    /// Also time forest training (15 trees on 6 creatures of ~28K vertices) and prediction on a
    /// ~50K-vertex creature.
    #[arg(long)]
    pub forest: bool,
}

/// What the peer script must run: `scripts/peer_bench.py` reads it.
#[derive(Debug, Serialize, Deserialize)]
pub struct Manifest {
    /// Number of eigenpairs.
    pub k: usize,
    /// Shift σ of the peer's shift-invert solve on the unit-area mesh (shapeforest's solver
    /// chooses its own, an interior one).
    pub shift: f64,
    /// Number of distance sources per mesh.
    pub n_sources: usize,
    /// Best-of count the peer should use too.
    pub repeat: usize,
    /// How the sources were chosen.
    pub sources_method: String,
    /// The meshes.
    pub meshes: Vec<ManifestMesh>,
}

/// One mesh of the manifest.
#[derive(Debug, Serialize, Deserialize)]
pub struct ManifestMesh {
    /// Short name (`creature-5000`, `wolf0`, ...).
    pub name: String,
    /// Absolute path of the OFF file.
    pub path: PathBuf,
    /// Vertex count.
    pub vertices: usize,
    /// Distance sources (vertex indices).
    pub sources: Vec<usize>,
}

/// Our timings.
#[derive(Debug, Serialize, Deserialize)]
pub struct OurResults {
    /// Rayon worker threads used.
    pub threads: usize,
    /// Number of eigenpairs.
    pub k: usize,
    /// Best-of count.
    pub repeat: usize,
    /// Per-mesh results.
    pub meshes: Vec<OurMesh>,
    /// Forest figures, when `--forest` was given.
    #[serde(default)]
    pub forest: Option<ForestResults>,
    /// The machine's load averages (1, 5, 15 minutes) before and after our runs, where the
    /// system reports them (`/proc/loadavg`): figures measured under load are not comparable.
    #[serde(default)]
    pub load_average: Vec<[f64; 3]>,
}

/// The 1-, 5- and 15-minute load averages from `/proc/loadavg` (`None` where absent).
pub fn load_average() -> Option<[f64; 3]> {
    let text = std::fs::read_to_string("/proc/loadavg").ok()?;
    let mut it = text.split_whitespace().map(|x| x.parse::<f64>().ok());
    Some([it.next()??, it.next()??, it.next()??])
}

/// Our timings on one mesh.
#[derive(Debug, Serialize, Deserialize)]
pub struct OurMesh {
    /// Mesh name, as in the manifest.
    pub name: String,
    /// Vertex count.
    pub vertices: usize,
    /// Best time of `compute_spectrum` (assembly, factorisation, Lanczos, verification), s.
    pub eigen_s: f64,
    /// Heat-method setup (assembly and both factorisations), s.
    pub heat_setup_s: f64,
    /// Distances from all sources (one block solve), s.
    pub heat_solve_s: f64,
    /// WKS (100 energies) of every vertex from the spectrum, s.
    pub wks_s: f64,
    /// Eigenvalues of the unit-area mesh, ascending.
    pub eigenvalues: Vec<f64>,
}

/// Forest training and prediction figures.
#[derive(Debug, Serialize, Deserialize)]
pub struct ForestResults {
    /// Training shapes.
    pub n_shapes: usize,
    /// Vertices per training shape.
    pub train_vertices: usize,
    /// Trees.
    pub n_trees: usize,
    /// Spectra of the training shapes, s (not part of the training time).
    pub spectra_s: f64,
    /// `fit`, s.
    pub train_s: f64,
    /// Serialised model size, bytes.
    pub model_bytes: usize,
    /// Vertices of the prediction shape.
    pub predict_vertices: usize,
    /// `predict` on a precomputed spectrum, s.
    pub predict_s: f64,
}

/// The peer's results, as written by `scripts/peer_bench.py`.
#[derive(Debug, Deserialize)]
pub struct PeerResults {
    /// Peer package versions (`scipy`, `potpourri3d`).
    #[serde(default)]
    pub peer: std::collections::BTreeMap<String, String>,
    /// Per-mesh results.
    pub meshes: Vec<PeerMesh>,
}

/// The peer's timings on one mesh.
#[derive(Debug, Deserialize)]
pub struct PeerMesh {
    /// Mesh name.
    pub name: String,
    /// scipy `eigsh` time, s.
    pub eigsh_s: f64,
    /// scipy's eigenvalues, ascending.
    pub eigenvalues: Vec<f64>,
    /// potpourri3d `MeshHeatMethodDistanceSolver` construction, s.
    #[serde(default)]
    pub heat_setup_s: Option<f64>,
    /// potpourri3d distances from all sources (one call each), s.
    #[serde(default)]
    pub heat_solve_s: Option<f64>,
}

pub fn run(args: BenchArgs) -> Result<()> {
    match (&args.out, &args.report) {
        (Some(out), _) => run_out(&args, out),
        (None, Some(dir)) => {
            print!("{}", report(dir)?);
            Ok(())
        }
        (None, None) => bail!("give --out DIR or --report DIR"),
    }
}

/// Best wall time of `repeat` runs of `f`, with the last result.
fn best_of<T>(repeat: usize, mut f: impl FnMut() -> Result<T>) -> Result<(f64, T)> {
    let mut best = f64::INFINITY;
    let mut last = None;
    for _ in 0..repeat.max(1) {
        let t0 = Instant::now();
        let value = f()?;
        best = best.min(t0.elapsed().as_secs_f64());
        last = Some(value);
    }
    match last {
        Some(v) => Ok((best, v)),
        None => bail!("no run"),
    }
}

fn data_dir(args: &BenchArgs) -> Option<PathBuf> {
    if args.no_data {
        return None;
    }
    if let Some(d) = &args.data {
        return Some(d.clone());
    }
    Some(
        std::env::var_os("SHAPEFOREST_DATA")
            .map(PathBuf::from)
            .unwrap_or_else(|| PathBuf::from("../shared/data")),
    )
}

/// The benchmark meshes: the creature ladder, then the TOSCA shapes found.
fn benchmark_meshes(args: &BenchArgs) -> Result<Vec<(String, Mesh)>> {
    let mut meshes = Vec::new();
    for &size in &args.sizes {
        let params = CreatureParams { target_vertices: size, seed: 1, ..Default::default() };
        let family = creature_family(&params, 2).with_context(|| format!("creature of ~{size} vertices"))?;
        let mesh = family.shapes.into_iter().nth(1).context("creature family without a posed shape")?;
        meshes.push((format!("creature-{size}"), mesh));
    }
    match data_dir(args) {
        None => eprintln!("TOSCA meshes skipped (--no-data)"),
        Some(dir) => {
            let tosca = dir.join("tosca");
            if !tosca.is_dir() {
                if args.data.is_some() {
                    bail!("no tosca/ folder under {}", dir.display());
                }
                eprintln!(
                    "TOSCA data absent: no tosca/ folder under {} (pass --data DIR or set SHAPEFOREST_DATA); \
                     benchmarking the synthetic ladder only",
                    dir.display()
                );
            } else {
                for name in TOSCA_SHAPES {
                    let path = tosca.join(format!("{name}.off"));
                    if !path.is_file() {
                        eprintln!("TOSCA {name} absent ({}), skipped", path.display());
                        continue;
                    }
                    let mesh = read_mesh(&path).with_context(|| format!("reading {}", path.display()))?;
                    meshes.push((name.to_string(), mesh));
                }
            }
        }
    }
    Ok(meshes)
}

fn write_json(path: &Path, value: &impl Serialize) -> Result<()> {
    let text = serde_json::to_string_pretty(value)?;
    fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

fn run_out(args: &BenchArgs, out: &Path) -> Result<()> {
    if args.k == 0 {
        bail!("--k must be at least 1");
    }
    fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let out = out.canonicalize().with_context(|| format!("resolving {}", out.display()))?;
    let params = SpectrumParams::new(args.k);
    let meshes = benchmark_meshes(args)?;
    if meshes.is_empty() {
        bail!("no meshes to benchmark (empty --sizes and no TOSCA data)");
    }
    let mut manifest = Manifest {
        k: args.k,
        shift: params.shift,
        n_sources: args.sources,
        repeat: args.repeat.max(1),
        sources_method: "Euclidean farthest point sampling from the vertex farthest from the centroid".into(),
        meshes: Vec::new(),
    };
    let mut ours = OurResults {
        threads: rayon::current_num_threads(),
        k: args.k,
        repeat: args.repeat.max(1),
        meshes: Vec::new(),
        forest: None,
        load_average: load_average().into_iter().collect(),
    };
    for (name, mesh) in &meshes {
        let n = mesh.n_vertices();
        let path = out.join(format!("{name}.off"));
        write_mesh(&path, mesh).with_context(|| format!("writing {}", path.display()))?;
        let sources = farthest_point_sampling_euclidean(mesh, args.sources.min(n), None)?;
        eprintln!("{name}: {n} vertices, {} faces", mesh.faces.len());

        let (eigen_s, spectrum) = best_of(args.repeat, || Ok(compute_spectrum(mesh, &params)?))?;
        eprintln!("  spectrum K={}: {eigen_s:.3} s", args.k);
        let mut heat_setup_s = f64::INFINITY;
        let mut heat_solve_s = f64::INFINITY;
        for _ in 0..args.repeat.max(1) {
            let t0 = Instant::now();
            let solver = HeatMethodSolver::new(mesh, HeatParams::default())?;
            heat_setup_s = heat_setup_s.min(t0.elapsed().as_secs_f64());
            let t0 = Instant::now();
            let d = solver.distances_from_many(&sources)?;
            heat_solve_s = heat_solve_s.min(t0.elapsed().as_secs_f64());
            if d.ncols() != sources.len() {
                bail!("heat method returned {} columns for {} sources", d.ncols(), sources.len());
            }
        }
        eprintln!("  heat method: setup {heat_setup_s:.3} s + {} sources {heat_solve_s:.3} s", sources.len());
        let (wks_s, wks) =
            best_of(args.repeat, || Ok(wave_kernel_signature(&spectrum, &WksParams::default(), None)?))?;
        if wks.nrows() != n {
            bail!("WKS has {} rows for {n} vertices", wks.nrows());
        }
        eprintln!("  WKS of {n} vertices: {wks_s:.3} s");

        manifest.meshes.push(ManifestMesh { name: name.clone(), path, vertices: n, sources });
        ours.meshes.push(OurMesh {
            name: name.clone(),
            vertices: n,
            eigen_s,
            heat_setup_s,
            heat_solve_s,
            wks_s,
            eigenvalues: spectrum.eigenvalues.clone(),
        });
        // Written after every mesh so that an interrupted run still leaves usable files.
        write_json(&out.join("manifest.json"), &manifest)?;
        write_json(&out.join("shapeforest.json"), &ours)?;
    }
    if args.forest {
        ours.forest = Some(bench_forest(args.k)?);
    }
    ours.load_average.extend(load_average());
    write_json(&out.join("shapeforest.json"), &ours)?;
    eprintln!(
        "wrote {} meshes, manifest.json and shapeforest.json to {}",
        manifest.meshes.len(),
        out.display()
    );
    Ok(())
}

/// Forest training on 6 creatures of ~28K vertices (15 trees) and prediction on ~50K.
fn bench_forest(k: usize) -> Result<ForestResults> {
    let (n_shapes, n_trees) = (6, 15);
    let params = CreatureParams { target_vertices: 28_000, seed: 7, ..Default::default() };
    let family = creature_family(&params, n_shapes)?;
    let n = family.template.n_vertices();
    eprintln!("forest: {n_shapes} creatures of {n} vertices");
    let t0 = Instant::now();
    let mut shapes = Vec::with_capacity(n_shapes);
    for (i, mesh) in family.shapes.iter().enumerate() {
        let spectrum = Arc::new(compute_spectrum(mesh, &SpectrumParams::new(k))?);
        shapes.push(TrainingShape::new(format!("creature-{i}"), spectrum, labels_identity(n)));
    }
    let spectra_s = t0.elapsed().as_secs_f64();
    eprintln!("  spectra: {spectra_s:.2} s");
    let set = TrainingSet::new(shapes, n)?;
    let t0 = Instant::now();
    let forest = RandomForest::params().n_trees(n_trees).seed(1).fit(&set)?;
    let train_s = t0.elapsed().as_secs_f64();
    let model_bytes = forest.to_bytes()?.len();
    eprintln!("  training {n_trees} trees: {train_s:.2} s, model {:.1} MB", model_bytes as f64 / 1e6);
    let target = CreatureParams { target_vertices: 50_000, seed: 8, ..Default::default() };
    let probe = creature_family(&target, 2)?
        .shapes
        .into_iter()
        .nth(1)
        .context("creature family without a posed shape")?;
    let spectrum = compute_spectrum(&probe, &SpectrumParams::new(k))?;
    let t0 = Instant::now();
    let prediction = forest.predict(&spectrum)?;
    let predict_s = t0.elapsed().as_secs_f64();
    if prediction.n_vertices() != probe.n_vertices() {
        bail!("prediction covers {} of {} vertices", prediction.n_vertices(), probe.n_vertices());
    }
    eprintln!("  prediction on {} vertices: {predict_s:.2} s", probe.n_vertices());
    Ok(ForestResults {
        n_shapes,
        train_vertices: n,
        n_trees,
        spectra_s,
        train_s,
        model_bytes,
        predict_vertices: probe.n_vertices(),
        predict_s,
    })
}

/// Largest relative difference between two ascending eigenvalue lists (over the common length).
/// Differences are relative to `max(|a|, |b|, 1e-6·λ_max)`, so the (near-)zero eigenvalue of
/// each component is compared on the scale of the spectrum instead of its own rounding noise.
pub fn max_relative_difference(a: &[f64], b: &[f64]) -> f64 {
    let scale = a.iter().chain(b).fold(0.0_f64, |m, x| m.max(x.abs()));
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs() / x.abs().max(y.abs()).max(1e-6 * scale).max(f64::MIN_POSITIVE))
        .fold(0.0, f64::max)
}

fn read_json<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<T> {
    let text = fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))
}

fn fmt_ratio(ours: f64, peer: Option<f64>) -> String {
    match peer {
        Some(p) if p > 0.0 => format!("{:.2}", ours / p),
        _ => "–".into(),
    }
}

fn fmt_secs(s: Option<f64>) -> String {
    s.map_or_else(|| "–".into(), |s| format!("{s:.3}"))
}

/// The Markdown report of `DIR/shapeforest.json` against `DIR/peer.json`.
pub fn report(dir: &Path) -> Result<String> {
    let ours: OurResults = read_json(&dir.join("shapeforest.json"))?;
    let peer: PeerResults = read_json(&dir.join("peer.json"))?;
    let mut s = String::new();
    let versions: Vec<String> = peer.peer.iter().map(|(k, v)| format!("{k} {v}")).collect();
    let loads: Vec<String> =
        ours.load_average.iter().map(|l| format!("{:.2} {:.2} {:.2}", l[0], l[1], l[2])).collect();
    writeln!(
        s,
        "Load average (1, 5, 15 min) before and after shapeforest's runs: {} (a quiet machine is below 1).\n",
        if loads.is_empty() { "not recorded".to_string() } else { loads.join(" → ") }
    )?;
    writeln!(
        s,
        "K = {} eigenpairs on the unit-area mesh (scipy shift-inverts at σ = −0.01, shapeforest at an \
         interior shift of its own, see `SpectrumReport::shift`); times in seconds (best of {}), \
         {} rayon threads; peers: {}. Ratio = shapeforest / peer (below 1: shapeforest is faster).\n",
        ours.k,
        ours.repeat,
        ours.threads,
        if versions.is_empty() { "unknown versions".to_string() } else { versions.join(", ") }
    )?;
    writeln!(
        s,
        "| mesh | vertices | shapeforest eigen | scipy eigsh | ratio | shapeforest heat setup + 50 | \
         potpourri3d setup + 50 | ratio | max rel. Δλ | WKS (all vertices) |"
    )?;
    writeln!(s, "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")?;
    for m in &ours.meshes {
        let p = peer.meshes.iter().find(|p| p.name == m.name);
        let eigsh = p.map(|p| p.eigsh_s);
        let heat_ours = m.heat_setup_s + m.heat_solve_s;
        let heat_peer = p.and_then(|p| Some(p.heat_setup_s? + p.heat_solve_s?));
        let heat_peer_txt = match p.and_then(|p| Some((p.heat_setup_s?, p.heat_solve_s?))) {
            Some((a, b)) => format!("{a:.3} + {b:.3}"),
            None => "–".into(),
        };
        let dl = p.map_or_else(
            || "–".into(),
            |p| {
                if p.eigenvalues.len() != m.eigenvalues.len() {
                    format!("{} vs {} values", m.eigenvalues.len(), p.eigenvalues.len())
                } else {
                    format!("{:.1e}", max_relative_difference(&m.eigenvalues, &p.eigenvalues))
                }
            },
        );
        writeln!(
            s,
            "| {} | {} | {:.3} | {} | {} | {:.3} + {:.3} | {} | {} | {} | {:.3} |",
            m.name,
            m.vertices,
            m.eigen_s,
            fmt_secs(eigsh),
            fmt_ratio(m.eigen_s, eigsh),
            m.heat_setup_s,
            m.heat_solve_s,
            heat_peer_txt,
            fmt_ratio(heat_ours, heat_peer),
            dl,
            m.wks_s
        )?;
    }
    let missing: Vec<&str> = ours
        .meshes
        .iter()
        .filter(|m| !peer.meshes.iter().any(|p| p.name == m.name))
        .map(|m| m.name.as_str())
        .collect();
    if !missing.is_empty() {
        writeln!(s, "\nNo peer result for: {}.", missing.join(", "))?;
    }
    if let Some(f) = &ours.forest {
        writeln!(
            s,
            "\nForest: {} trees on {} shapes of {} vertices trained in {:.1} s (spectra {:.1} s), \
             model {:.1} MB; prediction on {} vertices {:.2} s.",
            f.n_trees,
            f.n_shapes,
            f.train_vertices,
            f.train_s,
            f.spectra_s,
            f.model_bytes as f64 / 1e6,
            f.predict_vertices,
            f.predict_s
        )?;
    }
    Ok(s)
}
