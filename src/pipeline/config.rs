//! Pipelines as data: the `pipelines/*.toml` format, its validation, and building a
//! [`Pipeline`] from it.
//!
//! ```toml
//! name = "match"
//! description = "match every mesh of a folder against the newest model"
//!
//! [settings]
//! data_dir = "shapeforest-data"   # relative folders below are taken from here
//! channel_capacity = 2
//!
//! [[stage]]
//! name = "scans"
//! type = "folder"
//! folder = "incoming"
//!
//! [[stage]]
//! name = "read"
//! type = "ingest"
//! input = "scans"
//! # … spectral, descriptor, forest, matcher, fmap …
//! ```
//!
//! Every stage has a unique `name`, a `type`, an `input` (the stage whose output it consumes;
//! not for sources) and the settings of its type. Stage types, with what they consume → emit:
//!
//! | type | consumes | emits |
//! |---|---|---|
//! | `folder`, `watch-folder` | — | file |
//! | `synthetic` | — | shape |
//! | `ingest` | file | shape |
//! | `spectral` | shape | spectrum |
//! | `descriptor` | spectrum | descriptor |
//! | `forest` | descriptor | prediction |
//! | `matcher` | prediction | matches |
//! | `fmap` | matches | map |
//! | `match-sink`, `eval-sink` | map | — |
//! | `trainer` | spectrum | — |
//!
//! Validation reports every problem at once, each naming the file, the stage and the key.

use std::{
    collections::{HashMap, HashSet},
    fmt,
    path::{Path, PathBuf},
    sync::Arc,
};

use serde::Deserialize;

use super::{
    actor::PipelineContext,
    graph::{Pipeline, Port},
    message::{
        DescribedShape, InputFile, MatchedShape, PredictedShape, Shape, SparselyMatched, SpectralShape,
    },
    model::LiveModel,
    stages::*,
    store::DataDir,
};
use crate::geodesic::HeatParams;

/// What flows on an edge.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PortType {
    /// Input files.
    File,
    /// Meshes (with labels).
    Shape,
    /// Shapes with spectra.
    Spectrum,
    /// Forest descriptors.
    Descriptor,
    /// Forest predictions.
    Prediction,
    /// Sparse matches.
    Matches,
    /// Dense maps.
    Map,
}

impl fmt::Display for PortType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = match self {
            PortType::File => "file",
            PortType::Shape => "shape",
            PortType::Spectrum => "spectrum",
            PortType::Descriptor => "descriptor",
            PortType::Prediction => "prediction",
            PortType::Matches => "matches",
            PortType::Map => "map",
        };
        f.write_str(s)
    }
}

/// A stage's type and settings.
#[derive(Clone, Debug)]
pub enum StageKind {
    /// `folder`.
    Folder(FolderConfig),
    /// `watch-folder`.
    WatchFolder(WatchConfig),
    /// `synthetic`.
    Synthetic(SyntheticConfig),
    /// `ingest`.
    Ingest(IngestConfig),
    /// `spectral`.
    Spectral(SpectralConfig),
    /// `descriptor`.
    Descriptor,
    /// `forest`.
    Forest,
    /// `matcher`.
    Matcher(MatcherConfig),
    /// `fmap`.
    Fmap(FmapConfig),
    /// `match-sink`.
    MatchSink(MatchSinkConfig),
    /// `eval-sink`.
    EvalSink(EvalSinkConfig),
    /// `trainer`.
    Trainer(TrainerConfig),
}

/// The stage types, for messages.
pub const STAGE_TYPES: &[&str] = &[
    "folder",
    "watch-folder",
    "synthetic",
    "ingest",
    "spectral",
    "descriptor",
    "forest",
    "matcher",
    "fmap",
    "match-sink",
    "eval-sink",
    "trainer",
];

