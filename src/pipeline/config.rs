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
    any::Any,
    collections::{HashMap, HashSet},
    fmt,
    path::{Path, PathBuf},
    sync::Arc,
};

use serde::{de::DeserializeOwned, Deserialize};

use super::{
    actor::PipelineContext,
    error::Error,
    graph::{Pipeline, Port},
    message::{
        DescribedShape, InputFile, MatchedShape, PredictedShape, Shape, SparselyMatched, SpectralShape,
    },
    model::LiveModel,
    store::DataDir,
    transport::Dynamic,
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

/// What a stage type consumes (`None`: a source) and emits (`None`: a sink).
pub type Ports = (Option<PortType>, Option<PortType>);

/// A typed port of any payload, as a pipeline built from a file passes them between stages.
#[derive(Clone)]
pub enum AnyPort {
    /// Input files.
    File(Port<InputFile>),
    /// Shapes.
    Shape(Port<Shape>),
    /// Shapes with spectra.
    Spectrum(Port<SpectralShape>),
    /// Described shapes.
    Descriptor(Port<DescribedShape>),
    /// Predictions.
    Prediction(Port<PredictedShape>),
    /// Sparse matches.
    Matches(Port<SparselyMatched>),
    /// Dense maps.
    Map(Port<MatchedShape>),
}

/// The settings of one stage type, as read from a pipeline file: implemented once per type
/// (in `stages/<type>.rs`), with the type's registration as `TYPE`.
pub trait StageConfig: Any + fmt::Debug + Send + Sync + Sized {
    /// The type's name, ports and parser (listed in [`super::stages::builtin`] or given to
    /// [`Registry::with`]).
    const TYPE: StageType;
    /// Checks the settings beyond their syntax, naming the broken rule.
    fn check(&self) -> Result<(), String> {
        Ok(())
    }
    /// Adds the stage to the pipeline under construction; `input` is the upstream's output
    /// (`None` for a source), of the type `TYPE.ports` says. Returns its output (`None` for a
    /// sink).
    fn build(&self, b: &mut Builder<'_>, input: Option<AnyPort>) -> Result<Option<AnyPort>, Error>;
}

/// A [`StageConfig`] behind a pointer, as a [`StageSpec`] holds it (implemented for every
/// `StageConfig`).
pub trait AnyStageConfig: Any + fmt::Debug + Send + Sync {
    /// The type's name in pipeline files (`type = "…"`).
    fn type_name(&self) -> &'static str;
    /// What it consumes and emits.
    fn ports(&self) -> Ports;
    /// See [`StageConfig::build`].
    fn build(&self, b: &mut Builder<'_>, input: Option<AnyPort>) -> Result<Option<AnyPort>, Error>;
    /// For downcasting ([`StageSpec::config`]).
    fn as_any(&self) -> &dyn Any;
}

impl<C: StageConfig> AnyStageConfig for C {
    fn type_name(&self) -> &'static str {
        C::TYPE.name
    }
    fn ports(&self) -> Ports {
        C::TYPE.ports
    }
    fn build(&self, b: &mut Builder<'_>, input: Option<AnyPort>) -> Result<Option<AnyPort>, Error> {
        StageConfig::build(self, b, input)
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// A stage type: its name, ports and how its settings are parsed. Each `stages/<type>.rs`
/// holds one as `TYPE`; a [`Registry`] lists those a pipeline file may use.
#[derive(Clone, Copy)]
pub struct StageType {
    /// The name in pipeline files.
    pub name: &'static str,
    /// What it consumes and emits.
    pub ports: Ports,
    /// Parses and checks the settings (the stage table without `name`, `type`, `input`).
    pub parse: fn(toml::Table) -> Result<Arc<dyn AnyStageConfig>, String>,
}

impl fmt::Debug for StageType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "StageType({})", self.name)
    }
}

/// Parses a stage's settings into `C` (unknown keys rejected by `C`'s serde attributes) and
/// checks them: the `parse` of most [`StageType`]s.
pub fn parse_config<C: StageConfig + DeserializeOwned>(
    rest: toml::Table,
) -> Result<Arc<dyn AnyStageConfig>, String> {
    let c: C = toml::Value::Table(rest).try_into::<C>().map_err(|e| e.message().to_string())?;
    c.check()?;
    Ok(Arc::new(c))
}

/// The stage types a pipeline file may use.
#[derive(Clone, Debug)]
pub struct Registry {
    types: Vec<StageType>,
}

impl Default for Registry {
    fn default() -> Self {
        Self::builtin()
    }
}

impl Registry {
    /// The built-in types ([`super::stages::builtin`]).
    pub fn builtin() -> Self {
        Self { types: super::stages::builtin() }
    }

    /// The registry with one more type (replacing a built-in one of the same name).
    pub fn with(mut self, t: StageType) -> Self {
        self.types.retain(|x| x.name != t.name);
        self.types.push(t);
        self
    }

    /// The type named `name`.
    pub fn get(&self, name: &str) -> Option<&StageType> {
        self.types.iter().find(|t| t.name == name)
    }

    /// The names, for messages.
    pub fn names(&self) -> Vec<&'static str> {
        self.types.iter().map(|t| t.name).collect()
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
    pub config: Arc<dyn AnyStageConfig>,
}

impl StageSpec {
    /// The type's name.
    pub fn type_name(&self) -> &'static str {
        self.config.type_name()
    }

    /// The settings, if they are of type `C`.
    pub fn config<C: StageConfig>(&self) -> Option<&C> {
        self.config.as_any().downcast_ref::<C>()
    }
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
    /// How edges travel: `in-process` (default: bounded channels in one process) or `nats`
    /// (NATS JetStream between worker processes: `shapeforest worker`).
    #[serde(default)]
    pub transport: TransportKind,
    /// The NATS server for `transport = "nats"` (the commands' `--nats` overrides it).
    #[serde(default)]
    pub nats_url: Option<String>,
    /// Prefix of the pipeline's streams, buckets and subjects on the server. Default
    /// `shapeforest`.
    #[serde(default = "default_prefix")]
    pub stream_prefix: String,
    /// Seconds a delivered job may go without an acknowledgement before it is redelivered
    /// (a worker holding it sends progress acknowledgements meanwhile). Default 30.
    #[serde(default = "default_ack_wait")]
    pub nats_ack_wait_s: f64,
    /// Deliveries of a job before it is dead-lettered and rejected. Default 5.
    #[serde(default = "default_max_deliver")]
    pub nats_max_deliver: u32,
    /// Jobs delivered and unacknowledged per consuming stage, all its workers together (the
    /// fleet's bound; each worker holds no more than its in-process channels do). Default 64.
    #[serde(default)]
    pub nats_max_ack_pending: Option<usize>,
}

