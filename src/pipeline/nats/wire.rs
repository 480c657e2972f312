//! What travels through NATS JetStream: message and object formats.
//!
//! A message is small: the job (number, key, name, timings), the payload's object keys and
//! its small metadata, or the job's failure. Large parts — input files, meshes, spectra,
//! predictions, dense maps, model versions — go to the JetStream object store under the
//! SHA-256 of their bytes (content-addressed: a part already stored is not uploaded again).
//! Everything is serde + rmp-serde. Every message and object starts with its format name and
//! version ([`FORMAT_VERSION`]); a reader refuses a name or version it does not know with an
//! error that says so, and never guesses.

use std::path::Path;

use serde::{de::DeserializeOwned, Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::{
    forest::Prediction,
    geodesic::{HeatBoundary, HeatParams},
    matching::{GameMatching, WeightedMatch},
    mesh::Mesh,
    regularizer::{DenseMap, RegularizerTimings, SparseMatches, VertexMatch},
    spectral::Spectrum,
};

/// The version of every format below. A reader accepts exactly the versions it knows.
///
/// Version 2: every edge of the graph travels (shape, spectrum, descriptor, prediction and
/// sparse-match messages), and the map message no longer carries the spectrum (its consumers,
/// the sinks, never read it).
pub const FORMAT_VERSION: u32 = 2;

/// Header naming a message's format (`shapeforest.file`, `shapeforest.map`).
pub const FORMAT_HEADER: &str = "Shapeforest-Format";
/// Header with the format's version.
pub const VERSION_HEADER: &str = "Shapeforest-Version";
/// Header with the job's key (for a message that cannot be read: its report still names it).
pub const KEY_HEADER: &str = "Shapeforest-Key";
/// Header with the job's shape name.
pub const NAME_HEADER: &str = "Shapeforest-Name";

/// The SHA-256 of `bytes`, as lower-case hex: an object's key.
///
/// ```
/// use shapeforest::pipeline::nats::wire::content_key;
/// assert_eq!(&content_key(b"abc")[..16], "ba7816bf8f01cfea");
/// ```
pub fn content_key(bytes: &[u8]) -> String {
    let d = Sha256::digest(bytes);
    d.iter().map(|b| format!("{b:02x}")).collect()
}

/// Wraps a value in its format name and version (what every message and object holds).
#[derive(Serialize, Deserialize)]
struct Framed<T> {
    format: String,
    version: u32,
    value: T,
}

#[derive(Deserialize)]
struct FrameHead {
    format: String,
    version: u32,
}

/// Encodes `value` as format `format` (rmp-serde, with field names so that a reader can tell
/// formats apart).
pub fn encode<T: Serialize>(format: &str, value: &T) -> Result<Vec<u8>, String> {
    rmp_serde::to_vec_named(&Framed { format: format.to_string(), version: FORMAT_VERSION, value })
        .map_err(|e| format!("cannot encode {format}: {e}"))
}

/// Decodes bytes written by [`encode`] as `format`, refusing another format or an unknown
/// version.
///
/// ```
/// use shapeforest::pipeline::nats::wire::{decode, encode};
/// let b = encode("shapeforest.test", &vec![1u32, 2]).unwrap();
/// assert_eq!(decode::<Vec<u32>>("shapeforest.test", &b).unwrap(), vec![1, 2]);
/// assert!(decode::<Vec<u32>>("shapeforest.other", &b).unwrap_err().contains("shapeforest.test"));
/// assert!(decode::<Vec<u32>>("shapeforest.test", b"junk").is_err());
/// ```
pub fn decode<T: DeserializeOwned>(format: &str, bytes: &[u8]) -> Result<T, String> {
    let head: FrameHead = rmp_serde::from_slice(bytes)
        .map_err(|e| format!("not a shapeforest {format} (cannot read its header: {e})"))?;
    if head.format != format {
        return Err(format!("expected {format}, found {}", crate::limits::escape_name(&head.format)));
    }
    check_version(format, head.version)?;
    let f: Framed<T> =
        rmp_serde::from_slice(bytes).map_err(|e| format!("{format} version {}: {e}", head.version))?;
    Ok(f.value)
}

/// Whether this build reads `version` of `format`.
pub fn check_version(format: &str, version: u32) -> Result<(), String> {
    if version != FORMAT_VERSION {
        return Err(format!(
            "{format} version {version} is not known to this worker (it reads version {FORMAT_VERSION}); \
             a newer shapeforest wrote it"
        ));
    }
    Ok(())
}

/// A job as it travels: everything of [`crate::pipeline::Job`] that means something on
/// another machine (not its local paths).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct WireJob {
    /// Job number.
    pub id: u64,
    /// Unique key of the job: its input's content key and a nonce (`HASH16-NONCE`); the
    /// idempotent sink and the streams' de-duplication use it.
    pub key: String,
    /// Shape name.
    pub name: String,
    /// The file name the input arrived under.
    pub arrived_as: Option<String>,
    /// Seconds spent in each stage so far.
    pub stage_seconds: Vec<(String, f64)>,
    /// When the job entered the system (milliseconds since the Unix epoch), for latencies.
    pub submitted_unix_ms: u64,
}

