//! Anchor growth and the anchor-consistent placement of every vertex (steps 6–7 of the
//! regulariser): see [`super::AnchorGrowthParams`].

use super::{
    partial::{boundary_distances, pair_trust, PartialScanParams},
    smoothing::smooth_placement,
    *,
};
use crate::fmap::RowMajor;

/// For each test vertex, the candidate reference vertex whose normalised distances to the
/// anchors best match the vertex's own (weighted L1); `None` where there is no candidate at a
/// finite cost, or no anchor.
pub(super) fn anchor_consistent_map(
    test_fields: &Mat<f64>,
    ref_fields: &Mat<f64>,
    weights: &[f64],
    posterior: &LabelledPosterior<'_>,
) -> Vec<Option<usize>> {
    use rayon::prelude::*;
    let s = weights.len();
    let n = posterior.n_test_vertices();
    if s == 0 {
        return vec![None; n];
    }
    // Each vertex's distances as a contiguous row (the columns stride by the vertex count).
    let (test_rows, ref_rows) =
        rayon::join(|| RowMajor::new(test_fields.as_ref()), || RowMajor::new(ref_fields.as_ref()));
    (0..n)
        .into_par_iter()
        .map(|m| {
            let mut best = (f64::INFINITY, None);
            let a = test_rows.row(m);
            posterior.for_each_entry(m, &mut |r, _| {
                let b = ref_rows.row(r);
                let cost: f64 = (0..s).map(|j| weights[j] * (a[j] - b[j]).abs()).sum();
                if cost < best.0 {
                    best = (cost, Some(r));
                }
            });
            best.1
        })
        .collect()
}

/// What the growths of one scan's maps onto one reference share, made by the first growth that
/// needs each part: on a single view [`super::dense_map`] completes two games' maps, and their
/// growths have the same samples, test-side columns, boundary distances, extra candidates,
/// per-sample weights and normalised reference columns, and the same orientation terms when
/// both read the posterior through the same label table. (Before, the second growth remade
/// them: measured on SCAPE's single views, about 1 % of a view's time.)
#[derive(Default)]
pub(super) struct GrowthMemo {
    base: Option<Arc<GrowthBase>>,
    /// The orientation terms and the label table of the posterior they were made for.
    turning: Option<(Option<Vec<usize>>, Turning)>,
    /// Normalised reference distance columns by target vertex ([`grow_rounds`]).
    ref_cols: std::collections::HashMap<usize, Vec<f32>>,
    /// Each sample's anchor weights, once made ([`grow_rounds`]).
    sample_weights: Vec<Vec<f32>>,
}

/// Per test vertex, each candidate's orientation term `(1 − agreement) / 2` in the order of
/// [`for_each_candidate`].
type Turning = Arc<Vec<Vec<f32>>>;

