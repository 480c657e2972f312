//! Integration tests of the Laplace–Beltrami eigensolver and the spectrum cache, through the
//! public API only.

use std::f64::consts::PI;

use shapeforest::mesh::Mesh;
use shapeforest::spectral::{
    compute_spectrum, dense_spectrum, relative_residuals, LaplaceBeltramiSolver, SpectralError, Spectrum,
    SpectrumCache, SpectrumMethod, SpectrumParams,
};
use shapeforest::synth::{icosphere, torus};

/// Groups ascending eigenvalues into clusters separated by relative gaps above `gap`.
fn cluster_sizes(values: &[f64], gap: f64) -> Vec<usize> {
    let mut sizes = vec![1];
    for w in values.windows(2) {
        if (w[1] - w[0]) > gap * w[1].abs().max(1e-12) {
            sizes.push(1);
        } else {
            *sizes.last_mut().unwrap() += 1;
        }
    }
    sizes
}

/// `max |ΦᵀMΦ − I|`.
fn orthonormality_error(s: &Spectrum) -> f64 {
    let mut worst = 0.0f64;
    for a in 0..s.k() {
        for b in 0..=a {
            let dot: f64 = (0..s.n_vertices).map(|i| s.mass[i] * s.phi(a)[i] * s.phi(b)[i]).sum();
            let want = if a == b { 1.0 } else { 0.0 };
            worst = worst.max((dot - want).abs());
        }
    }
    worst
}

/// A torus with deterministic pseudo-random vertex jitter (irregular, no symmetry left).
fn jittered_torus(nu: usize, nv: usize, amount: f64) -> Mesh {
    let mut m = torus(nu, nv, 1.0, 0.4);
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    for p in m.vertices.iter_mut() {
        for c in p.iter_mut() {
            *c += amount * next();
        }
    }
    m
}

fn sphere_check(subdivisions: u32, k: usize, tolerance: f64) {
    let mesh = icosphere(subdivisions, 1.7);
    let (s, report) =
        LaplaceBeltramiSolver::new(&mesh, &SpectrumParams::new(k)).unwrap().solve_with_report().unwrap();
    assert_eq!(report.method, SpectrumMethod::Lanczos);
    assert!(report.count_verified_below.is_some());
    // Multiplicities 2l + 1, exactly.
    let sizes = cluster_sizes(&s.eigenvalues, 0.05);
    let want: Vec<usize> = (0..sizes.len()).map(|l| 2 * l + 1).collect();
    assert_eq!(sizes, want, "multiplicities of the sphere spectrum");
    // λ ≈ l(l+1)·4π on the unit-area sphere (radius-independent).
    let mut j = 0;
    for (l, &size) in sizes.iter().enumerate() {
        let exact = (l * (l + 1)) as f64 * 4.0 * PI;
        for _ in 0..size {
            let err = (s.eigenvalues[j] - exact).abs() / exact.max(1.0);
            assert!(
                err < tolerance,
                "l = {l}: λ = {} vs {exact} (relative error {err:.2e})",
                s.eigenvalues[j]
            );
            j += 1;
        }
    }
    let res = relative_residuals(&mesh, &s).unwrap();
    assert!(res.iter().all(|&r| r < 1e-9), "max residual {:e}", res.iter().cloned().fold(0.0, f64::max));
    assert!(orthonormality_error(&s) < 1e-10);
}

#[test]
fn icosphere_spectrum_has_sphere_eigenvalues_and_multiplicities() {
    // 2562 vertices, l = 0..5.
    sphere_check(4, 36, 0.02);
}

#[test]
fn icosphere_k100_multiplicities_up_to_19() {
    // 10242 vertices, l = 0..9 (multiplicity up to 19, more than the block size of 8).
    sphere_check(5, 100, 0.01);
}

