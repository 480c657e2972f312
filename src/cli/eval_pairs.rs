//! `shapeforest eval --pairs FILE` / `--protocol faust`: the field's pairwise protocol
//! ([`shapeforest::eval::pairs`]) on a class with ground truth.
//!
//! Prints the table (mean error ×100, the fractions within 0.05 and 0.1, strict and flips
//! allowed) and writes into `--out`: `pairs.csv` (per pair and method), `curves.csv`,
//! `curves.svg`, and `peer/pairs.json` (each pair as test = A, reference = B, with every
//! corresponded point, for `scripts/pyfm-peer.sh`).

use std::{fmt::Write as _, path::PathBuf};

use anyhow::{bail, Context, Result};
use rand::{seq::index::sample, SeedableRng};
use rand_chacha::ChaCha8Rng;
use shapeforest::{
    eval::{
        pairs::{run_pairs, PairMethod, PairsEvent, PairsParams, PairsReport},
        plot_curves_svg,
        protocol::ProtocolShape,
        write_curves_csv, ErrorSummary, PooledReport,
    },
    forest::RandomForest,
};

use super::eval::{bar, pct, write_file, EvalArgs};

/// Presets of the pairwise protocol.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Preset {
    /// FAUST remeshed: train on one shape of each of subjects 0–5, test on subjects 6–7.
    Faust,
}

/// `(training, pairs)` as shape indices.
type Plan = (Vec<usize>, Vec<(usize, usize)>);

fn index_of(shapes: &[ProtocolShape], name: &str, what: &str) -> Result<usize> {
    shapes
        .iter()
        .position(|s| s.name == name)
        .with_context(|| format!("{what}: no shape named `{name}` in the class"))
}

/// The FAUST preset: `tr_reg_0SP` is subject S, pose P.
fn faust_plan(shapes: &[ProtocolShape]) -> Result<Plan> {
    let subject_pose = |name: &str| -> Option<(usize, usize)> {
        let d = name.strip_prefix("tr_reg_")?;
        let n: usize = d.parse().ok()?;
        Some((n / 10, n % 10))
    };
    let mut training = Vec::new();
    for s in 0..6 {
        training.push(index_of(shapes, &format!("tr_reg_{:03}", s * 10 + s), "--protocol faust")?);
    }
    let tests: Vec<usize> = (0..shapes.len())
        .filter(|&i| subject_pose(&shapes[i].name).is_some_and(|(s, _)| s == 6 || s == 7))
        .collect();
    if tests.len() < 2 {
        bail!("--protocol faust needs the shapes of subjects 6 and 7 (tr_reg_060 … tr_reg_079) in the class");
    }
    let pairs =
        tests.iter().flat_map(|&a| tests.iter().filter(move |&&b| b != a).map(move |&b| (a, b))).collect();
    Ok((training, pairs))
}

/// Pairs from a file of lines `A B`; training shapes from `--train-shapes` or the first
/// `--train` shapes in no pair.
fn file_plan(args: &EvalArgs, path: &std::path::Path, shapes: &[ProtocolShape]) -> Result<Plan> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut pairs = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let toks: Vec<&str> = line.split_whitespace().collect();
        let [a, b] = toks.as_slice() else {
            bail!("{}: line {}: expected two shape names `A B`", path.display(), i + 1);
        };
        let at = format!("{}: line {}", path.display(), i + 1);
        let (a, b) = (index_of(shapes, a, &at)?, index_of(shapes, b, &at)?);
        if a == b {
            bail!("{at}: a pair of {} with itself", shapes[a].name);
        }
        pairs.push((a, b));
    }
    if pairs.is_empty() {
        bail!("{} lists no pair", path.display());
    }
    let training = if args.train_shapes.is_empty() {
        let in_pairs = |i: usize| pairs.iter().any(|&(a, b)| a == i || b == i);
        let t: Vec<usize> = (0..shapes.len()).filter(|&i| !in_pairs(i)).take(args.train).collect();
        if t.is_empty() {
            bail!("every shape of the class is in a pair: name the training shapes with --train-shapes");
        }
        t
    } else {
        args.train_shapes.iter().map(|n| index_of(shapes, n, "--train-shapes")).collect::<Result<_>>()?
    };
    Ok((training, pairs))
}

