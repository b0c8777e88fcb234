//! `raytile trace` and `raytile grade` as an instructor runs them: the lecture's worked
//! example, grading the reference against itself and against altered copies, every
//! submission form, the grader report formats, and bad submissions.

use std::path::{Path, PathBuf};
use std::process::Output;

use glam::DVec3;
use raytile::format::PixelHit;
use raytile::format::npy::{npy_header, npy_record};
use raytile::geometry::{Face, Surface};
use serde_json::Value;

use crate::support::*;

fn s(p: &Path) -> &str {
    p.to_str().expect("a UTF-8 path")
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Renders `scene` with the real binary and returns (width, height, RGB bytes).
fn render(dir: &tempfile::TempDir, scene: &Path) -> (u32, u32, Vec<u8>) {
    let png = dir.path().join("reference.png");
    let out = run(&["render", s(scene), "-o", s(&png)]);
    assert!(out.status.success(), "{}", stderr(&out));
    decode_png(&std::fs::read(png).expect("the rendered PNG"))
}

fn write(dir: &tempfile::TempDir, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.path().join(name);
    std::fs::write(&p, bytes).expect("temp dir writable");
    p
}

fn grade(scene: &Path, submission: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["grade", s(scene), s(submission)];
    args.extend_from_slice(extra);
    run(&args)
}

/// The reference hit data of `scene` as pixel records.
fn reference_hits(dir: &tempfile::TempDir, scene: &Path) -> Vec<PixelHit> {
    let p = dir.path().join("reference-hits.json");
    let out = run(&["hits", s(scene), "-o", s(&p)]);
    assert!(out.status.success(), "{}", stderr(&out));
    let doc: Value = serde_json::from_slice(&std::fs::read(p).expect("hits")).expect("JSON");
    serde_json::from_value(doc["pixels"].clone()).expect("pixel records")
}

fn hits_json(w: u32, h: u32, pixels: &[PixelHit]) -> Vec<u8> {
    serde_json::to_vec(&serde_json::json!({
        "width": w, "height": h,
        "region": {"x": 0, "y": 0, "width": w, "height": h},
        "pixels": pixels,
    }))
    .expect("serialisable")
}

fn hits_csv(pixels: &[PixelHit]) -> Vec<u8> {
    let mut t = String::from("u,v,hit,object,lambda,px,py,pz,nx,ny,nz\n");
    let f = |x: Option<f64>| x.map_or(String::new(), |x| format!("{x:?}"));
    for p in pixels {
        let pt = p.point.map(|a| a.map(Some)).unwrap_or([None; 3]);
        let n = p.normal.map(|a| a.map(Some)).unwrap_or([None; 3]);
        t.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{},{}\n",
            p.u,
            p.v,
            p.hit as u8,
            p.object.map_or(String::new(), |o| o.to_string()),
            f(p.lambda),
            f(pt[0]),
            f(pt[1]),
            f(pt[2]),
            f(n[0]),
            f(n[1]),
            f(n[2]),
        ));
    }
    t.into_bytes()
}

fn hits_npy(w: u32, h: u32, pixels: &[PixelHit]) -> Vec<u8> {
    let mut b = npy_header(h, w);
    let v3 = |a: Option<[f64; 3]>| DVec3::from_array(a.unwrap_or([f64::NAN; 3]));
    for p in pixels {
        let surface = p.hit.then(|| Surface {
            lambda: p.lambda.unwrap_or(f64::NAN),
            object: p.object.unwrap_or(0),
            point: v3(p.point),
            object_point: v3(p.object_point),
            normal: v3(p.normal),
            front: true,
            face: p.face.as_deref().and_then(Face::from_label),
        });
        npy_record(&mut b, p.u, p.v, &surface);
    }
    b
}

fn report_without_format(out: &Output) -> Value {
    let mut v = stdout_json(out);
    v.as_object_mut().expect("an object").remove("format");
    v
}

// ---------------------------------------------------------------------------------------
// trace

