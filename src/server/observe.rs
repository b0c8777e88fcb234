//! What the server says about each request: its id, its log line and its count.
//!
//! - **Request id**: the client's `X-Request-Id` when it sends a sensible one (a load
//!   balancer's, so one id follows the request through), otherwise a fresh one; it is
//!   returned as `X-Request-Id` and carried by every log line of the request (a span).
//! - **One log line per request**, written when the response body ends rather than when
//!   the head leaves: only then are the size, the duration and whether the stream
//!   completed known. Fields: `request_id`, `method`, `route`, `path`, `status`,
//!   `bytes`, `duration_ms`, `complete`.
//! - **`raytile_http_requests_total{route, method, status}`**, counted when the head
//!   leaves. `route` is the route's template (`/v1/scenes/{name}`), or `unmatched`, and
//!   `method` one of the methods HTTP defines, or `other`, so that a scan of random paths
//!   or invented methods cannot blow up the label set.

use std::hash::BuildHasher;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::task::{Context, Poll};
use std::time::Instant;

use axum::body::{Body, Bytes};
use axum::extract::{MatchedPath, Request, State};
use axum::http::{HeaderMap, HeaderName, HeaderValue, Method, StatusCode};
use axum::middleware::Next;
use axum::response::Response;
use http_body::{Body as _, Frame, SizeHint};
use tracing::Instrument;

use super::AppState;
use super::extract::RequestInfo;

/// The request id header.
pub const X_REQUEST_ID: HeaderName = HeaderName::from_static("x-request-id");

/// Longest incoming request id we keep; a longer one is replaced.
const MAX_REQUEST_ID_CHARS: usize = 128;

/// The middleware: id, span, count, and the log line at the end of the body.
pub async fn observe(State(app): State<AppState>, mut req: Request, next: Next) -> Response {
    let start = Instant::now();
    let id = incoming_id(req.headers()).unwrap_or_else(new_id);
    let method = req.method().clone();
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map_or_else(|| "unmatched".to_owned(), |p| p.as_str().to_owned());
    let path = req.uri().path().to_owned();
    req.extensions_mut().insert(RequestInfo {
        id: id.clone(),
        start,
    });
    let span = tracing::info_span!("request", request_id = %id);
    let mut res = next.run(req).instrument(span).await;
    let status = res.status();
    app.metrics
        .requests
        .with_label_values(&[route.as_str(), method_label(&method), status.as_str()])
        .inc();
    if let Ok(v) = HeaderValue::from_str(&id) {
        res.headers_mut().insert(X_REQUEST_ID, v);
    }
    res.map(|inner| {
        Body::new(Logged {
            inner,
            line: Some(LogLine {
                id,
                method,
                route,
                path,
                status,
                start,
            }),
            bytes: 0,
            ended: false,
        })
    })
}

/// The `method` label: one of the methods HTTP defines, `other` for any other, since a
/// client may send any token as a method and each label value is a series kept for ever.
fn method_label(method: &Method) -> &'static str {
    [
        Method::GET,
        Method::HEAD,
        Method::POST,
        Method::PUT,
        Method::DELETE,
        Method::CONNECT,
        Method::OPTIONS,
        Method::TRACE,
        Method::PATCH,
    ]
    .iter()
    .find(|m| *m == method)
    .map_or("other", |m| m.as_str())
}

/// The client's id, if it is 1 to 128 visible ASCII characters.
fn incoming_id(headers: &HeaderMap) -> Option<String> {
    let v = headers.get(X_REQUEST_ID)?.to_str().ok()?;
    let ok =
        !v.is_empty() && v.len() <= MAX_REQUEST_ID_CHARS && v.bytes().all(|b| b.is_ascii_graphic());
    ok.then(|| v.to_owned())
}

/// A fresh id: 32 hex digits, unique within the process and unlikely to repeat across
/// replicas (std's randomly keyed hasher over a counter and the clock).
fn new_id() -> String {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let keys = std::collections::hash_map::RandomState::new();
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    format!(
        "{:016x}{:016x}",
        keys.hash_one(n),
        keys.hash_one((nanos, n))
    )
}

struct LogLine {
    id: String,
    method: Method,
    route: String,
    path: String,
    status: StatusCode,
    start: Instant,
}

/// A response body that counts its bytes and logs the request's line once it ends, is
/// cut, or is dropped (the client left).
struct Logged {
    inner: Body,
    line: Option<LogLine>,
    bytes: u64,
    ended: bool,
}

impl Logged {
    fn log(&mut self, error: Option<&str>) {
        let Some(l) = self.line.take() else {
            return;
        };
        let complete = error.is_none() && (self.ended || self.inner.is_end_stream());
        let duration_ms = l.start.elapsed().as_secs_f64() * 1e3;
        tracing::info!(
            request_id = %l.id,
            method = %l.method,
            route = %l.route,
            path = %l.path,
            status = l.status.as_u16(),
            bytes = self.bytes,
            duration_ms = (duration_ms * 1000.0).round() / 1000.0,
            complete,
            error,
            "request"
        );
    }
}

impl http_body::Body for Logged {
    type Data = Bytes;
    type Error = axum::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, axum::Error>>> {
        let polled = Pin::new(&mut self.inner).poll_frame(cx);
        match &polled {
            Poll::Ready(Some(Ok(frame))) => {
                if let Some(data) = frame.data_ref() {
                    self.bytes += data.len() as u64;
                }
            }
            Poll::Ready(Some(Err(e))) => {
                let e = e.to_string();
                self.log(Some(&e));
            }
            Poll::Ready(None) => {
                self.ended = true;
                self.log(None);
            }
            Poll::Pending => {}
        }
        polled
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> SizeHint {
        self.inner.size_hint()
    }
}

impl Drop for Logged {
    fn drop(&mut self) {
        if self.line.is_some() {
            let gone = !(self.ended || self.inner.is_end_stream());
            self.log(gone.then_some("the client went away before the end"));
        }
    }
}

/// Installs the global log subscriber: `RUST_LOG` filters (default `info`), `json`
/// writes one JSON object per line.
pub fn init_logging(json: bool) {
    use tracing_subscriber::EnvFilter;
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info"));
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stdout());
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(ansi);
    // A second call (tests) finds a subscriber installed and keeps it.
    let _ = if json {
        builder.json().flatten_event(true).try_init()
    } else {
        builder.try_init()
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_are_kept_when_sensible_and_made_otherwise() {
        let mut h = HeaderMap::new();
        assert_eq!(incoming_id(&h), None);
        h.insert(X_REQUEST_ID, HeaderValue::from_static("abc-123"));
        assert_eq!(incoming_id(&h).as_deref(), Some("abc-123"));
        h.insert(X_REQUEST_ID, HeaderValue::from_static("has space"));
        assert_eq!(incoming_id(&h), None);
        let (a, b) = (new_id(), new_id());
        assert_eq!(a.len(), 32);
        assert_ne!(a, b);
    }

    #[test]
    fn method_labels_are_the_known_methods_or_other() {
        assert_eq!(method_label(&Method::GET), "GET");
        assert_eq!(method_label(&Method::PATCH), "PATCH");
        for invented in ["BREW", "get", "X-1", "PROPFIND"] {
            let m = Method::from_bytes(invented.as_bytes()).expect("a method token");
            assert_eq!(method_label(&m), "other", "{invented}");
        }
    }
}
