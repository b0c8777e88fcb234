//! `POST /v1/render` (scene → PNG) and `POST /v1/hits` (scene → per-pixel hit data),
//! both streamed while tiles finish, both with `?region=x,y,w,h`.
//!
//! The order is the point: every failure is decided before the first byte
//! (extract and validate, negotiate, admit, estimate the cost), because once the status
//! line is out it cannot change. Then the job goes to the rayon pool with its render
//! slot; there it builds the acceleration structure and runs the cost pilot
//! ([`CostLimit::check`]), whose verdict the handler awaits: a scene past `--max-rays`
//! is refused with 422, any other returns with a body fed by [`super::stream`].
//!
//! After the first byte, four things can cut the stream: the client leaving (the
//! channel closes; tracing stops at the next tile), the deadline (a tokio timer cancels
//! the render), the end of the shutdown grace period, and the render's ray budget (its
//! cancel token goes up once it has traced half as much again as `--max-rays`; its
//! outcome is `over_budget`). A cut stream ends with a body
//! error, so hyper aborts the transfer and the client cannot mistake a partial image for
//! a whole one.
//!
//! Headers: `X-Raytile-Width` and `X-Raytile-Height` (the size of this answer's image),
//! `X-Raytile-Region` (`x,y,w,h` in the full frame), and `Server-Timing` with `parse`
//! and `queue` durations, which are known when the head leaves. How long tracing took is
//! known only at the end: a client that sends `TE: trailers` gets it as a trailer,
//! `Server-Timing: render;dur=…` with `X-Raytile-Rays`; every client finds it in the log
//! line and the `raytile_render_duration_seconds` histogram.

use std::panic::AssertUnwindSafe;
use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::Router;
use axum::body::Body;
use axum::extract::State;
use axum::http::{HeaderMap, HeaderName, HeaderValue, header};
use axum::response::{IntoResponse, Response};
use axum::routing::post;
use tokio::sync::oneshot;

use super::AppState;
use super::admission::{CostLimit, RenderSlot};
use super::error::ApiError;
use super::extract::{
    Accepted, Offers, RegionQuery, RequestInfo, SceneBody, charge_to, deadline_exceeded,
};
use super::memory::{Charge, Reservation};
use super::metrics::Metrics;
use super::shutdown::Phase;
use super::stream::{self, Aborter, BodyWriter};
use crate::format::{HitFormat, png};
use crate::output::{HitSink, PngSink};
use crate::render::{
    self, Cancel, ColourKernel, HitKernel, Rect, RenderStats, Renderer, SinkClosed, Stopped, Tile,
    TileSink, Work,
};
use crate::scene::Scene;

/// The routes: `POST /v1/render`, `POST /v1/hits`.
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/v1/render", post(render))
        .route("/v1/hits", post(hits))
}

/// What `/v1/render` answers with.
#[derive(Debug, Clone, Copy)]
pub struct PngOnly;

impl Offers for PngOnly {
    const OFFERS: &'static [&'static str] = &[png::MEDIA_TYPE];
}

/// What `/v1/hits` answers with, the default first (`docs/spec/hit-data.md`, Formats).
#[derive(Debug, Clone, Copy)]
pub struct HitTypes;

impl Offers for HitTypes {
    const OFFERS: &'static [&'static str] = &[
        HitFormat::Json.media_type(),
        HitFormat::Ndjson.media_type(),
        HitFormat::Npy.media_type(),
        HitFormat::Csv.media_type(),
    ];
}

/// The image's width in pixels (of the region when one was asked for).
pub const X_RAYTILE_WIDTH: HeaderName = HeaderName::from_static("x-raytile-width");
/// The image's height in pixels.
pub const X_RAYTILE_HEIGHT: HeaderName = HeaderName::from_static("x-raytile-height");
/// The rectangle of the full frame this answer covers: `x,y,w,h`.
pub const X_RAYTILE_REGION: HeaderName = HeaderName::from_static("x-raytile-region");
/// Rays traced (a trailer).
pub const X_RAYTILE_RAYS: HeaderName = HeaderName::from_static("x-raytile-rays");
/// `Server-Timing` (W3C): `parse` and `queue` in the head, `render` as a trailer.
pub const SERVER_TIMING: HeaderName = HeaderName::from_static("server-timing");

/// What a job writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Output {
    Png,
    Hits(HitFormat),
}

impl Output {
    fn media_type(self) -> &'static str {
        match self {
            Output::Png => png::MEDIA_TYPE,
            Output::Hits(f) => f.media_type(),
        }
    }

    /// What its pixels compute, which decides their cost.
    fn work(self) -> Work {
        match self {
            Output::Png => Work::Colour,
            Output::Hits(_) => Work::Hits,
        }
    }

    /// The `output` label of the duration histogram.
    fn label(self) -> &'static str {
        match self {
            Output::Png => png::NAME,
            Output::Hits(f) => f.name(),
        }
    }
}

