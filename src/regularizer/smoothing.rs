//! Smoothing of the final placement (iterated conditional modes over mesh neighbours).

use super::*;

/// Smoothing of the final placement (iterated conditional modes): each test vertex takes the
/// candidate minimising its anchor cost plus `smoothness` times the mean Euclidean distance
/// (√area units) on the reference to where its mesh neighbours are placed, all vertices at
/// once, until nothing changes or `smoothing_rounds` have run. It removes isolated
/// misplacements that the anchors alone cannot tell apart.
pub(super) fn smooth_placement(
    test: &Mesh,
    reference: &Mesh,
    ref_sqrt_area: f64,
    table: &[impl AsRef<[(u32, f32)]> + Sync],
    mut map: Vec<usize>,
    p: &AnchorGrowthParams,
) -> Vec<usize> {
    use rayon::prelude::*;
    let n = test.n_vertices();
    let (degree, nbrs) = crate::mesh::face_neighbour_lists(&test.faces, n);
    let pos = &reference.vertices;
    let scale = p.smoothness / ref_sqrt_area.max(f64::MIN_POSITIVE);
    // Each vertex's candidates by anchor cost (then table order): the spread term is never
    // negative, so a candidate whose anchor cost alone exceeds the best total so far cannot win,
    // nor can any after it. The same choice as trying them all in table order.
    let order: Vec<Vec<(f32, u32, u32)>> = table
        .par_iter()
        .map(|t| {
            let mut o: Vec<(f32, u32, u32)> =
                t.as_ref().iter().enumerate().map(|(i, &(r, c))| (c, i as u32, r)).collect();
            o.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            o
        })
        .collect();
    // A vertex's choice depends only on where its neighbours are placed: after the first sweep,
    // only the vertices next to one that moved can change.
    let mut dirty = vec![true; n];
    for _ in 0..p.smoothing_rounds {
        let next: Vec<usize> = (0..n)
            .into_par_iter()
            .map(|m| {
                let nb = &nbrs[degree[m]..degree[m + 1]];
                if !dirty[m] || order[m].len() < 2 || nb.is_empty() {
                    return map[m];
                }
                let inv = scale / nb.len() as f64;
                let mut best = (f64::INFINITY, u32::MAX, map[m]);
                for &(c, i, r) in &order[m] {
                    if c as f64 > best.0 {
                        break;
                    }
                    let x = pos[r as usize];
                    let spread: f64 = nb
                        .iter()
                        .map(|&q| {
                            let y = pos[map[q]];
                            ((x[0] - y[0]).powi(2) + (x[1] - y[1]).powi(2) + (x[2] - y[2]).powi(2)).sqrt()
                        })
                        .sum();
                    let total = c as f64 + inv * spread;
                    if total < best.0 || (total == best.0 && i < best.1) {
                        best = (total, i, r as usize);
                    }
                }
                best.2
            })
            .collect();
        let moved: Vec<usize> = (0..n).filter(|&m| next[m] != map[m]).collect();
        map = next;
        if moved.is_empty() {
            break;
        }
        dirty.iter_mut().for_each(|d| *d = false);
        for &m in &moved {
            for &q in &nbrs[degree[m]..degree[m + 1]] {
                dirty[q] = true;
            }
        }
    }
    map
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::{grid_plane, icosphere};

    /// The smoothing as first written: every candidate of every vertex, every sweep.
    fn every_candidate(
        test: &Mesh,
        reference: &Mesh,
        sqrt_area: f64,
        table: &[Vec<(u32, f32)>],
        mut map: Vec<usize>,
        p: &AnchorGrowthParams,
    ) -> Vec<usize> {
        let n = test.n_vertices();
        let (degree, nbrs) = crate::mesh::face_neighbour_lists(&test.faces, n);
        let scale = p.smoothness / sqrt_area;
        for _ in 0..p.smoothing_rounds {
            let next: Vec<usize> = (0..n)
                .map(|m| {
                    let nb = &nbrs[degree[m]..degree[m + 1]];
                    if table[m].len() < 2 || nb.is_empty() {
                        return map[m];
                    }
                    let inv = scale / nb.len() as f64;
                    let mut best = (f64::INFINITY, map[m]);
                    for &(r, c) in &table[m] {
                        let x = reference.vertices[r as usize];
                        let spread: f64 = nb
                            .iter()
                            .map(|&q| {
                                let y = reference.vertices[map[q]];
                                ((x[0] - y[0]).powi(2) + (x[1] - y[1]).powi(2) + (x[2] - y[2]).powi(2)).sqrt()
                            })
                            .sum();
                        if c as f64 + inv * spread < best.0 {
                            best = (c as f64 + inv * spread, r as usize);
                        }
                    }
                    best.1
                })
                .collect();
            let changed = next != map;
            map = next;
            if !changed {
                break;
            }
        }
        map
    }

    #[test]
    fn skipping_hopeless_candidates_and_settled_vertices_changes_no_choice() {
        // A noisy placement of a grid onto a sphere, 40 candidates per vertex with costs of
        // the spread's size, ties among them included.
        let test = grid_plane(12, 12, 1.0, 1.0);
        let reference = icosphere(3, 1.0);
        let (n, n_r) = (test.n_vertices(), reference.n_vertices());
        let mut state = 12345u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 33) as usize
        };
        let table: Vec<Vec<(u32, f32)>> = (0..n)
            .map(|_| (0..40).map(|_| ((next() % n_r) as u32, (next() % 8) as f32 * 0.05)).collect())
            .collect();
        let start: Vec<usize> = table.iter().map(|t| t[0].0 as usize).collect();
        for smoothness in [0.5, 2.0, 8.0] {
            let p = AnchorGrowthParams { smoothness, smoothing_rounds: 10, ..Default::default() };
            let fast = smooth_placement(&test, &reference, 2.0, &table, start.clone(), &p);
            let plain = every_candidate(&test, &reference, 2.0, &table, start.clone(), &p);
            assert_eq!(fast, plain, "smoothness {smoothness}");
            assert_ne!(fast, start, "smoothness {smoothness}: the smoothing moved nothing");
        }
    }
}
