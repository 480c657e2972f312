//! Training data: shapes with their spectra and a (partial) map from vertices to labels.

use std::io::BufRead;
use std::sync::Arc;

use super::ForestError;
use crate::descriptor::{first_nonzero_eigenvalue, LocalDescriptor, LocalParams};
use crate::spectral::Spectrum;

/// One reference shape: its spectrum and, per vertex, the label it maps to (`None` = unlabelled,
/// skipped during training).
#[derive(Clone, Debug)]
pub struct TrainingShape {
    /// Name used in error messages and logs.
    pub name: String,
    /// Unit-area spectrum of the shape.
    pub spectrum: Arc<Spectrum>,
    /// Label of each vertex in the common label set `0..n_labels`, or `None`.
    pub labels: Vec<Option<u32>>,
    /// The shape's local histograms ([`LocalDescriptor`], same vertex order), when the forest
    /// is to split on them too; every shape of a set carries them with the same settings, or
    /// none does.
    pub local: Option<Arc<LocalDescriptor>>,
}

impl TrainingShape {
    /// A shape without local histograms.
    pub fn new(name: impl Into<String>, spectrum: Arc<Spectrum>, labels: Vec<Option<u32>>) -> Self {
        Self { name: name.into(), spectrum, labels, local: None }
    }

    /// The same shape carrying the local histograms of `mesh` (its mesh: same vertices as the
    /// spectrum) with settings `params`, for a forest that splits on them; unchanged when
    /// `params` is `None` (a WKS-only forest).
    pub fn with_local(
        mut self,
        mesh: &crate::mesh::Mesh,
        params: Option<&LocalParams>,
    ) -> Result<Self, ForestError> {
        if let Some(p) = params {
            self.local = Some(Arc::new(LocalDescriptor::new(mesh, &self.spectrum, p)?));
        }
        Ok(self)
    }
}

/// A shape that was left out of a [`TrainingSet`], and why.
#[derive(Debug)]
pub struct RejectedShape {
    /// The shape's name.
    pub name: String,
    /// Why it was rejected.
    pub error: ForestError,
}

/// A validated list of training shapes sharing a label set `0..n_labels`.
///
/// Built with [`TrainingSet::new`], which checks every shape and keeps the ones that fit,
/// reporting the others in [`TrainingSet::rejected`]; training goes on with the rest.
#[derive(Clone, Debug)]
pub struct TrainingSet {
    shapes: Vec<TrainingShape>,
    n_labels: usize,
    k: usize,
    local: Option<LocalParams>,
    rejected: Vec<(String, String)>,
}

impl TrainingSet {
    /// Validates `shapes` against the label set `0..n_labels`.
    ///
    /// A shape is rejected (with a [`ForestError::BadShape`] naming it) when its label vector
    /// length differs from its vertex count, a label is `≥ n_labels`, its spectrum is malformed,
    /// it has fewer than 2 nonzero eigenvalues, no vertex is labelled, its local histograms do
    /// not match its vertex count, or it carries local histograms (or their settings) where the
    /// first accepted shape does not (or others). The common number of
    /// eigenpairs `K` is the smallest over the accepted shapes. Fails only when no shape is left
    /// (the error lists every rejection) or `n_labels` is 0.
    pub fn new(shapes: Vec<TrainingShape>, n_labels: usize) -> Result<Self, ForestError> {
        let (set, rejected) = Self::new_with_rejections(shapes, n_labels)?;
        let _ = rejected;
        Ok(set)
    }

