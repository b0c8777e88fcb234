//! `POST /v1/grade`: a scene and a student's submission in, a grading report out
//! ([`crate::grade::grade`]), the same as `raytile grade`.
//!
//! Two request forms, the body's `Content-Type` says which:
//!
//! - `multipart/form-data` (what `curl -F` sends), parts `scene` (the scene JSON),
//!   `submission` (a PNG, or hit data as JSON, NDJSON, NPY or CSV: its form from the
//!   part's media type, else its file name's extension, else its content) and optionally
//!   `tolerances` (a JSON document, section 3 of the grading guide);
//! - `application/json`, one document:
//!
//! ```json
//! { "scene": { "version": 1, … },
//!   "submission": { "png_base64": "iVBORw0KGgo…" },
//!   "tolerances": { "colour_abs": 4 } }
//! ```
//!
//!   where `submission` is hit data as `raytile hits` writes it (the document, or a bare
//!   array of pixels), or an object with exactly one of `png_base64`, `npy_base64` (the
//!   file, base64-encoded) or `csv`, `ndjson` (the text). Scene problems point into the
//!   body (`/scene/objects/0/material`).
//!
//! The query mirrors the command line's options: the tolerances (`colour_abs`,
//! `max_fail_share`, `lambda_rel`, `normal_degrees`, `edge_forgiving`, each overriding
//! the body's `tolerances`), `worst`, `inline_diff`, `flip`, `format` (the submission's
//! form, overriding the part's), `report` (`json`, `text`, `gradescope`,
//! `prairielearn`), `max_score`, and `output=diff` for the difference image as a PNG.
//! The answers are the bytes `raytile grade` writes, from the same function
//! ([`crate::grade::answer::write_report`]); `X-Raytile-Verdict` is `pass` or `fail`, so
//! even the difference image carries the verdict.
//!
//! As for renders, everything that can fail is decided before a render slot is taken:
//! the query (400), `Accept` (406), the body's media type (415), its size (413: the
//! limit applies to the whole request), its structure and the tolerances (400), the
//! scene (400, 422 `invalid-scene`), the submission (422 `invalid-submission`; a PNG of
//! the wrong size is refused from its header). Parsing runs off tokio's threads; the
//! reference render and the comparison run on the rayon pool under admission (503 with
//! `Retry-After` when saturated) and the deadline (504), see [`super::job`].

use std::sync::Arc;

use axum::Router;
use axum::body::{Body, Bytes};
use axum::extract::{DefaultBodyLimit, FromRequest, FromRequestParts, Multipart, Request, State};
use axum::http::request::Parts;
use axum::http::{HeaderMap, HeaderName, HeaderValue, header};
use axum::response::{IntoResponse, Response};
use axum::routing::post;
use base64::Engine as _;
use serde::Deserialize;
use serde_json::Value;

use super::AppState;
use super::admission::CostLimit;
use super::error::ApiError;
use super::extract::{
    RequestInfo, content_type, deadline_exceeded, is_json, media_essence, negotiate, once,
    parse_choice, parse_flag, parse_param, query_pairs, read_limited,
};
use super::job;
use crate::format::ReadError;
use crate::grade::answer::{ReportForm, write_report};
use crate::grade::{
    self, GradeError, GradeOptions, Hint, Submission, ToleranceOverrides, Tolerances, submission,
};
use crate::json;
use crate::render::{Renderer, Work};
use crate::scene::{self, Scene};

/// The routes: `POST /v1/grade`.
pub fn router() -> Router<AppState> {
    Router::new().route(
        "/v1/grade",
        // The body is read whole behind the server's own `--max-body-bytes` before the
        // multipart parser sees it; axum's default limit of 2 MiB must not cut it shorter.
        post(grade).layer(DefaultBodyLimit::disable()),
    )
}

/// The request bodies `/v1/grade` reads.
pub const GRADE_BODY_TYPES: &[&str] = &["multipart/form-data", "application/json"];

