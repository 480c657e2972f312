//! Regularisation onto the training shape in the nearest pose (a *relay*), carried back to the
//! reference through the labels.
//!
//! The regulariser's geodesic game, its anchor growth and the ZoomOut refinement all assume
//! that the test shape is an isometry of the shape they map onto. Bodies are not quite
//! isometric across poses: a leaping cat stretches at the hips and shoulders, and a map onto a
//! sitting reference slides there by 0.05–0.1 √area. (Started from the ground truth itself,
//! ZoomOut onto the other cats of tosca-r5k keeps between 90.6 and 97.1 % of cat3's points
//! within 0.05, depending on the target's pose.)
//!
//! Every training shape carries the labels, so the correspondence between any of them and the
//! reference is known. [`nearest_pose`] picks, among the training shapes (the reference
//! included), the one whose pose is nearest the test shape's, compared extrinsically under the
//! forest's most probable labels: the mean difference of the Euclidean distances among
//! farthest-point samples of the test shape and among their labels' vertices on the candidate,
//! each shape in units of its `√area`. (A label confused with its mirror image barely moves
//! these distances, so the raw forest suffices.) The caller regularises onto that shape and
//! carries the map back with [`through_labels`] and [`DenseMap::carried`].

use rayon::prelude::*;

use super::{
    finish_refinement, refines_partially, DenseMap, PreparedShape, RegularizerError as Error,
    RegularizerParams,
};
use crate::forest::Prediction;
use crate::geodesic::farthest_point_sampling_euclidean;
use crate::mesh::{norm, sub, Mesh};

/// Farthest-point samples of the test shape whose distances compare the poses.
pub const POSE_SAMPLES: usize = 200;

/// Labelled vertices averaged over to place an unlabelled one ([`through_labels`]).
const INTERPOLATION_NEIGHBOURS: usize = 4;
/// Of those, only the ones at most this many times as far as the nearest.
const NEIGHBOUR_REACH: f64 = 2.0;

/// Checks that `table` (label → vertex) has one entry per label, each a vertex of `mesh`.
fn check_table(mesh: &Mesh, table: &[usize], n_labels: usize, what: &str) -> Result<(), Error> {
    if table.len() != n_labels {
        return Err(Error::SizeMismatch(format!(
            "{what}: label table of {} entries for {n_labels} labels",
            table.len()
        )));
    }
    if table.iter().any(|&v| v >= mesh.n_vertices()) {
        return Err(Error::InvalidInput(format!(
            "{what}: label table names a vertex beyond the mesh's {}",
            mesh.n_vertices()
        )));
    }
    Ok(())
}

/// Mean difference of the Euclidean distances among `samples` of `test` and among their images
/// on `target` (`None`: no image; pairs with one are left out), each in units of its shape's
/// `√area`; `None` when no pair has both images.
fn pose_discrepancy(test: &Mesh, target: &Mesh, samples: &[usize], images: &[Option<usize>]) -> Option<f64> {
    let (st, sr) = (1.0 / test.surface_area().sqrt(), 1.0 / target.surface_area().sqrt());
    let (mut sum, mut count) = (0.0, 0usize);
    for i in 0..samples.len() {
        let Some(a) = images[i] else { continue };
        for j in i + 1..samples.len() {
            let Some(b) = images[j] else { continue };
            let dt = norm(sub(test.vertices[samples[i]], test.vertices[samples[j]]));
            let dr = norm(sub(target.vertices[a], target.vertices[b]));
            sum += (dt * st - dr * sr).abs();
            count += 1;
        }
    }
    (count > 0).then(|| sum / count as f64)
}

/// Among `candidates` (each a mesh and its label → vertex table), the index of the one whose
/// pose is nearest the test shape's under the forest's most probable labels (see the module
/// documentation); the first on ties or when the forest predicted too few labels to compare.
pub fn nearest_pose(
    test: &Mesh,
    prediction: &Prediction,
    candidates: &[(&Mesh, &[usize])],
) -> Result<usize, Error> {
    Ok(poses_by_nearness(test, prediction, candidates)?[0])
}

