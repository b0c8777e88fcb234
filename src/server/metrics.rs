//! Prometheus metrics and `GET /metrics`.
//!
//! Each [`Metrics`] owns its own registry rather than a process-wide one, so two
//! servers in one process (as in the tests) never count into each other.
//!
//! | metric | type | labels |
//! | --- | --- | --- |
//! | `raytile_http_requests_total` | counter | `route`, `method`, `status` |
//! | `raytile_render_duration_seconds` | histogram | `output` (png, json, ndjson, npy, csv; trace, grade), `outcome` (complete, cancelled, over_budget, failed) |
//! | `raytile_rays_traced_total` | counter | |
//! | `raytile_tiles_traced_total` | counter | |
//! | `raytile_renders_in_flight` | gauge | |
//! | `raytile_queue_depth` | gauge | |
//! | `raytile_renders_parked` | gauge | |
//! | `raytile_rejected_requests_total` | counter | `reason` (saturated, shutting_down, deadline, over_budget, memory) |
//! | `raytile_memory_reserved_bytes`, `raytile_memory_budget_bytes` | gauge | |
//! | `raytile_render_slots`, `raytile_queue_capacity` | gauge | |
//! | `raytile_reference_cache_hits_total`, `raytile_reference_cache_misses_total` | counter | |
//! | `raytile_reference_cache_bytes`, `raytile_reference_cache_entries` | gauge | |

