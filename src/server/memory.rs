//! The memory budget: a ledger of the bytes every request may allocate, kept under
//! `--memory-bytes`, so that no mix of requests makes the process grow past its
//! container's limit.
//!
//! Every request is charged its worst-case memory *before* it allocates it, and gives
//! it back when the work ends ([`Reservation`] is a guard: dropping it releases the
//! bytes, also when a client leaves and its handler is dropped). What is charged, and
//! who estimates it (each estimate lives beside what it estimates):
//!
//! | stage | charge | estimator |
//! | --- | --- | --- |
//! | reading the body | `Content-Length` (the body limit when chunked) × the copies the route keeps | [`super::extract::read_charged`] |
//! | parsing and validating a scene | from a cheap pre-scan of the JSON text | [`crate::scene::footprint::parse_peak`] |
//! | the built scene (objects, triangles, BVH) | from the validated scene's counts | [`crate::scene::footprint::built`] |
//! | decoding a submission | pixels × bytes a pixel, from the PNG or NPY header (other images: from the frame); JSON, NDJSON and CSV from the body size | [`crate::format::footprint::submission`] |
//! | the reference and the comparison of a grade | from the frame | [`crate::grade::footprint::grading`] |
//! | a streamed answer's buffers | the channel and the row bands of the sinks | [`fn@crate::output::footprint`] |
//!
//! A charge larger than the whole budget can never fit: it is refused at once with
//! [`ApiError::OverMemory`] (413 for a body, 422 with the JSON pointers of the fields
//! that drive it otherwise). A first charge (the body, before anything is allocated)
//! that does not fit *now* waits for earlier requests to give memory back, first come
//! first served, if fewer than `--queue` requests already wait for memory; otherwise it
//! is refused with 503 and `Retry-After`. The caller bounds the wait by the request's
//! deadline. A request that already holds memory never waits for more: it is refused
//! with 503 at once, giving back what it holds. Otherwise requests holding their bodies
//! could all wait for each other's memory until their deadlines (four large grades at
//! once did, before this rule). Both refusals count as `memory` in
//! `raytile_rejected_requests_total`; `raytile_memory_reserved_bytes` is the ledger.
//!
//! The ledger counts in KiB (a charge is rounded up), which lets a tokio semaphore
//! keep it: fair, cancellation-safe, and with `u32` permits good for 4 TiB.
//!
//! The reference cache ([`crate::grade::cache`]) keeps its references in the same
//! ledger, through [`MemoryBudget::cache_ledger`]: an entry takes its bytes only when
//! they are free now (never while a request waits for memory), and gives them back
//! whenever a request's charge does not fit now ([`MemoryBudget::reclaim_from`]), before
//! that request would wait or be refused. So the cache uses memory no request needs, and
//! never makes one fail. `raytile_memory_reserved_bytes` counts the requests' part,
//! `raytile_reference_cache_bytes` the cache's.

use std::sync::{Arc, OnceLock};

use prometheus::IntGauge;
use tokio::sync::{OwnedSemaphorePermit, Semaphore};

use super::error::ApiError;
use super::metrics::Metrics;
use super::places::Places;
use super::shutdown::{Phase, Shutdown};
use crate::grade::cache::{Lease, Ledger, ReferenceCache};
use crate::scene::Problem;

/// The ledger's unit: charges are rounded up to whole KiB.
pub const UNIT_BYTES: u64 = 1024;

/// The largest budget the ledger can keep (`u32::MAX` units).
pub const MAX_BUDGET_BYTES: u64 = crate::config::MAX_MEMORY_BYTES;

/// What a request is about to allocate, and what in the request drives it.
#[derive(Debug, Clone, PartialEq)]
pub struct Charge {
    /// Worst-case bytes.
    pub bytes: u64,
    /// What it is for, in words: "the body", "parsing the scene".
    pub what: String,
    /// The fields that drive it, as problems with JSON pointers into the body; empty
    /// when the body's size alone does (then a refusal is 413).
    pub fields: Vec<Problem>,
}

impl Charge {
    /// A charge driven by the body's size alone.
    pub fn body(bytes: u64, what: impl Into<String>) -> Charge {
        Charge {
            bytes,
            what: what.into(),
            fields: Vec::new(),
        }
    }

    /// A charge driven by `fields`.
    pub fn fields(bytes: u64, what: impl Into<String>, fields: Vec<Problem>) -> Charge {
        Charge {
            bytes,
            what: what.into(),
            fields,
        }
    }

