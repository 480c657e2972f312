//! The pipeline's edges on NATS JetStream: any number of worker processes, on any number of
//! machines, share the work of one pipeline file.
//!
//! [`NatsTransport`] implements the transport seam ([`super::transport::ErasedTransport`]).
//! Every edge `producer → consumer` of the graph (input files, shapes, spectra, descriptors,
//! predictions, sparse matches, dense maps) is a stream `PREFIX_<producer>_<consumer>` with work-queue retention (a message is
//! gone once acknowledged) and one durable pull consumer named after the consuming stage,
//! shared by every worker that runs it: explicit acknowledgements, `max_ack_pending` as the
//! back-pressure the bounded channels give in process, redelivery after `ack_wait` of a job
//! whose worker died, progress acknowledgements while a job is held (a long spectrum is not
//! redelivered for being long), and a dead-letter stream `PREFIX_DEAD` for a message no
//! worker could finish in `max_deliver` tries (it also goes to `rejected/` with its error).
//!
//! A job's message is acknowledged only when the job is done with: its output published on
//! the next stream (publish, then acknowledge: at-least-once), or consumed by a sink. The
//! streams drop a second publication of the same job (`Nats-Msg-Id`), and the sink's side
//! keeps a ledger of the jobs it finished (by the input's content key and a job nonce), so
//! each scan's result is written once.
//!
//! Payloads that hold in-process state travel as keys: the model snapshot as its version (a
//! worker that lacks it fetches the bundle from the store), the forest descriptor as nothing
//! (the receiver makes it again from the spectrum and the model), the heat-method factorisation
//! as its parameters (the receiver factorises again from the mesh). So any stage can run on
//! any worker (`shapeforest worker --stages`). Model versions go to the object store as
//! bundles, the current version into the key-value bucket `PREFIX-model`; every worker follows
//! it ([`model_sync`]).

pub mod gc;
pub mod model_sync;
pub mod wire;

use std::{
    any::{Any, TypeId},
    collections::{HashMap, HashSet},
    path::{Path, PathBuf},
    sync::Arc,
    time::{Duration, Instant},
};

use async_nats::jetstream::{self, consumer::pull, kv, object_store, stream, AckKind};
use futures_util::StreamExt;

use self::wire::{
    BlobRef, WireDescribed, WireEnvelope, WireFailure, WireFileRef, WireInput, WireJob, WireMatched,
    WirePredicted, WireShape, WireSparselyMatched, WireSpectral,
};
use super::{
    config::{PipelineSpec, PortType},
    error::Error,
    message::{
        DescribedShape, Envelope, Failure, FailureKind, InputFile, Job, LabelSpec, MatchedShape, PartialScan,
        PredictedShape, Shape, SparselyMatched, SpectralShape,
    },
    model::{LiveModel, ModelState, ServeNeeds},
    shutdown::Shutdown,
    store::{is_claimed, DataDir},
    transport::{BoxFuture, Delivery, ErasedTransport, Receiver, SendError, Sender, Settle, Settled},
};

/// How to reach JetStream and how its streams behave (`[settings]` of a pipeline file, or the
/// command line).
#[derive(Clone, Debug)]
pub struct NatsSettings {
    /// Server URL, e.g. `nats://127.0.0.1:4222`.
    pub url: String,
    /// Prefix of every stream, bucket and subject (several pipelines can share a server).
    pub prefix: String,
    /// How long a delivered job may go without an acknowledgement (or a progress one) before
    /// it is delivered again.
    pub ack_wait: Duration,
    /// Deliveries of a job before it is dead-lettered.
    pub max_deliver: u32,
    /// Jobs delivered and not yet acknowledged, per consuming stage, over all its workers.
    pub max_ack_pending: usize,
    /// Largest object a worker downloads.
    pub max_object_bytes: u64,
}

impl NatsSettings {
    /// The settings of a pipeline file, with `url` (the command line's) taking precedence.
    pub fn from_spec(spec: &PipelineSpec, url: Option<&str>) -> Result<Self, Error> {
        let s = &spec.settings;
        let url = url.map(str::to_string).or_else(|| s.nats_url.clone()).ok_or_else(|| {
            Error::BadInput("no NATS server: give --nats URL or `nats_url` in [settings]".into())
        })?;
        Ok(Self {
            url,
            prefix: s.stream_prefix.clone(),
            ack_wait: Duration::from_secs_f64(s.nats_ack_wait_s),
            max_deliver: s.nats_max_deliver,
            max_ack_pending: s.nats_max_ack_pending.unwrap_or(64),
            max_object_bytes: s.limits.max_file_bytes.saturating_mul(64),
        })
    }
}

fn nats_err(what: &str, e: impl std::fmt::Display) -> Error {
    Error::BadInput(format!("NATS: {what}: {e}"))
}

/// Keeps names to what stream, consumer and subject names allow.
fn token(s: &str) -> String {
    s.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '_' { c } else { '_' }).collect()
}

/// A connection to JetStream with the shapeforest buckets: what the transport, `submit`,
/// `results` and the model follower share.
pub struct Nats {
    runtime: tokio::runtime::Runtime,
    js: jetstream::Context,
    blobs: object_store::ObjectStore,
    blobs_name: String,
    blobs_stream: stream::Stream,
    kv: kv::Store,
    cache: std::sync::Mutex<BlobCache>,
    /// The settings.
    pub settings: NatsSettings,
}

/// Objects this process stored or read lately, by content key, up to [`BlobCache::CAPACITY`]
/// bytes: a stage that reads what its own worker's previous stage just stored (the spectrum is
/// read by the descriptor, forest, matcher and fmap stages) does not download it again. The
/// keys are content hashes, so a cached object is never stale. (A FIFO of a few lines rather
/// than an LRU crate: an object is read a few times right after it is stored, then never.)
#[derive(Default)]
struct BlobCache {
    order: std::collections::VecDeque<String>,
    objects: HashMap<String, Arc<Vec<u8>>>,
    bytes: usize,
}

impl BlobCache {
    /// Bytes kept at most (a 20K-vertex scan's objects are ~32 MB).
    const CAPACITY: usize = 128 << 20;

    fn get(&self, key: &str) -> Option<Arc<Vec<u8>>> {
        self.objects.get(key).cloned()
    }

    fn insert(&mut self, key: &str, bytes: Arc<Vec<u8>>) {
        if bytes.len() > Self::CAPACITY / 2 || self.objects.contains_key(key) {
            return;
        }
        self.bytes += bytes.len();
        self.objects.insert(key.to_string(), bytes);
        self.order.push_back(key.to_string());
        while self.bytes > Self::CAPACITY {
            let Some(old) = self.order.pop_front() else { break };
            if let Some(b) = self.objects.remove(&old) {
                self.bytes -= b.len();
            }
        }
    }
}