/// Most pixels `worst` may list: each is a few hundred bytes of report.
pub const MAX_WORST: usize = 1000;

/// `pass` or `fail`, on every graded answer.
pub const X_RAYTILE_VERDICT: HeaderName = HeaderName::from_static("x-raytile-verdict");

/// The query string of `/v1/grade`; every field is optional.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GradeQuery {
    /// `colour_abs` (`color_abs` too), `max_fail_share`, `lambda_rel`, `normal_degrees`
    /// and `edge_forgiving`, over the body's `tolerances`.
    pub tolerances: ToleranceOverrides,
    /// How many of the worst pixels to list (default 10, at most [`MAX_WORST`]).
    pub worst: Option<usize>,
    /// Put the difference image in the JSON report.
    pub inline_diff: Option<bool>,
    /// Compute FLIP (default true).
    pub flip: Option<bool>,
    /// `report=json|text|gradescope|prairielearn`.
    pub report: Option<ReportForm>,
    /// `output=diff` (or `output=report`, the default).
    pub diff: Option<bool>,
    /// Points for a pass in the Gradescope report (default 1).
    pub max_score: Option<f64>,
    /// The submission's form, overriding what the request says of it.
    pub format: Option<Hint>,
}

impl<S: Send + Sync> FromRequestParts<S> for GradeQuery {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, ApiError> {
        let mut q = GradeQuery::default();
        let number = "a number";
        for (k, v) in query_pairs(&parts.uri)? {
            let k = k.as_str();
            match k {
                "colour_abs" | "color_abs" => {
                    let x = parse_param(k, &v, "a whole number from 0 to 255")?;
                    once(&mut q.tolerances.colour_abs, "colour_abs", x)?;
                }
                "max_fail_share" => once(
                    &mut q.tolerances.max_fail_share,
                    k,
                    parse_param(k, &v, number)?,
                )?,
                "lambda_rel" => once(&mut q.tolerances.lambda_rel, k, parse_param(k, &v, number)?)?,
                "normal_degrees" => once(
                    &mut q.tolerances.normal_degrees,
                    k,
                    parse_param(k, &v, number)?,
                )?,
                "edge_forgiving" => once(&mut q.tolerances.edge_forgiving, k, parse_flag(k, &v)?)?,
                "inline_diff" => once(&mut q.inline_diff, k, parse_flag(k, &v)?)?,
                "flip" => once(&mut q.flip, k, parse_flag(k, &v)?)?,
                "worst" => {
                    let n: usize = parse_param(k, &v, "a whole number ≥ 0")?;
                    if n > MAX_WORST {
                        return Err(ApiError::BadRequest(format!(
                            "query parameter `worst` may be at most {MAX_WORST}, not {n}"
                        )));
                    }
                    once(&mut q.worst, k, n)?;
                }
                "max_score" => {
                    let x: f64 = parse_param(k, &v, number)?;
                    if !(x.is_finite() && x >= 0.0) {
                        return Err(ApiError::BadRequest(format!(
                            "query parameter `max_score` must be a finite number ≥ 0, not `{v}`"
                        )));
                    }
                    once(&mut q.max_score, k, x)?;
                }
                "report" => {
                    let a = parse_choice(
                        k,
                        &v,
                        &[
                            ("json", ReportForm::Json),
                            ("text", ReportForm::Text),
                            ("gradescope", ReportForm::Gradescope),
                            ("prairielearn", ReportForm::Prairielearn),
                        ],
                    )?;
                    once(&mut q.report, k, a)?;
                }
                "output" => {
                    let diff = parse_choice(k, &v, &[("diff", true), ("report", false)])?;
                    once(&mut q.diff, k, diff)?;
                }
                "format" => {
                    let h = Hint::from_name(&v).ok_or_else(|| {
                        ApiError::BadRequest(format!(
                            "query parameter `format` must be `auto`, `png`, `json`, `ndjson`, \
                             `npy` or `csv`, not `{v}`"
                        ))
                    })?;
                    once(&mut q.format, k, h)?;
                }
                other => {
                    return Err(ApiError::BadRequest(format!(
                        "unknown query parameter `{other}`: this route takes `colour_abs`, \
                         `max_fail_share`, `lambda_rel`, `normal_degrees`, `edge_forgiving`, \
                         `worst`, `inline_diff`, `flip`, `format`, `report`, `max_score` and \
                         `output`"
                    )));
                }
            }
        }
        if q.diff == Some(true) && q.report.is_some() {
            return Err(ApiError::BadRequest(
                "`output=diff` answers with the difference image, not a report: leave out \
                 `report`"
                    .into(),
            ));
        }
        Ok(q)
    }
}

