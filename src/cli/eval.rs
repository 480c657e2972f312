//! `shapeforest eval`: the paper's protocol on a class of shapes with ground truth.
//!
//! Prints a table (method × {≤0.05, ≤0.1, mean}, strict and symmetric where a symmetry map
//! exists) and per-stage timings, and writes into `--out`: `results.csv` (per test shape and
//! method), `timings.csv` (per test shape and stage), `curves.csv` and `curves.svg` (cumulative
//! curves, one per method), and `peer/pairs.json` (the test/reference pairs with their mesh
//! files and the evaluated vertices, for `scripts/pyfm_peer.py`).

use std::{
    fmt::Write as _,
    path::{Path, PathBuf},
    sync::Arc,
};

use anyhow::{bail, Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use shapeforest::{
    eval::{
        plot_curves_svg,
        protocol::{run_protocol, Method, ProtocolEvent, ProtocolParams, ProtocolReport, ProtocolShape},
        write_curves_csv, ErrorSummary,
    },
    forest::RandomForest,
    mesh::{read_mesh, write_mesh},
    synth::{creature_family, CreatureParams},
};

/// Arguments of `shapeforest eval`.
#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Folder of OFF meshes of one class sharing vertex indexing (ground truth by index).
    #[arg(long, conflicts_with = "synthetic", required_unless_present = "synthetic")]
    pub class: Option<PathBuf>,
    /// Only files named PREFIX<number>.off (or PREFIX.off) in --class, e.g. `cat`.
    #[arg(long)]
    pub prefix: Option<String>,
    /// Use the built-in synthetic creature family instead of files.
    #[arg(long)]
    pub synthetic: bool,
    /// Vertices per synthetic shape.
    #[arg(long, default_value_t = 5000)]
    pub vertices: usize,
    /// Shapes in the synthetic family.
    #[arg(long, default_value_t = 8)]
    pub shapes: usize,
    /// Training shapes per test shape.
    #[arg(long, default_value_t = 6)]
    pub train: usize,
    /// At most this many test shapes.
    #[arg(long)]
    pub tests: Option<usize>,
    /// One training set for all tests (faster).
    #[arg(long)]
    pub train_once: bool,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Trees per forest.
    #[arg(long, default_value_t = 15)]
    pub trees: usize,
    /// Evaluated ground-truth points per test shape.
    #[arg(long, default_value_t = 1000)]
    pub eval_points: usize,
    /// Output folder.
    #[arg(long, default_value = "shapeforest-eval")]
    pub out: PathBuf,
    /// Spectrum cache folder.
    #[arg(long, default_value = "shapeforest-data/spectra")]
    pub cache: PathBuf,
    /// Do not use the spectrum cache.
    #[arg(long)]
    pub no_cache: bool,
    /// No progress bars.
    #[arg(long)]
    pub quiet: bool,
}

/// The class of shapes to evaluate: shapes, mesh files (for the peer script), symmetry.
struct Class {
    shapes: Vec<ProtocolShape>,
    files: Vec<PathBuf>,
    symmetry: Option<Vec<usize>>,
    title: String,
}

/// Numeric suffix of `stem` after `prefix` (`None` when it is not `prefix` + digits).
fn suffix_number(stem: &str, prefix: &str) -> Option<u64> {
    let rest = stem.strip_prefix(prefix)?;
    if rest.is_empty() {
        return Some(0);
    }
    if rest.chars().all(|c| c.is_ascii_digit()) {
        rest.parse().ok().map(|n: u64| n + 1)
    } else {
        None
    }
}