impl Nats {
    /// Connects (on a small runtime of its own, so that it serves any pipeline runtime) and
    /// creates the object store, the key-value bucket and the dead-letter stream if needed.
    pub fn connect(settings: NatsSettings) -> Result<Arc<Self>, Error> {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name("shapeforest-nats")
            .enable_all()
            .build()
            .map_err(Error::Runtime)?;
        let s = settings.clone();
        let (js, blobs, blobs_name, blobs_stream, kv) = runtime.block_on(async move {
            let client = async_nats::ConnectOptions::new()
                .retry_on_initial_connect()
                .connection_timeout(Duration::from_secs(5))
                .connect(&s.url)
                .await
                .map_err(|e| nats_err(&format!("cannot connect to {}", s.url), e))?;
            let js = jetstream::new(client);
            let blobs_name = format!("{}-blobs", token(&s.prefix));
            let blobs = match js.get_object_store(&blobs_name).await {
                Ok(b) => b,
                Err(_) => js
                    .create_object_store(object_store::Config {
                        bucket: blobs_name.clone(),
                        storage: stream::StorageType::File,
                        ..Default::default()
                    })
                    .await
                    .map_err(|e| nats_err("cannot create the object store", e))?,
            };
            let kv = js
                .create_or_update_key_value(kv::Config {
                    bucket: format!("{}-model", token(&s.prefix)),
                    history: 8,
                    storage: stream::StorageType::File,
                    ..Default::default()
                })
                .await
                .map_err(|e| nats_err("cannot create the model bucket", e))?;
            js.get_or_create_stream(stream::Config {
                name: format!("{}_DEAD", token(&s.prefix)),
                subjects: vec![format!("{}.dead.>", token(&s.prefix))],
                storage: stream::StorageType::File,
                ..Default::default()
            })
            .await
            .map_err(|e| nats_err("cannot create the dead-letter stream", e))?;
            let blobs_stream = js
                .get_stream(format!("OBJ_{blobs_name}"))
                .await
                .map_err(|e| nats_err("cannot open the object store's stream", e))?;
            Ok::<_, Error>((js, blobs, blobs_name, blobs_stream, kv))
        })?;
        // `retry_on_initial_connect` returns before the connection is made; the buckets above
        // waited for it.
        let cache = Default::default();
        Ok(Arc::new(Self { runtime, js, blobs, blobs_name, blobs_stream, kv, cache, settings }))
    }

    /// Runs `f` to completion on the connection's runtime (from a thread that is not inside
    /// an async task: set-up, commands, blocking sends).
    pub fn block_on<F: std::future::Future>(&self, f: F) -> F::Output {
        self.runtime.handle().block_on(f)
    }

    /// The JetStream context.
    pub fn jetstream(&self) -> &jetstream::Context {
        &self.js
    }

    /// The key-value bucket of the model.
    pub fn model_bucket(&self) -> &kv::Store {
        &self.kv
    }

    fn cached(&self, key: &str) -> Option<Arc<Vec<u8>>> {
        self.cache.lock().ok().and_then(|c| c.get(key))
    }

    fn remember(&self, key: &str, bytes: Arc<Vec<u8>>) {
        if let Ok(mut c) = self.cache.lock() {
            c.insert(key, bytes);
        }
    }

    /// Stores `bytes` under their content key (once: a part already stored is not sent again).
    pub async fn put_blob(&self, bytes: &[u8]) -> Result<BlobRef, String> {
        let key = wire::content_key(bytes);
        let blob = BlobRef { key: key.clone(), size: bytes.len() as u64 };
        self.remember(&key, Arc::new(bytes.to_vec()));
        // Asked even when cached: the store may have collected it since (see [`gc`]).
        let stored = self.blobs.info(&key).await.is_ok_and(|i| i.size as u64 == blob.size && !i.deleted);
        if !stored {
            let mut reader = bytes;
            self.blobs
                .put(key.as_str(), &mut reader)
                .await
                .map_err(|e| format!("cannot store object {key}: {e}"))?;
        }
        if self.cached(&key).is_none() {
            self.remember(&key, Arc::new(bytes.to_vec()));
        }
        Ok(blob)
    }

    /// Reads an object back, checking its size against the limit and its contents against its
    /// key.
    pub async fn get_blob(&self, blob: &BlobRef) -> Result<Vec<u8>, String> {
        let max = self.settings.max_object_bytes;
        if blob.size > max {
            return Err(format!("object {} is {} bytes, more than the {max} allowed", blob.key, blob.size));
        }
        if let Some(b) = self.cached(&blob.key).filter(|b| b.len() as u64 == blob.size) {
            return Ok(b.to_vec());
        }
        let info = self.blobs.info(&blob.key).await.map_err(|e| format!("object {}: {e}", blob.key))?;
        if info.deleted || info.size as u64 != blob.size {
            return Err(format!("object {}: missing, or not of the size its key says", blob.key));
        }
        // The chunks by direct get (the object store's own reader makes a consumer per read,
        // and a burst of reads runs into the server's consumer limit).
        let subject = format!("$O.{}.C.{}", self.blobs_name, info.nuid);
        let mut bytes = Vec::with_capacity(blob.size as usize);
        let mut seq = None;
        for _ in 0..info.chunks {
            let m = self
                .blobs_stream
                .direct_get_next_for_subject(&subject, seq)
                .await
                .map_err(|e| format!("object {}: {e}", blob.key))?;
            let m = jetstream::message::StreamMessage::try_from(m.message)
                .map_err(|e| format!("object {}: a chunk: {e}", blob.key))?;
            let at = m.sequence;
            bytes.extend_from_slice(&m.payload);
            if bytes.len() as u64 > blob.size {
                break;
            }
            seq = Some(at + 1);
        }
        if bytes.len() as u64 != blob.size || wire::content_key(&bytes) != blob.key {
            return Err(format!("object {}: its contents do not match its key", blob.key));
        }
        let bytes = Arc::new(bytes);
        self.remember(&blob.key, bytes.clone());
        Ok(Arc::try_unwrap(bytes).unwrap_or_else(|b| b.to_vec()))
    }

    /// Whether the server answers a JetStream request now (an account query, at most 2 s).
    /// Tells an error of the server being away (a restart, a lost connection: worth waiting
    /// for) from one of the job itself.
    pub async fn answers(&self) -> bool {
        tokio::time::timeout(Duration::from_secs(2), self.js.query_account()).await.is_ok_and(|r| r.is_ok())
    }

    /// Stream, subject and durable consumer of the edge `producer → consumer`.
    pub fn edge(&self, producer: &str, consumer: &str) -> Edge {
        let p = token(&self.settings.prefix);
        let (a, b) = (token(producer), token(consumer));
        Edge {
            stream: format!("{p}_{a}_{b}"),
            subject: format!("{p}.edge.{a}.{b}"),
            durable: b.clone(),
            dead_subject: format!("{p}.dead.{a}.{b}"),
            producer: producer.to_string(),
            consumer: consumer.to_string(),
        }
    }

    /// Creates the stream of an edge if needed.
    pub async fn ensure_stream(&self, edge: &Edge) -> Result<stream::Stream, String> {
        self.js
            .get_or_create_stream(stream::Config {
                name: edge.stream.clone(),
                subjects: vec![edge.subject.clone()],
                retention: stream::RetentionPolicy::WorkQueue,
                storage: stream::StorageType::File,
                duplicate_window: Duration::from_secs(120),
                ..Default::default()
            })
            .await
            .map_err(|e| format!("stream {}: {e}", edge.stream))
    }

    /// The durable pull consumer of an edge (created if needed).
    pub async fn edge_consumer(
        &self,
        edge: &Edge,
    ) -> Result<jetstream::consumer::Consumer<pull::Config>, String> {
        let stream = self.ensure_stream(edge).await?;
        let s = &self.settings;
        stream
            .get_or_create_consumer(
                &edge.durable,
                pull::Config {
                    durable_name: Some(edge.durable.clone()),
                    ack_policy: jetstream::consumer::AckPolicy::Explicit,
                    ack_wait: s.ack_wait,
                    // One delivery more than the tries: that last one dead-letters the job.
                    max_deliver: i64::from(s.max_deliver) + 1,
                    max_ack_pending: s.max_ack_pending.max(1) as i64,
                    ..Default::default()
                },
            )
            .await
            .map_err(|e| format!("consumer {} of {}: {e}", edge.durable, edge.stream))
    }