#[test]
fn agrees_with_dense_solver_on_irregular_mesh() {
    let mesh = jittered_torus(40, 20, 0.02); // 800 vertices > dense threshold
    let k = 30;
    let solver = LaplaceBeltramiSolver::new(&mesh, &SpectrumParams::new(k)).unwrap();
    assert_eq!(solver.method(), SpectrumMethod::Lanczos);
    let s = solver.solve().unwrap();
    let d = dense_spectrum(&mesh, k).unwrap();
    for j in 0..k {
        let (a, b) = (s.eigenvalues[j], d.eigenvalues[j]);
        assert!((a - b).abs() <= 1e-9 * b.max(1.0), "λ_{j}: {a} vs {b}");
    }
    // Spanned subspaces: every Lanczos eigenvector lies in the span of the dense eigenvectors
    // of its cluster, and, the spectrum being simple here, equals the dense one including sign.
    let sizes = cluster_sizes(&d.eigenvalues, 1e-6);
    let mut start = 0;
    for size in sizes {
        for a in start..start + size {
            let mut proj = 0.0;
            for b in start..start + size {
                let dot: f64 = (0..s.n_vertices).map(|i| d.mass[i] * s.phi(a)[i] * d.phi(b)[i]).sum();
                proj += dot * dot;
            }
            assert!((proj - 1.0).abs() < 1e-8, "eigenvector {a}: squared projection {proj}");
            if size == 1 {
                let diff = s.phi(a).iter().zip(d.phi(a)).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
                assert!(
                    diff < 1e-6,
                    "eigenvector {a} differs from the dense one by {diff} (sign convention?)"
                );
            }
        }
        start += size;
    }
    assert_eq!(s.mass, d.mass);
}

#[test]
fn disconnected_mesh_with_unreferenced_vertex() {
    // Two spheres side by side plus one vertex referenced by no triangle.
    let a = icosphere(3, 1.0);
    let b = icosphere(3, 0.5);
    let mut vertices = a.vertices.clone();
    let offset = vertices.len();
    vertices.extend(b.vertices.iter().map(|p| [p[0] + 5.0, p[1], p[2]]));
    let mut faces = a.faces.clone();
    faces.extend(b.faces.iter().map(|f| [f[0] + offset, f[1] + offset, f[2] + offset]));
    vertices.push([9.0, 9.0, 9.0]);
    let stray = vertices.len() - 1;
    let mesh = Mesh::new(vertices, faces).unwrap();

    let params = SpectrumParams { dense_threshold: 0, ..SpectrumParams::new(12) };
    let (s, report) = LaplaceBeltramiSolver::new(&mesh, &params).unwrap().solve_with_report().unwrap();
    assert_eq!(report.method, SpectrumMethod::Lanczos);
    assert_eq!(report.n_components, 2);
    assert_eq!(report.n_unreferenced, 1);
    assert_eq!(&s.eigenvalues[..2], &[0.0, 0.0]);
    assert!(s.eigenvalues[2] > 1.0);
    // Null vectors: constant and positive on one component, zero elsewhere.
    for (c, range) in [(0, 0..offset), (1, offset..stray)] {
        let phi = s.phi(c);
        let value = phi[range.start];
        assert!(value > 0.0);
        assert!(range.clone().all(|i| (phi[i] - value).abs() < 1e-12));
        assert!((0..mesh.n_vertices()).filter(|i| !range.contains(i)).all(|i| phi[i] == 0.0));
    }
    assert!((0..s.k()).all(|j| s.phi(j)[stray] == 0.0), "unreferenced vertex must be 0");
    assert_eq!(s.mass[stray], 0.0);
    assert!((s.mass.iter().sum::<f64>() - 1.0).abs() < 1e-9);
    assert!(orthonormality_error(&s) < 1e-10);
    let res = relative_residuals(&mesh, &s).unwrap();
    assert!(res.iter().all(|&r| r < 1e-9));
    // Same eigenvalues as the dense reference.
    let d = dense_spectrum(&mesh, 12).unwrap();
    for j in 0..12 {
        assert!((s.eigenvalues[j] - d.eigenvalues[j]).abs() <= 1e-9 * d.eigenvalues[j].max(1.0));
    }
}

#[test]
fn many_components_beyond_block_size() {
    // Ten separate spheres: eigenvalue 0 ten times, more than the block size.
    let mut vertices = Vec::new();
    let mut faces = Vec::new();
    for c in 0..10 {
        let s = icosphere(2, 1.0 + 0.1 * c as f64);
        let off = vertices.len();
        vertices.extend(s.vertices.iter().map(|p| [p[0] + 4.0 * c as f64, p[1], p[2]]));
        faces.extend(s.faces.iter().map(|f| [f[0] + off, f[1] + off, f[2] + off]));
    }
    let mesh = Mesh::new(vertices, faces).unwrap();
    let params = SpectrumParams { dense_threshold: 0, ..SpectrumParams::new(16) };
    let s = compute_spectrum(&mesh, &params).unwrap();
    assert!(s.eigenvalues[..10].iter().all(|&l| l == 0.0));
    assert!(s.eigenvalues[10] > 1.0);
    let d = dense_spectrum(&mesh, 16).unwrap();
    for j in 10..16 {
        assert!((s.eigenvalues[j] - d.eigenvalues[j]).abs() <= 1e-8 * d.eigenvalues[j]);
    }
}