    /// The same charge with every pointer put under `prefix` (where its document lies
    /// in the body, e.g. `/scene`).
    pub fn under(mut self, prefix: &str) -> Charge {
        if !prefix.is_empty() {
            for p in &mut self.fields {
                *p = Problem::new(format!("{prefix}{}", p.pointer), p.message.clone());
            }
        }
        self
    }
}

/// The memory budget and the requests waiting for it.
#[derive(Debug)]
pub struct MemoryBudget {
    units: Arc<Semaphore>,
    total_bytes: u64,
    queue: Places,
    metrics: Metrics,
    /// What gives memory back when a charge does not fit now.
    cache: OnceLock<Arc<ReferenceCache>>,
}

/// Bytes held in the ledger; dropping it gives them back.
#[derive(Debug)]
pub struct Reservation {
    permit: Option<OwnedSemaphorePermit>,
    gauge: IntGauge,
}

impl Reservation {
    /// Bytes held.
    pub fn bytes(&self) -> u64 {
        self.permit
            .as_ref()
            .map_or(0, |p| p.num_permits() as u64 * UNIT_BYTES)
    }

    /// Takes over what `other` holds.
    pub fn absorb(&mut self, mut other: Reservation) {
        match (&mut self.permit, other.permit.take()) {
            (Some(mine), Some(theirs)) => mine.merge(theirs),
            (None, theirs) => self.permit = theirs,
            (Some(_), None) => {}
        }
    }

    /// Gives back what is held beyond `bytes` (nothing when it holds less).
    pub fn shrink_to(&mut self, bytes: u64) {
        let keep = units(bytes) as usize;
        if let Some(p) = &mut self.permit
            && p.num_permits() > keep
        {
            let freed = p.split(p.num_permits() - keep);
            if let Some(freed) = freed {
                self.gauge
                    .sub((freed.num_permits() as u64 * UNIT_BYTES) as i64);
            }
        }
    }
}

impl Drop for Reservation {
    fn drop(&mut self) {
        self.gauge.sub(self.bytes() as i64);
    }
}

/// `bytes` in whole units, rounded up (and at most what the ledger can hold).
fn units(bytes: u64) -> u32 {
    bytes.div_ceil(UNIT_BYTES).min(u32::MAX as u64) as u32
}

impl MemoryBudget {
    /// A budget of `total_bytes`; up to `queue` requests may wait for memory at once.
    pub fn new(total_bytes: u64, queue: usize, metrics: Metrics) -> MemoryBudget {
        let total_bytes = total_bytes.min(MAX_BUDGET_BYTES);
        metrics.memory_budget.set(total_bytes as i64);
        MemoryBudget {
            units: Arc::new(Semaphore::new(units(total_bytes) as usize)),
            // What is charged is rounded up; so is the budget, not to refuse a charge of
            // exactly the budget.
            total_bytes,
            queue: Places::new(queue),
            metrics,
            cache: OnceLock::new(),
        }
    }

    /// The ledger the reference cache takes its entries' bytes from.
    pub fn cache_ledger(&self) -> Arc<dyn Ledger> {
        Arc::new(CacheLedger {
            units: self.units.clone(),
        })
    }

    /// Makes `cache` give back its bytes when a charge does not fit now (once; later
    /// calls are ignored).
    pub fn reclaim_from(&self, cache: Arc<ReferenceCache>) {
        let _ = self.cache.set(cache);
    }

    /// `n` units now, after asking the cache for what is missing if they are not free.
    fn try_take(&self, n: u32) -> Option<OwnedSemaphorePermit> {
        if let Ok(p) = self.units.clone().try_acquire_many_owned(n) {
            return Some(p);
        }
        let cache = self.cache.get()?;
        let short = (n as u64).saturating_sub(self.units.available_permits() as u64) * UNIT_BYTES;
        // Emptying the cache would not make it fit: keep the references the waiting
        // requests are likely to need.
        if cache.bytes() < short || cache.release(short) == 0 {
            return None;
        }
        self.units.clone().try_acquire_many_owned(n).ok()
    }

    /// The whole budget.
    pub fn total_bytes(&self) -> u64 {
        self.total_bytes
    }

    /// Bytes reserved now.
    pub fn reserved_bytes(&self) -> u64 {
        (units(self.total_bytes) as u64 - self.units.available_permits() as u64) * UNIT_BYTES
    }

    /// Requests waiting for memory now.
    pub fn waiting(&self) -> usize {
        self.queue.taken()
    }