// The extractors run in argument order: the cheap checks of the head (query, `Accept`)
// before the body is read and validated.

/// `POST /v1/render`.
async fn render(
    State(app): State<AppState>,
    info: RequestInfo,
    query: RegionQuery,
    _: Accepted<PngOnly>,
    headers: HeaderMap,
    body: SceneBody,
) -> Result<Response, ApiError> {
    start(app, info, query, &headers, body, Output::Png).await
}

/// `POST /v1/hits`.
async fn hits(
    State(app): State<AppState>,
    info: RequestInfo,
    query: RegionQuery,
    Accepted(media, _): Accepted<HitTypes>,
    headers: HeaderMap,
    body: SceneBody,
) -> Result<Response, ApiError> {
    let format = HitFormat::from_media_type(media).unwrap_or(HitFormat::Json);
    start(app, info, query, &headers, body, Output::Hits(format)).await
}

/// Why a render was pulled when the server shuts down.
const SHUTTING_DOWN: &str = "the server is shutting down";

/// Checks the region, takes a render slot, checks the cost, and starts the streamed
/// answer.
async fn start(
    app: AppState,
    info: RequestInfo,
    query: RegionQuery,
    headers: &HeaderMap,
    body: SceneBody,
    output: Output,
) -> Result<Response, ApiError> {
    let region = query.within(&body.scene)?;
    let deadline = info.start + app.config.deadline();
    let mut memory = body.memory;
    charge_output(&app, &body.scene, &mut memory, region, output, deadline).await?;
    let queued = Instant::now();
    let slot = tokio::time::timeout_at(deadline.into(), app.admission.admit(&app.shutdown))
        .await
        .map_err(|_| deadline_exceeded(&app))??;
    let queue = queued.elapsed();
    let trailers = wants_trailers(headers);

    let (writer, stream_body) = stream::channel(app.config.stall());
    let cost = CostLimit::new(&app.config);
    let cut = Cut::new(writer.aborter(), cost.token());
    let done = spawn_watch(&app, cut.clone(), deadline);
    let (verdict_tx, verdict) = oneshot::channel();
    let job = Job {
        app: app.clone(),
        scene: body.scene,
        region,
        output,
        cut,
        writer,
        trailers,
        slot,
        memory,
        done,
        cost,
        verdict: verdict_tx,
        span: tracing::Span::current(),
    };
    app.pool.spawn(move || job.run());
    // The watch cuts the pilot at the deadline and counts it; this timeout only makes
    // sure the answer is not later than that.
    match tokio::time::timeout_at(deadline.into(), verdict).await {
        Err(_) => return Err(ApiError::DeadlineExceeded(app.config.deadline())),
        Ok(Err(_)) => {
            return Err(ApiError::Internal(
                "the render ended before its cost was known".into(),
            ));
        }
        Ok(Ok(verdict)) => verdict?,
    }

    let mut res = Body::new(stream_body).into_response();
    let h = res.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static(output.media_type()),
    );
    h.insert(X_RAYTILE_WIDTH, HeaderValue::from(region.width));
    h.insert(X_RAYTILE_HEIGHT, HeaderValue::from(region.height));
    if let Ok(v) = HeaderValue::from_str(&region.to_string()) {
        h.insert(X_RAYTILE_REGION, v);
    }
    if let Ok(v) = HeaderValue::from_str(&format!(
        "parse;dur={:.3}, queue;dur={:.3}",
        ms(body.parse),
        ms(queue)
    )) {
        h.insert(SERVER_TIMING, v);
    }
    if trailers {
        h.insert(
            header::TRAILER,
            HeaderValue::from_static("server-timing, x-raytile-rays"),
        );
    }
    Ok(res)
}

