//! The assignment routes (`docs/assignments.md`, over HTTP): an instructor pushes,
//! lists, reads and deletes assignments; a grader scoped to one fetches its scene
//! documents and submits a student's files, graded by
//! [`crate::assignment::grade::grade_submission`] into one combined report
//! ([`crate::assignment::report`]).
//!
//! | route | who | answer |
//! | --- | --- | --- |
//! | `PUT /v1/assignments/{id}` | instructor | 201 or 200 `{"id", "revision"}`, `ETag` |
//! | `GET /v1/assignments` | both | `{"assignments": [{"id", "title", "revision", "due"?, "scenes"}]}` |
//! | `GET /v1/assignments/{id}` | both | the document (instructor) or its scenes (grader), `ETag` |
//! | `DELETE /v1/assignments/{id}` | instructor | 204; its grader tokens are revoked |
//! | `POST /v1/assignments/{id}/submissions` | both | 201 (recorded) or 200 (a replay), `Location` |
//!
//! Every route needs a bearer token, with or without `--require-token` (that setting
//! closes the routes that take a posted scene). The database (`--data-dir`,
//! `--database`) is opened on the first request that needs it, so a server that
//! never sees one makes no data folder.
//!
//! A grader sees of an assignment what its student's tracer needs and nothing more:
//! the title, the due date, and each scene's name, points, what is graded and its
//! scene document (no tolerances, no visibility settings).
//!
//! A submission is `multipart/form-data`: a `student` field and a file part per scene,
//! named by the scene (its file name gives the form, as for `/v1/grade`). It is graded
//! as `/v1/grade` grades: the body charged to the memory budget before it is read, the
//! assignment document parsed off tokio's threads and charged first, what grading every
//! file takes charged before the work is admitted, the grading on the rayon pool under
//! admission (503 with `Retry-After`), the deadline (504) and the ray budget. The result
//! is committed to the store before the answer is sent. With an `Idempotency-Key`, a
//! retry finds the stored result and answers it (200) without grading or recording
//! again; a retry is not counted by the rate limit (`--submissions-per-hour`, counted
//! in the store so that every replica counts alike: 429 with `Retry-After`, the seconds
//! until the oldest submission of the hour leaves it).

use axum::Router;
use axum::body::{Body, Bytes};
use axum::extract::{DefaultBodyLimit, FromRequest, Multipart, Path, Request, State};
use axum::http::request::Parts;
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use serde::Deserialize;
use serde_json::{Map, Value, json};
use tokio::sync::OnceCell;

use super::AppState;
use super::admission::CostLimit;
use super::auth::{Auth, scoped_to, sees};
use super::error::ApiError;
use super::extract::{
    RequestInfo, blocking, charge_to, content_type, deadline_of, is_json, media_essence, negotiate,
    once, parse_choice, query_pairs, read_charged,
};
use super::grade::{decoding_for, family, part_hint};
use super::job;
use super::memory::{Charge, Reservation};
use crate::assignment::grade::{SubmittedFile, grade_submission};
use crate::assignment::{self, AssignmentError, Graded, report};
use crate::format::footprint::Family;
use crate::grade::answer::ReportForm;
use crate::grade::{self, GradeOptions};
use crate::render::{Renderer, Work};
use crate::scene::Problem;
use crate::scene::footprint::{self as scene_footprint, JsonShape};
use crate::store::assignments::{NewSubmission, PutError, Recorded, Submission, Window};
use crate::store::{Role, Store, StoreError};

/// The routes.
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/v1/assignments", get(list))
        .route(
            "/v1/assignments/{id}",
            // Bodies are read behind the server's own `--max-body-bytes`.
            get(read)
                .put(put)
                .delete(delete)
                .layer(DefaultBodyLimit::disable()),
        )
        .route(
            "/v1/assignments/{id}/submissions",
            post(submit).layer(DefaultBodyLimit::disable()),
        )
}

/// The token checks of these routes, on the database opened at the first request that
/// needs it (or the one `--require-token` opened at the start).
#[derive(Debug)]
pub struct Course {
    auth: OnceCell<Auth>,
}

impl Course {
    /// With `auth` when the server opened the store already.
    pub fn new(auth: Option<Auth>) -> Course {
        Course {
            auth: OnceCell::new_with(auth),
        }
    }

