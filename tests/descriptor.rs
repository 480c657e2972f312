//! Descriptor invariants on small meshes with a dense reference spectrum.

use shapeforest::descriptor::{
    heat_kernel_signature, wave_kernel_signature, HksParams, ParametricWks, WksParams,
};
use shapeforest::mesh::Mesh;
use shapeforest::spectral::{dense_spectrum, Spectrum};
use shapeforest::synth::{icosphere, torus};

fn bumpy() -> Mesh {
    let m = torus(24, 12, 1.0, 0.35);
    let v = m.vertices.iter().map(|&[x, y, z]| [x * (1.0 + 0.1 * y), y, z + 0.1 * x * x]).collect();
    Mesh::new(v, m.faces.clone()).unwrap()
}

#[test]
fn wks_is_non_negative_and_hks_decreases_in_time() {
    let s = dense_spectrum(&bumpy(), 40).unwrap();
    let w = wave_kernel_signature(&s, &WksParams::default(), None).unwrap();
    assert_eq!((w.nrows(), w.ncols()), (s.n_vertices, 100));
    for i in 0..w.nrows() {
        for j in 0..w.ncols() {
            assert!(w[(i, j)] >= 0.0);
        }
    }
    let h = heat_kernel_signature(&s, &HksParams::default()).unwrap();
    assert_eq!(h.ncols(), 100);
    for i in 0..h.nrows() {
        for j in 1..h.ncols() {
            assert!(h[(i, j)] <= h[(i, j - 1)] * (1.0 + 1e-12), "vertex {i} time {j}");
        }
        assert!(h[(i, 0)] > h[(i, 99)]);
    }
}

fn flip_signs(s: &Spectrum) -> Spectrum {
    let mut t = s.clone();
    for k in (1..s.k()).step_by(2) {
        for x in &mut t.eigenvectors[k * s.n_vertices..(k + 1) * s.n_vertices] {
            *x = -*x;
        }
    }
    t
}

#[test]
fn invariant_to_sign_flips_and_scale() {
    let mesh = bumpy();
    let s = dense_spectrum(&mesh, 30).unwrap();
    let s2 = dense_spectrum(&mesh.scaled(2.0), 30).unwrap();
    let flipped = flip_signs(&s);
    let p = WksParams::default();
    let (w, wf, w2) = (
        wave_kernel_signature(&s, &p, None).unwrap(),
        wave_kernel_signature(&flipped, &p, None).unwrap(),
        wave_kernel_signature(&s2, &p, None).unwrap(),
    );
    let (h, h2) = (
        heat_kernel_signature(&s, &HksParams::default()).unwrap(),
        heat_kernel_signature(&s2, &HksParams::default()).unwrap(),
    );
    for i in 0..w.nrows() {
        for j in 0..w.ncols() {
            assert!((w[(i, j)] - wf[(i, j)]).abs() <= 1e-12 * w[(i, j)].abs().max(1.0));
            assert!((w[(i, j)] - w2[(i, j)]).abs() <= 1e-6 * w[(i, j)].abs().max(1e-3), "{i} {j}");
            assert!((h[(i, j)] - h2[(i, j)]).abs() <= 1e-6 * h[(i, j)].abs().max(1e-3));
        }
    }
    let (a, b, c) = (
        ParametricWks::new(&s, 30).unwrap(),
        ParametricWks::new(&flipped, 30).unwrap(),
        ParametricWks::new(&s2, 30).unwrap(),
    );
    let (mut wa, mut wc) = (vec![0.0f32; 30], vec![0.0f32; 30]);
    let e = (s.eigenvalues[10]).ln();
    a.weights(e, 0.3, &mut wa);
    c.weights(e, 0.3, &mut wc);
    for v in 0..s.n_vertices {
        assert_eq!(a.eval(v, &wa, 20), b.eval(v, &wa, 20));
        let (x, y) = (a.eval(v, &wa, 20), c.eval(v, &wc, 20));
        assert!((x - y).abs() <= 1e-4 * x.abs().max(1e-3), "{x} {y}");
    }
}

#[test]
fn parametric_wks_is_invariant_to_rotations_within_a_sphere_eigenspace() {
    let s = dense_spectrum(&icosphere(2, 1.0), 9).unwrap();
    // Eigenspace l = 1 is columns 1..4, l = 2 columns 4..9. Rotate within each.
    let mut r = s.clone();
    let n = s.n_vertices;
    let rot = |r: &mut Spectrum, a: usize, b: usize, t: f64| {
        for i in 0..n {
            let (x, y) = (s.eigenvectors[a * n + i], s.eigenvectors[b * n + i]);
            r.eigenvectors[a * n + i] = t.cos() * x - t.sin() * y;
            r.eigenvectors[b * n + i] = t.sin() * x + t.cos() * y;
        }
    };
    rot(&mut r, 1, 3, 0.7);
    rot(&mut r, 5, 8, 1.1);
    let (a, b) = (ParametricWks::new(&s, 9).unwrap(), ParametricWks::new(&r, 9).unwrap());
    let mut w = vec![0.0f32; 9];
    for &e in &[s.eigenvalues[1].ln(), s.eigenvalues[6].ln()] {
        a.weights(e, 0.5, &mut w);
        for v in 0..n {
            for kb in [4usize, 9] {
                let (x, y) = (a.eval(v, &w, kb), b.eval(v, &w, kb));
                assert!((x - y).abs() <= 1e-4 * x.abs().max(1e-3), "vertex {v} k̄ {kb}: {x} vs {y}");
            }
        }
    }
    let mut out = vec![0.0f32; 3];
    a.eval_many(&[0, 5, 9], &w, 9, &mut out);
    assert_eq!(out[1], a.eval(5, &w, 9));
}

#[test]
fn descriptor_errors_name_the_parameter() {
    let s = dense_spectrum(&icosphere(1, 1.0), 10).unwrap();
    let e = wave_kernel_signature(&s, &WksParams { n_energies: 0, sigma_factor: 7.0 }, None).unwrap_err();
    assert!(e.to_string().contains("`n_energies`") && e.to_string().contains("at least 1"), "{e}");
    let e = wave_kernel_signature(&s, &WksParams { n_energies: 10, sigma_factor: -1.0 }, None).unwrap_err();
    assert!(e.to_string().contains("`sigma_factor`"), "{e}");
    let e = ParametricWks::new(&s, 11).unwrap_err();
    assert!(e.to_string().contains("`k`") && e.to_string().contains("10 eigenpairs"), "{e}");
    let e = heat_kernel_signature(&s, &HksParams { n_times: 0 }).unwrap_err();
    assert!(e.to_string().contains("`n_times`"), "{e}");
}
