//! Model files.
//!
//! Layout (little-endian): the 8-byte magic `SFOREST\0`, the format version (`u32`), the payload
//! length (`u64`), the FNV-1a 64-bit checksum of the payload (`u64`), then the payload: a
//! MessagePack (rmp-serde) encoding of a [`ModelHeader`] (hyper-parameters, label count,
//! descriptor settings `K` and energy grid) followed by the trees and, from version 2, the
//! optional reference table ([`ModelReference`](super::ModelReference): where each label lies
//! on the reference shape). From version 3 each tree is a compact pre-order code (leaf labels
//! in the node records, probabilities only for multi-label leaves, child and leaf indices
//! implicit: see the `compact` module), about a quarter of version 2's size; versions 1 (no
//! table) and 2 (full node records) are still read. Version 4 is version 3 with the settings of
//! the local histograms ([`LocalParams`]) at the end of the header and of the forest, for a
//! forest that splits on them (feature indices past the energy grid); a forest that does not is
//! still written as version 3, so older builds keep reading it, and an older build refuses a
//! version-4 file by its version instead of misreading its splits. Writes go to a temporary
//! file in the same directory, are flushed and synced, then renamed over the target, so a reader
//! never sees a half-written model. Every failure to read is a typed [`ForestError`].

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::compact::CompactTree;
use super::params::RandomForestParams;
use super::reference::ModelReference;
use super::{ForestError, RandomForest};
use crate::descriptor::{EnergyGrid, LocalParams};

/// Magic bytes at the start of a model file.
pub const MODEL_MAGIC: [u8; 8] = *b"SFOREST\0";
/// Current model file format version (written for a forest with local histograms; one without
/// is written as version 3, which is the same layout without them).
pub const MODEL_FORMAT_VERSION: u32 = 4;
/// The oldest format version this build still reads (version 1 has no reference table).
pub const MODEL_FORMAT_OLDEST: u32 = 1;
/// The format's own head in the frame: the version (`u32`).
const HEAD_LEN: usize = 4;
const PREFIX_LEN: usize = crate::fsutil::frame_prefix_len(HEAD_LEN);

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
    /// Settings of the local histograms the trees also split on (none: WKS only; absent
    /// before format version 4).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub local: Option<LocalParams>,
}

/// The payload of versions 1 and 2: the forest with its trees' full node records.
#[derive(Serialize, Deserialize)]
struct Payload {
    header: ModelHeader,
    forest: RandomForest,
}

/// The payload of version 3 (written): [`RandomForest`]'s fields with compact trees.
#[derive(Serialize)]
struct PayloadV3Out<'a> {
    header: ModelHeader,
    forest: ForestV3Out<'a>,
}

#[derive(Serialize)]
struct ForestV3Out<'a> {
    params: &'a RandomForestParams,
    n_labels: usize,
    k: usize,
    grid: EnergyGrid,
    trees: Vec<CompactTree>,
    next_tree_index: u64,
    reference: &'a Option<ModelReference>,
    #[serde(skip_serializing_if = "Option::is_none")]
    local: Option<LocalParams>,
}

/// The payload of version 3 (read).
#[derive(Deserialize)]
struct PayloadV3 {
    header: ModelHeader,
    forest: ForestV3,
}

#[derive(Deserialize)]
struct ForestV3 {
    params: RandomForestParams,
    n_labels: usize,
    k: usize,
    grid: EnergyGrid,
    trees: Vec<CompactTree>,
    next_tree_index: u64,
    reference: Option<ModelReference>,
    #[serde(default)]
    local: Option<LocalParams>,
}

impl ForestV3 {
    fn into_forest(self) -> Result<RandomForest, ForestError> {
        use rayon::prelude::*;
        let trees = self
            .trees
            .par_iter()
            .enumerate()
            .map(|(i, t)| t.decode().map_err(|e| ForestError::CorruptModel(format!("tree {i}: {e}"))))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(RandomForest {
            params: self.params,
            n_labels: self.n_labels,
            k: self.k,
            grid: self.grid,
            trees,
            next_tree_index: self.next_tree_index,
            reference: self.reference,
            local: self.local,
        })
    }
}

