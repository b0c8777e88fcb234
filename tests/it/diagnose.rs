//! Diagnosis: a failing submission is tested against the catalogue of classic mistakes,
//! and the report names the one that explains it. Every mistake here is made by code
//! that shares nothing with the grader: the student's tracer of `wrong_tracer` (written
//! from the specification, with a flag per mistake), or a transformation of the
//! reference's pixels written in this file.

use std::path::{Path, PathBuf};

use glam::DVec3;
use reqwest::multipart::{Form, Part};
use serde_json::{Value, json};

use crate::support::*;
use crate::support_server::TestApp;
use crate::wrong_tracer::{Flags, Material, Object, Scene, Shape, Tracer};

fn material(diffuse: [f64; 3]) -> Material {
    let d = DVec3::from_array(diffuse);
    Material {
        ambient: d,
        diffuse: d,
        specular: DVec3::ZERO,
        shininess: 32.0,
        mirror: DVec3::ZERO,
        transmission: DVec3::ZERO,
        ior: 1.5,
    }
}

/// A floor with a faint mirror, an oval (a non-uniformly scaled sphere) with highlights, a
/// mirror ball and a glass ball, lit by one point light: every mistake of the catalogue
/// changes some of its pixels.
fn student_scene(width: u32, height: u32) -> Scene {
    Scene {
        width,
        height,
        gamma: Some(2.2),
        background: DVec3::new(0.25, 0.35, 0.55),
        ambient: DVec3::splat(0.12),
        max_depth: 2,
        objects: vec![
            Object {
                shape: Shape::Plane,
                scale: DVec3::ONE,
                translate: DVec3::new(0.0, 1.0, 0.0),
                material: Material {
                    mirror: DVec3::splat(0.25),
                    ..material([0.6, 0.6, 0.55])
                },
            },
            Object {
                shape: Shape::Sphere,
                scale: DVec3::new(0.9, 0.45, 0.6),
                translate: DVec3::new(-1.1, 0.45, 4.0),
                material: Material {
                    specular: DVec3::splat(0.6),
                    shininess: 30.0,
                    ..material([0.8, 0.15, 0.1])
                },
            },
            Object {
                shape: Shape::Sphere,
                scale: DVec3::splat(0.6),
                translate: DVec3::new(0.25, 0.35, 5.0),
                material: Material {
                    specular: DVec3::splat(0.8),
                    shininess: 100.0,
                    mirror: DVec3::splat(0.8),
                    ..material([0.05, 0.05, 0.05])
                },
            },
            Object {
                shape: Shape::Sphere,
                scale: DVec3::splat(0.45),
                translate: DVec3::new(1.15, 0.5, 3.6),
                material: Material {
                    ambient: DVec3::ZERO,
                    specular: DVec3::splat(0.8),
                    shininess: 120.0,
                    mirror: DVec3::splat(0.05),
                    transmission: DVec3::splat(0.9),
                    ..material([0.02, 0.02, 0.02])
                },
            },
        ],
        lights: vec![(DVec3::new(-2.5, -3.0, 1.5), DVec3::splat(0.9))],
    }
}

fn s(p: &Path) -> &str {
    p.to_str().expect("a UTF-8 path")
}

fn write(dir: &tempfile::TempDir, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.path().join(name);
    std::fs::write(&p, bytes).expect("temp dir writable");
    p
}

