//! What travels on the pipeline's channels: one [`Envelope`] per job and edge, carrying the
//! job's identity and either the stage's output or the failure that stopped the job.
//!
//! Payloads hold their large parts behind [`Arc`], so passing a job along (or keeping a copy in
//! a report) never copies a mesh, a spectrum or a prediction.

use std::{
    fmt,
    path::{Path, PathBuf},
    sync::Arc,
    time::Instant,
};

use crate::{
    forest::{ForestDescriptor, Prediction},
    mesh::Mesh,
    regularizer::{DenseMap, PreparedShape, ScanPart, SparseMatches},
    spectral::Spectrum,
};

use super::model::ModelState;

/// A job's number, unique within one run of a pipeline.
pub type JobId = u64;

/// Identity and history of one job (one input shape), carried with it through every stage.
#[derive(Clone, Debug)]
pub struct Job {
    /// Job number.
    pub id: JobId,
    /// Name of the shape (the input file's stem, or a generated name).
    pub name: String,
    /// Where the input is now (`None` for generated shapes). A daemon moves claimed inputs, so
    /// this is the claimed location.
    pub source: Option<PathBuf>,
    /// The label map that came with the input, if any.
    pub labels_file: Option<PathBuf>,
    /// Other files that travel with the input (the `.tri` of a TOSCA `.vert`).
    pub companions: Vec<PathBuf>,
    /// The file name the input arrived under (for reports and output names).
    pub arrived_as: Option<String>,
    /// When the job entered the pipeline.
    pub started: Instant,
    /// Seconds spent in each stage so far, in order.
    pub stage_seconds: Vec<(String, f64)>,
    /// The queue message the job came from, under a networked transport (`None` in process):
    /// acknowledged once the job is done with, redelivered if it is lost.
    pub delivery: Option<super::transport::Delivery>,
    /// The job's key under a networked transport (its input's content key and a nonce; `None`
    /// in process): a job may be delivered more than once, and a sink writes each key once.
    pub key: Option<String>,
}

impl Job {
    /// A job for a generated (file-less) shape.
    pub fn generated(id: JobId, name: impl Into<String>) -> Self {
        Self {
            id,
            name: name.into(),
            source: None,
            labels_file: None,
            companions: Vec::new(),
            arrived_as: None,
            started: Instant::now(),
            stage_seconds: Vec::new(),
            delivery: None,
            key: None,
        }
    }

    /// A job for a file.
    pub fn for_file(id: JobId, path: &Path, labels_file: Option<PathBuf>) -> Self {
        Self {
            id,
            name: shape_stem(path),
            source: Some(path.to_path_buf()),
            labels_file,
            companions: Vec::new(),
            arrived_as: path.file_name().and_then(|n| n.to_str()).map(str::to_string),
            started: Instant::now(),
            stage_seconds: Vec::new(),
            delivery: None,
            key: None,
        }
    }

    /// Every claimed file of the job: the input, its label map, its companions.
    pub fn files(&self) -> impl Iterator<Item = &PathBuf> {
        self.source.iter().chain(self.labels_file.iter()).chain(self.companions.iter())
    }

    /// The input's path for messages: the file, or the generated name.
    pub fn display_source(&self) -> String {
        match &self.source {
            Some(p) => p.display().to_string(),
            None => self.name.clone(),
        }
    }

    /// Total seconds recorded by stages.
    pub fn seconds_in_stages(&self) -> f64 {
        self.stage_seconds.iter().map(|s| s.1).sum()
    }
}

/// The file stem of a mesh path, without compression and mesh extensions
/// (`scan.off.gz` → `scan`).
///
/// ```
/// use std::path::Path;
/// use shapeforest::pipeline::shape_stem;
/// assert_eq!(shape_stem(Path::new("a/cat3.off.gz")), "cat3");
/// assert_eq!(shape_stem(Path::new("b/scan.v2.ply")), "scan.v2");
/// ```
pub fn shape_stem(path: &Path) -> String {
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("shape");
    let name = name.strip_suffix(".gz").unwrap_or(name);
    match name.rsplit_once('.') {
        Some((stem, _)) if !stem.is_empty() => stem.to_string(),
        _ => name.to_string(),
    }
}

