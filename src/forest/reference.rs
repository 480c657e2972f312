//! Where a model's labels lie on its reference shape.
//!
//! A forest predicts labels; a dense map needs reference vertices. For a class with shared
//! vertex indexing the label *is* the reference vertex, but a model trained from per-label maps
//! (`.vts` files of remeshed TOSCA, FAUST or SCAPE, each shape triangulated on its own) needs a
//! table `label → reference vertex`. [`reference_table`] builds it from the reference's own
//! label map:
//! 1. **exact**: from the per-label rows when the reference has them (row `k` = the vertex of
//!    label `k`; several labels may share one vertex, as in the remeshed sets), else from the
//!    first vertex carrying each label;
//! 2. **filled**: a label the reference does not carry but another training shape (a *donor*)
//!    does, at vertex `v`, takes the reference vertex of the label nearest to `v` on the donor
//!    (Dijkstra along the donor's edges) among the labels the reference carries;
//! 3. **unused**: a label no shape carries is never predicted by the forest; it maps to vertex 0
//!    and is counted.
//!
//! [`ModelReference`] is that table with the reference's name and a fingerprint of its mesh
//! (vertex count and [`Mesh::content_hash`]), stored in the model file so that `match` can use
//! any labelled training shape as the reference and refuses a different mesh instead of
//! writing a wrong map.

use serde::{Deserialize, Serialize};

use crate::geodesic::dijkstra_nearest_source;
use crate::mesh::Mesh;

use super::ForestError;

/// The reference shape a model maps onto: its name, a fingerprint of its mesh and the vertex of
/// every label.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelReference {
    /// The reference shape's name (file stem).
    pub name: String,
    /// Vertices of the reference mesh.
    pub n_vertices: usize,
    /// [`Mesh::content_hash`] of the reference mesh.
    pub mesh_hash: u64,
    /// `label_to_vertex[label]` = the reference vertex of `label`.
    pub label_to_vertex: Vec<u32>,
    /// The training shapes share one vertex indexing and the labels are vertex indices
    /// (`label_to_vertex` is the identity): any mesh of the class with `n_vertices` vertices
    /// can serve as the reference, not only this one.
    pub shared_indexing: bool,
    /// The reference's left/right self-map (`symmetry[v]`: the vertex at the mirror image of
    /// `v`), when the training data gave one (a `.sym.vts` beside the reference's `.vts`); with
    /// it the regulariser repairs mirrored maps ([`crate::regularizer::unflip`]). Absent in
    /// files written before it existed.
    #[serde(default)]
    pub symmetry: Option<Vec<u32>>,
}

impl ModelReference {
    /// A reference from a name, its mesh and a table built by [`reference_table`].
    pub fn new(name: impl Into<String>, mesh: &Mesh, table: &LabelTable) -> Self {
        ModelReference {
            name: name.into(),
            n_vertices: mesh.n_vertices(),
            mesh_hash: mesh.content_hash(),
            label_to_vertex: table.table.iter().map(|&v| v as u32).collect(),
            shared_indexing: false,
            symmetry: None,
        }
    }

    /// The reference of a shared-indexing class (labels = vertex indices of every shape).
    pub fn shared_indexing(name: impl Into<String>, mesh: &Mesh) -> Self {
        ModelReference {
            name: name.into(),
            n_vertices: mesh.n_vertices(),
            mesh_hash: mesh.content_hash(),
            label_to_vertex: (0..mesh.n_vertices() as u32).collect(),
            shared_indexing: true,
            symmetry: None,
        }
    }

    /// The label → vertex table to use with `mesh` as the reference: this table when `mesh` is
    /// the stored reference, the identity for another shape of a shared-indexing class, `None`
    /// for any other mesh (its own label map is then needed).
    pub fn table_for(&self, mesh: &Mesh) -> Option<Vec<usize>> {
        if self.is_mesh(mesh) {
            Some(self.table())
        } else if self.shared_indexing && mesh.n_vertices() == self.n_vertices {
            Some((0..self.n_vertices).collect())
        } else {
            None
        }
    }

    /// Whether `mesh` is this reference (same vertex count and content hash).
    pub fn is_mesh(&self, mesh: &Mesh) -> bool {
        mesh.n_vertices() == self.n_vertices && mesh.content_hash() == self.mesh_hash
    }

    /// The table as reference-vertex indices.
    pub fn table(&self) -> Vec<usize> {
        self.label_to_vertex.iter().map(|&v| v as usize).collect()
    }

