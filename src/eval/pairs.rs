//! The field's pairwise protocol: maps between pairs of test shapes, scored on the target.
//!
//! The shape-correspondence literature (FAUST, SCAPE, SHREC'19 tables) scores a method by the
//! maps it gives between **pairs of test shapes**, none of them seen in training: for a pair
//! `(A, B)` and every corresponded point `k` (row `k` of the ground-truth tables), vertex
//! `truth_A[k]` is mapped to a vertex `m` of `B`, and its error is the geodesic distance on `B`
//! from `m` to `truth_B[k]`, divided by `√area(B)`. Tables give the mean error ×100 over all
//! points of all pairs, strict (no symmetric allowance); the fraction within 0.05 and 0.1 and
//! the cumulative curve complete it. With a symmetry map of the labels the flips-allowed
//! figures are given beside them.
//!
//! One forest is trained on the given training shapes; its first shape is the reference. Three
//! maps `A → B` are measured on the same points:
//!
//! | [`PairMethod`] | map |
//! |---|---|
//! | `Pair` | [`crate::regularizer::regularize_pair`]: `A`'s posterior read through `B`'s map onto the reference and regularised against `B`, before its ZoomOut |
//! | `Composed` | `A → reference` and `B → reference`, each regularised (and refined when the regulariser's ZoomOut is on and [`crate::regularizer::PairParams::refine_halves`]), composed by inverting the second ([`crate::regularizer::invert_map`]) |
//! | `PairZoomOut` | the pair map, refined: with the regulariser's refinement on (the default), `Composed` refined against `B` ([`crate::regularizer::PairStart::Composed`], the default) or `Pair` refined ([`crate::regularizer::PairStart::Regularised`]); with it off, `Pair` refined by ZoomOut ([`crate::regularizer::refine_zoomout`]) |
//!
//! Each shape's map onto the reference is computed once, whatever the number of pairs it is in.
//! Distances on `B` come from the heat method (`t = h²`), in blocks of sources, so memory stays
//! `O(n_B · block)` whatever the number of points. The protocol is pure orchestration: no
//! printing; progress through an optional callback.

use std::{collections::HashMap, path::PathBuf, sync::Arc, time::Instant};

use serde::{Deserialize, Serialize};

use super::EvalError;
use crate::{
    eval::protocol::ProtocolShape,
    forest::{RandomForestParams, TrainingSet, TrainingShape},
    geodesic::{HeatMethodSolver, HeatParams},
    regularizer::{
        refine_zoomout, regularize, regularize_onto, DenseMap, PairParams, PreparedShape, RegularizerParams,
        ZoomOutParams,
    },
    spectral::{spectrum_cached, Spectrum, SpectrumCache, SpectrumParams},
};

/// A measured pairwise method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum PairMethod {
    /// Regularised against the target (the method).
    Pair,
    /// Two maps onto the reference, composed.
    Composed,
    /// The pair map, refined (see the module docs: from `Composed` by default).
    PairZoomOut,
}

impl PairMethod {
    /// All methods, in report order.
    pub const ALL: [PairMethod; 3] = [PairMethod::Pair, PairMethod::Composed, PairMethod::PairZoomOut];

    /// A short name for tables and CSV files.
    ///
    /// ```
    /// use shapeforest::eval::pairs::PairMethod;
    /// assert_eq!(PairMethod::Pair.name(), "pair+reg");
    /// ```
    pub fn name(self) -> &'static str {
        match self {
            PairMethod::Pair => "pair+reg",
            PairMethod::Composed => "composed",
            PairMethod::PairZoomOut => "pair+zoomout",
        }
    }
}

