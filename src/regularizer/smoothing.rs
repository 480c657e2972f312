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
    table: &[Vec<(u32, f32)>],
    mut map: Vec<usize>,
    p: &AnchorGrowthParams,
) -> Vec<usize> {
    use rayon::prelude::*;
    let n = test.n_vertices();
    let (degree, nbrs) = crate::mesh::face_neighbour_lists(&test.faces, n);
    let pos = &reference.vertices;
    let scale = p.smoothness / ref_sqrt_area.max(f64::MIN_POSITIVE);
    for _ in 0..p.smoothing_rounds {
        let next: Vec<usize> = (0..n)
            .into_par_iter()
            .map(|m| {
                let nb = &nbrs[degree[m]..degree[m + 1]];
                if table[m].len() < 2 || nb.is_empty() {
                    return map[m];
                }
                let inv = scale / nb.len() as f64;
                let mut best = (f64::INFINITY, map[m]);
                for &(r, c) in &table[m] {
                    let x = pos[r as usize];
                    let spread: f64 = nb
                        .iter()
                        .map(|&q| {
                            let y = pos[map[q]];
                            ((x[0] - y[0]).powi(2) + (x[1] - y[1]).powi(2) + (x[2] - y[2]).powi(2)).sqrt()
                        })
                        .sum();
                    let total = c as f64 + inv * spread;
                    if total < best.0 {
                        best = (total, r as usize);
                    }
                }
                best.1
            })
            .collect();
        let changed = next.iter().zip(&map).any(|(a, b)| a != b);
        map = next;
        if !changed {
            break;
        }
    }
    map
}