/// Grades `submission` with the binary; the JSON report (exit 0 or 1).
fn grade(scene: &Path, submission: &Path, extra: &[&str]) -> Value {
    let mut args = vec!["grade", s(scene), s(submission)];
    args.extend_from_slice(extra);
    let out = run(&args);
    assert!(
        matches!(out.status.code(), Some(0 | 1)),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout_json(&out)
}

/// The names of the mistakes the report's diagnosis gives.
fn named(report: &Value) -> Vec<String> {
    report["diagnosis"]["mistakes"]
        .as_array()
        .map(|a| {
            a.iter()
                .map(|m| m["mistake"].as_str().unwrap_or("?").to_owned())
                .collect()
        })
        .unwrap_or_default()
}

/// Every case's verdict, gathered before asserting so that one run shows them all.
fn check_all(cases: Vec<(&str, Value)>) {
    // The diagnoses as a student reads them, shown with `--no-capture`.
    for (want, r) in &cases {
        let d = &r["diagnosis"];
        for m in d["mistakes"].as_array().into_iter().flatten() {
            eprintln!(
                "{want}: {} — matches {:.2} % of pixels, the reference {:.2} %.",
                m["title"].as_str().unwrap_or("?"),
                100.0 * m["matches"].as_f64().unwrap_or(f64::NAN),
                100.0 * d["reference_matches"].as_f64().unwrap_or(f64::NAN)
            );
        }
    }
    let wrong: Vec<String> = cases
        .iter()
        .filter(|(want, r)| named(r) != [*want])
        .map(|(want, r)| {
            format!(
                "{want}: named {:?}, pass {}, reference matches {}, tried {}",
                named(r),
                r["pass"],
                r["diagnosis"]["reference_matches"],
                r["diagnosis"]["tried"]
            )
        })
        .collect();
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

fn flip_rows(w: u32, h: u32, rgb: &[u8]) -> Vec<u8> {
    let row = 3 * w as usize;
    (0..h as usize)
        .rev()
        .flat_map(|v| rgb[v * row..(v + 1) * row].to_vec())
        .collect()
}

#[test]
fn a_correct_tracer_passes_and_gets_no_diagnosis() {
    let dir = tempfile::tempdir().unwrap();
    let scene = student_scene(96, 72);
    let path = scene_file(&dir, "scene.json", &scene.document());
    let img = Tracer {
        scene: &scene,
        flags: Flags::default(),
    }
    .image();
    let sub = write(&dir, "good.png", &encode_png(96, 72, &img));
    let r = grade(&path, &sub, &[]);
    assert_eq!(r["pass"], true, "{r}");
    assert!(r.get("diagnosis").is_none(), "{r}");
    let hits = Tracer {
        scene: &scene,
        flags: Flags::default(),
    }
    .hits();
    let doc = json!({"width": 96, "height": 72, "pixels": hits});
    let sub = write(&dir, "good.json", &serde_json::to_vec(&doc).unwrap());
    let r = grade(&path, &sub, &[]);
    assert_eq!(r["pass"], true, "{r}");
    assert!(r.get("diagnosis").is_none(), "{r}");
}

#[test]
fn each_image_mistake_is_named_and_only_it() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (96, 72);
    let scene = student_scene(w, h);
    let path = scene_file(&dir, "scene.json", &scene.document());
    let flagged: Vec<(&str, Flags)> = vec![
        (
            "flipped_vertically",
            Flags {
                y_up: true,
                ..Default::default()
            },
        ),
        (
            "flipped_horizontally",
            Flags {
                x_left: true,
                ..Default::default()
            },
        ),
        (
            "bgr_order",
            Flags {
                bgr: true,
                ..Default::default()
            },
        ),
        (
            "gamma_missing",
            Flags {
                no_gamma: true,
                ..Default::default()
            },
        ),
        (
            "gamma_twice",
            Flags {
                gamma_twice: true,
                ..Default::default()
            },
        ),
        (
            "srgb_instead_of_gamma",
            Flags {
                srgb: true,
                ..Default::default()
            },
        ),
        (
            "truncated",
            Flags {
                truncate: true,
                ..Default::default()
            },
        ),
        (
            "pixel_corner",
            Flags {
                corner: true,
                ..Default::default()
            },
        ),
        (
            "normals_not_inverse_transpose",
            Flags {
                forward_normals: true,
                ..Default::default()
            },
        ),
        (
            "normals_not_normalised",
            Flags {
                raw_normals: true,
                ..Default::default()
            },
        ),
        (
            "shadow_acne",
            Flags {
                no_shadow_offset: true,
                ..Default::default()
            },
        ),
        (
            "shadows_missing",
            Flags {
                no_shadows: true,
                ..Default::default()
            },
        ),
        (
            "ambient_missing",
            Flags {
                no_ambient: true,
                ..Default::default()
            },
        ),
        (
            "specular_missing",
            Flags {
                no_specular: true,
                ..Default::default()
            },
        ),
        (
            "blinn_phong",
            Flags {
                blinn: true,
                ..Default::default()
            },
        ),
        (
            "reflection_missing",
            Flags {
                no_reflection: true,
                ..Default::default()
            },
        ),
        (
            "refraction_missing",
            Flags {
                no_refraction: true,
                ..Default::default()
            },
        ),
        (
            "refraction_ratio_inverted",
            Flags {
                inverted_eta: true,
                ..Default::default()
            },
        ),
        (
            "max_depth_plus_one",
            Flags {
                depth_delta: 1,
                ..Default::default()
            },
        ),
        (
            "max_depth_minus_one",
            Flags {
                depth_delta: -1,
                ..Default::default()
            },
        ),
    ];
    let mut cases = Vec::new();
    for (want, flags) in flagged {
        let img = Tracer {
            scene: &scene,
            flags,
        }
        .image();
        let sub = write(&dir, &format!("{want}.png"), &encode_png(w, h, &img));
        // Truncation is at most 1/255 off: it fails only where no difference is allowed.
        let strict: &[&str] = if flags.truncate {
            &["--colour-abs", "0"]
        } else {
            &[]
        };
        cases.push((want, grade(&path, &sub, strict)));
    }
    check_all(cases);
}

#[test]
fn mistakes_that_need_a_square_frame_or_no_gamma() {
    let dir = tempfile::tempdir().unwrap();
    let square = student_scene(64, 64);
    let path = scene_file(&dir, "square.json", &square.document());
    let img = Tracer {
        scene: &square,
        flags: Flags {
            uv_swapped: true,
            ..Default::default()
        },
    }
    .image();
    let sub = write(&dir, "transposed.png", &encode_png(64, 64, &img));
    let transposed = grade(&path, &sub, &[]);

    let linear = Scene {
        gamma: None,
        ..student_scene(96, 72)
    };
    let path = scene_file(&dir, "linear.json", &linear.document());
    let img = Tracer {
        scene: &linear,
        flags: Flags {
            gamma_unasked: true,
            ..Default::default()
        },
    }
    .image();
    let sub = write(&dir, "unasked.png", &encode_png(96, 72, &img));
    let unasked = grade(&path, &sub, &[]);
    check_all(vec![("transposed", transposed), ("gamma_unasked", unasked)]);
}

#[test]
fn the_reference_transformed_in_the_test_is_named_too() {
    // The reference's own pixels, moved by this test: rows in reverse order.
    let dir = tempfile::tempdir().unwrap();
    let scene = resized_scene(&dir, "showcase.json", 80, 60);
    let png = dir.path().join("reference.png");
    let out = run(&["render", s(&scene), "-o", s(&png)]);
    assert!(out.status.success());
    let (w, h, rgb) = decode_png(&std::fs::read(&png).unwrap());
    let sub = write(
        &dir,
        "flipped.png",
        &encode_png(w, h, &flip_rows(w, h, &rgb)),
    );
    let r = grade(&scene, &sub, &[]);
    check_all(vec![("flipped_vertically", r)]);
}

#[test]
fn a_random_image_gets_a_diagnosis_that_names_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let scene = student_scene(96, 72);
    let path = scene_file(&dir, "scene.json", &scene.document());
    let mut x = 0x9e37_79b9_u32;
    let noise: Vec<u8> = (0..96 * 72 * 3)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x as u8
        })
        .collect();
    let sub = write(&dir, "noise.png", &encode_png(96, 72, &noise));
    let r = grade(&path, &sub, &[]);
    assert_eq!(r["pass"], false);
    assert_eq!(named(&r), Vec::<String>::new(), "{r}");
    assert!(!r["diagnosis"]["tried"].as_array().unwrap().is_empty());
}