    /// The same reference with its left/right self-map (one entry per reference vertex, each a
    /// vertex of the reference; see [`ModelReference::symmetry`]).
    pub fn with_symmetry(mut self, symmetry: &[usize]) -> Result<Self, ForestError> {
        if symmetry.len() != self.n_vertices || symmetry.iter().any(|&v| v >= self.n_vertices) {
            return Err(ForestError::IncompatibleModel(format!(
                "a symmetry map of {} entries for a reference of {} vertices",
                symmetry.len(),
                self.n_vertices
            )));
        }
        self.symmetry = Some(symmetry.iter().map(|&v| v as u32).collect());
        Ok(self)
    }

    /// The self-map as reference-vertex indices, when stored.
    pub fn symmetry_map(&self) -> Option<Vec<usize>> {
        self.symmetry.as_ref().map(|s| s.iter().map(|&v| v as usize).collect())
    }

    /// Checks the table against a label count (used when a model file is read).
    pub(crate) fn validate(&self, n_labels: usize) -> Result<(), String> {
        if self.label_to_vertex.len() != n_labels {
            return Err(format!(
                "reference table has {} entries for {n_labels} labels",
                self.label_to_vertex.len()
            ));
        }
        if let Some(&v) = self.label_to_vertex.iter().find(|&&v| v as usize >= self.n_vertices) {
            return Err(format!(
                "reference table names vertex {v} of a {}-vertex reference",
                self.n_vertices
            ));
        }
        if let Some(s) = &self.symmetry {
            if s.len() != self.n_vertices || s.iter().any(|&v| v as usize >= self.n_vertices) {
                return Err(format!(
                    "reference symmetry has {} entries (or names a vertex outside) for a {}-vertex reference",
                    s.len(),
                    self.n_vertices
                ));
            }
        }
        Ok(())
    }
}

/// A label → reference-vertex table and how each entry was found.
#[derive(Clone, Debug, PartialEq)]
pub struct LabelTable {
    /// `table[label]` = reference vertex.
    pub table: Vec<usize>,
    /// Labels the reference carries itself.
    pub exact: usize,
    /// Labels placed through a donor shape's nearest carried label.
    pub filled: usize,
    /// Labels no shape carries (never predicted; mapped to vertex 0).
    pub unused: usize,
}

/// Per-label rows of a `.vts`-style map (row `k` = the vertex of label `k`, `None` where a row is
/// blank or names no vertex); `one_based` says the file counts vertices from 1. Unlike
/// [`read_per_label_map`](super::read_per_label_map), several labels on one vertex are all kept.
///
/// ```
/// use shapeforest::forest::read_per_label_rows;
/// let rows = read_per_label_rows("3\n3\n0\n1\n".as_bytes(), true, 4).unwrap();
/// assert_eq!(rows, vec![Some(2), Some(2), None, Some(0)]);
/// assert!(read_per_label_rows("5\n".as_bytes(), true, 4).is_err());
/// ```
pub fn read_per_label_rows<R: std::io::BufRead>(
    reader: R,
    one_based: bool,
    n_vertices: usize,
) -> Result<Vec<Option<u32>>, ForestError> {
    let mut rows = Vec::new();
    let mut first: Option<(u32, usize)> = None;
    let mut one_vertex = true;
    for (k, line) in reader.lines().enumerate() {
        let bad = |reason: String| ForestError::LabelMap { line: k + 1, reason };
        let line = line.map_err(|e| bad(format!("cannot read: {e}")))?;
        // Signs of a corrupt or misread map are errors naming the line: more than one value
        // on a line, a negative index other than the none marker, every label on one vertex.
        let mut toks = line.split_whitespace();
        let tok = toks.next().unwrap_or("");
        if toks.next().is_some() {
            return Err(bad(format!(
                "{} values on one line; a per-label map holds one vertex per line",
                line.split_whitespace().count()
            )));
        }
        if tok.is_empty() {
            rows.push(None);
            continue;
        }
        if k >= u32::MAX as usize {
            return Err(bad("too many labels".into()));
        }
        let v: i64 = tok.parse().map_err(|_| {
            bad(format!("expected a vertex index, found {}", crate::limits::excerpt(tok.as_bytes(), 24)))
        })?;
        let none = if one_based { 0 } else { -1 };
        if v == none {
            rows.push(None);
            continue;
        }
        if v < none {
            return Err(bad(format!(
                "vertex {tok} is negative (only {none} marks a label without a vertex{})",
                if one_based { "; indices are 1-based" } else { "" }
            )));
        }
        let v = if one_based { v - 1 } else { v };
        if v as usize >= n_vertices {
            return Err(bad(format!(
                "vertex {tok} is out of range for a mesh of {n_vertices} vertices ({})",
                if one_based {
                    "1-based, the .vts convention"
                } else {
                    "read 0-based; .vts files are 1-based"
                }
            )));
        }
        match first {
            None => first = Some((v as u32, k + 1)),
            Some((f, _)) if f != v as u32 => one_vertex = false,
            _ => {}
        }
        rows.push(Some(v as u32));
    }
    let placed = rows.iter().flatten().count();
    if let (Some((v, line)), true, true) = (first, one_vertex, placed >= 2) {
        return Err(ForestError::LabelMap {
            line,
            reason: format!("all {placed} labels are on vertex {v}: a sign of a corrupt map"),
        });
    }
    Ok(rows)
}

