//! Training-set augmentation with partiality (the paper's thesis that the learning absorbs
//! deformations the training set shows): each labelled shape is also presented as seeded
//! perturbed copies (holes, single-view scans, crops; see [`crate::mesh::perturb`]), so the
//! forest's splits pick descriptor components that survive missing surface.
//!
//! A copy is prepared as a scan would be: its largest connected component, its small holes
//! closed before the spectrum is computed (as `regularizer::ScanPart` closes a scan's), the
//! spectrum normalised by the area of the whole shape (the training shape is complete, so its
//! area is the body's), and labelled through the perturbation's vertex map.

use std::sync::Arc;

use rayon::prelude::*;

use super::{ForestError, TrainingShape};
use crate::{
    descriptor::LocalParams,
    mesh::{fill_holes, largest_component, perturb, perturbations_name, Mesh, Perturbation},
    spectral::{spectrum_cached, Spectrum, SpectrumCache, SpectrumParams},
};

/// A perturbed copy of a labelled shape as a training shape: `perturbations` applied with
/// `seed`, the largest component kept, its holes of perimeter at most
/// `fill_perimeter·√area(mesh)` closed for the spectrum (`None`: left open; a scan's are closed
/// at `regularizer::ScanPart::FILL_PERIMETER` of the reference's), its spectrum (through
/// `cache` when given) normalised by the area of `mesh` and restricted to the part's vertices,
/// its vertices labelled as in `labels` (one entry per vertex of `mesh`), with the part's local
/// histograms when `local` is given.
#[allow(clippy::too_many_arguments)]
pub fn augmented_shape(
    name: &str,
    mesh: &Mesh,
    labels: &[Option<u32>],
    perturbations: &[Perturbation],
    seed: u64,
    fill_perimeter: Option<f64>,
    spectrum: &SpectrumParams,
    cache: Option<&SpectrumCache>,
    local: Option<&LocalParams>,
) -> Result<TrainingShape, ForestError> {
    let p = perturb(mesh, perturbations, seed)?;
    let (part, kept) = match largest_component(&p.mesh) {
        Some((m, k)) => (m, k.iter().map(|&v| p.kept[v]).collect::<Vec<_>>()),
        None => (p.mesh, p.kept),
    };
    let area = mesh.surface_area();
    // The closed mesh keeps the part's vertices first, so its spectrum restricted to them is
    // the part's.
    let closed = fill_perimeter.map(|f| fill_holes(&part, f * area.sqrt())).filter(|(_, n)| *n > 0);
    let sp: Spectrum = spectrum_cached(closed.as_ref().map_or(&part, |(m, _)| m), spectrum, cache)?;
    let sp = sp.renormalised(area).restricted(part.n_vertices());
    let shape = TrainingShape::new(
        format!("{name}~{}#{seed}", perturbations_name(perturbations)),
        Arc::new(sp),
        kept.iter().map(|&v| labels.get(v).copied().flatten()).collect(),
    );
    shape.with_local(&part, local)
}

/// What every copy of [`augmented_copies`] shares.
#[derive(Clone, Copy, Debug)]
pub struct Augmentation<'a> {
    /// The kinds (each a list of perturbations applied together).
    pub kinds: &'a [Vec<Perturbation>],
    /// Copies of each kind.
    pub copies: usize,
    /// See [`augmented_shape`].
    pub fill_perimeter: Option<f64>,
    /// The copies' spectra.
    pub spectrum: &'a SpectrumParams,
    /// Where spectra are cached, if anywhere.
    pub cache: Option<&'a SpectrumCache>,
    /// The local histograms' settings, when the forest splits on them (each copy gets its own,
    /// computed on the part).
    pub local: Option<&'a LocalParams>,
}

/// The perturbed copies of one labelled shape: `copies` of every kind ([`augmented_shape`]),
/// kind by kind, built in parallel. Copy `c` of kind `k` is seeded by `seed` and the shape's
/// `shape_key` (its index in a training set; 0 where `seed` already tells the shapes apart):
/// `seed ^ (shape_key << 32 | k << 16 | c) · 0x9e3779b97f4a7c15`.
pub fn augmented_copies(
    name: &str,
    mesh: &Mesh,
    labels: &[Option<u32>],
    augmentation: &Augmentation<'_>,
    seed: u64,
    shape_key: u64,
) -> Vec<Result<TrainingShape, ForestError>> {
    let copy_seed = |k: usize, c: usize| {
        seed ^ (shape_key << 32 | (k as u64) << 16 | c as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15)
    };
    let a = augmentation;
    let jobs: Vec<(usize, usize)> =
        (0..a.kinds.len()).flat_map(|k| (0..a.copies).map(move |c| (k, c))).collect();
    jobs.par_iter()
        .map(|&(k, c)| {
            augmented_shape(
                name,
                mesh,
                labels,
                &a.kinds[k],
                copy_seed(k, c),
                a.fill_perimeter,
                a.spectrum,
                a.cache,
                a.local,
            )
        })
        .collect()
}
