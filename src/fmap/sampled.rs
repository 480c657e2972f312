//! ZoomOut on samples of both shapes, with the final point map on every vertex.
//!
//! ZoomOut (Melzi et al. 2019) alternates a point map read from the functional map and a
//! functional map one step larger fitted to that point map. Done on every vertex it costs a
//! nearest-neighbour search of `n_M × n_R` rows per step; here the steps run on farthest-point
//! samples of both shapes (the least-squares fit weighted by each test sample's share of the
//! area), and only the final functional map is read back on every test vertex: among the
//! reference samples first, then among the reference vertices of the winning sample's cell and
//! its neighbouring cells ([`SampleCells`]). With every vertex a sample, this is ZoomOut exactly.

use faer::{linalg::matmul::matmul, Accum, Mat, MatRef, Par, Side};
use rayon::prelude::*;

use super::{
    basis, check_basis, mapped_reference_rows, nearest_rows_in, nearest_rows_single, single,
    squared_distance, FmapError, Real, RowMajor,
};
use crate::spectral::Spectrum;

/// Samples of a shape and the cells they split it into: every vertex belongs to the cell of its
/// nearest sample (e.g. along the mesh's edges), and two cells are neighbours when a mesh edge
/// joins them. Built by mesh-aware code (see `regularizer`); plain data here.
#[derive(Clone, Debug, PartialEq)]
pub struct SampleCells {
    /// The sample vertices.
    pub samples: Vec<usize>,
    /// Cell (index into `samples`) of every vertex.
    pub cell_of: Vec<u32>,
    /// Vertices of cell `c`: `members[member_offsets[c]..member_offsets[c + 1]]`.
    pub member_offsets: Vec<usize>,
    /// See `member_offsets`.
    pub members: Vec<u32>,
    /// Cells neighbouring cell `c` (itself included):
    /// `neighbours[neighbour_offsets[c]..neighbour_offsets[c + 1]]`.
    pub neighbour_offsets: Vec<usize>,
    /// See `neighbour_offsets`.
    pub neighbours: Vec<u32>,
}

impl SampleCells {
    /// Cells from `samples`, the nearest sample of every vertex (`cell_of`, an index into
    /// `samples`) and the shape's edges (pairs of vertices).
    ///
    /// ```
    /// use shapeforest::fmap::SampleCells;
    /// // A path 0 - 1 - 2 - 3 with samples 0 and 3: cells {0, 1} and {2, 3}, neighbours.
    /// let cells = SampleCells::new(vec![0, 3], vec![0, 0, 1, 1], [(0, 1), (1, 2), (2, 3)]).unwrap();
    /// assert_eq!(cells.members_of(1), &[2, 3]);
    /// assert_eq!(cells.neighbours_of(0), &[0, 1]);
    /// ```
    pub fn new(
        samples: Vec<usize>,
        cell_of: Vec<u32>,
        edges: impl IntoIterator<Item = (usize, usize)>,
    ) -> Result<Self, FmapError> {
        let ns = samples.len();
        let n = cell_of.len();
        if ns == 0 {
            return Err(FmapError::InvalidParameter { name: "samples", reason: "no samples".into() });
        }
        if let Some(&c) = cell_of.iter().find(|&&c| c as usize >= ns) {
            return Err(FmapError::SizeMismatch(format!("cell {c} named, there are {ns} samples")));
        }
        if let Some(&s) = samples.iter().find(|&&s| s >= n) {
            return Err(FmapError::SizeMismatch(format!("sample vertex {s}, the shape has {n} vertices")));
        }
        let mut member_offsets = vec![0usize; ns + 1];
        for &c in &cell_of {
            member_offsets[c as usize + 1] += 1;
        }
        for c in 0..ns {
            member_offsets[c + 1] += member_offsets[c];
        }
        let mut fill = member_offsets.clone();
        let mut members = vec![0u32; n];
        for (v, &c) in cell_of.iter().enumerate() {
            members[fill[c as usize]] = v as u32;
            fill[c as usize] += 1;
        }
        let mut pairs: Vec<(u32, u32)> = (0..ns as u32).map(|c| (c, c)).collect();
        for (a, b) in edges {
            if a >= n || b >= n {
                return Err(FmapError::SizeMismatch(format!("edge ({a}, {b}) on a shape of {n} vertices")));
            }
            let (ca, cb) = (cell_of[a], cell_of[b]);
            if ca != cb {
                pairs.push((ca, cb));
                pairs.push((cb, ca));
            }
        }
        pairs.sort_unstable();
        pairs.dedup();
        let mut neighbour_offsets = vec![0usize; ns + 1];
        for &(c, _) in &pairs {
            neighbour_offsets[c as usize + 1] += 1;
        }
        for c in 0..ns {
            neighbour_offsets[c + 1] += neighbour_offsets[c];
        }
        let neighbours = pairs.into_iter().map(|(_, d)| d).collect();
        Ok(Self { samples, cell_of, member_offsets, members, neighbour_offsets, neighbours })
    }

