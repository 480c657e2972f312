//! Pictures beside results: the PNG snapshot of every match, `view.html` pages, and the
//! evaluation's `index.html`. The subcommands call these with one line each.

use std::{
    fmt::Write as _,
    path::{Path, PathBuf},
};

use anyhow::{Context, Result};
use shapeforest::{
    eval::{
        protocol::{Method, ProtocolReport, ProtocolShape},
        ErrorSummary,
    },
    mesh::Mesh,
    viz::{
        error_color, index_html, snapshot_png, view_html, IndexPage, IndexShape, PointErrors, SnapshotParams,
        ViewPair,
    },
};

fn write(path: &Path, bytes: &[u8]) -> Result<()> {
    std::fs::write(path, bytes).with_context(|| format!("cannot write {}", path.display()))
}

/// Writes `NAME.png` (scan through the map | reference) into `dir`.
pub fn write_snapshot(
    dir: &Path,
    scan_name: &str,
    scan: &Mesh,
    reference: &Mesh,
    map: &[usize],
) -> Result<PathBuf> {
    let pair = ViewPair { scan, scan_name, reference, reference_name: "reference", map, errors: None };
    let png = snapshot_png(&pair, None, &SnapshotParams::default())
        .with_context(|| format!("cannot draw the snapshot of {scan_name}"))?;
    let path = dir.join(format!("{scan_name}.png"));
    write(&path, &png)?;
    Ok(path)
}

/// Writes `path` = the interactive view of a pair.
pub fn write_view(path: &Path, pair: &ViewPair<'_>) -> Result<()> {
    let title = format!("{} → {}", pair.scan_name, pair.reference_name);
    let html =
        view_html(pair, &title).with_context(|| format!("cannot build the view of {}", pair.scan_name))?;
    write(path, html.as_bytes())
}

/// The evaluation's pictures: per test shape `shapes/NAME.png` (regularised forest map),
/// `shapes/NAME.errors.png` (its error heat map) and `shapes/NAME.view.html` (with ground
/// truth), then `index.html` with the table, the curves and the snapshots.
pub fn write_eval_pages(
    out: &Path,
    shapes: &[ProtocolShape],
    report: &ProtocolReport,
    table: &str,
) -> Result<()> {
    let dir = out.join("shapes");
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut entries = Vec::new();
    for t in &report.tests {
        let Some(m) = t.errors(Method::ForestRegularized) else { continue };
        let (test, reference) = (&shapes[t.test], &shapes[t.reference]);
        let scan = t.scan.as_deref().unwrap_or(&test.mesh);
        if m.map.len() != scan.n_vertices() || t.evaluated.len() != m.strict.len() {
            continue; // a report read back without maps
        }
        let evaluated = &t.evaluated;
        let errors = &m.strict;
        let pair = ViewPair {
            scan,
            scan_name: &test.name,
            reference: &reference.mesh,
            reference_name: &reference.name,
            map: &m.map,
            errors: Some(PointErrors { vertices: evaluated, errors }),
        };
        let params = SnapshotParams::default();
        let png = snapshot_png(&pair, None, &params)?;
        write(&dir.join(format!("{}.png", test.name)), &png)?;
        if let Some(per_vertex) = pair.vertex_errors() {
            let colors: Vec<[u8; 3]> = per_vertex.iter().map(|&e| error_color(e, 0.1)).collect();
            write(
                &dir.join(format!("{}.errors.png", test.name)),
                &snapshot_png(&pair, Some(&colors), &params)?,
            )?;
        }
        write_view(&dir.join(format!("{}.view.html", test.name)), &pair)?;
        let s = ErrorSummary::of(errors);
        entries.push(IndexShape {
            name: test.name.clone(),
            snapshot: format!("shapes/{}.png", test.name),
            view: format!("shapes/{}.view.html", test.name),
            caption: format!(
                "→ {}: {:.1} % within 0.05, mean {:.4} (heat map: shapes/{}.errors.png)",
                reference.name,
                100.0 * s.within_005,
                s.mean,
                test.name
            ),
        });
    }
    let curves_svg = std::fs::read_to_string(out.join("curves.svg")).ok();
    let mut title = String::from("shapeforest eval");
    if let Some(first) = shapes.first() {
        let _ = write!(title, ": {} shapes, from {}", shapes.len(), first.name);
    }
    let page = IndexPage {
        title,
        table: table.to_string(),
        curves_svg,
        files: ["results.csv", "timings.csv", "curves.csv", "curves.svg"]
            .iter()
            .map(|s| s.to_string())
            .collect(),
        shapes: entries,
    };
    write(&out.join("index.html"), index_html(&page).as_bytes())
}

/// Writes `dir/view.html` for a scan scored against ground truth (errors at `evaluated`).
#[allow(clippy::too_many_arguments)]
pub fn write_scored_view(
    dir: &Path,
    scan_name: &str,
    scan: &Mesh,
    reference: &Mesh,
    reference_name: &str,
    map: &[usize],
    evaluated: &[usize],
    errors: &[f64],
) -> Result<()> {
    let pair = ViewPair {
        scan,
        scan_name,
        reference,
        reference_name,
        map,
        errors: Some(PointErrors { vertices: evaluated, errors }),
    };
    write_view(&dir.join("view.html"), &pair)
}
