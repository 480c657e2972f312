//! The ZoomOut refinement (step 8) for a partial scan: rectangular functional maps whose test
//! basis grows with the part's spectrum ([`crate::fmap::zoomout_partial_on_samples`]), used
//! instead of [`super::refine_zoomout`] when the test shape is an open part of less than
//! [`PARTIAL_AREA_RATIO`] of the reference's area.

use serde::{Deserialize, Serialize};

use super::{PreparedShape, RegularizerError as Error, ZoomOutParams};
use crate::{
    fmap::{point_to_point_partial, zoomout_partial_on_samples, ZoomOutSchedule},
    geodesic::dijkstra_distances,
    mesh::{boundary_loops, Mesh},
};

/// Anchor growth on a scan with holes or a partial scan (see
/// [`super::RegularizerParams::partial_scan`]). Both are off by default.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PartialScanParams {
    /// Weigh every (vertex, anchor) distance of anchor growth by how much it can be trusted on
    /// an open test shape ([`pair_trust`]): a geodesic that may pass along a hole is longer on
    /// the scan than on the whole body, so such pairs count less in the placement of a vertex
    /// and are left out of the anchors' consistency scores.
    pub boundary_trust: bool,
    /// Reference farthest-point samples added to every vertex's forest candidates in anchor
    /// growth (0: the forest's candidates only), so that a vertex whose candidates are all
    /// wrong can still be placed by its distances to the anchors.
    pub free_candidates: usize,
}

/// Distances along edges from every vertex of `mesh` to its boundary, divided by `scale`;
/// `None` for a closed mesh. A vertex of a component without boundary gets `∞`.
///
/// ```
/// use shapeforest::{regularizer::boundary_distances, synth::{grid_plane, icosphere}};
/// assert!(boundary_distances(&icosphere(1, 1.0), 1.0).is_none());
/// let d = boundary_distances(&grid_plane(4, 4, 1.0, 1.0), 1.0).unwrap();
/// assert_eq!(d.iter().cloned().fold(f64::INFINITY, f64::min), 0.0);
/// assert!(d.iter().cloned().fold(0.0, f64::max) > 0.3); // inner vertices are a third of a side away or more
/// ```
pub fn boundary_distances(mesh: &Mesh, scale: f64) -> Option<Vec<f64>> {
    let mut sources: Vec<usize> = boundary_loops(mesh).into_iter().flatten().collect();
    if sources.is_empty() {
        return None;
    }
    sources.sort_unstable();
    sources.dedup();
    let d = dijkstra_distances(mesh, &sources).ok()?;
    let inv = 1.0 / scale.max(f64::MIN_POSITIVE);
    Some(d.into_iter().map(|x| x * inv).collect())
}

/// How far the geodesic distance `d` between two vertices of an open scan can be trusted,
/// given their distances `da`, `db` to the boundary (all in the same units), in (0, 1].
///
/// A path through a boundary point is at least `da + db` long, so when `d ≤ da + db` the
/// geodesic does not come near a hole and is (up to one hole's reach) the whole body's: trust 1.
/// Beyond that it may run around a hole, longer than on the body: trust `((da + db) / d)²`.
///
/// ```
/// use shapeforest::regularizer::pair_trust;
/// assert_eq!(pair_trust(0.3, 0.2, 0.2), 1.0);
/// assert!((pair_trust(0.4, 0.1, 0.1) - 0.25).abs() < 1e-12);
/// assert_eq!(pair_trust(0.0, 0.0, 0.0), 1.0);
/// ```
pub fn pair_trust(d: f64, da: f64, db: f64) -> f64 {
    let reach = da + db;
    if d <= reach || !d.is_finite() {
        1.0
    } else {
        let r = reach / d;
        (r * r).max(1e-6)
    }
}

/// A test shape with boundary and less than this fraction of the reference's area is refined as
/// a part ([`refine_zoomout_partial`]); above it (a scan with small holes) the square ZoomOut is
/// used, as for a complete scan.
pub const PARTIAL_AREA_RATIO: f64 = 0.9;

/// A part of less than this fraction of the reference's area (a single-view scan keeps 20–45 %
/// of a body) is not refined at all: its map stays the grown one. On single views of SCAPE the
/// partial ZoomOut lost 2.2 points within 0.05 strict and 5.2 with flips allowed on average over
/// eight trainings with single-view copies (it gained strict points in two of them; 2026-12-05,
/// README "Scans with holes and single views"), where a part of 80 % gains 38.
pub const MIN_REFINED_AREA_RATIO: f64 = 0.5;

/// Whether `test` is an open part of less than [`MIN_REFINED_AREA_RATIO`] of the reference's
/// area (a single view): the whole body's spectral cues fail there, so it is not refined and
/// the game's orientation is read extrinsically.
pub(super) fn is_small_part(test: &PreparedShape, reference: &PreparedShape) -> bool {
    is_small_part_mesh(&test.mesh, &reference.mesh)
}