impl StageKind {
    /// The type's name in pipeline files.
    pub fn type_name(&self) -> &'static str {
        match self {
            StageKind::Folder(_) => "folder",
            StageKind::WatchFolder(_) => "watch-folder",
            StageKind::Synthetic(_) => "synthetic",
            StageKind::Ingest(_) => "ingest",
            StageKind::Spectral(_) => "spectral",
            StageKind::Descriptor => "descriptor",
            StageKind::Forest => "forest",
            StageKind::Matcher(_) => "matcher",
            StageKind::Fmap(_) => "fmap",
            StageKind::MatchSink(_) => "match-sink",
            StageKind::EvalSink(_) => "eval-sink",
            StageKind::Trainer(_) => "trainer",
        }
    }

    /// What it consumes (`None`: a source) and emits (`None`: a sink).
    pub fn ports(&self) -> (Option<PortType>, Option<PortType>) {
        ports_of(self.type_name()).unwrap_or((None, None))
    }

    fn parse(kind: &str, rest: toml::Table) -> Result<StageKind, String> {
        fn cfg<T: serde::de::DeserializeOwned>(rest: toml::Table) -> Result<T, String> {
            toml::Value::Table(rest).try_into::<T>().map_err(|e| e.message().to_string())
        }
        fn none(rest: toml::Table) -> Result<(), String> {
            match rest.keys().next() {
                Some(k) => Err(format!("unknown key `{k}` (this stage type takes no settings)")),
                None => Ok(()),
            }
        }
        Ok(match kind {
            "folder" => StageKind::Folder(cfg(rest)?),
            "watch-folder" => StageKind::WatchFolder(cfg(rest)?),
            "synthetic" => StageKind::Synthetic(cfg(rest)?),
            "ingest" => StageKind::Ingest(cfg(rest)?),
            "spectral" => StageKind::Spectral(cfg(rest)?),
            "descriptor" => {
                none(rest)?;
                StageKind::Descriptor
            }
            "forest" => {
                none(rest)?;
                StageKind::Forest
            }
            "matcher" => {
                let c: MatcherConfig = cfg(rest)?;
                check_regularizer(&regularizer_params(&c, &FmapConfig::default()))?;
                StageKind::Matcher(c)
            }
            "fmap" => {
                let c: FmapConfig = cfg(rest)?;
                check_regularizer(&regularizer_params(&MatcherConfig::default(), &c))?;
                StageKind::Fmap(c)
            }
            "match-sink" => StageKind::MatchSink(cfg(rest)?),
            "eval-sink" => StageKind::EvalSink(cfg(rest)?),
            "trainer" => {
                let c: TrainerConfig = cfg(rest)?;
                c.forest_params()?;
                StageKind::Trainer(c)
            }
            other => {
                return Err(format!("unknown stage type `{other}` (one of: {})", STAGE_TYPES.join(", ")))
            }
        })
    }
}

/// One stage of a pipeline file.
#[derive(Clone, Debug)]
pub struct StageSpec {
    /// Unique name.
    pub name: String,
    /// The stage it consumes (none for sources).
    pub input: Option<String>,
    /// Type and settings.
    pub kind: StageKind,
}

/// Settings for the whole pipeline.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Settings {
    /// The data folder; relative folders of stages are taken from it. Default `shapeforest-data`.
    #[serde(default = "default_data_dir")]
    pub data_dir: PathBuf,
    /// Capacity of every channel. Default 2.
    #[serde(default = "default_capacity")]
    pub channel_capacity: usize,
    /// Limits on input sizes (`[settings.limits]`; see [`crate::limits::Limits`]).
    #[serde(default)]
    pub limits: crate::limits::Limits,
}

fn default_data_dir() -> PathBuf {
    PathBuf::from("shapeforest-data")
}
fn default_capacity() -> usize {
    2
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            data_dir: default_data_dir(),
            channel_capacity: default_capacity(),
            limits: crate::limits::Limits::default(),
        }
    }
}

