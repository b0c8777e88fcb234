//! The learning platforms' results files and partial credit, as an instructor's
//! autograder script uses them: `raytile grade --report gradescope | prairielearn` for
//! submissions that cannot be graded (the file is still written, the exit status 2),
//! missing output folders, Gradescope's visibilities, each scoring mode's score for a
//! submission with a known share of wrong pixels (made here by editing the reference
//! render), the tests' points adding up to the score, and the same over HTTP.

use std::path::{Path, PathBuf};
use std::process::Output;

use raytile::format::PixelHit;
use reqwest::multipart::{Form, Part};
use serde_json::Value;

use crate::support::*;
use crate::support_server::*;

fn s(p: &Path) -> &str {
    p.to_str().expect("a UTF-8 path")
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn grade(scene: &Path, submission: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["grade", s(scene), s(submission)];
    args.extend_from_slice(extra);
    run(&args)
}

fn read_json(p: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(p).expect("the results file")).expect("JSON")
}

/// The width and height of the test frame: 5000 pixels, so that shares are round.
const W: u32 = 100;
const H: u32 = 50;

/// The sphere scene at `W × H` and its reference render.
fn reference(dir: &tempfile::TempDir) -> (PathBuf, Vec<u8>) {
    let scene = resized_scene(dir, "sphere.json", W, H);
    let png = dir.path().join("reference.png");
    let out = run(&["render", s(&scene), "-o", s(&png)]);
    assert!(out.status.success(), "{}", stderr(&out));
    let (_, _, rgb) = decode_png(&std::fs::read(png).unwrap());
    (scene, rgb)
}

/// The reference with its first `n` pixels off by exactly 51 in every channel (down
/// where the channel is bright, up where it is dark), written as a PNG.
fn with_wrong_pixels(dir: &tempfile::TempDir, rgb: &[u8], n: usize) -> PathBuf {
    let mut px = rgb.to_vec();
    for c in px.iter_mut().take(3 * n) {
        *c = if *c > 127 { *c - 51 } else { *c + 51 };
    }
    let p = dir.path().join(format!("wrong-{n}.png"));
    std::fs::write(&p, encode_png(W, H, &px)).unwrap();
    p
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-9
}

/// The tests' points of a Gradescope document, added in order.
fn gradescope_points(g: &Value) -> (f64, f64) {
    g["tests"]
        .as_array()
        .unwrap()
        .iter()
        .fold((0.0, 0.0), |(p, m), t| {
            (
                p + t["score"].as_f64().unwrap_or(0.0),
                m + t["max_score"].as_f64().unwrap_or(0.0),
            )
        })
}

fn prairielearn_points(pl: &Value) -> (f64, f64) {
    pl["tests"]
        .as_array()
        .unwrap()
        .iter()
        .fold((0.0, 0.0), |(p, m), t| {
            (
                p + t["points"].as_f64().unwrap(),
                m + t["max_points"].as_f64().unwrap(),
            )
        })
}

// ---- ungradable submissions ------------------------------------------------------------

#[test]
fn prairielearn_gets_a_results_file_for_an_ungradable_submission_in_a_new_folder() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, _) = reference(&dir);
    let bad = dir.path().join("render.png");
    std::fs::write(&bad, b"GIF89a not a png").unwrap();
    // PrairieLearn does not create /grade/results: neither folder exists yet.
    let results = dir.path().join("grade/results/results.json");
    let out = grade(
        &scene,
        &bad,
        &["--report", "prairielearn", "-o", s(&results)],
    );
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert_eq!(
        stderr(&out).trim_end().lines().count(),
        1,
        "{}",
        stderr(&out)
    );
    let pl = read_json(&results);
    assert_eq!(pl["gradable"], false);
    let errors = pl["format_errors"].as_array().unwrap();
    assert_eq!(errors.len(), 1);
    assert!(
        errors[0].as_str().unwrap().contains("not a PNG file"),
        "{pl}"
    );
    assert!(pl.get("score").is_none(), "{pl}");
}

