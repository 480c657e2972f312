//! `shapeforest view RESULT_DIR`: the interactive `view.html` of a match result.
//!
//! RESULT_DIR is a folder written by `shapeforest match` (`SCAN.map.txt`, `SCAN.colored.ply`,
//! `REF.colored.ply`, `SCAN.report.json`; with `--to B`, `SCAN.to.B.map.txt` and
//! `B.colored.ply`) or a daemon's `matched/NAME/` (the reference is
//! `../reference-REF.colored.ply`). The coloured PLY files carry the geometry (vertex order is
//! that of the inputs). An optional `SCAN.errors.csv` (`vertex,error` lines, errors normalised
//! by √area of the reference) adds the error heat map and the cumulative curve.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;
use shapeforest::{
    mesh::read_mesh,
    viz::{PointErrors, ViewPair},
};

use super::visual::write_view;

/// Arguments of `shapeforest view`.
#[derive(Debug, Args)]
pub struct ViewArgs {
    /// A `shapeforest match` output folder or a daemon's `matched/NAME/` folder.
    pub result_dir: PathBuf,
    /// The page to write (default RESULT_DIR/view.html; with several maps in the folder,
    /// RESULT_DIR/SCAN.view.html each).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Reads a map file: `#` comment lines, then one reference vertex per line.
pub fn read_map(path: &Path, n_scan: usize, n_ref: usize) -> Result<Vec<usize>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut map = Vec::with_capacity(n_scan);
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.starts_with('#') || line.is_empty() {
            continue;
        }
        match line.parse::<usize>() {
            Ok(v) if v < n_ref => map.push(v),
            Ok(v) => bail!(
                "{} line {}: vertex {v} is outside the reference's {n_ref} vertices",
                path.display(),
                i + 1
            ),
            Err(_) => bail!("{} line {}: not a vertex index", path.display(), i + 1),
        }
    }
    if map.len() != n_scan {
        bail!("{} has {} entries but the scan has {n_scan} vertices", path.display(), map.len());
    }
    Ok(map)
}

fn read_errors(path: &Path, n_scan: usize) -> Result<(Vec<usize>, Vec<f64>)> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let (mut vertices, mut errors) = (Vec::new(), Vec::new());
    for (i, line) in text.lines().enumerate() {
        if i == 0 && line.starts_with("vertex") || line.trim().is_empty() {
            continue;
        }
        let bad = || format!("{} line {}: expected `vertex,error`", path.display(), i + 1);
        let (v, e) = line.split_once(',').with_context(bad)?;
        let v: usize = v.trim().parse().ok().filter(|&v| v < n_scan).with_context(bad)?;
        let e: f64 = e.trim().parse().ok().filter(|e: &f64| e.is_finite() && *e >= 0.0).with_context(bad)?;
        vertices.push(v);
        errors.push(e);
    }
    Ok((vertices, errors))
}

/// The reference of a result folder: the daemon's `../reference-REF.colored.ply`, or the
/// `REF.colored.ply` beside the map (named by the report's `reference`).
fn find_reference(dir: &Path, scan_name: &str) -> Result<PathBuf> {
    let report_path = dir.join(format!("{scan_name}.report.json"));
    let report: serde_json::Value = std::fs::read_to_string(&report_path)
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
        .with_context(|| format!("cannot read {} (it names the reference)", report_path.display()))?;
    let reference = report["reference"].as_str().unwrap_or_default();
    let stem = super::common::shape_name(Path::new(reference));
    let mut places = Vec::new();
    if let Some(parent) = dir.parent() {
        places.push(parent.join(format!("reference-{stem}.colored.ply")));
    }
    places.push(dir.join(format!("{stem}.colored.ply")));
    places.push(PathBuf::from(reference));
    places.into_iter().find(|p| p.is_file()).with_context(|| {
        format!(
            "cannot find the reference `{reference}` of {}: looked for reference-{stem}.colored.ply beside \
             the folder and {stem}.colored.ply in it",
            dir.display()
        )
    })
}

/// Runs `shapeforest view`.
pub fn run(args: ViewArgs) -> Result<()> {
    let dir = &args.result_dir;
    let mut maps: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("cannot read the folder {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.ends_with(".map.txt")))
        .collect();
    maps.sort();
    if maps.is_empty() {
        bail!(
            "no SCAN.map.txt in {}: give a folder written by `shapeforest match` or a daemon's matched/NAME/",
            dir.display()
        );
    }
    for map_path in &maps {
        let file = map_path.file_name().and_then(|n| n.to_str()).unwrap_or_default();
        let name = file.trim_end_matches(".map.txt");
        // `match --to B` writes SCAN.to.B.map.txt: a map onto B, whose coloured mesh is beside it.
        let (name, onto) = match name.split_once(".to.") {
            Some((scan, onto)) => (scan, Some(onto)),
            None => (name, None),
        };
        let scan_path = dir.join(format!("{name}.colored.ply"));
        let scan =
            read_mesh(&scan_path).with_context(|| format!("cannot read mesh {}", scan_path.display()))?;
        let ref_path = match onto {
            Some(b) => dir.join(format!("{b}.colored.ply")),
            None => find_reference(dir, name)?,
        };
        let reference =
            read_mesh(&ref_path).with_context(|| format!("cannot read mesh {}", ref_path.display()))?;
        let map = read_map(map_path, scan.n_vertices(), reference.n_vertices())?;
        let errors_path = dir.join(format!("{name}.errors.csv"));
        let errors =
            errors_path.is_file().then(|| read_errors(&errors_path, scan.n_vertices())).transpose()?;
        let ref_name = super::common::shape_name(&ref_path);
        let ref_name = ref_name.trim_start_matches("reference-").trim_end_matches(".colored");
        let pair = ViewPair {
            scan: &scan,
            scan_name: name,
            reference: &reference,
            reference_name: ref_name,
            map: &map,
            errors: errors.as_ref().map(|(v, e)| PointErrors { vertices: v, errors: e }),
        };
        let out = match &args.out {
            Some(p) if maps.len() == 1 => p.clone(),
            _ if maps.len() == 1 => dir.join("view.html"),
            _ => dir.join(format!("{}.view.html", file.trim_end_matches(".map.txt"))),
        };
        write_view(&out, &pair)?;
        println!("wrote {} ({name} → {ref_name}); open it in a browser", out.display());
    }
    Ok(())
}
