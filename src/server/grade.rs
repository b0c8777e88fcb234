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
//! `max_fail_share`, `lambda_rel`, `normal_degrees`, `linear_rel`, `linear_abs`,
//! `edge_forgiving`, each overriding
//! the body's `tolerances`), `worst`, `inline_diff`, `flip`, `format` (the submission's
//! form, overriding the part's), `report` (`json`, `text`, `gradescope`,
//! `prairielearn`), `max_score`, `visibility`, `stdout_visibility`, the scoring
//! (`scoring`, `zero_share`, `error_k`, `weight_*`), and `output=diff` for the
//! difference image as a PNG. A submission that cannot be graded is 422, except in the
//! grader forms: their ungradable results file, with `X-Raytile-Verdict: ungradable`.
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
use serde_json::value::RawValue;

use super::AppState;
use super::admission::CostLimit;
use super::error::ApiError;
use super::extract::{
    RequestInfo, blocking, charge_to, content_type, is_json, media_essence, negotiate, once,
    parse_choice, parse_flag, parse_param, query_pairs, read_charged,
};
use super::job;
use super::memory::{Charge, Reservation};
use crate::format::footprint::{self as decoding, Decoding, Family};
use crate::format::raster::RasterFormat;
use crate::format::{HitFormat, ReadError};
use crate::grade::answer::{ReportForm, write_report, write_ungradable};
use crate::grade::cache::{Kind, SceneKey};
use crate::grade::report::{LmsOptions, Visibility};
use crate::grade::score::ScoringMode;
use crate::grade::{
    self, GradeError, GradeOptions, Hint, Scoring, ScoringOverrides, Submission,
    ToleranceOverrides, Tolerances, submission,
};
use crate::json;
use crate::render::{Renderer, Work};
use crate::scene::footprint::{self as scene_footprint, JsonShape};
use crate::scene::{self, Problem, Scene};

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
    /// `scoring`, `zero_share`, `error_k`, `weight_hit_miss`, `weight_object`,
    /// `weight_lambda`, `weight_normal`.
    pub scoring: ScoringOverrides,
    /// Gradescope's `visibility` and `stdout_visibility`.
    pub visibility: Option<Visibility>,
    /// Gradescope's `stdout_visibility`.
    pub stdout_visibility: Option<Visibility>,
}

