//! The instructor's read side of an assignment: its submissions
//! (`GET /v1/assignments/{id}/submissions[?student=S]`), the gradebook an LMS imports
//! (`GET /v1/assignments/{id}/grades.csv[?pick=latest|best]`) and the statistics per
//! scene (`GET /v1/assignments/{id}/stats[?pick=latest|best]`). Instructors only (401
//! without a valid token, 403 for a grader), 404 for an assignment that does not
//! exist (or was deleted). What is computed is [`crate::assignment::gradebook`]'s;
//! here are the queries, the token checks and the answers, with every stored result
//! read off tokio's threads.

use axum::Router;
use axum::extract::{Path, Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use serde_json::json;

use super::AppState;
use super::assignments::{check_id, not_found, store_error};
use super::error::ApiError;
use super::extract::{blocking, deadline_of, negotiate, once, parse_choice, query_pairs};
use crate::assignment::gradebook::{
    self, Attempt, Choice, GradeRow, Pick, Scored, grades_csv, max_score_of,
};
use crate::assignment::{self, format_rfc3339_ms};
use crate::store::Store;
use crate::store::assignments::{StoredAssignment, Submission};

/// The routes.
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/v1/assignments/{id}/submissions", get(submissions))
        .route(
            "/v1/assignments/{id}/submissions/{sid}",
            get(one_submission),
        )
        .route("/v1/assignments/{id}/grades.csv", get(grades))
        .route("/v1/assignments/{id}/stats", get(stats))
}

/// The store, once the request's token is an instructor's and assignment `id` exists;
/// with the assignment's live revision.
async fn instructor_at(
    app: &AppState,
    headers: &HeaderMap,
    id: &str,
) -> Result<(Store, StoredAssignment), ApiError> {
    check_id(id)?;
    let auth = app.course.auth(app).await?;
    let who = auth.instructor(headers).await?;
    tracing::debug!(token_id = %who.id, assignment = %id, "gradebook read");
    let store = auth.store().clone();
    let stored = store
        .assignment(id)
        .await
        .map_err(store_error)?
        .ok_or_else(|| not_found(id))?;
    Ok((store, stored))
}

/// The value of the query's one parameter `name` (absent: `None`); any other is 400.
fn only_param(req: &Request, name: &str) -> Result<Option<String>, ApiError> {
    let mut value = None;
    for (k, v) in query_pairs(req.uri())? {
        if k != name {
            return Err(ApiError::BadRequest(format!(
                "unknown query parameter `{k}`: this route takes `{name}`"
            )));
        }
        once(&mut value, name, v)?;
    }
    Ok(value)
}

/// `?pick=latest|best`, the query's only parameter (absent: `None`).
fn pick_param(req: &Request) -> Result<Option<Pick>, ApiError> {
    only_param(req, "pick")?
        .map(|v| {
            parse_choice(
                "pick",
                &v,
                &[("latest", Pick::Latest), ("best", Pick::Best)],
            )
        })
        .transpose()
}

fn scored(s: &Submission) -> Scored {
    Scored {
        id: s.id.clone(),
        student: s.student.clone(),
        submitted_ms: s.submitted_ms,
        score: s.score,
    }
}

/// Reads every stored result (off tokio's threads: the caller runs this in `blocking`).
fn read_all(id: &str, subs: Vec<Submission>) -> Result<Vec<Attempt>, ApiError> {
    subs.into_iter()
        .map(|s| {
            Attempt::read(scored(&s), s.revision, &s.result).map_err(|e| {
                ApiError::Internal(format!(
                    "the stored result of submission {} to `{id}` cannot be read: {e}",
                    s.id
                ))
            })
        })
        .collect()
}

fn json_response(body: Vec<u8>) -> Response {
    (
        StatusCode::OK,
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/json"),
        )],
        body,
    )
        .into_response()
}

/// `GET /v1/assignments/{id}/submissions/{sid}`: one submission, as the listing shows
/// it (where a recorded submission's `Location` points).
async fn one_submission(
    State(app): State<AppState>,
    Path((id, sid)): Path<(String, String)>,
    req: Request,
) -> Result<Response, ApiError> {
    if let Some((k, _)) = query_pairs(req.uri())?.into_iter().next() {
        return Err(ApiError::BadRequest(format!(
            "unknown query parameter `{k}`: this route takes none"
        )));
    }
    negotiate(req.headers(), &["application/json"])?;
    let deadline = deadline_of(&req, &app);
    let (store, _) = instructor_at(&app, req.headers(), &id).await?;
    let sub = store
        .submission(&id, &sid)
        .await
        .map_err(store_error)?
        .ok_or_else(|| {
            ApiError::NotFound(format!("assignment `{id}` has no submission `{sid}`"))
        })?;
    let body = blocking(&app, deadline, move || {
        let attempts = read_all(&id, vec![sub])?;
        let view = attempts.first().map(Attempt::view);
        serde_json::to_vec(&view)
            .map_err(|e| ApiError::Internal(format!("cannot write the submission: {e}")))
    })
    .await??;
    Ok(json_response(body))
}

