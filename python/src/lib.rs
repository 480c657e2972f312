//! Python bindings of shapeforest (`import shapeforest`): numpy in, numpy out.
//!
//! Conventions are those of the geometry tools people use in Python (potpourri3d,
//! robust_laplacian, trimesh, pyFM): vertices `(n, 3)` float64, faces `(m, 3)` integer,
//! 0-based. Every long call (spectra, training, prediction, matching, geodesics) releases the
//! GIL (`Python::detach`, PyO3's name for `allow_threads`). Errors raise
//! [`ShapeforestError`] (a `ValueError`) with the messages of the command-line tool.
//!
//! This file is glue only: every computation is the `shapeforest` crate's.

use std::{
    path::PathBuf,
    sync::{
        atomic::{AtomicUsize, Ordering},
        Arc,
    },
};

use ndarray::{Array1, Array2, ShapeBuilder};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::{create_exception, exceptions::PyValueError, prelude::*, types::PyDict};
use rayon::prelude::*;
use shapeforest::{
    descriptor::{heat_kernel_signature, wave_kernel_signature, HksParams, LocalParams, WksParams},
    eval,
    forest::{
        augmented_copies, labels_identity, reference_table, Augmentation, ModelReference, RandomForest,
        TrainingSet, TrainingShape,
    },
    geodesic::{HeatMethodSolver, HeatParams},
    mesh::{self, Mesh as CoreMesh},
    regularizer::{regularize, PreparedShape, RegularizerParams, ScanPart},
    spectral::{compute_spectrum, Spectrum as CoreSpectrum, SpectrumParams},
    synth, viz,
};

create_exception!(
    shapeforest,
    ShapeforestError,
    PyValueError,
    "An error of the shapeforest library (bad mesh, bad model file, failed solve); the message is the command-line tool's."
);

fn sf_err(e: impl std::fmt::Display) -> PyErr {
    ShapeforestError::new_err(e.to_string())
}

/// `context: error`, as the command-line tool prints a chained error.
fn ctx_err(context: String) -> impl FnOnce(shapeforest::Error) -> PyErr {
    move |e| ShapeforestError::new_err(format!("{context}: {e}"))
}

/// Converts any array-like to a contiguous numpy array of `dtype` (numpy's own conversion).
fn as_array<'py>(obj: &Bound<'py, PyAny>, dtype: &str) -> PyResult<Bound<'py, PyAny>> {
    let py = obj.py();
    let np = py.import("numpy")?;
    let kwargs = PyDict::new(py);
    kwargs.set_item("dtype", dtype)?;
    np.call_method("ascontiguousarray", (obj,), Some(&kwargs))
}

fn rows3<'py>(obj: &Bound<'py, PyAny>, dtype: &str, what: &str) -> PyResult<Bound<'py, PyAny>> {
    let arr = as_array(obj, dtype)?;
    let shape: Vec<usize> = arr.getattr("shape")?.extract()?;
    if shape.len() != 2 || shape[1] != 3 {
        return Err(PyValueError::new_err(format!("{what} must be an (n, 3) array, got shape {shape:?}")));
    }
    Ok(arr)
}

fn index_vector(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<i64>> {
    let arr = as_array(obj, "int64")?;
    let arr: PyReadonlyArray1<'_, i64> = arr
        .extract()
        .map_err(|_| PyValueError::new_err(format!("{what} must be a one-dimensional integer array")))?;
    Ok(arr.as_slice()?.to_vec())
}

fn vertex_indices(obj: &Bound<'_, PyAny>, n: usize, what: &str) -> PyResult<Vec<usize>> {
    index_vector(obj, what)?
        .into_iter()
        .enumerate()
        .map(|(i, v)| {
            usize::try_from(v).ok().filter(|&v| v < n).ok_or_else(|| {
                PyValueError::new_err(format!("{what}[{i}] = {v} is not a vertex (0 ≤ v < {n})"))
            })
        })
        .collect()
}

/// Column-major `n × k` data as a numpy array of shape `(n, k)`.
fn col_major<'py>(py: Python<'py>, data: Vec<f64>, n: usize, k: usize) -> Bound<'py, PyArray2<f64>> {
    Array2::from_shape_vec((n, k).f(), data).expect("n·k entries").into_pyarray(py)
}

fn mat_to_py<'py>(py: Python<'py>, m: faer::Mat<f64>) -> Bound<'py, PyArray2<f64>> {
    let (n, k) = (m.nrows(), m.ncols());
    let mut data = Vec::with_capacity(n * k);
    for j in 0..k {
        data.extend_from_slice(m.col(j).try_as_col_major().expect("faer columns are contiguous").as_slice());
    }
    col_major(py, data, n, k)
}

/// Progress reporting: `progress=True` writes `stage done/total` lines to `sys.stderr`; a
/// callable is called as `progress(stage, done, total)`. Called from worker threads, it takes
/// the GIL only for the report itself.
#[derive(Clone)]
struct Progress(Option<Arc<Py<PyAny>>>, bool);

impl Progress {
    fn from(obj: &Bound<'_, PyAny>) -> PyResult<Self> {
        if obj.is_callable() {
            return Ok(Self(Some(Arc::new(obj.clone().unbind())), false));
        }
        Ok(Self(None, obj.is_truthy()?))
    }

