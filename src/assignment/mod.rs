//! Assignments: several scenes graded together ([`grade::grade_submission`]), each with
//! its points, what is graded, its tolerances and scoring (those of `/v1/grade`) and its
//! visibility, in one combined report ([`report`]).
//!
//! The document ([`parse`]) is read as strictly as a scene: unknown fields, duplicated
//! keys, bad names, points and dates, and every problem inside each scene document, all
//! reported at once with their JSON pointers (`/scenes/1/scene/objects/0/radius`).
//! The format is described in `docs/assignments.md`.
//!
//! [`grade::grade_submission`]: crate::assignment::grade::grade_submission
//! [`report`]: crate::assignment::report
//! [`parse`]: crate::assignment::parse

pub mod grade;
pub mod gradebook;
pub mod report;
mod time;

use std::sync::Arc;

use serde_json::{Map, Value};

use crate::grade::{Scoring, ScoringMode, Tolerances};
use crate::scene::problem::Pointer;
use crate::scene::{self, Limits, Problem, Scene, SceneError};
pub use time::{format_rfc3339_ms, parse_rfc3339};

/// The assignment document's one version.
pub const VERSION: u64 = 1;

/// An assignment, validated: every scene traceable, every setting in range.
#[derive(Debug, Clone)]
pub struct Assignment {
    /// Its title.
    pub title: String,
    /// The due date, if any.
    pub due: Option<Due>,
    /// The scenes, in document order, with distinct names.
    pub scenes: Vec<AssignedScene>,
}

/// A due date: as written, and in seconds since the Unix epoch.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Due {
    /// The RFC 3339 text of the document.
    pub text: String,
    /// Seconds since 1970-01-01T00:00:00Z.
    pub unix: i64,
}

/// What is graded of a scene.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Graded {
    /// The image.
    Image,
    /// The hit data.
    Hits,
    /// Both, each half of the scene's points.
    Both,
}

impl Graded {
    fn from_name(s: &str) -> Option<Graded> {
        match s {
            "image" => Some(Graded::Image),
            "hits" => Some(Graded::Hits),
            "both" => Some(Graded::Both),
            _ => None,
        }
    }

    /// The kinds of submission the scene needs: `"image"`, `"hits"`, or both.
    pub fn kinds(self) -> &'static [&'static str] {
        match self {
            Graded::Image => &["image"],
            Graded::Hits => &["hits"],
            Graded::Both => &["image", "hits"],
        }
    }
}

/// Who sees what of a scene's grading.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Visibility {
    /// Full feedback.
    Visible,
    /// Score and verdict only; with `after_due_date`, full feedback once the due date
    /// has passed.
    Hidden {
        /// `"feedback": "after_due_date"`.
        after_due_date: bool,
    },
}

/// One scene of an assignment.
#[derive(Debug, Clone)]
pub struct AssignedScene {
    /// Its name: a file stem, `[A-Za-z0-9_-]+`.
    pub name: String,
    /// The scene, validated.
    pub scene: Arc<Scene>,
    /// Points for a full score (> 0).
    pub points: f64,
    /// What is graded.
    pub graded: Graded,
    /// Who sees what.
    pub visibility: Visibility,
    /// The tolerances (defaults filled in).
    pub tolerances: Tolerances,
    /// The scoring (defaults filled in).
    pub scoring: Scoring,
}

/// Why an assignment document was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AssignmentError {
    /// The bytes are not JSON.
    #[error("the assignment is not valid JSON: {message} at line {line}, column {column}")]
    Syntax {
        /// serde_json's reason.
        message: String,
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
    },
    /// JSON, but not a valid assignment: every problem found.
    #[error("the assignment is invalid: {} problem(s), the first {}", .0.len(), .0.first().map_or(String::new(), |p| p.to_string()))]
    Invalid(Vec<Problem>),
}

const TOP_FIELDS: &[&str] = &["version", "title", "due", "scenes"];
const SCENE_FIELDS: &[&str] = &[
    "name",
    "scene",
    "points",
    "grade",
    "visibility",
    "feedback",
    "tolerances",
    "scoring",
];