/// A validated pipeline file.
#[derive(Clone, Debug)]
pub struct PipelineSpec {
    /// Its name.
    pub name: String,
    /// What it does.
    pub description: String,
    /// Pipeline-wide settings.
    pub settings: Settings,
    /// Stages, in file order.
    pub stages: Vec<StageSpec>,
}

/// Problems found in a pipeline file, all of them.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ConfigError {
    /// The file (or `<text>`).
    pub file: String,
    /// One line per problem.
    pub problems: Vec<String>,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: invalid pipeline", self.file)?;
        for p in &self.problems {
            write!(f, "\n  - {p}")?;
        }
        Ok(())
    }
}

impl std::error::Error for ConfigError {}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFile {
    name: String,
    #[serde(default)]
    description: String,
    #[serde(default)]
    settings: Option<toml::Table>,
    #[serde(default)]
    stage: Vec<toml::Table>,
}

impl PipelineSpec {
    /// Reads and validates a pipeline file.
    pub fn from_file(path: &Path) -> Result<Self, ConfigError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path)
            .map_err(|e| ConfigError { file: file.clone(), problems: vec![format!("cannot read: {e}")] })?;
        Self::from_toml(&text, &file)
    }

    /// Parses and validates pipeline text; `file` names it in errors.
    ///
    /// ```
    /// use shapeforest::pipeline::PipelineSpec;
    /// let bad = r#"
    /// name = "x"
    /// [[stage]]
    /// name = "in"
    /// type = "folder"
    /// folder = "incoming"
    /// [[stage]]
    /// name = "spectra"
    /// type = "spectral"
    /// input = "in"
    /// kk = 3
    /// "#;
    /// let e = PipelineSpec::from_toml(bad, "x.toml").unwrap_err();
    /// let text = e.to_string();
    /// assert!(text.contains("stage `spectra`") && text.contains("kk"), "{text}");
    /// assert!(text.contains("takes shape but `in` emits file"), "{text}");
    /// ```
    pub fn from_toml(text: &str, file: &str) -> Result<Self, ConfigError> {
        let err = |problems: Vec<String>| ConfigError { file: file.to_string(), problems };
        let raw: RawFile = toml::from_str(text).map_err(|e| err(vec![e.to_string().trim().to_string()]))?;
        let mut problems = Vec::new();
        let settings = match raw.settings {
            None => Settings::default(),
            Some(t) => toml::Value::Table(t).try_into::<Settings>().unwrap_or_else(|e| {
                problems.push(format!("[settings]: {}", e.message()));
                Settings::default()
            }),
        };
        if settings.channel_capacity == 0 {
            problems.push("[settings]: channel_capacity must be at least 1".into());
        }
        if let Err(e) = settings.limits.check() {
            problems.push(format!("[settings]: {e}"));
        }
        let mut stages = Vec::new();
        let mut nodes = Vec::new();
        let mut seen_names = HashSet::new();
        for t in &raw.stage {
            if let Some(toml::Value::String(n)) = t.get("name") {
                if !seen_names.insert(n.clone()) {
                    problems.push(format!("stage `{n}`: the name is used twice"));
                }
            }
        }
        for (i, mut t) in raw.stage.into_iter().enumerate() {
            let mut take_str = |key: &str| -> Result<Option<String>, String> {
                match t.remove(key) {
                    None => Ok(None),
                    Some(toml::Value::String(s)) => Ok(Some(s)),
                    Some(v) => Err(format!("`{key}` must be a string, found {}", v.type_str())),
                }
            };
            let name = take_str("name");
            let kind = take_str("type");
            let input = take_str("input");
            let label = match &name {
                Ok(Some(n)) => format!("stage `{n}`"),
                _ => format!("stage #{}", i + 1),
            };
            let (name, kind, input) = match (name, kind, input) {
                (Ok(Some(n)), Ok(Some(k)), Ok(input)) => (n, k, input),
                (n, k, inp) => {
                    for (key, r) in [("name", &n), ("type", &k)] {
                        match r {
                            Ok(None) => problems.push(format!("{label}: missing `{key}`")),
                            Err(e) => problems.push(format!("{label}: {e}")),
                            _ => {}
                        }
                    }
                    if let Err(e) = inp {
                        problems.push(format!("{label}: {e}"));
                    }
                    continue;
                }
            };
            nodes.push(Node { name: name.clone(), input: input.clone(), ports: ports_of(&kind) });
            match StageKind::parse(&kind, t) {
                Ok(k) => stages.push(StageSpec { name, input, kind: k }),
                Err(e) => problems.push(format!("{label} ({kind}): {e}")),
            }
        }
        validate_graph(&nodes, &mut problems);
        if problems.is_empty() {
            Ok(Self { name: raw.name, description: raw.description, settings, stages })
        } else {
            Err(err(problems))
        }
    }

    /// Whether any stage watches a folder (a daemon).
    pub fn is_daemon(&self) -> bool {
        self.stages.iter().any(|s| matches!(s.kind, StageKind::WatchFolder(_)))
    }

    /// Whether a stage of this type is present.
    pub fn has(&self, pred: impl Fn(&StageKind) -> bool) -> bool {
        self.stages.iter().any(|s| pred(&s.kind))
    }
}