    fn report(&self, stage: &str, done: usize, total: usize) {
        if self.0.is_none() && !self.1 {
            return;
        }
        Python::attach(|py| {
            let r = match &self.0 {
                Some(f) => f.call1(py, (stage, done, total)).map(|_| ()),
                // On a terminal one line is rewritten in place; in a log, one line per report.
                None => py.import("sys").and_then(|sys| {
                    let err = sys.getattr("stderr")?;
                    let tty = err.call_method0("isatty").and_then(|t| t.is_truthy()).unwrap_or(false);
                    let line = match (tty, done >= total) {
                        (true, false) => format!("\r{stage}: {done}/{total}"),
                        (true, true) => format!("\r{stage}: {done}/{total}\n"),
                        (false, _) => format!("{stage}: {done}/{total}\n"),
                    };
                    err.call_method1("write", (line,))?;
                    err.call_method0("flush").map(|_| ())
                }),
            };
            if let Err(e) = r {
                e.write_unraisable(py, None);
            }
        });
    }
}

/// A triangle mesh: vertices `(n, 3)` float64 and faces `(m, 3)` integer (0-based).
///
/// `Mesh(vertices, faces)` checks what every algorithm relies on: at least one vertex and one
/// face (a point cloud is refused), finite coordinates, face indices in range, no face
/// repeating a vertex. Vertex order is kept as given: ground truth is by vertex index.
#[pyclass(name = "Mesh", module = "shapeforest", frozen, from_py_object)]
#[derive(Clone)]
struct PyMesh {
    inner: Arc<CoreMesh>,
    name: String,
}

#[pymethods]
impl PyMesh {
    #[new]
    #[pyo3(signature = (vertices, faces, name = None))]
    fn new(vertices: &Bound<'_, PyAny>, faces: &Bound<'_, PyAny>, name: Option<String>) -> PyResult<Self> {
        let v = rows3(vertices, "float64", "vertices")?;
        let v: PyReadonlyArray2<'_, f64> = v.extract()?;
        let f = rows3(faces, "int64", "faces")?;
        let f: PyReadonlyArray2<'_, i64> = f.extract()?;
        let verts: Vec<[f64; 3]> = v.as_slice()?.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let mut tris = Vec::with_capacity(f.shape()[0]);
        for (i, c) in f.as_slice()?.chunks_exact(3).enumerate() {
            let mut t = [0usize; 3];
            for (a, &x) in c.iter().enumerate() {
                t[a] = usize::try_from(x)
                    .map_err(|_| sf_err(format!("face {i} has a negative vertex index {x}")))?;
            }
            tris.push(t);
        }
        let mesh = CoreMesh::new(verts, tris).map_err(sf_err)?;
        Ok(Self { inner: Arc::new(mesh), name: name.unwrap_or_else(|| "mesh".into()) })
    }

    /// Vertex positions, `(n, 3)` float64 (a copy).
    #[getter]
    fn vertices<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let flat: Vec<f64> = self.inner.vertices.iter().flatten().copied().collect();
        Array2::from_shape_vec((self.inner.n_vertices(), 3), flat).expect("n·3").into_pyarray(py)
    }

    /// Triangles, `(m, 3)` int64, 0-based (a copy).
    #[getter]
    fn faces<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<i64>> {
        let flat: Vec<i64> = self.inner.faces.iter().flatten().map(|&i| i as i64).collect();
        Array2::from_shape_vec((self.inner.n_faces(), 3), flat).expect("m·3").into_pyarray(py)
    }

    /// The name used in messages (the file stem for a mesh read from a file).
    #[getter]
    fn name(&self) -> String {
        self.name.clone()
    }

    /// Number of vertices.
    #[getter]
    fn n_vertices(&self) -> usize {
        self.inner.n_vertices()
    }

    /// Number of faces.
    #[getter]
    fn n_faces(&self) -> usize {
        self.inner.n_faces()
    }

    /// Total surface area, in the mesh's units.
    #[getter]
    fn area(&self) -> f64 {
        self.inner.surface_area()
    }

    /// Writes the mesh; the format follows the extension (`.off`, `.obj`, `.ply`, `.vert`,
    /// optionally `.gz`).
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let mesh = self.inner.clone();
        py.detach(|| mesh::write_mesh(&path, &mesh))
            .map_err(|e| sf_err(format!("cannot write {}: {e}", path.display())))
    }

    fn __repr__(&self) -> String {
        format!("Mesh({:?}, {} vertices, {} faces)", self.name, self.inner.n_vertices(), self.inner.n_faces())
    }
}

/// Reads a mesh file: OFF (also COFF and extra columns), OBJ, PLY (ascii or binary), TOSCA
/// `.vert`/`.tri`, each optionally gzipped. Raises `ShapeforestError` naming the file and the
/// line or element on bad input.
#[pyfunction]
fn read_mesh(py: Python<'_>, path: PathBuf) -> PyResult<PyMesh> {
    let mesh = py
        .detach(|| mesh::read_mesh(&path))
        .map_err(|e| sf_err(format!("cannot read mesh {}: {e}", path.display())))?;
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("mesh");
    let name = name.strip_suffix(".gz").unwrap_or(name);
    let name = name.rsplit_once('.').map_or(name, |(s, _)| s).to_string();
    Ok(PyMesh { inner: Arc::new(mesh), name })
}

