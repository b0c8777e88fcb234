//! Every way a request can fail, as one enum, and the one place where each becomes a
//! response: an `application/problem+json` document (RFC 9457) with a stable `type`
//! URI, a `title`, the `status` and a `detail`, plus fields of its own where they help
//! (`problems` with JSON pointers for an invalid scene, `line` and `column` for bad
//! JSON, `limit_bytes` for a body that is too large, `supported` for media types,
//! `reason` for a submission the grader cannot read).
//!
//! 4xx say what was wrong with the request; 5xx are logged here and say nothing of the
//! server's insides.
//!
//! ```json
//! { "type": "https://raytile.example/problems/invalid-scene", "title": "Invalid scene",
//!   "status": 422, "detail": "the scene has 1 problem",
//!   "problems": [ { "pointer": "/image/width", "message": "must be at least 1" } ] }
//! ```

use std::time::Duration;

use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use serde_json::{Map, Value, json};

use crate::grade::GradeError;
use crate::grade::explain::ExplainError;
use crate::scene::{Problem, SceneError};

/// Where the problem types live; `{BASE}{slug}` is each `type`.
pub const PROBLEM_TYPE_BASE: &str = "https://raytile.example/problems/";

/// The media type of every error body.
pub const PROBLEM_JSON: &str = "application/problem+json";

/// How long a refused client should wait before trying again (whole seconds).
pub const RETRY_AFTER_SECONDS: u64 = 1;

/// Why a request failed, decided before the first byte of the answer.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ApiError {
    /// The body (or a part of it) is not JSON (400).
    #[error("{what} is not valid JSON: {message} at line {line}, column {column}")]
    InvalidJson {
        /// What was read: "the body", "the `scene` part".
        what: &'static str,
        /// serde_json's reason.
        message: String,
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
    },
    /// A query parameter or header is malformed (400).
    #[error("{0}")]
    BadRequest(String),
    /// No bearer token, or one that is unknown or revoked (401 + `WWW-Authenticate`).
    #[error("{0}")]
    Unauthorized(String),
    /// A valid token whose role may not do this (403).
    #[error("{0}")]
    Forbidden(String),
    /// No such resource (404).
    #[error("{0}")]
    NotFound(String),
    /// The resource is not at the version the request expects (409).
    #[error("{0}")]
    Conflict(String),
    /// JSON, but not a valid assignment: every problem found (422).
    #[error("the assignment has {} problem(s)", .0.len())]
    InvalidAssignment(Vec<Problem>),
    /// A student made as many submissions to an assignment as the hour allows (429 +
    /// `Retry-After`: when the oldest of them leaves the window).
    #[error(
        "at most {limit} submissions an hour are allowed; the next is possible in {retry_after_seconds} s"
    )]
    TooManySubmissions {
        /// `--submissions-per-hour`.
        limit: u32,
        /// Whole seconds until a submission is allowed again.
        retry_after_seconds: u64,
    },
    /// The path exists but not with this method (405; axum adds `Allow`).
    #[error("this path does not answer that method")]
    MethodNotAllowed,
    /// Nothing we can send matches `Accept` (406).
    #[error("cannot answer with any of the accepted media types `{accept}`")]
    NotAcceptable {
        /// The request's `Accept`.
        accept: String,
        /// What this route can send.
        supported: &'static [&'static str],
    },
    /// The body is larger than the limit (413).
    #[error("the body is larger than the limit of {limit_bytes} bytes")]
    BodyTooLarge {
        /// The limit.
        limit_bytes: usize,
    },
    /// The body is none of the route's media types by its `Content-Type` (415).
    #[error("the body must be {}, not `{got}`", one_of(.supported))]
    UnsupportedMediaType {
        /// The request's `Content-Type` (empty when missing).
        got: String,
        /// What the route reads.
        supported: &'static [&'static str],
    },
    /// JSON, but not a scene we can render: every problem found (422).
    #[error("the scene has {} problem(s)", .0.len())]
    InvalidScene(Vec<Problem>),
    /// The pixel to explain lies outside the image (422).
    #[error("{0}")]
    PixelOutside(ExplainError),
    /// A submission the grader cannot read: empty, corrupt, the wrong size, … (422).
    #[error("{0}")]
    InvalidSubmission(GradeError),
    /// The scene's reference answer could not be computed (422). Not the submission's
    /// fault; it answers 422 rather than 500 because it follows from this scene, and
    /// retrying the same request would fail the same way.
    #[error("the reference answer of this scene could not be computed: {0}")]
    ReferenceFailed(String),
    /// Every render slot is busy and the queue is full (503 + `Retry-After`).
    #[error("every render slot is busy and the queue is full")]
    Saturated,
    /// What the request needs at worst exceeds the whole memory budget, so it can never
    /// be served (`super::memory`): 413 when the body's size alone drives it, 422 with
    /// the fields that do otherwise.
    #[error(
        "{what} needs up to {needed_bytes} bytes of memory, more than the server's whole budget of {budget_bytes} bytes"
    )]
    OverMemory {
        /// What the memory is for: "the body", "parsing the scene".
        what: String,
        /// The worst case of the request.
        needed_bytes: u64,
        /// `--memory-bytes`.
        budget_bytes: u64,
        /// The fields that drive it, with their pointers (empty for the body's size).
        problems: Vec<Problem>,
    },
    /// The memory budget is taken by requests in flight and as many as allowed wait for
    /// it already (503 + `Retry-After`).
    #[error("the memory budget is taken by the requests in flight and the queue is full")]
    MemoryFull,
    /// The server has as many connections open as it allows (503 + `Retry-After`),
    /// answered by the accept loop before the connection is read.
    #[error("the server has {limit} connections open, as many as it allows")]
    TooManyConnections {
        /// `--max-connections`.
        limit: usize,
    },
    /// The database is busy: no connection came free in time, or SQLite's writer lock
    /// did not (503 + `Retry-After`).
    #[error("the database is busy")]
    DatabaseBusy,
    /// The server is shutting down and takes no new work (503 + `Retry-After`).
    #[error("the server is shutting down")]
    ShuttingDown,
    /// The request reached its deadline before the answer could start (504).
    #[error("the request took longer than the deadline of {0:?}")]
    DeadlineExceeded(Duration),
    /// A fault of ours (500): logged, not explained.
    #[error("internal error: {0}")]
    Internal(String),
}

