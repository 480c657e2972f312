//! The spatial regulariser of Rodolà et al. (§5 of the method): it turns the forest's fuzzy,
//! symmetry-confused posterior into a consistent dense point-to-point map.
//!
//! 1. `n_samples` (default 50) Euclidean farthest-point samples on the test shape;
//! 2. candidate matches: each sample with its `top_k` most probable reference points
//!    (`part_top_k` on a single view, whose posterior is flatter);
//! 3. geodesic distances among the samples (test) and among the candidate points (reference),
//!    by the heat method, normalised by √area;
//! 4. game-theoretic matching picks a sparse, geodesically consistent subset with weights ω;
//! 5. the regularised functional map (eq. 11.19) with the distance maps of the matched pairs;
//! 6. conversion to a point-to-point map: among each vertex's forest candidates, the one whose
//!    geodesic distances to the anchors agree best with the vertex's own (plus the nearest
//!    neighbour in the spectral embedding, reported separately);
//! 7. anchor growth (on by default): the game keeps only a handful of matches (often ~10 of
//!    50 samples), too few to place every vertex; a denser set of farthest-point samples is
//!    mapped through the current map, the pairs that agree with the others are kept as
//!    anchors, and every vertex is placed again with locality-weighted distances to them,
//!    a few rounds (see [`AnchorGrowthParams`]);
//! 8. an optional ZoomOut refinement of the grown map (off by default), kept only when it brings
//!    the map closer to an isometry.
//!
//! Shapes are prepared once ([`PreparedShape`]: mesh, spectrum, heat-method factorisation), so a
//! reference serves many test shapes.

use std::{sync::Arc, time::Instant};

mod columns;
mod error;
mod extrinsic;
mod flip;
mod growth;
mod memo;
mod orientation;
mod pair;
mod partial;
mod refine;
mod relay;
mod rigid;
mod scan;
mod smoothing;

pub use error::RegularizerError;
use error::RegularizerError as Error;
pub use extrinsic::{refine_extrinsic, settle_map, ExtrinsicParams, SETTLE_REACH};
pub use flip::{
    map_orientation, reversed_area, smoothed_orientation, symmetry_from_pairs, unflip, unflip_rounds,
    MapOrientation, Unflip, UNFLIP_THRESHOLD,
};
use growth::{anchor_consistent_map, grow_anchors, GrowthMemo};
use orientation::Orientation;

pub use pair::{
    invert_map, pair_posterior, regularize_onto, regularize_pair, PairMap, PairParams, PairStart, PairStep,
};
pub use partial::{
    boundary_distances, pair_trust, partial_area_ratio, refine_zoomout_partial, view_orientation,
    PartialScanParams, MIN_REFINED_AREA_RATIO, PARTIAL_AREA_RATIO,
};
pub use refine::{
    cell_balls, map_distortion, posterior_support, refine_zoomout, sample_cells, select_by_posterior,
};
pub use relay::{nearest_pose, poses_by_nearness, through_labels, vote_maps, POSE_SAMPLES};
pub use rigid::{local_rigid, LocalRigidParams};
pub use scan::ScanPart;

use faer::Mat;
use serde::{Deserialize, Serialize};

use crate::{
    fmap::{self, FmapParams, SoftCorrespondence},
    forest::Prediction,
    geodesic::{farthest_point_sampling_euclidean, HeatMethodSolver, HeatParams},
    matching::{game_theoretic_matching, Candidate, GameMatcherParams},
    mesh::Mesh,
    spectral::Spectrum,
};

/// A shape ready for regularisation: mesh, spectrum and a heat-method factorisation.
pub struct PreparedShape {
    /// The mesh.
    pub mesh: Arc<Mesh>,
    /// Its unit-area spectrum.
    pub spectrum: Arc<Spectrum>,
    /// Heat-method geodesic solver (factorised once).
    pub heat: HeatMethodSolver,
    /// The distance columns solved so far (see the `columns` module).
    columns: columns::ColumnCache,
    /// The shape's left/right self-map (`symmetry[v]`: the vertex at the mirror image of `v`),
    /// when known; a reference with one lets the regulariser repair mirrored maps
    /// ([`RegularizerParams::unflip`]).
    pub symmetry: Option<Arc<[usize]>>,
    /// A spectrum with more eigenpairs than [`PreparedShape::spectrum`] (whose first ones it
    /// repeats) for the ZoomOut refinement ([`refine_zoomout`]), when given: ZoomOut's precision
    /// grows with its final basis, the descriptors need only the first K.
    pub zoomout_spectrum: Option<Arc<Spectrum>>,
    /// What regularisations from or onto this shape make once and reuse (the `memo` module).
    kept: memo::Kept,
}

impl PreparedShape {
    /// Prepares a shape: factorises the heat-method matrices.
    pub fn new(mesh: Arc<Mesh>, spectrum: Arc<Spectrum>, heat: HeatParams) -> Result<Self, Error> {
        if spectrum.n_vertices != mesh.n_vertices() {
            return Err(Error::SizeMismatch(format!(
                "spectrum of {} vertices for a mesh of {}",
                spectrum.n_vertices,
                mesh.n_vertices()
            )));
        }
        let heat = HeatMethodSolver::new(&mesh, heat)?;
        Ok(Self {
            mesh,
            spectrum,
            heat,
            columns: columns::ColumnCache::new(Self::KEPT_COLUMNS),
            symmetry: None,
            zoomout_spectrum: None,
            kept: Default::default(),
        })
    }

    /// `n` Euclidean farthest-point samples of the shape and their cells ([`sample_cells`]),
    /// made once per `n` and then reused.
    pub fn sample_cells(&self, n: usize) -> Result<Arc<fmap::SampleCells>, Error> {
        self.kept.cells.get_or_make(self, n, || sample_cells(&self.mesh, n))
    }

    /// The same shape with a larger spectrum for ZoomOut (see
    /// [`PreparedShape::zoomout_spectrum`]); one of another mesh is refused.
    pub fn with_zoomout_spectrum(mut self, spectrum: Arc<Spectrum>) -> Result<Self, Error> {
        if spectrum.n_vertices != self.mesh.n_vertices() {
            return Err(Error::SizeMismatch(format!(
                "a ZoomOut spectrum of {} vertices for a shape of {}",
                spectrum.n_vertices,
                self.mesh.n_vertices()
            )));
        }
        self.zoomout_spectrum = Some(spectrum);
        Ok(self)
    }

    /// The basis ZoomOut refines in: the ZoomOut spectrum when given, else the spectrum.
    pub fn zoomout_basis(&self) -> &Spectrum {
        self.zoomout_spectrum.as_deref().unwrap_or(&self.spectrum)
    }

    /// The same shape with its left/right self-map (see [`PreparedShape::symmetry`]); a map of
    /// another length is refused.
    pub fn with_symmetry(mut self, symmetry: Arc<[usize]>) -> Result<Self, Error> {
        let n = self.mesh.n_vertices();
        if symmetry.len() != n || symmetry.iter().any(|&v| v >= n) {
            return Err(Error::SizeMismatch(format!(
                "a symmetry map of {} entries for a shape of {n} vertices",
                symmetry.len()
            )));
        }
        self.symmetry = Some(symmetry);
        Ok(self)
    }

    /// Distance columns a prepared shape keeps for reuse (least recently used dropped first), at
    /// 16 bits a value: `512 · n · 2` bytes at most, 20 MB at 20K vertices, 53 MB at 52K. A
    /// shape that serves many scans keeps more ([`PreparedShape::serving_many`]).
    pub const KEPT_COLUMNS: usize = 512;

    /// The same shape keeping at most `columns` distance columns (0: none).
    pub fn with_kept_columns(mut self, columns: usize) -> Self {
        self.columns = columns::ColumnCache::new(columns);
        self
    }

    /// Bytes of distance columns kept by a shape that serves many scans
    /// ([`PreparedShape::serving_many`]).
    pub const SERVING_BYTES: usize = 256 << 20;