/// The transport of a pipeline file's edges.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TransportKind {
    /// Bounded channels inside one process.
    #[default]
    InProcess,
    /// NATS JetStream streams between worker processes.
    Nats,
}

fn default_prefix() -> String {
    "shapeforest".into()
}
fn default_ack_wait() -> f64 {
    30.0
}
fn default_max_deliver() -> u32 {
    5
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
            transport: TransportKind::default(),
            nats_url: None,
            stream_prefix: default_prefix(),
            nats_ack_wait_s: default_ack_wait(),
            nats_max_deliver: default_max_deliver(),
            nats_max_ack_pending: None,
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
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{file}: invalid pipeline{}", problems.iter().map(|p| format!("\n  - {p}")).collect::<String>())]
pub struct ConfigError {
    /// The file (or `<text>`).
    pub file: String,
    /// One line per problem.
    pub problems: Vec<String>,
}

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
        Self::from_toml_with(text, file, &Registry::builtin())
    }

    /// [`PipelineSpec::from_toml`] with the stage types of `registry` (built-in ones and
    /// your own).
    pub fn from_toml_with(text: &str, file: &str, registry: &Registry) -> Result<Self, ConfigError> {
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
        if !(settings.nats_ack_wait_s.is_finite() && settings.nats_ack_wait_s >= 1.0) {
            problems.push("[settings]: nats_ack_wait_s must be at least 1 (seconds)".into());
        }
        if settings.nats_max_deliver == 0 || settings.nats_max_ack_pending == Some(0) {
            problems.push("[settings]: nats_max_deliver and nats_max_ack_pending must be at least 1".into());
        }
        if settings.stream_prefix.is_empty()
            || !settings.stream_prefix.chars().all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        {
            problems.push("[settings]: stream_prefix must be letters, digits, `-` or `_`".into());
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
            let Some(ty) = registry.get(&kind) else {
                nodes.push(Node { name, input, ports: None });
                problems.push(format!(
                    "{label} ({kind}): unknown stage type `{kind}` (one of: {})",
                    registry.names().join(", ")
                ));
                continue;
            };
            nodes.push(Node { name: name.clone(), input: input.clone(), ports: Some(ty.ports) });
            match (ty.parse)(t) {
                Ok(config) => stages.push(StageSpec { name, input, config }),
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
        self.configs::<super::stages::WatchConfig>().next().is_some()
    }

    /// Whether a stage of the type named `type_name` is present.
    pub fn has_type(&self, type_name: &str) -> bool {
        self.stages.iter().any(|s| s.type_name() == type_name)
    }

    /// The settings of every stage whose settings are of type `C`.
    pub fn configs<C: StageConfig>(&self) -> impl Iterator<Item = &C> {
        self.stages.iter().filter_map(|s| s.config::<C>())
    }

    /// The stage named `name`.
    pub fn stage(&self, name: &str) -> Option<&StageSpec> {
        self.stages.iter().find(|s| s.name == name)
    }
}

/// What graph validation needs of a stage; `ports` is `None` for an unknown type.
struct Node {
    name: String,
    input: Option<String>,
    ports: Option<(Option<PortType>, Option<PortType>)>,
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
        // An output may feed several stages (each gets every job), but must feed one.
        if let (Some(Some(o)), 0) = (s.ports.map(|p| p.1), users.len()) {
            problems.push(format!(
                "stage `{}`: its output ({o}) goes nowhere; add a stage with `input = \"{}\"`",
                s.name, s.name
            ));
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

/// What a [`StageConfig::build`] gets: the pipeline under construction and what the stage
/// may need to know about the rest of the file.
pub struct Builder<'a> {
    /// The pipeline being built.
    pub pipeline: &'a mut Pipeline,
    /// The whole file.
    pub spec: &'a PipelineSpec,
    /// The stage being built.
    pub stage: &'a StageSpec,
    /// The data folder.
    pub data: &'a DataDir,
    /// The live model.
    pub live: &'a Arc<LiveModel>,
    /// Heat-method settings shared by the trainer's reference and the matcher.
    pub heat: HeatParams,
}

impl Builder<'_> {
    /// The stage's name.
    pub fn name(&self) -> &str {
        &self.stage.name
    }

    /// A folder of a stage, taken from the data folder when relative.
    pub fn resolve(&self, p: &Path) -> PathBuf {
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            self.data.root().join(p)
        }
    }

    /// The settings of the stage's upstream, if they are of type `C`.
    pub fn upstream<C: StageConfig>(&self) -> Option<&C> {
        self.stage.input.as_deref().and_then(|i| self.spec.stage(i)).and_then(|u| u.config::<C>())
    }

    /// An error of this stage.
    pub fn error(&self, message: impl fmt::Display) -> Error {
        Error::stage(&self.stage.name, message.to_string())
    }

    /// The error for an input of the wrong type (validation rules it out for files).
    pub fn wrong_input(&self) -> Error {
        self.error("input of the wrong type")
    }
}

