//! Geodesic kernels on a ladder of torus sizes (~5K, ~20K, ~50K vertices): heat-method setup
//! (both factorisations), 50 heat distance maps solved as one block (and one at a time), fast
//! marching from one source (with and without the cached precomputation) and Dijkstra.
//!
//! Set `GEODESIC_BENCH_OFF_DIR=/some/dir` to also write the benchmark meshes there as OFF
//! files (`torus_<n>.off`), so a peer (e.g. potpourri3d's `MeshHeatMethodDistanceSolver`) can
//! be timed on exactly the same meshes.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use shapeforest::geodesic::{
    dijkstra_distances, fast_marching_distances, FastMarchingSolver, HeatMethodSolver, HeatParams,
};
use shapeforest::mesh::{write_mesh, Mesh};
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

/// One benchmark group over the mesh ladder: `prepare` runs once per mesh (untimed), `run` is
/// timed; throughput counts `per_vertex` elements per vertex.
fn ladder<'m, S, R>(
    c: &mut Criterion,
    name: &str,
    seconds: u64,
    per_vertex: usize,
    meshes: &'m [Mesh],
    prepare: impl Fn(&'m Mesh) -> S,
    run: impl Fn(&Mesh, &S) -> R,
) {
    let mut group = c.benchmark_group(name);
    group.sample_size(10).measurement_time(Duration::from_secs(seconds)).warm_up_time(Duration::from_secs(1));
    for m in meshes {
        let state = prepare(m);
        group.throughput(Throughput::Elements((m.n_vertices() * per_vertex) as u64));
        group.bench_with_input(BenchmarkId::from_parameter(m.n_vertices()), m, |b, m| {
            b.iter(|| black_box(run(black_box(m), &state)))
        });
    }
    group.finish();
}

fn heat_solver(m: &Mesh) -> HeatMethodSolver {
    HeatMethodSolver::new(m, HeatParams::default()).expect("solver")
}

fn bench_geodesic(c: &mut Criterion) {
    let meshes = meshes();
    if let Ok(dir) = std::env::var("GEODESIC_BENCH_OFF_DIR") {
        for m in &meshes {
            let path = std::path::Path::new(&dir).join(format!("torus_{}.off", m.n_vertices()));
            if let Err(e) = write_mesh(&path, m) {
                eprintln!("could not write {}: {e}", path.display());
            }
        }
    }

    ladder(c, "heat_setup", 4, 1, &meshes, |_| (), |m, _| heat_solver(m));
    ladder(
        c,
        "heat_50_sources",
        5,
        N_SOURCES,
        &meshes,
        |m| (heat_solver(m), sources(m.n_vertices())),
        |_, (solver, src)| solver.distances_from_many(src).expect("distances"),
    );
    ladder(
        c,
        "heat_50_sources_one_at_a_time",
        5,
        N_SOURCES,
        &meshes,
        |m| (heat_solver(m), sources(m.n_vertices())),
        |_, (solver, src)| {
            for &s in src {
                black_box(solver.distances_from(s).expect("distances"));
            }
        },
    );
    ladder(
        c,
        "fast_marching_one_source",
        3,
        1,
        &meshes,
        |_| (),
        |m, _| fast_marching_distances(m, &[0]).expect("distances"),
    );
    ladder(c, "fast_marching_query_cached", 3, 1, &meshes, FastMarchingSolver::new, |_, solver| {
        solver.distances_from(&[0]).expect("distances")
    });
    ladder(
        c,
        "dijkstra_one_source",
        3,
        1,
        &meshes,
        |_| (),
        |m, _| dijkstra_distances(m, &[0]).expect("distances"),
    );
}

criterion_group!(benches, bench_geodesic);
criterion_main!(benches);
