//! Diagnosis: naming the mistake behind a failing submission.
//!
//! A catalogue ([`catalogue`]) holds the classic mistakes of the course. For each entry
//! that can change the scene's picture, a "wrong reference" is made ([`wrong`]): the
//! reference moved (flipped, transposed), recoloured (BGR), its linear colours written to
//! 8 bits the wrong way (gamma, sRGB, truncation), or rendered again by the tracer with
//! the mistake switched on (a [`Conventions`](crate::render::Conventions) instantiation,
//! compiled apart from the renderer's). The submission is compared with it under the
//! grade's own tolerances, exactly as with the reference.
//!
//! A mistake is **named** when its wrong reference
//!
//! - matches at least [`MATCH_AT_LEAST`] (99 %) of the pixels, and
//! - leaves at most [`FAILURES_LEFT_AT_MOST`] (a tenth) of the pixels that fail against
//!   the reference failing,
//!
//! and it is the best such entry, or fails at most twice as many pixels as the best (then
//! the scene cannot tell them apart and each is named). A correct submission is never
//! diagnosed (only failing ones are), and an image that is simply different matches no
//! entry.
//!
//! An entry that explains all but [`CONCLUSIVE_MATCH`] (0.1 %) of the pixels, and at most
//! [`CONCLUSIVE_LEFT`] (1 %) of the reference's failures, ends the search (the entries
//! are tried cheapest first).
//!
//! The cost is bounded: diagnosis runs only for a failing submission of at most
//! [`Settings::max_pixels`] pixels, and spends at most [`Settings::time_factor`] times
//! the reference's render time (or [`Settings::min_budget`], whichever is longer); entries that
//! do not fit are skipped, and the report says which.

pub mod catalogue;
pub mod forms;
pub mod wrong;

use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use catalogue::Making;
pub use catalogue::Mistake;
pub use forms::{HIT_DIFF_LEGEND, message_suffix, size_cause, size_note, text};

use super::compare::{self, FAIL_RGB};
use super::legend::{LAMBDA_RGB, NORMAL_RGB, OBJECT_RGB};
use super::submission::SubmittedHit;
use super::{GradeError, RgbImage, Tolerances};
use crate::geometry::Surface;
use crate::render::{Cancel, Renderer};

/// A named mistake's wrong reference matches at least this share of the pixels.
pub const MATCH_AT_LEAST: f64 = 0.99;

/// A named mistake leaves at most this share of the reference's failing pixels failing.
pub const FAILURES_LEFT_AT_MOST: f64 = 0.1;

/// An entry that matches at least this share of the pixels …
pub const CONCLUSIVE_MATCH: f64 = 0.999;

/// … and leaves at most this share of the reference's failing pixels failing ends the
/// diagnosis: no later entry can explain the submission clearly better.
pub const CONCLUSIVE_LEFT: f64 = 0.01;

/// The default of [`Settings::max_pixels`]: 4 megapixels (a 2560 × 1600 frame).
pub const DEFAULT_MAX_PIXELS: u64 = 4_000_000;

/// The default of [`Settings::time_factor`].
pub const DEFAULT_TIME_FACTOR: f64 = 20.0;

/// The default of [`Settings::min_budget`]: the time diagnosis may always spend, however
/// fast the reference rendered.
pub const MIN_BUDGET: Duration = Duration::from_secs(2);

/// What diagnosis may cost.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Settings {
    /// Whether failing submissions are diagnosed at all (default true).
    pub enabled: bool,
    /// Larger frames are not diagnosed (the report says so); 0 diagnoses none. Default
    /// [`DEFAULT_MAX_PIXELS`].
    pub max_pixels: u64,
    /// Diagnosis spends at most this many times the reference's render time (default
    /// [`DEFAULT_TIME_FACTOR`]), or `min_budget` if that is longer.
    pub time_factor: f64,
    /// The time diagnosis may always spend (default [`MIN_BUDGET`]).
    pub min_budget: Duration,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            enabled: true,
            max_pixels: DEFAULT_MAX_PIXELS,
            time_factor: DEFAULT_TIME_FACTOR,
            min_budget: MIN_BUDGET,
        }
    }
}

/// A mistake that explains the submission.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Finding {
    /// The catalogue's name for it (`"flipped_vertically"`).
    pub mistake: Mistake,
    /// In a few words.
    pub title: &'static str,
    /// Share of pixels its wrong reference matches.
    pub matches: f64,
    /// What went wrong, for the student.
    pub explanation: &'static str,
    /// The page and section of the conventions it breaks.
    pub convention: &'static str,
}

