//! What the handlers take from a request, each refusing in our own error format:
//!
//! - [`RequestInfo`]: the request id and arrival time (set by [`super::observe`]), from
//!   which the deadline counts;
//! - [`RegionQuery`]: `?region=x,y,w,h`, and nothing else;
//! - [`Accepted`]: the media type to answer with, from `Accept` (406 when none fits),
//!   decided by [`negotiate`] before the body is read;
//! - [`SceneBody`]: the body as a validated scene: `Content-Type` first (415), then the
//!   size limit (413), then JSON syntax (400 with line and column), then the scene's
//!   meaning and the server's limits (422 with every problem). All of it before
//!   admission, so a bad request never takes a render slot; but each step is charged
//!   to the memory budget before it allocates ([`super::memory`]): the body by its
//!   `Content-Length`, the parse by a pre-scan of the text, and the scene it holds by
//!   its counts;
//! - the pieces other extractors are made of: [`query_pairs`] and the parsers of single
//!   parameters, [`media_essence`], [`read_limited`] (the body behind the size limit and
//!   the deadline), [`read_charged`] (the same, charged to the memory budget first),
//!   [`charge_to`], [`deadline_of`].

use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::body::{Body, Bytes};
use axum::extract::{FromRequest, FromRequestParts, Query, Request};
use axum::http::request::Parts;
use axum::http::{HeaderMap, Uri, header};

use super::AppState;
use super::error::ApiError;
use super::memory::{Charge, Reservation};
use crate::render::{Rect, region_in_frame};
use crate::scene::footprint::{self, JsonShape};
use crate::scene::{self, Scene};

/// The request's id and when it arrived.
#[derive(Debug, Clone)]
pub struct RequestInfo {
    /// The `X-Request-Id` (the client's, or one we made).
    pub id: String,
    /// When the request arrived.
    pub start: Instant,
}

impl<S: Send + Sync> FromRequestParts<S> for RequestInfo {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, ApiError> {
        // Set by the observing middleware; without it (a router used bare) start now.
        Ok(parts
            .extensions
            .get::<RequestInfo>()
            .cloned()
            .unwrap_or_else(|| RequestInfo {
                id: String::new(),
                start: Instant::now(),
            }))
    }
}

/// `?region=x,y,w,h`: a rectangle of the full frame, or the whole frame.
#[derive(Debug, Clone, Copy, Default)]
pub struct RegionQuery {
    /// The rectangle asked for, if any.
    pub region: Option<Rect>,
}

impl<S: Send + Sync> FromRequestParts<S> for RegionQuery {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, ApiError> {
        let mut q = RegionQuery::default();
        for (k, v) in query_pairs(&parts.uri)? {
            match k.as_str() {
                "region" if q.region.is_none() => {
                    q.region = Some(v.parse::<Rect>().map_err(|e| {
                        ApiError::BadRequest(format!("query parameter `region`: {e}"))
                    })?);
                }
                "region" => {
                    return Err(ApiError::BadRequest(
                        "query parameter `region` is given more than once".into(),
                    ));
                }
                other => {
                    return Err(ApiError::BadRequest(format!(
                        "unknown query parameter `{other}`: this route takes only `region`"
                    )));
                }
            }
        }
        Ok(q)
    }
}

/// The query string as `(name, value)` pairs, percent-decoded, in order.
pub fn query_pairs(uri: &Uri) -> Result<Vec<(String, String)>, ApiError> {
    let Query(pairs) = Query::<Vec<(String, String)>>::try_from_uri(uri)
        .map_err(|e| ApiError::BadRequest(format!("cannot read the query string: {e}")))?;
    Ok(pairs)
}

/// Sets `slot` from query parameter `name` once; a second value is an error (which one
/// the client meant is not ours to guess).
pub fn once<T>(slot: &mut Option<T>, name: &str, value: T) -> Result<(), ApiError> {
    if slot.is_some() {
        return Err(ApiError::BadRequest(format!(
            "query parameter `{name}` is given more than once"
        )));
    }
    *slot = Some(value);
    Ok(())
}