/// A failure as it travels.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct WireFailure {
    /// The stage that failed.
    pub stage: String,
    /// `bad-input` or `internal` (interrupted jobs are not sent: they are redelivered).
    pub kind: String,
    /// The error.
    pub message: String,
}

/// An object of the store, named by its content key.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct BlobRef {
    /// Content key (SHA-256 hex).
    pub key: String,
    /// Size in bytes.
    pub size: u64,
}

/// A file of a job (input, label map, companion): its name and contents' key.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct WireFileRef {
    /// File name (no folder).
    pub name: String,
    /// Its contents.
    pub blob: BlobRef,
}

/// The payload of a `file` edge: an input file and what travels with it.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct WireInput {
    /// The mesh file.
    pub mesh: WireFileRef,
    /// Its label map, for a labelled shape.
    pub labels: Option<WireFileRef>,
    /// Label = vertex index (a class sharing one vertex indexing).
    pub identity_labels: bool,
    /// Files that travel with it (the `.tri` of a TOSCA `.vert`).
    pub companions: Vec<WireFileRef>,
}

/// The payload of a `shape` edge: a mesh and, for a labelled shape, its labels.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct WireShape {
    /// [`Mesh`], format `shapeforest.mesh`.
    pub mesh: BlobRef,
    /// Per-vertex labels, format `shapeforest.labels` (labelled shapes only).
    pub labels: Option<BlobRef>,
}

/// The payload of a `spectrum` edge: the shape, its spectrum and, for a scan matched on a
/// part of itself, how the part was made.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct WireSpectral {
    /// The shape matched (for a partial scan: the part).
    pub shape: WireShape,
    /// [`Spectrum`], format `shapeforest.spectrum`.
    pub spectrum: BlobRef,
    /// For a scan matched on a part of itself: the whole scan and how the part was made.
    pub partial: Option<WirePartial>,
}

/// The payload of a `descriptor` edge: the spectral shape and the model version the
/// descriptor is made with. The descriptor itself does not travel: it is a pure function of
/// the spectrum and the model (`ForestDescriptor` keeps its arrays private), so the receiver
/// makes it again from the two (the descriptor stage takes ~0.05 s at 20K vertices).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct WireDescribed {
    /// The shape and its spectrum.
    pub spectral: WireSpectral,
    /// The model version (its bundle is in the store, see `model_sync`).
    pub model_version: u64,
}

/// The payload of a `prediction` edge.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct WirePredicted {
    /// The shape and its spectrum.
    pub spectral: WireSpectral,
    /// The model version the prediction was made with.
    pub model_version: u64,
    /// [`Prediction`], format `shapeforest.prediction`.
    pub prediction: BlobRef,
}

/// The payload of a `matches` edge: the prediction, the sparse matches and the heat-method
/// parameters the matcher prepared the shape with (the factorisation itself does not travel:
/// the receiver factorises again from the mesh).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct WireSparselyMatched {
    /// The prediction it came from.
    pub predicted: WirePredicted,
    /// [`SparseMatches`], format `shapeforest.sparse-matches`.
    pub sparse: BlobRef,
    /// Heat-method time factor.
    pub heat_time_factor: f64,
    /// Heat-method boundary condition: `neumann`, `dirichlet` or `average`.
    pub heat_boundary: String,
}