/// [`is_small_part`] of the meshes.
fn is_small_part_mesh(test: &Mesh, reference: &Mesh) -> bool {
    part_area_ratio(test, reference).is_some_and(|r| r < MIN_REFINED_AREA_RATIO)
}

/// On a single view (an open part of less than [`MIN_REFINED_AREA_RATIO`] of `onto`'s area), the
/// orientation score of `map` (test
/// vertex → `onto` vertex; [`super::map_orientation`]): near 1 where the images of the view's
/// triangles face the way `onto`'s surface does, lower where the map folds or mirrors parts of
/// the view. On a view it tells a good map from a poor one (over SCAPE's 68 single views its
/// correlation with the share of points within 0.05 is 0.75), so a view whose map reads below a
/// threshold is regularised onto other poses too and the best oriented map kept (README
/// "Doubted views"). `None` on other scans.
pub fn view_orientation(test: &Mesh, onto: &Mesh, map: &[usize]) -> Option<f64> {
    is_small_part_mesh(test, onto).then(|| super::map_orientation(test, onto, map).score)
}

/// The area of `test` over the reference's when `test` is an open part of it (it has boundary
/// and less than [`PARTIAL_AREA_RATIO`] of the area; the scan is taken to be at the reference's
/// scale, as [`super::normalising_area`] does), `None` otherwise.
pub fn partial_area_ratio(test: &PreparedShape, reference: &PreparedShape) -> Option<f64> {
    part_area_ratio(&test.mesh, &reference.mesh)
}

/// [`partial_area_ratio`] of the meshes.
fn part_area_ratio(test: &Mesh, reference: &Mesh) -> Option<f64> {
    let ratio = test.surface_area() / reference.surface_area();
    (ratio.is_finite() && ratio > 0.0 && ratio < PARTIAL_AREA_RATIO && test.summary().n_boundary_loops > 0)
        .then_some(ratio)
}

