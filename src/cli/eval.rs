//! `shapeforest eval`: the paper's protocol on a class of shapes with ground truth.
//!
//! A class folder holds OFF meshes (`.off` or `.off.gz`). Ground truth is read from per-label
//! `NAME.vts` tables (1-based; row k of two shapes' tables correspond), found beside the meshes
//! or in a `corres/` folder, when every mesh has one (remeshed TOSCA); otherwise the shapes
//! must share vertex indexing. The symmetry map behind the "flips allowed" figures comes from
//! `NAME.sym.vts` (row k: the mirror image of row k) for `.vts` classes, and for shared-indexing
//! classes is derived on the first shape from the sparse symmetric feature points
//! `CLASS.sym.info` + `CLASS.pid` ([`shapeforest::eval::symmetry::SymmetrySolver`]); the
//! derived map is cross-validated at the feature points and refused (strict figures only) when
//! less than `--symmetry-min` of them land within 0.05.
//!
//! Prints a table (method × {≤0.05, ≤0.1, mean}, strict and symmetric where a symmetry map
//! exists) and per-stage timings, and writes into `--out`: `results.csv` (per test shape and
//! method), `timings.csv` (per test shape and stage), `curves.csv` and `curves.svg` (cumulative
//! curves, one per method), `symmetry.csv` (held-out errors of a derived symmetry at the
//! feature points) and `peer/pairs.json` (the test/reference pairs with their mesh files, the
//! evaluated vertices and their mirror images, for `scripts/pyfm_peer.py`).

use std::{
    fmt::Write as _,
    path::{Path, PathBuf},
    sync::Arc,
};

