//! Evaluation of correspondences as the paper and the field do (Kim et al. 2011 protocol).
//!
//! The error of a matched test vertex `m` with predicted reference vertex `T(m)` and ground
//! truth `g(m)` is the geodesic distance `d_R(T(m), g(m)) / √area(R)` on the reference (eq.
//! 11.22). The cumulative curve gives, for thresholds `t ∈ [0, 0.25]`, the fraction of
//! evaluated vertices with error ≤ t. With a left/right symmetry map `s` of the reference, the
//! symmetric error is `min(d(T(m), g(m)), d(s(T(m)), g(m)))` — a mirrored match counts as
//! correct — and is reported separately from the strict figure. The protocol
//! ([`protocol`]) uses the equivalent form with the mirrored ground truth,
//! `min(d(T(m), g(m)), d(T(m), s(g(m))))` (equal for an exact isometric symmetry), which needs
//! `s` only at the evaluated points; [`symmetry`] builds the maps `s` of real classes.
//!
//! Distances come as columns of a distance-field matrix, one field per ground-truth point (any
//! geodesic solver: the crate's heat method with a fine time step, or fast marching), so the
//! numeric core here is solver-agnostic and pure.

pub mod pairs;
pub mod protocol;
mod report;
pub mod symmetry;

pub use report::{plot_curves_svg, write_curves_csv, CurveSeries};