    /// Number of vertices of the shape.
    pub fn n_vertices(&self) -> usize {
        self.cell_of.len()
    }

    /// The vertices of cell `c`.
    pub fn members_of(&self, c: usize) -> &[u32] {
        &self.members[self.member_offsets[c]..self.member_offsets[c + 1]]
    }

    /// The cells next to cell `c`, itself included.
    pub fn neighbours_of(&self, c: usize) -> &[u32] {
        &self.neighbours[self.neighbour_offsets[c]..self.neighbour_offsets[c + 1]]
    }

    /// The area (from the lumped `mass` of every vertex) of each cell.
    pub fn cell_areas(&self, mass: &[f64]) -> Vec<f64> {
        (0..self.samples.len()).map(|c| self.members_of(c).iter().map(|&v| mass[v as usize]).sum()).collect()
    }
}

/// For every cell of a [`SampleCells`], the cells within some radius of it (itself included), as
/// compressed rows. ZoomOut restricted by them moves a vertex's image only within the ball around
/// where the starting map put it, so that the refinement sharpens the map without drifting to a
/// mirror image or another limb.
#[derive(Clone, Debug, PartialEq)]
pub struct CellBalls {
    /// Cells of ball `c`: `cells[offsets[c]..offsets[c + 1]]`.
    pub offsets: Vec<usize>,
    /// See `offsets`.
    pub cells: Vec<u32>,
}

impl CellBalls {
    /// The cells of the ball around cell `c`.
    pub fn of(&self, c: usize) -> &[u32] {
        &self.cells[self.offsets[c]..self.offsets[c + 1]]
    }

    /// Number of balls (the cells they are centred on).
    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Whether there are no balls.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// The ZoomOut schedule: from `k_start` basis functions to `k_final`, `step` at a time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ZoomOutSchedule {
    /// First basis size (the map's functional map is fitted at this size).
    pub k_start: usize,
    /// Last basis size.
    pub k_final: usize,
    /// Basis functions added per step.
    pub step: usize,
}

impl ZoomOutSchedule {
    /// Checks the steps alone: `1 ≤ k_start ≤ k_final`, `step ≥ 1`.
    pub(super) fn check_steps(&self) -> Result<(), FmapError> {
        if self.step == 0 || self.k_start == 0 || self.k_start > self.k_final {
            return Err(FmapError::InvalidParameter {
                name: "zoomout",
                reason: format!(
                    "needs 1 ≤ k_start ≤ k_final and step ≥ 1, got {}, {}, {}",
                    self.k_start, self.k_final, self.step
                ),
            });
        }
        Ok(())
    }

    fn check(&self, test: &Spectrum, reference: &Spectrum) -> Result<(), FmapError> {
        self.check_steps()?;
        check_basis("test", test, self.k_final)?;
        check_basis("reference", reference, self.k_final)
    }
}

