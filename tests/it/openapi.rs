//! `api/openapi.yaml` and the server agree: every documented operation exists, and
//! every answer the server gives (successes for every example scene, and each kind of
//! error) has a documented status, a documented media type, the documented headers,
//! and a body that validates against the documented schema (JSON Schema 2020-12, the
//! dialect of OpenAPI 3.1, with `$ref: scene.schema.json` resolved to
//! `api/scene.schema.json`).

use std::path::Path;
use std::time::Duration;

use axum::body::Body;
use axum::http::{HeaderMap, Request};
use jsonschema::{Draft, Resource, Validator};
use raytile::config::ServeArgs;
use raytile::server::shutdown::Phase;
use serde_json::{Value, json};
use tower::ServiceExt;

use crate::support_server::*;

/// The base the document's relative `$ref`s resolve against.
const BASE: &str = "https://raytile.example/api/";

fn api_dir() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/api"))
}

/// The OpenAPI document as JSON.
pub(crate) fn document() -> Value {
    let text = std::fs::read_to_string(api_dir().join("openapi.yaml")).expect("api/openapi.yaml");
    serde_yaml_ng::from_str(&text).expect("openapi.yaml is YAML")
}

fn scene_schema() -> Value {
    let text =
        std::fs::read_to_string(api_dir().join("scene.schema.json")).expect("the scene schema");
    serde_json::from_str(&text).expect("the scene schema is JSON")
}

/// Follows a local `$ref` (`#/components/…`) of an OpenAPI object.
fn resolve<'a>(doc: &'a Value, v: &'a Value) -> &'a Value {
    match v.get("$ref").and_then(Value::as_str) {
        Some(r) if r.starts_with("#/") => doc.pointer(&r[1..]).unwrap_or(&Value::Null),
        _ => v,
    }
}

/// A validator for `schema`, a schema of the document: it is placed in a root that
/// carries the document's `components` (so `#/components/schemas/…` resolves) and
/// whose base makes `scene.schema.json` the scene schema.
fn validator(doc: &Value, schema: &Value) -> Validator {
    let root = json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": format!("{BASE}openapi.json"),
        "components": doc["components"],
        "allOf": [schema],
    });
    jsonschema::options()
        .with_draft(Draft::Draft202012)
        .with_resource(
            format!("{BASE}scene.schema.json"),
            Resource::from_contents(scene_schema()),
        )
        .build(&root)
        .unwrap_or_else(|e| panic!("the documented schema {schema} does not compile: {e}"))
}

/// One answer of the server, as the checks need it.
pub(crate) struct Answer {
    pub(crate) status: u16,
    headers: HeaderMap,
    pub(crate) body: Vec<u8>,
}

impl Answer {
    pub(crate) async fn from_reqwest(res: reqwest::Response) -> Answer {
        Answer {
            status: res.status().as_u16(),
            headers: res.headers().clone(),
            body: res.bytes().await.expect("a body").to_vec(),
        }
    }

    async fn from_axum(res: axum::response::Response) -> Answer {
        let status = res.status().as_u16();
        let headers = res.headers().clone();
        let body = axum::body::to_bytes(res.into_body(), usize::MAX)
            .await
            .expect("a body")
            .to_vec();
        Answer {
            status,
            headers,
            body,
        }
    }
}