/// Anchor growth (see [`AnchorGrowthParams`]): returns the final map and the number of anchors
/// of the last round. `memo` holds what an earlier growth of the same scan onto the same
/// reference with the same settings made (see [`GrowthMemo`]); a fresh one for a growth alone.
#[allow(clippy::too_many_arguments)]
pub(super) fn grow_anchors(
    test: &PreparedShape,
    reference: &PreparedShape,
    posterior: &LabelledPosterior<'_>,
    start: Vec<usize>,
    p: &AnchorGrowthParams,
    partial: &PartialScanParams,
    prior: Option<&[Vec<f32>]>,
    memo: &mut GrowthMemo,
) -> Result<Grown, Error> {
    let base = match &memo.base {
        Some(base) => Arc::clone(base),
        None => Arc::clone(memo.base.insert(Arc::new(GrowthBase::new(test, reference, p, partial)?))),
    };
    if base.samples.len() < 3 {
        let score = base.orientation.mean_agreement(&start);
        return Ok(Grown { map: start, anchors: 0, orientation: score, reoriented: false });
    }
    // Each candidate's orientation term is the same in every round and run: made once.
    let turning = (p.orientation > 0.0 || p.reorient > 0.0).then(|| match &memo.turning {
        Some((table, terms)) if table.as_deref() == posterior.label_to_vertex => Arc::clone(terms),
        _ => {
            use rayon::prelude::*;
            let terms: Turning = Arc::new(
                (0..test.mesh.n_vertices())
                    .into_par_iter()
                    .map(|m| {
                        let mut terms = Vec::new();
                        for_each_candidate(posterior, prior, &base.extra, m, &mut |r, _| {
                            terms.push((0.5 * (1.0 - base.orientation.agreement(m, r))) as f32);
                        });
                        terms
                    })
                    .collect(),
            );
            memo.turning = Some((posterior.label_to_vertex.map(<[usize]>::to_vec), Arc::clone(&terms)));
            terms
        }
    });
    let setup = GrowthSetup { base, prior, turning };
    // Reference columns are shared by both runs (and kept for the next growth): the second
    // run's rounds mostly revisit the targets of the first, and each costs a heat-method solve.
    // The second hypothesis: a first round placed with a strong orientation term, which puts
    // every vertex on the side its orientation descriptor says (undoing a mirror image of the
    // game's anchors, whole or in part), then the ordinary rounds. The better oriented map wins.
    // Both runs' first rounds place from the same anchors (the start map's): one pass.
    let first = if p.reorient > 0.0 { vec![p.orientation, p.reorient] } else { vec![p.orientation] };
    let mut runs = grow_rounds(
        test,
        reference,
        posterior,
        start,
        p,
        &first,
        &setup,
        &mut memo.ref_cols,
        &mut memo.sample_weights,
    )?
    .into_iter();
    let orientation = &setup.base.orientation;
    let (map, anchors) = runs.next().expect("one run per first orientation");
    let score = orientation.mean_agreement(&map);
    let Some((second, second_anchors)) = runs.next() else {
        return Ok(Grown { map, anchors, orientation: score, reoriented: false });
    };
    let second_score = orientation.mean_agreement(&second);
    if second_score > score {
        Ok(Grown { map: second, anchors: second_anchors, orientation: second_score, reoriented: true })
    } else {
        Ok(Grown { map, anchors, orientation: score, reoriented: false })
    }
}

/// What growth reads of the scan and the reference whatever the posterior: the same for every
/// growth of one scan onto one reference with the same settings.
struct GrowthBase {
    /// Farthest-point samples of the test shape.
    samples: Vec<usize>,
    /// Distances from the samples on the test shape (one column per sample, not normalised).
    a_fields: Vec<Arc<[f32]>>,
    /// Orientation descriptors of the test and reference shapes.
    orientation: Orientation,
    /// Normalised distances to the test shape's boundary, when pairs are weighed by
    /// [`pair_trust`].
    boundary: Option<Vec<f64>>,
    /// Reference vertices tried for every test vertex besides its forest candidates.
    extra: Vec<usize>,
}

impl GrowthBase {
    fn new(
        test: &PreparedShape,
        reference: &PreparedShape,
        p: &AnchorGrowthParams,
        partial: &PartialScanParams,
    ) -> Result<Self, Error> {
        let orientation = Orientation::of(test, reference);
        let samples =
            farthest_point_sampling_euclidean(&test.mesh, p.samples.min(test.mesh.n_vertices()), None)?;
        if samples.len() < 3 {
            return Ok(Self {
                samples,
                a_fields: Vec::new(),
                orientation,
                boundary: None,
                extra: Vec::new(),
            });
        }
        // The sparse step's samples are the first of these (the same farthest-point sequence):
        // their columns are kept by the test shape.
        let a_fields = test.distance_columns(&samples)?;
        let boundary =
            if partial.boundary_trust { boundary_distances(&test.mesh, test.sqrt_area()) } else { None };
        let extra = if partial.free_candidates > 0 {
            let n = partial.free_candidates.min(reference.mesh.n_vertices());
            farthest_point_sampling_euclidean(&reference.mesh, n, None)?
        } else {
            Vec::new()
        };
        Ok(Self { samples, a_fields, orientation, boundary, extra })
    }
}

