//! Hit data as one JSON document (`.json`, `application/json`), pixels in row-major
//! order, as `raytile hits` writes it:
//!
//! ```json
//! {"width": 5, "height": 5, "region": {"x": 0, "y": 0, "width": 5, "height": 5},
//!  "pixels": [{"u": 0, "v": 0, "hit": false}, {"u": 1, "v": 0, "hit": true, "object": 0,
//!              "lambda": 2.0, "normal": [-1, 0, 0]}]}
//! ```
//!
//! The writer gives every field of [`PixelHit`] (`null` when there is nothing), numbers
//! in their shortest round-trip form. The reader also takes a bare array of pixel
//! objects; `u`, `v` may be left out when the pixels are in row-major order, `object`
//! may be −1 for none, and any field [`PixelHit`] does not name is an error (a misspelt
//! `lamda` is caught). The pixel objects and their checks are shared with [`super::ndjson`].
//!
//! Numbers may also be `NaN`, `Infinity` or `-Infinity`, bare as Python's `json.dump`
//! writes them (or quoted), and `object` may be `NaN`: a NumPy tracer's miss
//! (`"lambda": NaN, "normal": [NaN, NaN, NaN]`) reads as a miss with nothing, and a hit
//! whose `λ` or normal is not finite reads as given and fails the comparison.

use std::io::{self, Write};

use serde::Deserialize;

use super::ReadError;
use super::hit::{Group, HitData, HitFormat, PixelHit, SubmittedHit};
use crate::render::Rect;

/// Writes the document's opening, up to the `[` of its pixels.
pub fn write_start(out: &mut impl Write, width: u32, height: u32, region: Rect) -> io::Result<()> {
    write!(out, "{{\"width\":{width},\"height\":{height},\"region\":")?;
    serde_json::to_writer(&mut *out, &region)?;
    out.write_all(b",\"pixels\":[")
}

/// Appends one pixel object to `buf`, after a comma unless it is the `first`.
pub fn push_pixel(buf: &mut Vec<u8>, first: &mut bool, p: &PixelHit) -> io::Result<()> {
    if !*first {
        buf.push(b',');
    }
    *first = false;
    serde_json::to_writer(buf, p).map_err(io::Error::other)
}

/// The document's closing bytes.
pub const END: &[u8] = b"]}\n";

/// Reads a document or a bare array of pixels.
pub fn read(bytes: &[u8]) -> Result<HitData, ReadError> {
    let format = HitFormat::Json;
    // A bare array of pixels, or a document; chosen by the first character so that an
    // error names the field at fault rather than "matched no variant".
    if bytes.trim_ascii_start().first() == Some(&b'[') {
        let pixels: Vec<PixelIn> = from_json(bytes, format, 0)?;
        return Ok(HitData {
            format: format.name(),
            size: None,
            groups: vec![group(None, pixels, 0)?],
        });
    }
    let d: DocIn = from_json(bytes, format, 0)?;
    let size = match (d.width, d.height) {
        (Some(w), Some(h)) => Some((w, h)),
        (None, None) => None,
        _ => {
            return Err(ReadError::WrongShape(
                "the document gives only one of `width` and `height`".into(),
            ));
        }
    };
    let rect = d.tile.or(d.region);
    Ok(HitData {
        format: format.name(),
        size,
        groups: vec![group(rect, d.pixels, 0)?],
    })
}

/// A number, or one of the non-finite words (see [`crate::json::non_finite`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct Num(f64);

impl<'de> Deserialize<'de> for Num {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Num, D::Error> {
        struct V;
        impl serde::de::Visitor<'_> for V {
            type Value = Num;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a number, NaN, Infinity or -Infinity")
            }
            fn visit_f64<E>(self, x: f64) -> Result<Num, E> {
                Ok(Num(x))
            }
            fn visit_i64<E>(self, x: i64) -> Result<Num, E> {
                Ok(Num(x as f64))
            }
            fn visit_u64<E>(self, x: u64) -> Result<Num, E> {
                Ok(Num(x as f64))
            }
            fn visit_str<E: serde::de::Error>(self, s: &str) -> Result<Num, E> {
                crate::json::non_finite(s)
                    .map(Num)
                    .ok_or_else(|| E::invalid_value(serde::de::Unexpected::Str(s), &self))
            }
        }
        d.deserialize_any(V)
    }
}

