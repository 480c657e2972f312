//! Pictures of a correspondence: PNG snapshots rendered headless, and a self-contained
//! interactive `view.html`.
//!
//! A [`ViewPair`] is a scan, a reference and the point map between them (`map[i]` = the
//! reference vertex of scan vertex `i`), optionally with the geodesic errors measured at some
//! scan vertices (normalised by √area of the reference, as in [`crate::eval`]). The reference is
//! coloured by a smooth function of its coordinates ([`crate::mesh::coordinate_colors`]) and
//! the scan through the map, so matching parts share colours — the colouring of the
//! `*.colored.ply` files.
//!
//! - [`render_snapshot`] rasterises both meshes side by side (scan left, reference right) with
//!   a fixed camera, per-vertex colours and Lambert shading, in a small software rasteriser of
//!   our own (no GPU and no window are needed: it runs in CI and in the daemon); [`snapshot_png`]
//!   encodes it with the `png` crate.
//! - [`view_html`] writes one HTML file that embeds three.js r170 (vendored from the npm
//!   package with its MIT licence in `src/viz/vendor/`) and the meshes: orbit/zoom, click a
//!   point to see its match on the other shape, and with errors a heat map and the cumulative
//!   curve. It works offline from a `file://` URL.
//!
//! Everything here is pure (bytes and strings out) except [`write_snapshot`], the one-call
//! helper of the daemon's sink.

mod html;
mod raster;

pub use html::{index_html, view_html, IndexPage, IndexShape};
pub use raster::{render_snapshot, snapshot_png, Image, SnapshotParams};

use crate::mesh::{coordinate_colors, Mesh};
use thiserror::Error;

/// A picture could not be made from the given data.
#[derive(Debug, Error)]
pub enum VizError {
    /// The map, the colours or the errors do not fit the meshes.
    #[error("{0}")]
    SizeMismatch(String),
    /// A parameter is out of range.
    #[error("invalid picture parameter `{name}`: {reason}")]
    InvalidParameter {
        /// The parameter.
        name: &'static str,
        /// Why.
        reason: String,
    },
    /// PNG encoding failed.
    #[error("PNG encoding failed: {0}")]
    Png(String),
}

/// Geodesic errors measured at some vertices of the scan (ground truth known).
#[derive(Clone, Copy, Debug)]
pub struct PointErrors<'a> {
    /// Evaluated scan vertices.
    pub vertices: &'a [usize],
    /// Error of each, normalised by √area of the reference.
    pub errors: &'a [f64],
}

/// A scan, a reference and the map between them.
#[derive(Clone, Copy, Debug)]
pub struct ViewPair<'a> {
    /// The matched shape.
    pub scan: &'a Mesh,
    /// Its display name.
    pub scan_name: &'a str,
    /// The reference shape.
    pub reference: &'a Mesh,
    /// Its display name.
    pub reference_name: &'a str,
    /// `map[i]` = reference vertex matched to scan vertex `i`.
    pub map: &'a [usize],
    /// Errors at evaluated points, when ground truth is known.
    pub errors: Option<PointErrors<'a>>,
}

impl<'a> ViewPair<'a> {
    /// A pair without errors (no ground truth known); add them with [`ViewPair::with_errors`].
    pub fn new(
        scan: &'a Mesh,
        scan_name: &'a str,
        reference: &'a Mesh,
        reference_name: &'a str,
        map: &'a [usize],
    ) -> Self {
        Self { scan, scan_name, reference, reference_name, map, errors: None }
    }

    /// The same pair with errors at evaluated points.
    pub fn with_errors(self, errors: PointErrors<'a>) -> Self {
        Self { errors: Some(errors), ..self }
    }