    /// The same shape keeping as many distance columns as [`PreparedShape::SERVING_BYTES`] hold
    /// (at least [`PreparedShape::KEPT_COLUMNS`], at most one per vertex; 16 bits a value):
    /// 10,737 at 12.5K vertices, 6,710 at 20K, 2,581 at 52K. For a reference or relay that the
    /// maps of many scans go onto (the daemon's model reference, an evaluation's reference and
    /// relays): a single view asks the reference for some 1,860 columns (its game's candidates
    /// and anchor growth's targets), the next view for many of the same, and 512 kept ones
    /// served 280 of them (README "Distance columns kept"); over SCAPE's 34 views the reference
    /// is asked for nearly every one of its 12.5K columns.
    pub fn serving_many(self) -> Self {
        let n = self.mesh.n_vertices();
        let columns =
            (Self::SERVING_BYTES / (2 * n.max(1))).clamp(Self::KEPT_COLUMNS, n.max(Self::KEPT_COLUMNS));
        self.with_kept_columns(columns)
    }

    /// Geodesic distances (mesh units) from each source to every vertex, one column per
    /// source, solved by the heat method in one block for the sources not kept from earlier
    /// calls (see [`PreparedShape::KEPT_COLUMNS`]), each value at 16 bits' precision (off by at
    /// most 1.5·10⁻⁵ of the column's largest distance) whether it was kept or solved now.
    pub fn distance_columns(&self, sources: &[usize]) -> Result<Vec<Arc<[f32]>>, Error> {
        self.columns.get_or_solve(sources, |missing| Ok(self.heat.distance_columns_f32(missing)?))
    }

    /// Heat-method columns solved, and served from the kept ones, since the shape was prepared.
    pub fn column_counts(&self) -> (u64, u64) {
        self.columns.counts()
    }

    /// `√area` of the mesh, the unit of normalised distances.
    pub fn sqrt_area(&self) -> f64 {
        self.spectrum.area.sqrt()
    }
}

/// The area a scan's spectrum and distances are normalised by (see
/// [`Spectrum::renormalised`]): its own, unless it is an open surface (it has boundary) whose
/// area is between 5 % and 97 % of the reference's (`reference_area`, in the same units): a
/// partial scan of a body like the reference, normalised by the reference's area so that its
/// eigenvalues, descriptors and normalised distances are those of the whole body. A complete
/// or closed scan, or one in other units (area ratio outside that range), keeps its own area,
/// so the method stays scale invariant where it can be.
///
/// ```
/// use shapeforest::{regularizer::normalising_area, synth::{grid_plane, icosphere}};
/// let closed = icosphere(2, 1.0);
/// assert_eq!(normalising_area(&closed, 100.0), closed.surface_area());
/// let open = grid_plane(4, 4, 1.0, 1.0); // area 1, with boundary
/// assert_eq!(normalising_area(&open, 2.0), 2.0);
/// // Other units: its own area (1 up to rounding).
/// assert!((normalising_area(&open, 1000.0) - open.surface_area()).abs() < 1e-15);
/// assert!((open.surface_area() - 1.0).abs() < 1e-12);
/// ```
pub fn normalising_area(scan: &Mesh, reference_area: f64) -> f64 {
    let own = scan.surface_area();
    let ratio = own / reference_area;
    if ratio > 0.05 && ratio < 0.97 && scan.summary().n_boundary_loops > 0 {
        reference_area
    } else {
        own
    }
}

/// ZoomOut refinement settings (step 8, from the anchor-grown map; see [`refine_zoomout`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ZoomOutParams {
    /// First basis size: the grown map's functional map is fitted at this size, but at most
    /// half the final basis actually used (so that ZoomOut still has half its range to refine
    /// when the spectra hold fewer eigenpairs than `k_final`). Default 100: the grown map is
    /// right at that scale already, and a start from 20 eigenpairs throws its precision away
    /// (from the true map, a ZoomOut from 20 to 200 leaves 90 % of a FAUST pair's points within
    /// 0.05, from 100 99 %).
    pub k_start: usize,
    /// Final basis size (at most the spectra's K). Default 200: shapes get a spectrum of that
    /// many eigenpairs for ZoomOut ([`PreparedShape::with_zoomout_spectrum`]).
    pub k_final: usize,
    /// Basis functions added per iteration. Default 10 (5 until 2026-12-07, with twice the
    /// iterations; README "Faster refinement": the classes measured within ±0.3 points,
    /// FAUST pairs 0.04 of mean error worse).
    pub step: usize,
    /// Farthest-point samples per shape the iterations run on (a shape with fewer vertices
    /// uses all of them, which is ZoomOut exactly). Default 2000 (3000 until 2026-12-07).
    pub samples: usize,
    /// Keep every vertex's image within this distance (in units of the reference's `√area`,
    /// along the reference) of where the anchor-grown map put it; `None`: unrestricted ZoomOut.
    #[serde(default)]
    pub radius: Option<f64>,
    /// Keep the refined map only if it is closer to an isometry than the map it started from,
    /// measured on this many farthest-point samples of the test shape (see
    /// [`map_distortion`]); 0: always keep it (the default: across bodies of other builds the
    /// check throws good refinements away).
    #[serde(default)]
    pub check_samples: usize,
    /// The extrinsic refinement after ZoomOut ([`refine_extrinsic`]; `None`: off). Default on.
    #[serde(default)]
    pub extrinsic: Option<ExtrinsicParams>,
    /// A second, coarse ZoomOut, the extrinsic step of the unrefined map, and the choice,
    /// region by region, among the refined map and those ([`MapSelection`]; `None`: off).
    /// Default on.
    #[serde(default)]
    pub select: Option<MapSelection>,
    /// After the choice (and after a map is carried to the reference from a relay or voted),
    /// one more round of the extrinsic step, each image moved at most this far (× the
    /// reference's `√area`; [`settle_map`]); `None`: off. Default [`SETTLE_REACH`].
    #[serde(default = "ZoomOutParams::settle_reach")]
    pub settle: Option<f64>,
    /// Last, every image re-placed by the rigid fit of its neighbourhood's images
    /// ([`local_rigid`]; `None`: off). Default on.
    #[serde(default = "ZoomOutParams::rigid_default")]
    pub rigid: Option<LocalRigidParams>,
    /// First and final basis sizes of the partial ZoomOut of an open part
    /// ([`refine_zoomout_partial`]), whose maps are coarser. Default (20, 100).
    #[serde(default = "ZoomOutParams::partial_schedule")]
    pub partial: (usize, usize),
}

impl ZoomOutParams {
    fn partial_schedule() -> (usize, usize) {
        (20, 100)
    }

    fn settle_reach() -> Option<f64> {
        Some(SETTLE_REACH)
    }

    fn rigid_default() -> Option<LocalRigidParams> {
        Some(LocalRigidParams::default())
    }

    /// Whether the settling round runs ([`settle_map`]: it needs the extrinsic step on too).
    pub fn settles(&self) -> bool {
        self.settle.is_some() && self.extrinsic.is_some()
    }

    /// The schedule `(k_start, k_final)` actually used with bases of `available` eigenpairs:
    /// `k_final` at most `available`, `k_start` at most half of that (and at least 1).
    ///
    /// ```
    /// use shapeforest::regularizer::ZoomOutParams;
    /// let z = ZoomOutParams::default();
    /// assert_eq!(z.schedule(300), (100, 200));
    /// assert_eq!(z.schedule(100), (50, 100));
    /// ```
    pub fn schedule(&self, available: usize) -> (usize, usize) {
        let k_final = self.k_final.min(available).max(1);
        (self.k_start.min(k_final / 2).max(1), k_final)
    }
}

impl Default for ZoomOutParams {
    fn default() -> Self {
        Self {
            k_start: 100,
            k_final: 200,
            step: 10,
            samples: 2000,
            radius: None,
            check_samples: 0,
            extrinsic: Some(ExtrinsicParams::default()),
            select: Some(MapSelection::default()),
            settle: Self::settle_reach(),
            rigid: Self::rigid_default(),
            partial: Self::partial_schedule(),
        }
    }
}

