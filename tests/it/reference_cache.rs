//! References rendered once, as a client sees it: grading the same scene again through
//! `/v1/grade` finds its reference in the cache (`raytile_reference_cache_*` on
//! `/metrics`), answers with the very bytes an uncached grade does, and concurrent grades
//! of one scene render it once; `--reference-cache-bytes 0` renders every time.

use raytile::config::ServeArgs;
use serde_json::{Value, json};

use crate::support::{decode_png, encode_png};
use crate::support_server::*;

const HITS: &str = "raytile_reference_cache_hits_total";
const MISSES: &str = "raytile_reference_cache_misses_total";
const BYTES: &str = "raytile_reference_cache_bytes";
const ENTRIES: &str = "raytile_reference_cache_entries";

async fn body_of(res: reqwest::Response, path: &str) -> Vec<u8> {
    assert_eq!(res.status(), 200, "{path}");
    res.bytes().await.unwrap().to_vec()
}

/// The scene's image with a band of wrong pixels (a failing submission: worst pixels,
/// statistics and a diagnosis in its report), and its hit data, from the server.
async fn submissions(app: &TestApp, scene: &Value) -> (Vec<u8>, Value) {
    let png = body_of(app.post_scene("/v1/render", scene).await, "/v1/render").await;
    let (w, h, mut px) = decode_png(&png);
    for p in px.iter_mut().take(3 * w as usize * 2) {
        *p = p.wrapping_add(40);
    }
    let hits = body_of(app.post_scene("/v1/hits", scene).await, "/v1/hits").await;
    (
        encode_png(w, h, &px),
        serde_json::from_slice(&hits).unwrap(),
    )
}

/// A `/v1/grade` JSON envelope.
fn envelope(scene: &Value, submission: Value) -> Vec<u8> {
    serde_json::to_vec(&json!({ "scene": scene, "submission": submission })).unwrap()
}

fn png_member(png: &[u8]) -> Value {
    use base64::Engine as _;
    json!({ "png_base64": base64::engine::general_purpose::STANDARD.encode(png) })
}