    /// A set of shapes sharing one vertex indexing (a TOSCA or SCAPE class, a synthetic
    /// family): label = vertex index, and `n_labels` is the first shape's vertex count. A shape
    /// with another vertex count is rejected by name, as in [`TrainingSet::new`].
    pub fn same_indexing(
        shapes: impl IntoIterator<Item = (String, Arc<Spectrum>)>,
    ) -> Result<Self, ForestError> {
        let shapes: Vec<(String, Arc<Spectrum>)> = shapes.into_iter().collect();
        let Some(n) = shapes.first().map(|s| s.1.n_vertices) else {
            return Err(ForestError::EmptyTrainingSet { rejected: "no shape was given".into() });
        };
        let labels = labels_identity(n);
        let shapes = shapes
            .into_iter()
            .map(|(name, spectrum)| TrainingShape::new(name, spectrum, labels.clone()))
            .collect();
        Self::new(shapes, n)
    }

    /// Like [`TrainingSet::new`], also returning each rejected shape with its error.
    pub fn new_with_rejections(
        shapes: Vec<TrainingShape>,
        n_labels: usize,
    ) -> Result<(Self, Vec<RejectedShape>), ForestError> {
        if n_labels == 0 || n_labels > u32::MAX as usize {
            return Err(ForestError::InvalidParameter {
                name: "n_labels",
                reason: format!("must be between 1 and 2^32 - 1, got {n_labels}"),
            });
        }
        let mut ok: Vec<TrainingShape> = Vec::new();
        let mut rejected = Vec::new();
        for s in shapes {
            let first = ok.first().map(|f| f.local.as_ref().map(|l| *l.params()));
            match check_shape(&s, n_labels, first) {
                Ok(()) => ok.push(s),
                Err(reason) => {
                    tracing::warn!(shape = %s.name, %reason, "training shape rejected");
                    rejected.push(RejectedShape {
                        name: s.name.clone(),
                        error: ForestError::BadShape { name: s.name, reason },
                    })
                }
            }
        }
        if ok.is_empty() {
            let list: Vec<String> = rejected.iter().map(|r| r.error.to_string()).collect();
            return Err(ForestError::EmptyTrainingSet { rejected: list.join("; ") });
        }
        if ok.len() > u16::MAX as usize {
            return Err(ForestError::InvalidParameter {
                name: "shapes",
                reason: format!("at most {} training shapes, got {}", u16::MAX, ok.len()),
            });
        }
        let k = ok.iter().map(|s| s.spectrum.k()).min().unwrap_or(0);
        let local = ok[0].local.as_ref().map(|l| *l.params());
        let rej = rejected.iter().map(|r| (r.name.clone(), r.error.to_string())).collect();
        Ok((Self { shapes: ok, n_labels, k, local, rejected: rej }, rejected))
    }

    /// The accepted shapes.
    pub fn shapes(&self) -> &[TrainingShape] {
        &self.shapes
    }

    /// Size of the label set.
    pub fn n_labels(&self) -> usize {
        self.n_labels
    }

    /// The mean number of labelled vertices per label, over the labels some shape carries (0
    /// for a set without labelled vertices): how many examples of each label the forest sees.
    pub fn samples_per_label(&self) -> f64 {
        let mut seen = vec![false; self.n_labels];
        let mut samples = 0usize;
        for l in self.shapes.iter().flat_map(|s| s.labels.iter().flatten()) {
            seen[*l as usize] = true;
            samples += 1;
        }
        let labels = seen.iter().filter(|&&s| s).count();
        if labels == 0 {
            0.0
        } else {
            samples as f64 / labels as f64
        }
    }

    /// Number of eigenpairs used from each shape (the minimum over the shapes).
    pub fn k(&self) -> usize {
        self.k
    }

    /// The settings of the local histograms every shape carries, if they do.
    pub fn local_params(&self) -> Option<LocalParams> {
        self.local
    }

    /// Names and reasons of the rejected shapes.
    pub fn rejected(&self) -> &[(String, String)] {
        &self.rejected
    }

    /// Total number of labelled vertices (training samples).
    pub fn n_samples(&self) -> usize {
        self.shapes.iter().map(|s| s.labels.iter().flatten().count()).sum()
    }
}

