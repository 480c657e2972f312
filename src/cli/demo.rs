//! `shapeforest demo`: the watch-folder daemon end to end on built-in data. It starts the daemon
//! pipeline (pipelines/watch.toml) on a fresh folder, drops labelled synthetic creatures into
//! `labeled/` and waits for the model, then drops held-out poses (and one broken file) into
//! `incoming/`, waits for the results, stops the daemon as Ctrl-C would, and scores the maps it
//! wrote against the known ground truth.

use std::{
    path::{Path, PathBuf},
    sync::Arc,
    thread,
    time::{Duration, Instant},
};

use anyhow::{anyhow, bail, Context, Result};
use clap::Args;
use shapeforest::{
    eval::{geodesic_errors, ErrorSummary},
    forest::labels_identity,
    geodesic::HeatParams,
    mesh::{perturb, read_mesh, write_mesh, Mesh, Perturbation},
    pipeline::{
        daemon::run_spec, label_map_text, latest_manifest, DataDir, PipelineSpec, RunOptions, Shutdown,
    },
    regularizer::PreparedShape,
    spectral::{SpectrumCache, SpectrumParams},
    synth::{creature_family, CreatureParams},
};

use super::common::progress;

/// The daemon's pipeline, built in so the demo runs from anywhere.
const WATCH: &str = include_str!("../../pipelines/watch.toml");
/// Marks a folder as the demo's own, so a later run may clear it.
const MARKER: &str = ".shapeforest-demo";

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Vertices per synthetic shape.
    #[arg(long, default_value_t = 5000)]
    pub vertices: usize,
    /// Labelled shapes to learn from (the paper uses 6).
    #[arg(long, default_value_t = 6)]
    pub train: usize,
    /// Held-out scans to match.
    #[arg(long, default_value_t = 2)]
    pub test: usize,
    /// Seed of the shape family.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// The daemon's data folder (cleared first if an earlier demo made it).
    #[arg(long, default_value = "shapeforest-demo")]
    pub out: PathBuf,
    /// Give up waiting for the daemon after this many seconds.
    #[arg(long, default_value_t = 900)]
    pub timeout: u64,
}

fn fresh_folder(dir: &Path) -> Result<()> {
    if dir.exists() {
        let empty = std::fs::read_dir(dir).map(|mut d| d.next().is_none()).unwrap_or(false);
        if !empty && !dir.join(MARKER).exists() {
            bail!("{} exists and was not made by the demo; choose another --out", dir.display());
        }
        std::fs::remove_dir_all(dir).with_context(|| format!("cannot clear {}", dir.display()))?;
    }
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    std::fs::write(dir.join(MARKER), "made by `shapeforest demo`; removed by the next demo run\n")?;
    Ok(())
}

/// Writes a file into a watched folder the way a careful copier does: aside, then renamed in.
fn drop_file(
    staging: &Path,
    target_dir: &Path,
    name: &str,
    write: impl FnOnce(&Path) -> Result<()>,
) -> Result<()> {
    let tmp = staging.join(name);
    write(&tmp)?;
    std::fs::rename(&tmp, target_dir.join(name)).with_context(|| format!("cannot move {name} into place"))
}

/// Waits until `done()` holds, ticking a progress bar with `count()`; fails if the daemon
/// stopped or the time is up.
fn wait_for(
    what: &str,
    total: u64,
    deadline: Instant,
    daemon: &thread::JoinHandle<
        std::result::Result<shapeforest::pipeline::PipelineReport, shapeforest::pipeline::Error>,
    >,
    mut count: impl FnMut() -> u64,
) -> Result<()> {
    let bar = progress(total, what);
    loop {
        let n = count();
        bar.set_position(n.min(total));
        if n >= total {
            bar.finish_and_clear();
            return Ok(());
        }
        if daemon.is_finished() {
            bar.abandon();
            bail!("the daemon stopped while {what}");
        }
        if Instant::now() > deadline {
            bar.abandon();
            bail!("timed out while {what}");
        }
        thread::sleep(Duration::from_millis(100));
    }
}