/// Parses query parameter `name` (a number); the error names the parameter and what it
/// must be.
pub fn parse_param<T: std::str::FromStr>(
    name: &str,
    value: &str,
    what: &str,
) -> Result<T, ApiError> {
    value.trim().parse().map_err(|_| {
        ApiError::BadRequest(format!(
            "query parameter `{name}` must be {what}, not `{value}`"
        ))
    })
}

/// Parses a boolean query parameter: `true` or `false` (also `1`, `0`); the bare name
/// (`?edge_forgiving`) means true.
pub fn parse_flag(name: &str, value: &str) -> Result<bool, ApiError> {
    match value.trim().to_ascii_lowercase().as_str() {
        "" | "true" | "1" => Ok(true),
        "false" | "0" => Ok(false),
        _ => Err(ApiError::BadRequest(format!(
            "query parameter `{name}` must be `true` or `false`, not `{value}`"
        ))),
    }
}

/// Parses a query parameter that is one of a few words, each standing for a value; the
/// error lists the words.
pub fn parse_choice<T: Copy>(
    name: &str,
    value: &str,
    choices: &[(&str, T)],
) -> Result<T, ApiError> {
    if let Some(&(_, t)) = choices.iter().find(|(word, _)| *word == value) {
        return Ok(t);
    }
    let words: Vec<String> = choices.iter().map(|(w, _)| format!("`{w}`")).collect();
    let listed = match words.split_last() {
        Some((last, [])) => last.clone(),
        Some((last, rest)) => format!("{} or {last}", rest.join(", ")),
        None => String::new(),
    };
    Err(ApiError::BadRequest(format!(
        "query parameter `{name}` must be {listed}, not `{value}`"
    )))
}

impl RegionQuery {
    /// The region within `scene`'s frame (the whole frame by default).
    pub fn within(&self, scene: &Scene) -> Result<Rect, ApiError> {
        region_in_frame(self.region, scene.width, scene.height)
            .map_err(|e| ApiError::BadRequest(e.to_string()))
    }
}

/// The media types a route can answer with, in order of preference.
pub trait Offers: Send + Sync {
    /// The media types, the default first.
    const OFFERS: &'static [&'static str];
}

/// The media type chosen from `O::OFFERS` by the request's `Accept`.
#[derive(Debug, Clone, Copy)]
pub struct Accepted<O>(pub &'static str, pub std::marker::PhantomData<O>);

impl<S: Send + Sync, O: Offers> FromRequestParts<S> for Accepted<O> {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, ApiError> {
        negotiate(&parts.headers, O::OFFERS).map(|m| Accepted(m, std::marker::PhantomData))
    }
}

/// Routes that answer with JSON only.
#[derive(Debug, Clone, Copy)]
pub struct JsonOnly;

impl Offers for JsonOnly {
    const OFFERS: &'static [&'static str] = &["application/json"];
}

/// Picks what to answer with from `offers` (in order of preference) by the request's
/// `Accept` (RFC 9110 §12.5.1): the most specific matching range sets an offer's
/// quality; the best quality wins, ties go to the earlier offer; no header, the first.
pub fn negotiate(
    headers: &HeaderMap,
    offers: &'static [&'static str],
) -> Result<&'static str, ApiError> {
    let accept: Vec<&str> = headers
        .get_all(header::ACCEPT)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .collect();
    let not_acceptable = || ApiError::NotAcceptable {
        accept: accept.join(", "),
        supported: offers,
    };
    if accept.is_empty() {
        return offers.first().copied().ok_or_else(not_acceptable);
    }
    let ranges: Vec<(String, f32)> = accept
        .iter()
        .flat_map(|v| v.split(','))
        .filter_map(|r| {
            let mut parts = r.split(';');
            let range = parts.next()?.trim().to_ascii_lowercase();
            if range.is_empty() {
                return None;
            }
            let q = parts
                .filter_map(|p| p.trim().strip_prefix("q=").or(p.trim().strip_prefix("Q=")))
                .find_map(|q| q.trim().parse::<f32>().ok())
                .unwrap_or(1.0);
            Some((range, q))
        })
        .collect();
    let quality = |offer: &str| -> f32 {
        let (ty, _) = offer.split_once('/').unwrap_or((offer, ""));
        let mut best: Option<(u8, f32)> = None;
        for (range, q) in &ranges {
            let specificity = if range == offer {
                3
            } else if range.strip_suffix("/*") == Some(ty) {
                2
            } else if range == "*/*" || range == "*" {
                1
            } else {
                continue;
            };
            if best.is_none_or(|(s, _)| specificity > s) {
                best = Some((specificity, *q));
            }
        }
        best.map_or(0.0, |(_, q)| q)
    };
    let mut chosen: Option<(&'static str, f32)> = None;
    for offer in offers {
        let q = quality(offer);
        if q > 0.0 && chosen.is_none_or(|(_, best)| q > best) {
            chosen = Some((offer, q));
        }
    }
    chosen.map(|(o, _)| o).ok_or_else(not_acceptable)
}

