//! `raytile trace` (explain one pixel) and `raytile grade` (grade a submission): thin
//! wrappers over [`crate::grade`] that read files and write the result.
//!
//! `grade` exits 0 when the submission passes, 1 when it fails, and 2 (through `main`)
//! with one line on standard error when it cannot be graded at all. For a submission
//! that cannot be graded, the Gradescope and PrairieLearn reports are still written
//! (score 0, `gradable` false) before it exits 2, so the student sees why.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;

use anyhow::Context;

use super::input::load_scene;
use crate::grade::answer::{
    ExplanationForm, ReportForm, write_explanation, write_report, write_ungradable,
};
use crate::grade::explain::{self, Candidates, ExplainOptions};
use crate::grade::report::{LmsOptions, Visibility};
use crate::grade::{
    self, GradeError, GradeOptions, Hint, Report, ScoringOverrides, Submission, ToleranceOverrides,
    Tolerances,
};
use crate::render::Renderer;

/// Which objects `trace` lists for each ray.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum CandidatesArg {
    /// All objects for scenes of at most 64 objects, else the BVH's candidates.
    Auto,
    /// Every object.
    All,
    /// Only objects whose bounding box the ray enters.
    Bvh,
}

/// `raytile trace`.
#[derive(Debug, clap::Args)]
pub struct TraceArgs {
    /// The scene file (JSON); `-` reads standard input.
    scene: PathBuf,
    /// The pixel to explain: `U,V` (column, row from the top left).
    #[arg(long, value_parser = parse_pixel)]
    pixel: (u32, u32),
    /// Output format.
    #[arg(long, value_enum, default_value_t = ExplanationForm::Text)]
    format: ExplanationForm,
    /// Which objects each ray is shown tested against.
    #[arg(long, value_enum, default_value_t = CandidatesArg::Auto)]
    candidates: CandidatesArg,
    /// Most object tests listed per ray, 0–1024 (the chosen hit's is listed besides).
    #[arg(long, default_value_t = ExplainOptions::default().max_tests,
          value_parser = parse_max_tests)]
    max_tests: usize,
    /// Most triangle misses, and other hits, listed per mesh and ray (the hit that
    /// counts is always listed).
    #[arg(long, default_value_t = ExplainOptions::default().max_triangles)]
    max_triangles: usize,
    /// Most rays (primary, reflected, refracted) broken down.
    #[arg(long, default_value_t = ExplainOptions::default().max_rays)]
    max_rays: usize,
}

/// `raytile grade`.
#[derive(Debug, clap::Args)]
pub struct GradeArgs {
    /// The scene file (JSON) the submission was rendered from.
    scene: PathBuf,
    /// The submission: an image (PNG, PPM, BMP, TGA, JPEG, PFM, OpenEXR: told by its
    /// content), or hit data (.json, .ndjson, .npy, .csv); `-` reads standard input.
    submission: PathBuf,
    /// The format of hit data (default: by its extension, else by its content); an
    /// image's signature decides whatever this says.
    #[arg(long, value_enum)]
    format: Option<Hint>,
    /// The report's form.
    #[arg(long, value_enum, default_value_t = ReportForm::Json)]
    report: ReportForm,
    /// Write the report here instead of standard output (missing folders are created).
    #[arg(short, long)]
    output: Option<PathBuf>,
    /// Also write the difference image (failing pixels magenta) to this PNG (missing
    /// folders are created).
    #[arg(long)]
    diff: Option<PathBuf>,
    /// Put the difference image in the JSON report as `diff_png_base64`.
    #[arg(long)]
    inline_diff: bool,
    /// How many of the worst pixels to list.
    #[arg(long, default_value_t = GradeOptions::default().worst)]
    worst: usize,
    /// Tolerances from a JSON file (fields as in the report's `tolerances`); the
    /// options below override it.
    #[arg(long)]
    tolerances: Option<PathBuf>,
    #[command(flatten)]
    overrides: ToleranceOverrides,
    /// Skip the FLIP metric (it is the slowest part on large images).
    #[arg(long)]
    no_flip: bool,
    #[command(flatten)]
    scoring: ScoringOverrides,
    /// Points for a full score in the Gradescope report.
    #[arg(long, default_value_t = 1.0)]
    max_score: f64,
    /// Gradescope: when students see the results and tests.
    #[arg(long, value_enum, default_value_t = Visibility::Visible)]
    visibility: Visibility,
    /// Gradescope: when students see the autograder's standard output.
    #[arg(long, value_enum, default_value_t = Visibility::Visible)]
    stdout_visibility: Visibility,
    /// Rayon worker threads (default: one per core).
    #[arg(long, env = "RAYTILE_THREADS")]
    threads: Option<usize>,
}

/// Parses `U,V`.
fn parse_pixel(s: &str) -> Result<(u32, u32), String> {
    let (u, v) = s
        .split_once(',')
        .ok_or_else(|| format!("expected U,V (two whole numbers), got `{s}`"))?;
    let n = |t: &str| {
        t.trim()
            .parse::<u32>()
            .map_err(|_| format!("`{t}` is not a whole number ≥ 0"))
    };
    Ok((n(u)?, n(v)?))
}

/// Parses `--max-tests`: a whole number 0–1024, as `/v1/trace` allows.
fn parse_max_tests(s: &str) -> Result<usize, String> {
    match s.trim().parse::<usize>() {
        Ok(n) if n <= 1024 => Ok(n),
        _ => Err(format!("expected a whole number from 0 to 1024, got `{s}`")),
    }
}

fn renderer(scene: &Path) -> anyhow::Result<Renderer> {
    Ok(Renderer::new(Arc::new(load_scene(scene)?)))
}

