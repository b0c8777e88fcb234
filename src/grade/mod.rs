//! Autograding: comparing a student's submission with the reference rendered from the
//! same scene ([`grade`]), and explaining one pixel's computation ([`explain()`], in
//! [`explain`](mod@crate::grade::explain)).
//!
//! ```text
//! Submission::parse(bytes, hint) ──► grade(&renderer, submission, &tolerances, &options)
//!  PNG │ PPM │ BMP │ TGA │ JPEG │ PFM │ EXR     │ renders the reference (colour, linear
//!       JSON │ NDJSON │ NPY │ CSV                │ colour or hits)
//!                                                  │ compares pixel by pixel (compare)
//!                                                  │ error statistics (metrics)
//!                                                  ▼
//!                                   Report ──► JSON │ Gradescope │ PrairieLearn │ text
//!                                          └─► difference image (PNG)
//! ```
//!
//! Each form of a report and of an explanation is written once, in [`answer`], for the
//! command line and the server alike.
//!
//! Everything runs offline and in memory: the same calls serve the command line
//! (`raytile grade`, `raytile trace`) and the HTTP handlers. A submission the grader
//! cannot read is a [`GradeError`] saying what is wrong, never a panic.
//!
//! [`grade`]: crate::grade::grade
//! [`explain()`]: crate::grade::explain()
//! [`answer`]: crate::grade::answer
//! [`GradeError`]: crate::grade::GradeError

pub mod answer;
pub mod cache;
pub mod compare;
pub mod diagnose;
pub mod explain;
pub mod footprint;
pub mod image;
pub mod legend;
pub mod metrics;
pub mod report;
pub mod score;
pub mod submission;

use serde::{Deserialize, Serialize};

use crate::format::{LinearImage, Raster, ReadError};
use crate::geometry::Surface;
use crate::output::FrameSink;
use crate::render::{
    Cancel, ColourKernel, DEFAULT_TILE_PX, HitKernel, Kernel, LinearKernel, Rect, Renderer, Stopped,
};
pub use explain::{ExplainOptions, Explanation, explain};
pub use image::RgbImage;
pub use report::Report;
pub use score::{Score, Scoring, ScoringMode, ScoringOverrides};
pub use submission::{Hint, Submission};

/// When a submission passes. Every field has a default; unknown fields are an error.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Tolerances {
    /// Largest absolute difference per colour channel, in 8-bit units (default 2).
    #[serde(alias = "color_abs")]
    pub colour_abs: u8,
    /// Share of pixels allowed to fail, 0–1 (default 0.001, i.e. 0.1 %).
    pub max_fail_share: f64,
    /// Largest relative error of `λ`, `|λ − λref| / λref` (default 1e-6).
    pub lambda_rel: f64,
    /// Largest angle between the normals, in degrees (default 0.1).
    pub normal_degrees: f64,
    /// A pixel also passes when it matches any reference pixel of its 3 × 3
    /// neighbourhood (default false).
    pub edge_forgiving: bool,
    /// Float images (PFM, OpenEXR), compared in linear radiance: the allowed difference
    /// per channel grows by this share of the reference's value (default 0.001).
    pub linear_rel: f64,
    /// Float images: the allowed difference per channel at a reference value of 0
    /// (default 0.0001).
    pub linear_abs: f64,
}

impl Default for Tolerances {
    fn default() -> Self {
        Tolerances {
            colour_abs: 2,
            max_fail_share: 0.001,
            lambda_rel: 1e-6,
            normal_degrees: 0.1,
            edge_forgiving: false,
            linear_rel: 1e-3,
            linear_abs: 1e-4,
        }
    }
}

impl Tolerances {
    /// Checks the ranges: a share in `[0, 1]`, a non-negative `λ` tolerance, an angle in
    /// `[0, 180]`.
    pub fn check(&self) -> Result<(), GradeError> {
        let bad = |field: &'static str, message: &str| {
            Err(GradeError::BadTolerance {
                field,
                message: message.to_owned(),
            })
        };
        if !(0.0..=1.0).contains(&self.max_fail_share) {
            return bad("max_fail_share", "must be between 0 and 1");
        }
        if !(self.lambda_rel >= 0.0 && self.lambda_rel.is_finite()) {
            return bad("lambda_rel", "must be a finite number ≥ 0");
        }
        if !(0.0..=180.0).contains(&self.normal_degrees) {
            return bad("normal_degrees", "must be between 0 and 180");
        }
        for (field, x) in [
            ("linear_rel", self.linear_rel),
            ("linear_abs", self.linear_abs),
        ] {
            if !(x >= 0.0 && x.is_finite()) {
                return bad(field, "must be a finite number ≥ 0");
            }
        }
        Ok(())
    }
}