#[test]
fn gradescope_gets_score_zero_and_the_reason_when_the_file_is_missing() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, _) = reference(&dir);
    let missing = dir.path().join("submission/render.png");
    let results = dir.path().join("results/results.json");
    let out = grade(
        &scene,
        &missing,
        &[
            "--report",
            "gradescope",
            "--max-score",
            "10",
            "-o",
            s(&results),
        ],
    );
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    let g = read_json(&results);
    assert_eq!(g["score"], 0.0);
    assert_eq!(g["max_score"], 10.0);
    assert_eq!(g["output_format"], "md");
    let output = g["output"].as_str().unwrap();
    assert!(output.contains("could not be graded"), "{output}");
    assert!(output.contains("render.png"), "{output}");
    assert_eq!(g["tests"][0]["status"], "failed");
    assert_eq!(gradescope_points(&g), (0.0, 10.0));
}

#[test]
fn the_other_reports_still_write_nothing_for_an_ungradable_submission() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, _) = reference(&dir);
    let empty = dir.path().join("empty.png");
    std::fs::write(&empty, b"").unwrap();
    let report = dir.path().join("out/report.json");
    let out = grade(&scene, &empty, &["-o", s(&report)]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("the submission is empty"));
    assert!(!report.exists());
}

// ---- output folders and visibility -----------------------------------------------------

#[test]
fn missing_folders_of_the_report_and_the_diff_are_created() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, rgb) = reference(&dir);
    let sub = with_wrong_pixels(&dir, &rgb, 0);
    let report = dir.path().join("a/b/report.json");
    let diff = dir.path().join("c/d/diff.png");
    let out = grade(&scene, &sub, &["-o", s(&report), "--diff", s(&diff)]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    assert_eq!(read_json(&report)["pass"], true);
    assert!(std::fs::read(&diff).unwrap().starts_with(b"\x89PNG"));
}

#[test]
fn gradescope_visibility_is_the_instructors_choice() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, rgb) = reference(&dir);
    let sub = with_wrong_pixels(&dir, &rgb, 0);
    let out = grade(
        &scene,
        &sub,
        &[
            "--report",
            "gradescope",
            "--visibility",
            "after_due_date",
            "--stdout-visibility",
            "hidden",
        ],
    );
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let g = stdout_json(&out);
    assert_eq!(g["visibility"], "after_due_date");
    assert_eq!(g["stdout_visibility"], "hidden");
    assert_eq!(g["test_output_format"], "md");
    for t in g["tests"].as_array().unwrap() {
        assert_eq!(t["visibility"], "after_due_date", "{t}");
    }
    // The difference image, inline in an html test.
    let image = g["tests"]
        .as_array()
        .unwrap()
        .iter()
        .find(|t| t["name"] == "Difference image")
        .expect("a difference image test");
    assert_eq!(image["output_format"], "html");
    assert!(
        image["output"]
            .as_str()
            .unwrap()
            .contains("<img src=\"data:image/png;base64,iVBOR"),
        "{image}"
    );
    assert!(image.get("score").is_none());

    let out = grade(
        &scene,
        &sub,
        &["--report", "gradescope", "--visibility", "soon"],
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("after_published"), "{}", stderr(&out));
}

// ---- scoring --------------------------------------------------------------------------