impl GradeQuery {
    /// What to answer with, given `Accept`: `output` or `report` when given (and
    /// acceptable), else JSON or text as `Accept` prefers.
    fn answer(&self, headers: &HeaderMap) -> Result<ReportForm, ApiError> {
        let chosen = match (self.diff, self.report) {
            (Some(true), _) => ReportForm::DiffPng,
            (_, Some(r)) => r,
            _ => {
                return Ok(
                    match negotiate(headers, &["application/json", "text/plain"])? {
                        "text/plain" => ReportForm::Text,
                        _ => ReportForm::Json,
                    },
                );
            }
        };
        // An explicit choice must still be something the client accepts.
        let offers: &'static [&'static str] = match chosen.media_type() {
            "image/png" => &["image/png"],
            "text/plain" => &["text/plain"],
            _ => &["application/json"],
        };
        negotiate(headers, offers)?;
        Ok(chosen)
    }
}

/// The request body as read, before anything in it is parsed.
#[derive(Debug, Clone)]
pub enum GradeBody {
    /// The parts of a `multipart/form-data` form.
    Form {
        /// The `scene` part.
        scene: Bytes,
        /// The `submission` part.
        submission: Bytes,
        /// What the part's media type or file name say of its form.
        hint: Hint,
        /// The `tolerances` part, if sent.
        tolerances: Option<Bytes>,
    },
    /// An `application/json` document `{scene, submission, tolerances}`.
    Json(Bytes),
}

impl FromRequest<AppState> for GradeBody {
    type Rejection = ApiError;

    async fn from_request(req: Request, app: &AppState) -> Result<Self, ApiError> {
        let got = content_type(req.headers());
        let multipart = media_essence(&got) == "multipart/form-data";
        if !multipart && !is_json(&got) {
            return Err(ApiError::UnsupportedMediaType {
                got,
                supported: GRADE_BODY_TYPES,
            });
        }
        let (parts, bytes) = read_limited(req, app).await?;
        if !multipart {
            return Ok(GradeBody::Json(bytes));
        }
        // The whole form is in memory and within the limit: splitting it is quick.
        let req = Request::from_parts(parts, Body::from(bytes));
        let mut form = Multipart::from_request(req, &()).await.map_err(|e| {
            ApiError::BadRequest(format!("cannot read the form: {}", e.body_text()))
        })?;
        let form_error = |e: axum::extract::multipart::MultipartError| {
            ApiError::BadRequest(format!("cannot read the form: {}", e.body_text()))
        };
        let (mut scene, mut submission, mut tolerances) = (None, None, None);
        while let Some(field) = form.next_field().await.map_err(form_error)? {
            let name = field.name().unwrap_or_default().to_owned();
            match name.as_str() {
                "scene" => {
                    let b = field.bytes().await.map_err(form_error)?;
                    once_part(&mut scene, "scene", b)?;
                }
                "submission" => {
                    let hint = part_hint(field.content_type(), field.file_name());
                    let b = field.bytes().await.map_err(form_error)?;
                    once_part(&mut submission, "submission", (b, hint))?;
                }
                "tolerances" => {
                    let b = field.bytes().await.map_err(form_error)?;
                    once_part(&mut tolerances, "tolerances", b)?;
                }
                other => {
                    return Err(ApiError::BadRequest(format!(
                        "unknown part `{other}`: the form takes `scene`, `submission` and \
                         `tolerances`"
                    )));
                }
            }
        }
        let missing = |part: &str| {
            ApiError::BadRequest(format!(
                "the form has no `{part}` part: send `-F scene=@scene.json -F submission=@FILE`"
            ))
        };
        let scene = scene.ok_or_else(|| missing("scene"))?;
        let (submission, hint) = submission.ok_or_else(|| missing("submission"))?;
        Ok(GradeBody::Form {
            scene,
            submission,
            hint,
            tolerances,
        })
    }
}