/// The choice among maps after ZoomOut. A ZoomOut started from many eigenpairs
/// ([`ZoomOutParams::k_start`]) keeps the grown map's precision but also its large errors (a
/// limb left mirrored, a patch slid along the body), which a ZoomOut from few eigenpairs undoes
/// at the price of precision elsewhere (on remeshed TOSCA cats, the best of the two per point
/// would be 91.5 % within 0.05 where either alone is 83.8 or 89.1 %). ZoomOut also assumes an
/// isometry: where a pose stretches the body (a cat's hips and shoulders as it leaps), even the
/// true map slides by 0.05–0.1 √area under it (from the true map, ZoomOut 100 → 200 leaves
/// 90–91 % of remeshed cat pairs' points within 0.05, where the extrinsic step alone keeps
/// 99 %, `examples/zoomout_oracle.rs`). So two more maps run: a coarse ZoomOut (`coarse`, with
/// its own repair of mirrored parts) and, with `grown_extrinsic`, the extrinsic step applied to
/// the map before ZoomOut (with the same repair). Region by region ([`select_by_posterior`],
/// kernel width `sigma`), first the refined or the coarse map is chosen, whichever the forest's
/// posterior supports best; then the third map's image replaces the chosen one where it lies
/// within `reach` of it and is clearly better supported (by the factor `margin`). The third map
/// only sharpens: far from the chosen image it would bring back what ZoomOut undid (a limb the
/// forest mirrored on david), and at the kernel's resolution maps that agree within ~`sigma`
/// score alike, so that a plain maximum would trade the refined map's precision for noise.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MapSelection {
    /// First and last basis size of the coarse ZoomOut. Default (20, 100).
    pub coarse: (usize, usize),
    /// Kernel width of the posterior's density (units of the reference's `√area`). Default 0.02.
    pub sigma: f64,
    /// The extrinsic step ([`refine_extrinsic`]) of the map before ZoomOut as a third
    /// candidate (when [`ZoomOutParams::extrinsic`] is on). Default on.
    #[serde(default = "MapSelection::default_grown_extrinsic")]
    pub grown_extrinsic: bool,
    /// The third map replaces the chosen one at a vertex only where its smoothed posterior
    /// support is more than `margin` times the chosen map's (≥ 1; 1: the plain maximum).
    /// Default 1.5.
    #[serde(default = "MapSelection::default_margin")]
    pub margin: f64,
    /// The third map's images farther than this (units of the reference's `√area`, Euclidean)
    /// from the chosen map's are not candidates. Default 0.1.
    #[serde(default = "MapSelection::default_reach")]
    pub reach: f64,
}

impl MapSelection {
    fn default_grown_extrinsic() -> bool {
        true
    }

    fn default_margin() -> f64 {
        1.5
    }

    fn default_reach() -> f64 {
        0.1
    }

    /// Checks the settings, naming the broken rule.
    pub fn check(&self) -> Result<(), String> {
        if !(self.sigma > 0.0 && self.sigma.is_finite()) {
            return Err(format!("select sigma = {}: must be finite and > 0", self.sigma));
        }
        if !(self.margin >= 1.0 && self.margin.is_finite()) {
            return Err(format!("select margin = {}: must be finite and ≥ 1", self.margin));
        }
        if !(self.reach >= 0.0 && self.reach.is_finite()) {
            return Err(format!("select reach = {}: must be finite and ≥ 0", self.reach));
        }
        let (start, end) = self.coarse;
        if start == 0 || end < start {
            return Err(format!("select coarse = ({start}, {end}): needs 1 ≤ first ≤ last"));
        }
        Ok(())
    }
}

impl Default for MapSelection {
    fn default() -> Self {
        Self {
            coarse: (20, 100),
            sigma: 0.02,
            grown_extrinsic: Self::default_grown_extrinsic(),
            margin: Self::default_margin(),
            reach: Self::default_reach(),
        }
    }
}

/// Anchor growth: densifies the game's sparse matches into many geodesically consistent ones
/// before the final placement of every vertex.
///
/// Each round maps `samples` Euclidean farthest-point samples of the test shape through the
/// current map, scores each pair by the median disagreement of its distances to the other
/// pairs (`|d_M(s_i, s_j) − d_R(t_i, t_j)|`, in √area units), keeps the `keep` fraction that
/// agrees best, and re-places every test vertex among its forest candidates by
/// `Σ_j w_j(m) |d_M(m, s_j) − d_R(r, t_j)|` with `w_j(m) = exp(−d_M(m, s_j) / locality)`, so that
/// nearby anchors, least affected by non-isometric distortion, count most. The last placement
/// is smoothed: a vertex's choice also pays for landing far from where its mesh neighbours
/// land (`smoothness`), and a candidate whose orientation descriptor disagrees pays
/// `orientation`. A second run whose first round is placed by orientation (`reorient`) guards
/// against a mirrored set of game anchors; the better oriented of the two maps is kept.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AnchorGrowthParams {
    /// Farthest-point samples mapped per round. Default 200.
    pub samples: usize,
    /// Fraction of the most consistent sample pairs kept as anchors, in (0, 1]. Default 0.7.
    pub keep: f64,
    /// Locality scale of the anchor weights (√area units; 0: uniform weights). Default 0.2.
    pub locality: f64,
    /// Rounds. Default 3.
    pub rounds: usize,
    /// Weight of the smoothness term of the final placement: the mean distance (√area units)
    /// on the reference between a vertex's placement and its mesh neighbours' (0: off).
    /// Default 2.
    pub smoothness: f64,
    /// At most this many sweeps of the smoothing. Default 10.
    pub smoothing_rounds: usize,
    /// Weight of the orientation term of every placement: a candidate pays
    /// `orientation · (1 − cos)/2`, `cos` the agreement of the orientation descriptors
    /// `⟨n, ∇f × ∇g⟩` (which change sign under a mirror image) at the vertex and at the
    /// candidate. Default 0.01 (√area units, like the distance cost).
    pub orientation: f64,
    /// Orientation weight of the first round of a second growth run (0: no second run). The
    /// game's anchors may be a mirror image of the reference, whole or in part, which distances
    /// alone cannot tell from the true map on a symmetric shape; the second run first puts
    /// every vertex on the side its orientation descriptor says, then grows as usual, and of
    /// the two maps the one whose orientation descriptors agree best over all vertices is kept.
    /// Default 1.
    pub reorient: f64,
    /// On a single view (an open part of less than half the reference's area, as
    /// [`RegularizerParams::part_top_k`]): weight of the forest's posterior in every placement,
    /// a candidate `r` of vertex `m` paying `part_prior · min(−ln(p(r|m) / max_r' p(r'|m)), 5)`
    /// (√area units, like the distance cost; 0: off). A view's posterior is wide (its training
    /// copies are partial too, and their leaves hold several samples), and among the many
    /// candidates that fit the few anchors a view has, the forest's own preference is what tells
    /// them apart. Other scans are placed by their anchors alone (a prior of 0.01 cost complete
    /// FAUST_r scans 2.6 points). Default 0.02.
    #[serde(default = "AnchorGrowthParams::default_part_prior")]
    pub part_prior: f64,
    /// On a single view: only each vertex's this many most probable posterior entries are tried
    /// in a placement (0: all). A forest of many trees with leaves of several samples (60 trees,
    /// [`crate::forest::AUTO_TREES_MIXED`]) gives a view's vertices ~500 entries, most of them
    /// improbable, and a placement's time grows with them; the 160 most probable keep the
    /// maps nearly as they were (README "More trees for views"). Default 160.
    #[serde(default = "AnchorGrowthParams::default_part_candidates")]
    pub part_candidates: usize,
}

impl AnchorGrowthParams {
    /// The cap of a candidate's prior cost, in units of `part_prior`: a candidate the forest
    /// gives less than e⁻⁵ ≈ 0.7 % of the vertex's most probable label's mass pays no more than
    /// one it gives that much.
    pub const PRIOR_CAP: f64 = 5.0;

    fn default_part_prior() -> f64 {
        0.02
    }

    fn default_part_candidates() -> usize {
        160
    }
}

impl Default for AnchorGrowthParams {
    fn default() -> Self {
        Self {
            samples: 200,
            keep: 0.7,
            locality: 0.2,
            rounds: 3,
            smoothness: 2.0,
            smoothing_rounds: 10,
            orientation: 0.01,
            reorient: 1.0,
            part_prior: Self::default_part_prior(),
            part_candidates: Self::default_part_candidates(),
        }
    }
}