/// The Laplace–Beltrami spectrum of a mesh scaled to unit area.
///
/// Unpacks as `eigenvalues, eigenvectors, mass = spectrum(mesh)`:
/// - `eigenvalues` `(k,)`, ascending, of the unit-area mesh (divide by `mesh.area` for the
///   mesh's own units);
/// - `eigenvectors` `(n, k)`, orthonormal in the **mass inner product**:
///   `eigenvectors.T @ (mass[:, None] * eigenvectors) ≈ I` — not under the plain dot product;
/// - `mass` `(n,)`, the lumped (barycentric) mass diagonal of the unit-area mesh, summing to 1.
#[pyclass(name = "Spectrum", module = "shapeforest", frozen)]
struct PySpectrum {
    inner: Arc<CoreSpectrum>,
}

#[pymethods]
impl PySpectrum {
    /// Eigenvalues `(k,)` of the unit-area mesh, ascending.
    #[getter]
    fn eigenvalues<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.eigenvalues.clone().into_pyarray(py)
    }

    /// Eigenvectors `(n, k)`, M-orthonormal (`Φᵀ M Φ = I`).
    #[getter]
    fn eigenvectors<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        col_major(py, self.inner.eigenvectors.clone(), self.inner.n_vertices, self.inner.k())
    }

    /// Lumped mass diagonal `(n,)` of the unit-area mesh (sums to 1).
    #[getter]
    fn mass<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.mass.clone().into_pyarray(py)
    }

    /// Surface area of the original mesh.
    #[getter]
    fn area(&self) -> f64 {
        self.inner.area
    }

    /// Number of eigenpairs.
    #[getter]
    fn k(&self) -> usize {
        self.inner.k()
    }

    fn __iter__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let t = (self.eigenvalues(py), self.eigenvectors(py), self.mass(py)).into_pyobject(py)?;
        t.try_iter().map(|i| i.into_any())
    }

    fn __repr__(&self) -> String {
        format!("Spectrum(k={}, n_vertices={})", self.inner.k(), self.inner.n_vertices)
    }
}

fn compute(py: Python<'_>, mesh: &PyMesh, k: usize) -> PyResult<Arc<CoreSpectrum>> {
    let m = mesh.inner.clone();
    py.detach(|| compute_spectrum(&m, &SpectrumParams::new(k)))
        .map(Arc::new)
        .map_err(|e| sf_err(format!("cannot compute the spectrum of {}: {e}", mesh.name)))
}

/// Computes the first `k` eigenpairs of the cotangent Laplacian (lumped mass) of `mesh`
/// scaled to unit area. Returns a `Spectrum`, which unpacks as
/// `eigenvalues, eigenvectors, mass`; eigenvectors are orthonormal in the mass (M) inner
/// product, not the plain dot product.
#[pyfunction]
#[pyo3(signature = (mesh, k = 100))]
fn spectrum(py: Python<'_>, mesh: &PyMesh, k: usize) -> PyResult<PySpectrum> {
    Ok(PySpectrum { inner: compute(py, mesh, k)? })
}

/// Takes a `Mesh` (its spectrum is computed with `k` eigenpairs) or a `Spectrum`.
fn spectrum_of(py: Python<'_>, shape: &Bound<'_, PyAny>, k: usize) -> PyResult<Arc<CoreSpectrum>> {
    if let Ok(s) = shape.cast::<PySpectrum>() {
        return Ok(s.get().inner.clone());
    }
    let mesh: PyRef<'_, PyMesh> = shape.extract().map_err(|_| {
        pyo3::exceptions::PyTypeError::new_err("expected a shapeforest.Mesh or a shapeforest.Spectrum")
    })?;
    compute(py, &mesh, k)
}

/// Heat kernel signature `(n, n_times)` of a `Mesh` (spectrum with `k` eigenpairs) or of a
/// `Spectrum`; times log-spaced over `[4 ln 10 / λ_max, 4 ln 10 / λ_1]` (Sun et al. 2009).
#[pyfunction]
#[pyo3(signature = (shape, n_times = 100, k = 100))]
fn hks<'py>(
    py: Python<'py>,
    shape: &Bound<'py, PyAny>,
    n_times: usize,
    k: usize,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let s = spectrum_of(py, shape, k)?;
    let m = py.detach(|| heat_kernel_signature(&s, &HksParams { n_times })).map_err(sf_err)?;
    Ok(mat_to_py(py, m))
}

/// Wave kernel signature `(n, n_energies)` of a `Mesh` (spectrum with `k` eigenpairs) or of a
/// `Spectrum` (Aubry et al. 2011): log-energies over the spectrum's range, band width
/// `sigma_factor · (e_max − e_min) / n_energies`; each column sums the filtered squared
/// eigenvectors, normalised. Entries are non-negative.
#[pyfunction]
#[pyo3(signature = (shape, n_energies = 100, sigma_factor = 7.0, k = 100))]
fn wks<'py>(
    py: Python<'py>,
    shape: &Bound<'py, PyAny>,
    n_energies: usize,
    sigma_factor: f64,
    k: usize,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let s = spectrum_of(py, shape, k)?;
    let params = WksParams { n_energies, sigma_factor };
    let m = py.detach(|| wave_kernel_signature(&s, &params, None)).map_err(sf_err)?;
    Ok(mat_to_py(py, m))
}