/// What both growth runs share.
struct GrowthSetup<'a> {
    /// What every growth of the scan onto the reference shares.
    base: Arc<GrowthBase>,
    /// On a single view, each posterior entry's cost in a placement ([`prior_costs`]; ∞: not
    /// tried); `None` elsewhere.
    prior: Option<&'a [Vec<f32>]>,
    /// The orientation terms ([`Turning`]); `None` when no run weighs them.
    turning: Option<Turning>,
}

/// Each candidate reference vertex of test vertex `m` with its prior cost, in the order a
/// placement considers them: the posterior's entries (with `prior`, a single view's, only those
/// of finite cost), then `extra` at no cost.
fn for_each_candidate(
    posterior: &LabelledPosterior<'_>,
    prior: Option<&[Vec<f32>]>,
    extra: &[usize],
    m: usize,
    f: &mut dyn FnMut(usize, f32),
) {
    match prior {
        Some(costs) => {
            let mut entry = costs[m].iter();
            posterior.for_each_entry(m, &mut |r, _| {
                let cost = *entry.next().unwrap_or(&0.0);
                // Beyond the vertex's most probable entries: not a candidate.
                if cost.is_finite() {
                    f(r, cost);
                }
            });
        }
        None => posterior.for_each_entry(m, &mut |r, _| f(r, 0.0)),
    }
    for &r in extra {
        f(r, 0.0);
    }
}

/// The placement cost of every posterior entry, `weight · min(−ln(p / p_max), cap)` per test
/// vertex in the posterior's order (see [`AnchorGrowthParams::part_prior`]); unless
/// `candidates` is 0, the entries beyond a vertex's `candidates` most probable (ties in the
/// posterior's order) cost `f32::INFINITY` and are not tried
/// ([`AnchorGrowthParams::part_candidates`]). It depends on
/// the probabilities alone, not on the reference vertices the labels are read as, so one table
/// serves the growth of both games' maps, both runs and every round.
pub(super) fn prior_costs(prediction: &Prediction, weight: f64, candidates: usize) -> Vec<Vec<f32>> {
    use rayon::prelude::*;
    (0..prediction.n_vertices())
        .into_par_iter()
        .map(|m| {
            let (_, probs) = prediction.posterior(m);
            let top = probs.iter().fold(0f64, |t, &q| t.max(q as f64));
            let mut costs: Vec<f32> = probs
                .iter()
                .map(|&q| {
                    let surprise =
                        (-(q as f64 / top).max(f64::MIN_POSITIVE).ln()).min(AnchorGrowthParams::PRIOR_CAP);
                    (weight * surprise) as f32
                })
                .collect();
            if candidates > 0 && probs.len() > candidates {
                let mut order: Vec<u32> = (0..probs.len() as u32).collect();
                order.select_nth_unstable_by(candidates, |&a, &b| {
                    probs[b as usize].total_cmp(&probs[a as usize]).then(a.cmp(&b))
                });
                for &i in &order[candidates..] {
                    costs[i as usize] = f32::INFINITY;
                }
            }
            costs
        })
        .collect()
}

/// Normalised (÷ √area) reference distance columns from `targets`, as f32 (the ones the
/// reference does not keep: one block solve).
fn reference_columns(
    reference: &PreparedShape,
    targets: &[usize],
) -> Result<std::collections::HashMap<usize, Vec<f32>>, Error> {
    let rs = 1.0 / reference.sqrt_area();
    let f = reference.distance_columns(targets)?;
    Ok(targets
        .iter()
        .zip(f)
        .map(|(&t, col)| (t, col.iter().map(|&d| (f64::from(d) * rs) as f32).collect()))
        .collect())
}

/// The result of anchor growth.
pub(super) struct Grown {
    /// Test vertex → reference vertex.
    pub(super) map: Vec<usize>,
    /// Anchors of the last round.
    pub(super) anchors: usize,
    /// Mean orientation agreement of the map over all test vertices.
    pub(super) orientation: f64,
    /// Whether the map came from the second, strongly oriented run.
    pub(super) reoriented: bool,
}