/// Tolerances set one by one over others (the defaults, a file, a request's document):
/// the command line's `--colour-abs`, `--max-fail-share`, `--lambda-rel`,
/// `--normal-degrees` and `--edge-forgiving`, and the query parameters of the same
/// names on `POST /v1/grade`. Each field left `None` keeps the value beneath.
#[derive(Debug, Clone, Copy, Default, PartialEq, clap::Args)]
pub struct ToleranceOverrides {
    /// Largest difference per colour channel, 0–255 (default 2).
    #[arg(long, alias = "color-abs")]
    pub colour_abs: Option<u8>,
    /// Share of pixels that may fail, 0–1 (default 0.001).
    #[arg(long)]
    pub max_fail_share: Option<f64>,
    /// Largest relative error of λ (default 1e-6).
    #[arg(long)]
    pub lambda_rel: Option<f64>,
    /// Largest angle between normals, in degrees (default 0.1).
    #[arg(long)]
    pub normal_degrees: Option<f64>,
    /// A pixel also passes when it matches a reference pixel of its 3 × 3 neighbourhood.
    // On the command line a bare flag: present sets it, absent leaves the value beneath.
    #[arg(long, num_args = 0, default_missing_value = "true")]
    pub edge_forgiving: Option<bool>,
    /// Float images: allowed linear difference as a share of the reference (default 0.001).
    #[arg(long)]
    pub linear_rel: Option<f64>,
    /// Float images: allowed linear difference at 0 (default 0.0001).
    #[arg(long)]
    pub linear_abs: Option<f64>,
}

impl ToleranceOverrides {
    /// `base` with the tolerances these set.
    pub fn apply(&self, base: Tolerances) -> Tolerances {
        Tolerances {
            colour_abs: self.colour_abs.unwrap_or(base.colour_abs),
            max_fail_share: self.max_fail_share.unwrap_or(base.max_fail_share),
            lambda_rel: self.lambda_rel.unwrap_or(base.lambda_rel),
            normal_degrees: self.normal_degrees.unwrap_or(base.normal_degrees),
            edge_forgiving: self.edge_forgiving.unwrap_or(base.edge_forgiving),
            linear_rel: self.linear_rel.unwrap_or(base.linear_rel),
            linear_abs: self.linear_abs.unwrap_or(base.linear_abs),
        }
    }
}

/// What the report includes, and how the grading runs.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GradeOptions {
    /// How many of the worst pixels to list (default 10).
    pub worst: usize,
    /// Include the difference image in the report as `diff_png_base64` (default false).
    pub inline_diff: bool,
    /// Compute FLIP for images (default true; it costs about as much as the SSIM).
    pub flip: bool,
    /// How the score is computed (default all or nothing).
    pub scoring: Scoring,
    /// Stops rendering the reference (a deadline, a client that left).
    #[serde(skip)]
    pub cancel: Cancel,
    /// What diagnosing a failing submission may cost.
    #[serde(skip)]
    pub diagnosis: diagnose::Settings,
    /// Where references rendered before are kept ([`cache`]); None renders every one.
    #[serde(skip)]
    pub references: Option<std::sync::Arc<cache::ReferenceCache>>,
}

impl Default for GradeOptions {
    fn default() -> Self {
        GradeOptions {
            worst: 10,
            inline_diff: false,
            flip: true,
            scoring: Scoring::default(),
            cancel: Cancel::new(),
            diagnosis: diagnose::Settings::default(),
            references: None,
        }
    }
}

