//! `raytile grade-assignment FILE DIR`: a two-scene assignment (a visible image scene, a
//! hidden hit-data scene) graded offline from files `raytile render` and `raytile hits`
//! wrote, wrong ones, missing and unreadable ones, and an invalid document.

use std::path::Path;

use serde_json::{Value, json};

use super::support::{raytile, run};

fn scene(translate: [f64; 3]) -> Value {
    json!({"version": 1, "image": {"width": 16, "height": 12}, "camera": {"focal_length": 1},
           "objects": [{"name": "ball", "shape": "sphere", "transform": [{"translate": translate}]}],
           "lights": [{"type": "point", "position": [0, -4, 0], "colour": [1, 0.75, 0.5]}]})
}

fn assignment() -> Value {
    json!({"version": 1, "title": "Ray casting", "due": "2099-12-24T23:59:00Z",
           "scenes": [
             {"name": "spheres", "scene": scene([0.5, 0.0, 2.0]), "points": 5, "grade": "image",
              "visibility": "visible"},
             {"name": "secret", "scene": scene([-0.5, 0.2, 2.5]), "points": 3, "grade": "hits",
              "visibility": "hidden", "feedback": "after_due_date",
              "tolerances": {"lambda_rel": 1e-6}, "scoring": "linear"}]})
}

fn write(p: &Path, v: &Value) {
    std::fs::write(p, serde_json::to_vec(v).unwrap()).unwrap();
}

/// The assignment, each scene's document, and a folder of correct files rendered from
/// them by the binary.
fn setup() -> (tempfile::TempDir, std::path::PathBuf, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let a = dir.path().join("assignment.json");
    write(&a, &assignment());
    let sub = dir.path().join("sub");
    std::fs::create_dir(&sub).unwrap();
    for (name, t, cmd, ext) in [
        ("spheres", [0.5, 0.0, 2.0], "render", "png"),
        ("secret", [-0.5, 0.2, 2.5], "hits", "npy"),
    ] {
        let s = dir.path().join(format!("{name}.json"));
        write(&s, &scene(t));
        let out = sub.join(format!("{name}.{ext}"));
        let o = run(&[cmd, s.to_str().unwrap(), "-o", out.to_str().unwrap()]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    (dir, a, sub)
}

fn grade(a: &Path, sub: &Path, report: &str) -> (Option<i32>, String) {
    let o = raytile()
        .args([
            "grade-assignment",
            a.to_str().unwrap(),
            sub.to_str().unwrap(),
            "--report",
            report,
        ])
        .output()
        .unwrap();
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
    )
}

#[test]
fn a_correct_submission_earns_full_marks_in_every_form() {
    let (_dir, a, sub) = setup();
    let (code, out) = grade(&a, &sub, "json");
    assert_eq!(code, Some(0), "{out}");
    let r: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(r["score"], 8.0);
    assert_eq!(r["max_score"], 8.0);
    assert_eq!(r["scenes"][0]["status"], "passed");
    assert_eq!(r["scenes"][1]["status"], "passed");
    // The visible scene carries its full report, the hidden one none.
    assert_eq!(r["scenes"][0]["parts"][0]["report"]["pass"], true);
    assert!(r["scenes"][1]["parts"][0].get("report").is_none());
    let (_, gs) = grade(&a, &sub, "gradescope");
    let g: Value = serde_json::from_str(&gs).unwrap();
    assert_eq!(g["score"], 8.0);
    assert_eq!(g["tests"][0]["visibility"], "visible");
    assert_eq!(g["tests"][1]["visibility"], "after_due_date");
    assert_eq!(g["tests"][1]["max_score"], 3.0);
    let (_, pl) = grade(&a, &sub, "prairielearn");
    let p: Value = serde_json::from_str(&pl).unwrap();
    assert_eq!(p["gradable"], true);
    assert_eq!(p["score"], 1.0);
    assert_eq!(p["tests"][1]["hidden"], true);
    let (_, text) = grade(&a, &sub, "text");
    assert!(text.starts_with("Ray casting: 8 of 8 points"), "{text}");
}

#[test]
fn a_wrong_missing_or_unreadable_scene_costs_only_its_points() {
    let (dir, a, sub) = setup();
    // A wrong hidden scene: the hits of another scene. Its feedback reveals nothing.
    let other = dir.path().join("other.json");
    write(&other, &scene([0.0, 0.0, 3.0]));
    let wrong = sub.join("secret.npy");
    let o = run(&[
        "hits",
        other.to_str().unwrap(),
        "-o",
        wrong.to_str().unwrap(),
    ]);
    assert!(o.status.success());
    for form in ["json", "text", "gradescope", "prairielearn"] {
        let (code, out) = grade(&a, &sub, form);
        assert_eq!(code, Some(1));
        for leak in ["worst", "lambda", "λ", "reference", "data:image"] {
            let secret_part = if form == "json" || form == "prairielearn" || form == "gradescope" {
                let v: Value = serde_json::from_str(&out).unwrap();
                let tests = if form == "json" {
                    &v["scenes"][1]
                } else {
                    &v["tests"][1]
                };
                tests.to_string()
            } else {
                out[out.find("\nsecret:").unwrap()..].to_owned()
            };
            assert!(
                !secret_part.contains(leak),
                "{form} shows `{leak}`: {secret_part}"
            );
        }
    }
    let (_, out) = grade(&a, &sub, "json");
    let r: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(r["scenes"][0]["points"], 5.0);
    assert_eq!(r["scenes"][1]["status"], "failed");
    // Missing: no file for the hidden scene.
    std::fs::remove_file(&wrong).unwrap();
    let (code, out) = grade(&a, &sub, "json");
    assert_eq!(code, Some(1));
    let r: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(r["score"], 5.0);
    assert_eq!(r["scenes"][1]["status"], "missing");
    assert!(
        r["scenes"][1]["message"]
            .as_str()
            .unwrap()
            .contains("secret")
    );
    // Unreadable: junk for the image scene makes only that scene ungradable.
    std::fs::write(sub.join("spheres.png"), b"not a PNG at all").unwrap();
    let (_, out) = grade(&a, &sub, "gradescope");
    let g: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(g["score"], 0.0);
    assert_eq!(g["tests"][0]["status"], "failed");
    assert!(
        g["tests"][0]["output"]
            .as_str()
            .unwrap()
            .contains("spheres.png")
    );
    let (_, out) = grade(&a, &sub, "json");
    let r: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(r["scenes"][0]["status"], "ungradable");
}

#[test]
fn an_invalid_assignment_lists_every_problem_with_its_pointer() {
    let dir = tempfile::tempdir().unwrap();
    let mut doc = assignment();
    doc["due"] = json!("next week");
    doc["scenes"][0]["points"] = json!(-1);
    doc["scenes"][1]["name"] = json!("secret.npy");
    doc["scenes"][1]["scene"]["objects"][0]["shape"] = json!("blob");
    doc["scenes"][1]["colour"] = json!(1);
    let a = dir.path().join("a.json");
    write(&a, &doc);
    let o = run(&[
        "grade-assignment",
        a.to_str().unwrap(),
        dir.path().to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    for pointer in [
        "/due:",
        "/scenes/0/points:",
        "/scenes/1/name:",
        "/scenes/1/scene/objects/0/shape:",
        "/scenes/1/colour:",
    ] {
        assert!(err.contains(pointer), "{pointer} missing from {err}");
    }
}
