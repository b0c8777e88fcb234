//! The assignment routes on the real binary, as a course uses them: an instructor pushes
//! and replaces assignments (If-Match, every problem of an invalid one with its
//! pointer), a grader's token sees only its assignment's scenes and may only fetch and
//! submit, submissions are graded into one combined report (a hidden scene's shows no
//! reference data in any form), recorded once per idempotency key, rate-limited per
//! student, and a grader's token dies with its assignment. The access flow runs on
//! SQLite in a temporary data folder, and on PostgreSQL when
//! `RAYTILE_TEST_DATABASE_URL` names one (`bash .ci/test-all` sets it up).

use std::collections::BTreeSet;

use reqwest::multipart::{Form, Part};
use serde_json::{Value, json};

use crate::auth::{ADMIN, Server, create_token, serve};
use crate::openapi::{Answer, check, document};
use crate::support::{decode_png, encode_png};
use crate::support_server::{client, problem, resized, shipped};

const W: u32 = 16;
const H: u32 = 12;

/// A fresh suffix: the PostgreSQL database outlives a test run.
pub(crate) fn fresh(prefix: &str) -> String {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    format!("{prefix}-{}-{nanos}", std::process::id())
}

pub(crate) fn small(name: &str) -> Value {
    resized(shipped(name), W, H)
}

pub(crate) fn entry(name: &str, scene: Value, grade: &str, visibility: &str) -> Value {
    json!({"name": name, "scene": scene, "points": 5, "grade": grade, "visibility": visibility})
}

pub(crate) fn assignment(title: &str, scenes: Vec<Value>) -> Value {
    json!({"version": 1, "title": title, "due": "2030-01-01T00:00:00Z", "scenes": scenes})
}

/// A request with the token, if any.
pub(crate) fn authed(req: reqwest::RequestBuilder, token: Option<&str>) -> reqwest::RequestBuilder {
    match token {
        Some(t) => req.header("authorization", format!("Bearer {t}")),
        None => req,
    }
}

async fn put(url: &str, id: &str, doc: &Value, token: &str, headers: &[(&str, &str)]) -> Answer {
    let mut req = authed(
        client().put(format!("{url}/v1/assignments/{id}")),
        Some(token),
    )
    .header("content-type", "application/json")
    .body(serde_json::to_vec(doc).expect("JSON"));
    for (k, v) in headers {
        req = req.header(*k, *v);
    }
    let answer = Answer::from_reqwest(req.send().await.expect("an answer")).await;
    check(&document(), "put", "/v1/assignments/{id}", &answer);
    answer
}

pub(crate) async fn get(url: &str, path: &str, token: Option<&str>) -> reqwest::Response {
    authed(client().get(format!("{url}{path}")), token)
        .send()
        .await
        .expect("an answer")
}

pub(crate) fn json_of(a: &Answer) -> Value {
    serde_json::from_slice(&a.body).expect("a JSON body")
}

pub(crate) fn header(a: &reqwest::Response, name: &str) -> Option<String> {
    a.headers()
        .get(name)
        .and_then(|v| v.to_str().ok())
        .map(str::to_owned)
}

/// One submission: the student and `(scene, file name, bytes)` parts.
pub(crate) struct Submit<'a> {
    pub(crate) student: &'a str,
    pub(crate) files: Vec<(&'a str, &'a str, Vec<u8>)>,
    pub(crate) report: Option<&'a str>,
    pub(crate) key: Option<&'a str>,
}

/// Posts `s` and checks the answer against the document; gives the answer and its
/// `Location` and `Retry-After`.
pub(crate) async fn submit(
    url: &str,
    id: &str,
    token: &str,
    s: Submit<'_>,
) -> (Answer, Option<String>, Option<String>) {
    let mut form = Form::new().text("student", s.student.to_owned());
    for (scene, file, bytes) in s.files {
        form = form.part(
            scene.to_owned(),
            Part::bytes(bytes).file_name(file.to_owned()),
        );
    }
    let query = s.report.map_or(String::new(), |r| format!("?report={r}"));
    let mut req = authed(
        client().post(format!("{url}/v1/assignments/{id}/submissions{query}")),
        Some(token),
    )
    .multipart(form);
    if let Some(k) = s.key {
        req = req.header("idempotency-key", k);
    }
    let res = req.send().await.expect("an answer");
    let (location, retry) = (header(&res, "location"), header(&res, "retry-after"));
    let answer = Answer::from_reqwest(res).await;
    check(
        &document(),
        "post",
        "/v1/assignments/{id}/submissions",
        &answer,
    );
    (answer, location, retry)
}