impl AnchorGrowthParams {
    /// Checks the settings, naming the broken rule.
    pub fn check(&self) -> Result<(), String> {
        if self.samples < 3 {
            return Err(format!("growth_samples = {}: at least 3 are needed", self.samples));
        }
        if !(self.keep > 0.0 && self.keep <= 1.0) {
            return Err(format!("growth_keep = {}: must be in (0, 1]", self.keep));
        }
        if !(self.locality >= 0.0 && self.locality.is_finite()) {
            return Err(format!("growth_locality = {}: must be finite and ≥ 0", self.locality));
        }
        if !(self.smoothness >= 0.0 && self.smoothness.is_finite()) {
            return Err(format!("growth_smoothness = {}: must be finite and ≥ 0", self.smoothness));
        }
        for (name, v) in [
            ("growth_orientation", self.orientation),
            ("growth_reorient", self.reorient),
            ("growth_part_prior", self.part_prior),
        ] {
            if !(v >= 0.0 && v.is_finite()) {
                return Err(format!("{name} = {v}: must be finite and ≥ 0"));
            }
        }
        if self.rounds == 0 {
            return Err("growth_rounds = 0: at least 1 (turn growth off with growth_samples = 0)".into());
        }
        Ok(())
    }
}

/// Parameters of the regulariser.
#[derive(Clone, Debug, PartialEq)]
pub struct RegularizerParams {
    /// Farthest-point samples on the test shape. Default 50 (the paper's choice).
    pub n_samples: usize,
    /// Candidate reference points per sample (most probable labels). Default 5.
    pub top_k: usize,
    /// Candidate reference points per sample when the test shape is a small open part of the
    /// reference (less than [`MIN_REFINED_AREA_RATIO`] of its area: a single-view scan), whose
    /// posterior is flatter: with the 5 of a complete scan the game's few matches (4–11 of 50
    /// samples) were often all wrong and the whole map with them. Default 20 (single views of
    /// SCAPE, 34 tests: 46.8 → 54.5 % within 0.05; README "Local histograms").
    pub part_top_k: usize,
    /// Game-theoretic matcher settings.
    pub matcher: GameMatcherParams,
    /// Functional-map solve settings.
    pub fmap: FmapParams,
    /// Heat-method settings for the distance maps.
    pub heat: HeatParams,
    /// Anchor growth before the final placement (default on; `None`: the game's anchors only).
    pub growth: Option<AnchorGrowthParams>,
    /// Optional ZoomOut refinement after the solve. Default off.
    pub zoomout: Option<ZoomOutParams>,
    /// Refine an open part of the reference (less than [`PARTIAL_AREA_RATIO`] of its area) with
    /// the partial ZoomOut ([`refine_zoomout_partial`]: rectangular maps whose test basis grows
    /// with the part's spectrum) instead of the square one. Default on.
    pub partial_zoomout: bool,
    /// Repair of mirrored parts of the grown map (before ZoomOut) when the reference carries
    /// its symmetry ([`PreparedShape::symmetry`]): where the map's smoothed orientation
    /// ([`smoothed_orientation`]) is below minus this threshold, images are replaced by their
    /// mirror ([`unflip`]). Default `Some(0.2)`; `None`: off.
    pub unflip: Option<f64>,
    /// Also compute the two spectral point maps of the regularised functional map for every
    /// vertex ([`DenseMap::fmap_map`], [`DenseMap::spectral_map`]), for comparison. Default off:
    /// the regulariser itself needs the spectral nearest neighbour only for the vertices that no
    /// candidate places, and the full search over every reference vertex was a tenth of its time.
    pub spectral_maps: bool,
    /// Anchor growth on scans with holes and partial scans (see [`PartialScanParams`]).
    /// Default: off.
    pub partial_scan: PartialScanParams,
    /// On a single view (see `part_top_k`), also play the game among the `top_k` candidates
    /// and keep whichever completed map the forest's posterior supports best. Default on.
    pub part_alternative: bool,
}

impl Default for RegularizerParams {
    fn default() -> Self {
        Self {
            n_samples: 50,
            top_k: 5,
            part_top_k: 20,
            matcher: GameMatcherParams::default(),
            fmap: FmapParams::default(),
            heat: HeatParams::default(),
            growth: Some(AnchorGrowthParams::default()),
            zoomout: None,
            partial_zoomout: true,
            unflip: Some(UNFLIP_THRESHOLD),
            spectral_maps: false,
            partial_scan: PartialScanParams::default(),
            part_alternative: true,
        }
    }
}

impl RegularizerParams {
    /// These settings without the refinement's last steps, ZoomOut's settling round and local
    /// rigid fit ([`ZoomOutParams::settle`], [`ZoomOutParams::rigid`]): for a map onto a relay
    /// that is carried to the reference and settled there ([`DenseMap::carried`],
    /// [`DenseMap::settled`]), which runs the same steps onto the reference.
    pub fn unsettled(&self) -> Self {
        let zoomout = self.zoomout.map(|z| ZoomOutParams { settle: None, rigid: None, ..z });
        Self { zoomout, ..self.clone() }
    }

    /// These settings for a map that is voted with others and then settled onto the reference
    /// ([`DenseMap::voted`], [`DenseMap::settled`]). A voter decides where the maps agree; the
    /// vote's settling round gives the precision. So, where the settling round is on: no
    /// settling or local rigid fit of its own ([`Self::unsettled`]); the choice after ZoomOut
    /// without its third map, the extrinsic step of the grown map
    /// ([`MapSelection::grown_extrinsic`], which only sharpens the chosen map where it lies
    /// close); and a coarser refinement, ZoomOut on half the samples with twice the step and one
    /// extrinsic round instead of [`ExtrinsicParams::rounds`]. SCAPE scans with holes whose map
    /// was doubted and voted took 20–31 % less time so, and the vote lost nothing (README "Voters
    /// refined lighter").
    ///
    /// ```
    /// use shapeforest::regularizer::{RegularizerParams, ZoomOutParams};
    /// let params = RegularizerParams { zoomout: Some(ZoomOutParams::default()), ..Default::default() };
    /// let z = params.voter().zoomout.unwrap();
    /// assert!(z.settle.is_none() && z.rigid.is_none());
    /// assert!(!z.select.unwrap().grown_extrinsic);
    /// assert_eq!((z.samples, z.step, z.extrinsic.unwrap().rounds), (1000, 20, 1));
    /// // Without the settling round, nothing takes their place: a voter is refined in full.
    /// let unsettled = params.unsettled();
    /// assert_eq!(unsettled.voter(), unsettled);
    /// ```
    pub fn voter(&self) -> Self {
        let mut voter = self.unsettled();
        let settled = self.zoomout.is_some_and(|z| z.settles());
        if let Some(z) = voter.zoomout.as_mut().filter(|_| settled) {
            z.select = z.select.map(|s| MapSelection { grown_extrinsic: false, ..s });
            z.samples = (z.samples / 2).max(1);
            z.step = z.step.saturating_mul(2);
            z.extrinsic = z.extrinsic.map(|e| ExtrinsicParams { rounds: e.rounds.min(1), ..e });
        }
        voter
    }

    /// The settings for a map by what happens to it next: voted with others and then settled
    /// ([`Self::voter`]); carried to the reference from a relay and settled there
    /// ([`Self::unsettled`]); or neither (these settings).
    ///
    /// ```
    /// use shapeforest::regularizer::{RegularizerParams, ZoomOutParams};
    /// let params = RegularizerParams { zoomout: Some(ZoomOutParams::default()), ..Default::default() };
    /// assert_eq!(params.for_map(false, false), params);
    /// assert_eq!(params.for_map(true, false), params.unsettled());
    /// assert_eq!(params.for_map(true, true), params.voter());
    /// ```
    pub fn for_map(&self, carried: bool, voted: bool) -> Self {
        match (carried, voted) {
            (_, true) => self.voter(),
            (true, false) => self.unsettled(),
            (false, false) => self.clone(),
        }
    }
}

/// A matched pair of vertices with its confidence.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct VertexMatch {
    /// Vertex of the test shape.
    pub test: usize,
    /// Vertex of the reference shape.
    pub reference: usize,
    /// Confidence in (0, 1].
    pub weight: f64,
}

/// Seconds spent in each stage of the regulariser.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RegularizerTimings {
    /// Farthest point sampling and candidate selection.
    pub sampling_s: f64,
    /// Heat-method distance maps on both shapes.
    pub distances_s: f64,
    /// Game-theoretic matching.
    pub matching_s: f64,
    /// Functional-map assembly and solve.
    pub fmap_s: f64,
    /// Point-to-point conversion.
    pub point_map_s: f64,
    /// Anchor growth (0 when off).
    #[serde(default)]
    pub growth_s: f64,
    /// ZoomOut refinement (0 when off).
    pub zoomout_s: f64,
}

