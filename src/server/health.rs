//! `GET /healthz` and `GET /readyz`.
//!
//! Liveness says only that the process answers: a replica busy rendering is alive and
//! must not be restarted. Readiness says whether to send it more work: 503 while it
//! drains after SIGTERM, and while it is saturated (every slot busy and the queue full),
//! so that a load balancer routes around it until a slot frees.

use axum::Json;
use axum::Router;
use axum::extract::State;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use serde_json::json;

use super::AppState;
use super::error::ApiError;

/// The routes: `GET /healthz`, `GET /readyz`.
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/healthz", get(healthz))
        .route("/readyz", get(readyz))
}

async fn healthz() -> Json<serde_json::Value> {
    Json(json!({ "status": "ok" }))
}

async fn readyz(State(app): State<AppState>) -> Response {
    if app.shutdown.is_draining() {
        return ApiError::ShuttingDown.into_response();
    }
    if app.admission.is_saturated() {
        return ApiError::Saturated.into_response();
    }
    Json(json!({
        "status": "ready",
        "renders_waiting": app.admission.waiting(),
    }))
    .into_response()
}