/// Why a submission could not be graded. Everything but [`GradeError::Cancelled`] and
/// [`GradeError::Reference`] is the submission's (or the caller's) fault.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GradeError {
    /// The submission has no content.
    #[error("the submission is empty")]
    Empty,
    /// The content is none of the accepted forms.
    #[error(
        "cannot tell what the submission is: it is none of {}",
        submission::ACCEPTED
    )]
    UnknownFormat,
    /// A PNG was expected but the bytes are not one.
    #[error("the submission is not a PNG file (it does not start with the PNG signature)")]
    NotPng,
    /// The image or hit data is not the scene's size.
    #[error(
        "the submission is {width} × {height} pixels but the scene renders {expected_width} × {expected_height}{}",
        diagnose::size_note(.width, .height, .expected_width, .expected_height)
    )]
    SizeMismatch {
        /// Submitted width.
        width: u32,
        /// Submitted height.
        height: u32,
        /// The scene's width.
        expected_width: u32,
        /// The scene's height.
        expected_height: u32,
    },
    /// Bytes the format's reader refused (corrupt PNG, bad JSON, NDJSON, NPY or CSV,
    /// missing fields, values of the wrong kind), as the reader says it.
    #[error(transparent)]
    Unreadable(ReadError),
    /// A pixel outside the frame.
    #[error("pixel ({u}, {v}) lies outside the {width} × {height} image")]
    OutsideImage {
        /// Column.
        u: u32,
        /// Row.
        v: u32,
        /// The scene's width.
        width: u32,
        /// The scene's height.
        height: u32,
    },
    /// A pixel given twice.
    #[error("pixel ({u}, {v}) appears more than once")]
    DuplicatePixel {
        /// Column.
        u: u32,
        /// Row.
        v: u32,
    },
    /// Pixels of the frame that the hit data does not cover.
    #[error("{count} pixel(s) of the image are missing from the hit data, the first is ({u}, {v})")]
    MissingPixels {
        /// How many.
        count: u64,
        /// Column of the first.
        u: u32,
        /// Row of the first.
        v: u32,
    },
    /// A tolerance out of range.
    #[error("the tolerance `{field}` {message}")]
    BadTolerance {
        /// Which.
        field: &'static str,
        /// The range it must be in.
        message: String,
    },
    /// A scoring setting out of range.
    #[error("the scoring setting `{field}` {message}")]
    BadScoring {
        /// Which.
        field: &'static str,
        /// The range it must be in.
        message: String,
    },
    /// The grading was cancelled before the reference was rendered.
    #[error("the grading was cancelled")]
    Cancelled,
    /// The reference could not be rendered (not the submission's fault).
    #[error("the reference could not be rendered: {0}")]
    Reference(String),
}

impl GradeError {
    /// Whether the submission is to blame (what a student must fix), rather than the
    /// grader's settings or the reference: the grader formats then report it as
    /// ungradable instead of failing.
    pub fn is_submissions_fault(&self) -> bool {
        !matches!(
            self,
            GradeError::BadTolerance { .. }
                | GradeError::BadScoring { .. }
                | GradeError::Cancelled
                | GradeError::Reference(_)
        )
    }
}

/// Traces the whole frame with `kernel` on the current rayon pool, row-major.
pub fn render_frame<K: Kernel>(
    kernel: &K,
    width: u32,
    height: u32,
    cancel: &Cancel,
) -> Result<Vec<K::Pixel>, GradeError>
where
    K::Pixel: Clone + Default,
{
    let sink = FrameSink::new(Rect::frame(width, height));
    crate::render::run(
        kernel,
        Rect::frame(width, height),
        DEFAULT_TILE_PX,
        cancel,
        &sink,
    )
    .map_err(|e| match e {
        Stopped::Cancelled => GradeError::Cancelled,
        Stopped::Sink(s) => GradeError::Reference(s.to_string()),
    })?;
    sink.into_pixels()
        .ok_or_else(|| GradeError::Reference("a worker panicked".into()))
}

/// The reference image, exactly as `raytile render` writes it.
pub fn reference_image(r: &Renderer, cancel: &Cancel) -> Result<RgbImage, GradeError> {
    let (w, h) = (r.scene.width, r.scene.height);
    let px = render_frame(&ColourKernel(r), w, h, cancel)?;
    Ok(RgbImage::from_pixels(w, h, &px))
}

/// The reference's linear colours, before gamma and quantisation, exactly as
/// `raytile render -o x.exr` writes them.
pub fn reference_linear(r: &Renderer, cancel: &Cancel) -> Result<LinearImage, GradeError> {
    let (w, h) = (r.scene.width, r.scene.height);
    let px = render_frame(&LinearKernel(r), w, h, cancel)?;
    Ok(LinearImage::from_pixels(w, h, &px))
}

/// The reference hit data, exactly as `raytile hits` writes it.
pub fn reference_hits(r: &Renderer, cancel: &Cancel) -> Result<Vec<Option<Surface>>, GradeError> {
    render_frame(&HitKernel(r), r.scene.width, r.scene.height, cancel)
}