/// The rounds of anchor growth from `start`, one run per orientation weight of the first round
/// in `first_orientations` (one or two; the later rounds weigh it `p.orientation`): each run's
/// map and its anchors. The runs' first rounds share their anchors (the start map's), and so
/// one pass places them all. `ref_cols` holds the normalised reference distance columns
/// computed so far (by target vertex); the missing ones are added.
#[allow(clippy::too_many_arguments)]
fn grow_rounds(
    test: &PreparedShape,
    reference: &PreparedShape,
    posterior: &LabelledPosterior<'_>,
    start: Vec<usize>,
    p: &AnchorGrowthParams,
    first_orientations: &[f64],
    setup: &GrowthSetup,
    ref_cols: &mut std::collections::HashMap<usize, Vec<f32>>,
    sample_weights: &mut Vec<Vec<f32>>,
) -> Result<Vec<(Vec<usize>, usize)>, Error> {
    use rayon::prelude::*;
    let (n_t, n_r) = (test.mesh.n_vertices(), reference.mesh.n_vertices());
    let GrowthSetup { base, prior, turning } = setup;
    let GrowthBase { samples, a_fields, boundary, extra, .. } = &**base;
    let trust = |d: f64, a: usize, b: usize| boundary.as_ref().map_or(1.0, |db| pair_trust(d, db[a], db[b]));
    let s = samples.len();
    let ts = 1.0 / test.sqrt_area();
    let a_col = |j: usize| &a_fields[j][..];
    let n_keep = ((s as f64 * p.keep).ceil() as usize).clamp(3, s);
    let runs = first_orientations.len();
    assert!((1..=MAX_RUNS).contains(&runs), "one or two growth runs, not {runs}");
    if p.rounds == 0 {
        return Ok(vec![(start, 0); runs]);
    }
    // Row-major tables, rewritten whole every round (allocated once: fresh pages fault):
    // test distances and weights (n_t × k), reference distances (n_r × k).
    let (mut a, mut w, mut b) =
        (vec![0f32; n_t * n_keep], vec![0f32; n_t * n_keep], vec![0f32; n_r * n_keep]);
    // Each sample's anchor weight at every test vertex (locality × trust), once it was kept
    // (empty before).
    sample_weights.resize(s, Vec::new());
    // One round from `map`: a placement per orientation weight in `gammas`.
    let mut round = |map: &[usize], gammas: &[f64], last: bool| -> Result<Vec<Vec<usize>>, Error> {
        let targets: Vec<usize> = samples.iter().map(|&v| map[v]).collect();
        let mut missing: Vec<usize> = targets.iter().copied().filter(|t| !ref_cols.contains_key(t)).collect();
        missing.sort_unstable();
        missing.dedup();
        if !missing.is_empty() {
            ref_cols.extend(reference_columns(reference, &missing)?);
        }
        // Consistency of each pair with the others: median distance disagreement.
        let mut consistency: Vec<(f64, usize)> = (0..s)
            .into_par_iter()
            .map(|i| {
                let ci = &ref_cols[&targets[i]];
                let disagreement =
                    |j: usize| (f64::from(a_col(i)[samples[j]]) * ts - f64::from(ci[targets[j]])).abs();
                // Pairs whose geodesic may run along a hole are left out (all kept when too few
                // remain).
                let mut d: Vec<f64> = (0..s)
                    .filter(|&j| {
                        j != i && trust(f64::from(a_col(i)[samples[j]]) * ts, samples[i], samples[j]) >= 0.5
                    })
                    .map(disagreement)
                    .collect();
                if d.len() < 5 {
                    d = (0..s).filter(|&j| j != i).map(disagreement).collect();
                }
                let mid = d.len() / 2;
                d.select_nth_unstable_by(mid, f64::total_cmp);
                (d[mid], i)
            })
            .collect();
        consistency.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let kept: Vec<usize> = consistency[..n_keep].iter().map(|c| c.1).collect();
        let k = kept.len();
        debug_assert_eq!(k, n_keep);
        // A sample's weights depend on the sample alone: made the first round it is kept.
        let fresh: Vec<usize> = kept.iter().copied().filter(|&i| sample_weights[i].is_empty()).collect();
        let made: Vec<Vec<f32>> = fresh
            .par_iter()
            .map(|&i| {
                let (col, sample) = (a_col(i), samples[i]);
                (0..n_t)
                    .map(|v| {
                        let d = f64::from(col[v]) * ts;
                        let local = if p.locality > 0.0 { (-d / p.locality).exp() } else { 1.0 };
                        (local * trust(d, v, sample)) as f32
                    })
                    .collect()
            })
            .collect();
        for (i, weights) in fresh.into_iter().zip(made) {
            sample_weights[i] = weights;
        }
        // Filled a row (vertex) at a time, in parallel.
        let kept_cols: Vec<(&[f32], &[f32])> =
            kept.iter().map(|&i| (a_col(i), &sample_weights[i][..])).collect();
        a.par_chunks_mut(k).zip(w.par_chunks_mut(k)).enumerate().for_each(|(v, (av, wv))| {
            for (j, &(col, weights)) in kept_cols.iter().enumerate() {
                av[j] = (f64::from(col[v]) * ts) as f32;
                wv[j] = weights[v];
            }
        });
        let ref_kept: Vec<&[f32]> = kept.iter().map(|&i| &ref_cols[&targets[i]][..]).collect();
        b.par_chunks_mut(k).enumerate().for_each(|(r, br)| {
            for (x, col) in br.iter_mut().zip(&ref_kept) {
                *x = col[r];
            }
        });
        let gammas: Vec<f32> = gammas.iter().map(|&g| g as f32).collect();
        let turns = gammas.iter().any(|&g| g > 0.0);
        let (a, w, b) = (&a, &w, &b);
        // Each vertex's candidates with their cost (mean locality-weighted disagreement, in
        // √area units, plus the orientation term at each weight); the cheapest is the new
        // placement. The last round keeps the tables for the smoothing below.
        let placed: Vec<[Placement; MAX_RUNS]> = (0..n_t)
            .into_par_iter()
            .map(|m| {
                let (am, wm) = (&a[m * k..(m + 1) * k], &w[m * k..(m + 1) * k]);
                let norm = 1.0 / wm.iter().sum::<f32>().max(f32::MIN_POSITIVE);
                let mut best = [(f32::INFINITY, map[m]); MAX_RUNS];
                let mut tables: [Vec<(u32, f32)>; MAX_RUNS] = Default::default();
                let mut terms = turning.as_ref().filter(|_| turns).map(|t| t[m].iter());
                let mut consider = |r: usize, prior_cost: f32| {
                    let br = &b[r * k..(r + 1) * k];
                    let distance = weighted_l1(am, wm, br) * norm + prior_cost;
                    let disagreement = terms.as_mut().and_then(|t| t.next()).copied().unwrap_or(0.0);
                    for (g, &gamma) in gammas.iter().enumerate() {
                        let mut cost = distance;
                        if gamma > 0.0 {
                            cost += gamma * disagreement;
                        }
                        if cost < best[g].0 {
                            best[g] = (cost, r);
                        }
                        if last {
                            tables[g].push((r as u32, cost));
                        }
                    }
                };
                // Each candidate's reference row is a cache miss of its own: fetched while the
                // candidate before it is costed (the same candidates in the same order).
                let mut pending: Option<(usize, f32)> = None;
                for_each_candidate(posterior, *prior, extra, m, &mut |r, prior_cost| {
                    prefetch(&b[r * k..(r + 1) * k]);
                    if let Some((r, prior_cost)) = pending.replace((r, prior_cost)) {
                        consider(r, prior_cost);
                    }
                });
                if let Some((r, prior_cost)) = pending {
                    consider(r, prior_cost);
                }
                let [t0, t1] = tables;
                [(best[0].1, t0), (best[1].1, t1)]
            })
            .collect();
        let mut maps = Vec::with_capacity(gammas.len());
        for g in 0..gammas.len() {
            let mut map: Vec<usize> = placed.iter().map(|p| p[g].0).collect();
            if last && p.smoothness > 0.0 && p.smoothing_rounds > 0 {
                let table: Vec<&[(u32, f32)]> = placed.iter().map(|p| &p[g].1[..]).collect();
                map = smooth_placement(&test.mesh, &reference.mesh, reference.sqrt_area(), &table, map, p);
            }
            maps.push(map);
        }
        Ok(maps)
    };
    let firsts = round(&start, first_orientations, p.rounds == 1)?;
    let mut out = Vec::with_capacity(runs);
    for mut map in firsts {
        for r in 1..p.rounds {
            map = round(&map, &[p.orientation], r + 1 == p.rounds)?.swap_remove(0);
        }
        out.push((map, n_keep));
    }
    Ok(out)
}

