//! File-level entry points: [`read_mesh`], [`read_mesh_with_report`], [`write_mesh`], and
//! [`parse_mesh`] / [`read_mesh_from`] for data already in memory or behind a reader.
//!
//! The format follows the file extension (`.off`, `.obj`, `.ply`, `.vert`, `.tri`, any of
//! them optionally followed by `.gz`, case-insensitive). Gzip data is recognised by its magic
//! number, so a compressed file without `.gz` reads too. Every error from a file is wrapped
//! in [`MeshError::InFile`] naming it.

use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use super::obj::{parse_obj, write_obj};
use super::off::{parse_off, write_off};
use super::ply::{parse_ply, write_ply, PlyEncoding};
use super::report::{MeshFormat, MeshReport};
use super::tosca::{parse_tri, parse_vert, write_tosca};
use super::{Mesh, MeshError};

impl MeshFormat {
    /// The format a file name announces, ignoring a trailing `.gz` and letter case.
    ///
    /// ```
    /// use shapeforest::mesh::MeshFormat;
    /// assert_eq!(MeshFormat::from_path("cat0.off.gz".as_ref()).unwrap(), MeshFormat::Off);
    /// assert_eq!(MeshFormat::from_path("a/b/Scan.PLY".as_ref()).unwrap(), MeshFormat::Ply);
    /// assert_eq!(MeshFormat::from_path("wolf.tri".as_ref()).unwrap(), MeshFormat::Tosca);
    /// assert!(MeshFormat::from_path("notes.txt".as_ref()).is_err());
    /// ```
    pub fn from_path(path: &Path) -> Result<MeshFormat, MeshError> {
        let (stem, _) = split_gz(path);
        let ext = stem.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
        match ext.as_str() {
            "off" => Ok(MeshFormat::Off),
            "obj" => Ok(MeshFormat::Obj),
            "ply" => Ok(MeshFormat::Ply),
            "vert" | "tri" => Ok(MeshFormat::Tosca),
            _ => Err(MeshError::UnknownExtension { extension: ext }),
        }
    }
}

/// Splits a trailing `.gz` (any case) off a path: `(path without .gz, had .gz)`.
fn split_gz(path: &Path) -> (PathBuf, bool) {
    match path.extension() {
        Some(e) if e.eq_ignore_ascii_case("gz") => (path.with_extension(""), true),
        _ => (path.to_path_buf(), false),
    }
}

/// Reads a mesh file; see [`read_mesh_with_report`] for the warnings.
pub fn read_mesh(path: impl AsRef<Path>) -> Result<Mesh, MeshError> {
    read_mesh_with_report(path).map(|(mesh, _)| mesh)
}

/// Reads a mesh file, choosing the reader by extension, and reports what it found.
///
/// For TOSCA, either file of the pair may be given; the other is looked up beside it
/// (`NAME.vert` ↔ `NAME.tri`, with or without `.gz`).
pub fn read_mesh_with_report(path: impl AsRef<Path>) -> Result<(Mesh, MeshReport), MeshError> {
    let path = path.as_ref();
    let format = MeshFormat::from_path(path).map_err(|e| e.in_file(path))?;
    if format == MeshFormat::Tosca {
        return read_tosca_pair(path);
    }
    let bytes = std::fs::read(path).map_err(|e| MeshError::Io(e).in_file(path))?;
    parse_mesh(&bytes, format).map_err(|e| e.in_file(path))
}

/// Parses mesh data held in memory (plain or gzip-compressed).
///
/// ```
/// use shapeforest::mesh::{parse_mesh, MeshFormat};
/// let (mesh, report) = parse_mesh(b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", MeshFormat::Off).unwrap();
/// assert_eq!(mesh.n_faces(), 1);
/// assert!(report.is_clean());
/// ```
pub fn parse_mesh(bytes: &[u8], format: MeshFormat) -> Result<(Mesh, MeshReport), MeshError> {
    match format {
        MeshFormat::Off => parse_off(bytes),
        MeshFormat::Obj => parse_obj(bytes),
        MeshFormat::Ply => parse_ply(bytes),
        MeshFormat::Tosca => Err(MeshError::Unsupported {
            what: "reading a TOSCA mesh from one buffer (use parse_tosca with the .vert and .tri data)"
                .into(),
        }),
    }
}

/// Reads mesh data from any reader (a socket, a decompressor, …) and parses it.
pub fn read_mesh_from<R: Read>(mut reader: R, format: MeshFormat) -> Result<(Mesh, MeshReport), MeshError> {
    let mut bytes = Vec::new();
    reader.read_to_end(&mut bytes)?;
    parse_mesh(&bytes, format)
}

