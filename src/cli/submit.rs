//! `raytile submit`: what a grader's container (Gradescope's `run_autograder`, a
//! PrairieLearn grader script) runs to grade a student's files on the grading service
//! and write the platform's results file.
//!
//! The files are posted to `POST /v1/assignments/{id}/submissions` as one multipart
//! submission, each part named by its scene (the file's stem, or `NAME=FILE`). The
//! service may be busy (503) or the student may be submitting too fast (429): those,
//! its own faults (5xx) and failed connections are retried, after `Retry-After` when it
//! says, until `--deadline`; every try carries the same random `Idempotency-Key`, so a
//! submission whose answer was lost is recorded once and its stored result returned.
//!
//! A results file is written whatever happens: the service's report when it graded the
//! submission, else [`report::not_graded`] saying why, so that the student sees a
//! message, never a grader crash. Exit status: 0 when the service graded and recorded
//! the submission (the score is in the results file), 1 when it did not (the results
//! file says why), 2 when nothing could be written (bad arguments, an unwritable
//! output).

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use clap::ValueEnum;
use reqwest::StatusCode;
use reqwest::header::RETRY_AFTER;

use super::distributed::{Failure, is_retryable, parse_retry_after, transport};
use super::remote::{self, Remote, ServerArgs};
use crate::assignment::report::{self, NotGraded};
use crate::assignment::valid_name;
use crate::grade::answer::ReportForm;

/// `raytile submit`.
#[derive(Debug, clap::Args)]
pub struct SubmitArgs {
    /// The grading service and the token.
    #[command(flatten)]
    pub remote: ServerArgs,
    /// The assignment's id.
    #[arg(long)]
    pub assignment: String,
    /// The student, as the learning platform names them (an opaque id).
    #[arg(long)]
    pub student: String,
    /// The results file's form.
    #[arg(long, value_enum, default_value_t = ReportForm::Json)]
    pub report: ReportForm,
    /// Write the results here instead of standard output (missing folders are created).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Give up retrying after this many seconds, and write a results file saying the
    /// service could not be reached. Keep it below the platform's own time limit.
    #[arg(long, default_value = "600", value_parser = crate::config::parse_seconds)]
    pub deadline: f64,
    /// The files: `spheres.png` is for the scene `spheres` (its stem), `NAME=FILE` names
    /// the scene, and a folder stands for the files in it.
    #[arg(required = true, value_name = "FILES-or-DIR")]
    pub files: Vec<String>,
}

/// One file to send: the scene it is for, its name (the form hint) and its bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Upload {
    /// The scene's name: the multipart part's name.
    pub scene: String,
    /// The file's name as sent (the service reads its form from the extension).
    pub file_name: String,
    /// Its content.
    pub bytes: Vec<u8>,
}

/// A `NAME=FILE` argument: the name when it is a scene name and no file is called the
/// whole argument.
fn named(arg: &str) -> Option<(&str, &str)> {
    let (name, file) = arg.split_once('=')?;
    (valid_name(name) && !file.is_empty() && !Path::new(arg).exists()).then_some((name, file))
}

/// The file's name and the stem that names its scene.
fn name_and_stem(path: &Path) -> (String, String) {
    let file_name = path
        .file_name()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    (file_name, stem)
}

/// Reads one file for `scene`. A file that is not there is left out with a warning
/// (its scene is then missing, and the report says so); one that is there but cannot
/// be read is sent empty, so that its scene is ungradable, as `grade-assignment` does.
fn read_upload(scene: String, path: &Path, out: &mut Vec<Upload>) {
    let (file_name, _) = name_and_stem(path);
    match std::fs::read(path) {
        Ok(bytes) => out.push(Upload {
            scene,
            file_name,
            bytes,
        }),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            eprintln!(
                "raytile submit: {} is not there; the scene `{scene}` is sent without it",
                path.display()
            );
        }
        Err(e) => {
            eprintln!(
                "raytile submit: cannot read {} ({e}); it is sent empty",
                path.display()
            );
            out.push(Upload {
                scene,
                file_name,
                bytes: Vec::new(),
            });
        }
    }
}

/// The uploads the arguments name, in order (a folder's files sorted by name; its
/// subfolders and hidden files skipped).
pub fn collect(args: &[String]) -> anyhow::Result<Vec<Upload>> {
    let mut out = Vec::new();
    for arg in args {
        if let Some((name, file)) = named(arg) {
            read_upload(name.to_owned(), Path::new(file), &mut out);
            continue;
        }
        let path = Path::new(arg);
        if path.is_dir() {
            let mut files: Vec<PathBuf> = std::fs::read_dir(path)
                .with_context(|| format!("cannot read the folder {}", path.display()))?
                .filter_map(Result::ok)
                .map(|e| e.path())
                .filter(|p| !p.is_dir())
                .filter(|p| !name_and_stem(p).0.starts_with('.'))
                .collect();
            files.sort();
            for f in files {
                let (_, stem) = name_and_stem(&f);
                read_upload(stem, &f, &mut out);
            }
        } else {
            let (_, stem) = name_and_stem(path);
            if stem.is_empty() {
                bail!("`{arg}` names no file");
            }
            read_upload(stem, path, &mut out);
        }
    }
    Ok(out)
}

