//! The combined report of a graded submission, in the forms `raytile grade` writes:
//! our JSON, readable text, Gradescope's `results.json` (a test per scene, its
//! `visibility` from the scene's) and PrairieLearn's results (a test per scene, hidden
//! scenes' tests marked `hidden`). Each scene's own report text is
//! [`crate::grade::report::to_text`]'s; what a hidden scene shows was decided when it
//! was graded ([`super::grade::feedback`]), so no form here can show more. The forms
//! read nothing of a result that its JSON does not keep, so a stored result read back
//! ([`read`]) writes every form as it was first written.

use std::fmt::Write as _;

use serde_json::{Value, json};

use super::grade::{AssignmentResult, SceneResult, Status};
use crate::grade::answer::ReportForm;
use crate::grade::report::md_block;
use crate::grade::score::short;

/// The report in `form` as bytes (the difference image has no combined form: JSON).
pub fn write(result: &AssignmentResult, form: ReportForm) -> Vec<u8> {
    let value = match form {
        ReportForm::Text => return text(result).into_bytes(),
        ReportForm::Gradescope => gradescope(result),
        ReportForm::Prairielearn => prairielearn(result),
        ReportForm::Json | ReportForm::DiffPng => json(result),
    };
    let mut bytes = serde_json::to_vec_pretty(&value).unwrap_or_default();
    bytes.push(b'\n');
    bytes
}

/// A result stored as its JSON form, read back to write it in another form (the JSON
/// form is the stored text itself: the full reports are not read back).
pub fn read(json: &str) -> Result<AssignmentResult, serde_json::Error> {
    serde_json::from_str(json)
}

/// Our JSON: the result as it is.
pub fn json(result: &AssignmentResult) -> Value {
    serde_json::to_value(result).unwrap_or(Value::Null)
}

fn status_name(s: Status) -> &'static str {
    match s {
        Status::Passed => "passed",
        Status::Failed => "failed",
        Status::Missing => "missing",
        Status::Ungradable => "ungradable",
    }
}

/// One scene as text: its points and verdict, then each shown part's full report.
fn scene_text(s: &SceneResult) -> String {
    let mut o = String::new();
    let _ = writeln!(
        o,
        "{}: {} of {} points, {} ({})",
        s.name,
        short(s.points),
        short(s.max_points),
        status_name(s.status),
        s.visibility
    );
    for p in &s.parts {
        let file = p.file.as_deref().unwrap_or("no file");
        let _ = writeln!(o, "  {} ({file}): {}", p.kind, p.message);
        if let Some(text) = &p.report_text {
            for line in text.lines() {
                let _ = writeln!(o, "    {line}");
            }
        }
    }
    o
}

/// The whole result as readable text.
pub fn text(result: &AssignmentResult) -> String {
    let mut o = String::new();
    let _ = writeln!(
        o,
        "{}: {} of {} points",
        result.title,
        short(result.score),
        short(result.max_score)
    );
    for s in &result.scenes {
        o.push('\n');
        o.push_str(&scene_text(s));
    }
    if !result.ignored.is_empty() {
        let _ = writeln!(
            o,
            "\nIgnored (they name no scene): {}",
            result.ignored.join(", ")
        );
    }
    o
}

/// Gradescope's `visibility` of a scene's test: a hidden scene's test is shown after
/// the due date when its feedback is allowed then, else never.
fn gradescope_visibility(s: &SceneResult) -> &'static str {
    match (s.visibility, s.after_due_date) {
        ("visible", _) => "visible",
        (_, true) => "after_due_date",
        _ => "hidden",
    }
}

/// Gradescope's `results.json`: a test per scene carrying its points, the total score.
pub fn gradescope(result: &AssignmentResult) -> Value {
    let tests: Vec<Value> = result
        .scenes
        .iter()
        .map(|s| {
            json!({
                "name": s.name,
                "score": s.points,
                "max_score": s.max_points,
                "status": if s.status == Status::Passed { "passed" } else { "failed" },
                "output": md_block(&scene_text(s)),
                "visibility": gradescope_visibility(s),
            })
        })
        .collect();
    json!({
        "score": result.score,
        "max_score": result.max_score,
        "output": md_block(&format!(
            "{}: {} of {} points",
            result.title,
            short(result.score),
            short(result.max_score)
        )),
        "output_format": "md",
        "test_output_format": "md",
        "test_name_format": "text",
        "visibility": "visible",
        "stdout_visibility": "hidden",
        "tests": tests,
    })
}

