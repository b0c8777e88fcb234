//! Every accepted submission format, written by encoders other than raytile's
//! (`tests/fixtures/submissions/`, made by its `make.py` with Pillow, NumPy, the OpenEXR
//! library and plain Python): a correct image of the lecture's scene passes, the same
//! image upside down fails, a truncated one is an invalid submission, by `raytile grade`
//! and by `POST /v1/grade` alike. Also the float images `raytile render` writes, and hit
//! data as Python's `json.dump` writes it.

use std::path::{Path, PathBuf};
use std::process::Output;

use base64::Engine as _;
use raytile::format::{Raster, RasterFormat, raster};
use reqwest::multipart::{Form, Part};
use serde_json::{Value, json};

use crate::support::*;
use crate::support_server::{TestApp, problem};

/// Each image fixture (without its `ok-` or `flipped-` prefix) and the report's format.
const IMAGES: [(&str, &str); 14] = [
    ("p3.ppm", "ppm"),
    ("p6.ppm", "ppm"),
    ("p6-16bit.ppm", "ppm"),
    ("rgb.png", "png"),
    ("rgba.png", "png"),
    ("palette.png", "png"),
    ("16bit.png", "png"),
    ("rgb.bmp", "bmp"),
    ("rgb.tga", "tga"),
    ("rle.tga", "tga"),
    ("q100.jpg", "jpeg"),
    ("linear.pfm", "pfm"),
    ("float.exr", "exr"),
    ("half.exr", "exr"),
];

/// A quality-100 JPEG is off by up to 3/255 (see the grading guide's formats).
const JPEG_TOLERANCE: &str = "3";

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/submissions")
        .join(name)
}

fn s(p: &Path) -> &str {
    p.to_str().expect("a UTF-8 path")
}

fn read(name: &str) -> Vec<u8> {
    std::fs::read(fixture(name)).expect("a committed fixture")
}

fn grade(submission: &Path, extra: &[&str]) -> Output {
    let scene = fixture("scene.json");
    let mut args = vec!["grade", s(&scene), s(submission)];
    args.extend_from_slice(extra);
    run(&args)
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn tolerance_for(name: &str) -> Vec<&'static str> {
    if name.ends_with(".jpg") {
        vec!["--colour-abs", JPEG_TOLERANCE]
    } else {
        vec![]
    }
}

#[test]
fn a_correct_image_in_every_format_passes_and_upside_down_fails() {
    for (name, format) in IMAGES {
        let extra = tolerance_for(name);
        let out = grade(&fixture(&format!("ok-{name}")), &extra);
        assert_eq!(out.status.code(), Some(0), "{name}: {}", stderr(&out));
        let r = stdout_json(&out);
        assert_eq!(
            (r["pass"].as_bool(), r["format"].as_str()),
            (Some(true), Some(format)),
            "{name}"
        );
        assert_eq!(r["failing_pixels"], 0, "{name}");
        let out = grade(&fixture(&format!("flipped-{name}")), &extra);
        assert_eq!(out.status.code(), Some(1), "{name}: {}", stderr(&out));
        let r = stdout_json(&out);
        assert_eq!(r["pass"], false, "{name}");
        assert!(r["failing_pixels"].as_u64().unwrap() > 100, "{name}: {r}");
    }
}

#[test]
fn float_images_are_compared_in_linear_radiance() {
    for name in ["ok-linear.pfm", "ok-float.exr", "ok-half.exr"] {
        let r = stdout_json(&grade(&fixture(name), &[]));
        assert_eq!(r["pass"], true, "{name}");
        assert!(
            r["summary"].as_str().unwrap().contains("linear radiance"),
            "{r}"
        );
        let max = r["linear"]["max_abs_error"].as_f64().unwrap();
        // Full floats carry the reference's values; half floats round them to 11 bits.
        if name == "ok-half.exr" {
            assert!(max > 0.0 && max < 2e-3, "{max}");
        } else {
            assert!(max < 1e-6, "{max}");
        }
    }
    // Half floats pass the default tolerance, not a tenfold tighter one: the linear
    // tolerances decide.
    let out = grade(
        &fixture("ok-half.exr"),
        &["--linear-rel", "0.0001", "--linear-abs", "0"],
    );
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let r = stdout_json(&out);
    assert_eq!(r["worst"][0]["failures"], json!(["linear"]));
    assert!(r["worst"][0]["submitted"]["linear"].is_array(), "{r}");
}

