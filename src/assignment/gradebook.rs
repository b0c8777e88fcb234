//! The gradebook: what an instructor reads of an assignment's recorded submissions.
//! Which submission of a student counts ([`pick`]: the latest or the best), the CSV an
//! LMS imports ([`grades_csv`]), each submission as the listing shows it
//! ([`Attempt::view`]), and the statistics per scene ([`stats`]: pass rate, mean
//! points, the commonest diagnoses). Pure functions over what the store holds, so that
//! the server and the command line share them.

use std::collections::BTreeMap;
use std::collections::btree_map::Entry;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::format_rfc3339_ms;
use super::grade::Status;

/// How many of a scene's diagnoses [`stats`] lists, the commonest first.
pub const TOP_DIAGNOSES: usize = 5;

/// The header row of [`grades_csv`].
pub const CSV_HEADER: [&str; 5] = ["student", "score", "max_score", "submitted", "submissions"];

/// Which of a student's submissions counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Pick {
    /// The last one submitted.
    #[default]
    Latest,
    /// The highest score; of equal scores, the first (when the student earned it).
    Best,
}

impl Pick {
    /// Its name in a query (`?pick=best`).
    pub fn as_str(self) -> &'static str {
        match self {
            Pick::Latest => "latest",
            Pick::Best => "best",
        }
    }
}

/// What picking needs of a recorded submission.
#[derive(Debug, Clone, PartialEq)]
pub struct Scored {
    /// The submission's id.
    pub id: String,
    /// The student.
    pub student: String,
    /// When it was recorded (ms since the Unix epoch).
    pub submitted_ms: i64,
    /// Points earned.
    pub score: f64,
}

/// One student's chosen submission: where it is among the items picked from, and how
/// many the student made.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Choice {
    /// The chosen item's index.
    pub index: usize,
    /// The student's submissions.
    pub submissions: usize,
}

/// Whether `a` counts rather than `b` (the one chosen so far) under `how`. Equal times
/// go to the later item, so that items in recording order end on the last recorded.
fn better(a: &Scored, b: &Scored, how: Pick) -> bool {
    match how {
        Pick::Latest => a.submitted_ms >= b.submitted_ms,
        Pick::Best => a
            .score
            .total_cmp(&b.score)
            .then(b.submitted_ms.cmp(&a.submitted_ms))
            .is_gt(),
    }
}

/// One [`Choice`] per student, sorted by student: the submission `how` picks among
/// `items`, which `scored` reads.
pub fn pick<T>(items: &[T], how: Pick, scored: impl Fn(&T) -> &Scored) -> Vec<Choice> {
    let mut by_student: BTreeMap<&str, Choice> = BTreeMap::new();
    for (index, item) in items.iter().enumerate() {
        let s = scored(item);
        match by_student.entry(s.student.as_str()) {
            Entry::Vacant(e) => {
                e.insert(Choice {
                    index,
                    submissions: 1,
                });
            }
            Entry::Occupied(mut e) => {
                let chosen = e.get_mut();
                chosen.submissions += 1;
                if better(s, scored(&items[chosen.index]), how) {
                    chosen.index = index;
                }
            }
        }
    }
    by_student.into_values().collect()
}

/// One row of the gradebook.
#[derive(Debug, Clone, PartialEq)]
pub struct GradeRow {
    /// The student.
    pub student: String,
    /// Points of the chosen submission.
    pub score: f64,
    /// Points possible in it.
    pub max_score: f64,
    /// When it was recorded (ms since the Unix epoch).
    pub submitted_ms: i64,
    /// How many the student made.
    pub submissions: usize,
}

/// A score as the gradebook writes it: at most four decimals, no trailing zeros.
fn points(x: f64) -> String {
    crate::grade::score::short(x)
}

/// The gradebook as CSV (RFC 4180): [`CSV_HEADER`], then one row per student in the
/// order given, the time in RFC 3339 (UTC).
pub fn grades_csv(rows: &[GradeRow]) -> Result<Vec<u8>, csv::Error> {
    let mut w = csv::Writer::from_writer(Vec::new());
    w.write_record(CSV_HEADER)?;
    for r in rows {
        w.write_record([
            r.student.as_str(),
            &points(r.score),
            &points(r.max_score),
            &format_rfc3339_ms(r.submitted_ms),
            &r.submissions.to_string(),
        ])?;
    }
    w.into_inner().map_err(|e| e.into_error().into())
}

