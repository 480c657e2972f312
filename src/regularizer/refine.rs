//! The ZoomOut refinement of the regulariser's map (step 8): spectral upsampling from the
//! anchor-grown map, on farthest-point samples of both shapes for large meshes (see
//! [`crate::fmap::zoomout_on_samples`]).

use super::{PreparedShape, RegularizerError as Error, ZoomOutParams};
use crate::{
    fmap::{point_to_point_in_cells, zoomout_on_samples, SampleCells, ZoomOutSchedule},
    geodesic::{dijkstra_nearest_source, farthest_point_sampling_euclidean},
    mesh::Mesh,
};

/// `n` Euclidean farthest-point samples of `mesh` (every vertex when it has at most `n`) and
/// their cells along the mesh's edges; a vertex no sample reaches (another component) joins
/// the Euclidean-nearest sample.
pub fn sample_cells(mesh: &Mesh, n: usize) -> Result<SampleCells, Error> {
    let nv = mesh.n_vertices();
    let edges = || mesh.faces.iter().flat_map(|f| [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])]);
    if nv <= n {
        return Ok(SampleCells::new((0..nv).collect(), (0..nv as u32).collect(), edges())?);
    }
    let samples = farthest_point_sampling_euclidean(mesh, n, None)?;
    let (_, nearest) = dijkstra_nearest_source(mesh, &samples)?;
    let d2 = |a: [f64; 3], b: [f64; 3]| (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2);
    let cell_of = nearest
        .iter()
        .enumerate()
        .map(|(v, &c)| {
            if c != usize::MAX {
                return c as u32;
            }
            let p = mesh.vertices[v];
            (0..samples.len())
                .min_by(|&i, &j| d2(p, mesh.vertices[samples[i]]).total_cmp(&d2(p, mesh.vertices[samples[j]])))
                .unwrap_or(0) as u32
        })
        .collect();
    Ok(SampleCells::new(samples, cell_of, edges())?)
}

/// ZoomOut of `map` (test vertex → reference vertex) by `params`, read back on every test vertex.
pub fn refine_zoomout(
    test: &PreparedShape,
    reference: &PreparedShape,
    map: &[usize],
    params: &ZoomOutParams,
) -> Result<Vec<usize>, Error> {
    let k_final = params.k_final.min(test.spectrum.k()).min(reference.spectrum.k());
    let schedule = ZoomOutSchedule { k_start: params.k_start.min(k_final), k_final, step: params.step };
    let test_cells = sample_cells(&test.mesh, params.samples)?;
    let reference_cells = sample_cells(&reference.mesh, params.samples)?;
    let c = zoomout_on_samples(&test.spectrum, &test_cells, &reference.spectrum, &reference_cells, map, schedule)?;
    Ok(point_to_point_in_cells(&test.spectrum, &reference.spectrum, &reference_cells, c.as_ref())?)
}
