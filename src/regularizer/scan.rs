//! The part of a scan that is matched: a scan in pieces is matched on its largest connected
//! component, and an open, partial scan is normalised by the reference's area (see
//! [`normalising_area`]); a map of the part is extended to the whole scan by nearest vertex
//! ([`crate::mesh::extend_map_by_nearest`]).

use std::sync::Arc;

use super::normalising_area;
use crate::{
    mesh::{extend_map_by_nearest, fill_holes, largest_component, Mesh},
    spectral::Spectrum,
};

/// The matched part of a scan.
#[derive(Clone, Debug)]
pub struct ScanPart {
    /// The part (the scan itself when it is connected).
    pub mesh: Arc<Mesh>,
    /// `kept[i]`: the scan vertex that part vertex `i` is (`None`: the part is the scan).
    pub kept: Option<Vec<usize>>,
    /// Connected components of the scan.
    pub components: usize,
}

impl ScanPart {
    /// Holes of a scan whose perimeter is at most this fraction of the reference's `√area` are
    /// closed before its spectrum is computed (a round hole of radius ~0.055·√area).
    pub const FILL_PERIMETER: f64 = 0.35;

    /// The part of `scan` to match: its largest connected component when it has several.
    pub fn of(scan: &Arc<Mesh>) -> ScanPart {
        let components = crate::mesh::vertex_components(scan).1.len();
        match largest_component(scan) {
            Some((mesh, kept)) => ScanPart { mesh: Arc::new(mesh), kept: Some(kept), components },
            None => ScanPart { mesh: scan.clone(), kept: None, components },
        }
    }

    /// The mesh the part's spectrum is computed on: the part with its holes of perimeter at
    /// most `max_perimeter` closed ([`fill_holes`]; its first vertices are the part's), or
    /// `None` when no hole is that small. A small hole changes every eigenfunction a little
    /// (the descriptors are global); closed, the surface is nearly the whole body's again.
    pub fn filled(&self, max_perimeter: f64) -> Option<Arc<Mesh>> {
        let (mesh, closed) = fill_holes(&self.mesh, max_perimeter);
        (closed > 0).then(|| Arc::new(mesh))
    }

    /// The spectrum of the part for matching, from the spectrum of `spectrum_mesh` (the part,
    /// or its [`ScanPart::filled`] mesh): normalised by [`normalising_area`] of `spectrum_mesh`
    /// against `reference_area`, restricted to the part's vertices. Returns it with the ratio
    /// of the area used to the part's own.
    pub fn spectrum_for_matching(
        &self,
        spectrum_mesh: &Mesh,
        spectrum: Spectrum,
        reference_area: f64,
    ) -> (Spectrum, f64) {
        let area = normalising_area(spectrum_mesh, reference_area);
        let ratio = area / self.mesh.surface_area();
        (spectrum.renormalised(area).restricted(self.mesh.n_vertices()), ratio)
    }

    /// The mesh to compute the part's spectrum on, for a reference of area `reference_area`:
    /// the part with its holes of perimeter at most [`ScanPart::FILL_PERIMETER`]`·√reference_area`
    /// closed, or the part itself when none is that small; with the number of holes closed.
    pub fn spectrum_mesh(&self, reference_area: f64) -> (Arc<Mesh>, usize) {
        let (mesh, closed) = fill_holes(&self.mesh, Self::FILL_PERIMETER * reference_area.sqrt());
        if closed > 0 {
            (Arc::new(mesh), closed)
        } else {
            (self.mesh.clone(), 0)
        }
    }

    /// Whether the part is the scan as it is (connected; nothing to restrict or extend).
    pub fn is_whole(&self) -> bool {
        self.kept.is_none()
    }

    /// A map of the part as a map of the whole `scan`.
    pub fn extend(&self, scan: &Mesh, map: Vec<usize>) -> Vec<usize> {
        match &self.kept {
            Some(k) => extend_map_by_nearest(scan, k, &map),
            None => map,
        }
    }

    /// Vertices of the scan outside the matched part.
    pub fn unmatched_vertices(&self, scan: &Mesh) -> usize {
        scan.n_vertices() - self.mesh.n_vertices()
    }
}
