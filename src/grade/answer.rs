//! The forms a grading report and a pixel's explanation are written in, each written
//! here once: `raytile grade` and `raytile trace` write these bytes to a file or standard
//! output, and `POST /v1/grade` and `POST /v1/trace` answer with the same bytes under the
//! media type given here, so the two agree byte for byte by construction.
//!
//! ```text
//! Report      ──► write_report(report, ReportForm::…, &LmsOptions)  ──► bytes
//!                   Json │ Text │ Gradescope │ Prairielearn │ DiffPng
//! GradeError  ──► write_ungradable(reason, ReportForm::…, &LmsOptions) ──► bytes
//!                   Gradescope │ Prairielearn (the others have none)
//! Explanation ──► write_explanation(explanation, ExplanationForm::…) ──► bytes
//!                   Text │ Json
//! ```

use super::explain::{self, Explanation};
use super::report::{self, LmsOptions, Report};

/// The media type of every text answer.
pub const TEXT_PLAIN_UTF8: &str = "text/plain; charset=utf-8";

/// A form of a grading report, or the difference image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ReportForm {
    /// raytile's own JSON report.
    Json,
    /// Readable text.
    Text,
    /// Gradescope's `results.json`.
    Gradescope,
    /// PrairieLearn's results (under 1 MB, the difference image inline).
    Prairielearn,
    /// The difference image: failing pixels magenta over the dimmed reference, a PNG.
    #[value(skip)]
    DiffPng,
}

impl ReportForm {
    /// The media type, without parameters (what `Accept` is matched against).
    pub fn media_type(self) -> &'static str {
        match self {
            ReportForm::Json | ReportForm::Gradescope | ReportForm::Prairielearn => {
                "application/json"
            }
            ReportForm::Text => "text/plain",
            ReportForm::DiffPng => "image/png",
        }
    }

    /// The `Content-Type` to send it with (text with its character set).
    pub fn content_type(self) -> &'static str {
        match self {
            ReportForm::Text => TEXT_PLAIN_UTF8,
            other => other.media_type(),
        }
    }

    /// Whether this is a learning platform's results file, which must be written even
    /// for a submission that cannot be graded.
    pub fn is_lms(self) -> bool {
        matches!(self, ReportForm::Gradescope | ReportForm::Prairielearn)
    }
}

/// The report in `form`. JSON forms end in a newline; raytile's report and Gradescope's
/// are indented, PrairieLearn's is compact (its size limit was measured on that form).
/// `lms` holds Gradescope's points and visibilities.
pub fn write_report(
    r: &Report,
    form: ReportForm,
    lms: &LmsOptions,
) -> Result<Vec<u8>, serde_json::Error> {
    Ok(match form {
        ReportForm::Json => pretty(r)?,
        ReportForm::Text => report::to_text(r).into_bytes(),
        ReportForm::Gradescope => pretty(&report::to_gradescope(r, lms))?,
        ReportForm::Prairielearn => compact(&report::to_prairielearn(r))?,
        ReportForm::DiffPng => r.diff_png(),
    })
}

/// A learning platform's results file for a submission that cannot be graded, `reason`
/// its one-line message: Gradescope's with score 0, PrairieLearn's with `gradable`
/// false. `None` for the other forms, which have no such document (the command line
/// exits 2, the server answers 422).
pub fn write_ungradable(
    reason: &str,
    form: ReportForm,
    lms: &LmsOptions,
) -> Result<Option<Vec<u8>>, serde_json::Error> {
    Ok(match form {
        ReportForm::Gradescope => Some(pretty(&report::gradescope_ungradable(reason, lms))?),
        ReportForm::Prairielearn => Some(compact(&report::prairielearn_ungradable(reason))?),
        _ => None,
    })
}

/// Compact JSON and a newline.
fn compact<T: serde::Serialize + ?Sized>(v: &T) -> Result<Vec<u8>, serde_json::Error> {
    let mut out = serde_json::to_vec(v)?;
    out.push(b'\n');
    Ok(out)
}

/// A form of a pixel's explanation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ExplanationForm {
    /// Laid out like the lecture's worked example.
    Text,
    /// The explanation as JSON.
    Json,
}