/// Runs the pairwise protocol for `shapeforest eval`.
pub fn run(
    args: &EvalArgs,
    shapes: &[ProtocolShape],
    files: &[PathBuf],
    symmetry: Option<&[usize]>,
    title: &str,
) -> Result<()> {
    let (training, mut pairs) = match (&args.pairs, args.protocol) {
        (Some(path), _) => file_plan(args, path, shapes)?,
        (None, Some(Preset::Faust)) => faust_plan(shapes)?,
        (None, None) => bail!("internal: no pairs"),
    };
    if let Some(m) = args.max_pairs.filter(|&m| m < pairs.len()) {
        let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
        let mut keep = sample(&mut rng, pairs.len(), m).into_vec();
        keep.sort_unstable();
        pairs = keep.into_iter().map(|i| pairs[i]).collect();
    }
    let names = |ix: &[usize]| ix.iter().map(|&i| shapes[i].name.as_str()).collect::<Vec<_>>().join(", ");
    println!(
        "{title}: pairwise protocol, {} pairs; training on {} ({} trees), reference {}; {} points per pair",
        pairs.len(),
        names(&training),
        super::eval::trees_text(args.trees),
        shapes[training[0]].name,
        shapes[0].truth.len()
    );
    let params = PairsParams {
        training,
        pairs,
        forest: RandomForest::params().n_trees(args.trees).seed(args.seed),
        cache_dir: (!args.no_cache).then(|| args.cache.clone()),
        regularizer: args.regularizer_params(true),
        zoomout: args.zoomout_params(),
        eval_distances: if args.fast_marching_eval {
            shapeforest::eval::pairs::EvalDistances::FastMarching
        } else {
            shapeforest::eval::pairs::EvalDistances::Heat
        },
        pair: shapeforest::regularizer::PairParams {
            radius: args.pair_radius,
            composed_weight: args.pair_composed_weight,
            refine_halves: !args.unrefined_halves,
            start: args.pair_start.into(),
        },
        ..PairsParams::default()
    };
    let pb = bar(args.quiet);
    let mut on_event = |e: PairsEvent<'_>| match e {
        PairsEvent::Stage(s) => pb.set_prefix(s),
        PairsEvent::ToReference { done, total, name } => {
            pb.set_length(total as u64);
            pb.set_position(done as u64);
            pb.set_message(name.to_string());
        }
        PairsEvent::PairDone { done, total, a, b } => {
            pb.set_length(total as u64);
            pb.set_position(done as u64);
            pb.set_message(format!("{a} → {b}"));
        }
    };
    let report = run_pairs(shapes, symmetry, &params, Some(&mut on_event))?;
    pb.finish_and_clear();
    print!("{}", format_table(&report));
    let t = &report.timings;
    println!(
        "time: spectra {:.1} s, training {:.1} s, {} shapes onto the reference {:.1} s, {} pairs {:.1} s \
         ({:.2} s each), evaluation {:.1} s",
        t.spectra_s,
        t.train_s,
        {
            let mut s: Vec<usize> = report.pairs.iter().flat_map(|p| [p.a, p.b]).collect();
            s.sort_unstable();
            s.dedup();
            s.len()
        },
        t.to_reference_s,
        report.pairs.len(),
        t.pairs_s,
        t.pairs_s / report.pairs.len().max(1) as f64,
        t.eval_s
    );
    write_outputs(args, shapes, files, symmetry, title, &report)?;
    println!("wrote pairs.csv, curves.csv, curves.svg, peer/pairs.json to {}", args.out.display());
    Ok(())
}

/// The table: per method, mean ×100 and fractions, strict and flips allowed.
fn format_table(report: &PairsReport) -> String {
    let mut s = String::new();
    let n: usize = report.pairs.iter().map(|p| p.methods.first().map_or(0, |m| m.strict.len())).sum();
    let _ = writeln!(
        s,
        "\naccuracy over {} pairs, {n} points (geodesic error on the target / √area)",
        report.pairs.len()
    );
    let _ = write!(s, "{:<12} | {:>9} {:>7} {:>7}", "method", "mean×100", "≤0.05", "≤0.1");
    if report.has_symmetry {
        let _ = write!(s, " | {:>13} {:>10} {:>9}", "sym mean×100", "sym ≤0.05", "sym ≤0.1");
    }
    s.push('\n');
    for m in PairMethod::ALL {
        let (st, sy) = report.summary(m);
        let _ = write!(
            s,
            "{:<10} | {:>9.2} {:>7} {:>7}",
            m.name(),
            100.0 * st.mean,
            pct(st.within_005),
            pct(st.within_010)
        );
        if let Some(y) = sy {
            let _ =
                write!(s, " | {:>13.2} {:>10} {:>9}", 100.0 * y.mean, pct(y.within_005), pct(y.within_010));
        }
        s.push('\n');
    }
    s
}