/// The result of regularising one prediction.
pub struct DenseMap {
    /// Test vertex → reference vertex (the regulariser's output): [`DenseMap::anchor_map`]
    /// after anchor growth (the same map when growth is off).
    pub map: Vec<usize>,
    /// Test vertex → reference vertex placed by the game's anchors alone: among the forest's
    /// candidates of each vertex, the one whose geodesic distances to the matched anchors agree
    /// best with the vertex's own (`Σ_j ω_j |d_M(m, p_j) − d_R(r, q_j)|`, the pointwise form of
    /// the distance-map term of eq. 11.19); vertices without candidates take the functional
    /// map's.
    pub anchor_map: Vec<usize>,
    /// Anchors used in the last round of growth (0 when growth is off).
    pub grown_anchors: usize,
    /// Mean orientation agreement (in [−1, 1]) of the grown map over all test vertices
    /// (`None` when growth is off); negative for a mirror image.
    pub dense_orientation: Option<f64>,
    /// Whether growth found a mirror image and the strongly oriented second run replaced it.
    pub reoriented: bool,
    /// Test vertex → reference vertex: among the forest's candidates, the one nearest to the
    /// regularised functional map's spectral embedding (with [`RegularizerParams::spectral_maps`]).
    pub spectral_map: Option<Vec<usize>>,
    /// Test vertex → reference vertex from the regularised functional map alone
    /// (unrestricted nearest neighbour in the spectral embedding; with
    /// [`RegularizerParams::spectral_maps`]).
    pub fmap_map: Option<Vec<usize>>,
    /// The anchor-grown map before the ZoomOut refinement replaced it in [`DenseMap::map`]
    /// (`None` when refinement was off or did not bring the map closer to an isometry: `map` is
    /// then the grown map itself).
    pub grown_map: Option<Vec<usize>>,
    /// The forest's own maximum-a-posteriori map (test vertex → reference vertex), for
    /// comparison; `None` where the forest gave no label.
    pub forest_map: Vec<Option<usize>>,
    /// The functional map of the raw prediction (`k_test × k_ref`).
    pub fmap_predicted: Mat<f64>,
    /// The regularised functional map.
    pub fmap: Mat<f64>,
    /// The sparse consistent matches chosen by the game.
    pub matches: Vec<VertexMatch>,
    /// Weighted mean agreement (in [−1, 1]) of the orientation descriptors at the matches:
    /// positive for an orientation-preserving match set, negative for a mirror image.
    pub orientation_score: f64,
    /// Whether the first equilibrium of the game was a mirror image and was replaced by the
    /// orientation-preserving one.
    pub mirror_rejected: bool,
    /// Whether the forest's own map ([`DenseMap::forest_map`]) read as a mirror image as a whole
    /// (orientation score below minus [`RegularizerParams::unflip`]'s threshold), so that the
    /// prediction was read through the reference's symmetry (each label's vertex replaced by its
    /// mirror image) before the regulariser used it; needs the reference's symmetry.
    pub prediction_mirrored: bool,
    /// Whether this map completes [`SparseMatches::alternative`] (on a single view, the game
    /// among each sample's [`RegularizerParams::top_k`] candidates), which the forest's
    /// posterior supported better than the map of the game among its
    /// [`RegularizerParams::part_top_k`].
    pub alternative_kept: bool,
    /// Time per stage (of both completed maps when there was an alternative).
    pub timings: RegularizerTimings,
}

impl DenseMap {
    /// The anchor-grown map, before any ZoomOut refinement (the method of the paper).
    pub fn unrefined_map(&self) -> &[usize] {
        self.grown_map.as_deref().unwrap_or(&self.map)
    }
}

/// A forest prediction read through a label → reference-vertex table.
struct LabelledPosterior<'a> {
    prediction: &'a Prediction,
    label_to_vertex: Option<&'a [usize]>,
}

impl LabelledPosterior<'_> {
    fn vertex(&self, label: u32) -> usize {
        match self.label_to_vertex {
            Some(t) => t[label as usize],
            None => label as usize,
        }
    }
}

impl SoftCorrespondence for LabelledPosterior<'_> {
    fn n_test_vertices(&self) -> usize {
        self.prediction.n_vertices()
    }
    fn for_each_entry(&self, m: usize, f: &mut dyn FnMut(usize, f64)) {
        let (labels, probs) = self.prediction.posterior(m);
        for (&l, &p) in labels.iter().zip(probs) {
            f(self.vertex(l), p as f64);
        }
    }
}

/// Symmetrised, normalised distance matrix among `points` from their columns.
fn pairwise(fields: &[Arc<[f32]>], points: &[usize], scale: f64) -> Vec<f64> {
    let s = points.len();
    let mut d = vec![0.0; s * s];
    for i in 0..s {
        for j in 0..s {
            d[i * s + j] = 0.5 * (f64::from(fields[i][points[j]]) + f64::from(fields[j][points[i]])) / scale;
        }
    }
    d
}

/// The sparse, geodesically consistent matches of a prediction (steps 1–4 of the regulariser),
/// with the distance fields the dense step reuses.
pub struct SparseMatches {
    /// Farthest-point samples on the test shape.
    pub samples: Vec<usize>,
    /// Reference vertices that are candidates of some sample.
    pub ref_points: Vec<usize>,
    /// Distances (divided by √area) from the test vertex of each match (`n_test × matches`):
    /// the distance maps `d_p` of eq. 11.19. Only the matched columns are kept, so a job
    /// waiting for the dense step holds little.
    pub test_fields: Mat<f64>,
    /// Distances (divided by √area) from the reference vertex of each match (`n_ref × matches`).
    pub ref_fields: Mat<f64>,
    /// The game's equilibrium: indices into `samples` and `ref_points`, with weights.
    pub game: crate::matching::GameMatching,
    /// The matches in vertex indices.
    pub matches: Vec<VertexMatch>,
    /// Orientation agreement of the match set (see [`DenseMap::orientation_score`]).
    pub orientation_score: f64,
    /// Whether a mirror-image equilibrium was replaced.
    pub mirror_rejected: bool,
    /// Whether the prediction read as a mirror image as a whole and was read through the
    /// reference's symmetry (see [`DenseMap::prediction_mirrored`]); the dense step reads it
    /// the same way.
    pub prediction_mirrored: bool,
    /// Time of sampling, distances and matching.
    pub timings: RegularizerTimings,
    /// On a single view ([`RegularizerParams::part_alternative`]), the equilibrium of the game
    /// among each sample's [`RegularizerParams::top_k`] candidates beside this one among its
    /// [`RegularizerParams::part_top_k`]: [`dense_map`] completes both and keeps the map the
    /// forest's posterior supports best.
    pub alternative: Option<Box<SparseMatches>>,
}

fn check_inputs(
    test: &PreparedShape,
    reference: &PreparedShape,
    prediction: &Prediction,
    label_to_vertex: Option<&[usize]>,
    params: &RegularizerParams,
) -> Result<(), Error> {
    params.matcher.check()?;
    params.fmap.check()?;
    if let Some(g) = &params.growth {
        g.check().map_err(|reason| Error::InvalidParameter { name: "growth", reason })?;
    }
    let n_ref = reference.mesh.n_vertices();
    if prediction.n_vertices() != test.mesh.n_vertices() {
        return Err(Error::SizeMismatch(format!(
            "prediction for {} vertices, test shape has {}",
            prediction.n_vertices(),
            test.mesh.n_vertices()
        )));
    }
    match label_to_vertex {
        Some(t) if t.len() != prediction.n_labels() || t.iter().any(|&v| v >= n_ref) => {
            Err(Error::SizeMismatch(format!(
                "label table of {} entries for {} labels and a reference of {n_ref} vertices",
                t.len(),
                prediction.n_labels()
            )))
        }
        None if prediction.n_labels() > n_ref => Err(Error::SizeMismatch(format!(
            "{} labels but the reference has only {n_ref} vertices: give a label → vertex table",
            prediction.n_labels()
        ))),
        _ => Ok(()),
    }
}