use faer::MatRef;
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// An evaluation could not be carried out.
#[derive(Debug, Error)]
pub enum EvalError {
    /// Input sizes do not agree.
    #[error("size mismatch: {0}")]
    SizeMismatch(String),
    /// The protocol's input is unusable (names the shape or setting at fault).
    #[error("invalid evaluation input: {0}")]
    InvalidInput(String),
    /// Writing a report failed.
    #[error("cannot write {path}: {message}")]
    Write {
        /// File being written.
        path: std::path::PathBuf,
        /// What went wrong.
        message: String,
    },
    /// Regularising a map failed.
    #[error(transparent)]
    Regularizer(#[from] crate::regularizer::RegularizerError),
    /// A geodesic computation failed.
    #[error(transparent)]
    Geodesic(#[from] crate::geodesic::GeodesicError),
    /// A functional-map computation failed.
    #[error(transparent)]
    Fmap(#[from] crate::fmap::FmapError),
    /// A spectrum could not be computed.
    #[error(transparent)]
    Spectral(#[from] crate::spectral::SpectralError),
    /// Training or predicting with a forest failed.
    #[error(transparent)]
    Forest(#[from] crate::forest::ForestError),
    /// A descriptor could not be computed.
    #[error(transparent)]
    Descriptor(#[from] crate::descriptor::DescriptorError),
    /// Matching failed.
    #[error(transparent)]
    Matching(#[from] crate::matching::MatchingError),
}

/// Largest threshold of the cumulative curves (as in the paper's plots).
pub const CURVE_MAX: f64 = 0.25;

/// Strict errors and, with a symmetry map, flips-allowed errors.
pub type PooledErrors = (Vec<f64>, Option<Vec<f64>>);

/// A report that holds, for each of several results (test shapes, pairs), the errors of
/// several methods; its pooled views (errors, summaries, curves over every result) come with it.
///
/// ```no_run
/// use shapeforest::eval::{protocol::{Method, ProtocolReport}, PooledReport};
/// # fn show(report: &ProtocolReport) {
/// let (strict, flips) = report.summary(Method::ForestRegularized);
/// println!("{:.1} % within 0.05", 100.0 * strict.within_005);
/// # }
/// ```
pub trait PooledReport {
    /// The methods compared.
    type Method: Copy + 'static;
    /// Every method, in report order.
    const METHODS: &'static [Self::Method];

    /// A method's short name, for tables and curves.
    fn method_name(method: Self::Method) -> &'static str;

    /// Whether flips-allowed (symmetric) errors were computed.
    fn has_symmetry(&self) -> bool;

    /// `(strict, symmetric)` errors of `method`, one item per result that has them.
    fn method_errors(&self, method: Self::Method) -> impl Iterator<Item = (&[f64], Option<&[f64]>)>;

    /// Errors of `method` pooled over all results: `(strict, symmetric)`, the symmetric list
    /// `None` unless [`PooledReport::has_symmetry`].
    fn pooled(&self, method: Self::Method) -> PooledErrors {
        let mut strict = Vec::new();
        let mut sym: Option<Vec<f64>> = self.has_symmetry().then(Vec::new);
        for (s, y) in self.method_errors(method) {
            strict.extend_from_slice(s);
            if let (Some(out), Some(y)) = (sym.as_mut(), y) {
                out.extend_from_slice(y);
            }
        }
        (strict, sym)
    }

    /// Summary of `method` over all results: `(strict, symmetric)`.
    fn summary(&self, method: Self::Method) -> (ErrorSummary, Option<ErrorSummary>) {
        let (s, y) = self.pooled(method);
        (ErrorSummary::of(&s), y.map(|y| ErrorSummary::of(&y)))
    }

    /// Cumulative curves: one per method that was run (strict), then one per method with flips
    /// allowed (named `NAME (sym)`) when a symmetry map was given.
    fn curves(&self, steps: usize) -> Vec<CurveSeries> {
        let mut out = Vec::new();
        let mut sym = Vec::new();
        for &m in Self::METHODS {
            let name = Self::method_name(m);
            let (s, y) = self.pooled(m);
            if s.is_empty() {
                // A method that was not run (the baseline when skipped, ZoomOut when off).
                continue;
            }
            out.push(CurveSeries { name: name.to_string(), curve: cumulative_curve(&s, steps) });
            if let Some(y) = y {
                sym.push(CurveSeries { name: format!("{name} (sym)"), curve: cumulative_curve(&y, steps) });
            }
        }
        out.extend(sym);
        out
    }
}

/// Implements [`PooledReport`] for a report type whose field `$results` lists results with an
/// `errors(method)` accessor, for a method enum with `ALL` and `name()`.
macro_rules! pooled_report {
    ($report:ty, $method:ty, $results:ident) => {
        impl $crate::eval::PooledReport for $report {
            type Method = $method;
            const METHODS: &'static [$method] = &<$method>::ALL;

            fn method_name(method: $method) -> &'static str {
                method.name()
            }

            fn has_symmetry(&self) -> bool {
                self.has_symmetry
            }

            fn method_errors(&self, method: $method) -> impl Iterator<Item = (&[f64], Option<&[f64]>)> {
                self.$results
                    .iter()
                    .filter_map(move |r| r.errors(method))
                    .map(|e| (&e.strict[..], e.symmetric.as_deref()))
            }
        }
    };
}
pub(crate) use pooled_report;

/// Normalised geodesic errors of a map at a set of evaluated test vertices.
///
/// - `map`: test vertex → predicted reference vertex, for every test vertex;
/// - `evaluated`: the test vertices evaluated;
/// - `fields`: `n_ref × evaluated.len()`; column `j` holds geodesic distances on the reference
///   from the ground-truth point of `evaluated[j]`;
/// - `symmetry`: optional left/right map of the reference; when given, the second result holds
///   the symmetric errors;
/// - `reference_area`: surface area of the reference, for the √area normalisation.
///
/// ```
/// use shapeforest::eval::geodesic_errors;
/// // Reference = 3 vertices on a line at 0, 1, 2; one field from the ground truth vertex 0.
/// let fields = faer::mat![[0.0], [1.0], [2.0]];
/// let (strict, sym) = geodesic_errors(&[2, 1, 0], &[0], fields.as_ref(), Some(&[2, 1, 0]), 4.0).unwrap();
/// assert_eq!(strict, vec![1.0]); // d(2, 0) / √4
/// assert_eq!(sym.unwrap(), vec![0.0]); // mirrored match counts as correct
/// ```
pub fn geodesic_errors(
    map: &[usize],
    evaluated: &[usize],
    fields: MatRef<'_, f64>,
    symmetry: Option<&[usize]>,
    reference_area: f64,
) -> Result<(Vec<f64>, Option<Vec<f64>>), EvalError> {
    if fields.ncols() != evaluated.len() {
        return Err(EvalError::SizeMismatch(format!(
            "{} distance fields for {} evaluated vertices",
            fields.ncols(),
            evaluated.len()
        )));
    }
    let n_ref = fields.nrows();
    if let Some(s) = symmetry {
        if s.len() != n_ref || s.iter().any(|&v| v >= n_ref) {
            return Err(EvalError::SizeMismatch(format!(
                "symmetry map of {} entries for a reference of {n_ref} vertices",
                s.len()
            )));
        }
    }
    let norm = 1.0 / reference_area.max(f64::MIN_POSITIVE).sqrt();
    let mut strict = Vec::with_capacity(evaluated.len());
    let mut sym = symmetry.map(|_| Vec::with_capacity(evaluated.len()));
    for (j, &m) in evaluated.iter().enumerate() {
        let t = *map.get(m).ok_or_else(|| {
            EvalError::SizeMismatch(format!(
                "evaluated vertex {m} is outside the map of {} vertices",
                map.len()
            ))
        })?;
        if t >= n_ref {
            return Err(EvalError::SizeMismatch(format!(
                "the map sends vertex {m} to {t}, outside the reference"
            )));
        }
        let e = fields[(t, j)] * norm;
        strict.push(e);
        if let (Some(s), Some(out)) = (symmetry, sym.as_mut()) {
            out.push(e.min(fields[(s[t], j)] * norm));
        }
    }
    Ok((strict, sym))
}

/// A cumulative error curve: `fractions[i]` of the errors are ≤ `thresholds[i]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ErrorCurve {
    /// Increasing thresholds from 0 to [`CURVE_MAX`].
    pub thresholds: Vec<f64>,
    /// Fraction of points within each threshold (non-decreasing, in [0, 1]).
    pub fractions: Vec<f64>,
}

/// The cumulative curve of `errors` on `steps + 1` evenly spaced thresholds in `[0, CURVE_MAX]`.
///
/// ```
/// let c = shapeforest::eval::cumulative_curve(&[0.0, 0.1, 0.3], 5);
/// assert_eq!(c.thresholds.len(), 6);
/// assert!((c.fractions[0] - 1.0 / 3.0).abs() < 1e-12);
/// assert!((c.fractions[5] - 2.0 / 3.0).abs() < 1e-12);
/// ```
pub fn cumulative_curve(errors: &[f64], steps: usize) -> ErrorCurve {
    let steps = steps.max(1);
    let mut sorted: Vec<f64> = errors.to_vec();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len().max(1) as f64;
    let thresholds: Vec<f64> = (0..=steps).map(|i| CURVE_MAX * i as f64 / steps as f64).collect();
    let fractions = thresholds.iter().map(|&t| sorted.partition_point(|&e| e <= t) as f64 / n).collect();
    ErrorCurve { thresholds, fractions }
}

/// Summary figures of a set of normalised errors.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ErrorSummary {
    /// Number of evaluated points.
    pub n: usize,
    /// Mean error.
    pub mean: f64,
    /// Median error.
    pub median: f64,
    /// Fraction of points with error ≤ 0.05.
    pub within_005: f64,
    /// Fraction of points with error ≤ 0.1.
    pub within_010: f64,
}

impl ErrorSummary {
    /// Summarises `errors`.
    ///
    /// ```
    /// let s = shapeforest::eval::ErrorSummary::of(&[0.0, 0.04, 0.08, 0.2]);
    /// assert_eq!(s.within_005, 0.5);
    /// assert_eq!(s.within_010, 0.75);
    /// assert!((s.mean - 0.08).abs() < 1e-12);
    /// ```
    pub fn of(errors: &[f64]) -> ErrorSummary {
        if errors.is_empty() {
            return ErrorSummary::default();
        }
        let mut sorted = errors.to_vec();
        sorted.sort_by(f64::total_cmp);
        let n = sorted.len();
        let frac = |t: f64| sorted.partition_point(|&e| e <= t) as f64 / n as f64;
        let median = if n % 2 == 1 { sorted[n / 2] } else { 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]) };
        ErrorSummary {
            n,
            mean: sorted.iter().sum::<f64>() / n as f64,
            median,
            within_005: frac(0.05),
            within_010: frac(0.1),
        }
    }
}