/// Parses and validates an assignment document; the scenes are checked against `limits`.
pub fn parse(bytes: &[u8], limits: &Limits) -> Result<Assignment, AssignmentError> {
    let mut de = serde_json::Deserializer::from_slice(bytes);
    let syntax = |e: &serde_json::Error| AssignmentError::Syntax {
        message: crate::json::strip_position(&e.to_string()),
        line: e.line(),
        column: e.column(),
    };
    let (value, duplicates) = match scene::strict_json::deserialize(&mut de) {
        Ok(v) => v,
        Err(e) => {
            let at = Pointer::root().join_path(e.path());
            let inner = e.into_inner();
            if inner.to_string().starts_with("number out of range") {
                return Err(AssignmentError::Invalid(vec![Problem::new(
                    at.to_string(),
                    "the number is out of range: numbers must be finite",
                )]));
            }
            return Err(syntax(&inner));
        }
    };
    de.end().map_err(|e| syntax(&e))?;
    let mut problems = duplicates.into_problems();
    let assignment = check(value, limits, &mut problems);
    match assignment {
        Some(a) if problems.is_empty() => Ok(a),
        _ => Err(AssignmentError::Invalid(problems)),
    }
}

fn unknown_fields(obj: &Map<String, Value>, known: &[&str], at: &Pointer, p: &mut Vec<Problem>) {
    for k in obj.keys().filter(|k| !known.contains(&k.as_str())) {
        p.push(Problem::new(
            at.key(k).to_string(),
            format!("unknown field `{k}`: expected one of {}", known.join(", ")),
        ));
    }
}

fn check(value: Value, limits: &Limits, p: &mut Vec<Problem>) -> Option<Assignment> {
    let root = Pointer::root();
    let Value::Object(mut top) = value else {
        p.push(Problem::new("", "an assignment must be a JSON object"));
        return None;
    };
    unknown_fields(&top, TOP_FIELDS, &root, p);
    match top.get("version") {
        Some(v) if v.as_u64() == Some(VERSION) => {}
        Some(v) => p.push(Problem::new(
            "/version",
            format!("unsupported version {v}: this grader reads version {VERSION}"),
        )),
        None => p.push(Problem::new("/version", "missing field `version`")),
    }
    let title = match top.get("title") {
        Some(Value::String(s)) if !s.trim().is_empty() => Some(s.clone()),
        Some(_) => {
            p.push(Problem::new("/title", "must be a non-empty string"));
            None
        }
        None => {
            p.push(Problem::new("/title", "missing field `title`"));
            None
        }
    };
    let due = match top.get("due") {
        None | Some(Value::Null) => None,
        Some(Value::String(s)) => match parse_rfc3339(s) {
            Some(unix) => Some(Due {
                text: s.clone(),
                unix,
            }),
            None => {
                p.push(Problem::new(
                    "/due",
                    format!("`{s}` is not an RFC 3339 date and time (2026-12-24T23:59:00Z)"),
                ));
                None
            }
        },
        Some(_) => {
            p.push(Problem::new(
                "/due",
                "must be an RFC 3339 date and time as a string",
            ));
            None
        }
    };
    let scenes = match top.remove("scenes") {
        Some(Value::Array(list)) if !list.is_empty() => list,
        Some(Value::Array(_)) => {
            p.push(Problem::new(
                "/scenes",
                "an assignment needs at least one scene",
            ));
            Vec::new()
        }
        Some(_) => {
            p.push(Problem::new("/scenes", "must be an array of scenes"));
            Vec::new()
        }
        None => {
            p.push(Problem::new("/scenes", "missing field `scenes`"));
            Vec::new()
        }
    };
    let mut checked = Vec::new();
    let mut names: Vec<String> = Vec::new();
    let list = root.key("scenes");
    for (i, s) in scenes.into_iter().enumerate() {
        let at = list.index(i);
        if let Some(s) = check_scene(s, &at, limits, p) {
            if names.contains(&s.name) {
                p.push(Problem::new(
                    at.key("name").to_string(),
                    format!("the name `{}` is used by an earlier scene", s.name),
                ));
            }
            names.push(s.name.clone());
            checked.push(s);
        }
    }
    if !p.is_empty() {
        return None;
    }
    Some(Assignment {
        title: title?,
        due,
        scenes: checked,
    })
}

/// Whether `name` can be a file stem everywhere: `[A-Za-z0-9_-]+`, at most 64 long.
pub fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= 64
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
}

