//! What the commands that talk to a course server share (`raytile assignment push |
//! grades`, `raytile submit`, `raytile scenes`): `--server` and `--token` (or
//! `RAYTILE_TOKEN`), the HTTP client with the bearer token on every request, URLs built
//! from path segments (each percent-encoded, so an id cannot reach another route), and
//! an error answer's problem document as readable text, every problem at its pointer.

use std::fmt::Write as _;
use std::time::Duration;

use anyhow::{Context, bail};
use reqwest::{Method, RequestBuilder, Response, StatusCode, Url};
use serde_json::Value;

use crate::store::Secret;

/// How long connecting may take before a request gives up.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(10);

/// How much of an error answer is kept: a problem document is far smaller.
const ERROR_BODY_LIMIT: usize = 1 << 20;

/// How much of a body that is not a problem document is shown.
const PLAIN_EXCERPT_CHARS: usize = 300;

/// `--server` and `--token`, for every command that talks to a course server.
#[derive(Debug, Clone, clap::Args)]
pub struct ServerArgs {
    /// The server's base URL: `http://host:port` or `https://host`, with a path
    /// prefix if it has one.
    #[arg(long)]
    pub server: String,
    /// The bearer token (an instructor's or a grader's, as the command needs). Prefer
    /// the environment: the command line shows in `ps`.
    #[arg(long, env = "RAYTILE_TOKEN", hide_env_values = true)]
    pub token: Option<Secret>,
}

/// A server base URL, checked: `http://host[:port][/prefix]`, without a trailing slash.
pub fn server_url(s: &str) -> anyhow::Result<String> {
    base_url(s, false)
}

/// A base URL as [`server_url`] checks it, with `https://` allowed too when `tls`: a
/// course server is often reached across the internet, replicas never are.
pub fn base_url(s: &str, tls: bool) -> anyhow::Result<String> {
    let s = s.trim();
    let url = reqwest::Url::parse(s).with_context(|| format!("`{s}` is not a URL"))?;
    let scheme_ok = url.scheme() == "http" || (tls && url.scheme() == "https");
    if !scheme_ok {
        if tls {
            bail!("`{s}`: give the server as http:// or https://");
        }
        bail!(
            "`{s}`: only http:// servers are supported (raytile speaks plain HTTP to its replicas)"
        );
    }
    if url.host_str().is_none_or(str::is_empty) || url.query().is_some() || url.fragment().is_some()
    {
        bail!("`{s}`: give a server as http(s)://host:port, with no query or fragment");
    }
    Ok(url.as_str().trim_end_matches('/').to_owned())
}

/// The builder every HTTP client of raytile starts from. reqwest is built without a
/// crypto provider so that TLS runs on ring, which needs only a C compiler to build;
/// this installs it first (a second installation is refused, harmlessly).
pub fn client_builder() -> reqwest::ClientBuilder {
    let _ = rustls::crypto::ring::default_provider().install_default();
    reqwest::Client::builder()
}

/// A course server to talk to: its base URL, the client, the token.
#[derive(Debug, Clone)]
pub struct Remote {
    base: Url,
    client: reqwest::Client,
    token: Option<Secret>,
}

/// A server's answer that is not a success: its status and what it said, readably.
#[derive(Debug, Clone, thiserror::Error)]
#[error("the server answered {status}: {message}")]
pub struct Refused {
    /// The status.
    pub status: StatusCode,
    /// The problem document (or the body) as text: [`describe_problem`].
    pub message: String,
    /// `Retry-After` in whole seconds, when the answer carried one.
    pub retry_after: Option<u64>,
}

impl Remote {
    /// The server `args` names; each request gives up after `timeout`.
    pub fn new(args: &ServerArgs, timeout: Duration) -> anyhow::Result<Remote> {
        let base = base_url(&args.server, true)?;
        let base = Url::parse(&base).with_context(|| format!("`{base}` is not a URL"))?;
        let client = client_builder()
            .timeout(timeout)
            .connect_timeout(CONNECT_TIMEOUT.min(timeout))
            .build()
            .context("cannot set up the HTTP client")?;
        // An empty `RAYTILE_TOKEN` is no token, not an empty one.
        let token = args
            .token
            .as_ref()
            .map(|t| t.expose().trim())
            .filter(|t| !t.is_empty())
            .map(Secret::new);
        Ok(Remote {
            base,
            client,
            token,
        })
    }

