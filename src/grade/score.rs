//! The score: how much of an assignment's marks a submission earns, from 0 to 1, and
//! how it was reached, written out with its numbers ([`Score::formula`]).
//!
//! The verdict (`pass`) is always the tolerances' (at most `max_fail_share` of the pixels
//! fail); the scoring mode only decides the marks:
//!
//! | mode | score |
//! | --- | --- |
//! | `all-or-nothing` | 1 on a pass, 0 on a fail |
//! | `linear` | 1 at or below `max_fail_share` failing, 0 at or above `zero_share`, linear between |
//! | `error` | `max(0, 1 − error_k · e)`, `e` the mean colour error as a share of 255 |
//!
//! Hit data is scored per kind of check (hit/miss, object, λ, normal), each kind by its own
//! failing share, and the kinds are weighted ([`HitWeights`]); in `error` mode a kind's
//! mean error is its failing share (a pixel's error is 0 or 1). `all-or-nothing` follows the
//! verdict, whatever the weights.

use serde::{Deserialize, Serialize};

use super::compare::HitCounts;
use super::{GradeError, Tolerances};

/// How a submission's marks are computed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum ScoringMode {
    /// Full marks on a pass, none on a fail.
    #[default]
    AllOrNothing,
    /// Full marks up to `max_fail_share` failing pixels, none from `zero_share` on,
    /// linear between.
    Linear,
    /// `max(0, 1 − error_k · mean colour error)`.
    Error,
}

impl ScoringMode {
    /// The name used on the command line, in query strings and in documents.
    pub fn name(self) -> &'static str {
        match self {
            ScoringMode::AllOrNothing => "all-or-nothing",
            ScoringMode::Linear => "linear",
            ScoringMode::Error => "error",
        }
    }

    /// The mode named `name`, if any.
    pub fn from_name(name: &str) -> Option<ScoringMode> {
        [
            ScoringMode::AllOrNothing,
            ScoringMode::Linear,
            ScoringMode::Error,
        ]
        .into_iter()
        .find(|m| m.name() == name)
    }
}

/// The weights of the kinds of hit-data check in a hit-data score (each ≥ 0, not all 0;
/// default 1 each, so each kind is a quarter of the marks).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HitWeights {
    /// Hit where the reference misses, or the reverse.
    pub hit_miss: f64,
    /// The object hit.
    pub object: f64,
    /// `λ`.
    pub lambda: f64,
    /// The normal.
    pub normal: f64,
}

impl Default for HitWeights {
    fn default() -> Self {
        HitWeights {
            hit_miss: 1.0,
            object: 1.0,
            lambda: 1.0,
            normal: 1.0,
        }
    }
}

/// The scoring settings. Every field has a default; unknown fields are an error.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Scoring {
    /// The mode (default `all-or-nothing`).
    pub scoring: ScoringMode,
    /// `linear`: the failing share at and above which the score is 0 (default 0.05,
    /// i.e. 5 %); it must exceed `max_fail_share`.
    pub zero_share: f64,
    /// `error`: `k` of `max(0, 1 − k · e)` (default 10: a mean error of 10 % of full
    /// scale, 25.5/255, scores 0).
    pub error_k: f64,
    /// Hit data: the weights of the kinds of check.
    pub weights: HitWeights,
}

impl Default for Scoring {
    fn default() -> Self {
        Scoring {
            scoring: ScoringMode::AllOrNothing,
            zero_share: 0.05,
            error_k: 10.0,
            weights: HitWeights::default(),
        }
    }
}