/// The heat parameters as they travel.
pub fn heat_to_wire(h: &HeatParams) -> (f64, String) {
    let b = match h.boundary {
        HeatBoundary::Neumann => "neumann",
        HeatBoundary::Dirichlet => "dirichlet",
        HeatBoundary::Average => "average",
    };
    (h.time_factor, b.to_string())
}

/// The heat parameters back, refusing an unknown boundary condition.
pub fn heat_from_wire(time_factor: f64, boundary: &str) -> Result<HeatParams, String> {
    let boundary = match boundary {
        "neumann" => HeatBoundary::Neumann,
        "dirichlet" => HeatBoundary::Dirichlet,
        "average" => HeatBoundary::Average,
        other => {
            return Err(format!("unknown heat boundary condition {:?}", crate::limits::escape_name(other)))
        }
    };
    if !(time_factor.is_finite() && time_factor > 0.0) {
        return Err(format!("heat time factor {time_factor} is not a positive number"));
    }
    Ok(HeatParams { time_factor, boundary })
}

/// The payload of a `map` edge: a matched scan, every part in the object store. The spectrum
/// does not travel (the map's consumers, the sinks, never read it; it was ~5× the rest of the
/// objects at 20K vertices): a map read back carries a spectrum without eigenpairs (see
/// `MapCodec`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct WireMatched {
    /// [`Mesh`], format `shapeforest.mesh`.
    pub mesh: BlobRef,
    /// Per-vertex labels, format `shapeforest.labels` (labelled shapes only).
    pub labels: Option<BlobRef>,
    /// The area of the mesh the spectrum was computed on (kept with the empty spectrum).
    pub spectrum_area: f64,
    /// [`Prediction`], format `shapeforest.prediction`.
    pub prediction: BlobRef,
    /// [`DenseMap`], format `shapeforest.dense-map`.
    pub dense: BlobRef,
    /// The model version the job was matched with (its bundle is `model-vN` in the store).
    pub model_version: u64,
    /// For a scan matched on a part of itself: the whole scan and how the part was made.
    pub partial: Option<WirePartial>,
}

/// A scan matched on a part of itself ([`crate::pipeline::PartialScan`]).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct WirePartial {
    /// The whole scan, format `shapeforest.mesh`.
    pub scan: BlobRef,
    /// The part, format `shapeforest.mesh`.
    pub part: BlobRef,
    /// `kept[i]`: the scan vertex that part vertex `i` is, format `shapeforest.kept`.
    pub kept: Option<BlobRef>,
    /// Connected components of the scan.
    pub components: usize,
    /// Holes closed for the spectrum.
    pub holes_closed: usize,
    /// The area the part's spectrum is normalised by, relative to its own.
    pub scale_ratio: f64,
}

/// A message: the job and its payload or failure.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct WireEnvelope<B> {
    /// The job.
    pub job: WireJob,
    /// The payload, or why there is none.
    pub body: Result<B, WireFailure>,
}

/// Format name of a mesh object.
pub const MESH: &str = "shapeforest.mesh";
/// Format name of a labels object.
pub const LABELS: &str = "shapeforest.labels";
/// Format name of the vertex list of a scan's part.
pub const KEPT: &str = "shapeforest.kept";
/// Format name of a spectrum object.
pub const SPECTRUM: &str = "shapeforest.spectrum";
/// Format name of a prediction object.
pub const PREDICTION: &str = "shapeforest.prediction";
/// Format name of a dense-map object.
pub const DENSE_MAP: &str = "shapeforest.dense-map";
/// Format name of a model bundle object.
pub const MODEL_BUNDLE: &str = "shapeforest.model-bundle";
/// Format name of a `file` message.
pub const FILE_MESSAGE: &str = "shapeforest.file";
/// Format name of a `map` message.
pub const MAP_MESSAGE: &str = "shapeforest.map";
/// Format name of a `shape` message.
pub const SHAPE_MESSAGE: &str = "shapeforest.shape";
/// Format name of a `spectrum` message.
pub const SPECTRUM_MESSAGE: &str = "shapeforest.spectral-shape";
/// Format name of a `descriptor` message.
pub const DESCRIPTOR_MESSAGE: &str = "shapeforest.described-shape";
/// Format name of a `prediction` message.
pub const PREDICTION_MESSAGE: &str = "shapeforest.predicted-shape";
/// Format name of a `matches` message.
pub const MATCHES_MESSAGE: &str = "shapeforest.sparsely-matched";
/// Format name of a sparse-matches object.
pub const SPARSE_MATCHES: &str = "shapeforest.sparse-matches";