#[test]
fn each_hit_data_mistake_is_named_and_only_it() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (96, 72);
    let scene = student_scene(w, h);
    let path = scene_file(&dir, "scene.json", &scene.document());
    let flagged: Vec<(&str, Flags)> = vec![
        (
            "flipped_vertically",
            Flags {
                y_up: true,
                ..Default::default()
            },
        ),
        (
            "flipped_horizontally",
            Flags {
                x_left: true,
                ..Default::default()
            },
        ),
        (
            "pixel_corner",
            Flags {
                corner: true,
                ..Default::default()
            },
        ),
        (
            "lambda_unit_direction",
            Flags {
                unit_lambda: true,
                ..Default::default()
            },
        ),
        (
            "normals_not_inverse_transpose",
            Flags {
                forward_normals: true,
                ..Default::default()
            },
        ),
    ];
    let mut cases = Vec::new();
    for (want, flags) in flagged {
        let doc =
            json!({"width": w, "height": h, "pixels": Tracer { scene: &scene, flags }.hits()});
        let sub = write(
            &dir,
            &format!("{want}.json"),
            &serde_json::to_vec(&doc).unwrap(),
        );
        cases.push((want, grade(&path, &sub, &[])));
    }
    check_all(cases);
}

/// The flipped student image of the student scene, written to `dir`: (scene, submission).
fn flipped_submission(dir: &tempfile::TempDir) -> (PathBuf, PathBuf, Vec<u8>) {
    let scene = student_scene(96, 72);
    let path = scene_file(dir, "scene.json", &scene.document());
    let flags = Flags {
        y_up: true,
        ..Default::default()
    };
    let png = encode_png(
        96,
        72,
        &Tracer {
            scene: &scene,
            flags,
        }
        .image(),
    );
    let sub = write(dir, "flipped.png", &png);
    (path, sub, png)
}