/// The indices of `candidates` (at least one), nearest pose first (see [`nearest_pose`]);
/// candidates that cannot be compared come last, in their order.
pub fn poses_by_nearness(
    test: &Mesh,
    prediction: &Prediction,
    candidates: &[(&Mesh, &[usize])],
) -> Result<Vec<usize>, Error> {
    if prediction.n_vertices() != test.n_vertices() {
        return Err(Error::SizeMismatch(format!(
            "prediction for {} vertices, test shape has {}",
            prediction.n_vertices(),
            test.n_vertices()
        )));
    }
    if candidates.is_empty() {
        return Err(Error::InvalidInput("pose candidates: none given".into()));
    }
    for (i, (mesh, table)) in candidates.iter().enumerate() {
        check_table(mesh, table, prediction.n_labels(), &format!("pose candidate {i}"))?;
    }
    if candidates.len() < 2 {
        return Ok(vec![0]);
    }
    let samples = farthest_point_sampling_euclidean(test, POSE_SAMPLES.min(test.n_vertices()), None)?;
    let labels = prediction.map_labels();
    let mut scored: Vec<(f64, usize)> = candidates
        .iter()
        .enumerate()
        .map(|(c, (mesh, table))| {
            let images: Vec<Option<usize>> =
                samples.iter().map(|&s| labels[s].map(|l| table[l as usize])).collect();
            (pose_discrepancy(test, mesh, &samples, &images).unwrap_or(f64::INFINITY), c)
        })
        .collect();
    // A stable sort: ties keep the candidates' order.
    scored.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(scored.into_iter().map(|(_, c)| c).collect())
}

/// `a`'s vertex → `b`'s vertex through the labels (`a_table`, `b_table`: label → vertex).
/// Each vertex of `a` is placed on `b` at the mean position of its labels' vertices there (of
/// the `INTERPOLATION_NEIGHBOURS` labelled vertices nearest in space, those at most
/// `NEIGHBOUR_REACH` times as far as the nearest, weighted by inverse distance, when it carries
/// no label) and takes the vertex of `b` nearest that point. (The
/// nearest labelled vertex alone would move the image of every unlabelled vertex by about an
/// edge: in the remeshed sets a third of the vertices carry no label.)
pub fn through_labels(a: &Mesh, a_table: &[usize], b: &Mesh, b_table: &[usize]) -> Result<Vec<usize>, Error> {
    use kiddo::immutable::float::kdtree::ImmutableKdTree;
    use kiddo::SquaredEuclidean;
    use std::num::NonZero;
    check_table(a, a_table, b_table.len(), "relay")?;
    check_table(b, b_table, a_table.len(), "reference")?;
    // Per vertex of `a`: the sum of its labels' positions on `b` and their count.
    let mut sums = vec![([0.0; 3], 0usize); a.n_vertices()];
    for (&va, &vb) in a_table.iter().zip(b_table) {
        let (sum, count) = &mut sums[va];
        for (s, x) in sum.iter_mut().zip(b.vertices[vb]) {
            *s += x;
        }
        *count += 1;
    }
    let labelled: Vec<usize> = (0..a.n_vertices()).filter(|&v| sums[v].1 > 0).collect();
    let Some(want) = NonZero::new(INTERPOLATION_NEIGHBOURS.min(labelled.len())) else {
        return Err(Error::InvalidInput("relay: no label".into()));
    };
    let position = |v: usize| sums[v].0.map(|x| x / sums[v].1 as f64);
    let points: Vec<[f64; 3]> = labelled.iter().map(|&v| a.vertices[v]).collect();
    let near_labelled: ImmutableKdTree<f64, u32, 3, 32> = ImmutableKdTree::new_from_slice(&points);
    let on_b: ImmutableKdTree<f64, u32, 3, 32> = ImmutableKdTree::new_from_slice(&b.vertices);
    Ok((0..a.n_vertices())
        .into_par_iter()
        .map(|v| {
            let target = if sums[v].1 > 0 {
                position(v)
            } else {
                let (mut acc, mut total) = ([0.0; 3], 0.0);
                let hits = near_labelled.nearest_n::<SquaredEuclidean>(&a.vertices[v], want);
                // Only neighbours about as near as the nearest: no average across a thin gap.
                let reach = NEIGHBOUR_REACH * hits[0].distance.sqrt();
                for hit in hits.iter().filter(|h| h.distance.sqrt() <= reach) {
                    let w = 1.0 / (hit.distance.sqrt() + 1e-12);
                    let p = position(labelled[hit.item as usize]);
                    for d in 0..3 {
                        acc[d] += w * p[d];
                    }
                    total += w;
                }
                acc.map(|x| x / total)
            };
            on_b.nearest_one::<SquaredEuclidean>(&target).item as usize
        })
        .collect())
}

impl DenseMap {
    /// This map onto a relay, carried to the reference by `to_reference` (relay vertex →
    /// reference vertex, e.g. from [`through_labels`]): every reference vertex it names (the
    /// maps and the matches) is replaced. The functional maps stay in the relay's basis.
    pub fn carried(mut self, to_reference: &[usize]) -> Result<Self, Error> {
        let carry = |v: &mut usize| -> Result<(), Error> {
            *v = *to_reference.get(*v).ok_or_else(|| {
                Error::SizeMismatch(format!("relay vertex {v} beyond the table of {}", to_reference.len()))
            })?;
            Ok(())
        };
        let carry_all = |m: &mut [usize]| m.iter_mut().try_for_each(carry);
        carry_all(&mut self.map)?;
        carry_all(&mut self.anchor_map)?;
        for m in [&mut self.grown_map, &mut self.spectral_map, &mut self.fmap_map].into_iter().flatten() {
            carry_all(m)?;
        }
        self.forest_map.iter_mut().flatten().try_for_each(carry)?;
        self.matches.iter_mut().try_for_each(|m| carry(&mut m.reference))?;
        Ok(self)
    }

