//! Writing evaluation results: cumulative curves as CSV and as an SVG plot.

use std::path::Path;

use plotters::prelude::*;

use super::{ErrorCurve, EvalError};

/// A named curve to write or plot.
#[derive(Clone, Debug)]
pub struct CurveSeries {
    /// Legend label, e.g. "forest + regulariser".
    pub name: String,
    /// The curve.
    pub curve: ErrorCurve,
}

/// Writes curves as CSV: a `threshold` column, then one column per series.
pub fn write_curves_csv(path: &Path, series: &[CurveSeries]) -> Result<(), EvalError> {
    let err = |e: std::io::Error| EvalError::Write { path: path.to_path_buf(), message: e.to_string() };
    let mut out = String::from("threshold");
    for s in series {
        out.push(',');
        out.push_str(&s.name.replace(',', ";"));
    }
    out.push('\n');
    let rows = series.iter().map(|s| s.curve.thresholds.len()).max().unwrap_or(0);
    for i in 0..rows {
        let t = series.iter().find_map(|s| s.curve.thresholds.get(i)).copied().unwrap_or(0.0);
        out.push_str(&format!("{t:.4}"));
        for s in series {
            match s.curve.fractions.get(i) {
                Some(f) => out.push_str(&format!(",{f:.6}")),
                None => out.push(','),
            }
        }
        out.push('\n');
    }
    std::fs::write(path, out).map_err(err)
}

/// Plots cumulative curves to an SVG file (x: normalised geodesic error, y: % of points).
pub fn plot_curves_svg(path: &Path, title: &str, series: &[CurveSeries]) -> Result<(), EvalError> {
    let fail = |e: String| EvalError::Write { path: path.to_path_buf(), message: e };
    let root = SVGBackend::new(path, (800, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| fail(e.to_string()))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(16)
        .x_label_area_size(44)
        .y_label_area_size(54)
        .build_cartesian_2d(0f64..super::CURVE_MAX, 0f64..100f64)
        .map_err(|e| fail(e.to_string()))?;
    chart
        .configure_mesh()
        .x_desc("geodesic error / √area")
        .y_desc("% of points")
        .draw()
        .map_err(|e| fail(e.to_string()))?;
    for (i, s) in series.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        let pts: Vec<(f64, f64)> =
            s.curve.thresholds.iter().zip(&s.curve.fractions).map(|(&t, &f)| (t, 100.0 * f)).collect();
        chart
            .draw_series(LineSeries::new(pts, color.stroke_width(2)))
            .map_err(|e| fail(e.to_string()))?
            .label(s.name.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|e| fail(e.to_string()))?;
    root.present().map_err(|e| fail(e.to_string()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::cumulative_curve;

    #[test]
    fn csv_and_svg_are_written() {
        let dir = tempfile::tempdir().unwrap();
        let series = vec![
            CurveSeries { name: "a".into(), curve: cumulative_curve(&[0.0, 0.02, 0.2], 50) },
            CurveSeries { name: "b".into(), curve: cumulative_curve(&[0.1, 0.1], 50) },
        ];
        let csv = dir.path().join("c.csv");
        write_curves_csv(&csv, &series).unwrap();
        let text = std::fs::read_to_string(&csv).unwrap();
        assert!(text.starts_with("threshold,a,b\n"));
        assert_eq!(text.lines().count(), 52);
        assert!(text.lines().last().unwrap().starts_with("0.2500,1.0"));
        let svg = dir.path().join("c.svg");
        plot_curves_svg(&svg, "test", &series).unwrap();
        assert!(std::fs::read_to_string(&svg).unwrap().contains("<svg"));
        assert!(write_curves_csv(&dir.path().join("missing/x.csv"), &series).is_err());
    }
}