/// PrairieLearn's results: a test per scene (hidden scenes' tests `hidden`), the score
/// as a share of the points.
pub fn prairielearn(result: &AssignmentResult) -> Value {
    let tests: Vec<Value> = result
        .scenes
        .iter()
        .map(|s| {
            json!({
                "name": s.name,
                "points": s.points,
                "max_points": s.max_points,
                "message": s.message,
                "output": scene_text(s),
                "hidden": s.visibility == "hidden" && !s.feedback,
            })
        })
        .collect();
    let score = if result.max_score > 0.0 {
        result.score / result.max_score
    } else {
        0.0
    };
    json!({
        "gradable": true,
        "score": score,
        "message": format!(
            "{} of {} points",
            short(result.score),
            short(result.max_score)
        ),
        "output": text(result),
        "tests": tests,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::assignment::grade::{SubmittedFile, grade_submission};
    use crate::assignment::{self, tests::sphere};
    use crate::grade::{GradeOptions, Hint, RgbImage, reference_image};
    use crate::render::{Cancel, Renderer};
    use crate::scene::Limits;

    fn assignment(visibility: &str, due: &str) -> assignment::Assignment {
        let doc = format!(
            r#"{{"version": 1, "title": "t", "due": "{due}", "scenes": [
                {{"name": "s", "scene": {}, "points": 3, "grade": "image", "visibility": {visibility}}}]}}"#,
            sphere(6, "sphere")
        );
        assignment::parse(doc.as_bytes(), &Limits::NONE).unwrap()
    }

    /// Every form of the report, compact.
    fn forms(r: &AssignmentResult) -> Vec<String> {
        vec![
            json(r).to_string(),
            text(r),
            gradescope(r).to_string(),
            prairielearn(r).to_string(),
        ]
    }

    fn graded(a: &assignment::Assignment, now: i64) -> (AssignmentResult, Vec<String>) {
        let s = &a.scenes[0];
        let reference = reference_image(&Renderer::new(s.scene.clone()), &Cancel::new()).unwrap();
        let lit: Vec<String> = (0..reference.height)
            .flat_map(|v| (0..reference.width).map(move |u| (u, v)))
            .map(|(u, v)| reference.get(u, v))
            .filter(|p| *p != [0, 0, 0])
            .flat_map(|[r, g, b]| [format!("rgb({r}, {g}, {b})"), format!("[{r},{g},{b}]")])
            .collect();
        assert!(!lit.is_empty(), "the reference must show the sphere");
        let black = RgbImage::from_pixels(
            reference.width,
            reference.height,
            &vec![[0u8; 3]; (reference.width * reference.height) as usize],
        );
        let files = vec![SubmittedFile {
            scene: "s".into(),
            file_name: "s.png".into(),
            bytes: black.encode_png(),
            hint: Hint::Png,
        }];
        let r = grade_submission(a, files, now, &GradeOptions::default());
        (r, lit)
    }

    fn leaks(forms: &[String], lit: &[String]) -> Vec<String> {
        let mut found = Vec::new();
        for f in forms {
            for v in
                lit.iter()
                    .map(String::as_str)
                    .chain(["data:image/png", "\"worst\"", "reference"])
            {
                if f.contains(v) {
                    found.push(v.to_owned());
                }
            }
        }
        found
    }

    #[test]
    fn a_hidden_scene_shows_no_reference_value_in_any_form() {
        let a = assignment(r#""hidden""#, "2026-01-01T00:00:00Z");
        let (r, lit) = graded(&a, i64::MAX);
        assert_eq!(r.scenes[0].status, Status::Failed);
        assert_eq!(r.score, 0.0);
        assert!(r.scenes[0].parts[0].report.is_none());
        assert_eq!(leaks(&forms(&r), &lit), Vec::<String>::new());
        assert_eq!(gradescope(&r)["tests"][0]["visibility"], "hidden");
        assert_eq!(prairielearn(&r)["tests"][0]["hidden"], true);
    }

    #[test]
    fn after_due_date_feedback_shows_only_once_due() {
        let a = assignment(
            r#""hidden", "feedback": "after_due_date""#,
            "2026-01-01T00:00:00Z",
        );
        let due = a.due.as_ref().unwrap().unix;
        let (before, lit) = graded(&a, due - 1);
        assert_eq!(leaks(&forms(&before), &lit), Vec::<String>::new());
        assert_eq!(
            gradescope(&before)["tests"][0]["visibility"],
            "after_due_date"
        );
        let (after, lit) = graded(&a, due + 1);
        assert!(!leaks(&forms(&after), &lit).is_empty());
    }

    #[test]
    fn a_visible_scene_shows_the_reference() {
        let a = assignment(r#""visible""#, "2026-01-01T00:00:00Z");
        let (r, lit) = graded(&a, 0);
        // Every form but the summary ones lists the worst pixels' reference values.
        let f = forms(&r);
        assert!(lit.iter().any(|v| f[0].contains(v.as_str())));
        assert!(lit.iter().any(|v| f[1].contains(v.as_str())));
        assert_eq!(gradescope(&r)["tests"][0]["visibility"], "visible");
        assert_eq!(gradescope(&r)["max_score"], 3.0);
    }

    #[test]
    fn a_result_read_back_writes_every_form_as_before() {
        for (visibility, now) in [(r#""visible""#, 0), (r#""hidden""#, 0)] {
            let a = assignment(visibility, "2026-01-01T00:00:00Z");
            let (r, _) = graded(&a, now);
            let stored = String::from_utf8(write(&r, ReportForm::Json)).unwrap();
            let back = read(&stored).unwrap();
            // The JSON form is its stored text itself; the others come from it.
            for form in [
                ReportForm::Text,
                ReportForm::Gradescope,
                ReportForm::Prairielearn,
            ] {
                assert_eq!(
                    String::from_utf8(write(&back, form)).unwrap(),
                    String::from_utf8(write(&r, form)).unwrap(),
                    "{visibility} {form:?}"
                );
            }
        }
        assert!(read(r#"{"title": "t"}"#).is_err());
    }

    #[test]
    fn a_missing_scene_scores_zero() {
        let a = assignment(r#""visible""#, "2026-01-01T00:00:00Z");
        let r = grade_submission(&a, Vec::new(), 0, &GradeOptions::default());
        assert_eq!(r.scenes[0].status, Status::Missing);
        assert!(
            r.scenes[0].message.contains("no image file"),
            "{}",
            r.scenes[0].message
        );
        assert_eq!(prairielearn(&r)["score"], 0.0);
        let junk = vec![SubmittedFile {
            scene: "s".into(),
            file_name: "s.png".into(),
            bytes: b"not an image".to_vec(),
            hint: Hint::Png,
        }];
        let r = grade_submission(&a, junk, 0, &GradeOptions::default());
        assert_eq!(r.scenes[0].status, Status::Ungradable);
        assert!(
            r.scenes[0].message.starts_with("s.png: "),
            "{}",
            r.scenes[0].message
        );
    }
}