/// Why a job stopped.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FailureKind {
    /// The input is bad (unreadable mesh, bad label map, degenerate shape): it is rejected.
    BadInput,
    /// The pipeline shut down before the job finished: the input is left for the next start.
    Interrupted,
    /// Anything else (an internal error, a panic in a stage): the input is rejected with the
    /// error so that it is not retried forever.
    Internal,
}

/// A job's failure: which stage, what happened. Failures travel to the sink as values.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Failure {
    /// The stage that failed.
    pub stage: String,
    /// Kind of failure.
    pub kind: FailureKind,
    /// The error, as a person reads it (with its causes).
    pub message: String,
}

impl Failure {
    /// A bad-input failure in `stage`.
    pub fn bad_input(stage: &str, message: impl Into<String>) -> Self {
        Self { stage: stage.to_string(), kind: FailureKind::BadInput, message: message.into() }
    }

    /// An interrupted job.
    pub fn interrupted(stage: &str) -> Self {
        Self {
            stage: stage.to_string(),
            kind: FailureKind::Interrupted,
            message: "the pipeline shut down before this job finished".into(),
        }
    }
}

impl fmt::Display for Failure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "stage `{}`: {}", self.stage, self.message)
    }
}

/// One job on one edge: its identity and the previous stage's output, or its failure.
#[derive(Clone, Debug)]
pub struct Envelope<T> {
    /// The job.
    pub job: Job,
    /// The payload, or why there is none.
    pub body: Result<T, Failure>,
}

/// An input file found by a source.
#[derive(Clone, Debug)]
pub struct InputFile {
    /// The mesh file.
    pub path: PathBuf,
    /// Where its labels come from, for labelled shapes.
    pub labels: Option<LabelSpec>,
}

/// Where a labelled shape's labels come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum LabelSpec {
    /// A label map file (see [`crate::pipeline::read_labels`]).
    File(PathBuf),
    /// Label = vertex index.
    Identity,
}

/// A shape: its mesh and, for labelled shapes, a label per vertex.
#[derive(Clone, Debug)]
pub struct Shape {
    /// The mesh.
    pub mesh: Arc<Mesh>,
    /// Per-vertex labels (`None` entries: unlabelled vertex); `None` for a scan.
    pub labels: Option<Arc<Vec<Option<u32>>>>,
}

/// A shape with its Laplace spectrum.
#[derive(Clone, Debug)]
pub struct SpectralShape {
    /// The shape (for a scan matched on a part of itself: the part).
    pub shape: Shape,
    /// Its unit-area spectrum (for a partial scan: normalised as [`ScanPart`] says).
    pub spectrum: Arc<Spectrum>,
    /// For a scan matched on a part of itself: the whole scan and how the part was made.
    pub partial: Option<Arc<PartialScan>>,
}

/// A scan matched on a part of itself (its largest connected piece, its small holes closed
/// for the spectrum, or normalised by the reference's area; see [`ScanPart`]): the map of the
/// part is extended to the whole scan before it is written.
#[derive(Clone, Debug)]
pub struct PartialScan {
    /// The whole scan, as it arrived.
    pub scan: Arc<Mesh>,
    /// The part matched.
    pub part: ScanPart,
    /// Holes closed for the spectrum.
    pub holes_closed: usize,
    /// The area the part's spectrum is normalised by, relative to its own (1: its own).
    pub scale_ratio: f64,
}

/// A shape described for the forest: the model snapshot it is matched with travels along, so
/// every later stage of the job uses the same model even if a newer one is swapped in.
#[derive(Clone)]
pub struct DescribedShape {
    /// The shape and its spectrum.
    pub shape: SpectralShape,
    /// The model the descriptor was made for.
    pub model: Arc<ModelState>,
    /// The forest's descriptor.
    pub descriptor: Arc<ForestDescriptor>,
}