    /// Messages waiting on an edge and delivered but not yet acknowledged.
    pub async fn edge_backlog(&self, edge: &Edge) -> Result<(u64, usize), String> {
        let mut c = self.edge_consumer(edge).await?;
        let info = c.info().await.map_err(|e| e.to_string())?;
        Ok((info.num_pending, info.num_ack_pending))
    }
}

/// Names of one edge on the server.
#[derive(Clone, Debug)]
pub struct Edge {
    /// Stream name.
    pub stream: String,
    /// Subject its messages are published on.
    pub subject: String,
    /// The durable consumer (the consuming stage's name).
    pub durable: String,
    /// Where its dead letters go.
    pub dead_subject: String,
    /// Producing stage.
    pub producer: String,
    /// Consuming stage.
    pub consumer: String,
}

/// The NATS transport of one worker: the edges whose payload can travel go through
/// JetStream, the others stay in process.
pub struct NatsTransport {
    nats: Arc<Nats>,
    data: DataDir,
    sinks: HashSet<String>,
    shutdown: Shutdown,
    models: Arc<ModelResolver>,
}

impl NatsTransport {
    /// A transport for the stages of `spec`, over `data` (spool of received files, ledger of
    /// finished jobs, model versions fetched), stopping its receivers on `shutdown`.
    pub fn new(
        nats: Arc<Nats>,
        spec: &PipelineSpec,
        data: DataDir,
        live: Arc<LiveModel>,
        shutdown: Shutdown,
    ) -> Self {
        let sinks =
            spec.stages.iter().filter(|s| s.config.ports().1.is_none()).map(|s| s.name.clone()).collect();
        let needs = ServeNeeds { limits: spec.settings.limits, ..Default::default() };
        Self::with_sinks(nats, sinks, needs, data, live, shutdown)
    }

    /// [`NatsTransport::new`] for a pipeline composed in code: `sinks` names its sinks.
    pub fn with_sinks(
        nats: Arc<Nats>,
        sinks: HashSet<String>,
        needs: ServeNeeds,
        data: DataDir,
        live: Arc<LiveModel>,
        shutdown: Shutdown,
    ) -> Self {
        let models = Arc::new(ModelResolver {
            nats: nats.clone(),
            root: data.root().join(".nats"),
            live,
            needs,
            cache: Default::default(),
        });
        Self { nats, data, sinks, shutdown, models }
    }

    /// Whether edges of `port` travel between workers: every kind does (a payload's
    /// in-process parts travel as keys, see the module's notes).
    pub fn carries(port: PortType) -> bool {
        matches!(
            port,
            PortType::File
                | PortType::Shape
                | PortType::Spectrum
                | PortType::Descriptor
                | PortType::Prediction
                | PortType::Matches
                | PortType::Map
        )
    }

    /// The sending end of an edge of input files (what `shapeforest submit` uses).
    pub fn file_sender(&self, producer: &str, consumer: &str) -> Result<Arc<dyn Sender<InputFile>>, Error> {
        self.sender::<FileCodec>(producer, consumer)
    }

    fn sender<C: Codec>(&self, producer: &str, consumer: &str) -> Result<Arc<dyn Sender<C::T>>, Error> {
        let edge = self.nats.edge(producer, consumer);
        self.nats.block_on(self.nats.ensure_stream(&edge)).map_err(|e| nats_err("set-up", e))?;
        Ok(Arc::new(NatsSender::<C> {
            nats: self.nats.clone(),
            edge,
            data: self.data.clone(),
            shutdown: self.shutdown.clone(),
            _c: std::marker::PhantomData,
        }))
    }

    /// Both ends of an edge, boxed as [`ErasedTransport::connect_erased`] returns them.
    fn pair<C: Codec>(
        &self,
        producer: &str,
        consumer: &str,
        capacity: usize,
        codec: C,
    ) -> Result<Box<dyn Any>, Error> {
        let tx = self.sender::<C>(producer, consumer)?;
        let rx = self.receiver(producer, consumer, capacity, codec)?;
        Ok(Box::new((tx, rx)))
    }

    fn receiver<C: Codec>(
        &self,
        producer: &str,
        consumer: &str,
        capacity: usize,
        codec: C,
    ) -> Result<Box<dyn Receiver<C::T>>, Error> {
        let edge = self.nats.edge(producer, consumer);
        let c = self.nats.block_on(self.nats.edge_consumer(&edge)).map_err(|e| nats_err("set-up", e))?;
        let ledger = self
            .sinks
            .contains(consumer)
            .then(|| self.data.root().join(".nats").join("done").join(token(consumer)));
        Ok(Box::new(NatsReceiver {
            nats: self.nats.clone(),
            consumer: c,
            messages: tokio::sync::Mutex::new(Default::default()),
            batch: capacity.max(1),
            edge,
            shutdown: self.shutdown.clone(),
            ledger,
            codec,
        }))
    }
}

impl ErasedTransport for NatsTransport {
    fn connect_erased(
        &self,
        producer: &str,
        consumer: &str,
        capacity: usize,
        payload: TypeId,
    ) -> Option<Box<dyn Any>> {
        let models = || self.models.clone();
        let r = if payload == TypeId::of::<InputFile>() {
            let spool = self.data.root().join(".nats").join("spool");
            self.pair(producer, consumer, capacity, FileCodec { spool })
        } else if payload == TypeId::of::<Shape>() {
            self.pair(producer, consumer, capacity, ShapeCodec)
        } else if payload == TypeId::of::<SpectralShape>() {
            self.pair(producer, consumer, capacity, SpectralCodec)
        } else if payload == TypeId::of::<DescribedShape>() {
            self.pair(producer, consumer, capacity, DescribedCodec { models: models() })
        } else if payload == TypeId::of::<PredictedShape>() {
            self.pair(producer, consumer, capacity, PredictedCodec { models: models() })
        } else if payload == TypeId::of::<SparselyMatched>() {
            self.pair(producer, consumer, capacity, SparseCodec { models: models() })
        } else if payload == TypeId::of::<MatchedShape>() {
            self.pair(producer, consumer, capacity, MapCodec { models: models() })
        } else {
            return None;
        };
        match r {
            Ok(pair) => Some(pair),
            Err(e) => {
                // Set-up failures surface before the run: the worker checks the server first.
                tracing::error!(producer, consumer, "cannot put the edge on JetStream: {e}");
                None
            }
        }
    }

    fn is_sink(&self, consumer: &str) -> bool {
        self.sinks.contains(consumer)
    }
}

/// How one payload type travels: its message body and how it is made and read back.
trait Codec: Send + Sync + 'static {
    type T: Clone + Send + Sync + 'static;
    type Body: serde::Serialize + serde::de::DeserializeOwned + Send;
    const FORMAT: &'static str;
    fn make_body<'a>(
        nats: &'a Nats,
        job: &'a Job,
        value: &'a Self::T,
    ) -> BoxFuture<'a, Result<Self::Body, String>>;
    fn read_body<'a>(
        &'a self,
        nats: &'a Nats,
        job: &'a mut Job,
        body: Self::Body,
    ) -> BoxFuture<'a, Result<Self::T, String>>;
}

fn unix_ms() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_millis() as u64)
}

