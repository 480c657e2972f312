//! The seam between actors and the channels that connect them.
//!
//! Actors never see a channel type: a stage's loop reads a [`Receiver`] and writes an
//! [`Output`], which fans each envelope out to every consumer of the stage (each gets a clone:
//! the payloads' large parts are behind `Arc`, so a clone is cheap). A [`Transport`] makes the
//! connection for one edge; [`InProcess`] (bounded flume channels inside one process) is the
//! one used today. A networked transport (a message queue between machines) implements the
//! same two traits, and [`super::Pipeline::with_transport`] selects it, without a change to any
//! stage.

use std::{future::Future, pin::Pin, sync::Arc, time::Duration};

use super::message::Envelope;

/// A boxed future, as the object-safe transport traits return.
pub type BoxFuture<'a, T> = Pin<Box<dyn Future<Output = T> + Send + 'a>>;

/// What may travel on an edge: any payload that can be cloned for fan-out and sent between
/// threads. (A networked transport adds its own bound, e.g. serde, on what it carries.)
pub trait Payload: Clone + Send + Sync + 'static {}
impl<T: Clone + Send + Sync + 'static> Payload for T {}

/// Why a send did not go through; the envelope comes back (it is moved, not boxed: it lives
/// on for the retry).
#[derive(Debug)]
#[allow(clippy::large_enum_variant)]
pub enum SendError<T> {
    /// The consumer is gone.
    Closed(Envelope<T>),
    /// The consumer did not take it within the time given (back-pressure).
    Timeout(Envelope<T>),
}

/// The sending end of one edge.
pub trait Sender<T>: Send + Sync {
    /// Sends, waiting (asynchronously) while the consumer is full.
    fn send(&self, envelope: Envelope<T>) -> BoxFuture<'_, Result<(), Envelope<T>>>;
    /// Sends from a blocking thread, waiting at most `timeout`.
    #[allow(clippy::result_large_err)]
    fn send_timeout(&self, envelope: Envelope<T>, timeout: Duration) -> Result<(), SendError<T>>;
}

/// The receiving end of one edge.
pub trait Receiver<T>: Send + Sync {
    /// The next envelope; `None` once every sender is gone and the edge is drained.
    fn recv(&self) -> BoxFuture<'_, Option<Envelope<T>>>;
    /// Whether nothing is waiting right now.
    fn is_empty(&self) -> bool;
    /// Called by a sink's loop once it has consumed the job last received: `Err(why)` when it
    /// could not (its result could not be written: a full disk, a read-only folder). A durable
    /// queue then delivers the job again instead of acknowledging it; in process it does
    /// nothing (the sink defers the claimed input itself).
    fn consumed(&self, _outcome: Result<(), String>) {}
}

/// Makes the connection of one edge, `producer → consumer`, holding up to `capacity`
/// envelopes in flight.
pub trait Transport: Send + Sync + 'static {
    /// A connected pair of ends.
    fn connect<T: Payload>(
        &self,
        producer: &str,
        consumer: &str,
        capacity: usize,
    ) -> (Arc<dyn Sender<T>>, Box<dyn Receiver<T>>);
}

/// Bounded flume channels between tasks of one process.
#[derive(Clone, Copy, Debug, Default)]
pub struct InProcess;

struct FlumeSender<T>(flume::Sender<Envelope<T>>);
struct FlumeReceiver<T>(flume::Receiver<Envelope<T>>);

impl<T: Payload> Sender<T> for FlumeSender<T> {
    fn send(&self, envelope: Envelope<T>) -> BoxFuture<'_, Result<(), Envelope<T>>> {
        Box::pin(async move { self.0.send_async(envelope).await.map_err(|e| e.into_inner()) })
    }

    #[allow(clippy::result_large_err)]
    fn send_timeout(&self, envelope: Envelope<T>, timeout: Duration) -> Result<(), SendError<T>> {
        self.0.send_timeout(envelope, timeout).map_err(|e| match e {
            flume::SendTimeoutError::Timeout(back) => SendError::Timeout(back),
            flume::SendTimeoutError::Disconnected(back) => SendError::Closed(back),
        })
    }
}

impl<T: Payload> Receiver<T> for FlumeReceiver<T> {
    fn recv(&self) -> BoxFuture<'_, Option<Envelope<T>>> {
        Box::pin(async move { self.0.recv_async().await.ok() })
    }

    fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

impl Transport for InProcess {
    fn connect<T: Payload>(
        &self,
        _: &str,
        _: &str,
        capacity: usize,
    ) -> (Arc<dyn Sender<T>>, Box<dyn Receiver<T>>) {
        let (tx, rx) = flume::bounded(capacity.max(1));
        (Arc::new(FlumeSender(tx)), Box::new(FlumeReceiver(rx)))
    }
}

/// An actor's output: the senders of every consumer. Each envelope goes to all of them (a
/// clone for all but the last); a consumer that has gone is dropped, and the output counts as
/// closed once none is left.
pub struct Output<T> {
    consumers: Vec<Arc<dyn Sender<T>>>,
}