/// A prediction's arrays (it keeps them private; [`Prediction::from_parts`] checks them again
/// when read back).
#[derive(Serialize, Deserialize)]
pub struct WirePrediction {
    n_labels: usize,
    offsets: Vec<usize>,
    labels: Vec<u32>,
    probs: Vec<f32>,
}

impl WirePrediction {
    /// The arrays of `p`.
    pub fn of(p: &Prediction) -> Self {
        let n = p.n_vertices();
        let mut offsets = Vec::with_capacity(n + 1);
        let (mut labels, mut probs) = (Vec::new(), Vec::new());
        offsets.push(0);
        for v in 0..n {
            let (l, q) = p.posterior(v);
            labels.extend_from_slice(l);
            probs.extend_from_slice(q);
            offsets.push(labels.len());
        }
        Self { n_labels: p.n_labels(), offsets, labels, probs }
    }

    /// The prediction, checked.
    pub fn into_prediction(self) -> Result<Prediction, String> {
        Prediction::from_parts(self.n_labels, self.offsets, self.labels, self.probs)
            .map_err(|e| e.to_string())
    }
}

/// A dense matrix, column-major (faer's `Mat` has no serde of its own).
#[derive(Serialize, Deserialize)]
struct WireMat {
    rows: usize,
    cols: usize,
    data: Vec<f64>,
}

impl WireMat {
    fn of(m: &faer::Mat<f64>) -> Self {
        let mut data = Vec::with_capacity(m.nrows() * m.ncols());
        for j in 0..m.ncols() {
            for i in 0..m.nrows() {
                data.push(m[(i, j)]);
            }
        }
        Self { rows: m.nrows(), cols: m.ncols(), data }
    }

    fn into_mat(self) -> Result<faer::Mat<f64>, String> {
        if self.rows.checked_mul(self.cols) != Some(self.data.len()) {
            return Err(format!("a {}×{} matrix with {} entries", self.rows, self.cols, self.data.len()));
        }
        Ok(faer::Mat::from_fn(self.rows, self.cols, |i, j| self.data[j * self.rows + i]))
    }
}

/// Every field of a [`DenseMap`].
#[derive(Serialize, Deserialize)]
pub struct WireDense {
    map: Vec<usize>,
    anchor_map: Vec<usize>,
    grown_anchors: usize,
    dense_orientation: Option<f64>,
    reoriented: bool,
    spectral_map: Option<Vec<usize>>,
    fmap_map: Option<Vec<usize>>,
    grown_map: Option<Vec<usize>>,
    forest_map: Vec<Option<usize>>,
    fmap_predicted: WireMat,
    fmap: WireMat,
    matches: Vec<VertexMatch>,
    orientation_score: f64,
    mirror_rejected: bool,
    #[serde(default)]
    prediction_mirrored: bool,
    timings: RegularizerTimings,
    #[serde(default)]
    alternative_kept: bool,
}

impl WireDense {
    /// The fields of `d`.
    pub fn of(d: &DenseMap) -> Self {
        Self {
            map: d.map.clone(),
            anchor_map: d.anchor_map.clone(),
            grown_anchors: d.grown_anchors,
            dense_orientation: d.dense_orientation,
            reoriented: d.reoriented,
            spectral_map: d.spectral_map.clone(),
            fmap_map: d.fmap_map.clone(),
            grown_map: d.grown_map.clone(),
            forest_map: d.forest_map.clone(),
            fmap_predicted: WireMat::of(&d.fmap_predicted),
            fmap: WireMat::of(&d.fmap),
            matches: d.matches.clone(),
            orientation_score: d.orientation_score,
            mirror_rejected: d.mirror_rejected,
            prediction_mirrored: d.prediction_mirrored,
            timings: d.timings,
            alternative_kept: d.alternative_kept,
        }
    }