    /// A reservation holding nothing (to be grown by [`MemoryBudget::resize`]).
    pub fn empty(&self) -> Reservation {
        Reservation {
            permit: None,
            gauge: self.metrics.memory_reserved.clone(),
        }
    }

    /// Reserves `charge`, waiting behind earlier requests while it does not fit now (if
    /// there is room in the queue). Refuses a charge that can never fit (413 or 422), a
    /// full queue (503) and a server that is draining (503). The caller bounds the wait
    /// by the request's deadline.
    pub async fn reserve(
        &self,
        charge: &Charge,
        shutdown: &Shutdown,
    ) -> Result<Reservation, ApiError> {
        if charge.bytes > self.total_bytes {
            self.metrics.reject("memory");
            tracing::info!(
                what = %charge.what,
                needed_bytes = charge.bytes,
                budget_bytes = self.total_bytes,
                "refused: it can never fit in the memory budget"
            );
            return Err(ApiError::OverMemory {
                what: charge.what.clone(),
                needed_bytes: charge.bytes,
                budget_bytes: self.total_bytes,
                problems: charge.fields.clone(),
            });
        }
        let n = units(charge.bytes);
        if n == 0 {
            return Ok(self.empty());
        }
        if let Some(p) = self.try_take(n) {
            return Ok(self.held(p));
        }
        let Some(_place) = self.queue.enter() else {
            self.metrics.reject("memory");
            return Err(ApiError::MemoryFull);
        };
        tokio::select! {
            p = self.units.clone().acquire_many_owned(n) => match p {
                Ok(p) => Ok(self.held(p)),
                Err(_) => Err(ApiError::ShuttingDown),
            },
            _ = shutdown.reached(Phase::Draining) => {
                self.metrics.reject("shutting_down");
                Err(ApiError::ShuttingDown)
            }
        }
    }

    /// Makes `r` hold `charge.bytes` in all: reserves the difference as
    /// [`MemoryBudget::reserve`] does, or gives back what it holds beyond when the charge
    /// is smaller. A reservation that holds something already does not wait: what does
    /// not fit now is refused with 503, so that no two requests wait for each other.
    pub async fn resize(
        &self,
        r: &mut Reservation,
        charge: &Charge,
        shutdown: &Shutdown,
    ) -> Result<(), ApiError> {
        let held = r.bytes();
        if charge.bytes <= held {
            r.shrink_to(charge.bytes);
            return Ok(());
        }
        if charge.bytes > self.total_bytes {
            // Refused as a whole, with its own size.
            return self.reserve(charge, shutdown).await.map(|_| ());
        }
        let more = Charge {
            bytes: charge.bytes - held,
            ..charge.clone()
        };
        if held > 0 {
            let p = self.try_take(units(more.bytes)).ok_or_else(|| {
                self.metrics.reject("memory");
                ApiError::MemoryFull
            })?;
            r.absorb(self.held(p));
            return Ok(());
        }
        let extra = self.reserve(&more, shutdown).await?;
        r.absorb(extra);
        Ok(())
    }

    fn held(&self, permit: OwnedSemaphorePermit) -> Reservation {
        self.metrics
            .memory_reserved
            .add((permit.num_permits() as u64 * UNIT_BYTES) as i64);
        Reservation {
            permit: Some(permit),
            gauge: self.metrics.memory_reserved.clone(),
        }
    }
}

/// The reference cache's side of the ledger: units taken only when free now, and
/// never while a request waits for memory (the semaphore hands what is given back to
/// the waiters first). Never calls back into the cache, which holds its lock here.
#[derive(Debug)]
struct CacheLedger {
    units: Arc<Semaphore>,
}