fn once_part<T>(slot: &mut Option<T>, name: &str, value: T) -> Result<(), ApiError> {
    if slot.is_some() {
        return Err(ApiError::BadRequest(format!(
            "the form has more than one `{name}` part"
        )));
    }
    *slot = Some(value);
    Ok(())
}

/// The submission's form from its part: the media type when it names one (`image/png`,
/// `text/csv`, …), else the file name's extension (`curl -F` sends most files as
/// `application/octet-stream`), else [`Hint::Auto`] (told from the content).
fn part_hint(media_type: Option<&str>, file_name: Option<&str>) -> Hint {
    match media_type.map(Hint::from_media_type) {
        Some(h) if h != Hint::Auto => h,
        _ => file_name.map_or(Hint::Auto, |n| Hint::from_path(std::path::Path::new(n))),
    }
}

/// The JSON request form.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Envelope {
    scene: Value,
    submission: Value,
    #[serde(default)]
    tolerances: Option<Tolerances>,
}

/// Everything grading needs, parsed and checked.
struct Prepared {
    scene: Arc<Scene>,
    submission: Submission,
    tolerances: Tolerances,
    /// Where the scene lies in the body, for the pointers of its problems.
    scene_at: &'static str,
}

/// Parses the body in the order a client fixes things: the request's structure and the
/// tolerances (400: the JSON document or the form's parts, the query's tolerances on top
/// of the body's), then the scene (against the server's limits), then the submission
/// (against the scene's frame). CPU work proportional to the body: called off tokio's
/// threads.
fn prepare(
    body: GradeBody,
    query: &GradeQuery,
    limits: &scene::Limits,
) -> Result<Prepared, ApiError> {
    // The scene and the submission as sent, with what is known of the submission's form.
    enum Sent {
        Form(Bytes, Bytes, Hint),
        Json(Value, Value),
    }
    let (sent, tolerances) = match body {
        GradeBody::Form {
            scene,
            submission,
            hint,
            tolerances,
        } => {
            let tolerances = match tolerances {
                Some(b) => Some(strict::<Tolerances>(&b, "the `tolerances` part")?),
                None => None,
            };
            (Sent::Form(scene, submission, hint), tolerances)
        }
        GradeBody::Json(bytes) => {
            let env: Envelope = strict(&bytes, "the body")?;
            (Sent::Json(env.scene, env.submission), env.tolerances)
        }
    };
    let tolerances = query.tolerances.apply(tolerances.unwrap_or_default());
    tolerances
        .check()
        .map_err(|e| ApiError::BadRequest(e.to_string()))?;
    let (scene, submission, hint, scene_at) = match sent {
        Sent::Form(scene, submission, hint) => {
            let scene = scene::parse(&scene, limits)
                .map_err(|e| ApiError::scene(e, "the `scene` part", ""))?;
            (scene, submission, hint, "")
        }
        Sent::Json(scene, submission) => {
            let scene = scene::parse_value(scene, limits)
                .map_err(|e| ApiError::scene(e, "the `scene` part", "/scene"))?;
            let (submission, hint) =
                submission_member(submission).map_err(ApiError::InvalidSubmission)?;
            (scene, Bytes::from(submission), hint, "/scene")
        }
    };
    let hint = query.format.unwrap_or(hint);
    let submission = Submission::parse_for_frame(&submission, hint, scene.width, scene.height)
        .map_err(ApiError::InvalidSubmission)?;
    Ok(Prepared {
        scene: Arc::new(scene),
        submission,
        tolerances,
        scene_at,
    })
}

