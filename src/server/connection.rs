//! Connections: the accept loop and what each connection may hold.
//!
//! `axum::serve` has no header-read timeout, no idle timeout and no connection cap, so a
//! few hundred sockets that send nothing (or one byte a minute) would hold file
//! descriptors for ever and lock everyone else out. Here every connection is served by
//! hyper's HTTP/1 server under three rules, each a setting of `raytile serve`:
//!
//! - **`--max-connections`**: connections open at once. Past it a new connection is
//!   answered at once with a 503 problem document (`too-many-connections`,
//!   `Retry-After`) and closed, without reading it, so a proxy retries elsewhere.
//! - **`--header-timeout-seconds`**: once a request's first byte has arrived, its head
//!   (request line and headers) must be complete within this; a new connection must
//!   send its first byte within it too. A client that drips its headers is cut.
//! - **`--idle-timeout-seconds`**: a kept-alive connection with no request in flight is
//!   closed after this. Kept longer than a proxy's upstream keep-alive (nginx: 60 s)
//!   so that the proxy, not us, closes idle connections, and never reuses one we closed.
//!
//! A request in flight (its body being read, or its response streaming) is never cut
//! by these: the request deadline and the stall rule of [`super::stream`] govern it.

use std::future::Future;
use std::io;
use std::pin::Pin;
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
    let slots = Arc::new(Semaphore::new(limits.max_connections));
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
        let Ok(permit) = slots.clone().try_acquire_owned() else {
            tracing::warn!(%peer, limit = limits.max_connections, "too many connections: refused");
            refuse(tcp, limits.max_connections);
            continue;
        };
        let app = app.clone();
        let closing = closing_rx.clone();
        tokio::spawn(async move {
            serve_one(tcp, app, limits, closing).await;
            drop(permit);
        });
    }
    drop(listener);
    let _ = closing_tx.send(true);
    // Every permit back means every connection has closed.
    let _ = slots.acquire_many(limits.max_connections as u32).await;
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
) {
    let watch = Arc::new(Activity::new());
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
            _ = watch.changed.notified() => {}
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
    /// Woken when the phase changes, so the deadline is recomputed.
    changed: Notify,
}

impl Activity {
    fn new() -> Activity {
        Activity {
            phase: Mutex::new(Phase::New(Instant::now())),
            changed: Notify::new(),
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