/// Builds the pipeline a spec describes, over `data` and `live`.
pub fn build(
    spec: &PipelineSpec,
    data: &DataDir,
    live: Arc<LiveModel>,
    ctx: PipelineContext,
) -> Result<Pipeline, Error> {
    build_with(spec, data, live, ctx, Dynamic::default(), None)
}

/// The output port of a stage this process does not run (its consumers' edges come from the
/// transport).
fn detached(port: PortType, name: &str) -> AnyPort {
    match port {
        PortType::File => AnyPort::File(Port::new(name)),
        PortType::Shape => AnyPort::Shape(Port::new(name)),
        PortType::Spectrum => AnyPort::Spectrum(Port::new(name)),
        PortType::Descriptor => AnyPort::Descriptor(Port::new(name)),
        PortType::Prediction => AnyPort::Prediction(Port::new(name)),
        PortType::Matches => AnyPort::Matches(Port::new(name)),
        PortType::Map => AnyPort::Map(Port::new(name)),
    }
}

/// Connects `port` to a consumer this process does not run (through the transport).
fn attach_remote(p: &Pipeline, port: &AnyPort, consumer: &str) {
    match port {
        AnyPort::File(x) => x.attach(p.connect_edge(&x.producer, consumer).0),
        AnyPort::Shape(x) => x.attach(p.connect_edge(&x.producer, consumer).0),
        AnyPort::Spectrum(x) => x.attach(p.connect_edge(&x.producer, consumer).0),
        AnyPort::Descriptor(x) => x.attach(p.connect_edge(&x.producer, consumer).0),
        AnyPort::Prediction(x) => x.attach(p.connect_edge(&x.producer, consumer).0),
        AnyPort::Matches(x) => x.attach(p.connect_edge(&x.producer, consumer).0),
        AnyPort::Map(x) => x.attach(p.connect_edge(&x.producer, consumer).0),
    }
}