#[test]
fn every_report_form_carries_the_diagnosis() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, sub, _) = flipped_submission(&dir);
    let form = |f: &str| {
        let out = run(&["grade", s(&scene), s(&sub), "--report", f]);
        assert_eq!(out.status.code(), Some(1));
        String::from_utf8(out.stdout).unwrap()
    };
    let text = form("text");
    assert!(
        text.contains("Diagnosis: upside down (y up instead of down) — this explains the submission: it matches"),
        "{text}"
    );
    assert!(
        text.contains("See docs/spec/camera.md, \"Pixels\""),
        "{text}"
    );
    let g: Value = serde_json::from_str(&form("gradescope")).unwrap();
    assert!(
        g["output"]
            .as_str()
            .unwrap()
            .contains("Diagnosis: upside down")
    );
    assert!(
        g["tests"][0]["output"]
            .as_str()
            .unwrap()
            .contains("Likely mistake: upside down")
    );
    let pl: Value = serde_json::from_str(&form("prairielearn")).unwrap();
    assert!(
        pl["message"]
            .as_str()
            .unwrap()
            .contains("Likely mistake: upside down")
    );
    assert!(
        pl["output"]
            .as_str()
            .unwrap()
            .contains("Diagnosis: upside down")
    );
    let json: Value = serde_json::from_str(&form("json")).unwrap();
    let m = &json["diagnosis"]["mistakes"][0];
    assert_eq!(m["mistake"], "flipped_vertically");
    assert!(m["matches"].as_f64().unwrap() >= 0.99);
    assert_eq!(
        m["convention"],
        "docs/spec/camera.md, \"Pixels\" and \"The primary ray\""
    );
    assert!(json["diagnosis"]["reference_matches"].as_f64().unwrap() < 0.9);
}

#[test]
fn an_image_of_the_wrong_size_says_the_likely_cause() {
    let dir = tempfile::tempdir().unwrap();
    let scene = student_scene(96, 72);
    let path = scene_file(&dir, "scene.json", &scene.document());
    let swapped = Scene {
        width: 72,
        height: 96,
        ..scene.clone()
    };
    let img = Tracer {
        scene: &swapped,
        flags: Flags::default(),
    }
    .image();
    let sub = write(&dir, "swapped.png", &encode_png(72, 96, &img));
    let out = run(&["grade", s(&path), s(&sub)]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("the submission is 72 × 96 pixels but the scene renders 96 × 72; likely cause: width and height are swapped"),
        "{err}"
    );
    let other = write(
        &dir,
        "other.png",
        &encode_png(50, 50, &vec![0; 50 * 50 * 3]),
    );
    let out = run(&["grade", s(&path), s(&other)]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("renders 96 × 72") && !err.contains("likely cause"),
        "{err}"
    );
}

