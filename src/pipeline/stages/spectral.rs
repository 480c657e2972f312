//! `spectral`: [`Shape`] → [`SpectralShape`] (the first K Laplace–Beltrami eigenpairs), with an
//! optional on-disk cache keyed by mesh content.

use std::{path::PathBuf, sync::Arc};

use serde::Deserialize;

use crate::{
    pipeline::{
        actor::Stage,
        message::{Failure, Job, Shape, SpectralShape},
    },
    spectral::{compute_spectrum, SpectrumCache, SpectrumParams},
};

/// Settings of `spectral`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpectralConfig {
    /// Eigenpairs. Default 100.
    #[serde(default = "default_k")]
    pub k: usize,
    /// Cache spectra in the data folder's `cache/`. Default true.
    #[serde(default = "default_true")]
    pub cache: bool,
}

fn default_k() -> usize {
    100
}
fn default_true() -> bool {
    true
}

impl Default for SpectralConfig {
    fn default() -> Self {
        Self { k: default_k(), cache: true }
    }
}

/// Computes spectra.
pub struct SpectralStage {
    params: SpectrumParams,
    cache: Option<SpectrumCache>,
}

impl SpectralStage {
    /// A spectral stage; `cache_dir` is used when given.
    pub fn new(config: &SpectralConfig, cache_dir: Option<PathBuf>) -> Result<Self, String> {
        let params = SpectrumParams::new(config.k);
        params.check().map_err(|e| e.to_string())?;
        let cache = match cache_dir {
            Some(d) if config.cache => Some(SpectrumCache::new(d).map_err(|e| e.to_string())?),
            _ => None,
        };
        Ok(Self { params, cache })
    }
}

impl Stage for SpectralStage {
    type In = Shape;
    type Out = SpectralShape;

    fn process(&mut self, job: &mut Job, shape: Shape) -> Result<SpectralShape, Failure> {
        let r = match &self.cache {
            Some(c) => c.get_or_compute(&shape.mesh, &self.params),
            None => compute_spectrum(&shape.mesh, &self.params),
        };
        let spectrum =
            r.map_err(|e| Failure::bad_input("spectral", format!("{}: {e}", job.display_source())))?;
        Ok(SpectralShape { shape, spectrum: Arc::new(spectrum) })
    }
}