impl<T: Payload> Output<T> {
    /// An output to `consumers`.
    pub fn new(consumers: Vec<Arc<dyn Sender<T>>>) -> Self {
        Self { consumers }
    }

    /// Whether no consumer is left.
    pub fn is_closed(&self) -> bool {
        self.consumers.is_empty()
    }

    /// Sends to every consumer, waiting while one is full. `false` once no consumer is left.
    pub async fn send(&mut self, envelope: Envelope<T>) -> bool {
        let mut gone = Vec::new();
        let last = self.consumers.len().saturating_sub(1);
        let mut envelope = Some(envelope);
        for (i, c) in self.consumers.iter().enumerate() {
            let env = if i == last { envelope.take() } else { envelope.clone() };
            let Some(env) = env else { break };
            if c.send(env).await.is_err() {
                gone.push(i);
            }
        }
        self.drop_consumers(&gone);
        !self.consumers.is_empty()
    }

    /// [`Output::send`] from a blocking thread: waits in steps of `step` while a consumer is
    /// full, and gives up (returning `false`) when `give_up()` says so between steps.
    pub fn send_blocking(
        &mut self,
        envelope: Envelope<T>,
        step: Duration,
        give_up: impl Fn() -> bool,
    ) -> bool {
        let mut gone = Vec::new();
        let last = self.consumers.len().saturating_sub(1);
        let mut envelope = Some(envelope);
        'consumers: for (i, c) in self.consumers.iter().enumerate() {
            let env = if i == last { envelope.take() } else { envelope.clone() };
            let Some(mut env) = env else { break };
            loop {
                match c.send_timeout(env, step) {
                    Ok(()) => continue 'consumers,
                    Err(SendError::Closed(_)) => {
                        gone.push(i);
                        continue 'consumers;
                    }
                    Err(SendError::Timeout(back)) => {
                        if give_up() {
                            return false;
                        }
                        env = back;
                    }
                }
            }
        }
        self.drop_consumers(&gone);
        !self.consumers.is_empty()
    }

    fn drop_consumers(&mut self, gone: &[usize]) {
        for &i in gone.iter().rev() {
            self.consumers.remove(i);
        }
    }
}

/// How a delivery from a durable queue ended.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Settled {
    /// The job is done with (its output published further, or consumed by a sink).
    Done,
    /// A worker gave it up unfinished (a shutdown, a dropped copy): deliver it again.
    Lost,
    /// Its consumer failed on it (a sink could not write the result): deliver it again after
    /// a pause, and dead-letter it with this error once its deliveries are spent.
    Failed(String),
}

/// How a delivery from a durable queue ends: [`Settle::settle`] is called once.
pub trait Settle: Send + Sync {
    /// Ends the delivery.
    fn settle(&self, outcome: Settled);
}

/// A job's claim on the queue message it came from (a networked transport's delivery), carried
/// in [`super::Job::delivery`] through in-process stages. Each clone (a fan-out copy of the
/// job) must be marked [`Delivery::done`]; once all are dropped the message is acknowledged,
/// or handed back for redelivery if any copy was dropped unfinished (the job was lost in a
/// panic, a shutdown, a dropped channel).
pub struct Delivery {
    inner: Arc<DeliveryInner>,
    done: bool,
}

struct DeliveryInner {
    key: String,
    settle: Box<dyn Settle>,
    lost: std::sync::atomic::AtomicBool,
    failed: std::sync::Mutex<Option<String>>,
}

impl Delivery {
    /// A delivery identified by `key` (unique per job: the content hash and a job number),
    /// ended through `settle`.
    pub fn new(key: impl Into<String>, settle: impl Settle + 'static) -> Self {
        let inner = DeliveryInner {
            key: key.into(),
            settle: Box::new(settle),
            lost: std::sync::atomic::AtomicBool::new(false),
            failed: std::sync::Mutex::new(None),
        };
        Self { inner: Arc::new(inner), done: false }
    }

    /// The job's key on the wire.
    pub fn key(&self) -> &str {
        &self.inner.key
    }

    /// This copy of the job is done with.
    pub fn done(mut self) {
        self.done = true;
    }

    /// This copy of the job failed in its consumer (`why`): the job is delivered again later,
    /// and dead-lettered with `why` once its deliveries are spent.
    pub fn failed(mut self, why: impl Into<String>) {
        if let Ok(mut f) = self.inner.failed.lock() {
            *f = Some(why.into());
        }
        self.done = true;
    }
}

impl Clone for Delivery {
    fn clone(&self) -> Self {
        Self { inner: self.inner.clone(), done: false }
    }
}

impl Drop for Delivery {
    fn drop(&mut self) {
        if !self.done {
            self.inner.lost.store(true, std::sync::atomic::Ordering::Relaxed);
        }
    }
}

