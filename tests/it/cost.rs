//! The ray budget as a client sees it: a scene whose estimate exceeds `--max-rays` is
//! refused with 422 and the fields that drive its cost, before any tracing; ordinary
//! scenes pass; a render that traces past its budget is cut like any stopped render.

use std::time::{Duration, Instant};

use raytile::config::ServeArgs;
use serde_json::{Value, json};

use crate::support::encode_png;
use crate::support_server::{TestApp, config, problem, shipped};

/// The camera inside two large spheres of one glass-and-mirror material, 1024² at
/// 8 × 8 samples, `max_depth` 10: every ray reflects and refracts.
fn branching() -> Value {
    json!({
        "version": 1,
        "image": { "width": 1024, "height": 1024, "samples": 8 },
        "max_depth": 10,
        "materials": { "glass": { "mirror": [0.5, 0.5, 0.5], "transmission": [0.5, 0.5, 0.5], "ior": 1.5 } },
        "objects": [
            { "shape": "sphere", "material": "glass", "transform": [{ "scale": 100 }] },
            { "shape": "sphere", "material": "glass", "transform": [{ "scale": 200 }] }
        ],
        "lights": [{ "type": "point", "position": [0, 50, 0], "colour": [1, 1, 1] }]
    })
}

/// A 1600² frame whose costly pixels lie between the pilot's samples: small balls on
/// the corners of its 50-pixel grid cells, lit by 64 lights (65 rays a pixel), and
/// background (1 ray) wherever the pilot looks.
fn hidden_cost() -> Value {
    let mut objects = Vec::new();
    for i in 1..32 {
        for j in 1..32 {
            let x = -1.0 + 2.0 * (50.0 * i as f64) / 1600.0;
            let y = -1.0 + 2.0 * (50.0 * j as f64) / 1600.0;
            objects.push(json!({
                "shape": "sphere",
                "transform": [{ "scale": 0.18 }, { "translate": [10.0 * x, 10.0 * y, 10.0] }]
            }));
        }
    }
    let lights: Vec<Value> = (0..64)
        .map(|k| json!({ "type": "point", "position": [0.01 * k as f64, 0, 0], "colour": [0.01, 0.01, 0.01] }))
        .collect();
    json!({ "version": 1, "image": { "width": 1600, "height": 1600 }, "objects": objects, "lights": lights })
}

fn pointers(doc: &Value) -> Vec<&str> {
    doc["problems"]
        .as_array()
        .expect("problems")
        .iter()
        .map(|p| p["pointer"].as_str().expect("a pointer"))
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_scene_whose_every_ray_branches_is_refused_before_it_traces() {
    let app = TestApp::spawn().await;
    let started = Instant::now();
    let res = app.post_scene("/v1/render", &branching()).await;
    let took = started.elapsed();
    let doc = problem(res, 422, "invalid-scene").await;
    eprintln!("refused in {took:?}");
    assert_eq!(
        pointers(&doc),
        [
            "/image/width",
            "/image/height",
            "/image/samples",
            "/max_depth",
            "/materials/glass"
        ]
    );
    let message = doc["problems"][0]["message"].as_str().unwrap();
    assert!(
        message.contains("at least") && message.contains("more than the limit of 500000000 rays"),
        "{message}"
    );
    assert_eq!(
        app.metric("raytile_rejected_requests_total{reason=\"over_budget\"}")
            .await,
        1.0
    );
    // Nothing was rendered: only the pilot traced, and the slot is free again.
    assert_eq!(app.metric("raytile_tiles_traced_total").await, 0.0);
    assert_eq!(app.metric("raytile_renders_in_flight").await, 0.0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn grading_against_a_branching_scene_is_refused_with_pointers_into_the_body() {
    let app = TestApp::spawn().await;
    let png = encode_png(1024, 1024, &vec![0; 1024 * 1024 * 3]);
    use base64::Engine as _;
    let b64 = base64::engine::general_purpose::STANDARD.encode(&png);
    let body = json!({ "scene": branching(), "submission": { "png_base64": b64 } });
    let res = app
        .post_json("/v1/grade", serde_json::to_vec(&body).unwrap(), &[])
        .await;
    let doc = problem(res, 422, "invalid-scene").await;
    assert_eq!(
        pointers(&doc),
        [
            "/scene/image/width",
            "/scene/image/height",
            "/scene/image/samples",
            "/scene/max_depth",
            "/scene/materials/glass"
        ]
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hit_data_costs_a_ray_a_pixel() {
    let app = TestApp::with(ServeArgs {
        max_rays: 1000,
        ..config()
    })
    .await;
    let small = json!({ "version": 1, "image": { "width": 40, "height": 25 }, "objects": [] });
    assert_eq!(app.post_scene("/v1/hits", &small).await.status(), 200);
    let large = json!({ "version": 1, "image": { "width": 40, "height": 26 }, "objects": [] });
    let doc = problem(
        app.post_scene("/v1/hits", &large).await,
        422,
        "invalid-scene",
    )
    .await;
    assert_eq!(pointers(&doc), ["/image/width", "/image/height"]);
    assert!(
        doc["problems"][0]["message"]
            .as_str()
            .unwrap()
            .contains("about 1040 rays, more than the limit of 1000 rays"),
        "{doc}"
    );
    // A region is what is traced, and what is counted.
    let res = app.post_scene("/v1/hits?region=0,0,40,25", &large).await;
    assert_eq!(res.status(), 200);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_showcase_at_2048_with_4x4_samples_is_not_refused() {
    let app = TestApp::spawn().await;
    let mut scene = shipped("showcase.json");
    scene["image"] = json!({ "width": 2048, "height": 2048, "samples": 4, "gamma": 2.2 });
    let mut res = app.post_scene("/v1/render", &scene).await;
    assert_eq!(res.status(), 200);
    // The first bytes are the PNG's; no need to wait for the whole frame.
    let first = res.chunk().await.unwrap().unwrap();
    assert!(first.starts_with(b"\x89PNG"));
    drop(res);
    assert_eq!(
        app.metric("raytile_rejected_requests_total{reason=\"over_budget\"}")
            .await,
        0.0
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_render_past_its_budget_is_cut_and_counted_as_over_budget() {
    // The pilot sees 1 ray a pixel, 2.56 M in all; the render traces 65 on a third of
    // the frame and is stopped at 6 M.
    let app = TestApp::with(ServeArgs {
        max_rays: 4_000_000,
        ..config()
    })
    .await;
    let res = app.post_scene("/v1/render", &hidden_cost()).await;
    assert_eq!(res.status(), 200);
    assert!(
        res.bytes().await.is_err(),
        "a cut render must not look whole"
    );
    app.wait_for_metric("raytile_renders_in_flight", Duration::from_secs(60), |v| {
        v == 0.0
    })
    .await;
    let text = app.get("/metrics").await.text().await.unwrap();
    assert!(
        text.contains(
            "raytile_render_duration_seconds_count{outcome=\"over_budget\",output=\"png\"} 1"
        ),
        "{text}"
    );
    let rays = app.metric("raytile_rays_traced_total").await;
    assert!(rays < 6_000_000.0 + 64.0 * 32.0 * 65.0, "{rays} rays");
}