use axum::Router;
use axum::extract::State;
use axum::http::{HeaderValue, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use prometheus::{
    Encoder, Histogram, HistogramOpts, HistogramVec, IntCounter, IntCounterVec, IntGauge, Opts,
    Registry, TextEncoder,
};

use super::AppState;
use super::error::ApiError;
use crate::grade::cache::CacheMetrics;

/// The routes: `GET /metrics`.
pub fn router() -> Router<AppState> {
    Router::new().route("/metrics", get(metrics))
}

/// Every metric the server keeps, in its own registry.
#[derive(Debug, Clone)]
pub struct Metrics {
    registry: Registry,
    /// Requests answered, by route template, method and status.
    pub requests: IntCounterVec,
    /// Time from the start of tracing to the last byte handed to the body.
    pub render_duration: HistogramVec,
    /// Rays traced (primary and secondary), counted as each tile finishes.
    pub rays: IntCounter,
    /// Tiles traced.
    pub tiles: IntCounter,
    /// Renders tracing now.
    pub in_flight: IntGauge,
    /// Requests waiting for a render slot now.
    pub queue_depth: IntGauge,
    /// Renders parked now: their client is behind, so they hold no slot and no thread.
    pub parked: IntGauge,
    /// Requests refused by load shedding, by reason.
    pub rejected: IntCounterVec,
    /// Bytes reserved in the memory budget now (`super::memory`).
    pub memory_reserved: IntGauge,
    /// The memory budget, `--memory-bytes`.
    pub memory_budget: IntGauge,
    /// The reference cache's hits, misses, bytes and entries (`crate::grade::cache`).
    pub reference_cache: CacheMetrics,
}

/// The `reason` labels of `raytile_rejected_requests_total`; `over_budget` counts the
/// 422s of renders whose estimated rays exceed `--max-rays`, `memory` the requests
/// refused by the memory budget (never fitting, or 503 while it is taken).
pub const REJECT_REASONS: [&str; 5] = [
    "saturated",
    "shutting_down",
    "deadline",
    "over_budget",
    "memory",
];

/// Render durations from 10 ms to about 10 minutes.
const DURATION_BUCKETS_SECONDS: [f64; 14] = [
    0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 180.0, 600.0,
];

impl Metrics {
    /// Registers every metric; `render_slots` and `queue_capacity` are the configured
    /// sizes, exported so that a dashboard can show saturation as a fraction.
    pub fn new(render_slots: usize, queue_capacity: usize) -> prometheus::Result<Metrics> {
        let registry = Registry::new();
        let requests = IntCounterVec::new(
            Opts::new(
                "raytile_http_requests_total",
                "HTTP requests answered, by route, method and status.",
            ),
            &["route", "method", "status"],
        )?;
        let render_duration = HistogramVec::new(
            HistogramOpts::new(
                "raytile_render_duration_seconds",
                "Time spent tracing and encoding one render, by output and outcome.",
            )
            .buckets(DURATION_BUCKETS_SECONDS.to_vec()),
            &["output", "outcome"],
        )?;
        let rays = IntCounter::new("raytile_rays_traced_total", "Rays traced.")?;
        let tiles = IntCounter::new("raytile_tiles_traced_total", "Tiles traced.")?;
        let in_flight = IntGauge::new("raytile_renders_in_flight", "Renders tracing now.")?;
        let queue_depth =
            IntGauge::new("raytile_queue_depth", "Requests waiting for a render slot.")?;
        let parked = IntGauge::new(
            "raytile_renders_parked",
            "Renders waiting for their client to read, holding no render slot.",
        )?;
        let rejected = IntCounterVec::new(
            Opts::new(
                "raytile_rejected_requests_total",
                "Requests refused by load shedding, the deadline or the ray budget, by reason.",
            ),
            &["reason"],
        )?;
        let memory_reserved = IntGauge::new(
            "raytile_memory_reserved_bytes",
            "Bytes reserved in the memory budget by the requests in flight (the reference \
             cache's are raytile_reference_cache_bytes).",
        )?;
        let memory_budget = IntGauge::new(
            "raytile_memory_budget_bytes",
            "The memory budget requests are charged against.",
        )?;
        let slots = IntGauge::new("raytile_render_slots", "Renders allowed to trace at once.")?;
        let capacity = IntGauge::new(
            "raytile_queue_capacity",
            "Requests allowed to wait for a render slot.",
        )?;
        // Export every reason from the start, at 0, so that rates and alerts work
        // before the first refusal.
        for reason in REJECT_REASONS {
            rejected.with_label_values(&[reason]);
        }
        slots.set(render_slots as i64);
        capacity.set(queue_capacity as i64);
        registry.register(Box::new(requests.clone()))?;
        registry.register(Box::new(render_duration.clone()))?;
        registry.register(Box::new(rays.clone()))?;
        registry.register(Box::new(tiles.clone()))?;
        registry.register(Box::new(in_flight.clone()))?;
        registry.register(Box::new(queue_depth.clone()))?;
        registry.register(Box::new(parked.clone()))?;
        registry.register(Box::new(rejected.clone()))?;
        registry.register(Box::new(memory_reserved.clone()))?;
        registry.register(Box::new(memory_budget.clone()))?;
        registry.register(Box::new(slots))?;
        registry.register(Box::new(capacity))?;
        let reference_cache = CacheMetrics::new()?;
        for c in reference_cache.collectors() {
            registry.register(c)?;
        }
        Ok(Metrics {
            registry,
            requests,
            render_duration,
            rays,
            tiles,
            in_flight,
            queue_depth,
            parked,
            rejected,
            memory_reserved,
            memory_budget,
            reference_cache,
        })
    }

    /// The duration histogram of one output and outcome.
    pub fn render_duration(&self, output: &str, outcome: &str) -> Histogram {
        self.render_duration.with_label_values(&[output, outcome])
    }

    /// Counts a request refused for `reason`.
    pub fn reject(&self, reason: &str) {
        self.rejected.with_label_values(&[reason]).inc();
    }

    /// The Prometheus text exposition of every metric.
    pub fn encode(&self) -> Result<Vec<u8>, prometheus::Error> {
        let mut out = Vec::new();
        TextEncoder::new().encode(&self.registry.gather(), &mut out)?;
        Ok(out)
    }
}

/// `GET /metrics`: the Prometheus text format, version 0.0.4.
async fn metrics(State(app): State<AppState>) -> Result<Response, ApiError> {
    let body = app
        .metrics
        .encode()
        .map_err(|e| ApiError::Internal(format!("cannot encode the metrics: {e}")))?;
    let mut res = body.into_response();
    res.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("text/plain; version=0.0.4; charset=utf-8"),
    );
    Ok(res)
}
