//! The paper's evaluation protocol on a class of shapes with ground truth.
//!
//! For each test shape of a class: train a forest on `n_train` other shapes of the class (a
//! seeded random choice), predict the test shape's posterior, regularise it against a reference
//! (the first training shape) and measure the normalised geodesic error (see [`super`]) at a
//! fixed, seeded subset of ground-truth points. Four methods are measured on the same points:
//!
//! | [`Method`] | map |
//! |---|---|
//! | `ForestRaw` | the forest's maximum-a-posteriori label of each vertex |
//! | `ForestRegularized` | the regulariser's output ([`crate::regularizer::DenseMap::map`]) on the forest posterior |
//! | `WksKnnRaw` | the most voted label of the `k` nearest training WKS descriptors |
//! | `WksKnnRegularized` | the same regulariser on the WKS k-NN posterior |
//!
//! The WKS k-NN baseline uses the forest's energy range and eigenpair count, and `k` = the
//! forest's mean posterior support on the test shape (rounded), so both give the regulariser
//! posteriors of the same size.
//!
//! **Ground truth.** Every shape carries a table `truth[label] = vertex`: the labels are the
//! points that correspond across the class. For a TOSCA/SCAPE class with common vertex indexing
//! the table is the identity; for remeshed shapes (`.vts` files) row `k` of each shape's table is
//! its vertex for correspondence `k`. The forest is trained with these labels, and the label →
//! reference-vertex table of the regulariser is the reference's truth table.
//!
//! **Errors.** For an evaluated label `k`, the test vertex `truth_test[k]` is mapped to a
//! reference vertex `r`; its error is the geodesic distance on the reference from
//! `truth_ref[k]` to `r`, divided by `√area(reference)`. Distances come from the crate's heat
//! method ([`HeatMethodSolver`], time step `t = h²` with `h` the mean edge length, as Crane et
//! al. recommend), one distance field per evaluated point, computed once per reference. With a
//! symmetry map of the labels (`symmetry[k]` is the label at the left/right mirror image of `k`),
//! symmetric errors are reported beside the strict ones: a match counts as correct when it lands
//! near the ground truth or near its mirror image, `min(d(r, truth_ref[k]),
//! d(r, truth_ref[symmetry[k]]))` (the "symmetric ground truth" of Kim et al. 2011). This needs
//! no symmetry in vertex space, so it also works for remeshed shapes whose labels cover only
//! some of the reference's vertices; it costs a second set of distance fields.
//!
//! The protocol is pure orchestration: no printing; progress is reported through an optional
//! callback. Spectra go through a [`SpectrumCache`] when a cache directory is given.

use std::{collections::HashMap, path::PathBuf, sync::Arc, time::Instant};