/// How failed tries are spaced: `Retry-After` when the service sends it, else a backoff
/// from a quarter second doubling to ten; either stretched by up to half again at
/// random, so that clients turned away together do not all come back together.
fn pause(tries: u32, retry_after: Option<Duration>) -> Duration {
    let base = retry_after.unwrap_or_else(|| {
        Duration::from_millis(250)
            .saturating_mul(1 << tries.saturating_sub(1).min(6))
            .min(Duration::from_secs(10))
    });
    let mut b = [0u8; 2];
    let spread = if getrandom::fill(&mut b).is_ok() {
        f64::from(u16::from_le_bytes(b)) / f64::from(u16::MAX) / 2.0
    } else {
        0.25
    };
    base.mul_f64(1.0 + spread)
}

/// How a request ended, after its retries.
#[derive(Debug)]
pub enum Answer {
    /// A status that no retry changes (2xx, or a 4xx other than 408 and 429), with its
    /// body.
    Final {
        /// The status.
        status: StatusCode,
        /// The body.
        body: Vec<u8>,
    },
    /// Every try failed in a way another might not, until the deadline: the last
    /// failure, on one line.
    GaveUp(String),
}

/// Sends the request `build` makes until it gets an answer no retry changes, or the
/// deadline passes. `build` is called for every try (a multipart body is used up).
pub async fn send_retrying(
    build: impl Fn() -> reqwest::RequestBuilder,
    deadline: Instant,
) -> Answer {
    let mut tries = 0u32;
    loop {
        tries += 1;
        let remaining = deadline.saturating_duration_since(Instant::now());
        let (failure, retry_after) = match build().timeout(remaining).send().await {
            Ok(res) if !is_retryable(res.status().as_u16()) => {
                let status = res.status();
                match res.bytes().await {
                    Ok(body) => {
                        return Answer::Final {
                            status,
                            body: body.to_vec(),
                        };
                    }
                    // An answer cut off may still be of a recorded submission: the
                    // retry, under the same key, gets its stored result.
                    Err(e) => (transport(e).to_string(), None),
                }
            }
            Ok(res) => {
                let status = res.status();
                let retry_after = res
                    .headers()
                    .get(RETRY_AFTER)
                    .and_then(|v| v.to_str().ok())
                    .and_then(parse_retry_after);
                let body = res.bytes().await.unwrap_or_default();
                (refusal(status, &body), retry_after)
            }
            Err(e) => (transport(e).to_string(), None),
        };
        let wait = pause(tries, retry_after);
        if Instant::now() + wait >= deadline {
            return Answer::GaveUp(if tries == 1 {
                failure
            } else {
                format!("{failure}; {tries} tries")
            });
        }
        tokio::time::sleep(wait).await;
    }
}

/// An answer no retry changes, readably: its status and the problem document's text.
pub(super) fn refusal(status: StatusCode, body: &[u8]) -> String {
    Failure::Status {
        status: status.as_u16(),
        retry_after: None,
        detail: remote::describe_problem(body),
    }
    .to_string()
}

/// A new idempotency key: 128 random bits in hex.
fn idempotency_key() -> anyhow::Result<String> {
    let mut b = [0u8; 16];
    getrandom::fill(&mut b).map_err(|e| anyhow::anyhow!("no randomness: {e}"))?;
    Ok(hex::encode(b))
}

/// Whether a 2xx body is a report in `form` (JSON forms must be a JSON object).
fn is_report(body: &[u8], form: ReportForm) -> bool {
    match form {
        ReportForm::Text => std::str::from_utf8(body).is_ok(),
        _ => serde_json::from_slice::<serde_json::Value>(body).is_ok_and(|v| v.is_object()),
    }
}

/// Writes `bytes` to `path` (through a temporary file beside it, so that a grader
/// stopped halfway leaves no half a results file), or to standard output.
pub(super) fn write_output(path: Option<&Path>, bytes: &[u8]) -> anyhow::Result<()> {
    use std::io::Write;
    let Some(path) = path else {
        let mut out = std::io::stdout().lock();
        out.write_all(bytes)?;
        return Ok(out.flush()?);
    };
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create the folder {}", dir.display()))?;
    }
    let mut part = path.as_os_str().to_owned();
    part.push(".part");
    let part = PathBuf::from(part);
    std::fs::write(&part, bytes).with_context(|| format!("cannot write {}", part.display()))?;
    std::fs::rename(&part, path).with_context(|| format!("cannot write {}", path.display()))
}