impl submission::HitData {
    /// Places every pixel in a `w × h` frame, row-major: explicit `u`, `v` where given,
    /// else row-major over the group's rectangle (or the frame). Every pixel must be
    /// given exactly once.
    pub fn place(&self, w: u32, h: u32) -> Result<Vec<submission::SubmittedHit>, GradeError> {
        if let Some((sw, sh)) = self.size
            && (sw, sh) != (w, h)
        {
            return Err(GradeError::SizeMismatch {
                width: sw,
                height: sh,
                expected_width: w,
                expected_height: h,
            });
        }
        let n = w as usize * h as usize;
        let mut out: Vec<Option<submission::SubmittedHit>> = vec![None; n];
        for g in &self.groups {
            let rect = g.rect.unwrap_or(Rect::frame(w, h));
            for (k, p) in g.pixels.iter().enumerate() {
                let (u, v) = match (p.u, p.v) {
                    (Some(u), Some(v)) => (u, v),
                    _ if rect.width == 0 => {
                        return Err(GradeError::Unreadable(ReadError::WrongShape(
                            "a group has width 0".into(),
                        )));
                    }
                    _ => (
                        rect.x.saturating_add(k as u32 % rect.width),
                        rect.y.saturating_add((k / rect.width as usize) as u32),
                    ),
                };
                if u >= w || v >= h {
                    return Err(GradeError::OutsideImage {
                        u,
                        v,
                        width: w,
                        height: h,
                    });
                }
                let slot = &mut out[v as usize * w as usize + u as usize];
                if slot.is_some() {
                    return Err(GradeError::DuplicatePixel { u, v });
                }
                *slot = Some(*p);
            }
        }
        let missing = out.iter().filter(|p| p.is_none()).count() as u64;
        if let Some(first) = out.iter().position(Option::is_none) {
            return Err(GradeError::MissingPixels {
                count: missing,
                u: (first % w as usize) as u32,
                v: (first / w as usize) as u32,
            });
        }
        Ok(out.into_iter().flatten().collect())
    }
}

/// Grades a submission against the scene's reference: renders the reference (the image,
/// or the hit data), compares pixel by pixel under `tol`, and reports.
pub fn grade(
    r: &Renderer,
    submission: Submission,
    tol: &Tolerances,
    opts: &GradeOptions,
) -> Result<Report, GradeError> {
    tol.check()?;
    opts.scoring.check(tol)?;
    let (w, h) = (r.scene.width, r.scene.height);
    match submission {
        Submission::Image(img) => {
            let (iw, ih) = img.size();
            if (iw, ih) != (w, h) {
                return Err(GradeError::SizeMismatch {
                    width: iw,
                    height: ih,
                    expected_width: w,
                    expected_height: h,
                });
            }
            // A float image is compared in linear radiance; its statistics are those of
            // both images as the renderer would quantise them. Diagnosis is budgeted by
            // the reference's render time and the comparison, cached or not.
            let (reference, submitted, cmp, reference_time) = match &img.pixels {
                Raster::Rgb8(s) => {
                    let reference = reference_of(r, opts, || reference_image(r, &opts.cancel))?;
                    let started = std::time::Instant::now();
                    let cmp = compare::images(&reference.value, s, tol, opts.worst);
                    let time = reference.render_time + started.elapsed();
                    (reference.value, std::borrow::Cow::Borrowed(s), cmp, time)
                }
                Raster::Linear(s) => {
                    let linear = reference_of(r, opts, || reference_linear(r, &opts.cancel))?;
                    let started = std::time::Instant::now();
                    let reference = linear.value.quantise(r.scene.gamma);
                    let cmp = compare::linear(&linear.value, s, &reference, tol, opts.worst);
                    let submitted = std::borrow::Cow::Owned(s.quantise(r.scene.gamma));
                    let time = linear.render_time + started.elapsed();
                    (std::sync::Arc::new(reference), submitted, cmp, time)
                }
            };
            let ctx = diagnose_context(opts, reference_time);
            let image = report::ImageMetrics {
                errors: metrics::error_stats(&reference, &submitted),
                ssim: metrics::ssim(&reference, &submitted),
                flip: opts.flip.then(|| metrics::flip(&reference, &submitted)),
            };
            let mut report = Report::new(img.format.name(), w, h, tol, opts, cmp, Some(image));
            report.warnings = img.warnings();
            // A float image is diagnosed as the renderer would quantise it.
            let against = diagnose::Against::Image {
                reference: &reference,
                submitted: &submitted,
            };
            report.diagnosis = diagnose::for_report(r, &report, against, tol, &ctx);
            Ok(report)
        }
        Submission::Hits(data) => {
            let placed = data.place(w, h)?;
            let reference = reference_of(r, opts, || reference_hits(r, &opts.cancel))?;
            let ctx = diagnose_context(opts, reference.render_time);
            let reference = &*reference.value;
            let cmp = compare::hits(reference, &placed, w, h, tol, opts.worst);
            let mut report = Report::new(data.format, w, h, tol, opts, cmp, None);
            let against = diagnose::Against::Hits {
                reference,
                submitted: &placed,
            };
            report.diagnosis = diagnose::for_report(r, &report, against, tol, &ctx);
            Ok(report)
        }
    }
}

