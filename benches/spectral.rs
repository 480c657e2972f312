//! Benchmark of the Laplace–Beltrami eigensolver: K = 100 eigenpairs of bumpy tori of about
//! 5K, 20K and 50K vertices (seeded, deterministic), throughput in vertices.
//!
//! Peer comparison: with `SHAPEFOREST_DUMP_DIR=<dir>` set, each benchmark mesh is also written
//! to `<dir>/bumpy_torus_<n>.off`, together with its cotangent matrix `L` (MatrixMarket,
//! `…_L.mtx`) and unit-area lumped mass (`…_M.txt`, one value per line), so that a peer solver
//! (e.g. `scipy.sparse.linalg.eigsh(L, k=100, M=diags(M), sigma=-0.01)`) runs on exactly the
//! same matrices.

use std::fmt::Write as _;
use std::hint::black_box;
use std::path::Path;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use shapeforest::mesh::Mesh;
use shapeforest::spectral::{compute_spectrum, cotan_laplacian, vertex_lumped_mass, SpectrumParams};
use shapeforest::synth::torus;

/// A torus whose tube radius carries smooth bumps: irregular enough to have a simple
/// spectrum, smooth enough to be a realistic surface.
fn bumpy_torus(nu: usize, nv: usize) -> Mesh {
    let mut m = torus(nu, nv, 1.0, 0.35);
    let tau = std::f64::consts::TAU;
    for i in 0..nu {
        let u = tau * i as f64 / nu as f64;
        for j in 0..nv {
            let v = tau * j as f64 / nv as f64;
            let r =
                0.35 * (1.0 + 0.15 * (5.0 * u).sin() * (3.0 * v).cos() + 0.05 * (11.0 * u + 2.0 * v).cos());
            let rr = 1.0 + r * v.cos();
            m.vertices[i * nv + j] = [rr * u.cos(), rr * u.sin(), r * v.sin()];
        }
    }
    m
}

fn write_off(mesh: &Mesh, path: &Path) -> std::io::Result<()> {
    let mut s = String::new();
    let _ = writeln!(s, "OFF\n{} {} 0", mesh.n_vertices(), mesh.n_faces());
    for p in &mesh.vertices {
        let _ = writeln!(s, "{:.17e} {:.17e} {:.17e}", p[0], p[1], p[2]);
    }
    for f in &mesh.faces {
        let _ = writeln!(s, "3 {} {} {}", f[0], f[1], f[2]);
    }
    std::fs::write(path, s)
}

fn dump(mesh: &Mesh, dir: &Path) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    let stem = dir.join(format!("bumpy_torus_{}", mesh.n_vertices()));
    write_off(mesh, &stem.with_extension("off"))?;
    let l = cotan_laplacian(mesh);
    let mut s = String::new();
    let entries: usize = (0..l.ncols()).map(|j| l.val_of_col(j).len()).sum();
    let _ =
        writeln!(s, "%%MatrixMarket matrix coordinate real general\n{} {} {}", l.nrows(), l.ncols(), entries);
    for j in 0..l.ncols() {
        for (&i, &v) in l.symbolic().row_idx_of_col_raw(j).iter().zip(l.val_of_col(j)) {
            let _ = writeln!(s, "{} {} {:.17e}", i + 1, j + 1, v);
        }
    }
    std::fs::write(format!("{}_L.mtx", stem.display()), s)?;
    let area = mesh.surface_area();
    let m: String = vertex_lumped_mass(mesh).iter().map(|x| format!("{:.17e}\n", x / area)).collect();
    std::fs::write(format!("{}_M.txt", stem.display()), m)
}

fn bench_spectrum(c: &mut Criterion) {
    let mut group = c.benchmark_group("laplace_beltrami_k100");
    group.sample_size(10);
    let params = SpectrumParams::new(100);
    for (nu, nv) in [(100, 50), (200, 100), (316, 158)] {
        let mesh = bumpy_torus(nu, nv);
        if let Ok(dir) = std::env::var("SHAPEFOREST_DUMP_DIR") {
            if let Err(e) = dump(&mesh, Path::new(&dir)) {
                eprintln!("could not dump the benchmark meshes to {dir}: {e}");
            }
        }
        group.throughput(Throughput::Elements(mesh.n_vertices() as u64));
        group.bench_with_input(BenchmarkId::from_parameter(mesh.n_vertices()), &mesh, |b, mesh| {
            b.iter(|| compute_spectrum(black_box(mesh), &params).expect("spectrum"))
        });
    }
    group.finish();
}

criterion_group!(benches, bench_spectrum);
criterion_main!(benches);