/// Checks that the stages `only` of `spec` can run as one worker whose edges to the other
/// stages go through a transport that carries the port types `carries` accepts: names every
/// edge to or from a stage outside `only` that would have to carry a payload that only
/// travels in process.
pub fn check_selection(
    spec: &PipelineSpec,
    only: &HashSet<String>,
    carries: fn(PortType) -> bool,
) -> Result<(), Error> {
    let mut problems = Vec::new();
    for n in only {
        if spec.stage(n).is_none() {
            problems.push(format!("`{n}` is not a stage of this pipeline"));
        }
    }
    for s in &spec.stages {
        let Some(i) = &s.input else { continue };
        let Some(u) = spec.stage(i) else { continue };
        if only.contains(&s.name) == only.contains(&u.name) {
            continue;
        }
        if let Some(port) = u.config.ports().1 {
            if !carries(port) {
                problems.push(format!(
                    "`{}` → `{}` carries {port}s, which only travel in process: run both stages in the same worker",
                    u.name, s.name
                ));
            }
        }
    }
    if problems.is_empty() {
        Ok(())
    } else {
        Err(Error::Config(ConfigError { file: format!("pipeline `{}`", spec.name), problems }))
    }
}

/// [`build`] with a transport, building only the stages in `only` (all when `None`): the
/// edges from or to the others come from the transport (see [`check_selection`]).
pub fn build_with(
    spec: &PipelineSpec,
    data: &DataDir,
    live: Arc<LiveModel>,
    ctx: PipelineContext,
    transport: Dynamic,
    only: Option<&HashSet<String>>,
) -> Result<Pipeline, Error> {
    let mut p =
        Pipeline::with_context(data.clone(), live.clone(), ctx).with_capacity(spec.settings.channel_capacity);
    p.set_transport(transport);
    let runs = |name: &str| only.is_none_or(|o| o.contains(name));
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
                // A port may feed several stages: each takes a clone.
                Some(i) => match outputs.get(i) {
                    Some(port) => Some(port.clone()),
                    None => continue,
                },
            };
            if !runs(&s.name) {
                if let Some(port) = s.config.ports().1 {
                    outputs.insert(s.name.clone(), detached(port, &s.name));
                }
                done.insert(s.name.clone());
                continue;
            }
            let mut b =
                Builder { pipeline: &mut p, spec, stage: s, data, live: &live, heat: HeatParams::default() };
            if let Some(o) = s.config.build(&mut b, input)? {
                for c in spec.stages.iter().filter(|c| c.input.as_deref() == Some(&s.name) && !runs(&c.name))
                {
                    attach_remote(b.pipeline, &o, &c.name);
                }
                outputs.insert(s.name.clone(), o);
            }
            done.insert(s.name.clone());
        }
        if done.len() == before {
            return Err(Error::BadInput("the stages do not form a graph fed by sources".into()));
        }
    }
    Ok(p)
}