/// Asks the CPU to bring `values` into its cache ahead of their use (a hint: nothing else
/// changes).
#[inline(always)]
fn prefetch(values: &[f32]) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        // One address per 64-byte line the values span, and their last.
        for i in (0..values.len()).step_by(16).chain(values.len().checked_sub(1)) {
            // SAFETY: a prefetch reads nothing and faults on no address; this one is in bounds.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(values.as_ptr().add(i).cast::<i8>()) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = values;
}

/// Growth runs at most: the ordinary one and the re-orienting one.
const MAX_RUNS: usize = 2;

/// A vertex's placement in one run's round, and (in the last round) every candidate's cost.
type Placement = (usize, Vec<(u32, f32)>);

/// `Σ w·|x − y|` over equal-length slices, summed in 16 lanes (vectorised; the lanes are added
/// up in a fixed order, so the result does not depend on the thread), compiled for the widest
/// vector unit the CPU has: the same operations in the same order on every path, so the same
/// bits.
fn weighted_l1(x: &[f32], w: &[f32], y: &[f32]) -> f32 {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F, checked just above.
            return unsafe { weighted_l1_avx512(x, w, y) };
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, checked just above.
            return unsafe { weighted_l1_avx2(x, w, y) };
        }
    }
    weighted_l1_impl(x, w, y)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn weighted_l1_avx512(x: &[f32], w: &[f32], y: &[f32]) -> f32 {
    weighted_l1_impl(x, w, y)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn weighted_l1_avx2(x: &[f32], w: &[f32], y: &[f32]) -> f32 {
    weighted_l1_impl(x, w, y)
}

#[inline(always)]
fn weighted_l1_impl(x: &[f32], w: &[f32], y: &[f32]) -> f32 {
    const LANES: usize = 16;
    let mut acc = [0f32; LANES];
    let (xc, yc, wc) = (x.chunks_exact(LANES), y.chunks_exact(LANES), w.chunks_exact(LANES));
    let tail: f32 = xc
        .remainder()
        .iter()
        .zip(wc.remainder())
        .zip(yc.remainder())
        .map(|((x, w), y)| w * (x - y).abs())
        .sum();
    for ((xs, ws), ys) in xc.zip(wc).zip(yc) {
        for l in 0..LANES {
            acc[l] += ws[l] * (xs[l] - ys[l]).abs();
        }
    }
    acc.iter().sum::<f32>() + tail
}

#[cfg(test)]
mod tests {
    use faer::Mat;
    use rand::{Rng, SeedableRng};

    use super::{anchor_consistent_map, prior_costs, weighted_l1, weighted_l1_impl, LabelledPosterior};
    use crate::forest::Prediction;

    #[test]
    fn each_vertex_is_placed_on_its_candidate_nearest_in_weighted_anchor_distances() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let (n_t, n_r, s, per_vertex) = (60, 45, 7, 6);
        let mut uniform = |n: usize| Mat::from_fn(n, s, |_, _| rng.random_range(0.0..1.0));
        let (a, b) = (uniform(n_t), uniform(n_r));
        let weights: Vec<f64> = (0..s).map(|j| 1.0 / (1.0 + j as f64)).collect();
        // Each test vertex's candidates: labels (read as the reference vertices) spread over
        // the reference.
        let labels: Vec<u32> = (0..n_t)
            .flat_map(|m| {
                let mut row: Vec<u32> = (0..per_vertex).map(|j| ((m * 11 + j * 7) % n_r) as u32).collect();
                row.sort_unstable();
                row
            })
            .collect();
        let offsets: Vec<usize> = (0..=n_t).map(|m| m * per_vertex).collect();
        let probs = vec![1.0 / per_vertex as f32; labels.len()];
        let prediction = Prediction::from_parts(n_r, offsets, labels.clone(), probs).unwrap();
        let posterior = LabelledPosterior { prediction: &prediction, label_to_vertex: None };
        let placed = anchor_consistent_map(&a, &b, &weights, &posterior);
        for (m, &got) in placed.iter().enumerate() {
            let cost = |r: usize| (0..s).map(|j| weights[j] * (a[(m, j)] - b[(r, j)]).abs()).sum::<f64>();
            let candidates = labels[m * per_vertex..(m + 1) * per_vertex].iter().map(|&l| l as usize);
            // The first of the cheapest, in the posterior's order.
            let best = candidates.fold((f64::INFINITY, None), |best, r| {
                if cost(r) < best.0 {
                    (cost(r), Some(r))
                } else {
                    best
                }
            });
            assert_eq!(got, best.1, "test vertex {m}");
        }
    }

    #[test]
    fn a_views_placements_try_only_each_vertexs_most_probable_entries() {
        // Vertex 0: five entries; vertex 1: two (fewer than the cap, all tried).
        let p = Prediction::from_parts(
            6,
            vec![0, 5, 7],
            vec![0, 1, 2, 3, 4, 1, 5],
            vec![0.1, 0.4, 0.2, 0.05, 0.25, 0.5, 0.5],
        )
        .unwrap();
        let capped = prior_costs(&p, 0.02, 3);
        // The three most probable (0.4, 0.25, 0.2) are tried; the most probable costs nothing.
        let tried: Vec<bool> = capped[0].iter().map(|c| c.is_finite()).collect();
        assert_eq!(tried, vec![false, true, true, false, true]);
        assert_eq!(capped[0][1], 0.0);
        assert!((capped[0][2] - (0.02 * 2f64.ln()) as f32).abs() < 1e-7, "{:?}", capped[0]);
        assert_eq!(capped[1], vec![0.0, 0.0]);
        // No cap: every entry is tried, with the same costs.
        let all = prior_costs(&p, 0.02, 0);
        assert!(all.iter().flatten().all(|c| c.is_finite()));
        assert_eq!(all[0][1..3], capped[0][1..3]);
    }

    #[test]
    fn lane_sums_equal_the_plain_sum() {
        // Lengths below, at and past the lane count, with a remainder.
        for len in [0, 5, 16, 140, 141] {
            let x: Vec<f32> = (0..len).map(|i| (i as f32 * 0.37).sin()).collect();
            let y: Vec<f32> = (0..len).map(|i| (i as f32 * 0.11).cos()).collect();
            let w: Vec<f32> = (0..len).map(|i| 1.0 / (1.0 + i as f32)).collect();
            let plain: f64 = (0..len).map(|i| w[i] as f64 * (x[i] as f64 - y[i] as f64).abs()).sum();
            let lanes = weighted_l1(&x, &w, &y) as f64;
            assert!((lanes - plain).abs() <= 1e-5 * plain.max(1.0), "len {len}: {lanes} vs {plain}");
            // The path compiled for this CPU's vector unit gives the bits of the portable one.
            assert_eq!(
                weighted_l1(&x, &w, &y).to_bits(),
                weighted_l1_impl(&x, &w, &y).to_bits(),
                "len {len}"
            );
        }
    }
}
