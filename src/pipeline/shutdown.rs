//! The shutdown signal every actor holds (after mini-redis's `shutdown.rs`): a flag that, once
//! triggered, makes sources stop taking new inputs and stages pass the jobs that reach them on
//! as interrupted.

use std::{
    sync::{
        atomic::{AtomicBool, Ordering},
        Arc,
    },
    time::{Duration, Instant},
};

use tokio::sync::Notify;

/// A shared shutdown flag: once triggered, sources stop taking new inputs and stages pass the
/// jobs that reach them on as [`super::FailureKind::Interrupted`] (their inputs stay claimed and
/// are picked up again at the next start).
#[derive(Clone, Default)]
pub struct Shutdown {
    inner: Arc<(AtomicBool, Notify)>,
}

impl Shutdown {
    /// A flag that is not triggered.
    pub fn new() -> Self {
        Self::default()
    }

    /// Triggers the shutdown (idempotent).
    pub fn trigger(&self) {
        self.inner.0.store(true, Ordering::SeqCst);
        self.inner.1.notify_waiters();
    }

    /// Whether the shutdown was triggered.
    pub fn is_triggered(&self) -> bool {
        self.inner.0.load(Ordering::SeqCst)
    }

    /// Sleeps `d` or until the shutdown is triggered (on a blocking thread); returns whether it
    /// was triggered.
    pub fn sleep(&self, d: Duration) -> bool {
        let step = Duration::from_millis(25);
        let end = Instant::now() + d;
        while Instant::now() < end {
            if self.is_triggered() {
                return true;
            }
            std::thread::sleep(step.min(end.saturating_duration_since(Instant::now())));
        }
        self.is_triggered()
    }

    /// Waits (asynchronously) for the trigger.
    pub async fn triggered(&self) {
        loop {
            let notified = self.inner.1.notified();
            if self.is_triggered() {
                return;
            }
            notified.await;
        }
    }
}
