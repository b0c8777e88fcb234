//! `POST /v1/render` (scene → PNG) and `POST /v1/hits` (scene → per-pixel hit data),
//! both streamed while tiles finish, both with `?region=x,y,w,h`.
//!
//! The order is the point: every failure is decided before the first byte
//! (extract and validate, negotiate, admit, estimate the cost), because once the status
//! line is out it cannot change. Then the job goes to the pool's queue with its render
//! slot; there it builds the acceleration structure and runs the cost pilot
//! ([`CostLimit::check`]), whose verdict the handler awaits: a scene past `--max-rays`
//! is refused with 422, any other returns with a body fed by [`super::stream`].
//!
//! The tiles are then traced a step at a time on the [`Scheduler`] (one tile a step, as
//! many lanes as the pool has threads), so the tiles of every admitted render
//! interleave. Before each tile a lane checks whether the client is behind
//! ([`BodyWriter::is_backed_up`]); if so the render parks once its last lane stops: it
//! holds no thread, gives back its render slot, and waits on the runtime for its client
//! ([`BodyWriter::room`]); when the client has read it takes a slot again
//! ([`super::admission::Admission::readmit`]) and its lanes resume. A client that takes
//! nothing for `--stall-seconds` stops it for good (outcome `cancelled`).
//!
//! After the first byte, five things can cut the stream: the client leaving (the body
//! is dropped; tracing stops at the next tile), the client taking nothing for
//! `--stall-seconds`, the deadline (a tokio timer cancels the render), the end of the
//! shutdown grace period, and the render's ray budget (its cancel token goes up once it
//! has traced half as much again as `--max-rays`; its outcome is `over_budget`). A cut
//! stream ends with a body error, so hyper aborts the transfer and the client cannot
//! mistake a partial image for a whole one.
//!
//! Headers: `X-Raytile-Width` and `X-Raytile-Height` (the size of this answer's image),
//! `X-Raytile-Region` (`x,y,w,h` in the full frame), and `Server-Timing` with `parse`
//! and `queue` durations, which are known when the head leaves. How long tracing took is
//! known only at the end: a client that sends `TE: trailers` gets it as a trailer,
//! `Server-Timing: render;dur=…` with `X-Raytile-Rays`; every client finds it in the log
//! line and the `raytile_render_duration_seconds` histogram.