fn write_outputs(
    args: &EvalArgs,
    shapes: &[ProtocolShape],
    files: &[PathBuf],
    symmetry: Option<&[usize]>,
    title: &str,
    report: &PairsReport,
) -> Result<()> {
    let out = &args.out;
    let mut csv = String::from(
        "a,b,method,n,mean,within_005,within_010,median,sym_mean,sym_within_005,sym_within_010,pair_s\n",
    );
    for p in &report.pairs {
        for m in &p.methods {
            let st = ErrorSummary::of(&m.strict);
            let sy = m.symmetric.as_ref().map(|y| {
                let y = ErrorSummary::of(y);
                format!("{:.6},{:.6},{:.6}", y.mean, y.within_005, y.within_010)
            });
            let _ = writeln!(
                csv,
                "{},{},{},{},{:.6},{:.6},{:.6},{:.6},{},{:.3}",
                shapes[p.a].name,
                shapes[p.b].name,
                m.method.name(),
                st.n,
                st.mean,
                st.within_005,
                st.within_010,
                st.median,
                sy.unwrap_or_else(|| ",,".into()),
                p.pair_s
            );
        }
    }
    write_file(&out.join("pairs.csv"), &csv)?;
    if args.point_errors {
        // Every corresponded point of every pair: errors per method, strict and flips allowed.
        let mut pts = String::from("a,b,k,method,strict,sym,image,truth\n");
        for p in &report.pairs {
            for m in &p.methods {
                for (k, &e) in m.strict.iter().enumerate() {
                    let sym = m
                        .symmetric
                        .as_ref()
                        .and_then(|y| y.get(k))
                        .map_or(String::new(), |y| format!("{y:.6}"));
                    let _ = writeln!(
                        pts,
                        "{},{},{k},{},{e:.6},{sym},{},{}",
                        shapes[p.a].name,
                        shapes[p.b].name,
                        m.method.name(),
                        m.images.get(k).map_or(String::new(), |v| v.to_string()),
                        shapes[p.b].truth.get(k).map_or(String::new(), |v| v.to_string())
                    );
                }
            }
        }
        write_file(&out.join("points.csv"), &pts)?;
    }
    let curves = report.curves(100);
    write_curves_csv(&out.join("curves.csv"), &curves)?;
    plot_curves_svg(&out.join("curves.svg"), &format!("{title}: pairs, cumulative geodesic error"), &curves)?;

    // The pairs for the peer script: test = A, reference = B, every corresponded point.
    let peer = out.join("peer");
    std::fs::create_dir_all(&peer).with_context(|| format!("cannot create {}", peer.display()))?;
    let abs = |p: &PathBuf| std::fs::canonicalize(p).unwrap_or_else(|_| p.clone()).display().to_string();
    let list: Vec<serde_json::Value> = report
        .pairs
        .iter()
        .map(|p| {
            let (a, b) = (&shapes[p.a], &shapes[p.b]);
            serde_json::json!({
                "test": a.name,
                "reference": b.name,
                "test_mesh": abs(&files[p.a]),
                "reference_mesh": abs(&files[p.b]),
                "eval_test_vertices": a.truth,
                "eval_reference_vertices": b.truth,
                "eval_reference_mirror_vertices":
                    symmetry.map(|sym| sym.iter().map(|&k| b.truth[k]).collect::<Vec<_>>()),
            })
        })
        .collect();
    let json = serde_json::json!({ "pairs": list, "reference_symmetry": null });
    write_file(&peer.join("pairs.json"), &(serde_json::to_string(&json)? + "\n"))?;
    Ok(())
}