/// Grows the scene's reservation by what streaming `region` as `output` holds
/// ([`crate::output::footprint`]), before a render slot is taken: a frame too wide to
/// stream within the budget is refused with 422 and `/image/width`.
async fn charge_output(
    app: &AppState,
    scene: &Scene,
    memory: &mut Reservation,
    region: Rect,
    output: Output,
    deadline: Instant,
) -> Result<(), ApiError> {
    let format = match output {
        Output::Png => None,
        Output::Hits(f) => Some(f),
    };
    let channel = crate::output::footprint::Channel {
        chunk_bytes: stream::CHUNK_BYTES,
        chunks: stream::CHANNEL_CHUNKS,
    };
    let streaming = crate::output::footprint(
        scene,
        format,
        region,
        app.config.tile,
        app.pool.current_num_threads(),
        channel,
    );
    let charge = Charge::fields(
        memory.bytes() + streaming,
        "streaming the answer",
        vec![crate::scene::Problem::new(
            "/image/width",
            format!(
                "a row of {} pixels drives the memory its answer holds while it streams",
                region.width
            ),
        )],
    );
    charge_to(app, memory, &charge, deadline.into()).await
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Whether the client said it accepts trailers (`TE: trailers`); hyper sends them
/// only then.
fn wants_trailers(headers: &HeaderMap) -> bool {
    headers
        .get_all(header::TE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .any(|t| {
            t.split(';')
                .next()
                .unwrap_or("")
                .trim()
                .eq_ignore_ascii_case("trailers")
        })
}

/// How a render is pulled: its cancel flag (tracing stops between tiles), the writer's
/// aborter (a wait for a client that does not read ends), and the reason.
#[derive(Debug, Clone)]
struct Cut {
    cancel: Cancel,
    aborter: Aborter,
    why: Arc<std::sync::OnceLock<&'static str>>,
}

impl Cut {
    fn new(aborter: Aborter, cancel: Cancel) -> Cut {
        Cut {
            cancel,
            aborter,
            why: Arc::new(std::sync::OnceLock::new()),
        }
    }

    fn pull(&self, why: &'static str) {
        let _ = self.why.set(why);
        self.cancel.cancel();
        self.aborter.abort();
    }
}

/// A tokio timer that pulls the render at its deadline or when the grace period ends.
/// It ends with the render: the job holds the sender of `done` and drops it at the end.
fn spawn_watch(app: &AppState, cut: Cut, deadline: Instant) -> oneshot::Sender<()> {
    let (done_tx, done) = oneshot::channel::<()>();
    let shutdown = app.shutdown.clone();
    let metrics = app.metrics.clone();
    tokio::spawn(async move {
        tokio::select! {
            _ = tokio::time::sleep_until(deadline.into()) => {
                metrics.reject("deadline");
                cut.pull("the deadline passed");
            }
            _ = shutdown.reached(Phase::Stopping) => cut.pull(SHUTTING_DOWN),
            _ = done => {}
        }
    });
    done_tx
}

/// Everything a render needs on its rayon thread.
struct Job {
    app: AppState,
    scene: Arc<Scene>,
    region: Rect,
    output: Output,
    cut: Cut,
    writer: BodyWriter,
    trailers: bool,
    slot: RenderSlot,
    /// The render's memory, given back when the job ends.
    memory: Reservation,
    done: oneshot::Sender<()>,
    cost: CostLimit,
    /// Whether the render may start: the cost pilot's answer, sent before any tracing.
    verdict: oneshot::Sender<Result<(), ApiError>>,
    span: tracing::Span,
}

/// Why a job stopped early.
#[derive(Debug, thiserror::Error)]
enum Failure {
    #[error(transparent)]
    Stopped(#[from] Stopped),
    #[error("cannot write the output: {0}")]
    Io(#[from] std::io::Error),
}

impl Job {
    /// Traces, streams and reports; runs on a rayon thread.
    fn run(self) {
        let Job {
            app,
            scene,
            region,
            output,
            cut,
            writer,
            trailers,
            slot,
            memory: _memory,
            done,
            cost,
            verdict,
            span,
        } = self;
        let _enter = span.enter();
        let started = Instant::now();
        let checked = std::panic::catch_unwind(AssertUnwindSafe(|| {
            // The pilot needs the acceleration structure; the render reuses it.
            let renderer = Renderer::new(scene);
            let v = cost.check(
                &renderer,
                region,
                output.work(),
                &cut.cancel,
                &app.metrics,
                "",
            );
            (renderer, v)
        }));
        let renderer = match checked {
            Ok((renderer, Ok(()))) => {
                // The handler may be gone (the client left): then the body is closed
                // too, and tracing stops at its first tile.
                let _ = verdict.send(Ok(()));
                renderer
            }
            Ok((_, Err(e))) => {
                // Refused before tracing: free the slot first, so that it is free by
                // the time the client reads the answer.
                drop(slot);
                drop(done);
                let e = match cut.why.get() {
                    Some(&SHUTTING_DOWN) => ApiError::ShuttingDown,
                    _ => e,
                };
                let _ = verdict.send(Err(e));
                return;
            }
            Err(_) => {
                // The handler answers 500 when the verdict is dropped unsent.
                tracing::error!("a render panicked before it started");
                app.metrics
                    .render_duration(output.label(), "failed")
                    .observe(started.elapsed().as_secs_f64());
                drop(slot);
                return;
            }
        };
        let result = std::panic::catch_unwind(AssertUnwindSafe(|| {
            trace(&app, renderer, region, output, &cut.cancel, &writer)
        }));
        let elapsed = started.elapsed();
        let outcome = match result {
            Ok(Ok(stats)) => {
                let t = trailers.then(|| render_trailers(elapsed, stats));
                match writer.finish(t) {
                    Ok(()) => {
                        tracing::debug!(rays = stats.rays, tiles = stats.tiles, "render complete");
                        "complete"
                    }
                    Err(_) => "cancelled",
                }
            }
            Ok(Err(e)) => {
                // A sink error or a cancel can follow from the client leaving or from a
                // cut; anything else is a fault.
                let why = if writer.is_closed() {
                    "the client went away"
                } else if writer.has_stalled() {
                    "the client stopped reading"
                } else if cut.cancel.is_over_budget() {
                    OVER_BUDGET
                } else if let Some(why) = cut.why.get() {
                    why
                } else if matches!(e, Failure::Stopped(Stopped::Cancelled)) {
                    "cancelled"
                } else {
                    ""
                };
                if why.is_empty() {
                    tracing::error!(error = %e, "render failed");
                    writer.fail(format!("the render failed: {e}"));
                    "failed"
                } else if why == OVER_BUDGET {
                    let limit = cut.cancel.budget().map_or(0, |b| b.limit());
                    tracing::warn!(limit, "render stopped early: {why}");
                    writer.fail(format!("{why} of {limit} rays"));
                    "over_budget"
                } else {
                    tracing::info!(reason = why, "render stopped early");
                    writer.fail(why);
                    "cancelled"
                }
            }
            Err(_) => {
                tracing::error!("a render panicked");
                writer.fail("the render failed");
                "failed"
            }
        };
        app.metrics
            .render_duration(output.label(), outcome)
            .observe(elapsed.as_secs_f64());
        // Free the slot only now, after the last byte was handed over.
        drop(slot);
        drop(done);
    }
}

/// Why a render that traced past its ray budget was stopped.
const OVER_BUDGET: &str = "the render traced more rays than its budget";

fn render_trailers(elapsed: Duration, stats: RenderStats) -> HeaderMap {
    let mut t = HeaderMap::new();
    if let Ok(v) = HeaderValue::from_str(&format!("render;dur={:.3}", ms(elapsed))) {
        t.insert(SERVER_TIMING, v);
    }
    t.insert(X_RAYTILE_RAYS, HeaderValue::from(stats.rays));
    t
}

/// Builds the sink for `output`, sends its header at once, traces, and completes it.
fn trace(
    app: &AppState,
    renderer: Renderer,
    region: Rect,
    output: Output,
    cancel: &Cancel,
    writer: &BodyWriter,
) -> Result<RenderStats, Failure> {
    let tile = app.config.tile;
    match output {
        Output::Png => {
            let png = PngSink::new(writer.clone(), region, tile)?;
            writer.send_pending()?;
            let sink = Observed::new(&png, writer, &app.metrics);
            let stats = render::run(&ColourKernel(&renderer), region, tile, cancel, &sink)?;
            png.finish()?;
            Ok(stats)
        }
        Output::Hits(format) => {
            let hits = HitSink::new(&renderer.scene, format, writer.clone(), region, tile)?;
            writer.send_pending()?;
            let sink = Observed::new(&hits, writer, &app.metrics);
            let stats = render::run(&HitKernel(&renderer), region, tile, cancel, &sink)?;
            hits.finish()?;
            Ok(stats)
        }
    }
}

/// Wraps a sink: counts rays and tiles into the metrics, refuses tiles once the client
/// is gone (so tracing stops even while no bytes are due), and sends the bytes each
/// tile released (a completed band of rows, or an NDJSON line) without waiting for a
/// full chunk, so the first rows leave early.
struct Observed<'a, S> {
    inner: &'a S,
    writer: &'a BodyWriter,
    metrics: &'a Metrics,
}

impl<'a, S> Observed<'a, S> {
    fn new(inner: &'a S, writer: &'a BodyWriter, metrics: &'a Metrics) -> Self {
        Observed {
            inner,
            writer,
            metrics,
        }
    }
}

impl<T, S: TileSink<T>> TileSink<T> for Observed<'_, S> {
    fn tile(&self, tile: Tile<T>) -> Result<(), SinkClosed> {
        self.metrics.rays.inc_by(tile.rays);
        self.metrics.tiles.inc();
        if self.writer.is_closed() {
            return Err(SinkClosed("the client went away".into()));
        }
        self.inner.tile(tile)?;
        self.writer
            .send_pending()
            .map_err(|e| SinkClosed(e.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn te_trailers_is_recognised() {
        let mut h = HeaderMap::new();
        assert!(!wants_trailers(&h));
        h.insert(header::TE, HeaderValue::from_static("gzip, trailers"));
        assert!(wants_trailers(&h));
    }
}