use anyhow::{bail, Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use shapeforest::{
    eval::{
        plot_curves_svg,
        protocol::{
            run_protocol, Method, ProtocolEvent, ProtocolParams, ProtocolReport, ProtocolShape, TestResult,
            TestTimings, DOUBT_REVERSED_AREA, DOUBT_VIEW_ORIENTATION,
        },
        symmetry::{
            label_symmetry_from_mirrored_truth, MirroredTruth, SymmetricFeatures, SymmetryParams,
            SymmetrySolver,
        },
        write_curves_csv, ErrorSummary, PooledReport,
    },
    forest::RandomForest,
    mesh::{perturbations_name, read_mesh, write_mesh, Perturbation},
    regularizer::map_orientation,
    spectral::{compute_spectrum, SpectrumCache, SpectrumParams},
    synth::{creature_family, CreatureParams},
};

/// Arguments of `shapeforest eval`.
#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Folder of OFF meshes (`.off` or `.off.gz`) of one class. Ground truth: per-label `NAME.vts`
    /// tables (1-based; row k of two shapes correspond) when every mesh has one beside it or in
    /// a `corres/` folder, else common vertex indexing.
    #[arg(long, conflicts_with = "synthetic", required_unless_present = "synthetic")]
    pub class: Option<PathBuf>,
    /// Only files named PREFIX<number>.off (or PREFIX.off) in --class, e.g. `cat`.
    #[arg(long)]
    pub prefix: Option<String>,
    /// Strict errors only: do not derive a symmetry map (from `NAME.sym.vts`, or from the
    /// symmetric feature points `CLASS.sym.info` + `CLASS.pid`).
    #[arg(long)]
    pub no_symmetry: bool,
    /// A symmetry derived from feature points is used only when at least this fraction of the
    /// held-out feature points (and of the S∘S ≈ id checks) is within 0.05.
    #[arg(long, default_value_t = 0.67)]
    pub symmetry_min: f64,
    /// Use the built-in synthetic creature family instead of files.
    #[arg(long)]
    pub synthetic: bool,
    /// Vertices per synthetic shape.
    #[arg(long, default_value_t = 5000)]
    pub vertices: usize,
    /// Shapes in the synthetic family.
    #[arg(long, default_value_t = 8)]
    pub shapes: usize,
    /// Training shapes per test shape.
    #[arg(long, default_value_t = 6)]
    pub train: usize,
    /// At most this many test shapes.
    #[arg(long)]
    pub tests: Option<usize>,
    /// One training set for all tests (faster).
    #[arg(long)]
    pub train_once: bool,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Trees per forest (`train --trees`): `auto` (default) 15 where the leaves are pure, 60
    /// where they hold several samples (a training set with --augment copies; README "More
    /// trees for views"), or a number.
    #[arg(long, default_value = "auto", value_name = "N|auto", value_parser = parse_trees)]
    pub trees: usize,
    /// Split candidates per node.
    #[arg(long, default_value_t = 20)]
    pub candidates: usize,
    /// Each child of a split keeps at least this many training samples (`train --min-leaf`):
    /// `auto` (default) an eighth of the training set's samples per label (pure leaves for six
    /// complete shapes, 3–5 with 15 single-view copies of each), or a number (1: pure leaves).
    #[arg(long, default_value = "auto", value_name = "N|auto", value_parser = parse_min_leaf)]
    pub min_leaf: usize,
    /// Deepest level of a tree (the root is 0; `train --depth`).
    #[arg(long = "depth", alias = "max-depth", default_value_t = 25, value_name = "N")]
    pub max_depth: usize,
    /// Eigenpairs of every shape's spectrum, the descriptors' basis (K; `train --k`).
    #[arg(short, long, default_value_t = 100)]
    pub k: usize,
    /// Evaluated ground-truth points per test shape.
    #[arg(long, default_value_t = 1000)]
    pub eval_points: usize,
    /// Output folder.
    #[arg(long, default_value = "shapeforest-eval")]
    pub out: PathBuf,
    /// Spectrum cache folder (the watch daemon's `cache/` by default, so either reuses the other's spectra).
    #[arg(long, default_value = "shapeforest-data/cache")]
    pub cache: PathBuf,
    /// Do not use the spectrum cache.
    #[arg(long)]
    pub no_cache: bool,
    /// No progress bars.
    #[arg(long)]
    pub quiet: bool,
    /// The field's pairwise protocol on these pairs: a file of lines `A B` (shape names of the
    /// class; `#` starts a comment): each `A` is mapped to `B` and scored on `B` at every
    /// ground-truth point.
    #[arg(long, value_name = "FILE", conflicts_with = "synthetic")]
    pub pairs: Option<PathBuf>,
    /// A preset of the pairwise protocol: `faust` (FAUST remeshed, `tr_reg_0SP` = subject S,
    /// pose P): train on one shape of each of subjects 0–5 (`tr_reg_000`, `011`, …, `055`),
    /// map every ordered pair of the shapes of subjects 6 and 7.
    #[arg(long, value_enum, conflicts_with_all = ["synthetic", "pairs"])]
    pub protocol: Option<super::eval_pairs::Preset>,
    /// With --pairs: the training shapes (comma-separated names; the first is the reference).
    /// Default: the first --train shapes of the class that are in no pair.
    #[arg(long, value_delimiter = ',', value_name = "NAMES")]
    pub train_shapes: Vec<String>,
    /// With --pairs or --protocol: at most this many pairs (a seeded sample, in file order).
    #[arg(long)]
    pub max_pairs: Option<usize>,
    /// How every test shape is perturbed (seeded per test shape).
    #[command(flatten)]
    pub perturb: super::perturb::PerturbFlags,
    /// Turn every test shape into a point cloud: faces dropped, a seeded random FRACTION of its
    /// vertices kept (default 1: all), surface rebuilt from local triangulations. Applied
    /// after the other perturbations.
    #[arg(long, value_name = "FRACTION", num_args = 0..=1, default_missing_value = "1")]
    pub point_cloud: Option<f64>,
    /// Skip the WKS k-NN baseline (faster; its rows are left out).
    #[arg(long)]
    pub no_baseline: bool,
    /// Match every component of a perturbed scan together instead of its largest component
    /// (an ablation of the partial-scan handling).
    #[arg(long)]
    pub whole_scan: bool,
    /// Normalise a partial scan by its own area instead of the reference's (an ablation).
    #[arg(long)]
    pub own_area: bool,
    /// Holes of a perturbed scan whose perimeter is at most this fraction of the reference's
    /// √area are closed before its spectrum is computed (0: leave every hole open).
    #[arg(long, default_value_t = shapeforest::regularizer::ScanPart::FILL_PERIMETER, value_name = "F")]
    pub fill_perimeter: f64,
    /// Augment every training set with perturbed copies of its shapes: `partial-view`,
    /// `holes:N:R` or `crop:R` (repeatable; --augment-copies copies of each shape per kind).
    #[arg(long, value_name = "KIND", value_parser = parse_augment)]
    pub augment: Vec<Perturbation>,
    /// Perturbed copies per training shape and --augment kind.
    #[arg(long, default_value_t = 15)]
    pub augment_copies: usize,
    #[command(flatten)]
    pub local: super::common::LocalFlags,
    /// Also measure the regularised map refined by ZoomOut (the `forest+reg+zo` row). With
    /// --pairs / --protocol, ZoomOut is on by default (maps onto the reference and pair maps).
    #[arg(long, conflicts_with = "no_zoomout")]
    pub zoomout: bool,
    /// With --pairs / --protocol: no ZoomOut refinement (the `pair+zoomout` row then refines
    /// the pair map alone).
    #[arg(long)]
    pub no_zoomout: bool,
    /// Basis functions added per ZoomOut step.
    #[arg(long, default_value_t = 10, value_name = "N")]
    pub zoomout_step: usize,
    /// First basis size of ZoomOut (at most half the last one).
    #[arg(long, default_value_t = 100, value_name = "K")]
    pub zoomout_start: usize,
    /// Last basis size of ZoomOut. More than the spectrum's eigenpairs (100) computes the
    /// reference's and every scan's spectrum again with this many for ZoomOut (the descriptors
    /// keep the first 100).
    #[arg(long, default_value_t = 200, value_name = "K")]
    pub zoomout_final: usize,
    /// Farthest-point samples per shape that ZoomOut's iterations run on.
    #[arg(long, default_value_t = 2000, value_name = "N")]
    pub zoomout_samples: usize,
    /// Keep ZoomOut's images within this distance (× √area of the reference) of the
    /// regularised map's.
    #[arg(long, value_name = "R")]
    pub zoomout_radius: Option<f64>,
    /// Farthest-point samples on which a ZoomOut result must be closer to an isometry than the
    /// map it started from to be kept (0: always keep it).
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub zoomout_check: usize,
    /// Refine an open partial scan with the square ZoomOut too (ablation; by default a part of
    /// less than 90 % of the reference's area gets the partial, rectangular ZoomOut).
    #[arg(long)]
    pub zoomout_square: bool,
    /// Print, for every test, where the wrong points come from: the fraction within 0.05 of the
    /// best forest candidate, of the game's matches, of the map after each stage, and of the
    /// regulariser with the partial-scan variants (`trust`: boundary-aware anchor weights, `free`:
    /// reference samples as extra candidates, `top20`: 20 candidates per sample in the game on a
    /// scan that is not a single view, `top20+free`, `part top5`: 5 on a single view).
    #[arg(long)]
    pub diagnose: bool,
    /// Regularise each test shape onto the reference itself instead of onto the training shape
    /// in the pose nearest its own (`ProtocolParams::relay`; README, "Relays").
    #[arg(long)]
    pub no_relay: bool,
    /// Regularise each test shape onto this many of the nearest poses and vote per vertex among
    /// the maps (`ProtocolParams::relay_votes`; 1: the nearest pose alone; each vote costs a
    /// regularisation).
    #[arg(long, default_value_t = 1, value_name = "N")]
    pub relay_votes: usize,
    /// With one vote: a map that reads as mirrored on more than this fraction of the scan's area
    /// (a mirrored limb; results.csv: reversed_area) is voted with the maps onto the next two
    /// nearest poses (`ProtocolParams::doubt`; 0: never).
    #[arg(long, default_value_t = DOUBT_REVERSED_AREA, value_name = "F", value_parser = parse_share)]
    pub doubt_votes: f64,
    /// With one vote, on a single view: a map whose orientation score reads below this
    /// (results.csv: view_orientation) is doubted: the view is regularised onto the next nearest
    /// poses too, one after another until a map reads at least this (two at most), and the best
    /// oriented map kept (results.csv: tried_poses;
    /// `ProtocolParams::doubt_view`; README "Doubted views"; 0: never).
    #[arg(long, default_value_t = DOUBT_VIEW_ORIENTATION, value_name = "S", value_parser = parse_share)]
    pub doubt_view: f64,
    /// Anchor growth weighs each (vertex, anchor) distance by how far it can be from the
    /// scan's boundary (see `regularizer::pair_trust`).
    #[arg(long)]
    pub boundary_trust: bool,
    /// Reference farthest-point samples that anchor growth tries for every vertex besides its
    /// forest candidates (0: none).
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub free_candidates: usize,
    /// Forest candidates per farthest-point sample in the regulariser's game on a single-view
    /// scan (an open part of less than half the reference's area; 5 on other scans).
    #[arg(long, default_value_t = 20, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub part_game_candidates: u32,
    /// On a single-view scan, weight of the forest's posterior in anchor growth's placements
    /// (`AnchorGrowthParams::part_prior`, √area units; 0: placed by the anchors alone; README
    /// "The forest's word in a view's placement").
    #[arg(long, default_value_t = shapeforest::regularizer::AnchorGrowthParams::default().part_prior, value_name = "W", value_parser = parse_part_prior)]
    pub part_prior: f64,
    /// On a single-view scan, each vertex's most probable posterior entries tried in anchor
    /// growth's placements (`AnchorGrowthParams::part_candidates`; 0: all; README "More trees
    /// for views").
    #[arg(long, default_value_t = shapeforest::regularizer::AnchorGrowthParams::default().part_candidates, value_name = "N")]
    pub part_candidates: usize,
    /// On a single-view scan play the game among the --part-game-candidates only, without the
    /// second game among 5 whose completed map is kept when the forest's posterior supports it
    /// better (`RegularizerParams::part_alternative`).
    #[arg(long)]
    pub no_part_alternative: bool,
    /// Farthest-point samples of the regulariser's game on the test shape.
    #[arg(long, default_value_t = 50, value_name = "N", value_parser = clap::value_parser!(u32).range(3..=1000))]
    pub game_samples: u32,
    /// Distance-distortion scale σ of the game's payoff (× √area).
    #[arg(long, default_value_t = 0.05, value_name = "S", value_parser = parse_positive)]
    pub game_sigma: f64,
    /// Also write `points.csv`: every evaluated point's error per method (strict and flips
    /// allowed), where it was mapped and whether it lies in the matched part (`in_part`: the
    /// largest piece of a scan in pieces), for finding where the errors are.
    #[arg(long)]
    pub point_errors: bool,
    /// With --pairs / --protocol: measure errors with first-order fast marching instead of the
    /// heat method (closer to the exact geodesics of published tables at short range; slower).
    #[arg(long)]
    pub fast_marching_eval: bool,
    /// With --pairs / --protocol: do not refine the maps onto the reference whose composition
    /// starts the pair maps (`PairParams::refine_halves` false; faster, less accurate).
    #[arg(long)]
    pub unrefined_halves: bool,
    /// With --pairs / --protocol: where the pair map's refinement starts: `composed` (the
    /// composed map, refined against the target) or `regularised` (the pair's posterior
    /// regularised against the target first, as before 2026-12-03).
    #[arg(long, value_enum, default_value_t = PairStartArg::Composed)]
    pub pair_start: PairStartArg,
    /// With --pairs / --protocol: forest candidates of `A` farther than this (× √area of `B`)
    /// from the composed map's vertex are dropped from the pair's posterior (`PairParams::radius`).
    #[arg(long, default_value_t = 0.2, value_name = "R")]
    pub pair_radius: f64,
    /// With --pairs / --protocol: weight of the composed map's vertex among a vertex's candidates
    /// in the pair's posterior (`PairParams::composed_weight`).
    #[arg(long, default_value_t = 0.5, value_name = "W")]
    pub pair_composed_weight: f64,
    /// Kernel width (× √area) of the choice, by the forest's posterior, between the refined map,
    /// a coarse (20 → 100) ZoomOut's and the extrinsic step of the map before ZoomOut
    /// (`regularizer::MapSelection`; 0: no choice).
    #[arg(long, default_value_t = 0.02, value_name = "S")]
    pub zoomout_select: f64,
    /// In that choice, the third map replaces the chosen one only where the posterior supports
    /// it more than M times as well (`MapSelection::margin`; 1: the plain maximum).
    #[arg(long, default_value_t = 1.5, value_name = "M")]
    pub zoomout_select_margin: f64,
    /// Leave out the choice's third map, the extrinsic step of the map before ZoomOut
    /// (`MapSelection::grown_extrinsic`).
    #[arg(long)]
    pub no_grown_extrinsic: bool,
    /// Extrinsic refinement after ZoomOut (`regularizer::refine_extrinsic`): rounds (0: off).
    #[arg(long, default_value_t = 3, value_name = "N")]
    pub extrinsic_rounds: usize,
    /// Weight of the coordinates in the extrinsic refinement.
    #[arg(long, default_value_t = 1.0, value_name = "W")]
    pub extrinsic_weight: f64,
    /// Basis functions carrying the extrinsic refinement's deformation.
    #[arg(long, default_value_t = 200, value_name = "K")]
    pub extrinsic_k: usize,
    /// The settling round after the choice and after a relay's or a vote's map reaches the
    /// reference: how far (× √area) it may move an image (`regularizer::settle_map`; 0: off).
    #[arg(long, default_value_t = shapeforest::regularizer::SETTLE_REACH, value_name = "R", value_parser = parse_reach)]
    pub settle_reach: f64,
    /// The last step of the refinement: each image re-placed by the rigid fit of the images of
    /// its neighbours within this radius (× √area; `regularizer::local_rigid`; 0: off).
    #[arg(long, default_value_t = shapeforest::regularizer::LocalRigidParams::default().radius, value_name = "R", value_parser = parse_reach)]
    pub rigid_radius: f64,
}

