//! Errors raised while building, reading or writing meshes.
//!
//! Errors from readers are layered: the innermost variant says *what* is wrong
//! ([`MeshError::Parse`], [`MeshError::NonFiniteVertex`], …), [`MeshError::At`] says *where*
//! in the data (a line, or an element of a binary PLY file) and [`MeshError::InFile`] names
//! the file. Their messages compose into one line such as
//! `cat.off: line 17: expected 3 coordinates, found 2`. Use [`MeshError::root`],
//! [`MeshError::path`] and [`MeshError::line`] to inspect an error without matching the layers.

use std::fmt;
use std::path::{Path, PathBuf};

use thiserror::Error;

/// Where in a file's data an error was found.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Location {
    /// A 1-based line of a text file.
    Line(usize),
    /// A 0-based element of a PLY file (used for binary PLY, which has no lines).
    Element {
        /// The PLY element name (`vertex`, `face`, …).
        element: String,
        /// 0-based index of the element among those with that name.
        index: usize,
    },
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Location::Line(line) => write!(f, "line {line}"),
            Location::Element { element, index } => write!(f, "{element} element {index}"),
        }
    }
}

/// A mesh could not be built, read or written.
#[derive(Debug, Error)]
pub enum MeshError {
    /// The mesh has no vertices (and hence no usable faces).
    #[error("empty mesh: {vertices} vertices, {faces} faces")]
    Empty {
        /// Vertex count found.
        vertices: usize,
        /// Face count found.
        faces: usize,
    },
    /// A [`crate::mesh::Mesh`] was built from vertices without faces. (Readers accept such data
    /// as a point cloud instead, see [`crate::mesh::point_cloud_mesh`].)
    #[error("the mesh has {vertices} vertices but no faces (a point cloud: build it with point_cloud_mesh)")]
    PointCloud {
        /// Vertex count found.
        vertices: usize,
    },
    /// A point cloud has too few points to build local triangulations.
    #[error("a point cloud needs at least {min} points, this one has {points}")]
    PointCloudTooSmall {
        /// Points found.
        points: usize,
        /// The minimum.
        min: usize,
    },
    /// No surface could be built for a point cloud.
    #[error("point cloud of {points} points is degenerate: {reason}")]
    DegeneratePointCloud {
        /// Points found.
        points: usize,
        /// What is wrong.
        reason: String,
    },
    /// A perturbation ([`super::Perturbation`]) has out-of-range settings or removes the whole
    /// surface.
    #[error("invalid perturbation {0}")]
    InvalidPerturbation(String),
    /// A vertex coordinate is NaN or infinite.
    #[error("vertex {vertex} has a NaN or infinite coordinate")]
    NonFiniteVertex {
        /// 0-based vertex index.
        vertex: usize,
    },
    /// A face refers to a vertex that does not exist.
    #[error("face {face} refers to vertex {index}, but the mesh has {n_vertices} vertices")]
    FaceIndexOutOfRange {
        /// 0-based face (triangle) index.
        face: usize,
        /// The offending 0-based vertex index.
        index: usize,
        /// Number of vertices in the mesh.
        n_vertices: usize,
    },
    /// A face uses the same vertex twice.
    #[error("face {face} repeats a vertex: {indices:?}")]
    RepeatedVertexInFace {
        /// 0-based face (triangle) index.
        face: usize,
        /// The face's vertex indices (0-based).
        indices: [usize; 3],
    },
    /// Reading or writing failed at the operating-system level.
    #[error("I/O error: {0}")]
    Io(#[from] std::io::Error),
    /// Gzip-compressed data is corrupt or truncated.
    #[error("cannot decompress gzip data: {0}")]
    Decompress(std::io::Error),
    /// Decompressed data is larger than [`crate::mesh::MAX_DECOMPRESSED_BYTES`].
    #[error("decompressed data exceeds the limit of {limit} bytes")]
    TooLarge {
        /// The limit in bytes.
        limit: u64,
    },
    /// The path is not a regular file (a directory, a FIFO, a device, or a symbolic link where
    /// links are not followed); nothing is read from it.
    #[error("not a regular file but {what}; nothing was read")]
    NotAFile {
        /// What it is, e.g. `a symbolic link`.
        what: String,
    },
    /// The file is larger than the configured limit; nothing was read.
    #[error("the file has {size} bytes, more than the limit of {limit} (limits.max_file_bytes)")]
    FileTooLarge {
        /// Size of the file.
        size: u64,
        /// The limit.
        limit: u64,
    },
    /// The mesh has more vertices or faces than the configured limit.
    #[error("{found} {what}, more than the limit of {limit} (limits.max_{what})")]
    OverLimit {
        /// `vertices` or `faces`.
        what: &'static str,
        /// Count found.
        found: usize,
        /// The limit.
        limit: usize,
    },
    /// The file name does not end in an extension this crate reads or writes.
    #[error(
        "unknown mesh file extension {extension:?}: expected .off, .obj, .ply, .vert, .tri or .xyz, optionally followed by .gz"
    )]
    UnknownExtension {
        /// The extension found (empty when there is none).
        extension: String,
    },
    /// One file of a TOSCA `.vert` / `.tri` pair is missing.
    #[error("a TOSCA mesh needs both a .vert and a .tri file, but {} does not exist", missing.display())]
    MissingSibling {
        /// The sibling that was looked for (without `.gz`).
        missing: PathBuf,
    },
    /// The data uses a feature of its format that this crate does not read.
    #[error("{what} is not supported")]
    Unsupported {
        /// The unsupported feature, e.g. `binary OFF`.
        what: String,
    },
    /// The data ends before everything its header announced was read.
    #[error("the file ends early: expected {expected}, found {found}")]
    Truncated {
        /// What the header announced, e.g. `12 faces`.
        expected: String,
        /// What was found instead, e.g. `7`.
        found: String,
    },
    /// A token or line could not be parsed.
    #[error("expected {expected}, found {found}")]
    Parse {
        /// What the reader expected, e.g. `3 coordinates`.
        expected: String,
        /// What it found, e.g. `2`.
        found: String,
    },
    /// A PLY-level error reported by the PLY parser.
    #[error("invalid PLY data: {message}")]
    Ply {
        /// The parser's message.
        message: String,
    },
    /// The number of per-vertex colours given to a writer differs from the vertex count.
    #[error("{colors} vertex colours given for {vertices} vertices")]
    ColorCountMismatch {
        /// Colours given.
        colors: usize,
        /// Vertices in the mesh.
        vertices: usize,
    },
    /// An error at a known place in the data.
    #[error("{location}: {inner}")]
    At {
        /// Where the error was found.
        location: Location,
        /// The error itself.
        inner: Box<MeshError>,
    },
    /// An error while reading or writing a named file.
    #[error("{}: {inner}", path.display())]
    InFile {
        /// The file.
        path: PathBuf,
        /// The error itself.
        inner: Box<MeshError>,
    },
}