    /// The token checks, opening the database the first time: what every route on
    /// assignments (these, and the gradebook's) checks tokens with and reads from.
    pub async fn auth(&self, app: &AppState) -> Result<&Auth, ApiError> {
        self.auth
            .get_or_try_init(|| async {
                let store = app
                    .config
                    .store
                    .open()
                    .await
                    .map_err(|e| ApiError::Internal(format!("cannot open the store: {e}")))?;
                Ok(Auth::new(store, app.config.admin_token.as_ref()))
            })
            .await
    }
}

/// The copies of a submission's body held at most while its form is split: the body,
/// the parts, and the files taken from them.
const BODY_COPIES: u64 = 3;

/// How long the rate limit's window is.
const HOUR_MS: i64 = 3_600_000;

/// The longest `student` and `Idempotency-Key` accepted.
const MAX_STUDENT_LEN: usize = 256;
const MAX_KEY_LEN: usize = 255;

/// A store failure as the client sees it: a busy database (no connection free in
/// time, SQLite's writer lock not free, PostgreSQL out of connections) is 503 with
/// `Retry-After`, so that a burst of submissions is answered as a busy server would;
/// anything else is a fault of ours.
pub fn store_error(e: StoreError) -> ApiError {
    let busy = match &e {
        StoreError::Database(sqlx::Error::PoolTimedOut) => true,
        // SQLite's SQLITE_BUSY and its extended codes; PostgreSQL's too_many_connections
        // and cannot_connect_now.
        StoreError::Database(sqlx::Error::Database(d)) => d
            .code()
            .is_some_and(|c| matches!(c.as_ref(), "5" | "261" | "517" | "773" | "53300" | "57P03")),
        _ => false,
    };
    if busy {
        tracing::warn!(error = %e, "the database is busy");
        ApiError::DatabaseBusy
    } else {
        ApiError::Internal(format!("the database failed: {e}"))
    }
}

pub(crate) fn not_found(id: &str) -> ApiError {
    ApiError::NotFound(format!("there is no assignment `{id}`"))
}

/// An id is a name that every URL and file system takes as it is.
pub(crate) fn check_id(id: &str) -> Result<(), ApiError> {
    if assignment::valid_name(id) {
        Ok(())
    } else {
        Err(ApiError::BadRequest(format!(
            "`{id}` cannot name an assignment: use 1 to 64 letters, digits, `_` and `-`"
        )))
    }
}

fn etag(revision: i64) -> HeaderValue {
    HeaderValue::from_str(&format!("\"{revision}\"")).unwrap_or(HeaderValue::from_static("\"0\""))
}

fn json_response(status: StatusCode, body: Vec<u8>) -> Response {
    (
        status,
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/json"),
        )],
        body,
    )
        .into_response()
}

/// The revision a `PUT` expects to replace: `If-Match: "N"`, or `If-None-Match: *`
/// for an assignment that must not exist yet (0); `None` without either.
fn expected_revision(headers: &HeaderMap) -> Result<Option<i64>, ApiError> {
    let text = |name: header::HeaderName| -> Result<Option<&str>, ApiError> {
        headers
            .get(&name)
            .map(|v| {
                v.to_str()
                    .map(str::trim)
                    .map_err(|_| ApiError::BadRequest(format!("`{name}` must be ASCII")))
            })
            .transpose()
    };
    match (text(header::IF_MATCH)?, text(header::IF_NONE_MATCH)?) {
        (Some(_), Some(_)) => Err(ApiError::BadRequest(
            "send `If-Match` or `If-None-Match`, not both".into(),
        )),
        (None, Some("*")) => Ok(Some(0)),
        (None, Some(v)) => Err(ApiError::BadRequest(format!(
            "`If-None-Match` may only be `*` (create, never replace), not `{v}`"
        ))),
        (Some(v), None) => {
            let n = v
                .strip_prefix('"')
                .and_then(|v| v.strip_suffix('"'))
                .and_then(|n| n.parse::<i64>().ok())
                .filter(|n| *n >= 1);
            n.map(Some).ok_or_else(|| {
                ApiError::BadRequest(format!(
                    "`If-Match` must be the `ETag` of a revision, `\"N\"`, not `{v}`"
                ))
            })
        }
        (None, None) => Ok(None),
    }
}

