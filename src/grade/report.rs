//! The grading report and its forms: our JSON ([`Report`]), a readable text
//! ([`to_text`]), Gradescope's `results.json` ([`to_gradescope`]) and PrairieLearn's
//! results ([`to_prairielearn`], kept under its 1 MB limit), and the difference image as
//! a PNG ([`Report::diff_png`]).
//!
//! The verdict: a submission passes when at most `floor(max_fail_share × pixels)` of its
//! pixels fail. The score ([`Score`], in [`super::score`]) follows the instructor's
//! scoring mode; every form carries it with its formula, and in the grader formats the
//! scored tests' points add up to it.

use std::fmt::Write as _;

use base64::Engine as _;
use serde::Serialize;
use serde_json::{Value, json};

use super::compare::{Comparison, HitCounts, LinearCounts, PixelValue, WorstPixel};
use super::image::RgbImage;
use super::metrics::{ErrorStats, FlipStats};
use super::score::{self, Score};
use super::{GradeOptions, Tolerances};

/// PrairieLearn refuses results files of 1 MB or more.
pub const PRAIRIELEARN_MAX_BYTES: usize = 1_000_000;

/// Image statistics.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ImageMetrics {
    /// Absolute error and PSNR.
    #[serde(flatten)]
    pub errors: ErrorStats,
    /// Mean SSIM on luma.
    pub ssim: f64,
    /// FLIP, when computed.
    pub flip: Option<FlipStats>,
}

/// A grading report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Report {
    /// The verdict.
    pub pass: bool,
    /// `"image"` or `"hits"`.
    pub kind: &'static str,
    /// The submission's form: `"png"`, `"json"`, `"ndjson"`, `"npy"` or `"csv"`.
    pub format: &'static str,
    /// The verdict in one sentence.
    pub summary: String,
    /// The score, 0–1, and how it was reached.
    pub score: Score,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Number of pixels.
    pub pixels: u64,
    /// Pixels that fail.
    pub failing_pixels: u64,
    /// `failing_pixels / pixels`.
    pub failing_share: f64,
    /// `floor(max_fail_share × pixels)`: the most that may fail for a pass.
    pub max_failing_pixels: u64,
    /// Pixels that pass only thanks to the edge-forgiving mode.
    pub forgiven_pixels: u64,
    /// The tolerances applied.
    pub tolerances: Tolerances,
    /// Image statistics (images only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub image: Option<ImageMetrics>,
    /// Failing pixels per check (hit data only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hits: Option<HitCounts>,
    /// Linear error statistics (float images only: PFM, OpenEXR).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub linear: Option<LinearCounts>,
    /// What the grader warns of besides the verdict (a JPEG's lossy compression).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
    /// The worst pixels, worst first: failing ones, then those that differ but pass.
    pub worst: Vec<WorstPixel>,
    /// The mistakes that explain a failing submission (`docs/grading.md`, Diagnosis).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub diagnosis: Option<super::diagnose::Diagnosis>,
    /// The difference image as a base64 PNG, when asked for.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub diff_png_base64: Option<String>,
    /// The difference image: failing pixels magenta over the dimmed reference.
    #[serde(skip)]
    pub diff: RgbImage,
}

fn percent(share: f64) -> String {
    let p = share * 100.0;
    if p == 0.0 {
        "0 %".into()
    } else if p >= 0.01 {
        format!("{p:.2} %")
    } else {
        format!("{p:.1e} %")
    }
}