impl EvalArgs {
    /// The ZoomOut settings of the command line.
    pub(super) fn zoomout_params(&self) -> shapeforest::regularizer::ZoomOutParams {
        shapeforest::regularizer::ZoomOutParams {
            k_start: self.zoomout_start,
            k_final: self.zoomout_final,
            step: self.zoomout_step,
            samples: self.zoomout_samples,
            radius: self.zoomout_radius,
            check_samples: self.zoomout_check,
            extrinsic: (self.extrinsic_rounds > 0).then_some(shapeforest::regularizer::ExtrinsicParams {
                rounds: self.extrinsic_rounds,
                deformation_k: self.extrinsic_k,
                weight: self.extrinsic_weight,
                samples: self.zoomout_samples,
            }),
            select: (self.zoomout_select > 0.0).then_some(shapeforest::regularizer::MapSelection {
                sigma: self.zoomout_select,
                margin: self.zoomout_select_margin,
                grown_extrinsic: !self.no_grown_extrinsic,
                ..Default::default()
            }),
            settle: (self.settle_reach > 0.0).then_some(self.settle_reach),
            rigid: rigid_params(self.rigid_radius),
            ..Default::default()
        }
    }

    /// The regulariser's settings of the command line; `zoomout_default`: whether ZoomOut is on
    /// unless --no-zoomout says otherwise.
    pub(super) fn regularizer_params(
        &self,
        zoomout_default: bool,
    ) -> shapeforest::regularizer::RegularizerParams {
        let on = self.zoomout || (zoomout_default && !self.no_zoomout);
        shapeforest::regularizer::RegularizerParams {
            zoomout: on.then(|| self.zoomout_params()),
            partial_zoomout: !self.zoomout_square,
            partial_scan: shapeforest::regularizer::PartialScanParams {
                boundary_trust: self.boundary_trust,
                free_candidates: self.free_candidates,
            },
            part_top_k: self.part_game_candidates as usize,
            part_alternative: !self.no_part_alternative,
            growth: Some(shapeforest::regularizer::AnchorGrowthParams {
                part_prior: self.part_prior,
                part_candidates: self.part_candidates,
                ..Default::default()
            }),
            n_samples: self.game_samples as usize,
            matcher: shapeforest::matching::GameMatcherParams {
                sigma: self.game_sigma,
                ..Default::default()
            },
            ..Default::default()
        }
    }
}

/// `text` as a finite number ≥ 0, the rule of `--part-prior` and of the reaches.
fn finite_non_negative(text: &str) -> Option<f64> {
    text.parse::<f64>().ok().filter(|x| *x >= 0.0 && x.is_finite())
}

/// `--part-prior`: a finite weight ≥ 0.
fn parse_part_prior(text: &str) -> Result<f64, String> {
    finite_non_negative(text).ok_or_else(|| format!("`{text}`: a finite weight ≥ 0 (0: off)"))
}

/// A kind of `--augment`.
pub(super) fn parse_augment(text: &str) -> Result<Perturbation, String> {
    Perturbation::parse_kind(text)
}

/// `auto` (0: resolved from the training set) or a count of at least 1 (`what`: of what, for
/// the message); the rule of `--min-leaf` and `--trees`.
fn parse_auto_count(text: &str, what: &str) -> Result<usize, String> {
    match text.trim() {
        "auto" => Ok(0),
        t => match t.parse::<usize>() {
            Ok(n) if n >= 1 => Ok(n),
            _ => Err(format!("expected `auto` or a number of {what} of at least 1, got {text:?}")),
        },
    }
}

/// `--min-leaf`: `auto` (0, resolved from the training set) or a number of samples ≥ 1.
pub(super) fn parse_min_leaf(text: &str) -> Result<usize, String> {
    parse_auto_count(text, "samples")
}

/// `--trees`: `auto` (0, resolved from the training set) or a number of trees ≥ 1.
pub(super) fn parse_trees(text: &str) -> Result<usize, String> {
    parse_auto_count(text, "trees")
}

/// `--trees` as given: `auto` for 0.
pub(super) fn trees_text(trees: usize) -> String {
    if trees == 0 {
        "auto".into()
    } else {
        trees.to_string()
    }
}

/// A share of an area: a number in [0, 1].
pub(super) fn parse_share(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(f) if (0.0..=1.0).contains(&f) => Ok(f),
        _ => Err(format!("expected a fraction between 0 and 1, got {text:?}")),
    }
}