/// Grows `memory` by what parsing `text` takes (priced from a pre-scan, both off
/// tokio's threads), then runs `parse` on it off tokio's threads too.
async fn parse_charged<T: Send + 'static>(
    app: &AppState,
    memory: &mut Reservation,
    text: Bytes,
    what: &str,
    deadline: tokio::time::Instant,
    parse: impl FnOnce(&[u8]) -> T + Send + 'static,
) -> Result<T, ApiError> {
    let (text, shape) = blocking(app, deadline, move || {
        let shape = JsonShape::scan(&text);
        (text, shape)
    })
    .await?;
    let charge = Charge::fields(
        memory.bytes() + text.len() as u64 + scene_footprint::parse_peak(&shape),
        what,
        scene_footprint::parse_fields(&shape),
    );
    charge_to(app, memory, &charge, deadline).await?;
    blocking(app, deadline, move || parse(&text)).await
}

/// `PUT /v1/assignments/{id}`: the document validated as strictly as a scene, each
/// scene's reference priced against `--max-rays` (so that no submission is refused
/// for it later), then stored as the next revision.
async fn put(
    State(app): State<AppState>,
    info: RequestInfo,
    Path(id): Path<String>,
    req: Request,
) -> Result<Response, ApiError> {
    check_id(&id)?;
    let auth = app.course.auth(&app).await?;
    let who = auth.instructor(req.headers()).await?;
    let expected = expected_revision(req.headers())?;
    let got = content_type(req.headers());
    if !is_json(&got) {
        return Err(ApiError::UnsupportedMediaType {
            got,
            supported: &["application/json"],
        });
    }
    let deadline = deadline_of(&req, &app);
    let (_, bytes, mut memory) = read_charged(req, &app, 1, "the body").await?;
    let limits = app.config.limits();
    let (text, parsed) = parse_charged(
        &app,
        &mut memory,
        bytes,
        "parsing the assignment",
        deadline,
        move |t| {
            // Valid JSON is UTF-8, so a document that parses is text.
            let parsed = assignment::parse(t, &limits);
            (String::from_utf8_lossy(t).into_owned(), parsed)
        },
    )
    .await?;
    let a = match parsed {
        Ok(a) => a,
        Err(AssignmentError::Syntax {
            message,
            line,
            column,
        }) => {
            return Err(ApiError::InvalidJson {
                what: "the body",
                message,
                line,
                column,
            });
        }
        Err(AssignmentError::Invalid(problems)) => {
            return Err(ApiError::InvalidAssignment(problems));
        }
    };
    let (cost, metrics) = (CostLimit::new(&app.config), app.metrics.clone());
    job::run(&app, &info, "assignment_cost", move |cancel| {
        // The parsed assignment is what the memory holds.
        let _memory = memory;
        for (i, s) in a.scenes.iter().enumerate() {
            let r = Renderer::new(s.scene.clone());
            // An image's rays are a superset of the hit data's.
            let work = match s.graded {
                Graded::Hits => Work::Hits,
                Graded::Image | Graded::Both => Work::Colour,
            };
            cost.check(
                &r,
                r.frame(),
                work,
                cancel,
                &metrics,
                &format!("/scenes/{i}/scene"),
            )?;
        }
        Ok::<_, ApiError>(())
    })
    .await??;
    let put = auth
        .store()
        .put_assignment(&id, &text, expected)
        .await
        .map_err(|e| match e {
            PutError::Conflict {
                expected,
                current: 0,
            } => ApiError::Conflict(format!(
                "there is no assignment `{id}` to replace at revision {expected}"
            )),
            PutError::Conflict { expected, current } => ApiError::Conflict(format!(
                "the assignment `{id}` is at revision {current}, not {expected}: fetch it again"
            )),
            PutError::Store(e) => store_error(e),
        })?;
    tracing::info!(token_id = %who.id, assignment = %id, revision = put.revision, "assignment stored");
    let body = serde_json::to_vec(&json!({"id": id, "revision": put.revision}))
        .map_err(|e| ApiError::Internal(e.to_string()))?;
    let status = if put.created {
        StatusCode::CREATED
    } else {
        StatusCode::OK
    };
    let mut res = json_response(status, body);
    res.headers_mut().insert(header::ETAG, etag(put.revision));
    Ok(res)
}