fn wire_job(job: &Job, key: &str) -> WireJob {
    let age_ms = job.started.elapsed().as_millis() as u64;
    WireJob {
        id: job.id,
        key: key.to_string(),
        name: job.name.clone(),
        arrived_as: job.arrived_as.clone(),
        stage_seconds: job.stage_seconds.clone(),
        submitted_unix_ms: unix_ms().saturating_sub(age_ms),
    }
}

fn local_job(w: &WireJob) -> Job {
    let mut job = Job::generated(w.id, w.name.clone());
    job.key = Some(w.key.clone());
    job.arrived_as = w.arrived_as.clone();
    job.stage_seconds = w.stage_seconds.clone();
    let age = Duration::from_millis(unix_ms().saturating_sub(w.submitted_unix_ms));
    job.started = Instant::now().checked_sub(age).unwrap_or_else(Instant::now);
    job
}

fn wire_failure(f: &Failure) -> WireFailure {
    let kind = if f.kind == FailureKind::BadInput { "bad-input" } else { "internal" };
    WireFailure { stage: f.stage.clone(), kind: kind.into(), message: f.message.clone() }
}

fn local_failure(f: WireFailure) -> Failure {
    let kind = if f.kind == "bad-input" { FailureKind::BadInput } else { FailureKind::Internal };
    Failure { stage: f.stage, kind, message: f.message }
}

/// A job's key: its first content key and a nonce (fresh for a job that starts here).
fn job_key(job: &Job, content: &str) -> String {
    match (&job.delivery, &job.key) {
        (Some(d), _) => d.key().to_string(),
        (None, Some(k)) => k.clone(),
        (None, None) => format!("{}-{:016x}", &content[..16.min(content.len())], rand::random::<u64>()),
    }
}

/// The pause before the next try of a send while the server is away: `wait` (100 ms at first),
/// doubled for the next, at most 2 s. `false` at shutdown: no more tries.
async fn back_off(shutdown: &Shutdown, wait: &mut Duration) -> bool {
    if shutdown.is_triggered() {
        return false;
    }
    tokio::time::sleep(*wait).await;
    *wait = (*wait * 2).min(Duration::from_secs(2));
    true
}

struct NatsSender<C: Codec> {
    nats: Arc<Nats>,
    edge: Edge,
    data: DataDir,
    shutdown: Shutdown,
    _c: std::marker::PhantomData<fn() -> C>,
}

impl<C: Codec> NatsSender<C> {
    /// The message body: the value's parts stored in the object store. Retried while the
    /// server is away (a failure then is not the job's); `None` at shutdown.
    async fn body(&self, env: &Envelope<C::T>) -> Option<Result<C::Body, Failure>> {
        let v = match &env.body {
            Ok(v) => v,
            Err(f) => return Some(Err(f.clone())),
        };
        let mut wait = Duration::from_millis(100);
        loop {
            match C::make_body(&self.nats, &env.job, v).await {
                Ok(b) => return Some(Ok(b)),
                Err(e) if !self.nats.answers().await => {
                    tracing::warn!(
                        job = env.job.id,
                        "cannot store the job's parts ({e}); the server is away, retrying"
                    );
                    if !back_off(&self.shutdown, &mut wait).await {
                        return None;
                    }
                }
                Err(e) => {
                    return Some(Err(Failure {
                        stage: self.edge.producer.clone(),
                        kind: FailureKind::Internal,
                        message: format!("cannot send the job on: {e}"),
                    }))
                }
            }
        }
    }

    /// Encodes and publishes, retrying while the server is away; `Err` only at shutdown.
    async fn publish(&self, env: &mut Envelope<C::T>) -> Result<(), ()> {
        let body = self.body(env).await.ok_or(())?;
        let content = match &body {
            Ok(b) => wire::content_key(&rmp_serde::to_vec(b).unwrap_or_default()),
            Err(f) => wire::content_key(f.message.as_bytes()),
        };
        let key = job_key(&env.job, &content);
        let wenv = WireEnvelope { job: wire_job(&env.job, &key), body: body.map_err(|f| wire_failure(&f)) };
        let bytes = match wire::encode(C::FORMAT, &wenv) {
            Ok(b) => b,
            Err(e) => {
                tracing::error!(job = env.job.id, "{e}");
                return Err(());
            }
        };
        let mut headers = async_nats::HeaderMap::new();
        headers.insert(wire::FORMAT_HEADER, C::FORMAT);
        headers.insert(wire::VERSION_HEADER, wire::FORMAT_VERSION.to_string().as_str());
        headers.insert(wire::KEY_HEADER, key.as_str());
        headers.insert(wire::NAME_HEADER, crate::limits::escape_name(&env.job.name).as_str());
        let msg_id = format!("{key}:{}:{}", self.edge.producer, self.edge.consumer);
        let mut wait = Duration::from_millis(100);
        loop {
            let publish = jetstream::context::Publish::build()
                .payload(bytes.clone().into())
                .headers(headers.clone())
                .message_id(&msg_id);
            let r = match self.nats.js.send_publish(self.edge.subject.clone(), publish).await {
                Ok(ack) => ack.await.map(|_| ()).map_err(|e| e.to_string()),
                Err(e) => Err(e.to_string()),
            };
            match r {
                Ok(()) => break,
                Err(e) => {
                    tracing::warn!(job = env.job.id, stream = %self.edge.stream, "publish failed ({e}); retrying");
                    if !back_off(&self.shutdown, &mut wait).await {
                        return Err(());
                    }
                }
            }
        }
        if let Some(d) = env.job.delivery.take() {
            d.done();
        } else if is_claimed(&self.data, &env.job) {
            // A local watcher's claimed input is in the object store now; the queue owns it.
            for f in env.job.files() {
                let _ = std::fs::remove_file(f);
            }
        }
        Ok(())
    }
}

impl<C: Codec> Sender<C::T> for NatsSender<C> {
    fn send(&self, mut envelope: Envelope<C::T>) -> BoxFuture<'_, Result<(), Envelope<C::T>>> {
        Box::pin(async move {
            if matches!(&envelope.body, Err(f) if f.kind == FailureKind::Interrupted) {
                return Ok(()); // not sent: its delivery, dropped unfinished, is redelivered
            }
            match self.publish(&mut envelope).await {
                Ok(()) => Ok(()),
                Err(()) => Err(envelope),
            }
        })
    }

    fn send_timeout(&self, envelope: Envelope<C::T>, _timeout: Duration) -> Result<(), SendError<C::T>> {
        // Publishing waits for the server's acknowledgement, not for a consumer: no timeout.
        self.nats.block_on(self.send(envelope)).map_err(SendError::Closed)
    }
}

/// Ends a delivery: acknowledges (recording a sink's job in its ledger first) or hands the
/// message back; sends progress acknowledgements while the job is held.
struct NatsSettle {
    tx: std::sync::Mutex<Option<tokio::sync::oneshot::Sender<Settled>>>,
}

impl Settle for NatsSettle {
    fn settle(&self, outcome: Settled) {
        if let Some(tx) = self.tx.lock().ok().and_then(|mut t| t.take()) {
            let _ = tx.send(outcome);
        }
    }
}

/// Copies a message to the dead-letter stream, with the error in a header.
async fn dead_letter(js: &jetstream::Context, subject: &str, msg: &jetstream::Message, why: &str) {
    let mut headers = msg.headers.clone().unwrap_or_default();
    headers.insert("Shapeforest-Error", crate::limits::escape_name(why).as_str());
    let r = js.publish_with_headers(subject.to_string(), headers, msg.payload.clone()).await;
    match r {
        Ok(ack) => {
            if let Err(e) = ack.await {
                tracing::error!("the dead letter was not stored ({e})");
            }
        }
        Err(e) => tracing::error!("cannot publish the dead letter ({e})"),
    }
}