/// A positive finite number.
pub(super) fn parse_positive(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(x) if x > 0.0 && x.is_finite() => Ok(x),
        _ => Err(format!("expected a positive finite number, got {text:?}")),
    }
}

/// A reach (× √area): a finite number ≥ 0.
pub(super) fn parse_reach(text: &str) -> Result<f64, String> {
    finite_non_negative(text.trim())
        .ok_or_else(|| format!("expected a finite number ≥ 0 (× √area), got {text:?}"))
}

/// The local rigid fit of `--rigid-radius R` (0: off).
pub(super) fn rigid_params(radius: f64) -> Option<shapeforest::regularizer::LocalRigidParams> {
    (radius > 0.0).then(|| shapeforest::regularizer::LocalRigidParams { radius, ..Default::default() })
}

/// `N:R` of `--holes`.
pub(super) fn parse_holes(text: &str) -> Result<Perturbation, String> {
    Perturbation::parse_holes(text)
}

impl EvalArgs {
    /// The test-shape perturbations, in the order they are applied: crop, single view, holes,
    /// noise.
    pub(super) fn perturbations(&self) -> Vec<Perturbation> {
        let mut list = self.perturb.list();
        if let Some(fraction) = self.point_cloud {
            list.push(Perturbation::PointCloud { fraction });
        }
        list
    }
}

/// The class of shapes to evaluate: shapes, mesh files (for the peer script), symmetry.
struct Class {
    shapes: Vec<ProtocolShape>,
    files: Vec<PathBuf>,
    symmetry: Option<Vec<usize>>,
    title: String,
    /// Ground truth from `.vts` tables (labels are table rows, not vertices).
    per_label: bool,
}

/// Numeric suffix of `stem` after `prefix` (`None` when it is not `prefix` + digits).
fn suffix_number(stem: &str, prefix: &str) -> Option<u64> {
    let rest = stem.strip_prefix(prefix)?;
    if rest.is_empty() {
        return Some(0);
    }
    if rest.chars().all(|c| c.is_ascii_digit()) {
        rest.parse().ok().map(|n: u64| n + 1)
    } else {
        None
    }
}

/// The stem of a class mesh file: `NAME` for `NAME.off` or `NAME.off.gz` (any case).
fn off_stem(path: &Path) -> Option<String> {
    let name = path.file_name()?.to_str()?;
    let lower = name.to_ascii_lowercase();
    let cut = if lower.ends_with(".off.gz") {
        7
    } else if lower.ends_with(".off") {
        4
    } else {
        return None;
    };
    Some(name[..name.len() - cut].to_string())
}

/// `dir/NAME.EXT`, `dir/corres/NAME.EXT` or `dir/../corres/NAME.EXT`, the first that exists.
fn find_beside(dir: &Path, name: &str) -> Option<PathBuf> {
    let mut places = vec![dir.join(name), dir.join("corres").join(name)];
    if let Some(parent) = dir.parent() {
        places.push(parent.join("corres").join(name));
    }
    places.into_iter().find(|p| p.is_file())
}

/// Reads a per-label (`.vts`) table: line k holds the 1-based vertex of label k. Every line must
/// name a vertex of the mesh (the protocol needs a ground-truth vertex for every label).
fn read_vts(path: &Path, n_vertices: usize) -> Result<Vec<usize>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let Some(tok) = line.split_whitespace().next() else { continue };
        let v: usize = tok.parse().with_context(|| {
            format!("{}: line {}: expected a 1-based vertex index, found {tok:?}", path.display(), i + 1)
        })?;
        if v == 0 || v > n_vertices {
            bail!(
                "{}: line {}: vertex {v} is outside 1..={n_vertices} (the file is 1-based)",
                path.display(),
                i + 1
            );
        }
        out.push(v - 1);
    }
    if out.is_empty() {
        bail!("{} holds no vertex", path.display());
    }
    Ok(out)
}

fn load_class(dir: &Path, args: &EvalArgs, out: &Path) -> Result<Class> {
    let prefix = args.prefix.as_deref();
    let entries =
        std::fs::read_dir(dir).with_context(|| format!("cannot read the class folder {}", dir.display()))?;
    let mut files: Vec<(u64, String, PathBuf)> = Vec::new();
    for e in entries {
        let path = e.with_context(|| format!("cannot list {}", dir.display()))?.path();
        let Some(stem) = off_stem(&path) else { continue };
        match prefix {
            Some(p) => {
                if let Some(n) = suffix_number(&stem, p) {
                    files.push((n, stem, path));
                }
            }
            None => files.push((0, stem, path)),
        }
    }
    files.sort();
    if files.len() < 2 {
        bail!(
            "{} holds {} OFF mesh(es){}; the protocol needs at least 2",
            dir.display(),
            files.len(),
            prefix.map(|p| format!(" named {p}<number>.off[.gz]")).unwrap_or_default()
        );
    }
    // Ground truth: per-label `.vts` tables when every mesh has one, else common indexing.
    let vts: Vec<Option<PathBuf>> =
        files.iter().map(|(_, stem, _)| find_beside(dir, &format!("{stem}.vts"))).collect();
    let n_vts = vts.iter().filter(|v| v.is_some()).count();
    if n_vts > 0 && n_vts < files.len() {
        let missing: Vec<&str> =
            files.iter().zip(&vts).filter(|(_, v)| v.is_none()).map(|(f, _)| f.1.as_str()).collect();
        bail!(
            "{} of {} meshes have a .vts ground-truth file; missing for: {}",
            n_vts,
            files.len(),
            missing.join(", ")
        );
    }
    let per_label = n_vts == files.len();
    let mut shapes: Vec<ProtocolShape> = Vec::with_capacity(files.len());
    for ((_, stem, path), vts) in files.iter().zip(&vts) {
        let mesh = read_mesh(path).with_context(|| format!("cannot read mesh {}", path.display()))?;
        match vts {
            Some(vts) => {
                let truth = read_vts(vts, mesh.n_vertices())?;
                if let Some(first) = shapes.first() {
                    if truth.len() != first.truth.len() {
                        bail!(
                            "{} has {} rows but the first shape's table has {}",
                            vts.display(),
                            truth.len(),
                            first.truth.len()
                        );
                    }
                }
                shapes.push(ProtocolShape { name: stem.clone(), mesh: Arc::new(mesh), truth });
            }
            None => {
                if let Some(first) = shapes.first() {
                    if mesh.n_vertices() != first.mesh.n_vertices() {
                        bail!(
                            "{} has {} vertices but {} has {}: without .vts ground truth a class needs \
                             common vertex indexing",
                            path.display(),
                            mesh.n_vertices(),
                            files[0].2.display(),
                            first.mesh.n_vertices()
                        );
                    }
                }
                shapes.push(ProtocolShape::identity(stem.clone(), Arc::new(mesh)));
            }
        }
    }
    let title = prefix.map(str::to_string).unwrap_or_else(|| dir.display().to_string());
    let symmetry = if args.no_symmetry {
        None
    } else if per_label {
        mirrored_truth_symmetry(dir, &files, &shapes)?
    } else {
        feature_symmetry(dir, args, &shapes, out)?
    };
    Ok(Class { shapes, files: files.into_iter().map(|f| f.2).collect(), symmetry, title, per_label })
}

