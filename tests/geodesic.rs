//! Geodesic distances against analytic answers (flat grid, unit sphere), symmetry, scale
//! equivariance, disconnected meshes, and farthest point sampling.
//!
//! Tolerances are stated per method next to each assertion; the measured values they guard
//! are listed in the `geodesic` module documentation.

mod common;

use shapeforest::geodesic::{
    dijkstra_distances, farthest_point_sampling_euclidean, farthest_point_sampling_geodesic,
    fast_marching_distances, GeodesicError, HeatBoundary, HeatMethodSolver, HeatParams, SamplingMetric,
};
use shapeforest::mesh::Mesh;
use shapeforest::synth::{grid_plane, icosphere};

fn dist3(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Max relative error against the Euclidean distance from `src`, over vertices farther than
/// `r_min` from it.
fn max_rel_error_plane(mesh: &Mesh, src: usize, d: &[f64], r_min: f64) -> f64 {
    let p = mesh.vertices[src];
    mesh.vertices
        .iter()
        .zip(d)
        .map(|(&q, &dq)| (dist3(p, q), dq))
        .filter(|&(e, _)| e > r_min)
        .map(|(e, dq)| (dq - e).abs() / e)
        .fold(0.0, f64::max)
}

/// (mean, max) absolute error against the great-circle distance on a sphere of radius `r`.
fn sphere_errors(mesh: &Mesh, src: usize, d: &[f64], r: f64) -> (f64, f64) {
    let p = mesh.vertices[src];
    let mut sum = 0.0;
    let mut max: f64 = 0.0;
    for (&q, &dq) in mesh.vertices.iter().zip(d) {
        let c = ((p[0] * q[0] + p[1] * q[1] + p[2] * q[2]) / (r * r)).clamp(-1.0, 1.0);
        let err = (dq - r * c.acos()).abs();
        sum += err;
        max = max.max(err);
    }
    (sum / d.len() as f64, max)
}

const GRID_N: usize = 61;
const GRID_CENTRE: usize = 30 * GRID_N + 30;

#[test]
fn flat_grid_heat_method_matches_euclidean() {
    let grid = grid_plane(GRID_N, GRID_N, 1.0, 1.0);
    for (boundary, tol) in
        [(HeatBoundary::Average, 0.05), (HeatBoundary::Neumann, 0.08), (HeatBoundary::Dirichlet, 0.08)]
    {
        let solver = HeatMethodSolver::new(&grid, HeatParams { boundary, ..Default::default() }).unwrap();
        let d = solver.distances_from(GRID_CENTRE).unwrap();
        assert_eq!(d[GRID_CENTRE], 0.0);
        assert!(d.iter().all(|&x| x >= 0.0 && x.is_finite()));
        let err = max_rel_error_plane(&grid, GRID_CENTRE, &d, 0.1);
        eprintln!("grid 61x61, heat {boundary:?}: max relative error beyond r = 0.1: {err:.4}");
        assert!(err < tol, "{boundary:?}: max relative error {err} ≥ {tol}");
    }
}

#[test]
fn flat_grid_fast_marching_and_dijkstra() {
    let grid = grid_plane(GRID_N, GRID_N, 1.0, 1.0);
    let fmm = fast_marching_distances(&grid, &[GRID_CENTRE]).unwrap();
    let err = max_rel_error_plane(&grid, GRID_CENTRE, &fmm, 0.1);
    eprintln!("grid 61x61, fast marching: max relative error beyond r = 0.1: {err:.2e}");
    // a point source in the plane is reproduced exactly by the virtual-source update
    assert!(err < 1e-6, "fast marching max relative error {err}");

    let dij = dijkstra_distances(&grid, &[GRID_CENTRE]).unwrap();
    let err = max_rel_error_plane(&grid, GRID_CENTRE, &dij, 0.1);
    eprintln!("grid 61x61, Dijkstra: max relative error beyond r = 0.1: {err:.4}");
    // edge paths: an upper bound, off by a few percent to ~10 % depending on direction
    assert!(err < 0.12, "Dijkstra max relative error {err}");
    let p = grid.vertices[GRID_CENTRE];
    for (q, &d) in grid.vertices.iter().zip(&dij) {
        assert!(d >= dist3(p, *q) - 1e-12, "Dijkstra must be an upper bound");
    }
}

#[test]
fn unit_sphere_against_great_circle_distance() {
    let sphere = icosphere(5, 1.0);
    assert_eq!(sphere.n_vertices(), 10_242);
    let solver = HeatMethodSolver::new(&sphere, HeatParams::default()).unwrap();
    let heat = solver.distances_from(0).unwrap();
    let (mean, max) = sphere_errors(&sphere, 0, &heat, 1.0);
    eprintln!("sphere 10K, heat: mean abs error {mean:.2e}, max {max:.2e}");
    assert!(mean < 0.01 && max < 0.04, "heat: mean {mean}, max {max}");

    let fmm = fast_marching_distances(&sphere, &[0]).unwrap();
    let (mean, max) = sphere_errors(&sphere, 0, &fmm, 1.0);
    eprintln!("sphere 10K, fast marching: mean abs error {mean:.2e}, max {max:.2e}");
    assert!(mean < 0.01 && max < 0.03, "fast marching: mean {mean}, max {max}");

    let dij = dijkstra_distances(&sphere, &[0]).unwrap();
    let (mean, max) = sphere_errors(&sphere, 0, &dij, 1.0);
    eprintln!("sphere 10K, Dijkstra: mean abs error {mean:.2e}, max {max:.2e}");
    assert!(mean < 0.15 && max < 0.25, "Dijkstra: mean {mean}, max {max}");
}

#[test]
fn heat_distances_are_nearly_symmetric_and_batched_equals_single() {
    let sphere = icosphere(4, 1.0);
    let solver = HeatMethodSolver::new(&sphere, HeatParams::default()).unwrap();
    let sources = [0, 17, 500, 1234, 2561];
    let d = solver.distances_from_many(&sources).unwrap();
    assert_eq!((d.nrows(), d.ncols()), (sphere.n_vertices(), sources.len()));
    for (i, &a) in sources.iter().enumerate() {
        assert_eq!(d[(a, i)], 0.0);
        for (j, &b) in sources.iter().enumerate() {
            let (ab, ba) = (d[(b, i)], d[(a, j)]);
            // the heat method is not exactly symmetric: a few parts in a thousand of π here
            assert!((ab - ba).abs() < 0.01, "d({a},{b}) = {ab} but d({b},{a}) = {ba}");
        }
    }
    let single = solver.distances_from(500).unwrap();
    for (v, &x) in single.iter().enumerate() {
        assert!((x - d[(v, 2)]).abs() < 1e-9);
    }
}

#[test]
fn heat_distances_scale_with_the_mesh() {
    let sphere = icosphere(3, 1.0);
    let big = sphere.scaled(7.5);
    let d1 = HeatMethodSolver::new(&sphere, HeatParams::default()).unwrap().distances_from(3).unwrap();
    let d2 = HeatMethodSolver::new(&big, HeatParams::default()).unwrap().distances_from(3).unwrap();
    for (a, b) in d1.iter().zip(&d2) {
        assert!((7.5 * a - b).abs() < 1e-6 * b.max(1.0), "{a} × 7.5 ≠ {b}");
    }
}

#[test]
fn other_components_are_unreachable() {
    let a = icosphere(2, 1.0);
    let mut vertices = a.vertices.clone();
    let mut faces = a.faces.clone();
    let n = vertices.len();
    vertices.extend(a.vertices.iter().map(|p| [p[0] + 5.0, p[1], p[2]]));
    faces.extend(a.faces.iter().map(|f| [f[0] + n, f[1] + n, f[2] + n]));
    let two = Mesh::new(vertices, faces).unwrap();
    let heat = HeatMethodSolver::new(&two, HeatParams::default()).unwrap().distances_from(0).unwrap();
    let fmm = fast_marching_distances(&two, &[0]).unwrap();
    let dij = dijkstra_distances(&two, &[0]).unwrap();
    for d in [&heat, &fmm, &dij] {
        assert!(d[..n].iter().all(|x| x.is_finite()));
        assert!(d[n..].iter().all(|x| x.is_infinite()));
    }
}

#[test]
fn bad_sources_are_typed_errors() {
    let sphere = icosphere(1, 1.0);
    let solver = HeatMethodSolver::new(&sphere, HeatParams::default()).unwrap();
    assert!(matches!(
        solver.distances_from(42),
        Err(GeodesicError::SourceOutOfRange { vertex: 42, n_vertices: 42 })
    ));
    assert!(matches!(solver.distances_from_many(&[]), Err(GeodesicError::NoSources)));
    let msg = solver.distances_from(100).unwrap_err().to_string();
    assert!(msg.contains("100") && msg.contains("42"), "{msg}");
}

#[test]
fn multi_source_fields_are_distance_to_nearest_source() {
    let grid = grid_plane(21, 21, 1.0, 1.0);
    let sources = [0, 440];
    let both = fast_marching_distances(&grid, &sources).unwrap();
    let a = fast_marching_distances(&grid, &sources[..1]).unwrap();
    let b = fast_marching_distances(&grid, &sources[1..]).unwrap();
    for v in 0..grid.n_vertices() {
        assert!((both[v] - a[v].min(b[v])).abs() < 1e-12);
    }
}

#[test]
fn farthest_point_sampling_on_the_sphere() {
    let sphere = icosphere(3, 1.0);
    for metric in [None, Some(SamplingMetric::Dijkstra), Some(SamplingMetric::FastMarching)] {
        let s = match metric {
            None => farthest_point_sampling_euclidean(&sphere, 30, None).unwrap(),
            Some(m) => farthest_point_sampling_geodesic(&sphere, 30, None, m).unwrap(),
        };
        assert_eq!(s.len(), 30);
        let mut sorted = s.clone();
        sorted.sort_unstable();
        sorted.dedup();
        assert_eq!(sorted.len(), 30, "{metric:?}: samples are not distinct");
        // the first two samples are (nearly) antipodal
        let (p, q) = (sphere.vertices[s[0]], sphere.vertices[s[1]]);
        let cos = p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
        assert!(cos < -0.99, "{metric:?}: first two samples have p·q = {cos}");
        // covering radius (max distance to the nearest sample) never increases
        let mut last = f64::INFINITY;
        for k in [1, 2, 5, 10, 20, 30] {
            let r = dijkstra_distances(&sphere, &s[..k]).unwrap().into_iter().fold(0.0, f64::max);
            assert!(r <= last + 1e-12, "{metric:?}: covering radius grew to {r} at {k} samples");
            last = r;
        }
        // 30 well-spread points on the unit sphere cover it within ~0.5 (area 4π / 30 caps)
        assert!(last < 0.6, "{metric:?}: covering radius {last}");
    }
    // deterministic
    let a = farthest_point_sampling_geodesic(&sphere, 10, Some(5), SamplingMetric::Dijkstra).unwrap();
    let b = farthest_point_sampling_geodesic(&sphere, 10, Some(5), SamplingMetric::Dijkstra).unwrap();
    assert_eq!(a, b);
    assert_eq!(a[0], 5);
}

/// Minimal OFF reader for the optional real-data test (the crate's readers live elsewhere).
fn read_off(path: &std::path::Path) -> Option<Mesh> {
    let text = std::fs::read_to_string(path).ok()?;
    let mut tokens = text.split_whitespace();
    if tokens.next()? != "OFF" {
        return None;
    }
    let nv: usize = tokens.next()?.parse().ok()?;
    let nf: usize = tokens.next()?.parse().ok()?;
    tokens.next()?;
    let mut vertices = Vec::with_capacity(nv);
    for _ in 0..nv {
        let mut p = [0.0; 3];
        for c in &mut p {
            *c = tokens.next()?.parse().ok()?;
        }
        vertices.push(p);
    }
    let mut faces = Vec::with_capacity(nf);
    for _ in 0..nf {
        if tokens.next()? != "3" {
            return None;
        }
        let mut f = [0usize; 3];
        for i in &mut f {
            *i = tokens.next()?.parse().ok()?;
        }
        faces.push(f);
    }
    Mesh::new(vertices, faces).ok()
}

#[test]
fn tosca_wolf_heat_agrees_with_fast_marching() {
    let Some(path) = common::shared_data("tosca/wolf0.off") else { return };
    let wolf = read_off(&path).expect("TOSCA wolf0.off reads");
    let sqrt_area = wolf.surface_area().sqrt();
    let solver = HeatMethodSolver::new(&wolf, HeatParams::default()).unwrap();
    let sources = [0, 1000, 2000, 3000];
    let heat = solver.distances_from_many(&sources).unwrap();
    for (j, &s) in sources.iter().enumerate() {
        let fmm = fast_marching_distances(&wolf, &[s]).unwrap();
        let dij = dijkstra_distances(&wolf, &[s]).unwrap();
        let n = wolf.n_vertices() as f64;
        let mean = (0..wolf.n_vertices()).map(|v| (heat[(v, j)] - fmm[v]).abs()).sum::<f64>() / n / sqrt_area;
        let max =
            (0..wolf.n_vertices()).map(|v| (heat[(v, j)] - fmm[v]).abs()).fold(0.0, f64::max) / sqrt_area;
        eprintln!("wolf0 source {s}: |heat − fmm| / √area mean {mean:.2e}, max {max:.2e}");
        // both are first-order approximations on a coarse irregular mesh (measured: mean
        // 0.9–1.4 % of √area, max 2.6–5.3 %)
        assert!(mean < 0.02 && max < 0.08, "source {s}: mean {mean}, max {max}");
        // edge paths never beat the surface
        assert!(fmm.iter().zip(&dij).all(|(f, d)| *f <= d + 1e-9), "fast marching exceeds Dijkstra");
    }
}

/// A 61×61 unit-square grid with interior vertices jittered by up to ±0.35 h (seeded), which
/// creates obtuse triangles: the case where fast marching falls back to edge updates.
fn jittered_grid() -> Mesh {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let mut grid = grid_plane(GRID_N, GRID_N, 1.0, 1.0);
    let h = 1.0 / (GRID_N - 1) as f64;
    for (v, p) in grid.vertices.iter_mut().enumerate() {
        let (i, j) = (v % GRID_N, v / GRID_N);
        if i == 0 || j == 0 || i == GRID_N - 1 || j == GRID_N - 1 || v == GRID_CENTRE {
            continue;
        }
        p[0] += rng.random_range(-0.35..0.35) * h;
        p[1] += rng.random_range(-0.35..0.35) * h;
    }
    grid
}

#[test]
fn jittered_flat_grid_with_obtuse_triangles() {
    let grid = jittered_grid();
    let fmm = fast_marching_distances(&grid, &[GRID_CENTRE]).unwrap();
    let err_fmm = max_rel_error_plane(&grid, GRID_CENTRE, &fmm, 0.1);
    let heat =
        HeatMethodSolver::new(&grid, HeatParams::default()).unwrap().distances_from(GRID_CENTRE).unwrap();
    let err_heat = max_rel_error_plane(&grid, GRID_CENTRE, &heat, 0.1);
    let dij = dijkstra_distances(&grid, &[GRID_CENTRE]).unwrap();
    let err_dij = max_rel_error_plane(&grid, GRID_CENTRE, &dij, 0.1);
    eprintln!("jittered grid: max relative error beyond r = 0.1: fmm {err_fmm:.4}, heat {err_heat:.4}, dijkstra {err_dij:.4}");
    let p = grid.vertices[GRID_CENTRE];
    let far: Vec<usize> = (0..grid.n_vertices()).filter(|&v| dist3(p, grid.vertices[v]) > 0.1).collect();
    let mean_fmm = far.iter().map(|&v| (fmm[v] / dist3(p, grid.vertices[v]) - 1.0).abs()).sum::<f64>()
        / far.len() as f64;
    eprintln!("jittered grid: fast marching mean relative error beyond r = 0.1: {mean_fmm:.4}");
    // measured: max 3.1 % at isolated vertices (6.7 % before obtuse corners were unfolded), mean 1e-4
    assert!(err_fmm < 0.04, "fast marching {err_fmm}");
    assert!(mean_fmm < 1e-3, "fast marching mean {mean_fmm}");
    assert!(err_heat < 0.05, "heat {err_heat}");
    assert!(err_fmm < err_dij);
}

#[test]
fn solvers_are_send_and_sync() {
    fn check<T: Send + Sync>() {}
    check::<HeatMethodSolver>();
    check::<shapeforest::geodesic::FastMarchingSolver<'static>>();
    check::<GeodesicError>();
}

#[test]
fn heat_method_with_a_source_on_the_boundary() {
    let grid = grid_plane(GRID_N, GRID_N, 1.0, 1.0);
    let edge_mid = 30; // middle of the bottom edge
                       // Dirichlet alone is poor for a boundary source (measured 34 %: the boundary is held cold
                       // right next to the source), so only Average and Neumann are held to a bound here.
    for boundary in [HeatBoundary::Average, HeatBoundary::Neumann] {
        let solver = HeatMethodSolver::new(&grid, HeatParams { boundary, ..Default::default() }).unwrap();
        let d = solver.distances_from(edge_mid).unwrap();
        let err = max_rel_error_plane(&grid, edge_mid, &d, 0.1);
        eprintln!("grid 61x61, heat {boundary:?}, source on the boundary: max relative error beyond r = 0.1: {err:.4}");
        assert_eq!(d[edge_mid], 0.0);
        assert!(err < 0.05, "{boundary:?}: {err}");
    }
}

#[test]
fn unreferenced_vertex_is_unreachable_and_never_sampled() {
    let mut sphere = icosphere(2, 1.0);
    sphere.vertices.push([3.0, 3.0, 3.0]); // touches no face
    let sphere = Mesh::new(sphere.vertices, sphere.faces).unwrap();
    let lonely = sphere.n_vertices() - 1;
    let heat = HeatMethodSolver::new(&sphere, HeatParams::default()).unwrap().distances_from(0).unwrap();
    assert!(heat[lonely].is_infinite());
    assert!(heat[..lonely].iter().all(|x| x.is_finite()));
    let s = farthest_point_sampling_geodesic(&sphere, 20, Some(0), SamplingMetric::Dijkstra).unwrap();
    assert!(!s.contains(&lonely));
}
