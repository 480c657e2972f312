//! How the evaluation's heat-method distances compare with fast marching and edge paths at
//! the short range where a map's errors mostly lie (a few edge lengths), on one mesh.
//!
//! `cargo run --release --example distance_floor -- MESH [SOURCES]`: for SOURCES seeded
//! vertices, the mean heat-method distance (t = h²), fast-marching distance and Dijkstra
//! distance to the vertices within 1, 2 and 3 rings, in units of √area.

use anyhow::{Context, Result};
use shapeforest::{
    geodesic::{dijkstra_distances, fast_marching_distances, HeatMethodSolver, HeatParams},
    mesh::read_mesh,
};

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let path = args.next().context("usage: distance_floor MESH [SOURCES]")?;
    let n_sources: usize = args.next().map_or(Ok(100), |s| s.parse())?;
    let mesh = read_mesh(&path)?;
    let n = mesh.n_vertices();
    let sa = mesh.surface_area().sqrt();
    let mut nb = vec![Vec::new(); n];
    for f in &mesh.faces {
        for (a, b) in [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])] {
            nb[a].push(b);
            nb[b].push(a);
        }
    }
    let heat = HeatMethodSolver::new(&mesh, HeatParams::default())?;
    let sources: Vec<usize> = (0..n_sources).map(|i| (i * 7919) % n).collect();
    let fields = heat.distances_from_many(&sources)?;
    // Per ring: sums of heat, fast marching, Dijkstra; count.
    let mut sums = [[0.0f64; 4]; 4];
    for (j, &s) in sources.iter().enumerate() {
        let fmm = fast_marching_distances(&mesh, &[s])?;
        let dij = dijkstra_distances(&mesh, &[s])?;
        let mut ring = vec![usize::MAX; n];
        ring[s] = 0;
        let mut frontier = vec![s];
        for r in 1..=3 {
            let mut next = Vec::new();
            for &u in &frontier {
                for &w in &nb[u] {
                    if ring[w] == usize::MAX {
                        ring[w] = r;
                        next.push(w);
                    }
                }
            }
            frontier = next;
        }
        for v in 0..n {
            if ring[v] <= 3 {
                let r = ring[v];
                sums[r][0] += fields[(v, j)] / sa;
                sums[r][1] += fmm[v] / sa;
                sums[r][2] += dij[v] / sa;
                sums[r][3] += 1.0;
            }
        }
    }
    println!("{path}: {n} vertices, {n_sources} sources; mean distance ×100 (units of √area)");
    println!("ring | heat (t = h²) | fast marching | Dijkstra | points");
    for (r, s) in sums.iter().enumerate() {
        let c = s[3].max(1.0);
        println!(
            "{r} | {:.3} | {:.3} | {:.3} | {}",
            100.0 * s[0] / c,
            100.0 * s[1] / c,
            100.0 * s[2] / c,
            s[3]
        );
    }
    Ok(())
}