/// The label → reference-vertex table that reads `posterior` through the reference's symmetry,
/// where the forest's own map reads as a mirror image as a whole: its orientation score
/// ([`map_orientation`]) is below minus [`RegularizerParams::unflip`]'s threshold (the
/// descriptors are intrinsic, so a forest can predict a mirror image of a whole scan; the game
/// and the repair of mirrored parts then turn back most of it but not all). `None` where the
/// prediction is read as it is: it does not read as mirrored, the reference carries no
/// symmetry, the repair is off, or some vertex has no label.
fn mirror_table(
    test: &PreparedShape,
    reference: &PreparedShape,
    posterior: &LabelledPosterior<'_>,
    params: &RegularizerParams,
) -> Option<Vec<usize>> {
    let (symmetry, threshold) = (reference.symmetry.as_deref()?, params.unflip?);
    let forest_map: Vec<usize> = posterior
        .prediction
        .map_labels()
        .into_iter()
        .map(|l| l.map(|l| posterior.vertex(l)))
        .collect::<Option<_>>()?;
    (map_orientation(&test.mesh, &reference.mesh, &forest_map).score < -threshold)
        .then(|| through_symmetry(posterior, symmetry))
}

/// `posterior`'s label → reference-vertex table with every vertex replaced by its mirror image.
fn through_symmetry(posterior: &LabelledPosterior<'_>, symmetry: &[usize]) -> Vec<usize> {
    (0..posterior.prediction.n_labels()).map(|l| symmetry[posterior.vertex(l as u32)]).collect()
}

/// Regularises a forest prediction for `test` against `reference`: [`sparse_matches`] then
/// [`dense_map`].
///
/// `label_to_vertex` maps forest labels to reference vertices (`None`: label = vertex index).
pub fn regularize(
    test: &PreparedShape,
    reference: &PreparedShape,
    prediction: &Prediction,
    label_to_vertex: Option<&[usize]>,
    params: &RegularizerParams,
) -> Result<DenseMap, Error> {
    crate::pool::on_pool(|| {
        let sparse = sparse_matches(test, reference, prediction, label_to_vertex, params)?;
        dense_map(test, reference, prediction, label_to_vertex, &sparse, params)
    })
}

/// Steps 1–4: farthest-point samples, their candidate matches, heat-method distances and the
/// game-theoretic selection of a consistent, orientation-preserving match set.
pub fn sparse_matches(
    test: &PreparedShape,
    reference: &PreparedShape,
    prediction: &Prediction,
    label_to_vertex: Option<&[usize]>,
    params: &RegularizerParams,
) -> Result<SparseMatches, Error> {
    crate::pool::on_pool(|| {
        check_inputs(test, reference, prediction, label_to_vertex, params)?;
        let mirrored =
            mirror_table(test, reference, &LabelledPosterior { prediction, label_to_vertex }, params);
        let prediction_mirrored = mirrored.is_some();
        let posterior =
            LabelledPosterior { prediction, label_to_vertex: mirrored.as_deref().or(label_to_vertex) };
        let mut timings = RegularizerTimings::default();
        // 1–2. Samples and candidates.
        let t0 = Instant::now();
        let n_samples = params.n_samples.min(test.mesh.n_vertices());
        let samples = farthest_point_sampling_euclidean(&test.mesh, n_samples, None)?;
        // A single view: more candidates per sample, and its orientation read extrinsically (below).
        let small_part = partial::is_small_part(test, reference);
        let top_k = if small_part { params.part_top_k } else { params.top_k };
        // A single view also plays the game among the `top_k` most probable candidates (the
        // complete scan's): the dense step keeps whichever map the posterior supports best.
        let alternative_k =
            (small_part && params.part_alternative && params.top_k < top_k).then_some(params.top_k);
        let mut ref_points: Vec<usize> = Vec::new();
        let mut ref_index = std::collections::HashMap::new();
        let mut candidates = Vec::new();
        let mut fewer = Vec::new();
        for (i, &m) in samples.iter().enumerate() {
            for (rank, (label, p)) in prediction.top_k(m, top_k).into_iter().enumerate() {
                let r = posterior.vertex(label);
                let idx = *ref_index.entry(r).or_insert_with(|| {
                    ref_points.push(r);
                    ref_points.len() - 1
                });
                let c = Candidate { test: i, reference: idx, prior: p as f64 };
                candidates.push(c);
                if alternative_k.is_some_and(|k| rank < k) {
                    fewer.push(c);
                }
            }
        }
        timings.sampling_s = t0.elapsed().as_secs_f64();

        // 3. Distances.
        let t0 = Instant::now();
        let test_fields = test.distance_columns(&samples)?;
        let ref_fields = reference.distance_columns(&ref_points)?;
        let d_test = pairwise(&test_fields, &samples, test.sqrt_area());
        let d_ref = pairwise(&ref_fields, &ref_points, reference.sqrt_area());
        timings.distances_s = t0.elapsed().as_secs_f64();

        // 4. Game.
        let t0 = Instant::now();
        let orientation = Orientation::of(test, reference);
        let agreement = |m: usize, r: usize| orientation.agreement(m, r);
        let group_score = |g: &crate::matching::GameMatching| {
            let (mut num, mut den) = (0.0, 0.0);
            for m in &g.matches {
                num += m.weight * agreement(samples[m.test], ref_points[m.reference]);
                den += m.weight;
            }
            if den > 0.0 {
                num / den
            } else {
                0.0
            }
        };
        let play = |candidates: &[Candidate]| {
            game_theoretic_matching(
                candidates,
                &d_test,
                samples.len(),
                &d_ref,
                ref_points.len(),
                &params.matcher,
            )
        };
        let symmetry = reference.symmetry.as_deref().filter(|_| small_part);
        let equilibrium = |candidates: &[Candidate]| -> Result<SparseMatches, Error> {
            let mut game = play(candidates)?;
            let mut orientation_score = group_score(&game);
            let mut mirror_rejected = false;
            if orientation_score < 0.0 {
                // The equilibrium is a mirror image: play again among orientation-preserving
                // candidates.
                let kept: Vec<Candidate> = candidates
                    .iter()
                    .copied()
                    .filter(|c| agreement(samples[c.test], ref_points[c.reference]) > 0.0)
                    .collect();
                let second = play(&kept)?;
                let second_score = group_score(&second);
                if second_score > orientation_score && !second.matches.is_empty() {
                    game = second;
                    orientation_score = second_score;
                    mirror_rejected = true;
                }
            }
            // A small part (a single view): the spectral orientation descriptors do not survive
            // it, so the equilibrium's orientation is also read extrinsically, and a mirror image is
            // read through the reference's symmetry (an isometry: the game's consistency is kept).
            let mut through: Option<&[usize]> = None;
            if let (Some(symmetry), Some(threshold)) = (symmetry, params.unflip) {
                let pairs: Vec<(usize, usize)> =
                    game.matches.iter().map(|m| (samples[m.test], ref_points[m.reference])).collect();
                if flip::matches_orientation(&test.mesh, &reference.mesh, &pairs) < -threshold {
                    through = Some(symmetry);
                    mirror_rejected = true;
                }
            }
            let image = |r: usize| through.map_or(r, |s| s[r]);
            let matched: Vec<usize> = game.matches.iter().map(|m| image(ref_points[m.reference])).collect();
            let matches = game
                .matches
                .iter()
                .zip(&matched)
                .map(|(m, &r)| VertexMatch { test: samples[m.test], reference: r, weight: m.weight })
                .collect();
            let (ts, rs) = (test.sqrt_area(), reference.sqrt_area());
            let kept_test = Mat::from_fn(test.mesh.n_vertices(), game.matches.len(), |v, j| {
                f64::from(test_fields[game.matches[j].test][v]) / ts
            });
            // Through the symmetry the matched images' own columns (the game's are their mirrors').
            let mirrored_columns = match through {
                Some(_) => Some(reference.distance_columns(&matched)?),
                None => None,
            };
            let kept_ref = Mat::from_fn(reference.mesh.n_vertices(), game.matches.len(), |v, j| {
                let column =
                    mirrored_columns.as_ref().map_or(&ref_fields[game.matches[j].reference], |c| &c[j]);
                f64::from(column[v]) / rs
            });
            Ok(SparseMatches {
                samples: samples.clone(),
                ref_points: ref_points.iter().map(|&r| image(r)).collect(),
                test_fields: kept_test,
                ref_fields: kept_ref,
                game,
                matches,
                orientation_score,
                mirror_rejected,
                prediction_mirrored,
                timings: RegularizerTimings::default(),
                alternative: None,
            })
        };
        let mut sparse = equilibrium(&candidates)?;
        if alternative_k.is_some() {
            sparse.alternative = Some(Box::new(equilibrium(&fewer)?));
        }
        timings.matching_s = t0.elapsed().as_secs_f64();
        sparse.timings = timings;
        Ok(sparse)
    })
}

