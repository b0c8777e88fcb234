//! The HTTP service as a client sees it: the real router on a loopback port (and, for
//! SIGTERM, the real binary), spoken to with reqwest or, where a client library would
//! hide what is tested, raw TCP. Every wait is bounded; no assertion depends on how fast
//! the machine is, only on the order things happen in.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::process::Command;
use std::time::{Duration, Instant};

use raytile::config::ServeArgs;
use raytile::format::npy::{NPY_DESCR, NPY_RECORD_BYTES};
use serde_json::{Value, json};

use crate::support::{decode_png, raytile, scene_file};
use crate::support_server::*;

/// The PNG signature.
const PNG_SIGNATURE: &[u8] = b"\x89PNG\r\n\x1a\n";

/// Runs `raytile <command> <scene> -o <out> [args]` and returns the output file.
fn cli_output(command: &str, scene: &Value, out_name: &str, args: &[&str]) -> Vec<u8> {
    let dir = tempfile::tempdir().expect("a temp dir");
    let input = scene_file(&dir, "scene.json", scene);
    let out = dir.path().join(out_name);
    let status = raytile()
        .arg(command)
        .arg(&input)
        .arg("-o")
        .arg(&out)
        .args(args)
        .status()
        .expect("raytile runs");
    assert!(status.success(), "raytile {command} failed");
    std::fs::read(out).expect("the output file")
}

fn header<'a>(res: &'a reqwest::Response, name: &str) -> &'a str {
    res.headers()
        .get(name)
        .and_then(|v| v.to_str().ok())
        .unwrap_or_else(|| panic!("no {name} header"))
}