/// The pause before a job whose consumer failed is delivered again: 1 s, doubling with each
/// delivery, at most 30 s.
fn retry_delay(delivered: i64) -> Duration {
    Duration::from_secs(1u64 << delivered.clamp(1, 6).saturating_sub(1)).min(Duration::from_secs(30))
}

fn hold(
    msg: jetstream::Message,
    nats: &Arc<Nats>,
    dead_subject: String,
    ledger: Option<PathBuf>,
    spool: Option<PathBuf>,
) -> NatsSettle {
    let (tx, mut rx) = tokio::sync::oneshot::channel::<Settled>();
    let ack_wait = nats.settings.ack_wait;
    let tries = i64::from(nats.settings.max_deliver);
    let js = nats.js.clone();
    nats.runtime.handle().spawn(async move {
        let every = (ack_wait / 3).max(Duration::from_millis(200));
        let outcome = loop {
            tokio::select! {
                // The job is done with (or lost, or failed): settle it.
                r = &mut rx => break r.unwrap_or(Settled::Lost),
                // Still working: tell the server, so that it does not redeliver.
                _ = tokio::time::sleep(every) => {
                    let _ = msg.ack_with(AckKind::Progress).await;
                }
            }
        };
        match outcome {
            Settled::Done => {
                if let Some(l) = &ledger {
                    let _ = std::fs::create_dir_all(l.parent().unwrap_or(Path::new(".")));
                    let _ = std::fs::write(l, b"");
                }
                if let Err(e) = msg.double_ack().await {
                    tracing::warn!(
                        "acknowledgement lost ({e}); the job may be delivered again (the sink skips it)"
                    );
                }
            }
            Settled::Lost => {
                let _ = msg.ack_with(AckKind::Nak(Some(Duration::from_millis(500)))).await;
            }
            Settled::Failed(why) => {
                let delivered = msg.info().map(|i| i.delivered).unwrap_or(1);
                if delivered >= tries {
                    let why =
                        format!("{why} (in each of {delivered} deliveries); dead-lettered to {dead_subject}");
                    tracing::error!("dead letter: {why}");
                    dead_letter(&js, &dead_subject, &msg, &why).await;
                    let _ = msg.ack_with(AckKind::Term).await;
                } else {
                    let delay = retry_delay(delivered);
                    tracing::warn!(
                        delivery = delivered,
                        "{why}; the job is delivered again in {} s",
                        delay.as_secs()
                    );
                    let _ = msg.ack_with(AckKind::Nak(Some(delay))).await;
                }
            }
        }
        if let Some(s) = spool {
            let _ = std::fs::remove_dir_all(s);
        }
    });
    NatsSettle { tx: std::sync::Mutex::new(Some(tx)) }
}

struct NatsReceiver<C: Codec> {
    nats: Arc<Nats>,
    consumer: jetstream::consumer::Consumer<pull::Config>,
    messages: tokio::sync::Mutex<std::collections::VecDeque<jetstream::Message>>,
    batch: usize,
    edge: Edge,
    shutdown: Shutdown,
    ledger: Option<PathBuf>,
    codec: C,
}

impl<C: Codec> NatsReceiver<C> {
    /// The next message: from the batch already pulled, or from a new pull request of up to
    /// `batch` messages that the server answers within a second (with fewer, or none, when
    /// nothing waits or `max_ack_pending` jobs are out). A request that expires is simply
    /// made again; one that fails (the server is away) too, after a pause.
    async fn next_message(&self) -> Option<jetstream::Message> {
        let mut pulled = self.messages.lock().await;
        loop {
            if let Some(m) = pulled.pop_front() {
                return Some(m);
            }
            if self.shutdown.is_triggered() {
                return None;
            }
            let request =
                self.consumer.batch().max_messages(self.batch).expires(Duration::from_secs(1)).messages();
            let batch = tokio::select! {
                // Shutdown: no more jobs are taken; those held finish and are acknowledged.
                _ = self.shutdown.triggered() => return None,
                b = request => b,
            };
            match batch {
                Ok(mut b) => loop {
                    let m = tokio::select! {
                        _ = self.shutdown.triggered() => return None,
                        m = b.next() => m,
                    };
                    match m {
                        Some(Ok(m)) => pulled.push_back(m),
                        Some(Err(e)) => {
                            tracing::debug!(consumer = %self.edge.durable, "pull: {e}");
                            break;
                        }
                        None => break,
                    }
                },
                Err(e) => {
                    tracing::warn!(consumer = %self.edge.durable, "cannot pull ({e}); retrying");
                    tokio::select! {
                        _ = self.shutdown.triggered() => return None,
                        _ = tokio::time::sleep(Duration::from_millis(500)) => {}
                    }
                }
            }
        }
    }

    fn header(msg: &jetstream::Message, name: &str) -> Option<String> {
        msg.headers.as_ref().and_then(|h| h.get(name)).map(|v| v.as_str().to_string())
    }

    /// Reads a message; `Err` when it cannot be read (an unknown format or version, a missing
    /// object).
    async fn read(&self, msg: &jetstream::Message) -> Result<(Job, String, Result<C::T, Failure>), String> {
        let format = Self::header(msg, wire::FORMAT_HEADER).unwrap_or_default();
        if format != C::FORMAT {
            return Err(format!(
                "expected a {} message, found {:?}",
                C::FORMAT,
                crate::limits::escape_name(&format)
            ));
        }
        let version =
            Self::header(msg, wire::VERSION_HEADER).and_then(|v| v.parse::<u32>().ok()).unwrap_or(0);
        wire::check_version(C::FORMAT, version)?;
        let w: WireEnvelope<C::Body> = wire::decode(C::FORMAT, &msg.payload)?;
        let mut job = local_job(&w.job);
        let body = match w.body {
            Ok(b) => Ok(self.codec.read_body(&self.nats, &mut job, b).await?),
            Err(f) => Err(local_failure(f)),
        };
        Ok((job, w.job.key, body))
    }
}