async fn grade(app: &TestApp, body: &[u8]) -> Vec<u8> {
    let res = app
        .post_json("/v1/grade?worst=20", body.to_vec(), &[])
        .await;
    body_of(res, "/v1/grade").await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_grade_of_a_scene_does_not_render_it_and_answers_the_same_bytes() {
    let app = TestApp::spawn().await;
    let scene = resized(shipped("sphere.json"), 48, 36);
    let (png, hits) = submissions(&app, &scene).await;
    let image = envelope(&scene, png_member(&png));
    let hit_data = envelope(&scene, hits);
    assert_eq!(
        (app.metric(HITS).await, app.metric(MISSES).await),
        (0.0, 0.0)
    );

    let first = grade(&app, &image).await;
    assert_eq!(
        (app.metric(HITS).await, app.metric(MISSES).await),
        (0.0, 1.0)
    );
    assert_eq!(app.metric(ENTRIES).await, 1.0);
    // The 8-bit reference, 48 × 36 × 3 bytes, and a little for the entry.
    let held = app.metric(BYTES).await;
    assert!((5184.0..=5184.0 + 1024.0).contains(&held), "{held}");
    let second = grade(&app, &image).await;
    assert_eq!(
        (app.metric(HITS).await, app.metric(MISSES).await),
        (1.0, 1.0)
    );
    assert_eq!(first, second, "a cached reference grades to the same bytes");
    let report: Value = serde_json::from_slice(&second).unwrap();
    assert_eq!(report["pass"], false, "{report}");

    // The hit data is another reference of the same scene.
    let hits_first = grade(&app, &hit_data).await;
    let hits_second = grade(&app, &hit_data).await;
    assert_eq!(hits_first, hits_second);
    assert_eq!(
        (app.metric(HITS).await, app.metric(MISSES).await),
        (2.0, 2.0)
    );
    assert_eq!(app.metric(ENTRIES).await, 2.0);

    // A server without a cache renders every time, and answers the same bytes.
    let uncached = TestApp::with(ServeArgs {
        reference_cache_bytes: Some(0),
        ..config()
    })
    .await;
    for _ in 0..2 {
        assert_eq!(grade(&uncached, &image).await, first);
        assert_eq!(grade(&uncached, &hit_data).await, hits_first);
    }
    assert_eq!(uncached.metric(MISSES).await, 4.0);
    assert_eq!(uncached.metric(HITS).await, 0.0);
    assert_eq!(uncached.metric(ENTRIES).await, 0.0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn concurrent_grades_of_one_scene_render_its_reference_once() {
    let app = TestApp::with(ServeArgs {
        queue: 16,
        ..config()
    })
    .await;
    let scene = sphere_grid(160, 120, 4, 2);
    // A passing submission: nothing in its report depends on how long grading took.
    let png = body_of(app.post_scene("/v1/render", &scene).await, "/v1/render").await;
    let body = envelope(&scene, png_member(&png));
    let grades: Vec<_> = (0..6)
        .map(|_| {
            let (client, url, body) = (
                app.client.clone(),
                app.at("/v1/grade?worst=20"),
                body.clone(),
            );
            tokio::spawn(async move {
                let res = client
                    .post(url)
                    .header("content-type", "application/json")
                    .body(body)
                    .send()
                    .await
                    .unwrap();
                assert_eq!(res.status(), 200);
                res.bytes().await.unwrap()
            })
        })
        .collect();
    let mut answers = Vec::new();
    for g in grades {
        answers.push(g.await.unwrap());
    }
    assert!(answers.windows(2).all(|w| w[0] == w[1]));
    assert_eq!(app.metric(MISSES).await, 1.0, "rendered once");
    assert_eq!(app.metric(HITS).await, 5.0);
}

// ---- assignment submissions ------------------------------------------------------------

async fn metric_of(url: &str, name: &str) -> f64 {
    let text = client()
        .get(format!("{url}/metrics"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    metric_value(&text, name).unwrap_or_else(|| panic!("no {name} in {text}"))
}

async fn post_as_admin(url: &str, path: &str, scene: &Value) -> Vec<u8> {
    let res = client()
        .post(format!("{url}{path}"))
        .header("authorization", format!("Bearer {}", crate::auth::ADMIN))
        .header("content-type", "application/json")
        .body(serde_json::to_vec(scene).unwrap())
        .send()
        .await
        .unwrap();
    body_of(res, path).await
}

/// Submits `files` (scene name, file name, bytes) for `student`: the JSON result.
async fn submit(url: &str, id: &str, student: &str, files: &[(&str, &str, Vec<u8>)]) -> Value {
    let mut form = reqwest::multipart::Form::new().text("student", student.to_owned());
    for (scene, file, bytes) in files {
        form = form.part(
            scene.to_string(),
            reqwest::multipart::Part::bytes(bytes.clone()).file_name(file.to_string()),
        );
    }
    let res = client()
        .post(format!("{url}/v1/assignments/{id}/submissions"))
        .header("authorization", format!("Bearer {}", crate::auth::ADMIN))
        .multipart(form)
        .send()
        .await
        .unwrap();
    assert_eq!(res.status(), 201);
    res.json().await.unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn submissions_of_an_assignment_render_each_reference_once() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let server = crate::auth::serve(
        &["--data-dir", data.to_str().unwrap()],
        &[("RAYTILE_ADMIN_TOKEN", crate::auth::ADMIN)],
    );
    let url = server.url.clone();
    let spheres = resized(shipped("sphere.json"), 40, 30);
    let cubes = resized(shipped("cube.json"), 40, 30);
    let doc = json!({"version": 1, "title": "Once", "scenes": [
        {"name": "spheres", "scene": spheres, "points": 5, "grade": "image", "visibility": "visible"},
        {"name": "cubes", "scene": cubes, "points": 5, "grade": "both", "visibility": "hidden"}]});
    let res = client()
        .put(format!("{url}/v1/assignments/once"))
        .header("authorization", format!("Bearer {}", crate::auth::ADMIN))
        .header("content-type", "application/json")
        .body(serde_json::to_vec(&doc).unwrap())
        .send()
        .await
        .unwrap();
    assert_eq!(res.status(), 201);
    let files = vec![
        (
            "spheres",
            "spheres.png",
            post_as_admin(&url, "/v1/render", &spheres).await,
        ),
        (
            "cubes",
            "cubes.png",
            post_as_admin(&url, "/v1/render", &cubes).await,
        ),
        (
            "cubes",
            "cubes.json",
            post_as_admin(&url, "/v1/hits", &cubes).await,
        ),
    ];
    // Four students at once: three references (two scenes, one of them graded twice),
    // each rendered once.
    let first: Vec<_> = (0..4)
        .map(|i| {
            let (url, files) = (url.clone(), files.clone());
            tokio::spawn(async move { submit(&url, "once", &format!("s{i}"), &files).await })
        })
        .collect();
    let mut results = Vec::new();
    for f in first {
        results.push(f.await.unwrap());
    }
    assert_eq!(metric_of(&url, MISSES).await, 3.0);
    assert_eq!(metric_of(&url, HITS).await, 9.0);
    assert_eq!(metric_of(&url, ENTRIES).await, 3.0);
    // A later submission renders nothing, and fares as the first did.
    results.push(submit(&url, "once", "late", &files).await);
    assert_eq!(metric_of(&url, MISSES).await, 3.0);
    assert_eq!(metric_of(&url, HITS).await, 12.0);
    for r in &results {
        assert_eq!(r["score"], 10.0, "{r}");
        assert_eq!(r["scenes"], results[0]["scenes"]);
    }
}
