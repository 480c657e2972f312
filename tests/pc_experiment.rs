use rand::{Rng, SeedableRng};
use shapeforest::mesh::point_cloud_mesh;
use shapeforest::spectral::{compute_spectrum, point_cloud_laplacian, SpectrumParams, TuftedParams};

fn sphere_points(n: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| loop {
            let p: [f64; 3] = [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)];
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            if r > 0.1 && r <= 1.0 {
                break [p[0] / r, p[1] / r, p[2] / r];
            }
        })
        .collect()
}

fn dense_eigs(l: &shapeforest::spectral::IntrinsicLaplacian, k: usize) -> Vec<f64> {
    let n = l.n_vertices;
    let area: f64 = l.total_mass();
    let mut d = faer::Mat::<f64>::zeros(n, n);
    for &(i, j, w) in &l.weights {
        d[(i, j)] -= w; d[(j, i)] -= w; d[(i, i)] += w; d[(j, j)] += w;
    }
    let s: Vec<f64> = l.mass.iter().map(|m| (m / area).max(1e-14).sqrt()).collect();
    let a = faer::Mat::<f64>::from_fn(n, n, |i, j| d[(i, j)] / (s[i] * s[j]));
    let e = a.self_adjoint_eigen(faer::Side::Lower).unwrap();
    (0..k).map(|i| e.S()[i]).collect()
}

#[test]
fn experiment() {
    for &n in &[1000usize, 3000] {
        let pts = sphere_points(n, 1);
        let t = std::time::Instant::now();
        let m = point_cloud_mesh(&pts, 30).unwrap();
        let t_mesh = t.elapsed();
        let s = compute_spectrum(&m, &SpectrumParams::new(16)).unwrap();
        let unit = 4.0 * std::f64::consts::PI;
        let dedup: Vec<f64> = s.eigenvalues.iter().map(|x| x / unit).collect();
        eprintln!("n={n} mesh {:?} faces {} area {:.4}", t_mesh, m.n_faces(), m.surface_area() / unit);
        eprintln!("dedup  λ/4π: {:.3?}", dedup);
        if n <= 1000 {
            let l = point_cloud_laplacian(&pts, 30, TuftedParams::default()).unwrap();
            let e: Vec<f64> = dense_eigs(&l, 16).iter().map(|x| x / unit).collect();
            eprintln!("faithful λ/4π: {:.3?} area {:.4}", e, l.total_mass() / unit);
        }
    }
}

#[test]
fn timing() {
    for &n in &[3000usize, 20000, 50000] {
        let pts = sphere_points(n, 2);
        let t = std::time::Instant::now();
        let lt = shapeforest::mesh::local_triangulation(&pts, 30).unwrap();
        let a = t.elapsed();
        let m = point_cloud_mesh(&pts, 30).unwrap();
        let b = t.elapsed();
        let op = shapeforest::spectral::surface_operator(&m);
        let c = t.elapsed();
        eprintln!("n={n} lt {:?} mesh {:?} op {:?} fans {} faces {} {:?}", a, b - a, c - b, lt.fans.len(), m.n_faces(), op.kind);
    }
}