/// One scene of a stored result, as much as the gradebook reads.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneOutcome {
    /// The scene's name.
    pub name: String,
    /// Points earned.
    pub points: f64,
    /// Points for a full score.
    pub max_points: f64,
    /// How it fared.
    pub status: Status,
    /// The catalogue names of the mistakes diagnosed (only where the feedback was shown).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub diagnosis: Vec<String>,
}

/// What the gradebook reads of a stored result (our JSON report).
#[derive(Debug, Deserialize)]
struct Outcome {
    max_score: f64,
    scenes: Vec<SceneOutcome>,
}

/// A recorded submission with its result read.
#[derive(Debug, Clone, PartialEq)]
pub struct Attempt {
    /// Who, when, what score.
    pub scored: Scored,
    /// The assignment's revision it was graded against.
    pub revision: i64,
    /// Points possible.
    pub max_score: f64,
    /// Each scene's outcome.
    pub scenes: Vec<SceneOutcome>,
    /// The stored result, whole.
    pub result: Value,
}

/// The `max_score` of a stored result (JSON), without reading the rest into memory.
pub fn max_score_of(result: &str) -> Result<f64, serde_json::Error> {
    #[derive(Deserialize)]
    struct Max {
        max_score: f64,
    }
    Ok(serde_json::from_str::<Max>(result)?.max_score)
}

impl Attempt {
    /// Reads `result`, the stored JSON report of the submission `scored` describes.
    pub fn read(scored: Scored, revision: i64, result: &str) -> Result<Attempt, serde_json::Error> {
        let value: Value = serde_json::from_str(result)?;
        let outcome = Outcome::deserialize(&value)?;
        Ok(Attempt {
            scored,
            revision,
            max_score: outcome.max_score,
            scenes: outcome.scenes,
            result: value,
        })
    }

    /// The submission as `GET /v1/assignments/{id}/submissions` lists it.
    pub fn view(&self) -> SubmissionView<'_> {
        SubmissionView {
            id: &self.scored.id,
            student: &self.scored.student,
            submitted: format_rfc3339_ms(self.scored.submitted_ms),
            revision: self.revision,
            score: self.scored.score,
            max_score: self.max_score,
            scenes: &self.scenes,
            result: &self.result,
        }
    }

    /// Its gradebook row, for a student who made `submissions`.
    pub fn row(&self, submissions: usize) -> GradeRow {
        GradeRow {
            student: self.scored.student.clone(),
            score: self.scored.score,
            max_score: self.max_score,
            submitted_ms: self.scored.submitted_ms,
            submissions,
        }
    }
}

/// A submission as listed.
#[derive(Debug, Serialize)]
pub struct SubmissionView<'a> {
    /// Its id.
    pub id: &'a str,
    /// The student.
    pub student: &'a str,
    /// When it was recorded, RFC 3339 in UTC.
    pub submitted: String,
    /// The revision graded against.
    pub revision: i64,
    /// Points earned.
    pub score: f64,
    /// Points possible.
    pub max_score: f64,
    /// Each scene's outcome.
    pub scenes: &'a [SceneOutcome],
    /// The stored result (our JSON report), whole.
    pub result: &'a Value,
}

/// How many of a scene's submissions fared each way.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct StatusCounts {
    /// Every part passes.
    pub passed: usize,
    /// Graded, some part fails.
    pub failed: usize,
    /// Not submitted.
    pub missing: usize,
    /// Not gradable.
    pub ungradable: usize,
}

impl StatusCounts {
    fn count(&mut self, s: Status) {
        match s {
            Status::Passed => self.passed += 1,
            Status::Failed => self.failed += 1,
            Status::Missing => self.missing += 1,
            Status::Ungradable => self.ungradable += 1,
        }
    }
}

/// A diagnosis and in how many submissions of the scene it was made.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct DiagnosisCount {
    /// Its catalogue name.
    pub name: String,
    /// The submissions it was made in.
    pub count: usize,
}

/// One scene's statistics.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SceneStats {
    /// The scene's name.
    pub name: String,
    /// Its points: the assignment's now, else those of its newest submission.
    pub max_points: Option<f64>,
    /// Submissions that were graded for it.
    pub submissions: usize,
    /// How they fared.
    pub statuses: StatusCounts,
    /// The share that passed (`null` without submissions).
    pub pass_rate: Option<f64>,
    /// The mean points earned (`null` without submissions).
    pub mean_points: Option<f64>,
    /// The commonest diagnoses (at most [`TOP_DIAGNOSES`]), the commonest first.
    pub diagnoses: Vec<DiagnosisCount>,
}