/// Settings of the pairwise protocol.
#[derive(Clone, Debug)]
pub struct PairsParams {
    /// Training shapes (indices into the shape list); the first is the reference.
    pub training: Vec<usize>,
    /// Pairs `(A, B)` to map `A → B` (indices into the shape list).
    pub pairs: Vec<(usize, usize)>,
    /// Forest hyper-parameters.
    pub forest: RandomForestParams,
    /// Spectrum settings (default 100 eigenpairs).
    pub spectrum: SpectrumParams,
    /// Regulariser settings.
    pub regularizer: RegularizerParams,
    /// Heat-method settings of the evaluation distances.
    pub eval_heat: HeatParams,
    /// Spectrum cache directory (`None`: no cache).
    pub cache_dir: Option<PathBuf>,
    /// Sources per block of evaluation distance fields (default 512).
    pub block: usize,
    /// Settings of the pair step.
    pub pair: PairParams,
    /// ZoomOut of [`PairMethod::PairZoomOut`] (see [`crate::regularizer::refine_zoomout`]).
    pub zoomout: ZoomOutParams,
    /// The distances errors are measured with (default: the heat method).
    pub eval_distances: EvalDistances,
}

/// How the evaluation measures geodesic distances on the target.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum EvalDistances {
    /// The heat method (`t = h²`, one factorisation, blocks of sources): fast, but it smooths
    /// short distances (one edge length reads ~12 % short on FAUST remeshed).
    #[default]
    Heat,
    /// First-order fast marching from each source ([`crate::geodesic::fast_marching_distances`]):
    /// exact along an edge, a few per cent long across triangles; closer to the exact geodesics
    /// of the published tables at the short range where a map's errors lie.
    FastMarching,
}

impl Default for PairsParams {
    fn default() -> Self {
        Self {
            training: Vec::new(),
            pairs: Vec::new(),
            forest: RandomForestParams::default(),
            spectrum: SpectrumParams::new(100),
            // ZoomOut on: across bodies of other builds it is the largest single gain.
            regularizer: RegularizerParams { zoomout: Some(ZoomOutParams::default()), ..Default::default() },
            eval_heat: HeatParams::default(),
            cache_dir: None,
            block: 512,
            pair: PairParams::default(),
            zoomout: ZoomOutParams::default(),
            eval_distances: EvalDistances::Heat,
        }
    }
}

/// Errors of one method on one pair.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PairErrors {
    /// The method.
    pub method: PairMethod,
    /// Strict errors, one per corresponded point.
    pub strict: Vec<f64>,
    /// Flips-allowed errors, when a symmetry map was given.
    pub symmetric: Option<Vec<f64>>,
    /// The vertex of `B` each corresponded point was mapped to (the true one is
    /// [`ProtocolShape::truth`](super::protocol::ProtocolShape::truth)`[k]` of `B`), for measuring the
    /// errors with other distances.
    #[serde(default)]
    pub images: Vec<usize>,
}

/// The result of one pair.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PairResult {
    /// Source shape `A` (index into the shape list).
    pub a: usize,
    /// Target shape `B`.
    pub b: usize,
    /// Errors per method, in [`PairMethod::ALL`] order.
    pub methods: Vec<PairErrors>,
    /// Seconds of the step specific to the pair (the pair map from the two maps onto the
    /// reference; the `Pair` row's own regularisation is not counted when the map did not
    /// need it).
    pub pair_s: f64,
}

impl PairResult {
    /// The errors of `method`.
    pub fn errors(&self, method: PairMethod) -> Option<&PairErrors> {
        self.methods.iter().find(|m| m.method == method)
    }
}

/// The result of the pairwise protocol.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PairsReport {
    /// Shape names, in input order.
    pub shape_names: Vec<String>,
    /// Training shapes (the first is the reference).
    pub training: Vec<usize>,
    /// Whether flips-allowed errors were computed.
    pub has_symmetry: bool,
    /// Corresponded points evaluated per pair.
    pub points_per_pair: usize,
    /// Seconds: spectra, training, maps onto the reference (all shapes), evaluation fields.
    pub timings: PairsTimings,
    /// One result per pair, in input order.
    pub pairs: Vec<PairResult>,
}

/// Seconds per stage of [`run_pairs`].
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize)]
pub struct PairsTimings {
    /// Spectra (or cache reads) of every shape used.
    pub spectra_s: f64,
    /// Training the forest.
    pub train_s: f64,
    /// Predicting and regularising every test shape onto the reference.
    pub to_reference_s: f64,
    /// Regularising the pairs.
    pub pairs_s: f64,
    /// Evaluation distance fields.
    pub eval_s: f64,
}

super::pooled_report!(PairsReport, PairMethod, pairs);