/// What a listing says of an assignment, read from its document without its scenes.
#[derive(Deserialize)]
struct Summary {
    title: String,
    #[serde(default)]
    due: Option<String>,
    scenes: Vec<Named>,
}

#[derive(Deserialize)]
struct Named {
    name: String,
}

/// `GET /v1/assignments`: every assignment an instructor's token may see, or those a
/// grader's is scoped to.
async fn list(
    State(app): State<AppState>,
    info: RequestInfo,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let auth = app.course.auth(&app).await?;
    let who = auth.principal(&headers).await?;
    let listed: Vec<_> = auth
        .store()
        .live_assignments()
        .await
        .map_err(store_error)?
        .into_iter()
        .filter(|l| sees(&who, &l.id))
        .collect();
    let deadline = tokio::time::Instant::from_std(info.start + app.config.deadline());
    let body = blocking(&app, deadline, move || {
        let items: Vec<Value> = listed
            .iter()
            .filter_map(|l| {
                // Every document was validated when it was stored; one that does not
                // read (written by hand into the database) is left out, not fatal.
                let s: Summary = match serde_json::from_str(&l.stored.document) {
                    Ok(s) => s,
                    Err(e) => {
                        tracing::warn!(assignment = %l.id, error = %e, "a stored assignment does not read: not listed");
                        return None;
                    }
                };
                let mut item = json!({
                    "id": l.id,
                    "title": s.title,
                    "revision": l.stored.revision,
                    "scenes": s.scenes.into_iter().map(|n| n.name).collect::<Vec<_>>(),
                });
                if let Some(due) = s.due {
                    item["due"] = json!(due);
                }
                Some(item)
            })
            .collect();
        serde_json::to_vec(&json!({ "assignments": items }))
            .map_err(|e| ApiError::Internal(e.to_string()))
    })
    .await??;
    Ok(json_response(StatusCode::OK, body))
}

/// What a grader may see of an assignment document (validated when it was stored):
/// the title, the due date, and each scene's name, points, what is graded and its
/// scene document.
fn grader_view(text: &[u8]) -> Result<Vec<u8>, serde_json::Error> {
    let Value::Object(mut top) = serde_json::from_slice::<Value>(text)? else {
        return Ok(b"{}".to_vec());
    };
    let mut view = Map::new();
    for key in ["version", "title", "due"] {
        if let Some(v) = top.remove(key).filter(|v| !v.is_null()) {
            view.insert(key.into(), v);
        }
    }
    let scenes: Vec<Value> = match top.remove("scenes") {
        Some(Value::Array(list)) => list
            .into_iter()
            .map(|s| {
                let Value::Object(mut s) = s else {
                    return Value::Null;
                };
                let mut shown = Map::new();
                for key in ["name", "points", "grade", "scene"] {
                    if let Some(v) = s.remove(key) {
                        shown.insert(key.into(), v);
                    }
                }
                Value::Object(shown)
            })
            .collect(),
        _ => Vec::new(),
    };
    view.insert("scenes".into(), Value::Array(scenes));
    serde_json::to_vec(&Value::Object(view))
}

/// `GET /v1/assignments/{id}`: the document as pushed for an instructor, the
/// [`grader_view`] for a grader.
async fn read(
    State(app): State<AppState>,
    Path(id): Path<String>,
    req: Request,
) -> Result<Response, ApiError> {
    check_id(&id)?;
    let auth = app.course.auth(&app).await?;
    let who = auth.principal(req.headers()).await?;
    scoped_to(&who, &id)?;
    let stored = auth
        .store()
        .assignment(&id)
        .await
        .map_err(store_error)?
        .ok_or_else(|| not_found(&id))?;
    let (body, _memory) = match who.role {
        Role::Instructor => (stored.document.into_bytes(), None),
        Role::Grader => {
            let deadline = deadline_of(&req, &app);
            let mut memory = app.memory.empty();
            let view = parse_charged(
                &app,
                &mut memory,
                Bytes::from(stored.document),
                "reading the assignment",
                deadline,
                grader_view,
            )
            .await?
            .map_err(|e| ApiError::Internal(format!("stored assignment `{id}`: {e}")))?;
            (view, Some(memory))
        }
    };
    let mut res = json_response(StatusCode::OK, body);
    res.headers_mut()
        .insert(header::ETAG, etag(stored.revision));
    Ok(res)
}

