//! The ZoomOut refinement of the regulariser's map (step 8): spectral upsampling from the
//! anchor-grown map, on farthest-point samples of both shapes for large meshes (see
//! [`crate::fmap::zoomout_on_samples`]).

use std::{cmp::Reverse, collections::BinaryHeap};

use super::{MapSelection, PreparedShape, RegularizerError as Error, ZoomOutParams};
use crate::{
    fmap::{point_to_point_in_cells, zoomout_on_samples, CellBalls, SampleCells, ZoomOutSchedule},
    geodesic::{dijkstra_nearest_source, farthest_point_sampling_euclidean},
    mesh::{Mesh, OrdF64},
};

/// `n` Euclidean farthest-point samples of `mesh` (every vertex when it has at most `n`) and
/// their cells along the mesh's edges; a vertex no sample reaches (another component) joins
/// the Euclidean-nearest sample.
pub fn sample_cells(mesh: &Mesh, n: usize) -> Result<SampleCells, Error> {
    let nv = mesh.n_vertices();
    let edges = || mesh.faces.iter().flat_map(|f| [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])]);
    if nv <= n {
        return Ok(SampleCells::new((0..nv).collect(), (0..nv as u32).collect(), edges())?);
    }
    let samples = farthest_point_sampling_euclidean(mesh, n, None)?;
    let (_, nearest) = dijkstra_nearest_source(mesh, &samples)?;
    let d2 = |a: [f64; 3], b: [f64; 3]| (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2);
    let cell_of = nearest
        .iter()
        .enumerate()
        .map(|(v, &c)| {
            if c != usize::MAX {
                return c as u32;
            }
            let p = mesh.vertices[v];
            (0..samples.len())
                .min_by(|&i, &j| {
                    d2(p, mesh.vertices[samples[i]]).total_cmp(&d2(p, mesh.vertices[samples[j]]))
                })
                .unwrap_or(0) as u32
        })
        .collect();
    Ok(SampleCells::new(samples, cell_of, edges())?)
}

/// For every cell of `cells` (samples of `mesh`), the cells whose samples are within `radius`
/// of its sample along the cell graph (edges between neighbouring cells, as long as the
/// straight segment between their samples): a cheap stand-in for the geodesic ball that does not
/// jump across a gap between limbs.
pub fn cell_balls(mesh: &Mesh, cells: &SampleCells, radius: f64) -> CellBalls {
    let ns = cells.samples.len();
    let pos = |c: usize| mesh.vertices[cells.samples[c]];
    let dist = |a: [f64; 3], b: [f64; 3]| {
        ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
    };
    let mut offsets = Vec::with_capacity(ns + 1);
    offsets.push(0);
    let mut out = Vec::new();
    let mut best = vec![f64::INFINITY; ns];
    let mut touched = Vec::new();
    let mut heap = BinaryHeap::new();
    for c in 0..ns {
        best[c] = 0.0;
        touched.push(c);
        heap.push((Reverse(OrdF64(0.0)), c));
        while let Some((Reverse(OrdF64(d)), u)) = heap.pop() {
            if d > best[u] {
                continue;
            }
            out.push(u as u32);
            for &w in cells.neighbours_of(u) {
                let w = w as usize;
                let nd = d + dist(pos(u), pos(w));
                if nd <= radius && nd < best[w] {
                    if best[w].is_infinite() {
                        touched.push(w);
                    }
                    best[w] = nd;
                    heap.push((Reverse(OrdF64(nd)), w));
                }
            }
        }
        for &t in &touched {
            best[t] = f64::INFINITY;
        }
        touched.clear();
        offsets.push(out.len());
    }
    CellBalls { offsets, cells: out }
}