impl Report {
    /// Assembles a report from a comparison.
    pub fn new(
        format: &'static str,
        width: u32,
        height: u32,
        tol: &Tolerances,
        opts: &GradeOptions,
        cmp: Comparison,
        image: Option<ImageMetrics>,
    ) -> Report {
        let pixels = width as u64 * height as u64;
        // The small epsilon keeps `0.001 × 1000` at 1 despite binary rounding.
        let max_failing = (tol.max_fail_share * pixels as f64 + 1e-9).floor() as u64;
        let pass = cmp.failing <= max_failing;
        let share = cmp.failing as f64 / pixels.max(1) as f64;
        let kind = if cmp.hits.is_some() { "hits" } else { "image" };
        let what = match &cmp.hits {
            None if cmp.linear.is_some() => format!(
                "differ from the reference's linear radiance by more than {} + {} × its value in some channel",
                tol.linear_abs, tol.linear_rel
            ),
            None => format!(
                "differ from the reference by more than {}/255 in some channel",
                tol.colour_abs
            ),
            Some(c) => format!(
                "disagree with the reference (hit/miss {}, object {}, λ {}, normal {})",
                c.hit_miss, c.wrong_object, c.lambda, c.normal
            ),
        };
        let summary = format!(
            "{}: {} of {} pixels ({}) {what}; at most {} ({}) may{}.",
            if pass { "PASS" } else { "FAIL" },
            cmp.failing,
            pixels,
            percent(share),
            max_failing,
            percent(tol.max_fail_share),
            if tol.edge_forgiving {
                format!(" ({} more forgiven at edges)", cmp.forgiven)
            } else {
                String::new()
            }
        );
        let score = score::score(
            &opts.scoring,
            tol,
            score::Counts {
                pixels,
                failing: cmp.failing,
                max_failing,
                hits: cmp.hits.as_ref(),
                mean_abs_error: image.as_ref().map(|m| m.errors.mean_abs_error),
            },
        );
        let mut r = Report {
            pass,
            kind,
            format,
            summary,
            score,
            width,
            height,
            pixels,
            failing_pixels: cmp.failing,
            failing_share: share,
            max_failing_pixels: max_failing,
            forgiven_pixels: cmp.forgiven,
            tolerances: tol.clone(),
            image,
            hits: cmp.hits,
            linear: cmp.linear,
            warnings: Vec::new(),
            worst: cmp.worst,
            diagnosis: None,
            diff_png_base64: None,
            diff: cmp.diff,
        };
        if opts.inline_diff {
            r.diff_png_base64 =
                Some(base64::engine::general_purpose::STANDARD.encode(r.diff_png()));
        }
        r
    }

    /// The difference image as PNG bytes.
    pub fn diff_png(&self) -> Vec<u8> {
        self.diff.encode_png()
    }
}

fn num(x: f64) -> String {
    if x.fract() == 0.0 && x.abs() < 1e15 {
        format!("{x:.0}")
    } else {
        format!("{x:?}")
    }
}

fn opt_vec(v: &Option<[f64; 3]>) -> String {
    match v {
        Some(v) => format!("[{}, {}, {}]", num(v[0]), num(v[1]), num(v[2])),
        None => "none".into(),
    }
}

fn value_text(p: &PixelValue) -> String {
    match p {
        PixelValue::Colour { rgb } => format!("rgb({}, {}, {})", rgb[0], rgb[1], rgb[2]),
        PixelValue::Linear { linear } => {
            let c = linear.map(|x| x.map_or("not finite".into(), |x| format!("{x}")));
            format!("linear({}, {}, {})", c[0], c[1], c[2])
        }
        PixelValue::Hit { hit: false, .. } => "miss".into(),
        PixelValue::Hit {
            object,
            lambda,
            normal,
            ..
        } => format!(
            "hit object {}, λ = {}, normal {}",
            object.map_or("?".into(), |o| o.to_string()),
            lambda.map_or("none".into(), num),
            opt_vec(normal)
        ),
    }
}