impl Drop for DeliveryInner {
    fn drop(&mut self) {
        let failed = self.failed.lock().ok().and_then(|mut f| f.take());
        let outcome = match failed {
            Some(why) => Settled::Failed(why),
            None if self.lost.load(std::sync::atomic::Ordering::Relaxed) => Settled::Lost,
            None => Settled::Done,
        };
        self.settle.settle(outcome);
    }
}

impl std::fmt::Debug for Delivery {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Delivery({})", self.inner.key)
    }
}

/// The receiving end of a sink's edge under a networked transport: a job's [`Delivery`] is
/// held here while the sink consumes it and settled when the sink's loop reports how that
/// went ([`Receiver::consumed`]; or, failing that, when the sink asks for the next job: a
/// sink consumes one job at a time), so the queue message is acknowledged only after the
/// result is written, and a job whose result could not be written is delivered again. An
/// interrupted job is handed back instead.
pub struct Settling<T> {
    inner: Arc<dyn Receiver<T>>,
    held: std::sync::Mutex<Option<Delivery>>,
}

impl<T: Payload> Settling<T> {
    /// Wraps the receiver of a sink's edge.
    pub fn new(inner: Arc<dyn Receiver<T>>) -> Self {
        Self { inner, held: std::sync::Mutex::new(None) }
    }

    fn finish_held(&self) {
        if let Ok(mut h) = self.held.lock() {
            if let Some(d) = h.take() {
                d.done();
            }
        }
    }
}

impl<T: Payload> Receiver<T> for Settling<T> {
    fn recv(&self) -> BoxFuture<'_, Option<Envelope<T>>> {
        self.finish_held();
        Box::pin(async move {
            let mut env = self.inner.recv().await?;
            let interrupted =
                matches!(&env.body, Err(f) if f.kind == super::message::FailureKind::Interrupted);
            if let Some(d) = env.job.delivery.take() {
                if interrupted {
                    drop(d); // not done: delivered again
                } else if let Ok(mut h) = self.held.lock() {
                    *h = Some(d);
                }
            }
            Some(env)
        })
    }

    fn is_empty(&self) -> bool {
        self.inner.is_empty()
    }

    fn consumed(&self, outcome: Result<(), String>) {
        let held = self.held.lock().ok().and_then(|mut h| h.take());
        match (held, outcome) {
            (Some(d), Ok(())) => d.done(),
            (Some(d), Err(why)) => d.failed(why),
            (None, _) => {}
        }
    }
}

impl<T> Drop for Settling<T> {
    fn drop(&mut self) {
        // The sink has finished (its loop ended after consuming the last job).
        if let Ok(mut h) = self.held.lock() {
            if let Some(d) = h.take() {
                d.done();
            }
        }
    }
}

/// A transport chosen at run time, in object-safe form (what a pipeline file's `transport`
/// setting selects): it connects the edges it carries and leaves the others in process.
pub trait ErasedTransport: Send + Sync + 'static {
    /// Connects `producer → consumer` for the payload type `payload`: a boxed
    /// `(Arc<dyn Sender<T>>, Box<dyn Receiver<T>>)` for that `T`, or `None` to connect the
    /// edge in process.
    fn connect_erased(
        &self,
        producer: &str,
        consumer: &str,
        capacity: usize,
        payload: std::any::TypeId,
    ) -> Option<Box<dyn std::any::Any>>;
    /// Whether `consumer` is a sink (its receiver settles deliveries, see [`Settling`]).
    fn is_sink(&self, consumer: &str) -> bool;
}

/// The transport of a pipeline built from a file: [`InProcess`] by default, or an
/// [`ErasedTransport`] (e.g. NATS JetStream) for the edges it carries.
#[derive(Clone, Default)]
pub struct Dynamic(Option<Arc<dyn ErasedTransport>>);

impl Dynamic {
    /// Edges through `transport` (those it carries), the rest in process.
    pub fn new(transport: Arc<dyn ErasedTransport>) -> Self {
        Self(Some(transport))
    }
}

impl Transport for Dynamic {
    fn connect<T: Payload>(
        &self,
        producer: &str,
        consumer: &str,
        capacity: usize,
    ) -> (Arc<dyn Sender<T>>, Box<dyn Receiver<T>>) {
        let Some(x) = &self.0 else { return InProcess.connect(producer, consumer, capacity) };
        let (tx, rx) = match x.connect_erased(producer, consumer, capacity, std::any::TypeId::of::<T>()) {
            Some(pair) => match pair.downcast::<(Arc<dyn Sender<T>>, Box<dyn Receiver<T>>)>() {
                Ok(pair) => *pair,
                Err(_) => InProcess.connect(producer, consumer, capacity),
            },
            None => InProcess.connect(producer, consumer, capacity),
        };
        if x.is_sink(consumer) {
            (tx, Box::new(Settling::new(Arc::from(rx))))
        } else {
            (tx, rx)
        }
    }
}