/// The media type without parameters, lower case: `multipart/form-data; boundary=x` →
/// `multipart/form-data`.
pub fn media_essence(content_type: &str) -> String {
    content_type
        .split(';')
        .next()
        .unwrap_or("")
        .trim()
        .to_ascii_lowercase()
}

/// The request's `Content-Type` (empty when missing).
pub fn content_type(headers: &HeaderMap) -> String {
    headers
        .get(header::CONTENT_TYPE)
        .map(|v| String::from_utf8_lossy(v.as_bytes()).into_owned())
        .unwrap_or_default()
}

/// Whether `Content-Type` says JSON: `application/json` or any `application/…+json`,
/// with any parameters (`; charset=utf-8`).
pub fn is_json(content_type: &str) -> bool {
    let essence = media_essence(content_type);
    essence == "application/json"
        || (essence.starts_with("application/") && essence.ends_with("+json"))
}

/// The body, read and validated into a scene.
#[derive(Debug)]
pub struct SceneBody {
    /// The scene.
    pub scene: Arc<Scene>,
    /// Time spent reading and validating the body.
    pub parse: Duration,
    /// What the scene holds, reserved in the memory budget ([`footprint::built`]):
    /// whoever keeps the scene keeps this too, and grows it for what they add.
    pub memory: Reservation,
}

impl FromRequest<AppState> for SceneBody {
    type Rejection = ApiError;

    async fn from_request(req: Request, app: &AppState) -> Result<Self, ApiError> {
        let deadline = deadline_of(&req, app);
        let content_type = content_type(req.headers());
        if !is_json(&content_type) {
            return Err(ApiError::UnsupportedMediaType {
                got: content_type,
                supported: &["application/json"],
            });
        }
        let t = Instant::now();
        let (_, bytes, mut memory) = read_charged(req, app, 1, "the body").await?;
        let (bytes, scene) = parse_charged(app, bytes, &mut memory, "", deadline).await?;
        drop(bytes);
        let scene = scene.map_err(ApiError::from)?;
        let held = Charge::fields(
            footprint::built(&scene),
            "the scene",
            footprint::built_fields(&scene),
        );
        charge_to(app, &mut memory, &held, deadline).await?;
        Ok(SceneBody {
            scene: Arc::new(scene),
            parse: t.elapsed(),
            memory,
        })
    }
}

/// Parses and validates the scene `text` against the server's limits, charged first to
/// `memory` (which holds the text already): a pre-scan of the text prices the parse
/// ([`footprint::parse_peak`]; the fields that drive it under `scene_at`). Both run off
/// tokio's threads: they are CPU work proportional to the text (16 MiB of mesh takes a
/// while). Gives the text back with the outcome; `memory` then holds the text and the
/// parse's peak, to be resized by the caller.
pub async fn parse_charged(
    app: &AppState,
    text: Bytes,
    memory: &mut Reservation,
    scene_at: &str,
    deadline: tokio::time::Instant,
) -> Result<(Bytes, Result<Scene, scene::SceneError>), ApiError> {
    let (text, shape) = blocking(app, deadline, move || {
        let shape = JsonShape::scan(&text);
        (text, shape)
    })
    .await?;
    let parse = Charge::fields(
        text.len() as u64 + footprint::parse_peak(&shape),
        "parsing the scene",
        footprint::parse_fields(&shape),
    )
    .under(scene_at);
    charge_to(app, memory, &parse, deadline).await?;
    let limits = app.config.limits();
    blocking(app, deadline, move || {
        let scene = scene::parse(&text, &limits);
        (text, scene)
    })
    .await
}