/// The worst pixels as lines of text.
fn worst_text(r: &Report, limit: usize) -> String {
    let mut o = String::new();
    for w in r.worst.iter().take(limit) {
        let mut detail = Vec::new();
        if let Some(e) = w.colour_error {
            detail.push(format!("off by {e}/255"));
        }
        if let Some(e) = w.linear_error {
            detail.push(format!("linear difference {e:.3e}"));
        }
        if let Some(e) = w.lambda_rel_error {
            detail.push(format!("λ relative error {e:.3e}"));
        }
        if let Some(a) = w.normal_angle_degrees {
            detail.push(format!("normal off by {a:.4}°"));
        }
        let verdict = if w.pass {
            "passes".to_owned()
        } else {
            format!("FAILS {}", w.failures.join(", "))
        };
        let _ = writeln!(
            o,
            "  ({}, {}) {verdict}: reference {}, submitted {}{}",
            w.u,
            w.v,
            value_text(&w.reference),
            value_text(&w.submitted),
            if detail.is_empty() {
                String::new()
            } else {
                format!(" ({})", detail.join(", "))
            }
        );
    }
    o
}

/// The report as readable text: one section after another, each written by its own
/// function, so that a section can be added without touching the others.
pub fn to_text(r: &Report) -> String {
    let mut o = String::new();
    for section in [
        summary_text,
        tolerances_text,
        score_text,
        linear_text,
        image_text,
        hits_text,
        diagnosis_text,
        worst_section_text,
    ] {
        section(r, &mut o);
    }
    o
}

fn summary_text(r: &Report, o: &mut String) {
    let _ = writeln!(o, "{}", r.summary);
    for w in &r.warnings {
        let _ = writeln!(o, "Warning: {w}");
    }
}

fn tolerances_text(r: &Report, o: &mut String) {
    let t = &r.tolerances;
    let _ = writeln!(
        o,
        "Tolerances: colour ±{}/255 per channel, λ relative {}, normal {}°, failing share {}, edge-forgiving {}",
        t.colour_abs,
        num(t.lambda_rel),
        num(t.normal_degrees),
        num(t.max_fail_share),
        if t.edge_forgiving { "on" } else { "off" }
    );
}

/// `Score: 0.5 of 1 (linear: …)`, and for hit data one line per part.
fn score_text(r: &Report, o: &mut String) {
    let s = &r.score;
    let _ = writeln!(o, "Score: {} of 1 ({})", score::short(s.value), s.formula);
    if s.parts.len() > 1 {
        for p in &s.parts {
            let _ = writeln!(
                o,
                "  {} (weight {}): {}",
                p.name,
                score::short(p.weight),
                p.formula
            );
        }
    }
}

fn linear_text(r: &Report, o: &mut String) {
    let Some(l) = &r.linear else { return };
    let t = &r.tolerances;
    let _ = writeln!(
        o,
        "Linear radiance: tolerance {} + {} × the reference per channel; max difference {:.3e}, mean {:.3e}, {} channel(s) not finite",
        num(t.linear_abs),
        num(t.linear_rel),
        l.max_abs_error,
        l.mean_abs_error,
        l.non_finite
    );
}

fn image_text(r: &Report, o: &mut String) {
    let Some(m) = &r.image else { return };
    let _ = writeln!(
        o,
        "Image: max error {}/255, mean {:.4}/255, PSNR {}, SSIM {:.6}",
        m.errors.max_abs_error,
        m.errors.mean_abs_error,
        m.errors
            .psnr_db
            .map_or("∞ (identical)".into(), |p| format!("{p:.2} dB")),
        m.ssim
    );
    if let Some(f) = &m.flip {
        let _ = writeln!(
            o,
            "FLIP: mean {:.5}, median {:.5}, 95th percentile {:.5}, 99th {:.5}, max {:.5}",
            f.mean, f.p50, f.p95, f.p99, f.max
        );
    }
}

fn hits_text(r: &Report, o: &mut String) {
    let Some(c) = &r.hits else { return };
    let _ = writeln!(
        o,
        "Hit data: {} pixel(s) hit/miss wrong, {} wrong object, {} λ out of tolerance, {} normal out of tolerance",
        c.hit_miss, c.wrong_object, c.lambda, c.normal
    );
    if let (Some(l), Some(a)) = (c.max_lambda_rel_error, c.max_normal_angle_degrees) {
        let _ = writeln!(
            o,
            "Where both hit: largest λ relative error {l:.3e}, largest normal angle {a:.4}°"
        );
    }
}