/// Progress of [`run_pairs`].
#[derive(Clone, Copy, Debug)]
pub enum PairsEvent<'a> {
    /// A stage started: "spectra", "train", "to-reference", "pairs".
    Stage(&'static str),
    /// A shape is mapped onto the reference (`done` of `total`).
    ToReference {
        /// Shapes done.
        done: usize,
        /// Shapes in all.
        total: usize,
        /// The shape.
        name: &'a str,
    },
    /// A pair is done.
    PairDone {
        /// Pairs done.
        done: usize,
        /// Pairs in all.
        total: usize,
        /// Source shape.
        a: &'a str,
        /// Target shape.
        b: &'a str,
    },
}

/// The maps of one pair in [`PairMethod::ALL`] order, and the pair step's seconds.
type PairMaps = (Vec<usize>, Vec<usize>, Vec<usize>, f64);

fn invalid(msg: String) -> EvalError {
    EvalError::InvalidInput(msg)
}

/// Checks the shapes, the symmetry, the training set and the pairs.
fn check(
    shapes: &[ProtocolShape],
    symmetry: Option<&[usize]>,
    params: &PairsParams,
) -> Result<usize, EvalError> {
    let n_labels = super::protocol::check_shapes(shapes, symmetry)?;
    params.pair.check().map_err(|e| invalid(e.to_string()))?;
    if params.training.is_empty() {
        return Err(invalid("the pairwise protocol needs at least one training shape".into()));
    }
    if params.pairs.is_empty() {
        return Err(invalid("no pairs to evaluate".into()));
    }
    let n = shapes.len();
    if let Some(&i) = params.training.iter().find(|&&i| i >= n) {
        return Err(invalid(format!("training shape index {i} outside the {n} shapes")));
    }
    for &(a, b) in &params.pairs {
        if a >= n || b >= n {
            return Err(invalid(format!("pair ({a}, {b}) outside the {n} shapes")));
        }
        if a == b {
            return Err(invalid(format!("pair of {} with itself", shapes[a].name)));
        }
    }
    Ok(n_labels)
}

/// Distances on `mesh` from each of `sources` (one column each) by `kind`.
fn distance_block(
    mesh: &crate::mesh::Mesh,
    solver: &HeatMethodSolver,
    sources: &[usize],
    kind: EvalDistances,
) -> Result<faer::Mat<f64>, EvalError> {
    use rayon::prelude::*;
    match kind {
        EvalDistances::Heat => Ok(solver.distances_from_many(sources)?),
        EvalDistances::FastMarching => {
            let cols: Vec<Vec<f64>> = sources
                .par_iter()
                .map(|&s| crate::geodesic::fast_marching_distances(mesh, &[s]))
                .collect::<Result<_, _>>()?;
            Ok(faer::Mat::from_fn(mesh.n_vertices(), sources.len(), |v, j| cols[j][v]))
        }
    }
}