use std::panic::AssertUnwindSafe;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
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
use super::shutdown::Phase;
use super::stream::{self, Aborter, BodyWriter, Room};
use crate::format::{HitFormat, png};
use crate::output::rows::{LANES_PER_THREAD, WINDOW_PER_LANE};
use crate::output::{HitSink, PngSink};
use crate::render::{
    Cancel, ColourKernel, HitKernel, Rect, RenderStats, Renderer, Scheduler, SinkClosed, Step,
    Stopped, TileCursor, TileShape, TileSink, Work, trace_tile,
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

    let (writer, stream_body) = stream::channel();
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
        runtime: tokio::runtime::Handle::current(),
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
/// ([`fn@crate::output::footprint`]), before a render slot is taken: a frame too wide to
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
    let streaming = crate::output::footprint(
        scene,
        format,
        region,
        app.config.tile,
        app.pool.current_num_threads(),
        stream::IN_FLIGHT_BYTES,
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

/// Everything a render needs to start on a trace thread.
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
    /// Where a parked render waits for its client.
    runtime: tokio::runtime::Handle,
}

/// Why a job stopped early.
#[derive(Debug, thiserror::Error)]
enum Failure {
    #[error(transparent)]
    Stopped(#[from] Stopped),
    #[error("cannot write the output: {0}")]
    Io(#[from] std::io::Error),
    #[error("a trace thread panicked")]
    Panicked,
}

impl Job {
    /// Builds the acceleration structure, checks the cost, writes the output's header
    /// and schedules the tiles; runs on a trace thread.
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
            runtime,
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
        let sink = match output {
            Output::Png => PngSink::new(writer.clone(), region).map(|s| Sink::Png(Box::new(s))),
            Output::Hits(f) => {
                HitSink::new(renderer.scene.clone(), f, writer.clone(), region).map(Sink::Hits)
            }
        }
        .and_then(|sink| writer.send_pending().map(|()| sink));
        let lanes = app.pool.current_num_threads().max(1) * LANES_PER_THREAD;
        let (rects, sink, failure) = match sink {
            Ok(sink) => (
                sink.shape(region, app.config.tile).cut(region),
                Some(sink),
                None,
            ),
            Err(e) => (Vec::new(), None, Some(Failure::Io(e))),
        };
        let render = Arc::new(Render {
            app: app.clone(),
            renderer,
            output,
            sink,
            cursor: TileCursor::new(rects, lanes * WINDOW_PER_LANE),
            lanes,
            cut,
            writer,
            trailers,
            runtime,
            span: span.clone(),
            started,
            rays: AtomicU64::new(0),
            stalled: AtomicBool::new(false),
            lanes_state: Mutex::new(Lanes {
                running: lanes,
                parking: false,
                parked: false,
                failure,
                finished: false,
                slot: Some(slot),
                done: Some(done),
            }),
        });
        for _ in 0..lanes {
            app.pool.schedule(render.clone());
        }
    }
}

/// The sink a render writes into.
enum Sink {
    Png(Box<PngSink<BodyWriter>>),
    Hits(HitSink<BodyWriter>),
}

impl Sink {
    fn shape(&self, region: Rect, tile_px: u32) -> TileShape {
        match self {
            Sink::Png(s) => s.tile_shape(region, tile_px),
            Sink::Hits(s) => s.tile_shape(region, tile_px),
        }
    }

    fn finish(&self) -> std::io::Result<()> {
        match self {
            Sink::Png(s) => s.finish(),
            Sink::Hits(s) => s.finish(),
        }
    }
}

/// A render being traced: `lanes` steps of it at a time on the scheduler, each one
/// tile. Before each tile a lane checks that the client is not behind; when it is, the
/// lanes stop, and once the last has stopped the render parks: it gives back its slot
/// and waits on the runtime for the client ([`BodyWriter::room`]); when the client has
/// read, it takes a slot again and its lanes resume. A client that takes nothing for
/// `--stall-seconds` stops it for good.
struct Render {
    app: AppState,
    renderer: Renderer,
    output: Output,
    /// None when it could not be started (its header could not be written).
    sink: Option<Sink>,
    cursor: TileCursor,
    lanes: usize,
    cut: Cut,
    writer: BodyWriter,
    trailers: bool,
    runtime: tokio::runtime::Handle,
    span: tracing::Span,
    started: Instant,
    rays: AtomicU64,
    /// The client took nothing for the whole stall period.
    stalled: AtomicBool,
    lanes_state: Mutex<Lanes>,
}

/// The lanes of a [`Render`] and what it holds.
struct Lanes {
    /// Lanes scheduled or running a step.
    running: usize,
    /// A lane found the client behind: no lane goes on until the render resumes.
    parking: bool,
    /// Every lane has stopped and the render waits for its client.
    parked: bool,
    /// The first reason a lane stopped for good.
    failure: Option<Failure>,
    finished: bool,
    slot: Option<RenderSlot>,
    /// Ends the deadline watch when dropped.
    done: Option<oneshot::Sender<()>>,
}

/// What one step of a lane did.
enum Stepped {
    /// Traced a tile and handed it to the sink.
    Traced,
    /// Found no tile to take now (all taken, or the window full).
    Idle,
    /// Found the client behind.
    Behind,
    Failed(Failure),
}

impl Render {
    fn lock(&self) -> std::sync::MutexGuard<'_, Lanes> {
        // Every update of the state is a few assignments, consistent at every point.
        self.lanes_state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// One tile, unless the render must stop or wait.
    fn one_tile(&self) -> Stepped {
        let Some(sink) = &self.sink else {
            return Stepped::Idle;
        };
        if self.cut.cancel.is_cancelled() {
            return Stepped::Failed(Stopped::Cancelled.into());
        }
        if self.writer.is_closed() {
            return Stepped::Failed(
                Stopped::Sink(SinkClosed("the client went away".into())).into(),
            );
        }
        if self.writer.is_backed_up() {
            return Stepped::Behind;
        }
        let Some((i, rect)) = self.cursor.take() else {
            return Stepped::Idle;
        };
        let traced = std::panic::catch_unwind(AssertUnwindSafe(|| self.trace(sink, rect)));
        self.cursor.finished(i);
        match traced {
            Ok(Ok(())) => Stepped::Traced,
            Ok(Err(e)) => Stepped::Failed(e),
            Err(_) => Stepped::Failed(Failure::Panicked),
        }
    }

    fn trace(&self, sink: &Sink, rect: Rect) -> Result<(), Failure> {
        let cancel = &self.cut.cancel;
        let sent = match sink {
            Sink::Png(s) => {
                let t = trace_tile(&ColourKernel(&self.renderer), rect, cancel)?;
                self.count(t.rays);
                s.tile(t)
            }
            Sink::Hits(s) => {
                let t = trace_tile(&HitKernel(&self.renderer), rect, cancel)?;
                self.count(t.rays);
                s.tile(t)
            }
        };
        sent.map_err(Stopped::Sink)?;
        // The bytes the tile released leave now if the client is waiting for them.
        self.writer.send_pending()?;
        Ok(())
    }

    fn count(&self, rays: u64) {
        self.rays.fetch_add(rays, Ordering::Relaxed);
        self.app.metrics.rays.inc_by(rays);
        self.app.metrics.tiles.inc();
    }

    /// Parks: gives back the slot and waits on the runtime for the client.
    fn park(self: &Arc<Self>, l: &mut Lanes, scheduler: &Arc<Scheduler>) {
        l.parked = true;
        drop(l.slot.take());
        self.app.metrics.parked.inc();
        tracing::debug!(
            queued = self.writer.queued_bytes(),
            "render parked: the client is behind"
        );
        let (me, scheduler) = (self.clone(), scheduler.clone());
        self.runtime.spawn(async move {
            let slot = match me.writer.room(me.app.config.stall()).await {
                Room::Ready => tokio::select! {
                    s = me.app.admission.readmit() => s.ok(),
                    _ = me.writer.aborted() => None,
                },
                Room::Stalled => {
                    me.stalled.store(true, Ordering::Relaxed);
                    me.cut.cancel.cancel();
                    None
                }
                // The lanes find out why at their first step.
                Room::Closed | Room::Aborted => None,
            };
            if slot.is_none() && !me.cut.cancel.is_cancelled() && !me.writer.is_closed() {
                me.cut.pull(SHUTTING_DOWN);
            }
            me.app.metrics.parked.dec();
            me.resume(slot, &scheduler);
        });
    }

    /// Takes the slot back and starts every lane again.
    fn resume(self: &Arc<Self>, slot: Option<RenderSlot>, scheduler: &Arc<Scheduler>) {
        {
            let mut l = self.lock();
            l.parked = false;
            l.parking = false;
            l.slot = slot;
            l.running = self.lanes;
        }
        for _ in 0..self.lanes {
            scheduler.schedule(self.clone());
        }
    }

    /// Completes the body (or fails it), records the outcome and frees the slot.
    fn finish(&self, l: &mut Lanes) {
        l.finished = true;
        let elapsed = self.started.elapsed();
        let failure = l.failure.take().or_else(|| {
            let sink = self.sink.as_ref()?;
            sink.finish().err().map(Failure::Io)
        });
        let outcome = match failure {
            None => {
                let stats = RenderStats {
                    tiles: self.cursor.len() as u64,
                    rays: self.rays.load(Ordering::Relaxed),
                    trace_thread_time: Duration::ZERO,
                };
                let t = self.trailers.then(|| render_trailers(elapsed, stats));
                match self.writer.finish(t) {
                    Ok(()) => {
                        tracing::debug!(rays = stats.rays, tiles = stats.tiles, "render complete");
                        "complete"
                    }
                    Err(_) => "cancelled",
                }
            }
            Some(e) => self.fail(e),
        };
        self.app
            .metrics
            .render_duration(self.output.label(), outcome)
            .observe(elapsed.as_secs_f64());
        // Free the slot only now, after the last byte was handed over.
        drop(l.slot.take());
        drop(l.done.take());
    }

    /// Ends the body with the reason it stopped; returns the outcome.
    fn fail(&self, e: Failure) -> &'static str {
        // A sink error or a cancel can follow from the client leaving or from a cut;
        // anything else is a fault.
        let why = if self.writer.is_closed() {
            "the client went away"
        } else if self.stalled.load(Ordering::Relaxed) {
            "the client stopped reading"
        } else if self.cut.cancel.is_over_budget() {
            OVER_BUDGET
        } else if let Some(why) = self.cut.why.get() {
            why
        } else if matches!(e, Failure::Stopped(Stopped::Cancelled)) {
            "cancelled"
        } else {
            ""
        };
        if why.is_empty() {
            tracing::error!(error = %e, "render failed");
            self.writer.fail(format!("the render failed: {e}"));
            "failed"
        } else if why == OVER_BUDGET {
            let limit = self.cut.cancel.budget().map_or(0, |b| b.limit());
            tracing::warn!(limit, "render stopped early: {why}");
            self.writer.fail(format!("{why} of {limit} rays"));
            "over_budget"
        } else {
            tracing::info!(reason = why, "render stopped early");
            self.writer.fail(why);
            "cancelled"
        }
    }
}

impl Step for Render {
    fn step(self: Arc<Self>, scheduler: &Arc<Scheduler>) {
        let span = self.span.clone();
        let _enter = span.enter();
        let stepped = self.one_tile();
        let mut l = self.lock();
        let mut more = 0;
        match stepped {
            Stepped::Traced if !l.parking && l.failure.is_none() => {
                // This lane goes on, and lanes that found the window full come back
                // now that it has moved.
                more = 1;
                while l.running < self.lanes && self.cursor.can_take() {
                    l.running += 1;
                    more += 1;
                }
            }
            Stepped::Traced | Stepped::Idle => l.running -= 1,
            Stepped::Behind => {
                l.running -= 1;
                l.parking = true;
            }
            Stepped::Failed(e) => {
                l.running -= 1;
                if l.failure.is_none() {
                    l.failure = Some(e);
                }
                // The other lanes stop at their next row.
                self.cut.cancel.cancel();
            }
        }
        if l.running == 0 && !l.finished && !l.parked {
            if l.failure.is_some() || self.cursor.is_done() || self.sink.is_none() {
                self.finish(&mut l);
            } else if l.parking {
                self.park(&mut l, scheduler);
            } else {
                // Every lane found the window full while no tile ran: cannot happen
                // (the oldest tile running opens it), but a lane more costs nothing.
                l.running = 1;
                more = 1;
            }
        }
        drop(l);
        for _ in 0..more {
            scheduler.schedule(self.clone());
        }
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
