//! An on-disk cache of spectra: [`SpectrumCache`].
//!
//! One file per (mesh, K): `{mesh_hash:016x}-k{K}.spectrum`, where `mesh_hash` is
//! [`Mesh::content_hash`] (exact coordinates and faces). The file is a fixed little-endian
//! header followed by the [`Spectrum`] encoded with MessagePack (`rmp-serde`):
//!
//! | bytes | field |
//! |---|---|
//! | 8 | magic `b"SFSPEC\0\0"` |
//! | 4 | file format version ([`SpectrumCache::FORMAT_VERSION`]) |
//! | 4 | solver version ([`SOLVER_VERSION`]) |
//! | 8 | mesh content hash |
//! | 8 | K |
//! | 8 | payload length in bytes |
//! | 8 | FNV-1a 64 checksum of the payload |
//!
//! Files are written atomically (a temporary file in the same directory, synced, then renamed),
//! so a reader never sees a half-written file. [`SpectrumCache::get_or_compute`] treats any
//! unusable file (truncated, corrupted, other version, other mesh) as a miss: it logs a warning,
//! recomputes and overwrites it. [`SpectrumCache::load`] reports the problem as an error.

use std::fs;
use std::path::{Path, PathBuf};

use super::{compute_spectrum, SpectralError, Spectrum, SpectrumParams, SOLVER_VERSION};
use crate::mesh::Mesh;

const MAGIC: [u8; 8] = *b"SFSPEC\0\0";
/// The format's own head in the frame: format and solver versions, mesh hash, K.
const HEAD_LEN: usize = 4 + 4 + 8 + 8;
#[cfg(test)]
const HEADER_LEN: usize = crate::fsutil::frame_prefix_len(HEAD_LEN);

/// Spectra cached as files in one directory.
///
/// ```
/// use shapeforest::spectral::{SpectrumCache, SpectrumParams};
/// use shapeforest::synth::icosphere;
/// let dir = std::env::temp_dir().join(format!("sf-doc-cache-{}", std::process::id()));
/// let cache = SpectrumCache::new(&dir).unwrap();
/// let mesh = icosphere(1, 1.0);
/// let params = SpectrumParams::new(5);
/// let first = cache.get_or_compute(&mesh, &params).unwrap();
/// assert!(cache.path_for(&mesh, &params).exists());
/// assert_eq!(cache.load(&mesh, &params).unwrap(), first);
/// std::fs::remove_dir_all(&dir).unwrap();
/// ```
#[derive(Clone, Debug)]
pub struct SpectrumCache {
    dir: PathBuf,
}

impl SpectrumCache {
    /// Version of the file layout; files of another version are not read.
    pub const FORMAT_VERSION: u32 = 1;

    /// A cache in `dir`, created (with its parents) if missing.
    pub fn new(dir: impl Into<PathBuf>) -> Result<Self, SpectralError> {
        let dir = dir.into();
        fs::create_dir_all(&dir).map_err(|source| SpectralError::CacheIo { path: dir.clone(), source })?;
        Ok(Self { dir })
    }

    /// The cache directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The file that holds (or would hold) the spectrum of `mesh` with `params.k` pairs.
    pub fn path_for(&self, mesh: &Mesh, params: &SpectrumParams) -> PathBuf {
        self.dir.join(format!("{:016x}-k{}.spectrum", mesh.content_hash(), params.k))
    }

    /// Reads the cached spectrum of `mesh`; a missing or unusable file is an error
    /// ([`SpectralError::CacheIo`] or [`SpectralError::CacheInvalid`]).
    pub fn load(&self, mesh: &Mesh, params: &SpectrumParams) -> Result<Spectrum, SpectralError> {
        let path = self.path_for(mesh, params);
        let bytes =
            fs::read(&path).map_err(|source| SpectralError::CacheIo { path: path.clone(), source })?;
        decode(&bytes, mesh.content_hash(), params.k, mesh.n_vertices())
            .map_err(|reason| SpectralError::CacheInvalid { path, reason })
    }

    /// Writes `spectrum` as the cached spectrum of `mesh` (atomically), returning the path.
    pub fn store(
        &self,
        mesh: &Mesh,
        params: &SpectrumParams,
        spectrum: &Spectrum,
    ) -> Result<PathBuf, SpectralError> {
        let path = self.path_for(mesh, params);
        if spectrum.k() != params.k || spectrum.n_vertices != mesh.n_vertices() {
            return Err(SpectralError::CacheInvalid {
                path,
                reason: format!(
                    "refusing to store a spectrum of {} pairs on {} vertices as k = {} on {} vertices",
                    spectrum.k(),
                    spectrum.n_vertices,
                    params.k,
                    mesh.n_vertices()
                ),
            });
        }
        let bytes = encode(spectrum, mesh.content_hash())
            .map_err(|reason| SpectralError::CacheInvalid { path: path.clone(), reason })?;
        write_atomic(&path, &bytes)?;
        Ok(path)
    }

    /// The cached spectrum if a valid one exists, otherwise computed with
    /// [`compute_spectrum`] and stored. Unusable files are logged and overwritten; a failure to
    /// write the cache is logged and the computed spectrum returned anyway.
    pub fn get_or_compute(&self, mesh: &Mesh, params: &SpectrumParams) -> Result<Spectrum, SpectralError> {
        match self.load(mesh, params) {
            Ok(s) => return Ok(s),
            Err(SpectralError::CacheIo { source, .. }) if source.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => tracing::warn!(error = %e, "ignoring unusable spectrum cache entry"),
        }
        let spectrum = compute_spectrum(mesh, params)?;
        if let Err(e) = self.store(mesh, params, &spectrum) {
            tracing::warn!(error = %e, "could not write the spectrum cache");
        }
        Ok(spectrum)
    }
}

