//! Training-set augmentation with partiality (the paper's thesis that the learning absorbs
//! deformations the training set shows): each labelled shape is also presented as seeded
//! perturbed copies (holes, single-view scans, crops; see [`crate::mesh::perturb`]), so the
//! forest's splits pick descriptor components that survive missing surface.
//!
//! A copy is matched as a scan would be: its largest connected component, normalised by the
//! area of the whole shape (the training shape is complete, so its area is the body's), and
//! labelled through the perturbation's vertex map.

use std::sync::Arc;

use super::{ForestError, TrainingShape};
use crate::{
    mesh::{largest_component, perturb, perturbations_name, Mesh, Perturbation},
    spectral::{spectrum_cached, Spectrum, SpectrumCache, SpectrumParams},
};

/// A perturbed copy of a labelled shape as a training shape: `perturbations` applied with
/// `seed`, the largest component kept, its spectrum (through `cache` when given) normalised by
/// the area of `mesh`, its vertices labelled as in `labels` (one entry per vertex of `mesh`).
pub fn augmented_shape(
    name: &str,
    mesh: &Mesh,
    labels: &[Option<u32>],
    perturbations: &[Perturbation],
    seed: u64,
    spectrum: &SpectrumParams,
    cache: Option<&SpectrumCache>,
) -> Result<TrainingShape, ForestError> {
    let p = perturb(mesh, perturbations, seed)?;
    let (part, kept) = match largest_component(&p.mesh) {
        Some((m, k)) => (m, k.iter().map(|&v| p.kept[v]).collect::<Vec<_>>()),
        None => (p.mesh, p.kept),
    };
    let sp: Spectrum = spectrum_cached(&part, spectrum, cache)?;
    let sp = sp.renormalised(mesh.surface_area());
    Ok(TrainingShape {
        name: format!("{name}~{}#{seed}", perturbations_name(perturbations)),
        spectrum: Arc::new(sp),
        labels: kept.iter().map(|&v| labels.get(v).copied().flatten()).collect(),
    })
}