/// The scene rendered by the instructor: the submission that earns full marks.
pub(crate) async fn render_png(url: &str, scene: &Value) -> Vec<u8> {
    let res = authed(client().post(format!("{url}/v1/render")), Some(ADMIN))
        .header("content-type", "application/json")
        .body(serde_json::to_vec(scene).expect("JSON"))
        .send()
        .await
        .expect("an answer");
    assert_eq!(res.status().as_u16(), 200);
    res.bytes().await.expect("a PNG").to_vec()
}

pub(crate) fn black_png() -> Vec<u8> {
    encode_png(W, H, &vec![0u8; (W * H * 3) as usize])
}

/// How the reference's pixels could appear in a report: as JSON arrays and as the text
/// form writes them.
fn pixel_spellings(png: &[u8]) -> BTreeSet<String> {
    let (_, _, rgb) = decode_png(png);
    rgb.chunks(3)
        .filter(|p| p != &[0, 0, 0])
        .flat_map(|p| {
            let (r, g, b) = (p[0], p[1], p[2]);
            [format!("[{r},{g},{b}]"), format!("rgb({r}, {g}, {b})")]
        })
        .collect()
}

/// What in `body` gives the reference away: a pixel value, the worst pixels, a
/// difference image, the word `reference`. JSON bodies are compacted first, so that a
/// pretty-printed array reads as `[r,g,b]`.
fn leaks(body: &[u8], pixels: &BTreeSet<String>) -> Vec<String> {
    let text = match serde_json::from_slice::<Value>(body) {
        Ok(v) => v.to_string(),
        Err(_) => String::from_utf8_lossy(body).into_owned(),
    };
    pixels
        .iter()
        .map(String::as_str)
        .chain(["\"worst\"", "data:image/png", "reference", "diff"])
        .filter(|s| text.contains(s))
        .map(str::to_owned)
        .collect()
}

/// `GET /v1/assignments` as `token` sees it, by id.
async fn listed(url: &str, token: &str) -> std::collections::BTreeMap<String, Value> {
    let answer = Answer::from_reqwest(get(url, "/v1/assignments", Some(token)).await).await;
    check(&document(), "get", "/v1/assignments", &answer);
    assert_eq!(answer.status, 200);
    json_of(&answer)["assignments"]
        .as_array()
        .expect("a list")
        .iter()
        .map(|a| (a["id"].as_str().unwrap_or("").to_owned(), a.clone()))
        .collect()
}

async fn submissions_in_store(store: &[&str], id: &str, student: &str) -> usize {
    let s = match store {
        ["--data-dir", dir] => raytile::store::Store::open_dir(std::path::Path::new(dir)).await,
        ["--database", url] => raytile::store::Store::connect(url).await,
        other => panic!("unknown store {other:?}"),
    }
    .expect("the store opens");
    let n = s
        .submissions(id, Some(student))
        .await
        .expect("submissions")
        .len();
    s.close().await;
    n
}