/// The label symmetry from `NAME.sym.vts` files (row k: the vertex at the mirror image of row k
/// of `NAME.vts`), when every shape has one.
fn mirrored_truth_symmetry(
    dir: &Path,
    files: &[(u64, String, PathBuf)],
    shapes: &[ProtocolShape],
) -> Result<Option<Vec<usize>>> {
    let mut mirrored = Vec::with_capacity(shapes.len());
    for ((_, stem, _), s) in files.iter().zip(shapes) {
        let Some(path) = find_beside(dir, &format!("{stem}.sym.vts")) else {
            println!("no {stem}.sym.vts: strict errors only");
            return Ok(None);
        };
        let m = read_vts(&path, s.mesh.n_vertices())?;
        if m.len() != s.truth.len() {
            bail!("{} has {} rows, {stem}.vts has {}", path.display(), m.len(), s.truth.len());
        }
        mirrored.push(m);
    }
    let views: Vec<MirroredTruth<'_>> = shapes
        .iter()
        .zip(&mirrored)
        .map(|(s, m)| MirroredTruth { mesh: &s.mesh, truth: &s.truth, mirrored: m })
        .collect();
    let sym = label_symmetry_from_mirrored_truth(&views)?;
    // How well the label symmetry reproduces each shape's own mirrored table (in mesh units
    // relative to √area: rows whose mirror label sits on another vertex than `.sym.vts` says).
    let mut worst = 0.0f64;
    for (s, m) in shapes.iter().zip(&mirrored) {
        let scale = s.mesh.surface_area().sqrt();
        let mut sum = 0.0;
        for (k, &mk) in m.iter().enumerate() {
            let (a, b) = (s.mesh.vertices[s.truth[sym[k]]], s.mesh.vertices[mk]);
            sum += ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt() / scale;
        }
        worst = worst.max(sum / m.len() as f64);
    }
    println!(
        "symmetry from .sym.vts: label map of {} rows; mean Euclidean gap to the listed mirror \
         vertex ≤ {worst:.4} √area on every shape",
        sym.len()
    );
    Ok(Some(sym))
}

/// The symmetric feature points of a class: `CLASS.sym.info` (pairs of feature ids, then after
/// a blank line the features on the symmetry plane) read through `CLASS.pid` (line k: the
/// 0-based vertex of feature k, first number). `CLASS` is the prefix, or the only `*.sym.info`
/// of the folder (SCAPE's `1.sym.info`). `None` when there is no such file.
fn read_features(dir: &Path, prefix: Option<&str>) -> Result<Option<(String, SymmetricFeatures)>> {
    let info = match prefix.map(|p| dir.join(format!("{p}.sym.info"))).filter(|p| p.is_file()) {
        Some(p) => p,
        None => {
            let mut found = Vec::new();
            for e in std::fs::read_dir(dir).with_context(|| format!("cannot list {}", dir.display()))? {
                let path = e?.path();
                if path.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.ends_with(".sym.info")) {
                    found.push(path);
                }
            }
            match found.len() {
                1 => found.remove(0),
                _ => return Ok(None),
            }
        }
    };
    let name =
        info.file_name().and_then(|n| n.to_str()).unwrap_or("").trim_end_matches(".sym.info").to_string();
    let pid_path = dir.join(format!("{name}.pid"));
    let pid_text =
        std::fs::read_to_string(&pid_path).with_context(|| format!("cannot read {}", pid_path.display()))?;
    let mut pid = Vec::new();
    for (i, line) in pid_text.lines().enumerate() {
        let Some(tok) = line.split_whitespace().next() else { continue };
        let v: usize = tok.parse().with_context(|| {
            format!("{}: line {}: expected a vertex index, found {tok:?}", pid_path.display(), i + 1)
        })?;
        pid.push(v);
    }
    let text = std::fs::read_to_string(&info).with_context(|| format!("cannot read {}", info.display()))?;
    let mut features = SymmetricFeatures::default();
    let feature = |tok: &str, line: usize| -> Result<usize> {
        let k: usize = tok.parse().with_context(|| {
            format!("{}: line {line}: expected a feature number, found {tok:?}", info.display())
        })?;
        pid.get(k).copied().with_context(|| {
            format!(
                "{}: line {line}: feature {k}, but {} lists {} features",
                info.display(),
                pid_path.display(),
                pid.len()
            )
        })
    };
    for (i, line) in text.lines().enumerate() {
        let toks: Vec<&str> = line.split_whitespace().collect();
        match toks.as_slice() {
            [] => {}
            [a] => features.plane.push(feature(a, i + 1)?),
            [a, b] => features.pairs.push((feature(a, i + 1)?, feature(b, i + 1)?)),
            _ => bail!("{}: line {}: expected one or two feature numbers", info.display(), i + 1),
        }
    }
    Ok(Some((name, features)))
}

/// The dense symmetry of a class sharing vertex indexing, derived on its first shape from the
/// symmetric feature points, cross-validated at those points; `None` (strict figures only) when
/// the class has no feature file or the derived map is not accurate enough.
fn feature_symmetry(
    dir: &Path,
    args: &EvalArgs,
    shapes: &[ProtocolShape],
    out: &Path,
) -> Result<Option<Vec<usize>>> {
    let Some((name, features)) = read_features(dir, args.prefix.as_deref())? else {
        println!("no CLASS.sym.info feature file in {}: no symmetry map", dir.display());
        return Ok(None);
    };
    let shape = &shapes[0];
    let n = shape.mesh.n_vertices();
    if let Some((p, _)) = features.points().into_iter().find(|&(p, _)| p >= n) {
        bail!("{name}.pid names vertex {p}, outside the {n} vertices of {}", shape.name);
    }
    let t0 = std::time::Instant::now();
    let params = SpectrumParams::new(100);
    let spectrum = if args.no_cache {
        compute_spectrum(&shape.mesh, &params)?
    } else {
        SpectrumCache::new(args.cache.clone())?.get_or_compute(&shape.mesh, &params)?
    };
    let solver = SymmetrySolver::new(&shape.mesh, Arc::new(spectrum), SymmetryParams::default())?;
    let derived = solver.derive(&features)?;
    let check = solver.validate(&features, 10, &derived)?;
    println!(
        "symmetry from {name}.sym.info ({} pairs, {} plane points) on {}: held-out feature points \
         ({} folds) {:.1} % within 0.05, mean {:.4}, max {:.4}; S∘S ≈ id on {:.1} % of sampled \
         vertices ({:.1} s)",
        features.pairs.len(),
        features.plane.len(),
        shape.name,
        check.folds,
        100.0 * check.within_005,
        check.mean,
        check.max,
        100.0 * check.involution_within_005,
        t0.elapsed().as_secs_f64()
    );
    let mut csv = String::from("vertex,expected,mapped,error\n");
    for e in &check.held_out {
        let _ = writeln!(csv, "{},{},{},{:.6}", e.vertex, e.expected, e.mapped, e.error);
    }
    write_file(&out.join("symmetry.csv"), &csv)?;
    if check.within_005 < args.symmetry_min || check.involution_within_005 < args.symmetry_min {
        println!(
            "the derived symmetry is not accurate enough (needs {:.0} % of held-out feature points \
             and of S∘S checks within 0.05, see --symmetry-min): strict errors only",
            100.0 * args.symmetry_min
        );
        return Ok(None);
    }
    Ok(Some(derived.map))
}

