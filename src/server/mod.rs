//! The HTTP service (`docs/spec/http.md`): axum on tokio in front of the renderer on rayon.
//! Tokio's threads only move bytes; tracing runs on a rayon pool of `--threads`.
//!
//! Where to start reading:
//! - [`app`] builds the router, the same one the tests talk to; [`serve`] binds it and
//!   runs it until SIGTERM or Ctrl-C, then drains.
//! - one file per group of routes: [`render`] (`/v1/render`, `/v1/hits`), [`trace`]
//!   (`/v1/trace`), [`grade`] (`/v1/grade`), [`validate`], [`scenes`], [`health`],
//!   [`metrics`], [`assignments`] (`/v1/assignments`: push, read, submit),
//!   [`gradebook`] (an assignment's submissions, grades and statistics);
//! - the machinery they share: [`connection`] (the accept loop: connection cap, header
//!   and idle timeouts), [`extract`] (body, query, `Accept`), [`admission`]
//!   (render slots and the queue), [`memory`] (the memory budget every request is
//!   charged against), [`stream`] (rayon thread → response body), [`job`]
//!   (CPU work that answers in one piece, admitted like a render),
//!   [`error`] (every failure → `application/problem+json`, in one place),
//!   [`observe`] (request ids, log lines, request counts), [`shutdown`] (the phases of
//!   a graceful stop), [`auth`] (bearer tokens under `--require-token`).
//!
//! [`app`]: crate::server::app
//! [`serve`]: crate::server::serve
//! [`render`]: crate::server::render
//! [`trace`]: crate::server::trace
//! [`grade`]: crate::server::grade
//! [`validate`]: crate::server::validate
//! [`scenes`]: crate::server::scenes
//! [`health`]: crate::server::health
//! [`metrics`]: crate::server::metrics
//! [`assignments`]: crate::server::assignments
//! [`gradebook`]: crate::server::gradebook
//! [`connection`]: crate::server::connection
//! [`extract`]: crate::server::extract
//! [`admission`]: crate::server::admission
//! [`memory`]: crate::server::memory
//! [`stream`]: crate::server::stream
//! [`job`]: crate::server::job
//! [`error`]: crate::server::error
//! [`observe`]: crate::server::observe
//! [`shutdown`]: crate::server::shutdown
//! [`auth`]: crate::server::auth

pub mod admission;
pub mod assignments;
pub mod auth;
pub mod connection;
pub mod error;
pub mod extract;
pub mod grade;
pub mod gradebook;
pub mod health;
pub mod job;
pub mod memory;
pub mod metrics;
pub mod observe;
pub mod places;
pub mod render;
pub mod scenes;
pub mod shutdown;
pub mod stream;
pub mod studio;
pub mod trace;
pub mod validate;

use std::future::Future;
use std::ops::Deref;
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;
use axum::Router;
use tokio::net::TcpListener;
use tower_http::catch_panic::CatchPanicLayer;

use crate::config::ServeArgs;
use crate::grade::cache::ReferenceCache;
use crate::render::Scheduler;
use crate::store::Store;
use admission::Admission;
use memory::MemoryBudget;
use metrics::Metrics;
use shutdown::{Phase, Shutdown};

/// After the grace period, how long cut streams get to close, and cut renders to stop,
/// before we exit anyway.
const CUT_WAIT: Duration = Duration::from_secs(5);

/// What every handler shares; cheap to clone.
#[derive(Debug, Clone)]
pub struct AppState(Arc<Shared>);

/// The shared state behind [`AppState`].
#[derive(Debug)]
pub struct Shared {
    /// The configuration.
    pub config: ServeArgs,
    /// The threads that trace, behind one queue that interleaves the renders' tiles.
    pub pool: Arc<Scheduler>,
    /// Render slots and the queue.
    pub admission: Admission,
    /// The memory budget.
    pub memory: MemoryBudget,
    /// The metrics.
    pub metrics: Metrics,
    /// Running, draining or stopping.
    pub shutdown: Shutdown,
    /// The token store, opened when `--require-token` is set.
    pub auth: Option<auth::Auth>,
    /// The references of recently graded scenes, `--reference-cache-bytes`, kept in the
    /// memory budget.
    pub references: Arc<ReferenceCache>,
    /// The assignment routes' token checks, on the store opened when first needed.
    pub course: assignments::Course,
}

impl Deref for AppState {
    type Target = Shared;
    fn deref(&self) -> &Shared {
        &self.0
    }
}

impl AppState {
    /// Starts the rayon pool and sets up admission and metrics for `config`, without a
    /// token store (so not with `--require-token`: see [`AppState::with_store`]).
    pub fn new(config: ServeArgs) -> anyhow::Result<AppState> {
        AppState::with_store(config, None)
    }