/// The statistics of a set of submissions.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Stats {
    /// How many submissions.
    pub submissions: usize,
    /// From how many students.
    pub students: usize,
    /// Their mean score (`null` without submissions).
    pub mean_score: Option<f64>,
    /// Per scene: the assignment's scenes in its order, then any that only older
    /// revisions had, in the order they were first met.
    pub scenes: Vec<SceneStats>,
}

/// What a scene's statistics add up while the submissions are read.
#[derive(Default)]
struct Tally {
    max_points: Option<f64>,
    submissions: usize,
    statuses: StatusCounts,
    points: f64,
    diagnoses: BTreeMap<String, usize>,
}

fn mean(sum: f64, n: usize) -> Option<f64> {
    (n > 0).then(|| sum / n as f64)
}

/// The statistics of `attempts`, per scene: `scenes` are the assignment's (name and
/// points), in its order.
pub fn stats<'a>(
    scenes: &[(String, f64)],
    attempts: impl IntoIterator<Item = &'a Attempt>,
) -> Stats {
    let mut order: Vec<String> = scenes.iter().map(|(n, _)| n.clone()).collect();
    let mut tallies: BTreeMap<String, Tally> = scenes
        .iter()
        .map(|(n, p)| {
            let t = Tally {
                max_points: Some(*p),
                ..Tally::default()
            };
            (n.clone(), t)
        })
        .collect();
    let (mut submissions, mut total) = (0, 0.0);
    let mut students = std::collections::BTreeSet::new();
    for a in attempts {
        submissions += 1;
        total += a.scored.score;
        students.insert(a.scored.student.as_str());
        for s in &a.scenes {
            let t = match tallies.entry(s.name.clone()) {
                Entry::Occupied(e) => e.into_mut(),
                Entry::Vacant(e) => {
                    order.push(s.name.clone());
                    e.insert(Tally::default())
                }
            };
            // Of a scene the assignment no longer has, the newest points seen.
            if !scenes.iter().any(|(n, _)| *n == s.name) {
                t.max_points = Some(s.max_points);
            }
            t.submissions += 1;
            t.statuses.count(s.status);
            t.points += s.points;
            let mut named: Vec<&String> = s.diagnosis.iter().collect();
            named.sort();
            named.dedup();
            for d in named {
                *t.diagnoses.entry(d.clone()).or_default() += 1;
            }
        }
    }
    let scenes = order
        .into_iter()
        .filter_map(|name| {
            let t = tallies.remove(&name)?;
            let mut diagnoses: Vec<DiagnosisCount> = t
                .diagnoses
                .into_iter()
                .map(|(name, count)| DiagnosisCount { name, count })
                .collect();
            // Stable: of equal counts the names stay in alphabetical order.
            diagnoses.sort_by_key(|d| std::cmp::Reverse(d.count));
            diagnoses.truncate(TOP_DIAGNOSES);
            Some(SceneStats {
                name,
                max_points: t.max_points,
                submissions: t.submissions,
                pass_rate: mean(t.statuses.passed as f64, t.submissions),
                mean_points: mean(t.points, t.submissions),
                statuses: t.statuses,
                diagnoses,
            })
        })
        .collect();
    Stats {
        submissions,
        students: students.len(),
        mean_score: mean(total, submissions),
        scenes,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn scored(id: &str, student: &str, ms: i64, score: f64) -> Scored {
        Scored {
            id: id.into(),
            student: student.into(),
            submitted_ms: ms,
            score,
        }
    }

    /// A stored result of two scenes, as `report::json` writes one.
    fn result(spheres: (f64, &str, &[&str]), secret: (f64, &str)) -> String {
        json!({
            "title": "Ray casting", "due": null,
            "score": spheres.0 + secret.0, "max_score": 10.0,
            "scenes": [
                {"name": "spheres", "points": spheres.0, "max_points": 5.0,
                 "status": spheres.1, "visibility": "visible", "feedback": true,
                 "message": "…", "diagnosis": spheres.2, "parts": []},
                {"name": "secret", "points": secret.0, "max_points": 5.0,
                 "status": secret.1, "visibility": "hidden", "feedback": false,
                 "message": "…", "parts": []},
            ],
        })
        .to_string()
    }

    fn attempt(
        id: &str,
        student: &str,
        ms: i64,
        sph: (f64, &str, &[&str]),
        sec: (f64, &str),
    ) -> Attempt {
        Attempt::read(scored(id, student, ms, sph.0 + sec.0), 1, &result(sph, sec)).unwrap()
    }

    #[test]
    fn latest_and_best_pick_one_submission_per_student_sorted_by_student() {
        let items = vec![
            scored("a", "zoe", 100, 4.0),
            scored("b", "amy", 200, 9.0),
            scored("c", "zoe", 300, 8.0),
            scored("d", "amy", 400, 3.0),
            scored("e", "zoe", 500, 8.0),
            scored("f", "bob", 50, 1.0),
        ];
        let picked = |how| -> Vec<(&str, usize)> {
            pick(&items, how, |s| s)
                .iter()
                .map(|c| (items[c.index].id.as_str(), c.submissions))
                .collect()
        };
        assert_eq!(picked(Pick::Latest), [("d", 2), ("f", 1), ("e", 3)]);
        // Zoe's two 8s: the first one counts, when she earned it.
        assert_eq!(picked(Pick::Best), [("b", 2), ("f", 1), ("c", 3)]);
        assert!(pick(&items[..0], Pick::Best, |s| s).is_empty());
    }

    #[test]
    fn the_order_of_the_items_does_not_change_the_choice() {
        let items = vec![
            scored("late", "s", 900, 2.0),
            scored("early-best", "s", 100, 7.0),
            scored("later-equal", "s", 500, 7.0),
        ];
        let id = |how| items[pick(&items, how, |s| s)[0].index].id.as_str();
        assert_eq!(id(Pick::Latest), "late");
        assert_eq!(id(Pick::Best), "early-best");
    }

    #[test]
    fn the_gradebook_is_csv_with_quoted_ids_and_utc_times() {
        let rows = [
            GradeRow {
                student: "amy".into(),
                score: 7.5,
                max_score: 10.0,
                submitted_ms: 1_798_156_740_250,
                submissions: 2,
            },
            GradeRow {
                student: "o'neil, \"bo\"".into(),
                score: 10.0 / 3.0,
                max_score: 10.0,
                submitted_ms: 0,
                submissions: 1,
            },
        ];
        let csv = String::from_utf8(grades_csv(&rows).unwrap()).unwrap();
        assert_eq!(
            csv,
            "student,score,max_score,submitted,submissions\n\
             amy,7.5,10,2026-12-24T23:59:00.250Z,2\n\
             \"o'neil, \"\"bo\"\"\",3.3333,10,1970-01-01T00:00:00.000Z,1\n"
        );
        // A reader gets the id back as it was.
        let mut r = csv::Reader::from_reader(csv.as_bytes());
        let second = r.records().nth(1).unwrap().unwrap();
        assert_eq!(&second[0], "o'neil, \"bo\"");
        assert_eq!(
            grades_csv(&[]).unwrap(),
            b"student,score,max_score,submitted,submissions\n"
        );
    }

    #[test]
    fn a_stored_result_is_read_and_listed_with_its_scenes() {
        let a = attempt(
            "s1",
            "amy",
            1_798_156_740_250,
            (5.0, "passed", &[]),
            (2.5, "failed"),
        );
        assert_eq!(a.max_score, 10.0);
        assert_eq!(a.scenes.len(), 2);
        assert_eq!(a.scenes[1].status, Status::Failed);
        let view = serde_json::to_value(a.view()).unwrap();
        assert_eq!(view["submitted"], "2026-12-24T23:59:00.250Z");
        assert_eq!(view["score"], 7.5);
        assert_eq!(view["max_score"], 10.0);
        assert_eq!(
            view["scenes"][1],
            json!({"name": "secret", "points": 2.5, "max_points": 5.0, "status": "failed"})
        );
        assert_eq!(view["result"]["title"], "Ray casting");
        assert_eq!(a.row(3).submissions, 3);
        assert_eq!(
            max_score_of(&result((1.0, "failed", &[]), (0.0, "missing"))).unwrap(),
            10.0
        );
        assert!(Attempt::read(scored("x", "y", 0, 0.0), 1, "{\"score\": 1}").is_err());
        assert!(max_score_of("not json").is_err());
    }

    #[test]
    fn stats_count_statuses_points_and_the_commonest_diagnoses_per_scene() {
        let attempts = [
            attempt("1", "amy", 1, (5.0, "passed", &[]), (0.0, "missing")),
            attempt(
                "2",
                "bob",
                2,
                (
                    1.0,
                    "failed",
                    &[
                        "flipped_vertically",
                        "shadows_missing",
                        "flipped_vertically",
                    ],
                ),
                (5.0, "passed"),
            ),
            attempt(
                "3",
                "bob",
                3,
                (2.0, "failed", &["shadows_missing"]),
                (1.0, "failed"),
            ),
            attempt("4", "cy", 4, (0.0, "ungradable", &[]), (5.0, "passed")),
        ];
        let scenes = [("spheres".to_owned(), 5.0), ("secret".to_owned(), 5.0)];
        let s = stats(&scenes, &attempts);
        assert_eq!((s.submissions, s.students), (4, 3));
        assert_eq!(s.mean_score, Some((5.0 + 6.0 + 3.0 + 5.0) / 4.0));
        let sph = &s.scenes[0];
        assert_eq!(sph.name, "spheres");
        assert_eq!(sph.submissions, 4);
        assert_eq!(
            sph.statuses,
            StatusCounts {
                passed: 1,
                failed: 2,
                missing: 0,
                ungradable: 1
            }
        );
        assert_eq!(sph.pass_rate, Some(0.25));
        assert_eq!(sph.mean_points, Some(2.0));
        // A mistake named twice in one submission counts once for it.
        assert_eq!(
            sph.diagnoses,
            [
                DiagnosisCount {
                    name: "shadows_missing".into(),
                    count: 2
                },
                DiagnosisCount {
                    name: "flipped_vertically".into(),
                    count: 1
                },
            ]
        );
        let sec = &s.scenes[1];
        assert_eq!((sec.statuses.passed, sec.statuses.missing), (2, 1));
        assert_eq!(sec.pass_rate, Some(0.5));
        assert!(sec.diagnoses.is_empty());

        // Only the latest of each student: bob's first no longer counts.
        let latest: Vec<&Attempt> = pick(&attempts, Pick::Latest, |a| &a.scored)
            .iter()
            .map(|c| &attempts[c.index])
            .collect();
        let s = stats(&scenes, latest);
        assert_eq!((s.submissions, s.students), (3, 3));
        assert_eq!(s.scenes[0].diagnoses.len(), 1);
    }

    #[test]
    fn scenes_without_submissions_and_scenes_of_older_revisions_are_listed() {
        let old = attempt("1", "amy", 1, (5.0, "passed", &[]), (5.0, "passed"));
        // The assignment now has `spheres` (8 points) and a new `cubes`, no `secret`.
        let scenes = [("spheres".to_owned(), 8.0), ("cubes".to_owned(), 2.0)];
        let s = stats(&scenes, [&old]);
        let names: Vec<&str> = s.scenes.iter().map(|x| x.name.as_str()).collect();
        assert_eq!(names, ["spheres", "cubes", "secret"]);
        assert_eq!(s.scenes[0].max_points, Some(8.0));
        let cubes = &s.scenes[1];
        assert_eq!(
            (cubes.submissions, cubes.pass_rate, cubes.mean_points),
            (0, None, None)
        );
        assert_eq!(s.scenes[2].max_points, Some(5.0));
        let none = stats(&scenes, []);
        assert_eq!((none.submissions, none.mean_score), (0, None));
        assert_eq!(none.scenes.len(), 2);
    }

    #[test]
    fn more_diagnoses_than_are_listed_keep_the_commonest() {
        let names = ["a", "b", "c", "d", "e", "f", "g"];
        let attempts: Vec<Attempt> = (0..names.len())
            .map(|i| {
                let named: Vec<&str> = names[..=i].to_vec();
                attempt(
                    &i.to_string(),
                    "s",
                    i as i64,
                    (0.0, "failed", &named),
                    (0.0, "missing"),
                )
            })
            .collect();
        let s = stats(&[], &attempts);
        let listed: Vec<(&str, usize)> = s.scenes[0]
            .diagnoses
            .iter()
            .map(|d| (d.name.as_str(), d.count))
            .collect();
        assert_eq!(listed, [("a", 7), ("b", 6), ("c", 5), ("d", 4), ("e", 3)]);
    }
}