/// A shape with the forest's posterior.
#[derive(Clone)]
pub struct PredictedShape {
    /// The shape and its spectrum.
    pub shape: SpectralShape,
    /// The model.
    pub model: Arc<ModelState>,
    /// The posterior over labels of every vertex.
    pub prediction: Arc<Prediction>,
}

/// A shape with its sparse consistent matches to the model's reference.
#[derive(Clone)]
pub struct SparselyMatched {
    /// The prediction it came from.
    pub predicted: PredictedShape,
    /// The shape prepared for geodesics (heat-method factorisation), reused by the dense step.
    pub prepared: Arc<PreparedShape>,
    /// The heat-method parameters `prepared` was made with (a receiver on another machine
    /// prepares the shape again with them).
    pub heat: crate::geodesic::HeatParams,
    /// The matches.
    pub sparse: Arc<SparseMatches>,
}

/// A shape with its dense map to the model's reference.
#[derive(Clone)]
pub struct MatchedShape {
    /// The prediction it came from.
    pub predicted: PredictedShape,
    /// The dense map.
    pub dense: Arc<DenseMap>,
}

impl SpectralShape {
    /// A shape and its spectrum, matched whole.
    pub fn whole(shape: Shape, spectrum: Arc<Spectrum>) -> Self {
        Self { shape, spectrum, partial: None }
    }

    /// The mesh matched (for a partial scan: the part).
    pub fn mesh(&self) -> &Arc<Mesh> {
        &self.shape.mesh
    }

    /// The whole scan as it arrived (the mesh matched, unless the scan is matched on a part).
    pub fn scan(&self) -> &Arc<Mesh> {
        self.partial.as_ref().map_or(&self.shape.mesh, |p| &p.scan)
    }

    /// The per-vertex labels, for a labelled shape.
    pub fn labels(&self) -> Option<&Arc<Vec<Option<u32>>>> {
        self.shape.labels.as_ref()
    }
}

impl PredictedShape {
    /// The mesh matched (for a partial scan: the part).
    pub fn mesh(&self) -> &Arc<Mesh> {
        self.shape.mesh()
    }

    /// The whole scan as it arrived.
    pub fn scan(&self) -> &Arc<Mesh> {
        self.shape.scan()
    }

    /// The per-vertex labels, for a labelled shape.
    pub fn labels(&self) -> Option<&Arc<Vec<Option<u32>>>> {
        self.shape.labels()
    }

    /// The spectrum.
    pub fn spectrum(&self) -> &Arc<Spectrum> {
        &self.shape.spectrum
    }
}

/// Accessors of the payloads that carry a prediction (`m.mesh()` rather than
/// `m.predicted.shape.shape.mesh`).
macro_rules! predicted_accessors {
    ($t:ty) => {
        impl $t {
            /// The mesh matched (for a partial scan: the part).
            pub fn mesh(&self) -> &Arc<Mesh> {
                self.predicted.mesh()
            }

            /// The whole scan as it arrived.
            pub fn scan(&self) -> &Arc<Mesh> {
                self.predicted.scan()
            }

            /// The per-vertex labels, for a labelled shape.
            pub fn labels(&self) -> Option<&Arc<Vec<Option<u32>>>> {
                self.predicted.labels()
            }

            /// The model the job is matched with.
            pub fn model(&self) -> &Arc<ModelState> {
                &self.predicted.model
            }

            /// The forest's posterior.
            pub fn prediction(&self) -> &Arc<Prediction> {
                &self.predicted.prediction
            }
        }
    };
}

predicted_accessors!(SparselyMatched);
predicted_accessors!(MatchedShape);

impl fmt::Debug for DescribedShape {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "DescribedShape(model v{})", self.model.version)
    }
}

impl fmt::Debug for PredictedShape {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "PredictedShape(model v{}, {} vertices)", self.model.version, self.prediction.n_vertices())
    }
}

impl fmt::Debug for SparselyMatched {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "SparselyMatched({} matches)", self.sparse.matches.len())
    }
}

impl fmt::Debug for MatchedShape {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "MatchedShape({} vertices)", self.dense.map.len())
    }
}