fn vec3(v: Option<[Num; 3]>) -> Option<[f64; 3]> {
    v.map(|v| v.map(|n| n.0))
}

/// The fields of a hit-data document (or NDJSON line), as its reader accepts them.
pub const DOCUMENT_FIELDS: [&str; 5] = ["width", "height", "region", "tile", "pixels"];

/// A pixel object as JSON and NDJSON carry it: the fields of [`PixelHit`].
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct PixelIn {
    #[serde(default)]
    u: Option<u32>,
    #[serde(default)]
    v: Option<u32>,
    hit: bool,
    /// −1 (as NPY writes it) and NaN are accepted for "none".
    #[serde(default)]
    object: Option<Num>,
    #[serde(default)]
    #[allow(dead_code)]
    name: Option<String>,
    #[serde(default)]
    lambda: Option<Num>,
    #[serde(default)]
    point: Option<[Num; 3]>,
    #[serde(default)]
    #[allow(dead_code)]
    object_point: Option<[Num; 3]>,
    #[serde(default)]
    normal: Option<[Num; 3]>,
    #[serde(default)]
    #[allow(dead_code)]
    face: Option<String>,
}

/// A JSON document or one NDJSON line.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct DocIn {
    #[serde(default)]
    pub width: Option<u32>,
    #[serde(default)]
    pub height: Option<u32>,
    #[serde(default)]
    pub region: Option<Rect>,
    #[serde(default)]
    pub tile: Option<Rect>,
    pub pixels: Vec<PixelIn>,
}

fn json_error(format: HitFormat, line_offset: usize) -> impl Fn(serde_json::Error) -> ReadError {
    move |e| ReadError::Syntax {
        format: format.title(),
        line: e.line() + line_offset,
        column: e.column(),
        message: crate::json::strip_position(&e.to_string()),
    }
}

/// Deserialises with the path of the offending field in the message; `line_offset` is
/// added to the line the parser reports (the lines before an NDJSON line).
pub(super) fn from_json<T: serde::de::DeserializeOwned>(
    bytes: &[u8],
    format: HitFormat,
    line_offset: usize,
) -> Result<T, ReadError> {
    crate::json::from_slice_non_finite(bytes).map_err(|f| {
        let mut err = json_error(format, line_offset)(f.error);
        if let (ReadError::Syntax { message, .. }, Some(path)) = (&mut err, f.path) {
            *message = format!("{path}: {message}");
        }
        err
    })
}

