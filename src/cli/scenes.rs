//! `raytile scenes`: fetches an assignment's scene documents from the grading service
//! (`GET /v1/assignments/{id}`, with a grader's token) and writes each as
//! `DIR/NAME.json`, for the student's tracer to render. Busy answers are retried as
//! `raytile submit` retries them ([`super::submit::send_retrying`]).
//!
//! Each scene written is a line on standard output, `NAME<tab>GRADE<tab>PATH` (GRADE
//! is `image`, `hits` or `both`: what the student's tracer must write for it), so that a
//! grader script can loop over them with `while IFS=$'\t' read -r name grade path`.
//!
//! The names come from the service, so each is checked to be a plain file stem before
//! it becomes a path, and each document is checked to be a scene this version reads
//! before it is written: a student's tracer is never handed a broken file.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use serde_json::Value;

use super::remote::{self, Remote, ServerArgs};
use super::submit::{Answer, refusal, send_retrying, write_output};
use crate::assignment::valid_name;
use crate::scene::{self, Limits};

/// `raytile scenes`.
#[derive(Debug, clap::Args)]
pub struct ScenesArgs {
    /// The grading service and the token.
    #[command(flatten)]
    pub remote: ServerArgs,
    /// The assignment's id.
    #[arg(long)]
    pub assignment: String,
    /// The folder to write `NAME.json` into (created if missing).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Give up retrying after this many seconds.
    #[arg(long, default_value = "600", value_parser = crate::config::parse_seconds)]
    pub deadline: f64,
}

/// One scene of an assignment as the service sends it.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneFile {
    /// Its name, a file stem.
    pub name: String,
    /// What is graded: `image`, `hits` or `both`.
    pub grade: String,
    /// The scene document, valid.
    pub scene: Value,
}

/// The scenes of an assignment as the service sends them, each name a file stem, each
/// `grade` one this version knows and each document a valid scene.
pub fn scenes_of(doc: &Value) -> anyhow::Result<Vec<SceneFile>> {
    let Some(list) = doc.get("scenes").and_then(Value::as_array) else {
        bail!("the answer has no `scenes` list");
    };
    let mut out: Vec<SceneFile> = Vec::with_capacity(list.len());
    for (i, s) in list.iter().enumerate() {
        let name = s.get("name").and_then(Value::as_str).unwrap_or_default();
        if !valid_name(name) {
            bail!("scene {i} has no usable name ({name:?})");
        }
        if out.iter().any(|s| s.name == name) {
            bail!("the scene name `{name}` appears twice");
        }
        let grade = s.get("grade").and_then(Value::as_str).unwrap_or_default();
        if !["image", "hits", "both"].contains(&grade) {
            bail!("the scene `{name}` grades {grade:?}, not image, hits or both");
        }
        let Some(scene) = s.get("scene") else {
            bail!("the scene `{name}` has no document");
        };
        let bytes = serde_json::to_vec(scene)?;
        scene::parse(&bytes, &Limits::NONE).map_err(|e| {
            anyhow::anyhow!("the scene `{name}` is not one this raytile reads: {e}")
        })?;
        out.push(SceneFile {
            name: name.to_owned(),
            grade: grade.to_owned(),
            scene: scene.clone(),
        });
    }
    Ok(out)
}

/// `raytile scenes`.
pub fn scenes(a: ScenesArgs) -> anyhow::Result<ExitCode> {
    let deadline = Instant::now() + Duration::from_secs_f64(a.deadline);
    let remote = Remote::new(&a.remote, Duration::from_secs_f64(a.deadline))?;
    let url = remote.url(&["v1", "assignments", &a.assignment]);
    let answer = remote::runtime()?.block_on(send_retrying(
        || remote.request(reqwest::Method::GET, url.clone()),
        deadline,
    ));
    let body = match answer {
        Answer::Final { status, body } if status.is_success() => body,
        Answer::Final { status, body } => bail!("{}: {}", remote.base(), refusal(status, &body)),
        Answer::GaveUp(detail) => bail!("{}: {detail}", remote.base()),
    };
    let doc: Value = serde_json::from_slice(&body)
        .with_context(|| format!("{}: the answer is not JSON", remote.base()))?;
    let list = scenes_of(&doc)?;
    std::fs::create_dir_all(&a.output)
        .with_context(|| format!("cannot create the folder {}", a.output.display()))?;
    for s in &list {
        let path = a.output.join(format!("{}.json", s.name));
        let mut bytes = serde_json::to_vec_pretty(&s.scene)?;
        bytes.push(b'\n');
        write_output(Some(&path), &bytes)?;
        println!("{}\t{}\t{}", s.name, s.grade, path.display());
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::assignment::tests::sphere;

    #[test]
    fn names_must_be_stems_and_documents_scenes() {
        let good: Value = serde_json::from_str(&sphere(4, "sphere")).unwrap();
        let doc = serde_json::json!({"scenes": [
            {"name": "a", "grade": "image", "scene": good},
            {"name": "b-2", "grade": "both", "scene": good}]});
        let list = scenes_of(&doc).unwrap();
        assert_eq!(list.len(), 2);
        assert_eq!(
            (list[1].name.as_str(), list[1].grade.as_str()),
            ("b-2", "both")
        );
        assert_eq!(list[0].scene, good);
        let g = "image";
        for bad in [
            serde_json::json!({"scenes": [{"name": "../etc/x", "grade": g, "scene": good}]}),
            serde_json::json!({"scenes": [{"name": "a", "grade": g, "scene": good},
                                          {"name": "a", "grade": g, "scene": good}]}),
            serde_json::json!({"scenes": [{"name": "a", "grade": g, "scene": {"version": 1}}]}),
            serde_json::json!({"scenes": [{"name": "a", "grade": "colour", "scene": good}]}),
            serde_json::json!({"scenes": [{"name": "a", "grade": g}]}),
            serde_json::json!({"assignments": []}),
        ] {
            assert!(scenes_of(&bad).is_err(), "{bad}");
        }
    }
}