/// Heat-method geodesic distances (Crane et al. 2013, `t = time_factor · h²`) from each of
/// `sources` (a vertex index or a sequence of them): shape `(n,)` for one index, `(n, s)` for a
/// sequence (one column per source, solved as one block). Distances are in the mesh's units.
#[pyfunction]
#[pyo3(signature = (mesh, sources, time_factor = 1.0))]
fn heat_geodesics<'py>(
    py: Python<'py>,
    mesh: &PyMesh,
    sources: &Bound<'py, PyAny>,
    time_factor: f64,
) -> PyResult<Bound<'py, PyAny>> {
    let n = mesh.inner.n_vertices();
    let single = sources.extract::<i64>().is_ok();
    let list = if single {
        vertex_indices(&pyo3::types::PyList::new(py, [sources])?.into_any(), n, "sources")?
    } else {
        vertex_indices(sources, n, "sources")?
    };
    let m = mesh.inner.clone();
    let params = HeatParams { time_factor, ..HeatParams::default() };
    let fields = py
        .detach(|| HeatMethodSolver::new(&m, params).and_then(|s| s.distances_from_many(&list)))
        .map_err(|e| sf_err(format!("cannot compute heat geodesics on {}: {e}", mesh.name)))?;
    let arr = mat_to_py(py, fields);
    if single {
        Ok(arr.call_method1("reshape", (n,))?)
    } else {
        Ok(arr.into_any())
    }
}

/// Normalised geodesic errors of a point map, as `shapeforest eval` measures them: for each
/// evaluated vertex `i` of the mapped shape, the heat-method distance on `reference` between
/// `map[i]` and `truth[i]`, divided by `√reference.area`.
///
/// `map` and `truth` are `(n,)` integer arrays of reference vertices (one per vertex of the
/// mapped shape); `points` (default: every vertex) selects the evaluated vertices. Returns
/// `(len(points),)` float64. Distance fields are solved in blocks of 256 sources (memory stays
/// bounded on large meshes).
#[pyfunction]
#[pyo3(signature = (reference, map, truth, points = None))]
fn geodesic_errors<'py>(
    py: Python<'py>,
    reference: &PyMesh,
    map: &Bound<'py, PyAny>,
    truth: &Bound<'py, PyAny>,
    points: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let n_ref = reference.inner.n_vertices();
    let map = vertex_indices(map, n_ref, "map")?;
    let truth = vertex_indices(truth, n_ref, "truth")?;
    if map.len() != truth.len() {
        return Err(PyValueError::new_err(format!(
            "map has {} entries but truth has {}: both give one reference vertex per mapped vertex",
            map.len(),
            truth.len()
        )));
    }
    let points = match points {
        Some(p) => vertex_indices(p, map.len(), "points")?,
        None => (0..map.len()).collect(),
    };
    let m = reference.inner.clone();
    let errors = py
        .detach(|| -> Result<Vec<f64>, shapeforest::Error> {
            let solver = HeatMethodSolver::new(&m, HeatParams::default())?;
            let area = m.surface_area();
            let mut out = Vec::with_capacity(points.len());
            for chunk in points.chunks(256) {
                let sources: Vec<usize> = chunk.iter().map(|&p| truth[p]).collect();
                let fields = solver.distances_from_many(&sources)?;
                let (e, _) = eval::geodesic_errors(&map, chunk, fields.as_ref(), None, area)?;
                out.extend(e);
            }
            Ok(out)
        })
        .map_err(ctx_err(format!("cannot measure geodesic errors on {}", reference.name)))?;
    Ok(errors.into_pyarray(py))
}

/// `(labels, probabilities)` of `Forest.predict`.
type Predicted<'py> = (Bound<'py, PyArray2<i64>>, Bound<'py, PyArray2<f64>>);

/// A random forest over parametric wave kernel signatures (Rodolà et al. 2014): it labels each
/// vertex of a new shape with a posterior over the training class's labels.
///
/// `Forest.train(...)` fits one, `Forest.load(path)` reads a `.sfm` model file (also those of
/// `shapeforest train`), `forest.save(path)` writes one atomically.
#[pyclass(name = "Forest", module = "shapeforest", frozen)]
struct PyForest {
    inner: Arc<RandomForest>,
}

