//! Admission: who may trace now, who may wait, who is turned away.
//!
//! A semaphore holds `max_renders` render slots. A request that finds none free joins
//! the queue if fewer than `queue` are already waiting, and otherwise gets 503 with
//! `Retry-After` at once: a saturated server says so instead of piling requests up,
//! and a load balancer can try another replica. Waiting ends when a slot frees (the
//! semaphore is fair, so first come, first served), when the request's deadline passes
//! (the caller's timeout, 504), or when the server starts draining (503).

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use prometheus::IntGauge;
use tokio::sync::{OwnedSemaphorePermit, Semaphore};

use super::error::ApiError;
use super::metrics::Metrics;
use super::shutdown::{Phase, Shutdown};

/// The render slots and the queue in front of them.
#[derive(Debug)]
pub struct Admission {
    permits: Arc<Semaphore>,
    queue: usize,
    waiting: AtomicUsize,
    metrics: Metrics,
}

/// A render slot, held for as long as its render traces; dropping it frees the slot.
#[derive(Debug)]
pub struct RenderSlot {
    _permit: OwnedSemaphorePermit,
    in_flight: IntGauge,
}

impl Drop for RenderSlot {
    fn drop(&mut self) {
        self.in_flight.dec();
    }
}

/// One place in the queue, given back when dropped (also when the client leaves while
/// waiting, which drops the handler's future).
struct Waiting<'a>(&'a Admission);

impl Drop for Waiting<'_> {
    fn drop(&mut self) {
        self.0.waiting.fetch_sub(1, Ordering::SeqCst);
        self.0.metrics.queue_depth.dec();
    }
}

impl Admission {
    /// `slots` renders at once, `queue` more waiting.
    pub fn new(slots: usize, queue: usize, metrics: Metrics) -> Admission {
        Admission {
            permits: Arc::new(Semaphore::new(slots.max(1))),
            queue,
            waiting: AtomicUsize::new(0),
            metrics,
        }
    }

    /// A render slot, waiting in the queue if there is room there.
    pub async fn admit(&self, shutdown: &Shutdown) -> Result<RenderSlot, ApiError> {
        if shutdown.is_draining() {
            self.metrics.reject("shutting_down");
            return Err(ApiError::ShuttingDown);
        }
        if let Ok(p) = self.permits.clone().try_acquire_owned() {
            return Ok(self.slot(p));
        }
        if self
            .waiting
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |w| {
                (w < self.queue).then_some(w + 1)
            })
            .is_err()
        {
            self.metrics.reject("saturated");
            return Err(ApiError::Saturated);
        }
        self.metrics.queue_depth.inc();
        let _place = Waiting(self);
        tokio::select! {
            p = self.permits.clone().acquire_owned() => match p {
                Ok(p) => Ok(self.slot(p)),
                Err(_) => Err(ApiError::ShuttingDown),
            },
            _ = shutdown.reached(Phase::Draining) => {
                self.metrics.reject("shutting_down");
                Err(ApiError::ShuttingDown)
            }
        }
    }

    fn slot(&self, permit: OwnedSemaphorePermit) -> RenderSlot {
        self.metrics.in_flight.inc();
        RenderSlot {
            _permit: permit,
            in_flight: self.metrics.in_flight.clone(),
        }
    }

    /// Requests waiting for a slot now.
    pub fn waiting(&self) -> usize {
        self.waiting.load(Ordering::SeqCst)
    }

    /// Whether the next render request would be refused.
    pub fn is_saturated(&self) -> bool {
        self.permits.available_permits() == 0 && self.waiting() >= self.queue
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn runtime() -> tokio::runtime::Runtime {
        tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .build()
            .unwrap()
    }

    #[test]
    fn past_the_queue_requests_are_refused_at_once() {
        runtime().block_on(async {
            let a = Arc::new(Admission::new(1, 1, Metrics::new(1, 1).unwrap()));
            let s = Shutdown::default();
            let slot = a.admit(&s).await.unwrap();
            let (a2, s2) = (a.clone(), s.clone());
            let waiter = tokio::spawn(async move { a2.admit(&s2).await.map(|_| ()) });
            while a.waiting() == 0 {
                tokio::time::sleep(Duration::from_millis(1)).await;
            }
            assert!(a.is_saturated());
            assert_eq!(a.admit(&s).await.unwrap_err(), ApiError::Saturated);
            drop(slot);
            waiter.await.unwrap().unwrap();
            assert_eq!(a.waiting(), 0);
        });
    }

    #[test]
    fn draining_releases_the_queue() {
        runtime().block_on(async {
            let a = Arc::new(Admission::new(1, 4, Metrics::new(1, 4).unwrap()));
            let s = Shutdown::default();
            let _slot = a.admit(&s).await.unwrap();
            let (a2, s2) = (a.clone(), s.clone());
            let waiter = tokio::spawn(async move { a2.admit(&s2).await.map(|_| ()) });
            while a.waiting() == 0 {
                tokio::time::sleep(Duration::from_millis(1)).await;
            }
            s.advance(Phase::Draining);
            assert_eq!(waiter.await.unwrap(), Err(ApiError::ShuttingDown));
            assert_eq!(a.admit(&s).await.unwrap_err(), ApiError::ShuttingDown);
        });
    }
}
