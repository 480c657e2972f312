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