/// Checks `answer` to `method path` against the document.
pub(crate) fn check(doc: &Value, method: &str, path: &str, answer: &Answer) {
    let what = format!("{} {path} → {}", method.to_uppercase(), answer.status);
    let op = &doc["paths"][path][method];
    assert!(op.is_object(), "{what}: operation not documented");
    let response = resolve(doc, &op["responses"][answer.status.to_string()]);
    assert!(response.is_object(), "{what}: status not documented");
    let media = answer
        .headers
        .get("content-type")
        .and_then(|v| v.to_str().ok())
        .unwrap_or("")
        .split(';')
        .next()
        .unwrap_or("")
        .trim()
        .to_owned();
    let content = &response["content"][&media];
    assert!(
        content.is_object(),
        "{what}: media type `{media}` not documented"
    );
    if let Some(headers) = response["headers"].as_object() {
        for name in headers.keys() {
            // Trailer is sent only to clients that asked for trailers.
            if !name.eq_ignore_ascii_case("trailer") {
                assert!(
                    answer
                        .headers
                        .contains_key(name.to_ascii_lowercase().as_str()),
                    "{what}: documented header {name} missing"
                );
            }
        }
    }
    let schema = &content["schema"];
    let instances: Vec<Value> = if media == "application/json" || media.ends_with("+json") {
        vec![serde_json::from_slice(&answer.body).expect("a JSON body")]
    } else if media == "application/x-ndjson" {
        std::str::from_utf8(&answer.body)
            .expect("UTF-8 lines")
            .lines()
            .map(|l| serde_json::from_str(l).expect("a JSON line"))
            .collect()
    } else {
        Vec::new()
    };
    if instances.is_empty() {
        return;
    }
    let v = validator(doc, schema);
    for instance in &instances {
        let errors: Vec<String> = v
            .iter_errors(instance)
            .take(5)
            .map(|e| format!("{} at {}", e, e.instance_path()))
            .collect();
        assert!(
            errors.is_empty(),
            "{what}: the body does not match the documented schema:\n{}",
            errors.join("\n")
        );
    }
}

fn scene_names() -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(crate::support::scene(""))
        .unwrap()
        .filter_map(|e| {
            let p = e.ok()?.path();
            (p.extension()? == "json").then(|| p.file_stem()?.to_str().map(String::from))?
        })
        .collect();
    names.sort();
    names
}

/// Every local `$ref` of `v`, with the JSON pointer where it stands.
fn local_refs(v: &Value, at: String, out: &mut Vec<(String, String)>) {
    match v {
        Value::Object(m) => {
            for (k, x) in m {
                if let Some(p) = x
                    .as_str()
                    .filter(|_| k == "$ref")
                    .and_then(|r| r.strip_prefix('#'))
                {
                    out.push((at.clone(), p.to_owned()));
                }
                local_refs(
                    x,
                    format!("{at}/{}", k.replace('~', "~0").replace('/', "~1")),
                    out,
                );
            }
        }
        Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                local_refs(x, format!("{at}/{i}"), out);
            }
        }
        _ => {}
    }
}

#[test]
fn every_local_reference_resolves() {
    // A component written twice under one key (a second `parameters:` block) leaves
    // the first one's members unresolvable; the YAML reader keeps only the last.
    let doc = document();
    let mut refs = Vec::new();
    local_refs(&doc, String::new(), &mut refs);
    assert!(refs.len() > 50, "{} local references", refs.len());
    let broken: Vec<_> = refs
        .iter()
        .filter(|(_, p)| doc.pointer(p).is_none())
        .collect();
    assert!(broken.is_empty(), "unresolvable: {broken:?}");
}