impl Ledger for CacheLedger {
    fn try_take(&self, bytes: u64) -> Option<Lease> {
        let p = self
            .units
            .clone()
            .try_acquire_many_owned(units(bytes))
            .ok()?;
        Some(Box::new(p))
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

    fn budget(bytes: u64, queue: usize) -> (Arc<MemoryBudget>, Metrics) {
        let m = Metrics::new(1, queue).unwrap();
        (Arc::new(MemoryBudget::new(bytes, queue, m.clone())), m)
    }

    #[test]
    fn a_reservation_is_given_back_when_dropped_and_the_gauge_follows() {
        runtime().block_on(async {
            let (b, m) = budget(1 << 20, 4);
            let s = Shutdown::default();
            let r = b.reserve(&Charge::body(1000, "x"), &s).await.unwrap();
            // Rounded up to a whole KiB.
            assert_eq!(r.bytes(), 1024);
            assert_eq!(b.reserved_bytes(), 1024);
            assert_eq!(m.memory_reserved.get(), 1024);
            assert_eq!(m.memory_budget.get(), 1 << 20);
            drop(r);
            assert_eq!(b.reserved_bytes(), 0);
            assert_eq!(m.memory_reserved.get(), 0);
        });
    }

    #[test]
    fn a_charge_beyond_the_whole_budget_is_refused_with_its_fields() {
        runtime().block_on(async {
            let (b, m) = budget(1 << 20, 4);
            let s = Shutdown::default();
            let body = b.reserve(&Charge::body(2 << 20, "the body"), &s).await;
            let e = body.unwrap_err();
            assert_eq!(e.status().as_u16(), 413);
            let c = Charge::fields(
                2 << 20,
                "the answer",
                vec![Problem::new("/image/width", "drives it")],
            )
            .under("/scene");
            let e = b.reserve(&c, &s).await.unwrap_err();
            assert_eq!(e.status().as_u16(), 422);
            let doc = serde_json::to_value(e.problem()).unwrap();
            assert_eq!(doc["problems"][0]["pointer"], "/scene/image/width");
            assert_eq!(doc["budget_bytes"], 1 << 20);
            assert_eq!(
                m.rejected.with_label_values(&["memory"]).get(),
                2,
                "both counted"
            );
            assert_eq!(b.reserved_bytes(), 0);
        });
    }

    #[test]
    fn what_does_not_fit_now_waits_in_order_or_is_refused_past_the_queue() {
        runtime().block_on(async {
            let (b, _) = budget(10 << 10, 1);
            let s = Shutdown::default();
            let first = b.reserve(&Charge::body(8 << 10, "a"), &s).await.unwrap();
            let (b2, s2) = (b.clone(), s.clone());
            let waiter = tokio::spawn(async move {
                b2.reserve(&Charge::body(6 << 10, "b"), &s2)
                    .await
                    .map(|r| r.bytes())
            });
            while b.waiting() == 0 {
                tokio::time::sleep(Duration::from_millis(1)).await;
            }
            // The queue (1) is full: the next one that does not fit is refused...
            let e = b
                .reserve(&Charge::body(4 << 10, "c"), &s)
                .await
                .unwrap_err();
            assert_eq!(e, ApiError::MemoryFull);
            assert_eq!(e.status().as_u16(), 503);
            drop(first);
            assert_eq!(waiter.await.unwrap().unwrap(), 6 << 10);
            assert_eq!(b.reserved_bytes(), 0);
        });
    }

    #[test]
    fn draining_releases_the_waiters() {
        runtime().block_on(async {
            let (b, _) = budget(4 << 10, 4);
            let s = Shutdown::default();
            let _all = b.reserve(&Charge::body(4 << 10, "a"), &s).await.unwrap();
            let (b2, s2) = (b.clone(), s.clone());
            let waiter =
                tokio::spawn(
                    async move { b2.reserve(&Charge::body(1, "b"), &s2).await.map(|_| ()) },
                );
            while b.waiting() == 0 {
                tokio::time::sleep(Duration::from_millis(1)).await;
            }
            s.advance(Phase::Draining);
            assert_eq!(waiter.await.unwrap(), Err(ApiError::ShuttingDown));
        });
    }

    #[test]
    fn a_reservation_grows_and_shrinks() {
        runtime().block_on(async {
            let (b, m) = budget(64 << 10, 4);
            let s = Shutdown::default();
            let mut r = b.empty();
            b.resize(&mut r, &Charge::body(10 << 10, "a"), &s)
                .await
                .unwrap();
            assert_eq!(r.bytes(), 10 << 10);
            b.resize(&mut r, &Charge::body(30 << 10, "b"), &s)
                .await
                .unwrap();
            assert_eq!((r.bytes(), b.reserved_bytes()), (30 << 10, 30 << 10));
            b.resize(&mut r, &Charge::body(3 << 10, "c"), &s)
                .await
                .unwrap();
            assert_eq!((r.bytes(), b.reserved_bytes()), (3 << 10, 3 << 10));
            assert_eq!(m.memory_reserved.get(), 3 << 10);
            let e = b.resize(&mut r, &Charge::body(65 << 10, "d"), &s).await;
            assert_eq!(e.unwrap_err().status().as_u16(), 413);
            assert_eq!(r.bytes(), 3 << 10, "a refusal keeps what was held");
            // What holds memory does not wait for more: 503 at once.
            let other = b.reserve(&Charge::body(60 << 10, "e"), &s).await.unwrap();
            let e = b.resize(&mut r, &Charge::body(10 << 10, "f"), &s).await;
            assert_eq!(e.unwrap_err(), ApiError::MemoryFull);
            assert_eq!(b.waiting(), 0);
            drop(other);
            drop(r);
            assert_eq!((b.reserved_bytes(), m.memory_reserved.get()), (0, 0));
        });
    }

    fn cached_budget(bytes: u64) -> (Arc<MemoryBudget>, Arc<ReferenceCache>) {
        let (b, m) = budget(bytes, 4);
        let cache = Arc::new(ReferenceCache::new(
            bytes,
            Some(b.cache_ledger()),
            m.reference_cache.clone(),
        ));
        b.reclaim_from(cache.clone());
        (b, cache)
    }

    /// Caches a reference of about `kib` KiB for scene number `n`.
    fn cache_one(cache: &ReferenceCache, n: u32, kib: usize) {
        let text = format!(
            r#"{{"version": 1, "image": {{"width": {}, "height": 1}}, "objects": []}}"#,
            n + 1
        );
        let scene = crate::scene::parse(text.as_bytes(), &Default::default()).unwrap();
        let key = crate::grade::cache::SceneKey::of(&scene).unwrap();
        let image = crate::grade::RgbImage {
            width: 1,
            height: 1,
            data: vec![0; (kib << 10) - 512],
        };
        cache.get_or_render(key, || Ok(image)).unwrap();
    }

    #[test]
    fn the_reference_cache_holds_its_bytes_in_the_budget_and_gives_them_to_requests() {
        runtime().block_on(async {
            let (b, cache) = cached_budget(64 << 10);
            let s = Shutdown::default();
            cache_one(&cache, 0, 20);
            cache_one(&cache, 1, 20);
            assert_eq!(cache.len(), 2);
            assert_eq!(
                b.reserved_bytes(),
                40 << 10,
                "the cache's bytes are in the ledger"
            );
            assert_eq!(b.metrics.memory_reserved.get(), 0, "and not the requests'");
            // 40 KiB do not fit beside the cache now: it gives back its oldest entry
            // rather than make the request wait.
            let r = b.reserve(&Charge::body(40 << 10, "a"), &s).await.unwrap();
            assert_eq!(cache.len(), 1);
            assert_eq!(b.reserved_bytes(), 60 << 10);
            // A request that holds memory grows at the cache's expense too, not with 503.
            let mut r = r;
            b.resize(&mut r, &Charge::body(60 << 10, "b"), &s)
                .await
                .unwrap();
            assert!(cache.is_empty());
            // With the budget taken, a new reference is graded but not kept.
            cache_one(&cache, 2, 20);
            assert!(cache.is_empty());
            drop(r);
            assert_eq!(b.reserved_bytes(), 0);
            cache_one(&cache, 3, 20);
            assert_eq!((cache.len(), b.reserved_bytes()), (1, 20 << 10));
        });
    }

    #[test]
    fn the_reference_cache_takes_nothing_while_a_request_waits_and_keeps_what_would_not_help() {
        runtime().block_on(async {
            let (b, cache) = cached_budget(64 << 10);
            let s = Shutdown::default();
            cache_one(&cache, 9, 4);
            let first = b.reserve(&Charge::body(50 << 10, "a"), &s).await.unwrap();
            let (b2, s2) = (b.clone(), s.clone());
            let waiter = tokio::spawn(async move {
                b2.reserve(&Charge::body(30 << 10, "b"), &s2)
                    .await
                    .map(|r| r.bytes())
            });
            while b.waiting() == 0 {
                tokio::time::sleep(Duration::from_millis(1)).await;
            }
            // Giving back its 4 KiB would not let 30 KiB fit: the cache keeps them.
            assert_eq!(cache.len(), 1);
            // 10 KiB are free, but a request waits for them: a new reference is not
            // kept, and the old one, given back to make room, goes to the waiter too.
            cache_one(&cache, 0, 4);
            assert!(cache.is_empty());
            drop(first);
            assert_eq!(waiter.await.unwrap().unwrap(), 30 << 10);
        });
    }

    #[test]
    fn the_counting_allocator_sees_a_buffer() {
        crate::measure::alone_or_return!(the_counting_allocator_sees_a_buffer);
        let before = crate::measure::live();
        let (v, peak) = crate::measure::peak(|| vec![1u8; 5 << 20]);
        assert!(peak >= 5 << 20, "{peak}");
        drop(v);
        assert!(crate::measure::live() <= before + (1 << 20));
    }
}