fn load_class(dir: &Path, prefix: Option<&str>) -> Result<Class> {
    let entries =
        std::fs::read_dir(dir).with_context(|| format!("cannot read the class folder {}", dir.display()))?;
    let mut files: Vec<(u64, String, PathBuf)> = Vec::new();
    for e in entries {
        let path = e.with_context(|| format!("cannot list {}", dir.display()))?.path();
        if path.extension().and_then(|e| e.to_str()).map(|e| e.eq_ignore_ascii_case("off")) != Some(true) {
            continue;
        }
        let Some(stem) = path.file_stem().and_then(|s| s.to_str()).map(str::to_string) else { continue };
        match prefix {
            Some(p) => {
                if let Some(n) = suffix_number(&stem, p) {
                    files.push((n, stem, path));
                }
            }
            None => files.push((0, stem, path)),
        }
    }
    files.sort();
    if files.len() < 2 {
        bail!(
            "{} holds {} OFF mesh(es){}; the protocol needs at least 2",
            dir.display(),
            files.len(),
            prefix.map(|p| format!(" named {p}<number>.off")).unwrap_or_default()
        );
    }
    let mut shapes: Vec<ProtocolShape> = Vec::with_capacity(files.len());
    for (_, stem, path) in &files {
        let mesh = read_mesh(path).with_context(|| format!("cannot read mesh {}", path.display()))?;
        if let Some(first) = shapes.first() {
            if mesh.n_vertices() != first.mesh.n_vertices() {
                bail!(
                    "{} has {} vertices but {} has {}: a class needs common vertex indexing",
                    path.display(),
                    mesh.n_vertices(),
                    files[0].2.display(),
                    first.mesh.n_vertices()
                );
            }
        }
        shapes.push(ProtocolShape::identity(stem.clone(), Arc::new(mesh)));
    }
    let title = prefix.map(str::to_string).unwrap_or_else(|| dir.display().to_string());
    Ok(Class { shapes, files: files.into_iter().map(|f| f.2).collect(), symmetry: None, title })
}

fn synthetic_class(args: &EvalArgs, out: &Path) -> Result<Class> {
    let params = CreatureParams { target_vertices: args.vertices, seed: args.seed, ..Default::default() };
    let family = creature_family(&params, args.shapes).context("cannot build the synthetic family")?;
    let dir = out.join("meshes");
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut shapes = Vec::new();
    let mut files = Vec::new();
    for (i, m) in family.shapes.into_iter().enumerate() {
        let name = format!("creature{i}");
        let path = dir.join(format!("{name}.off"));
        write_mesh(&path, &m).with_context(|| format!("cannot write {}", path.display()))?;
        files.push(path);
        shapes.push(ProtocolShape::identity(name, Arc::new(m)));
    }
    let n = shapes[0].mesh.n_vertices();
    Ok(Class {
        shapes,
        files,
        symmetry: Some(family.symmetry),
        title: format!("synthetic creatures, {n} vertices"),
    })
}

fn bar(quiet: bool) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(0);
    if let Ok(style) =
        ProgressStyle::with_template("{prefix:>10} [{bar:30}] {pos}/{len} {elapsed_precise} {msg}")
    {
        pb.set_style(style.progress_chars("=> "));
    }
    pb
}

/// Runs `shapeforest eval`.
pub fn run(args: EvalArgs) -> Result<()> {
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create the output folder {}", args.out.display()))?;
    let class = match &args.class {
        Some(dir) => load_class(dir, args.prefix.as_deref())?,
        None => synthetic_class(&args, &args.out)?,
    };
    let params = ProtocolParams {
        n_train: args.train,
        max_tests: args.tests,
        train_once: args.train_once,
        seed: args.seed,
        eval_points: args.eval_points,
        forest: RandomForest::params().n_trees(args.trees).seed(args.seed),
        cache_dir: (!args.no_cache).then(|| args.cache.clone()),
        ..ProtocolParams::default()
    };
    let n = class.shapes[0].mesh.n_vertices();
    println!(
        "{}: {} shapes × {n} vertices; training on {} shape(s){}, {} trees, {} evaluation points",
        class.title,
        class.shapes.len(),
        args.train.min(class.shapes.len() - 1),
        if args.train_once { " (one training set)" } else { " per test" },
        args.trees,
        args.eval_points.min(n)
    );
    if class.symmetry.is_none() {
        println!("no dense symmetry map for this class: strict errors only");
    }
    let pb = bar(args.quiet);
    let mut on_event = |e: ProtocolEvent<'_>| match e {
        ProtocolEvent::Spectrum { done, total, name } => {
            pb.set_prefix("spectra");
            pb.set_length(total as u64);
            pb.set_position(done as u64);
            pb.set_message(name.to_string());
        }
        ProtocolEvent::Stage { test, stage } => {
            pb.set_prefix("tests");
            pb.set_message(format!("{test}: {stage}"));
        }
        ProtocolEvent::TestDone { done, total, name } => {
            pb.set_prefix("tests");
            pb.set_length(total as u64);
            pb.set_position(done as u64);
            pb.set_message(format!("{name} done"));
        }
    };
    let report = run_protocol(&class.shapes, class.symmetry.as_deref(), &params, Some(&mut on_event))?;
    pb.finish_and_clear();

    print!("{}", format_table(&report));
    print!("{}", format_timings(&report));
    write_outputs(&args.out, &class, &report, params.curve_steps)?;
    println!(
        "wrote results.csv, timings.csv, curves.csv, curves.svg, peer/pairs.json to {}",
        args.out.display()
    );
    Ok(())
}

