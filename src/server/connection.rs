//! Connections: the accept loop and what each connection may hold.
//!
//! `axum::serve` has no header-read timeout, no idle timeout and no connection cap, so a
//! few hundred sockets that send nothing (or one byte a minute) would hold file
//! descriptors for ever and lock everyone else out. Here every connection is served by
//! hyper's HTTP/1 server under three rules, each a setting of `raytile serve`:
//!
//! - **`--max-connections`**: connections open at once, lowered at start to what the
//!   process's file-descriptor limit allows (the soft limit is first raised to the hard
//!   one; [`RESERVED_DESCRIPTORS`] stay free for everything else). At the cap, a new
//!   connection takes the place of the longest-waiting one that has no request in
//!   flight (silent since accept, dripping its head, or kept alive and idle): that one
//!   is closed, as HTTP allows for a connection between requests. The newcomer must
//!   send its first byte within half a second to do so (a silent one is no better than
//!   those it would displace), and only 16 may try at once. Otherwise, or when every
//!   connection has a request in flight, the new one is answered with a 503
//!   problem document (`too-many-connections`, `Retry-After`) and closed, without
//!   reading it, so a proxy retries elsewhere. So sockets that send nothing can never
//!   lock out a client that does.
//! - **`--header-timeout-seconds`**: once a request's first byte has arrived, its head
//!   (request line and headers) must be complete within this; a new connection must
//!   send its first byte within it too. A client that drips its headers is cut.
//! - **`--idle-timeout-seconds`**: a kept-alive connection with no request in flight is
//!   closed after this. Kept longer than a proxy's upstream keep-alive (nginx: 60 s)
//!   so that the proxy, not us, closes idle connections, and never reuses one we closed.
//!
//! A request in flight (its body being read, or its response streaming) is never cut
//! by these: the request deadline and the stall rule of [`super::stream`] govern it.

use std::collections::HashMap;
use std::future::Future;
use std::io;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use axum::Router;
use axum::body::Body;
use axum::http::Request;
use hyper::body::Incoming;
use hyper_util::rt::{TokioIo, TokioTimer};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{Notify, Semaphore, watch};
use tokio::time::Instant;
use tower::ServiceExt;

use super::error::ApiError;
use super::places::Places;
use crate::config::ConnectionLimits;

/// Accepts connections on `listener` and serves `app` on each, under `limits`, until
/// `drain` resolves; then stops accepting, asks every connection to finish its
/// current response and close, and resolves once all have closed.
pub async fn serve_connections(
    listener: TcpListener,
    app: Router,
    limits: ConnectionLimits,
    drain: impl Future<Output = ()>,
) {
    let limits = ConnectionLimits {
        max_connections: descriptor_cap(limits.max_connections),
        ..limits
    };
    let slots = Arc::new(Semaphore::new(limits.max_connections));
    let open = Arc::new(Registry::default());
    let probation = Arc::new(Places::new(MOST_WAITING));
    let (closing_tx, closing_rx) = watch::channel(false);
    let mut drain = std::pin::pin!(drain);
    loop {
        let (tcp, peer) = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok(a) => a,
                Err(e) => {
                    // Out of file descriptors, or the peer left during the handshake:
                    // pause briefly instead of spinning, then go on.
                    tracing::debug!(error = %e, "accept failed");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            },
            _ = &mut drain => break,
        };
        // Streamed bodies go out as many small writes (the head, the PNG header, each
        // band): without TCP_NODELAY, Nagle's algorithm holds each one back until the
        // client's delayed ACK, about 40 ms per response.
        if let Err(e) = tcp.set_nodelay(true) {
            tracing::debug!(error = %e, "cannot set TCP_NODELAY");
        }
        let app = app.clone();
        let closing = closing_rx.clone();
        let open = open.clone();
        if let Ok(permit) = slots.clone().try_acquire_owned() {
            tokio::spawn(async move {
                serve_one(tcp, app, limits, closing, &open).await;
                drop(permit);
            });
            continue;
        }
        // A newcomer on probation holds a descriptor beyond the cap, so only a few may
        // wait at once (within the reserve); the others are refused at once.
        let Some(waiting) = probation.enter_owned() else {
            tracing::warn!(%peer, limit = limits.max_connections, "too many connections: refused");
            refuse(tcp, limits.max_connections);
            continue;
        };
        let slots = slots.clone();
        tokio::spawn(async move {
            // Only a newcomer that sends its request promptly displaces a connection;
            // a silent one, like those filling the cap, is refused.
            let spoke = tokio::time::timeout(PROBATION, tcp.readable()).await;
            let slot = match spoke {
                Ok(Ok(())) if open.evict_one() => {
                    // The evicted connection gives its slot back as soon as its task
                    // sees the request.
                    tokio::time::timeout(EVICTION_WAIT, slots.acquire_owned())
                        .await
                        .ok()
                        .and_then(Result::ok)
                }
                _ => None,
            };
            drop(waiting);
            match slot {
                Some(permit) => {
                    serve_one(tcp, app, limits, closing, &open).await;
                    drop(permit);
                }
                None => {
                    tracing::warn!(%peer, limit = limits.max_connections, "too many connections: refused");
                    refuse(tcp, limits.max_connections);
                }
            }
        });
    }
    drop(listener);
    let _ = closing_tx.send(true);
    // Every permit back means every connection has closed.
    let _ = slots.acquire_many(limits.max_connections as u32).await;
}