/// The scene's reference of type `T`: from `opts.references` when it holds it (or can
/// keep it once `render` has made it), else rendered by `render`.
fn reference_of<T: cache::Cached>(
    r: &Renderer,
    opts: &GradeOptions,
    render: impl FnOnce() -> Result<T, GradeError>,
) -> Result<cache::Rendered<T>, GradeError> {
    let cached = opts
        .references
        .as_ref()
        .and_then(|c| Some((c, cache::SceneKey::of(&r.scene)?)));
    match cached {
        Some((references, key)) => references.get_or_render(key, render),
        None => cache::render_uncached(render),
    }
}

fn diagnose_context(
    opts: &GradeOptions,
    reference_time: std::time::Duration,
) -> diagnose::Context<'_> {
    diagnose::Context {
        settings: opts.diagnosis,
        cancel: &opts.cancel,
        reference_time,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use submission::{Group, HitData, SubmittedHit};

    #[test]
    fn tolerances_refuse_unknown_fields_and_bad_ranges() {
        let t: Tolerances = serde_json::from_str(r#"{"color_abs": 5}"#).unwrap();
        assert_eq!(t.colour_abs, 5);
        assert_eq!(t.max_fail_share, 0.001);
        assert!(serde_json::from_str::<Tolerances>(r#"{"colour": 5}"#).is_err());
        let t = Tolerances {
            max_fail_share: 2.0,
            ..Default::default()
        };
        assert!(t.check().is_err());
        let t = Tolerances {
            lambda_rel: f64::NAN,
            ..Default::default()
        };
        assert!(t.check().is_err());
    }

    #[test]
    fn overrides_set_only_what_they_name() {
        let base = Tolerances {
            colour_abs: 7,
            edge_forgiving: true,
            ..Default::default()
        };
        assert_eq!(ToleranceOverrides::default().apply(base.clone()), base);
        let o = ToleranceOverrides {
            max_fail_share: Some(0.5),
            edge_forgiving: Some(false),
            ..Default::default()
        };
        assert_eq!(
            o.apply(base.clone()),
            Tolerances {
                max_fail_share: 0.5,
                edge_forgiving: false,
                ..base
            }
        );
    }

    fn data(pixels: Vec<SubmittedHit>, rect: Option<Rect>) -> HitData {
        HitData {
            format: "json",
            size: None,
            groups: vec![Group { rect, pixels }],
        }
    }

    #[test]
    fn placing_pixels() {
        let miss = SubmittedHit::default();
        let at = |u, v| SubmittedHit {
            u: Some(u),
            v: Some(v),
            ..miss
        };
        assert_eq!(data(vec![miss; 4], None).place(2, 2).unwrap().len(), 4);
        assert!(matches!(
            data(vec![miss; 3], None).place(2, 2),
            Err(GradeError::MissingPixels {
                count: 1,
                u: 1,
                v: 1
            })
        ));
        assert!(matches!(
            data(vec![at(0, 0), at(0, 0)], None).place(2, 1),
            Err(GradeError::DuplicatePixel { u: 0, v: 0 })
        ));
        assert!(matches!(
            data(vec![at(2, 0)], None).place(2, 1),
            Err(GradeError::OutsideImage { .. })
        ));
        let sized = HitData {
            size: Some((3, 3)),
            ..data(vec![], None)
        };
        assert!(matches!(
            sized.place(2, 2),
            Err(GradeError::SizeMismatch { .. })
        ));
    }
}