impl From<SceneError> for ApiError {
    fn from(e: SceneError) -> Self {
        ApiError::scene(e, "the body", "")
    }
}

impl ApiError {
    /// A scene error of `what` (the part of the request that held the scene), with every
    /// pointer put under `prefix` so that it points into the body that was sent.
    pub fn scene(e: SceneError, what: &'static str, prefix: &str) -> ApiError {
        match e {
            SceneError::Syntax {
                message,
                line,
                column,
            } => ApiError::InvalidJson {
                what,
                message,
                line,
                column,
            },
            SceneError::Invalid(problems) if prefix.is_empty() => ApiError::InvalidScene(problems),
            SceneError::Invalid(problems) => ApiError::InvalidScene(
                problems
                    .into_iter()
                    .map(|p| Problem::new(format!("{prefix}{}", p.pointer), p.message))
                    .collect(),
            ),
        }
    }
}

impl ApiError {
    /// A grading failure as the client should see it: the submission's faults are 422
    /// (`invalid-submission`, with a `reason`), tolerances out of range are 400 like any
    /// bad parameter, a reference that could not be computed is 422 (`reference-failed`).
    /// [`GradeError::Cancelled`] means the reference render was stopped, which only the
    /// request's `deadline` does (the end of the shutdown grace period is answered by
    /// whoever stops the job, before any result is read): 504.
    pub fn grading(e: GradeError, deadline: Duration) -> ApiError {
        match e {
            GradeError::Cancelled => ApiError::DeadlineExceeded(deadline),
            GradeError::Reference(why) => ApiError::ReferenceFailed(why),
            GradeError::BadTolerance { .. } | GradeError::BadScoring { .. } => {
                ApiError::BadRequest(e.to_string())
            }
            other => ApiError::InvalidSubmission(other),
        }
    }
}

/// `` `a` `` or `` `a` or `b` ``: the media types a route reads.
fn one_of(types: &[&str]) -> String {
    let quoted: Vec<String> = types.iter().map(|t| format!("`{t}`")).collect();
    quoted.join(" or ")
}