#[test]
fn each_scoring_mode_scores_a_known_share_of_wrong_pixels() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, rgb) = reference(&dir);
    // 125 of 5000 pixels (2.5 %) off by 51/255 in every channel: a mean colour error of
    // 125 × 51 / 5000 = 1.275 (0.005 of full scale).
    let sub = with_wrong_pixels(&dir, &rgb, 125);
    let tol = ["--max-fail-share", "0.01"];
    let report = |extra: &[&str]| {
        let mut args = tol.to_vec();
        args.extend_from_slice(extra);
        let out = grade(&scene, &sub, &args);
        assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
        stdout_json(&out)
    };

    let r = report(&[]);
    assert_eq!(r["failing_pixels"], 125);
    assert_eq!(r["score"]["scoring"], "all-or-nothing");
    assert_eq!(r["score"]["value"], 0.0);

    // Linear from 1 % (full marks) to 4 % (none): 2.5 % is halfway.
    let r = report(&["--scoring", "linear", "--zero-share", "0.04"]);
    assert!(
        close(r["score"]["value"].as_f64().unwrap(), 0.5),
        "{}",
        r["score"]
    );
    let formula = r["score"]["formula"].as_str().unwrap();
    assert!(
        formula.contains("(0.04 − 0.025) / (0.04 − 0.01) = 0.5"),
        "{formula}"
    );
    // The default zero share, 5 %: (0.05 − 0.025) / (0.05 − 0.01) = 0.625.
    let r = report(&["--scoring", "linear"]);
    assert!(
        close(r["score"]["value"].as_f64().unwrap(), 0.625),
        "{}",
        r["score"]
    );

    // Error: 1 − 10 × 0.005 = 0.95 by default; 1 − 40 × 0.005 = 0.8.
    let r = report(&["--scoring", "error"]);
    assert!(
        close(r["score"]["value"].as_f64().unwrap(), 0.95),
        "{}",
        r["score"]
    );
    let r = report(&["--scoring", "error", "--error-k", "40"]);
    assert!(
        close(r["score"]["value"].as_f64().unwrap(), 0.8),
        "{}",
        r["score"]
    );

    // Every form carries the score and its formula.
    let mut args = tol.to_vec();
    args.extend_from_slice(&["--scoring", "linear", "--zero-share", "0.04"]);
    let text = {
        let mut a = args.clone();
        a.extend_from_slice(&["--report", "text"]);
        String::from_utf8(grade(&scene, &sub, &a).stdout).unwrap()
    };
    assert!(
        text.contains("Score: 0.5 of 1 (linear: (zero_share − share)"),
        "{text}"
    );
    let g = {
        let mut a = args.clone();
        a.extend_from_slice(&["--report", "gradescope", "--max-score", "10"]);
        stdout_json(&grade(&scene, &sub, &a))
    };
    assert!(close(g["score"].as_f64().unwrap(), 5.0), "{g}");
    let (points, max) = gradescope_points(&g);
    assert!(close(points, 5.0) && close(max, 10.0), "{points} of {max}");
    assert!(g["output"].as_str().unwrap().contains("Score: 0.5 of 1"));
    let pl = {
        let mut a = args.clone();
        a.extend_from_slice(&["--report", "prairielearn"]);
        stdout_json(&grade(&scene, &sub, &a))
    };
    assert!(close(pl["score"].as_f64().unwrap(), 0.5), "{pl}");
    let (points, max) = prairielearn_points(&pl);
    assert!(close(points, 0.5) && close(max, 1.0), "{points} of {max}");
    assert!(pl["tests"][0]["output"].as_str().unwrap().contains("= 0.5"));
}

#[test]
fn a_failing_submission_scored_all_or_nothing_shows_no_test_points() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, rgb) = reference(&dir);
    let sub = with_wrong_pixels(&dir, &rgb, 125);
    let out = grade(&scene, &sub, &["--report", "prairielearn"]);
    let pl = stdout_json(&out);
    assert_eq!(pl["score"], 0.0);
    assert_eq!(prairielearn_points(&pl), (0.0, 1.0));
    let out = grade(
        &scene,
        &sub,
        &["--report", "gradescope", "--max-score", "5"],
    );
    let g = stdout_json(&out);
    assert_eq!(g["score"], 0.0);
    assert_eq!(gradescope_points(&g), (0.0, 5.0));
}

#[test]
fn scoring_settings_out_of_range_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, rgb) = reference(&dir);
    let sub = with_wrong_pixels(&dir, &rgb, 0);
    for (args, want) in [
        (
            &["--scoring", "linear", "--zero-share", "0.0005"][..],
            "zero_share",
        ),
        (&["--error-k=-1"][..], "error_k"),
        (
            &[
                "--weight-hit-miss",
                "0",
                "--weight-object",
                "0",
                "--weight-lambda",
                "0",
                "--weight-normal",
                "0",
            ][..],
            "weights",
        ),
    ] {
        let out = grade(&scene, &sub, args);
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        assert!(stderr(&out).contains(want), "{args:?}: {}", stderr(&out));
    }
}

/// The reference hit data of `scene` as pixel records.
fn reference_hits(dir: &tempfile::TempDir, scene: &Path) -> Vec<PixelHit> {
    let p = dir.path().join("reference-hits.json");
    let out = run(&["hits", s(scene), "-o", s(&p)]);
    assert!(out.status.success(), "{}", stderr(&out));
    serde_json::from_value(read_json(&p)["pixels"].clone()).expect("pixel records")
}