/// Checks that a map of the test shape and the cells of both shapes have the shapes' sizes.
pub(super) fn check_sizes(
    test: &Spectrum,
    test_cells: &SampleCells,
    reference: &Spectrum,
    reference_cells: &SampleCells,
    map: &[usize],
) -> Result<(), FmapError> {
    if map.len() != test.n_vertices || test_cells.n_vertices() != test.n_vertices {
        return Err(FmapError::SizeMismatch(format!(
            "a map of {} and cells of {} vertices for a test shape of {}",
            map.len(),
            test_cells.n_vertices(),
            test.n_vertices
        )));
    }
    if reference_cells.n_vertices() != reference.n_vertices {
        return Err(FmapError::SizeMismatch(format!(
            "cells of {} vertices for a reference of {}",
            reference_cells.n_vertices(),
            reference.n_vertices
        )));
    }
    Ok(())
}

/// The rows `vertices` of the first `k` basis functions of `s` (`|vertices| × k`).
pub(super) fn basis_rows(s: &Spectrum, vertices: &[usize], k: usize) -> Mat<f64> {
    let phi = basis(s, k);
    Mat::from_fn(vertices.len(), k, |i, j| phi[(vertices[i], j)])
}

/// The area-weighted least-squares fit of functional maps on the samples of a test shape, shared
/// by every step of a ZoomOut: `fit(k_m, k_r, target)` is the `k_m × k_r` matrix `C` minimising
/// `Σ_i w_i |Φ[i, :k_m] C − target_i|²` (`Φ` the samples' basis rows, `w_i` their cells' areas,
/// `target_i` the `k_r` reference basis values of sample `i`'s image). The weighted Gram matrix
/// is formed once at the largest size; its leading blocks serve every smaller one.
pub(super) struct SampledFit {
    /// `w_i Φ[i, j]`.
    weighted: Mat<f64>,
    /// `Φᵀ W Φ`.
    gram: Mat<f64>,
}

impl SampledFit {
    /// The fit for the samples' basis rows `phi` (one row per sample) and their `weights`.
    pub(super) fn new(phi: MatRef<'_, f64>, weights: &[f64]) -> Self {
        let weighted = Mat::from_fn(phi.nrows(), phi.ncols(), |i, j| weights[i] * phi[(i, j)]);
        let mut gram = Mat::<f64>::zeros(phi.ncols(), phi.ncols());
        matmul(gram.as_mut(), Accum::Replace, weighted.transpose(), phi, 1.0, Par::rayon(0));
        Self { weighted, gram }
    }

    /// The `k_m × k_r` map whose target row `i` has entries `target(i, j)`, `j < k_r`.
    pub(super) fn fit(
        &self,
        k_m: usize,
        k_r: usize,
        target: &dyn Fn(usize, usize) -> f64,
    ) -> Result<Mat<f64>, FmapError> {
        let n = self.weighted.nrows();
        let target = Mat::from_fn(n, k_r, target);
        let mut rhs = Mat::<f64>::zeros(k_m, k_r);
        matmul(
            rhs.as_mut(),
            Accum::Replace,
            self.weighted.subcols(0, k_m).transpose(),
            target.as_ref(),
            1.0,
            Par::Seq,
        );
        let llt = self.gram.subrows(0, k_m).subcols(0, k_m).to_owned().llt(Side::Lower).map_err(|_| {
            FmapError::InvalidParameter {
                name: "zoomout samples",
                reason: format!("{n} test samples are too few for {k_m} basis functions"),
            }
        })?;
        Ok(faer::linalg::solvers::Solve::solve(&llt, rhs.as_ref()))
    }
}