/// ZoomOut of `map` (test vertex → reference vertex) for a partial test shape, by `params`
/// (the schedule counts reference eigenfunctions; `radius` is not used: the point map is
/// searched over the whole reference), read back on every test vertex; `None` when the check of
/// `params.check_samples` found it farther from an isometry than `map`.
pub fn refine_zoomout_partial(
    test: &PreparedShape,
    reference: &PreparedShape,
    map: &[usize],
    params: &ZoomOutParams,
) -> Result<Option<Vec<usize>>, Error> {
    // The shapes' ZoomOut bases (more eigenpairs than the descriptors' when they carry them).
    let (test_basis, reference_basis) = (test.zoomout_basis(), reference.zoomout_basis());
    let (k_start, k_final) = params.partial;
    let k_final = k_final.min(reference_basis.k());
    let schedule = ZoomOutSchedule { k_start: k_start.min(k_final), k_final, step: params.step };
    let test_cells = test.sample_cells(params.samples)?;
    let reference_cells = reference.sample_cells(params.samples)?;
    let c = zoomout_partial_on_samples(
        test_basis,
        &test_cells,
        reference_basis,
        &reference_cells,
        map,
        schedule,
    )?;
    let refined = point_to_point_partial(test_basis, reference_basis, &reference_cells, c.as_ref())?;
    super::refine::kept_if_closer_to_isometry(test, reference, map, refined, params.check_samples)
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use rand::{Rng, SeedableRng};

    use super::*;
    use crate::{
        fmap::partial_basis_size,
        geodesic::HeatParams,
        mesh::{perturb, Perturbation},
        regularizer::{normalising_area, refine_zoomout},
        spectral::dense_spectrum,
        synth::icosphere,
    };

    /// An ellipsoid (distinct axes, so that its low eigenfunctions are not degenerate), and a
    /// cropped part of it (about half) with the ellipsoid vertex of each part vertex.
    fn ellipsoid_and_part() -> (PreparedShape, PreparedShape, Vec<usize>) {
        let mut mesh = icosphere(3, 1.0);
        for v in &mut mesh.vertices {
            v[1] *= 1.3;
            v[2] *= 1.7;
        }
        let p = perturb(&mesh, &[Perturbation::Crop { radius: 0.3 }], 11).unwrap();
        let area = mesh.surface_area();
        let whole = Arc::new(dense_spectrum(&mesh, 40).unwrap());
        let part_spectrum =
            dense_spectrum(&p.mesh, 40).unwrap().renormalised(normalising_area(&p.mesh, area));
        let reference = PreparedShape::new(Arc::new(mesh), whole, HeatParams::default()).unwrap();
        let part =
            PreparedShape::new(Arc::new(p.mesh), Arc::new(part_spectrum), HeatParams::default()).unwrap();
        (part, reference, p.kept)
    }

    #[test]
    fn a_part_is_refined_with_a_slanted_map_and_beats_the_square_one() {
        let (part, reference, truth) = ellipsoid_and_part();
        let ratio = partial_area_ratio(&part, &reference).expect("an open part of the ellipsoid");
        assert!(ratio > 0.2 && ratio < 0.8, "{ratio}");
        // The part's basis grows about as the area ratio times the reference's.
        let km = partial_basis_size(&part.spectrum, &reference.spectrum, 40);
        assert!((km as f64) < 0.9 * 40.0 && (km as f64) > 0.3 * ratio * 40.0, "{km} for ratio {ratio}");
        // Start from every part vertex sent to a random neighbour of its true image.
        let n_ref = reference.mesh.n_vertices();
        let mut neighbours = vec![Vec::new(); n_ref];
        for f in &reference.mesh.faces {
            for (a, b) in [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])] {
                neighbours[a].push(b);
                neighbours[b].push(a);
            }
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let noisy: Vec<usize> = truth
            .iter()
            .map(|&t| {
                let t = neighbours[t][rng.random_range(0..neighbours[t].len())];
                neighbours[t][rng.random_range(0..neighbours[t].len())]
            })
            .collect();
        let params = ZoomOutParams { partial: (10, 40), step: 3, samples: 100_000, ..Default::default() };
        let score = |map: &[usize]| {
            map.iter().zip(&truth).filter(|(a, b)| a == b).count() as f64 / truth.len() as f64
        };
        let before = score(&noisy);
        let partial = refine_zoomout_partial(&part, &reference, &noisy, &params).unwrap().unwrap();
        let square = refine_zoomout(&part, &reference, &noisy, &params).unwrap().unwrap();
        let (p, s) = (score(&partial), score(&square));
        eprintln!("exact: start {before:.3}, partial {p:.3}, square {s:.3}");
        assert!(p > 0.5, "partial ZoomOut maps {p:.3} of the part exactly");
        assert!(p > s + 0.05, "partial {p:.3} against square {s:.3}");
    }

    #[test]
    fn a_complete_shape_is_not_a_part() {
        let (_, reference, _) = ellipsoid_and_part();
        assert_eq!(partial_area_ratio(&reference, &reference), None);
    }

    #[test]
    fn a_views_orientation_tells_its_true_map_from_folded_and_mirrored_ones() {
        let mut mesh = icosphere(3, 1.0);
        for v in &mut mesh.vertices {
            v[1] *= 1.3;
            v[2] *= 1.7;
        }
        let p = perturb(&mesh, &[Perturbation::Crop { radius: 0.2 }], 5).unwrap();
        let spectrum = |m: &Mesh| Arc::new(dense_spectrum(m, 20).unwrap());
        let whole =
            PreparedShape::new(Arc::new(mesh.clone()), spectrum(&mesh), HeatParams::default()).unwrap();
        let view =
            PreparedShape::new(Arc::new(p.mesh.clone()), spectrum(&p.mesh), HeatParams::default()).unwrap();
        let ratio = partial_area_ratio(&view, &whole).expect("an open part");
        assert!(ratio < MIN_REFINED_AREA_RATIO, "{ratio}");
        // Not a view: a closed shape is not read.
        let identity: Vec<usize> = (0..mesh.n_vertices()).collect();
        assert_eq!(view_orientation(&whole.mesh, &whole.mesh, &identity), None);
        let truth = p.kept.clone();
        assert!(view_orientation(&view.mesh, &whole.mesh, &truth).unwrap() > 0.99);
        // The mirror image (x → −x, the ellipsoid's own symmetry) reads reversed.
        let nearest = |q: [f64; 3]| {
            let d = |v: usize| (0..3).map(|i| (mesh.vertices[v][i] - q[i]).powi(2)).sum::<f64>();
            (0..mesh.n_vertices()).min_by(|&a, &b| d(a).total_cmp(&d(b))).unwrap()
        };
        let mirrored: Vec<usize> = truth
            .iter()
            .map(|&t| {
                let v = mesh.vertices[t];
                nearest([-v[0], v[1], v[2]])
            })
            .collect();
        assert!(view_orientation(&view.mesh, &whole.mesh, &mirrored).unwrap() < -0.9);
        // A map that sends half the view through the mirror reads in between, below the truth.
        let mut ys: Vec<f64> = truth.iter().map(|&t| mesh.vertices[t][1]).collect();
        ys.sort_by(f64::total_cmp);
        let mid = ys[ys.len() / 2];
        let half: Vec<usize> = truth
            .iter()
            .zip(&mirrored)
            .map(|(&t, &m)| if mesh.vertices[t][1] > mid { m } else { t })
            .collect();
        let h = view_orientation(&view.mesh, &whole.mesh, &half).unwrap();
        assert!(h < 0.9 && h > -0.9, "{h}");
    }
}