/// `DELETE /v1/assignments/{id}`: gone, with the grader tokens scoped to it; its
/// submissions stay in the database.
async fn delete(
    State(app): State<AppState>,
    Path(id): Path<String>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    check_id(&id)?;
    let auth = app.course.auth(&app).await?;
    let who = auth.instructor(&headers).await?;
    if !auth
        .store()
        .delete_assignment(&id)
        .await
        .map_err(store_error)?
    {
        return Err(not_found(&id));
    }
    tracing::info!(token_id = %who.id, assignment = %id, "assignment deleted");
    Ok(StatusCode::NO_CONTENT.into_response())
}

/// `?report=json|text|gradescope|prairielearn` (default `json`), acceptable by `Accept`.
fn report_form(uri: &axum::http::Uri, headers: &HeaderMap) -> Result<ReportForm, ApiError> {
    let mut form = None;
    for (k, v) in query_pairs(uri)? {
        match k.as_str() {
            "report" => {
                let f = parse_choice(
                    "report",
                    &v,
                    &[
                        ("json", ReportForm::Json),
                        ("text", ReportForm::Text),
                        ("gradescope", ReportForm::Gradescope),
                        ("prairielearn", ReportForm::Prairielearn),
                    ],
                )?;
                once(&mut form, "report", f)?;
            }
            other => {
                return Err(ApiError::BadRequest(format!(
                    "unknown query parameter `{other}`: this route takes `report`"
                )));
            }
        }
    }
    let form = form.unwrap_or(ReportForm::Json);
    let offers: &'static [&'static str] = match form {
        ReportForm::Text => &["text/plain"],
        _ => &["application/json"],
    };
    negotiate(headers, offers)?;
    Ok(form)
}

/// The `Idempotency-Key`, if sent: 1 to 255 visible ASCII characters.
fn idempotency_key(headers: &HeaderMap) -> Result<Option<String>, ApiError> {
    let Some(v) = headers.get("idempotency-key") else {
        return Ok(None);
    };
    let bad = || {
        ApiError::BadRequest(format!(
            "`Idempotency-Key` must be 1 to {MAX_KEY_LEN} visible ASCII characters"
        ))
    };
    let key = v.to_str().map_err(|_| bad())?.trim();
    if key.is_empty() || key.len() > MAX_KEY_LEN || !key.bytes().all(|b| b.is_ascii_graphic()) {
        return Err(bad());
    }
    Ok(Some(key.to_owned()))
}

fn form_error(e: axum::extract::multipart::MultipartError) -> ApiError {
    ApiError::BadRequest(format!("cannot read the form: {}", e.body_text()))
}

/// The form's `student` field and its files, each named by its part (the scene).
/// The whole form is in memory and within the limit: splitting it is quick.
async fn read_form(parts: Parts, bytes: Bytes) -> Result<(String, Vec<SubmittedFile>), ApiError> {
    let req = Request::from_parts(parts, Body::from(bytes));
    let mut form = Multipart::from_request(req, &())
        .await
        .map_err(|e| ApiError::BadRequest(format!("cannot read the form: {}", e.body_text())))?;
    let mut student: Option<String> = None;
    let mut files = Vec::new();
    while let Some(field) = form.next_field().await.map_err(form_error)? {
        let name = field.name().unwrap_or_default().to_owned();
        if name == "student" {
            let text = field.text().await.map_err(form_error)?;
            if student.replace(text).is_some() {
                return Err(ApiError::BadRequest(
                    "the form has more than one `student` field".into(),
                ));
            }
            continue;
        }
        if name.is_empty() {
            return Err(ApiError::BadRequest(
                "a part of the form has no name: name each file part after its scene".into(),
            ));
        }
        let hint = part_hint(field.content_type(), field.file_name());
        let file_name = field
            .file_name()
            .map_or_else(|| name.clone(), str::to_owned);
        let bytes = field.bytes().await.map_err(form_error)?;
        files.push(SubmittedFile {
            scene: name,
            file_name,
            bytes: Vec::from(bytes),
            hint,
        });
    }
    let student = student.ok_or_else(|| {
        ApiError::BadRequest(
            "the form has no `student` field: send `-F student=ID` with the files".into(),
        )
    })?;
    let student = student.trim().to_owned();
    if student.is_empty()
        || student.len() > MAX_STUDENT_LEN
        || student.chars().any(char::is_control)
    {
        return Err(ApiError::BadRequest(format!(
            "`student` must be 1 to {MAX_STUDENT_LEN} bytes without control characters"
        )));
    }
    Ok((student, files))
}