/// A stable, machine-readable name for why a submission cannot be graded (the
/// `reason` member of an invalid-submission problem).
fn submission_reason(e: &GradeError) -> &'static str {
    match e {
        GradeError::Empty => "empty",
        GradeError::UnknownFormat => "unknown-format",
        GradeError::NotPng => "not-png",
        GradeError::SizeMismatch { .. } => "size-mismatch",
        GradeError::Unreadable(r) => r.reason(),
        GradeError::OutsideImage { .. } => "pixel-outside-image",
        GradeError::DuplicatePixel { .. } => "duplicate-pixel",
        GradeError::MissingPixels { .. } => "missing-pixels",
        GradeError::BadTolerance { .. } => "bad-tolerance",
        GradeError::BadScoring { .. } => "bad-scoring",
        GradeError::Cancelled => "cancelled",
        GradeError::Reference(_) => "reference",
    }
}

impl ApiError {
    /// The HTTP status.
    pub fn status(&self) -> StatusCode {
        match self {
            ApiError::InvalidJson { .. } | ApiError::BadRequest(_) => StatusCode::BAD_REQUEST,
            ApiError::Unauthorized(_) => StatusCode::UNAUTHORIZED,
            ApiError::Forbidden(_) => StatusCode::FORBIDDEN,
            ApiError::NotFound(_) => StatusCode::NOT_FOUND,
            ApiError::Conflict(_) => StatusCode::CONFLICT,
            ApiError::InvalidAssignment(_) => StatusCode::UNPROCESSABLE_ENTITY,
            ApiError::TooManySubmissions { .. } => StatusCode::TOO_MANY_REQUESTS,
            ApiError::MethodNotAllowed => StatusCode::METHOD_NOT_ALLOWED,
            ApiError::NotAcceptable { .. } => StatusCode::NOT_ACCEPTABLE,
            ApiError::BodyTooLarge { .. } => StatusCode::PAYLOAD_TOO_LARGE,
            ApiError::OverMemory { problems, .. } if problems.is_empty() => {
                StatusCode::PAYLOAD_TOO_LARGE
            }
            ApiError::OverMemory { .. } => StatusCode::UNPROCESSABLE_ENTITY,
            ApiError::UnsupportedMediaType { .. } => StatusCode::UNSUPPORTED_MEDIA_TYPE,
            ApiError::InvalidScene(_)
            | ApiError::PixelOutside(_)
            | ApiError::InvalidSubmission(_)
            | ApiError::ReferenceFailed(_) => StatusCode::UNPROCESSABLE_ENTITY,
            ApiError::Saturated
            | ApiError::MemoryFull
            | ApiError::TooManyConnections { .. }
            | ApiError::DatabaseBusy
            | ApiError::ShuttingDown => StatusCode::SERVICE_UNAVAILABLE,
            ApiError::DeadlineExceeded(_) => StatusCode::GATEWAY_TIMEOUT,
            ApiError::Internal(_) => StatusCode::INTERNAL_SERVER_ERROR,
        }
    }

    /// The last segment of the problem `type` URI, and the `title`.
    pub fn kind(&self) -> (&'static str, &'static str) {
        match self {
            ApiError::InvalidJson { .. } => ("invalid-json", "Invalid JSON"),
            ApiError::BadRequest(_) => ("bad-request", "Bad request"),
            ApiError::Unauthorized(_) => ("unauthorized", "Unauthorized"),
            ApiError::Forbidden(_) => ("forbidden", "Forbidden"),
            ApiError::NotFound(_) => ("not-found", "Not found"),
            ApiError::Conflict(_) => ("conflict", "Conflicting version"),
            ApiError::InvalidAssignment(_) => ("invalid-assignment", "Invalid assignment"),
            ApiError::TooManySubmissions { .. } => ("too-many-submissions", "Too many submissions"),
            ApiError::MethodNotAllowed => ("method-not-allowed", "Method not allowed"),
            ApiError::NotAcceptable { .. } => ("not-acceptable", "Not acceptable"),
            ApiError::BodyTooLarge { .. } => ("body-too-large", "Body too large"),
            ApiError::UnsupportedMediaType { .. } => {
                ("unsupported-media-type", "Unsupported media type")
            }
            ApiError::InvalidScene(_) => ("invalid-scene", "Invalid scene"),
            ApiError::PixelOutside(_) => ("pixel-outside-image", "Pixel outside the image"),
            ApiError::InvalidSubmission(_) => ("invalid-submission", "Invalid submission"),
            ApiError::ReferenceFailed(_) => ("reference-failed", "Reference not computed"),
            ApiError::Saturated => ("saturated", "Server saturated"),
            ApiError::OverMemory { .. } => ("over-memory", "Too large for the memory budget"),
            ApiError::MemoryFull => ("memory-full", "Memory budget taken"),
            ApiError::TooManyConnections { .. } => ("too-many-connections", "Too many connections"),
            ApiError::DatabaseBusy => ("database-busy", "Database busy"),
            ApiError::ShuttingDown => ("shutting-down", "Server shutting down"),
            ApiError::DeadlineExceeded(_) => ("deadline-exceeded", "Deadline exceeded"),
            ApiError::Internal(_) => ("internal", "Internal server error"),
        }
    }