#[test]
fn the_document_is_openapi_3_1_and_its_schemas_compile() {
    let doc = document();
    assert!(doc["openapi"].as_str().unwrap().starts_with("3.1."));
    for (name, schema) in doc["components"]["schemas"].as_object().unwrap() {
        let _ = validator(&doc, schema);
        assert!(schema.is_object(), "{name}");
    }
    // Every operation documents its responses, each with a description.
    for (path, item) in doc["paths"].as_object().unwrap() {
        for (method, op) in item.as_object().unwrap() {
            let responses = op["responses"].as_object().unwrap_or_else(|| {
                panic!("{method} {path}: no responses");
            });
            for (status, r) in responses {
                assert!(
                    resolve(&doc, r)["description"].is_string(),
                    "{method} {path} {status}"
                );
            }
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_documented_operation_is_served() {
    let doc = document();
    let app = TestApp::spawn().await;
    let lecture = serde_json::to_vec(&shipped("lecture.json")).unwrap();
    // A grading request in the JSON form: the lecture's own hit data.
    let hits: Value = app
        .post_json("/v1/hits", lecture.clone(), &[])
        .await
        .json()
        .await
        .unwrap();
    let grading = serde_json::to_vec(&json!({
        "scene": shipped("lecture.json"),
        "submission": hits,
    }))
    .unwrap();
    for (path, item) in doc["paths"].as_object().unwrap() {
        if path.starts_with("/v1/assignments") {
            // They need the database and tokens: `assignments_http` checks every answer.
            continue;
        }
        for method in item.as_object().unwrap().keys() {
            let url = app.at(&path.replace("{name}", "showcase"));
            let (url, body) = match path.as_str() {
                "/v1/trace" => (format!("{url}?u=2&v=2"), lecture.clone()),
                "/v1/grade" => (url, grading.clone()),
                _ => (url, lecture.clone()),
            };
            let req = match method.as_str() {
                "get" => app.client.get(&url),
                "post" => app
                    .client
                    .post(&url)
                    .header("content-type", "application/json")
                    .body(body),
                other => panic!("{other} {path}: a method the test does not know"),
            };
            let answer = Answer::from_reqwest(req.send().await.unwrap()).await;
            assert_eq!(answer.status, 200, "{method} {path}");
            check(&doc, method, path, &answer);
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn answers_for_every_example_scene_match_their_schemas() {
    let doc = document();
    let app = TestApp::spawn().await;
    let small = "/v1/render?region=0,0,5,5";
    for name in scene_names() {
        let scene = shipped(&format!("{name}.json"));
        let body = serde_json::to_vec(&scene).unwrap();

        let get = Answer::from_reqwest(app.get(&format!("/v1/scenes/{name}")).await).await;
        check(&doc, "get", "/v1/scenes/{name}", &get);

        let res = app.post_json("/v1/validate", body.clone(), &[]).await;
        check(
            &doc,
            "post",
            "/v1/validate",
            &Answer::from_reqwest(res).await,
        );

        let res = app.post_json(small, body.clone(), &[]).await;
        check(&doc, "post", "/v1/render", &Answer::from_reqwest(res).await);

        // A corner of at most 40 × 40 keeps the documents small.
        let side = |k: &str| scene["image"][k].as_u64().unwrap().min(40);
        let hits = format!("/v1/hits?region=0,0,{},{}", side("width"), side("height"));
        for accept in [
            "application/json",
            "application/x-ndjson",
            "application/x-npy",
            "text/csv",
        ] {
            let res = app
                .post_json(&hits, body.clone(), &[("accept", accept)])
                .await;
            assert_eq!(res.status(), 200, "{name} {accept}");
            check(&doc, "post", "/v1/hits", &Answer::from_reqwest(res).await);
        }

        // The middle pixel, explained as JSON and as text.
        let (w, h) = (side("width") as u32, side("height") as u32);
        let centre = |k: &str| scene["image"][k].as_u64().unwrap() / 2;
        let trace = format!("/v1/trace?u={}&v={}", centre("width"), centre("height"));
        for accept in ["application/json", "text/plain"] {
            let res = app
                .post_json(&trace, body.clone(), &[("accept", accept)])
                .await;
            assert_eq!(res.status(), 200, "{name} {accept}");
            check(&doc, "post", "/v1/trace", &Answer::from_reqwest(res).await);
        }

        // Grading at most 40 × 40 of it: its own image and hit data, in every report form.
        let small_scene = resized(scene.clone(), w, h);
        let small_body = serde_json::to_vec(&small_scene).unwrap();
        let png = app
            .post_json("/v1/render", small_body.clone(), &[])
            .await
            .bytes()
            .await
            .unwrap();
        let hits: Value = app
            .post_json("/v1/hits", small_body.clone(), &[])
            .await
            .json()
            .await
            .unwrap();
        for query in [
            "",
            "?report=text",
            "?report=gradescope&max_score=5",
            "?report=prairielearn",
            "?output=diff",
            "?inline_diff=true&flip=false",
        ] {
            let form = reqwest::multipart::Form::new()
                .part(
                    "scene",
                    reqwest::multipart::Part::bytes(small_body.clone()).file_name("scene.json"),
                )
                .part(
                    "submission",
                    reqwest::multipart::Part::bytes(png.to_vec())
                        .file_name("student.png")
                        .mime_str("image/png")
                        .unwrap(),
                );
            let res = app
                .client
                .post(app.at(&format!("/v1/grade{query}")))
                .multipart(form)
                .send()
                .await
                .unwrap();
            assert_eq!(res.status(), 200, "{name} {query}");
            check(&doc, "post", "/v1/grade", &Answer::from_reqwest(res).await);
        }
        let grading =
            serde_json::to_vec(&json!({ "scene": small_scene, "submission": hits })).unwrap();
        let res = app.post_json("/v1/grade", grading, &[]).await;
        assert_eq!(res.status(), 200, "{name} hits");
        check(&doc, "post", "/v1/grade", &Answer::from_reqwest(res).await);
    }
    for path in ["/v1/scenes", "/healthz", "/readyz", "/metrics"] {
        check(
            &doc,
            "get",
            path,
            &Answer::from_reqwest(app.get(path).await).await,
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_error_answer_is_documented() {
    let doc = document();
    let app = TestApp::with(ServeArgs {
        max_body_bytes: 4096,
        ..config()
    })
    .await;
    let lecture = serde_json::to_vec(&shipped("lecture.json")).unwrap();
    let post = |path: &str, body: Vec<u8>, headers: &[(&str, &str)]| {
        let mut req = app.client.post(app.at(path)).body(body);
        for (k, v) in headers {
            req = req.header(*k, *v);
        }
        req.send()
    };
    let json = ("content-type", "application/json");
    // The JSON form of a grading request with `png` as the submission.
    let grading = |png: &[u8]| {
        use base64::Engine as _;
        serde_json::to_vec(&json!({
            "scene": shipped("lecture.json"),
            "submission": {
                "png_base64": base64::engine::general_purpose::STANDARD.encode(png),
            },
        }))
        .unwrap()
    };
    let cases: Vec<(&str, &str, reqwest::Response)> = vec![
        (
            "post",
            "/v1/render",
            post("/v1/render", b"{".to_vec(), &[json]).await.unwrap(),
        ),
        (
            "post",
            "/v1/hits",
            post("/v1/hits?region=9,9,9,9", lecture.clone(), &[json])
                .await
                .unwrap(),
        ),
        (
            "post",
            "/v1/hits",
            post(
                "/v1/hits",
                lecture.clone(),
                &[json, ("accept", "image/gif")],
            )
            .await
            .unwrap(),
        ),
        (
            "post",
            "/v1/validate",
            post("/v1/validate", vec![b' '; 5000], &[json])
                .await
                .unwrap(),
        ),
        (
            "post",
            "/v1/validate",
            post(
                "/v1/validate",
                lecture.clone(),
                &[("content-type", "text/csv")],
            )
            .await
            .unwrap(),
        ),
        (
            "post",
            "/v1/render",
            post("/v1/render", br#"{"version": 1}"#.to_vec(), &[json])
                .await
                .unwrap(),
        ),
        ("get", "/v1/scenes/{name}", app.get("/v1/scenes/none").await),
        (
            "post",
            "/v1/trace",
            post("/v1/trace?v=1", lecture.clone(), &[json])
                .await
                .unwrap(),
        ),
        (
            "post",
            "/v1/trace",
            post(
                "/v1/trace?u=1&v=1",
                lecture.clone(),
                &[json, ("accept", "image/png")],
            )
            .await
            .unwrap(),
        ),
        (
            "post",
            "/v1/trace",
            post("/v1/trace?u=5&v=0", lecture.clone(), &[json])
                .await
                .unwrap(),
        ),
        (
            "post",
            "/v1/trace",
            post("/v1/trace?u=0&v=0", br#"{"version": 1}"#.to_vec(), &[json])
                .await
                .unwrap(),
        ),
        (
            "post",
            "/v1/grade",
            post(
                "/v1/grade",
                b"x".to_vec(),
                &[("content-type", "text/plain")],
            )
            .await
            .unwrap(),
        ),
        (
            "post",
            "/v1/grade",
            post("/v1/grade", b"{".to_vec(), &[json]).await.unwrap(),
        ),
        (
            "post",
            "/v1/grade",
            post("/v1/grade?worst=-1", lecture.clone(), &[json])
                .await
                .unwrap(),
        ),
        (
            "post",
            "/v1/grade",
            post("/v1/grade", grading(b"not a png"), &[json])
                .await
                .unwrap(),
        ),
        (
            "post",
            "/v1/grade",
            post("/v1/grade", vec![b' '; 5000], &[json]).await.unwrap(),
        ),
        // 405 is documented with the operations the path has.
        ("post", "/v1/render", app.get("/v1/render").await),
    ];
    let mut statuses = Vec::new();
    for (method, path, res) in cases {
        let answer = Answer::from_reqwest(res).await;
        statuses.push(answer.status);
        check(&doc, method, path, &answer);
    }
    assert_eq!(
        statuses,
        [
            400, 400, 406, 413, 415, 422, 404, 400, 406, 422, 422, 415, 400, 400, 422, 413, 405
        ]
    );

    // 503 and 504, straight through the router (no network needed).
    let state = raytile::server::AppState::new(ServeArgs {
        deadline_seconds: 0.2,
        ..config()
    })
    .unwrap();
    let router = raytile::server::app(state.clone());
    let stalled = Request::post("/v1/render")
        .header("content-type", "application/json")
        .body(Body::from_stream(futures::stream::pending::<
            Result<Vec<u8>, std::io::Error>,
        >()))
        .unwrap();
    let answer = tokio::time::timeout(Duration::from_secs(60), router.clone().oneshot(stalled))
        .await
        .expect("the deadline answers")
        .unwrap();
    let answer = Answer::from_axum(answer).await;
    assert_eq!(answer.status, 504);
    check(&doc, "post", "/v1/render", &answer);
    // The same for a grading request whose form never finishes arriving.
    let stalled = Request::post("/v1/grade")
        .header("content-type", "multipart/form-data; boundary=x")
        .body(Body::from_stream(futures::stream::pending::<
            Result<Vec<u8>, std::io::Error>,
        >()))
        .unwrap();
    let answer = tokio::time::timeout(Duration::from_secs(60), router.clone().oneshot(stalled))
        .await
        .expect("the deadline answers")
        .unwrap();
    let answer = Answer::from_axum(answer).await;
    assert_eq!(answer.status, 504);
    check(&doc, "post", "/v1/grade", &answer);

    state.shutdown.advance(Phase::Draining);
    for (method, path, body) in [
        ("post", "/v1/render", lecture.clone()),
        ("post", "/v1/hits", lecture.clone()),
        ("post", "/v1/trace?u=0&v=0", lecture.clone()),
        ("post", "/v1/grade", grading(&render_lecture())),
        ("get", "/readyz", Vec::new()),
    ] {
        let req = Request::builder()
            .method(method.to_uppercase().as_str())
            .uri(path)
            .header("content-type", "application/json")
            .body(Body::from(body))
            .unwrap();
        let answer = Answer::from_axum(router.clone().oneshot(req).await.unwrap()).await;
        assert_eq!(answer.status, 503, "{path}");
        check(&doc, method, path.split('?').next().unwrap(), &answer);
    }
}

/// The lecture's image, as `raytile render` writes it.
fn render_lecture() -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("lecture.png");
    let scene = crate::support::scene("lecture.json");
    let run = crate::support::run(&[
        "render",
        scene.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    std::fs::read(out).unwrap()
}