use faer::Mat;
use rand::{seq::index::sample, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{geodesic_errors, EvalError};
use crate::{
    descriptor::{LocalParams, WksParams},
    forest::{
        augmented_copies, Augmentation, Prediction, RandomForest, RandomForestParams, TrainingSet,
        TrainingShape, WksKnn,
    },
    geodesic::{HeatMethodSolver, HeatParams},
    mesh::{perturb, perturbations_name, Mesh, Perturbation},
    regularizer::{
        poses_by_nearness, regularize, reversed_area, through_labels, view_orientation, DenseMap,
        PreparedShape, RegularizerParams, ScanPart, UNFLIP_THRESHOLD,
    },
    spectral::{spectrum_cached, Spectrum, SpectrumCache, SpectrumParams},
};

/// Relays kept prepared between tests besides those a test votes with or tries (each holds a
/// spectrum, a heat factorisation and its kept distance columns): as many as a doubted map
/// votes with, so that the poses a doubt tries do not send away the relay most tests go
/// through (it would be prepared again, its columns solved again).
const RELAYS_KEPT: usize = DOUBT_VOTES;

/// CPU seconds (user and system, every thread) the process has used so far; NaN where the
/// platform does not report them.
fn process_cpu_s() -> f64 {
    #[cfg(unix)]
    {
        let mut usage = std::mem::MaybeUninit::<libc::rusage>::uninit();
        // SAFETY: getrusage writes a whole `rusage` into the pointer it is given and returns 0,
        // or returns -1 (then nothing is read).
        if unsafe { libc::getrusage(libc::RUSAGE_SELF, usage.as_mut_ptr()) } == 0 {
            // SAFETY: written by the successful call above.
            let usage = unsafe { usage.assume_init() };
            let seconds = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
            return seconds(usage.ru_utime) + seconds(usage.ru_stime);
        }
    }
    f64::NAN
}

/// One shape of the evaluated class with its ground-truth table.
#[derive(Clone, Debug)]
pub struct ProtocolShape {
    /// Name used in reports (e.g. the file stem).
    pub name: String,
    /// The mesh.
    pub mesh: Arc<Mesh>,
    /// `truth[label]` = this shape's vertex for the label; the same length for every shape.
    pub truth: Vec<usize>,
}

impl ProtocolShape {
    /// A shape whose labels are its vertex indices (TOSCA/SCAPE classes, synthetic families).
    pub fn identity(name: impl Into<String>, mesh: Arc<Mesh>) -> Self {
        let truth = (0..mesh.n_vertices()).collect();
        Self { name: name.into(), mesh, truth }
    }
}

/// Settings of the protocol.
#[derive(Clone, Debug)]
pub struct ProtocolParams {
    /// Training shapes per test shape (default 6, as in the paper).
    pub n_train: usize,
    /// At most this many test shapes (default: all).
    pub max_tests: Option<usize>,
    /// Draw one training set for all tests (the tests are the remaining shapes) instead of one
    /// per test shape. Default `false`.
    pub train_once: bool,
    /// Seed of the training-set and evaluation-point choices.
    pub seed: u64,
    /// Number of evaluated ground-truth points per test (default 1000; all when fewer labels).
    pub eval_points: usize,
    /// Forest hyper-parameters.
    pub forest: RandomForestParams,
    /// Spectrum settings (default 100 eigenpairs).
    pub spectrum: SpectrumParams,
    /// Regulariser settings.
    pub regularizer: RegularizerParams,
    /// Heat-method settings of the evaluation distance fields.
    pub eval_heat: HeatParams,
    /// Spectrum cache directory (`None`: no cache).
    pub cache_dir: Option<PathBuf>,
    /// Steps of the cumulative curves (default 100).
    pub curve_steps: usize,
    /// Perturbations applied, in order, to every test shape before it is matched (holes, a
    /// single-view scan, a crop, noise; see [`crate::mesh::perturb`]), seeded per test shape.
    /// Errors are measured only at the evaluated points the perturbed scan still has.
    pub perturbations: Vec<Perturbation>,
    /// Skip the WKS k-NN baseline (its rows are then absent from the report).
    pub skip_baseline: bool,
    /// Match only the largest connected component of a scan in pieces; the vertices of the
    /// other pieces take the match of their nearest matched vertex (default `true`; see
    /// [`crate::mesh::largest_component`]).
    pub largest_component: bool,
    /// Normalise an open, partial scan by the reference's area instead of its own (default
    /// `true`; see [`crate::regularizer::normalising_area`]).
    pub partial_scale: bool,
    /// Close the holes of a perturbed scan whose perimeter is at most this fraction of the
    /// reference's `√area` before its spectrum is computed (see [`ScanPart::filled`]); `None`:
    /// leave them open. Default `Some(0.35)` (a round hole of radius ~0.055·√area).
    pub fill_holes: Option<f64>,
    /// Training-set augmentation: for every kind (a perturbation list), `augment_copies`
    /// seeded perturbed copies of each training shape join the training set (see
    /// [`crate::forest::augmented_shape`]). Default: none.
    pub augment: Vec<Vec<Perturbation>>,
    /// Copies per training shape and augmentation kind (default 15: on single views of SCAPE,
    /// 4 copies reach 17.9 % within 0.05, 15 copies 26.1 %, 60 copies 29.1 %).
    pub augment_copies: usize,
    /// Let the forest split on local histograms of the surface ([`LocalParams`]) besides the
    /// parametric WKS: every training shape and copy carries them, and each test's are computed
    /// on its (perturbed) mesh. Default none (WKS only).
    pub local: Option<LocalParams>,
    /// Diagnose every test ([`TestResult::diagnosis`]): how many evaluated points are right
    /// at each stage of the regulariser, and with each of these variants of its settings
    /// (named). Default off.
    pub diagnose: Option<Vec<(String, RegularizerParams)>>,
    /// Regularise each test shape onto the training shape in the pose nearest its own (a
    /// relay, or the reference itself) and carry the map back to the reference through the
    /// labels (see [`crate::regularizer::nearest_pose`]; the WKS baseline goes onto the same
    /// shape). Default `true`; off while diagnosing (the diagnosis reads the regulariser's
    /// stages on the reference).
    pub relay: bool,
    /// With `relay`: regularise onto this many of the nearest poses (the reference among the
    /// candidates) and vote per vertex among the maps carried to the reference
    /// ([`crate::regularizer::vote_maps`]; ties and the other outputs go to the nearest pose's).
    /// 1: the nearest pose alone. Each vote costs a regularisation. Default 1.
    pub relay_votes: usize,
    /// With `relay` and one vote: a map that reads as mirrored on more than this fraction of
    /// the scan's area ([`crate::regularizer::reversed_area`], a mirrored limb) is voted with
    /// the maps onto the next nearest poses, [`DOUBT_VOTES`] in all. `None`: never. Default
    /// `Some(`[`DOUBT_REVERSED_AREA`]`)`.
    pub doubt: Option<f64>,
    /// With `relay` and one vote, on a single view: a map whose orientation score reads below
    /// this ([`crate::regularizer::view_orientation`]: a map that folds or mirrors much of the
    /// view) is doubted too: the view is regularised onto the next nearest poses as well, one
    /// after another until a map reads at or above the threshold, [`DOUBT_VOTES`] poses at
    /// most, and the best oriented of the maps kept. `None`: never. Default
    /// `Some(`[`DOUBT_VIEW_ORIENTATION`]`)` (a doubted view costs up to three regularisations; README
    /// "Doubted views" and "Distance columns kept" measure its accuracy and time).
    pub doubt_view: Option<f64>,
}

/// Maps voted on a doubted map ([`ProtocolParams::doubt`]), the doubted one included.
pub const DOUBT_VOTES: usize = 3;

/// The default of [`ProtocolParams::doubt`]: a fiftieth of the scan's area reads as mirrored
/// (good maps of the hi-res classes read 0–1.8 %, and most of those above 2 % are the worst of
/// their class; README, "Relay votes").
pub const DOUBT_REVERSED_AREA: f64 = 0.02;

/// The default of [`ProtocolParams::doubt_view`] (README "Doubted views"): a single view's map
/// whose orientation score reads below 0.3 (SCAPE's views read 0.13–0.64 and the 13 % below 0.3
/// are matched at 44–82 %).
pub const DOUBT_VIEW_ORIENTATION: f64 = 0.3;

/// Where a test's wrong points come from (with [`ProtocolParams::diagnose`]): the fraction of
/// the evaluated points of the matched part within 0.05 (strict, and up to the mirror
/// symmetry) at each stage of the regulariser, in pipeline order.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Diagnosis {
    /// Evaluated points in the matched part (the denominators of the point rows).
    pub points: usize,
    /// Sparse matches of the game (the denominator of its row).
    pub matches: usize,
    /// `(stage, strict, up to symmetry)`: fractions within 0.05. Stages: `candidates` (the
    /// best of the forest's candidates of each point: what a placement among them can reach at
    /// most), `top-5 candidates`, `game matches` (of the sparse matches), `forest-raw`,
    /// `anchor map` (placed by the game's matches alone), `grown`, `final`, then
    /// `VARIANT grown` and `VARIANT final` for each variant.
    pub rows: Vec<(String, f64, f64)>,
}

impl Default for ProtocolParams {
    fn default() -> Self {
        Self {
            n_train: 6,
            max_tests: None,
            train_once: false,
            seed: 0,
            eval_points: 1000,
            forest: RandomForestParams::default(),
            spectrum: SpectrumParams::new(100),
            regularizer: RegularizerParams::default(),
            eval_heat: HeatParams::default(),
            cache_dir: None,
            curve_steps: 100,
            perturbations: Vec::new(),
            skip_baseline: false,
            largest_component: true,
            partial_scale: true,
            fill_holes: Some(ScanPart::FILL_PERIMETER),
            augment: Vec::new(),
            augment_copies: 15,
            local: None,
            diagnose: None,
            relay: true,
            relay_votes: 1,
            doubt: Some(DOUBT_REVERSED_AREA),
            doubt_view: Some(DOUBT_VIEW_ORIENTATION),
        }
    }
}

/// A measured method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Method {
    /// The forest's maximum-a-posteriori map.
    ForestRaw,
    /// The regularised forest (the method of the paper).
    ForestRegularized,
    /// The regularised forest refined by ZoomOut (when the regulariser's `zoomout` is set; the
    /// grown map where the refinement was not kept).
    ForestZoomOut,
    /// The WKS k-NN baseline's most voted label.
    WksKnnRaw,
    /// The WKS k-NN posterior through the same regulariser.
    WksKnnRegularized,
}

impl Method {
    /// All methods, in report order.
    pub const ALL: [Method; 5] = [
        Method::ForestRaw,
        Method::ForestRegularized,
        Method::ForestZoomOut,
        Method::WksKnnRaw,
        Method::WksKnnRegularized,
    ];

    /// A short name for tables and CSV files.
    ///
    /// ```
    /// use shapeforest::eval::protocol::Method;
    /// assert_eq!(Method::ForestRegularized.name(), "forest+reg");
    /// ```
    pub fn name(self) -> &'static str {
        match self {
            Method::ForestRaw => "forest-raw",
            Method::ForestRegularized => "forest+reg",
            Method::ForestZoomOut => "forest+reg+zo",
            Method::WksKnnRaw => "wks-knn-raw",
            Method::WksKnnRegularized => "wks-knn+reg",
        }
    }
}

/// Errors of one method on one test shape.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MethodErrors {
    /// The method.
    pub method: Method,
    /// Strict errors, one per evaluated point.
    pub strict: Vec<f64>,
    /// Symmetric errors, when a symmetry map was given.
    pub symmetric: Option<Vec<f64>>,
    /// The method's map: reference vertex of each test vertex (for pictures of the result).
    #[serde(default)]
    pub map: Vec<usize>,
}

