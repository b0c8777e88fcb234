//! The memory budget as a client sees it: what can never fit is refused with the field
//! at fault, what does not fit now waits or gets 503 with `Retry-After`, what fits
//! works, and the ledger returns to zero after every request.

use std::time::Duration;

use raytile::config::ServeArgs;
use raytile::server::AppState;
use serde_json::{Value, json};
use std::io::Write;

use crate::support_server::{TestApp, config, problem, shipped};

const RESERVED: &str = "raytile_memory_reserved_bytes";
const REFUSED: &str = "raytile_rejected_requests_total{reason=\"memory\"}";

/// The test defaults with the smallest budget the default body limit allows (48 MiB).
fn small(queue: usize) -> ServeArgs {
    ServeArgs {
        memory_bytes: 48 << 20,
        queue,
        ..config()
    }
}

async fn ledger_back_to_zero(app: &TestApp) {
    app.wait_for_metric(RESERVED, Duration::from_secs(10), |v| v == 0.0)
        .await;
}

#[tokio::test]
async fn a_budget_too_small_for_the_body_limit_is_a_startup_error() {
    let e = AppState::new(ServeArgs {
        memory_bytes: 40 << 20,
        ..config()
    })
    .expect_err("refused");
    let message = e.to_string();
    assert!(
        message.contains("--memory-bytes 41943040 is too small"),
        "{message}"
    );
    assert!(message.contains("--max-body-bytes"), "{message}");
}

#[tokio::test]
async fn a_frame_too_wide_to_stream_within_the_budget_is_refused_with_its_pointer() {
    // A PNG's encoder holds three rows of the frame: 16 M pixels wide, 150 MB, more
    // than the smallest budget (48 MiB).
    let app = TestApp::with(small(4)).await;
    let mut scene = shipped("lecture.json");
    scene["image"] = json!({ "width": 16_777_216, "height": 1 });
    let res = app.post_scene("/v1/render", &scene).await;
    let doc = problem(res, 422, "over-memory").await;
    assert_eq!(doc["problems"][0]["pointer"], "/image/width", "{doc}");
    assert_eq!(doc["budget_bytes"], 48u64 << 20, "{doc}");
    assert!(doc["needed_bytes"].as_u64().unwrap() > 48 << 20, "{doc}");
    assert_eq!(app.metric(REFUSED).await, 1.0);
    // Hit data streams in bounded pieces whatever the width: the same budget serves a
    // row of 4 000 000 pixels (the answer is left unread: dropping it stops the render).
    scene["image"] = json!({ "width": 4_000_000, "height": 1 });
    let res = app.post_scene("/v1/hits", &scene).await;
    assert_eq!(res.status(), 200);
    drop(res);
    ledger_back_to_zero(&app).await;
}

/// `n` objects, each with a problem: validation reads them through a JSON tree.
fn invalid_objects(n: usize) -> Value {
    let mut scene = shipped("lecture.json");
    scene["objects"] = Value::Array(vec![json!({ "shape": "sphere", "radius": -1 }); n]);
    scene
}

#[tokio::test]
async fn a_scene_whose_parse_can_never_fit_is_refused_before_it_is_parsed() {
    let app = TestApp::with(small(4)).await;
    let res = app
        .post_scene("/v1/validate", &invalid_objects(60_000))
        .await;
    let doc = problem(res, 422, "over-memory").await;
    assert_eq!(doc["problems"][0]["pointer"], "/objects", "{doc}");
    assert!(
        doc["detail"]
            .as_str()
            .unwrap()
            .contains("parsing the scene"),
        "{doc}"
    );
    // A few such objects are parsed as ever: every problem listed.
    let res = app.post_scene("/v1/validate", &invalid_objects(3)).await;
    let doc = problem(res, 422, "invalid-scene").await;
    assert!(doc["problems"].as_array().unwrap().len() >= 3, "{doc}");
    ledger_back_to_zero(&app).await;
}

/// A `/v1/grade` envelope of the lecture's scene and `pixels` as its submission.
fn envelope(pixels: usize) -> Vec<u8> {
    serde_json::to_vec(&json!({
        "scene": shipped("lecture.json"),
        "submission": vec![json!({ "hit": false }); pixels],
    }))
    .unwrap()
}

#[tokio::test]
async fn a_submission_that_can_never_be_read_within_the_budget_is_refused_naming_it() {
    let app = TestApp::with(small(4)).await;
    let res = app.post_json("/v1/grade", envelope(300_000), &[]).await;
    let doc = problem(res, 422, "over-memory").await;
    assert_eq!(doc["problems"][0]["pointer"], "/submission", "{doc}");
    assert_eq!(doc["problems"][1]["pointer"], "/scene/image/width", "{doc}");
    assert_eq!(app.metric(REFUSED).await, 1.0);
    ledger_back_to_zero(&app).await;
}