fn diagnosis_text(r: &Report, o: &mut String) {
    o.push_str(&super::diagnose::text(r.diagnosis.as_ref()));
}

fn worst_section_text(r: &Report, o: &mut String) {
    if !r.worst.is_empty() {
        let _ = writeln!(o, "Worst pixels (u, v):");
        o.push_str(&worst_text(r, r.worst.len()));
    }
}

/// When a Gradescope test, or all its results, are shown to students.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Visibility {
    /// Never shown to students.
    #[value(name = "hidden")]
    Hidden,
    /// Shown once the assignment's due date has passed.
    #[value(name = "after_due_date")]
    AfterDueDate,
    /// Shown once the grades are published.
    #[value(name = "after_published")]
    AfterPublished,
    /// Always shown.
    #[default]
    #[value(name = "visible")]
    Visible,
}

impl Visibility {
    /// Gradescope's name for it.
    pub fn name(self) -> &'static str {
        match self {
            Visibility::Hidden => "hidden",
            Visibility::AfterDueDate => "after_due_date",
            Visibility::AfterPublished => "after_published",
            Visibility::Visible => "visible",
        }
    }

    /// The visibility Gradescope names `name`, if any.
    pub fn from_name(name: &str) -> Option<Visibility> {
        [
            Visibility::Hidden,
            Visibility::AfterDueDate,
            Visibility::AfterPublished,
            Visibility::Visible,
        ]
        .into_iter()
        .find(|v| v.name() == name)
    }
}

/// What the grader formats need beyond the report: the points of a full score
/// (Gradescope), and when Gradescope shows the results and the autograder's standard
/// output to students.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmsOptions {
    /// Points for a full score in the Gradescope report (default 1).
    pub max_score: f64,
    /// Gradescope's `visibility` of the results and of each test (default `visible`).
    pub visibility: Visibility,
    /// Gradescope's `stdout_visibility` (default `visible`).
    pub stdout_visibility: Visibility,
}

impl Default for LmsOptions {
    fn default() -> Self {
        LmsOptions {
            max_score: 1.0,
            visibility: Visibility::Visible,
            stdout_visibility: Visibility::Visible,
        }
    }
}

/// A test of a grader format: a scored one carries its share of the marks (the scored
/// tests' shares add up to 1, their points to the score); an informational one none.
struct LmsTest {
    name: String,
    /// `(points, max_points)` as shares of a full score; `None` for information.
    points: Option<(f64, f64)>,
    pass: bool,
    output: String,
}

/// Each check as (name, passes, what it found).
fn checks(r: &Report) -> Vec<(String, bool, String)> {
    let allowed = r.max_failing_pixels;
    match &r.hits {
        None => Vec::new(),
        Some(c) => [
            ("Hit or miss", c.hit_miss),
            ("Object hit", c.wrong_object),
            ("λ within tolerance", c.lambda),
            ("Normal within tolerance", c.normal),
        ]
        .into_iter()
        .map(|(name, n)| {
            (
                name.to_owned(),
                n <= allowed,
                format!("{n} failing pixel(s), at most {allowed} allowed"),
            )
        })
        .collect(),
    }
}