/// What graph validation needs of a stage; `ports` is `None` for an unknown type.
struct Node {
    name: String,
    input: Option<String>,
    ports: Option<(Option<PortType>, Option<PortType>)>,
}

/// The ports of a stage type, by name.
fn ports_of(kind: &str) -> Option<(Option<PortType>, Option<PortType>)> {
    use PortType::*;
    Some(match kind {
        "folder" | "watch-folder" => (None, Some(File)),
        "synthetic" => (None, Some(Shape)),
        "ingest" => (Some(File), Some(Shape)),
        "spectral" => (Some(Shape), Some(Spectrum)),
        "descriptor" => (Some(Spectrum), Some(Descriptor)),
        "forest" => (Some(Descriptor), Some(Prediction)),
        "matcher" => (Some(Prediction), Some(Matches)),
        "fmap" => (Some(Matches), Some(Map)),
        "match-sink" | "eval-sink" => (Some(Map), None),
        "trainer" => (Some(Spectrum), None),
        _ => return None,
    })
}

fn validate_graph(stages: &[Node], problems: &mut Vec<String>) {
    let mut by_name: HashMap<&str, &Node> = HashMap::new();
    for s in stages {
        by_name.entry(s.name.as_str()).or_insert(s); // a repeated name is reported elsewhere
    }
    if stages.is_empty() {
        problems.push("no stages: add [[stage]] tables".into());
        return;
    }
    let mut consumers: HashMap<&str, Vec<&str>> = HashMap::new();
    for s in stages {
        let takes = s.ports.map(|p| p.0);
        match (&s.input, takes) {
            (Some(_), Some(None)) => problems.push(format!("stage `{}`: a source takes no `input`", s.name)),
            (None, Some(Some(t))) => {
                problems.push(format!("stage `{}`: missing `input` (it takes {t})", s.name))
            }
            (Some(i), _) => match by_name.get(i.as_str()) {
                None => problems.push(format!("stage `{}`: `input` names no stage: `{i}`", s.name)),
                Some(p) => {
                    consumers.entry(p.name.as_str()).or_default().push(&s.name);
                    match (p.ports.map(|x| x.1), takes) {
                        (Some(None), _) => problems
                            .push(format!("stage `{}`: input `{i}` is a sink and emits nothing", s.name)),
                        (Some(Some(o)), Some(Some(t))) if o != t => {
                            problems.push(format!("stage `{}`: takes {t} but `{i}` emits {o}", s.name))
                        }
                        _ => {}
                    }
                }
            },
            _ => {}
        }
    }
    for s in stages {
        let users = consumers.get(s.name.as_str()).map_or(&[][..], |v| v.as_slice());
        match (s.ports.map(|p| p.1), users.len()) {
            (Some(Some(o)), 0) => problems.push(format!(
                "stage `{}`: its output ({o}) goes nowhere; add a stage with `input = \"{}\"`",
                s.name, s.name
            )),
            (_, n) if n > 1 => problems.push(format!(
                "stage `{}`: feeds {} stages ({}); an output goes to exactly one stage",
                s.name,
                n,
                users.join(", ")
            )),
            _ => {}
        }
    }
    // Everything must hang off a source (this also rules out cycles).
    let mut reached: HashSet<&str> =
        stages.iter().filter(|s| s.input.is_none()).map(|s| s.name.as_str()).collect();
    if !stages.iter().any(|s| s.input.is_none() && s.ports.is_some_and(|p| p.0.is_none())) {
        problems.push("no source stage (folder, watch-folder or synthetic)".into());
    }
    loop {
        let before = reached.len();
        for s in stages {
            if let Some(i) = &s.input {
                if reached.contains(i.as_str()) {
                    reached.insert(&s.name);
                }
            }
        }
        if reached.len() == before {
            break;
        }
    }
    // A stage no source reaches is either on a cycle (said once per cycle, naming it) or
    // downstream of a stage with a problem already reported (an unknown input): no more lines.
    let mut on_reported_cycle: HashSet<&str> = HashSet::new();
    for s in stages {
        if s.input.is_none()
            || reached.contains(s.name.as_str())
            || on_reported_cycle.contains(s.name.as_str())
        {
            continue;
        }
        let mut path: Vec<&str> = vec![s.name.as_str()];
        let mut at = s;
        while let Some(next) = at.input.as_deref().and_then(|i| by_name.get(i)) {
            if let Some(start) = path.iter().position(|n| *n == next.name) {
                let cycle = &path[start..];
                if cycle.iter().all(|n| !on_reported_cycle.contains(n)) {
                    // Listed in data-flow order: each stage feeds the next.
                    let mut flow: Vec<&str> = cycle.iter().rev().copied().collect();
                    flow.push(flow[0]);
                    problems.push(format!(
                        "stages {} form a cycle: each takes its input from the one before, so no \
                         source feeds them",
                        flow.iter().map(|n| format!("`{n}`")).collect::<Vec<_>>().join(" → ")
                    ));
                    on_reported_cycle.extend(cycle.iter().copied());
                }
                break;
            }
            path.push(next.name.as_str());
            at = next;
        }
    }
}