    /// The dense map, checked against the scan's vertex count.
    pub fn into_dense(self, n_vertices: usize) -> Result<DenseMap, String> {
        if self.map.len() != n_vertices {
            return Err(format!("dense map: {} entries for {n_vertices} vertices", self.map.len()));
        }
        Ok(DenseMap {
            map: self.map,
            anchor_map: self.anchor_map,
            grown_anchors: self.grown_anchors,
            dense_orientation: self.dense_orientation,
            reoriented: self.reoriented,
            spectral_map: self.spectral_map,
            fmap_map: self.fmap_map,
            grown_map: self.grown_map,
            forest_map: self.forest_map,
            fmap_predicted: self.fmap_predicted.into_mat()?,
            fmap: self.fmap.into_mat()?,
            matches: self.matches,
            orientation_score: self.orientation_score,
            mirror_rejected: self.mirror_rejected,
            prediction_mirrored: self.prediction_mirrored,
            alternative_kept: self.alternative_kept,
            timings: self.timings,
        })
    }
}

/// Every field of [`SparseMatches`] (the distance fields as matrices, the game's matches).
#[derive(Serialize, Deserialize)]
pub struct WireSparse {
    samples: Vec<usize>,
    ref_points: Vec<usize>,
    test_fields: WireMat,
    ref_fields: WireMat,
    game_matches: Vec<(usize, usize, f64)>,
    game_iterations: usize,
    game_converged: bool,
    game_payoff: f64,
    matches: Vec<VertexMatch>,
    orientation_score: f64,
    mirror_rejected: bool,
    #[serde(default)]
    prediction_mirrored: bool,
    timings: RegularizerTimings,
    /// [`SparseMatches::alternative`].
    #[serde(default)]
    alternative: Option<Box<WireSparse>>,
}

impl WireSparse {
    /// The fields of `s`.
    pub fn of(s: &SparseMatches) -> Self {
        Self {
            samples: s.samples.clone(),
            ref_points: s.ref_points.clone(),
            test_fields: WireMat::of(&s.test_fields),
            ref_fields: WireMat::of(&s.ref_fields),
            game_matches: s.game.matches.iter().map(|m| (m.test, m.reference, m.weight)).collect(),
            game_iterations: s.game.iterations,
            game_converged: s.game.converged,
            game_payoff: s.game.payoff,
            matches: s.matches.clone(),
            orientation_score: s.orientation_score,
            mirror_rejected: s.mirror_rejected,
            prediction_mirrored: s.prediction_mirrored,
            timings: s.timings,
            alternative: s.alternative.as_deref().map(|a| Box::new(Self::of(a))),
        }
    }

    /// The sparse matches, checked against the scan's and the reference's vertex counts.
    pub fn into_sparse(self, n_test: usize, n_ref: usize) -> Result<SparseMatches, String> {
        // One level: the alternative of an alternative is not a thing the matcher sends.
        let alternative = match self.alternative {
            Some(a) if a.alternative.is_some() => return Err("nested alternative sparse matches".into()),
            Some(a) => Some(Box::new(a.into_sparse(n_test, n_ref)?)),
            None => None,
        };
        let test_fields = self.test_fields.into_mat()?;
        let ref_fields = self.ref_fields.into_mat()?;
        let bad = self.samples.iter().any(|&v| v >= n_test)
            || self.ref_points.iter().any(|&v| v >= n_ref)
            || self.matches.iter().any(|m| m.test >= n_test || m.reference >= n_ref)
            || self
                .game_matches
                .iter()
                .any(|&(t, r, _)| t >= self.samples.len() || r >= self.ref_points.len())
            || (test_fields.ncols() > 0 && test_fields.nrows() != n_test)
            || (ref_fields.ncols() > 0 && ref_fields.nrows() != n_ref)
            || test_fields.ncols() != ref_fields.ncols();
        if bad {
            return Err(format!("sparse matches of other shapes (not {n_test} and {n_ref} vertices)"));
        }
        Ok(SparseMatches {
            samples: self.samples,
            ref_points: self.ref_points,
            test_fields,
            ref_fields,
            game: GameMatching {
                matches: self
                    .game_matches
                    .into_iter()
                    .map(|(test, reference, weight)| WeightedMatch { test, reference, weight })
                    .collect(),
                iterations: self.game_iterations,
                converged: self.game_converged,
                payoff: self.game_payoff,
            },
            matches: self.matches,
            orientation_score: self.orientation_score,
            mirror_rejected: self.mirror_rejected,
            prediction_mirrored: self.prediction_mirrored,
            timings: self.timings,
            alternative,
        })
    }
}