// ---- /v1/render ------------------------------------------------------------------

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn render_is_byte_identical_to_the_command_line() {
    let app = TestApp::spawn().await;
    for name in ["sphere.json", "mesh.json", "lecture.json"] {
        let scene = shipped(name);
        let expected = cli_output("render", &scene, "out.png", &[]);
        let res = app.post_scene("/v1/render", &scene).await;
        assert_eq!(res.status(), 200, "{name}");
        assert_eq!(header(&res, "content-type"), "image/png");
        let (w, h) = (
            scene["image"]["width"].clone(),
            scene["image"]["height"].clone(),
        );
        assert_eq!(header(&res, "x-raytile-width"), w.to_string());
        assert_eq!(header(&res, "x-raytile-height"), h.to_string());
        assert_eq!(header(&res, "x-raytile-region"), format!("0,0,{w},{h}"));
        let timing = header(&res, "server-timing");
        assert!(
            timing.contains("parse;dur=") && timing.contains("queue;dur="),
            "{timing}"
        );
        assert_eq!(header(&res, "x-request-id").len(), 32);
        let body = res.bytes().await.expect("the PNG");
        assert!(
            body == expected,
            "{name}: the served PNG differs from `raytile render`"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_region_is_exactly_that_crop_of_the_full_render() {
    let app = TestApp::spawn().await;
    let scene = shipped("sphere.json");
    let full = app.post_scene("/v1/render", &scene).await;
    let (fw, _, full_px) = decode_png(&full.bytes().await.unwrap());
    let (x, y, w, h) = (37u32, 21u32, 101u32, 77u32);
    let res = app
        .post_json(
            &format!("/v1/render?region={x},{y},{w},{h}"),
            serde_json::to_vec(&scene).unwrap(),
            &[],
        )
        .await;
    assert_eq!(res.status(), 200);
    assert_eq!(header(&res, "x-raytile-width"), w.to_string());
    assert_eq!(header(&res, "x-raytile-height"), h.to_string());
    assert_eq!(header(&res, "x-raytile-region"), format!("{x},{y},{w},{h}"));
    let (rw, rh, region_px) = decode_png(&res.bytes().await.unwrap());
    assert_eq!((rw, rh), (w, h));
    for row in 0..h {
        let src = (((y + row) * fw + x) * 3) as usize;
        let dst = (row * w * 3) as usize;
        assert_eq!(
            region_px[dst..dst + (w * 3) as usize],
            full_px[src..src + (w * 3) as usize],
            "row {row} of the region"
        );
    }
    // The region's bytes are also what `raytile render --region` writes.
    let expected = cli_output(
        "render",
        &scene,
        "r.png",
        &["--region", &format!("{x},{y},{w},{h}")],
    );
    let again = app
        .post_json(
            &format!("/v1/render?region={x},{y},{w},{h}"),
            serde_json::to_vec(&scene).unwrap(),
            &[],
        )
        .await;
    assert!(again.bytes().await.unwrap() == expected);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_first_bytes_leave_before_the_last_tile_is_traced() {
    let app = TestApp::spawn().await;
    let scene = sphere_grid(2048, 2048, 10, 1);
    let total_tiles = (2048 / 32) * (2048 / 32);
    let mut res = app.post_scene("/v1/render", &scene).await;
    assert_eq!(res.status(), 200);
    // The PNG header leaves before anything is traced…
    let first = res.chunk().await.unwrap().expect("a first chunk");
    assert!(first.starts_with(PNG_SIGNATURE));
    let tiles_at_header = app.metric("raytile_tiles_traced_total").await;
    assert!(tiles_at_header < total_tiles as f64, "{tiles_at_header}");
    // …and image data (the first bands of rows) while the rest is still tracing.
    let mut got = first.to_vec();
    got.extend(read_at_least(&mut res, 2048).await);
    let tiles_at_data = app.metric("raytile_tiles_traced_total").await;
    assert!(
        tiles_at_data < total_tiles as f64,
        "{tiles_at_data} of {total_tiles} tiles were done when the first rows arrived"
    );
    while let Some(c) = res.chunk().await.expect("the rest") {
        got.extend_from_slice(&c);
    }
    let (w, h, _) = decode_png(&got);
    assert_eq!((w, h), (2048, 2048));
    assert_eq!(
        app.metric("raytile_tiles_traced_total").await,
        total_tiles as f64
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn trailers_carry_the_render_time_when_asked_for() {
    let app = TestApp::spawn().await;
    // reqwest does not expose trailers: read the raw chunked response.
    let body = serde_json::to_vec(&shipped("lecture.json")).unwrap();
    let raw = raw_request(
        app.addr,
        &format!(
            "POST /v1/render HTTP/1.1\r\nHost: t\r\nContent-Type: application/json\r\nTE: trailers\r\nConnection: close\r\nContent-Length: {}\r\n\r\n",
            body.len()
        ),
        &body,
    );
    let text = String::from_utf8_lossy(&raw).to_ascii_lowercase();
    assert!(text.starts_with("http/1.1 200"), "{text}");
    assert!(text.contains("trailer: server-timing, x-raytile-rays"));
    let tail = &text[text.rfind("iend").expect("a whole PNG")..];
    assert!(tail.contains("server-timing: render;dur="), "{tail}");
    assert!(tail.contains("x-raytile-rays: "), "{tail}");
}

// ---- /v1/hits --------------------------------------------------------------------

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hits_json_and_npy_are_byte_identical_to_the_command_line() {
    let app = TestApp::spawn().await;
    let scene = shipped("cube.json");
    for (accept, file) in [
        (None, "h.json"),
        (Some("application/json"), "h.json"),
        (Some("*/*"), "h.json"),
        (Some("application/x-npy"), "h.npy"),
    ] {
        let expected = cli_output("hits", &scene, file, &[]);
        let headers: Vec<(&str, &str)> = accept.iter().map(|a| ("accept", *a)).collect();
        let res = app
            .post_json("/v1/hits", serde_json::to_vec(&scene).unwrap(), &headers)
            .await;
        assert_eq!(res.status(), 200);
        let media = if file.ends_with("npy") {
            "application/x-npy"
        } else {
            "application/json"
        };
        assert_eq!(header(&res, "content-type"), media);
        assert!(res.bytes().await.unwrap() == expected, "{accept:?}");
    }
}

/// CSV is offered through `Accept` like the other forms: asked for by name, by `text/*`
/// or preferred by weight, and the bytes are the command line's, of a region too.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hits_as_csv_through_accept_are_the_command_line_bytes() {
    let app = TestApp::spawn().await;
    let scene = shipped("cube.json");
    let body = serde_json::to_vec(&scene).unwrap();
    let expected = cli_output("hits", &scene, "h.csv", &[]);
    for accept in ["text/csv", "text/*", "application/json;q=0.5, text/csv"] {
        let res = app
            .post_json("/v1/hits", body.clone(), &[("accept", accept)])
            .await;
        assert_eq!(res.status(), 200, "{accept}");
        assert_eq!(header(&res, "content-type"), "text/csv", "{accept}");
        assert!(res.bytes().await.unwrap() == expected, "{accept}");
    }
    let expected = cli_output("hits", &scene, "h.csv", &["--region", "3,2,20,9"]);
    let res = app
        .post_json("/v1/hits?region=3,2,20,9", body, &[("accept", "text/csv")])
        .await;
    assert_eq!(res.status(), 200);
    assert!(res.bytes().await.unwrap() == expected);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn npy_has_the_documented_dtype_and_shape() {
    let app = TestApp::spawn().await;
    let res = app
        .post_json(
            "/v1/hits?region=1,0,3,4",
            serde_json::to_vec(&shipped("lecture.json")).unwrap(),
            &[("accept", "application/x-npy")],
        )
        .await;
    assert_eq!(res.status(), 200);
    let b = res.bytes().await.unwrap();
    assert_eq!(&b[..8], b"\x93NUMPY\x01\x00", "NumPy format 1.0");
    let header_len = u16::from_le_bytes([b[8], b[9]]) as usize;
    assert_eq!((10 + header_len) % 64, 0, "the data starts aligned");
    let dict = std::str::from_utf8(&b[10..10 + header_len]).unwrap();
    assert!(dict.contains(&format!("'descr': {NPY_DESCR}")), "{dict}");
    assert!(dict.contains("'fortran_order': False"), "{dict}");
    assert!(dict.contains("'shape': (4, 3)"), "{dict}");
    assert_eq!(b.len(), 10 + header_len + 12 * NPY_RECORD_BYTES);
    // The record of pixel (2, 2): row 2, column 1 of the region. The lecture's centre
    // ray grazes the ball at λ = 2 (scenes/README.md).
    let rec = &b[10 + header_len + (2 * 3 + 1) * NPY_RECORD_BYTES..][..NPY_RECORD_BYTES];
    assert_eq!(i32::from_le_bytes(rec[0..4].try_into().unwrap()), 2, "u");
    assert_eq!(i32::from_le_bytes(rec[4..8].try_into().unwrap()), 2, "v");
    assert_eq!(rec[8], 1, "hit");
    assert_eq!(
        i32::from_le_bytes(rec[9..13].try_into().unwrap()),
        0,
        "object"
    );
    let lambda = f64::from_le_bytes(rec[13..21].try_into().unwrap());
    assert!((lambda - 2.0).abs() < 1e-6, "lambda {lambda}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ndjson_tiles_cover_every_pixel_exactly_once() {
    let app = TestApp::spawn().await;
    let (x0, y0, w, h) = (10u32, 20u32, 100u32, 70u32);
    let res = app
        .post_json(
            &format!("/v1/hits?region={x0},{y0},{w},{h}"),
            serde_json::to_vec(&shipped("sphere.json")).unwrap(),
            &[("accept", "application/x-ndjson")],
        )
        .await;
    assert_eq!(res.status(), 200);
    assert_eq!(header(&res, "content-type"), "application/x-ndjson");
    let text = res.text().await.unwrap();
    let mut seen = vec![0u32; (w * h) as usize];
    let mut tiles = 0;
    for line in text.lines() {
        let doc: Value = serde_json::from_str(line).expect("one JSON document per line");
        tiles += 1;
        let t = &doc["tile"];
        let (tx, ty, tw, th) = (
            t["x"].as_u64().unwrap() as u32,
            t["y"].as_u64().unwrap() as u32,
            t["width"].as_u64().unwrap() as u32,
            t["height"].as_u64().unwrap() as u32,
        );
        let pixels = doc["pixels"].as_array().unwrap();
        assert_eq!(pixels.len() as u32, tw * th);
        for p in pixels {
            let (u, v) = (
                p["u"].as_u64().unwrap() as u32,
                p["v"].as_u64().unwrap() as u32,
            );
            assert!(
                u >= tx && u < tx + tw && v >= ty && v < ty + th,
                "inside its tile"
            );
            assert!(
                u >= x0 && u < x0 + w && v >= y0 && v < y0 + h,
                "inside the region"
            );
            seen[((v - y0) * w + (u - x0)) as usize] += 1;
        }
    }
    assert_eq!(tiles, 4 * 3, "tiles of 32 over 100 × 70");
    assert!(seen.iter().all(|&n| n == 1), "every pixel exactly once");
}

// ---- /v1/validate, /v1/scenes, health, metrics -----------------------------------

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn validate_answers_the_normalised_scene_and_its_statistics() {
    let app = TestApp::spawn().await;
    let res = app
        .post_scene("/v1/validate", &shipped("lecture.json"))
        .await;
    assert_eq!(res.status(), 200);
    let doc: Value = res.json().await.unwrap();
    assert_eq!(doc["valid"], true);
    assert_eq!(doc["scene"]["image"]["width"], 5);
    assert_eq!(doc["scene"]["objects"][0]["name"], "ball");
    let s = &doc["statistics"];
    assert_eq!(s["pixels"], 25);
    assert_eq!(s["objects"], 1);
    assert_eq!(s["lights"], 1);
    assert_eq!(s["primary_rays"], 25);
    assert_eq!(doc["limits"]["max_body_bytes"], 16 * 1024 * 1024);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scenes_are_listed_and_served_as_shipped() {
    let app = TestApp::spawn().await;
    let list: Value = app.get("/v1/scenes").await.json().await.unwrap();
    let names: Vec<&str> = list["scenes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["name"].as_str().unwrap())
        .collect();
    assert!(names.contains(&"showcase") && names.contains(&"lecture"));
    assert_eq!(names.len(), 9);
    let file = std::fs::read(crate::support::scene("showcase.json")).unwrap();
    for path in ["/v1/scenes/showcase", "/v1/scenes/showcase.json"] {
        let res = app.get(path).await;
        assert_eq!(res.status(), 200);
        assert_eq!(header(&res, "content-type"), "application/json");
        assert!(res.bytes().await.unwrap() == file);
    }
    problem(app.get("/v1/scenes/nope").await, 404, "not-found").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn health_readiness_and_metrics() {
    let app = TestApp::spawn().await;
    assert_eq!(app.get("/healthz").await.status(), 200);
    assert_eq!(app.get("/readyz").await.status(), 200);
    app.post_scene("/v1/render", &shipped("lecture.json"))
        .await
        .bytes()
        .await
        .unwrap();
    // The last byte can reach the client before the render has recorded its duration
    // and freed its slot (in that order): wait for the slot.
    app.wait_for_metric("raytile_renders_in_flight", Duration::from_secs(10), |v| {
        v == 0.0
    })
    .await;
    let res = app.get("/metrics").await;
    assert!(header(&res, "content-type").starts_with("text/plain; version=0.0.4"));
    let text = res.text().await.unwrap();
    for name in [
        "raytile_http_requests_total{method=\"POST\",route=\"/v1/render\",status=\"200\"} 1",
        "raytile_render_duration_seconds_bucket{outcome=\"complete\",output=\"png\"",
        "raytile_rays_traced_total ",
        "raytile_tiles_traced_total 1",
        "raytile_renders_in_flight 0",
        "raytile_queue_depth 0",
        "raytile_render_slots 2",
        "raytile_queue_capacity 16",
        "raytile_rejected_requests_total{reason=\"saturated\"} 0",
    ] {
        assert!(text.contains(name), "{name} missing from\n{text}");
    }
    assert!(metric_value(&text, "raytile_rays_traced_total").unwrap() >= 25.0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn invented_methods_share_one_metric_series() {
    let app = TestApp::spawn().await;
    for i in 0..50 {
        let method = reqwest::Method::from_bytes(format!("BREW{i}").as_bytes()).unwrap();
        let res = app
            .client
            .request(method, app.at("/healthz"))
            .send()
            .await
            .unwrap();
        assert_eq!(res.status(), 405);
    }
    let text = app.get("/metrics").await.text().await.unwrap();
    let series: Vec<&str> = text
        .lines()
        .filter(|l| l.starts_with("raytile_http_requests_total{"))
        .collect();
    assert!(
        series.iter().all(|l| !l.contains("BREW")),
        "an invented method became a label value: {series:?}"
    );
    assert!(
        text.contains(
            "raytile_http_requests_total{method=\"other\",route=\"/healthz\",status=\"405\"} 50"
        ),
        "{series:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_request_id_is_returned_and_an_incoming_one_kept() {
    let app = TestApp::spawn().await;
    let res = app
        .client
        .get(app.at("/healthz"))
        .header("x-request-id", "lb-7f3a")
        .send()
        .await
        .unwrap();
    assert_eq!(header(&res, "x-request-id"), "lb-7f3a");
    let a = app.get("/healthz").await;
    let b = app.get("/nowhere").await;
    assert_ne!(header(&a, "x-request-id"), header(&b, "x-request-id"));
}

// ---- errors ----------------------------------------------------------------------

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_error_is_a_problem_document() {
    let app = TestApp::spawn().await;
    let lecture = serde_json::to_vec(&shipped("lecture.json")).unwrap();

    // 400: unreadable JSON, with where.
    let doc = problem(
        app.post_json("/v1/render", "{\n  \"version\": 1,\n  oops\n}", &[])
            .await,
        400,
        "invalid-json",
    )
    .await;
    assert_eq!(
        (doc["line"].as_u64(), doc["column"].as_u64()),
        (Some(3), Some(3))
    );

    // 400: a malformed or misplaced region, an unknown parameter.
    for q in [
        "region=1,2,3",
        "region=0,0,0,5",
        "region=0,0,6,5",
        "regoin=0,0,1,1",
    ] {
        problem(
            app.post_json(&format!("/v1/render?{q}"), lecture.clone(), &[])
                .await,
            400,
            "bad-request",
        )
        .await;
    }

    // 404 and 405 (with Allow).
    problem(app.get("/v2/render").await, 404, "not-found").await;
    let res = app.get("/v1/render").await;
    assert_eq!(header(&res, "allow"), "POST");
    problem(res, 405, "method-not-allowed").await;
    let res = app.client.delete(app.at("/healthz")).send().await.unwrap();
    problem(res, 405, "method-not-allowed").await;

    // 406: nothing we can send is acceptable.
    let doc = problem(
        app.post_json("/v1/hits", lecture.clone(), &[("accept", "text/html")])
            .await,
        406,
        "not-acceptable",
    )
    .await;
    assert_eq!(doc["supported"][2], "application/x-npy");
    // Decided from the head, before the body is read: a broken body does not matter.
    problem(
        app.post_json("/v1/hits", "{", &[("accept", "text/html")])
            .await,
        406,
        "not-acceptable",
    )
    .await;
    problem(
        app.post_json(
            "/v1/render",
            lecture.clone(),
            &[("accept", "application/json")],
        )
        .await,
        406,
        "not-acceptable",
    )
    .await;

    // 415: not JSON by its media type; JSON with parameters or a +json suffix is fine.
    let res = app
        .client
        .post(app.at("/v1/render"))
        .header("content-type", "text/plain")
        .body(lecture.clone())
        .send()
        .await
        .unwrap();
    problem(res, 415, "unsupported-media-type").await;
    let res = app
        .client
        .post(app.at("/v1/render"))
        .body(lecture.clone())
        .send()
        .await
        .unwrap();
    problem(res, 415, "unsupported-media-type").await;
    for ct in [
        "application/json; charset=utf-8",
        "application/vnd.raytile.scene+json",
    ] {
        let res = app
            .client
            .post(app.at("/v1/validate"))
            .header("content-type", ct)
            .body(lecture.clone())
            .send()
            .await
            .unwrap();
        assert_eq!(res.status(), 200, "{ct}");
    }

    // 422: every problem, each with its JSON pointer.
    let bad = json!({
        "version": 1, "image": { "width": 64, "height": 48 },
        "objects": [
            { "name": "a", "shape": "sphere", "material": "nope" },
            { "name": "a", "shape": "cube", "transform": [ { "scale": 0 } ] }
        ],
        "lights": [ { "type": "point", "position": [0, 0, 0], "colour": [-1, 0, 0] } ]
    });
    for route in ["/v1/render", "/v1/hits", "/v1/validate"] {
        let doc = problem(app.post_scene(route, &bad).await, 422, "invalid-scene").await;
        let pointers: Vec<&str> = doc["problems"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| {
                assert!(p["message"].is_string());
                p["pointer"].as_str().unwrap()
            })
            .collect();
        assert_eq!(
            pointers,
            [
                "/objects/0/material",
                "/objects/1/name",
                "/objects/1/transform/0/scale",
                "/lights/0/colour/0"
            ]
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_server_limits_are_422_and_413() {
    let app = TestApp::with(ServeArgs {
        max_pixels: 100 * 100,
        max_samples: 2,
        max_body_bytes: 4096,
        ..config()
    })
    .await;
    let big = resized(shipped("lecture.json"), 101, 100);
    let doc = problem(
        app.post_scene("/v1/render", &big).await,
        422,
        "invalid-scene",
    )
    .await;
    assert!(
        doc["problems"][0]["pointer"]
            .as_str()
            .unwrap()
            .starts_with("/image")
    );
    let mut sampled = shipped("lecture.json");
    sampled["image"]["samples"] = json!(3);
    let doc = problem(
        app.post_scene("/v1/hits", &sampled).await,
        422,
        "invalid-scene",
    )
    .await;
    assert_eq!(doc["problems"][0]["pointer"], "/image/samples");

    // Declared too large: refused without being kept.
    let padded = format!("{{\"version\": 1{}}}", " ".repeat(5000));
    let doc = problem(
        app.post_json("/v1/render", padded.clone(), &[]).await,
        413,
        "body-too-large",
    )
    .await;
    assert_eq!(doc["limit_bytes"], 4096);
    // Chunked, so the size is known only while reading.
    let chunk = format!("{:x}\r\n{padded}\r\n0\r\n\r\n", padded.len());
    let raw = raw_request(
        app.addr,
        "POST /v1/render HTTP/1.1\r\nHost: t\r\nContent-Type: application/json\r\nTransfer-Encoding: chunked\r\nConnection: close\r\n\r\n",
        chunk.as_bytes(),
    );
    let text = String::from_utf8_lossy(&raw);
    assert!(text.starts_with("HTTP/1.1 413"), "{text}");
    assert!(text.contains("problems/body-too-large"), "{text}");
}

/// Most HTTP clients send the whole body before they read the answer. Closing on unread
/// bytes would reset the connection and lose the 413; the server reads and drops a body
/// declared too large instead, so the answer arrives even when the body comes slowly.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_body_declared_too_large_is_read_and_dropped_before_the_413() {
    let app = TestApp::with(ServeArgs {
        max_body_bytes: 4096,
        ..config()
    })
    .await;
    let addr = app.addr;
    let (sent_all, text) = tokio::task::spawn_blocking(move || {
        let body = vec![b' '; 256 * 1024];
        let mut s = TcpStream::connect(addr).expect("connects");
        s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
        let head = format!(
            "POST /v1/render HTTP/1.1\r\nHost: t\r\nContent-Type: application/json\r\n\
             Content-Length: {}\r\nConnection: close\r\n\r\n",
            body.len()
        );
        s.write_all(head.as_bytes()).unwrap();
        // Slowly enough that the server has decided long before the last piece; a
        // server that closed on the unread rest makes these writes fail.
        let mut sent = 0;
        for piece in body.chunks(16 * 1024) {
            std::thread::sleep(Duration::from_millis(10));
            if s.write_all(piece).is_err() {
                break;
            }
            sent += piece.len();
        }
        let mut out = Vec::new();
        let _ = s.read_to_end(&mut out);
        (
            sent == body.len(),
            String::from_utf8_lossy(&out).into_owned(),
        )
    })
    .await
    .unwrap();
    assert!(
        sent_all,
        "the connection was reset while the body was being sent"
    );
    assert!(text.starts_with("HTTP/1.1 413"), "{text}");
    assert!(text.contains("problems/body-too-large"), "{text}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn no_input_makes_it_answer_500() {
    let app = TestApp::spawn().await;
    let deep = "[".repeat(100_000);
    let bodies: Vec<Vec<u8>> = vec![
        b"".to_vec(),
        b"null".to_vec(),
        b"[]".to_vec(),
        b"1e999".to_vec(),
        b"\xff\xfe\x00".to_vec(),
        deep.into_bytes(),
        br#"{"version": 1}"#.to_vec(),
        br#"{"version": 2, "image": {"width": 1, "height": 1}, "objects": []}"#.to_vec(),
        br#"{"version": 1, "image": {"width": 1e20, "height": -1}, "objects": []}"#.to_vec(),
        br#"{"version": 1, "image": {"width": 4294967295, "height": 4294967295}, "objects": []}"#
            .to_vec(),
        br#"{"version": 1, "image": {"width": 2, "height": 2}, "objects": [{"shape": "mesh", "positions": [[0,0,0]], "indices": [[0, 1, 99999999999]]}]}"#.to_vec(),
    ];
    for route in ["/v1/render", "/v1/hits", "/v1/validate"] {
        for b in &bodies {
            let res = app.post_json(route, b.clone(), &[]).await;
            let status = res.status().as_u16();
            assert!(
                (400..500).contains(&status),
                "{route} {:?}: {status}",
                String::from_utf8_lossy(&b[..b.len().min(80)])
            );
            assert_eq!(header(&res, "content-type"), "application/problem+json");
        }
    }
    for q in [
        "region=%zz",
        "region=-1,0,1,1",
        "region=4294967295,0,1,1",
        "region=1,1,1,1&region=1,1,1,1",
    ] {
        let res = app
            .post_json(
                &format!("/v1/render?{q}"),
                serde_json::to_vec(&shipped("lecture.json")).unwrap(),
                &[("accept", ";;,q=x, */*;q=abc")],
            )
            .await;
        assert!(res.status().is_client_error(), "{q}: {}", res.status());
    }
    assert_eq!(app.get("/healthz").await.status(), 200, "still alive");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn past_the_deadline_before_the_first_byte_is_504() {
    let app = TestApp::with(ServeArgs {
        deadline_seconds: 0.5,
        ..config()
    })
    .await;
    // A client that sends half its body and stalls.
    let raw = raw_request(
        app.addr,
        "POST /v1/render HTTP/1.1\r\nHost: t\r\nContent-Type: application/json\r\nContent-Length: 1000\r\n\r\n",
        b"{\"version\": 1,",
    );
    let text = String::from_utf8_lossy(&raw);
    assert!(text.starts_with("HTTP/1.1 504"), "{text}");
    assert!(text.contains("application/problem+json"), "{text}");
    assert!(text.contains("problems/deadline-exceeded"), "{text}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn past_the_deadline_after_the_first_byte_the_stream_is_cut() {
    let app = TestApp::with(ServeArgs {
        deadline_seconds: 1.0,
        ..config()
    })
    .await;
    let mut res = app
        .post_scene("/v1/render", &sphere_grid(4096, 4096, 10, 3))
        .await;
    assert_eq!(res.status(), 200);
    let mut outcome = Ok(0usize);
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(90) {
        match res.chunk().await {
            Ok(Some(c)) => *outcome.as_mut().unwrap() += c.len(),
            Ok(None) => break,
            Err(e) => {
                outcome = Err(e);
                break;
            }
        }
    }
    assert!(outcome.is_err(), "the body ended cleanly: {outcome:?}");
    let text = app.get("/metrics").await.text().await.unwrap();
    assert_eq!(
        metric_value(
            &text,
            "raytile_rejected_requests_total{reason=\"deadline\"}"
        ),
        Some(1.0)
    );
}

// ---- load ------------------------------------------------------------------------

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn saturated_it_sheds_load_with_503_and_retry_after() {
    let app = TestApp::with(ServeArgs {
        max_renders: Some(1),
        queue: 1,
        ..config()
    })
    .await;
    // Occupy the one slot with a long render…
    let mut long = app
        .post_scene("/v1/render", &sphere_grid(4096, 4096, 10, 2))
        .await;
    assert_eq!(long.status(), 200);
    long.chunk().await.unwrap();
    app.wait_for_metric("raytile_renders_in_flight", Duration::from_secs(60), |v| {
        v == 1.0
    })
    .await;
    // …and the one place in the queue.
    let small = resized(shipped("sphere.json"), 64, 48);
    let expected = cli_output("render", &small, "s.png", &[]);
    let queued = {
        let (client, url, body) = (
            client(),
            app.at("/v1/render"),
            serde_json::to_vec(&small).unwrap(),
        );
        tokio::spawn(async move {
            let res = client
                .post(url)
                .header("content-type", "application/json")
                .body(body)
                .send()
                .await
                .unwrap();
            (res.status().as_u16(), res.bytes().await.unwrap())
        })
    };
    app.wait_for_metric("raytile_queue_depth", Duration::from_secs(60), |v| v == 1.0)
        .await;
    problem(app.get("/readyz").await, 503, "saturated").await;

    // A burst now is refused at once, every request of it, with Retry-After.
    let burst: Vec<_> = (0..6)
        .map(|_| {
            let (client, url, body) = (
                client(),
                app.at("/v1/render"),
                serde_json::to_vec(&small).unwrap(),
            );
            tokio::spawn(async move {
                client
                    .post(url)
                    .header("content-type", "application/json")
                    .body(body)
                    .send()
                    .await
                    .unwrap()
            })
        })
        .collect();
    for r in burst {
        let res = tokio::time::timeout(Duration::from_secs(60), r)
            .await
            .expect("a refusal comes at once")
            .unwrap();
        assert_eq!(header(&res, "retry-after"), "1");
        let doc = problem(res, 503, "saturated").await;
        assert_eq!(doc["retry_after_seconds"], 1);
    }
    let text = app.get("/metrics").await.text().await.unwrap();
    assert_eq!(
        metric_value(
            &text,
            "raytile_rejected_requests_total{reason=\"saturated\"}"
        ),
        Some(6.0)
    );

    // Let go of the long render: the queued request gets the slot and its image.
    drop(long);
    let (status, png) = tokio::time::timeout(Duration::from_secs(90), queued)
        .await
        .expect("the queued request is served")
        .unwrap();
    assert_eq!(status, 200);
    assert!(png == expected);
    assert_eq!(app.get("/readyz").await.status(), 200);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_leaves_stops_the_tracing() {
    let app = TestApp::spawn().await;
    let pixels = 4096.0 * 4096.0;
    let mut res = app
        .post_scene("/v1/render", &sphere_grid(4096, 4096, 10, 3))
        .await;
    assert_eq!(res.status(), 200);
    res.chunk().await.unwrap();
    app.wait_for_metric("raytile_rays_traced_total", Duration::from_secs(60), |r| {
        r > 0.0
    })
    .await;
    drop(res);
    // The render ends (its slot frees), and after that nothing more is traced.
    app.wait_for_metric("raytile_renders_in_flight", Duration::from_secs(60), |v| {
        v == 0.0
    })
    .await;
    let r1 = app.metric("raytile_rays_traced_total").await;
    tokio::time::sleep(Duration::from_millis(500)).await;
    let r2 = app.metric("raytile_rays_traced_total").await;
    assert_eq!(r1, r2, "rays are still being traced");
    assert!(
        r1 < pixels * 9.0 / 2.0,
        "{r1} rays: most of the frame was traced for nobody"
    );
    let text = app.get("/metrics").await.text().await.unwrap();
    assert!(
        text.contains(
            "raytile_render_duration_seconds_count{outcome=\"cancelled\",output=\"png\"} 1"
        ),
        "{text}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_stops_reading_releases_the_trace_threads() {
    let app = TestApp::with(ServeArgs {
        stall_seconds: 0.5,
        ..config()
    })
    .await;
    // JSON hit data of a 4096² frame is gigabytes: the buffers fill at once.
    let mut res = app
        .post_scene("/v1/hits", &sphere_grid(4096, 4096, 10, 3))
        .await;
    assert_eq!(res.status(), 200);
    res.chunk().await.unwrap();
    // The response is held but not read: the render parks (freeing its slot at once)
    // and must still end, long before its deadline.
    let start = std::time::Instant::now();
    loop {
        let text = app.get("/metrics").await.text().await.unwrap();
        if text.contains(
            "raytile_render_duration_seconds_count{outcome=\"cancelled\",output=\"json\"} 1",
        ) {
            break;
        }
        assert!(start.elapsed() < Duration::from_secs(60), "{text}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert_eq!(app.metric("raytile_renders_in_flight").await, 0.0);
    // Other renders go on.
    let ok = app
        .post_scene("/v1/render", &sphere_grid(64, 48, 2, 1))
        .await;
    assert_eq!(ok.status(), 200);
    assert!(!ok.bytes().await.unwrap().is_empty());
    drop(res);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn thirty_two_concurrent_small_renders_all_succeed() {
    let app = TestApp::with(ServeArgs {
        queue: 32,
        ..config()
    })
    .await;
    let scenes: Vec<(Value, Vec<u8>)> = ["sphere.json", "cube.json", "cone.json", "mesh.json"]
        .iter()
        .map(|n| {
            let s = resized(shipped(n), 64, 64);
            let png = cli_output("render", &s, "s.png", &[]);
            (s, png)
        })
        .collect();
    let tasks: Vec<_> = (0..32)
        .map(|i| {
            let (scene, expected) = scenes[i % scenes.len()].clone();
            let (client, url) = (app.client.clone(), app.at("/v1/render"));
            tokio::spawn(async move {
                let res = client
                    .post(url)
                    .header("content-type", "application/json")
                    .body(serde_json::to_vec(&scene).unwrap())
                    .send()
                    .await
                    .unwrap();
                assert_eq!(res.status(), 200);
                assert!(res.bytes().await.unwrap() == expected, "request {i}");
            })
        })
        .collect();
    for t in tasks {
        tokio::time::timeout(Duration::from_secs(120), t)
            .await
            .expect("every render finishes")
            .unwrap();
    }
}

// ---- shutdown, and the binary ------------------------------------------------------

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn draining_refuses_new_work_and_finishes_what_runs() {
    let mut app = TestApp::spawn().await;
    let mut res = app
        .post_scene("/v1/render", &sphere_grid(1024, 1024, 8, 2))
        .await;
    assert_eq!(res.status(), 200);
    let mut png = res.chunk().await.unwrap().unwrap().to_vec();
    app.signal_shutdown();
    while !app.state.shutdown.is_draining() {
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    while let Some(c) = res.chunk().await.expect("the in-flight response completes") {
        png.extend_from_slice(&c);
    }
    assert_eq!(decode_png(&png).0, 1024);
    let task = app.task.take().unwrap();
    tokio::time::timeout(Duration::from_secs(60), task)
        .await
        .expect("the server stops")
        .unwrap()
        .unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn past_the_grace_period_in_flight_streams_are_cut_and_the_server_stops() {
    let mut app = TestApp::with(ServeArgs {
        grace_seconds: 0.5,
        ..config()
    })
    .await;
    let mut res = app
        .post_scene("/v1/render", &sphere_grid(4096, 4096, 10, 3))
        .await;
    assert_eq!(res.status(), 200);
    res.chunk().await.unwrap();
    app.signal_shutdown();
    let mut outcome = Ok(());
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(90) {
        match res.chunk().await {
            Ok(Some(_)) => {}
            Ok(None) => break,
            Err(e) => {
                outcome = Err(e);
                break;
            }
        }
    }
    assert!(outcome.is_err(), "the cut stream ended like a complete one");
    let task = app.task.take().unwrap();
    tokio::time::timeout(Duration::from_secs(60), task)
        .await
        .expect("the server stops")
        .unwrap()
        .unwrap();
    assert_eq!(app.metric_after_stop("raytile_renders_in_flight"), 0.0);
}

#[test]
fn sigterm_during_a_render_lets_it_finish_then_exits_zero() {
    let (mut child, addr, lines) = spawn_binary(&[
        "--threads",
        "2",
        "--max-renders",
        "2",
        "--grace-seconds",
        "60",
    ]);
    let rt = tokio::runtime::Runtime::new().unwrap();
    let png = rt.block_on(async {
        let client = client();
        let mut res = client
            .post(format!("http://{addr}/v1/render"))
            .header("content-type", "application/json")
            .body(serde_json::to_vec(&sphere_grid(1536, 1536, 8, 2)).unwrap())
            .send()
            .await
            .unwrap();
        assert_eq!(res.status(), 200);
        let mut png = res.chunk().await.unwrap().unwrap().to_vec();
        let killed = Command::new("kill")
            .args(["-TERM", &child.id().to_string()])
            .status()
            .unwrap();
        assert!(killed.success());
        while let Some(c) = res.chunk().await.expect("the response completes") {
            png.extend_from_slice(&c);
        }
        png
    });
    assert_eq!(decode_png(&png).0, 1536);
    let status = wait_exit(&mut child, Duration::from_secs(90));
    assert_eq!(status.code(), Some(0));
    let log: Vec<String> = lines.try_iter().collect();
    let drain = log.iter().position(|l| l.contains("shutting down"));
    let done = log
        .iter()
        .position(|l| l.contains("route=/v1/render") && l.contains("complete=true"));
    assert!(
        matches!((drain, done), (Some(d), Some(r)) if d < r),
        "the render finished after the drain began:\n{}",
        log.join("\n")
    );
}

#[test]
fn healthcheck_exits_zero_on_200_and_one_otherwise() {
    let (mut child, addr, _lines) = spawn_binary(&["--threads", "1"]);
    let port = addr.rsplit(':').next().unwrap().to_owned();
    let ok = raytile()
        .args(["healthcheck", "--url", &format!("http://{addr}/healthz")])
        .status()
        .unwrap();
    assert_eq!(ok.code(), Some(0));
    // Without --url: 127.0.0.1 at RAYTILE_ADDR's port.
    let by_env = raytile()
        .arg("healthcheck")
        .env("RAYTILE_ADDR", format!("0.0.0.0:{port}"))
        .status()
        .unwrap();
    assert_eq!(by_env.code(), Some(0));
    let not_200 = raytile()
        .args(["healthcheck", "--url", &format!("http://{addr}/nowhere")])
        .status()
        .unwrap();
    assert_eq!(not_200.code(), Some(1));
    let _ = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status();
    assert_eq!(
        wait_exit(&mut child, Duration::from_secs(60)).code(),
        Some(0)
    );
    let closed = raytile()
        .args(["healthcheck", "--url", &format!("http://{addr}/healthz")])
        .status()
        .unwrap();
    assert_eq!(closed.code(), Some(1));
}

/// Sends `head` and `body` over a fresh connection and reads until the server closes
/// it (or 60 s pass).
fn raw_request(addr: std::net::SocketAddr, head: &str, body: &[u8]) -> Vec<u8> {
    let mut s = TcpStream::connect(addr).expect("connects");
    s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
    s.write_all(head.as_bytes()).unwrap();
    // The server may answer (and close) before it has read everything.
    let _ = s.write_all(body);
    let mut out = Vec::new();
    let _ = s.read_to_end(&mut out);
    out
}

// ---- connections -----------------------------------------------------------------

/// Reads from `s` until the server closes it (or `limit` passes); what it sent and
/// whether it closed.
fn read_until_closed(s: &mut TcpStream, limit: Duration) -> (Vec<u8>, bool) {
    let start = Instant::now();
    let mut out = Vec::new();
    let mut buf = [0u8; 4096];
    while start.elapsed() < limit {
        s.set_read_timeout(Some(Duration::from_millis(100)))
            .unwrap();
        match s.read(&mut buf) {
            Ok(0) => return (out, true),
            Ok(n) => out.extend_from_slice(&buf[..n]),
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(_) => return (out, true),
        }
    }
    (out, false)
}

/// Sends a `GET /healthz` on `s` and reads its whole answer (it has a Content-Length).
fn healthz_on(s: &mut TcpStream) -> String {
    s.write_all(b"GET /healthz HTTP/1.1\r\nhost: t\r\n\r\n")
        .unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let mut got = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        let n = s.read(&mut buf).expect("an answer");
        assert!(
            n > 0,
            "closed before answering: {}",
            String::from_utf8_lossy(&got)
        );
        got.extend_from_slice(&buf[..n]);
        let text = String::from_utf8_lossy(&got).into_owned();
        if let Some((head, body)) = text.split_once("\r\n\r\n") {
            let len: usize = head
                .lines()
                .find_map(|l| {
                    l.to_ascii_lowercase()
                        .strip_prefix("content-length: ")
                        .map(|v| v.trim().parse().unwrap())
                })
                .expect("a content-length");
            if body.len() >= len {
                return text;
            }
        }
    }
}

fn connection_config(header: f64, idle: f64, max: u32) -> ServeArgs {
    ServeArgs {
        header_timeout_seconds: header,
        idle_timeout_seconds: idle,
        max_connections: max,
        ..config()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_drips_its_head_is_cut_after_the_header_timeout() {
    let app = TestApp::with(connection_config(0.5, 30.0, 64)).await;
    let addr = app.addr;
    tokio::task::spawn_blocking(move || {
        let mut s = TcpStream::connect(addr).unwrap();
        let start = Instant::now();
        s.write_all(b"GET /healthz HTTP/1.1\r\n").unwrap();
        std::thread::sleep(Duration::from_millis(200));
        s.write_all(b"host: t\r\n").unwrap();
        let (got, closed) = read_until_closed(&mut s, Duration::from_secs(10));
        assert!(closed, "the connection is still open after 10 s");
        assert!(got.is_empty() || !String::from_utf8_lossy(&got).contains("200 OK"));
        let took = start.elapsed();
        assert!(took >= Duration::from_millis(450), "cut after {took:?}");
        // A silent new connection is cut too.
        let mut quiet = TcpStream::connect(addr).unwrap();
        assert!(read_until_closed(&mut quiet, Duration::from_secs(10)).1);
    })
    .await
    .unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_kept_alive_connection_waits_the_idle_timeout_then_closes() {
    // The idle timeout, not the (shorter) header timeout, governs a connection between
    // requests.
    let app = TestApp::with(connection_config(0.3, 1.5, 64)).await;
    let addr = app.addr;
    tokio::task::spawn_blocking(move || {
        let mut s = TcpStream::connect(addr).unwrap();
        assert!(healthz_on(&mut s).starts_with("HTTP/1.1 200"));
        std::thread::sleep(Duration::from_millis(800));
        assert!(
            healthz_on(&mut s).starts_with("HTTP/1.1 200"),
            "closed before the idle timeout"
        );
        let idle_from = Instant::now();
        let (_, closed) = read_until_closed(&mut s, Duration::from_secs(10));
        assert!(closed, "still open 10 s after its last request");
        assert!(
            idle_from.elapsed() >= Duration::from_millis(1300),
            "closed after {:?}",
            idle_from.elapsed()
        );
    })
    .await
    .unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn at_the_connection_cap_silent_sockets_make_room_and_only_busy_ones_get_503() {
    let app = TestApp::with(connection_config(30.0, 30.0, 4)).await;
    let addr = app.addr;
    tokio::task::spawn_blocking(move || {
        // Four sockets that send nothing fill the cap; a client that asks still gets in
        // (long before the 30 s header timeout would free one), taking the place of the
        // longest-silent socket, which is closed.
        let mut silent: Vec<TcpStream> = (0..4).map(|_| TcpStream::connect(addr).unwrap()).collect();
        std::thread::sleep(Duration::from_millis(100));
        let start = Instant::now();
        let mut s = TcpStream::connect(addr).unwrap();
        assert!(healthz_on(&mut s).starts_with("HTTP/1.1 200"));
        assert!(start.elapsed() < Duration::from_secs(5));
        let closed = silent
            .iter_mut()
            .map(|q| read_until_closed(q, Duration::from_millis(500)).1)
            .filter(|&closed| closed)
            .count();
        assert_eq!(closed, 1, "one silent socket is closed to make room");
        drop(s);
        drop(silent);
        std::thread::sleep(Duration::from_millis(200));

        // Four connections each with a request in flight (a body announced, not sent)
        // are never closed for a newcomer: it gets the 503 problem document.
        let mut busy = Vec::new();
        for _ in 0..4 {
            let mut b = TcpStream::connect(addr).unwrap();
            b.write_all(
                b"POST /v1/validate HTTP/1.1\r\nhost: t\r\ncontent-type: application/json\r\ncontent-length: 100\r\n\r\n{",
            )
            .unwrap();
            busy.push(b);
        }
        std::thread::sleep(Duration::from_millis(300));
        let mut s = TcpStream::connect(addr).unwrap();
        let (got, closed) = read_until_closed(&mut s, Duration::from_secs(5));
        let answer = String::from_utf8_lossy(&got).into_owned();
        assert!(closed);
        assert!(answer.starts_with("HTTP/1.1 503"), "{answer}");
        assert!(answer.contains("retry-after: 1"), "{answer}");
        assert!(answer.contains("/problems/too-many-connections"), "{answer}");
        // The busy ones are still served: finishing a body gets its answer.
        let body = format!("{{\"pad\": \"{}\"}}", "x".repeat(100 - 12));
        assert_eq!(body.len(), 99);
        busy[0].write_all(body.as_bytes()).unwrap();
        let (got, _) = read_until_closed(&mut busy[0], Duration::from_secs(2));
        assert!(String::from_utf8_lossy(&got).starts_with("HTTP/1.1 "), "no answer");
    })
    .await
    .unwrap();
}

#[test]
fn under_a_low_descriptor_limit_idle_sockets_do_not_delay_healthz() {
    // `ulimit -n 128` for the server alone: it lowers its cap to fit, so 200 silent
    // sockets are either held or refused at once, and /healthz still answers at once.
    let bin = std::path::Path::new(env!("CARGO_BIN_EXE_raytile"));
    let mut child = std::process::Command::new("sh")
        .arg("-c")
        .arg(format!(
            "ulimit -n 128 && exec '{}' serve --addr 127.0.0.1:0 --header-timeout-seconds 30",
            bin.display()
        ))
        .env("RAYTILE_LOG_FORMAT", "text")
        .env("RUST_LOG", "info")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("sh starts the server");
    let stdout = child.stdout.take().unwrap();
    let (tx, lines) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufRead::lines(std::io::BufReader::new(stdout)).map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let mut addr = None;
    let mut lowered = false;
    while addr.is_none() || !lowered {
        let line = lines
            .recv_timeout(Duration::from_secs(30))
            .expect("the server logs its address and its lowered cap");
        lowered |= line.contains("lowers --max-connections");
        if let Some(i) = line.find("listening on http://") {
            addr = line[i + "listening on http://".len()..]
                .split_whitespace()
                .next()
                .map(str::to_owned);
        }
    }
    let addr = addr.unwrap();
    let silent: Vec<TcpStream> = (0..200)
        .filter_map(|_| TcpStream::connect(&addr).ok())
        .collect();
    // Past the cap, silent newcomers are refused once their half-second probation ends.
    std::thread::sleep(Duration::from_millis(1500));
    let start = Instant::now();
    let mut s = TcpStream::connect(&addr).unwrap();
    let answer = healthz_on(&mut s);
    let took = start.elapsed();
    let _ = child.kill();
    let _ = child.wait();
    drop(silent);
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    assert!(took < Duration::from_secs(2), "/healthz took {took:?}");
}

/// A server set to the deepest `max_depth` explains and renders a pixel between two
/// facing mirrors, each bounce a level of recursion on one of its trace threads, and
/// answers the next request (an overflow there would abort the whole process).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn facing_mirrors_at_the_deepest_max_depth_are_traced_by_the_server() {
    use raytile::scene::DEEPEST;
    let app = TestApp::with(ServeArgs {
        max_depth: DEEPEST,
        ..config()
    })
    .await;
    let scene = crate::support::facing_mirrors(DEEPEST);
    let res = app
        .post_scene("/v1/trace?u=1&v=1&format=text", &scene)
        .await;
    assert_eq!(res.status(), 200);
    assert!(
        res.text()
            .await
            .unwrap()
            .contains("reflected ray, depth 40:")
    );
    let res = app.post_scene("/v1/render", &scene).await;
    assert_eq!(res.status(), 200);
    let (w, h, _) = decode_png(&res.bytes().await.unwrap());
    assert_eq!((w, h), (8, 8));
    let res = app
        .post_scene("/v1/validate", &crate::support::facing_mirrors(DEEPEST + 1))
        .await;
    assert_eq!(res.status(), 422);
    assert_eq!(app.get("/healthz").await.status(), 200);
}