impl MeshError {
    /// The innermost error, without the [`MeshError::At`] and [`MeshError::InFile`] layers.
    ///
    /// ```
    /// use shapeforest::mesh::{parse_off, MeshError};
    /// let err = parse_off(b"OFF\n1 1 0\n0 0\n3 0 0 0\n").unwrap_err();
    /// assert!(matches!(err.root(), MeshError::Parse { .. }));
    /// assert_eq!(err.line(), Some(3));
    /// ```
    pub fn root(&self) -> &MeshError {
        match self {
            MeshError::At { inner, .. } | MeshError::InFile { inner, .. } => inner.root(),
            other => other,
        }
    }

    /// The file the error is about, when known.
    pub fn path(&self) -> Option<&Path> {
        match self {
            MeshError::InFile { path, .. } => Some(path),
            MeshError::At { inner, .. } => inner.path(),
            _ => None,
        }
    }

    /// The 1-based line the error is about, when known.
    pub fn line(&self) -> Option<usize> {
        self.location().and_then(|l| match l {
            Location::Line(n) => Some(*n),
            Location::Element { .. } => None,
        })
    }

    /// Where in the data the error is, when known.
    pub fn location(&self) -> Option<&Location> {
        match self {
            MeshError::At { location, .. } => Some(location),
            MeshError::InFile { inner, .. } => inner.location(),
            _ => None,
        }
    }

    /// Wraps `self` with a location, unless it already carries one.
    pub(crate) fn at(self, location: Location) -> MeshError {
        match self {
            e @ (MeshError::At { .. } | MeshError::InFile { .. }) => e,
            e => MeshError::At { location, inner: Box::new(e) },
        }
    }

    /// Wraps `self` with a line number, unless it already carries a location.
    pub(crate) fn at_line(self, line: usize) -> MeshError {
        self.at(Location::Line(line))
    }

    /// Wraps `self` with a file name, unless it already names one.
    pub(crate) fn in_file(self, path: &Path) -> MeshError {
        match self {
            e @ MeshError::InFile { .. } => e,
            e => MeshError::InFile { path: path.to_path_buf(), inner: Box::new(e) },
        }
    }

    /// A [`MeshError::Parse`] at a line.
    pub(crate) fn parse_at(line: usize, expected: impl Into<String>, found: impl Into<String>) -> MeshError {
        MeshError::Parse { expected: expected.into(), found: found.into() }.at_line(line)
    }
}
