//! File-system helpers shared by the modules that write files (model files, the spectrum cache,
//! the pipeline's data folder): atomic writes, the FNV-1a checksum, and the checksummed frame of
//! the binary file formats.

use std::{
    fs,
    io::{self, Write},
    path::Path,
    sync::atomic::{AtomicU64, Ordering},
};

static TEMP_COUNTER: AtomicU64 = AtomicU64::new(0);

/// Writes `bytes` to `path` atomically: a temporary file in the same folder (named by process
/// and a counter, so concurrent writers never share one), synced, then renamed over `path`.
/// A reader sees the old file or the new one, never a part. The temporary file is removed on
/// failure.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "file".into());
    let tmp = dir.join(format!(
        ".{name}.{}.{}.tmp",
        std::process::id(),
        TEMP_COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let result = (|| {
        let mut f = fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        drop(f);
        fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// FNV-1a, 64 bit: small, stable across platforms and Rust versions (unlike `DefaultHasher`);
/// the mesh content hash and the checksums of model and spectrum files.
pub(crate) struct Fnv64(u64);

impl Fnv64 {
    pub(crate) fn new() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
    pub(crate) fn write_u64(&mut self, x: u64) {
        self.write_bytes(&x.to_le_bytes());
    }
    pub(crate) fn write_bytes(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= b as u64;
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    pub(crate) fn finish(&self) -> u64 {
        self.0
    }
}

/// FNV-1a 64-bit hash of `bytes`.
pub(crate) fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h = Fnv64::new();
    h.write_bytes(bytes);
    h.finish()
}

/// The checksummed frame of the binary files (model files, cached spectra), little-endian:
/// `magic (8) | head (the format's own fixed fields) | payload length (u64) | FNV-1a 64 of the
/// payload (u64) | payload`.
pub(crate) fn frame(magic: &[u8; 8], head: &[u8], payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(8 + head.len() + 16 + payload.len());
    out.extend_from_slice(magic);
    out.extend_from_slice(head);
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(&fnv1a64(payload).to_le_bytes());
    out.extend_from_slice(payload);
    out
}

/// A frame read back by [`unframe`], before any check: the caller checks the magic, its head
/// fields, the declared length and the checksum, in the order its error messages want.
pub(crate) struct Frame<'a> {
    /// The 8-byte magic.
    pub(crate) magic: &'a [u8],
    /// The format's fixed fields.
    pub(crate) head: &'a [u8],
    /// The payload length the frame declares.
    pub(crate) declared_len: u64,
    /// The checksum the frame declares.
    pub(crate) checksum: u64,
    /// Everything after the prefix.
    pub(crate) payload: &'a [u8],
}

impl Frame<'_> {
    /// Whether the payload's FNV-1a matches the declared checksum.
    pub(crate) fn checksum_ok(&self) -> bool {
        fnv1a64(self.payload) == self.checksum
    }
}

/// The bytes before the payload of a frame with a `head_len`-byte head.
pub(crate) const fn frame_prefix_len(head_len: usize) -> usize {
    8 + head_len + 16
}

/// Splits a frame with a `head_len`-byte head; `None` when `bytes` is shorter than the prefix.
pub(crate) fn unframe(bytes: &[u8], head_len: usize) -> Option<Frame<'_>> {
    let prefix = frame_prefix_len(head_len);
    if bytes.len() < prefix {
        return None;
    }
    let u64_at = |i: usize| {
        let mut b = [0u8; 8];
        b.copy_from_slice(&bytes[i..i + 8]);
        u64::from_le_bytes(b)
    };
    Some(Frame {
        magic: &bytes[..8],
        head: &bytes[8..8 + head_len],
        declared_len: u64_at(8 + head_len),
        checksum: u64_at(16 + head_len),
        payload: &bytes[prefix..],
    })
}
