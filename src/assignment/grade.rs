//! Grading a whole submission: each scene's files graded by [`crate::grade::grade`], one
//! combined [`AssignmentResult`]. A missing scene scores zero, an unreadable file makes
//! its scene ungradable and nothing more; what a hidden scene's result may show is
//! decided in one place, [`feedback`].
//!
//! A result is stored as its JSON and read back ([`AssignmentResult`] deserializes) to
//! answer a retried submission in another report form: everything the forms show is in
//! the JSON, each shown part's report also as its text, so the full reports themselves
//! need not be read back.

use serde::{Deserialize, Deserializer, Serialize};

use super::{AssignedScene, Assignment, Visibility};
use crate::grade::{self, GradeOptions, Hint, Report, Submission};
use crate::render::Renderer;

/// One file of a submission: the scene it is for (its name), its bytes, and what its
/// name or media type say of its form.
#[derive(Debug, Clone)]
pub struct SubmittedFile {
    /// The scene's name (the file's stem).
    pub scene: String,
    /// The file's name as sent, for messages.
    pub file_name: String,
    /// Its content.
    pub bytes: Vec<u8>,
    /// Its form, as far as its name tells.
    pub hint: Hint,
}

/// How a scene fared.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// Every part passes.
    Passed,
    /// Graded, and some part fails.
    Failed,
    /// No file for the scene (or for one of its parts).
    Missing,
    /// A file that cannot be graded (unreadable, the wrong size, the wrong kind).
    Ungradable,
}

/// One graded part of a scene (its image or its hit data), as much as may be shown.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PartResult {
    /// `"image"` or `"hits"`.
    #[serde(deserialize_with = "kind_name")]
    pub kind: StaticName,
    /// The file graded, if one was given.
    pub file: Option<String>,
    /// How it fared.
    pub status: Status,
    /// The score, 0–1.
    pub score: f64,
    /// The verdict, or why it could not be graded.
    pub message: String,
    /// The full report, only where the scene's feedback may show it (not read back).
    #[serde(skip_serializing_if = "Option::is_none", skip_deserializing)]
    pub report: Option<Report>,
    /// The full report as text ([`crate::grade::report::to_text`]), exactly where
    /// `report` is shown: what the text and grader forms print of it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub report_text: Option<String>,
}

/// A name from a fixed list. Spelled through an alias because serde's derive takes a
/// field written `&'static str` as borrowed from the input, which a result read from a
/// `String` cannot be; these are read by `static_name` instead.
pub type StaticName = &'static str;

/// One of `names` as read back, as the `&'static str` it was written from.
fn static_name<'de, D: Deserializer<'de>>(
    d: D,
    names: &'static [&'static str],
) -> Result<&'static str, D::Error> {
    let s = String::deserialize(d)?;
    names
        .iter()
        .find(|n| **n == s)
        .copied()
        .ok_or_else(|| serde::de::Error::unknown_variant(&s, names))
}

fn kind_name<'de, D: Deserializer<'de>>(d: D) -> Result<&'static str, D::Error> {
    static_name(d, &["image", "hits"])
}

fn visibility_name<'de, D: Deserializer<'de>>(d: D) -> Result<&'static str, D::Error> {
    static_name(d, &["visible", "hidden"])
}

/// One scene's result.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SceneResult {
    /// The scene's name.
    pub name: String,
    /// Points earned.
    pub points: f64,
    /// Points for a full score.
    pub max_points: f64,
    /// How it fared: the worst of its parts.
    pub status: Status,
    /// `"visible"` or `"hidden"`.
    #[serde(deserialize_with = "visibility_name")]
    pub visibility: StaticName,
    /// Whether the full feedback is shown (visible scenes, and hidden ones whose
    /// feedback is allowed after the due date once it has passed).
    pub feedback: bool,
    /// A hidden scene whose full feedback is allowed once the due date has passed.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub after_due_date: bool,
    /// The verdict in one sentence.
    pub message: String,
    /// The catalogue names of the mistakes diagnosed, when the feedback is shown.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub diagnosis: Vec<String>,
    /// Each part.
    pub parts: Vec<PartResult>,
}

/// A whole submission's result.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AssignmentResult {
    /// The assignment's title.
    pub title: String,
    /// The due date as written, if any.
    pub due: Option<String>,
    /// Points earned over every scene.
    pub score: f64,
    /// Points possible.
    pub max_score: f64,
    /// Each scene in the assignment's order.
    pub scenes: Vec<SceneResult>,
    /// Files that name no scene of the assignment (ignored).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub ignored: Vec<String>,
}

impl AssignmentResult {
    /// Whether every scene earned full marks.
    pub fn full_marks(&self) -> bool {
        self.scenes.iter().all(|s| s.status == Status::Passed)
    }
}

/// Whether a scene's full feedback may be shown at `now` (seconds since the Unix
/// epoch): always for a visible scene; for a hidden one only with `after_due_date`, a
/// due date, and `now` past it.
pub fn reveals(a: &Assignment, s: &AssignedScene, now: i64) -> bool {
    match s.visibility {
        Visibility::Visible => true,
        Visibility::Hidden { after_due_date } => {
            after_due_date && a.due.as_ref().is_some_and(|d| now > d.unix)
        }
    }
}

