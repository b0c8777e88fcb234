//! Bearer tokens as a course deploys them, on the real binary: `raytile token create`
//! writes to the server's database (also while it runs), and `serve --require-token`
//! lets only instructors post scenes: 401 with `WWW-Authenticate: Bearer` without a
//! valid token, 403 for a grader's. Without the setting everything stays open. The flow
//! runs on SQLite in a temporary data folder, and on PostgreSQL when
//! `RAYTILE_TEST_DATABASE_URL` names one (`bash .ci/test-all` sets it up).

use std::process::Child;

use serde_json::Value;

use crate::openapi::{Answer, check, document};
use crate::support::run;
use crate::support_server::{client, problem, resized, shipped, spawn_binary_env};

/// The bootstrap token the tests' servers get in `RAYTILE_ADMIN_TOKEN`.
pub(crate) const ADMIN: &str = "admin-token-for-the-tests-only";

/// The server process, killed when the test ends however it ends.
pub(crate) struct Server {
    child: Child,
    pub(crate) url: String,
    /// Kept so that the log reader keeps draining the pipe.
    _logs: std::sync::mpsc::Receiver<String>,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

pub(crate) fn serve(args: &[&str], env: &[(&str, &str)]) -> Server {
    let (child, addr, logs) = spawn_binary_env(args, env);
    Server {
        child,
        url: format!("http://{addr}"),
        _logs: logs,
    }
}

/// `raytile token create` with these arguments: the token (stdout) and its id (stderr).
pub(crate) fn create_token(args: &[&str]) -> (String, String) {
    let out = run(&[&["token", "create"], args].concat());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "token create failed: {stderr}");
    let token = String::from_utf8(out.stdout)
        .expect("UTF-8")
        .trim()
        .to_owned();
    let id = stderr
        .split_whitespace()
        .last()
        .expect("the id on stderr")
        .to_owned();
    assert!(token.starts_with("rt_") && token.len() == 67, "{token}");
    // The token is shown once, on stdout only.
    assert!(!stderr.contains(&token), "{stderr}");
    (token, id)
}

fn small_scene() -> Value {
    resized(shipped("sphere.json"), 16, 12)
}

async fn render(url: &str, token: Option<&str>) -> reqwest::Response {
    let mut req = client()
        .post(format!("{url}/v1/render"))
        .header("content-type", "application/json")
        .body(serde_json::to_vec(&small_scene()).expect("JSON"));
    if let Some(t) = token {
        req = req.header("authorization", format!("Bearer {t}"));
    }
    req.send().await.expect("the server answers")
}

async fn assert_unauthorized(res: reqwest::Response) {
    let www = res
        .headers()
        .get("www-authenticate")
        .and_then(|v| v.to_str().ok())
        .map(str::to_owned);
    assert_eq!(www.as_deref(), Some("Bearer"));
    problem(res, 401, "unauthorized").await;
}

