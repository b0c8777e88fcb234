//! `raytile grade-assignment FILE DIR`: grades a whole assignment offline, each file of
//! `DIR` for the scene its stem names (`spheres.png`, `secret.npy`), with the combined
//! report of [`crate::assignment::report`].
//!
//! Exits 0 at full marks, 1 when some scene falls short (failed, missing, ungradable),
//! and 2 (through `main`) with the problems listed when the assignment itself is invalid.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;

use crate::assignment::grade::{SubmittedFile, grade_submission};
use crate::assignment::{self, AssignmentError, report};
use crate::grade::answer::ReportForm;
use crate::grade::{GradeOptions, Hint};
use crate::scene::Limits;

/// `raytile grade-assignment`.
#[derive(Debug, clap::Args)]
pub struct GradeAssignmentArgs {
    /// The assignment document (JSON).
    assignment: PathBuf,
    /// The folder of submitted files, each named by its scene (`NAME.png`, `NAME.npy`).
    dir: PathBuf,
    /// The report's form.
    #[arg(long, value_enum, default_value_t = ReportForm::Json)]
    report: ReportForm,
    /// Write the report here instead of standard output (missing folders are created).
    #[arg(short, long)]
    output: Option<PathBuf>,
    /// Rayon worker threads (default: one per core).
    #[arg(long, env = "RAYTILE_THREADS")]
    threads: Option<usize>,
}

/// The files of `dir`, each for the scene its stem names (sorted, for a stable order);
/// one that cannot be read is kept, empty, so that its scene is ungradable.
fn read_dir(dir: &std::path::Path) -> anyhow::Result<Vec<SubmittedFile>> {
    let mut files = Vec::new();
    let entries = std::fs::read_dir(dir)
        .with_context(|| format!("cannot read the folder {}", dir.display()))?;
    for entry in entries {
        let entry = entry.with_context(|| format!("cannot read the folder {}", dir.display()))?;
        let path = entry.path();
        if path.is_dir() {
            continue;
        }
        let file_name = entry.file_name().to_string_lossy().into_owned();
        let scene = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let bytes = std::fs::read(&path).unwrap_or_default();
        files.push(SubmittedFile {
            scene,
            file_name,
            bytes,
            hint: Hint::from_path(&path),
        });
    }
    files.sort_by(|a, b| a.file_name.cmp(&b.file_name));
    Ok(files)
}

/// `raytile grade-assignment`.
pub fn grade_assignment(a: GradeAssignmentArgs) -> anyhow::Result<ExitCode> {
    let bytes = std::fs::read(&a.assignment)
        .with_context(|| format!("cannot read {}", a.assignment.display()))?;
    let doc = assignment::parse(&bytes, &Limits::NONE).map_err(|e| match e {
        AssignmentError::Invalid(problems) => {
            let list: Vec<String> = problems.iter().map(|p| format!("  {p}")).collect();
            anyhow::anyhow!(
                "{}: the assignment is invalid:\n{}",
                a.assignment.display(),
                list.join("\n")
            )
        }
        other => anyhow::anyhow!("{}: {other}", a.assignment.display()),
    })?;
    let files = read_dir(&a.dir)?;
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs() as i64);
    let pool = {
        let mut b = rayon::ThreadPoolBuilder::new();
        if let Some(n) = a.threads {
            b = b.num_threads(n.max(1));
        }
        b.build().context("cannot start the worker threads")?
    };
    let result = pool.install(|| grade_submission(&doc, files, now, &GradeOptions::default()));
    let out = report::write(&result, a.report);
    match &a.output {
        Some(p) => {
            if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir)
                    .with_context(|| format!("cannot create the folder {}", dir.display()))?;
            }
            std::fs::write(p, &out).with_context(|| format!("cannot write {}", p.display()))?;
        }
        None => std::io::stdout().write_all(&out)?,
    }
    Ok(if result.full_marks() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}