/// Runs `f` on tokio's blocking threads, within the deadline.
pub async fn blocking<T: Send + 'static>(
    app: &AppState,
    deadline: tokio::time::Instant,
    f: impl FnOnce() -> T + Send + 'static,
) -> Result<T, ApiError> {
    tokio::time::timeout_at(deadline, tokio::task::spawn_blocking(f))
        .await
        .map_err(|_| deadline_exceeded(app))?
        .map_err(|e| ApiError::Internal(format!("the parsing task failed: {e}")))
}

/// Makes `memory` hold `charge` in all, waiting for the budget within the deadline
/// (see [`super::memory::MemoryBudget::resize`]).
pub async fn charge_to(
    app: &AppState,
    memory: &mut Reservation,
    charge: &Charge,
    deadline: tokio::time::Instant,
) -> Result<(), ApiError> {
    tokio::time::timeout_at(deadline, app.memory.resize(memory, charge, &app.shutdown))
        .await
        .map_err(|_| deadline_exceeded(app))?
}

/// When the request must have its answer: its arrival plus the server's deadline.
pub fn deadline_of(req: &Request, app: &AppState) -> tokio::time::Instant {
    let start = req
        .extensions()
        .get::<RequestInfo>()
        .map_or_else(Instant::now, |i| i.start);
    tokio::time::Instant::from_std(start + app.config.deadline())
}

/// Reads the whole body behind `--max-body-bytes` and the request's deadline: 413 when
/// `Content-Length` declares more than the limit (the body is then read and dropped, see
/// `DISCARD_BYTES`), or as soon as more arrives; 504 when the deadline passes while it
/// arrives.
pub async fn read_limited(req: Request, app: &AppState) -> Result<(Parts, Bytes), ApiError> {
    let deadline = deadline_of(&req, app);
    let limit = app.config.max_body_bytes;
    let declared = declared_length(req.headers());
    let (parts, body) = req.into_parts();
    if let Some(n) = declared.filter(|&n| n > limit as u64) {
        // Refuse without keeping a byte of it.
        if n <= DISCARD_BYTES {
            discard(body, deadline).await;
        }
        return Err(ApiError::BodyTooLarge { limit_bytes: limit });
    }
    let bytes = read_body(body, limit, deadline, app).await?;
    Ok((parts, bytes))
}

/// [`read_limited`], charged first to the memory budget: `copies` × the body's declared
/// length (the body limit when it declares none), for the buffer and the copies the
/// route makes of it while it parses; `what` names it in a refusal. The reservation
/// is cut down to what arrived, and returned to be grown by what follows.
pub async fn read_charged(
    req: Request,
    app: &AppState,
    copies: u64,
    what: &str,
) -> Result<(Parts, Bytes, Reservation), ApiError> {
    let deadline = deadline_of(&req, app);
    let limit = app.config.max_body_bytes as u64;
    let size = declared_length(req.headers()).map_or(limit, |n| n.min(limit));
    let mut memory = app.memory.empty();
    charge_to(
        app,
        &mut memory,
        &Charge::body(size * copies, what),
        deadline,
    )
    .await?;
    let (parts, bytes) = read_limited(req, app).await?;
    memory.shrink_to(bytes.len() as u64 * copies);
    Ok((parts, bytes, memory))
}

/// The body's `Content-Length`, if it declares one.
fn declared_length(headers: &HeaderMap) -> Option<u64> {
    headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<u64>().ok())
}

/// How much of a body declared too large is still read, and dropped, before the 413.
/// Most HTTP clients write the whole body before they read the answer; closing on unread
/// bytes resets the connection, and they would report a broken pipe instead of the 413.
/// A larger body is cut off unread.
const DISCARD_BYTES: u64 = 64 << 20;

/// How long reading a refused body may take at most.
const DISCARD_TIME: Duration = Duration::from_secs(2);