fn check_scene(
    value: Value,
    at: &Pointer,
    limits: &Limits,
    p: &mut Vec<Problem>,
) -> Option<AssignedScene> {
    let Value::Object(mut obj) = value else {
        p.push(Problem::new(
            at.to_string(),
            "a scene entry must be an object",
        ));
        return None;
    };
    unknown_fields(&obj, SCENE_FIELDS, at, p);
    let before = p.len();
    let missing = |p: &mut Vec<Problem>, f: &str| {
        p.push(Problem::new(
            at.key(f).to_string(),
            format!("missing field `{f}`"),
        ))
    };
    let name = match obj.get("name") {
        Some(Value::String(s)) if valid_name(s) => Some(s.clone()),
        Some(Value::String(s)) => {
            p.push(Problem::new(
                at.key("name").to_string(),
                format!("`{s}` cannot name a file: use 1 to 64 letters, digits, `_` and `-`"),
            ));
            None
        }
        Some(_) => {
            p.push(Problem::new(at.key("name").to_string(), "must be a string"));
            None
        }
        None => {
            missing(p, "name");
            None
        }
    };
    let points = match obj.get("points").map(|v| v.as_f64()) {
        Some(Some(x)) if x > 0.0 && x.is_finite() => Some(x),
        Some(_) => {
            p.push(Problem::new(
                at.key("points").to_string(),
                "must be a number greater than 0",
            ));
            None
        }
        None => {
            missing(p, "points");
            None
        }
    };
    let graded = match obj.get("grade") {
        Some(Value::String(s)) if Graded::from_name(s).is_some() => Graded::from_name(s),
        Some(v) => {
            p.push(Problem::new(
                at.key("grade").to_string(),
                format!("must be `image`, `hits` or `both`, not {v}"),
            ));
            None
        }
        None => {
            missing(p, "grade");
            None
        }
    };
    let after_due_date = match obj.get("feedback") {
        None => false,
        Some(Value::String(s)) if s == "after_due_date" => true,
        Some(v) => {
            p.push(Problem::new(
                at.key("feedback").to_string(),
                format!("must be `after_due_date`, not {v}"),
            ));
            false
        }
    };
    let visibility = match obj.get("visibility").and_then(Value::as_str) {
        Some("visible") => {
            if obj.contains_key("feedback") {
                p.push(Problem::new(
                    at.key("feedback").to_string(),
                    "only a hidden scene takes `feedback`: a visible one always has full feedback",
                ));
            }
            Some(Visibility::Visible)
        }
        Some("hidden") => Some(Visibility::Hidden { after_due_date }),
        _ if !obj.contains_key("visibility") => {
            missing(p, "visibility");
            None
        }
        _ => {
            p.push(Problem::new(
                at.key("visibility").to_string(),
                "must be `visible` or `hidden`",
            ));
            None
        }
    };
    let tolerances = match obj.remove("tolerances") {
        None => Some(Tolerances::default()),
        Some(v) => typed::<Tolerances>(v, &at.key("tolerances"), p).and_then(|t| match t.check() {
            Ok(()) => Some(t),
            Err(crate::grade::GradeError::BadTolerance { field, message }) => {
                p.push(Problem::new(
                    at.key("tolerances").key(field).to_string(),
                    message,
                ));
                None
            }
            Err(e) => {
                p.push(Problem::new(
                    at.key("tolerances").to_string(),
                    e.to_string(),
                ));
                None
            }
        }),
    };
    let scoring = match obj.remove("scoring") {
        None => Some(Scoring::default()),
        Some(Value::String(s)) => match ScoringMode::from_name(&s) {
            Some(m) => Some(Scoring {
                scoring: m,
                ..Scoring::default()
            }),
            None => {
                p.push(Problem::new(
                    at.key("scoring").to_string(),
                    format!("must be `all-or-nothing`, `linear` or `error`, not `{s}`"),
                ));
                None
            }
        },
        Some(v) => typed::<Scoring>(v, &at.key("scoring"), p),
    };
    if let (Some(t), Some(s)) = (&tolerances, &scoring)
        && let Err(e) = s.check(t)
    {
        let field = match &e {
            crate::grade::GradeError::BadScoring { field, .. } => *field,
            _ => "",
        };
        let mut ptr = at.key("scoring").owned();
        for part in field.split('.').filter(|f| !f.is_empty()) {
            ptr = ptr.key(part).owned();
        }
        p.push(Problem::new(ptr.to_string(), e.to_string()));
    }
    let scene = match obj.remove("scene") {
        None => {
            missing(p, "scene");
            None
        }
        Some(v) => match scene::parse_value(v, limits) {
            Ok(s) => Some(s),
            Err(SceneError::Invalid(list)) => {
                let base = at.key("scene");
                p.extend(
                    list.into_iter()
                        .map(|q| Problem::new(format!("{}{}", base, q.pointer), q.message)),
                );
                None
            }
            Err(e) => {
                p.push(Problem::new(at.key("scene").to_string(), e.to_string()));
                None
            }
        },
    };
    if p.len() > before {
        return None;
    }
    Some(AssignedScene {
        name: name?,
        scene: Arc::new(scene?),
        points: points?,
        graded: graded?,
        visibility: visibility?,
        tolerances: tolerances?,
        scoring: scoring?,
    })
}

