//! `spectral`: [`Shape`] → [`SpectralShape`] (the first K Laplace–Beltrami eigenpairs), with an
//! optional on-disk cache keyed by mesh content.

use std::{path::PathBuf, sync::Arc};

use serde::Deserialize;

use crate::{
    mesh::Mesh,
    pipeline::{
        actor::Stage,
        config::{parse_config, AnyPort, Builder, PortType, StageConfig, StageType},
        error::Error,
        message::{Failure, Job, PartialScan, Shape, SpectralShape},
        model::LiveModel,
    },
    regularizer::{normalising_area, ScanPart},
    spectral::{spectrum_cached, Spectrum, SpectrumCache, SpectrumParams},
};

impl StageConfig for SpectralConfig {
    const TYPE: StageType = StageType {
        name: "spectral",
        ports: (Some(PortType::Shape), Some(PortType::Spectrum)),
        parse: parse_config::<SpectralConfig>,
    };
    fn build(&self, b: &mut Builder<'_>, input: Option<AnyPort>) -> Result<Option<AnyPort>, Error> {
        let Some(AnyPort::Shape(i)) = input else { return Err(b.wrong_input()) };
        let stage =
            SpectralStage::new(self, Some(b.data.cache())).map_err(|e| b.error(e))?.with_live(b.live.clone());
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

/// Computes spectra. A scan (a shape without labels) is matched on its part, as `shapeforest
/// match` does (see [`ScanPart`]): its largest connected piece, its small holes closed for the
/// spectrum, normalised by the live model's reference area when it is an open part of a body.
pub struct SpectralStage {
    params: SpectrumParams,
    cache: Option<SpectrumCache>,
    live: Option<Arc<LiveModel>>,
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
        Ok(Self { params, cache, live: None })
    }

    /// The same stage, reading the reference's area from `live` (without it, a scan is
    /// normalised by its own area).
    pub fn with_live(self, live: Arc<LiveModel>) -> Self {
        Self { live: Some(live), ..self }
    }

    fn spectrum(&self, job: &Job, mesh: &Mesh) -> Result<Spectrum, Failure> {
        spectrum_cached(mesh, &self.params, self.cache.as_ref())
            .map_err(|e| Failure::bad_input("spectral", format!("{}: {e}", job.display_source())))
    }
}

impl Stage for SpectralStage {
    type In = Shape;
    type Out = SpectralShape;

    fn process(&mut self, job: &mut Job, shape: Shape) -> Result<SpectralShape, Failure> {
        if shape.labels.is_some() {
            let spectrum = self.spectrum(job, &shape.mesh)?;
            return Ok(SpectralShape::whole(shape, Arc::new(spectrum)));
        }
        let part = ScanPart::of(&shape.mesh);
        let reference_area = match self.live.as_ref().and_then(|l| l.current()) {
            Some(model) => model.reference.mesh.surface_area(),
            None => part.mesh.surface_area(),
        };
        let (spectrum_mesh, holes_closed) = part.spectrum_mesh(reference_area);
        let spectrum = self.spectrum(job, &spectrum_mesh)?;
        if part.is_whole() && holes_closed == 0 {
            let own = spectrum_mesh.surface_area();
            if normalising_area(&spectrum_mesh, reference_area) == own {
                return Ok(SpectralShape::whole(shape, Arc::new(spectrum)));
            }
        }
        let (spectrum, scale_ratio) = part.spectrum_for_matching(&spectrum_mesh, spectrum, reference_area);
        if !part.is_whole() {
            tracing::warn!(
                job = job.id,
                "{}: {} connected components; matching the largest ({} of {} vertices), the other pieces take \
                 the match of their nearest matched vertex",
                job.display_source(),
                part.components,
                part.mesh.n_vertices(),
                shape.mesh.n_vertices()
            );
        }
        let matched = Shape { mesh: part.mesh.clone(), labels: None };
        let partial = PartialScan { scan: shape.mesh, part, holes_closed, scale_ratio };
        Ok(SpectralShape { shape: matched, spectrum: Arc::new(spectrum), partial: Some(Arc::new(partial)) })
    }
}
