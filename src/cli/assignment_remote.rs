//! `raytile assignment push FILE` and `raytile assignment grades ID`: the instructor's
//! side of a course server. `push` puts an assignment document (`PUT
//! /v1/assignments/{id}`) and prints its new revision alone on standard output; a
//! refused document is printed with every problem at its JSON pointer. `grades` writes
//! the gradebook (`GET /v1/assignments/{id}/grades.csv`) that an LMS imports.
//!
//! Exit codes: 0 done, 1 the server refused (its problem document on standard error),
//! 2 (through `main`) when the server could not be asked at all.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use reqwest::Method;
use reqwest::header::{ACCEPT, CONTENT_TYPE};
use serde::Deserialize;

use super::remote::{Refused, Remote, ServerArgs, runtime, success};
use crate::assignment::gradebook::Pick;

/// How long one request may take: pushing validates every scene of the document.
const REQUEST_TIMEOUT: Duration = Duration::from_secs(120);

/// The most a gradebook may weigh before we stop reading it.
const GRADES_LIMIT_BYTES: usize = 256 << 20;

/// `raytile assignment …`.
#[derive(Debug, clap::Args)]
pub struct AssignmentArgs {
    /// What to do.
    #[command(subcommand)]
    pub command: AssignmentCommand,
}

/// The assignment subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum AssignmentCommand {
    /// Create or replace an assignment on the server; prints its new revision.
    Push(PushArgs),
    /// Download the gradebook: one CSV row per student.
    Grades(GradesArgs),
}

/// `raytile assignment push`.
#[derive(Debug, clap::Args)]
pub struct PushArgs {
    /// The assignment document (JSON).
    pub file: PathBuf,
    /// The assignment's id (default: the file's stem).
    #[arg(long)]
    pub id: Option<String>,
    /// The server and the instructor's token.
    #[command(flatten)]
    pub server: ServerArgs,
}

/// `raytile assignment grades`.
#[derive(Debug, clap::Args)]
pub struct GradesArgs {
    /// The assignment's id.
    pub id: String,
    /// Which of a student's submissions counts: the latest or the best.
    #[arg(long, value_enum, default_value_t = Pick::Latest)]
    pub pick: Pick,
    /// Write the CSV here instead of standard output (missing folders are created).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// The server and the instructor's token.
    #[command(flatten)]
    pub server: ServerArgs,
}

/// Runs an assignment subcommand.
pub fn assignment(args: AssignmentArgs) -> anyhow::Result<ExitCode> {
    let runtime = runtime()?;
    let outcome = runtime.block_on(async {
        match args.command {
            AssignmentCommand::Push(a) => push(a).await,
            AssignmentCommand::Grades(a) => grades(a).await,
        }
    })?;
    match outcome {
        Ok(()) => Ok(ExitCode::SUCCESS),
        Err(refused) => {
            eprintln!("raytile assignment: {refused}");
            Ok(ExitCode::from(1))
        }
    }
}

/// The id a pushed file gets without `--id`: its stem.
fn default_id(file: &Path) -> anyhow::Result<String> {
    file.file_stem()
        .and_then(|s| s.to_str())
        .filter(|s| !s.is_empty())
        .map(str::to_owned)
        .with_context(|| format!("{}: give the assignment's id with --id", file.display()))
}

/// What the server answers to a successful push.
#[derive(Debug, Deserialize)]
struct Pushed {
    revision: i64,
}

async fn push(a: PushArgs) -> anyhow::Result<Result<(), Refused>> {
    let id = match a.id {
        Some(id) => id,
        None => default_id(&a.file)?,
    };
    let document =
        std::fs::read(&a.file).with_context(|| format!("cannot read {}", a.file.display()))?;
    let remote = Remote::new(&a.server, REQUEST_TIMEOUT)?;
    let res = remote
        .request(Method::PUT, remote.url(&["v1", "assignments", &id]))
        .header(CONTENT_TYPE, "application/json")
        .body(document)
        .send()
        .await
        .with_context(|| format!("cannot reach {}", remote.base()))?;
    let res = match success(res).await {
        Ok(res) => res,
        Err(refused) => return Ok(Err(refused)),
    };
    let created = res.status() == reqwest::StatusCode::CREATED;
    let body = res
        .bytes()
        .await
        .with_context(|| format!("the answer of {} was cut off", remote.base()))?;
    let pushed: Pushed = serde_json::from_slice(&body)
        .with_context(|| format!("{} answered the push with no revision", remote.base()))?;
    // The revision alone on standard output, for `$(raytile assignment push …)`.
    let mut out = std::io::stdout().lock();
    writeln!(out, "{}", pushed.revision)?;
    out.flush()?;
    eprintln!(
        "{} assignment {id} at revision {}",
        if created { "created" } else { "replaced" },
        pushed.revision
    );
    Ok(Ok(()))
}

async fn grades(a: GradesArgs) -> anyhow::Result<Result<(), Refused>> {
    let remote = Remote::new(&a.server, REQUEST_TIMEOUT)?;
    let mut url = remote.url(&["v1", "assignments", &a.id, "grades.csv"]);
    url.query_pairs_mut().append_pair("pick", a.pick.as_str());
    let res = remote
        .request(Method::GET, url)
        .header(ACCEPT, "text/csv")
        .send()
        .await
        .with_context(|| format!("cannot reach {}", remote.base()))?;
    let mut res = match success(res).await {
        Ok(res) => res,
        Err(refused) => return Ok(Err(refused)),
    };
    let mut csv = Vec::new();
    let cut = || format!("the gradebook from {} was cut off", remote.base());
    while let Some(chunk) = res.chunk().await.with_context(cut)? {
        if csv.len() + chunk.len() > GRADES_LIMIT_BYTES {
            anyhow::bail!("the gradebook is larger than {GRADES_LIMIT_BYTES} bytes");
        }
        csv.extend_from_slice(&chunk);
    }
    // Rows as a CSV reader finds them, not lines: a quoted id may hold a line break.
    let students = csv::Reader::from_reader(csv.as_slice())
        .records()
        .filter(Result::is_ok)
        .count();
    match &a.output {
        Some(p) => {
            if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir)
                    .with_context(|| format!("cannot create the folder {}", dir.display()))?;
            }
            std::fs::write(p, &csv).with_context(|| format!("cannot write {}", p.display()))?;
            eprintln!(
                "wrote the grades of {students} student(s) to {}",
                p.display()
            );
        }
        None => {
            let mut out = std::io::stdout().lock();
            out.write_all(&csv)?;
            out.flush()?;
        }
    }
    Ok(Ok(()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pushed_file_is_named_by_its_stem() {
        assert_eq!(
            default_id(Path::new("course/ray-casting.json")).unwrap(),
            "ray-casting"
        );
        assert!(default_id(Path::new("/")).is_err());
    }
}