/// The spectrum of `mesh`, through `cache` when there is one ([`SpectrumCache::get_or_compute`])
/// and computed otherwise: the one "cache or compute" every caller uses.
///
/// ```
/// use shapeforest::{spectral::{spectrum_cached, SpectrumParams}, synth::icosphere};
/// let s = spectrum_cached(&icosphere(1, 1.0), &SpectrumParams::new(10), None).unwrap();
/// assert_eq!(s.k(), 10);
/// ```
pub fn spectrum_cached(
    mesh: &Mesh,
    params: &SpectrumParams,
    cache: Option<&SpectrumCache>,
) -> Result<Spectrum, SpectralError> {
    match cache {
        Some(c) => c.get_or_compute(mesh, params),
        None => compute_spectrum(mesh, params),
    }
}

fn encode(spectrum: &Spectrum, mesh_hash: u64) -> Result<Vec<u8>, String> {
    let payload = rmp_serde::to_vec(spectrum).map_err(|e| format!("encoding: {e}"))?;
    let mut head = Vec::with_capacity(HEAD_LEN);
    head.extend_from_slice(&SpectrumCache::FORMAT_VERSION.to_le_bytes());
    head.extend_from_slice(&SOLVER_VERSION.to_le_bytes());
    head.extend_from_slice(&mesh_hash.to_le_bytes());
    head.extend_from_slice(&(spectrum.k() as u64).to_le_bytes());
    Ok(crate::fsutil::frame(&MAGIC, &head, &payload))
}

fn decode(bytes: &[u8], mesh_hash: u64, k: usize, n_vertices: usize) -> Result<Spectrum, String> {
    let Some(frame) = crate::fsutil::unframe(bytes, HEAD_LEN) else {
        return Err(format!("truncated header ({} bytes)", bytes.len()));
    };
    if frame.magic != MAGIC {
        return Err("not a shapeforest spectrum file (bad magic)".into());
    }
    let head = frame.head;
    let u32_at = |o: usize| u32::from_le_bytes(head[o..o + 4].try_into().expect("4 bytes"));
    let u64_at = |o: usize| u64::from_le_bytes(head[o..o + 8].try_into().expect("8 bytes"));
    let format = u32_at(0);
    if format != SpectrumCache::FORMAT_VERSION {
        return Err(format!("file format version {format}, expected {}", SpectrumCache::FORMAT_VERSION));
    }
    let solver = u32_at(4);
    if solver != SOLVER_VERSION {
        return Err(format!("written by solver version {solver}, current is {SOLVER_VERSION}"));
    }
    let (hash, file_k, len) = (u64_at(8), u64_at(16), frame.declared_len);
    if hash != mesh_hash {
        return Err(format!("belongs to mesh {hash:016x}, not {mesh_hash:016x}"));
    }
    if file_k != k as u64 {
        return Err(format!("holds k = {file_k}, expected {k}"));
    }
    let payload = frame.payload;
    if payload.len() as u64 != len {
        return Err(format!("payload has {} bytes, header says {len} (truncated?)", payload.len()));
    }
    if !frame.checksum_ok() {
        return Err("payload checksum mismatch (corrupted)".into());
    }
    let s: Spectrum = rmp_serde::from_slice(payload).map_err(|e| format!("decoding: {e}"))?;
    if s.k() != k
        || s.n_vertices != n_vertices
        || s.eigenvectors.len() != k * n_vertices
        || s.mass.len() != n_vertices
    {
        return Err("payload dimensions do not match the header and mesh".into());
    }
    Ok(s)
}

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), SpectralError> {
    crate::fsutil::write_atomic(path, bytes)
        .map_err(|source| SpectralError::CacheIo { path: path.to_path_buf(), source })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::icosphere;

    fn sample() -> (Mesh, SpectrumParams, Spectrum) {
        let mesh = icosphere(1, 1.0);
        let params = SpectrumParams::new(4);
        let s = compute_spectrum(&mesh, &params).unwrap();
        (mesh, params, s)
    }

    #[test]
    fn encode_decode_round_trip() {
        let (mesh, _, s) = sample();
        let bytes = encode(&s, mesh.content_hash()).unwrap();
        assert_eq!(decode(&bytes, mesh.content_hash(), 4, mesh.n_vertices()).unwrap(), s);
    }

    #[test]
    fn every_damage_is_detected() {
        let (mesh, _, s) = sample();
        let h = mesh.content_hash();
        let n = mesh.n_vertices();
        let good = encode(&s, h).unwrap();
        // Truncations anywhere.
        for cut in [0, 5, HEADER_LEN - 1, HEADER_LEN, good.len() / 2, good.len() - 1] {
            assert!(decode(&good[..cut], h, 4, n).is_err(), "cut at {cut}");
        }
        // A flipped bit in the payload.
        let mut bad = good.clone();
        let last = bad.len() - 3;
        bad[last] ^= 0x10;
        assert!(decode(&bad, h, 4, n).unwrap_err().contains("checksum"));
        // Other format version.
        let mut bad = good.clone();
        bad[8] = 99;
        assert!(decode(&bad, h, 4, n).unwrap_err().contains("format version"));
        // Other mesh or k.
        assert!(decode(&good, h ^ 1, 4, n).unwrap_err().contains("mesh"));
        assert!(decode(&good, h, 5, n).unwrap_err().contains("k = 4"));
        assert!(decode(b"garbage-garbage-garbage-garbage-garbage-garbage-garbage", h, 4, n)
            .unwrap_err()
            .contains("magic"));
    }
}
