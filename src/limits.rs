//! Limits on what untrusted input may make the program allocate, and the helpers that keep
//! input bytes and names from leaking into reports unescaped.
//!
//! Every size a file declares or implies is checked against a [`Limits`] value *before* the
//! memory it needs is allocated: a mesh file's size before it is read, its vertex and face
//! counts before a spectrum is computed, a label value before a label table is built, and every
//! dimension of a decoded model before it is used. The daemon reads its limits from the
//! pipeline file's `[settings.limits]` table; the command-line tools use the defaults.
//!
//! ```
//! use shapeforest::limits::{excerpt, Limits};
//! let l = Limits::default();
//! assert!(l.max_file_bytes >= 1 << 30);
//! assert_eq!(excerpt(b"ok\n\x1b[2J", 40), "\"ok\\n\\x1b[2J\"");
//! ```

use serde::{Deserialize, Serialize};

/// Limits on input sizes (see the module documentation). Each has a default sized for meshes
/// of a few million vertices on a machine with a few GiB of memory.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Limits {
    /// Largest mesh or label file, in bytes, on disk and after gzip decompression. Default
    /// 1 GiB.
    pub max_file_bytes: u64,
    /// Most vertices of a mesh. Default 2,000,000.
    pub max_vertices: usize,
    /// Most triangles of a mesh. Default 8,000,000.
    pub max_faces: usize,
    /// Most labels in a label set (every label value must be below it). Default 2,000,000.
    pub max_labels: usize,
    /// Largest model file, in bytes. Default 4 GiB.
    pub max_model_bytes: u64,
    /// Most eigenpairs (K) a model may use. Default 1000.
    pub max_k: usize,
    /// Most levels of a model's energy grid. Default 4096 (models use 256).
    pub max_energy_levels: u32,
    /// Most trees in a model. Default 1000.
    pub max_trees: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_file_bytes: 1 << 30,
            max_vertices: 2_000_000,
            max_faces: 8_000_000,
            max_labels: 2_000_000,
            max_model_bytes: 4 << 30,
            max_k: 1000,
            max_energy_levels: 4096,
            max_trees: 1000,
        }
    }
}

impl Limits {
    /// Checks that no limit is zero (the error names the key).
    pub fn check(&self) -> Result<(), String> {
        let zero = [
            ("max_file_bytes", self.max_file_bytes == 0),
            ("max_vertices", self.max_vertices == 0),
            ("max_faces", self.max_faces == 0),
            ("max_labels", self.max_labels == 0),
            ("max_model_bytes", self.max_model_bytes == 0),
            ("max_k", self.max_k == 0),
            ("max_energy_levels", self.max_energy_levels == 0),
            ("max_trees", self.max_trees == 0),
        ];
        match zero.iter().find(|z| z.1) {
            Some((k, _)) => Err(format!("limits.{k} must be at least 1")),
            None => Ok(()),
        }
    }

    /// Checks every dimension of a decoded model against the limits, so that a model file with
    /// a valid checksum but forged sizes is refused before anything is allocated for it.
    pub fn check_model(&self, forest: &crate::forest::RandomForest) -> Result<(), String> {
        let grid = forest.energy_grid();
        let checks = [
            (forest.k() > self.max_k, format!("K = {} exceeds limits.max_k = {}", forest.k(), self.max_k)),
            (
                grid.levels > self.max_energy_levels,
                format!(
                    "its energy grid has {} levels, above limits.max_energy_levels = {}",
                    grid.levels, self.max_energy_levels
                ),
            ),
            (
                forest.n_labels() > self.max_labels,
                format!("{} labels exceed limits.max_labels = {}", forest.n_labels(), self.max_labels),
            ),
            (
                forest.n_trees() > self.max_trees,
                format!("{} trees exceed limits.max_trees = {}", forest.n_trees(), self.max_trees),
            ),
        ];
        if let Some((_, why)) = checks.into_iter().find(|c| c.0) {
            return Err(format!("the model is outside the limits: {why}"));
        }
        // The reference table (format version 2): one vertex per label, on a mesh within the
        // vertex limit.
        if let Some(r) = forest.reference() {
            if r.n_vertices > self.max_vertices {
                return Err(format!(
                    "the model is outside the limits: its reference has {} vertices, above limits.max_vertices = {}",
                    r.n_vertices, self.max_vertices
                ));
            }
            if r.label_to_vertex.len() != forest.n_labels() {
                return Err(format!(
                    "the model's reference table has {} entries for {} labels",
                    r.label_to_vertex.len(),
                    forest.n_labels()
                ));
            }
            if let Some(v) = r.label_to_vertex.iter().find(|&&v| v as usize >= r.n_vertices) {
                return Err(format!(
                    "the model's reference table names vertex {v} of a reference with {} vertices",
                    r.n_vertices
                ));
            }
        }
        Ok(())
    }
}

/// A short, quoted, printable excerpt of raw input bytes for an error message: at most
/// `max_chars` characters of printable ASCII, everything else escaped (`\n`, `\xNN`), `…` when
/// cut. Reports never quote more of a file than this.
///
/// ```
/// use shapeforest::limits::excerpt;
/// assert_eq!(excerpt(b"abc", 40), "\"abc\"");
/// assert_eq!(excerpt(b"abcdef", 3), "\"abc…\"");
/// assert_eq!(excerpt("é".as_bytes(), 40), "\"\\xc3\\xa9\"");
/// ```
pub fn excerpt(bytes: &[u8], max_chars: usize) -> String {
    let mut out = String::from("\"");
    for (shown, &b) in bytes.iter().enumerate() {
        if shown >= max_chars {
            out.push('…');
            break;
        }
        match b {
            b'\n' => out.push_str("\\n"),
            b'\r' => out.push_str("\\r"),
            b'\t' => out.push_str("\\t"),
            b'"' => out.push_str("\\\""),
            b'\\' => out.push_str("\\\\"),
            0x20..=0x7e => out.push(b as char),
            _ => out.push_str(&format!("\\x{b:02x}")),
        }
    }
    out.push('"');
    out
}

/// A file name made safe for a line-based output (a map header, a log line): control
/// characters and backslashes are escaped, so a name can never start a new line.
///
/// ```
/// use shapeforest::limits::escape_name;
/// assert_eq!(escape_name("scan\n0 0 0.off"), "scan\\n0 0 0.off");
/// assert_eq!(escape_name("plain-name.off"), "plain-name.off");
/// ```
pub fn escape_name(name: &str) -> String {
    let mut out = String::with_capacity(name.len());
    for c in name.chars() {
        match c {
            '\\' => out.push_str("\\\\"),
            c if c.is_control() => out.extend(c.escape_default()),
            c => out.push(c),
        }
    }
    out
}