/// File descriptors kept free of connections: the listener, the runtime's poller, log
/// and data files, the database's connections.
pub const RESERVED_DESCRIPTORS: u64 = 64;

/// How soon a newcomer at the cap must send its first byte to displace a connection.
const PROBATION: Duration = Duration::from_millis(500);

/// Longest a connection that displaced an idle one waits for its slot.
const EVICTION_WAIT: Duration = Duration::from_secs(1);

/// Newcomers at the cap that may be on probation, or waiting for the slot of a
/// connection closed for them, at once.
const MOST_WAITING: usize = 16;

/// The connection cap the descriptor limit allows: `wanted`, or fewer when the process
/// may not open that many files. The soft limit is raised to the hard one first, as
/// servers do; past the descriptors, `accept` would fail and every client would wait.
fn descriptor_cap(wanted: usize) -> usize {
    use rustix::process::{Resource, Rlimit, getrlimit, setrlimit};
    let limit = getrlimit(Resource::Nofile);
    let raised = match (limit.current, limit.maximum) {
        (Some(soft), hard) if hard.is_none_or(|h| h > soft) => {
            let target = Rlimit {
                current: hard,
                maximum: hard,
            };
            match setrlimit(Resource::Nofile, target) {
                Ok(()) => hard,
                Err(e) => {
                    tracing::debug!(error = %e, "cannot raise the descriptor limit");
                    Some(soft)
                }
            }
        }
        (soft, _) => soft,
    };
    let Some(descriptors) = raised else {
        return wanted;
    };
    let allowed = descriptors.saturating_sub(RESERVED_DESCRIPTORS).max(1);
    let allowed = usize::try_from(allowed).unwrap_or(usize::MAX);
    if allowed < wanted {
        tracing::warn!(
            descriptors,
            wanted,
            allowed,
            "the file-descriptor limit lowers --max-connections"
        );
        return allowed;
    }
    wanted
}

/// The open connections, so that one with no request in flight can be closed to make
/// room for a new one at the cap.
#[derive(Default)]
struct Registry {
    open: Mutex<(u64, HashMap<u64, Arc<Activity>>)>,
}

impl Registry {
    fn add(&self, a: Arc<Activity>) -> u64 {
        let mut open = self.open.lock().unwrap_or_else(|e| e.into_inner());
        open.0 += 1;
        let id = open.0;
        open.1.insert(id, a);
        id
    }

    fn remove(&self, id: u64) {
        let mut open = self.open.lock().unwrap_or_else(|e| e.into_inner());
        open.1.remove(&id);
    }

