//! Maps between two scans through the label space (the paper's composition `A → labels → B`).
//!
//! Neither scan need be a training shape. Both scans are first mapped onto the model's
//! reference by the regulariser. `B`'s map, inverted, gives every label a vertex of `B` (a
//! reference vertex that no vertex of `B` lands on takes the `B` vertex of the nearest
//! reference vertex that one does, along the reference's edges), and composing `A`'s map with
//! that inverse gives a first map `A → B`, each half of it checked for orientation on its own.
//! `A`'s forest posterior is then read through the label → `B`-vertex table, kept only where it
//! lands within `radius` (Euclidean, in units of `√area(B)`) of the composed map's vertex, the
//! composed vertex itself added as a candidate with weight `composed_weight`: the pair's
//! posterior over `B`'s vertices, with the radius keeping the mirror image (which the game alone
//! can pick on a near-symmetric body) out of reach.
//!
//! With the regulariser's refinement on ([`super::RegularizerParams::zoomout`], the default for
//! pairs), the composed map itself is refined against `B` ([`super::refine_map`]: ZoomOut in
//! the two scans' own bases, the extrinsic step, the choice against a coarse ZoomOut by the
//! pair's posterior): [`PairStart::Composed`]. Otherwise, or with [`PairStart::Regularised`],
//! the pair's posterior is regularised against `B` itself (the same game, functional map and
//! anchor growth as a map to the reference, with `B`'s geometry deciding what is consistent),
//! then refined when the refinement is on. On FAUST pairs the composed start is the better one
//! (mean error ×100 1.49 vs 1.51 on 20 pairs) and skips a whole regularisation.

use serde::{Deserialize, Serialize};

use super::RegularizerError as Error;
use crate::{forest::Prediction, geodesic::dijkstra_nearest_source, mesh::Mesh};

use super::{refine_map, regularize, DenseMap, PreparedShape, RegularizerParams};

/// Settings of the pairwise map (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PairParams {
    /// Forest candidates farther than this from the composed map's vertex are dropped
    /// (Euclidean, in units of `√area(B)`; default 0.2).
    pub radius: f64,
    /// Weight of the composed map's vertex among a vertex's candidates, relative to the total
    /// weight of the kept forest candidates (default 0.5; a vertex with no kept candidate gets
    /// the composed vertex alone).
    pub composed_weight: f64,
    /// Refine the two maps onto the reference with the regulariser's refinement too (default
    /// true: their composition is where the pair map starts; on FAUST pairs, unrefined halves
    /// cost 0.05–0.07 of mean error ×100 and save half the time).
    #[serde(default = "yes")]
    pub refine_halves: bool,
    /// Where the refinement of the map `A → B` starts (see the module docs).
    #[serde(default)]
    pub start: PairStart,
}

fn yes() -> bool {
    true
}

/// Where the map `A → B` is refined from when the regulariser's refinement is on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum PairStart {
    /// The composed map `A → reference → B` (the default).
    #[default]
    Composed,
    /// The pair's posterior regularised against `B` (game, functional map, anchor growth).
    Regularised,
}

impl Default for PairParams {
    fn default() -> Self {
        Self { radius: 0.2, composed_weight: 0.5, refine_halves: true, start: PairStart::Composed }
    }
}

impl PairParams {
    /// Checks the settings, naming the broken rule.
    pub fn check(&self) -> Result<(), Error> {
        for (name, value) in [("pair radius", self.radius), ("pair composed_weight", self.composed_weight)] {
            if !(value >= 0.0 && value.is_finite()) {
                return Err(Error::InvalidParameter {
                    name,
                    reason: format!("{value}: must be finite and ≥ 0"),
                });
            }
        }
        Ok(())
    }

    /// The regulariser's settings for the two maps onto the reference: `params`, without its
    /// ZoomOut refinement unless [`PairParams::refine_halves`].
    pub fn halves(&self, params: &RegularizerParams) -> RegularizerParams {
        let mut halves = params.clone();
        if !self.refine_halves {
            halves.zoomout = None;
        }
        halves
    }
}

