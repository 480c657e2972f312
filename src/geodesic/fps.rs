//! Farthest point sampling, Euclidean and geodesic.

use crate::mesh::{dot, sub, Mesh};

use super::exact::{dijkstra_min_update, FastMarchingSolver};
use super::topology::{check_sources, EdgeGraph};
use super::GeodesicError;

/// The distance that geodesic farthest point sampling maximises.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SamplingMetric {
    /// Shortest paths along edges (an upper bound of the geodesic distance); each new sample
    /// only revisits the vertices that become closer to it, so sampling is cheap.
    #[default]
    Dijkstra,
    /// First-order fast marching ([`super::fast_marching_distances`]), run in full from each
    /// new sample: more accurate, slower.
    FastMarching,
}

/// The default first sample: the vertex farthest from the mean of the vertex positions
/// (lowest index among ties).
///
/// ```
/// use shapeforest::{geodesic::farthest_from_centroid, mesh::Mesh};
/// let m = Mesh::new(vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 5.0, 0.0]], vec![[0, 1, 2]]).unwrap();
/// assert_eq!(farthest_from_centroid(&m), 2);
/// ```
pub fn farthest_from_centroid(mesh: &Mesh) -> usize {
    let n = mesh.n_vertices() as f64;
    let mut c = [0.0; 3];
    for p in &mesh.vertices {
        for d in 0..3 {
            c[d] += p[d] / n;
        }
    }
    argmax(mesh.vertices.iter().map(|&p| {
        let v = sub(p, c);
        dot(v, v)
    }))
}

/// Index of the largest value (first among ties; NaN never wins).
fn argmax(values: impl Iterator<Item = f64>) -> usize {
    let mut best = (0, f64::NEG_INFINITY);
    for (i, v) in values.enumerate() {
        if v > best.1 {
            best = (i, v);
        }
    }
    best.0
}

fn check_count(n: usize, mesh: &Mesh, start: Option<usize>) -> Result<usize, GeodesicError> {
    if n > mesh.n_vertices() {
        return Err(GeodesicError::TooManySamples { wanted: n, n_vertices: mesh.n_vertices() });
    }
    match start {
        Some(s) => {
            check_sources(&[s], mesh.n_vertices())?;
            Ok(s)
        }
        None => Ok(farthest_from_centroid(mesh)),
    }
}

/// Greedy farthest point sampling in Euclidean distance (as in Rodolà et al. 2014): starting
/// from `start` (default [`farthest_from_centroid`]), each next sample is the vertex farthest
/// from all samples so far. Returns `n` distinct vertices in selection order (fewer only if
/// the mesh has fewer distinct positions than `n`: duplicates of a chosen point are never
/// picked, sampling stops instead). Deterministic: ties go to the lowest index.
///
/// ```
/// use shapeforest::geodesic::farthest_point_sampling_euclidean;
/// let grid = shapeforest::synth::grid_plane(5, 5, 1.0, 1.0);
/// let s = farthest_point_sampling_euclidean(&grid, 2, Some(0)).unwrap();
/// assert_eq!(s, vec![0, 24]); // opposite corners
/// ```
pub fn farthest_point_sampling_euclidean(
    mesh: &Mesh,
    n: usize,
    start: Option<usize>,
) -> Result<Vec<usize>, GeodesicError> {
    let first = check_count(n, mesh, start)?;
    let mut samples = Vec::with_capacity(n);
    if n == 0 {
        return Ok(samples);
    }
    let mut dist = vec![f64::INFINITY; mesh.n_vertices()];
    let mut next = first;
    while samples.len() < n {
        samples.push(next);
        let q = mesh.vertices[next];
        for (d, &p) in dist.iter_mut().zip(&mesh.vertices) {
            let v = sub(p, q);
            *d = d.min(dot(v, v));
        }
        next = argmax(dist.iter().copied());
        if !(dist[next] > 0.0) {
            break;
        }
    }
    Ok(samples)
}

/// Greedy farthest point sampling in geodesic distance: like
/// [`farthest_point_sampling_euclidean`], with the distance field to the samples so far kept
/// and min-updated by `metric` from each new sample. Vertices unreachable from the start are
/// never picked (sampling stops early if only those are left).
///
/// ```
/// use shapeforest::geodesic::{farthest_point_sampling_geodesic, SamplingMetric};
/// let grid = shapeforest::synth::grid_plane(5, 5, 1.0, 1.0);
/// let s = farthest_point_sampling_geodesic(&grid, 3, Some(0), SamplingMetric::Dijkstra).unwrap();
/// assert_eq!(s.len(), 3);
/// assert_eq!(s[1], 24);
/// ```
pub fn farthest_point_sampling_geodesic(
    mesh: &Mesh,
    n: usize,
    start: Option<usize>,
    metric: SamplingMetric,
) -> Result<Vec<usize>, GeodesicError> {
    let first = check_count(n, mesh, start)?;
    let (_field, samples) = geodesic_sampling_with_field(mesh, n, first, metric);
    Ok(samples)
}

/// The sampling loop; returns the final distance-to-samples field as well (used by tests to
/// measure the covering radius).
pub(crate) fn geodesic_sampling_with_field(
    mesh: &Mesh,
    n: usize,
    first: usize,
    metric: SamplingMetric,
) -> (Vec<f64>, Vec<usize>) {
    let mut samples = Vec::with_capacity(n);
    let mut dist = vec![f64::INFINITY; mesh.n_vertices()];
    if n == 0 {
        return (dist, samples);
    }
    let graph = (metric == SamplingMetric::Dijkstra).then(|| EdgeGraph::new(mesh));
    let marcher = (metric == SamplingMetric::FastMarching).then(|| FastMarchingSolver::new(mesh));
    let mut next = first;
    while samples.len() < n {
        samples.push(next);
        if let Some(graph) = &graph {
            dijkstra_min_update(graph, &mut dist, next);
        }
        if let Some(marcher) = &marcher {
            for (d, f) in dist.iter_mut().zip(marcher.run(&[next])) {
                *d = d.min(f);
            }
        }
        next = argmax(dist.iter().map(|&d| if d.is_finite() { d } else { f64::NEG_INFINITY }));
        if !(dist[next] > 0.0 && dist[next].is_finite()) {
            break;
        }
    }
    (dist, samples)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn too_many_samples_is_an_error() {
        let m = crate::synth::grid_plane(3, 3, 1.0, 1.0);
        assert!(matches!(
            farthest_point_sampling_euclidean(&m, 10, None),
            Err(GeodesicError::TooManySamples { wanted: 10, n_vertices: 9 })
        ));
        assert!(farthest_point_sampling_geodesic(&m, 2, Some(99), SamplingMetric::Dijkstra).is_err());
    }

    #[test]
    fn zero_samples_is_empty() {
        let m = crate::synth::grid_plane(3, 3, 1.0, 1.0);
        assert!(farthest_point_sampling_euclidean(&m, 0, None).unwrap().is_empty());
    }
}