    /// Asks the connection that has waited longest without a request in flight to
    /// close: one that has never finished a head before one kept alive between
    /// requests. False when every connection is busy.
    fn evict_one(&self) -> bool {
        let open = self.open.lock().unwrap_or_else(|e| e.into_inner());
        let victim = open
            .1
            .values()
            .filter(|a| !a.is_evicted())
            .filter_map(|a| a.eviction_rank().map(|rank| (rank, a)))
            .min_by_key(|(rank, _)| *rank)
            .map(|(_, a)| a.clone());
        match victim {
            Some(a) => {
                a.evict();
                true
            }
            None => false,
        }
    }
}

/// Keeps a connection in the [`Registry`] while it is served.
struct Registered<'a>(&'a Registry, u64);

impl Drop for Registered<'_> {
    fn drop(&mut self) {
        self.0.remove(self.1);
    }
}

/// Answers a connection over the cap with a 503 and closes it. One non-blocking write:
/// the socket's buffer is empty, and a client that cannot take 300 bytes gets nothing.
fn refuse(tcp: TcpStream, limit: usize) {
    let answer = refusal_bytes(limit);
    let _ = tcp.try_write(&answer);
}

/// The bytes of the 503 a connection over the cap gets, head and problem document.
fn refusal_bytes(limit: usize) -> Vec<u8> {
    let e = ApiError::TooManyConnections { limit };
    let body = serde_json::to_vec(&e.problem()).unwrap_or_default();
    let mut out = format!(
        "HTTP/1.1 503 Service Unavailable\r\ncontent-type: {}\r\nretry-after: {}\r\n\
         connection: close\r\ncontent-length: {}\r\n\r\n",
        super::error::PROBLEM_JSON,
        super::error::RETRY_AFTER_SECONDS,
        body.len()
    )
    .into_bytes();
    out.extend_from_slice(&body);
    out
}

/// Serves one connection until it closes, it breaks a rule, or the server drains.
async fn serve_one(
    tcp: TcpStream,
    app: Router,
    limits: ConnectionLimits,
    mut closing: watch::Receiver<bool>,
    open: &Registry,
) {
    let watch = Arc::new(Activity::new());
    let _registered = Registered(open, open.add(watch.clone()));
    let io = TokioIo::new(Watched {
        inner: tcp,
        watch: watch.clone(),
    });
    let service = {
        let watch = watch.clone();
        hyper::service::service_fn(move |req: Request<Incoming>| {
            watch.request_started();
            let guard = InFlight(watch.clone());
            let app = app.clone();
            async move {
                let res = app.oneshot(req.map(Body::new)).await;
                res.map(|r| {
                    r.map(|body| {
                        Body::new(Guarded {
                            body,
                            _guard: guard,
                        })
                    })
                })
            }
        })
    };
    let mut builder = hyper::server::conn::http1::Builder::new();
    // The watch below enforces the header timeout and the idle timeout; hyper's own
    // header timer would also run while a kept-alive connection is idle.
    builder.timer(TokioTimer::new()).header_read_timeout(None);
    let conn = builder.serve_connection(io, service);
    let mut conn = std::pin::pin!(conn);
    let mut draining = false;
    loop {
        let deadline = watch.deadline(limits);
        tokio::select! {
            result = conn.as_mut() => {
                if let Err(e) = result {
                    tracing::debug!(error = %e, "connection ended with an error");
                }
                return;
            }
            changed = closing.changed(), if !draining => {
                if changed.is_err() || *closing.borrow() {
                    draining = true;
                    conn.as_mut().graceful_shutdown();
                }
            }
            _ = sleep_until(deadline) => {
                if watch.expired(limits) {
                    tracing::debug!("connection closed: header or idle timeout");
                    return;
                }
            }
            _ = watch.changed.notified() => {
                if watch.is_evicted() && watch.eviction_rank().is_some() {
                    tracing::debug!("connection closed to make room for a new one");
                    return;
                }
            }
        }
    }
}

