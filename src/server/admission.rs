//! Admission: who may trace now, who may wait, who is turned away.
//!
//! A semaphore holds `max_renders` render slots. A request that finds none free joins
//! the queue if fewer than `queue` are already waiting, and otherwise gets 503 with
//! `Retry-After` at once: a saturated server says so instead of piling requests up,
//! and a load balancer can try another replica. Waiting ends when a slot frees (the
//! semaphore is fair, so first come, first served), when the request's deadline passes
//! (the caller's timeout, 504), or when the server starts draining (503).
//!
//! Holding a slot is not all: a render's cost is bounded too ([`CostLimit`]).
//! Once admitted, on its trace thread, a pilot estimates the rays it would trace
//! ([`crate::render::cost`]); past `--max-rays` the request is refused with 422 and the
//! fields that drive the cost. A render that passes and then traces half as much again
//! is stopped (its token carries the budget), so no scene holds the threads for its
//! whole deadline.

use std::sync::Arc;

use prometheus::IntGauge;
use tokio::sync::{OwnedSemaphorePermit, Semaphore};

use super::error::ApiError;
use super::metrics::Metrics;
use super::places::{Place, Places};
use super::shutdown::{Phase, Shutdown};
use crate::config::ServeArgs;
use crate::render::cost::{self, CostError, Work};
use crate::render::{Cancel, Rect, Renderer};
use crate::scene::{Problem, SceneError};

/// The render slots and the queue in front of them.
#[derive(Debug)]
pub struct Admission {
    permits: Arc<Semaphore>,
    queue: Places,
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

/// One place in the queue, counted by the queue-depth gauge while held.
struct Queued<'a> {
    _place: Place<'a>,
    depth: &'a IntGauge,
}

impl Drop for Queued<'_> {
    fn drop(&mut self) {
        self.depth.dec();
    }
}

impl Admission {
    /// `slots` renders at once, `queue` more waiting.
    pub fn new(slots: usize, queue: usize, metrics: Metrics) -> Admission {
        Admission {
            permits: Arc::new(Semaphore::new(slots.max(1))),
            queue: Places::new(queue),
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
        let Some(place) = self.queue.enter() else {
            self.metrics.reject("saturated");
            return Err(ApiError::Saturated);
        };
        self.metrics.queue_depth.inc();
        let _queued = Queued {
            _place: place,
            depth: &self.metrics.queue_depth,
        };
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

    /// A render slot again for a render that was admitted and then gave its slot back
    /// while its client was behind (it parked, [`crate::server::render`]): it waits for
    /// a slot behind those already waiting, but takes no place in the queue and is never
    /// refused for a full one, since it was admitted once.
    pub async fn readmit(&self) -> Result<RenderSlot, ApiError> {
        match self.permits.clone().acquire_owned().await {
            Ok(p) => Ok(self.slot(p)),
            Err(_) => Err(ApiError::ShuttingDown),
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
        self.queue.taken()
    }

    /// Whether the next render request would be refused.
    pub fn is_saturated(&self) -> bool {
        self.permits.available_permits() == 0 && self.waiting() >= self.queue.limit()
    }
}

/// The cost policy: `--max-rays` and what follows from it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CostLimit {
    /// The most rays a render may be estimated to trace.
    pub max_rays: u64,
    /// The request deadline, the answer when the estimate is cut short.
    pub deadline: std::time::Duration,
}

impl CostLimit {
    /// The server's policy.
    pub fn new(config: &ServeArgs) -> CostLimit {
        CostLimit {
            max_rays: config.max_rays,
            deadline: config.deadline(),
        }
    }

    /// The cancel token of an admitted render: it also stops the render once it has
    /// traced [`cost::overrun_limit`] rays.
    pub fn token(&self) -> Cancel {
        Cancel::with_ray_limit(cost::overrun_limit(self.max_rays))
    }

    /// Estimates the rays of rendering `region` of `r` as `work` (a pilot trace on the
    /// calling thread, which must be a trace thread: it is CPU work), and refuses past
    /// the limit: 422 with the fields that drive the cost, counted as rejected for
    /// `over_budget`; the pointers start with `scene_at`, where the scene lies in the
    /// body. When `cancel` goes up meanwhile (a deadline, the shutdown, a client that
    /// left): 504, if anyone still listens.
    pub fn check(
        &self,
        r: &Renderer,
        region: Rect,
        work: Work,
        cancel: &Cancel,
        metrics: &Metrics,
        scene_at: &str,
    ) -> Result<(), ApiError> {
        let started = std::time::Instant::now();
        match cost::check(r, region, work, self.max_rays, cancel) {
            Ok(e) => {
                tracing::debug!(
                    estimate = e.rays,
                    pilot_rays = e.pilot_rays,
                    pilot_s = started.elapsed().as_secs_f64(),
                    "cost estimated"
                );
                Ok(())
            }
            Err(CostError::TooCostly(t)) => {
                tracing::info!(
                    estimate = t.estimate.rays,
                    complete = t.estimate.complete,
                    limit = t.limit,
                    pilot_s = started.elapsed().as_secs_f64(),
                    "refused: {t}"
                );
                metrics.reject("over_budget");
                Err(invalid(t.problems(&r.scene), scene_at))
            }
            Err(CostError::Cancelled) => Err(ApiError::DeadlineExceeded(self.deadline)),
        }
    }

    /// The answer for work stopped by `cancel`'s ray budget, if that is what stopped
    /// it: 422 as for a refusal, with what it traced as the estimate's lower bound.
    pub fn overrun(
        &self,
        r: &Renderer,
        work: Work,
        cancel: &Cancel,
        scene_at: &str,
    ) -> Option<ApiError> {
        let budget = cancel.budget().filter(|b| b.is_exceeded())?;
        let t = cost::TooCostly {
            estimate: cost::Estimate {
                rays: budget.used(),
                complete: false,
                pilot_pixels: 0,
                pilot_rays: 0,
                branching: Vec::new(),
            },
            limit: budget.limit(),
            work,
        };
        Some(invalid(t.problems(&r.scene), scene_at))
    }
}

/// The 422 of a scene's `problems`, their pointers put under `scene_at`.
fn invalid(problems: Vec<Problem>, scene_at: &str) -> ApiError {
    ApiError::scene(SceneError::Invalid(problems), "the scene", scene_at)
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
    fn a_parked_render_is_readmitted_past_a_full_queue() {
        runtime().block_on(async {
            let a = Arc::new(Admission::new(1, 1, Metrics::new(1, 1).unwrap()));
            let s = Shutdown::default();
            let parked = a.admit(&s).await.unwrap();
            drop(parked);
            let other = a.admit(&s).await.unwrap();
            let (a2, s2) = (a.clone(), s.clone());
            let waiter = tokio::spawn(async move { a2.admit(&s2).await.map(|_| ()) });
            while a.waiting() == 0 {
                tokio::time::sleep(Duration::from_millis(1)).await;
            }
            assert!(a.is_saturated());
            let a3 = a.clone();
            let back = tokio::spawn(async move { a3.readmit().await.map(|_| ()) });
            tokio::time::sleep(Duration::from_millis(10)).await;
            assert!(!back.is_finished(), "the slot is taken");
            assert_eq!(a.waiting(), 1, "readmission takes no place in the queue");
            drop(other);
            waiter.await.unwrap().unwrap();
            back.await.unwrap().unwrap();
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