#[test]
fn same_seed_is_bit_identical_and_other_seeds_agree() {
    let mesh = jittered_torus(40, 25, 0.01);
    let p = SpectrumParams::new(20);
    let a = compute_spectrum(&mesh, &p).unwrap();
    let b = compute_spectrum(&mesh, &p).unwrap();
    assert_eq!(a, b);
    let c = compute_spectrum(&mesh, &SpectrumParams { seed: 12345, ..p }).unwrap();
    for j in 0..20 {
        assert!((a.eigenvalues[j] - c.eigenvalues[j]).abs() <= 1e-9 * a.eigenvalues[j].max(1.0));
    }
}

#[test]
fn spectrum_is_scale_invariant() {
    let mesh = jittered_torus(30, 25, 0.01);
    let p = SpectrumParams::new(10);
    let a = compute_spectrum(&mesh, &p).unwrap();
    let b = compute_spectrum(&mesh.scaled(7.5), &p).unwrap();
    assert!((b.area / a.area - 7.5 * 7.5).abs() < 1e-9);
    for j in 0..10 {
        assert!((a.eigenvalues[j] - b.eigenvalues[j]).abs() <= 1e-8 * a.eigenvalues[j].max(1.0));
    }
}

#[test]
fn error_cases() {
    let small = icosphere(1, 1.0); // 42 vertices
    match compute_spectrum(&small, &SpectrumParams::new(43)) {
        Err(SpectralError::TooManyEigenpairs { wanted: 43, n_vertices: 42 }) => {}
        other => panic!("expected TooManyEigenpairs, got {other:?}"),
    }
    let bad = SpectrumParams { shift: 1.0, ..SpectrumParams::new(5) };
    let err = compute_spectrum(&small, &bad).unwrap_err();
    assert!(matches!(err, SpectralError::InvalidParams { field: "shift", .. }));
    assert!(err.to_string().contains("negative"), "{err}");
    let flat = Mesh::new(vec![[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]], vec![[0, 1, 2]]).unwrap();
    assert!(matches!(compute_spectrum(&flat, &SpectrumParams::new(1)), Err(SpectralError::ZeroArea)));
    // A restart budget far too small is reported, not papered over.
    let mesh = jittered_torus(40, 25, 0.01);
    let starved = SpectrumParams { max_basis: 56, max_restarts: 1, ..SpectrumParams::new(40) };
    match compute_spectrum(&mesh, &starved) {
        Err(SpectralError::NotConverged { found, wanted: 40 }) => assert!(found < 40),
        other => panic!("expected NotConverged, got {other:?}"),
    }
}

#[test]
fn cache_round_trip_and_damage_recovery() {
    let dir = tempfile::tempdir().unwrap();
    let cache = SpectrumCache::new(dir.path().join("spectra")).unwrap();
    let mesh = icosphere(2, 1.0);
    let params = SpectrumParams::new(9);
    let path = cache.path_for(&mesh, &params);
    assert_eq!(
        path.file_name().unwrap().to_str().unwrap(),
        format!("{:016x}-k9.spectrum", mesh.content_hash())
    );

    // Missing: load is an error, get_or_compute computes and stores.
    assert!(matches!(cache.load(&mesh, &params), Err(SpectralError::CacheIo { .. })));
    let first = cache.get_or_compute(&mesh, &params).unwrap();
    assert!(path.exists());
    assert_eq!(cache.load(&mesh, &params).unwrap(), first);
    assert_eq!(cache.get_or_compute(&mesh, &params).unwrap(), first);
    let good = std::fs::read(&path).unwrap();

    // Truncated and corrupted files: load reports them, get_or_compute recomputes and rewrites.
    for damaged in [good[..good.len() / 2].to_vec(), {
        let mut b = good.clone();
        let i = b.len() - 10;
        b[i] ^= 0xff;
        b
    }] {
        std::fs::write(&path, &damaged).unwrap();
        let err = cache.load(&mesh, &params).unwrap_err();
        assert!(matches!(err, SpectralError::CacheInvalid { .. }), "{err}");
        assert_eq!(cache.get_or_compute(&mesh, &params).unwrap(), first);
        assert_eq!(std::fs::read(&path).unwrap(), good, "damaged file must be overwritten");
    }
    // Other format version.
    let mut other = good.clone();
    other[8] = other[8].wrapping_add(1);
    std::fs::write(&path, &other).unwrap();
    assert!(cache.load(&mesh, &params).unwrap_err().to_string().contains("version"));
    assert_eq!(cache.get_or_compute(&mesh, &params).unwrap(), first);
    // No temporary files are left behind.
    let names: Vec<_> = std::fs::read_dir(cache.dir()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(names.len(), 1, "{names:?}");
}
