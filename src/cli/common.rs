//! Helpers shared by the subcommands: loading meshes and spectra, progress bars.

use std::{
    path::{Path, PathBuf},
    sync::Arc,
    time::Duration,
};

use anyhow::{bail, Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use shapeforest::{
    mesh::{read_mesh_with_report, Mesh},
    spectral::{spectrum_cached, Spectrum, SpectrumCache, SpectrumParams},
};

/// The local-histogram flags, shared by `train` and `eval` (README, "Local histograms").
#[derive(Debug, clap::Args)]
pub struct LocalFlags {
    /// Let the forest split on local histograms of the surface (SHOT-like, in a ball of
    /// --local-radius·√area): for partial scans (single views, large holes). Matching then
    /// reads the scan's mesh.
    #[arg(long)]
    pub local_descriptors: bool,
    /// Support radius of the local histograms, as a fraction of √area.
    #[arg(long, default_value_t = 0.07, value_name = "R", requires = "local_descriptors")]
    pub local_radius: f64,
    /// With --local-descriptors, the share of split candidates drawn from the local histograms'
    /// bins (the rest from the parametric WKS).
    #[arg(long, default_value_t = 1.0, value_name = "S", requires = "local_descriptors")]
    pub local_share: f64,
}

impl LocalFlags {
    /// The histograms' settings when asked for, checked.
    pub fn params(&self) -> Result<Option<shapeforest::descriptor::LocalParams>> {
        if !self.local_descriptors {
            return Ok(None);
        }
        let p = shapeforest::descriptor::LocalParams { radius: self.local_radius, ..Default::default() };
        p.check().context("--local-radius")?;
        Ok(Some(p))
    }
}

/// Mesh file extensions the readers understand (optionally followed by `.gz`).
const MESH_EXTENSIONS: [&str; 5] = ["off", "obj", "ply", "vert", "tri"];

/// Whether `path` names a mesh file by its extension.
pub fn is_mesh_file(path: &Path) -> bool {
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("").to_ascii_lowercase();
    let name = name.strip_suffix(".gz").unwrap_or(&name);
    // A TOSCA pair counts once, by its .vert file.
    MESH_EXTENSIONS.iter().filter(|&&e| e != "tri").any(|e| name.ends_with(&format!(".{e}")))
}

/// Mesh files in `dir` whose file name starts with `prefix`, sorted by name.
pub fn mesh_files(dir: &Path, prefix: &str) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for entry in
        std::fs::read_dir(dir).with_context(|| format!("cannot read the folder {}", dir.display()))?
    {
        let path = entry?.path();
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
        if path.is_file() && name.starts_with(prefix) && is_mesh_file(&path) {
            out.push(path);
        }
    }
    out.sort();
    if out.is_empty() {
        bail!(
            "no mesh files (.off, .obj, .ply, .vert, optionally .gz) starting with {prefix:?} in {}",
            dir.display()
        );
    }
    Ok(out)
}

/// Short display name of a mesh file: the file name without mesh extensions (the one stem
/// rule, [`shapeforest::pipeline::shape_stem`]).
pub fn shape_name(path: &Path) -> String {
    shapeforest::pipeline::shape_stem(path)
}

/// Reads a mesh, logging the reader's warnings.
pub fn load_mesh(path: &Path) -> Result<Mesh> {
    let (mesh, report) = read_mesh_with_report(path)?;
    for w in &report.warnings {
        tracing::warn!(file = %path.display(), "{w}");
    }
    Ok(mesh)
}

/// Computes (or fetches from `cache`) the spectra of several meshes, in parallel, with a bar.
pub fn spectra(meshes: &[&Mesh], k: usize, cache: Option<&Path>, label: &str) -> Result<Vec<Arc<Spectrum>>> {
    let params = SpectrumParams::new(k);
    let cache = cache.map(SpectrumCache::new).transpose()?;
    let bar = progress(meshes.len() as u64, label);
    let out: Result<Vec<_>> = meshes
        .par_iter()
        .map(|m| {
            let s = spectrum_cached(m, &params, cache.as_ref())?;
            bar.inc(1);
            Ok(Arc::new(s))
        })
        .collect();
    bar.finish_and_clear();
    out
}

/// A progress bar on stderr (hidden when stderr is not a terminal).
pub fn progress(len: u64, label: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template("{prefix:>12} [{bar:30}] {pos}/{len} {elapsed}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_prefix(label.to_string());
    bar.enable_steady_tick(Duration::from_millis(200));
    bar
}