fn pct(x: f64) -> String {
    format!("{:5.1}%", 100.0 * x)
}

/// The accuracy table, pooled over test shapes.
fn format_table(report: &ProtocolReport) -> String {
    let mut s = String::new();
    let n_points: usize = report.tests.iter().map(|t| t.methods.first().map_or(0, |m| m.strict.len())).sum();
    let _ = writeln!(
        s,
        "\naccuracy over {} test shape(s), {} points (geodesic error / √area)",
        report.tests.len(),
        n_points
    );
    let _ = write!(s, "{:<13} | {:>7} {:>7} {:>7}", "method", "≤0.05", "≤0.1", "mean");
    if report.has_symmetry {
        let _ = write!(s, " | {:>11} {:>10} {:>8}", "sym ≤0.05", "sym ≤0.1", "sym mean");
    }
    s.push('\n');
    for m in Method::ALL {
        let (st, sy) = report.summary(m);
        let _ = write!(
            s,
            "{:<13} | {:>7} {:>7} {:>7.4}",
            m.name(),
            pct(st.within_005),
            pct(st.within_010),
            st.mean
        );
        if let Some(y) = sy {
            let _ = write!(s, " | {:>11} {:>10} {:>8.4}", pct(y.within_005), pct(y.within_010), y.mean);
        }
        s.push('\n');
    }
    s
}

/// Per-stage timings per test shape.
fn format_timings(report: &ProtocolReport) -> String {
    let mut s = String::new();
    let spectra: f64 = report.spectrum_s.iter().sum();
    let _ = writeln!(s, "\nspectra (100 eigenpairs, cache hits are fast): {spectra:.2} s in all");
    let _ = writeln!(
        s,
        "{:<14} {:>7} {:>7} {:>7} {:>7} {:>8} {:>7} {:>8} {:>7}",
        "test", "train", "knn-fit", "prepare", "predict", "regular.", "knn", "knn-reg", "eval-gt"
    );
    for t in &report.tests {
        let x = &t.timings;
        let _ = writeln!(
            s,
            "{:<14} {:>7.2} {:>7.2} {:>7.2} {:>7.2} {:>8.2} {:>7.2} {:>8.2} {:>7.2}",
            report.shape_names[t.test],
            x.train_s,
            x.knn_fit_s,
            x.prepare_s,
            x.predict_s,
            x.regularize_s,
            x.knn_predict_s,
            x.knn_regularize_s,
            x.eval_fields_s
        );
    }
    s
}

fn summary_cols(s: Option<ErrorSummary>) -> String {
    match s {
        Some(s) => format!("{:.6},{:.6},{:.6},{:.6}", s.within_005, s.within_010, s.mean, s.median),
        None => ",,,".into(),
    }
}