/// Checks one shape; `first` is the local settings of the first accepted shape (`None` when
/// none is accepted yet).
fn check_shape(s: &TrainingShape, n_labels: usize, first: Option<Option<LocalParams>>) -> Result<(), String> {
    let sp = &s.spectrum;
    if let Some(l) = &s.local {
        if l.n_vertices() != sp.n_vertices {
            return Err(format!(
                "local histograms of {} vertices but the spectrum has {}",
                l.n_vertices(),
                sp.n_vertices
            ));
        }
    }
    let own = s.local.as_ref().map(|l| *l.params());
    if let Some(first) = first {
        if own != first {
            return Err(match (first, own) {
                (None, _) => "it carries local histograms and the other shapes do not".into(),
                (_, None) => "it carries no local histograms and the other shapes do".into(),
                _ => "its local histograms have other settings than the other shapes'".into(),
            });
        }
    }
    if s.labels.len() != sp.n_vertices {
        return Err(format!(
            "label map has {} entries but the spectrum has {} vertices",
            s.labels.len(),
            sp.n_vertices
        ));
    }
    if sp.eigenvectors.len() != sp.n_vertices * sp.k() {
        return Err(format!(
            "spectrum stores {} eigenvector entries for {} vertices × {} eigenpairs",
            sp.eigenvectors.len(),
            sp.n_vertices,
            sp.k()
        ));
    }
    if sp.eigenvalues.iter().any(|l| !l.is_finite()) || sp.eigenvectors.iter().any(|v| !v.is_finite()) {
        return Err("spectrum has non-finite values".into());
    }
    let nonzero = first_nonzero_eigenvalue(&sp.eigenvalues).map_or(0, |f| sp.k() - f);
    if nonzero < 2 {
        return Err(format!("spectrum has {nonzero} nonzero eigenvalues, need at least 2"));
    }
    if let Some((v, l)) =
        s.labels.iter().enumerate().find_map(|(v, l)| l.filter(|&l| l as usize >= n_labels).map(|l| (v, l)))
    {
        return Err(format!("vertex {v} has label {l}, outside the label set 0..{n_labels}"));
    }
    if s.labels.iter().all(Option::is_none) {
        return Err("no vertex is labelled".into());
    }
    Ok(())
}

/// The identity label map for shapes of one class sharing vertex indexing: vertex `i` has
/// label `i`.
///
/// ```
/// use shapeforest::forest::labels_identity;
/// assert_eq!(labels_identity(3), vec![Some(0), Some(1), Some(2)]);
/// ```
pub fn labels_identity(n: usize) -> Vec<Option<u32>> {
    (0..n as u32).map(Some).collect()
}