/// One entry tried, and how well it explains the submission.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Tried {
    /// The entry.
    pub mistake: Mistake,
    /// Share of pixels its wrong reference matches.
    pub matches: f64,
}

/// What diagnosis found.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Diagnosis {
    /// Share of pixels the reference itself matches.
    pub reference_matches: f64,
    /// The mistakes named, best first (usually none or one).
    pub mistakes: Vec<Finding>,
    /// Every entry tried, best first.
    pub tried: Vec<Tried>,
    /// What was not tried, and why (the size limit, the time budget).
    pub notes: Vec<String>,
}

/// The submission being diagnosed, with the reference it failed against.
pub enum Against<'a> {
    /// An image and the reference image.
    Image {
        /// The reference.
        reference: &'a RgbImage,
        /// The submission.
        submitted: &'a RgbImage,
    },
    /// Hit data placed in the frame, and the reference hits.
    Hits {
        /// The reference.
        reference: &'a [Option<Surface>],
        /// The submission.
        submitted: &'a [SubmittedHit],
    },
}

/// How diagnosis runs: its settings, the grade's cancel token, and the reference's
/// render time that sets its budget.
pub struct Context<'a> {
    /// The limits.
    pub settings: Settings,
    /// Stops the renders (a deadline, a client that left, a ray budget).
    pub cancel: &'a Cancel,
    /// How long the reference took to render.
    pub reference_time: Duration,
}

/// Which pixels fail against a wrong reference, under the grade's tolerances.
fn failing_mask(against: &Against, wrong: &Wrong, r: &Renderer, tol: &Tolerances) -> Vec<bool> {
    let (w, h) = (r.scene.width, r.scene.height);
    let marked = |diff: RgbImage| -> Vec<bool> {
        // A failing pixel is marked in the difference image (the marks are bright, the
        // passing pixels dimmed), so the mask is the comparison's own verdict.
        diff.pixels()
            .into_iter()
            .map(|c| c == FAIL_RGB || c == OBJECT_RGB || c == LAMBDA_RGB || c == NORMAL_RGB)
            .collect()
    };
    match (against, wrong) {
        (Against::Image { submitted, .. }, Wrong::Image(img)) => {
            marked(compare::images(img, submitted, tol, 0).diff)
        }
        (Against::Hits { submitted, .. }, Wrong::Hits(hits)) => {
            marked(compare::hits(hits, submitted, w, h, tol, 0).diff)
        }
        (Against::Image { .. }, Wrong::AnyOf(images)) => {
            let mut mask = failing_mask(against, &reference_of(against), r, tol);
            for img in images {
                let m = marked(compare::images(img, against.submitted_image(), tol, 0).diff);
                mask.iter_mut().zip(m).for_each(|(a, b)| *a &= b);
            }
            mask
        }
        _ => vec![true; w as usize * h as usize],
    }
}

impl Against<'_> {
    fn submitted_image(&self) -> &RgbImage {
        static EMPTY: RgbImage = RgbImage {
            width: 0,
            height: 0,
            data: Vec::new(),
        };
        match self {
            Against::Image { submitted, .. } => submitted,
            Against::Hits { .. } => &EMPTY,
        }
    }
}

/// A wrong reference.
enum Wrong {
    /// An image.
    Image(RgbImage),
    /// Hit data.
    Hits(Vec<Option<Surface>>),
    /// A pixel is explained when it matches the reference or any of these at that pixel.
    AnyOf(Vec<RgbImage>),
}

