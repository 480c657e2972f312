//! Geodesic kernels on a ladder of torus sizes (~5K, ~20K, ~50K vertices): heat-method setup
//! (both factorisations), 50 heat distance maps solved as one block (and one at a time), fast
//! marching from one source (with and without the cached precomputation) and Dijkstra.
//!
//! Set `GEODESIC_BENCH_OFF_DIR=/some/dir` to also write the benchmark meshes there as OFF
//! files (`torus_<n>.off`), so a peer (e.g. potpourri3d's `MeshHeatMethodDistanceSolver`) can
//! be timed on exactly the same meshes.

use std::hint::black_box;
use std::io::Write;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use shapeforest::geodesic::{
    dijkstra_distances, fast_marching_distances, FastMarchingSolver, HeatMethodSolver, HeatParams,
};
use shapeforest::mesh::Mesh;
use shapeforest::synth::torus;

/// (nu, nv) of tori with ~5K, ~20K and ~50K vertices.
const SIZES: [(usize, usize); 3] = [(100, 50), (200, 100), (316, 158)];
const N_SOURCES: usize = 50;

fn meshes() -> Vec<Mesh> {
    SIZES.iter().map(|&(nu, nv)| torus(nu, nv, 2.0, 0.7)).collect()
}

/// 50 sources spread evenly over the vertex indices.
fn sources(n: usize) -> Vec<usize> {
    (0..N_SOURCES).map(|i| i * n / N_SOURCES).collect()
}

fn write_off(mesh: &Mesh, path: &std::path::Path) -> std::io::Result<()> {
    let mut w = std::io::BufWriter::new(std::fs::File::create(path)?);
    writeln!(w, "OFF\n{} {} 0", mesh.n_vertices(), mesh.n_faces())?;
    for p in &mesh.vertices {
        writeln!(w, "{:.17e} {:.17e} {:.17e}", p[0], p[1], p[2])?;
    }
    for f in &mesh.faces {
        writeln!(w, "3 {} {} {}", f[0], f[1], f[2])?;
    }
    w.flush()
}

fn bench_geodesic(c: &mut Criterion) {
    let meshes = meshes();
    if let Ok(dir) = std::env::var("GEODESIC_BENCH_OFF_DIR") {
        for m in &meshes {
            let path = std::path::Path::new(&dir).join(format!("torus_{}.off", m.n_vertices()));
            if let Err(e) = write_off(m, &path) {
                eprintln!("could not write {}: {e}", path.display());
            }
        }
    }

    let mut group = c.benchmark_group("heat_setup");
    group.sample_size(10).measurement_time(Duration::from_secs(4)).warm_up_time(Duration::from_secs(1));
    for m in &meshes {
        group.throughput(Throughput::Elements(m.n_vertices() as u64));
        group.bench_with_input(BenchmarkId::from_parameter(m.n_vertices()), m, |b, m| {
            b.iter(|| HeatMethodSolver::new(black_box(m), HeatParams::default()).expect("solver"))
        });
    }
    group.finish();

    let mut group = c.benchmark_group("heat_50_sources");
    group.sample_size(10).measurement_time(Duration::from_secs(5)).warm_up_time(Duration::from_secs(1));
    for m in &meshes {
        let solver = HeatMethodSolver::new(m, HeatParams::default()).expect("solver");
        let src = sources(m.n_vertices());
        group.throughput(Throughput::Elements((m.n_vertices() * N_SOURCES) as u64));
        group.bench_with_input(BenchmarkId::from_parameter(m.n_vertices()), &src, |b, src| {
            b.iter(|| solver.distances_from_many(black_box(src)).expect("distances"))
        });
    }
    group.finish();

    let mut group = c.benchmark_group("heat_50_sources_one_at_a_time");
    group.sample_size(10).measurement_time(Duration::from_secs(5)).warm_up_time(Duration::from_secs(1));
    for m in &meshes {
        let solver = HeatMethodSolver::new(m, HeatParams::default()).expect("solver");
        let src = sources(m.n_vertices());
        group.throughput(Throughput::Elements((m.n_vertices() * N_SOURCES) as u64));
        group.bench_with_input(BenchmarkId::from_parameter(m.n_vertices()), &src, |b, src| {
            b.iter(|| {
                for &s in src {
                    black_box(solver.distances_from(s).expect("distances"));
                }
            })
        });
    }
    group.finish();

    let mut group = c.benchmark_group("fast_marching_one_source");
    group.sample_size(10).measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_secs(1));
    for m in &meshes {
        group.throughput(Throughput::Elements(m.n_vertices() as u64));
        group.bench_with_input(BenchmarkId::from_parameter(m.n_vertices()), m, |b, m| {
            b.iter(|| fast_marching_distances(black_box(m), &[0]).expect("distances"))
        });
    }
    group.finish();

    let mut group = c.benchmark_group("fast_marching_query_cached");
    group.sample_size(10).measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_secs(1));
    for m in &meshes {
        let solver = FastMarchingSolver::new(m);
        group.throughput(Throughput::Elements(m.n_vertices() as u64));
        group.bench_with_input(BenchmarkId::from_parameter(m.n_vertices()), m, |b, _| {
            b.iter(|| solver.distances_from(black_box(&[0])).expect("distances"))
        });
    }
    group.finish();

    let mut group = c.benchmark_group("dijkstra_one_source");
    group.sample_size(10).measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_secs(1));
    for m in &meshes {
        group.throughput(Throughput::Elements(m.n_vertices() as u64));
        group.bench_with_input(BenchmarkId::from_parameter(m.n_vertices()), m, |b, m| {
            b.iter(|| dijkstra_distances(black_box(m), &[0]).expect("distances"))
        });
    }
    group.finish();
}

criterion_group!(benches, bench_geodesic);
criterion_main!(benches);