/// `zoom` (a ZoomOut refinement) of `map`; where the reference's symmetry is known and the
/// refined map reads mirrored in places (`unflip` at `threshold`), those places are repaired and
/// the repaired map refined once more. ZoomOut's map is smooth, so its orientation tells
/// mirrored limbs more clearly than the grown map's.
fn zoomed_and_repaired(
    test: &PreparedShape,
    reference: &PreparedShape,
    map: &[usize],
    threshold: Option<f64>,
    zoom: impl Fn(&[usize]) -> Result<Option<Vec<usize>>, Error>,
) -> Result<Option<Vec<usize>>, Error> {
    let refined = zoom(map)?;
    if let (Some(threshold), Some(symmetry), Some(r)) = (threshold, &reference.symmetry, &refined) {
        if let Some(u) = unflip(&test.mesh, &reference.mesh, r, symmetry, threshold) {
            return Ok(zoom(&u.map)?.or(Some(u.map)));
        }
    }
    Ok(refined)
}

/// Steps 5–6: the regularised functional map from the prediction and the sparse matches'
/// distance maps, and its conversion to point-to-point maps. With an alternative equilibrium
/// ([`SparseMatches::alternative`], a single view) both are completed and the map whose images
/// the forest's posterior supports best on average ([`posterior_support`]) is kept.
pub fn dense_map(
    test: &PreparedShape,
    reference: &PreparedShape,
    prediction: &Prediction,
    label_to_vertex: Option<&[usize]>,
    sparse: &SparseMatches,
    params: &RegularizerParams,
) -> Result<DenseMap, Error> {
    crate::pool::on_pool(|| {
        // The prior's costs of a single view's placements (and the entries not tried), shared by
        // both games' growths.
        let prior = params
            .growth
            .as_ref()
            .filter(|g| {
                (g.part_prior > 0.0 || g.part_candidates > 0) && partial::is_small_part(test, reference)
            })
            .map(|g| growth::prior_costs(prediction, g.part_prior, g.part_candidates));
        let prior = prior.as_deref();
        let mut memo = GrowthMemo::default();
        let first = dense_of_equilibrium(
            test,
            reference,
            prediction,
            label_to_vertex,
            sparse,
            params,
            prior,
            None,
            &mut memo,
        )?;
        let Some(alternative) = sparse.alternative.as_deref() else { return Ok(first) };
        // The predicted functional map depends on the game only through whether it read the
        // prediction as mirrored: the second game's completion takes the first's when they agree.
        let predicted =
            (alternative.prediction_mirrored == sparse.prediction_mirrored).then_some(&first.fmap_predicted);
        let second = dense_of_equilibrium(
            test,
            reference,
            prediction,
            label_to_vertex,
            alternative,
            params,
            prior,
            predicted,
            &mut memo,
        )?;
        let table = posterior_table(prediction, label_to_vertex, sparse, reference)?;
        let posterior =
            LabelledPosterior { prediction, label_to_vertex: table.as_deref().or(label_to_vertex) };
        // The whole map is chosen: region by region (as `select_by_posterior` does for the
        // refinements) measured 68.5 against 68.7 % on SCAPE's single views, with a mean error of
        // 0.077 against 0.065 (seams between two unrelated maps).
        let sigma = MapSelection::default().sigma;
        let mean = |map: &[usize]| {
            let s = posterior_support(&test.mesh, &reference.mesh, &posterior, map, sigma);
            s.iter().sum::<f64>() / s.len().max(1) as f64
        };
        let alternative_kept = mean(&second.map) > mean(&first.map);
        let (a, b) = (first.timings, second.timings);
        let mut kept = if alternative_kept { second } else { first };
        kept.alternative_kept = alternative_kept;
        kept.timings = RegularizerTimings {
            fmap_s: a.fmap_s + b.fmap_s,
            point_map_s: a.point_map_s + b.point_map_s,
            growth_s: a.growth_s + b.growth_s,
            zoomout_s: a.zoomout_s + b.zoomout_s,
            ..sparse.timings
        };
        Ok(kept)
    })
}

/// The label → reference vertex table the dense step reads the prediction through: the
/// reflected one of a prediction read as a mirror image as a whole (`None`: `label_to_vertex`).
fn posterior_table(
    prediction: &Prediction,
    label_to_vertex: Option<&[usize]>,
    sparse: &SparseMatches,
    reference: &PreparedShape,
) -> Result<Option<Vec<usize>>, Error> {
    let plain = LabelledPosterior { prediction, label_to_vertex };
    match (sparse.prediction_mirrored, reference.symmetry.as_deref()) {
        (false, _) => Ok(None),
        (true, Some(symmetry)) => Ok(Some(through_symmetry(&plain, symmetry))),
        (true, None) => Err(Error::InvalidInput(
            "sparse matches of a mirrored prediction need the reference's symmetry".into(),
        )),
    }
}

/// The dense map completed from one game's matches; `prior`: the single view's placement costs
/// ([`growth::prior_costs`]), `None` on other scans; `predicted`: the predicted functional map
/// when already made (from the same prediction, read as mirrored or not as `sparse` reads it);
/// `memo`: what the growths of this scan's maps onto `reference` share.
#[allow(clippy::too_many_arguments)]
fn dense_of_equilibrium(
    test: &PreparedShape,
    reference: &PreparedShape,
    prediction: &Prediction,
    label_to_vertex: Option<&[usize]>,
    sparse: &SparseMatches,
    params: &RegularizerParams,
    prior: Option<&[Vec<f32>]>,
    predicted: Option<&Mat<f64>>,
    memo: &mut GrowthMemo,
) -> Result<DenseMap, Error> {
    check_inputs(test, reference, prediction, label_to_vertex, params)?;
    let n_ref = reference.mesh.n_vertices();
    let plain = LabelledPosterior { prediction, label_to_vertex };
    let mirrored = posterior_table(prediction, label_to_vertex, sparse, reference)?;
    let posterior =
        LabelledPosterior { prediction, label_to_vertex: mirrored.as_deref().or(label_to_vertex) };
    let mut timings = sparse.timings;
    let SparseMatches { test_fields, ref_fields, game, .. } = sparse;
    // 5. Functional maps.
    let t0 = Instant::now();
    let (kt, kr) = (params.fmap.k_test.min(test.spectrum.k()), params.fmap.k_ref.min(reference.spectrum.k()));
    let fmap_predicted = match predicted {
        Some(c) => c.clone(),
        None => fmap::pullback_fmap(&test.spectrum, &reference.spectrum, kt, kr, &posterior)?,
    };
    let (a_fields, b_fields) = (test_fields, ref_fields);
    if a_fields.ncols() != game.matches.len() || b_fields.nrows() != n_ref {
        return Err(Error::SizeMismatch("sparse matches of another shape pair".into()));
    }
    let a = fmap::spectral_coefficients(&test.spectrum, kt, a_fields.as_ref())?;
    let b = fmap::spectral_coefficients(&reference.spectrum, kr, b_fields.as_ref())?;
    let weights: Vec<f64> = game.matches.iter().map(|m| m.weight).collect();
    let fmap_params = FmapParams { k_test: kt, k_ref: kr, ..params.fmap.clone() };
    let c = fmap::solve_regularised_fmap(
        fmap_predicted.as_ref(),
        a.as_ref(),
        b.as_ref(),
        &weights,
        &test.spectrum.eigenvalues,
        &reference.spectrum.eigenvalues,
        &fmap_params,
    )?;
    timings.fmap_s = t0.elapsed().as_secs_f64();

    // 6. Point map, and optional refinement.
    let t0 = Instant::now();
    let fmap_map = if params.spectral_maps {
        Some(fmap::point_to_point(&test.spectrum, &reference.spectrum, c.as_ref())?)
    } else {
        None
    };
    let spectral_map = if params.spectral_maps {
        Some(fmap::point_to_point_restricted(&test.spectrum, &reference.spectrum, c.as_ref(), &posterior)?)
    } else {
        None
    };
    // Vertices no candidate places take the functional map's spectral nearest neighbour.
    let mut anchor_placed = anchor_consistent_map(a_fields, b_fields, &weights, &posterior);
    let unplaced: Vec<usize> = (0..anchor_placed.len()).filter(|&m| anchor_placed[m].is_none()).collect();
    let fallback = match &fmap_map {
        Some(all) => unplaced.iter().map(|&m| all[m]).collect(),
        None => fmap::point_to_point_rows(&test.spectrum, &reference.spectrum, c.as_ref(), &unplaced)?,
    };
    for (&m, r) in unplaced.iter().zip(fallback) {
        anchor_placed[m] = Some(r);
    }
    let anchor_map: Vec<usize> = anchor_placed.into_iter().map(|r| r.unwrap_or(0)).collect();
    timings.point_map_s = t0.elapsed().as_secs_f64();
    let grown = match &params.growth {
        Some(g) if !weights.is_empty() => {
            let t0 = Instant::now();
            let grown = grow_anchors(
                test,
                reference,
                &posterior,
                anchor_map.clone(),
                g,
                &params.partial_scan,
                prior,
                memo,
            )?;
            timings.growth_s = t0.elapsed().as_secs_f64();
            Some(grown)
        }
        _ => None,
    };
    let (map, grown_anchors, dense_orientation, reoriented) = match grown {
        Some(g) => (g.map, g.anchors, Some(g.orientation), g.reoriented),
        None => (anchor_map.clone(), 0, None, false),
    };
    let map = match (params.unflip, &reference.symmetry) {
        (Some(threshold), Some(symmetry)) => {
            unflip(&test.mesh, &reference.mesh, &map, symmetry, threshold).map_or(map, |u| u.map)
        }
        _ => map,
    };
    let (map, grown_map) = match &params.zoomout {
        Some(z) => {
            let t0 = Instant::now();
            let refined = refine_with(test, reference, &posterior, &map, z, params)?;
            timings.zoomout_s = t0.elapsed().as_secs_f64();
            match refined {
                Some(r) => (r, Some(map)),
                None => (map, None),
            }
        }
        None => (map, None),
    };

    let forest_map = prediction.map_labels().into_iter().map(|l| l.map(|l| plain.vertex(l))).collect();
    Ok(DenseMap {
        map,
        anchor_map,
        grown_anchors,
        dense_orientation,
        reoriented,
        spectral_map,
        fmap_map,
        grown_map,
        forest_map,
        fmap_predicted,
        fmap: c,
        matches: sparse.matches.clone(),
        orientation_score: sparse.orientation_score,
        mirror_rejected: sparse.mirror_rejected,
        prediction_mirrored: sparse.prediction_mirrored,
        alternative_kept: false,
        timings,
    })
}