#[pymethods]
impl PyForest {
    /// Trains a forest on labelled meshes.
    ///
    /// `labels=None`: the meshes share one vertex indexing (a TOSCA/SCAPE class, a synthetic
    /// family) and label = vertex index of the first mesh. Otherwise one integer array per
    /// mesh: `labels[s][v]` is the label of vertex `v` (`-1` = unlabelled, skipped). Shapes that
    /// cannot be used (wrong vertex count, no labelled vertex) are left out as the CLI does;
    /// training fails only when none is left. `augment=["partial-view"]` (also `"holes:N:R"`,
    /// `"crop:R"`) adds `augment_copies` seeded perturbed copies of every mesh per kind, each
    /// prepared as a scan is, so the forest learns partial scans (as `shapeforest train
    /// --augment`). `local_descriptors=True` lets the forest split on local histograms of the
    /// surface too (as `shapeforest train --local-descriptors`; for partial scans).
    /// `n_trees`: default `None`, 15 where the leaves are pure and 60 where they hold several
    /// samples (with `augment` copies), as `shapeforest train --trees auto`.
    /// `min_samples_leaf`: the smallest leaf a split may leave, in training samples (default
    /// `None`: an eighth of the training set's samples per label, at least 1, as `shapeforest
    /// train --min-leaf auto`; 1: pure leaves).
    /// `progress=True` reports spectra, copies and trees on stderr; a callable gets
    /// `(stage, done, total)`.
    #[staticmethod]
    #[pyo3(signature = (meshes, labels = None, *, n_trees = None, max_depth = 25, k = 100, seed = 0, augment = Vec::new(), augment_copies = 15, local_descriptors = false, min_samples_leaf = None, progress = None))]
    #[allow(clippy::too_many_arguments)]
    fn train(
        py: Python<'_>,
        meshes: Vec<PyMesh>,
        labels: Option<Vec<Bound<'_, PyAny>>>,
        n_trees: Option<usize>,
        max_depth: usize,
        k: usize,
        seed: u64,
        augment: Vec<String>,
        augment_copies: usize,
        local_descriptors: bool,
        min_samples_leaf: Option<usize>,
        progress: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let local = local_descriptors.then(LocalParams::default);
        if n_trees == Some(0) {
            return Err(sf_err("n_trees = 0: at least 1 tree (None: chosen from the training set)"));
        }
        if min_samples_leaf == Some(0) {
            return Err(sf_err(
                "min_samples_leaf = 0: at least 1 sample (None: chosen from the training set)",
            ));
        }
        if meshes.is_empty() {
            return Err(sf_err("nothing to train on: give at least one mesh"));
        }
        let kinds: Vec<Vec<mesh::Perturbation>> = augment
            .iter()
            .map(|a| {
                mesh::Perturbation::parse_kind(a)
                    .map(|p| vec![p])
                    .map_err(|e| PyValueError::new_err(format!("augment {a:?}: {e}")))
            })
            .collect::<PyResult<_>>()?;
        let labels: Option<Vec<Vec<Option<u32>>>> = match labels {
            None => None,
            Some(l) if l.len() != meshes.len() => {
                return Err(PyValueError::new_err(format!(
                    "{} label arrays for {} meshes",
                    l.len(),
                    meshes.len()
                )))
            }
            Some(l) => Some(
                l.iter()
                    .map(|a| {
                        index_vector(a, "labels")?
                            .into_iter()
                            .map(|x| match x {
                                -1 => Ok(None),
                                x => u32::try_from(x).map(Some).map_err(|_| {
                                    PyValueError::new_err(format!(
                                        "label {x} is neither -1 nor a label index"
                                    ))
                                }),
                            })
                            .collect::<PyResult<Vec<_>>>()
                    })
                    .collect::<PyResult<_>>()?,
            ),
        };
        let params = RandomForest::params()
            .n_trees(n_trees.unwrap_or(0))
            .max_depth(max_depth)
            .min_samples_leaf(min_samples_leaf.unwrap_or(0))
            .seed(seed);
        let progress = match progress {
            Some(p) => Progress::from(p)?,
            None => Progress(None, false),
        };
        let inner = py.detach(|| -> Result<RandomForest, String> {
            let valid = params.check().map_err(|e| e.to_string())?;
            let done = AtomicUsize::new(0);
            let total = meshes.len();
            progress.report("spectra", 0, total);
            let spectra: Vec<Arc<CoreSpectrum>> = meshes
                .par_iter()
                .map(|m| {
                    let s = compute_spectrum(&m.inner, &SpectrumParams::new(k))
                        .map_err(|e| format!("cannot compute the spectrum of {}: {e}", m.name))?;
                    progress.report("spectra", done.fetch_add(1, Ordering::Relaxed) + 1, total);
                    Ok(Arc::new(s))
                })
                .collect::<Result<_, String>>()?;
            // The labels of a shared indexing: label = vertex of the first mesh.
            let identity = labels_identity(meshes[0].inner.n_vertices());
            // Perturbed copies of every mesh, labelled through their vertex maps (a mesh of
            // another vertex count than the first, in a shared indexing, is rejected below
            // and gets none).
            let mut copies = Vec::new();
            if !kinds.is_empty() {
                let sp = SpectrumParams::new(k);
                let augmentation = Augmentation {
                    kinds: &kinds,
                    copies: augment_copies,
                    fill_perimeter: Some(ScanPart::FILL_PERIMETER),
                    spectrum: &sp,
                    cache: None,
                    local: local.as_ref(),
                };
                let total = meshes.len() * kinds.len() * augment_copies;
                progress.report("copies", 0, total);
                for (i, m) in meshes.iter().enumerate() {
                    let l = match &labels {
                        Some(l) => &l[i],
                        None if m.inner.n_vertices() == identity.len() => &identity,
                        None => continue,
                    };
                    let made = augmented_copies(&m.name, &m.inner, l, &augmentation, seed, i as u64);
                    for copy in made {
                        copies.push(
                            copy.map_err(|e| format!("cannot make a perturbed copy of {}: {e}", m.name))?,
                        );
                    }
                    progress.report("copies", copies.len(), total);
                }
            }
            let names = meshes.iter().enumerate().map(|(i, m)| format!("{} (mesh {i})", m.name));
            // The meshes as training shapes, with their local histograms when asked for.
            let shape =
                |name: String, mesh: &CoreMesh, spectrum: Arc<CoreSpectrum>, labels: Vec<Option<u32>>| {
                    TrainingShape::new(name.clone(), spectrum, labels)
                        .with_local(mesh, local.as_ref())
                        .map_err(|e| format!("local histograms of {name}: {e}"))
                };
            // The model stores where its labels lie on the first mesh (the reference), as
            // `shapeforest train` does: the identity for a shared-indexing class, otherwise that
            // mesh's labels with those it lacks placed through the other meshes.
            let first = &meshes[0];
            let (set, reference) = match &labels {
                None => {
                    let n = identity.len();
                    let mut shapes: Vec<TrainingShape> = names
                        .zip(spectra)
                        .zip(&meshes)
                        .map(|((name, spectrum), m)| shape(name, &m.inner, spectrum, identity.clone()))
                        .collect::<Result<_, String>>()?;
                    shapes.extend(copies);
                    (TrainingSet::new(shapes, n), ModelReference::shared_indexing(&first.name, &first.inner))
                }
                Some(labels) => {
                    let n_labels = labels.iter().flatten().flatten().max().map_or(0, |&l| l as usize + 1);
                    let donors: Vec<(&CoreMesh, &[Option<u32>])> =
                        meshes.iter().zip(labels).skip(1).map(|(m, l)| (&*m.inner, &l[..])).collect();
                    let table = reference_table(n_labels, &first.inner, &labels[0], None, &donors)
                        .map_err(|e| format!("cannot use {} as the reference: {e}", first.name))?;
                    let mut shapes: Vec<TrainingShape> = names
                        .zip(spectra)
                        .zip(labels.iter().cloned())
                        .zip(&meshes)
                        .map(|(((name, spectrum), labels), m)| shape(name, &m.inner, spectrum, labels))
                        .collect::<Result<_, String>>()?;
                    shapes.extend(copies);
                    (
                        TrainingSet::new(shapes, n_labels),
                        ModelReference::new(&first.name, &first.inner, &table),
                    )
                }
            };
            let set = set.map_err(|e| e.to_string())?;
            let valid = valid.resolved_for(&set);
            let n_trees = valid.n_trees();
            let trees = AtomicUsize::new(0);
            progress.report("trees", 0, n_trees);
            let on_tree =
                |_: usize| progress.report("trees", trees.fetch_add(1, Ordering::Relaxed) + 1, n_trees);
            let forest = valid.fit_with_progress(None, &set, &on_tree).map_err(|e| e.to_string())?;
            forest.with_reference(reference).map_err(|e| e.to_string())
        });
        Ok(Self { inner: Arc::new(inner.map_err(sf_err)?) })
    }