/// `A`'s posterior over the vertices of `B`: each forest label read through `label_to_b`, kept
/// where it lands within `params.radius` of `composed[a]`, merged per vertex, plus `composed[a]`
/// itself (see [`PairParams`]).
///
/// ```
/// use shapeforest::{forest::Prediction, mesh::Mesh, regularizer::{pair_posterior, PairParams}};
/// let b = Mesh::new(vec![[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [5.0, 0.0, 0.0], [0.0, 5.0, 0.0]], vec![[0, 1, 3], [1, 2, 3]]).unwrap();
/// // One vertex of A with labels 0 (→ B vertex 1, near) and 1 (→ B vertex 2, far).
/// let a = Prediction::from_parts(2, vec![0, 2], vec![0, 1], vec![0.5, 0.5]).unwrap();
/// let p = pair_posterior(&a, &[1, 2], &[0], &b, &PairParams::default()).unwrap();
/// assert_eq!(p.posterior(0).0, &[0, 1]); // the composed vertex 0 and label 0's vertex 1
/// ```
pub fn pair_posterior(
    prediction_a: &Prediction,
    label_to_b: &[usize],
    composed: &[usize],
    b: &Mesh,
    params: &PairParams,
) -> Result<Prediction, Error> {
    params.check()?;
    let n_b = b.n_vertices();
    let radius = params.radius * b.surface_area().max(f64::MIN_POSITIVE).sqrt();
    let r2 = radius * radius;
    let d2 = |x: usize, y: usize| {
        let (p, q) = (b.vertices[x], b.vertices[y]);
        (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)
    };
    let n = prediction_a.n_vertices().min(composed.len());
    let mut offsets = Vec::with_capacity(n + 1);
    offsets.push(0);
    let (mut labels, mut probs) = (Vec::new(), Vec::new());
    let mut entries: Vec<(u32, f32)> = Vec::new();
    for (a, &c) in composed.iter().enumerate().take(n) {
        entries.clear();
        let (ls, ps) = prediction_a.posterior(a);
        for (&l, &p) in ls.iter().zip(ps) {
            if let Some(&v) = label_to_b.get(l as usize) {
                if v < n_b && c < n_b && d2(v, c) <= r2 {
                    entries.push((v as u32, p));
                }
            }
        }
        let kept: f32 = entries.iter().map(|e| e.1).sum();
        if c < n_b {
            let w = if kept > 0.0 { params.composed_weight as f32 * kept } else { 1.0 };
            entries.push((c as u32, w));
        }
        entries.sort_unstable_by_key(|e| e.0);
        let total: f32 = entries.iter().map(|e| e.1).sum();
        let mut last = u32::MAX;
        for &(v, p) in entries.iter() {
            let p = if total > 0.0 { p / total } else { p };
            if v == last {
                if let Some(x) = probs.last_mut() {
                    *x += p;
                }
            } else {
                labels.push(v);
                probs.push(p);
                last = v;
            }
        }
        offsets.push(labels.len());
    }
    Ok(Prediction::from_parts(n_b, offsets, labels, probs)?)
}

/// The pair step's result (see [`regularize_onto`]).
pub struct PairStep {
    /// `A` vertex → `B` vertex: the pair map.
    pub map: Vec<usize>,
    /// The pair's posterior regularised against `B`, when the map came that way
    /// ([`PairStart::Regularised`], or the refinement off); its `map` is `map`.
    pub regularised: Option<DenseMap>,
    /// The composed map `A → reference → B`.
    pub composed: Vec<usize>,
    /// `A`'s posterior over the vertices of `B` ([`pair_posterior`]).
    pub posterior: Prediction,
}

/// A map from scan `A` to scan `B` and the maps onto the reference it went through.
pub struct PairMap {
    /// `A` vertex → `B` vertex.
    pub map: Vec<usize>,
    /// The pair's posterior regularised against `B`, when the map came that way (see
    /// [`PairStep::regularised`]).
    pub regularised: Option<DenseMap>,
    /// `B` vertex → reference vertex (the step through the reference).
    pub b_to_reference: DenseMap,
    /// `A` vertex → reference vertex (the first half of the composed map).
    pub a_to_reference: DenseMap,
    /// The composed map `A → reference → B` that guided the pair's posterior.
    pub composed: Vec<usize>,
}