/// The `.vert` and `.tri` paths of the pair `path` belongs to, each the first that exists
/// among the plain and `.gz` names (preferring the compression of `path`).
fn tosca_pair(path: &Path) -> Result<(PathBuf, PathBuf), MeshError> {
    let (stem, gz) = split_gz(path);
    let find = |ext: &str| -> Result<PathBuf, MeshError> {
        let plain = stem.with_extension(ext);
        let zipped = stem.with_extension(format!("{ext}.gz"));
        let candidates = if gz { [zipped, plain.clone()] } else { [plain.clone(), zipped] };
        candidates.into_iter().find(|p| p.exists()).ok_or(MeshError::MissingSibling { missing: plain })
    };
    Ok((find("vert")?, find("tri")?))
}

fn read_tosca_pair(path: &Path) -> Result<(Mesh, MeshReport), MeshError> {
    let (vert_path, tri_path) = tosca_pair(path).map_err(|e| e.in_file(path))?;
    let read = |p: &Path| std::fs::read(p).map_err(|e| MeshError::Io(e).in_file(p));
    let vertices = parse_vert(&read(&vert_path)?).map_err(|e| e.in_file(&vert_path))?;
    let faces = parse_tri(&read(&tri_path)?, vertices.len()).map_err(|e| e.in_file(&tri_path))?;
    super::report::finish(vertices, faces, MeshFormat::Tosca, Vec::new()).map_err(|e| e.in_file(&vert_path))
}

/// A file being written, plain or gzip-compressed.
enum Output {
    Plain(BufWriter<File>),
    Gz(flate2::write::GzEncoder<BufWriter<File>>),
}

impl Output {
    /// Creates `path`, gzip-compressing when `gz`.
    fn create(path: &Path, gz: bool) -> Result<Output, MeshError> {
        let file = BufWriter::new(File::create(path).map_err(|e| MeshError::Io(e).in_file(path))?);
        Ok(if gz {
            Output::Gz(flate2::write::GzEncoder::new(file, flate2::Compression::default()))
        } else {
            Output::Plain(file)
        })
    }

    /// Flushes everything (for gzip, the trailer too), reporting any error.
    fn finish(self, path: &Path) -> Result<(), MeshError> {
        let result = match self {
            Output::Plain(mut w) => w.flush(),
            Output::Gz(w) => w.finish().and_then(|mut inner| inner.flush()),
        };
        result.map_err(|e| MeshError::Io(e).in_file(path))
    }
}

impl Write for Output {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        match self {
            Output::Plain(w) => w.write(buf),
            Output::Gz(w) => w.write(buf),
        }
    }

    fn flush(&mut self) -> std::io::Result<()> {
        match self {
            Output::Plain(w) => w.flush(),
            Output::Gz(w) => w.flush(),
        }
    }
}

/// Writes a mesh, choosing the format by extension (`.gz` compresses). PLY is written as
/// binary little-endian; for TOSCA both `NAME.vert` and `NAME.tri` are written, whichever
/// of the two `path` names.
pub fn write_mesh(path: impl AsRef<Path>, mesh: &Mesh) -> Result<(), MeshError> {
    let path = path.as_ref();
    let format = MeshFormat::from_path(path).map_err(|e| e.in_file(path))?;
    let (stem, gz) = split_gz(path);
    if format == MeshFormat::Tosca {
        let name =
            |ext: &str| if gz { stem.with_extension(format!("{ext}.gz")) } else { stem.with_extension(ext) };
        let (vert_path, tri_path) = (name("vert"), name("tri"));
        let mut vert = Output::create(&vert_path, gz)?;
        let mut tri = Output::create(&tri_path, gz)?;
        write_tosca(mesh, &mut vert, &mut tri).map_err(|e| e.in_file(path))?;
        vert.finish(&vert_path)?;
        return tri.finish(&tri_path);
    }
    let mut w = Output::create(path, gz)?;
    match format {
        MeshFormat::Off => write_off(mesh, &mut w),
        MeshFormat::Obj => write_obj(mesh, &mut w),
        _ => write_ply(mesh, &mut w, PlyEncoding::BinaryLittleEndian, None),
    }
    .map_err(|e| e.in_file(path))?;
    w.finish(path)
}

/// Writes a mesh as binary little-endian PLY with a colour per vertex (`.gz` compresses).
pub fn write_colored_ply(path: impl AsRef<Path>, mesh: &Mesh, colors: &[[u8; 3]]) -> Result<(), MeshError> {
    let path = path.as_ref();
    let (_, gz) = split_gz(path);
    let mut w = Output::create(path, gz)?;
    write_ply(mesh, &mut w, PlyEncoding::BinaryLittleEndian, Some(colors)).map_err(|e| e.in_file(path))?;
    w.finish(path)
}