/// Seconds spent per stage on one test shape (0 for a stage whose result was reused).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TestTimings {
    /// Training the forest (0 when a forest for the same training set was reused).
    pub train_s: f64,
    /// Fitting the WKS k-NN baseline (0 when reused).
    pub knn_fit_s: f64,
    /// Heat-method factorisation of the test shape (and of the reference and the relays when
    /// new).
    pub prepare_s: f64,
    /// Forest prediction.
    pub predict_s: f64,
    /// WKS k-NN prediction.
    pub knn_predict_s: f64,
    /// Regularising the forest posterior (a relay prepared meanwhile counted in `prepare_s`
    /// only).
    pub regularize_s: f64,
    /// Regularising the WKS k-NN posterior.
    pub knn_regularize_s: f64,
    /// Distance fields for the evaluation on the reference (0 when reused).
    pub eval_fields_s: f64,
    /// CPU time (user and system, every thread of the process) from the scan's preparation to
    /// the end of its regularisation: the work behind `prepare_s`, `predict_s` and
    /// `regularize_s`, which other programs running beside the evaluation inflate much less than
    /// those wall-clock seconds (NaN where the platform does not report it).
    pub scan_cpu_s: f64,
}

impl TestTimings {
    /// Every stage as `(table heading, CSV column, seconds)`, in report order.
    pub fn stages(&self) -> [(&'static str, &'static str, f64); 8] {
        [
            ("train", "train_s", self.train_s),
            ("knn-fit", "knn_fit_s", self.knn_fit_s),
            ("prepare", "prepare_s", self.prepare_s),
            ("predict", "predict_s", self.predict_s),
            ("regular.", "regularize_s", self.regularize_s),
            ("knn", "knn_predict_s", self.knn_predict_s),
            ("knn-reg", "knn_regularize_s", self.knn_regularize_s),
            ("eval-gt", "eval_fields_s", self.eval_fields_s),
        ]
    }
}

/// The result of one test shape.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TestResult {
    /// Test shape (index into the input list).
    pub test: usize,
    /// Reference shape (the first training shape).
    pub reference: usize,
    /// The training shape the test was regularised onto when it was not the reference (the one
    /// in the nearest pose, see [`ProtocolParams::relay`]); its map was carried to the
    /// reference through the labels.
    #[serde(default)]
    pub relay: Option<usize>,
    /// The other shapes whose maps were voted with it ([`ProtocolParams::relay_votes`], or
    /// [`ProtocolParams::doubt`] on a doubted map).
    #[serde(default)]
    pub votes: Vec<usize>,
    /// The share of the scan's area where the map onto the nearest pose (before it is carried to
    /// the reference) reads as mirrored ([`crate::regularizer::reversed_area`]); measured with
    /// one vote.
    #[serde(default)]
    pub reversed_area: Option<f64>,
    /// A doubted single view ([`ProtocolParams::doubt_view`]): the poses it was regularised onto
    /// besides the one whose map was kept (`relay`, or the reference when `relay` is `None`).
    #[serde(default)]
    pub tried: Vec<usize>,
    /// On a single view, the orientation score of the map from the nearest pose onto the
    /// reference ([`crate::regularizer::view_orientation`]); measured with one vote and no
    /// doubt of a mirrored part.
    #[serde(default)]
    pub view_orientation: Option<f64>,
    /// Whether the forest's prediction read as a mirror image as a whole and the regulariser
    /// read it through the symmetry ([`crate::regularizer::DenseMap::prediction_mirrored`], of
    /// the map onto the nearest pose).
    #[serde(default)]
    pub prediction_mirrored: bool,
    /// Whether the map onto the nearest pose completes the game among `top_k` candidates,
    /// kept over the one among `part_top_k` on a single view ([`crate::regularizer::DenseMap::alternative_kept`]).
    #[serde(default)]
    pub alternative_kept: bool,
    /// Training shapes (indices into the input list, sorted).
    pub training: Vec<usize>,
    /// Whether the forest was reused from an earlier test with the same training set.
    pub forest_reused: bool,
    /// Mean posterior support of the forest on the test shape (also the baseline's `k`).
    pub mean_support: f64,
    /// The smallest leaf the test's forest was grown with (resolved when automatic:
    /// [`crate::forest::RandomForestValidParams::resolved_for`]).
    #[serde(default)]
    pub min_samples_leaf: usize,
    /// The number of trees of the test's forest (resolved when automatic).
    #[serde(default)]
    pub n_trees: usize,
    /// Orientation score of the regularised forest's matches (positive: not mirrored).
    pub orientation_score: f64,
    /// Number of sparse matches chosen by the regulariser on the forest posterior.
    pub n_matches: usize,
    /// Errors per method, in [`Method::ALL`] order.
    pub methods: Vec<MethodErrors>,
    /// Time per stage.
    pub timings: TestTimings,
    /// The perturbation of the test shape (`"none"`), see [`ProtocolParams::perturbations`].
    #[serde(default)]
    pub perturbation: String,
    /// Vertices of the scan that was matched (the perturbed test shape).
    #[serde(default)]
    pub scan_vertices: usize,
    /// Fraction of the test shape's area present in the scan (1 without perturbation).
    #[serde(default)]
    pub area_fraction: f64,
    /// Evaluated points present in the scan (the errors are theirs).
    #[serde(default)]
    pub present_points: usize,
    /// The scan vertex of each error (in the order of [`MethodErrors::strict`]).
    #[serde(default)]
    pub evaluated: Vec<usize>,
    /// The label of each error (a subset of [`ProtocolReport::eval_labels`]).
    #[serde(default)]
    pub labels: Vec<usize>,
    /// Whether each error's point lies in the part of the scan that was matched (its largest
    /// component; all `true` for a connected scan).
    #[serde(default)]
    pub in_matched_part: Vec<bool>,
    /// Vertices of the matched part of the scan.
    #[serde(default)]
    pub matched_part_vertices: usize,
    /// The area the scan was normalised by, relative to its own (1: its own area).
    #[serde(default)]
    pub scale_ratio: f64,
    /// The perturbed scan (`None` without perturbation: the scan is the test shape).
    #[serde(skip)]
    pub scan: Option<Arc<Mesh>>,
    /// Where the wrong points come from (with [`ProtocolParams::diagnose`]).
    #[serde(default)]
    pub diagnosis: Option<Diagnosis>,
}

impl TestResult {
    /// The errors of `method`.
    pub fn errors(&self, method: Method) -> Option<&MethodErrors> {
        self.methods.iter().find(|m| m.method == method)
    }

    /// The entries of `errors` (one per evaluated point, as [`MethodErrors::strict`]) at the
    /// points that lie in the matched part of the scan ([`TestResult::in_matched_part`]).
    pub fn matched_part_errors<'a>(&'a self, errors: &'a [f64]) -> impl Iterator<Item = f64> + 'a {
        errors.iter().zip(&self.in_matched_part).filter(|&(_, &inside)| inside).map(|(&e, _)| e)
    }
}