impl Scoring {
    /// Checks the ranges against the tolerances they go with: `zero_share` in
    /// `(max_fail_share, 1]` (in `linear` mode), `error_k` finite and ≥ 0, every weight
    /// finite and ≥ 0 and their sum positive.
    pub fn check(&self, tol: &Tolerances) -> Result<(), GradeError> {
        let bad =
            |field: &'static str, message: String| Err(GradeError::BadScoring { field, message });
        if !(self.zero_share > 0.0 && self.zero_share <= 1.0) {
            return bad("zero_share", "must be greater than 0 and at most 1".into());
        }
        if self.scoring == ScoringMode::Linear && self.zero_share <= tol.max_fail_share {
            return bad(
                "zero_share",
                format!(
                    "must be greater than max_fail_share ({}) for linear scoring",
                    tol.max_fail_share
                ),
            );
        }
        if !(self.error_k >= 0.0 && self.error_k.is_finite()) {
            return bad("error_k", "must be a finite number ≥ 0".into());
        }
        let w = self.weights;
        for (field, x) in [
            ("weights.hit_miss", w.hit_miss),
            ("weights.object", w.object),
            ("weights.lambda", w.lambda),
            ("weights.normal", w.normal),
        ] {
            if !(x >= 0.0 && x.is_finite()) {
                return bad(field, "must be a finite number ≥ 0".into());
            }
        }
        if w.hit_miss + w.object + w.lambda + w.normal <= 0.0 {
            return bad("weights", "must not all be 0".into());
        }
        Ok(())
    }
}

/// Scoring settings set one by one over others: the command line's `--scoring`,
/// `--zero-share`, `--error-k` and `--weight-*`, and the query parameters of the same
/// names (with `_`) on `POST /v1/grade`. Each field left `None` keeps the value beneath.
#[derive(Debug, Clone, Copy, Default, PartialEq, clap::Args)]
pub struct ScoringOverrides {
    /// How the score is computed: all-or-nothing (default), linear, error.
    #[arg(long, value_enum)]
    pub scoring: Option<ScoringMode>,
    /// Linear scoring: the failing share, 0–1, at which the score reaches 0 (default 0.05).
    #[arg(long)]
    pub zero_share: Option<f64>,
    /// Error scoring: k in max(0, 1 − k · mean colour error) (default 10).
    #[arg(long)]
    pub error_k: Option<f64>,
    /// Hit data: weight of the hit/miss check (default 1).
    #[arg(long)]
    pub weight_hit_miss: Option<f64>,
    /// Hit data: weight of the object check (default 1).
    #[arg(long)]
    pub weight_object: Option<f64>,
    /// Hit data: weight of the λ check (default 1).
    #[arg(long)]
    pub weight_lambda: Option<f64>,
    /// Hit data: weight of the normal check (default 1).
    #[arg(long)]
    pub weight_normal: Option<f64>,
}

impl ScoringOverrides {
    /// `base` with the settings these set.
    pub fn apply(&self, base: Scoring) -> Scoring {
        let w = base.weights;
        Scoring {
            scoring: self.scoring.unwrap_or(base.scoring),
            zero_share: self.zero_share.unwrap_or(base.zero_share),
            error_k: self.error_k.unwrap_or(base.error_k),
            weights: HitWeights {
                hit_miss: self.weight_hit_miss.unwrap_or(w.hit_miss),
                object: self.weight_object.unwrap_or(w.object),
                lambda: self.weight_lambda.unwrap_or(w.lambda),
                normal: self.weight_normal.unwrap_or(w.normal),
            },
        }
    }
}

/// One part of a score: a check and the share of the marks it carries. The parts'
/// `points` add up to the score.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ScorePart {
    /// `colour` for images; `hits` (all or nothing), or `hit_miss`, `object`, `lambda`,
    /// `normal` for hit data.
    pub check: &'static str,
    /// The check's name as the grader formats show it.
    pub name: &'static str,
    /// The share of the marks it carries, 0–1 (the parts' weights add up to 1).
    pub weight: f64,
    /// Its own score, 0–1.
    pub score: f64,
    /// `weight × score`.
    pub points: f64,
    /// How its score was reached, with the numbers.
    pub formula: String,
}

/// A submission's score and how it was reached.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Score {
    /// The mode.
    pub scoring: ScoringMode,
    /// The score, 0–1: the sum of the parts' points.
    pub value: f64,
    /// How it was reached, with the numbers.
    pub formula: String,
    /// Its parts.
    pub parts: Vec<ScorePart>,
    /// The settings applied.
    pub settings: Scoring,
}