#[tokio::test]
async fn a_duplicate_key_in_the_scene_of_a_grade_envelope_is_refused_with_its_pointer() {
    let app = TestApp::spawn().await;
    let scene = serde_json::to_string(&shipped("lecture.json")).unwrap();
    // serde_json keeps one of two equal keys: write the second by hand.
    let doubled = scene.replacen("\"width\":5", "\"width\":5,\"width\":7", 1);
    assert_ne!(doubled, scene);
    let body = format!(r#"{{"scene": {doubled}, "submission": [{{"hit": false}}]}}"#);
    let res = app.post_json("/v1/grade", body, &[]).await;
    let doc = problem(res, 422, "invalid-scene").await;
    assert_eq!(doc["problems"][0]["pointer"], "/scene/image/width", "{doc}");
    assert!(
        doc["problems"][0]["message"]
            .as_str()
            .unwrap()
            .contains("duplicate key"),
        "{doc}"
    );
}

/// A request declaring a body of `--max-body-bytes` that sends a few bytes of it and
/// then nothing: it holds its body's charge while it is open.
fn slow_upload(app: &TestApp) -> std::net::TcpStream {
    // A few bytes written to loopback never block.
    let mut s = std::net::TcpStream::connect(app.addr).unwrap();
    let head = format!(
        "POST /v1/validate HTTP/1.1\r\nhost: x\r\ncontent-type: application/json\r\n\
         content-length: {}\r\n\r\n{{\"version\"",
        16 << 20
    );
    s.write_all(head.as_bytes()).unwrap();
    s
}

#[tokio::test]
async fn requests_that_do_not_fit_now_wait_or_get_503_and_the_ledger_returns_to_zero() {
    let app = TestApp::with(small(1)).await;
    // Three bodies of 16 MiB in flight take the whole 48 MiB.
    let mut uploads = Vec::new();
    for _ in 0..3 {
        uploads.push(slow_upload(&app));
    }
    app.wait_for_metric(RESERVED, Duration::from_secs(10), |v| {
        v == (48 << 20) as f64
    })
    .await;
    // One more waits (the queue holds one)...
    let (url, client) = (app.at("/v1/validate"), app.client.clone());
    let body = serde_json::to_vec(&shipped("lecture.json")).unwrap();
    let waiting = tokio::spawn({
        let body = body.clone();
        async move {
            client
                .post(url)
                .header("content-type", "application/json")
                .body(body)
                .send()
                .await
                .unwrap()
                .status()
                .as_u16()
        }
    });
    while app.state.memory.waiting() == 0 {
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    // ...and the next is refused at once, to be retried.
    let res = app.post_json("/v1/validate", body.clone(), &[]).await;
    assert_eq!(
        res.headers()
            .get("retry-after")
            .and_then(|v| v.to_str().ok()),
        Some("1")
    );
    problem(res, 503, "memory-full").await;
    assert_eq!(app.metric(REFUSED).await, 1.0);
    // A client that leaves gives its memory back: the waiting request goes ahead.
    uploads.pop();
    assert_eq!(waiting.await.unwrap(), 200);
    drop(uploads);
    ledger_back_to_zero(&app).await;
    // Now everything fits again: a render streams as ever.
    let res = app.post_scene("/v1/render", &shipped("lecture.json")).await;
    assert_eq!(res.status(), 200);
    let png = res.bytes().await.unwrap();
    assert!(png.starts_with(b"\x89PNG"));
    ledger_back_to_zero(&app).await;
}

#[tokio::test]
async fn renders_hits_and_grades_that_fit_work_and_give_their_memory_back() {
    let app = TestApp::spawn().await;
    assert_eq!(
        app.metric("raytile_memory_budget_bytes").await,
        (768u64 << 20) as f64
    );
    let scene = shipped("lecture.json");
    for path in ["/v1/render", "/v1/hits", "/v1/validate"] {
        let res = app.post_scene(path, &scene).await;
        assert_eq!(res.status(), 200, "{path}");
        res.bytes().await.unwrap();
    }
    let res = app.post_json("/v1/grade", envelope(25), &[]).await;
    assert_eq!(res.status(), 200);
    res.bytes().await.unwrap();
    ledger_back_to_zero(&app).await;
    assert_eq!(app.metric(REFUSED).await, 0.0);
}