#[test]
fn a_jpeg_carries_a_warning_and_rarely_matches_exactly() {
    let out = grade(&fixture("ok-q100.jpg"), &[]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let r = stdout_json(&out);
    assert!(r["image"]["max_abs_error"].as_u64().unwrap() <= 3, "{r}");
    let warning = r["warnings"][0].as_str().unwrap();
    assert!(
        warning.contains("JPEG") && warning.contains("lossy"),
        "{warning}"
    );
    let text = grade(&fixture("ok-q100.jpg"), &["--report", "text"]);
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(text.contains("Warning: the submission is a JPEG"), "{text}");
    // Other formats warn of nothing.
    let r = stdout_json(&grade(&fixture("ok-rgb.png"), &[]));
    assert!(r.get("warnings").is_none(), "{r}");
}

#[test]
fn the_format_is_told_by_content_not_by_the_file_name() {
    let dir = tempfile::tempdir().unwrap();
    for (from, to) in [
        ("ok-p3.ppm", "student.png"),
        ("ok-rgb.bmp", "student.jpg"),
        ("ok-float.exr", "out.txt"),
        ("ok-linear.pfm", "hits.json"),
    ] {
        let p = dir.path().join(to);
        std::fs::copy(fixture(from), &p).unwrap();
        let out = grade(&p, &[]);
        assert_eq!(
            out.status.code(),
            Some(0),
            "{from} as {to}: {}",
            stderr(&out)
        );
    }
}

#[test]
fn truncated_and_transparent_images_are_invalid_submissions() {
    let dir = tempfile::tempdir().unwrap();
    for (name, _) in IMAGES {
        let bytes = read(&format!("ok-{name}"));
        let p = dir.path().join(format!("cut-{name}"));
        std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
        let out = grade(&p, &[]);
        assert_eq!(out.status.code(), Some(2), "{name}");
        let err = stderr(&out);
        assert!(err.contains("file is corrupt"), "{name}: {err}");
    }
    // An image whose alpha is not opaque everywhere is refused, saying where.
    let rgba = read("ok-rgba.png");
    let img = match raster::decode(&rgba, RasterFormat::Png, &Default::default()).unwrap() {
        Raster::Rgb8(i) => i,
        Raster::Linear(_) => unreachable!(),
    };
    let mut px: Vec<u8> = img
        .data
        .chunks(3)
        .flat_map(|c| [c[0], c[1], c[2], 255])
        .collect();
    px[4 * 33 + 3] = 128;
    let mut png = Vec::new();
    let mut enc = png::Encoder::new(&mut png, img.width, img.height);
    enc.set_color(png::ColorType::Rgba);
    let mut w = enc.write_header().unwrap();
    w.write_image_data(&px).unwrap();
    w.finish().unwrap();
    let p = dir.path().join("transparent.png");
    std::fs::write(&p, &png).unwrap();
    let out = grade(&p, &[]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr(&out).contains("pixel (1, 1) is not opaque (alpha 128)"),
        "{}",
        stderr(&out)
    );
    // Nothing recognisable: every accepted format is named.
    let p = dir.path().join("notes.txt");
    std::fs::write(&p, b"my ray tracer's output").unwrap();
    let err = stderr(&grade(&p, &[]));
    for name in [
        "PNG", "PPM", "BMP", "TGA", "JPEG", "PFM", "OpenEXR", "JSON", "NDJSON", "NPY", "CSV",
    ] {
        assert!(err.contains(name), "{name}: {err}");
    }
}

#[test]
fn render_writes_the_linear_colours_as_exr_and_pfm() {
    let dir = tempfile::tempdir().unwrap();
    let scene = fixture("scene.json");
    let mut images = Vec::new();
    for name in ["x.exr", "x.pfm"] {
        let p = dir.path().join(name);
        let out = run(&["render", s(&scene), "-o", s(&p)]);
        assert!(out.status.success(), "{}", stderr(&out));
        let bytes = std::fs::read(&p).unwrap();
        let f = RasterFormat::sniff(&bytes).unwrap();
        let Raster::Linear(img) = raster::decode(&bytes, f, &Default::default()).unwrap() else {
            panic!("{name} is not linear");
        };
        // What `render` writes as a float image grades as a correct submission.
        let out = grade(&p, &[]);
        assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
        images.push(img);
    }
    assert_eq!(images[0], images[1]);
    // Quantised as the renderer does (the scene has no gamma), it is the PNG.
    let png = dir.path().join("x.png");
    assert!(run(&["render", s(&scene), "-o", s(&png)]).status.success());
    let (w, h, rgb) = decode_png(&std::fs::read(&png).unwrap());
    assert_eq!((images[0].width, images[0].height), (w, h));
    assert_eq!(images[0].quantise(None).data, rgb);
    // A region is written at its own size.
    let part = dir.path().join("part.exr");
    let out = run(&["render", s(&scene), "-o", s(&part), "--region", "4,3,10,5"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let bytes = std::fs::read(&part).unwrap();
    let Raster::Linear(p) = raster::decode(&bytes, RasterFormat::Exr, &Default::default()).unwrap()
    else {
        panic!("linear");
    };
    assert_eq!((p.width, p.height), (10, 5));
    assert_eq!(p.get(0, 0), images[0].get(4, 3));
    assert_eq!(p.get(9, 4), images[0].get(13, 7));
}

#[test]
fn hit_data_as_python_writes_it_with_nan_for_misses_passes() {
    for name in ["ok-hits-nan.json", "ok-hits-nan.ndjson"] {
        let text = read(name);
        assert!(text.windows(3).any(|w| w == b"NaN"));
        let out = grade(&fixture(name), &[]);
        assert_eq!(out.status.code(), Some(0), "{name}: {}", stderr(&out));
        let r = stdout_json(&out);
        assert_eq!(r["kind"], "hits");
        // Infinity and null read as well; a NaN λ on a hit fails that pixel, not the file.
        let t = String::from_utf8(text.clone()).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join(name);
        let first_hit = t.find("\"hit\": true").unwrap();
        let lambda = first_hit + t[first_hit..].find("\"lambda\": ").unwrap() + 10;
        let end = lambda + t[lambda..].find(',').unwrap();
        let bad = format!(
            "{}NaN{}",
            &t[..lambda].replacen("\"lambda\": NaN", "\"lambda\": -Infinity", 1),
            &t[end..]
        )
        .replacen("\"object\": NaN", "\"object\": null", 1);
        std::fs::write(&p, bad).unwrap();
        let out = grade(&p, &[]);
        assert_eq!(out.status.code(), Some(1), "{name}: {}", stderr(&out));
        let r = stdout_json(&out);
        assert_eq!(
            (r["failing_pixels"].as_u64(), r["hits"]["lambda"].as_u64()),
            (Some(1), Some(1))
        );
    }
}

// ---- the server ------------------------------------------------------------------------

fn scene_doc() -> Value {
    serde_json::from_slice(&read("scene.json")).unwrap()
}

fn form(bytes: Vec<u8>, file_name: &str) -> Form {
    Form::new()
        .part(
            "scene",
            Part::bytes(read("scene.json"))
                .file_name("scene.json")
                .mime_str("application/json")
                .unwrap(),
        )
        .part(
            "submission",
            Part::bytes(bytes)
                .file_name(file_name.to_owned())
                .mime_str("application/octet-stream")
                .unwrap(),
        )
}

async fn post(app: &TestApp, query: &str, form: Form) -> reqwest::Response {
    app.client
        .post(app.at(&format!("/v1/grade{query}")))
        .multipart(form)
        .send()
        .await
        .expect("the server answers")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_server_grades_every_format_the_same() {
    let app = TestApp::spawn().await;
    for (name, format) in IMAGES {
        let query = if name.ends_with(".jpg") {
            format!("?colour_abs={JPEG_TOLERANCE}")
        } else {
            String::new()
        };
        // The file name says nothing true: the content decides.
        let res = post(
            &app,
            &query,
            form(read(&format!("ok-{name}")), "submission.png"),
        )
        .await;
        assert_eq!(res.status(), 200, "{name}");
        assert_eq!(res.headers()["x-raytile-verdict"], "pass", "{name}");
        let r: Value = res.json().await.unwrap();
        assert_eq!(r["format"], format, "{name}");
        let res = post(
            &app,
            &query,
            form(read(&format!("flipped-{name}")), "s.bin"),
        )
        .await;
        assert_eq!(res.headers()["x-raytile-verdict"], "fail", "{name}");
        let bytes = read(&format!("ok-{name}"));
        let res = post(&app, "", form(bytes[..bytes.len() / 2].to_vec(), "s.bin")).await;
        let doc = problem(res, 422, "invalid-submission").await;
        let reason = if format == "png" {
            "corrupt-png"
        } else {
            "corrupt-image"
        };
        assert_eq!(doc["reason"], reason, "{name}: {doc}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_json_request_as_python_writes_it_with_nan_for_misses_is_graded() {
    let app = TestApp::spawn().await;
    // What `json.dumps({"scene": scene, "submission": hits})` sends: bare NaN for misses.
    let hits = String::from_utf8(read("ok-hits-nan.json")).unwrap();
    let scene = String::from_utf8(read("scene.json")).unwrap();
    let body = format!("{{\"scene\": {scene}, \"submission\": {hits}}}");
    assert!(body.contains("NaN"));
    let res = app.post_json("/v1/grade", body, &[]).await;
    assert_eq!(res.status(), 200);
    assert_eq!(res.headers()["x-raytile-verdict"], "pass");
    // A NaN in the scene is still refused, with where it is.
    let mut doc = scene_doc();
    doc["camera"]["focal_length"] = json!("NAN_HERE");
    let bad_scene = doc.to_string().replace("\"NAN_HERE\"", "NaN");
    let body = format!("{{\"scene\": {bad_scene}, \"submission\": {hits}}}");
    let res = app.post_json("/v1/grade", body, &[]).await;
    let doc = problem(res, 400, "invalid-json").await;
    assert!(doc["column"].as_u64().unwrap() > 0, "{doc}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_linear_tolerances_are_query_parameters_too() {
    let app = TestApp::spawn().await;
    let half = || form(read("ok-half.exr"), "s.exr");
    let res = post(&app, "", half()).await;
    assert_eq!(res.headers()["x-raytile-verdict"], "pass");
    // Half floats fail a tenfold tighter tolerance, given in the query as on the command line.
    let res = post(&app, "?linear_rel=0.0001&linear_abs=0", half()).await;
    assert_eq!(res.status(), 200);
    assert_eq!(res.headers()["x-raytile-verdict"], "fail");
    let r: Value = res.json().await.unwrap();
    assert_eq!(r["tolerances"]["linear_rel"], 0.0001, "{r}");
    assert_eq!(r["worst"][0]["failures"], json!(["linear"]), "{r}");
    let res = post(&app, "?linear_abs=x", half()).await;
    problem(res, 400, "bad-request").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn json_requests_carry_images_as_members_and_unknown_members_list_every_name() {
    let app = TestApp::spawn().await;
    let b64 = |name: &str| base64::engine::general_purpose::STANDARD.encode(read(name));
    let p3 = String::from_utf8(read("ok-p3.ppm")).unwrap();
    for submission in [
        json!({"ppm": p3}),
        json!({"ppm_base64": b64("ok-p6.ppm")}),
        json!({"exr_base64": b64("ok-float.exr")}),
        json!({"pfm_base64": b64("ok-linear.pfm")}),
        json!({"image_base64": b64("ok-rgb.tga")}),
        json!({"bmp_base64": b64("ok-rgb.bmp")}),
    ] {
        let body = json!({"scene": scene_doc(), "submission": submission});
        let res = app.post_json("/v1/grade", body.to_string(), &[]).await;
        assert_eq!(res.status(), 200);
        assert_eq!(
            res.headers()["x-raytile-verdict"],
            "pass",
            "{submission:.60}"
        );
    }
    for (submission, at) in [
        (json!({"pgm": p3}), "submission.pgm"),
        (
            json!({"png_base64": "", "width": 2}),
            "submission.png_base64",
        ),
    ] {
        let body = json!({"scene": scene_doc(), "submission": submission});
        let res = app.post_json("/v1/grade", body.to_string(), &[]).await;
        let doc = problem(res, 422, "invalid-submission").await;
        let detail = doc["detail"].as_str().unwrap();
        assert!(detail.contains(at), "{detail}");
        for name in [
            "`pixels`",
            "`width`",
            "`png_base64`",
            "`ppm`",
            "`exr_base64`",
            "`csv`",
            "`ndjson`",
        ] {
            assert!(detail.contains(name), "{name}: {detail}");
        }
    }
}
