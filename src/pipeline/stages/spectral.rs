//! `spectral`: [`Shape`] → [`SpectralShape`] (the first K Laplace–Beltrami eigenpairs), with an
//! optional on-disk cache keyed by mesh content.

use std::{path::PathBuf, sync::Arc};

use serde::Deserialize;

use crate::{
    pipeline::{
        actor::Stage,
        config::{parse_config, AnyPort, Builder, PortType, StageConfig, StageType},
        error::Error,
        message::{Failure, Job, Shape, SpectralShape},
    },
    spectral::{spectrum_cached, SpectrumCache, SpectrumParams},
};

impl StageConfig for SpectralConfig {
    const TYPE: StageType = StageType {
        name: "spectral",
        ports: (Some(PortType::Shape), Some(PortType::Spectrum)),
        parse: parse_config::<SpectralConfig>,
    };
    fn build(&self, b: &mut Builder<'_>, input: Option<AnyPort>) -> Result<Option<AnyPort>, Error> {
        let Some(AnyPort::Shape(i)) = input else { return Err(b.wrong_input()) };
        let stage = SpectralStage::new(self, Some(b.data.cache())).map_err(|e| b.error(e))?;
        let name = b.stage.name.clone();
        Ok(Some(AnyPort::Spectrum(b.pipeline.stage(&name, i, stage))))
    }
}

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
    pub fn new(config: &SpectralConfig, cache_dir: Option<PathBuf>) -> Result<Self, Error> {
        let params = SpectrumParams::new(config.k);
        params.check()?;
        let cache = match cache_dir {
            Some(d) if config.cache => Some(SpectrumCache::new(d)?),
            _ => None,
        };
        Ok(Self { params, cache })
    }
}

impl Stage for SpectralStage {
    type In = Shape;
    type Out = SpectralShape;

    fn process(&mut self, job: &mut Job, shape: Shape) -> Result<SpectralShape, Failure> {
        let spectrum = spectrum_cached(&shape.mesh, &self.params, self.cache.as_ref())
            .map_err(|e| Failure::bad_input("spectral", format!("{}: {e}", job.display_source())))?;
        Ok(SpectralShape { shape, spectrum: Arc::new(spectrum) })
    }
}