/// Refuses a submission past `--submissions-per-hour` for this student and assignment:
/// 429 with the seconds until the oldest of the hour's submissions leaves the window.
async fn check_rate(
    app: &AppState,
    store: &Store,
    id: &str,
    student: &str,
) -> Result<(), ApiError> {
    let limit = app.config.submissions_per_hour;
    if limit == 0 {
        return Ok(());
    }
    let now = crate::store::now_ms();
    let times = store
        .recent_submission_times(id, student, now - HOUR_MS, limit)
        .await
        .map_err(store_error)?;
    match times.get(limit as usize - 1) {
        Some(&oldest) => Err(rate_limited(app, limit, oldest)),
        None => Ok(()),
    }
}

/// The 429 of a full hour whose oldest counted submission was recorded at `oldest_ms`.
fn rate_limited(app: &AppState, limit: u32, oldest_ms: i64) -> ApiError {
    let wait_ms = (oldest_ms + HOUR_MS - crate::store::now_ms()).max(0) as u64;
    app.metrics.reject("rate_limit");
    ApiError::TooManySubmissions {
        limit,
        retry_after_seconds: wait_ms.div_ceil(1000).max(1),
    }
}

/// What grading `files` against `a` takes at most, beyond the body: the files, every
/// built scene, the costliest file's decoding and comparison (files are graded one after
/// another), and each graded part's difference image, kept in its report.
fn grading_charge(
    a: &assignment::Assignment,
    files: &[SubmittedFile],
    diagnosis_max: u64,
) -> Charge {
    let built: u64 = a
        .scenes
        .iter()
        .map(|s| scene_footprint::built(&s.scene))
        .sum();
    let held: u64 = files.iter().map(|f| f.bytes.len() as u64).sum();
    let (mut peak, mut kept) = (0u64, 0u64);
    for f in files {
        let Some(s) = a.scenes.iter().find(|s| s.name == f.scene) else {
            continue;
        };
        let (w, h) = (s.scene.width, s.scene.height);
        let pixels = w as u64 * h as u64;
        let image = matches!(family(&f.bytes, f.hint), Some(Family::Image(_)));
        let decode = decoding_for(&f.bytes, f.hint, &s.scene);
        let graded = grade::footprint::grading(w, h, image, pixels <= diagnosis_max);
        peak = peak.max(decode.peak + graded);
        kept += pixels * 3;
    }
    Charge::fields(
        held + built + peak + kept,
        "grading the submission",
        vec![Problem::new(
            "",
            "the submitted files and the frames of the assignment's scenes drive the memory \
             grading needs",
        )],
    )
}

/// A graded answer: the report in its form, where the submission is kept.
fn graded(status: StatusCode, form: ReportForm, id: &str, sid: &str, body: Vec<u8>) -> Response {
    let location = HeaderValue::from_str(&format!("/v1/assignments/{id}/submissions/{sid}"))
        .unwrap_or(HeaderValue::from_static("/v1/assignments"));
    (
        status,
        [
            (
                header::CONTENT_TYPE,
                HeaderValue::from_static(form.content_type()),
            ),
            (header::LOCATION, location),
        ],
        body,
    )
        .into_response()
}

/// The stored result of `sub` in `form` (200): the JSON as stored, another form
/// written from it off tokio's threads.
async fn replay(
    app: &AppState,
    id: &str,
    sub: Submission,
    form: ReportForm,
    deadline: tokio::time::Instant,
) -> Result<Response, ApiError> {
    let sid = sub.id.clone();
    let body = match form {
        ReportForm::Json => sub.result.into_bytes(),
        _ => blocking(app, deadline, move || {
            report::read(&sub.result).map(|r| report::write(&r, form))
        })
        .await?
        .map_err(|e| ApiError::Internal(format!("a stored result cannot be read back: {e}")))?,
    };
    Ok(graded(StatusCode::OK, form, id, &sid, body))
}

