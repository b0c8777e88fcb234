//! How a diagnosis is written in each form of the report (text, the Gradescope and
//! PrairieLearn messages; the JSON is its `Serialize`), the likely cause of an image of
//! the wrong size, and the legend of the hit-data difference image.

use std::fmt::Write as _;

use super::Diagnosis;
use crate::grade::compare::FAIL_RGB;
use crate::grade::legend::{LAMBDA_RGB, NORMAL_RGB, OBJECT_RGB};

fn percent(share: f64) -> String {
    let p = 100.0 * share;
    if p >= 99.95 && share < 1.0 {
        // Never round a mismatch up to a perfect match.
        format!("{:.2} %", (p * 100.0).floor() / 100.0)
    } else {
        format!("{p:.1} %")
    }
}

/// The diagnosis as lines of the text report; empty when there is none.
pub fn text(d: Option<&Diagnosis>) -> String {
    let Some(d) = d else {
        return String::new();
    };
    let mut o = String::new();
    if d.mistakes.is_empty() {
        if !d.tried.is_empty() {
            let _ = writeln!(
                o,
                "Diagnosis: none of the {} classic mistakes tried explains the submission (the closest, {}, matches {} of pixels; the reference {}).",
                d.tried.len(),
                d.tried[0].mistake.title(),
                percent(d.tried[0].matches),
                percent(d.reference_matches)
            );
        }
    } else {
        if d.mistakes.len() > 1 {
            let _ = writeln!(
                o,
                "Diagnosis: {} mistakes explain the submission equally well in this scene:",
                d.mistakes.len()
            );
        }
        for f in &d.mistakes {
            let _ = writeln!(
                o,
                "Diagnosis: {} — this explains the submission: it matches {} of pixels, the reference {}.",
                f.title,
                percent(f.matches),
                percent(d.reference_matches)
            );
            let _ = writeln!(o, "  {}", f.explanation);
            let _ = writeln!(o, "  See {}.", f.convention);
        }
    }
    for n in &d.notes {
        let _ = writeln!(o, "Diagnosis: {n}");
    }
    o
}

/// The diagnosis in one sentence to follow a verdict (PrairieLearn's `message`, the
/// Gradescope test's output); empty when nothing was named.
pub fn message_suffix(d: Option<&Diagnosis>) -> String {
    match d.map(|d| (d, d.mistakes.as_slice())) {
        Some((d, [f, ..])) => format!(
            " Likely mistake: {} (matches {} of pixels, the reference {}). {} See {}.",
            f.title,
            percent(f.matches),
            percent(d.reference_matches),
            f.explanation,
            f.convention
        ),
        _ => String::new(),
    }
}

/// The likely cause of a submission of `width × height` pixels where the scene renders
/// `ew × eh`, from the sizes alone; `None` when no classic mistake gives that size.
pub fn size_cause(width: u32, height: u32, ew: u32, eh: u32) -> Option<String> {
    let (w, h) = (width as u64, height as u64);
    let (ew, eh) = (ew as u64, eh as u64);
    if (w, h) == (eh, ew) {
        return Some(
            "width and height are swapped: the image has the scene's height as its width. \
             Check the order of the loops over rows and columns, and an array's shape, \
             which is (height, width)"
                .into(),
        );
    }
    let round_div = |a: u64, b: u64| (2 * a + b) / (2 * b.max(1));
    if ew != eh && (w, h) == (ew, round_div(ew * ew, eh)) {
        return Some(
            "the height was computed from the aspect ratio the wrong way round \
             (w · w/h instead of h, or h from the aspect of h instead of w)"
                .into(),
        );
    }
    if ew != eh && (w, h) == (round_div(eh * eh, ew), eh) {
        return Some(
            "the width was computed from the aspect ratio the wrong way round \
             (h · h/w instead of w)"
                .into(),
        );
    }
    let off = |a: u64, b: u64| a.abs_diff(b) <= 1;
    if off(w, ew) && off(h, eh) {
        return Some(
            "one pixel too many or too few: the pixels run u = 0 … w−1 and v = 0 … h−1 \
             (a loop to w inclusive, or from 1, is off by one)"
                .into(),
        );
    }
    if w > ew && w % ew == 0 && h == eh * (w / ew) {
        let k = w / ew;
        return Some(format!(
            "{k} times the size in each direction: each sample of a {k} × {k} grid was \
             written as a pixel of its own; a pixel's colour is the mean of its samples"
        ));
    }
    None
}

/// [`size_cause`] as the end of the size-mismatch error: `" (likely cause: …)"`.
pub fn size_note(width: &u32, height: &u32, ew: &u32, eh: &u32) -> String {
    size_cause(*width, *height, *ew, *eh).map_or(String::new(), |c| format!("; likely cause: {c}"))
}

/// The hit-data difference image's legend: each kind of disagreement and its colour, in
/// the order of precedence (a pixel shows the first it fails; see
/// [`hit_diff_colour`](crate::grade::legend::hit_diff_colour)).
pub const HIT_DIFF_LEGEND: [(&str, [u8; 3]); 4] = [
    ("hit where the reference misses, or the reverse", FAIL_RGB),
    ("another object", OBJECT_RGB),
    ("λ out of tolerance", LAMBDA_RGB),
    ("normal out of tolerance", NORMAL_RGB),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_and_their_causes() {
        assert!(size_cause(480, 640, 640, 480).unwrap().contains("swapped"));
        assert!(size_cause(640, 853, 640, 480).unwrap().contains("aspect"));
        assert!(
            size_cause(639, 480, 640, 480)
                .unwrap()
                .contains("off by one")
        );
        assert!(
            size_cause(1280, 960, 640, 480)
                .unwrap()
                .starts_with("2 times")
        );
        assert_eq!(size_cause(100, 100, 640, 480), None);
        assert_eq!(size_note(&100, &100, &640, &480), "");
        assert!(size_note(&480, &640, &640, &480).starts_with("; likely cause: width"));
    }

    #[test]
    fn the_legend_has_one_colour_per_kind() {
        let colours: Vec<_> = HIT_DIFF_LEGEND.iter().map(|l| l.1).collect();
        for (i, a) in colours.iter().enumerate() {
            assert!(colours[i + 1..].iter().all(|b| b != a));
        }
    }

    #[test]
    fn percentages_never_round_up_to_a_match() {
        assert_eq!(percent(0.99999), "99.99 %");
        assert_eq!(percent(1.0), "100.0 %");
        assert_eq!(percent(0.4567), "45.7 %");
    }
}