fn synthetic_class(args: &EvalArgs, out: &Path) -> Result<Class> {
    let params = CreatureParams { target_vertices: args.vertices, seed: args.seed, ..Default::default() };
    let family = creature_family(&params, args.shapes).context("cannot build the synthetic family")?;
    let dir = out.join("meshes");
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut shapes = Vec::new();
    let mut files = Vec::new();
    for (i, m) in family.shapes.into_iter().enumerate() {
        let name = format!("creature{i}");
        let path = dir.join(format!("{name}.off"));
        write_mesh(&path, &m).with_context(|| format!("cannot write {}", path.display()))?;
        files.push(path);
        shapes.push(ProtocolShape::identity(name, Arc::new(m)));
    }
    let n = shapes[0].mesh.n_vertices();
    Ok(Class {
        shapes,
        files,
        symmetry: Some(family.symmetry),
        title: format!("synthetic creatures, {n} vertices"),
        per_label: false,
    })
}

pub(super) fn bar(quiet: bool) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(0);
    if let Ok(style) =
        ProgressStyle::with_template("{prefix:>10} [{bar:30}] {pos}/{len} {elapsed_precise} {msg}")
    {
        pb.set_style(style.progress_chars("=> "));
    }
    pb
}

/// The regulariser variants `--diagnose` measures besides `base`.
fn diagnosis_variants(
    base: &shapeforest::regularizer::RegularizerParams,
) -> Vec<(String, shapeforest::regularizer::RegularizerParams)> {
    use shapeforest::regularizer::PartialScanParams;
    let (k, part_k) = (base.top_k, base.part_top_k);
    [
        ("trust", true, 0, k, part_k),
        ("free", false, 1000, k, part_k),
        ("top20", false, 0, 20, part_k),
        ("top20+free", false, 1000, 20, part_k),
        ("part top5", false, 0, k, 5),
    ]
    .into_iter()
    .map(|(name, boundary_trust, free_candidates, top_k, part_top_k)| {
        let partial_scan = PartialScanParams { boundary_trust, free_candidates };
        (
            name.to_string(),
            shapeforest::regularizer::RegularizerParams { partial_scan, top_k, part_top_k, ..base.clone() },
        )
    })
    .collect()
}

/// The `--diagnose` tables, one per test (empty without diagnoses).
fn format_diagnoses(report: &shapeforest::eval::protocol::ProtocolReport) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    for t in &report.tests {
        let Some(d) = &t.diagnosis else { continue };
        let _ = writeln!(
            out,
            "diagnosis of {} ({} evaluated points in the matched part, {} game matches): within 0.05 strict / up to symmetry",
            report.shape_names[t.test], d.points, d.matches
        );
        for (name, strict, sym) in &d.rows {
            let _ = writeln!(out, "  {name:<24} {:>6.1} / {:>5.1}", 100.0 * strict, 100.0 * sym);
        }
    }
    out
}

/// Runs `shapeforest eval`.
pub fn run(args: EvalArgs) -> Result<()> {
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create the output folder {}", args.out.display()))?;
    let class = match &args.class {
        Some(dir) => load_class(dir, &args, &args.out)?,
        None => synthetic_class(&args, &args.out)?,
    };
    if args.pairs.is_some() || args.protocol.is_some() {
        let symmetry = class.symmetry.as_deref();
        return super::eval_pairs::run(&args, &class.shapes, &class.files, symmetry, &class.title);
    }
    let params = ProtocolParams {
        n_train: args.train,
        max_tests: args.tests,
        train_once: args.train_once,
        seed: args.seed,
        eval_points: args.eval_points,
        forest: RandomForest::params()
            .n_trees(args.trees)
            .seed(args.seed)
            .candidates_per_node(args.candidates)
            .min_samples_leaf(args.min_leaf)
            .max_depth(args.max_depth)
            .local_share(args.local.local_share),
        spectrum: SpectrumParams::new(args.k),
        cache_dir: (!args.no_cache).then(|| args.cache.clone()),
        perturbations: args.perturbations(),
        skip_baseline: args.no_baseline,
        largest_component: !args.whole_scan,
        partial_scale: !args.own_area,
        fill_holes: (args.fill_perimeter > 0.0).then_some(args.fill_perimeter),
        augment: args.augment.iter().map(|&p| vec![p]).collect(),
        augment_copies: args.augment_copies,
        local: args.local.params()?,
        regularizer: args.regularizer_params(false),
        diagnose: args.diagnose.then(|| diagnosis_variants(&args.regularizer_params(false))),
        relay: !args.no_relay,
        relay_votes: args.relay_votes,
        doubt: (args.doubt_votes > 0.0).then_some(args.doubt_votes),
        doubt_view: (args.doubt_view > 0.0).then_some(args.doubt_view),
        ..ProtocolParams::default()
    };
    let n_labels = class.shapes[0].truth.len();
    let (v_min, v_max) = class
        .shapes
        .iter()
        .map(|s| s.mesh.n_vertices())
        .fold((usize::MAX, 0), |(a, b), n| (a.min(n), b.max(n)));
    let size =
        if v_min == v_max { format!("{v_min} vertices") } else { format!("{v_min}–{v_max} vertices") };
    let truth =
        if class.per_label { format!(", {n_labels} ground-truth rows (.vts)") } else { String::new() };
    println!(
        "{}: {} shapes × {size}{truth}; training on {} shape(s){}, {} trees, {} evaluation points",
        class.title,
        class.shapes.len(),
        args.train.min(class.shapes.len() - 1),
        if args.train_once { " (one training set)" } else { " per test" },
        trees_text(args.trees),
        args.eval_points.min(n_labels)
    );
    if class.symmetry.is_none() {
        println!("no symmetry map for this class: strict errors only");
    }
    if !params.perturbations.is_empty() {
        println!(
            "test shapes perturbed: {} (seeded per test shape; errors at the evaluated points the scan keeps)",
            perturbations_name(&params.perturbations)
        );
    }
    let pb = bar(args.quiet);
    let mut on_event = |e: ProtocolEvent<'_>| match e {
        ProtocolEvent::Spectrum { done, total, name } => {
            pb.set_prefix("spectra");
            pb.set_length(total as u64);
            pb.set_position(done as u64);
            pb.set_message(name.to_string());
        }
        ProtocolEvent::Stage { test, stage } => {
            pb.set_prefix("tests");
            pb.set_message(format!("{test}: {stage}"));
        }
        ProtocolEvent::TestDone { done, total, name } => {
            pb.set_prefix("tests");
            pb.set_length(total as u64);
            pb.set_position(done as u64);
            pb.set_message(format!("{name} done"));
        }
    };
    let report = run_protocol(&class.shapes, class.symmetry.as_deref(), &params, Some(&mut on_event))?;
    pb.finish_and_clear();

    print!("{}", format_table(&report));
    let mirrored: Vec<&str> = report
        .tests
        .iter()
        .filter(|t| t.prediction_mirrored)
        .map(|t| report.shape_names[t.test].as_str())
        .collect();
    if !mirrored.is_empty() {
        println!(
            "predictions mirrored as a whole, read through the symmetry: {} (results.csv: prediction_mirrored)",
            mirrored.join(", ")
        );
    }
    // The distinct values the tests' forests had, ascending.
    let distinct = |of: fn(&TestResult) -> usize| {
        let mut v: Vec<usize> = report.tests.iter().map(of).collect();
        v.sort_unstable();
        v.dedup();
        v.iter().map(|x| x.to_string()).collect::<Vec<_>>().join(", ")
    };
    println!(
        "forest leaves of at least {} training sample(s){}; {} trees{}",
        distinct(|t| t.min_samples_leaf),
        if args.min_leaf == 0 { " (--min-leaf auto: an eighth of the samples per label)" } else { "" },
        distinct(|t| t.n_trees),
        if args.trees == 0 { " (--trees auto: 15 with pure leaves, 60 with larger ones)" } else { "" }
    );
    let alternatives = report.tests.iter().filter(|t| t.alternative_kept).count();
    if alternatives > 0 {
        println!(
            "single views whose map completes the game among {} candidates, better supported than the one among {}: \
             {alternatives} of {} (results.csv: alternative_kept; --no-part-alternative: none)",
            params.regularizer.top_k,
            params.regularizer.part_top_k,
            report.tests.len()
        );
    }
    if params.relay {
        let relayed = report.tests.iter().filter(|t| t.relay.is_some()).count();
        println!(
            "relays: {relayed} of {} test shape(s) regularised onto the training shape in the nearest pose \
             instead of the reference (results.csv: regularised_onto; --no-relay: none)",
            report.tests.len()
        );
        if params.relay_votes > 1 {
            println!(
                "votes: each map voted per vertex with the maps onto the next {} nearest pose(s) (results.csv: voted_with)",
                params.relay_votes - 1
            );
        } else if let Some(limit) = params.doubt {
            let doubted: Vec<String> = report
                .tests
                .iter()
                .filter(|t| !t.votes.is_empty())
                .map(|t| {
                    format!(
                        "{} ({:.1} %)",
                        report.shape_names[t.test],
                        100.0 * t.reversed_area.unwrap_or(0.0)
                    )
                })
                .collect();
            println!(
                "doubted maps (mirrored on more than {:.1} % of the area; voted with the next two nearest poses): {} \
                 (results.csv: reversed_area, voted_with; --doubt-votes 0: never)",
                100.0 * limit,
                if doubted.is_empty() { "none".to_string() } else { doubted.join(", ") }
            );
        }
    }
    print!("{}", format_timings(&report));
    print!("{}", format_diagnoses(&report));
    write_outputs(&args.out, &class, &report, params.curve_steps)?;
    if args.point_errors {
        write_point_errors(&args.out, &report)?;
    }
    super::visual::write_eval_pages(&args.out, &class.shapes, &report, &format_table(&report))?;
    println!(
        "wrote results.csv, timings.csv, curves.csv, curves.svg, peer/pairs.json, index.html, shapes/ to {}",
        args.out.display()
    );
    Ok(())
}