    /// Reads a model file (`.sfm`) written by `save` or `shapeforest train`.
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        if !path.is_file() {
            return Err(sf_err(format!("model file {} does not exist", path.display())));
        }
        let inner = py
            .detach(|| RandomForest::load(&path))
            .map_err(|e| sf_err(format!("cannot load the model {}: {e}", path.display())))?;
        Ok(Self { inner: Arc::new(inner) })
    }

    /// Writes the model file atomically (format version, parameters, checksum).
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let f = self.inner.clone();
        py.detach(|| f.save(&path))
            .map_err(|e| sf_err(format!("cannot write the model {}: {e}", path.display())))
    }

    /// Number of labels (for a same-indexing class: the reference's vertex count).
    #[getter]
    fn n_labels(&self) -> usize {
        self.inner.n_labels()
    }

    /// Name of the reference shape the labels are tabulated on (`None` for an old model file).
    #[getter]
    fn reference(&self) -> Option<String> {
        self.inner.reference().map(|r| r.name.clone())
    }

    /// Number of trees.
    #[getter]
    fn n_trees(&self) -> usize {
        self.inner.n_trees()
    }

    /// Number of eigenpairs the descriptor uses.
    #[getter]
    fn k(&self) -> usize {
        self.inner.k()
    }

    /// Labels each vertex of `mesh`: returns `(labels, probabilities)`, both `(n, top_k)`, most
    /// probable first; where a vertex has fewer than `top_k` labels in its posterior the rest
    /// are `-1` with probability 0.
    #[pyo3(signature = (mesh, top_k = 1))]
    fn predict<'py>(&self, py: Python<'py>, mesh: &PyMesh, top_k: usize) -> PyResult<Predicted<'py>> {
        if top_k == 0 {
            return Err(PyValueError::new_err("top_k must be at least 1"));
        }
        let s = compute(py, mesh, self.inner.k())?;
        let f = self.inner.clone();
        let p = py
            .detach(|| f.predict_mesh(&mesh.inner, &s))
            .map_err(|e| sf_err(format!("forest prediction failed: {e}")))?;
        let n = p.n_vertices();
        let mut labels = Array2::<i64>::from_elem((n, top_k), -1);
        let mut probs = Array2::<f64>::zeros((n, top_k));
        for v in 0..n {
            for (j, (l, pr)) in p.top_k(v, top_k).into_iter().enumerate() {
                labels[(v, j)] = i64::from(l);
                probs[(v, j)] = f64::from(pr);
            }
        }
        Ok((labels.into_pyarray(py), probs.into_pyarray(py)))
    }

    /// Dense correspondence of `scan` to `reference`, as `shapeforest match` computes it: forest
    /// prediction, then the regulariser (game-theoretic matches, functional map, anchor growth).
    /// Returns the point map `(n_scan,)` int64: `map[i]` is the reference vertex of scan vertex
    /// `i`. The reference must be a shape whose vertex indices are the model's labels.
    #[pyo3(name = "match", signature = (scan, reference, progress = None))]
    fn match_<'py>(
        &self,
        py: Python<'py>,
        scan: &PyMesh,
        reference: &PyMesh,
        progress: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray1<i64>>> {
        // Labels are read through the model's label → reference-vertex table, as `shapeforest
        // match` reads them; a reference the model cannot place its labels on is refused.
        let table: Option<Vec<usize>> = match self.inner.reference() {
            Some(r) => Some(r.table_for(&reference.inner).ok_or_else(|| {
                sf_err(format!(
                    "the model maps onto its reference `{}` ({} vertices), and {} ({} vertices) is another \
                     mesh: pass that reference",
                    r.name,
                    r.n_vertices,
                    reference.name,
                    reference.inner.n_vertices()
                ))
            })?),
            None if self.inner.n_labels() == reference.inner.n_vertices() => None,
            None => {
                return Err(sf_err(format!(
                    "the model has {} labels but the reference {} has {} vertices, and the model stores no \
                     reference table (it predates format version 2): use a shape whose vertex indices are \
                     the model's labels",
                    self.inner.n_labels(),
                    reference.name,
                    reference.inner.n_vertices()
                )))
            }
        };
        let progress = match progress {
            Some(p) => Progress::from(p)?,
            None => Progress(None, false),
        };
        let f = self.inner.clone();
        let (s, r) = (scan.clone(), reference.clone());
        let map = py.detach(|| -> Result<Vec<usize>, String> {
            let reg = RegularizerParams::default();
            let sp = SpectrumParams::new(f.k().max(reg.fmap.k_test).max(reg.fmap.k_ref));
            let steps = 4;
            progress.report("match", 0, steps);
            let spectra: Vec<Result<CoreSpectrum, String>> = [&s, &r]
                .par_iter()
                .map(|m| {
                    compute_spectrum(&m.inner, &sp)
                        .map_err(|e| format!("cannot compute the spectrum of {}: {e}", m.name))
                })
                .collect();
            let mut spectra = spectra.into_iter();
            let scan_sp = Arc::new(spectra.next().expect("two spectra")?);
            let ref_sp = Arc::new(spectra.next().expect("two spectra")?);
            progress.report("match", 1, steps);
            let prediction =
                f.predict_mesh(&s.inner, &scan_sp).map_err(|e| format!("forest prediction failed: {e}"))?;
            progress.report("match", 2, steps);
            let test = PreparedShape::new(s.inner.clone(), scan_sp, reg.heat).map_err(|e| e.to_string())?;
            let refp = PreparedShape::new(r.inner.clone(), ref_sp, reg.heat).map_err(|e| e.to_string())?;
            progress.report("match", 3, steps);
            let dense =
                regularize(&test, &refp, &prediction, table.as_deref(), &reg).map_err(|e| e.to_string())?;
            progress.report("match", 4, steps);
            Ok(dense.map)
        });
        let map: Vec<i64> = map.map_err(sf_err)?.into_iter().map(|v| v as i64).collect();
        Ok(Array1::from(map).into_pyarray(py))
    }

    fn __repr__(&self) -> String {
        format!(
            "Forest({} trees, {} labels, k={})",
            self.inner.n_trees(),
            self.inner.n_labels(),
            self.inner.k()
        )
    }
}