/// `raytile submit`.
pub fn submit(a: SubmitArgs) -> anyhow::Result<ExitCode> {
    let deadline = Instant::now() + Duration::from_secs_f64(a.deadline);
    let remote = Remote::new(&a.remote, Duration::from_secs_f64(a.deadline))?;
    let uploads = collect(&a.files)?;
    let key = idempotency_key()?;
    let mut url = remote.url(&["v1", "assignments", &a.assignment, "submissions"]);
    let form_name = a
        .report
        .to_possible_value()
        .map(|v| v.get_name().to_owned())
        .unwrap_or_else(|| "json".to_owned());
    url.query_pairs_mut().append_pair("report", &form_name);
    let answer = remote::runtime()?.block_on(send_retrying(
        || {
            let mut form = reqwest::multipart::Form::new().text("student", a.student.clone());
            for u in &uploads {
                let part =
                    reqwest::multipart::Part::bytes(u.bytes.clone()).file_name(u.file_name.clone());
                form = form.part(u.scene.clone(), part);
            }
            remote
                .request(reqwest::Method::POST, url.clone())
                .header("idempotency-key", &key)
                .multipart(form)
        },
        deadline,
    ));
    let (results, graded) = match answer {
        Answer::Final { status, body } if status.is_success() && is_report(&body, a.report) => {
            (body, true)
        }
        Answer::Final { status, .. } if status.is_success() => {
            let detail =
                format!("the service answered {status} with something that is not a report");
            (
                report::not_graded(NotGraded::Unreachable(&detail), a.report),
                false,
            )
        }
        Answer::Final { status, body } => {
            let detail = refusal(status, &body);
            (
                report::not_graded(NotGraded::Refused(&detail), a.report),
                false,
            )
        }
        Answer::GaveUp(detail) => (
            report::not_graded(NotGraded::Unreachable(&detail), a.report),
            false,
        ),
    };
    write_output(a.output.as_deref(), &results)?;
    if graded {
        Ok(ExitCode::SUCCESS)
    } else {
        eprintln!(
            "raytile submit: not graded; the results file says why: {}",
            String::from_utf8_lossy(&results)
                .lines()
                .next()
                .unwrap_or("")
        );
        Ok(ExitCode::from(1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stems(u: &[Upload]) -> Vec<(&str, &str)> {
        u.iter()
            .map(|u| (u.scene.as_str(), u.file_name.as_str()))
            .collect()
    }

    #[test]
    fn stems_name_scenes_and_name_equals_file_overrides() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::write(d.join("spheres.png"), b"png").unwrap();
        std::fs::write(d.join("secret.npy"), b"npy").unwrap();
        std::fs::write(d.join(".hidden"), b"x").unwrap();
        std::fs::create_dir(d.join("sub")).unwrap();
        std::fs::write(d.join("sub/inner.png"), b"x").unwrap();
        let other = d.join("sub/render-1.png");
        std::fs::write(&other, b"mine").unwrap();
        // A file whose name holds `=` is a file, not NAME=FILE.
        let odd = d.join("sub/a=b.png");
        std::fs::write(&odd, b"odd").unwrap();

        let args = vec![
            d.to_str().unwrap().to_owned(),
            format!("walls={}", other.display()),
            odd.to_str().unwrap().to_owned(),
        ];
        let u = collect(&args).unwrap();
        assert_eq!(
            stems(&u),
            vec![
                ("secret", "secret.npy"),
                ("spheres", "spheres.png"),
                ("walls", "render-1.png"),
                ("a=b", "a=b.png"),
            ]
        );
        assert_eq!(u[2].bytes, b"mine");
    }

    #[test]
    fn a_file_that_is_not_there_is_left_out() {
        let dir = tempfile::tempdir().unwrap();
        let gone = dir.path().join("spheres.png");
        let u = collect(&[
            gone.to_str().unwrap().to_owned(),
            format!("walls={}", gone.display()),
        ])
        .unwrap();
        assert!(u.is_empty());
    }

    #[test]
    fn pauses_honour_retry_after_and_back_off_without_it() {
        for tries in 1..10 {
            let p = pause(tries, Some(Duration::from_secs(2)));
            assert!(
                p >= Duration::from_secs(2) && p <= Duration::from_secs(3),
                "{p:?}"
            );
        }
        let first = pause(1, None);
        assert!(first >= Duration::from_millis(250) && first <= Duration::from_millis(375));
        let late = pause(30, None);
        assert!(late >= Duration::from_secs(10) && late <= Duration::from_secs(15));
    }

    #[test]
    fn keys_are_random_and_long() {
        let (a, b) = (idempotency_key().unwrap(), idempotency_key().unwrap());
        assert_eq!(a.len(), 32);
        assert_ne!(a, b);
    }

    #[test]
    fn only_a_report_in_the_asked_form_counts() {
        assert!(is_report(br#"{"score": 1}"#, ReportForm::Gradescope));
        assert!(!is_report(b"<html>proxy</html>", ReportForm::Prairielearn));
        assert!(!is_report(b"[1]", ReportForm::Json));
        assert!(is_report(b"t: 1 of 2 points\n", ReportForm::Text));
    }

    #[test]
    fn results_are_written_whole_into_new_folders() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("results/results.json");
        write_output(Some(&p), b"{}\n").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"{}\n");
        assert!(!dir.path().join("results/results.json.part").exists());
    }
}