#[test]
fn the_hit_data_difference_image_colours_each_kind_of_disagreement() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (96, 72);
    let scene = student_scene(w, h);
    let path = scene_file(&dir, "scene.json", &scene.document());
    let count = |flags: Flags, name: &str| {
        let doc =
            json!({"width": w, "height": h, "pixels": Tracer { scene: &scene, flags }.hits()});
        let sub = write(
            &dir,
            &format!("{name}.json"),
            &serde_json::to_vec(&doc).unwrap(),
        );
        let diff = dir.path().join(format!("{name}-diff.png"));
        let out = run(&["grade", s(&path), s(&sub), "--diff", s(&diff)]);
        assert_eq!(out.status.code(), Some(1));
        let (_, _, px) = decode_png(&std::fs::read(&diff).unwrap());
        let n = |c: [u8; 3]| px.chunks(3).filter(|p| *p == c).count();
        // hit/miss, object, λ, normal: the legend of docs/grading.md.
        [
            n([255, 0, 255]),
            n([255, 200, 0]),
            n([255, 64, 0]),
            n([0, 200, 255]),
        ]
    };
    let lambda = count(
        Flags {
            unit_lambda: true,
            ..Default::default()
        },
        "lambda",
    );
    assert!(
        lambda[2] > 1000 && lambda[0] == 0 && lambda[1] == 0 && lambda[3] == 0,
        "{lambda:?}"
    );
    let normals = count(
        Flags {
            forward_normals: true,
            ..Default::default()
        },
        "normals",
    );
    assert!(
        normals[3] > 50 && normals[0] + normals[1] + normals[2] == 0,
        "{normals:?}"
    );
    let corner = count(
        Flags {
            corner: true,
            ..Default::default()
        },
        "corner",
    );
    assert!(corner[0] > 10 && corner[1] > 10, "{corner:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn post_grade_carries_the_diagnosis() {
    let app = TestApp::spawn().await;
    let dir = tempfile::tempdir().unwrap();
    let (scene, _, png) = flipped_submission(&dir);
    let form = Form::new()
        .part(
            "scene",
            Part::bytes(std::fs::read(&scene).unwrap()).file_name("scene.json"),
        )
        .part("submission", Part::bytes(png).file_name("s.png"));
    let res = app
        .client
        .post(app.at("/v1/grade"))
        .multipart(form)
        .send()
        .await
        .expect("the server answers");
    assert_eq!(res.status(), 200);
    let answer = crate::openapi::Answer::from_reqwest(res).await;
    // The failing report, diagnosis included, is the documented GradeReport.
    crate::openapi::check(&crate::openapi::document(), "post", "/v1/grade", &answer);
    let r: Value = serde_json::from_slice(&answer.body).unwrap();
    assert_eq!(named(&r), ["flipped_vertically"], "{r}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_server_diagnoses_frames_up_to_its_setting() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, _, png) = flipped_submission(&dir);
    let scene = std::fs::read(&scene).unwrap();
    let diagnosis = |max: u64| {
        let (scene, png) = (scene.clone(), png.clone());
        async move {
            let app = TestApp::with(raytile::config::ServeArgs {
                diagnosis_max_pixels: max,
                ..crate::support_server::config()
            })
            .await;
            let form = Form::new()
                .part("scene", Part::bytes(scene).file_name("scene.json"))
                .part("submission", Part::bytes(png).file_name("s.png"));
            let r: Value = app
                .client
                .post(app.at("/v1/grade"))
                .multipart(form)
                .send()
                .await
                .expect("the server answers")
                .json()
                .await
                .unwrap();
            assert_eq!(r["pass"], false);
            r.get("diagnosis").cloned()
        }
    };
    assert_eq!(diagnosis(0).await, None);
    let over = diagnosis(96 * 72 - 1).await.expect("a diagnosis");
    assert_eq!(over["mistakes"], json!([]));
    assert_eq!(
        over["notes"][0],
        "No diagnosis: the image has 6912 pixels, more than the 6911 this grader diagnoses."
    );
    let at = diagnosis(96 * 72).await.expect("a diagnosis");
    assert_eq!(named(&json!({ "diagnosis": at })), ["flipped_vertically"]);
}
