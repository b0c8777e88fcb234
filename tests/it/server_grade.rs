//! `POST /v1/trace` and `POST /v1/grade` as an instructor's scripts use them: the lecture's
//! worked example over HTTP, grading a reference against itself and against a copy with
//! one pixel changed (multipart, as `curl -F` sends it, and the JSON form), every answer
//! form, and each kind of bad request, decided before a render slot is taken.

use base64::Engine as _;
use raytile::config::ServeArgs;
use reqwest::multipart::{Form, Part};
use serde_json::{Value, json};

use crate::support::{decode_png, encode_png, run, scene_file};
use crate::support_server::*;

const LECTURE_TRACE: &str = "/v1/trace?u=2&v=2";

fn header<'a>(res: &'a reqwest::Response, name: &str) -> &'a str {
    res.headers()
        .get(name)
        .and_then(|v| v.to_str().ok())
        .unwrap_or_default()
}

/// A small scene worth grading: the shipped sphere at 32 × 24. Under 1000 pixels, so
/// that the default `max_fail_share` (0.1 %) lets no pixel fail.
fn small_scene() -> Value {
    resized(shipped("sphere.json"), 32, 24)
}

/// The form `curl -F scene=@scene.json -F submission=@FILE` sends (curl sends a `.json`
/// file as `application/octet-stream`, and so do we here).
fn form(scene: &Value, submission: Vec<u8>, file_name: &str) -> Form {
    Form::new()
        .part(
            "scene",
            Part::bytes(serde_json::to_vec(scene).unwrap())
                .file_name("scene.json")
                .mime_str("application/octet-stream")
                .unwrap(),
        )
        .part(
            "submission",
            Part::bytes(submission)
                .file_name(file_name.to_owned())
                .mime_str("application/octet-stream")
                .unwrap(),
        )
}

async fn grade(app: &TestApp, query: &str, form: Form) -> reqwest::Response {
    app.client
        .post(app.at(&format!("/v1/grade{query}")))
        .multipart(form)
        .send()
        .await
        .expect("the server answers")
}

/// The scene's image, from `/v1/render`.
async fn render(app: &TestApp, scene: &Value) -> Vec<u8> {
    let res = app.post_scene("/v1/render", scene).await;
    assert_eq!(res.status(), 200);
    res.bytes().await.unwrap().to_vec()
}

/// `png` with pixel `(u, v)` set to `rgb`.
fn with_pixel(png: &[u8], u: u32, v: u32, rgb: [u8; 3]) -> Vec<u8> {
    let (w, h, mut px) = decode_png(png);
    let k = 3 * (v * w + u) as usize;
    px[k..k + 3].copy_from_slice(&rgb);
    encode_png(w, h, &px)
}