/// Diagnoses a failing submission: which entries of the catalogue explain it.
/// `reference_failing` is the number of pixels that fail against the reference.
pub fn diagnose(
    r: &Renderer,
    against: Against,
    tol: &Tolerances,
    reference_failing: u64,
    ctx: &Context,
) -> Diagnosis {
    let started = Instant::now();
    let (w, h) = (r.scene.width, r.scene.height);
    let pixels = w as u64 * h as u64;
    let share = |failing: u64| 1.0 - failing as f64 / pixels.max(1) as f64;
    let mut d = Diagnosis {
        reference_matches: share(reference_failing),
        ..Diagnosis::default()
    };
    if pixels > ctx.settings.max_pixels {
        d.notes.push(format!(
            "No diagnosis: the image has {pixels} pixels, more than the {} this grader diagnoses.",
            ctx.settings.max_pixels
        ));
        return d;
    }
    let image = matches!(against, Against::Image { .. });
    let budget = ctx
        .reference_time
        .mul_f64(ctx.settings.time_factor.max(0.0))
        .max(ctx.settings.min_budget);
    // The cost of the next render is estimated as the reference's, then as the last one's.
    let mut render_cost = ctx.reference_time;
    let mut linear = None;
    let mut skipped = Vec::new();
    let mut tried: Vec<(Mistake, u64)> = Vec::new();
    for mistake in catalogue::ALL {
        if !mistake.applies(&r.scene, image) {
            continue;
        }
        let making = mistake.making();
        let renders =
            making == Making::Rendered || (making == Making::Quantised && linear.is_none());
        if renders && started.elapsed() + render_cost > budget {
            skipped.push(mistake);
            continue;
        }
        let t = Instant::now();
        let wrong = match make(mistake, r, &against, &mut linear, ctx.cancel) {
            Ok(Some(w)) => w,
            Ok(None) => continue,
            Err(e) => {
                d.notes.push(format!("Diagnosis stopped: {e}."));
                break;
            }
        };
        if renders {
            render_cost = t.elapsed();
        }
        let mask = failing_mask(&against, &wrong, r, tol);
        let failing = mask.iter().filter(|f| **f).count() as u64;
        tried.push((mistake, failing));
        if failing as f64 <= (1.0 - CONCLUSIVE_MATCH) * pixels as f64
            && failing as f64 <= CONCLUSIVE_LEFT * reference_failing as f64
        {
            break;
        }
    }
    if !skipped.is_empty() {
        d.notes.push(format!(
            "Not tried, to keep within {:.0} × the reference's render time: {}.",
            ctx.settings.time_factor,
            skipped
                .iter()
                .map(|m| m.id())
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    tried.sort_by_key(|&(_, f)| f);
    let limit_share = ((1.0 - MATCH_AT_LEAST) * pixels as f64).floor() as u64;
    let limit_left = (FAILURES_LEFT_AT_MOST * reference_failing as f64).floor() as u64;
    let qualifies = |f: u64| f <= limit_share && f <= limit_left && f < reference_failing;
    if let Some(&(_, best)) = tried.first()
        && qualifies(best)
    {
        d.mistakes = tried
            .iter()
            .filter(|&&(_, f)| qualifies(f) && f <= 2 * best)
            .map(|&(m, f)| Finding {
                mistake: m,
                title: m.title(),
                matches: share(f),
                explanation: m.explanation(),
                convention: m.convention(),
            })
            .collect();
    }
    d.tried = tried
        .iter()
        .map(|&(mistake, f)| Tried {
            mistake,
            matches: share(f),
        })
        .collect();
    d
}

/// The reference the submission failed against, as a wrong reference that is right.
fn reference_of(against: &Against) -> Wrong {
    match against {
        Against::Image { reference, .. } => Wrong::Image((*reference).clone()),
        Against::Hits { reference, .. } => Wrong::Hits(reference.to_vec()),
    }
}

/// Makes the wrong reference of `mistake`; the linear frame is rendered once, when the
/// first entry needs it.
fn make(
    mistake: Mistake,
    r: &Renderer,
    against: &Against,
    linear: &mut Option<Vec<glam::DVec3>>,
    cancel: &Cancel,
) -> Result<Option<Wrong>, GradeError> {
    let (w, h, gamma) = (r.scene.width, r.scene.height, r.scene.gamma);
    Ok(match (mistake.making(), against) {
        (Making::Moved, Against::Image { reference, .. }) => {
            wrong::moved_image(mistake, reference).map(Wrong::Image)
        }
        (Making::Moved, Against::Hits { reference, .. }) => {
            wrong::moved(mistake, reference, w, h).map(Wrong::Hits)
        }
        (Making::Channels, Against::Image { reference, .. }) => {
            Some(Wrong::Image(wrong::bgr(reference)))
        }
        (Making::Quantised, Against::Image { .. }) => {
            if linear.is_none() {
                *linear = Some(wrong::linear_frame(r, cancel)?);
            }
            linear
                .as_deref()
                .and_then(|l| wrong::quantised(mistake, l, w, h, gamma))
                .map(Wrong::Image)
        }
        (Making::Rendered, Against::Image { .. }) if mistake == Mistake::ShadowAcne => {
            let pictures = wrong::acne_linear(r, cancel)?;
            Some(Wrong::AnyOf(
                pictures
                    .iter()
                    .map(|l| wrong::to_image(l, w, h, gamma))
                    .collect(),
            ))
        }
        (Making::Rendered, Against::Image { .. }) => {
            match wrong::rendered_linear(mistake, r, cancel) {
                Some(l) => Some(Wrong::Image(wrong::to_image(&l?, w, h, gamma))),
                None => None,
            }
        }
        (Making::Rendered, Against::Hits { .. }) => {
            match wrong::rendered_hits(mistake, r, cancel) {
                Some(hits) => Some(Wrong::Hits(hits?)),
                None => None,
            }
        }
        _ => None,
    })
}

/// The diagnosis a report carries: `None` for a passing submission or when diagnosis is
/// off (or its pixel limit is 0), else [`diagnose`] against the reference it failed against.
pub fn for_report(
    r: &Renderer,
    report: &super::Report,
    against: Against,
    tol: &Tolerances,
    ctx: &Context,
) -> Option<Diagnosis> {
    (!report.pass && ctx.settings.enabled && ctx.settings.max_pixels > 0)
        .then(|| diagnose(r, against, tol, report.failing_pixels, ctx))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grade::{GradeOptions, Submission, grade};
    use crate::scene::{Limits, parse};
    use std::sync::Arc;

    fn showcase(w: u32, h: u32) -> Renderer {
        let path = format!("{}/scenes/showcase.json", env!("CARGO_MANIFEST_DIR"));
        let mut doc: serde_json::Value =
            serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
        doc["image"]["width"] = w.into();
        doc["image"]["height"] = h.into();
        let bytes = serde_json::to_vec(&doc).unwrap();
        Renderer::new(Arc::new(parse(&bytes, &Limits::NONE).unwrap()))
    }

    fn flipped(r: &Renderer) -> RgbImage {
        let img = crate::grade::reference_image(r, &Cancel::new()).unwrap();
        wrong::moved_image(Mistake::FlippedVertically, &img).unwrap()
    }

    #[test]
    fn a_frame_above_the_limit_is_not_diagnosed_and_the_report_says_so() {
        let r = showcase(40, 30);
        let opts = GradeOptions {
            diagnosis: Settings {
                max_pixels: 1199,
                ..Settings::default()
            },
            ..GradeOptions::default()
        };
        let tol = Tolerances::default();
        let rep = grade(&r, Submission::Image(flipped(&r).into()), &tol, &opts).unwrap();
        let d = rep.diagnosis.as_ref().unwrap();
        assert!(d.mistakes.is_empty() && d.tried.is_empty());
        assert!(
            d.notes[0].contains("1200 pixels, more than the 1199"),
            "{:?}",
            d.notes
        );
        let opts = GradeOptions {
            diagnosis: Settings {
                enabled: false,
                ..Settings::default()
            },
            ..GradeOptions::default()
        };
        let rep = grade(&r, Submission::Image(flipped(&r).into()), &tol, &opts).unwrap();
        assert_eq!(rep.diagnosis, None);
    }

    #[test]
    fn entries_past_the_time_budget_are_skipped_with_a_note() {
        let r = showcase(40, 30);
        let opts = GradeOptions {
            diagnosis: Settings {
                time_factor: 0.0,
                min_budget: Duration::ZERO,
                ..Settings::default()
            },
            ..GradeOptions::default()
        };
        // Flipped and in BGR order: no entry explains it, so every entry is wanted.
        let sub = wrong::bgr(&flipped(&r));
        let rep = grade(
            &r,
            Submission::Image(sub.into()),
            &Tolerances::default(),
            &opts,
        )
        .unwrap();
        let d = rep.diagnosis.as_ref().unwrap();
        assert!(d.mistakes.is_empty());
        // Moving and recolouring pixels costs no render: those are still tried.
        assert_eq!(d.tried.len(), 3);
        assert!(
            d.tried
                .iter()
                .all(|t| !matches!(t.mistake.making(), Making::Rendered | Making::Quantised))
        );
        assert!(
            d.notes[0].starts_with(
                "Not tried, to keep within 0 × the reference's render time: gamma_missing"
            ),
            "{:?}",
            d.notes
        );
    }

    #[test]
    fn an_entry_that_explains_all_ends_the_search() {
        let r = showcase(40, 30);
        let opts = GradeOptions::default();
        let rep = grade(
            &r,
            Submission::Image(flipped(&r).into()),
            &Tolerances::default(),
            &opts,
        )
        .unwrap();
        let d = rep.diagnosis.as_ref().unwrap();
        assert_eq!(d.mistakes[0].mistake, Mistake::FlippedVertically);
        assert_eq!(d.tried.len(), 1);
        assert!(d.notes.is_empty());
        // Blue and red exchanged as well: the flip alone no longer explains it, and every
        // entry is tried.
        let rep = grade(
            &r,
            Submission::Image(wrong::bgr(&flipped(&r)).into()),
            &Tolerances::default(),
            &opts,
        )
        .unwrap();
        assert!(rep.diagnosis.as_ref().unwrap().tried.len() > 10);
    }
}