/// The options every grade on this server takes, as `/v1/grade`'s defaults.
fn grade_options(app: &AppState) -> GradeOptions {
    let defaults = GradeOptions::default();
    GradeOptions {
        diagnosis: grade::diagnose::Settings {
            max_pixels: app.config.diagnosis_max_pixels,
            ..defaults.diagnosis
        },
        references: Some(app.references.clone()),
        ..defaults
    }
}

/// Seconds since the Unix epoch (for hidden feedback after the due date).
fn unix_now() -> i64 {
    crate::store::now_ms() / 1000
}

/// `POST /v1/assignments/{id}/submissions`.
async fn submit(
    State(app): State<AppState>,
    info: RequestInfo,
    Path(id): Path<String>,
    req: Request,
) -> Result<Response, ApiError> {
    check_id(&id)?;
    let form = report_form(req.uri(), req.headers())?;
    let key = idempotency_key(req.headers())?;
    let deadline = deadline_of(&req, &app);
    let auth = app.course.auth(&app).await?;
    let who = auth.principal(req.headers()).await?;
    scoped_to(&who, &id)?;
    let store = auth.store();
    let stored = store
        .assignment(&id)
        .await
        .map_err(store_error)?
        .ok_or_else(|| not_found(&id))?;
    if let Some(k) = &key
        && let Some(done) = store.submission_by_key(&id, k).await.map_err(store_error)?
    {
        return replay(&app, &id, done, form, deadline).await;
    }
    let got = content_type(req.headers());
    if media_essence(&got) != "multipart/form-data" {
        return Err(ApiError::UnsupportedMediaType {
            got,
            supported: &["multipart/form-data"],
        });
    }
    let (parts, bytes, mut memory) = read_charged(req, &app, BODY_COPIES, "the body").await?;
    let (student, files) = read_form(parts, bytes).await?;
    check_rate(&app, store, &id, &student).await?;

    let limits = app.config.limits();
    let revision = stored.revision;
    let a = parse_charged(
        &app,
        &mut memory,
        Bytes::from(stored.document),
        "parsing the assignment",
        deadline,
        move |t| assignment::parse(t, &limits),
    )
    .await?
    .map_err(|e| {
        ApiError::Internal(format!(
            "the stored assignment `{id}` is not valid under this server's limits: {e}"
        ))
    })?;
    let charge = grading_charge(&a, &files, app.config.diagnosis_max_pixels);
    charge_to(&app, &mut memory, &charge, deadline).await?;

    // Concurrent submissions render each missing reference once (`grade::cache`).
    let scenes: Vec<_> = a
        .scenes
        .iter()
        .map(|s| (s.scene.clone(), s.graded.kinds()))
        .collect();
    let wants = blocking(&app, deadline, move || grade::cache::wants(&scenes)).await?;
    let turn = tokio::time::timeout_at(deadline, app.references.turn(&wants))
        .await
        .map_err(|_| super::extract::deadline_exceeded(&app))?;
    let opts = grade_options(&app);
    let now = unix_now();
    let deadline_len = app.config.deadline();
    let (json, answer, score) = job::run(&app, &info, "assignment", move |cancel| {
        // Given back when the work ends, as is the turn.
        let _memory = memory;
        let _turn = turn;
        let opts = GradeOptions {
            cancel: cancel.clone(),
            ..opts
        };
        let result = grade_submission(&a, files, now, &opts);
        // A stopped reference leaves its scene ungradable: that is no result to keep.
        if cancel.is_over_budget() {
            return Err(ApiError::ReferenceFailed(
                "a scene's reference takes more rays than the server's `--max-rays` allows".into(),
            ));
        }
        if cancel.is_cancelled() {
            return Err(ApiError::DeadlineExceeded(deadline_len));
        }
        let json = String::from_utf8(report::write(&result, ReportForm::Json))
            .map_err(|e| ApiError::Internal(format!("the report is not UTF-8: {e}")))?;
        let answer = (form != ReportForm::Json).then(|| report::write(&result, form));
        Ok((json, answer, result.score))
    })
    .await??;
    let new = NewSubmission {
        assignment: &id,
        revision,
        student: &student,
        idempotency_key: key.as_deref(),
        result: &json,
        score,
    };
    // Checked again as it is recorded: submissions graded at the same time may have
    // filled the hour meanwhile, and their verdicts are withheld.
    let window = match app.config.submissions_per_hour {
        0 => None,
        limit => Some(Window {
            limit,
            since_ms: crate::store::now_ms() - HOUR_MS,
        }),
    };
    let recorded = store
        .record_submission_within(&new, window)
        .await
        .map_err(store_error)?;
    let sub = match recorded {
        Recorded::New(sub) => sub,
        // A concurrent retry with the same key was recorded first: answer that one.
        Recorded::Existing(sub) => return replay(&app, &id, sub, form, deadline).await,
        Recorded::Limited { oldest_ms } => {
            return Err(rate_limited(
                &app,
                app.config.submissions_per_hour,
                oldest_ms,
            ));
        }
    };
    tracing::info!(token_id = %who.id, assignment = %id, submission = %sub.id, score, "submission recorded");
    let body = answer.unwrap_or_else(|| json.into_bytes());
    Ok(graded(StatusCode::CREATED, form, &id, &sub.id, body))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn headers(pairs: &[(&'static str, &str)]) -> HeaderMap {
        let mut h = HeaderMap::new();
        for (k, v) in pairs {
            h.insert(*k, HeaderValue::from_str(v).unwrap());
        }
        h
    }

    #[test]
    fn the_expected_revision_comes_from_if_match_or_if_none_match() {
        assert_eq!(expected_revision(&headers(&[])).unwrap(), None);
        assert_eq!(
            expected_revision(&headers(&[("if-match", "\"3\"")])).unwrap(),
            Some(3)
        );
        assert_eq!(
            expected_revision(&headers(&[("if-none-match", "*")])).unwrap(),
            Some(0)
        );
        for bad in [
            &[("if-match", "3")][..],
            &[("if-match", "\"0\"")],
            &[("if-match", "*")],
            &[("if-none-match", "\"2\"")],
            &[("if-match", "\"1\""), ("if-none-match", "*")],
        ] {
            assert!(
                matches!(
                    expected_revision(&headers(bad)),
                    Err(ApiError::BadRequest(_))
                ),
                "{bad:?}"
            );
        }
    }

    #[test]
    fn a_busy_database_is_503_and_other_failures_500() {
        assert_eq!(
            store_error(StoreError::Database(sqlx::Error::PoolTimedOut)),
            ApiError::DatabaseBusy
        );
        assert!(matches!(
            store_error(StoreError::Corrupt("x".into())),
            ApiError::Internal(_)
        ));
    }

    #[test]
    fn idempotency_keys_are_visible_ascii() {
        assert_eq!(idempotency_key(&headers(&[])).unwrap(), None);
        assert_eq!(
            idempotency_key(&headers(&[("idempotency-key", "k-1")])).unwrap(),
            Some("k-1".into())
        );
        let long = "k".repeat(MAX_KEY_LEN + 1);
        for bad in ["", "a b", long.as_str()] {
            assert!(
                idempotency_key(&headers(&[("idempotency-key", bad)])).is_err(),
                "{bad}"
            );
        }
    }

    #[test]
    fn a_grader_sees_names_points_grades_and_scenes_only() {
        let doc = r#"{"version": 1, "title": "t", "due": "2026-12-24T23:59:00Z", "scenes": [
            {"name": "s", "scene": {"version": 1}, "points": 5, "grade": "hits",
             "visibility": "hidden", "feedback": "after_due_date",
             "tolerances": {"lambda_rel": 1e-6}, "scoring": "linear"}]}"#;
        let v: Value = serde_json::from_slice(&grader_view(doc.as_bytes()).unwrap()).unwrap();
        assert_eq!(
            v,
            json!({"version": 1, "title": "t", "due": "2026-12-24T23:59:00Z", "scenes": [
                {"name": "s", "points": 5, "grade": "hits", "scene": {"version": 1}}]})
        );
    }
}