/// Step 8, the refinement of `map` (test vertex → reference vertex) by `zoomout`: ZoomOut with
/// its repair of mirrored parts (the partial ZoomOut for an open part of the reference), then
/// the extrinsic step and the choice against a coarse ZoomOut and the extrinsic step of `map`
/// itself by the forest's posterior (`prediction` read through `label_to_vertex`) as
/// [`ZoomOutParams`] and [`MapSelection`] say. `None` when the
/// ZoomOut's check kept `map`. This is what [`regularize`] does after anchor growth when
/// [`RegularizerParams::zoomout`] is on; any other map of the shapes (e.g. one composed through
/// a third shape) can be refined the same way.
pub fn refine_map(
    test: &PreparedShape,
    reference: &PreparedShape,
    prediction: &Prediction,
    label_to_vertex: Option<&[usize]>,
    map: &[usize],
    zoomout: &ZoomOutParams,
    params: &RegularizerParams,
) -> Result<Option<Vec<usize>>, Error> {
    crate::pool::on_pool(|| {
        check_inputs(test, reference, prediction, label_to_vertex, params)?;
        check_map_onto(test, reference, map)?;
        refine_with(test, reference, &LabelledPosterior { prediction, label_to_vertex }, map, zoomout, params)
    })
}

/// Checks that `map` has one entry per test vertex, each a reference vertex.
pub(super) fn check_map_onto(
    test: &PreparedShape,
    reference: &PreparedShape,
    map: &[usize],
) -> Result<(), Error> {
    let (n_t, n_r) = (test.mesh.n_vertices(), reference.mesh.n_vertices());
    if map.len() != n_t || map.iter().any(|&r| r >= n_r) {
        return Err(Error::SizeMismatch(format!(
            "a map of {} entries for a test shape of {n_t} vertices onto {n_r}",
            map.len()
        )));
    }
    Ok(())
}

/// Whether `test` is refined onto `reference` by the partial ZoomOut (an open part of it), which
/// skips the extrinsic step, the choice and the settling round.
pub(super) fn refines_partially(
    test: &PreparedShape,
    reference: &PreparedShape,
    params: &RegularizerParams,
) -> bool {
    params.partial_zoomout && partial_area_ratio(test, reference).is_some()
}

/// A point map, test vertex → reference vertex.
type Map = Vec<usize>;

fn refine_with(
    test: &PreparedShape,
    reference: &PreparedShape,
    posterior: &LabelledPosterior<'_>,
    map: &[usize],
    z: &ZoomOutParams,
    params: &RegularizerParams,
) -> Result<Option<Vec<usize>>, Error> {
    // An open part of the reference gets the partial (rectangular) ZoomOut; a small part none.
    let partial = refines_partially(test, reference, params);
    if partial && partial::is_small_part(test, reference) {
        return Ok(None);
    }
    let zoom = |m: &[usize]| {
        if partial {
            refine_zoomout_partial(test, reference, m, z)
        } else {
            refine_zoomout(test, reference, m, z)
        }
    };
    // The refined map, and the choice's two other maps: all three start from `map` alone, so
    // they run side by side (parts of each are sequential).
    let fine = || -> Result<Option<Map>, Error> {
        let refined = zoomed_and_repaired(test, reference, map, params.unflip, zoom)?;
        match (&z.extrinsic, refined, partial) {
            (Some(e), Some(r), false) => Ok(Some(refine_extrinsic(test, reference, &r, e)?)),
            (_, refined, _) => Ok(refined),
        }
    };
    let select = match (&z.select, partial) {
        (Some(select), false) => {
            select.check().map_err(|reason| Error::InvalidParameter { name: "select", reason })?;
            Some(select)
        }
        _ => None,
    };
    let others = |select: &MapSelection| -> Result<(Option<Map>, Option<Map>), Error> {
        let zc = ZoomOutParams { k_start: select.coarse.0, k_final: select.coarse.1, select: None, ..*z };
        let (coarse, sharper) = rayon::join(
            || {
                zoomed_and_repaired(test, reference, map, params.unflip, |m| {
                    refine_zoomout(test, reference, m, &zc)
                })
            },
            // The extrinsic step of `map` itself, with the same repair of mirrored parts.
            || match (&z.extrinsic, select.grown_extrinsic) {
                (Some(e), true) => zoomed_and_repaired(test, reference, map, params.unflip, |m| {
                    refine_extrinsic(test, reference, m, e).map(Some)
                }),
                _ => Ok(None),
            },
        );
        Ok((coarse?, sharper?))
    };
    let (mut refined, others) = match select {
        Some(select) => {
            let (refined, others) = rayon::join(fine, || others(select));
            (refined?, Some(others?))
        }
        None => (fine()?, None),
    };
    if let (Some(select), Some(fine), Some((coarse, sharper))) = (select, &refined, others) {
        refined = Some(refine::choose_refined(
            test,
            reference,
            posterior,
            fine,
            coarse.as_deref(),
            sharper,
            select,
        ));
    }
    if partial {
        return Ok(refined);
    }
    refined.map(|chosen| finish_refinement(test, reference, chosen, z)).transpose()
}

/// The refinement's last steps on `map`: the settling round ([`settle_map`], when it and the
/// extrinsic step are on), then the local rigid fit ([`local_rigid`], when on). Run at the end of
/// every refinement of a complete scan and again on a map that reached the reference by a carry
/// or a vote ([`DenseMap::settled`]).
pub(super) fn finish_refinement(
    test: &PreparedShape,
    reference: &PreparedShape,
    mut map: Vec<usize>,
    z: &ZoomOutParams,
) -> Result<Vec<usize>, Error> {
    if let (Some(reach), Some(e)) = (z.settle, &z.extrinsic) {
        map = settle_map(test, reference, &map, e, reach)?;
    }
    if let Some(rigid) = &z.rigid {
        map = local_rigid(&test.mesh, &reference.mesh, &map, rigid)?;
    }
    Ok(map)
}