/// The result of the whole protocol.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ProtocolReport {
    /// Shape names, in input order.
    pub shape_names: Vec<String>,
    /// Evaluated labels (the same for every test), sorted.
    pub eval_labels: Vec<usize>,
    /// Seconds spent computing (or loading) each shape's spectrum, in input order (0 for shapes
    /// not used).
    pub spectrum_s: Vec<f64>,
    /// Whether symmetric errors were computed.
    pub has_symmetry: bool,
    /// One result per test shape.
    pub tests: Vec<TestResult>,
}

super::pooled_report!(ProtocolReport, Method, tests);

/// Progress of [`run_protocol`].
#[derive(Clone, Copy, Debug)]
pub enum ProtocolEvent<'a> {
    /// The spectrum of a shape is ready (`done` of `total`).
    Spectrum {
        /// Shapes done.
        done: usize,
        /// Shapes in all.
        total: usize,
        /// The shape.
        name: &'a str,
    },
    /// A stage of a test started.
    Stage {
        /// The test shape.
        test: &'a str,
        /// The stage: "train", "predict", "regularize", "baseline", "evaluate".
        stage: &'static str,
    },
    /// A test shape is done (`done` of `total`).
    TestDone {
        /// Tests done.
        done: usize,
        /// Tests in all.
        total: usize,
        /// The test shape.
        name: &'a str,
    },
}

/// The test shapes and their training sets (indices, each training set sorted, reference first
/// is `training[0]` of the *drawn* order).
fn plan(n_shapes: usize, params: &ProtocolParams) -> Vec<(usize, Vec<usize>)> {
    let mut rng = ChaCha8Rng::seed_from_u64(params.seed);
    let n_train = params.n_train.min(n_shapes - 1);
    let mut out = Vec::new();
    if params.train_once {
        let train = sample(&mut rng, n_shapes, n_train).into_vec();
        for t in (0..n_shapes).filter(|t| !train.contains(t)) {
            out.push((t, train.clone()));
        }
    } else {
        for t in 0..n_shapes {
            let others: Vec<usize> = (0..n_shapes).filter(|&o| o != t).collect();
            let train = sample(&mut rng, others.len(), n_train).into_iter().map(|i| others[i]).collect();
            out.push((t, train));
        }
    }
    if let Some(m) = params.max_tests {
        out.truncate(m);
    }
    out
}

/// A reference ready for evaluation: index, prepared shape, distance fields from the evaluated
/// ground-truth points and, with a symmetry map, from their mirror images.
type PreparedReference = (usize, PreparedShape, Mat<f64>, Option<Mat<f64>>);

fn invalid(msg: String) -> EvalError {
    EvalError::InvalidInput(msg)
}

/// Checks that `shapes` (at least one) have ground-truth tables of one length, with entries
/// inside their meshes, and that `symmetry` maps labels to labels; the number of labels.
pub(crate) fn check_shapes(shapes: &[ProtocolShape], symmetry: Option<&[usize]>) -> Result<usize, EvalError> {
    let Some(first) = shapes.first() else {
        return Err(invalid("no shapes given".into()));
    };
    let n_labels = first.truth.len();
    if n_labels == 0 {
        return Err(invalid(format!("shape {} has an empty ground-truth table", first.name)));
    }
    for s in shapes {
        if s.truth.len() != n_labels {
            return Err(invalid(format!(
                "shape {} has {} ground-truth points, {} has {n_labels}",
                s.name,
                s.truth.len(),
                first.name
            )));
        }
        if let Some(&v) = s.truth.iter().find(|&&v| v >= s.mesh.n_vertices()) {
            return Err(invalid(format!(
                "shape {}: ground-truth vertex {v} outside its {} vertices",
                s.name,
                s.mesh.n_vertices()
            )));
        }
    }
    if let Some(sym) = symmetry {
        if sym.len() != n_labels || sym.iter().any(|&k| k >= n_labels) {
            return Err(invalid(format!("symmetry map of {} entries for {n_labels} labels", sym.len())));
        }
    }
    Ok(n_labels)
}