/// The pixels of a document or line (`line` is the NDJSON line, 0 for a document),
/// checked; without `u`, `v` they must fill `rect` exactly.
pub(super) fn group(
    rect: Option<Rect>,
    pixels: Vec<PixelIn>,
    line: usize,
) -> Result<Group, ReadError> {
    let at = |k: usize| {
        if line > 0 {
            format!("line {line}, pixels[{k}]")
        } else {
            format!("pixels[{k}]")
        }
    };
    let pixels = pixels
        .into_iter()
        .enumerate()
        .map(|(k, p)| {
            if p.u.is_some() != p.v.is_some() {
                return Err(ReadError::BadValue {
                    at: at(k),
                    message: "gives only one of `u` and `v`".into(),
                });
            }
            let object = match p.object.map(|o| o.0) {
                None => None,
                Some(o) if o.is_nan() || o < 0.0 => None,
                Some(o) if o.fract() == 0.0 && o <= u32::MAX as f64 => Some(o as u32),
                Some(o) => {
                    return Err(ReadError::BadValue {
                        at: at(k),
                        message: format!("`object` {o} is not a valid index"),
                    });
                }
            };
            let s = SubmittedHit {
                u: p.u,
                v: p.v,
                hit: p.hit,
                object,
                lambda: p.lambda.map(|l| l.0),
                point: vec3(p.point),
                normal: vec3(p.normal),
            };
            s.check(|| at(k))?;
            Ok(s)
        })
        .collect::<Result<Vec<_>, _>>()?;
    if let Some(r) = rect
        && pixels.iter().any(|p| p.u.is_none())
        && r.pixels() != pixels.len() as u64
    {
        return Err(ReadError::WrongShape(format!(
            "{} pixels without `u`, `v` cannot fill the {} × {} rectangle at ({}, {})",
            pixels.len(),
            r.width,
            r.height,
            r.x,
            r.y
        )));
    }
    Ok(Group { rect, pixels })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::hit::tests::sample_records;

    #[test]
    fn what_is_written_reads_back_the_same() {
        let records: Vec<PixelHit> = sample_records()
            .iter()
            .map(|(u, v, s)| PixelHit::from_surface(*u, *v, s, Some("ball")))
            .collect();
        let region = Rect::frame(2, 2);
        let mut out = Vec::new();
        write_start(&mut out, 2, 2, region).unwrap();
        let mut first = true;
        for p in &records {
            push_pixel(&mut out, &mut first, p).unwrap();
        }
        out.extend_from_slice(END);
        let back = read(&out).unwrap();
        assert_eq!(back.format, "json");
        assert_eq!(back.size, Some((2, 2)));
        let expected: Vec<SubmittedHit> = records.iter().map(SubmittedHit::from).collect();
        assert_eq!(
            back.groups,
            vec![Group {
                rect: Some(region),
                pixels: expected
            }]
        );
        // Every field survives serde as well, bit for bit.
        let doc: serde_json::Value = serde_json::from_slice(&out).unwrap();
        let again: Vec<PixelHit> = serde_json::from_value(doc["pixels"].clone()).unwrap();
        assert_eq!(again, records);
    }

    #[test]
    fn python_s_non_finite_numbers_and_null_mark_a_miss() {
        // What `json.dump` writes for a NumPy tracer's miss and hit.
        let text = br#"[{"u": 0, "v": 0, "hit": false, "object": NaN, "lambda": NaN,
            "point": [NaN, NaN, NaN], "normal": [NaN, -Infinity, Infinity]},
            {"u": 1, "v": 0, "hit": false, "object": null, "lambda": null, "normal": null},
            {"u": 2, "v": 0, "hit": true, "object": 1, "lambda": Infinity, "normal": [0, 0, -1]},
            {"u": 3, "v": 0, "hit": true, "object": 2.0, "lambda": "NaN", "normal": [0, 0, -1]}]"#;
        let h = read(text).unwrap();
        let p = &h.groups[0].pixels;
        assert!(!p[0].hit && p[0].object.is_none());
        assert!(p[0].lambda.unwrap().is_nan());
        assert_eq!(p[0].normal.unwrap()[1], f64::NEG_INFINITY);
        assert_eq!((p[1].object, p[1].lambda), (None, None));
        assert_eq!(p[2].lambda, Some(f64::INFINITY));
        assert_eq!(p[3].object, Some(2));
        assert!(p[3].lambda.unwrap().is_nan());
        let e = read(br#"[{"hit": true, "object": 1.5, "lambda": 1, "normal": [0, 0, 1]}]"#)
            .unwrap_err();
        assert!(
            e.to_string().contains("`object` 1.5 is not a valid index"),
            "{e}"
        );
        let e = read(br#"[{"hit": false, "lambda": "far"}]"#).unwrap_err();
        assert!(
            e.to_string()
                .contains("expected a number, NaN, Infinity or -Infinity"),
            "{e}"
        );
        // The column of an error after a NaN is the one in the text as sent.
        let column = |text: &[u8]| match read(text).unwrap_err() {
            ReadError::Syntax {
                line: 1, column, ..
            } => column,
            e => panic!("{e:?}"),
        };
        assert_eq!(
            column(br#"[{"hit": false, "lambda": NaN, "x": 1}]"#),
            column(br#"[{"hit": false, "lambda": 1.0, "x": 1}]"#)
        );
    }

    #[test]
    fn a_document_gives_both_sides_or_neither() {
        let e = read(br#"{"width":2,"pixels":[]}"#).unwrap_err();
        assert!(matches!(e, ReadError::WrongShape(_)), "{e}");
    }
}
