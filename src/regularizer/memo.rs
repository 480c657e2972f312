//! What a prepared shape makes once from its mesh and spectra and then reuses: farthest-point
//! sample cells, orientation descriptors, the extrinsic step's single-precision bases and
//! coordinate tree. Every regularisation from or onto the shape reads them: a reference serves
//! many scans, a scan is regularised several times (the sparse and dense steps, several
//! refinements, votes).
//!
//! A kept value is tied to the mesh and spectra it was made from: once [`PreparedShape::mesh`],
//! [`PreparedShape::spectrum`] or [`PreparedShape::zoomout_spectrum`] is replaced, it is made
//! again. (The weak handles keep the allocations, so their addresses cannot be reused while a
//! value is kept: a replaced mesh or spectrum never matches.)

use std::sync::{Arc, Mutex, MutexGuard, Weak};

use faer::Mat;

use super::{extrinsic::CoordinateTree, orientation::OrientationSide, PreparedShape};
use crate::{fmap::SampleCells, mesh::Mesh, spectral::Spectrum};

/// What a prepared shape keeps (see the module documentation).
#[derive(Default)]
pub(super) struct Kept {
    /// Farthest-point samples and their cells, per sample count.
    pub(super) cells: Memo<usize, SampleCells>,
    /// Orientation descriptors, per band energies (chosen on the reference's spectrum).
    pub(super) orientation: Memo<Vec<f64>, OrientationSide>,
    /// The ZoomOut basis's first `k` functions in single precision as rows (`k × n`), per `k`.
    pub(super) rows: Memo<usize, Mat<f32>>,
    /// The ZoomOut basis's first `k` functions weighted by the mass, in single precision
    /// (`n × k`), per `k`.
    pub(super) weighted: Memo<usize, Mat<f32>>,
    /// The mean step along the mesh's edges of the coordinates (in units of `√area`) and of the
    /// ZoomOut basis's first `k` functions, per `k`.
    pub(super) edge_steps: Memo<usize, (f64, f64)>,
    /// The coordinates in units of `√area` and their kd-tree.
    pub(super) coordinates: Memo<(), CoordinateTree>,
}

/// The mesh and spectra of a prepared shape a value was made from.
struct Sources {
    mesh: Weak<Mesh>,
    spectrum: Weak<Spectrum>,
    zoomout: Option<Weak<Spectrum>>,
}

impl Sources {
    fn of(shape: &PreparedShape) -> Self {
        Self {
            mesh: Arc::downgrade(&shape.mesh),
            spectrum: Arc::downgrade(&shape.spectrum),
            zoomout: shape.zoomout_spectrum.as_ref().map(Arc::downgrade),
        }
    }

    fn are_of(&self, shape: &PreparedShape) -> bool {
        let zoomout = match (&self.zoomout, &shape.zoomout_spectrum) {
            (None, None) => true,
            (Some(kept), Some(now)) => kept.as_ptr() == Arc::as_ptr(now),
            _ => false,
        };
        zoomout
            && self.mesh.as_ptr() == Arc::as_ptr(&shape.mesh)
            && self.spectrum.as_ptr() == Arc::as_ptr(&shape.spectrum)
    }
}

/// Values by key, made once per key from a shape's current mesh and spectra; at most `limit`
/// kept (the oldest dropped first).
pub(super) struct Memo<K, V> {
    entries: Mutex<Vec<(K, Sources, Arc<V>)>>,
    limit: usize,
}

impl<K: PartialEq, V> Memo<K, V> {
    pub(super) fn new(limit: usize) -> Self {
        Self { entries: Mutex::new(Vec::new()), limit: limit.max(1) }
    }

    fn lock(&self) -> MutexGuard<'_, Vec<(K, Sources, Arc<V>)>> {
        self.entries.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The value kept for `key` on `shape`'s current mesh and spectra, or the one `make` makes
    /// (then kept). Not held locked while making: two threads asking at once may both make it.
    pub(super) fn get_or_make<E>(
        &self,
        shape: &PreparedShape,
        key: K,
        make: impl FnOnce() -> Result<V, E>,
    ) -> Result<Arc<V>, E> {
        if let Some((_, _, v)) = self.lock().iter().find(|(k, s, _)| *k == key && s.are_of(shape)) {
            return Ok(v.clone());
        }
        let made = Arc::new(make()?);
        let mut entries = self.lock();
        entries.retain(|(_, s, _)| s.are_of(shape));
        if entries.len() >= self.limit {
            entries.remove(0);
        }
        entries.push((key, Sources::of(shape), made.clone()));
        Ok(made)
    }
}

impl<K: PartialEq, V> Memo<K, V> {
    /// [`Memo::get_or_make`] with a `make` that cannot fail.
    pub(super) fn get_or_insert_with(
        &self,
        shape: &PreparedShape,
        key: K,
        make: impl FnOnce() -> V,
    ) -> Arc<V> {
        match self.get_or_make(shape, key, || Ok::<_, std::convert::Infallible>(make())) {
            Ok(v) => v,
            Err(never) => match never {},
        }
    }
}

impl<K: PartialEq, V> Default for Memo<K, V> {
    fn default() -> Self {
        Self::new(8)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{geodesic::HeatParams, spectral::compute_spectrum, synth::icosphere};

    fn shape() -> PreparedShape {
        let mesh = Arc::new(icosphere(1, 1.0));
        let spectrum = compute_spectrum(&mesh, &crate::spectral::SpectrumParams::new(6))
            .expect("spectrum of an icosphere");
        PreparedShape::new(mesh, Arc::new(spectrum), HeatParams::default()).expect("prepared")
    }

    #[test]
    fn a_kept_value_is_made_once_and_again_after_the_mesh_or_spectrum_is_replaced() {
        let mut shape = shape();
        let memo: Memo<usize, usize> = Memo::new(2);
        let made = std::cell::Cell::new(0);
        let get = |shape: &PreparedShape, key: usize| {
            *memo.get_or_insert_with(shape, key, || {
                made.set(made.get() + 1);
                key * 10
            })
        };
        assert_eq!((get(&shape, 1), get(&shape, 1)), (10, 10));
        assert_eq!(get(&shape, 2), 20);
        // The limit: the oldest goes.
        assert_eq!(get(&shape, 3), 30);
        assert_eq!(get(&shape, 1), 10);
        // A replaced spectrum (the same values, another allocation) makes every value again.
        shape.spectrum = Arc::new((*shape.spectrum).clone());
        assert_eq!(get(&shape, 3), 30);
        shape.zoomout_spectrum = Some(shape.spectrum.clone());
        assert_eq!(get(&shape, 3), 30);
        assert_eq!(made.get(), 6);
    }

    #[test]
    fn a_failure_to_make_keeps_nothing() {
        let shape = shape();
        let memo: Memo<(), u8> = Memo::default();
        assert_eq!(memo.get_or_make(&shape, (), || Err("no")), Err("no"));
        assert_eq!(*memo.get_or_make(&shape, (), || Ok::<_, ()>(7)).unwrap(), 7);
    }
}