/// How far `map` is from an isometry on `samples` of the test shape: the mean, over pairs of
/// samples, of `|d_M(s_i, s_j) − d_R(map(s_i), map(s_j))|`, geodesic distances (heat method) in
/// units of each shape's `√area`. `test_fields` are the test shape's distances from the samples
/// (one column each), shared between the maps compared.
pub fn map_distortion(
    reference: &PreparedShape,
    test_fields: &faer::Mat<f64>,
    samples: &[usize],
    test_sqrt_area: f64,
    map: &[usize],
) -> Result<f64, Error> {
    let targets: Vec<usize> = samples.iter().map(|&s| map[s]).collect();
    let ref_fields = reference.heat.distances_from_many(&targets)?;
    let (st, sr) =
        (1.0 / test_sqrt_area.max(f64::MIN_POSITIVE), 1.0 / reference.sqrt_area().max(f64::MIN_POSITIVE));
    let n = samples.len();
    let mut total = 0.0;
    for i in 0..n {
        for j in (i + 1)..n {
            total += (test_fields[(samples[i], j)] * st - ref_fields[(targets[i], j)] * sr).abs();
        }
    }
    Ok(if n > 1 { total / (n * (n - 1) / 2) as f64 } else { 0.0 })
}

/// ZoomOut of `map` (test vertex → reference vertex) by `params`, read back on every test vertex;
/// `None` when the check of `params.check_samples` found it farther from an isometry than `map`.
pub fn refine_zoomout(
    test: &PreparedShape,
    reference: &PreparedShape,
    map: &[usize],
    params: &ZoomOutParams,
) -> Result<Option<Vec<usize>>, Error> {
    // The shapes' ZoomOut bases: more eigenpairs than the descriptors' when they carry them.
    let (test_basis, reference_basis) = (test.zoomout_basis(), reference.zoomout_basis());
    let (k_start, k_final) = params.schedule(test_basis.k().min(reference_basis.k()));
    let schedule = ZoomOutSchedule { k_start, k_final, step: params.step };
    let test_cells = test.sample_cells(params.samples)?;
    let reference_cells = reference.sample_cells(params.samples)?;
    let balls = params
        .radius
        .map(|r| cell_balls(&reference.mesh, &reference_cells, r * reference.mesh.surface_area().sqrt()));
    let c = zoomout_on_samples(
        test_basis,
        &test_cells,
        reference_basis,
        &reference_cells,
        balls.as_ref(),
        map,
        schedule,
    )?;
    let restrict = balls.as_ref().map(|b| (b, map));
    let refined =
        point_to_point_in_cells(test_basis, reference_basis, &reference_cells, restrict, c.as_ref())?;
    kept_if_closer_to_isometry(test, reference, map, refined, params.check_samples)
}

/// For every test vertex, the image among those of `maps` (test vertex → reference vertex)
/// where the forest's posterior is densest: each map's image scores
/// `Σ_r p(r) exp(−|x_r − x_image|² / 2σ²)` over the vertex's candidates `r` (Euclidean, `σ` =
/// `sigma` · √area of the reference), the scores are averaged over `rounds` passes of mesh
/// neighbours (so that a region, not a vertex, chooses), and the first map's image is kept
/// unless another map scores more than `margin` times as much (then the best such map's; the
/// earlier map on ties). `margin` = 1 takes the plain maximum.
///
/// ```
/// use shapeforest::{mesh::Mesh, regularizer::select_by_posterior};
/// let m = Mesh::new(vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], vec![[0, 1, 2]]).unwrap();
/// // Every vertex's only candidate is vertex 1: the second map, which lands there, wins.
/// let candidates: Vec<usize> = vec![1, 1, 1];
/// let chosen = select_by_posterior(&m, &m, candidates.as_slice(), &[&[0, 2, 2], &[1, 1, 1]], 0.1, 1.5, 0);
/// assert_eq!(chosen, vec![1, 1, 1]);
/// ```
pub fn select_by_posterior<S: crate::fmap::SoftCorrespondence + ?Sized>(
    test: &Mesh,
    reference: &Mesh,
    posterior: &S,
    maps: &[&[usize]],
    sigma: f64,
    margin: f64,
    rounds: usize,
) -> Vec<usize> {
    let n = test.n_vertices();
    if maps.is_empty() {
        return Vec::new();
    }
    let scores: Vec<Vec<f64>> =
        maps.iter().map(|map| posterior_support(test, reference, posterior, map, sigma)).collect();
    let (offsets, neighbours) = crate::mesh::face_neighbour_lists(&test.faces, n);
    let smoothed: Vec<Vec<f64>> =
        scores.into_iter().map(|s| super::flip::diffuse(&offsets, &neighbours, s, rounds)).collect();
    (0..n)
        .map(|m| {
            let bar = margin * smoothed[0][m];
            let best = (1..maps.len()).fold(0, |b, i| {
                if smoothed[i][m] > bar && smoothed[i][m] > smoothed[b][m] {
                    i
                } else {
                    b
                }
            });
            maps[best][m]
        })
        .collect()
}