fn b64(bytes: &[u8]) -> String {
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

// ---- trace ---------------------------------------------------------------------------

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn trace_explains_the_lecture_pixel_as_json() {
    let app = TestApp::spawn().await;
    let res = app
        .post_scene(LECTURE_TRACE, &shipped("lecture.json"))
        .await;
    assert_eq!(res.status(), 200);
    assert_eq!(header(&res, "content-type"), "application/json");
    let body = res.bytes().await.unwrap();
    let e: Value = serde_json::from_slice(&body).unwrap();
    let q = &e["tree"]["tests"][0]["quadratics"][0];
    assert_eq!(
        [&q["a"], &q["b"], &q["c"], &q["discriminant"]].map(Value::as_f64),
        [Some(1.0), Some(-4.0), Some(4.0), Some(0.0)]
    );
    assert_eq!(q["roots"][0]["lambda"], 2.0);
    assert_eq!(q["roots"][0]["counts"], true);
    assert_eq!(e["tree"]["hit"]["lambda"], 2.0);
    assert_eq!(e["tree"]["hit"]["point"], json!([0.0, 0.0, 2.0, 1.0]));

    // Byte for byte what the command line prints.
    let cli = run(&[
        "trace",
        crate::support::scene("lecture.json").to_str().unwrap(),
        "--pixel",
        "2,2",
        "--format",
        "json",
    ]);
    assert!(cli.status.success());
    assert_eq!(body.as_ref(), cli.stdout.as_slice());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn trace_as_text_by_format_or_accept() {
    let app = TestApp::spawn().await;
    let lecture = serde_json::to_vec(&shipped("lecture.json")).unwrap();
    let cli = run(&[
        "trace",
        crate::support::scene("lecture.json").to_str().unwrap(),
        "--pixel",
        "2,2",
    ]);
    assert!(cli.status.success());
    for (path, headers) in [
        ("/v1/trace?u=2&v=2&format=text", vec![]),
        (LECTURE_TRACE, vec![("accept", "text/plain")]),
        (
            LECTURE_TRACE,
            vec![("accept", "application/json;q=0.5, text/*")],
        ),
    ] {
        let res = app.post_json(path, lecture.clone(), &headers).await;
        assert_eq!(res.status(), 200, "{path} {headers:?}");
        assert_eq!(header(&res, "content-type"), "text/plain; charset=utf-8");
        let text = res.text().await.unwrap();
        for want in [
            "camera space: p(λ) = [0, 0, 0, 1] + λ [0, 0, 1, 0]",
            "ray in object space: [-1, 0, -2, 1] + λ [0, 0, 1, 0]",
            "sphere: a = 1, b = -4, c = 4; discriminant b² − 4ac = 0",
            "λ = 2 at [-1, 0, 0, 1]: the object's first hit",
            "Hit: object 0 \"ball\" (sphere) at λ = 2",
            "world point        [0, 0, 2, 1]",
        ] {
            assert!(text.contains(want), "missing {want:?} in\n{text}");
        }
        assert_eq!(text.as_bytes(), cli.stdout.as_slice());
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn trace_errors_are_problems() {
    let app = TestApp::spawn().await;
    let lecture = serde_json::to_vec(&shipped("lecture.json")).unwrap();
    for q in [
        "v=2",
        "u=2",
        "u=-1&v=2",
        "u=two&v=2",
        "u=2&v=2&u=3",
        "u=2&v=2&format=xml",
        "u=2&v=2&candidates=some",
        "u=2&v=2&max_rays=100000",
        "u=2&v=2&pixel=2,2",
    ] {
        problem(
            app.post_json(&format!("/v1/trace?{q}"), lecture.clone(), &[])
                .await,
            400,
            "bad-request",
        )
        .await;
    }

    // Outside the 5 × 5 image: where, and how large the image is.
    for (u, v) in [(5u32, 0u32), (0, 5), (u32::MAX, u32::MAX)] {
        let doc = problem(
            app.post_json(&format!("/v1/trace?u={u}&v={v}"), lecture.clone(), &[])
                .await,
            422,
            "pixel-outside-image",
        )
        .await;
        assert_eq!(
            (&doc["u"], &doc["v"], &doc["width"], &doc["height"]),
            (&json!(u), &json!(v), &json!(5), &json!(5))
        );
    }

    // A bad scene: every problem with its pointer, as for /v1/render.
    let mut bad = shipped("lecture.json");
    bad["image"]["width"] = json!(0);
    bad["objects"][0]["shape"] = json!("blob");
    let doc = problem(
        app.post_scene(LECTURE_TRACE, &bad).await,
        422,
        "invalid-scene",
    )
    .await;
    let pointers: Vec<&str> = doc["problems"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["pointer"].as_str().unwrap())
        .collect();
    assert!(pointers.contains(&"/image/width"), "{doc}");
    assert!(
        pointers.iter().any(|p| p.starts_with("/objects/0")),
        "{doc}"
    );
    problem(
        app.post_json(LECTURE_TRACE, "{", &[]).await,
        400,
        "invalid-json",
    )
    .await;

    // Nothing acceptable; an explicit format the client does not accept.
    problem(
        app.post_json(LECTURE_TRACE, lecture.clone(), &[("accept", "image/png")])
            .await,
        406,
        "not-acceptable",
    )
    .await;
    problem(
        app.post_json(
            "/v1/trace?u=2&v=2&format=text",
            lecture.clone(),
            &[("accept", "application/json")],
        )
        .await,
        406,
        "not-acceptable",
    )
    .await;

    // Listing every object of a large scene for every ray is refused, `bvh` is not.
    let grid = sphere_grid(40, 30, 33, 1);
    let doc = problem(
        app.post_scene("/v1/trace?u=20&v=20&candidates=all", &grid)
            .await,
        400,
        "bad-request",
    )
    .await;
    assert!(doc["detail"].as_str().unwrap().contains("candidates=bvh"));
    let res = app.post_scene("/v1/trace?u=20&v=20", &grid).await;
    assert_eq!(res.status(), 200);
    assert_eq!(res.json::<Value>().await.unwrap()["candidates"], "bvh");
}

// ---- grade: images -------------------------------------------------------------------

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_reference_itself_passes() {
    let app = TestApp::spawn().await;
    let scene = small_scene();
    let png = render(&app, &scene).await;
    let res = grade(&app, "", form(&scene, png, "student.png")).await;
    assert_eq!(res.status(), 200);
    assert_eq!(header(&res, "content-type"), "application/json");
    assert_eq!(header(&res, "x-raytile-verdict"), "pass");
    let r: Value = res.json().await.unwrap();
    assert_eq!(r["pass"], true, "{r}");
    assert_eq!(
        (r["kind"].as_str(), r["format"].as_str()),
        (Some("image"), Some("png"))
    );
    assert_eq!(r["failing_pixels"], 0);
    assert_eq!(
        (r["width"].as_u64(), r["height"].as_u64()),
        (Some(32), Some(24))
    );
    assert_eq!(r["image"]["max_abs_error"], 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_changed_pixel_fails_at_that_pixel() {
    let app = TestApp::spawn().await;
    let scene = small_scene();
    let (u, v) = (17, 11);
    let png = with_pixel(&render(&app, &scene).await, u, v, [255, 255, 0]);

    let res = grade(&app, "", form(&scene, png.clone(), "student.png")).await;
    assert_eq!(res.status(), 200, "a failing submission is still a 200");
    assert_eq!(header(&res, "x-raytile-verdict"), "fail");
    let body = res.bytes().await.unwrap();
    let r: Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(r["pass"], false);
    assert_eq!(r["failing_pixels"], 1);
    assert_eq!(
        (r["worst"][0]["u"].as_u64(), r["worst"][0]["v"].as_u64()),
        (Some(u as u64), Some(v as u64))
    );
    assert_eq!(r["worst"][0]["failures"], json!(["colour"]));
    assert_eq!(r["worst"][0]["submitted"]["rgb"], json!([255, 255, 0]));

    // Byte for byte the report `raytile grade` writes for the same files.
    let dir = tempfile::tempdir().unwrap();
    let scene_path = scene_file(&dir, "scene.json", &scene);
    let png_path = dir.path().join("student.png");
    std::fs::write(&png_path, &png).unwrap();
    let cli = run(&[
        "grade",
        scene_path.to_str().unwrap(),
        png_path.to_str().unwrap(),
    ]);
    assert_eq!(cli.status.code(), Some(1), "the command line says fail");
    assert_eq!(body.as_ref(), cli.stdout.as_slice());

    // Tolerances from the query, from a part, and the query over the part.
    let loose = grade(&app, "?colour_abs=255", form(&scene, png.clone(), "s.png")).await;
    assert_eq!(loose.json::<Value>().await.unwrap()["pass"], true);
    let with_part =
        |t: &str| form(&scene, png.clone(), "s.png").part("tolerances", Part::text(t.to_owned()));
    let r: Value = grade(&app, "", with_part(r#"{"colour_abs": 255}"#))
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(
        (r["pass"].as_bool(), r["tolerances"]["colour_abs"].as_u64()),
        (Some(true), Some(255))
    );
    let r: Value = grade(&app, "?colour_abs=0", with_part(r#"{"colour_abs": 255}"#))
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(
        (r["pass"].as_bool(), r["tolerances"]["colour_abs"].as_u64()),
        (Some(false), Some(0))
    );
    let r: Value = grade(
        &app,
        "?max_fail_share=0.01&worst=0",
        form(&scene, png, "s.png"),
    )
    .await
    .json()
    .await
    .unwrap();
    assert_eq!(r["pass"], true, "7 of 768 pixels may fail at 1 %");
    assert_eq!(r["worst"], json!([]));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_difference_image_and_the_report_forms() {
    let app = TestApp::spawn().await;
    let scene = small_scene();
    let (u, v) = (10, 20);
    let png = with_pixel(&render(&app, &scene).await, u, v, [0, 255, 0]);

    // output=diff: a PNG of the frame, the failing pixel magenta.
    let res = grade(&app, "?output=diff", form(&scene, png.clone(), "s.png")).await;
    assert_eq!(res.status(), 200);
    assert_eq!(header(&res, "content-type"), "image/png");
    assert_eq!(header(&res, "x-raytile-verdict"), "fail");
    let (w, h, px) = decode_png(&res.bytes().await.unwrap());
    assert_eq!((w, h), (32, 24));
    let k = 3 * (v * w + u) as usize;
    assert_eq!(px[k..k + 3], [255, 0, 255]);
    let magenta = px.chunks(3).filter(|p| *p == [255, 0, 255]).count();
    assert_eq!(magenta, 1);

    // Gradescope: all or nothing out of max_score.
    let res = grade(
        &app,
        "?report=gradescope&max_score=10",
        form(&scene, png.clone(), "s.png"),
    )
    .await;
    assert_eq!(header(&res, "content-type"), "application/json");
    let g: Value = res.json().await.unwrap();
    assert_eq!(
        (g["score"].as_f64(), g["max_score"].as_f64()),
        (Some(0.0), Some(10.0))
    );
    assert_eq!(g["tests"][0]["status"], "failed");
    // Markdown, the text report in a code block.
    assert!(g["output"].as_str().unwrap().starts_with("```text\nFAIL"));

    // PrairieLearn: score 0–1, the difference image inline.
    let p: Value = grade(
        &app,
        "?report=prairielearn",
        form(&scene, png.clone(), "s.png"),
    )
    .await
    .json()
    .await
    .unwrap();
    assert_eq!(
        (p["gradable"].as_bool(), p["score"].as_f64()),
        (Some(true), Some(0.0))
    );
    assert!(
        p["images"][0]["url"]
            .as_str()
            .unwrap()
            .starts_with("data:image/png;base64,")
    );

    // Text, by `report` or by `Accept`.
    for (query, accept) in [("?report=text", "*/*"), ("", "text/plain")] {
        let res = app
            .client
            .post(app.at(&format!("/v1/grade{query}")))
            .header("accept", accept)
            .multipart(form(&scene, png.clone(), "s.png"))
            .send()
            .await
            .unwrap();
        assert_eq!(header(&res, "content-type"), "text/plain; charset=utf-8");
        let text = res.text().await.unwrap();
        assert!(text.starts_with("FAIL: 1 of 768 pixels"), "{text}");
        assert!(text.contains(&format!("({u}, {v}) FAILS colour")), "{text}");
    }

    // The difference image inline in the JSON report, and the same as output=diff.
    let r: Value = grade(
        &app,
        "?inline_diff=true&flip=false",
        form(&scene, png.clone(), "s.png"),
    )
    .await
    .json()
    .await
    .unwrap();
    assert_eq!(r["image"]["flip"], Value::Null);
    let inline = base64::engine::general_purpose::STANDARD
        .decode(r["diff_png_base64"].as_str().unwrap())
        .unwrap();
    assert_eq!(decode_png(&inline), (w, h, px));
}

// ---- grade: the JSON form and hit data -----------------------------------------------

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hit_data_in_the_json_form() {
    let app = TestApp::spawn().await;
    let scene = small_scene();
    let mut hits: Value = app
        .post_scene("/v1/hits", &scene)
        .await
        .json()
        .await
        .unwrap();
    let res = app
        .post_json(
            "/v1/grade",
            serde_json::to_vec(&json!({ "scene": scene, "submission": hits })).unwrap(),
            &[],
        )
        .await;
    assert_eq!(res.status(), 200);
    let r: Value = res.json().await.unwrap();
    assert_eq!(
        (
            r["pass"].as_bool(),
            r["kind"].as_str(),
            r["format"].as_str()
        ),
        (Some(true), Some("hits"), Some("json"))
    );
    assert!(r["hits"]["both_hit"].as_u64().unwrap() > 0);

    // One pixel's λ off by 1 %: it fails the λ check there, with the body's tolerances.
    let k = hits["pixels"]
        .as_array()
        .unwrap()
        .iter()
        .position(|p| p["hit"] == true)
        .unwrap();
    let (u, v) = (
        hits["pixels"][k]["u"].clone(),
        hits["pixels"][k]["v"].clone(),
    );
    let lambda = hits["pixels"][k]["lambda"].as_f64().unwrap();
    hits["pixels"][k]["lambda"] = json!(lambda * 1.01);
    let body = |tolerances: Value| {
        serde_json::to_vec(&json!({ "scene": scene, "submission": hits, "tolerances": tolerances }))
            .unwrap()
    };
    let r: Value = app
        .post_json("/v1/grade", body(json!({})), &[])
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(
        (r["pass"].as_bool(), r["hits"]["lambda"].as_u64()),
        (Some(false), Some(1))
    );
    assert_eq!((&r["worst"][0]["u"], &r["worst"][0]["v"]), (&u, &v));
    assert_eq!(r["worst"][0]["failures"], json!(["lambda"]));
    let r: Value = app
        .post_json("/v1/grade", body(json!({ "lambda_rel": 0.02 })), &[])
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(r["pass"], true);

    // The bare array of pixels, and CSV as text.
    let pixels = hits["pixels"].clone();
    let r: Value = app
        .post_json(
            "/v1/grade?lambda_rel=0.02",
            serde_json::to_vec(&json!({ "scene": scene, "submission": pixels })).unwrap(),
            &[],
        )
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(r["pass"], true);
    let mut csv = String::from("u,v,hit,lambda,nx,ny,nz\n");
    for p in pixels.as_array().unwrap() {
        let n = |i: usize| {
            p["normal"][i]
                .as_f64()
                .map_or(String::new(), |x| format!("{x:?}"))
        };
        let l = p["lambda"]
            .as_f64()
            .map_or(String::new(), |x| format!("{x:?}"));
        csv.push_str(&format!(
            "{},{},{},{l},{},{},{}\n",
            p["u"],
            p["v"],
            p["hit"],
            n(0),
            n(1),
            n(2)
        ));
    }
    let r: Value = app
        .post_json(
            "/v1/grade",
            serde_json::to_vec(&json!({ "scene": scene, "submission": { "csv": csv } })).unwrap(),
            &[],
        )
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(
        (
            r["pass"].as_bool(),
            r["format"].as_str(),
            r["hits"]["lambda"].as_u64()
        ),
        (Some(false), Some("csv"), Some(1))
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_png_in_the_json_form_and_hit_data_in_the_form() {
    let app = TestApp::spawn().await;
    let scene = small_scene();
    let png = render(&app, &scene).await;
    let res = app
        .post_json(
            "/v1/grade",
            serde_json::to_vec(
                &json!({ "scene": scene, "submission": { "png_base64": b64(&png) } }),
            )
            .unwrap(),
            &[],
        )
        .await;
    assert_eq!(res.status(), 200);
    assert_eq!(res.json::<Value>().await.unwrap()["pass"], true);

    // Hit data as NPY in the form, its form told by the file name.
    let npy = app
        .post_json(
            "/v1/hits",
            serde_json::to_vec(&scene).unwrap(),
            &[("accept", "application/x-npy")],
        )
        .await
        .bytes()
        .await
        .unwrap();
    let r: Value = grade(&app, "", form(&scene, npy.to_vec(), "student.npy"))
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(
        (r["pass"].as_bool(), r["format"].as_str()),
        (Some(true), Some("npy"))
    );
}

// ---- grade: what cannot be graded ----------------------------------------------------

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn submissions_that_cannot_be_graded_are_422() {
    let app = TestApp::spawn().await;
    let scene = small_scene();
    let png = render(&app, &scene).await;
    let wrong_size = render(&app, &resized(scene.clone(), 31, 24)).await;
    let cases: Vec<(Vec<u8>, &str, &str, &str)> = vec![
        (
            png[..png.len() / 2].to_vec(),
            "s.png",
            "corrupt-png",
            "the PNG file is corrupt",
        ),
        (
            wrong_size,
            "s.png",
            "size-mismatch",
            "the submission is 31 × 24 pixels but the scene renders 32 × 24",
        ),
        (b"not a png".to_vec(), "s.png", "not-png", "not a PNG file"),
        (Vec::new(), "s.png", "empty", "the submission is empty"),
        (
            vec![0xff; 100],
            "s.bin",
            "unknown-format",
            "cannot tell what the submission is",
        ),
        (
            b"u,v,hit\n0,0,1\n".to_vec(),
            "s.csv",
            "missing-field",
            "no CSV column `lambda`",
        ),
        (
            b"[{\"hit\": false}]".to_vec(),
            "s.json",
            "missing-pixels",
            "missing from the hit data",
        ),
    ];
    for (bytes, name, reason, detail) in cases {
        let doc = problem(
            grade(&app, "", form(&scene, bytes, name)).await,
            422,
            "invalid-submission",
        )
        .await;
        assert_eq!(doc["reason"], reason, "{doc}");
        assert!(doc["detail"].as_str().unwrap().contains(detail), "{doc}");
    }

    // `format` overrides what the part says (an image's signature overrides both).
    let ragged = b"u,v,hit,lambda,nx,ny,nz\n0,0\n".to_vec();
    let doc = problem(
        grade(&app, "?format=csv", form(&scene, ragged, "s.png")).await,
        422,
        "invalid-submission",
    )
    .await;
    assert_eq!(doc["reason"], "syntax", "{doc}");

    // The JSON form: bad base64, a submission of no known shape.
    for submission in [
        json!({ "png_base64": "@@@" }),
        json!(42),
        json!({ "png_base64": 1 }),
    ] {
        let doc = problem(
            app.post_json(
                "/v1/grade",
                serde_json::to_vec(&json!({ "scene": scene, "submission": submission })).unwrap(),
                &[],
            )
            .await,
            422,
            "invalid-submission",
        )
        .await;
        assert_eq!(doc["reason"], "bad-value", "{doc}");
    }

    // A bad scene in either form; in the JSON form the pointers point into the body.
    let mut bad = scene.clone();
    bad["image"]["width"] = json!(0);
    let doc = problem(
        grade(&app, "", form(&bad, png.clone(), "s.png")).await,
        422,
        "invalid-scene",
    )
    .await;
    assert_eq!(doc["problems"][0]["pointer"], "/image/width");
    let doc = problem(
        app.post_json(
            "/v1/grade",
            serde_json::to_vec(&json!({ "scene": bad, "submission": { "png_base64": b64(&png) } }))
                .unwrap(),
            &[],
        )
        .await,
        422,
        "invalid-scene",
    )
    .await;
    assert_eq!(doc["problems"][0]["pointer"], "/scene/image/width");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_grading_requests_are_400_406_415_413() {
    let app = TestApp::with(ServeArgs {
        max_body_bytes: 64 * 1024,
        ..config()
    })
    .await;
    let scene = small_scene();
    let png = render(&app, &scene).await;
    let ok = || form(&scene, png.clone(), "s.png");

    for query in [
        "?colour_abs=256",
        "?max_fail_share=2",
        "?max_fail_share=nan",
        "?lambda_rel=-1",
        "?normal_degrees=181",
        "?edge_forgiving=maybe",
        "?worst=1001",
        "?max_score=-1",
        "?report=html",
        "?output=diff&report=json",
        "?format=gif",
        "?colour_abs=1&color_abs=2",
        "?tolerance=1",
    ] {
        problem(grade(&app, query, ok()).await, 400, "bad-request").await;
    }
    let cases = [
        Form::new().part("scene", Part::bytes(serde_json::to_vec(&scene).unwrap())),
        Form::new().part("submission", Part::bytes(png.clone())),
        ok().part("notes", Part::text("hello")),
        ok().part("scene", Part::text("{}")),
        ok().part("tolerances", Part::text(r#"{"colour": 1}"#)),
    ];
    for f in cases {
        problem(grade(&app, "", f).await, 400, "bad-request").await;
    }
    let doc = problem(
        grade(&app, "", ok().part("tolerances", Part::text("{"))).await,
        400,
        "invalid-json",
    )
    .await;
    assert!(
        doc["detail"]
            .as_str()
            .unwrap()
            .contains("`tolerances` part")
    );
    for body in [
        json!({ "scene": scene }),
        json!({ "scene": scene, "submission": [], "extra": 1 }),
        json!({ "scene": scene, "submission": [], "tolerances": { "colour_abs": 300 } }),
    ] {
        problem(
            app.post_json("/v1/grade", serde_json::to_vec(&body).unwrap(), &[])
                .await,
            400,
            "bad-request",
        )
        .await;
    }

    problem(
        app.client
            .post(app.at("/v1/grade"))
            .header("accept", "image/gif")
            .multipart(ok())
            .send()
            .await
            .unwrap(),
        406,
        "not-acceptable",
    )
    .await;
    problem(
        app.client
            .post(app.at("/v1/grade?output=diff"))
            .header("accept", "application/json")
            .multipart(ok())
            .send()
            .await
            .unwrap(),
        406,
        "not-acceptable",
    )
    .await;

    let doc = problem(
        app.client
            .post(app.at("/v1/grade"))
            .header("content-type", "image/png")
            .body(png.clone())
            .send()
            .await
            .unwrap(),
        415,
        "unsupported-media-type",
    )
    .await;
    assert_eq!(
        doc["supported"],
        json!(["multipart/form-data", "application/json"])
    );

    // The limit is the whole request's, not a part's.
    let big = vec![b'x'; 40 * 1024];
    let doc = problem(
        grade(
            &app,
            "",
            ok().part("tolerances", Part::bytes(big.clone()))
                .part("more", Part::bytes(big)),
        )
        .await,
        413,
        "body-too-large",
    )
    .await;
    assert_eq!(doc["limit_bytes"], 64 * 1024);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_form_larger_than_two_mebibytes_is_read_whole() {
    // axum's own default limit for forms is 2 MiB; the server's `--max-body-bytes` (16
    // MiB by default) is the one that applies.
    let app = TestApp::spawn().await;
    let scene = small_scene();
    let noise: Vec<u8> = (0..3_000_000u32)
        .map(|i| (i.wrapping_mul(2654435761) >> 24) as u8)
        .collect();
    let doc = problem(
        grade(&app, "?format=png", form(&scene, noise, "s.png")).await,
        422,
        "invalid-submission",
    )
    .await;
    assert_eq!(doc["reason"], "not-png");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn no_input_makes_grading_answer_500() {
    let app = TestApp::spawn().await;
    let scene = small_scene();
    let bodies: Vec<Vec<u8>> = vec![
        b"".to_vec(),
        b"null".to_vec(),
        b"[]".to_vec(),
        b"{}".to_vec(),
        b"1e999".to_vec(),
        "[".repeat(100_000).into_bytes(),
        serde_json::to_vec(&json!({ "scene": null, "submission": null })).unwrap(),
        serde_json::to_vec(&json!({ "scene": scene, "submission": { "npy_base64": "k05VTVBZ" } }))
            .unwrap(),
        serde_json::to_vec(&json!({ "scene": scene, "submission": { "ndjson": "{\n" } })).unwrap(),
        serde_json::to_vec(&json!({ "scene": scene, "submission": [{ "u": 4294967295u32, "v": 0, "hit": false }] }))
            .unwrap(),
        serde_json::to_vec(&json!({ "scene": scene, "submission": { "width": 4294967295u32, "height": 4294967295u32, "pixels": [] } }))
            .unwrap(),
    ];
    for b in bodies {
        let res = app.post_json("/v1/grade", b.clone(), &[]).await;
        let status = res.status().as_u16();
        assert!(
            (400..500).contains(&status),
            "{:?}: {status}",
            String::from_utf8_lossy(&b[..b.len().min(80)])
        );
        assert_eq!(header(&res, "content-type"), "application/problem+json");
    }
    for (ct, body) in [
        ("multipart/form-data", b"--x\r\n".to_vec()),
        (
            "multipart/form-data; boundary=x",
            b"--x\r\nnonsense".to_vec(),
        ),
        ("multipart/form-data; boundary=x", b"".to_vec()),
    ] {
        let res = app
            .client
            .post(app.at("/v1/grade"))
            .header("content-type", ct)
            .body(body)
            .send()
            .await
            .unwrap();
        assert_eq!(res.status(), 400, "{ct}");
    }
    assert_eq!(app.get("/healthz").await.status(), 200, "still alive");
}

// ---- admission -------------------------------------------------------------------------

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn saturated_trace_and_grade_are_503_but_bad_requests_still_4xx() {
    let app = TestApp::with(ServeArgs {
        max_renders: Some(1),
        queue: 0,
        ..config()
    })
    .await;
    let scene = small_scene();
    let png = render(&app, &scene).await;
    let lecture = shipped("lecture.json");
    // The render above frees its slot just after its last byte.
    app.wait_for_metric(
        "raytile_renders_in_flight",
        std::time::Duration::from_secs(30),
        |v| v == 0.0,
    )
    .await;

    // Hold the one render slot, as a long render would.
    let slot = app
        .state
        .admission
        .admit(&app.state.shutdown)
        .await
        .expect("a free slot");
    let res = app.post_scene(LECTURE_TRACE, &lecture).await;
    assert_eq!(header(&res, "retry-after"), "1");
    problem(res, 503, "saturated").await;
    let res = grade(&app, "", form(&scene, png.clone(), "s.png")).await;
    assert_eq!(header(&res, "retry-after"), "1");
    problem(res, 503, "saturated").await;
    // Decided before admission, so still answered as what they are.
    problem(
        app.post_scene("/v1/trace?u=9&v=9", &lecture).await,
        422,
        "pixel-outside-image",
    )
    .await;
    problem(
        grade(&app, "", form(&scene, b"junk".to_vec(), "s.png")).await,
        422,
        "invalid-submission",
    )
    .await;

    drop(slot);
    assert_eq!(app.post_scene(LECTURE_TRACE, &lecture).await.status(), 200);
    assert_eq!(
        grade(&app, "", form(&scene, png, "s.png")).await.status(),
        200
    );
    // The slot is free again once each answer is out.
    app.wait_for_metric(
        "raytile_renders_in_flight",
        std::time::Duration::from_secs(30),
        |v| v == 0.0,
    )
    .await;
}

// ---- trace: bounded answers ------------------------------------------------------------

/// `n` identical unit spheres around the camera, of one mirror-and-glass material: every
/// ray of a pixel's tree is a candidate ray of every sphere.
fn coincident_spheres(n: usize) -> Value {
    let objects = vec![json!({"shape": "sphere", "material": "glass"}); n];
    json!({
        "version": 1,
        "image": {"width": 5, "height": 5},
        "camera": {"focal_length": 1},
        "max_depth": 10,
        "materials": {"glass": {
            "diffuse": [0.1, 0.1, 0.1],
            "mirror": [0.5, 0.5, 0.5],
            "transmission": [0.5, 0.5, 0.5],
            "ior": 1.5
        }},
        "objects": objects,
        "lights": [{"type": "point", "position": [0, -4, 0], "colour": [1, 1, 1]}]
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn trace_answers_are_bounded_in_every_candidates_mode() {
    let app = TestApp::spawn().await;
    let largest = "max_rays=1024&max_triangles=1024&max_tests=1024";
    for n in [2_000, 20_000] {
        let scene = coincident_spheres(n);
        // `all` lists every object for every ray only up to 65 536 tests: 3 rays here.
        for q in [
            format!("candidates=auto&{largest}"),
            format!("candidates=bvh&{largest}"),
            "candidates=all&max_rays=3&max_tests=1024&max_triangles=1024".to_owned(),
            "candidates=bvh&max_rays=1024&format=text".to_owned(),
        ] {
            let res = app
                .post_scene(&format!("/v1/trace?u=2&v=2&{q}"), &scene)
                .await;
            assert_eq!(res.status(), 200, "{n} {q}");
            let body = res.bytes().await.unwrap();
            // The budget is 2 MiB of the JSON answer; the text of it is smaller.
            assert!(body.len() < 2_400_000, "{n} {q}: {} bytes", body.len());
            if q.ends_with("text") {
                let text = String::from_utf8_lossy(&body);
                assert!(text.contains("Shortened to stay readable"), "{n} {q}");
                assert!(text.contains("more objects tested, not listed"), "{n} {q}");
                continue;
            }
            let e: Value = serde_json::from_slice(&body).unwrap();
            assert_eq!(e["truncated"], true, "{n} {q}");
            let t = &e["truncation"];
            assert!(t["tests_unlisted"].as_u64().unwrap() > 0, "{n} {q}");
            assert_eq!(t["max_bytes"], 2 * 1024 * 1024);
            assert_eq!(e["tree"]["tested"], n);
            let listed = e["tree"]["tests"].as_array().unwrap().len();
            assert!(listed <= 1025, "{n} {q}");
            assert_eq!(e["tree"]["tests_unlisted"], n - listed, "{n} {q}");
            if q.starts_with("candidates=all") {
                assert_eq!(e["candidates"], "all");
            } else {
                // The budget ran out, and the answer says at which ray.
                let at = &t["budget_spent_at"];
                assert!(at["pointer"].as_str().unwrap().starts_with("/tree"), "{at}");
                assert!(at["ray"].as_u64().unwrap() >= 1, "{at}");
            }
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn trace_max_tests_is_checked() {
    let app = TestApp::spawn().await;
    let lecture = serde_json::to_vec(&shipped("lecture.json")).unwrap();
    for q in [
        "max_tests=1025",
        "max_tests=-1",
        "max_tests=x",
        "max_tests=1&max_tests=2",
    ] {
        let doc = problem(
            app.post_json(&format!("/v1/trace?u=2&v=2&{q}"), lecture.clone(), &[])
                .await,
            400,
            "bad-request",
        )
        .await;
        assert!(
            doc["detail"].as_str().unwrap().contains("max_tests"),
            "{q}: {doc}"
        );
    }
    let res = app
        .post_json("/v1/trace?u=2&v=2&max_tests=0", lecture.clone(), &[])
        .await;
    assert_eq!(res.status(), 200);
    let e: Value = res.json().await.unwrap();
    // The chosen hit's test is always listed.
    assert_eq!(e["tree"]["tests"].as_array().unwrap().len(), 1);
    assert_eq!(e["truncation"]["max_tests"], 0);
    assert_eq!(e["truncated"], false);
}