impl<C: Codec> Receiver<C::T> for NatsReceiver<C> {
    fn recv(&self) -> BoxFuture<'_, Option<Envelope<C::T>>> {
        Box::pin(async move {
            loop {
                let msg = self.next_message().await?;
                let delivered = msg.info().map(|i| i.delivered).unwrap_or(1);
                let key = Self::header(&msg, wire::KEY_HEADER).unwrap_or_default();
                let ledger = self.ledger.as_ref().filter(|_| !key.is_empty()).map(|l| l.join(token(&key)));
                if ledger.as_ref().is_some_and(|l| l.exists()) {
                    // Finished before (a redelivery after a lost acknowledgement): written once.
                    let _ = msg.double_ack().await;
                    continue;
                }
                let tries = i64::from(self.nats.settings.max_deliver);
                let mut read = self.read(&msg).await;
                // A message that cannot be read while the server is away (its parts are in the
                // object store) is read again when it is back, not handed back: a restart
                // must not use up its deliveries.
                while read.is_err() && !self.nats.answers().await {
                    tracing::warn!(stream = %self.edge.stream, "cannot read a message while the server is away; waiting");
                    tokio::select! {
                        _ = self.shutdown.triggered() => return None,
                        _ = tokio::time::sleep(Duration::from_millis(500)) => {}
                    }
                    read = self.read(&msg).await;
                }
                let read = match read {
                    // Readable, but every worker that took it stopped before finishing it
                    // (a crash, kill -9, an out-of-memory kill): it is not tried again, and
                    // what reading it spooled goes now.
                    Ok((job, _, _)) if delivered > tries => {
                        if let Some(spool) = job.source.as_ref().and_then(|s| s.parent()) {
                            let _ = std::fs::remove_dir_all(spool);
                        }
                        Err(format!(
                            "no worker finished this job in {tries} deliveries (each one that took it stopped, \
                             was killed or timed out); dead-lettered to {}",
                            self.edge.dead_subject
                        ))
                    }
                    Ok(x) => Ok(x),
                    Err(e) if delivered > tries => Err(format!(
                        "no worker could read this message in {tries} deliveries ({e}); dead-lettered to {}",
                        self.edge.dead_subject
                    )),
                    Err(e) => Err(e),
                };
                let (job, key, body) = match read {
                    Ok(x) => x,
                    Err(e) if delivered <= tries => {
                        // Perhaps another worker (a newer one) can read it: hand it back.
                        tracing::warn!(stream = %self.edge.stream, delivery = delivered, "cannot read a message: {e}");
                        let _ = msg.ack_with(AckKind::Nak(Some(Duration::from_millis(200)))).await;
                        continue;
                    }
                    Err(e) => {
                        tracing::error!(stream = %self.edge.stream, "dead letter: {e}");
                        dead_letter(&self.nats.js, &self.edge.dead_subject, &msg, &e).await;
                        let name = Self::header(&msg, wire::NAME_HEADER).unwrap_or_else(|| "message".into());
                        let mut job = Job::generated(0, token(&super::message::shape_stem(Path::new(&name))));
                        job.arrived_as = Some(name);
                        let f = Failure {
                            stage: self.edge.consumer.clone(),
                            kind: FailureKind::Internal,
                            message: e,
                        };
                        (job, key.clone(), Err(f))
                    }
                };
                let spool = job.source.as_ref().and_then(|s| s.parent()).map(Path::to_path_buf);
                let settle = hold(msg, &self.nats, self.edge.dead_subject.clone(), ledger, spool);
                let mut job = job;
                job.delivery = Some(Delivery::new(key, settle));
                return Some(Envelope { job, body });
            }
        })
    }

    fn is_empty(&self) -> bool {
        // Unknown without asking the server; a batching sink (the trainer) acts after each job.
        true
    }
}

/// Input files: their bytes go to the object store; a worker that receives one writes it into
/// its spool folder (`.nats/spool/KEY/NAME`, removed when the job is done with).
struct FileCodec {
    spool: PathBuf,
}

async fn file_ref(nats: &Nats, path: &Path) -> Result<WireFileRef, String> {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).ok_or("a file without a name")?;
    let bytes = tokio::fs::read(path).await.map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(WireFileRef { name, blob: nats.put_blob(&bytes).await? })
}

impl Codec for FileCodec {
    type T = InputFile;
    type Body = WireInput;
    const FORMAT: &'static str = wire::FILE_MESSAGE;

    fn make_body<'a>(
        nats: &'a Nats,
        job: &'a Job,
        value: &'a InputFile,
    ) -> BoxFuture<'a, Result<WireInput, String>> {
        Box::pin(async move {
            let mesh = file_ref(nats, &value.path).await?;
            let (labels, identity) = match &value.labels {
                Some(LabelSpec::File(p)) => (Some(file_ref(nats, p).await?), false),
                Some(LabelSpec::Identity) => (None, true),
                None => (None, false),
            };
            let mut companions = Vec::new();
            for c in &job.companions {
                companions.push(file_ref(nats, c).await?);
            }
            Ok(WireInput { mesh, labels, identity_labels: identity, companions })
        })
    }

    fn read_body<'a>(
        &'a self,
        nats: &'a Nats,
        job: &'a mut Job,
        body: WireInput,
    ) -> BoxFuture<'a, Result<InputFile, String>> {
        Box::pin(async move {
            let dir = self.spool.join(token(&format!("{}-{}", job.id, rand::random::<u32>())));
            tokio::fs::create_dir_all(&dir).await.map_err(|e| format!("{}: {e}", dir.display()))?;
            let write = |f: &WireFileRef, bytes: Vec<u8>| {
                let name = Path::new(&f.name)
                    .file_name()
                    .map(|n| n.to_os_string())
                    .ok_or("a file without a name")?;
                let p = dir.join(name);
                std::fs::write(&p, bytes).map_err(|e| format!("{}: {e}", p.display()))?;
                Ok::<_, String>(p)
            };
            let files = async {
                let mesh = write(&body.mesh, nats.get_blob(&body.mesh.blob).await?)?;
                let labels = match &body.labels {
                    Some(l) => Some(write(l, nats.get_blob(&l.blob).await?)?),
                    None => None,
                };
                let mut companions = Vec::new();
                for c in &body.companions {
                    companions.push(write(c, nats.get_blob(&c.blob).await?)?);
                }
                Ok::<_, String>((mesh, labels, companions))
            };
            let (mesh, labels, companions) = match files.await {
                Ok(x) => x,
                Err(e) => {
                    // Nothing of a message that cannot be read stays in the spool.
                    let _ = std::fs::remove_dir_all(&dir);
                    return Err(e);
                }
            };
            job.companions.extend(companions);
            job.source = Some(mesh.clone());
            job.labels_file = labels.clone();
            let spec = match labels {
                Some(l) => Some(LabelSpec::File(l)),
                None if body.identity_labels => Some(LabelSpec::Identity),
                None => None,
            };
            Ok(InputFile { path: mesh, labels: spec })
        })
    }
}

/// A mesh from the store, checked as [`crate::mesh::Mesh::new`] checks a mesh read from a file.
async fn get_mesh(nats: &Nats, blob: &BlobRef) -> Result<crate::mesh::Mesh, String> {
    let raw: crate::mesh::Mesh = get_decoded(nats, wire::MESH, blob).await?;
    let mut mesh = crate::mesh::Mesh::new(raw.vertices, raw.faces).map_err(|e| format!("mesh: {e}"))?;
    mesh.face_multiplicity = raw.face_multiplicity;
    Ok(mesh)
}

async fn put_encoded<T: serde::Serialize>(nats: &Nats, format: &str, value: &T) -> Result<BlobRef, String> {
    let bytes = wire::encode(format, value)?;
    nats.put_blob(&bytes).await
}

async fn get_decoded<T: serde::de::DeserializeOwned>(
    nats: &Nats,
    format: &str,
    blob: &BlobRef,
) -> Result<T, String> {
    let bytes = nats.get_blob(blob).await?;
    wire::decode(format, &bytes)
}

/// Runs CPU work (a descriptor, a factorisation) off the async threads.
async fn off_thread<R: Send + 'static>(f: impl FnOnce() -> R + Send + 'static) -> Result<R, String> {
    tokio::task::spawn_blocking(f).await.map_err(|e| format!("a worker thread failed: {e}"))
}

async fn put_shape(nats: &Nats, s: &Shape) -> Result<WireShape, String> {
    Ok(WireShape {
        mesh: put_encoded(nats, wire::MESH, &*s.mesh).await?,
        labels: match &s.labels {
            Some(l) => Some(put_encoded(nats, wire::LABELS, &**l).await?),
            None => None,
        },
    })
}