    /// The URL of `segments` under the base, each segment percent-encoded as one:
    /// `url(&["v1", "assignments", id, "grades.csv"])`.
    pub fn url(&self, segments: &[&str]) -> Url {
        let mut url = self.base.clone();
        if let Ok(mut path) = url.path_segments_mut() {
            path.pop_if_empty().extend(segments);
        }
        url
    }

    /// A request to `url` carrying the bearer token, if there is one.
    pub fn request(&self, method: Method, url: Url) -> RequestBuilder {
        let req = self.client.request(method, url);
        match &self.token {
            Some(t) => req.bearer_auth(t.expose()),
            None => req,
        }
    }

    /// The base URL, for messages.
    pub fn base(&self) -> &str {
        self.base.as_str().trim_end_matches('/')
    }
}

/// `res` if it is a success; else a [`Refused`] with its problem document as text.
pub async fn success(res: Response) -> Result<Response, Refused> {
    let status = res.status();
    if status.is_success() {
        return Ok(res);
    }
    let retry_after = res
        .headers()
        .get(reqwest::header::RETRY_AFTER)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse().ok());
    let body = read_limited(res, ERROR_BODY_LIMIT).await;
    Err(Refused {
        status,
        message: describe_problem(&body),
        retry_after,
    })
}

/// At most `limit` bytes of the body; what could not be read is left out (this is for
/// messages, which must not fail themselves).
async fn read_limited(mut res: Response, limit: usize) -> Vec<u8> {
    let mut body = Vec::new();
    while let Ok(Some(chunk)) = res.chunk().await {
        let room = limit.saturating_sub(body.len());
        body.extend_from_slice(&chunk[..chunk.len().min(room)]);
        if body.len() >= limit {
            break;
        }
    }
    body
}

/// An error answer's body as readable text: a problem document's title and detail on
/// the first line, then each of its `problems` on a line of its own, pointer first;
/// any other body as the start of its text.
pub fn describe_problem(body: &[u8]) -> String {
    let one_line = |s: &str| s.split_whitespace().collect::<Vec<_>>().join(" ");
    let doc = serde_json::from_slice::<Value>(body)
        .ok()
        .filter(|d| d.get("title").is_some_and(Value::is_string));
    let Some(doc) = doc else {
        let text = one_line(&String::from_utf8_lossy(body));
        if text.is_empty() {
            return "no explanation".to_owned();
        }
        return text.chars().take(PLAIN_EXCERPT_CHARS).collect();
    };
    let text = |k: &str| doc.get(k).and_then(Value::as_str).map(one_line);
    let mut out = match (text("title"), text("detail")) {
        (Some(t), Some(d)) => format!("{t}: {d}"),
        (Some(t), None) => t,
        (None, Some(d)) => d,
        (None, None) => String::new(),
    };
    for p in doc
        .get("problems")
        .and_then(Value::as_array)
        .into_iter()
        .flatten()
    {
        let pointer = p.get("pointer").and_then(Value::as_str).unwrap_or("");
        let message = p.get("message").and_then(Value::as_str).unwrap_or("");
        let pointer = if pointer.is_empty() { "/" } else { pointer };
        let _ = write!(out, "\n  {pointer}: {}", one_line(message));
    }
    out
}