/// ZoomOut of the point map `map` (test vertex → reference vertex) run on the samples of
/// `test_cells` and `reference_cells`; returns the final `k_final × k_final` functional map
/// (pulling back from the reference, as everywhere in this module). Read it back on every test
/// vertex with [`point_to_point_in_cells`]. With `balls`, a test sample's image is searched only
/// among the reference samples of the ball around the cell of its image under `map`.
pub fn zoomout_on_samples(
    test: &Spectrum,
    test_cells: &SampleCells,
    reference: &Spectrum,
    reference_cells: &SampleCells,
    balls: Option<&CellBalls>,
    map: &[usize],
    schedule: ZoomOutSchedule,
) -> Result<Mat<f64>, FmapError> {
    schedule.check(test, reference)?;
    check_sizes(test, test_cells, reference, reference_cells, map)?;
    check_map(map, reference, balls, reference_cells)?;
    let kf = schedule.k_final;
    let phi_t = basis_rows(test, &test_cells.samples, kf);
    let phi_r = basis_rows(reference, &reference_cells.samples, kf);
    let fit = SampledFit::new(phi_t.as_ref(), &test_cells.cell_areas(&test.mass));
    // The map's own functional map at k_start, from every sample's image under `map`.
    let first: Vec<usize> = test_cells.samples.iter().map(|&s| map[s]).collect();
    let phi_ref = basis(reference, kf);
    let mut k = schedule.k_start;
    let mut c = fit.fit(k, k, &|i, j| phi_ref[(first[i], j)])?;
    loop {
        // Test samples onto reference samples: rows of Φ_t against rows of Φ_r Cᵀ.
        let points = mapped_reference_rows(phi_r.subcols(0, k), c.as_ref());
        let t = match balls {
            None => nearest_rows_single(phi_t.subcols(0, k), points.as_ref()),
            Some(b) => {
                nearest_among(&RowMajor::new(phi_t.subcols(0, k)), &RowMajor::new(points.as_ref()), |i| {
                    b.of(reference_cells.cell_of[first[i]] as usize)
                })
            }
        };
        let last = k == kf;
        k = (k + schedule.step).min(kf);
        c = fit.fit(k, k, &|i, j| phi_r[(t[i], j)])?;
        if last {
            return Ok(c);
        }
    }
}

/// The point map `T: M → R` of `c` (`k × k`) on every test vertex, read as ZoomOut reads it (the
/// row of `Φ_M` against the rows of `Φ_R Cᵀ`, see [`super::point_to_point_orthogonal`]), searched
/// among the reference samples first and then among the vertices of the nearest sample's cell
/// and its neighbouring cells. With `balls` and the starting `map`, the samples searched first
/// are those of the ball around the cell of the vertex's image under `map`. Computed in single
/// precision: where two reference vertices are equally near up to its rounding, either may be
/// returned.
pub fn point_to_point_in_cells(
    test: &Spectrum,
    reference: &Spectrum,
    reference_cells: &SampleCells,
    restrict: Option<(&CellBalls, &[usize])>,
    c: MatRef<'_, f64>,
) -> Result<Vec<usize>, FmapError> {
    let k = c.nrows();
    if c.ncols() != k {
        return Err(FmapError::SizeMismatch("the functional map must be square".into()));
    }
    check_basis("test", test, k)?;
    check_basis("reference", reference, k)?;
    if reference_cells.n_vertices() != reference.n_vertices {
        return Err(FmapError::SizeMismatch(format!(
            "cells of {} vertices for a reference of {}",
            reference_cells.n_vertices(),
            reference.n_vertices
        )));
    }
    // In single precision (twice the throughput of the product and the distances; the image
    // of a vertex changes only where two candidates are as near as single-precision rounding
    // tells apart): the rows of `Φ_R Cᵀ`, and the test rows searched among them.
    let points = mapped_reference_rows(single(basis(reference, k)).as_ref(), single(c).as_ref());
    let queries = single(basis(test, k));
    let sample_points =
        Mat::<f32>::from_fn(reference_cells.samples.len(), k, |i, j| points[(reference_cells.samples[i], j)]);
    let (points, query_rows) = (RowMajor::new(points.as_ref()), RowMajor::new(queries.as_ref()));
    let coarse = match restrict {
        None => nearest_rows_in(queries.as_ref(), sample_points.as_ref()),
        Some((balls, map)) => {
            if map.len() != test.n_vertices {
                return Err(FmapError::SizeMismatch(format!(
                    "a map of {} vertices for a test shape of {}",
                    map.len(),
                    test.n_vertices
                )));
            }
            check_map(map, reference, Some(balls), reference_cells)?;
            let sample_points = RowMajor::new(sample_points.as_ref());
            nearest_among(&query_rows, &sample_points, |m| balls.of(reference_cells.cell_of[map[m]] as usize))
        }
    };
    Ok(nearest_in_cell_rows(&query_rows, &points, reference_cells, &coarse))
}

