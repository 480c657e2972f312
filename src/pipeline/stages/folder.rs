//! `folder`: a folder listed once; its meshes (sorted by name, numbers compared as numbers),
//! optionally with their labels.

use std::path::PathBuf;

use serde::Deserialize;

use crate::pipeline::{
    actor::{Emitter, Source},
    config::{parse_config, AnyPort, Builder, PortType, StageConfig, StageType},
    error::Error,
    message::{shape_stem, Envelope, Failure, InputFile, Job, LabelSpec},
    store::{is_mesh_file, label_sidecar, natural_key, read_dir_sorted},
};

impl StageConfig for FolderConfig {
    const TYPE: StageType = StageType {
        name: "folder",
        ports: (None, Some(PortType::File)),
        parse: parse_config::<FolderConfig>,
    };
    fn build(&self, b: &mut Builder<'_>, input: Option<AnyPort>) -> Result<Option<AnyPort>, Error> {
        if input.is_some() {
            return Err(b.wrong_input());
        }
        let mut c = self.clone();
        c.folder = b.resolve(&c.folder);
        let name = b.stage.name.clone();
        Ok(Some(AnyPort::File(b.pipeline.source(&name, FolderSource::new(c)))))
    }
}

/// How a folder source finds the labels of its shapes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Labels {
    /// Scans: no labels.
    #[default]
    None,
    /// A sidecar per mesh: `NAME.labels` (per vertex) or `NAME.vts` (per label, 1-based).
    Sidecar,
    /// Label = vertex index (classes sharing one vertex indexing, e.g. TOSCA, SCAPE).
    Identity,
}

/// Settings of a `folder` source.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FolderConfig {
    /// The folder (relative paths are taken from the pipeline's data folder).
    pub folder: PathBuf,
    /// Only meshes whose name starts with this.
    #[serde(default)]
    pub prefix: Option<String>,
    /// Only these shapes (file stems), in this order.
    #[serde(default)]
    pub names: Option<Vec<String>>,
    /// Skip this many meshes (after sorting by name, numbers in names compared as numbers).
    #[serde(default)]
    pub skip: usize,
    /// At most this many meshes.
    #[serde(default)]
    pub take: Option<usize>,
    /// Where the labels come from.
    #[serde(default)]
    pub labels: Labels,
}

/// Lists a folder once and emits its meshes.
pub struct FolderSource {
    config: FolderConfig,
}

impl FolderSource {
    /// A folder source; `config.folder` must already be resolved.
    pub fn new(config: FolderConfig) -> Self {
        Self { config }
    }

    /// The meshes it will emit, in order.
    pub fn files(&self) -> Result<Vec<PathBuf>, Error> {
        let c = &self.config;
        let entries = read_dir_sorted(&c.folder)
            .map_err(|e| Error::BadInput(format!("cannot list the folder: {e}")))?;
        let mut files: Vec<PathBuf> = entries
            .into_iter()
            .filter(|p| p.is_file() && is_mesh_file(p))
            .filter(|p| c.prefix.as_ref().is_none_or(|pre| shape_stem(p).starts_with(pre.as_str())))
            .collect();
        files.sort_by_key(|p| natural_key(&shape_stem(p)));
        if let Some(names) = &c.names {
            let mut chosen = Vec::new();
            for n in names {
                match files.iter().find(|p| &shape_stem(p) == n) {
                    Some(p) => chosen.push(p.clone()),
                    None => {
                        return Err(Error::BadInput(format!("no mesh named `{n}` in {}", c.folder.display())))
                    }
                }
            }
            files = chosen;
        }
        let files: Vec<PathBuf> = files.into_iter().skip(c.skip).take(c.take.unwrap_or(usize::MAX)).collect();
        if files.is_empty() {
            return Err(Error::BadInput(format!(
                "no mesh files (.off .obj .ply .vert, optionally .gz) in {}",
                c.folder.display()
            )));
        }
        Ok(files)
    }
}

impl Source for FolderSource {
    type Out = InputFile;

    fn run(&mut self, out: &Emitter<InputFile>) -> Result<(), Error> {
        for path in self.files()? {
            let labels = match self.config.labels {
                Labels::None => None,
                Labels::Identity => Some(LabelSpec::Identity),
                Labels::Sidecar => label_sidecar(&path).map(LabelSpec::File),
            };
            let mut job = Job::for_file(out.next_job_id(), &path, None);
            let body = match (&self.config.labels, labels) {
                (Labels::Sidecar, None) => Err(Failure::bad_input(
                    "source",
                    format!("{}: no label map beside it (NAME.labels or NAME.vts)", path.display()),
                )),
                (_, labels) => {
                    if let Some(LabelSpec::File(f)) = &labels {
                        job.labels_file = Some(f.clone());
                    }
                    Ok(InputFile { path, labels })
                }
            };
            if !out.emit(Envelope { job, body }) {
                break;
            }
        }
        Ok(())
    }
}