    /// The problem document.
    pub fn problem(&self) -> ProblemDoc {
        let (slug, title) = self.kind();
        let status = self.status();
        let detail = match self {
            // Say nothing of our insides: the log has the details.
            ApiError::Internal(_) => {
                "the server failed; the request id locates it in the log".to_string()
            }
            other => other.to_string(),
        };
        let extra = match self {
            ApiError::InvalidJson { line, column, .. } => {
                json!({ "line": line, "column": column })
            }
            ApiError::NotAcceptable { supported, .. } => json!({ "supported": supported }),
            ApiError::UnsupportedMediaType { supported, .. } => json!({ "supported": supported }),
            ApiError::BodyTooLarge { limit_bytes } => json!({ "limit_bytes": limit_bytes }),
            ApiError::InvalidScene(problems) | ApiError::InvalidAssignment(problems) => {
                json!({ "problems": problems })
            }
            ApiError::TooManySubmissions {
                limit,
                retry_after_seconds,
            } => json!({ "limit": limit, "retry_after_seconds": retry_after_seconds }),
            ApiError::PixelOutside(ExplainError::OutsideImage {
                u,
                v,
                width,
                height,
            }) => json!({ "u": u, "v": v, "width": width, "height": height }),
            ApiError::InvalidSubmission(e) => json!({ "reason": submission_reason(e) }),
            ApiError::OverMemory {
                needed_bytes,
                budget_bytes,
                problems,
                ..
            } => {
                let mut m = json!({ "needed_bytes": needed_bytes, "budget_bytes": budget_bytes });
                if !problems.is_empty() {
                    m["problems"] = json!(problems);
                }
                m
            }
            ApiError::Saturated
            | ApiError::MemoryFull
            | ApiError::DatabaseBusy
            | ApiError::ShuttingDown => {
                json!({ "retry_after_seconds": RETRY_AFTER_SECONDS })
            }
            ApiError::TooManyConnections { limit } => {
                json!({ "retry_after_seconds": RETRY_AFTER_SECONDS, "limit": limit })
            }
            ApiError::DeadlineExceeded(d) => json!({ "deadline_seconds": d.as_secs_f64() }),
            _ => json!({}),
        };
        ProblemDoc {
            kind: format!("{PROBLEM_TYPE_BASE}{slug}"),
            title,
            status: status.as_u16(),
            detail,
            extra: match extra {
                Value::Object(m) => m,
                _ => Map::new(),
            },
        }
    }
}