async fn get_shape(nats: &Nats, w: &WireShape) -> Result<Shape, String> {
    let mesh = get_mesh(nats, &w.mesh).await?;
    let n = mesh.n_vertices();
    let labels: Option<Vec<Option<u32>>> = match &w.labels {
        Some(l) => Some(get_decoded(nats, wire::LABELS, l).await?),
        None => None,
    };
    if labels.as_ref().is_some_and(|l| l.len() != n) {
        return Err(format!("labels for another mesh (not {n} vertices)"));
    }
    Ok(Shape { mesh: Arc::new(mesh), labels: labels.map(Arc::new) })
}

async fn put_partial(nats: &Nats, x: &PartialScan) -> Result<wire::WirePartial, String> {
    Ok(wire::WirePartial {
        scan: put_encoded(nats, wire::MESH, &*x.scan).await?,
        part: put_encoded(nats, wire::MESH, &*x.part.mesh).await?,
        kept: match &x.part.kept {
            Some(k) => Some(put_encoded(nats, wire::KEPT, k).await?),
            None => None,
        },
        components: x.part.components,
        holes_closed: x.holes_closed,
        scale_ratio: x.scale_ratio,
    })
}

/// A partial scan whose part is `part` (the shape matched, already read when the keys agree).
async fn get_partial(
    nats: &Nats,
    x: &wire::WirePartial,
    part: Option<&Arc<crate::mesh::Mesh>>,
) -> Result<PartialScan, String> {
    let scan = Arc::new(get_mesh(nats, &x.scan).await?);
    let part = match part {
        Some(p) => p.clone(),
        None => Arc::new(get_mesh(nats, &x.part).await?),
    };
    let kept: Option<Vec<usize>> = match &x.kept {
        Some(k) => Some(get_decoded(nats, wire::KEPT, k).await?),
        None => None,
    };
    let bad = kept
        .as_ref()
        .is_some_and(|k| k.len() != part.n_vertices() || k.iter().any(|&v| v >= scan.n_vertices()));
    if bad {
        return Err("a part whose vertices are not the scan's".into());
    }
    Ok(PartialScan {
        scan,
        part: crate::regularizer::ScanPart { mesh: part, kept, components: x.components },
        holes_closed: x.holes_closed,
        scale_ratio: x.scale_ratio,
    })
}

async fn put_spectral(nats: &Nats, s: &SpectralShape) -> Result<WireSpectral, String> {
    Ok(WireSpectral {
        shape: put_shape(nats, &s.shape).await?,
        spectrum: put_encoded(nats, wire::SPECTRUM, &*s.spectrum).await?,
        partial: match &s.partial {
            Some(x) => Some(put_partial(nats, x).await?),
            None => None,
        },
    })
}

async fn get_spectral(nats: &Nats, w: &WireSpectral) -> Result<SpectralShape, String> {
    let shape = get_shape(nats, &w.shape).await?;
    let n = shape.mesh.n_vertices();
    let spectrum: crate::spectral::Spectrum = get_decoded(nats, wire::SPECTRUM, &w.spectrum).await?;
    let k = spectrum.eigenvalues.len();
    if spectrum.n_vertices != n
        || spectrum.mass.len() != n
        || Some(spectrum.eigenvectors.len()) != n.checked_mul(k)
    {
        return Err(format!("a spectrum of another mesh (not {n} vertices)"));
    }
    let partial = match &w.partial {
        Some(x) => {
            let same = (x.part == w.shape.mesh).then_some(&shape.mesh);
            Some(Arc::new(get_partial(nats, x, same).await?))
        }
        None => None,
    };
    Ok(SpectralShape { shape, spectrum: Arc::new(spectrum), partial })
}

async fn put_predicted(nats: &Nats, p: &PredictedShape) -> Result<WirePredicted, String> {
    Ok(WirePredicted {
        spectral: put_spectral(nats, &p.shape).await?,
        model_version: p.model.version,
        prediction: put_encoded(nats, wire::PREDICTION, &wire::WirePrediction::of(&p.prediction)).await?,
    })
}

async fn get_prediction(nats: &Nats, blob: &BlobRef, n: usize) -> Result<crate::forest::Prediction, String> {
    let prediction =
        get_decoded::<wire::WirePrediction>(nats, wire::PREDICTION, blob).await?.into_prediction()?;
    if prediction.n_vertices() != n {
        return Err(format!("a prediction of another mesh (not {n} vertices)"));
    }
    Ok(prediction)
}

async fn get_predicted(
    nats: &Nats,
    models: &ModelResolver,
    w: &WirePredicted,
) -> Result<PredictedShape, String> {
    let shape = get_spectral(nats, &w.spectral).await?;
    let prediction = get_prediction(nats, &w.prediction, shape.mesh().n_vertices()).await?;
    let model = models.version(w.model_version).await?;
    Ok(PredictedShape { shape, model, prediction: Arc::new(prediction) })
}

/// Shapes (ingest → spectral): mesh and labels in the object store.
struct ShapeCodec;

impl Codec for ShapeCodec {
    type T = Shape;
    type Body = WireShape;
    const FORMAT: &'static str = wire::SHAPE_MESSAGE;

    fn make_body<'a>(nats: &'a Nats, _: &'a Job, s: &'a Shape) -> BoxFuture<'a, Result<WireShape, String>> {
        Box::pin(put_shape(nats, s))
    }

    fn read_body<'a>(
        &'a self,
        nats: &'a Nats,
        _: &'a mut Job,
        b: WireShape,
    ) -> BoxFuture<'a, Result<Shape, String>> {
        Box::pin(async move { get_shape(nats, &b).await })
    }
}

/// Shapes with spectra (spectral → descriptor, spectral → trainer).
struct SpectralCodec;

impl Codec for SpectralCodec {
    type T = SpectralShape;
    type Body = WireSpectral;
    const FORMAT: &'static str = wire::SPECTRUM_MESSAGE;

    fn make_body<'a>(
        nats: &'a Nats,
        _: &'a Job,
        s: &'a SpectralShape,
    ) -> BoxFuture<'a, Result<WireSpectral, String>> {
        Box::pin(put_spectral(nats, s))
    }

    fn read_body<'a>(
        &'a self,
        nats: &'a Nats,
        _: &'a mut Job,
        b: WireSpectral,
    ) -> BoxFuture<'a, Result<SpectralShape, String>> {
        Box::pin(async move { get_spectral(nats, &b).await })
    }
}

/// Described shapes (descriptor → forest): the spectral shape and the model version; the
/// receiver makes the descriptor again (see [`wire::WireDescribed`]).
struct DescribedCodec {
    models: Arc<ModelResolver>,
}

impl Codec for DescribedCodec {
    type T = DescribedShape;
    type Body = WireDescribed;
    const FORMAT: &'static str = wire::DESCRIPTOR_MESSAGE;

    fn make_body<'a>(
        nats: &'a Nats,
        _: &'a Job,
        d: &'a DescribedShape,
    ) -> BoxFuture<'a, Result<WireDescribed, String>> {
        Box::pin(async move {
            Ok(WireDescribed {
                spectral: put_spectral(nats, &d.shape).await?,
                model_version: d.model.version,
            })
        })
    }

    fn read_body<'a>(
        &'a self,
        nats: &'a Nats,
        _: &'a mut Job,
        b: WireDescribed,
    ) -> BoxFuture<'a, Result<DescribedShape, String>> {
        Box::pin(async move {
            let shape = get_spectral(nats, &b.spectral).await?;
            let model = self.models.version(b.model_version).await?;
            let (m, spectrum, mesh) = (model.clone(), shape.spectrum.clone(), shape.shape.mesh.clone());
            let descriptor = off_thread(move || m.forest.descriptor_mesh(Some(&mesh), &spectrum))
                .await?
                .map_err(|e| format!("the descriptor of model v{}: {e}", model.version))?;
            Ok(DescribedShape { shape, model, descriptor: Arc::new(descriptor) })
        })
    }
}