/// How densely the forest's posterior surrounds each test vertex's image under `map` (test
/// vertex → reference vertex): `Σ_r p(r) exp(−|x_r − x_image|² / 2σ²)` over the vertex's
/// candidates `r` (Euclidean, `σ` = `sigma` · √area of the reference).
///
/// ```
/// use shapeforest::{mesh::Mesh, regularizer::posterior_support};
/// let m = Mesh::new(vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], vec![[0, 1, 2]]).unwrap();
/// // Every vertex's only candidate is vertex 1: a map onto it is supported, one onto 0 barely.
/// let candidates: Vec<usize> = vec![1, 1, 1];
/// let on = posterior_support(&m, &m, candidates.as_slice(), &[1, 1, 1], 0.1);
/// let off = posterior_support(&m, &m, candidates.as_slice(), &[0, 0, 0], 0.1);
/// assert!(on.iter().all(|&s| (s - 1.0).abs() < 1e-12) && off.iter().all(|&s| s < 1e-6));
/// ```
pub fn posterior_support<S: crate::fmap::SoftCorrespondence + ?Sized>(
    test: &Mesh,
    reference: &Mesh,
    posterior: &S,
    map: &[usize],
    sigma: f64,
) -> Vec<f64> {
    use rayon::prelude::*;
    let s = sigma * reference.surface_area().max(f64::MIN_POSITIVE).sqrt();
    let inv = 1.0 / (2.0 * s * s).max(f64::MIN_POSITIVE);
    let pos = &reference.vertices;
    (0..test.n_vertices().min(map.len()))
        .into_par_iter()
        .map(|m| {
            let Some(q) = pos.get(map[m]) else { return 0.0 };
            let mut total = 0.0;
            posterior.for_each_entry(m, &mut |r, p| {
                if let Some(x) = pos.get(r) {
                    let d2 = (x[0] - q[0]).powi(2) + (x[1] - q[1]).powi(2) + (x[2] - q[2]).powi(2);
                    total += p * (-d2 * inv).exp();
                }
            });
            total
        })
        .collect()
}

/// The choice of [`MapSelection`] (see there): region by region `fine` or `coarse`, whichever
/// the posterior supports best, then `sharper`'s image where it lies within `select.reach` of
/// that choice and the posterior supports it `select.margin` times as well. The scores are
/// smoothed over as many passes of mesh neighbours as the mirror repair's
/// ([`super::unflip_rounds`]).
pub(super) fn choose_refined<S: crate::fmap::SoftCorrespondence + ?Sized>(
    test: &PreparedShape,
    reference: &PreparedShape,
    posterior: &S,
    fine: &[usize],
    coarse: Option<&[usize]>,
    sharper: Option<Vec<usize>>,
    select: &MapSelection,
) -> Vec<usize> {
    let rounds = super::unflip_rounds(test.mesh.n_vertices());
    let choose = |maps: &[&[usize]], margin: f64| {
        select_by_posterior(&test.mesh, &reference.mesh, posterior, maps, select.sigma, margin, rounds)
    };
    let chosen = match coarse {
        Some(c) => choose(&[fine, c], 1.0),
        None => fine.to_vec(),
    };
    let Some(mut sharper) = sharper else { return chosen };
    let r2 = (select.reach * reference.sqrt_area()).powi(2);
    let pos = &reference.mesh.vertices;
    for (image, &c) in sharper.iter_mut().zip(&chosen) {
        if crate::fmap::squared_distance(&pos[*image], &pos[c]) > r2 {
            *image = c;
        }
    }
    choose(&[&chosen, &sharper], select.margin)
}