enum AnyPort {
    File(Port<InputFile>),
    Shape(Port<Shape>),
    Spectrum(Port<SpectralShape>),
    Descriptor(Port<DescribedShape>),
    Prediction(Port<PredictedShape>),
    Matches(Port<SparselyMatched>),
    Map(Port<MatchedShape>),
}

/// A folder of a stage, taken from the data folder when relative.
fn resolve(data: &DataDir, p: &Path) -> PathBuf {
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        data.root().join(p)
    }
}

/// Builds the pipeline a spec describes, over `data` and `live`. The heat-method settings are
/// shared by the trainer's reference and the matcher.
pub fn build(
    spec: &PipelineSpec,
    data: &DataDir,
    live: Arc<LiveModel>,
    ctx: PipelineContext,
) -> Result<Pipeline, String> {
    let heat = HeatParams::default();
    let mut p =
        Pipeline::with_context(data.clone(), live.clone(), ctx).with_capacity(spec.settings.channel_capacity);
    let shutdown = p.context().shutdown.clone();
    let mut outputs: HashMap<String, AnyPort> = HashMap::new();
    let mut done: HashSet<String> = HashSet::new();
    // Sources first, then any stage whose input is built, until all are.
    while done.len() < spec.stages.len() {
        let before = done.len();
        for s in &spec.stages {
            if done.contains(&s.name) {
                continue;
            }
            let input = match &s.input {
                None => None,
                Some(i) => match outputs.remove(i) {
                    Some(port) => Some(port),
                    None => continue,
                },
            };
            let name = s.name.as_str();
            let wrong = || format!("stage `{name}`: input of the wrong type");
            let out = match (&s.kind, input) {
                (StageKind::Folder(c), None) => {
                    let mut c = c.clone();
                    c.folder = resolve(data, &c.folder);
                    Some(AnyPort::File(p.source(name, FolderSource::new(c))))
                }
                (StageKind::WatchFolder(c), None) => {
                    Some(AnyPort::File(p.source(name, WatchSource::new(data.clone(), c.clone()))))
                }
                (StageKind::Synthetic(c), None) => {
                    Some(AnyPort::Shape(p.source(name, SyntheticSource::new(c.clone()))))
                }
                (StageKind::Ingest(c), Some(AnyPort::File(i))) => {
                    // Files dropped into a watched folder: links are not followed.
                    let watched = s.input.as_deref().is_some_and(|i| {
                        spec.stages.iter().any(|u| u.name == i && matches!(u.kind, StageKind::WatchFolder(_)))
                    });
                    let st = IngestStage::new(c.clone())
                        .with_limits(spec.settings.limits)
                        .follow_symlinks(!watched);
                    Some(AnyPort::Shape(p.stage(name, i, st)))
                }
                (StageKind::Spectral(c), Some(AnyPort::Shape(i))) => {
                    let st = SpectralStage::new(c, Some(data.cache()))
                        .map_err(|e| format!("stage `{name}`: {e}"))?;
                    Some(AnyPort::Spectrum(p.stage(name, i, st)))
                }
                (StageKind::Descriptor, Some(AnyPort::Spectrum(i))) => Some(AnyPort::Descriptor(p.stage(
                    name,
                    i,
                    DescriptorStage::new(live.clone(), shutdown.clone()),
                ))),
                (StageKind::Forest, Some(AnyPort::Descriptor(i))) => {
                    Some(AnyPort::Prediction(p.stage(name, i, ForestStage)))
                }
                (StageKind::Matcher(c), Some(AnyPort::Prediction(i))) => {
                    Some(AnyPort::Matches(p.stage(name, i, MatcherStage::new(c))))
                }
                (StageKind::Fmap(c), Some(AnyPort::Matches(i))) => {
                    Some(AnyPort::Map(p.stage(name, i, FmapStage::new(c))))
                }
                (StageKind::MatchSink(c), Some(AnyPort::Map(i))) => {
                    let mut c = c.clone();
                    c.folder = resolve(data, &c.folder);
                    p.sink(name, i, MatchSink::new(data.clone(), c));
                    None
                }
                (StageKind::EvalSink(c), Some(AnyPort::Map(i))) => {
                    let mut c = c.clone();
                    c.folder = resolve(data, &c.folder);
                    p.sink(name, i, EvalSink::new(data.clone(), c));
                    None
                }
                (StageKind::Trainer(c), Some(AnyPort::Spectrum(i))) => {
                    let upstream_k = s.input.as_deref().and_then(|i| {
                        spec.stages.iter().find(|u| u.name == i).and_then(|u| match &u.kind {
                            StageKind::Spectral(sc) => Some(sc.k),
                            _ => None,
                        })
                    });
                    let mut t = TrainerSink::new(data.clone(), c.clone(), heat, live.clone())
                        .map_err(|e| format!("stage `{name}`: {e}"))?
                        .with_shutdown(shutdown.clone())
                        .with_limits(spec.settings.limits);
                    if let Some(k) = upstream_k {
                        t = t.with_spectrum_k(k);
                    }
                    p.sink(name, i, t);
                    None
                }
                _ => return Err(wrong()),
            };
            if let Some(o) = out {
                outputs.insert(s.name.clone(), o);
            }
            done.insert(s.name.clone());
        }
        if done.len() == before {
            return Err("the stages do not form a graph fed by sources".into());
        }
    }
    Ok(p)
}