/// A family of posed, left/right symmetric synthetic creatures sharing one vertex indexing
/// (the built-in data of `shapeforest demo`): `n_shapes` meshes of about `vertices` vertices;
/// the first is the rest pose. Ground truth is the identity: vertex `i` of one is vertex `i`
/// of every other.
#[pyfunction]
#[pyo3(signature = (n_shapes = 8, vertices = 5000, seed = 0))]
fn synthetic_creatures(py: Python<'_>, n_shapes: usize, vertices: usize, seed: u64) -> PyResult<Vec<PyMesh>> {
    let params = synth::CreatureParams { target_vertices: vertices, seed, ..Default::default() };
    let fam = py.detach(|| synth::creature_family(&params, n_shapes)).map_err(sf_err)?;
    Ok(fam
        .shapes
        .into_iter()
        .enumerate()
        .map(|(i, m)| PyMesh { inner: Arc::new(m), name: format!("creature{i}") })
        .collect())
}

/// A geodesic icosphere of the given radius (`subdivisions` = 0 is the icosahedron; each
/// level multiplies the faces by 4).
#[pyfunction]
#[pyo3(signature = (subdivisions = 3, radius = 1.0))]
fn icosphere(subdivisions: u32, radius: f64) -> PyResult<PyMesh> {
    if subdivisions > 8 {
        return Err(PyValueError::new_err(format!("subdivisions must be at most 8, got {subdivisions}")));
    }
    Ok(PyMesh { inner: Arc::new(synth::icosphere(subdivisions, radius)), name: "icosphere".into() })
}