/// The single-threaded runtime a command's requests run on.
pub fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn server_urls_are_plain_http_bases() {
        assert_eq!(
            server_url("http://10.0.0.1:8080").unwrap(),
            "http://10.0.0.1:8080"
        );
        assert_eq!(
            server_url(" http://lb/raytile/ ").unwrap(),
            "http://lb/raytile"
        );
        for bad in ["https://lb", "lb:8080", "http://lb/?x=1", "", "ftp://x"] {
            assert!(server_url(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn course_servers_may_be_https() {
        assert_eq!(
            base_url("https://grader.example.edu/raytile/", true).unwrap(),
            "https://grader.example.edu/raytile"
        );
        assert!(base_url("https://lb", false).is_err());
        for bad in ["ftp://x", "https://lb/?x=1", "grader:8080"] {
            assert!(base_url(bad, true).is_err(), "{bad}");
        }
    }

    fn remote(server: &str, token: Option<&str>) -> Remote {
        let args = ServerArgs {
            server: server.into(),
            token: token.map(Secret::new),
        };
        Remote::new(&args, Duration::from_secs(5)).unwrap()
    }

    #[test]
    fn urls_join_the_base_and_encode_each_segment() {
        let r = remote("http://127.0.0.1:8080", None);
        assert_eq!(
            r.url(&["v1", "assignments", "ray-casting", "grades.csv"])
                .as_str(),
            "http://127.0.0.1:8080/v1/assignments/ray-casting/grades.csv"
        );
        // A prefix is kept, with or without its trailing slash.
        for base in ["http://h:1/course/", "http://h:1/course"] {
            let r = remote(base, None);
            assert_eq!(
                r.url(&["v1", "assignments"]).as_str(),
                "http://h:1/course/v1/assignments"
            );
            assert_eq!(r.base(), "http://h:1/course");
        }
        // An id cannot climb out of its segment or add a query.
        let odd = r.url(&["v1", "assignments", "../x?y#z", "stats"]);
        assert_eq!(
            odd.as_str(),
            "http://127.0.0.1:8080/v1/assignments/..%2Fx%3Fy%23z/stats"
        );
    }

    #[test]
    fn the_token_goes_in_the_authorization_header_and_an_empty_one_is_none() {
        let r = remote("http://h:1", Some(" rt_abc \n"));
        let req = r.request(Method::GET, r.url(&["v1"])).build().unwrap();
        assert_eq!(req.headers()["authorization"], "Bearer rt_abc");
        let r = remote("http://h:1", Some("  "));
        let req = r.request(Method::GET, r.url(&["v1"])).build().unwrap();
        assert!(req.headers().get("authorization").is_none());
    }

    #[test]
    fn servers_that_are_not_plain_http_urls_are_refused() {
        for bad in ["h:1", "ftp://h/", "http://h:1/?q=1", "not a url"] {
            let args = ServerArgs {
                server: bad.into(),
                token: None,
            };
            assert!(Remote::new(&args, Duration::from_secs(1)).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_problem_document_reads_with_every_pointer_on_its_line() {
        let body = br#"{"type": "https://raytile.example/problems/invalid-assignment",
            "title": "Invalid assignment", "status": 422,
            "detail": "the assignment has 2 problems",
            "problems": [
              {"pointer": "/scenes/0/points", "message": "must be more than 0"},
              {"pointer": "", "message": "unknown field\n `colour`"}]}"#;
        assert_eq!(
            describe_problem(body),
            "Invalid assignment: the assignment has 2 problems\n  \
             /scenes/0/points: must be more than 0\n  /: unknown field `colour`"
        );
        let plain = describe_problem(b"{\"title\": \"Forbidden\", \"detail\": \"a grader\"}");
        assert_eq!(plain, "Forbidden: a grader");
    }

    #[test]
    fn other_bodies_are_shown_as_the_start_of_their_text() {
        assert_eq!(
            describe_problem(b"<h1>502 Bad\n Gateway</h1>"),
            "<h1>502 Bad Gateway</h1>"
        );
        assert_eq!(describe_problem(b""), "no explanation");
        assert_eq!(describe_problem(b"[1, 2]"), "[1, 2]");
        let long = "x".repeat(1000);
        assert_eq!(describe_problem(long.as_bytes()).len(), PLAIN_EXCERPT_CHARS);
    }
}