impl ExplanationForm {
    /// The media type, without parameters (what `Accept` is matched against).
    pub fn media_type(self) -> &'static str {
        match self {
            ExplanationForm::Text => "text/plain",
            ExplanationForm::Json => "application/json",
        }
    }

    /// The `Content-Type` to send it with (text with its character set).
    pub fn content_type(self) -> &'static str {
        match self {
            ExplanationForm::Text => TEXT_PLAIN_UTF8,
            ExplanationForm::Json => "application/json",
        }
    }
}

/// The explanation in `form`: the lecture's layout, or indented JSON and a newline.
pub fn write_explanation(
    e: &Explanation,
    form: ExplanationForm,
) -> Result<Vec<u8>, serde_json::Error> {
    Ok(match form {
        ExplanationForm::Text => explain::to_text(e).into_bytes(),
        ExplanationForm::Json => pretty(e)?,
    })
}

/// Indented JSON and a newline.
fn pretty<T: serde::Serialize + ?Sized>(v: &T) -> Result<Vec<u8>, serde_json::Error> {
    let mut out = serde_json::to_vec_pretty(v)?;
    out.push(b'\n');
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grade::{GradeOptions, RgbImage, Tolerances, compare};

    fn report() -> Report {
        let img = RgbImage {
            width: 2,
            height: 1,
            data: vec![0, 10, 20, 30, 40, 50],
        };
        let tol = Tolerances::default();
        let cmp = compare::images(&img, &img, &tol, 10);
        Report::new("png", 2, 1, &tol, &GradeOptions::default(), cmp, None)
    }

    #[test]
    fn every_report_form_is_its_builder_in_its_layout() {
        let r = report();
        let one = LmsOptions::default();
        let five = LmsOptions {
            max_score: 5.0,
            ..Default::default()
        };
        let json = write_report(&r, ReportForm::Json, &one).unwrap();
        assert_eq!(
            json,
            format!("{}\n", serde_json::to_string_pretty(&r).unwrap()).into_bytes()
        );
        let text = write_report(&r, ReportForm::Text, &one).unwrap();
        assert_eq!(text, report::to_text(&r).into_bytes());
        let gradescope = write_report(&r, ReportForm::Gradescope, &five).unwrap();
        let g: serde_json::Value = serde_json::from_slice(&gradescope).unwrap();
        assert_eq!(g["max_score"], 5.0);
        assert!(gradescope.starts_with(b"{\n  ") && gradescope.ends_with(b"}\n"));
        let pl = write_report(&r, ReportForm::Prairielearn, &one).unwrap();
        assert!(pl.starts_with(b"{\"") && pl.ends_with(b"}\n"));
        assert_eq!(pl.iter().filter(|&&b| b == b'\n').count(), 1);
        let png = write_report(&r, ReportForm::DiffPng, &one).unwrap();
        assert_eq!(png, r.diff_png());
        assert!(png.starts_with(b"\x89PNG"));
    }

    #[test]
    fn ungradable_results_exist_for_the_grader_formats_only() {
        let lms = LmsOptions::default();
        let pl = write_ungradable("the submission is empty", ReportForm::Prairielearn, &lms)
            .unwrap()
            .unwrap();
        let v: serde_json::Value = serde_json::from_slice(&pl).unwrap();
        assert_eq!(v["gradable"], false);
        assert_eq!(v["format_errors"][0], "the submission is empty");
        let gs = write_ungradable("x", ReportForm::Gradescope, &lms)
            .unwrap()
            .unwrap();
        let v: serde_json::Value = serde_json::from_slice(&gs).unwrap();
        assert_eq!(v["score"], 0.0);
        for form in [ReportForm::Json, ReportForm::Text, ReportForm::DiffPng] {
            assert!(write_ungradable("x", form, &lms).unwrap().is_none());
        }
    }

    #[test]
    fn media_types() {
        assert_eq!(ReportForm::Prairielearn.media_type(), "application/json");
        assert_eq!(ReportForm::Text.media_type(), "text/plain");
        assert_eq!(ReportForm::Text.content_type(), TEXT_PLAIN_UTF8);
        assert_eq!(ReportForm::DiffPng.content_type(), "image/png");
        assert_eq!(ExplanationForm::Json.content_type(), "application/json");
        assert_eq!(ExplanationForm::Text.content_type(), TEXT_PLAIN_UTF8);
    }
}