/// `what` (the body, a part) read strictly as one `T`. Bad syntax is 400 `invalid-json`
/// with where; a document of the wrong shape is 400 `bad-request` naming the field.
fn strict<T: serde::de::DeserializeOwned>(bytes: &[u8], what: &'static str) -> Result<T, ApiError> {
    json::from_slice(bytes).map_err(|f| {
        let message = f.message();
        if f.error.is_syntax() || f.error.is_eof() {
            ApiError::InvalidJson {
                what,
                message,
                line: f.error.line(),
                column: f.error.column(),
            }
        } else if let Some(path) = &f.path {
            ApiError::BadRequest(format!("{what}: `{path}`: {message}"))
        } else {
            ApiError::BadRequest(format!("{what}: {message}"))
        }
    })
}

/// The members that carry a submission file inside the JSON form, and its form.
const ENCODED: &[(&str, Hint)] = &submission::ENCODED_MEMBERS;

/// The submission of the JSON form as bytes and their form: hit data as JSON (an object
/// or an array), or `{"png_base64" | "npy_base64" | "csv" | "ndjson": "…"}`.
fn submission_member(v: Value) -> Result<(Vec<u8>, Hint), GradeError> {
    let bad = |at: &str, message: &str| {
        GradeError::Unreadable(ReadError::BadValue {
            at: at.to_owned(),
            message: message.to_owned(),
        })
    };
    let encoded = match &v {
        Value::Object(m) if m.len() == 1 => m.iter().next().and_then(|(k, val)| {
            ENCODED
                .iter()
                .find(|(name, _)| name == k)
                .map(|&(name, hint)| (name, hint, val))
        }),
        _ => None,
    };
    if let (None, Value::Object(m)) = (encoded, &v) {
        submission::check_submission_members(m)?;
    }
    match (encoded, &v) {
        (Some((name, hint, val)), _) => {
            let at = format!("submission.{name}");
            let Value::String(s) = val else {
                return Err(bad(&at, "must be a string"));
            };
            if name.ends_with("_base64") {
                // Tolerate the line breaks `base64` puts in by default.
                let compact: Vec<u8> = s.bytes().filter(|b| !b.is_ascii_whitespace()).collect();
                let bytes = base64::engine::general_purpose::STANDARD
                    .decode(&compact)
                    .map_err(|e| bad(&at, &format!("is not valid base64: {e}")))?;
                Ok((bytes, hint))
            } else {
                Ok((s.clone().into_bytes(), hint))
            }
        }
        (None, Value::Object(_) | Value::Array(_)) => serde_json::to_vec(&v)
            .map(|b| (b, Hint::Json))
            .map_err(|e| bad("submission", &e.to_string())),
        (None, _) => Err(bad(
            "submission",
            &format!("must be {}", submission::submission_members()),
        )),
    }
}

fn write_failed(e: serde_json::Error) -> ApiError {
    ApiError::Internal(format!("cannot write the report: {e}"))
}