/// The tests of both grader formats: the score's parts, scored, then the checks that
/// carry no marks as information (for hit data scored all or nothing, the four checks;
/// for hit data scored per kind, the verdict).
fn lms_tests(r: &Report, worst_shown: usize) -> Vec<LmsTest> {
    let verdict_output = || {
        format!(
            "{}{}\n{}",
            r.summary,
            super::diagnose::message_suffix(r.diagnosis.as_ref()),
            worst_text_limited(r, worst_shown).trim_end()
        )
    };
    let mut tests: Vec<LmsTest> = r
        .score
        .parts
        .iter()
        .map(|p| {
            let found = match p.check {
                "colour" | "hits" => verdict_output(),
                _ => checks(r)
                    .into_iter()
                    .find(|(name, ..)| name == p.name)
                    .map_or_else(String::new, |(.., found)| found),
            };
            LmsTest {
                name: p.name.to_owned(),
                points: Some((p.points, p.weight)),
                pass: p.score >= 1.0,
                output: format!("{found}\nScore: {}", p.formula),
            }
        })
        .collect();
    let scored_per_kind = r.score.parts.len() > 1;
    if scored_per_kind {
        tests.push(LmsTest {
            name: "Matches the reference".into(),
            points: None,
            pass: r.pass,
            output: verdict_output(),
        });
    } else {
        for (name, pass, output) in checks(r) {
            tests.push(LmsTest {
                name,
                points: None,
                pass,
                output,
            });
        }
    }
    tests
}

fn worst_text_limited(r: &Report, limit: usize) -> String {
    worst_text(r, limit.min(r.worst.len()))
}

/// Text as a Markdown code block, so that Gradescope's `md` format keeps its layout.
pub(crate) fn md_block(text: &str) -> String {
    format!("```text\n{}\n```", text.trim_end())
}

fn status(pass: bool) -> &'static str {
    if pass { "passed" } else { "failed" }
}

/// The top of a Gradescope `results.json`, without tests.
fn gradescope_top(score: f64, output: String, lms: &LmsOptions) -> Value {
    json!({
        "score": score,
        "max_score": lms.max_score,
        "output": output,
        "output_format": "md",
        "test_output_format": "md",
        "test_name_format": "text",
        "visibility": lms.visibility.name(),
        "stdout_visibility": lms.stdout_visibility.name(),
        "tests": [],
    })
}

/// Gradescope's `results.json`: `score` is the report's score × `max_score`, and the
/// tests' scores add up to it (section 1 of the grading guide); outputs are Markdown
/// (`output_format`, `test_output_format` `md`) with the text in code blocks, and the
/// difference image is a last, informational test in `html`, as a `data:` URL.
pub fn to_gradescope(r: &Report, lms: &LmsOptions) -> Value {
    let scale = lms.max_score;
    let mut doc = gradescope_top(r.score.value * scale, md_block(&to_text(r)), lms);
    let mut tests: Vec<Value> = lms_tests(r, r.worst.len())
        .into_iter()
        .map(|t| {
            let mut v = json!({
                "name": t.name,
                "status": status(t.pass),
                "output": md_block(&t.output),
                "visibility": lms.visibility.name(),
            });
            if let Some((points, max)) = t.points {
                v["score"] = json!(points * scale);
                v["max_score"] = json!(max * scale);
            }
            v
        })
        .collect();
    let (image, notes) = fit_diff_image(r, GRADESCOPE_IMAGE_MAX_BYTES, "the image budget");
    let image_html = match image {
        Some((label, url)) => format!("<p>{}</p><img src=\"{url}\" alt=\"{label}\">", label),
        None => String::new(),
    };
    let note_html: String = notes.iter().map(|n| format!("<p>{n}</p>")).collect();
    tests.push(json!({
        "name": "Difference image",
        "status": status(r.pass),
        "output": format!("{image_html}{note_html}"),
        "output_format": "html",
        "visibility": lms.visibility.name(),
    }));
    doc["tests"] = Value::Array(tests);
    doc
}

/// Gradescope's `results.json` for a submission that cannot be graded: score 0 and
/// the reason, in the output and in a single failed test that carries the marks.
pub fn gradescope_ungradable(reason: &str, lms: &LmsOptions) -> Value {
    let text = format!("The submission could not be graded: {reason}");
    let mut doc = gradescope_top(0.0, md_block(&text), lms);
    doc["tests"] = json!([{
        "name": "The submission can be graded",
        "score": 0.0,
        "max_score": lms.max_score,
        "status": "failed",
        "output": md_block(&text),
        "visibility": lms.visibility.name(),
    }]);
    doc
}