#[test]
fn trace_shows_the_lecture_example_value_by_value() {
    let out = run(&["trace", s(&scene("lecture.json")), "--pixel", "2,2"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    for want in [
        "camera space: p(λ) = [0, 0, 0, 1] + λ [0, 0, 1, 0]",
        "world space:  p(λ) = [0, 0, 0, 1] + λ [0, 0, 1, 0]",
        "T⁻¹ = [ 1  0  0  -1 ]",
        "      [ 0  1  0   0 ]",
        "      [ 0  0  1  -2 ]",
        "      [ 0  0  0   1 ]",
        "ray in object space: [-1, 0, -2, 1] + λ [0, 0, 1, 0]",
        "sphere: a = 1, b = -4, c = 4; discriminant b² − 4ac = 0",
        "λ = 2 at [-1, 0, 0, 1]: the object's first hit",
        "Hit: object 0 \"ball\" (sphere) at λ = 2",
        "object-space point [-1, 0, 0, 1]",
        "world point        [0, 0, 2, 1]",
        "8-bit:",
    ] {
        assert!(text.contains(want), "missing {want:?} in\n{text}");
    }
}

#[test]
fn trace_json_carries_the_same_numbers() {
    let out = run(&[
        "trace",
        s(&scene("lecture.json")),
        "--pixel",
        "2,2",
        "--format",
        "json",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let e = stdout_json(&out);
    assert_eq!(
        e["primary"]["world"],
        serde_json::json!({"origin": [0.0, 0.0, 0.0, 1.0], "direction": [0.0, 0.0, 1.0, 0.0]})
    );
    let t = &e["tree"]["tests"][0];
    let rows: Vec<Vec<f64>> = serde_json::from_value(t["inverse_transform"].clone()).unwrap();
    assert_eq!(
        rows,
        vec![
            vec![1.0, 0.0, 0.0, -1.0],
            vec![0.0, 1.0, 0.0, 0.0],
            vec![0.0, 0.0, 1.0, -2.0],
            vec![0.0, 0.0, 0.0, 1.0]
        ]
    );
    let q = &t["quadratics"][0];
    assert_eq!((q["a"].as_f64(), q["b"].as_f64()), (Some(1.0), Some(-4.0)));
    assert_eq!(
        (q["c"].as_f64(), q["discriminant"].as_f64()),
        (Some(4.0), Some(0.0))
    );
    assert_eq!(e["tree"]["hit"]["lambda"], 2.0);
    assert_eq!(
        e["tree"]["hit"]["object_point"],
        serde_json::json!([-1.0, 0.0, 0.0, 1.0])
    );
    assert_eq!(e["candidates"], "all");
}

#[test]
fn trace_colour_is_the_rendered_pixel() {
    let dir = tempfile::tempdir().unwrap();
    let scene = resized_scene(&dir, "showcase.json", 96, 72);
    let (w, _, rgb) = render(&dir, &scene);
    for (u, v) in [(48, 60), (30, 35), (60, 44), (5, 5)] {
        let out = run(&[
            "trace",
            s(&scene),
            "--pixel",
            &format!("{u},{v}"),
            "--format",
            "json",
        ]);
        assert!(out.status.success(), "{}", stderr(&out));
        let k = 3 * (v * w + u) as usize;
        assert_eq!(
            stdout_json(&out)["colour"]["rgb8"],
            serde_json::json!(rgb[k..k + 3]),
            "pixel ({u}, {v})"
        );
    }
}

#[test]
fn trace_refuses_a_pixel_outside_the_image() {
    let out = run(&["trace", s(&scene("lecture.json")), "--pixel", "5,0"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("outside the 5 × 5 image"));
}

// ---------------------------------------------------------------------------------------
// grade: images

#[test]
fn the_reference_against_itself_passes_with_zero_error() {
    let dir = tempfile::tempdir().unwrap();
    let scene = resized_scene(&dir, "sphere.json", 80, 60);
    let (w, h, rgb) = render(&dir, &scene);
    let sub = write(&dir, "student.png", &encode_png(w, h, &rgb));
    let out = grade(&scene, &sub, &[]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let r = stdout_json(&out);
    assert_eq!(r["pass"], true);
    assert_eq!(r["kind"], "image");
    assert_eq!(r["failing_pixels"], 0);
    assert_eq!(r["image"]["max_abs_error"], 0);
    assert_eq!(r["image"]["mean_abs_error"], 0.0);
    assert_eq!(r["image"]["psnr_db"], Value::Null);
    assert_eq!(r["image"]["ssim"], 1.0);
    assert_eq!(r["image"]["flip"]["max"], 0.0);
    assert_eq!(r["worst"], serde_json::json!([]));
}

#[test]
fn a_single_changed_pixel_is_reported_where_it_is() {
    let dir = tempfile::tempdir().unwrap();
    let scene = resized_scene(&dir, "sphere.json", 80, 60);
    let (w, h, mut rgb) = render(&dir, &scene);
    let (u, v) = (37u32, 21u32);
    let k = 3 * (v * w + u) as usize;
    let before = [rgb[k], rgb[k + 1], rgb[k + 2]];
    rgb[k] = rgb[k].wrapping_add(128);
    let sub = write(&dir, "student.png", &encode_png(w, h, &rgb));
    let diff = dir.path().join("diff.png");

    // 1 of 4800 pixels is within the default 0.1 % share: a pass, but the pixel is listed.
    let out = grade(&scene, &sub, &["--diff", s(&diff)]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let r = stdout_json(&out);
    assert_eq!(r["failing_pixels"], 1);
    assert_eq!(r["max_failing_pixels"], 4);
    let worst = &r["worst"][0];
    assert_eq!(
        (worst["u"].as_u64(), worst["v"].as_u64()),
        (Some(37), Some(21))
    );
    assert_eq!(worst["failures"], serde_json::json!(["colour"]));
    assert_eq!(worst["reference"]["rgb"], serde_json::json!(before));
    assert_eq!(worst["submitted"]["rgb"], serde_json::json!(rgb[k..k + 3]));
    assert_eq!(r["worst"].as_array().unwrap().len(), 1);

    // The difference image marks it, and only it.
    let (dw, dh, d) = decode_png(&std::fs::read(&diff).unwrap());
    assert_eq!((dw, dh), (w, h));
    let magenta: Vec<usize> = d
        .chunks(3)
        .enumerate()
        .filter(|(_, p)| p == &[255, 0, 255])
        .map(|(i, _)| i)
        .collect();
    assert_eq!(magenta, vec![(v * w + u) as usize]);

    // No failures allowed: the same submission fails.
    let out = grade(&scene, &sub, &["--max-fail-share", "0"]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    assert_eq!(stdout_json(&out)["pass"], false);

    // A tolerance wide enough for the change: it passes with nothing failing.
    let out = grade(
        &scene,
        &sub,
        &["--max-fail-share", "0", "--colour-abs", "128"],
    );
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    assert_eq!(stdout_json(&out)["failing_pixels"], 0);
}

#[test]
fn an_image_shifted_by_one_pixel_fails_unless_edges_are_forgiven() {
    let dir = tempfile::tempdir().unwrap();
    let scene = resized_scene(&dir, "sphere.json", 80, 60);
    let (w, h, rgb) = render(&dir, &scene);
    // Every row moved one pixel right (the first column repeated).
    let mut shifted = Vec::with_capacity(rgb.len());
    for row in rgb.chunks(3 * w as usize) {
        shifted.extend_from_slice(&row[..3]);
        shifted.extend_from_slice(&row[..row.len() - 3]);
    }
    let sub = write(&dir, "shifted.png", &encode_png(w, h, &shifted));
    let out = grade(&scene, &sub, &[]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let r = stdout_json(&out);
    assert_eq!(r["pass"], false);
    assert!(r["failing_pixels"].as_u64().unwrap() > 4);
    assert!(r["image"]["ssim"].as_f64().unwrap() < 1.0);
    assert!(r["image"]["flip"]["mean"].as_f64().unwrap() > 0.0);
    assert!(r["summary"].as_str().unwrap().starts_with("FAIL"));

    let out = grade(&scene, &sub, &["--edge-forgiving"]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let r = stdout_json(&out);
    assert_eq!(r["failing_pixels"], 0);
    assert!(r["forgiven_pixels"].as_u64().unwrap() > 4);
}

#[test]
fn tolerances_from_a_file_and_their_errors() {
    let dir = tempfile::tempdir().unwrap();
    let scene = resized_scene(&dir, "sphere.json", 40, 30);
    let (w, h, rgb) = render(&dir, &scene);
    let sub = write(&dir, "student.png", &encode_png(w, h, &rgb));
    let tol = write(
        &dir,
        "tol.json",
        br#"{"colour_abs": 0, "max_fail_share": 0}"#,
    );
    let out = grade(&scene, &sub, &["--tolerances", s(&tol)]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    assert_eq!(stdout_json(&out)["tolerances"]["colour_abs"], 0);

    let typo = write(&dir, "typo.json", br#"{"colour": 0}"#);
    let out = grade(&scene, &sub, &["--tolerances", s(&typo)]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr(&out).contains("unknown field `colour`"),
        "{}",
        stderr(&out)
    );

    let out = grade(&scene, &sub, &["--max-fail-share", "1.5"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("max_fail_share"));
}

// ---------------------------------------------------------------------------------------
// grade: hit data

fn miss(u: u32, v: u32) -> PixelHit {
    PixelHit {
        u,
        v,
        hit: false,
        object: None,
        name: None,
        lambda: None,
        point: None,
        object_point: None,
        normal: None,
        face: None,
    }
}

fn hit_count(pixels: &[PixelHit]) -> u64 {
    pixels.iter().filter(|p| p.hit).count() as u64
}

#[test]
fn flipped_normals_fail_on_the_normal_only() {
    let dir = tempfile::tempdir().unwrap();
    let scene = resized_scene(&dir, "sphere.json", 48, 36);
    let mut pixels = reference_hits(&dir, &scene);
    let hits = hit_count(&pixels);
    assert!(hits > 100);
    for p in &mut pixels {
        if let Some(n) = &mut p.normal {
            *n = n.map(|x| -x);
        }
    }
    let sub = write(&dir, "flipped.json", &hits_json(48, 36, &pixels));
    let out = grade(&scene, &sub, &[]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let r = stdout_json(&out);
    assert_eq!(r["kind"], "hits");
    assert_eq!(r["format"], "json");
    assert_eq!(r["failing_pixels"], hits);
    assert_eq!(r["hits"]["normal"], hits);
    assert_eq!(r["hits"]["hit_miss"], 0);
    assert_eq!(r["hits"]["wrong_object"], 0);
    assert_eq!(r["hits"]["lambda"], 0);
    assert_eq!(r["hits"]["max_normal_angle_degrees"], 180.0);
    assert_eq!(r["worst"][0]["failures"], serde_json::json!(["normal"]));
}

#[test]
fn lambda_one_percent_off_fails_on_lambda_only() {
    let dir = tempfile::tempdir().unwrap();
    let scene = resized_scene(&dir, "cube.json", 48, 36);
    let mut pixels = reference_hits(&dir, &scene);
    let hits = hit_count(&pixels);
    for p in &mut pixels {
        if let Some(l) = &mut p.lambda {
            *l *= 1.01;
        }
    }
    let sub = write(&dir, "lambda.json", &hits_json(48, 36, &pixels));
    let out = grade(&scene, &sub, &[]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let r = stdout_json(&out);
    assert_eq!(r["hits"]["lambda"], hits);
    assert_eq!(r["hits"]["normal"], 0);
    assert_eq!(r["hits"]["hit_miss"], 0);
    assert_eq!(r["hits"]["wrong_object"], 0);
    let worst = &r["worst"][0];
    assert_eq!(worst["failures"], serde_json::json!(["lambda"]));
    let rel = worst["lambda_rel_error"].as_f64().unwrap();
    assert!((rel - 0.01).abs() < 1e-9, "{rel}");

    // A λ tolerance of 2 % accepts it.
    let out = grade(&scene, &sub, &["--lambda-rel", "0.02"]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
}

#[test]
fn every_hit_data_form_gives_the_same_report() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (40, 30);
    let scene = resized_scene(&dir, "showcase.json", w, h);
    let mut pixels = reference_hits(&dir, &scene);
    // A mix of mistakes: a λ off, a flipped normal, a wrong object, a missed hit.
    let hit_at: Vec<usize> = (0..pixels.len()).filter(|&i| pixels[i].hit).collect();
    pixels[hit_at[0]].lambda = pixels[hit_at[0]].lambda.map(|l| l * 1.001);
    pixels[hit_at[5]].normal = pixels[hit_at[5]].normal.map(|n| n.map(|x| -x));
    pixels[hit_at[9]].object = pixels[hit_at[9]].object.map(|o| o + 1);
    let k = hit_at[20];
    pixels[k] = miss(pixels[k].u, pixels[k].v);
    let json = write(&dir, "student.json", &hits_json(w, h, &pixels));
    let csv = write(&dir, "student.csv", &hits_csv(&pixels));
    let npy = write(&dir, "student.npy", &hits_npy(w, h, &pixels));
    let ndjson = write(
        &dir,
        "student.ndjson",
        format!(
            "{}\n",
            pixels
                .chunks(w as usize)
                .enumerate()
                .map(|(v, row)| serde_json::json!({
                    "tile": {"x": 0, "y": v, "width": w, "height": 1},
                    "pixels": row,
                })
                .to_string())
                .collect::<Vec<_>>()
                .join("\n")
        )
        .as_bytes(),
    );
    let reports: Vec<Value> = [&json, &csv, &npy, &ndjson]
        .into_iter()
        .map(|p| {
            let out = grade(&scene, p, &["--max-fail-share", "0.01"]);
            assert_eq!(
                out.status.code(),
                Some(0),
                "{}: {}",
                p.display(),
                stderr(&out)
            );
            report_without_format(&out)
        })
        .collect();
    let r = &reports[0];
    assert_eq!(r["failing_pixels"], 4);
    assert_eq!(r["hits"]["lambda"], 1);
    assert_eq!(r["hits"]["normal"], 1);
    assert_eq!(r["hits"]["wrong_object"], 1);
    assert_eq!(r["hits"]["hit_miss"], 1);
    for (form, other) in ["csv", "npy", "ndjson"].iter().zip(&reports[1..]) {
        assert_eq!(other, r, "{form} differs from JSON");
    }
}

// ---------------------------------------------------------------------------------------
// report formats

#[test]
fn gradescope_and_prairielearn_reports() {
    let dir = tempfile::tempdir().unwrap();
    let scene = resized_scene(&dir, "sphere.json", 64, 48);
    let (w, h, mut rgb) = render(&dir, &scene);
    for x in rgb.iter_mut().take(3 * 200) {
        *x = x.wrapping_add(60);
    }
    let sub = write(&dir, "student.png", &encode_png(w, h, &rgb));

    let results = dir.path().join("results.json");
    let out = grade(
        &scene,
        &sub,
        &[
            "--report",
            "gradescope",
            "--max-score",
            "5",
            "-o",
            s(&results),
        ],
    );
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let g: Value = serde_json::from_slice(&std::fs::read(&results).unwrap()).unwrap();
    assert_eq!(g["score"], 0.0);
    assert_eq!(g["max_score"], 5.0);
    assert_eq!(g["tests"][0]["status"], "failed");
    assert_eq!(g["tests"][0]["max_score"], 5.0);
    assert!(g["output"].as_str().unwrap().contains("Worst pixels"));

    let out = grade(&scene, &sub, &["--report", "prairielearn"]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    assert!(out.stdout.len() < 1_000_000);
    let pl = stdout_json(&out);
    assert_eq!(pl["gradable"], true);
    assert_eq!(pl["score"], 0.0);
    assert!(pl["message"].as_str().unwrap().starts_with("FAIL"));
    let url = pl["images"][0]["url"].as_str().unwrap();
    assert!(url.starts_with("data:image/png;base64,"));

    let out = grade(&scene, &sub, &["--report", "text"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.starts_with("FAIL: 200 of 3072 pixels"), "{text}");

    let out = grade(&scene, &sub, &["--inline-diff", "--worst", "3"]);
    let r = stdout_json(&out);
    assert_eq!(r["worst"].as_array().unwrap().len(), 3);
    assert!(!r["diff_png_base64"].as_str().unwrap().is_empty());
}

// ---------------------------------------------------------------------------------------
// bad submissions

#[test]
fn bad_submissions_exit_2_with_one_clear_line() {
    let dir = tempfile::tempdir().unwrap();
    let scene = resized_scene(&dir, "sphere.json", 16, 12);
    let (w, h, rgb) = render(&dir, &scene);
    let png = encode_png(w, h, &rgb);
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        (
            "truncated.png",
            png[..png.len() / 2].to_vec(),
            "the PNG file is corrupt",
        ),
        (
            "small.png",
            encode_png(w - 1, h, &rgb[..3 * ((w - 1) * h) as usize]),
            "the submission is 15 × 12 pixels but the scene renders 16 × 12",
        ),
        (
            "notes.txt",
            b"my ray tracer output".to_vec(),
            "cannot tell what the submission is",
        ),
        ("fake.png", b"GIF89a....".to_vec(), "not a PNG file"),
        ("empty.json", Vec::new(), "the submission is empty"),
        (
            "short.csv",
            b"u,v,hit,lambda,nx,ny\n0,0,0,,,\n".to_vec(),
            "no CSV column `nz`",
        ),
        (
            "few.json",
            br#"[{"hit": false}, {"hit": false}]"#.to_vec(),
            "190 pixel(s) of the image are missing",
        ),
        (
            "wrong.json",
            br#"{"width": 16, "height": 12, "pixels": [{"hit": true, "lambda": 1}]}"#.to_vec(),
            "pixels[0]: `hit` is true but `normal` is missing",
        ),
        (
            "syntax.json",
            b"{\"pixels\": [".to_vec(),
            "the hit data is not valid JSON",
        ),
        (
            "flat.npy",
            {
                let dict = "{'descr': '<f8', 'fortran_order': False, 'shape': (192,), }\n";
                let mut b = b"\x93NUMPY\x01\x00".to_vec();
                b.extend_from_slice(&(dict.len() as u16).to_le_bytes());
                b.extend_from_slice(dict.as_bytes());
                b.extend_from_slice(&[0; 192 * 8]);
                b
            },
            "wrong shape",
        ),
        (
            "small.npy",
            hits_npy(2, 1, &[miss(0, 0), miss(1, 0)]),
            "the submission is 2 × 1 pixels but the scene renders 16 × 12",
        ),
    ];
    for (name, bytes, want) in cases {
        let p = write(&dir, name, &bytes);
        let out = grade(&scene, &p, &[]);
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(2), "{name}: {err}");
        assert!(err.contains(want), "{name}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{name}: {err}");
        assert!(!err.contains("panicked"), "{name}: {err}");
        assert!(out.stdout.is_empty(), "{name}");
    }
}

// ---------------------------------------------------------------------------------------
// trace: bounded answers

#[test]
fn trace_of_many_coincident_spheres_is_bounded_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let objects = vec![serde_json::json!({"shape": "sphere", "material": "glass"}); 20_000];
    let scene = serde_json::json!({
        "version": 1,
        "image": {"width": 5, "height": 5},
        "camera": {"focal_length": 1},
        "max_depth": 10,
        "materials": {"glass": {"mirror": [0.5, 0.5, 0.5], "transmission": [0.5, 0.5, 0.5]}},
        "objects": objects,
        "lights": [{"type": "point", "position": [0, -4, 0], "colour": [1, 1, 1]}]
    });
    let path = write(&dir, "many.json", &serde_json::to_vec(&scene).unwrap());
    for (format, limit) in [("json", 2_400_000), ("text", 1_000_000)] {
        let out = run(&[
            "trace",
            s(&path),
            "--pixel",
            "2,2",
            "--candidates",
            "bvh",
            "--max-rays",
            "100000",
            "--max-triangles",
            "100000",
            "--max-tests",
            "1024",
            "--format",
            format,
        ]);
        assert!(out.status.success(), "{}", stderr(&out));
        assert!(
            out.stdout.len() < limit,
            "{format}: {} bytes",
            out.stdout.len()
        );
        if format == "json" {
            let e = stdout_json(&out);
            assert_eq!(e["truncated"], true);
            assert!(e["truncation"]["budget_spent_at"]["pointer"].is_string());
        } else {
            let text = String::from_utf8_lossy(&out.stdout);
            assert!(text.contains("Shortened to stay readable"), "{text}");
            assert!(text.contains("size budget of 2097152 bytes"), "{text}");
        }
    }
}

#[test]
fn trace_refuses_max_tests_out_of_range() {
    let out = run(&[
        "trace",
        s(&scene("lecture.json")),
        "--pixel",
        "2,2",
        "--max-tests",
        "1025",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr(&out).contains("expected a whole number from 0 to 1024, got `1025`"),
        "{}",
        stderr(&out)
    );
}