/// For every reference vertex, a vertex of `B` that lands on it under `map` (`B` → reference),
/// or, where none lands, the one landing on the nearest reference vertex that is hit (along
/// the reference's edges). Fails only for an empty map.
///
/// ```
/// use shapeforest::{mesh::Mesh, regularizer::invert_map};
/// let strip = Mesh::new(
///     vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [3.0, 0.0, 0.0], [3.0, 1.0, 0.0]],
///     vec![[0, 1, 3], [1, 2, 3]],
/// ).unwrap();
/// // B has two vertices, landing on reference vertices 0 and 2.
/// assert_eq!(invert_map(&[0, 2], &strip).unwrap(), vec![0, 0, 1, 1]);
/// ```
pub fn invert_map(map: &[usize], reference: &Mesh) -> Result<Vec<usize>, Error> {
    let n_ref = reference.n_vertices();
    let mut hit = vec![usize::MAX; n_ref];
    for (b, &r) in map.iter().enumerate() {
        if let Some(slot) = hit.get_mut(r) {
            if *slot == usize::MAX {
                *slot = b;
            }
        }
    }
    let sources: Vec<usize> = (0..n_ref).filter(|&r| hit[r] != usize::MAX).collect();
    let (_, nearest) = dijkstra_nearest_source(reference, &sources)?;
    // A reference vertex in a component that nothing lands on takes the first hit.
    let fallback = hit[sources[0]];
    Ok((0..n_ref)
        .map(|r| nearest.get(r).and_then(|&i| sources.get(i)).map_or(fallback, |&s| hit[s]))
        .collect())
}

/// Maps scan `a` to scan `b` through the reference (see the module docs): `prediction_a` and
/// `prediction_b` are the forest's posteriors of the two scans, `label_to_vertex` the model's
/// label → reference-vertex table (`None`: label = reference vertex). The maps onto the
/// reference take `pair.halves(params)`, the map `A → B` `params`.
#[allow(clippy::too_many_arguments)]
pub fn regularize_pair(
    a: &PreparedShape,
    b: &PreparedShape,
    reference: &PreparedShape,
    prediction_a: &Prediction,
    prediction_b: &Prediction,
    label_to_vertex: Option<&[usize]>,
    params: &RegularizerParams,
    pair: &PairParams,
) -> Result<PairMap, Error> {
    pair.check()?;
    let halves = pair.halves(params);
    let a_to_reference = regularize(a, reference, prediction_a, label_to_vertex, &halves)?;
    let b_to_reference = regularize(b, reference, prediction_b, label_to_vertex, &halves)?;
    let step = regularize_onto(
        a,
        b,
        &reference.mesh,
        prediction_a,
        &a_to_reference.map,
        &b_to_reference.map,
        label_to_vertex,
        params,
        pair,
    )?;
    Ok(PairMap {
        map: step.map,
        regularised: step.regularised,
        b_to_reference,
        a_to_reference,
        composed: step.composed,
    })
}

/// The pair step alone, from the two maps onto the reference (`a_to_reference`,
/// `b_to_reference`): the map `A → B` (see the module docs for the two routes), the composed
/// map and the pair's posterior.
#[allow(clippy::too_many_arguments)]
pub fn regularize_onto(
    a: &PreparedShape,
    b: &PreparedShape,
    reference: &Mesh,
    prediction_a: &Prediction,
    a_to_reference: &[usize],
    b_to_reference: &[usize],
    label_to_vertex: Option<&[usize]>,
    params: &RegularizerParams,
    pair: &PairParams,
) -> Result<PairStep, Error> {
    let inverse = invert_map(b_to_reference, reference)?;
    let label_to_b: Vec<usize> = match label_to_vertex {
        Some(t) => t.iter().map(|&r| inverse.get(r).copied().unwrap_or(0)).collect(),
        None => inverse.clone(),
    };
    let composed: Vec<usize> = a_to_reference.iter().map(|&r| inverse.get(r).copied().unwrap_or(0)).collect();
    let posterior = pair_posterior(prediction_a, &label_to_b, &composed, &b.mesh, pair)?;
    if let (Some(z), PairStart::Composed) = (&params.zoomout, pair.start) {
        let map =
            refine_map(a, b, &posterior, None, &composed, z, params)?.unwrap_or_else(|| composed.clone());
        return Ok(PairStep { map, regularised: None, composed, posterior });
    }
    let dense = regularize(a, b, &posterior, None, params)?;
    Ok(PairStep { map: dense.map.clone(), regularised: Some(dense), composed, posterior })
}