/// `raytile trace`.
pub fn trace(a: TraceArgs) -> anyhow::Result<ExitCode> {
    let r = renderer(&a.scene)?;
    let (u, v) = a.pixel;
    explain::check_pixel(&r, u, v)?;
    let opts = ExplainOptions {
        candidates: match a.candidates {
            CandidatesArg::Auto => Candidates::Auto,
            CandidatesArg::All => Candidates::All,
            CandidatesArg::Bvh => Candidates::Bvh,
        },
        max_tests: a.max_tests,
        max_triangles: a.max_triangles,
        max_rays: a.max_rays,
    };
    let e = explain::explain(&r, u, v, &opts);
    std::io::stdout().write_all(&write_explanation(&e, a.format)?)?;
    Ok(ExitCode::SUCCESS)
}

fn tolerances(a: &GradeArgs) -> anyhow::Result<Tolerances> {
    let t = match &a.tolerances {
        Some(p) => {
            let bytes = std::fs::read(p).with_context(|| format!("cannot read {}", p.display()))?;
            serde_json::from_slice(&bytes)
                .with_context(|| format!("{}: not a tolerances document", p.display()))?
        }
        None => Tolerances::default(),
    };
    let t = a.overrides.apply(t);
    t.check()?;
    Ok(t)
}

/// Writes `bytes` to `p`, creating its missing folders first (PrairieLearn does not
/// create `/grade/results`).
fn write_file(p: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create the folder {}", dir.display()))?;
    }
    std::fs::write(p, bytes).with_context(|| format!("cannot write {}", p.display()))
}

/// Writes the report's bytes to `-o`, or to standard output.
fn write_output(a: &GradeArgs, bytes: &[u8]) -> anyhow::Result<()> {
    match &a.output {
        Some(p) => write_file(p, bytes),
        None => Ok(std::io::stdout().write_all(bytes)?),
    }
}

/// Why a submission could not be graded, when it is the submission's fault (what the
/// grader formats report as ungradable); other errors pass through.
enum Failure {
    Submission(String),
    Other(anyhow::Error),
}

impl From<anyhow::Error> for Failure {
    fn from(e: anyhow::Error) -> Self {
        Failure::Other(e)
    }
}

fn lms_options(a: &GradeArgs) -> LmsOptions {
    LmsOptions {
        max_score: a.max_score,
        visibility: a.visibility,
        stdout_visibility: a.stdout_visibility,
    }
}

/// `raytile grade`.
pub fn grade(a: GradeArgs) -> anyhow::Result<ExitCode> {
    let tol = tolerances(&a)?;
    let scoring = a.scoring.apply(grade::Scoring::default());
    scoring.check(&tol)?;
    if !(a.max_score.is_finite() && a.max_score >= 0.0) {
        anyhow::bail!(
            "--max-score must be a finite number ≥ 0, not {}",
            a.max_score
        );
    }
    let r = renderer(&a.scene)?;
    let lms = lms_options(&a);
    match graded(&a, &r, &tol, scoring) {
        Ok(rep) => {
            if let Some(p) = &a.diff {
                write_file(p, &write_report(&rep, ReportForm::DiffPng, &lms)?)?;
            }
            write_output(&a, &write_report(&rep, a.report, &lms)?)?;
            Ok(if rep.pass {
                ExitCode::SUCCESS
            } else {
                ExitCode::from(1)
            })
        }
        Err(Failure::Submission(reason)) => {
            if let Some(bytes) = write_ungradable(&reason, a.report, &lms)? {
                write_output(&a, &bytes)?;
            }
            Err(anyhow::anyhow!(reason))
        }
        Err(Failure::Other(e)) => Err(e),
    }
}

/// Reads, parses and grades the submission.
fn graded(
    a: &GradeArgs,
    r: &Renderer,
    tol: &Tolerances,
    scoring: grade::Scoring,
) -> Result<Report, Failure> {
    let what = a.submission.display();
    let bytes = if a.submission == Path::new("-") {
        let mut b = Vec::new();
        std::io::stdin().read_to_end(&mut b).map_err(|e| {
            Failure::Submission(format!(
                "cannot read the submission from standard input: {e}"
            ))
        })?;
        b
    } else {
        std::fs::read(&a.submission)
            .map_err(|e| Failure::Submission(format!("cannot read {what}: {e}")))?
    };
    let blame = |e: GradeError| {
        if e.is_submissions_fault() {
            Failure::Submission(format!("{what}: {e}"))
        } else {
            Failure::Other(anyhow::Error::new(e).context(format!("{what}")))
        }
    };
    let hint = a.format.unwrap_or_else(|| Hint::from_path(&a.submission));
    let submission =
        Submission::parse_for_frame(&bytes, hint, r.scene.width, r.scene.height).map_err(blame)?;
    let opts = GradeOptions {
        worst: a.worst,
        inline_diff: a.inline_diff,
        flip: !a.no_flip,
        scoring,
        ..Default::default()
    };
    let pool = {
        let mut b = rayon::ThreadPoolBuilder::new();
        if let Some(n) = a.threads {
            b = b.num_threads(n.max(1));
        }
        b.build()
            .context("cannot start the worker threads")
            .map_err(Failure::Other)?
    };
    pool.install(|| grade::grade(r, submission, tol, &opts))
        .map_err(blame)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pixels_parse() {
        assert_eq!(parse_pixel("2,3"), Ok((2, 3)));
        assert_eq!(parse_pixel(" 2 , 3 "), Ok((2, 3)));
        assert!(parse_pixel("2").is_err());
        assert!(parse_pixel("-1,2").is_err());
    }
}