async fn sleep_until(deadline: Option<Instant>) {
    match deadline {
        Some(d) => tokio::time::sleep_until(d).await,
        None => std::future::pending().await,
    }
}

/// What a connection is doing, as the timeouts see it.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Phase {
    /// Accepted, nothing received yet: the header timeout runs.
    New(Instant),
    /// Bytes of a request head arrived: the header timeout runs from the first.
    Head(Instant),
    /// Requests in flight: no timeout of ours.
    Busy(usize),
    /// Kept alive with nothing in flight since then: the idle timeout runs.
    Idle(Instant),
}

/// A connection's phase, updated by its socket and its requests.
struct Activity {
    phase: Mutex<Phase>,
    /// Woken when the phase changes, so the deadline is recomputed, or on eviction.
    changed: Notify,
    /// Asked to close to make room for a new connection.
    evicted: AtomicBool,
}

impl Activity {
    fn new() -> Activity {
        Activity {
            phase: Mutex::new(Phase::New(Instant::now())),
            changed: Notify::new(),
            evicted: AtomicBool::new(false),
        }
    }

    /// Asks the connection to close (it does once no request is in flight).
    fn evict(&self) {
        self.evicted.store(true, Ordering::SeqCst);
        self.changed.notify_one();
    }

    fn is_evicted(&self) -> bool {
        self.evicted.load(Ordering::SeqCst)
    }

    /// The order in which connections without a request in flight make room: first
    /// those that never completed a head (silent or dripping), then idle kept-alive
    /// ones, longest waiting first. None for a connection with a request in flight.
    fn eviction_rank(&self) -> Option<(u8, Instant)> {
        match self.phase() {
            Phase::New(t) | Phase::Head(t) => Some((0, t)),
            Phase::Idle(t) => Some((1, t)),
            Phase::Busy(_) => None,
        }
    }

    fn update(&self, f: impl FnOnce(Phase) -> Phase) {
        let mut p = self.phase.lock().unwrap_or_else(|e| e.into_inner());
        let next = f(*p);
        if next != *p {
            *p = next;
            self.changed.notify_one();
        }
    }

    /// Bytes arrived from the client.
    fn bytes_read(&self) {
        self.update(|p| match p {
            Phase::New(_) | Phase::Idle(_) => Phase::Head(Instant::now()),
            other => other,
        });
    }

    /// hyper parsed a head and called the service.
    fn request_started(&self) {
        self.update(|p| match p {
            Phase::Busy(n) => Phase::Busy(n + 1),
            _ => Phase::Busy(1),
        });
    }

    /// A response body ended or was dropped.
    fn request_ended(&self) {
        self.update(|p| match p {
            Phase::Busy(n) if n > 1 => Phase::Busy(n - 1),
            _ => Phase::Idle(Instant::now()),
        });
    }

    fn phase(&self) -> Phase {
        *self.phase.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// When the current phase's timeout runs out, if it has one.
    fn deadline(&self, limits: ConnectionLimits) -> Option<Instant> {
        match self.phase() {
            Phase::New(t) | Phase::Head(t) => Some(t + limits.header_timeout),
            Phase::Idle(t) => Some(t + limits.idle_timeout),
            Phase::Busy(_) => None,
        }
    }

    fn expired(&self, limits: ConnectionLimits) -> bool {
        self.deadline(limits).is_some_and(|d| d <= Instant::now())
    }
}

/// Marks a request in flight until its response body is dropped.
struct InFlight(Arc<Activity>);

impl Drop for InFlight {
    fn drop(&mut self) {
        self.0.request_ended();
    }
}

/// A response body that keeps its request counted as in flight while it lives.
struct Guarded {
    body: Body,
    _guard: InFlight,
}

impl http_body::Body for Guarded {
    type Data = axum::body::Bytes;
    type Error = axum::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<http_body::Frame<Self::Data>, Self::Error>>> {
        Pin::new(&mut self.body).poll_frame(cx)
    }