/// The whole flow on the store that `store` names (`--data-dir D` or `--database URL`).
async fn course_flow(store: &[&str]) {
    let (instructor, _) = create_token(&[&["--role", "instructor"], store].concat());
    let (grader, _) = create_token(&[&["--role", "grader", "--assignment", "a1"], store].concat());
    let server = serve(
        &[&["--require-token"], store].concat(),
        &[("RAYTILE_ADMIN_TOKEN", ADMIN)],
    );
    let url = server.url.as_str();
    let doc = document();

    // No token, a made-up one, the wrong scheme: 401, as documented.
    let res = render(url, None).await;
    let answer = Answer::from_reqwest(res).await;
    check(&doc, "post", "/v1/render", &answer);
    assert_eq!(answer.status, 401);
    assert_unauthorized(render(url, None).await).await;
    assert_unauthorized(render(url, Some("rt_0000")).await).await;
    let basic = client()
        .post(format!("{url}/v1/render"))
        .header("authorization", format!("Basic {instructor}"))
        .body(serde_json::to_vec(&small_scene()).expect("JSON"))
        .send()
        .await
        .expect("an answer");
    assert_unauthorized(basic).await;

    // Every route that takes a scene is closed, before its body is even read.
    for path in ["/v1/hits", "/v1/trace?u=0&v=0", "/v1/validate", "/v1/grade"] {
        let res = client()
            .post(format!("{url}{path}"))
            .header("content-type", "application/json")
            .body("{}")
            .send()
            .await
            .expect("an answer");
        assert_eq!(res.status().as_u16(), 401, "{path}");
    }

    // A grader's token may not render: 403, as documented.
    let res = render(url, Some(&grader)).await;
    let answer = Answer::from_reqwest(res).await;
    check(&doc, "post", "/v1/render", &answer);
    assert_eq!(answer.status, 403);
    problem(render(url, Some(&grader)).await, 403, "forbidden").await;

    // Instructors render: a token from the database, and the bootstrap one.
    for token in [instructor.as_str(), ADMIN] {
        let res = render(url, Some(token)).await;
        assert_eq!(res.status().as_u16(), 200);
        let png = res.bytes().await.expect("a body");
        assert!(png.starts_with(b"\x89PNG"));
    }

    // A token created while the server runs works at once; revoked, it stops.
    let (late, late_id) = create_token(&[&["--role", "instructor"], store].concat());
    assert_eq!(render(url, Some(&late)).await.status().as_u16(), 200);
    let out = run(&[&["token", "revoke", late_id.as_str()], store].concat());
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_unauthorized(render(url, Some(&late)).await).await;

    // What carries no scene stays open.
    for path in ["/healthz", "/v1/scenes"] {
        let res = client()
            .get(format!("{url}{path}"))
            .send()
            .await
            .expect("an answer");
        assert_eq!(res.status().as_u16(), 200, "{path}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_course_server_lets_only_instructors_post_scenes_on_sqlite() {
    let dir = tempfile::tempdir().expect("a temp dir");
    let data = dir.path().join("data");
    let data = data.to_str().expect("UTF-8");
    course_flow(&["--data-dir", data]).await;
    assert!(dir.path().join("data/raytile.db").is_file());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs PostgreSQL: run .ci/test-all"]
async fn a_course_server_lets_only_instructors_post_scenes_on_postgres() {
    let url = std::env::var("RAYTILE_TEST_DATABASE_URL")
        .expect("RAYTILE_TEST_DATABASE_URL names a PostgreSQL database");
    course_flow(&["--database", &url]).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn without_require_token_everything_stays_open_and_no_database_is_made() {
    let dir = tempfile::tempdir().expect("a temp dir");
    let data = dir.path().join("data");
    let server = serve(
        &["--data-dir", data.to_str().expect("UTF-8")],
        &[("RAYTILE_ADMIN_TOKEN", ADMIN)],
    );
    let res = render(&server.url, None).await;
    assert_eq!(res.status().as_u16(), 200);
    // Even a token that would be refused is ignored when none is required.
    assert_eq!(
        render(&server.url, Some("rt_0000")).await.status().as_u16(),
        200
    );
    assert!(!data.exists(), "the data folder is made only when needed");
}

#[test]
fn token_create_refuses_what_makes_no_sense() {
    let dir = tempfile::tempdir().expect("a temp dir");
    let data = dir.path().to_str().expect("UTF-8");
    let out = run(&["token", "create", "--role", "student", "--data-dir", data]);
    assert!(!out.status.success());
    assert!(out.stdout.is_empty());
    let out = run(&[
        "token",
        "create",
        "--role",
        "instructor",
        "--assignment",
        "a1",
        "--data-dir",
        data,
    ]);
    assert!(!out.status.success());
    assert!(out.stdout.is_empty());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("--assignment scopes grader tokens"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = run(&["token", "revoke", "no-such-id", "--data-dir", data]);
    assert_eq!(out.status.code(), Some(1));
}