/// `POST /v1/grade`.
async fn grade(
    State(app): State<AppState>,
    info: RequestInfo,
    query: GradeQuery,
    headers: HeaderMap,
    body: GradeBody,
) -> Result<Response, ApiError> {
    let answer = query.answer(&headers)?;
    let limits = app.config.limits();
    let deadline = tokio::time::Instant::from_std(info.start + app.config.deadline());
    let q = query.clone();
    let prepared = tokio::time::timeout_at(
        deadline,
        tokio::task::spawn_blocking(move || prepare(body, &q, &limits)),
    )
    .await
    .map_err(|_| deadline_exceeded(&app))?
    .map_err(|e| ApiError::Internal(format!("the parsing task failed: {e}")))??;

    let defaults = GradeOptions::default();
    let opts = GradeOptions {
        worst: query.worst.unwrap_or(defaults.worst),
        inline_diff: query.inline_diff.unwrap_or(defaults.inline_diff),
        flip: query.flip.unwrap_or(defaults.flip),
        ..defaults
    };
    let max_score = query.max_score.unwrap_or(1.0);
    let deadline_len = app.config.deadline();
    let (cost, metrics) = (CostLimit::new(&app.config), app.metrics.clone());
    let (bytes, pass) = job::run(&app, &info, "grade", move |cancel| {
        let Prepared {
            scene,
            submission,
            tolerances,
            scene_at,
        } = prepared;
        let r = Renderer::new(scene);
        let work = match submission {
            Submission::Image(_) => Work::Colour,
            Submission::Hits(_) => Work::Hits,
        };
        cost.check(&r, r.frame(), work, cancel, &metrics, scene_at)?;
        let opts = GradeOptions {
            cancel: cancel.clone(),
            ..opts
        };
        let report = grade::grade(&r, submission, &tolerances, &opts).map_err(|e| {
            cost.overrun(&r, work, cancel, scene_at)
                .unwrap_or_else(|| ApiError::grading(e, deadline_len))
        })?;
        let bytes = write_report(&report, answer, max_score).map_err(write_failed)?;
        Ok::<_, ApiError>((bytes, report.pass))
    })
    .await??;
    let verdict = HeaderValue::from_static(if pass { "pass" } else { "fail" });
    Ok((
        [
            (
                header::CONTENT_TYPE,
                HeaderValue::from_static(answer.content_type()),
            ),
            (X_RAYTILE_VERDICT, verdict),
        ],
        bytes,
    )
        .into_response())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_submission_form_comes_from_the_part() {
        assert_eq!(part_hint(Some("image/png"), Some("x.csv")), Hint::Png);
        assert_eq!(
            part_hint(Some("application/octet-stream"), Some("student.npy")),
            Hint::Npy
        );
        assert_eq!(part_hint(None, Some("hits.ndjson")), Hint::Ndjson);
        assert_eq!(part_hint(None, None), Hint::Auto);
        assert_eq!(part_hint(Some("text/plain"), Some("notes")), Hint::Auto);
    }

    #[test]
    fn json_submissions() {
        let (b, h) = submission_member(serde_json::json!({"png_base64": "iVBO\nRw=="})).unwrap();
        assert_eq!(
            (b.as_slice(), h),
            (&[0x89, b'P', b'N', b'G'][..], Hint::Png)
        );
        let (b, h) = submission_member(serde_json::json!({"csv": "u,v\n"})).unwrap();
        assert_eq!((b.as_slice(), h), (&b"u,v\n"[..], Hint::Csv));
        let (_, h) = submission_member(serde_json::json!([{"hit": false}])).unwrap();
        assert_eq!(h, Hint::Json);
        let (_, h) = submission_member(serde_json::json!({"pixels": []})).unwrap();
        assert_eq!(h, Hint::Json);
        assert!(matches!(
            submission_member(serde_json::json!({"png_base64": "!!"})),
            Err(GradeError::Unreadable(ReadError::BadValue { .. }))
        ));
        assert!(matches!(
            submission_member(serde_json::json!({"png_base64": 5})),
            Err(GradeError::Unreadable(ReadError::BadValue { .. }))
        ));
        assert!(matches!(
            submission_member(serde_json::json!("x")),
            Err(GradeError::Unreadable(ReadError::BadValue { .. }))
        ));
    }
}