    fn is_end_stream(&self) -> bool {
        self.body.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.body.size_hint()
    }
}

/// The socket, telling the connection's [`Activity`] when bytes arrive.
struct Watched {
    inner: TcpStream,
    watch: Arc<Activity>,
}

impl AsyncRead for Watched {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let before = buf.filled().len();
        let polled = Pin::new(&mut self.inner).poll_read(cx, buf);
        if matches!(polled, Poll::Ready(Ok(()))) && buf.filled().len() > before {
            self.watch.bytes_read();
        }
        polled
    }
}

impl AsyncWrite for Watched {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write(cx, buf)
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits() -> ConnectionLimits {
        ConnectionLimits {
            max_connections: 4,
            header_timeout: Duration::from_secs(2),
            idle_timeout: Duration::from_secs(60),
        }
    }

    #[tokio::test(start_paused = true)]
    async fn each_phase_has_its_own_timeout() {
        let a = Activity::new();
        let t0 = Instant::now();
        assert_eq!(a.deadline(limits()), Some(t0 + Duration::from_secs(2)));
        tokio::time::advance(Duration::from_secs(1)).await;
        a.bytes_read();
        assert_eq!(a.deadline(limits()), Some(t0 + Duration::from_secs(3)));
        // More bytes of the same head do not extend it.
        tokio::time::advance(Duration::from_secs(1)).await;
        a.bytes_read();
        assert_eq!(a.deadline(limits()), Some(t0 + Duration::from_secs(3)));
        a.request_started();
        assert_eq!(a.deadline(limits()), None);
        a.request_started();
        a.request_ended();
        assert_eq!(a.deadline(limits()), None, "one request is still in flight");
        a.request_ended();
        assert_eq!(
            a.deadline(limits()),
            Some(Instant::now() + Duration::from_secs(60))
        );
        assert!(!a.expired(limits()));
        tokio::time::advance(Duration::from_secs(61)).await;
        assert!(a.expired(limits()));
    }

    #[tokio::test(start_paused = true)]
    async fn eviction_takes_the_longest_silent_connection_first_and_never_a_busy_one() {
        let open = Registry::default();
        let idle = Arc::new(Activity::new());
        idle.request_started();
        idle.request_ended();
        tokio::time::advance(Duration::from_secs(5)).await;
        let silent = Arc::new(Activity::new());
        let busy = Arc::new(Activity::new());
        busy.request_started();
        for a in [&idle, &silent, &busy] {
            open.add(a.clone());
        }
        // The silent one goes first although the idle one has waited longer.
        assert!(open.evict_one());
        assert!(silent.is_evicted() && !idle.is_evicted());
        assert!(open.evict_one());
        assert!(idle.is_evicted());
        assert!(
            !open.evict_one(),
            "a connection with a request in flight is never evicted"
        );
        assert!(!busy.is_evicted());
    }

    #[test]
    fn the_descriptor_limit_caps_connections_but_never_raises_the_setting() {
        assert_eq!(descriptor_cap(3), 3);
        let limit = rustix::process::getrlimit(rustix::process::Resource::Nofile);
        if let Some(soft) = limit.current {
            let most = usize::try_from(soft.saturating_sub(RESERVED_DESCRIPTORS)).unwrap();
            assert!(descriptor_cap(usize::MAX) <= most.max(1));
        }
    }

    #[test]
    fn the_refusal_is_a_complete_503_problem() {
        let bytes = refusal_bytes(7);
        let text = String::from_utf8(bytes).unwrap();
        let (head, body) = text.split_once("\r\n\r\n").unwrap();
        assert!(head.starts_with("HTTP/1.1 503 "));
        assert!(head.contains("retry-after: 1"));
        assert!(head.contains(&format!("content-length: {}", body.len())));
        let doc: serde_json::Value = serde_json::from_str(body).unwrap();
        assert_eq!(doc["status"], 503);
        assert_eq!(doc["limit"], 7);
        assert!(
            doc["type"]
                .as_str()
                .unwrap()
                .ends_with("/too-many-connections")
        );
    }
}
