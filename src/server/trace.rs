//! `POST /v1/trace?u=U&v=V`: the scene in the body, and out the ray tree of pixel
//! `(u, v)` with every intermediate value of the lecture's computation
//! ([`crate::grade::explain()`]), the same as `raytile trace --pixel U,V`.
//!
//! ```text
//! POST /v1/trace?u=2&v=2                  → application/json (the default)
//! POST /v1/trace?u=2&v=2&format=text      → text/plain; charset=utf-8
//! POST /v1/trace?u=2&v=2  Accept: text/plain   → the same text
//! ```
//!
//! Query: `u`, `v` (required: column and row from the top left), `format` (`json` or
//! `text`; without it `Accept` decides, JSON first), `candidates` (`auto`, `all`, `bvh`),
//! `max_tests`, `max_triangles`, `max_rays`, as on the command line. Any other parameter
//! is an error. The answer is bounded whatever they are (see
//! [`explain::MAX_ANSWER_BYTES`]): what it leaves out it counts, under `truncation`.
//!
//! Everything that can fail is decided before a render slot is taken: the query (400),
//! the scene (415, 413, 400, 422, as for `/v1/render`), a pixel outside the image (422,
//! `pixel-outside-image`). Then building the BVH and explaining, CPU work, run on the
//! rayon pool under the same admission as renders ([`super::job`]). The answer is the
//! bytes `raytile trace` prints, from the same function
//! ([`crate::grade::answer::write_explanation`]).

use axum::Router;
use axum::extract::{FromRequestParts, State};
use axum::http::request::Parts;
use axum::http::{HeaderMap, HeaderValue, header};
use axum::response::{IntoResponse, Response};
use axum::routing::post;

use super::AppState;
use super::error::ApiError;
use super::extract::{
    RequestInfo, SceneBody, negotiate, once, parse_choice, parse_param, query_pairs,
};
use super::job;
use crate::grade::answer::{ExplanationForm, write_explanation};
use crate::grade::explain::{self, Candidates, ExplainError, ExplainOptions};
use crate::render::Renderer;

/// The routes: `POST /v1/trace`.
pub fn router() -> Router<AppState> {
    Router::new().route("/v1/trace", post(trace))
}

/// What `/v1/trace` answers with, the default first (`text/plain` is sent with
/// `; charset=utf-8`).
pub const TRACE_TYPES: &[&str] = &["application/json", "text/plain"];

/// Largest `max_rays`, `max_tests` and `max_triangles` a request may ask for: an
/// explanation grows
/// with both, and it is built in memory before it is sent.
pub const MAX_LISTED: usize = 1024;

/// With `candidates=all`, at most this many object tests (objects × rays broken down)
/// may be listed; past it the request is refused (400) with a pointer to `bvh`, rather
/// than building an answer of gigabytes for a scene of a million objects.
pub const MAX_ALL_TESTS: usize = 65_536;

/// `?u=U&v=V[&format=json|text][&candidates=auto|all|bvh][&max_tests=N][&max_triangles=N][&max_rays=N]`.
#[derive(Debug, Clone)]
pub struct TraceQuery {
    /// Column.
    pub u: u32,
    /// Row.
    pub v: u32,
    /// `format=text` or `format=json`; `None` to let `Accept` decide.
    pub form: Option<ExplanationForm>,
    /// What to list.
    pub options: ExplainOptions,
}