/// For each query row `m`, the reference vertex whose row of `points` is nearest among the
/// vertices of cell `coarse[m]` and its neighbouring cells (the fine step of a point map read
/// back through [`SampleCells`]).
pub fn nearest_in_cells(
    queries: MatRef<'_, f64>,
    points: MatRef<'_, f64>,
    reference_cells: &SampleCells,
    coarse: &[usize],
) -> Vec<usize> {
    // Row-major copies: each distance reads two contiguous rows instead of one entry per
    // column of a column-major matrix (a cache miss each on large meshes).
    nearest_in_cell_rows(&RowMajor::new(queries), &RowMajor::new(points), reference_cells, coarse)
}

/// [`nearest_in_cells`] on rows already copied row-major, in either precision.
fn nearest_in_cell_rows<T: Real>(
    queries: &RowMajor<T>,
    points: &RowMajor<T>,
    reference_cells: &SampleCells,
    coarse: &[usize],
) -> Vec<usize> {
    let mut out = vec![0usize; queries.nrows()];
    out.par_iter_mut().enumerate().for_each(|(m, slot)| {
        let mut best = T::INFINITY;
        let q = queries.row(m);
        for &cell in reference_cells.neighbours_of(coarse[m]) {
            for &r in reference_cells.members_of(cell as usize) {
                let r = r as usize;
                let d = squared_distance(q, points.row(r));
                if d < best {
                    best = d;
                    *slot = r;
                }
            }
        }
    });
    out
}

/// Checks that `map` names reference vertices and that `balls` has one ball per cell.
pub(super) fn check_map(
    map: &[usize],
    reference: &Spectrum,
    balls: Option<&CellBalls>,
    reference_cells: &SampleCells,
) -> Result<(), FmapError> {
    if let Some(&r) = map.iter().find(|&&r| r >= reference.n_vertices) {
        return Err(FmapError::SizeMismatch(format!(
            "the map names reference vertex {r}, the reference has {}",
            reference.n_vertices
        )));
    }
    match balls {
        Some(b) if b.len() != reference_cells.samples.len() => Err(FmapError::SizeMismatch(format!(
            "{} balls for {} reference cells",
            b.len(),
            reference_cells.samples.len()
        ))),
        _ => Ok(()),
    }
}

/// For each row `i` of `queries`, the row of `points` nearest to it among `candidates(i)`
/// (the first candidate when all are equally far; row 0 when there are none).
fn nearest_among<'a, T: Real>(
    queries: &RowMajor<T>,
    points: &RowMajor<T>,
    candidates: impl Fn(usize) -> &'a [u32] + Sync,
) -> Vec<usize> {
    let mut out = vec![0usize; queries.nrows()];
    out.par_iter_mut().enumerate().for_each(|(i, slot)| {
        let mut best = T::INFINITY;
        let q = queries.row(i);
        for &p in candidates(i) {
            let p = p as usize;
            let d = squared_distance(q, points.row(p));
            if d < best {
                best = d;
                *slot = p;
            }
        }
    });
    out
}