/// Reads a label map with one label per vertex per line (the `.vts` convention of remeshed
/// FAUST/SCAPE: line `i` gives the label of vertex `i`). `one_based` says the file counts
/// labels from 1. A line that is blank, `none`, `nan`, `-1` (or `0` in a one-based file) marks
/// an unlabelled vertex. A line holds one token; more, a negative label other than `-1`, or
/// every labelled vertex carrying one label (signs of a corrupt or misread map) are errors.
/// Labels `≥ n_labels` (after conversion to 0-based) are an error naming the line.
///
/// ```
/// use shapeforest::forest::read_label_map;
/// let text = "3\n1\nnone\n2\n";
/// let l = read_label_map(text.as_bytes(), true, 3).unwrap();
/// assert_eq!(l, vec![Some(2), Some(0), None, Some(1)]);
/// assert!(read_label_map("4\n".as_bytes(), true, 3).is_err());
/// ```
pub fn read_label_map<R: BufRead>(
    reader: R,
    one_based: bool,
    n_labels: usize,
) -> Result<Vec<Option<u32>>, ForestError> {
    let mut out = Vec::new();
    let mut first: Option<(u32, usize)> = None;
    let mut all_same = true;
    for (i, line) in reader.lines().enumerate() {
        let line =
            line.map_err(|e| ForestError::LabelMap { line: i + 1, reason: format!("cannot read: {e}") })?;
        let bad = |reason: String| ForestError::LabelMap { line: i + 1, reason };
        let mut toks = line.split_whitespace();
        let tok = toks.next().unwrap_or("");
        if toks.next().is_some() {
            return Err(bad(format!(
                "{} values on one line; a per-vertex label map holds one label per line",
                line.split_whitespace().count()
            )));
        }
        let lower = tok.to_ascii_lowercase();
        if tok.is_empty() || lower == "none" || lower == "nan" || tok == "-1" {
            out.push(None);
            continue;
        }
        let v: u64 = tok.parse().map_err(|_| {
            let what = if tok.starts_with('-') {
                "a negative label (only -1, for none, is allowed)"
            } else {
                "not a label index"
            };
            bad(format!("{} is {what}", crate::limits::excerpt(tok.as_bytes(), 24)))
        })?;
        let v = if one_based {
            if v == 0 {
                out.push(None);
                continue;
            }
            v - 1
        } else {
            v
        };
        if v >= n_labels as u64 {
            return Err(bad(format!(
                "label {v} is outside the label set of {n_labels} ({})",
                if one_based { "1-based" } else { "0-based" }
            )));
        }
        match first {
            None => first = Some((v as u32, i + 1)),
            Some((f, _)) if f != v as u32 => all_same = false,
            _ => {}
        }
        out.push(Some(v as u32));
    }
    let labelled = out.iter().flatten().count();
    if let (Some((l, line)), true, true) = (first, all_same, labelled >= 2) {
        return Err(ForestError::LabelMap {
            line,
            reason: format!("all {labelled} labelled vertices carry label {l}: a sign of a corrupt map"),
        });
    }
    Ok(out)
}

/// Reads a per-label map (the `.vts` convention of remeshed TOSCA: line `k` names the vertex that
/// carries label `k`) and returns the per-vertex labels of a shape with `n_vertices` vertices.
/// `one_based` says vertex indices count from 1. A line that is blank, or names vertex `-1` (or
/// `0` in a one-based file), leaves its label without a vertex. A vertex named on several lines
/// (remeshed shapes can map several labels to one vertex) keeps the last of them. A line with
/// more than one token, a negative index other than the none marker, or every label on one
/// vertex is an error naming the line.
///
/// ```
/// use shapeforest::forest::read_per_label_map;
/// // labels 0, 1, 2 sit on vertices 3, 1, 2 (1-based)
/// let l = read_per_label_map("3\n1\n2\n".as_bytes(), true, 4).unwrap();
/// assert_eq!(l, vec![Some(1), Some(2), Some(0), None]);
/// assert!(read_per_label_map("5\n".as_bytes(), true, 4).is_err());
/// ```
pub fn read_per_label_map<R: BufRead>(
    reader: R,
    one_based: bool,
    n_vertices: usize,
) -> Result<Vec<Option<u32>>, ForestError> {
    let rows = super::read_per_label_rows(reader, one_based, n_vertices)?;
    Ok(per_vertex_labels(&rows, n_vertices))
}

/// The per-vertex labels of per-label rows (row `k` = the vertex of label `k`); a vertex named on
/// several rows keeps the last.
///
/// ```
/// use shapeforest::forest::per_vertex_labels;
/// assert_eq!(per_vertex_labels(&[Some(2), Some(2), None, Some(0)], 3), vec![Some(3), None, Some(1)]);
/// ```
pub fn per_vertex_labels(rows: &[Option<u32>], n_vertices: usize) -> Vec<Option<u32>> {
    let mut labels = vec![None; n_vertices];
    for (k, v) in rows.iter().enumerate() {
        if let Some(slot) = v.and_then(|v| labels.get_mut(v as usize)) {
            *slot = Some(k as u32);
        }
    }
    labels
}