/// Runs the pairwise protocol (see the module documentation).
///
/// `symmetry`, when given, maps each label to the label at its mirror image; it enables the
/// flips-allowed figures. Shapes in a pair may also be training shapes (the field's protocol
/// keeps them apart; the caller chooses).
pub fn run_pairs(
    shapes: &[ProtocolShape],
    symmetry: Option<&[usize]>,
    params: &PairsParams,
    mut progress: Option<&mut dyn FnMut(PairsEvent<'_>)>,
) -> Result<PairsReport, EvalError> {
    let n_labels = check(shapes, symmetry, params)?;
    let forest_params = params.forest.clone().check()?;
    let cache = match &params.cache_dir {
        Some(d) => Some(SpectrumCache::new(d.clone())?),
        None => None,
    };
    let mut emit = |e: PairsEvent<'_>| {
        if let Some(cb) = progress.as_mut() {
            cb(e);
        }
    };
    let mut timings = PairsTimings::default();

    // Spectra of every shape used.
    emit(PairsEvent::Stage("spectra"));
    let t0 = Instant::now();
    let mut tested: Vec<usize> = params.pairs.iter().flat_map(|&(a, b)| [a, b]).collect();
    tested.sort_unstable();
    tested.dedup();
    let mut spectra: HashMap<usize, Arc<Spectrum>> = HashMap::new();
    for &s in params.training.iter().chain(&tested) {
        if spectra.contains_key(&s) {
            continue;
        }
        let sp = spectrum_cached(&shapes[s].mesh, &params.spectrum, cache.as_ref())?;
        spectra.insert(s, Arc::new(sp));
    }
    timings.spectra_s = t0.elapsed().as_secs_f64();

    // One forest on the training shapes (vertex → label from the truth tables).
    emit(PairsEvent::Stage("train"));
    let t0 = Instant::now();
    let members: Vec<TrainingShape> = params
        .training
        .iter()
        .map(|&s| {
            let mut labels = vec![None; shapes[s].mesh.n_vertices()];
            for (k, &v) in shapes[s].truth.iter().enumerate() {
                labels[v] = Some(k as u32);
            }
            TrainingShape::new(shapes[s].name.clone(), spectra[&s].clone(), labels)
        })
        .collect();
    let forest = forest_params.fit(&TrainingSet::new(members, n_labels)?)?;
    timings.train_s = t0.elapsed().as_secs_f64();

    // Every tested shape onto the reference.
    emit(PairsEvent::Stage("to-reference"));
    let t0 = Instant::now();
    let reference = params.training[0];
    let table = &shapes[reference].truth;
    let heat = params.regularizer.heat;
    // ZoomOut beyond the descriptors' eigenpairs: every shape mapped gets a spectrum of as many
    // eigenpairs as the largest ZoomOut basis asks for (its first K are the descriptors' own).
    let zoomout_k = [params.regularizer.zoomout.map(|z| z.k_final), Some(params.zoomout.k_final)]
        .into_iter()
        .flatten()
        .max()
        .unwrap_or(0);
    let zoomout_params = params.spectrum.with_k(zoomout_k);
    let prepare = |s: usize| -> Result<PreparedShape, EvalError> {
        let p = PreparedShape::new(shapes[s].mesh.clone(), spectra[&s].clone(), heat)?;
        if zoomout_k <= params.spectrum.k {
            return Ok(p);
        }
        let sp = spectrum_cached(&shapes[s].mesh, &zoomout_params, cache.as_ref())?;
        Ok(p.with_zoomout_spectrum(Arc::new(sp))?)
    };
    let ref_prepared = prepare(reference)?.serving_many();
    let mut prepared: HashMap<usize, (PreparedShape, crate::forest::Prediction, DenseMap)> = HashMap::new();
    let halves = params.pair.halves(&params.regularizer);
    for (i, &s) in tested.iter().enumerate() {
        let p = prepare(s)?;
        let prediction = forest.predict(&p.spectrum)?;
        let dense = regularize(&p, &ref_prepared, &prediction, Some(table), &halves)?;
        prepared.insert(s, (p, prediction, dense));
        emit(PairsEvent::ToReference { done: i + 1, total: tested.len(), name: &shapes[s].name });
    }
    timings.to_reference_s = t0.elapsed().as_secs_f64();

    // The maps of every pair, grouped by target so that each target's fields are made once.
    emit(PairsEvent::Stage("pairs"));
    // Per pair: the three maps (pair, composed, pair + ZoomOut) and the pair step's seconds.
    let mut maps: Vec<PairMaps> = Vec::with_capacity(params.pairs.len());
    for (done, &(a, b)) in params.pairs.iter().enumerate() {
        let (pa, pred_a, a_to_ref) = &prepared[&a];
        let (pb, _, b_to_ref) = &prepared[&b];
        let t0 = Instant::now();
        let step = regularize_onto(
            pa,
            pb,
            &ref_prepared.mesh,
            pred_a,
            &a_to_ref.map,
            &b_to_ref.map,
            Some(table),
            &params.regularizer,
            &params.pair,
        )?;
        let pair_s = t0.elapsed().as_secs_f64();
        timings.pairs_s += pair_s;
        // The `pair+reg` row (the pair's posterior regularised against B, unrefined) and the
        // `pair+zoomout` row (the pair map, refined).
        let (pair_map, zoomed) = match (step.regularised, &params.regularizer.zoomout) {
            // Refined by the regulariser (or kept by its check: no grown map then).
            (Some(d), Some(_)) => (d.grown_map.unwrap_or_else(|| d.map.clone()), d.map),
            (Some(d), None) => {
                let zoomed =
                    refine_zoomout(pa, pb, &d.map, &params.zoomout)?.unwrap_or_else(|| d.map.clone());
                (d.map, zoomed)
            }
            // Refined from the composed map: the regularised pair map is measured beside it (not
            // part of the method, not timed).
            (None, _) => {
                let unrefined = RegularizerParams { zoomout: None, ..params.regularizer.clone() };
                (regularize(pa, pb, &step.posterior, None, &unrefined)?.map, step.map)
            }
        };
        let composed = step.composed;
        maps.push((pair_map, composed, zoomed, pair_s));
        emit(PairsEvent::PairDone {
            done: done + 1,
            total: params.pairs.len(),
            a: &shapes[a].name,
            b: &shapes[b].name,
        });
    }

    // Errors on each target, in blocks of ground-truth sources.
    let t0 = Instant::now();
    let mut errors: Vec<[Vec<f64>; 6]> = vec![Default::default(); params.pairs.len()];
    let block = params.block.max(1);
    for &b in &tested {
        let on_b: Vec<usize> = (0..params.pairs.len()).filter(|&i| params.pairs[i].1 == b).collect();
        if on_b.is_empty() {
            continue;
        }
        let mesh = &shapes[b].mesh;
        let norm = 1.0 / mesh.surface_area().max(f64::MIN_POSITIVE).sqrt();
        let solver = HeatMethodSolver::new(mesh, params.eval_heat)?;
        let truth_b = &shapes[b].truth;
        let mut start = 0;
        while start < n_labels {
            let end = (start + block).min(n_labels);
            let fields = distance_block(mesh, &solver, &truth_b[start..end], params.eval_distances)?;
            let mirror = match symmetry {
                Some(sym) => {
                    let m: Vec<usize> = (start..end).map(|k| truth_b[sym[k]]).collect();
                    Some(distance_block(mesh, &solver, &m, params.eval_distances)?)
                }
                None => None,
            };
            for &i in &on_b {
                let a = params.pairs[i].0;
                let truth_a = &shapes[a].truth;
                let (pair_map, composed, zoomed, _) = &maps[i];
                for (mi, map) in [pair_map, composed, zoomed].into_iter().enumerate() {
                    for k in start..end {
                        let m = map[truth_a[k]];
                        errors[i][2 * mi].push(fields[(m, k - start)] * norm);
                        if let Some(mf) = &mirror {
                            let s = fields[(m, k - start)].min(mf[(m, k - start)]);
                            errors[i][2 * mi + 1].push(s * norm);
                        }
                    }
                }
            }
            start = end;
        }
    }
    timings.eval_s = t0.elapsed().as_secs_f64();

    let images = |a: usize, map: &[usize]| shapes[a].truth.iter().map(|&v| map[v]).collect::<Vec<usize>>();
    let pairs = params
        .pairs
        .iter()
        .zip(errors)
        .zip(&maps)
        .map(|((&(a, b), [ps, py, cs, cy, zs, zy]), maps_i)| PairResult {
            a,
            b,
            methods: vec![
                PairErrors {
                    method: PairMethod::Pair,
                    strict: ps,
                    symmetric: symmetry.map(|_| py),
                    images: images(a, &maps_i.0),
                },
                PairErrors {
                    method: PairMethod::Composed,
                    strict: cs,
                    symmetric: symmetry.map(|_| cy),
                    images: images(a, &maps_i.1),
                },
                PairErrors {
                    method: PairMethod::PairZoomOut,
                    strict: zs,
                    symmetric: symmetry.map(|_| zy),
                    images: images(a, &maps_i.2),
                },
            ],
            pair_s: maps_i.3,
        })
        .collect();
    Ok(PairsReport {
        shape_names: shapes.iter().map(|s| s.name.clone()).collect(),
        training: params.training.clone(),
        has_symmetry: symmetry.is_some(),
        points_per_pair: n_labels,
        timings,
        pairs,
    })
}
