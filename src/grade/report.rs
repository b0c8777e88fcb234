//! The grading report and its forms: our JSON ([`Report`]), a readable text
//! ([`to_text`]), Gradescope's `results.json` ([`to_gradescope`]) and PrairieLearn's
//! results ([`to_prairielearn`], kept under its 1 MB limit), and the difference image as
//! a PNG ([`Report::diff_png`]).
//!
//! The verdict: a submission passes when at most `floor(max_fail_share × pixels)` of its
//! pixels fail. Scores in the grader formats are all or nothing (full marks on a pass),
//! with the per-check counts alongside as information.

use std::fmt::Write as _;

use base64::Engine as _;
use serde::Serialize;
use serde_json::{Value, json};

use super::compare::{Comparison, HitCounts, LinearCounts, PixelValue, WorstPixel};
use super::image::RgbImage;
use super::metrics::{ErrorStats, FlipStats};
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
        let mut r = Report {
            pass,
            kind,
            format,
            summary,
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

/// The report as readable text.
pub fn to_text(r: &Report) -> String {
    let mut o = String::new();
    let _ = writeln!(o, "{}", r.summary);
    for w in &r.warnings {
        let _ = writeln!(o, "Warning: {w}");
    }
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
    if let Some(l) = &r.linear {
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
    if let Some(m) = &r.image {
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
    if let Some(c) = &r.hits {
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
    if !r.worst.is_empty() {
        let _ = writeln!(o, "Worst pixels (u, v):");
        o.push_str(&worst_text(r, r.worst.len()));
    }
    o
}

fn checks(r: &Report) -> Vec<(String, bool, String)> {
    let allowed = r.max_failing_pixels;
    match &r.hits {
        None => vec![(
            format!("Colour within ±{}/255 per channel", r.tolerances.colour_abs),
            r.pass,
            format!(
                "{} failing pixel(s), at most {allowed} allowed",
                r.failing_pixels
            ),
        )],
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

/// Gradescope's `results.json`: `max_score` on a pass, 0 on a fail; one test carrying
/// the score and, for hit data, one informational test (0 points) per check.
pub fn to_gradescope(r: &Report, max_score: f64) -> Value {
    let score = if r.pass { max_score } else { 0.0 };
    let status = |ok: bool| if ok { "passed" } else { "failed" };
    let mut tests = vec![json!({
        "name": "Matches the reference",
        "score": score,
        "max_score": max_score,
        "status": status(r.pass),
        "output": format!("{}\n{}", r.summary, worst_text(r, r.worst.len())),
        "visibility": "visible",
    })];
    if r.kind == "hits" {
        for (name, ok, output) in checks(r) {
            tests.push(json!({
                "name": name,
                "score": 0.0,
                "max_score": 0.0,
                "status": status(ok),
                "output": output,
                "visibility": "visible",
            }));
        }
    }
    json!({
        "score": score,
        "max_score": max_score,
        "output": to_text(r),
        "visibility": "visible",
        "stdout_visibility": "visible",
        "tests": tests,
    })
}

/// PrairieLearn's results: `score` 1 on a pass, 0 on a fail, the checks as tests, and the
/// difference image inline. The file is kept under [`PRAIRIELEARN_MAX_BYTES`]: the list of
/// worst pixels is shortened first, then the image halved (failing pixels kept visible),
/// and if that is still too large the image is left out; the message says which.
pub fn to_prairielearn(r: &Report) -> Value {
    let score = if r.pass { 1.0 } else { 0.0 };
    let mut tests = vec![json!({
        "name": "Matches the reference",
        "points": score,
        "max_points": 1.0,
        "message": r.summary,
        "output": worst_text(r, r.worst.len()),
    })];
    for (name, ok, output) in checks(r) {
        tests.push(json!({
            "name": name,
            "points": if ok { 1.0 } else { 0.0 },
            "max_points": 1.0,
            "output": output,
        }));
    }
    let mut doc = json!({
        "gradable": true,
        "score": score,
        "message": r.summary,
        "output": to_text(r),
        "tests": tests,
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
        doc["tests"][0]["output"] = Value::String(worst_text(r, shown));
    }
    let mut notes = Vec::new();
    let mut img = r.diff.clone();
    let budget = PRAIRIELEARN_MAX_BYTES.saturating_sub(size(&doc) + 512);
    loop {
        let png = img.encode_png();
        let b64_len = png.len().div_ceil(3) * 4 + "data:image/png;base64,".len();
        if !png.is_empty() && b64_len <= budget {
            let label = if (img.width, img.height) == (r.diff.width, r.diff.height) {
                "Difference: failing pixels in magenta over the dimmed reference".to_owned()
            } else {
                notes.push(format!(
                    "The difference image was downscaled from {} × {} to {} × {} to stay under PrairieLearn's 1 MB limit.",
                    r.diff.width, r.diff.height, img.width, img.height
                ));
                format!(
                    "Difference (downscaled to {} × {}): failing pixels in magenta",
                    img.width, img.height
                )
            };
            doc["images"] = json!([{
                "label": label,
                "url": format!("data:image/png;base64,{}",
                    base64::engine::general_purpose::STANDARD.encode(&png)),
            }]);
            break;
        }
        if img.width <= 1 && img.height <= 1 || png.is_empty() {
            notes.push(
                "The difference image was left out: it does not fit PrairieLearn's 1 MB limit."
                    .to_owned(),
            );
            break;
        }
        img = img.halve(super::compare::FAIL_RGB);
    }
    if !notes.is_empty() {
        doc["message"] = Value::String(format!("{} {}", r.summary, notes.join(" ")));
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
        let g = to_gradescope(&report(&a, &a, &Tolerances::default()), 10.0);
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
