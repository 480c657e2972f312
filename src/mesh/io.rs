//! File-level entry points: [`read_mesh`], [`read_mesh_with_report`], [`write_mesh`], and
//! [`parse_mesh`] / [`read_mesh_from`] for data already in memory or behind a reader.
//!
//! The format follows the file extension (`.off`, `.obj`, `.ply`, `.vert`, `.tri`, `.xyz`, any of
//! them optionally followed by `.gz`, case-insensitive). Gzip data is recognised by its magic
//! number, so a compressed file without `.gz` reads too. Every error from a file is wrapped
//! in [`MeshError::InFile`] naming it.

use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use super::obj::{obj_parts, write_obj};
use super::off::{off_parts, write_off};
use super::ply::{ply_parts, write_ply, PlyEncoding};
use super::report::{MeshFormat, MeshReport, Parts};
use super::text::gunzip_limited;
use super::tosca::{parse_tri, parse_vert, write_tosca};
use super::xyz::{write_xyz, xyz_parts};
use super::{Mesh, MeshError};
use crate::limits::Limits;

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
            "xyz" => Ok(MeshFormat::Xyz),
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

/// Reads a mesh file, choosing the reader by extension, and reports what it found, under the
/// default [`Limits`] (symbolic links are followed: the path is the caller's own choice).
///
/// For TOSCA, either file of the pair may be given; the other is looked up beside it
/// (`NAME.vert` ↔ `NAME.tri`, with or without `.gz`).
pub fn read_mesh_with_report(path: impl AsRef<Path>) -> Result<(Mesh, MeshReport), MeshError> {
    read_mesh_limited(path, &Limits::default(), true)
}

/// [`read_mesh_with_report`] under explicit limits: the path must be a regular file (with
/// `follow_symlinks = false`, a symbolic link is refused without being opened, as the daemon
/// does for files dropped into its folders), no larger than `limits.max_file_bytes` on disk and
/// after decompression (checked before reading), and the mesh may have at most
/// `limits.max_vertices` vertices and `limits.max_faces` faces.
///
/// ```
/// use shapeforest::{limits::Limits, mesh::{read_mesh_limited, MeshError}};
/// let d = tempfile::tempdir().unwrap();
/// let p = d.path().join("a.off");
/// std::fs::write(&p, "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n").unwrap();
/// let small = Limits { max_file_bytes: 10, ..Limits::default() };
/// let e = read_mesh_limited(&p, &small, false).unwrap_err();
/// assert!(matches!(e.root(), MeshError::FileTooLarge { .. }), "{e}");
/// assert!(read_mesh_limited(&p, &Limits::default(), false).is_ok());
/// ```
pub fn read_mesh_limited(
    path: impl AsRef<Path>,
    limits: &Limits,
    follow_symlinks: bool,
) -> Result<(Mesh, MeshReport), MeshError> {
    let path = path.as_ref();
    let format = MeshFormat::from_path(path).map_err(|e| e.in_file(path))?;
    let (mesh, report) = if format == MeshFormat::Tosca {
        read_tosca_pair(path, limits, follow_symlinks)?
    } else {
        let bytes = read_file_limited(path, limits.max_file_bytes, follow_symlinks)?;
        let bytes = gunzip_limited(&bytes, limits.max_file_bytes).map_err(|e| e.in_file(path))?;
        parts(&bytes, format).and_then(|p| p.finish(limits)).map_err(|e| e.in_file(path))?
    };
    check_counts(&mesh, limits).map_err(|e| e.in_file(path))?;
    Ok((mesh, report))
}

fn check_counts(mesh: &Mesh, limits: &Limits) -> Result<(), MeshError> {
    if mesh.n_vertices() > limits.max_vertices {
        return Err(MeshError::OverLimit {
            what: "vertices",
            found: mesh.n_vertices(),
            limit: limits.max_vertices,
        });
    }
    if mesh.n_faces() > limits.max_faces {
        return Err(MeshError::OverLimit { what: "faces", found: mesh.n_faces(), limit: limits.max_faces });
    }
    Ok(())
}

/// What a non-regular file is, for messages.
fn file_kind(ft: &std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if ft.is_fifo() {
            return "a FIFO (named pipe)";
        }
        if ft.is_socket() {
            return "a socket";
        }
        if ft.is_block_device() || ft.is_char_device() {
            return "a device";
        }
    }
    if ft.is_symlink() {
        "a symbolic link (links are not followed here)"
    } else if ft.is_dir() {
        "a directory"
    } else {
        "not a regular file"
    }
}

/// Reads a whole regular file of at most `limit` bytes; the size is checked before reading and
/// again while reading (the file may grow), and a FIFO or device is never opened (it could
/// block forever). Without `follow_symlinks` the file is opened with `O_NOFOLLOW` after a
/// `symlink_metadata` check, so a link is never followed. Errors name the file.
pub fn read_file_limited(path: &Path, limit: u64, follow_symlinks: bool) -> Result<Vec<u8>, MeshError> {
    let io = |e: std::io::Error| MeshError::Io(e).in_file(path);
    let meta = if follow_symlinks { std::fs::metadata(path) } else { std::fs::symlink_metadata(path) }
        .map_err(io)?;
    if !meta.is_file() {
        return Err(MeshError::NotAFile { what: file_kind(&meta.file_type()).into() }.in_file(path));
    }
    if meta.len() > limit {
        return Err(MeshError::FileTooLarge { size: meta.len(), limit }.in_file(path));
    }
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(unix)]
    if !follow_symlinks {
        use std::os::unix::fs::OpenOptionsExt;
        options.custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK);
    }
    let file = options.open(path).map_err(io)?;
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    file.take(limit + 1).read_to_end(&mut bytes).map_err(io)?;
    if bytes.len() as u64 > limit {
        return Err(MeshError::FileTooLarge { size: bytes.len() as u64, limit }.in_file(path));
    }
    Ok(bytes)
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
    parts(bytes, format)?.finish(&Limits::default())
}

/// What the reader of `format` finds in `bytes`, before the mesh is built.
fn parts(bytes: &[u8], format: MeshFormat) -> Result<Parts, MeshError> {
    match format {
        MeshFormat::Off => off_parts(bytes),
        MeshFormat::Obj => obj_parts(bytes),
        MeshFormat::Ply => ply_parts(bytes),
        MeshFormat::Xyz => xyz_parts(bytes),
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

fn read_tosca_pair(path: &Path, limits: &Limits, follow: bool) -> Result<(Mesh, MeshReport), MeshError> {
    let (vert_path, tri_path) = tosca_pair(path).map_err(|e| e.in_file(path))?;
    let read = |p: &Path| -> Result<Vec<u8>, MeshError> {
        let bytes = read_file_limited(p, limits.max_file_bytes, follow)?;
        let plain = gunzip_limited(&bytes, limits.max_file_bytes).map_err(|e| e.in_file(p))?;
        Ok(plain.into_owned())
    };
    let vertices = parse_vert(&read(&vert_path)?).map_err(|e| e.in_file(&vert_path))?;
    let faces = parse_tri(&read(&tri_path)?, vertices.len()).map_err(|e| e.in_file(&tri_path))?;
    Parts { vertices, faces, format: MeshFormat::Tosca, notes: Vec::new() }
        .finish(limits)
        .map_err(|e| e.in_file(&vert_path))
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
        MeshFormat::Xyz => write_xyz(mesh, &mut w),
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