/// Reads `body` to its end, keeping nothing, for at most [`DISCARD_TIME`] (and not past
/// the deadline).
async fn discard(mut body: Body, deadline: tokio::time::Instant) {
    use http_body_util::BodyExt;
    let until = deadline.min(tokio::time::Instant::now() + DISCARD_TIME);
    let drain = async {
        let mut read = 0u64;
        while let Some(Ok(frame)) = body.frame().await {
            read += frame.data_ref().map_or(0, |d| d.len() as u64);
            if read > DISCARD_BYTES {
                break;
            }
        }
    };
    let _ = tokio::time::timeout_at(until, drain).await;
}

/// Counts and builds the 504 of a request whose deadline passed before its answer began.
pub fn deadline_exceeded(app: &AppState) -> ApiError {
    app.metrics.reject("deadline");
    ApiError::DeadlineExceeded(app.config.deadline())
}

async fn read_body(
    body: Body,
    limit: usize,
    deadline: tokio::time::Instant,
    app: &AppState,
) -> Result<Bytes, ApiError> {
    match tokio::time::timeout_at(deadline, axum::body::to_bytes(body, limit)).await {
        Err(_) => Err(deadline_exceeded(app)),
        Ok(Ok(b)) => Ok(b),
        Ok(Err(e)) => {
            let too_large =
                std::iter::successors(Some(&e as &(dyn std::error::Error + 'static)), |e| {
                    e.source()
                })
                .any(|e| e.is::<http_body_util::LengthLimitError>());
            if too_large {
                Err(ApiError::BodyTooLarge { limit_bytes: limit })
            } else {
                Err(ApiError::BadRequest(format!("cannot read the body: {e}")))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::http::HeaderValue;

    #[test]
    fn a_choice_maps_its_words_and_lists_them_when_none_fits() {
        let formats = [("json", false), ("text", true)];
        assert!(matches!(parse_choice("format", "text", &formats), Ok(true)));
        let three = [("auto", 0), ("all", 1), ("bvh", 2)];
        assert!(matches!(parse_choice("candidates", "all", &three), Ok(1)));
        fn message<T: std::fmt::Debug>(r: Result<T, ApiError>) -> String {
            match r {
                Err(ApiError::BadRequest(m)) => m,
                other => panic!("expected a bad request, got {other:?}"),
            }
        }
        assert_eq!(
            message(parse_choice("format", "xml", &formats)),
            "query parameter `format` must be `json` or `text`, not `xml`"
        );
        assert_eq!(
            message(parse_choice("candidates", "JSON", &three)),
            "query parameter `candidates` must be `auto`, `all` or `bvh`, not `JSON`"
        );
    }

    const HITS: &[&str] = &[
        "application/json",
        "application/x-ndjson",
        "application/x-npy",
    ];

    fn accept(v: &str) -> HeaderMap {
        let mut h = HeaderMap::new();
        h.insert(header::ACCEPT, HeaderValue::from_str(v).unwrap());
        h
    }

    #[test]
    fn negotiation_follows_rfc9110() {
        assert_eq!(negotiate(&HeaderMap::new(), HITS), Ok("application/json"));
        assert_eq!(negotiate(&accept("*/*"), HITS), Ok("application/json"));
        assert_eq!(
            negotiate(&accept("application/x-npy"), HITS),
            Ok("application/x-npy")
        );
        assert_eq!(
            negotiate(
                &accept("application/json;q=0.5, application/x-ndjson"),
                HITS
            ),
            Ok("application/x-ndjson")
        );
        assert_eq!(
            negotiate(&accept("application/*;q=0.1, application/json;q=0"), HITS),
            Ok("application/x-ndjson")
        );
        assert!(matches!(
            negotiate(&accept("text/html"), HITS),
            Err(ApiError::NotAcceptable { .. })
        ));
        assert!(negotiate(&accept("image/*"), &["image/png"]).is_ok());
    }

    #[test]
    fn json_content_types() {
        for ok in [
            "application/json",
            "Application/JSON; charset=utf-8",
            "application/scene+json",
        ] {
            assert!(is_json(ok), "{ok}");
        }
        for bad in [
            "",
            "text/plain",
            "application/x-www-form-urlencoded",
            "json",
        ] {
            assert!(!is_json(bad), "{bad}");
        }
    }
}