#[test]
fn hit_data_is_scored_per_kind_with_weights() {
    let dir = tempfile::tempdir().unwrap();
    let scene = resized_scene(&dir, "sphere.json", W, H);
    let mut pixels = reference_hits(&dir, &scene);
    // 250 of 5000 pixels (5 %) with the normal turned around: only the normal check fails.
    let mut flipped = 0;
    for p in pixels.iter_mut() {
        if let (Some(n), true) = (p.normal.as_mut(), flipped < 250) {
            *n = [-n[0], -n[1], -n[2]];
            flipped += 1;
        }
    }
    assert_eq!(flipped, 250);
    let sub = dir.path().join("hits.json");
    std::fs::write(
        &sub,
        serde_json::to_vec(&serde_json::json!({"width": W, "height": H, "pixels": pixels}))
            .unwrap(),
    )
    .unwrap();
    // Error scoring: the normal's part is 1 − 10 × 0.05 = 0.5; weighted 2 of 5.
    let out = grade(
        &scene,
        &sub,
        &[
            "--scoring",
            "error",
            "--weight-normal",
            "2",
            "--report",
            "prairielearn",
        ],
    );
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let pl = stdout_json(&out);
    let want = 0.2 + 0.2 + 0.2 + 0.4 * 0.5;
    assert!(
        close(pl["score"].as_f64().unwrap(), want),
        "{}",
        pl["score"]
    );
    let (points, max) = prairielearn_points(&pl);
    assert!(close(points, want) && close(max, 1.0), "{points} of {max}");
    let normal = pl["tests"]
        .as_array()
        .unwrap()
        .iter()
        .find(|t| t["name"] == "Normal within tolerance")
        .expect("a normal test");
    assert!(
        close(normal["max_points"].as_f64().unwrap(), 0.4),
        "{normal}"
    );
    assert!(close(normal["points"].as_f64().unwrap(), 0.2), "{normal}");
    // The verdict is information, worth no points.
    let verdict = pl["tests"]
        .as_array()
        .unwrap()
        .iter()
        .find(|t| t["name"] == "Matches the reference")
        .expect("the verdict");
    assert_eq!(verdict["max_points"], 0.0);

    let out = grade(
        &scene,
        &sub,
        &["--scoring", "error", "--weight-normal", "2"],
    );
    let r = stdout_json(&out);
    let parts = r["score"]["parts"].as_array().unwrap();
    assert_eq!(parts.len(), 4);
    assert!(close(parts[3]["weight"].as_f64().unwrap(), 0.4));
}

// ---- over HTTP ------------------------------------------------------------------------