pub fn run(args: DemoArgs) -> Result<()> {
    let started = Instant::now();
    if args.train == 0 || args.test == 0 {
        bail!("--train and --test must be at least 1");
    }
    fresh_folder(&args.out)?;
    let data = DataDir::new(&args.out);
    println!(
        "shapeforest demo: the watch-folder daemon on {} — {} labelled + {} held-out synthetic creatures of ~{} vertices",
        args.out.display(),
        args.train,
        args.test,
        args.vertices
    );
    let t0 = Instant::now();
    let fam = creature_family(
        &CreatureParams { target_vertices: args.vertices, seed: args.seed, ..Default::default() },
        args.train + args.test,
    )?;
    let n = fam.template.n_vertices();
    println!("  1. built {} shapes of {n} vertices ({:.1} s)", fam.shapes.len(), t0.elapsed().as_secs_f64());

    let spec = PipelineSpec::from_toml(WATCH, "built-in watch.toml")?;
    let shutdown = Shutdown::new();
    let daemon = {
        let (spec, out, sd) = (spec.clone(), args.out.clone(), shutdown.clone());
        let options = RunOptions {
            handle_signals: true,
            on_signal: Some(super::run::on_signal),
            after_job: super::run::long_running_allocator(),
            ..Default::default()
        };
        thread::spawn(move || run_spec(&spec, Some(&out), options, Some(sd), |_| Ok(())))
    };
    let deadline = Instant::now() + Duration::from_secs(args.timeout);
    while !data.labeled().is_dir() || !data.incoming().is_dir() {
        if daemon.is_finished() {
            let r = daemon.join().map_err(|_| anyhow!("the daemon panicked"))?;
            bail!("the daemon stopped at start: {}", r.err().map(|e| e.to_string()).unwrap_or_default());
        }
        thread::sleep(Duration::from_millis(20));
    }
    println!("  2. daemon started (pipelines/watch.toml): watching incoming/ and labeled/");

    let staging = args.out.join(".staging");
    std::fs::create_dir_all(&staging)?;
    let labels = label_map_text(&labels_identity(n));
    let t0 = Instant::now();
    for (i, mesh) in fam.shapes.iter().enumerate().take(args.train) {
        drop_file(&staging, &data.labeled(), &format!("creature{i}.labels"), |p| {
            Ok(std::fs::write(p, &labels)?)
        })?;
        drop_file(&staging, &data.labeled(), &format!("creature{i}.off"), |p| Ok(write_mesh(p, mesh)?))?;
    }
    let train = args.train as u64;
    wait_for("learning", train, deadline, &daemon, || {
        latest_manifest(&data.models()).map_or(0, |m| m.training_shapes.len() as u64)
    })?;
    let manifest = latest_manifest(&data.models()).ok_or_else(|| anyhow!("no model manifest"))?;
    println!(
        "  3. dropped {} labelled shapes into labeled/ → model v{} ({} trees, reference `{}`) in {:.1} s",
        args.train,
        manifest.version,
        manifest.n_trees,
        manifest.reference,
        t0.elapsed().as_secs_f64()
    );

    let t0 = Instant::now();
    // The held-out poses as scans, and the last one once more with five holes (a scan as they
    // really arrive; ground truth through the perturbation's vertex map).
    let mut scans: Vec<(String, Mesh, Option<Vec<usize>>)> = (args.train..args.train + args.test)
        .map(|t| (format!("scan-creature{t}"), fam.shapes[t].clone(), None))
        .collect();
    if args.test > 0 {
        let last = args.train + args.test - 1;
        let holed = perturb(&fam.shapes[last], &[Perturbation::Holes { count: 5, radius: 0.03 }], 1)?;
        scans.push((format!("scan-creature{last}-holed"), holed.mesh, Some(holed.kept)));
    }
    let names: Vec<String> = scans.iter().map(|s| s.0.clone()).collect();
    for (name, mesh, _) in &scans {
        drop_file(&staging, &data.incoming(), &format!("{name}.off"), |p| Ok(write_mesh(p, mesh)?))?;
    }
    drop_file(&staging, &data.incoming(), "broken-scan.off", |p| {
        Ok(std::fs::write(p, "OFF\n3 1 0\n0 0 0\n1 0 0\n")?)
    })?;
    let total = names.len() as u64 + 1;
    wait_for("matching", total, deadline, &daemon, || {
        let matched = names
            .iter()
            .filter(|s| data.matched().join(s).join(format!("{s}.report.json")).is_file())
            .count();
        matched as u64 + u64::from(data.rejected().join("broken-scan.error.json").is_file())
    })?;
    println!(
        "  4. dropped {} scans (one with five holes) and one broken file into incoming/ → {} matched, 1 rejected, in {:.1} s",
        names.len(),
        names.len(),
        t0.elapsed().as_secs_f64()
    );

    shutdown.trigger();
    let report = daemon.join().map_err(|_| anyhow!("the daemon panicked"))?.map_err(|e| anyhow!(e))?;
    println!("  5. daemon stopped (as on Ctrl-C); per-actor metrics:");
    for line in report.table().lines() {
        println!("     {line}");
    }

    // Score the written maps against the ground truth (the family shares one vertex indexing).
    let reference_file = data.training().join(format!("{}.off", manifest.reference));
    let reference = Arc::new(read_mesh(&reference_file)?);
    let cache = SpectrumCache::new(data.cache())?;
    let spectrum = Arc::new(cache.get_or_compute(&reference, &SpectrumParams::new(100))?);
    let prepared = PreparedShape::new(reference.clone(), spectrum, HeatParams::default())?;
    let evaluated: Vec<usize> = (0..n).step_by(5).collect();
    let fields = prepared.heat.distances_from_many(&evaluated)?;
    let area = reference.surface_area();
    println!(
        "\n  accuracy of the daemon's maps (geodesic error / √area, {} points per scan):",
        evaluated.len()
    );
    println!(
        "  {:<24} {:>8} {:>8} {:>7} {:>14} {:>9}",
        "scan", "≤ 0.05", "≤ 0.10", "mean", "sym. ≤ 0.05", "latency"
    );
    let mut pooled = (Vec::new(), Vec::new());
    for (name, scan, kept) in &scans {
        let dir = data.matched().join(name);
        let text = std::fs::read_to_string(dir.join(format!("{name}.map.txt")))?;
        let map: Vec<usize> = text
            .lines()
            .filter(|l| !l.starts_with('#'))
            .map(|l| l.trim().parse::<usize>())
            .collect::<std::result::Result<_, _>>()
            .context("bad map file")?;
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join(format!("{name}.report.json")))?)?;
        // The evaluated points the scan has, as scan vertices, and their distance fields.
        let (columns, on_scan): (Vec<usize>, Vec<usize>) = match kept {
            None => evaluated.iter().copied().enumerate().unzip(),
            Some(kept) => {
                let mut index = vec![None; n];
                for (new, &old) in kept.iter().enumerate() {
                    index[old] = Some(new);
                }
                evaluated.iter().enumerate().filter_map(|(j, &v)| index[v].map(|s| (j, s))).unzip()
            }
        };
        let scan_fields = faer::Mat::from_fn(fields.nrows(), columns.len(), |r, c| fields[(r, columns[c])]);
        let (strict, sym) = geodesic_errors(&map, &on_scan, scan_fields.as_ref(), Some(&fam.symmetry), area)?;
        let sym = sym.unwrap_or_default();
        super::visual::write_scored_view(
            &dir,
            name,
            scan,
            &reference,
            &manifest.reference,
            &map,
            &on_scan,
            &strict,
        )?;
        let (s, y) = (ErrorSummary::of(&strict), ErrorSummary::of(&sym));
        println!(
            "  {:<24} {:>7.1}% {:>7.1}% {:>7.3} {:>13.1}% {:>8.1}s",
            name,
            100.0 * s.within_005,
            100.0 * s.within_010,
            s.mean,
            100.0 * y.within_005,
            report["latency_s"].as_f64().unwrap_or(f64::NAN)
        );
        pooled.0.extend(strict);
        pooled.1.extend(sym);
    }
    let (s, y) = (ErrorSummary::of(&pooled.0), ErrorSummary::of(&pooled.1));
    println!(
        "  {:<24} {:>7.1}% {:>7.1}% {:>7.3} {:>13.1}%",
        "all",
        100.0 * s.within_005,
        100.0 * s.within_010,
        s.mean,
        100.0 * y.within_005
    );
    let _ = std::fs::remove_dir_all(&staging);
    println!("\n  outputs in {}:", args.out.display());
    println!("    matched/scan-creatureN/  map.txt (line i = reference vertex of scan vertex i), colored.ply, report.json, the scan");
    println!("                             .png snapshot and view.html: open it in a browser to see the two coloured shapes");
    println!(
        "    matched/reference-{}.colored.ply  the reference, coloured like the scans",
        manifest.reference
    );
    println!("    rejected/broken-scan.off + broken-scan.error.json  the broken file and why");
    println!("    models/model-v{:06}.sfm  the model; training/ its labelled shapes", manifest.version);
    println!("  run the daemon yourself: shapeforest watch --data-dir {}", args.out.display());
    println!("  compare with the WKS baseline and the raw forest: shapeforest eval --synthetic");
    if let Some(first) = names.first() {
        println!(
            "  look at a result: open {} in a browser",
            data.matched().join(first).join("view.html").display()
        );
    }
    println!("  total {:.1} s", started.elapsed().as_secs_f64());
    Ok(())
}