/// PrairieLearn's results for a submission that cannot be graded: `gradable` false and
/// the reason in `format_errors`, so the student loses no attempt and sees why.
pub fn prairielearn_ungradable(reason: &str) -> Value {
    json!({
        "gradable": false,
        "format_errors": [reason],
        "message": format!("The submission could not be graded: {reason}"),
    })
}

/// Gradescope states no size limit; the image is kept as small as PrairieLearn's.
pub const GRADESCOPE_IMAGE_MAX_BYTES: usize = PRAIRIELEARN_MAX_BYTES / 2;

/// The difference image as a `(label, data: URL)` no longer than `budget` bytes: halved
/// (failing pixels kept visible) until it fits, left out if even one pixel does not;
/// with notes saying which. `limit` names the limit in the notes.
fn fit_diff_image(
    r: &Report,
    budget: usize,
    limit: &str,
) -> (Option<(String, String)>, Vec<String>) {
    let mut notes = Vec::new();
    let mut img = r.diff.clone();
    loop {
        let png = img.encode_png();
        let b64_len = png.len().div_ceil(3) * 4 + "data:image/png;base64,".len();
        if !png.is_empty() && b64_len <= budget {
            let label = if (img.width, img.height) == (r.diff.width, r.diff.height) {
                "Difference: failing pixels in magenta over the dimmed reference".to_owned()
            } else {
                notes.push(format!(
                    "The difference image was downscaled from {} × {} to {} × {} to stay under {limit}.",
                    r.diff.width, r.diff.height, img.width, img.height
                ));
                format!(
                    "Difference (downscaled to {} × {}): failing pixels in magenta",
                    img.width, img.height
                )
            };
            let url = format!(
                "data:image/png;base64,{}",
                base64::engine::general_purpose::STANDARD.encode(&png)
            );
            return (Some((label, url)), notes);
        }
        if img.width <= 1 && img.height <= 1 || png.is_empty() {
            notes.push(format!(
                "The difference image was left out: it does not fit {limit}."
            ));
            return (None, notes);
        }
        img = img.halve(super::compare::FAIL_RGB);
    }
}

