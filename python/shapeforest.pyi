"""Dense non-rigid 3D shape correspondence with random forests over wave kernel signatures.

numpy in, numpy out: vertices ``(n, 3)`` float64, faces ``(m, 3)`` integer, 0-based. Long
calls release the GIL. Errors raise :class:`ShapeforestError` (a ``ValueError``) with the
messages of the ``shapeforest`` command-line tool.
"""

from os import PathLike
from typing import Callable, Iterator, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

ArrayLike = npt.ArrayLike
Progress = Union[bool, Callable[[str, int, int], object], None]

class ShapeforestError(ValueError):
    """An error of the shapeforest library; the message is the command-line tool's."""

class Mesh:
    """A triangle mesh. ``Mesh(vertices, faces)`` checks: at least one vertex and one face (a
    point cloud is refused), finite coordinates, face indices in range, no face repeating a
    vertex. Vertex order is kept: ground truth is by vertex index."""

    def __init__(self, vertices: ArrayLike, faces: ArrayLike, name: Optional[str] = None) -> None: ...
    @property
    def vertices(self) -> npt.NDArray[np.float64]:
        """``(n, 3)`` float64 (a copy)."""
    @property
    def faces(self) -> npt.NDArray[np.int64]:
        """``(m, 3)`` int64, 0-based (a copy)."""
    @property
    def name(self) -> str: ...
    @property
    def n_vertices(self) -> int: ...
    @property
    def n_faces(self) -> int: ...
    @property
    def area(self) -> float:
        """Total surface area in the mesh's units."""
    def save(self, path: Union[str, PathLike[str]]) -> None:
        """Writes the mesh; format by extension (.off .obj .ply .vert, optionally .gz)."""

class Spectrum:
    """The Laplace–Beltrami spectrum of a mesh scaled to unit area. Unpacks as
    ``eigenvalues, eigenvectors, mass``. Eigenvectors are orthonormal in the **mass inner
    product** (``Φᵀ diag(mass) Φ = I``), not the plain dot product."""

    @property
    def eigenvalues(self) -> npt.NDArray[np.float64]:
        """``(k,)`` ascending, of the unit-area mesh (divide by ``area`` for mesh units)."""
    @property
    def eigenvectors(self) -> npt.NDArray[np.float64]:
        """``(n, k)``, M-orthonormal."""
    @property
    def mass(self) -> npt.NDArray[np.float64]:
        """``(n,)`` lumped mass diagonal of the unit-area mesh (sums to 1)."""
    @property
    def area(self) -> float:
        """Surface area of the original mesh."""
    @property
    def k(self) -> int: ...
    def __iter__(self) -> Iterator[npt.NDArray[np.float64]]: ...

class Forest:
    """A random forest over parametric wave kernel signatures (Rodolà et al. 2014)."""

    @staticmethod
    def train(
        meshes: Sequence[Mesh],
        labels: Optional[Sequence[ArrayLike]] = None,
        *,
        n_trees: Optional[int] = None,
        max_depth: int = 25,
        k: int = 100,
        seed: int = 0,
        augment: Sequence[str] = (),
        augment_copies: int = 15,
        local_descriptors: bool = False,
        min_samples_leaf: Optional[int] = None,
        progress: Progress = None,
    ) -> "Forest":
        """Trains on labelled meshes. ``labels=None``: the meshes share one vertex indexing and
        label = vertex index. Otherwise one integer array per mesh (``-1`` = unlabelled).
        ``augment=["partial-view"]`` (also ``"holes:N:R"``, ``"crop:R"``) adds ``augment_copies``
        seeded perturbed copies of every mesh per kind, so partial scans are learnt.
        ``local_descriptors=True`` lets the forest split on local histograms of the surface too
        (for partial scans; prediction then reads the mesh, as it always does here).
        ``min_samples_leaf``: the smallest leaf a split may leave, in training samples (default
        ``None``: an eighth of the training set's samples per label, at least 1; 1: pure leaves).
        ``progress=True`` reports on stderr; a callable gets ``(stage, done, total)``."""
    @staticmethod
    def load(path: Union[str, PathLike[str]]) -> "Forest":
        """Reads a ``.sfm`` model file (also those of ``shapeforest train``)."""
    def save(self, path: Union[str, PathLike[str]]) -> None:
        """Writes the model file atomically."""
    @property
    def n_labels(self) -> int: ...
    @property
    def reference(self) -> Optional[str]:
        """Name of the reference the labels are tabulated on (the first training mesh)."""
    @property
    def n_trees(self) -> int: ...
    @property
    def k(self) -> int: ...
    def predict(self, mesh: Mesh, top_k: int = 1) -> Tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
        """``(labels, probabilities)``, both ``(n, top_k)``, most probable first; ``-1`` / 0 pad."""
    def match(self, scan: Mesh, reference: Mesh, progress: Progress = None) -> npt.NDArray[np.int64]:
        """Dense map ``(n_scan,)``: ``map[i]`` = reference vertex of scan vertex ``i``, as
        ``shapeforest match`` computes it (forest, then the regulariser). The reference must be
        the model's reference (``forest.reference``) or, for a shared-indexing class, any shape
        of the class."""

def read_mesh(path: Union[str, PathLike[str]]) -> Mesh:
    """Reads OFF/COFF, OBJ, PLY, TOSCA .vert/.tri, optionally gzipped."""

def spectrum(mesh: Mesh, k: int = 100) -> Spectrum:
    """The first ``k`` eigenpairs of the unit-area mesh (cotangent Laplacian, lumped mass)."""

def hks(shape: Union[Mesh, Spectrum], n_times: int = 100, k: int = 100) -> npt.NDArray[np.float64]:
    """Heat kernel signature ``(n, n_times)``."""

def wks(
    shape: Union[Mesh, Spectrum], n_energies: int = 100, sigma_factor: float = 7.0, k: int = 100
) -> npt.NDArray[np.float64]:
    """Wave kernel signature ``(n, n_energies)``, non-negative."""

def heat_geodesics(
    mesh: Mesh, sources: Union[int, ArrayLike], time_factor: float = 1.0
) -> npt.NDArray[np.float64]:
    """Heat-method distances: ``(n,)`` for one source, ``(n, s)`` for a sequence."""

def geodesic_errors(
    reference: Mesh, map: ArrayLike, truth: ArrayLike, points: Optional[ArrayLike] = None
) -> npt.NDArray[np.float64]:
    """Geodesic distance on ``reference`` between ``map[i]`` and ``truth[i]`` over √area, for
    each evaluated vertex ``i`` (default all)."""

def synthetic_creatures(n_shapes: int = 8, vertices: int = 5000, seed: int = 0) -> list[Mesh]:
    """Posed, symmetric synthetic creatures sharing one vertex indexing (ground truth = identity)."""

def icosphere(subdivisions: int = 3, radius: float = 1.0) -> Mesh:
    """A geodesic icosphere."""

def snapshot(
    scan: Mesh, reference: Mesh, map: ArrayLike, path: Union[str, PathLike[str]], width: int = 800, height: int = 400
) -> None:
    """PNG of the scan coloured through ``map`` (left) and the reference (right)."""

def view(
    scan: Mesh,
    reference: Mesh,
    map: ArrayLike,
    path: Union[str, PathLike[str]],
    points: Optional[ArrayLike] = None,
    errors: Optional[ArrayLike] = None,
    title: Optional[str] = None,
) -> None:
    """Self-contained interactive ``view.html`` of a map (three.js, offline)."""