pub(super) fn pct(x: f64) -> String {
    format!("{:5.1}%", 100.0 * x)
}

/// The accuracy table, pooled over test shapes.
fn format_table(report: &ProtocolReport) -> String {
    let mut s = String::new();
    let n_points: usize = report.tests.iter().map(|t| t.methods.first().map_or(0, |m| m.strict.len())).sum();
    let _ = writeln!(
        s,
        "\naccuracy over {} test shape(s), {} points (geodesic error / √area)",
        report.tests.len(),
        n_points
    );
    if let Some(first) = report.tests.first().filter(|t| t.perturbation != "none") {
        let n_eval = report.eval_labels.len() * report.tests.len();
        let area: f64 = report.tests.iter().map(|t| t.area_fraction).sum::<f64>() / report.tests.len() as f64;
        let verts: usize = report.tests.iter().map(|t| t.scan_vertices).sum::<usize>() / report.tests.len();
        let _ = writeln!(
            s,
            "perturbation {}: scans keep {:.1} % of the surface on average ({verts} vertices), {n_points} of \
             {n_eval} evaluated points present",
            first.perturbation,
            100.0 * area
        );
        // The regularised forest on the matched part (the largest component) alone.
        let mut part = Vec::new();
        let mut part_sym = Vec::new();
        for t in &report.tests {
            if let Some(m) = t.errors(Method::ForestRegularized) {
                part.extend(t.matched_part_errors(&m.strict));
                if let Some(y) = &m.symmetric {
                    part_sym.extend(t.matched_part_errors(y));
                }
            }
        }
        let (st, sy) = (ErrorSummary::of(&part), ErrorSummary::of(&part_sym));
        let part_v: usize =
            report.tests.iter().map(|t| t.matched_part_vertices).sum::<usize>() / report.tests.len();
        let _ = writeln!(
            s,
            "forest+reg on the matched part (largest component, {part_v} vertices on average): {} points, \
             {} ≤0.05, {} ≤0.1, mean {:.4}{}",
            part.len(),
            pct(st.within_005),
            pct(st.within_010),
            st.mean,
            if part_sym.is_empty() {
                String::new()
            } else {
                format!("; flips allowed {} ≤0.05", pct(sy.within_005))
            }
        );
    }
    let _ = write!(s, "{:<13} | {:>7} {:>7} {:>7}", "method", "≤0.05", "≤0.1", "mean");
    if report.has_symmetry {
        let _ = write!(s, " | {:>11} {:>10} {:>8}", "sym ≤0.05", "sym ≤0.1", "sym mean");
    }
    s.push('\n');
    for m in Method::ALL {
        if report.tests.iter().all(|t| t.errors(m).is_none()) {
            continue;
        }
        let (st, sy) = report.summary(m);
        let _ = write!(
            s,
            "{:<13} | {:>7} {:>7} {:>7.4}",
            m.name(),
            pct(st.within_005),
            pct(st.within_010),
            st.mean
        );
        if let Some(y) = sy {
            let _ = write!(s, " | {:>11} {:>10} {:>8.4}", pct(y.within_005), pct(y.within_010), y.mean);
        }
        s.push('\n');
    }
    s
}

/// Per-stage timings per test shape.
fn format_timings(report: &ProtocolReport) -> String {
    let mut s = String::new();
    let spectra: f64 = report.spectrum_s.iter().sum();
    let _ = writeln!(s, "\nspectra (100 eigenpairs, cache hits are fast): {spectra:.2} s in all");
    let _ = write!(s, "{:<14}", "test");
    for (head, _, _) in TestTimings::default().stages() {
        let _ = write!(s, " {head:>w$}", w = head.len().max(7));
    }
    s.push('\n');
    for t in &report.tests {
        let _ = write!(s, "{:<14}", report.shape_names[t.test]);
        for (head, _, secs) in t.timings.stages() {
            let _ = write!(s, " {secs:>w$.2}", w = head.len().max(7));
        }
        s.push('\n');
    }
    s
}

fn summary_cols(s: Option<ErrorSummary>) -> String {
    match s {
        Some(s) => format!("{:.6},{:.6},{:.6},{:.6}", s.within_005, s.within_010, s.mean, s.median),
        None => ",,,".into(),
    }
}