/// `GET /v1/assignments/{id}/submissions[?student=S]`: every submission, oldest first,
/// each with its per-scene outcome and the stored result whole.
async fn submissions(
    State(app): State<AppState>,
    Path(id): Path<String>,
    req: Request,
) -> Result<Response, ApiError> {
    let student = only_param(&req, "student")?;
    negotiate(req.headers(), &["application/json"])?;
    let deadline = deadline_of(&req, &app);
    let (store, _) = instructor_at(&app, req.headers(), &id).await?;
    let subs = store
        .submissions(&id, student.as_deref())
        .await
        .map_err(store_error)?;
    let body = blocking(&app, deadline, move || {
        let attempts = read_all(&id, subs)?;
        let views: Vec<_> = attempts.iter().map(Attempt::view).collect();
        serde_json::to_vec(&json!({ "submissions": views }))
            .map_err(|e| ApiError::Internal(format!("cannot write the listing: {e}")))
    })
    .await??;
    Ok(json_response(body))
}

/// `GET /v1/assignments/{id}/grades.csv[?pick=latest|best]`: one row per student,
/// sorted by student. Only the chosen submissions' results are read (for their
/// `max_score`); the rest of the table gives its scores alone.
async fn grades(
    State(app): State<AppState>,
    Path(id): Path<String>,
    req: Request,
) -> Result<Response, ApiError> {
    let pick = pick_param(&req)?.unwrap_or_default();
    negotiate(req.headers(), &["text/csv"])?;
    let deadline = deadline_of(&req, &app);
    let (store, _) = instructor_at(&app, req.headers(), &id).await?;
    let scores: Vec<Scored> = store
        .scores(&id)
        .await
        .map_err(store_error)?
        .into_iter()
        .map(|s| Scored {
            id: s.id,
            student: s.student,
            submitted_ms: s.submitted_ms,
            score: s.score,
        })
        .collect();
    let chosen: Vec<Choice> = gradebook::pick(&scores, pick, |s| s);
    let ids: Vec<&str> = chosen.iter().map(|c| scores[c.index].id.as_str()).collect();
    let results = store.results(&id, &ids).await.map_err(store_error)?;
    let csv = blocking(&app, deadline, move || {
        let max_scores: std::collections::HashMap<String, f64> = results
            .into_iter()
            .map(|(sid, text)| {
                let max = max_score_of(&text).map_err(|e| {
                    ApiError::Internal(format!(
                        "the stored result of submission {sid} to `{id}` cannot be read: {e}"
                    ))
                })?;
                Ok((sid, max))
            })
            .collect::<Result<_, ApiError>>()?;
        let rows: Vec<GradeRow> = chosen
            .iter()
            .map(|c| {
                let s = &scores[c.index];
                // Submissions are never deleted, so each chosen one has its result.
                let max_score = max_scores.get(&s.id).copied().ok_or_else(|| {
                    ApiError::Internal(format!("submission {} to `{id}` has no result", s.id))
                })?;
                Ok(GradeRow {
                    student: s.student.clone(),
                    score: s.score,
                    max_score,
                    submitted_ms: s.submitted_ms,
                    submissions: c.submissions,
                })
            })
            .collect::<Result<_, ApiError>>()?;
        grades_csv(&rows).map_err(|e| ApiError::Internal(format!("cannot write the CSV: {e}")))
    })
    .await??;
    Ok((
        StatusCode::OK,
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("text/csv; charset=utf-8"),
        )],
        csv,
    )
        .into_response())
}

/// `GET /v1/assignments/{id}/stats[?pick=latest|best]`: per scene, over every
/// submission (or only the one per student that `pick` chooses).
async fn stats(
    State(app): State<AppState>,
    Path(id): Path<String>,
    req: Request,
) -> Result<Response, ApiError> {
    let pick = pick_param(&req)?;
    negotiate(req.headers(), &["application/json"])?;
    let deadline = deadline_of(&req, &app);
    let (store, stored) = instructor_at(&app, req.headers(), &id).await?;
    let subs = store.submissions(&id, None).await.map_err(store_error)?;
    let limits = app.config.limits();
    let body = blocking(&app, deadline, move || {
        let doc = assignment::parse(stored.document.as_bytes(), &limits).map_err(|e| {
            ApiError::Internal(format!("the stored assignment `{id}` cannot be read: {e}"))
        })?;
        let scenes: Vec<(String, f64)> = doc
            .scenes
            .iter()
            .map(|s| (s.name.clone(), s.points))
            .collect();
        let attempts = read_all(&id, subs)?;
        let counted: Vec<&Attempt> = match pick {
            None => attempts.iter().collect(),
            Some(how) => gradebook::pick(&attempts, how, |a| &a.scored)
                .iter()
                .map(|c| &attempts[c.index])
                .collect(),
        };
        let last = counted.iter().map(|a| a.scored.submitted_ms).max();
        let stats = gradebook::stats(&scenes, counted);
        serde_json::to_vec(&json!({
            "assignment": id,
            "revision": stored.revision,
            "pick": pick.map_or("all", Pick::as_str),
            "last_submitted": last.map(format_rfc3339_ms),
            "submissions": stats.submissions,
            "students": stats.students,
            "mean_score": stats.mean_score,
            "scenes": stats.scenes,
        }))
        .map_err(|e| ApiError::Internal(format!("cannot write the statistics: {e}")))
    })
    .await??;
    Ok(json_response(body))
}