/// Reads one of the scoring and Gradescope parameters into `q`; `false` when `k` is
/// none of them.
fn scoring_param(q: &mut GradeQuery, k: &str, v: &str) -> Result<bool, ApiError> {
    let weight = |v: &str| parse_param::<f64>(k, v, "a number ≥ 0");
    let visibility = |v: &str| {
        Visibility::from_name(v).ok_or_else(|| {
            ApiError::BadRequest(format!(
                "query parameter `{k}` must be `hidden`, `after_due_date`, `after_published` \
                 or `visible`, not `{v}`"
            ))
        })
    };
    let s = &mut q.scoring;
    match k {
        "scoring" => {
            let m = ScoringMode::from_name(v).ok_or_else(|| {
                ApiError::BadRequest(format!(
                    "query parameter `scoring` must be `all-or-nothing`, `linear` or `error`, \
                     not `{v}`"
                ))
            })?;
            once(&mut s.scoring, k, m)?;
        }
        "zero_share" => once(&mut s.zero_share, k, parse_param(k, v, "a number")?)?,
        "error_k" => once(&mut s.error_k, k, parse_param(k, v, "a number")?)?,
        "weight_hit_miss" => once(&mut s.weight_hit_miss, k, weight(v)?)?,
        "weight_object" => once(&mut s.weight_object, k, weight(v)?)?,
        "weight_lambda" => once(&mut s.weight_lambda, k, weight(v)?)?,
        "weight_normal" => once(&mut s.weight_normal, k, weight(v)?)?,
        "visibility" => once(&mut q.visibility, k, visibility(v)?)?,
        "stdout_visibility" => once(&mut q.stdout_visibility, k, visibility(v)?)?,
        _ => return Ok(false),
    }
    Ok(true)
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
                "linear_rel" => once(&mut q.tolerances.linear_rel, k, parse_param(k, &v, number)?)?,
                "linear_abs" => once(&mut q.tolerances.linear_abs, k, parse_param(k, &v, number)?)?,
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
                            "query parameter `format` must be `auto`, `png`, `ppm`, `bmp`, `tga`, \
                             `jpeg`, `pfm`, `exr`, `json`, `ndjson`, `npy` or `csv`, not `{v}`"
                        ))
                    })?;
                    once(&mut q.format, k, h)?;
                }
                k if scoring_param(&mut q, k, &v)? => {}
                other => {
                    return Err(ApiError::BadRequest(format!(
                        "unknown query parameter `{other}`: this route takes `colour_abs`, \
                         `max_fail_share`, `lambda_rel`, `normal_degrees`, `linear_rel`, \
                         `linear_abs`, `edge_forgiving`, \
                         `worst`, `inline_diff`, `flip`, `format`, `report`, `max_score`, \
                         `visibility`, `stdout_visibility`, `scoring`, `zero_share`, \
                         `error_k`, `weight_hit_miss`, `weight_object`, `weight_lambda`, \
                         `weight_normal` and `output`"
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

/// The request body as read, before anything in it is parsed, with the memory it is
/// charged: the buffer and the copies parsing makes of its parts (three bodies' worth
/// at most: the parts or the envelope's members, and a decoded `png_base64`).
#[derive(Debug)]
pub struct GradeBody {
    /// The form it came in.
    pub sent: GradeForm,
    /// Its reservation in the memory budget.
    pub memory: Reservation,
}

/// The copies of the body grading holds at most while it reads it.
const BODY_COPIES: u64 = 3;

/// The request body's two forms.
#[derive(Debug, Clone)]
pub enum GradeForm {
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
        let (parts, bytes, memory) = read_charged(req, app, BODY_COPIES, "the body").await?;
        if !multipart {
            return Ok(GradeBody {
                sent: GradeForm::Json(bytes),
                memory,
            });
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
        Ok(GradeBody {
            sent: GradeForm::Form {
                scene,
                submission,
                hint,
                tolerances,
            },
            memory,
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
pub(super) fn part_hint(media_type: Option<&str>, file_name: Option<&str>) -> Hint {
    match media_type.map(Hint::from_media_type) {
        Some(h) if h != Hint::Auto => h,
        _ => file_name.map_or(Hint::Auto, |n| Hint::from_path(std::path::Path::new(n))),
    }
}

/// The JSON request form. The scene and the submission are kept as their text: the
/// scene is read by [`scene::parse`] like any other (strictly: a duplicated key is a
/// problem with its pointer), the submission by its reader, and neither becomes a JSON
/// tree, which would be tens of times the size of its text.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Envelope {
    scene: Box<RawValue>,
    submission: Box<RawValue>,
    #[serde(default)]
    tolerances: Option<Tolerances>,
}

/// The envelope as borrowed slices of the body, to find where its members lie.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct EnvelopeAt<'a> {
    #[serde(borrow)]
    scene: &'a RawValue,
    #[serde(borrow)]
    submission: &'a RawValue,
    #[serde(default, borrow)]
    tolerances: Option<&'a RawValue>,
}

/// A JSON form that is JSON only once Python's bare `NaN`, `Infinity` and `-Infinity`
/// are read as numbers, as `json.dumps` writes the hit data of a miss: its submission
/// keeps them (its reader accepts them), while the scene and the tolerances are taken
/// from the body as sent, so that a non-finite number there is still refused with its
/// position. None when that does not make the body an envelope either.
fn non_finite_envelope(bytes: &[u8]) -> Option<Envelope> {
    let quoted = json::quote_non_finite(bytes);
    if matches!(quoted, std::borrow::Cow::Borrowed(_)) {
        return None;
    }
    let text = std::str::from_utf8(&quoted).ok()?;
    let at: EnvelopeAt = serde_json::from_str(text).ok()?;
    // The stand-ins are as long as the words, so a member lies at the same bytes of
    // the body as sent.
    let original = |raw: &RawValue| -> Option<String> {
        let start = raw.get().as_ptr() as usize - text.as_ptr() as usize;
        let sent = bytes.get(start..start + raw.get().len())?;
        String::from_utf8(sent.to_vec()).ok()
    };
    let scene = RawValue::from_string(original(at.scene)?).ok()?;
    let tolerances = match at.tolerances {
        Some(t) => Some(serde_json::from_str(&original(t)?).ok()?),
        None => None,
    };
    let submission = RawValue::from_string(at.submission.get().to_owned()).ok()?;
    Some(Envelope {
        scene,
        submission,
        tolerances,
    })
}

/// The request's parts, split out and checked for structure, with what parsing them
/// will cost.
struct Split {
    scene: Bytes,
    submission: Bytes,
    hint: Hint,
    tolerances: Tolerances,
    /// Where the scene lies in the body, for the pointers of its problems.
    scene_at: &'static str,
    /// Where the submission lies, for the pointer of a refusal.
    submission_at: &'static str,
    /// The scene's text, pre-scanned.
    shape: JsonShape,
}

/// Everything grading needs, parsed and checked.
struct Prepared {
    scene: Arc<Scene>,
    submission: Submission,
    tolerances: Tolerances,
    /// Where the scene lies in the body, for the pointers of its problems.
    scene_at: &'static str,
}

/// The first step, in the order a client fixes things: the request's structure and the
/// tolerances (400: the JSON document or the form's parts, the query's tolerances on top
/// of the body's); then the scene's text is pre-scanned for the price of its parse.
/// CPU work proportional to the body: called off tokio's threads.
fn split(sent: GradeForm, query: &GradeQuery) -> Result<Split, ApiError> {
    let (scene, submission, hint, tolerances, scene_at, submission_at) = match sent {
        GradeForm::Form {
            scene,
            submission,
            hint,
            tolerances,
        } => {
            let tolerances = match tolerances {
                Some(b) => Some(strict::<Tolerances>(&b, "the `tolerances` part")?),
                None => None,
            };
            (scene, submission, hint, tolerances, "", "")
        }
        GradeForm::Json(bytes) => {
            let env: Envelope = match strict(&bytes, "the body") {
                Ok(env) => env,
                Err(e) => non_finite_envelope(&bytes).ok_or(e)?,
            };
            drop(bytes);
            let scene = Bytes::from(String::from(Box::<str>::from(env.scene)));
            let (submission, hint) =
                submission_member(env.submission).map_err(ApiError::InvalidSubmission)?;
            (
                scene,
                submission,
                hint,
                env.tolerances,
                "/scene",
                "/submission",
            )
        }
    };
    let tolerances = query.tolerances.apply(tolerances.unwrap_or_default());
    tolerances
        .check()
        .map_err(|e| ApiError::BadRequest(e.to_string()))?;
    let shape = JsonShape::scan(&scene);
    Ok(Split {
        scene,
        submission,
        hint: query.format.unwrap_or(hint),
        tolerances,
        scene_at,
        submission_at,
        shape,
    })
}

/// The family of the submission for the estimate of decoding, as its reader will tell
/// it: an image signature first, then the hint (`None`: told from the bytes).
pub(super) fn family(bytes: &[u8], hint: Hint) -> Option<Family> {
    if let Some(f) = RasterFormat::sniff(bytes) {
        return Some(Family::Image(f));
    }
    match hint {
        Hint::Json => Some(Family::Hits(HitFormat::Json)),
        Hint::Ndjson => Some(Family::Hits(HitFormat::Ndjson)),
        Hint::Npy => Some(Family::Hits(HitFormat::Npy)),
        Hint::Csv => Some(Family::Hits(HitFormat::Csv)),
        h => h.raster().map(Family::Image),
    }
}

/// What reading the submission for the scene's frame takes. Nothing much for a PNG of
/// another size, or one whose header cannot be read: its reader refuses it from the
/// header, with the grader's own error.
fn decoding_of(s: &Split, scene: &Scene) -> Decoding {
    decoding_for(&s.submission, s.hint, scene)
}

/// [`decoding_of`] for a submission's bytes and form.
pub(super) fn decoding_for(submission: &[u8], hint: Hint, scene: &Scene) -> Decoding {
    let nothing = Decoding { peak: 0, held: 0 };
    let family = family(submission, hint);
    if family == Some(Family::Image(RasterFormat::Png))
        && decoding::png_size(submission).ok() != Some((scene.width, scene.height))
    {
        return nothing;
    }
    decoding::submission(submission, family, (scene.width, scene.height)).unwrap_or(nothing)
}

/// The whole of grading, charged step by step to the request's `memory` before each
/// allocates: parsing the scene, then reading the submission with the reference and the
/// comparison (from the frame), then what is held while grading. Returns what grading
/// needs, `memory` holding what grading it takes.
async fn prepare(
    app: &AppState,
    body: GradeBody,
    query: &GradeQuery,
    deadline: tokio::time::Instant,
) -> Result<(Prepared, Reservation), ApiError> {
    let GradeBody { sent, mut memory } = body;
    let q = query.clone();
    let s = blocking(app, deadline, move || split(sent, &q)).await??;
    // The body's copies stay until the submission is read.
    let held = memory.bytes();
    let parse = Charge::fields(
        held + scene_footprint::parse_peak(&s.shape),
        "parsing the scene",
        scene_footprint::parse_fields(&s.shape),
    )
    .under(s.scene_at);
    charge_to(app, &mut memory, &parse, deadline).await?;
    let limits = app.config.limits();
    let (s, scene) = blocking(app, deadline, move || {
        let scene = scene::parse(&s.scene, &limits);
        (s, scene)
    })
    .await?;
    let scene = scene.map_err(|e| ApiError::scene(e, "the `scene` part", s.scene_at))?;
    let built = scene_footprint::built(&scene);
    let decode = decoding_of(&s, &scene);
    let image = matches!(family(&s.submission, s.hint), Some(Family::Image(_)));
    let pixels = scene.width as u64 * scene.height as u64;
    let diagnosed = pixels <= app.config.diagnosis_max_pixels;
    let grading = crate::grade::footprint::grading(scene.width, scene.height, image, diagnosed);
    let (w, h) = (scene.width, scene.height);
    let frame = |at: &str| {
        Problem::new(
            format!("{}/image/{at}", s.scene_at),
            format!("a frame of {w} × {h} pixels drives the memory its grading needs"),
        )
    };
    let reading = Charge::fields(
        held + built + decode.peak + grading,
        "grading the submission",
        vec![
            Problem::new(
                s.submission_at,
                format!(
                    "reading it takes up to {} bytes, before the reference and the comparison",
                    decode.peak
                ),
            ),
            frame("width"),
            frame("height"),
        ],
    );
    charge_to(app, &mut memory, &reading, deadline).await?;
    let Split {
        submission,
        hint,
        tolerances,
        scene_at,
        ..
    } = s;
    let submission = blocking(app, deadline, move || {
        Submission::parse_for_frame(&submission, hint, w, h)
    })
    .await?
    .map_err(ApiError::InvalidSubmission)?;
    // The body is gone; the submission is read.
    memory.shrink_to(built + decode.held + grading);
    Ok((
        Prepared {
            scene: Arc::new(scene),
            submission,
            tolerances,
            scene_at,
        },
        memory,
    ))
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
/// or an array, its text as sent), or `{"png_base64" | "npy_base64" | "csv" | "ndjson":
/// "…"}`.
fn submission_member(raw: Box<RawValue>) -> Result<(Bytes, Hint), GradeError> {
    let bad = |at: &str, message: &str| {
        GradeError::Unreadable(ReadError::BadValue {
            at: at.to_owned(),
            message: message.to_owned(),
        })
    };
    let text = raw.get();
    let encoded = if text.starts_with('{') {
        // The members as slices of the text: nothing of a large document is copied.
        let members = serde_json::from_str::<std::collections::BTreeMap<&str, &RawValue>>(text)
            .unwrap_or_default();
        let one = (members.len() == 1)
            .then(|| members.iter().next())
            .flatten()
            .and_then(|(&k, &v)| {
                let &(name, hint) = ENCODED.iter().find(|(name, _)| *name == k)?;
                Some((name, hint, v))
            });
        if one.is_none() {
            submission::check_submission_members(members.keys().copied())?;
        }
        one
    } else {
        None
    };
    if let Some((name, hint, val)) = encoded {
        let at = format!("submission.{name}");
        let s: String =
            serde_json::from_str(val.get()).map_err(|_| bad(&at, "must be a string"))?;
        if name.ends_with("_base64") {
            // Tolerate the line breaks `base64` puts in by default.
            let compact: Vec<u8> = s.bytes().filter(|b| !b.is_ascii_whitespace()).collect();
            drop(s);
            let bytes = base64::engine::general_purpose::STANDARD
                .decode(&compact)
                .map_err(|e| bad(&at, &format!("is not valid base64: {e}")))?;
            return Ok((Bytes::from(bytes), hint));
        }
        return Ok((Bytes::from(s), hint));
    }
    if text.starts_with('{') || text.starts_with('[') {
        return Ok((Bytes::from(String::from(Box::<str>::from(raw))), Hint::Json));
    }
    Err(bad(
        "submission",
        &format!("must be {}", submission::submission_members()),
    ))
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
    let deadline = tokio::time::Instant::from_std(info.start + app.config.deadline());
    let lms = lms_options(&query);
    let (prepared, memory) = match prepare(&app, body, &query, deadline).await {
        Err(ApiError::InvalidSubmission(e)) if answer.is_lms() => {
            return ungradable_answer(&e, answer, &lms);
        }
        other => other?,
    };
    let scoring = query.scoring.apply(Scoring::default());
    scoring
        .check(&prepared.tolerances)
        .map_err(|e| ApiError::BadRequest(e.to_string()))?;

    let defaults = GradeOptions::default();
    let opts = GradeOptions {
        worst: query.worst.unwrap_or(defaults.worst),
        inline_diff: query.inline_diff.unwrap_or(defaults.inline_diff),
        flip: query.flip.unwrap_or(defaults.flip),
        scoring,
        diagnosis: grade::diagnose::Settings {
            max_pixels: app.config.diagnosis_max_pixels,
            ..defaults.diagnosis
        },
        references: Some(app.references.clone()),
        ..defaults
    };
    // Concurrent grades of one scene render its reference once: the others wait here,
    // off the trace threads, and then find it cached. Hashing a large document takes a
    // while: not on tokio's threads either.
    let scene = prepared.scene.clone();
    let kind = Kind::of(&prepared.submission);
    let wants: Vec<_> = blocking(&app, deadline, move || SceneKey::of(&scene))
        .await?
        .map(|k| (k, kind))
        .into_iter()
        .collect();
    let turn = tokio::time::timeout_at(deadline, app.references.turn(&wants))
        .await
        .map_err(|_| super::extract::deadline_exceeded(&app))?;
    let deadline_len = app.config.deadline();
    let (cost, metrics) = (CostLimit::new(&app.config), app.metrics.clone());
    let (bytes, verdict) = job::run(&app, &info, "grade", move |cancel| {
        // Given back when the work ends, as is the turn.
        let _memory = memory;
        let _turn = turn;
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
        let report = match grade::grade(&r, submission, &tolerances, &opts) {
            Ok(report) => report,
            Err(e) if answer.is_lms() && e.is_submissions_fault() => {
                let bytes = write_ungradable(&e.to_string(), answer, &lms).map_err(write_failed)?;
                return Ok((bytes.unwrap_or_default(), "ungradable"));
            }
            Err(e) => {
                return Err(cost
                    .overrun(&r, work, cancel, scene_at)
                    .unwrap_or_else(|| ApiError::grading(e, deadline_len)));
            }
        };
        let bytes = write_report(&report, answer, &lms).map_err(write_failed)?;
        Ok::<_, ApiError>((bytes, if report.pass { "pass" } else { "fail" }))
    })
    .await??;
    Ok(graded_response(answer, bytes, verdict))
}

/// Gradescope's points and visibilities from the query.
fn lms_options(q: &GradeQuery) -> LmsOptions {
    let d = LmsOptions::default();
    LmsOptions {
        max_score: q.max_score.unwrap_or(d.max_score),
        visibility: q.visibility.unwrap_or(d.visibility),
        stdout_visibility: q.stdout_visibility.unwrap_or(d.stdout_visibility),
    }
}

/// A graded answer: `answer`'s media type and the verdict header.
fn graded_response(answer: ReportForm, bytes: Vec<u8>, verdict: &'static str) -> Response {
    (
        [
            (
                header::CONTENT_TYPE,
                HeaderValue::from_static(answer.content_type()),
            ),
            (X_RAYTILE_VERDICT, HeaderValue::from_static(verdict)),
        ],
        bytes,
    )
        .into_response()
}

/// A grader form's results file for a submission that cannot be graded (200, verdict
/// `ungradable`), as `raytile grade` writes it.
fn ungradable_answer(
    e: &GradeError,
    answer: ReportForm,
    lms: &LmsOptions,
) -> Result<Response, ApiError> {
    let bytes = write_ungradable(&e.to_string(), answer, lms)
        .map_err(write_failed)?
        .unwrap_or_default();
    Ok(graded_response(answer, bytes, "ungradable"))
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

    fn member(text: &str) -> Result<(Bytes, Hint), GradeError> {
        submission_member(RawValue::from_string(text.to_owned()).unwrap())
    }

    #[test]
    fn json_submissions() {
        let (b, h) = member(r#"{"png_base64": "iVBO\nRw=="}"#).unwrap();
        assert_eq!((&b[..], h), (&[0x89, b'P', b'N', b'G'][..], Hint::Png));
        let (b, h) = member(r#"{"csv": "u,v\n"}"#).unwrap();
        assert_eq!((&b[..], h), (&b"u,v\n"[..], Hint::Csv));
        let (b, h) = member(r#"[{"hit": false}]"#).unwrap();
        assert_eq!((&b[..], h), (&br#"[{"hit": false}]"#[..], Hint::Json));
        let (_, h) = member(r#"{"pixels": []}"#).unwrap();
        assert_eq!(h, Hint::Json);
        for bad in [r#"{"png_base64": "!!"}"#, r#"{"png_base64": 5}"#, r#""x""#] {
            assert!(
                matches!(
                    member(bad),
                    Err(GradeError::Unreadable(ReadError::BadValue { .. }))
                ),
                "{bad}"
            );
        }
    }
}
