//! Model files.
//!
//! Layout (little-endian): the 8-byte magic `SFOREST\0`, the format version (`u32`), the payload
//! length (`u64`), the FNV-1a 64-bit checksum of the payload (`u64`), then the payload: a
//! MessagePack (rmp-serde) encoding of a [`ModelHeader`] (hyper-parameters, label count,
//! descriptor settings `K` and energy grid) followed by the trees. Writes go to a temporary
//! file in the same directory, are flushed and synced, then renamed over the target, so a reader
//! never sees a half-written model. Every failure to read is a typed [`ForestError`].

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::params::RandomForestParams;
use super::{ForestError, RandomForest};
use crate::descriptor::EnergyGrid;

/// Magic bytes at the start of a model file.
pub const MODEL_MAGIC: [u8; 8] = *b"SFOREST\0";
/// Current model file format version.
pub const MODEL_FORMAT_VERSION: u32 = 1;
const PREFIX_LEN: usize = 8 + 4 + 8 + 8;

/// The descriptive part of a model file, readable without the trees.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelHeader {
    /// Hyper-parameters of the (last) fit.
    pub params: RandomForestParams,
    /// Size of the label set.
    pub n_labels: usize,
    /// Eigenpairs used by the splits.
    pub k: usize,
    /// Energy grid of the parametric WKS.
    pub grid: EnergyGrid,
    /// Number of trees.
    pub n_trees: usize,
}

#[derive(Serialize, Deserialize)]
struct Payload {
    header: ModelHeader,
    forest: RandomForest,
}

/// FNV-1a 64-bit hash (detects any single-byte change).
///
/// ```
/// use shapeforest::forest::fnv1a64;
/// assert_eq!(fnv1a64(b""), 0xcbf29ce484222325);
/// assert_ne!(fnv1a64(b"a"), fnv1a64(b"b"));
/// ```
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01B3);
    }
    h
}

impl RandomForest {
    /// The header that [`RandomForest::save`] writes.
    pub fn header(&self) -> ModelHeader {
        ModelHeader {
            params: self.params.clone(),
            n_labels: self.n_labels,
            k: self.k,
            grid: self.grid,
            n_trees: self.trees.len(),
        }
    }

    /// Encodes the model as bytes (the file format described in the module docs).
    pub fn to_bytes(&self) -> Result<Vec<u8>, ForestError> {
        let payload = rmp_serde::to_vec(&Payload { header: self.header(), forest: self.clone() })
            .map_err(|e| ForestError::CorruptModel(format!("cannot encode: {e}")))?;
        let mut out = Vec::with_capacity(PREFIX_LEN + payload.len());
        out.extend_from_slice(&MODEL_MAGIC);
        out.extend_from_slice(&MODEL_FORMAT_VERSION.to_le_bytes());
        out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
        out.extend_from_slice(&fnv1a64(&payload).to_le_bytes());
        out.extend_from_slice(&payload);
        Ok(out)
    }

    /// Decodes a model from bytes, checking magic, version, length, checksum and the forest's
    /// internal consistency.
    pub fn from_bytes(bytes: &[u8]) -> Result<RandomForest, ForestError> {
        if bytes.len() < 8 || bytes[..8] != MODEL_MAGIC {
            return Err(ForestError::NotAModel);
        }
        if bytes.len() < PREFIX_LEN {
            return Err(ForestError::Truncated { expected: PREFIX_LEN, found: bytes.len() });
        }
        let u32_at = |i: usize| u32::from_le_bytes([bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]]);
        let u64_at = |i: usize| {
            let mut b = [0u8; 8];
            b.copy_from_slice(&bytes[i..i + 8]);
            u64::from_le_bytes(b)
        };
        let version = u32_at(8);
        if version != MODEL_FORMAT_VERSION {
            return Err(ForestError::UnsupportedVersion { found: version, supported: MODEL_FORMAT_VERSION });
        }
        let len = u64_at(12);
        let checksum = u64_at(20);
        let expected = (PREFIX_LEN as u64).saturating_add(len);
        if (bytes.len() as u64) < expected {
            return Err(ForestError::Truncated {
                expected: expected.min(usize::MAX as u64) as usize,
                found: bytes.len(),
            });
        }
        if (bytes.len() as u64) > expected {
            return Err(ForestError::CorruptModel(format!(
                "{} trailing bytes after the payload",
                bytes.len() as u64 - expected
            )));
        }
        let payload = &bytes[PREFIX_LEN..];
        let found = fnv1a64(payload);
        if found != checksum {
            return Err(ForestError::ChecksumMismatch { expected: checksum, found });
        }
        let p: Payload =
            rmp_serde::from_slice(payload).map_err(|e| ForestError::CorruptModel(e.to_string()))?;
        if p.header != p.forest.header() {
            return Err(ForestError::CorruptModel("header does not match the forest".into()));
        }
        p.forest.validate().map_err(ForestError::CorruptModel)?;
        Ok(p.forest)
    }

    /// Writes the model to `path` atomically (temporary file in the same directory, fsync,
    /// rename).
    pub fn save(&self, path: impl AsRef<Path>) -> Result<(), ForestError> {
        let path = path.as_ref();
        let bytes = self.to_bytes()?;
        crate::fsutil::write_atomic(path, &bytes)
            .map_err(|error| ForestError::Io { path: path.to_path_buf(), error })
    }

    /// Reads a model written by [`RandomForest::save`].
    pub fn load(path: impl AsRef<Path>) -> Result<RandomForest, ForestError> {
        let path = path.as_ref();
        let bytes =
            std::fs::read(path).map_err(|e| ForestError::Io { path: path.to_path_buf(), error: e })?;
        Self::from_bytes(&bytes)
            .map_err(|e| ForestError::InFile { path: path.to_path_buf(), inner: Box::new(e) })
    }
}