/// `refined`, unless `check_samples` (> 0) farthest-point samples find it farther from an
/// isometry than `map` ([`map_distortion`]); `check_samples = 0` keeps it unchecked.
pub(super) fn kept_if_closer_to_isometry(
    test: &PreparedShape,
    reference: &PreparedShape,
    map: &[usize],
    refined: Vec<usize>,
    check_samples: usize,
) -> Result<Option<Vec<usize>>, Error> {
    if check_samples == 0 {
        return Ok(Some(refined));
    }
    let samples =
        farthest_point_sampling_euclidean(&test.mesh, check_samples.min(test.mesh.n_vertices()), None)?;
    let fields = test.heat.distances_from_many(&samples)?;
    let before = map_distortion(reference, &fields, &samples, test.sqrt_area(), map)?;
    let after = map_distortion(reference, &fields, &samples, test.sqrt_area(), &refined)?;
    Ok((after <= before).then_some(refined))
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use rand::{Rng, SeedableRng};

    use super::*;
    use crate::{geodesic::HeatParams, spectral::dense_spectrum, synth::icosphere};

    /// An ellipsoid (distinct axes, so that its low eigenfunctions are not degenerate).
    fn ellipsoid() -> PreparedShape {
        let mut mesh = icosphere(3, 1.0);
        for v in &mut mesh.vertices {
            v[1] *= 1.3;
            v[2] *= 1.7;
        }
        let spectrum = Arc::new(dense_spectrum(&mesh, 40).unwrap());
        PreparedShape::new(Arc::new(mesh), spectrum, HeatParams::default()).unwrap()
    }

    #[test]
    fn zoomout_on_samples_sharpens_a_map_that_is_right_in_the_large() {
        let shape = ellipsoid();
        let n = shape.mesh.n_vertices();
        // The true map is the identity; start from every vertex sent to a random mesh neighbour.
        let mut neighbours = vec![Vec::new(); n];
        for f in &shape.mesh.faces {
            for (a, b) in [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])] {
                neighbours[a].push(b);
                neighbours[b].push(a);
            }
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let noisy: Vec<usize> =
            (0..n).map(|v| neighbours[v][rng.random_range(0..neighbours[v].len())]).collect();
        assert!(noisy.iter().enumerate().all(|(v, &r)| v != r));
        // Fewer samples than vertices: the sampled iterations and the read-back in cells.
        let params = ZoomOutParams {
            k_start: 10,
            k_final: 40,
            step: 3,
            samples: n / 2,
            radius: None,
            check_samples: 0,
            extrinsic: None,
            ..Default::default()
        };
        let refined = refine_zoomout(&shape, &shape, &noisy, &params).unwrap().unwrap();
        let correct = refined.iter().enumerate().filter(|&(v, &r)| v == r).count();
        assert!(correct * 10 >= n * 9, "{correct} of {n} vertices mapped to themselves");
        // Restricted to balls and checked against the isometry: still sharp, and kept.
        let params = ZoomOutParams { radius: Some(0.2), check_samples: 30, ..params };
        let refined =
            refine_zoomout(&shape, &shape, &noisy, &params).unwrap().expect("closer to an isometry");
        let correct = refined.iter().enumerate().filter(|&(v, &r)| v == r).count();
        assert!(correct * 10 >= n * 9, "{correct} of {n} vertices mapped to themselves (restricted)");
    }

    #[test]
    fn a_refinement_farther_from_an_isometry_is_not_kept() {
        let shape = ellipsoid();
        let n = shape.mesh.n_vertices();
        let identity: Vec<usize> = (0..n).collect();
        let samples = farthest_point_sampling_euclidean(&shape.mesh, 30, None).unwrap();
        let fields = shape.heat.distances_from_many(&samples).unwrap();
        let exact = map_distortion(&shape, &fields, &samples, shape.sqrt_area(), &identity).unwrap();
        assert!(exact < 1e-9, "{exact}");
        // Everything onto one vertex is far from an isometry.
        let collapsed = vec![0; n];
        let bad = map_distortion(&shape, &fields, &samples, shape.sqrt_area(), &collapsed).unwrap();
        assert!(bad > 0.1, "{bad}");
        // Starting from the exact map, ZoomOut at too small a basis cannot improve it: a
        // refinement at least as good is kept, never a worse one.
        let params = ZoomOutParams {
            k_start: 3,
            k_final: 3,
            step: 1,
            samples: n,
            check_samples: 30,
            ..Default::default()
        };
        if let Some(r) = refine_zoomout(&shape, &shape, &identity, &params).unwrap() {
            let d = map_distortion(&shape, &fields, &samples, shape.sqrt_area(), &r).unwrap();
            assert!(d <= exact + 1e-12);
        }
    }
}