/// What a score is computed from.
#[derive(Debug, Clone, Copy)]
pub struct Counts<'a> {
    /// Pixels of the frame.
    pub pixels: u64,
    /// Pixels that fail (after edge forgiveness).
    pub failing: u64,
    /// The most that may fail for a pass.
    pub max_failing: u64,
    /// Hit data: failing pixels per check.
    pub hits: Option<&'a HitCounts>,
    /// Images: the mean absolute colour error over all channels, 0–255.
    pub mean_abs_error: Option<f64>,
}

/// A number in a formula: up to 4 decimals, trailing zeros dropped.
pub fn short(x: f64) -> String {
    // Small numbers keep four significant digits, so a share of 0.00005 stays readable.
    let digits = if x != 0.0 && x.abs() < 1.0 {
        (3 - x.abs().log10().floor() as i32).clamp(4, 12) as usize
    } else {
        4
    };
    let s = format!("{x:.digits$}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" { "0".into() } else { s.into() }
}

fn percent(share: f64) -> String {
    format!("{} %", short(share * 100.0))
}

/// The linear score of `failing` pixels (share `share`): 1 up to `max_failing`, 0 from
/// `zero_share` on.
fn linear(failing: u64, max_failing: u64, share: f64, a: f64, b: f64) -> (f64, String) {
    if failing <= max_failing {
        (
            1.0,
            format!("{failing} failing ≤ {max_failing} allowed → 1"),
        )
    } else if share >= b {
        (
            0.0,
            format!(
                "failing share {} ≥ zero_share {} → 0",
                percent(share),
                percent(b)
            ),
        )
    } else {
        let s = ((b - share) / (b - a)).clamp(0.0, 1.0);
        (
            s,
            format!(
                "(zero_share − share) / (zero_share − max_fail_share) = ({} − {}) / ({} − {}) = {}",
                short(b),
                short(share),
                short(b),
                short(a),
                short(s)
            ),
        )
    }
}

/// `max(0, 1 − k · e)` and its formula.
fn by_error(k: f64, e: f64, what: &str) -> (f64, String) {
    let s = (1.0 - k * e).max(0.0);
    (
        s,
        format!(
            "max(0, 1 − k · {what}) = max(0, 1 − {} × {}) = {}",
            short(k),
            short(e),
            short(s)
        ),
    )
}

/// The score of a comparison under `s` and `tol` (checked already).
pub fn score(s: &Scoring, tol: &Tolerances, c: Counts<'_>) -> Score {
    let pass = c.failing <= c.max_failing;
    let n = c.pixels.max(1) as f64;
    let share = c.failing as f64 / n;
    let verdict = |check: &'static str, name: &'static str| ScorePart {
        check,
        name,
        weight: 1.0,
        score: if pass { 1.0 } else { 0.0 },
        points: if pass { 1.0 } else { 0.0 },
        formula: format!(
            "{} failing {} {} allowed → {}",
            c.failing,
            if pass { "≤" } else { ">" },
            c.max_failing,
            if pass { 1 } else { 0 }
        ),
    };
    let parts = match (s.scoring, c.hits) {
        (ScoringMode::AllOrNothing, None) => vec![verdict("colour", "Matches the reference")],
        (ScoringMode::AllOrNothing, Some(_)) => vec![verdict("hits", "Matches the reference")],
        (mode, None) => {
            let (score, formula) = match mode {
                ScoringMode::Linear => {
                    let (v, f) = linear(
                        c.failing,
                        c.max_failing,
                        share,
                        tol.max_fail_share,
                        s.zero_share,
                    );
                    (v, f)
                }
                _ => {
                    let m = c.mean_abs_error.unwrap_or(0.0);
                    let e = m / 255.0;
                    let (v, f) = by_error(s.error_k, e, "e");
                    (
                        v,
                        format!(
                            "e = mean colour error / 255 = {}/255 = {}; {f}",
                            short(m),
                            short(e)
                        ),
                    )
                }
            };
            vec![ScorePart {
                check: "colour",
                name: "Matches the reference",
                weight: 1.0,
                score,
                points: score,
                formula,
            }]
        }
        (mode, Some(h)) => {
            let w = s.weights;
            let total = w.hit_miss + w.object + w.lambda + w.normal;
            [
                ("hit_miss", "Hit or miss", w.hit_miss, h.hit_miss),
                ("object", "Object hit", w.object, h.wrong_object),
                ("lambda", "λ within tolerance", w.lambda, h.lambda),
                ("normal", "Normal within tolerance", w.normal, h.normal),
            ]
            .into_iter()
            .map(|(check, name, weight, failing)| {
                let share = failing as f64 / n;
                let (score, formula) = match mode {
                    ScoringMode::Linear => {
                        let (v, f) = linear(
                            failing,
                            c.max_failing,
                            share,
                            tol.max_fail_share,
                            s.zero_share,
                        );
                        (v, f)
                    }
                    _ => {
                        let (v, f) = by_error(s.error_k, share, "share");
                        (
                            v,
                            format!(
                                "share = {failing} failing / {} pixels = {}; {f}",
                                c.pixels,
                                short(share)
                            ),
                        )
                    }
                };
                let weight = weight / total;
                ScorePart {
                    check,
                    name,
                    weight,
                    score,
                    points: weight * score,
                    formula,
                }
            })
            .collect()
        }
    };
    // The sum in the parts' order, so that a reader adding the parts' points (or the
    // tests' points of a grader format) gets exactly this number.
    let value = parts.iter().fold(0.0, |acc, p| acc + p.points);
    let formula = if parts.len() == 1 {
        format!("{}: {}", s.scoring.name(), parts[0].formula)
    } else {
        let terms: Vec<String> = parts
            .iter()
            .map(|p| format!("{} × {}", short(p.weight), short(p.score)))
            .collect();
        format!(
            "{}: Σ weight × part score = {} = {}",
            s.scoring.name(),
            terms.join(" + "),
            short(value)
        )
    };
    Score {
        scoring: s.scoring,
        value,
        formula,
        parts,
        settings: *s,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(s: &Scoring, failing: u64, mean: f64) -> Score {
        let tol = Tolerances::default();
        score(
            s,
            &tol,
            Counts {
                pixels: 10_000,
                failing,
                max_failing: 10,
                hits: None,
                mean_abs_error: Some(mean),
            },
        )
    }

    fn mode(m: ScoringMode) -> Scoring {
        Scoring {
            scoring: m,
            ..Default::default()
        }
    }

    #[test]
    fn all_or_nothing_follows_the_verdict() {
        let s = mode(ScoringMode::AllOrNothing);
        assert_eq!(image(&s, 10, 50.0).value, 1.0);
        let fail = image(&s, 11, 0.1);
        assert_eq!(fail.value, 0.0);
        assert!(
            fail.formula.contains("11 failing > 10 allowed → 0"),
            "{}",
            fail.formula
        );
    }

    #[test]
    fn linear_falls_from_the_allowed_share_to_zero_share() {
        let s = mode(ScoringMode::Linear);
        assert_eq!(image(&s, 10, 0.0).value, 1.0);
        // 2.55 % failing, halfway between 0.1 % and 5 %.
        let half = image(&s, 255, 0.0);
        assert!((half.value - 0.5).abs() < 1e-12, "{}", half.value);
        assert!(
            half.formula
                .contains("(0.05 − 0.0255) / (0.05 − 0.001) = 0.5"),
            "{}",
            half.formula
        );
        assert_eq!(image(&s, 500, 0.0).value, 0.0);
        assert_eq!(image(&s, 9000, 0.0).value, 0.0);
    }

    #[test]
    fn error_falls_with_the_mean_colour_error() {
        let s = mode(ScoringMode::Error);
        assert_eq!(image(&s, 0, 0.0).value, 1.0);
        // A mean error of 5.1/255 = 0.02: 1 − 10 × 0.02 = 0.8.
        let e = image(&s, 9000, 5.1);
        assert!((e.value - 0.8).abs() < 1e-12, "{}", e.value);
        assert!(e.formula.contains("1 − 10 × 0.02) = 0.8"), "{}", e.formula);
        assert_eq!(image(&s, 9000, 200.0).value, 0.0);
    }

    #[test]
    fn hit_data_weighs_the_kinds_and_the_points_add_up() {
        let counts = HitCounts {
            hit_miss: 0,
            wrong_object: 0,
            lambda: 255,
            normal: 10_000,
            max_lambda_rel_error: None,
            mean_lambda_rel_error: None,
            max_normal_angle_degrees: None,
            both_hit: 10_000,
        };
        let s = Scoring {
            scoring: ScoringMode::Linear,
            weights: HitWeights {
                hit_miss: 2.0,
                object: 0.0,
                lambda: 1.0,
                normal: 1.0,
            },
            ..Default::default()
        };
        let r = score(
            &s,
            &Tolerances::default(),
            Counts {
                pixels: 10_000,
                failing: 10_000,
                max_failing: 10,
                hits: Some(&counts),
                mean_abs_error: None,
            },
        );
        let weights: Vec<f64> = r.parts.iter().map(|p| p.weight).collect();
        assert_eq!(weights, vec![0.5, 0.0, 0.25, 0.25]);
        // hit/miss 1, object 1 (weight 0), λ 0.5, normal 0.
        assert!((r.value - (0.5 + 0.125)).abs() < 1e-12, "{}", r.value);
        let sum = r.parts.iter().fold(0.0, |a, p| a + p.points);
        assert_eq!(sum, r.value);
        assert!(
            r.formula
                .contains("0.5 × 1 + 0 × 1 + 0.25 × 0.5 + 0.25 × 0"),
            "{}",
            r.formula
        );

        let e = score(
            &Scoring {
                scoring: ScoringMode::Error,
                ..Default::default()
            },
            &Tolerances::default(),
            Counts {
                pixels: 10_000,
                failing: 10_000,
                max_failing: 10,
                hits: Some(&counts),
                mean_abs_error: None,
            },
        );
        // λ: 1 − 10 × 0.0255 = 0.745; normal: 0.
        assert!(
            (e.value - 0.25 * (1.0 + 1.0 + 0.745)).abs() < 1e-12,
            "{}",
            e.value
        );
    }

    #[test]
    fn settings_are_checked() {
        let tol = Tolerances::default();
        assert!(Scoring::default().check(&tol).is_ok());
        let linear = |z| Scoring {
            scoring: ScoringMode::Linear,
            zero_share: z,
            ..Default::default()
        };
        assert!(linear(0.001).check(&tol).is_err());
        assert!(linear(1.5).check(&tol).is_err());
        assert!(linear(0.002).check(&tol).is_ok());
        let bad_k = Scoring {
            error_k: f64::NAN,
            ..Default::default()
        };
        assert!(bad_k.check(&tol).is_err());
        let none = Scoring {
            weights: HitWeights {
                hit_miss: 0.0,
                object: 0.0,
                lambda: 0.0,
                normal: 0.0,
            },
            ..Default::default()
        };
        assert!(matches!(
            none.check(&tol),
            Err(GradeError::BadScoring {
                field: "weights",
                ..
            })
        ));
        let s: Scoring =
            serde_json::from_str(r#"{"scoring": "linear", "zero_share": 0.2}"#).unwrap();
        assert_eq!(s.scoring, ScoringMode::Linear);
        assert!(serde_json::from_str::<Scoring>(r#"{"scoring": "curve"}"#).is_err());
        assert_eq!(
            ScoringMode::from_name("all-or-nothing"),
            Some(ScoringMode::AllOrNothing)
        );
        assert_eq!(ScoringMode::from_name("x"), None);
    }
}