/// What a part's result shows of its report: everything when `reveal`, else the score
/// and the verdict alone, with no worst pixels, reference values, statistics, diagnosis
/// or difference image. Every result is built through here.
pub fn feedback(kind: &'static str, file: String, report: Report, reveal: bool) -> PartResult {
    let status = if report.pass {
        Status::Passed
    } else {
        Status::Failed
    };
    let score = report.score.value;
    if reveal {
        return PartResult {
            kind,
            file: Some(file),
            status,
            score,
            message: report.summary.clone(),
            report_text: Some(grade::report::to_text(&report)),
            report: Some(report),
        };
    }
    PartResult {
        kind,
        file: Some(file),
        status,
        score,
        message: format!(
            "{}: score {} of 1 (this scene is hidden: no further feedback)",
            if report.pass { "PASS" } else { "FAIL" },
            grade::score::short(score)
        ),
        report: None,
        report_text: None,
    }
}

/// Grades `files` against `a` at `now` (seconds since the Unix epoch, for hidden
/// feedback after the due date), on the current rayon pool.
pub fn grade_submission(
    a: &Assignment,
    files: Vec<SubmittedFile>,
    now: i64,
    opts: &GradeOptions,
) -> AssignmentResult {
    let mut files = files;
    let mut scenes = Vec::new();
    for s in &a.scenes {
        let mine: Vec<SubmittedFile> = {
            let (mine, rest) = files.into_iter().partition(|f| f.scene == s.name);
            files = rest;
            mine
        };
        scenes.push(grade_scene(s, mine, reveals(a, s, now), opts));
    }
    let mut ignored: Vec<String> = files.into_iter().map(|f| f.file_name).collect();
    ignored.sort();
    AssignmentResult {
        title: a.title.clone(),
        due: a.due.as_ref().map(|d| d.text.clone()),
        score: scenes.iter().map(|s| s.points).sum(),
        max_score: a.scenes.iter().map(|s| s.points).sum(),
        scenes,
        ignored,
    }
}

fn kind_of(sub: &Submission) -> &'static str {
    match sub {
        Submission::Image(_) => "image",
        Submission::Hits(_) => "hits",
    }
}

fn ungradable(kind: &'static str, file: Option<String>, message: String) -> PartResult {
    PartResult {
        kind,
        file,
        status: Status::Ungradable,
        score: 0.0,
        message,
        report: None,
        report_text: None,
    }
}

fn grade_scene(
    s: &AssignedScene,
    files: Vec<SubmittedFile>,
    reveal: bool,
    opts: &GradeOptions,
) -> SceneResult {
    let kinds = s.graded.kinds();
    let r = Renderer::new(s.scene.clone());
    let (w, h) = (s.scene.width, s.scene.height);
    let opts = GradeOptions {
        scoring: s.scoring,
        ..opts.clone()
    };
    let mut parts: Vec<PartResult> = Vec::new();
    let mut unplaced = Vec::new();
    for f in files {
        let parsed = Submission::parse_for_frame(&f.bytes, f.hint, w, h);
        let sub = match parsed {
            Ok(sub) => sub,
            Err(e) => {
                unplaced.push(ungradable(
                    kinds[0],
                    Some(f.file_name.clone()),
                    format!("{}: {e}", f.file_name),
                ));
                continue;
            }
        };
        let kind = kind_of(&sub);
        if !kinds.contains(&kind) || parts.iter().any(|p| p.kind == kind) {
            let why = if kinds.contains(&kind) {
                format!("{}: a second {kind} file for the scene", f.file_name)
            } else {
                format!(
                    "{}: the scene grades {}, not {kind}",
                    f.file_name,
                    kinds.join(" and ")
                )
            };
            unplaced.push(ungradable(kind, Some(f.file_name.clone()), why));
            continue;
        }
        let part = match grade::grade(&r, sub, &s.tolerances, &opts) {
            Ok(report) => feedback(kind, f.file_name, report, reveal),
            Err(e) => ungradable(
                kind,
                Some(f.file_name.clone()),
                format!("{}: {e}", f.file_name),
            ),
        };
        parts.push(part);
    }
    // An unreadable file stands for the part it did not fill; each part missing else.
    for kind in kinds {
        if parts.iter().any(|p| p.kind == *kind) {
            continue;
        }
        let part = match unplaced
            .iter()
            .position(|p| p.kind == *kind || kinds.len() == 1)
        {
            Some(i) => unplaced.remove(i),
            None => PartResult {
                kind,
                file: None,
                status: Status::Missing,
                score: 0.0,
                message: format!(
                    "no {kind} file was submitted for the scene `{}` (name it `{}.EXT`)",
                    s.name, s.name
                ),
                report: None,
                report_text: None,
            },
        };
        parts.push(part);
    }
    parts.sort_by_key(|p| kinds.iter().position(|k| *k == p.kind));
    let share = parts.iter().map(|p| p.score).sum::<f64>() / kinds.len() as f64;
    let status = [Status::Ungradable, Status::Missing, Status::Failed]
        .into_iter()
        .find(|st| parts.iter().any(|p| p.status == *st))
        .unwrap_or(Status::Passed);
    let mut message = parts
        .iter()
        .map(|p| p.message.clone())
        .collect::<Vec<_>>()
        .join(" ");
    for extra in &unplaced {
        message.push(' ');
        message.push_str(&extra.message);
    }
    let diagnosis = parts
        .iter()
        .filter_map(|p| p.report.as_ref()?.diagnosis.as_ref())
        .flat_map(|d| d.mistakes.iter())
        .filter_map(|m| {
            serde_json::to_value(m.mistake)
                .ok()?
                .as_str()
                .map(String::from)
        })
        .collect();
    SceneResult {
        name: s.name.clone(),
        points: share * s.points,
        max_points: s.points,
        status,
        visibility: match s.visibility {
            Visibility::Visible => "visible",
            Visibility::Hidden { .. } => "hidden",
        },
        feedback: reveal,
        after_due_date: matches!(
            s.visibility,
            Visibility::Hidden {
                after_due_date: true
            }
        ),
        message,
        diagnosis,
        parts,
    }
}