/// Runs the protocol (see the module documentation) on `shapes`.
///
/// `symmetry`, when given, maps each label to the label at its mirror image (`symmetry[k]`
/// mirrors `k`; usually a permutation, which is not required); it enables the symmetric
/// figures. Needs at least 2 shapes, equal truth-table lengths, truth
/// entries inside their meshes, and `n_train ≥ 1`.
pub fn run_protocol(
    shapes: &[ProtocolShape],
    symmetry: Option<&[usize]>,
    params: &ProtocolParams,
    mut progress: Option<&mut dyn FnMut(ProtocolEvent<'_>)>,
) -> Result<ProtocolReport, EvalError> {
    if shapes.len() < 2 {
        return Err(invalid(format!("the protocol needs at least 2 shapes, got {}", shapes.len())));
    }
    if params.n_train == 0 {
        return Err(invalid("n_train must be at least 1".into()));
    }
    let n_labels = check_shapes(shapes, symmetry)?;
    let forest_params = params.forest.clone().check()?;
    let jobs = plan(shapes.len(), params);
    let cache = match &params.cache_dir {
        Some(d) => Some(SpectrumCache::new(d.clone())?),
        None => None,
    };

    // Spectra of every shape the plan uses.
    let mut used: Vec<usize> =
        jobs.iter().flat_map(|(t, tr)| std::iter::once(*t).chain(tr.iter().copied())).collect();
    used.sort_unstable();
    used.dedup();
    let mut spectra: Vec<Option<Arc<Spectrum>>> = vec![None; shapes.len()];
    let mut spectrum_s = vec![0.0; shapes.len()];
    for (i, &s) in used.iter().enumerate() {
        let t0 = Instant::now();
        let sp = spectrum_cached(&shapes[s].mesh, &params.spectrum, cache.as_ref())?;
        spectra[s] = Some(Arc::new(sp));
        spectrum_s[s] = t0.elapsed().as_secs_f64();
        if let Some(cb) = progress.as_mut() {
            cb(ProtocolEvent::Spectrum { done: i + 1, total: used.len(), name: &shapes[s].name });
        }
    }
    let spectrum_of =
        |s: usize| spectra[s].clone().ok_or_else(|| invalid(format!("no spectrum for {}", shapes[s].name)));

    // Evaluated labels: a seeded subset, the same for every test.
    let mut rng = ChaCha8Rng::seed_from_u64(params.seed ^ 0x9e37_79b9_7f4a_7c15);
    let mut eval_labels = if params.eval_points >= n_labels {
        (0..n_labels).collect::<Vec<_>>()
    } else {
        sample(&mut rng, n_labels, params.eval_points).into_vec()
    };
    eval_labels.sort_unstable();

    // Label vectors (vertex → label) for training.
    let labels_of = |s: &ProtocolShape| {
        let mut l = vec![None; s.mesh.n_vertices()];
        for (k, &v) in s.truth.iter().enumerate() {
            l[v] = Some(k as u32);
        }
        l
    };

    let mut forests: HashMap<Vec<usize>, (Arc<RandomForest>, Arc<WksKnn>)> = HashMap::new();
    let mut reference_cache: Option<PreparedReference> = None;
    // ZoomOut beyond the descriptors' eigenpairs: the reference and every scan get a spectrum of
    // as many eigenpairs as ZoomOut's last basis asks for (its first K are the descriptors' own).
    let zoomout_spectrum = params
        .regularizer
        .zoomout
        .filter(|z| z.k_final > params.spectrum.k)
        .map(|z| params.spectrum.with_k(z.k_final));
    // A shape that maps are refined onto (the reference or a relay): prepared, with the
    // ZoomOut spectrum and, when known, the class's left/right symmetry, which lets the
    // regulariser repair mirrored maps (a property of the label set, the same from the
    // training shapes alone).
    let prepare_target = |s: usize| -> Result<PreparedShape, EvalError> {
        let r = &shapes[s];
        // The heat method's factorisation, the ZoomOut spectrum and the self-map need only the
        // mesh: side by side.
        let ((prepared, zoomout), self_map) = rayon::join(
            || {
                rayon::join(
                    || -> Result<_, EvalError> {
                        Ok(PreparedShape::new(r.mesh.clone(), spectrum_of(s)?, params.regularizer.heat)?)
                    },
                    || {
                        zoomout_spectrum
                            .as_ref()
                            .map(|zp| spectrum_cached(&r.mesh, zp, cache.as_ref()))
                            .transpose()
                    },
                )
            },
            || match (symmetry, params.regularizer.unflip) {
                (Some(sym), Some(_)) => super::symmetry::vertex_symmetry(&r.mesh, &r.truth, sym).map(Some),
                _ => Ok(None),
            },
        );
        let mut prepared = prepared?.serving_many();
        if let Some(sp) = zoomout? {
            prepared = prepared.with_zoomout_spectrum(Arc::new(sp))?;
        }
        if let Some(self_map) = self_map? {
            prepared = prepared.with_symmetry(self_map.into())?;
        }
        Ok(prepared)
    };
    // The last relays used: (the relay's index, the reference's), its prepared shape and its
    // vertex map to the reference; at most `RELAYS_KEPT` or as many as a test votes with.
    let mut prepared_relays: Vec<((usize, usize), PreparedShape, Vec<usize>)> = Vec::new();
    let mut tests = Vec::with_capacity(jobs.len());
    for (done, (t, train)) in jobs.iter().enumerate() {
        let test_shape = &shapes[*t];
        let mut timings = TestTimings::default();
        let stage = |p: &mut Option<&mut dyn FnMut(ProtocolEvent<'_>)>, stage: &'static str| {
            if let Some(cb) = p.as_mut() {
                cb(ProtocolEvent::Stage { test: &test_shape.name, stage });
            }
        };
        let reference = train[0];
        let mut key = train.clone();
        key.sort_unstable();
        let forest_reused = forests.contains_key(&key);
        if !forest_reused {
            stage(&mut progress, "train");
            let mut members = Vec::with_capacity(key.len());
            for &s in &key {
                let shape =
                    TrainingShape::new(shapes[s].name.clone(), spectrum_of(s)?, labels_of(&shapes[s]));
                members.push(shape.with_local(&shapes[s].mesh, params.local.as_ref())?);
            }
            let augmentation = Augmentation {
                kinds: &params.augment,
                copies: params.augment_copies,
                fill_perimeter: params.fill_holes,
                spectrum: &params.spectrum,
                cache: cache.as_ref(),
                local: params.local.as_ref(),
            };
            for &s in &key {
                let copies = augmented_copies(
                    &shapes[s].name,
                    &shapes[s].mesh,
                    &labels_of(&shapes[s]),
                    &augmentation,
                    params.seed,
                    s as u64,
                );
                for copy in copies {
                    members.push(copy?);
                }
            }
            let set = TrainingSet::new(members, n_labels)?;
            let t0 = Instant::now();
            let forest = forest_params.fit(&set)?;
            timings.train_s = t0.elapsed().as_secs_f64();
            let t0 = Instant::now();
            let knn = WksKnn::fit(&set, &WksParams::default(), forest.energy_grid().range, forest.k())?;
            timings.knn_fit_s = t0.elapsed().as_secs_f64();
            forests.insert(key.clone(), (Arc::new(forest), Arc::new(knn)));
        }
        let (forest, knn) =
            forests.get(&key).cloned().ok_or_else(|| invalid("internal: trained forest missing".into()))?;

        // Reference: prepared shape, evaluation distance fields and symmetry in vertex space.
        let t0 = Instant::now();
        if reference_cache.as_ref().map(|r| r.0) != Some(reference) {
            let r = &shapes[reference];
            let prepared = prepare_target(reference)?;
            timings.prepare_s += t0.elapsed().as_secs_f64();
            stage(&mut progress, "evaluate");
            let t1 = Instant::now();
            let solver = HeatMethodSolver::new(&r.mesh, params.eval_heat)?;
            let sources: Vec<usize> = eval_labels.iter().map(|&k| r.truth[k]).collect();
            let fields = solver.distances_from_many(&sources)?;
            let mirror_fields = match symmetry {
                Some(sym) => {
                    let mirrored: Vec<usize> = eval_labels.iter().map(|&k| r.truth[sym[k]]).collect();
                    Some(solver.distances_from_many(&mirrored)?)
                }
                None => None,
            };
            timings.eval_fields_s = t1.elapsed().as_secs_f64();
            reference_cache = Some((reference, prepared, fields, mirror_fields));
        }
        let (_, ref_prepared, fields, mirror_fields) =
            reference_cache.as_ref().ok_or_else(|| invalid("internal: reference missing".into()))?;
        // The scan: the test shape, perturbed when asked, with its vertex map to the test shape.
        let (scan_mesh, scan_spectrum, kept, area_fraction) = if params.perturbations.is_empty() {
            (test_shape.mesh.clone(), spectrum_of(*t)?, None, 1.0)
        } else {
            stage(&mut progress, "perturb");
            let seed = params.seed ^ (*t as u64 + 1).wrapping_mul(0x2545_f491_4f6c_dd1d);
            let p = perturb(&test_shape.mesh, &params.perturbations, seed).map_err(|e| {
                invalid(format!("{}: {}: {e}", test_shape.name, perturbations_name(&params.perturbations)))
            })?;
            let fraction = p.area_fraction(&test_shape.mesh);
            let mesh = Arc::new(p.mesh);
            let sp = spectrum_cached(&mesh, &params.spectrum, cache.as_ref())?;
            (mesh, Arc::new(sp), Some(p.kept), fraction)
        };
        // The part that is matched: the largest component of a scan in pieces, normalised by
        // the reference's area when it is an open part of a body.
        let part = if params.largest_component && kept.is_some() {
            ScanPart::of(&scan_mesh)
        } else {
            ScanPart { mesh: scan_mesh.clone(), kept: None, components: 1 }
        };
        let ref_area = shapes[reference].mesh.surface_area();
        let filled = match params.fill_holes {
            Some(f) if kept.is_some() => part.filled(f * ref_area.sqrt()),
            _ => None,
        };
        let spectrum_mesh = filled.clone().unwrap_or_else(|| part.mesh.clone());
        let part_spectrum = match (&part.kept, &filled) {
            (None, None) => scan_spectrum,
            _ => Arc::new(spectrum_cached(&spectrum_mesh, &params.spectrum, cache.as_ref())?),
        };
        let (part_spectrum, scale_ratio) = if kept.is_some() {
            let (sp, ratio) = if params.partial_scale {
                part.spectrum_for_matching(&spectrum_mesh, (*part_spectrum).clone(), ref_area)
            } else {
                (part_spectrum.restricted(part.mesh.n_vertices()), 1.0)
            };
            (Arc::new(sp), ratio)
        } else {
            (part_spectrum, 1.0)
        };
        let (part_mesh, part_kept) = (part.mesh.clone(), part.kept.clone());
        let cpu0 = process_cpu_s();
        let t0 = Instant::now();
        // The heat method's factorisation and the ZoomOut spectrum need only the mesh: side by
        // side.
        let zoomout_part = || -> Result<Option<Spectrum>, EvalError> {
            let Some(zp) = &zoomout_spectrum else { return Ok(None) };
            // The same mesh and the same normalisation as the descriptors' spectrum, more pairs.
            let sp = spectrum_cached(&spectrum_mesh, zp, cache.as_ref())?;
            Ok(Some(match (kept.is_some(), params.partial_scale) {
                (false, _) => sp,
                (true, true) => part.spectrum_for_matching(&spectrum_mesh, sp, ref_area).0,
                (true, false) => sp.restricted(part.mesh.n_vertices()),
            }))
        };
        let (test_prepared, zoomout_part) = rayon::join(
            || PreparedShape::new(part_mesh.clone(), part_spectrum, params.regularizer.heat),
            zoomout_part,
        );
        let mut test_prepared = test_prepared?;
        if let Some(sp) = zoomout_part? {
            test_prepared = test_prepared.with_zoomout_spectrum(Arc::new(sp))?;
        }
        timings.prepare_s += t0.elapsed().as_secs_f64();
        // A map on the part, as a map on the whole scan.
        let on_scan = |map: Vec<usize>| part.extend(&scan_mesh, map);

        stage(&mut progress, "predict");
        let t0 = Instant::now();
        let prediction = forest.predict_mesh(&test_prepared.mesh, &test_prepared.spectrum)?;
        timings.predict_s = t0.elapsed().as_secs_f64();
        let table = &shapes[reference].truth;

        stage(&mut progress, "regularize");
        let t0 = Instant::now();
        let prepared_before = timings.prepare_s;
        // Onto the training shape in the nearest pose (the reference itself, or a relay whose
        // map is carried back through the labels): the training shapes by nearness of pose.
        let ranked: Vec<usize> = if params.relay && params.diagnose.is_none() {
            let candidates: Vec<(&Mesh, &[usize])> =
                train.iter().map(|&s| (&*shapes[s].mesh, shapes[s].truth.as_slice())).collect();
            poses_by_nearness(&test_prepared.mesh, &prediction, &candidates)?
                .into_iter()
                .map(|c| train[c])
                .collect()
        } else {
            vec![reference]
        };
        let mut targets: Vec<usize> = ranked.iter().take(params.relay_votes.max(1)).copied().collect();
        // The relays among `wanted` prepared, with their label maps to the reference.
        let prepare_relays = |wanted: &[usize],
                              relays: &mut Vec<((usize, usize), PreparedShape, Vec<usize>)>,
                              timings: &mut TestTimings|
         -> Result<(), EvalError> {
            for &target in wanted.iter().filter(|&&t| t != reference) {
                if relays.iter().any(|r| r.0 == (target, reference)) {
                    continue;
                }
                let t1 = Instant::now();
                let to_reference = through_labels(
                    &shapes[target].mesh,
                    &shapes[target].truth,
                    &shapes[reference].mesh,
                    table,
                )?;
                // Room for it: a relay this test does not use goes.
                if relays.len() >= RELAYS_KEPT.max(wanted.len()) {
                    if let Some(i) = relays.iter().position(|r| !wanted.contains(&r.0 .0)) {
                        relays.remove(i);
                    }
                }
                relays.push(((target, reference), prepare_target(target)?, to_reference));
                timings.prepare_s += t1.elapsed().as_secs_f64();
            }
            Ok(())
        };
        prepare_relays(&targets, &mut prepared_relays, &mut timings)?;
        // A prediction regularised onto a target, as a map onto the reference, and with `read`
        // the share of the scan's area where the map onto the target reads as mirrored. A voter
        // (a map voted with others, then settled) gets the voters' settings.
        let threshold = params.regularizer.unflip.unwrap_or(UNFLIP_THRESHOLD);
        let regularize_onto = |relays: &[((usize, usize), PreparedShape, Vec<usize>)],
                               target: usize,
                               p: &Prediction,
                               read: bool,
                               voter: bool|
         -> Result<(DenseMap, Option<f64>), EvalError> {
            let reversed = |onto: &PreparedShape, d: &DenseMap| {
                read.then(|| reversed_area(&test_prepared.mesh, &onto.mesh, &d.map, threshold))
            };
            if target == reference {
                let reg = params.regularizer.for_map(false, voter);
                let dense = regularize(&test_prepared, ref_prepared, p, Some(table), &reg)?;
                let share = reversed(ref_prepared, &dense);
                return Ok((dense, share));
            }
            let (_, prepared, to_reference) =
                relays.iter().find(|r| r.0 == (target, reference)).expect("prepared above");
            // Carried, then settled onto the reference: not settled onto the relay first.
            let reg = params.regularizer.for_map(true, voter);
            let dense = regularize(&test_prepared, prepared, p, Some(&shapes[target].truth), &reg)?;
            let share = reversed(prepared, &dense);
            Ok((dense.carried(to_reference)?, share))
        };
        let mut target = targets[0];
        // A carried or voted map did not end with a refinement onto the reference: settled onto it.
        let settle = |dense: DenseMap, carried_or_voted: bool| -> Result<DenseMap, EvalError> {
            if !carried_or_voted {
                return Ok(dense);
            }
            Ok(dense.settled(&test_prepared, ref_prepared, &params.regularizer)?)
        };
        // A prediction regularised onto one target as a settled map onto the reference.
        let settled_onto = |relays: &[_], target: usize, p: &Prediction| -> Result<DenseMap, EvalError> {
            settle(regularize_onto(relays, target, p, false, false)?.0, target != reference)
        };
        // Maps onto the other targets, voted with the first.
        let voted = |first: DenseMap, others: &[usize], relays: &[_]| -> Result<DenseMap, EvalError> {
            // Independent regularisations, side by side.
            let others: Vec<DenseMap> = others
                .par_iter()
                .map(|&t| regularize_onto(relays, t, &prediction, false, true).map(|(d, _)| d))
                .collect::<Result<_, _>>()?;
            settle(first.voted(&others, &ref_prepared.mesh)?, true)
        };
        let one_vote = targets.len() == 1;
        let (first, reversed) = regularize_onto(&prepared_relays, target, &prediction, one_vote, !one_vote)?;
        let (prediction_mirrored, alternative_kept) = (first.prediction_mirrored, first.alternative_kept);
        let mut tried = Vec::new();
        let dense = if !one_vote {
            voted(first, &targets[1..], &prepared_relays)?
        } else if params.doubt.is_some_and(|limit| reversed.is_some_and(|r| r > limit)) && ranked.len() > 1 {
            // A map that reads as mirrored in part: voted with the next nearest poses'.
            targets = ranked.iter().take(DOUBT_VOTES).copied().collect();
            prepare_relays(&targets, &mut prepared_relays, &mut timings)?;
            voted(first, &targets[1..], &prepared_relays)?
        } else {
            settle(first, target != reference)?
        };
        // On a single view, how the map onto the reference reads; one that reads poorly
        // oriented: the view onto the next nearest poses too, the best oriented map kept.
        // (Not read on voted maps: several votes asked for, or a mirrored part's doubt.)
        let view_score = view_orientation(&test_prepared.mesh, &ref_prepared.mesh, &dense.map)
            .filter(|_| targets.len() == 1);
        let limit = params.doubt_view.unwrap_or(f64::NEG_INFINITY);
        let dense = match view_score {
            Some(score) if score < limit && ranked.len() > 1 => {
                let mut best = (score, dense);
                let mut regularised = vec![ranked[0]];
                for &other in ranked.iter().skip(1).take(DOUBT_VOTES - 1) {
                    // The next poses in order of nearness, until a map reads oriented enough.
                    if best.0 >= limit {
                        break;
                    }
                    regularised.push(other);
                    prepare_relays(&regularised, &mut prepared_relays, &mut timings)?;
                    let map = settled_onto(&prepared_relays, other, &prediction)?;
                    let s = view_orientation(&test_prepared.mesh, &ref_prepared.mesh, &map.map);
                    if let Some(s) = s.filter(|&s| s > best.0) {
                        best = (s, map);
                        target = other;
                    }
                }
                tried = regularised.into_iter().filter(|&t| t != target).collect();
                best.1
            }
            _ => dense,
        };
        // The relays prepared meanwhile are in `prepare_s`, not here as well.
        timings.regularize_s = t0.elapsed().as_secs_f64() - (timings.prepare_s - prepared_before);
        timings.scan_cpu_s = process_cpu_s() - cpu0;

        let baseline = if params.skip_baseline {
            None
        } else {
            stage(&mut progress, "baseline");
            let k = prediction.mean_support().round().max(1.0) as usize;
            let t0 = Instant::now();
            let knn_prediction = knn.predict(&test_prepared.spectrum, k)?;
            timings.knn_predict_s = t0.elapsed().as_secs_f64();
            let t0 = Instant::now();
            let knn_dense = settled_onto(&prepared_relays, target, &knn_prediction)?;
            timings.knn_regularize_s = t0.elapsed().as_secs_f64();
            Some((knn_prediction, knn_dense))
        };

        // Evaluated points present in the scan, as scan vertices, and their columns.
        let scan_index = kept.as_ref().map(|k| {
            let mut idx = vec![None; test_shape.mesh.n_vertices()];
            for (new, &old) in k.iter().enumerate() {
                idx[old] = Some(new);
            }
            idx
        });
        let (columns, evaluated): (Vec<usize>, Vec<usize>) = eval_labels
            .iter()
            .enumerate()
            .filter_map(|(j, &k)| {
                let v = test_shape.truth[k];
                match &scan_index {
                    Some(idx) => idx[v].map(|s| (j, s)),
                    None => Some((j, v)),
                }
            })
            .unzip();
        let all_columns = columns.len() == eval_labels.len();
        let pick = |m: &Mat<f64>| Mat::from_fn(m.nrows(), columns.len(), |r, c| m[(r, columns[c])]);
        let fields_here = if all_columns { None } else { Some(pick(fields)) };
        let mirror_here = match (all_columns, mirror_fields) {
            (false, Some(mf)) => Some(pick(mf)),
            _ => None,
        };
        let fields_used = fields_here.as_ref().unwrap_or(fields);
        let mirror_used = if all_columns { mirror_fields.as_ref() } else { mirror_here.as_ref() };
        let area = ref_prepared.mesh.surface_area();
        let measure = |method: Method, map: &[usize]| -> Result<MethodErrors, EvalError> {
            let (strict, _) = geodesic_errors(map, &evaluated, fields_used.as_ref(), None, area)?;
            let symmetric = match mirror_used {
                Some(mf) => {
                    let (mirrored, _) = geodesic_errors(map, &evaluated, mf.as_ref(), None, area)?;
                    Some(strict.iter().zip(&mirrored).map(|(a, b)| a.min(*b)).collect())
                }
                None => None,
            };
            Ok(MethodErrors { method, strict, symmetric, map: map.to_vec() })
        };
        let raw = |p: &Prediction| on_scan(raw_map(p, table));
        let mut methods = vec![
            measure(Method::ForestRaw, &raw(&prediction))?,
            measure(Method::ForestRegularized, &on_scan(dense.unrefined_map().to_vec()))?,
        ];
        if params.regularizer.zoomout.is_some() {
            methods.push(measure(Method::ForestZoomOut, &on_scan(dense.map.clone()))?);
        }
        if let Some((knn_prediction, knn_dense)) = &baseline {
            methods.push(measure(Method::WksKnnRaw, &raw(knn_prediction))?);
            methods.push(measure(Method::WksKnnRegularized, &on_scan(knn_dense.map.clone()))?);
        }
        let diagnosis = match &params.diagnose {
            Some(variants) => {
                let inputs = DiagnosisInputs {
                    test_prepared: &test_prepared,
                    reference: ref_prepared,
                    prediction: &prediction,
                    table,
                    part_kept: part_kept.as_deref(),
                    scan_kept: kept.as_deref(),
                    test_truth: &test_shape.truth,
                    evaluated: &evaluated,
                    fields: fields_used.as_ref(),
                    mirror: mirror_used.map(|m| m.as_ref()),
                };
                Some(diagnose(&inputs, &dense, variants, &params.regularizer)?)
            }
            None => None,
        };
        let in_matched_part = match &part_kept {
            Some(k) => {
                let mut inside = vec![false; scan_mesh.n_vertices()];
                for &v in k {
                    inside[v] = true;
                }
                evaluated.iter().map(|&v| inside[v]).collect()
            }
            None => vec![true; evaluated.len()],
        };
        tests.push(TestResult {
            test: *t,
            reference,
            relay: (target != reference).then_some(target),
            votes: targets[1..].to_vec(),
            tried,
            view_orientation: view_score,
            reversed_area: reversed,
            prediction_mirrored,
            alternative_kept,
            training: key,
            forest_reused,
            mean_support: prediction.mean_support(),
            min_samples_leaf: forest.min_samples_leaf(),
            n_trees: forest.n_trees(),
            orientation_score: dense.orientation_score,
            n_matches: dense.matches.len(),
            methods,
            timings,
            perturbation: perturbations_name(&params.perturbations),
            scan_vertices: scan_mesh.n_vertices(),
            area_fraction,
            present_points: evaluated.len(),
            scan: kept.is_some().then(|| scan_mesh.clone()),
            labels: columns.iter().map(|&j| eval_labels[j]).collect(),
            evaluated,
            in_matched_part,
            matched_part_vertices: part_mesh.n_vertices(),
            scale_ratio,
            diagnosis,
        });
        if let Some(cb) = progress.as_mut() {
            cb(ProtocolEvent::TestDone { done: done + 1, total: jobs.len(), name: &test_shape.name });
        }
    }
    Ok(ProtocolReport {
        shape_names: shapes.iter().map(|s| s.name.clone()).collect(),
        eval_labels,
        spectrum_s,
        has_symmetry: symmetry.is_some(),
        tests,
    })
}

/// What [`diagnose`] reads.
struct DiagnosisInputs<'a> {
    test_prepared: &'a PreparedShape,
    reference: &'a PreparedShape,
    prediction: &'a Prediction,
    /// Label → reference vertex.
    table: &'a [usize],
    /// Part vertex → scan vertex (`None`: the part is the scan).
    part_kept: Option<&'a [usize]>,
    /// Scan vertex → test-shape vertex (`None`: the scan is the test shape).
    scan_kept: Option<&'a [usize]>,
    /// Label → test-shape vertex.
    test_truth: &'a [usize],
    /// Evaluated scan vertices, one per column of `fields`.
    evaluated: &'a [usize],
    /// Reference distances from the true image of each evaluated point.
    fields: faer::MatRef<'a, f64>,
    /// The same from the mirror images.
    mirror: Option<faer::MatRef<'a, f64>>,
}

/// The stages of [`Diagnosis`] for one test.
fn diagnose(
    d: &DiagnosisInputs<'_>,
    dense: &crate::regularizer::DenseMap,
    variants: &[(String, RegularizerParams)],
    base: &RegularizerParams,
) -> Result<Diagnosis, EvalError> {
    let n_part = d.test_prepared.mesh.n_vertices();
    let mut scan_to_part: Vec<Option<usize>> = match d.part_kept {
        Some(k) => {
            let n_scan =
                k.iter().max().map_or(0, |&m| m + 1).max(d.evaluated.iter().max().map_or(0, |&m| m + 1));
            let mut idx = vec![None; n_scan];
            for (p, &v) in k.iter().enumerate() {
                idx[v] = Some(p);
            }
            idx
        }
        None => (0..n_part).map(Some).collect(),
    };
    scan_to_part.resize(d.evaluated.iter().max().map_or(0, |&m| m + 1).max(scan_to_part.len()), None);
    // (column, part vertex) of the evaluated points in the matched part.
    let points: Vec<(usize, usize)> =
        d.evaluated.iter().enumerate().filter_map(|(j, &v)| scan_to_part[v].map(|p| (j, p))).collect();
    let norm = 1.0 / d.reference.mesh.surface_area().max(f64::MIN_POSITIVE).sqrt();
    let error = |r: usize, j: usize| {
        let strict = d.fields[(r, j)] * norm;
        let sym = d.mirror.map_or(strict, |m| strict.min(m[(r, j)] * norm));
        (strict, sym)
    };
    let fraction = |count: usize, of: usize| if of == 0 { 0.0 } else { count as f64 / of as f64 };
    let score = |errors: &[(f64, f64)]| {
        let s = errors.iter().filter(|e| e.0 <= 0.05).count();
        let y = errors.iter().filter(|e| e.1 <= 0.05).count();
        (fraction(s, errors.len()), fraction(y, errors.len()))
    };
    let of_map = |map: &[usize]| score(&points.iter().map(|&(j, p)| error(map[p], j)).collect::<Vec<_>>());
    let best_of = |cands: &mut dyn Iterator<Item = usize>, j: usize| {
        cands.map(|r| error(r, j)).fold((f64::INFINITY, f64::INFINITY), |a, b| (a.0.min(b.0), a.1.min(b.1)))
    };
    let mut rows = Vec::new();
    let all: Vec<(f64, f64)> = points
        .iter()
        .map(|&(j, p)| {
            let (labels, _) = d.prediction.posterior(p);
            best_of(&mut labels.iter().map(|&l| d.table[l as usize]), j)
        })
        .collect();
    let (s, y) = score(&all);
    rows.push(("candidates".to_string(), s, y));
    let top: Vec<(f64, f64)> = points
        .iter()
        .map(|&(j, p)| {
            best_of(&mut d.prediction.top_k(p, base.top_k).into_iter().map(|(l, _)| d.table[l as usize]), j)
        })
        .collect();
    let (s, y) = score(&top);
    rows.push((format!("top-{} candidates", base.top_k), s, y));
    // The game's matches against the truth of their test vertex.
    let mut label_of = vec![None; d.test_truth.iter().max().map_or(0, |&v| v + 1)];
    for (k, &v) in d.test_truth.iter().enumerate() {
        label_of[v] = Some(k);
    }
    let truth_of = |p: usize| {
        let scan = d.part_kept.map_or(p, |k| k[p]);
        let shape = d.scan_kept.map_or(scan, |k| k[scan]);
        label_of.get(shape).copied().flatten().map(|k| d.table[k])
    };
    let judged: Vec<(usize, usize)> =
        dense.matches.iter().filter_map(|m| truth_of(m.test).map(|t| (m.reference, t))).collect();
    let sources: Vec<usize> = judged.iter().map(|&(r, _)| r).collect();
    let columns = d.reference.distance_columns(&sources)?;
    let symmetry = d.reference.symmetry.as_deref();
    let sqrt_area = d.reference.sqrt_area();
    let match_errors: Vec<(f64, f64)> = judged
        .iter()
        .zip(&columns)
        .map(|(&(_, t), col)| {
            let strict = f64::from(col[t]) / sqrt_area;
            (strict, symmetry.map_or(strict, |sym| strict.min(f64::from(col[sym[t]]) / sqrt_area)))
        })
        .collect();
    let (s, y) = score(&match_errors);
    rows.push(("game matches".to_string(), s, y));
    let raw = raw_map(d.prediction, d.table);
    let (s, y) = of_map(&raw);
    rows.push(("forest-raw".to_string(), s, y));
    for (name, map) in
        [("anchor map", &dense.anchor_map[..]), ("grown", dense.unrefined_map()), ("final", &dense.map[..])]
    {
        let (s, y) = of_map(map);
        rows.push((name.to_string(), s, y));
    }
    for (name, params) in variants {
        let v = regularize(d.test_prepared, d.reference, d.prediction, Some(d.table), params)?;
        let (s, y) = of_map(v.unrefined_map());
        rows.push((format!("{name} grown"), s, y));
        let (s, y) = of_map(&v.map);
        rows.push((format!("{name} final"), s, y));
    }
    Ok(Diagnosis { points: points.len(), matches: match_errors.len(), rows })
}

/// The maximum-a-posteriori map of a prediction read through `label_to_vertex`; a vertex with
/// an empty posterior maps to reference vertex `label_to_vertex[0]` (counted as an error like
/// any other wrong match).
///
/// ```
/// use shapeforest::{eval::protocol::raw_map, forest::Prediction};
/// // 2 vertices, 3 labels: vertex 0 → label 2, vertex 1 → label 0.
/// let p = Prediction::from_parts(3, vec![0, 1, 2], vec![2, 0], vec![1.0, 1.0]).unwrap();
/// assert_eq!(raw_map(&p, &[10, 11, 12]), vec![12, 10]);
/// ```
pub fn raw_map(prediction: &Prediction, label_to_vertex: &[usize]) -> Vec<usize> {
    let fallback = label_to_vertex.first().copied().unwrap_or(0);
    prediction
        .map_labels()
        .iter()
        .map(|l| l.and_then(|l| label_to_vertex.get(l as usize).copied()).unwrap_or(fallback))
        .collect()
}