/// Builds the label → vertex table of a reference with `n_labels` labels (see the module docs).
///
/// `labels` are the reference's per-vertex labels; `rows`, when given, its per-label rows (they
/// take precedence). `donors` are other training shapes with their per-vertex labels. Fails when
/// the reference carries no label at all.
///
/// ```
/// use shapeforest::forest::reference_table;
/// let path = shapeforest::mesh::Mesh::new(
///     vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 1.0, 0.0]],
///     vec![[0, 1, 3], [1, 2, 3]],
/// ).unwrap();
/// // The reference carries labels 0 and 2; a donor also carries label 1, next to label 2.
/// let reference = [Some(0), None, Some(2), None];
/// let donor = [Some(0), None, Some(2), Some(1)];
/// let t = reference_table(4, &path, &reference, None, &[(&path, &donor)]).unwrap();
/// assert_eq!(t.table[..3], [0, 2, 2]);
/// assert_eq!((t.exact, t.filled, t.unused), (2, 1, 1));
/// ```
pub fn reference_table(
    n_labels: usize,
    reference: &Mesh,
    labels: &[Option<u32>],
    rows: Option<&[Option<u32>]>,
    donors: &[(&Mesh, &[Option<u32>])],
) -> Result<LabelTable, ForestError> {
    let n_ref = reference.n_vertices();
    let mut table: Vec<Option<usize>> = vec![None; n_labels];
    if let Some(rows) = rows {
        for (l, r) in rows.iter().enumerate().take(n_labels) {
            if let Some(v) = r.filter(|&v| (v as usize) < n_ref) {
                table[l] = Some(v as usize);
            }
        }
    }
    for (v, l) in labels.iter().enumerate().take(n_ref) {
        if let Some(slot) = l.and_then(|l| table.get_mut(l as usize)) {
            slot.get_or_insert(v);
        }
    }
    let exact = table.iter().filter(|t| t.is_some()).count();
    if exact == 0 {
        return Err(ForestError::IncompatibleModel(
            "the reference carries none of the model's labels".to_string(),
        ));
    }
    let mut filled = 0;
    for (mesh, donor) in donors {
        if table.iter().all(Option::is_some) {
            break;
        }
        let n = mesh.n_vertices().min(donor.len());
        // Donor vertices whose label the reference carries are the sources.
        let sources: Vec<usize> = (0..n)
            .filter(|&v| donor[v].is_some_and(|l| table.get(l as usize).is_some_and(|t| t.is_some())))
            .collect();
        if sources.is_empty() {
            continue;
        }
        let Ok((_, nearest)) = dijkstra_nearest_source(mesh, &sources) else { continue };
        let known = table.clone();
        for v in 0..n {
            let Some(l) = donor[v] else { continue };
            let Some(slot) = table.get_mut(l as usize) else { continue };
            if slot.is_some() || nearest[v] == usize::MAX {
                continue;
            }
            let source_label = donor[sources[nearest[v]]].map(|l| l as usize);
            if let Some(r) = source_label.and_then(|sl| known[sl]) {
                *slot = Some(r);
                filled += 1;
            }
        }
    }
    let unused = table.iter().filter(|t| t.is_none()).count();
    Ok(LabelTable { table: table.into_iter().map(|t| t.unwrap_or(0)).collect(), exact, filled, unused })
}