/// FNV-1a 64-bit hash (detects any single-byte change).
///
/// ```
/// use shapeforest::forest::fnv1a64;
/// assert_eq!(fnv1a64(b""), 0xcbf29ce484222325);
/// assert_ne!(fnv1a64(b"a"), fnv1a64(b"b"));
/// ```
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    crate::fsutil::fnv1a64(bytes)
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
            local: self.local,
        }
    }

    /// Encodes the model as bytes (the file format described in the module docs: version
    /// [`MODEL_FORMAT_VERSION`] for a forest with local histograms, 3 for one without).
    pub fn to_bytes(&self) -> Result<Vec<u8>, ForestError> {
        self.to_bytes_version(if self.local.is_some() { MODEL_FORMAT_VERSION } else { 3 })
    }

    /// Encodes the model in format `version` (2, 3 or 4): version 2 for a reader that predates
    /// version 3, and to measure what the compact trees save. Versions 2 and 3 cannot hold a
    /// forest with local histograms (an error says so).
    pub fn to_bytes_version(&self, version: u32) -> Result<Vec<u8>, ForestError> {
        use rayon::prelude::*;
        let encode_error = |e: String| ForestError::CorruptModel(format!("cannot encode: {e}"));
        if self.local.is_some() && version < 4 {
            return Err(ForestError::UnsupportedVersion {
                found: version,
                oldest: 4,
                supported: MODEL_FORMAT_VERSION,
            });
        }
        let payload = match version {
            2 => rmp_serde::to_vec(&Payload { header: self.header(), forest: self.clone() })
                .map_err(|e| encode_error(e.to_string()))?,
            3 | 4 => {
                let trees = self
                    .trees
                    .par_iter()
                    .map(CompactTree::encode)
                    .collect::<Result<Vec<_>, _>>()
                    .map_err(encode_error)?;
                let forest = ForestV3Out {
                    params: &self.params,
                    n_labels: self.n_labels,
                    k: self.k,
                    grid: self.grid,
                    trees,
                    next_tree_index: self.next_tree_index,
                    reference: &self.reference,
                    local: self.local,
                };
                rmp_serde::to_vec(&PayloadV3Out { header: self.header(), forest })
                    .map_err(|e| encode_error(e.to_string()))?
            }
            v => {
                return Err(ForestError::UnsupportedVersion {
                    found: v,
                    oldest: 2,
                    supported: MODEL_FORMAT_VERSION,
                })
            }
        };
        Ok(crate::fsutil::frame(&MODEL_MAGIC, &version.to_le_bytes(), &payload))
    }

    /// Decodes a model from bytes, checking magic, version, length, checksum and the forest's
    /// internal consistency.
    pub fn from_bytes(bytes: &[u8]) -> Result<RandomForest, ForestError> {
        if bytes.len() < 8 || bytes[..8] != MODEL_MAGIC {
            return Err(ForestError::NotAModel);
        }
        let Some(frame) = crate::fsutil::unframe(bytes, HEAD_LEN) else {
            return Err(ForestError::Truncated { expected: PREFIX_LEN, found: bytes.len() });
        };
        let version = u32::from_le_bytes([frame.head[0], frame.head[1], frame.head[2], frame.head[3]]);
        if !(MODEL_FORMAT_OLDEST..=MODEL_FORMAT_VERSION).contains(&version) {
            return Err(ForestError::UnsupportedVersion {
                found: version,
                oldest: MODEL_FORMAT_OLDEST,
                supported: MODEL_FORMAT_VERSION,
            });
        }
        let expected = (PREFIX_LEN as u64).saturating_add(frame.declared_len);
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
        let payload = frame.payload;
        if !frame.checksum_ok() {
            return Err(ForestError::ChecksumMismatch { expected: frame.checksum, found: fnv1a64(payload) });
        }
        let corrupt = |e: rmp_serde::decode::Error| ForestError::CorruptModel(e.to_string());
        let (header, forest) = if version >= 3 {
            let p: PayloadV3 = rmp_serde::from_slice(payload).map_err(corrupt)?;
            if version == 3 && (p.header.local.is_some() || p.forest.local.is_some()) {
                return Err(ForestError::CorruptModel(
                    "a version-3 file with local-histogram settings".into(),
                ));
            }
            (p.header, p.forest.into_forest()?)
        } else {
            let p: Payload = rmp_serde::from_slice(payload).map_err(corrupt)?;
            (p.header, p.forest)
        };
        if header != forest.header() {
            return Err(ForestError::CorruptModel("header does not match the forest".into()));
        }
        forest.validate().map_err(ForestError::CorruptModel)?;
        Ok(forest)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::forest::{labels_identity, TrainingSet, TrainingShape};
    use crate::synth::{creature_family, CreatureParams};

    /// The forest as format version 1 laid it out: no reference table.
    #[derive(Serialize)]
    struct ForestV1<'a> {
        params: &'a RandomForestParams,
        n_labels: usize,
        k: usize,
        grid: EnergyGrid,
        trees: &'a [super::super::tree::Tree],
        next_tree_index: u64,
    }

    #[derive(Serialize)]
    struct PayloadV1<'a> {
        header: ModelHeader,
        forest: ForestV1<'a>,
    }

    #[test]
    fn version_2_files_are_still_read_and_version_3_predicts_the_same() {
        let fam =
            creature_family(&CreatureParams { target_vertices: 1500, ..Default::default() }, 2).unwrap();
        let p = crate::spectral::SpectrumParams::new(30);
        let spectra: Vec<_> = fam
            .shapes
            .iter()
            .map(|s| std::sync::Arc::new(crate::spectral::compute_spectrum(s, &p).unwrap()))
            .collect();
        let n = fam.template.n_vertices();
        let shape = |i: usize| TrainingShape::new(format!("s{i}"), spectra[i].clone(), labels_identity(n));
        let set = TrainingSet::new(vec![shape(0)], n).unwrap();
        let forest = RandomForest::params().n_trees(4).seed(3).fit(&set).unwrap();
        let v2 = forest.to_bytes_version(2).unwrap();
        let v3 = forest.to_bytes().unwrap();
        assert_eq!(u32::from_le_bytes([v3[8], v3[9], v3[10], v3[11]]), 3);
        let (from_v2, from_v3) =
            (RandomForest::from_bytes(&v2).unwrap(), RandomForest::from_bytes(&v3).unwrap());
        assert_eq!(from_v2, forest);
        assert_eq!(from_v3, forest, "same nodes, leaves and numbering");
        let (a, b) = (forest.predict(&spectra[1]).unwrap(), from_v3.predict(&spectra[1]).unwrap());
        for m in 0..n {
            let ((la, pa), (lb, pb)) = (a.posterior(m), b.posterior(m));
            assert_eq!(la, lb);
            assert!(pa.iter().zip(pb).all(|(x, y)| x.to_bits() == y.to_bits()), "vertex {m}");
        }
        // Implicit indices, labels in the node records: well under half the full records.
        assert!(
            v3.len() * 2 < v2.len(),
            "v3 {} bytes, v2 {} (leaf support {})",
            v3.len(),
            v2.len(),
            forest.mean_leaf_support()
        );
    }

    #[test]
    fn a_forest_with_local_histograms_is_version_4_splits_on_them_and_round_trips() {
        let fam =
            creature_family(&CreatureParams { target_vertices: 1200, ..Default::default() }, 2).unwrap();
        let p = crate::spectral::SpectrumParams::new(20);
        let local = crate::descriptor::LocalParams { radius: 0.1, ..Default::default() };
        let n = fam.template.n_vertices();
        let shapes: Vec<TrainingShape> = fam
            .shapes
            .iter()
            .enumerate()
            .map(|(i, m)| {
                let sp = std::sync::Arc::new(crate::spectral::compute_spectrum(m, &p).unwrap());
                TrainingShape::new(format!("s{i}"), sp, labels_identity(n))
                    .with_local(m, Some(&local))
                    .unwrap()
            })
            .collect();
        let set = TrainingSet::new(vec![shapes[0].clone()], n).unwrap();
        let forest = RandomForest::params().n_trees(3).seed(2).local_share(0.5).fit(&set).unwrap();
        assert_eq!(forest.local(), Some(&local));
        let levels = forest.grid.levels;
        let local_nodes = forest
            .trees
            .iter()
            .flat_map(|t| &t.nodes)
            .filter(|nd| nd.k_bar > 0 && nd.energy >= levels)
            .count();
        let wks_nodes = forest
            .trees
            .iter()
            .flat_map(|t| &t.nodes)
            .filter(|nd| nd.k_bar > 0 && nd.energy < levels)
            .count();
        assert!(local_nodes > 0 && wks_nodes > 0, "{local_nodes} local and {wks_nodes} WKS splits");
        let bytes = forest.to_bytes().unwrap();
        assert_eq!(u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]), 4);
        assert!(matches!(forest.to_bytes_version(3), Err(ForestError::UnsupportedVersion { found: 3, .. })));
        let read = RandomForest::from_bytes(&bytes).unwrap();
        assert_eq!(read, forest);
        assert_eq!(read.header().local, Some(local));
        // Prediction needs the mesh, and the model read back predicts the same.
        let (mesh, sp) = (&fam.shapes[1], &shapes[1].spectrum);
        let e = forest.predict(sp).unwrap_err();
        assert!(e.to_string().contains("mesh"), "{e}");
        let (a, b) = (forest.predict_mesh(mesh, sp).unwrap(), read.predict_mesh(mesh, sp).unwrap());
        assert_eq!(a.map_labels(), b.map_labels());
        // A descriptor without the histograms is refused by such a forest.
        let wks_only = RandomForest::params()
            .n_trees(1)
            .fit(&TrainingSet::new(vec![TrainingShape::new("w", sp.clone(), labels_identity(n))], n).unwrap())
            .unwrap();
        let plain = wks_only.descriptor(sp).unwrap();
        assert!(forest.predict_descriptor(&plain).is_err());
        // A WKS-only forest is still written as version 3, which older builds read.
        let v = wks_only.to_bytes().unwrap();
        assert_eq!(u32::from_le_bytes([v[8], v[9], v[10], v[11]]), 3);
        // A version-4 file whose local nodes point past the histogram's bins is refused.
        let mut bad = forest.clone();
        let node = bad.trees[0].nodes.iter_mut().find(|nd| nd.k_bar > 0).unwrap();
        node.energy = levels + local.dim() as u32;
        node.k_bar = 1;
        let e = RandomForest::from_bytes(&bad.to_bytes().unwrap()).unwrap_err();
        assert!(e.to_string().contains("malformed"), "{e}");
    }

    /// The hyper-parameters as builds before format version 4 decode them (no `local_share`).
    #[derive(Deserialize)]
    #[allow(dead_code)]
    struct ParamsV3 {
        n_trees: usize,
        max_depth: usize,
        min_samples_split: usize,
        min_samples_leaf: usize,
        candidates_per_node: usize,
        min_entropy: f64,
        bagging_fraction: f64,
        k_min: usize,
        energy_levels: u32,
        wks_n_energies: usize,
        wks_sigma_factor: f64,
        trees_per_update: usize,
        parallel_node_size: usize,
        seed: u64,
    }

    #[derive(Deserialize)]
    #[allow(dead_code)]
    struct HeaderV3 {
        params: ParamsV3,
        n_labels: usize,
        k: usize,
        grid: EnergyGrid,
        n_trees: usize,
    }

    #[derive(Deserialize)]
    #[allow(dead_code)]
    struct OlderForest {
        params: ParamsV3,
        n_labels: usize,
        k: usize,
        grid: EnergyGrid,
        trees: Vec<CompactTree>,
        next_tree_index: u64,
        reference: Option<ModelReference>,
    }

    #[derive(Deserialize)]
    #[allow(dead_code)]
    struct OlderPayload {
        header: HeaderV3,
        forest: OlderForest,
    }

    /// One synthetic shape of 800 vertices with identity labels and 20 eigenpairs.
    fn one_shape_set() -> TrainingSet {
        let fam = creature_family(&CreatureParams { target_vertices: 800, ..Default::default() }, 1).unwrap();
        let sp = crate::spectral::compute_spectrum(&fam.shapes[0], &crate::spectral::SpectrumParams::new(20))
            .unwrap();
        let n = fam.template.n_vertices();
        TrainingSet::new(vec![TrainingShape::new("a", std::sync::Arc::new(sp), labels_identity(n))], n)
            .unwrap()
    }

    #[test]
    fn a_forest_without_local_histograms_is_the_file_older_builds_read() {
        let set = one_shape_set();
        // A share set without histograms has no meaning and is not stored.
        let forest = RandomForest::params().n_trees(2).local_share(0.4).fit(&set).unwrap();
        let bytes = forest.to_bytes().unwrap();
        assert_eq!(u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]), 3);
        let frame = crate::fsutil::unframe(&bytes, HEAD_LEN).unwrap();
        let old: Result<OlderPayload, _> = rmp_serde::from_slice(frame.payload);
        assert!(old.is_ok(), "an older build's decoder: {:?}", old.err());
        assert_eq!(RandomForest::from_bytes(&bytes).unwrap(), forest);
    }

    #[test]
    fn version_1_files_are_still_read() {
        let set = one_shape_set();
        let forest = RandomForest::params().n_trees(2).fit(&set).unwrap();
        let v1 = PayloadV1 {
            header: forest.header(),
            forest: ForestV1 {
                params: &forest.params,
                n_labels: forest.n_labels,
                k: forest.k,
                grid: forest.grid,
                trees: &forest.trees,
                next_tree_index: forest.next_tree_index,
            },
        };
        let payload = rmp_serde::to_vec(&v1).unwrap();
        let mut bytes = MODEL_MAGIC.to_vec();
        bytes.extend_from_slice(&1u32.to_le_bytes());
        bytes.extend_from_slice(&(payload.len() as u64).to_le_bytes());
        bytes.extend_from_slice(&fnv1a64(&payload).to_le_bytes());
        bytes.extend_from_slice(&payload);
        let read = RandomForest::from_bytes(&bytes).unwrap();
        assert_eq!(read, forest);
        assert!(read.reference().is_none());
    }
}