    /// This map's final and unrefined maps replaced by the vote ([`vote_maps`] on `reference`)
    /// of its own and `others`' (maps of the same scan onto the same reference, e.g. regularised
    /// onto other relays and carried back); ties go to this map. The other fields stay this
    /// map's.
    pub fn voted(mut self, others: &[DenseMap], reference: &Mesh) -> Result<Self, Error> {
        if others.is_empty() {
            return Ok(self);
        }
        let finals: Vec<&[usize]> =
            std::iter::once(&self.map).chain(others.iter().map(|o| &o.map)).map(Vec::as_slice).collect();
        let map = vote_maps(reference, &finals)?;
        let unrefined: Vec<&[usize]> =
            std::iter::once(self.unrefined_map()).chain(others.iter().map(DenseMap::unrefined_map)).collect();
        let grown = vote_maps(reference, &unrefined)?;
        if self.grown_map.is_some() || map != grown {
            self.grown_map = Some(grown);
        }
        self.map = map;
        Ok(self)
    }

    /// This map's final map settled onto `reference` ([`super::settle_map`] with `params`' ZoomOut
    /// settings, then [`super::local_rigid`]), for a map that did not end with a refinement onto
    /// it: one carried from a relay ([`DenseMap::carried`]; the carry through the labels moves
    /// images by about an edge) or voted ([`DenseMap::voted`]; the vote switches between maps).
    /// Each step is skipped when off (the settling also when the extrinsic step is); the map is
    /// unchanged without ZoomOut or when the test shape is an open part refined by the partial
    /// ZoomOut.
    pub fn settled(
        mut self,
        test: &PreparedShape,
        reference: &PreparedShape,
        params: &RegularizerParams,
    ) -> Result<Self, Error> {
        let Some(z) = &params.zoomout else { return Ok(self) };
        if !refines_partially(test, reference, params) {
            let map = std::mem::take(&mut self.map);
            self.map = crate::pool::on_pool(|| finish_refinement(test, reference, map, z))?;
        }
        Ok(self)
    }
}

/// The per-vertex vote of several maps of one scan onto `reference` (test vertex → reference
/// vertex, all of one length): each vertex takes the image whose summed Euclidean distance to
/// the other maps' images is least (the medoid; with three maps, the image two of them agree
/// on), the earliest map's on ties. Where maps regularised onto different relays go wrong in
/// different places (a mirrored limb onto one, a slide onto another), the vote keeps the
/// images the majority agrees on.
///
/// ```
/// use shapeforest::{mesh::Mesh, regularizer::vote_maps};
/// let line = Mesh::new(
///     vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [9.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
///     vec![[0, 1, 4], [1, 2, 4], [2, 3, 4]],
/// )
/// .unwrap();
/// // Vertex 0: two maps agree on 1. Vertex 1: images at x = 0, 2 and 9: the medoid, 2.
/// let voted = vote_maps(&line, &[&[3, 0], &[1, 2], &[1, 3]]).unwrap();
/// assert_eq!(voted, vec![1, 2]);
/// ```
pub fn vote_maps(reference: &Mesh, maps: &[&[usize]]) -> Result<Vec<usize>, Error> {
    let Some(first) = maps.first() else {
        return Err(Error::InvalidInput("vote: no map".into()));
    };
    let n = first.len();
    let nr = reference.n_vertices();
    for (i, m) in maps.iter().enumerate() {
        if m.len() != n {
            return Err(Error::SizeMismatch(format!("vote: map {i} has {} entries, map 0 has {n}", m.len())));
        }
        if let Some(&r) = m.iter().find(|&&r| r >= nr) {
            return Err(Error::SizeMismatch(format!(
                "vote: map {i} names vertex {r}, the reference has {nr}"
            )));
        }
    }
    let pos = &reference.vertices;
    Ok((0..n)
        .into_par_iter()
        .map(|v| {
            let cost = |i: usize| maps.iter().map(|m| norm(sub(pos[maps[i][v]], pos[m[v]]))).sum::<f64>();
            let mut best = (0, cost(0));
            for i in 1..maps.len() {
                let c = cost(i);
                if c < best.1 {
                    best = (i, c);
                }
            }
            maps[best.0][v]
        })
        .collect())
}