impl<S: Send + Sync> FromRequestParts<S> for TraceQuery {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, ApiError> {
        let (mut u, mut v, mut form, mut candidates) = (None, None, None, None);
        let (mut max_tests, mut max_triangles, mut max_rays) = (None, None, None);
        let whole = "a whole number ≥ 0";
        for (k, value) in query_pairs(&parts.uri)? {
            match k.as_str() {
                "u" => once(&mut u, "u", parse_param::<u32>("u", &value, whole)?)?,
                "v" => once(&mut v, "v", parse_param::<u32>("v", &value, whole)?)?,
                "format" => {
                    let f = parse_choice(
                        "format",
                        &value,
                        &[
                            ("json", ExplanationForm::Json),
                            ("text", ExplanationForm::Text),
                        ],
                    )?;
                    once(&mut form, "format", f)?;
                }
                "candidates" => {
                    let c = parse_choice(
                        "candidates",
                        &value,
                        &[
                            ("auto", Candidates::Auto),
                            ("all", Candidates::All),
                            ("bvh", Candidates::Bvh),
                        ],
                    )?;
                    once(&mut candidates, "candidates", c)?;
                }
                "max_tests" => once(&mut max_tests, "max_tests", listed("max_tests", &value)?)?,
                "max_triangles" => once(
                    &mut max_triangles,
                    "max_triangles",
                    listed("max_triangles", &value)?,
                )?,
                "max_rays" => once(&mut max_rays, "max_rays", listed("max_rays", &value)?)?,
                other => {
                    return Err(ApiError::BadRequest(format!(
                        "unknown query parameter `{other}`: this route takes `u`, `v`, `format`, \
                         `candidates`, `max_tests`, `max_triangles` and `max_rays`"
                    )));
                }
            }
        }
        let required = |name: &str| {
            ApiError::BadRequest(format!(
                "query parameter `{name}` is required: the pixel to explain is `?u=COLUMN&v=ROW`"
            ))
        };
        let defaults = ExplainOptions::default();
        Ok(TraceQuery {
            u: u.ok_or_else(|| required("u"))?,
            v: v.ok_or_else(|| required("v"))?,
            form,
            options: ExplainOptions {
                candidates: candidates.unwrap_or(defaults.candidates),
                max_tests: max_tests.unwrap_or(defaults.max_tests),
                max_triangles: max_triangles.unwrap_or(defaults.max_triangles),
                max_rays: max_rays.unwrap_or(defaults.max_rays),
            },
        })
    }
}

/// A count of listed items, at most [`MAX_LISTED`].
fn listed(name: &str, value: &str) -> Result<usize, ApiError> {
    let n: usize = parse_param(name, value, "a whole number ≥ 0")?;
    if n > MAX_LISTED {
        return Err(ApiError::BadRequest(format!(
            "query parameter `{name}` may be at most {MAX_LISTED}, not {n}"
        )));
    }
    Ok(n)
}

/// `POST /v1/trace`.
async fn trace(
    State(app): State<AppState>,
    info: RequestInfo,
    query: TraceQuery,
    headers: HeaderMap,
    body: SceneBody,
) -> Result<Response, ApiError> {
    let form = match query.form {
        // An explicit format still has to be acceptable to the client.
        Some(ExplanationForm::Text) => {
            negotiate(&headers, &["text/plain"]).map(|_| ExplanationForm::Text)?
        }
        Some(ExplanationForm::Json) => {
            negotiate(&headers, &["application/json"]).map(|_| ExplanationForm::Json)?
        }
        None => match negotiate(&headers, TRACE_TYPES)? {
            "text/plain" => ExplanationForm::Text,
            _ => ExplanationForm::Json,
        },
    };
    let scene = body.scene;
    let (u, v) = (query.u, query.v);
    // The check `explain::check_pixel` makes, made before a slot is taken and without
    // building the BVH it needs a renderer for.
    if u >= scene.width || v >= scene.height {
        return Err(ApiError::PixelOutside(ExplainError::OutsideImage {
            u,
            v,
            width: scene.width,
            height: scene.height,
        }));
    }
    let objects = scene.objects.len();
    let listing_all = query.options.candidates == Candidates::All
        || (query.options.candidates == Candidates::Auto
            && objects <= explain::AUTO_ALL_MAX_OBJECTS);
    let rays = query.options.max_rays.max(1);
    if listing_all && objects.saturating_mul(rays) > MAX_ALL_TESTS {
        return Err(ApiError::BadRequest(format!(
            "`candidates=all` would list each of the scene's {objects} objects for each of up \
             to {rays} rays, more than the {MAX_ALL_TESTS} tests an answer may list: use \
             `candidates=bvh`, or fewer `max_rays`"
        )));
    }
    let options = query.options;
    let answer = job::run(
        &app,
        &info,
        "trace",
        move |_| -> Result<Vec<u8>, ApiError> {
            let r = Renderer::new(scene);
            explain::check_pixel(&r, u, v).map_err(ApiError::PixelOutside)?;
            let e = explain::explain(&r, u, v, &options);
            write_explanation(&e, form)
                .map_err(|e| ApiError::Internal(format!("cannot write the explanation: {e}")))
        },
    )
    .await??;
    Ok((
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static(form.content_type()),
        )],
        answer,
    )
        .into_response())
}