pub(super) fn write_file(path: &Path, text: &str) -> Result<()> {
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

/// One test/reference pair of `peer/pairs.json` (read by `scripts/pyfm_peer.py`).
#[derive(serde::Serialize)]
struct PeerPair {
    test: String,
    reference: String,
    test_mesh: String,
    reference_mesh: String,
    eval_test_vertices: Vec<usize>,
    eval_reference_vertices: Vec<usize>,
    eval_reference_mirror_vertices: Option<Vec<usize>>,
}

/// `peer/pairs.json`.
#[derive(serde::Serialize)]
struct PeerPairs {
    pairs: Vec<PeerPair>,
    reference_symmetry: Option<Vec<usize>>,
}

/// `points.csv`: one line per test, evaluated point and method (`in_part`: 1 when the point lies
/// in the matched part of the scan).
fn write_point_errors(out: &Path, report: &ProtocolReport) -> Result<()> {
    let mut csv = String::from("test,reference,label,method,strict,sym,mapped,in_part\n");
    for t in &report.tests {
        let labels = if t.labels.is_empty() { &report.eval_labels } else { &t.labels };
        for m in &t.methods {
            for (i, &e) in m.strict.iter().enumerate() {
                let sym =
                    m.symmetric.as_ref().and_then(|y| y.get(i)).map_or(String::new(), |y| format!("{y:.6}"));
                let mapped =
                    t.evaluated.get(i).and_then(|&v| m.map.get(v)).map_or(String::new(), |r| r.to_string());
                let _ = writeln!(
                    csv,
                    "{},{},{},{},{e:.6},{sym},{mapped},{}",
                    report.shape_names[t.test],
                    report.shape_names[t.reference],
                    labels.get(i).copied().unwrap_or(usize::MAX),
                    m.method.name(),
                    u8::from(t.in_matched_part.get(i).copied().unwrap_or(true)),
                );
            }
        }
    }
    write_file(&out.join("points.csv"), &csv)
}

fn write_outputs(out: &Path, class: &Class, report: &ProtocolReport, steps: usize) -> Result<()> {
    let mut csv = String::from(
        "test,reference,method,n,within_005,within_010,mean,median,sym_within_005,sym_within_010,sym_mean,sym_median,perturbation,scan_vertices,area_fraction,map_orientation,regularised_onto,voted_with,reversed_area,prediction_mirrored,alternative_kept,part_n,part_within_005,part_sym_within_005,view_orientation,tried_poses\n",
    );
    for t in &report.tests {
        let scan = t.scan.as_deref().unwrap_or(&class.shapes[t.test].mesh);
        let reference = &class.shapes[t.reference].mesh;
        for m in &t.methods {
            // Whether the map keeps orientation (−1: a mirror image), see `map_orientation`.
            let orientation = if m.map.len() == scan.n_vertices() {
                map_orientation(scan, reference, &m.map).score
            } else {
                f64::NAN
            };
            let st = ErrorSummary::of(&m.strict);
            let sy = m.symmetric.as_ref().map(|y| ErrorSummary::of(y));
            // The same errors on the matched part (the largest component of a scan in pieces).
            let in_part = |e: &[f64]| ErrorSummary::of(&t.matched_part_errors(e).collect::<Vec<_>>());
            let part = in_part(&m.strict);
            let part_sym = m.symmetric.as_deref().map(in_part);
            let _ = writeln!(
                csv,
                "{},{},{},{},{},{},{},{},{:.6},{:.4},{},{},{},{},{},{},{:.6},{},{},{}",
                report.shape_names[t.test],
                report.shape_names[t.reference],
                m.method.name(),
                st.n,
                summary_cols(Some(st)),
                summary_cols(sy),
                t.perturbation,
                t.scan_vertices,
                t.area_fraction,
                orientation,
                report.shape_names[t.relay.unwrap_or(t.reference)],
                t.votes.iter().map(|&v| report.shape_names[v].as_str()).collect::<Vec<_>>().join(" "),
                t.reversed_area.map_or(String::new(), |r| format!("{r:.4}")),
                t.prediction_mirrored,
                t.alternative_kept,
                part.n,
                part.within_005,
                part_sym.map_or(String::new(), |y| format!("{:.6}", y.within_005)),
                t.view_orientation.map_or(String::new(), |o| format!("{o:.4}")),
                t.tried.iter().map(|&v| report.shape_names[v].as_str()).collect::<Vec<_>>().join(" "),
            );
        }
    }
    write_file(&out.join("results.csv"), &csv)?;

    let mut tcsv =
        String::from("test,reference,forest_reused,mean_support,n_matches,orientation_score,spectrum_s");
    for (_, column, _) in TestTimings::default().stages() {
        tcsv.push(',');
        tcsv.push_str(column);
    }
    tcsv.push_str(",scan_cpu_s\n");
    for t in &report.tests {
        let _ = write!(
            tcsv,
            "{},{},{},{:.3},{},{:.4},{:.4}",
            report.shape_names[t.test],
            report.shape_names[t.reference],
            t.forest_reused,
            t.mean_support,
            t.n_matches,
            t.orientation_score,
            report.spectrum_s[t.test],
        );
        for (_, _, secs) in t.timings.stages() {
            let _ = write!(tcsv, ",{secs:.4}");
        }
        let _ = writeln!(tcsv, ",{:.4}", t.timings.scan_cpu_s);
    }
    write_file(&out.join("timings.csv"), &tcsv)?;

    let curves = report.curves(steps);
    write_curves_csv(&out.join("curves.csv"), &curves)?;
    plot_curves_svg(
        &out.join("curves.svg"),
        &format!("{}: cumulative geodesic error", class.title),
        &curves,
    )?;

    // Pairs and evaluation points for the peer script.
    let peer = out.join("peer");
    std::fs::create_dir_all(&peer).with_context(|| format!("cannot create {}", peer.display()))?;
    let abs = |p: &Path| std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf());
    let mut pairs = Vec::with_capacity(report.tests.len());
    for t in &report.tests {
        let test = &class.shapes[t.test];
        let reference = &class.shapes[t.reference];
        // A perturbed scan is written beside the results; the peer maps it and is scored at the
        // evaluated points it keeps.
        let (test_file, labels, ev_test) = match &t.scan {
            Some(scan) => {
                let dir = out.join("scans");
                std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
                let path = dir.join(format!("{}.{}.off", test.name, t.perturbation));
                write_mesh(&path, scan).with_context(|| format!("cannot write {}", path.display()))?;
                (path, t.labels.clone(), t.evaluated.clone())
            }
            None => (
                class.files[t.test].clone(),
                report.eval_labels.clone(),
                report.eval_labels.iter().map(|&k| test.truth[k]).collect(),
            ),
        };
        let ev_ref: Vec<usize> = labels.iter().map(|&k| reference.truth[k]).collect();
        let ev_mirror =
            class.symmetry.as_ref().map(|sym| labels.iter().map(|&k| reference.truth[sym[k]]).collect());
        pairs.push(PeerPair {
            test: test.name.clone(),
            reference: reference.name.clone(),
            test_mesh: abs(&test_file).display().to_string(),
            reference_mesh: abs(&class.files[t.reference]).display().to_string(),
            eval_test_vertices: ev_test,
            eval_reference_vertices: ev_ref,
            eval_reference_mirror_vertices: ev_mirror,
        });
    }
    let reference_symmetry = match &class.symmetry {
        // Identity truth tables: the label symmetry is the reference's vertex symmetry.
        Some(sym) if !class.per_label => Some(sym.clone()),
        _ => None,
    };
    let json = serde_json::to_string(&PeerPairs { pairs, reference_symmetry })? + "\n";
    write_file(&peer.join("pairs.json"), &json)?;
    Ok(())
}

/// `--pair-start` (see `regularizer::PairStart`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum PairStartArg {
    /// The composed map `A → reference → B`.
    Composed,
    /// The pair's posterior regularised against `B`.
    Regularised,
}

impl From<PairStartArg> for shapeforest::regularizer::PairStart {
    fn from(a: PairStartArg) -> Self {
        match a {
            PairStartArg::Composed => Self::Composed,
            PairStartArg::Regularised => Self::Regularised,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn class_file_names() {
        assert_eq!(suffix_number("cat10", "cat"), Some(11));
        assert_eq!(suffix_number("cat", "cat"), Some(0));
        assert_eq!(suffix_number("centaur0", "cat"), None);
        assert_eq!(suffix_number("catx", "cat"), None);
    }
}