    /// Checks that the map has one reference vertex per scan vertex and that the errors name
    /// scan vertices and are finite.
    ///
    /// ```
    /// use shapeforest::{synth::icosphere, viz::ViewPair};
    /// let s = icosphere(1, 1.0);
    /// let map: Vec<usize> = (0..s.n_vertices()).collect();
    /// let pair = ViewPair { scan: &s, scan_name: "a", reference: &s, reference_name: "b", map: &map, errors: None };
    /// assert!(pair.check().is_ok());
    /// assert!(ViewPair { map: &map[1..], ..pair }.check().is_err());
    /// ```
    pub fn check(&self) -> Result<(), VizError> {
        let (n, n_ref) = (self.scan.n_vertices(), self.reference.n_vertices());
        if self.map.len() != n {
            return Err(VizError::SizeMismatch(format!(
                "the map has {} entries but the scan `{}` has {n} vertices",
                self.map.len(),
                self.scan_name
            )));
        }
        if let Some((i, &r)) = self.map.iter().enumerate().find(|(_, &r)| r >= n_ref) {
            return Err(VizError::SizeMismatch(format!(
                "the map sends scan vertex {i} to {r}, outside the reference `{}` of {n_ref} vertices",
                self.reference_name
            )));
        }
        if let Some(e) = &self.errors {
            if e.vertices.len() != e.errors.len() {
                return Err(VizError::SizeMismatch(format!(
                    "{} errors for {} evaluated vertices",
                    e.errors.len(),
                    e.vertices.len()
                )));
            }
            if let Some(&v) = e.vertices.iter().find(|&&v| v >= n) {
                return Err(VizError::SizeMismatch(format!("evaluated vertex {v} is outside the scan")));
            }
            if e.errors.iter().any(|x| !x.is_finite() || *x < 0.0) {
                return Err(VizError::SizeMismatch("errors must be finite and non-negative".into()));
            }
        }
        Ok(())
    }

    /// Colours of the reference (by coordinates) and of the scan (through the map).
    pub fn map_colors(&self) -> (Vec<[u8; 3]>, Vec<[u8; 3]>) {
        let reference = coordinate_colors(self.reference);
        let scan = self.map.iter().map(|&r| reference.get(r).copied().unwrap_or([0, 0, 0])).collect();
        (reference, scan)
    }

    /// Error of every scan vertex, each taken from its nearest evaluated vertex (Euclidean, on
    /// the scan): errors are measured at a sample of points, the heat map shows them on the
    /// whole surface. `None` without errors.
    pub fn vertex_errors(&self) -> Option<Vec<f64>> {
        let e = self.errors.as_ref()?;
        if e.vertices.is_empty() {
            return None;
        }
        let pts: Vec<[f64; 3]> = e.vertices.iter().map(|&v| self.scan.vertices[v]).collect();
        Some(
            self.scan
                .vertices
                .iter()
                .map(|p| {
                    let mut best = (f64::INFINITY, 0.0);
                    for (q, &err) in pts.iter().zip(e.errors) {
                        let d = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2);
                        if d < best.0 {
                            best = (d, err);
                        }
                    }
                    best.1
                })
                .collect(),
        )
    }
}

/// Heat-map colour of a normalised geodesic error: dark blue at 0, through cyan, yellow, to red
/// at `max` and beyond.
///
/// ```
/// use shapeforest::viz::error_color;
/// assert_eq!(error_color(0.0, 0.1), [40, 60, 160]);
/// assert_eq!(error_color(1.0, 0.1), [200, 30, 30]);
/// ```
pub fn error_color(error: f64, max: f64) -> [u8; 3] {
    const STOPS: [[f64; 3]; 4] =
        [[40.0, 60.0, 160.0], [60.0, 190.0, 210.0], [240.0, 220.0, 60.0], [200.0, 30.0, 30.0]];
    let t = if max > 0.0 { (error / max).clamp(0.0, 1.0) } else { 1.0 } * 3.0;
    let i = (t.floor() as usize).min(2);
    let f = t - i as f64;
    let mut c = [0u8; 3];
    for a in 0..3 {
        c[a] = (STOPS[i][a] + f * (STOPS[i + 1][a] - STOPS[i][a])).round() as u8;
    }
    c
}

/// Writes the PNG snapshot of `scan` mapped to `reference` to `path` (default
/// [`SnapshotParams`]); the one file-writing helper here, for the daemon's sink. Errors are
/// messages naming the file.
pub fn write_snapshot(
    path: &std::path::Path,
    scan: &Mesh,
    reference: &Mesh,
    map: &[usize],
) -> Result<(), String> {
    let pair =
        ViewPair { scan, scan_name: "scan", reference, reference_name: "reference", map, errors: None };
    let png = snapshot_png(&pair, None, &SnapshotParams::default())
        .map_err(|e| format!("{}: {e}", path.display()))?;
    std::fs::write(path, png).map_err(|e| format!("{}: {e}", path.display()))
}