/// A model version as one object: the files of a data folder that [`crate::pipeline::load_live_model`]
/// reads (the manifest and model file in `models/`, the reference's mesh and label map in
/// `training/`), by path relative to the data folder.
#[derive(Serialize, Deserialize)]
pub struct ModelBundle {
    /// Model version.
    pub version: u64,
    /// `(relative path, contents)`.
    pub files: Vec<(String, Vec<u8>)>,
}

impl ModelBundle {
    /// Writes the files below `root`, refusing paths that would leave it.
    pub fn unpack(&self, root: &Path) -> Result<(), String> {
        for (rel, bytes) in &self.files {
            let p = Path::new(rel);
            let ok = p.components().count() == 2
                && p.components().all(|c| matches!(c, std::path::Component::Normal(_)))
                && (rel.starts_with("models/") || rel.starts_with("training/"));
            if !ok {
                return Err(format!("model bundle v{}: a file outside models/ and training/", self.version));
            }
            let path = root.join(p);
            if let Some(d) = path.parent() {
                std::fs::create_dir_all(d).map_err(|e| format!("{}: {e}", d.display()))?;
            }
            crate::pipeline::atomic_write(&path, bytes).map_err(|e| format!("{}: {e}", path.display()))?;
        }
        Ok(())
    }
}

/// A mesh, for the store.
pub fn mesh_bytes(mesh: &Mesh) -> Result<Vec<u8>, String> {
    encode(MESH, mesh)
}

/// A spectrum, for the store.
pub fn spectrum_bytes(s: &Spectrum) -> Result<Vec<u8>, String> {
    encode(SPECTRUM, s)
}

#[cfg(test)]
mod tests {
    use faer::Mat;

    use super::*;

    fn sparse(n_test: usize, n_ref: usize, reference: usize) -> SparseMatches {
        SparseMatches {
            samples: vec![0, 1],
            ref_points: vec![reference, 2],
            test_fields: Mat::from_fn(n_test, 1, |v, _| v as f64),
            ref_fields: Mat::from_fn(n_ref, 1, |v, _| 2.0 * v as f64),
            game: GameMatching {
                matches: vec![WeightedMatch { test: 0, reference: 0, weight: 1.0 }],
                iterations: 3,
                converged: true,
                payoff: 0.5,
            },
            matches: vec![VertexMatch { test: 0, reference, weight: 1.0 }],
            orientation_score: 0.25,
            mirror_rejected: false,
            prediction_mirrored: false,
            timings: RegularizerTimings::default(),
            alternative: None,
        }
    }

    #[test]
    fn a_single_views_second_equilibrium_travels_with_the_sparse_matches() {
        let mut s = sparse(4, 5, 1);
        s.alternative = Some(Box::new(sparse(4, 5, 3)));
        let bytes = encode(SPARSE_MATCHES, &WireSparse::of(&s)).unwrap();
        let back = decode::<WireSparse>(SPARSE_MATCHES, &bytes).unwrap().into_sparse(4, 5).unwrap();
        assert_eq!(back.matches[0].reference, 1);
        let alternative = back.alternative.expect("the alternative was lost on the wire");
        assert_eq!(alternative.matches[0].reference, 3);
        assert_eq!(alternative.ref_fields[(4, 0)], 8.0);
        // Checked as the first is: sparse matches of other shapes are refused.
        assert!(decode::<WireSparse>(SPARSE_MATCHES, &bytes).unwrap().into_sparse(4, 3).is_err());
        let mut nested = sparse(4, 5, 3);
        nested.alternative = Some(Box::new(sparse(4, 5, 1)));
        s.alternative = Some(Box::new(nested));
        let err = WireSparse::of(&s).into_sparse(4, 5).err().unwrap();
        assert!(err.contains("nested"), "{err}");
    }
}