fn view_pair_parts(scan: &PyMesh, reference: &PyMesh, map: &Bound<'_, PyAny>) -> PyResult<Vec<usize>> {
    let map = vertex_indices(map, reference.inner.n_vertices(), "map")?;
    if map.len() != scan.inner.n_vertices() {
        return Err(PyValueError::new_err(format!(
            "map has {} entries but the scan {} has {} vertices",
            map.len(),
            scan.name,
            scan.inner.n_vertices()
        )));
    }
    Ok(map)
}

/// Renders a PNG snapshot of a map (the picture `shapeforest match` writes beside its
/// results): the scan coloured through `map` (left) and the reference coloured by its
/// coordinates (right), fixed camera, shaded; matching parts share colours. Writes `path`.
#[pyfunction]
#[pyo3(signature = (scan, reference, map, path, width = 800, height = 400))]
fn snapshot(
    py: Python<'_>,
    scan: &PyMesh,
    reference: &PyMesh,
    map: &Bound<'_, PyAny>,
    path: PathBuf,
    width: usize,
    height: usize,
) -> PyResult<()> {
    let map = view_pair_parts(scan, reference, map)?;
    let (s, r) = (scan.clone(), reference.clone());
    py.detach(|| -> Result<(), String> {
        let pair = viz::ViewPair {
            scan: &s.inner,
            scan_name: &s.name,
            reference: &r.inner,
            reference_name: &r.name,
            map: &map,
            errors: None,
        };
        let params = viz::SnapshotParams { width, height, ..Default::default() };
        let png = viz::snapshot_png(&pair, None, &params).map_err(|e| e.to_string())?;
        std::fs::write(&path, png).map_err(|e| format!("cannot write {}: {e}", path.display()))
    })
    .map_err(sf_err)
}

/// Writes the interactive `view.html` of a map (the page of `shapeforest view`): both meshes
/// in WebGL, orbit/zoom, click a point to see its match; with `points` and `errors` (geodesic
/// errors at those scan vertices, e.g. from `geodesic_errors`) an error heat map and the
/// cumulative curve. The page is self-contained and works offline.
#[pyfunction]
#[pyo3(signature = (scan, reference, map, path, points = None, errors = None, title = None))]
#[allow(clippy::too_many_arguments)]
fn view(
    py: Python<'_>,
    scan: &PyMesh,
    reference: &PyMesh,
    map: &Bound<'_, PyAny>,
    path: PathBuf,
    points: Option<&Bound<'_, PyAny>>,
    errors: Option<&Bound<'_, PyAny>>,
    title: Option<String>,
) -> PyResult<()> {
    let map = view_pair_parts(scan, reference, map)?;
    let measured = match (points, errors) {
        (Some(p), Some(e)) => {
            let p = vertex_indices(p, scan.inner.n_vertices(), "points")?;
            let e: PyReadonlyArray1<'_, f64> = as_array(e, "float64")?.extract()?;
            Some((p, e.as_slice()?.to_vec()))
        }
        (None, None) => None,
        _ => return Err(PyValueError::new_err("give both points and errors, or neither")),
    };
    let (s, r) = (scan.clone(), reference.clone());
    let title = title.unwrap_or_else(|| format!("{} → {}", s.name, r.name));
    py.detach(|| -> Result<(), String> {
        let pair = viz::ViewPair {
            scan: &s.inner,
            scan_name: &s.name,
            reference: &r.inner,
            reference_name: &r.name,
            map: &map,
            errors: measured.as_ref().map(|(p, e)| viz::PointErrors { vertices: p, errors: e }),
        };
        let html = viz::view_html(&pair, &title).map_err(|e| e.to_string())?;
        std::fs::write(&path, html).map_err(|e| format!("cannot write {}: {e}", path.display()))
    })
    .map_err(sf_err)
}

/// Dense non-rigid 3D shape correspondence with random forests over wave kernel signatures.
#[pymodule(name = "shapeforest")]
fn shapeforest_module(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("ShapeforestError", m.py().get_type::<ShapeforestError>())?;
    m.add_class::<PyMesh>()?;
    m.add_class::<PySpectrum>()?;
    m.add_class::<PyForest>()?;
    m.add_function(wrap_pyfunction!(read_mesh, m)?)?;
    m.add_function(wrap_pyfunction!(spectrum, m)?)?;
    m.add_function(wrap_pyfunction!(hks, m)?)?;
    m.add_function(wrap_pyfunction!(wks, m)?)?;
    m.add_function(wrap_pyfunction!(heat_geodesics, m)?)?;
    m.add_function(wrap_pyfunction!(geodesic_errors, m)?)?;
    m.add_function(wrap_pyfunction!(synthetic_creatures, m)?)?;
    m.add_function(wrap_pyfunction!(icosphere, m)?)?;
    m.add_function(wrap_pyfunction!(snapshot, m)?)?;
    m.add_function(wrap_pyfunction!(view, m)?)?;
    Ok(())
}