/// The access flow on the store that `store` names (`--data-dir D` or `--database URL`).
async fn access_flow(store: &[&str]) {
    let a1 = fresh("a1");
    let a2 = fresh("a2");
    let (instructor, _) = create_token(&[&["--role", "instructor"], store].concat());
    let (grader, _) = create_token(&[&["--role", "grader", "--assignment", &a1], store].concat());
    let server: Server = serve(
        &[&["--require-token", "--submissions-per-hour", "3"], store].concat(),
        &[("RAYTILE_ADMIN_TOKEN", ADMIN)],
    );
    let url = server.url.as_str();
    let doc = document();
    let spheres = small("sphere.json");
    let first = assignment(
        "Ray casting",
        vec![entry("spheres", spheres.clone(), "image", "visible")],
    );

    // Pushing needs an instructor: none is 401, a grader's token 403.
    let res = authed(client().put(format!("{url}/v1/assignments/{a1}")), None)
        .header("content-type", "application/json")
        .body(first.to_string())
        .send()
        .await
        .expect("an answer");
    assert_eq!(header(&res, "www-authenticate").as_deref(), Some("Bearer"));
    problem(res, 401, "unauthorized").await;
    let answer = put(url, &a1, &first, &grader, &[]).await;
    assert_eq!(answer.status, 403);

    // Created, replaced, and a stale If-Match refused.
    let answer = put(url, &a1, &first, &instructor, &[("if-none-match", "*")]).await;
    assert_eq!(answer.status, 201);
    assert_eq!(json_of(&answer), json!({"id": a1, "revision": 1}));
    let second = assignment(
        "Ray casting",
        vec![
            entry("spheres", spheres.clone(), "image", "visible"),
            json!({"name": "secret", "scene": spheres, "points": 5, "grade": "image",
                   "visibility": "hidden", "tolerances": {"colour_abs": 3}}),
        ],
    );
    let answer = put(url, &a1, &second, &instructor, &[("if-match", "\"1\"")]).await;
    assert_eq!(answer.status, 200);
    assert_eq!(json_of(&answer)["revision"], 2);
    for stale in [&[("if-match", "\"1\"")][..], &[("if-none-match", "*")]] {
        let answer = put(url, &a1, &first, &instructor, stale).await;
        assert_eq!(answer.status, 409, "{stale:?}");
        assert_eq!(
            json_of(&answer)["type"],
            "https://raytile.example/problems/conflict"
        );
    }
    let answer = put(url, &a2, &first, ADMIN, &[]).await;
    assert_eq!(answer.status, 201);

    // An invalid document: every problem, each with its pointer.
    let mut bad = assignment(
        "",
        vec![entry("a b", small("sphere.json"), "pixels", "visible")],
    );
    bad["scenes"][0]["scene"]["objects"][0]["shape"] = json!("blob");
    bad["scenes"][0]["points"] = json!(-1);
    let answer = put(url, &fresh("bad"), &bad, &instructor, &[]).await;
    assert_eq!(answer.status, 422);
    let body = json_of(&answer);
    let pointers: BTreeSet<&str> = body["problems"]
        .as_array()
        .expect("problems")
        .iter()
        .filter_map(|p| p["pointer"].as_str())
        .collect();
    for want in [
        "/title",
        "/scenes/0/name",
        "/scenes/0/points",
        "/scenes/0/grade",
        "/scenes/0/scene/objects/0/shape",
    ] {
        assert!(pointers.contains(want), "{want} not in {pointers:?}");
    }

    // Listing: the instructor sees both, the grader its own.
    let all = listed(url, ADMIN).await;
    assert_eq!(all[&a1]["revision"], 2);
    assert_eq!(all[&a1]["scenes"], json!(["spheres", "secret"]));
    assert_eq!(all[&a1]["due"], "2030-01-01T00:00:00Z");
    assert!(all.contains_key(&a2));
    let mine = listed(url, &grader).await;
    assert_eq!(mine.keys().cloned().collect::<Vec<_>>(), vec![a1.clone()]);

    // Reading: the whole document for the instructor, the scenes alone for the grader.
    let res = get(url, &format!("/v1/assignments/{a1}"), Some(&instructor)).await;
    assert_eq!(header(&res, "etag").as_deref(), Some("\"2\""));
    let answer = Answer::from_reqwest(res).await;
    check(&doc, "get", "/v1/assignments/{id}", &answer);
    assert_eq!(json_of(&answer), second);
    let res = get(url, &format!("/v1/assignments/{a1}"), Some(&grader)).await;
    let answer = Answer::from_reqwest(res).await;
    check(&doc, "get", "/v1/assignments/{id}", &answer);
    let view = json_of(&answer);
    assert_eq!(view["scenes"][1]["scene"], second["scenes"][1]["scene"]);
    for s in view["scenes"].as_array().expect("scenes") {
        let keys: Vec<&str> = s
            .as_object()
            .expect("a scene")
            .keys()
            .map(String::as_str)
            .collect();
        assert_eq!(keys, ["grade", "name", "points", "scene"], "{s}");
    }
    assert!(!answer.body.windows(10).any(|w| w == b"tolerances"));
    assert!(!answer.body.windows(10).any(|w| w == b"visibility"));

    // A grader may not read another assignment, manage any, list submissions, or post
    // a scene of its own.
    let res = get(url, &format!("/v1/assignments/{a2}"), Some(&grader)).await;
    let answer = Answer::from_reqwest(res).await;
    check(&doc, "get", "/v1/assignments/{id}", &answer);
    assert_eq!(answer.status, 403);
    let res = authed(
        client().delete(format!("{url}/v1/assignments/{a1}")),
        Some(&grader),
    )
    .send()
    .await
    .expect("an answer");
    problem(res, 403, "forbidden").await;
    let res = get(
        url,
        &format!("/v1/assignments/{a1}/submissions"),
        Some(&grader),
    )
    .await;
    problem(res, 403, "forbidden").await;
    for path in ["/v1/render", "/v1/grade"] {
        let res = authed(client().post(format!("{url}{path}")), Some(&grader))
            .header("content-type", "application/json")
            .body(small("sphere.json").to_string())
            .send()
            .await
            .expect("an answer");
        problem(res, 403, "forbidden").await;
    }

    // Submissions: recorded (201), and a retry with the same key answered from the store
    // (200, the same submission, in whatever form it asks for) and recorded once.
    let good = render_png(url, &small("sphere.json")).await;
    let files = || {
        vec![
            ("spheres", "spheres.png", good.clone()),
            ("secret", "secret.png", good.clone()),
        ]
    };
    let (first_answer, location, _) = submit(
        url,
        &a1,
        &grader,
        Submit {
            student: "s1",
            files: files(),
            report: None,
            key: Some("k1"),
        },
    )
    .await;
    assert_eq!(first_answer.status, 201);
    let result = json_of(&first_answer);
    assert_eq!(
        (result["score"].as_f64(), result["max_score"].as_f64()),
        (Some(10.0), Some(10.0))
    );
    let location = location.expect("a Location");
    assert!(
        location.starts_with(&format!("/v1/assignments/{a1}/submissions/")),
        "{location}"
    );
    let (again, again_location, _) = submit(
        url,
        &a1,
        &grader,
        Submit {
            student: "s1",
            files: files(),
            report: None,
            key: Some("k1"),
        },
    )
    .await;
    assert_eq!(again.status, 200);
    assert_eq!(again.body, first_answer.body);
    assert_eq!(again_location.as_deref(), Some(location.as_str()));
    let (gradescope, _, _) = submit(
        url,
        &a1,
        &grader,
        Submit {
            student: "s1",
            files: Vec::new(),
            report: Some("gradescope"),
            key: Some("k1"),
        },
    )
    .await;
    assert_eq!(gradescope.status, 200);
    let gs = json_of(&gradescope);
    assert_eq!(gs["score"], 10.0);
    assert_eq!(gs["tests"][1]["visibility"], "hidden");
    assert_eq!(submissions_in_store(store, &a1, "s1").await, 1);

    // The rate limit: three an hour, replays not counted.
    for _ in 0..2 {
        let (a, _, _) = submit(
            url,
            &a1,
            &instructor,
            Submit {
                student: "s1",
                files: files(),
                report: Some("text"),
                key: None,
            },
        )
        .await;
        assert_eq!(a.status, 201);
        assert!(String::from_utf8_lossy(&a.body).contains("10 of 10 points"));
    }
    let (limited, _, retry) = submit(
        url,
        &a1,
        &grader,
        Submit {
            student: "s1",
            files: files(),
            report: None,
            key: Some("k2"),
        },
    )
    .await;
    assert_eq!(limited.status, 429);
    let retry: u64 = retry.expect("Retry-After").parse().expect("seconds");
    assert!((3500..=3600).contains(&retry), "Retry-After {retry}");
    assert_eq!(
        json_of(&limited)["type"],
        "https://raytile.example/problems/too-many-submissions"
    );
    let (replayed, _, _) = submit(
        url,
        &a1,
        &grader,
        Submit {
            student: "s1",
            files: Vec::new(),
            report: None,
            key: Some("k1"),
        },
    )
    .await;
    assert_eq!(replayed.status, 200);
    let (other, _, _) = submit(
        url,
        &a1,
        &grader,
        Submit {
            student: "s2",
            files: files(),
            report: None,
            key: None,
        },
    )
    .await;
    assert_eq!(other.status, 201);
    assert_eq!(submissions_in_store(store, &a1, "s1").await, 3);

    // A grader's token dies with its assignment, and stays dead if the id comes back.
    let res = authed(
        client().delete(format!("{url}/v1/assignments/{a1}")),
        Some(&instructor),
    )
    .send()
    .await
    .expect("an answer");
    // 204 has no body, so no media type to check.
    assert_eq!(res.status().as_u16(), 204);
    assert!(res.bytes().await.expect("a body").is_empty());
    let res = get(url, &format!("/v1/assignments/{a1}"), Some(&instructor)).await;
    problem(res, 404, "not-found").await;
    let (dead, _, _) = submit(
        url,
        &a1,
        &grader,
        Submit {
            student: "s3",
            files: files(),
            report: None,
            key: None,
        },
    )
    .await;
    assert_eq!(dead.status, 401);
    assert_eq!(put(url, &a1, &first, &instructor, &[]).await.status, 201);
    let res = get(url, &format!("/v1/assignments/{a1}"), Some(&grader)).await;
    problem(res, 401, "unauthorized").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn graders_see_and_do_only_what_their_assignment_allows_on_sqlite() {
    let dir = tempfile::tempdir().expect("a temp dir");
    let data = dir.path().join("data");
    access_flow(&["--data-dir", data.to_str().expect("UTF-8")]).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs PostgreSQL: run .ci/test-all"]
async fn graders_see_and_do_only_what_their_assignment_allows_on_postgres() {
    let url = std::env::var("RAYTILE_TEST_DATABASE_URL")
        .expect("RAYTILE_TEST_DATABASE_URL names a PostgreSQL database");
    access_flow(&["--database", &url]).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hidden_scene_gives_nothing_away_and_each_scene_fares_on_its_own() {
    let dir = tempfile::tempdir().expect("a temp dir");
    let data = dir.path().join("data");
    let server = serve(
        &[
            "--data-dir",
            data.to_str().expect("UTF-8"),
            "--submissions-per-hour",
            "0",
        ],
        &[("RAYTILE_ADMIN_TOKEN", ADMIN)],
    );
    let url = server.url.as_str();
    let (secret_scene, shown_scene) = (small("sphere.json"), small("showcase.json"));
    let id = "course";
    let doc = assignment(
        "Hidden",
        vec![
            entry("secret", secret_scene.clone(), "image", "hidden"),
            entry("shown", shown_scene.clone(), "image", "visible"),
        ],
    );
    assert_eq!(put(url, id, &doc, ADMIN, &[]).await.status, 201);
    let secret_png = render_png(url, &secret_scene).await;
    let secret_pixels = pixel_spellings(&secret_png);
    assert!(!secret_pixels.is_empty());

    // A wrong image for the hidden scene, nothing for the other: no form shows any of
    // the reference's values, and the missing scene scores 0 saying what it expected.
    for report in ["json", "text", "gradescope", "prairielearn"] {
        let (answer, _, _) = submit(
            url,
            id,
            ADMIN,
            Submit {
                student: "s",
                files: vec![("secret", "secret.png", black_png())],
                report: Some(report),
                key: None,
            },
        )
        .await;
        assert_eq!(answer.status, 201, "{report}");
        assert_eq!(
            leaks(&answer.body, &secret_pixels),
            Vec::<String>::new(),
            "{report}"
        );
        let text = String::from_utf8_lossy(&answer.body);
        assert!(
            text.contains("no image file was submitted for the scene `shown`"),
            "{report}: {text}"
        );
    }
    let (answer, _, _) = submit(
        url,
        id,
        ADMIN,
        Submit {
            student: "s",
            files: vec![("secret", "secret.png", black_png())],
            report: None,
            key: None,
        },
    )
    .await;
    let result = json_of(&answer);
    assert_eq!(result["score"], 0.0);
    assert_eq!(result["scenes"][0]["status"], "failed");
    assert_eq!(result["scenes"][0]["feedback"], false);
    assert_eq!(result["scenes"][1]["status"], "missing");
    assert_eq!(result["scenes"][1]["points"], 0.0);

    // The same wrong image for the visible scene shows its reference: what the check
    // above looks for is there to be found.
    let shown_png = render_png(url, &shown_scene).await;
    let (answer, _, _) = submit(
        url,
        id,
        ADMIN,
        Submit {
            student: "s",
            files: vec![("shown", "shown.png", black_png())],
            report: None,
            key: None,
        },
    )
    .await;
    assert!(!leaks(&answer.body, &pixel_spellings(&shown_png)).is_empty());

    // An unreadable file makes its scene ungradable and leaves the other graded.
    let (answer, _, _) = submit(
        url,
        id,
        ADMIN,
        Submit {
            student: "s",
            files: vec![
                ("secret", "secret.png", secret_png.clone()),
                ("shown", "shown.png", b"not an image".to_vec()),
            ],
            report: None,
            key: None,
        },
    )
    .await;
    assert_eq!(answer.status, 201);
    let result = json_of(&answer);
    assert_eq!(result["scenes"][0]["status"], "passed");
    assert_eq!(result["scenes"][0]["points"], 5.0);
    assert_eq!(result["scenes"][1]["status"], "ungradable");
    assert!(
        result["scenes"][1]["message"]
            .as_str()
            .unwrap_or("")
            .starts_with("shown.png: "),
        "{result}"
    );
    assert_eq!(result["score"], 5.0);

    // Nothing asks a submission's answer for more than the report: no worst pixels, no
    // difference image.
    for query in ["worst=1000", "output=diff", "inline_diff=true"] {
        let form = Form::new()
            .text("student", "s")
            .part("secret", Part::bytes(black_png()).file_name("secret.png"));
        let res = authed(
            client().post(format!("{url}/v1/assignments/{id}/submissions?{query}")),
            Some(ADMIN),
        )
        .multipart(form)
        .send()
        .await
        .expect("an answer");
        problem(res, 400, "bad-request").await;
    }

    // Requests the route refuses, each as documented.
    let form = Form::new().part("secret", Part::bytes(black_png()).file_name("secret.png"));
    let res = authed(
        client().post(format!("{url}/v1/assignments/{id}/submissions")),
        Some(ADMIN),
    )
    .multipart(form)
    .send()
    .await
    .expect("an answer");
    let answer = Answer::from_reqwest(res).await;
    check(
        &document(),
        "post",
        "/v1/assignments/{id}/submissions",
        &answer,
    );
    assert_eq!(answer.status, 400);
    let res = authed(
        client().post(format!("{url}/v1/assignments/nothing-here/submissions")),
        Some(ADMIN),
    )
    .multipart(Form::new().text("student", "s"))
    .send()
    .await
    .expect("an answer");
    problem(res, 404, "not-found").await;
    let res = authed(
        client().post(format!("{url}/v1/assignments/{id}/submissions")),
        None,
    )
    .multipart(Form::new().text("student", "s"))
    .send()
    .await
    .expect("an answer");
    problem(res, 401, "unauthorized").await;
    assert!(data.join("raytile.db").is_file());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_assignment_too_costly_to_grade_is_refused_when_pushed() {
    let dir = tempfile::tempdir().expect("a temp dir");
    let data = dir.path().join("data");
    let server = serve(
        &[
            "--data-dir",
            data.to_str().expect("UTF-8"),
            "--max-rays",
            "100",
        ],
        &[("RAYTILE_ADMIN_TOKEN", ADMIN)],
    );
    let doc = assignment(
        "Costly",
        vec![
            entry(
                "tiny",
                resized(shipped("sphere.json"), 4, 4),
                "hits",
                "visible",
            ),
            entry("costly", small("sphere.json"), "image", "visible"),
        ],
    );
    let answer = put(&server.url, "costly", &doc, ADMIN, &[]).await;
    assert_eq!(answer.status, 422);
    let body = json_of(&answer);
    assert_eq!(
        body["type"],
        "https://raytile.example/problems/invalid-scene"
    );
    let pointers: Vec<&str> = body["problems"]
        .as_array()
        .expect("problems")
        .iter()
        .filter_map(|p| p["pointer"].as_str())
        .collect();
    assert!(
        pointers.contains(&"/scenes/1/scene/image/width"),
        "{pointers:?}"
    );
    assert!(
        pointers.iter().all(|p| p.starts_with("/scenes/1/scene/")),
        "{pointers:?}"
    );
    let res = get(&server.url, "/v1/assignments/costly", Some(ADMIN)).await;
    problem(res, 404, "not-found").await;
}

/// Submissions made at once by one student: the limit holds as they are recorded.
async fn concurrent_flow(store: &[&str]) {
    let server = serve(
        &[
            &["--submissions-per-hour", "2", "--max-renders", "8"],
            store,
        ]
        .concat(),
        &[("RAYTILE_ADMIN_TOKEN", ADMIN)],
    );
    let url = server.url.clone();
    let id = fresh("burst");
    let doc = assignment(
        "Burst",
        vec![entry("spheres", small("sphere.json"), "image", "visible")],
    );
    assert_eq!(put(&url, &id, &doc, ADMIN, &[]).await.status, 201);
    let tasks: Vec<_> = (0..6)
        .map(|_| {
            let (url, id) = (url.clone(), id.clone());
            tokio::spawn(async move {
                let files = vec![("spheres", "spheres.png", black_png())];
                let s = Submit {
                    student: "busy",
                    files,
                    report: None,
                    key: None,
                };
                submit(&url, &id, ADMIN, s).await.0.status
            })
        })
        .collect();
    let mut statuses = Vec::new();
    for t in tasks {
        statuses.push(t.await.expect("a task"));
    }
    statuses.sort_unstable();
    assert_eq!(statuses, [201, 201, 429, 429, 429, 429]);
    assert_eq!(submissions_in_store(store, &id, "busy").await, 2);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn submissions_at_once_cannot_pass_the_limit_together_on_sqlite() {
    let dir = tempfile::tempdir().expect("a temp dir");
    let data = dir.path().join("data");
    concurrent_flow(&["--data-dir", data.to_str().expect("UTF-8")]).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs PostgreSQL: run .ci/test-all"]
async fn submissions_at_once_cannot_pass_the_limit_together_on_postgres() {
    let url = std::env::var("RAYTILE_TEST_DATABASE_URL")
        .expect("RAYTILE_TEST_DATABASE_URL names a PostgreSQL database");
    concurrent_flow(&["--database", &url]).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn grading_is_charged_to_the_memory_budget_before_it_starts() {
    let dir = tempfile::tempdir().expect("a temp dir");
    let data = dir.path().join("data");
    let data = data.to_str().expect("UTF-8");
    let server = serve(
        &[
            "--data-dir",
            data,
            "--max-body-bytes",
            "1048576",
            "--memory-bytes",
            "20MiB",
        ],
        &[("RAYTILE_ADMIN_TOKEN", ADMIN)],
    );
    // Grading a 2000 × 2000 frame takes hundreds of MiB: more than the whole budget.
    let big = resized(shipped("sphere.json"), 2000, 2000);
    let doc = assignment("Big", vec![entry("big", big, "image", "visible")]);
    assert_eq!(put(&server.url, "big", &doc, ADMIN, &[]).await.status, 201);
    let (answer, _, _) = submit(
        &server.url,
        "big",
        ADMIN,
        Submit {
            student: "s",
            files: vec![("big", "big.png", black_png())],
            report: None,
            key: None,
        },
    )
    .await;
    assert_eq!(answer.status, 422);
    let body = json_of(&answer);
    assert_eq!(body["type"], "https://raytile.example/problems/over-memory");
    assert!(
        body["needed_bytes"].as_u64().expect("bytes") > 20 << 20,
        "{body}"
    );
    assert_eq!(
        submissions_in_store(&["--data-dir", data], "big", "s").await,
        0
    );
}