    /// [`AppState::new`] with the store that `--require-token` checks tokens against.
    pub fn with_store(config: ServeArgs, store: Option<Store>) -> anyhow::Result<AppState> {
        config.check().map_err(anyhow::Error::msg)?;
        if config.require_token && store.is_none() {
            anyhow::bail!("--require-token needs the token store");
        }
        let auth = store.map(|s| auth::Auth::new(s, config.admin_token.as_ref()));
        let slots = config.max_renders();
        let metrics = Metrics::new(slots, config.queue).context("cannot register the metrics")?;
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(config.threads())
            .thread_name(|i| format!("raytile-trace-{i}"))
            // Jobs catch their own panics; this is the backstop that keeps a panic on a
            // trace thread from aborting the process (rayon's default).
            .panic_handler(|_| tracing::error!("a trace thread panicked"))
            .build()
            .context("cannot start the trace threads")?;
        let memory = MemoryBudget::new(config.memory_bytes, config.queue, metrics.clone());
        let references = Arc::new(ReferenceCache::new(
            config.reference_cache_bytes(),
            Some(memory.cache_ledger()),
            metrics.reference_cache.clone(),
        ));
        memory.reclaim_from(references.clone());
        Ok(AppState(Arc::new(Shared {
            admission: Admission::new(slots, config.queue, metrics.clone()),
            memory,
            references,
            config,
            pool: Scheduler::new(pool),
            metrics,
            shutdown: Shutdown::default(),
            course: assignments::Course::new(auth.clone()),
            auth,
        })))
    }
}

/// The whole service as a router: every route, the 404 and 405 fallbacks, and the
/// layers (panics to 500, request ids, logs and counts).
pub fn app(state: AppState) -> Router {
    // The routes that take a posted scene: whoever may call them can render a reference.
    let scene_routes = Router::new()
        .merge(render::router())
        .merge(trace::router())
        .merge(grade::router())
        .merge(validate::router());
    let scene_routes = if state.config.require_token {
        scene_routes.route_layer(axum::middleware::from_fn_with_state(
            state.clone(),
            auth::require_instructor,
        ))
    } else {
        scene_routes
    };
    Router::new()
        .merge(scene_routes)
        .merge(scenes::router())
        .merge(assignments::router())
        .merge(gradebook::router())
        .merge(health::router())
        .merge(metrics::router())
        .merge(studio::router())
        .fallback(error::not_found)
        // After the routes: it applies to the routes that exist when it is called.
        .method_not_allowed_fallback(error::method_not_allowed)
        .layer(CatchPanicLayer::custom(error::panic_response))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            observe::observe,
        ))
        .with_state(state)
}

/// Binds `config.addr`, logs the address, and serves until SIGTERM or Ctrl-C.
pub async fn serve(config: ServeArgs) -> anyhow::Result<()> {
    let listener = TcpListener::bind(config.addr)
        .await
        .with_context(|| format!("cannot listen on {}", config.addr))?;
    let addr = listener.local_addr()?;
    let store = if config.require_token {
        Some(
            config
                .store
                .open()
                .await
                .context("cannot open the token store")?,
        )
    } else {
        None
    };
    let state = AppState::with_store(config, store)?;
    tracing::info!(
        %addr,
        max_renders = state.config.max_renders(),
        queue = state.config.queue,
        memory_bytes = state.config.memory_bytes,
        threads = state.pool.current_num_threads(),
        require_token = state.config.require_token,
        "listening on http://{addr}"
    );
    run(listener, state, shutdown_signal()).await
}

/// Serves on `listener` until `signal` resolves, then shuts down gracefully: stop
/// accepting, refuse new work with 503 (`/readyz` too), let in-flight responses finish
/// for the grace period, then cut what is left and return.
pub async fn run(
    listener: TcpListener,
    state: AppState,
    signal: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    let shutdown = state.shutdown.clone();
    let metrics = state.metrics.clone();
    let grace = state.config.grace();
    let draining = {
        let shutdown = shutdown.clone();
        async move {
            signal.await;
            tracing::info!(
                grace_seconds = grace.as_secs_f64(),
                "shutting down: refusing new work, finishing in-flight responses"
            );
            shutdown.advance(Phase::Draining);
        }
    };
    let limits = state.config.connection_limits();
    let server = connection::serve_connections(listener, app(state), limits, draining);
    let mut server = std::pin::pin!(server);
    // Either the server ends by itself (with no connections open it ends as soon as the
    // drain begins), or the drain begins first and gets the grace period.
    let ended = tokio::select! {
        () = &mut server => Some(()),
        _ = shutdown.reached(Phase::Draining) => None,
    };
    match ended {
        Some(()) => {}
        None => match tokio::time::timeout(grace, &mut server).await {
            Ok(()) => {}
            Err(_) => {
                tracing::warn!("the grace period is over: cutting the responses still in flight");
                shutdown.advance(Phase::Stopping);
                if tokio::time::timeout(CUT_WAIT, &mut server).await.is_err() {
                    tracing::warn!("some connections are still open; exiting anyway");
                }
            }
        },
    }
    // Cut renders stop within a tile; let them release their slots (and log why they
    // stopped) before saying so, but not for ever.
    let wind_down = tokio::time::Instant::now() + CUT_WAIT;
    while metrics.in_flight.get() > 0 && tokio::time::Instant::now() < wind_down {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    tracing::info!("stopped");
    Ok(())
}

/// Resolves on SIGTERM or Ctrl-C (SIGINT).
pub async fn shutdown_signal() {
    let ctrl_c = async {
        if tokio::signal::ctrl_c().await.is_err() {
            // No handler could be installed: wait for SIGTERM alone.
            std::future::pending::<()>().await;
        }
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {}
        _ = term => {}
    }
}