/// An RFC 9457 problem document, members in the RFC's order, then our own.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ProblemDoc {
    /// A URI naming the kind of problem.
    #[serde(rename = "type")]
    pub kind: String,
    /// A short summary of the kind.
    pub title: &'static str,
    /// The HTTP status.
    pub status: u16,
    /// What happened this time.
    pub detail: String,
    /// Members of our own (`problems`, `line`, `column`, …).
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let status = self.status();
        let refused = matches!(
            self,
            ApiError::Saturated
                | ApiError::MemoryFull
                | ApiError::TooManyConnections { .. }
                | ApiError::DatabaseBusy
                | ApiError::ShuttingDown
        );
        if status.is_server_error() && !refused {
            tracing::error!(error = %self, status = status.as_u16(), "request failed");
        }
        if let ApiError::ReferenceFailed(why) = &self {
            // Answered as the scene's problem, but a renderer that cannot finish a
            // validated scene is a fault of ours too: make it visible in the log.
            tracing::error!(error = %why, "the reference could not be computed");
        }
        let body = serde_json::to_vec(&self.problem()).unwrap_or_default();
        let mut res = (status, body).into_response();
        let h = res.headers_mut();
        h.insert(header::CONTENT_TYPE, HeaderValue::from_static(PROBLEM_JSON));
        if matches!(self, ApiError::Unauthorized(_)) {
            h.insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
        }
        if refused {
            h.insert(header::RETRY_AFTER, HeaderValue::from(RETRY_AFTER_SECONDS));
        }
        if let ApiError::TooManySubmissions {
            retry_after_seconds,
            ..
        } = &self
        {
            h.insert(header::RETRY_AFTER, HeaderValue::from(*retry_after_seconds));
        }
        if matches!(
            self,
            ApiError::BodyTooLarge { .. }
                | ApiError::OverMemory { .. }
                | ApiError::DeadlineExceeded(_)
                | ApiError::ShuttingDown
                | ApiError::Internal(_)
        ) {
            // The body may be unread, or the server is leaving: don't reuse the connection.
            h.insert(header::CONNECTION, HeaderValue::from_static("close"));
        }
        res
    }
}

/// The answer for a panic caught by the outermost layer: a plain 500 problem.
pub fn panic_response(panic: Box<dyn std::any::Any + Send + 'static>) -> Response {
    let what = panic
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic".into());
    ApiError::Internal(format!("handler panicked: {what}")).into_response()
}

/// The fallback of unknown paths: 404.
pub async fn not_found(uri: axum::http::Uri) -> ApiError {
    ApiError::NotFound(format!("there is nothing at `{}`", uri.path()))
}

/// The fallback of known paths with an unknown method: 405.
pub async fn method_not_allowed() -> ApiError {
    ApiError::MethodNotAllowed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_problem_has_the_rfc9457_members() {
        let all = [
            ApiError::InvalidJson {
                what: "the body",
                message: "x".into(),
                line: 1,
                column: 2,
            },
            ApiError::BadRequest("x".into()),
            ApiError::Unauthorized("x".into()),
            ApiError::Forbidden("x".into()),
            ApiError::NotFound("x".into()),
            ApiError::Conflict("x".into()),
            ApiError::InvalidAssignment(vec![Problem::new("/scenes", "x")]),
            ApiError::TooManySubmissions {
                limit: 1,
                retry_after_seconds: 5,
            },
            ApiError::MethodNotAllowed,
            ApiError::NotAcceptable {
                accept: "text/html".into(),
                supported: &["application/json"],
            },
            ApiError::BodyTooLarge { limit_bytes: 1 },
            ApiError::UnsupportedMediaType {
                got: "x".into(),
                supported: &["application/json"],
            },
            ApiError::InvalidScene(vec![Problem::new("/image", "x")]),
            ApiError::PixelOutside(ExplainError::OutsideImage {
                u: 5,
                v: 0,
                width: 5,
                height: 5,
            }),
            ApiError::InvalidSubmission(GradeError::Empty),
            ApiError::ReferenceFailed("x".into()),
            ApiError::Saturated,
            ApiError::OverMemory {
                what: "the body".into(),
                needed_bytes: 2,
                budget_bytes: 1,
                problems: Vec::new(),
            },
            ApiError::MemoryFull,
            ApiError::DatabaseBusy,
            ApiError::ShuttingDown,
            ApiError::DeadlineExceeded(Duration::from_secs(1)),
            ApiError::Internal("secret".into()),
        ];
        for e in all {
            let p = serde_json::to_value(e.problem()).unwrap();
            assert!(p["type"].as_str().unwrap().starts_with(PROBLEM_TYPE_BASE));
            assert!(p["title"].is_string());
            assert_eq!(p["status"], e.status().as_u16());
            assert!(!p["detail"].as_str().unwrap().contains("secret"));
        }
    }
}