/// Predicted shapes (forest → matcher).
struct PredictedCodec {
    models: Arc<ModelResolver>,
}

impl Codec for PredictedCodec {
    type T = PredictedShape;
    type Body = WirePredicted;
    const FORMAT: &'static str = wire::PREDICTION_MESSAGE;

    fn make_body<'a>(
        nats: &'a Nats,
        _: &'a Job,
        p: &'a PredictedShape,
    ) -> BoxFuture<'a, Result<WirePredicted, String>> {
        Box::pin(put_predicted(nats, p))
    }

    fn read_body<'a>(
        &'a self,
        nats: &'a Nats,
        _: &'a mut Job,
        b: WirePredicted,
    ) -> BoxFuture<'a, Result<PredictedShape, String>> {
        Box::pin(async move { get_predicted(nats, &self.models, &b).await })
    }
}

/// Sparsely matched shapes (matcher → fmap): the prediction, the matches and the heat
/// parameters; the receiver factorises the heat method again from the mesh.
struct SparseCodec {
    models: Arc<ModelResolver>,
}

impl Codec for SparseCodec {
    type T = SparselyMatched;
    type Body = WireSparselyMatched;
    const FORMAT: &'static str = wire::MATCHES_MESSAGE;

    fn make_body<'a>(
        nats: &'a Nats,
        _: &'a Job,
        s: &'a SparselyMatched,
    ) -> BoxFuture<'a, Result<WireSparselyMatched, String>> {
        Box::pin(async move {
            let (heat_time_factor, heat_boundary) = wire::heat_to_wire(&s.heat);
            Ok(WireSparselyMatched {
                predicted: put_predicted(nats, &s.predicted).await?,
                sparse: put_encoded(nats, wire::SPARSE_MATCHES, &wire::WireSparse::of(&s.sparse)).await?,
                heat_time_factor,
                heat_boundary,
            })
        })
    }

    fn read_body<'a>(
        &'a self,
        nats: &'a Nats,
        _: &'a mut Job,
        b: WireSparselyMatched,
    ) -> BoxFuture<'a, Result<SparselyMatched, String>> {
        Box::pin(async move {
            let heat = wire::heat_from_wire(b.heat_time_factor, &b.heat_boundary)?;
            let predicted = get_predicted(nats, &self.models, &b.predicted).await?;
            let n_ref = predicted.model.reference.mesh.n_vertices();
            let sparse = get_decoded::<wire::WireSparse>(nats, wire::SPARSE_MATCHES, &b.sparse)
                .await?
                .into_sparse(predicted.mesh().n_vertices(), n_ref)?;
            let (mesh, spectrum) = (predicted.mesh().clone(), predicted.spectrum().clone());
            let prepared = off_thread(move || crate::regularizer::PreparedShape::new(mesh, spectrum, heat))
                .await?
                .map_err(|e| format!("cannot prepare the shape for geodesics again: {e}"))?;
            Ok(SparselyMatched { predicted, prepared: Arc::new(prepared), heat, sparse: Arc::new(sparse) })
        })
    }
}

/// Dense maps (fmap → the sinks): mesh, labels, prediction and map go to the object store, the
/// model is named by its version and fetched (once) from the store by a worker that lacks it.
/// The spectrum does not travel: its consumers, the sinks, never read it, so a map read back
/// carries a spectrum without eigenpairs (only its area is kept).
struct MapCodec {
    models: Arc<ModelResolver>,
}

impl Codec for MapCodec {
    type T = MatchedShape;
    type Body = WireMatched;
    const FORMAT: &'static str = wire::MAP_MESSAGE;

    fn make_body<'a>(
        nats: &'a Nats,
        _job: &'a Job,
        m: &'a MatchedShape,
    ) -> BoxFuture<'a, Result<WireMatched, String>> {
        Box::pin(async move {
            let p = &m.predicted;
            let shape = put_shape(nats, &p.shape.shape).await?;
            Ok(WireMatched {
                mesh: shape.mesh,
                labels: shape.labels,
                spectrum_area: p.shape.spectrum.area,
                prediction: put_encoded(nats, wire::PREDICTION, &wire::WirePrediction::of(&p.prediction))
                    .await?,
                dense: put_encoded(nats, wire::DENSE_MAP, &wire::WireDense::of(&m.dense)).await?,
                model_version: p.model.version,
                partial: match &p.shape.partial {
                    Some(x) => Some(put_partial(nats, x).await?),
                    None => None,
                },
            })
        })
    }

    fn read_body<'a>(
        &'a self,
        nats: &'a Nats,
        _job: &'a mut Job,
        b: WireMatched,
    ) -> BoxFuture<'a, Result<MatchedShape, String>> {
        Box::pin(async move {
            let shape =
                get_shape(nats, &WireShape { mesh: b.mesh.clone(), labels: b.labels.clone() }).await?;
            let n = shape.mesh.n_vertices();
            let partial = match &b.partial {
                Some(x) => {
                    let same = (x.part == b.mesh).then_some(&shape.mesh);
                    Some(Arc::new(get_partial(nats, x, same).await?))
                }
                None => None,
            };
            let n_scan = partial.as_ref().map_or(n, |p| p.scan.n_vertices());
            let prediction = get_prediction(nats, &b.prediction, n).await?;
            let dense =
                get_decoded::<wire::WireDense>(nats, wire::DENSE_MAP, &b.dense).await?.into_dense(n_scan)?;
            let model = self.models.version(b.model_version).await?;
            if let Some(bad) = dense.map.iter().find(|&&r| r >= model.reference.mesh.n_vertices()) {
                return Err(format!(
                    "the map names reference vertex {bad}, beyond model v{}'s reference",
                    model.version
                ));
            }
            let spectrum = crate::spectral::Spectrum {
                eigenvalues: Vec::new(),
                eigenvectors: Vec::new(),
                n_vertices: n,
                mass: Vec::new(),
                area: b.spectrum_area,
            };
            Ok(MatchedShape {
                predicted: PredictedShape {
                    shape: SpectralShape { shape, spectrum: Arc::new(spectrum), partial },
                    model,
                    prediction: Arc::new(prediction),
                },
                dense: Arc::new(dense),
            })
        })
    }
}

/// Model versions by number: the live one, or one fetched from the store (kept).
pub struct ModelResolver {
    nats: Arc<Nats>,
    root: PathBuf,
    live: Arc<LiveModel>,
    needs: ServeNeeds,
    cache: tokio::sync::Mutex<HashMap<u64, Arc<ModelState>>>,
}

impl ModelResolver {
    /// Model `version`.
    pub async fn version(&self, version: u64) -> Result<Arc<ModelState>, String> {
        if let Some(m) = self.live.current().filter(|m| m.version == version) {
            return Ok(m);
        }
        let mut cache = self.cache.lock().await;
        if let Some(m) = cache.get(&version) {
            return Ok(m.clone());
        }
        let m = Arc::new(model_sync::fetch_model(&self.nats, version, &self.root, &self.needs).await?);
        cache.insert(version, m.clone());
        Ok(m)
    }
}