fn form(scene: &Value, submission: Vec<u8>) -> Form {
    Form::new()
        .part(
            "scene",
            Part::bytes(serde_json::to_vec(scene).unwrap()).file_name("scene.json"),
        )
        .part(
            "submission",
            Part::bytes(submission).file_name("student.png"),
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
async fn the_server_scores_and_writes_ungradable_results_like_the_command_line() {
    let app = TestApp::spawn().await;
    let dir = tempfile::tempdir().unwrap();
    let (scene_path, rgb) = reference(&dir);
    let scene: Value = read_json(&scene_path);
    let sub = std::fs::read(with_wrong_pixels(&dir, &rgb, 125)).unwrap();

    let res = post(
        &app,
        "?max_fail_share=0.01&scoring=linear&zero_share=0.04",
        form(&scene, sub.clone()),
    )
    .await;
    assert_eq!(res.status(), 200);
    let r: Value = res.json().await.unwrap();
    assert!(
        close(r["score"]["value"].as_f64().unwrap(), 0.5),
        "{}",
        r["score"]
    );

    let res = post(
        &app,
        "?scoring=error&error_k=40&report=gradescope&max_score=10&visibility=hidden",
        form(&scene, sub.clone()),
    )
    .await;
    assert_eq!(res.status(), 200);
    let g: Value = res.json().await.unwrap();
    assert!(close(g["score"].as_f64().unwrap(), 8.0), "{g}");
    assert_eq!(g["visibility"], "hidden");
    assert_eq!(g["stdout_visibility"], "visible");

    for query in [
        "?scoring=curve",
        "?scoring=linear&max_fail_share=0.05&zero_share=0.04",
        "?weight_normal=-1",
        "?visibility=later",
    ] {
        let res = post(&app, query, form(&scene, sub.clone())).await;
        problem(res, 400, "bad-request").await;
    }

    let res = post(
        &app,
        "?report=prairielearn",
        form(&scene, b"not a png".to_vec()),
    )
    .await;
    assert_eq!(res.status(), 200);
    assert_eq!(res.headers()["x-raytile-verdict"], "ungradable");
    let pl: Value = res.json().await.unwrap();
    assert_eq!(pl["gradable"], false);
    assert!(
        pl["format_errors"][0].as_str().unwrap().contains("PNG"),
        "{pl}"
    );

    // Without a grader form it stays a problem document.
    let res = post(&app, "", form(&scene, b"not a png".to_vec())).await;
    problem(res, 422, "invalid-submission").await;
}

// ---- edge forgiveness and the half-pixel mistake --------------------------------------

/// The sphere scene at 320 × 240 rendered through pixel corners instead of centres (the
/// missing `+ ½`), by a camera-space shear in front of the scene's own placement: it
/// moves every primary direction by `−½ · 2/w` in x and y, exactly the mistake.
fn corner_render(dir: &tempfile::TempDir) -> (PathBuf, PathBuf) {
    use glam::DVec3;
    let bytes = std::fs::read(scene("sphere.json")).unwrap();
    let mut doc: Value = serde_json::from_slice(&bytes).unwrap();
    let reference = scene_file(dir, "reference.json", &doc);
    let (w, f) = (320.0, doc["camera"]["focal_length"].as_f64().unwrap());
    let la = doc["camera"]["look_at"].clone();
    let v = |k: &str| {
        let a: Vec<f64> = serde_json::from_value(la[k].clone()).unwrap();
        DVec3::new(a[0], a[1], a[2])
    };
    // look_at as camera/look_at in the scene spec builds it.
    let (eye, target, up) = (v("eye"), v("target"), v("up"));
    let z = (target - eye).normalize();
    let u = up.normalize();
    let y = -(u - u.dot(z) * z).normalize();
    let x = y.cross(z);
    let k = 0.5 * 2.0 / w / f;
    doc["camera"] = serde_json::json!({
        "focal_length": f,
        "transform": [
            {"matrix": [[1, 0, -k, 0], [0, 1, -k, 0], [0, 0, 1, 0], [0, 0, 0, 1]]},
            {"matrix": [
                [x.x, y.x, z.x, eye.x], [x.y, y.y, z.y, eye.y], [x.z, y.z, z.z, eye.z],
                [0, 0, 0, 1]
            ]}
        ]
    });
    let corner_scene = scene_file(dir, "corner.json", &doc);
    let png = dir.path().join("corner.png");
    let out = run(&["render", s(&corner_scene), "-o", s(&png)]);
    assert!(out.status.success(), "{}", stderr(&out));
    (reference, png)
}

/// What `docs/grading.md` says of edge forgiveness: the tuning example passes an image
/// traced through pixel corners, and the tolerances it suggests instead catch it.
#[test]
fn the_tuning_example_forgives_the_half_pixel_mistake_and_the_suggested_tolerances_do_not() {
    let dir = tempfile::tempdir().unwrap();
    let (reference, corner) = corner_render(&dir);
    let verdict = |args: &[&str]| {
        let mut a = vec!["--no-flip"];
        a.extend_from_slice(args);
        let r = stdout_json(&grade(&reference, &corner, &a));
        (
            r["pass"].as_bool().unwrap(),
            r["failing_share"].as_f64().unwrap(),
        )
    };
    let (pass, _) = verdict(&[]);
    assert!(!pass);
    let (pass, share) = verdict(&[
        "--colour-abs",
        "4",
        "--max-fail-share",
        "0.01",
        "--edge-forgiving",
    ]);
    assert!(pass, "{share}");
    let (pass, share) = verdict(&[
        "--colour-abs",
        "4",
        "--max-fail-share",
        "0.001",
        "--edge-forgiving",
    ]);
    assert!(!pass && share > 0.002, "{share}");
    let (pass, share) = verdict(&["--colour-abs", "4", "--max-fail-share", "0.01"]);
    assert!(!pass && share > 0.02, "{share}");
}