/// `v` as a `T`, or a problem at the failing field's pointer.
fn typed<T: serde::de::DeserializeOwned>(
    v: Value,
    at: &Pointer,
    p: &mut Vec<Problem>,
) -> Option<T> {
    match serde_path_to_error::deserialize::<_, T>(v) {
        Ok(t) => Some(t),
        Err(e) => {
            let ptr = at.join_path(e.path());
            p.push(Problem::new(
                ptr.to_string(),
                crate::json::strip_position(&e.into_inner().to_string()),
            ));
            None
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn sphere(width: u32, shape: &str) -> String {
        format!(
            r#"{{"version": 1, "image": {{"width": {width}, "height": 3}}, "camera": {{"focal_length": 1}},
               "objects": [{{"name": "ball", "shape": "{shape}", "transform": [{{"translate": [0, 0, 2]}}]}}],
               "lights": [{{"type": "point", "position": [0, -4, 0], "colour": [1, 0.75, 0.5]}}]}}"#
        )
    }

    #[test]
    fn a_valid_assignment_parses() {
        let doc = format!(
            r#"{{"version": 1, "title": "Ray casting", "due": "2026-12-24T23:59:00Z",
                "scenes": [
                  {{"name": "spheres", "scene": {}, "points": 5, "grade": "image", "visibility": "visible"}},
                  {{"name": "secret", "scene": {}, "points": 5, "grade": "hits", "visibility": "hidden",
                    "feedback": "after_due_date", "tolerances": {{"lambda_rel": 1e-5}}, "scoring": "linear"}}]}}"#,
            sphere(4, "sphere"),
            sphere(5, "sphere")
        );
        let a = parse(doc.as_bytes(), &Limits::NONE).unwrap();
        assert_eq!(a.title, "Ray casting");
        assert_eq!(a.due.as_ref().unwrap().unix, 1_798_156_740);
        assert_eq!(a.scenes.len(), 2);
        assert_eq!(
            a.scenes[1].visibility,
            Visibility::Hidden {
                after_due_date: true
            }
        );
        assert_eq!(a.scenes[1].tolerances.lambda_rel, 1e-5);
        assert_eq!(a.scenes[1].scoring.scoring, ScoringMode::Linear);
        assert_eq!(a.scenes[1].graded, Graded::Hits);
    }

    #[test]
    fn every_problem_is_listed_with_its_pointer() {
        let doc = format!(
            r#"{{"version": 2, "title": "t", "due": "tomorrow", "extra": 1,
                "scenes": [
                  {{"name": "a b", "scene": {}, "points": 0, "grade": "pixels", "visibility": "visible"}},
                  {{"name": "x", "scene": {}, "points": 1, "grade": "hits", "visibility": "hidden",
                    "tolerances": {{"lambda": 1}}, "name": "x"}},
                  {{"name": "x", "scene": {}, "points": 1, "grade": "image", "visibility": "visible",
                    "tolerances": {{"max_fail_share": 2}}}}]}}"#,
            sphere(4, "sphere"),
            sphere(4, "blob"),
            sphere(4, "sphere")
        );
        let Err(AssignmentError::Invalid(p)) = parse(doc.as_bytes(), &Limits::NONE) else {
            panic!("accepted")
        };
        let pointers: Vec<&str> = p.iter().map(|p| p.pointer.as_str()).collect();
        for want in [
            "/scenes/1/name",
            "/version",
            "/due",
            "/extra",
            "/scenes/0/name",
            "/scenes/0/points",
            "/scenes/0/grade",
            "/scenes/1/tolerances/lambda",
            "/scenes/1/scene/objects/0/shape",
            "/scenes/2/tolerances/max_fail_share",
        ] {
            assert!(pointers.contains(&want), "{want} not in {pointers:?}");
        }
        // The duplicated key comes first, as for a scene.
        assert_eq!(p[0].message, "duplicate key `name`");
    }

    #[test]
    fn a_repeated_name_is_refused() {
        let doc = format!(
            r#"{{"version": 1, "title": "t", "scenes": [
                  {{"name": "x", "scene": {0}, "points": 1, "grade": "image", "visibility": "visible"}},
                  {{"name": "x", "scene": {0}, "points": 1, "grade": "image", "visibility": "visible"}}]}}"#,
            sphere(4, "sphere")
        );
        let Err(AssignmentError::Invalid(p)) = parse(doc.as_bytes(), &Limits::NONE) else {
            panic!("accepted")
        };
        assert_eq!(p.len(), 1);
        assert_eq!(p[0].pointer, "/scenes/1/name");
    }

    #[test]
    fn names_are_file_stems() {
        assert!(valid_name("secret_2-b"));
        for bad in ["", "a.b", "a/b", "é", "a b"] {
            assert!(!valid_name(bad), "{bad}");
        }
    }
}