fn write_file(path: &Path, text: &str) -> Result<()> {
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

fn json_list(v: &[usize]) -> String {
    let items: Vec<String> = v.iter().map(|x| x.to_string()).collect();
    format!("[{}]", items.join(","))
}

fn json_str(s: &str) -> String {
    let mut out = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if (c as u32) < 0x20 => {
                let _ = write!(out, "\\u{:04x}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

fn write_outputs(out: &Path, class: &Class, report: &ProtocolReport, steps: usize) -> Result<()> {
    let mut csv = String::from(
        "test,reference,method,n,within_005,within_010,mean,median,sym_within_005,sym_within_010,sym_mean,sym_median\n",
    );
    for t in &report.tests {
        for m in &t.methods {
            let st = ErrorSummary::of(&m.strict);
            let sy = m.symmetric.as_ref().map(|y| ErrorSummary::of(y));
            let _ = writeln!(
                csv,
                "{},{},{},{},{},{}",
                report.shape_names[t.test],
                report.shape_names[t.reference],
                m.method.name(),
                st.n,
                summary_cols(Some(st)),
                summary_cols(sy)
            );
        }
    }
    write_file(&out.join("results.csv"), &csv)?;

    let mut tcsv = String::from(
        "test,reference,forest_reused,mean_support,n_matches,orientation_score,spectrum_s,train_s,knn_fit_s,prepare_s,predict_s,regularize_s,knn_predict_s,knn_regularize_s,eval_fields_s\n",
    );
    for t in &report.tests {
        let x = &t.timings;
        let _ = writeln!(
            tcsv,
            "{},{},{},{:.3},{},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4}",
            report.shape_names[t.test],
            report.shape_names[t.reference],
            t.forest_reused,
            t.mean_support,
            t.n_matches,
            t.orientation_score,
            report.spectrum_s[t.test],
            x.train_s,
            x.knn_fit_s,
            x.prepare_s,
            x.predict_s,
            x.regularize_s,
            x.knn_predict_s,
            x.knn_regularize_s,
            x.eval_fields_s
        );
    }
    write_file(&out.join("timings.csv"), &tcsv)?;

    let curves = report.curves(steps);
    write_curves_csv(&out.join("curves.csv"), &curves)?;
    plot_curves_svg(
        &out.join("curves.svg"),
        &format!("{}: cumulative geodesic error", class.title),
        &curves,
    )?;

    // Pairs and evaluation points for the peer script.
    let peer = out.join("peer");
    std::fs::create_dir_all(&peer).with_context(|| format!("cannot create {}", peer.display()))?;
    let abs = |p: &Path| std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf());
    let mut json = String::from("{\n  \"pairs\": [\n");
    for (i, t) in report.tests.iter().enumerate() {
        let test = &class.shapes[t.test];
        let reference = &class.shapes[t.reference];
        let ev_test: Vec<usize> = report.eval_labels.iter().map(|&k| test.truth[k]).collect();
        let ev_ref: Vec<usize> = report.eval_labels.iter().map(|&k| reference.truth[k]).collect();
        let _ = write!(
            json,
            "    {{\"test\": {}, \"reference\": {}, \"test_mesh\": {}, \"reference_mesh\": {},\n     \"eval_test_vertices\": {},\n     \"eval_reference_vertices\": {}}}{}\n",
            json_str(&test.name),
            json_str(&reference.name),
            json_str(&abs(&class.files[t.test]).display().to_string()),
            json_str(&abs(&class.files[t.reference]).display().to_string()),
            json_list(&ev_test),
            json_list(&ev_ref),
            if i + 1 < report.tests.len() { "," } else { "" }
        );
    }
    json.push_str("  ],\n");
    match &class.symmetry {
        // Identity truth tables: the label symmetry is the reference's vertex symmetry.
        Some(sym) => {
            let _ = writeln!(json, "  \"reference_symmetry\": {}", json_list(sym));
        }
        None => json.push_str("  \"reference_symmetry\": null\n"),
    }
    json.push_str("}\n");
    write_file(&peer.join("pairs.json"), &json)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn class_file_names() {
        assert_eq!(suffix_number("cat10", "cat"), Some(11));
        assert_eq!(suffix_number("cat", "cat"), Some(0));
        assert_eq!(suffix_number("centaur0", "cat"), None);
        assert_eq!(suffix_number("catx", "cat"), None);
    }

    #[test]
    fn json_strings_are_escaped() {
        assert_eq!(json_str("a\"b\\c"), "\"a\\\"b\\\\c\"");
    }
}