/// PrairieLearn's results: `score` is the report's score (0–1), the tests' points add up
/// to it (the scored tests' `max_points` to 1; informational tests carry 0 of 0), and
/// the difference image is inline. The file is kept under [`PRAIRIELEARN_MAX_BYTES`]:
/// the list of worst pixels is shortened first, then the image halved (failing pixels
/// kept visible), and if that is still too large the image is left out; the message
/// says which.
pub fn to_prairielearn(r: &Report) -> Value {
    let tests_json = |shown: usize| -> Value {
        lms_tests(r, shown)
            .into_iter()
            .map(|t| {
                let (points, max) = t.points.unwrap_or((0.0, 0.0));
                json!({
                    "name": t.name,
                    "points": points,
                    "max_points": max,
                    "message": if t.pass { "passed" } else { "failed" },
                    "output": t.output,
                })
            })
            .collect()
    };
    let summary = format!(
        "{}{}",
        r.summary,
        super::diagnose::message_suffix(r.diagnosis.as_ref())
    );
    let mut doc = json!({
        "gradable": true,
        "score": r.score.value,
        "message": summary,
        "output": to_text(r),
        "tests": tests_json(r.worst.len()),
        "images": [],
    });
    let size = |d: &Value| serde_json::to_vec(d).map_or(usize::MAX, |v| v.len());
    // The text grows with the worst list; shorten it if the text alone is too long.
    let mut shown = r.worst.len();
    while size(&doc) > PRAIRIELEARN_MAX_BYTES / 2 && shown > 0 {
        shown /= 2;
        let mut text = to_text(&Report {
            worst: r.worst[..shown].to_vec(),
            diff: RgbImage::default(),
            ..r.clone()
        });
        text.push_str(&format!("(only the {shown} worst pixels are listed)\n"));
        doc["output"] = Value::String(text);
        doc["tests"] = tests_json(shown);
    }
    let budget = PRAIRIELEARN_MAX_BYTES.saturating_sub(size(&doc) + 512);
    let (image, notes) = fit_diff_image(r, budget, "PrairieLearn's 1 MB limit");
    if let Some((label, url)) = image {
        doc["images"] = json!([{ "label": label, "url": url }]);
    }
    if !notes.is_empty() {
        doc["message"] = Value::String(format!("{summary} {}", notes.join(" ")));
    }
    doc
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grade::compare;

    fn noisy(w: u32, h: u32, seed: u32) -> RgbImage {
        // An incompressible image, to push the PNG past the limit.
        let mut x = seed.wrapping_mul(2654435761).max(1);
        let mut data = Vec::with_capacity((w * h * 3) as usize);
        for _ in 0..w * h * 3 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            data.push(x as u8);
        }
        RgbImage {
            width: w,
            height: h,
            data,
        }
    }

    fn report(a: &RgbImage, b: &RgbImage, tol: &Tolerances) -> Report {
        let cmp = compare::images(a, b, tol, 10);
        Report::new(
            "png",
            a.width,
            a.height,
            tol,
            &GradeOptions::default(),
            cmp,
            None,
        )
    }

    #[test]
    fn verdict_follows_the_share() {
        let a = noisy(10, 10, 1);
        let mut b = a.clone();
        b.set(3, 4, [a.get(3, 4)[0].wrapping_add(100), 0, 0]);
        let strict = report(&a, &b, &Tolerances::default());
        assert!(!strict.pass);
        assert_eq!(strict.max_failing_pixels, 0);
        let lenient = report(
            &a,
            &b,
            &Tolerances {
                max_fail_share: 0.01,
                ..Default::default()
            },
        );
        assert!(lenient.pass);
        assert_eq!(lenient.max_failing_pixels, 1);
        assert!(lenient.summary.starts_with("PASS: 1 of 100 pixels"));
    }

    #[test]
    fn gradescope_shape() {
        let a = noisy(4, 4, 2);
        let lms = LmsOptions {
            max_score: 10.0,
            ..Default::default()
        };
        let g = to_gradescope(&report(&a, &a, &Tolerances::default()), &lms);
        assert_eq!(g["score"], 10.0);
        assert_eq!(g["max_score"], 10.0);
        assert_eq!(g["tests"][0]["status"], "passed");
        assert_eq!(g["visibility"], "visible");
    }

    #[test]
    fn prairielearn_stays_under_the_limit() {
        let a = noisy(800, 600, 3);
        let b = noisy(800, 600, 4);
        let r = report(&a, &b, &Tolerances::default());
        let pl = to_prairielearn(&r);
        let bytes = serde_json::to_vec(&pl).unwrap();
        assert!(bytes.len() < PRAIRIELEARN_MAX_BYTES, "{}", bytes.len());
        assert_eq!(pl["gradable"], true);
        assert_eq!(pl["score"], 0.0);
        let url = pl["images"][0]["url"].as_str().unwrap();
        assert!(url.starts_with("data:image/png;base64,"));
        // Every pixel fails: the difference image is all magenta, small once compressed.
        assert!(pl["message"].as_str().unwrap().starts_with("FAIL"));
    }

    #[test]
    fn prairielearn_downscales_a_large_incompressible_image() {
        let a = noisy(900, 700, 5);
        let r = Report {
            diff: noisy(900, 700, 6),
            ..report(&a, &a, &Tolerances::default())
        };
        let pl = to_prairielearn(&r);
        assert!(serde_json::to_vec(&pl).unwrap().len() < PRAIRIELEARN_MAX_BYTES);
        assert!(pl["message"].as_str().unwrap().contains("downscaled"));
        assert!(
            pl["images"][0]["label"]
                .as_str()
                .unwrap()
                .contains("downscaled")
        );
    }
}
