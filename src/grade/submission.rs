//! A student's submission, parsed: an image (any PNG) or per-pixel hit data in one of
//! the forms raytile itself writes (JSON, NDJSON, NPY, CSV).
//!
//! Each form is read by its file in [`crate::format`], where its layout is described;
//! here the form is chosen (from what the caller knows, a [`Hint`], or else from the
//! bytes) and a reader's [`ReadError`] becomes the [`GradeError`] a report or a problem
//! document shows. Nothing here trusts the bytes: every problem says where.

use serde::Deserialize;

use super::GradeError;
use super::image::RgbImage;
use crate::format::png::{self, PNG_SIGNATURE};
pub use crate::format::{Group, HitData, SubmittedHit};
use crate::format::{HitFormat, ReadError, csv, json, ndjson, npy};

/// What the caller knows about the submission's format (a file extension, a media type,
/// the command line's `--format`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Hint {
    /// Tell from the bytes.
    #[default]
    Auto,
    /// A PNG image.
    Png,
    /// One JSON document (or a bare array of pixels).
    Json,
    /// One JSON object per line.
    Ndjson,
    /// A NumPy `.npy` structured array.
    Npy,
    /// A CSV table with a header.
    Csv,
}

impl From<HitFormat> for Hint {
    fn from(f: HitFormat) -> Hint {
        match f {
            HitFormat::Json => Hint::Json,
            HitFormat::Ndjson => Hint::Ndjson,
            HitFormat::Npy => Hint::Npy,
            HitFormat::Csv => Hint::Csv,
        }
    }
}

impl Hint {
    /// The hint of a format name: `png`, `json`, `ndjson` (or `jsonl`), `npy`, `csv`, `auto`.
    pub fn from_name(s: &str) -> Option<Hint> {
        match s.trim().to_ascii_lowercase().as_str() {
            "auto" => Some(Hint::Auto),
            png::NAME => Some(Hint::Png),
            other => HitFormat::from_name(other).map(Hint::from),
        }
    }

    /// The hint of a file name's extension; [`Hint::Auto`] when it says nothing.
    pub fn from_path(p: &std::path::Path) -> Hint {
        p.extension()
            .and_then(|e| e.to_str())
            .and_then(Hint::from_name)
            .unwrap_or(Hint::Auto)
    }

    /// The hint of a media type (`image/png`, `application/json`, `application/x-ndjson`,
    /// `application/x-npy`, `text/csv`); [`Hint::Auto`] for anything else.
    pub fn from_media_type(t: &str) -> Hint {
        let essence = t.split(';').next().unwrap_or("").trim();
        if essence.eq_ignore_ascii_case(png::MEDIA_TYPE) {
            return Hint::Png;
        }
        HitFormat::from_media_type(t).map_or(Hint::Auto, Hint::from)
    }
}

/// A parsed submission.
#[derive(Debug, Clone, PartialEq)]
pub enum Submission {
    /// An image, converted to 8-bit RGB.
    Image(RgbImage),
    /// Per-pixel hit data.
    Hits(HitData),
}

impl Submission {
    /// Parses a submission's bytes; `hint` picks the parser, [`Hint::Auto`] tells from the
    /// content (PNG and NPY by their signatures, JSON by `{` or `[`, several JSON lines as
    /// NDJSON, else CSV with a header).
    pub fn parse(bytes: &[u8], hint: Hint) -> Result<Submission, GradeError> {
        Submission::parse_impl(bytes, hint, None)
    }

    /// [`Submission::parse`] for a scene of `width × height` pixels: a PNG of another
    /// size is refused from its header, before it is decompressed (what a server should
    /// call; hit data is checked against the frame when graded).
    pub fn parse_for_frame(
        bytes: &[u8],
        hint: Hint,
        width: u32,
        height: u32,
    ) -> Result<Submission, GradeError> {
        Submission::parse_impl(bytes, hint, Some((width, height)))
    }

    fn parse_impl(
        bytes: &[u8],
        hint: Hint,
        frame: Option<(u32, u32)>,
    ) -> Result<Submission, GradeError> {
        if bytes.iter().all(u8::is_ascii_whitespace) {
            return Err(GradeError::Empty);
        }
        let hint = match hint {
            Hint::Auto => detect(bytes)?,
            h => h,
        };
        let hits = match hint {
            Hint::Png => return Ok(Submission::Image(RgbImage::decode_png(bytes, frame)?)),
            Hint::Json => json::read(bytes),
            Hint::Ndjson => ndjson::read(bytes),
            Hint::Npy => npy::read(bytes),
            Hint::Csv => csv::read(bytes),
            Hint::Auto => return Err(GradeError::UnknownFormat),
        };
        Ok(Submission::Hits(hits?))
    }

    /// `"image"` or `"hits"`.
    pub fn kind(&self) -> &'static str {
        match self {
            Submission::Image(_) => "image",
            Submission::Hits(_) => "hits",
        }
    }
}

fn detect(bytes: &[u8]) -> Result<Hint, GradeError> {
    if bytes.starts_with(PNG_SIGNATURE) {
        return Ok(Hint::Png);
    }
    if bytes.starts_with(npy::NPY_MAGIC) {
        return Ok(Hint::Npy);
    }
    let text = bytes.trim_ascii_start();
    match text.first() {
        Some(b'[') => Ok(Hint::Json),
        Some(b'{') if ndjson::sniff(text) => Ok(Hint::Ndjson),
        Some(b'{') => Ok(Hint::Json),
        _ if csv::sniff(text) => Ok(Hint::Csv),
        _ => Err(GradeError::UnknownFormat),
    }
}

impl From<ReadError> for GradeError {
    /// A reader's error, in the grader's words where a submission is at fault for being
    /// the wrong thing (not a PNG, not the scene's size); the reader's own otherwise.
    fn from(e: ReadError) -> GradeError {
        match e {
            ReadError::NotPng => GradeError::NotPng,
            ReadError::SizeMismatch {
                width,
                height,
                expected_width,
                expected_height,
            } => GradeError::SizeMismatch {
                width,
                height,
                expected_width,
                expected_height,
            },
            other => GradeError::Unreadable(other),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::npy::{npy_header, npy_record};

    fn pixels(h: &HitData) -> Vec<SubmittedHit> {
        h.groups.iter().flat_map(|g| g.pixels.clone()).collect()
    }

    fn hits(bytes: &[u8]) -> HitData {
        match Submission::parse(bytes, Hint::Auto).unwrap() {
            Submission::Hits(h) => h,
            Submission::Image(_) => panic!("an image"),
        }
    }

    #[test]
    fn json_document_and_bare_array() {
        let doc = br#"{"width":2,"height":1,"region":{"x":0,"y":0,"width":2,"height":1},
            "pixels":[{"u":0,"v":0,"hit":false,"object":null,"name":null,"lambda":null,
            "point":null,"object_point":null,"normal":null,"face":null},
            {"u":1,"v":0,"hit":true,"object":0,"lambda":2.5,"normal":[0,0,-1]}]}"#;
        let h = hits(doc);
        assert_eq!(h.format, "json");
        assert_eq!(h.size, Some((2, 1)));
        let p = pixels(&h);
        assert_eq!(p[1].lambda, Some(2.5));
        assert_eq!(p[1].object, Some(0));
        let bare = hits(br#"[{"hit":false},{"hit":true,"lambda":1,"normal":[1,0,0]}]"#);
        assert_eq!(pixels(&bare).len(), 2);
        assert_eq!(pixels(&bare)[0].u, None);
    }

    #[test]
    fn ndjson_lines_become_groups() {
        let text = b"{\"tile\":{\"x\":0,\"y\":0,\"width\":1,\"height\":1},\"pixels\":[{\"u\":0,\"v\":0,\"hit\":false}]}\n\
                     {\"tile\":{\"x\":1,\"y\":0,\"width\":1,\"height\":1},\"pixels\":[{\"u\":1,\"v\":0,\"hit\":false}]}\n";
        let h = hits(text);
        assert_eq!(h.format, "ndjson");
        assert_eq!(h.groups.len(), 2);
    }

    #[test]
    fn json_errors_say_where() {
        let e = Submission::parse(br#"{"pixels":[{"hit":true,"lambda":"x"}]}"#, Hint::Auto)
            .unwrap_err();
        assert!(e.to_string().contains("pixels[0].lambda"), "{e}");
        let e = Submission::parse(br#"[{"hit":true,"lambda":1}]"#, Hint::Auto).unwrap_err();
        assert!(e.to_string().contains("`normal` is missing"), "{e}");
        let e = Submission::parse(br#"[{"hit":true,"lamda":1}]"#, Hint::Auto).unwrap_err();
        assert!(e.to_string().contains("lamda"), "{e}");
    }

    #[test]
    fn csv_with_header_and_empty_misses() {
        let text = b"u,v,hit,object,lambda,px,py,pz,nx,ny,nz\n\
                     0,0,0,,,,,,,,\n\
                     1,0,true,2,1.5,0,0,1.5,0,0,-1\n";
        let h = hits(text);
        let p = pixels(&h);
        assert_eq!(p.len(), 2);
        assert!(!p[0].hit);
        assert_eq!(p[1].object, Some(2));
        assert_eq!(p[1].normal, Some([0.0, 0.0, -1.0]));
        assert_eq!(p[1].point, Some([0.0, 0.0, 1.5]));
    }

    #[test]
    fn csv_missing_column_and_bad_value() {
        let e = Submission::parse(b"u,v,hit,lambda,nx,ny\n", Hint::Csv).unwrap_err();
        assert!(
            matches!(e, GradeError::Unreadable(ReadError::MissingField { ref field, .. }) if field == "nz"),
            "{e}"
        );
        let e =
            Submission::parse(b"u,v,hit,lambda,nx,ny,nz\n0,0,maybe,,,,\n", Hint::Csv).unwrap_err();
        assert!(e.to_string().contains("line 2"), "{e}");
    }

    #[test]
    fn npy_as_raytile_writes_it() {
        let mut b = npy_header(1, 2);
        npy_record(&mut b, 0, 0, &None);
        let s = crate::geometry::Surface {
            lambda: 2.0,
            object: 3,
            point: glam::DVec3::new(0.0, 0.0, 2.0),
            object_point: glam::DVec3::new(-1.0, 0.0, 0.0),
            normal: glam::DVec3::new(-1.0, 0.0, 0.0),
            front: true,
            face: None,
        };
        npy_record(&mut b, 1, 0, &Some(s));
        let h = hits(&b);
        assert_eq!(h.size, Some((2, 1)));
        let p = pixels(&h);
        assert!(!p[0].hit);
        assert_eq!(p[0].lambda, None);
        assert_eq!(p[1].object, Some(3));
        assert_eq!(p[1].lambda, Some(2.0));
        assert_eq!(p[1].normal, Some([-1.0, 0.0, 0.0]));
    }

    fn npy(descr: &str, shape: &str, data: &[u8]) -> Vec<u8> {
        let dict = format!("{{'descr': {descr}, 'fortran_order': False, 'shape': {shape}, }}\n");
        let mut b = b"\x93NUMPY\x01\x00".to_vec();
        b.extend_from_slice(&(dict.len() as u16).to_le_bytes());
        b.extend_from_slice(dict.as_bytes());
        b.extend_from_slice(data);
        b
    }

    #[test]
    fn npy_permuted_minimal_fields() {
        let mut rec = Vec::new();
        for x in [0.0f64, 0.0, 1.0] {
            rec.extend_from_slice(&x.to_le_bytes());
        }
        rec.extend_from_slice(&4.5f64.to_le_bytes());
        rec.push(1);
        let b = npy(
            "[('normal', '<f8', (3,)), ('lambda', '<f8'), ('hit', '?')]",
            "(1, 1)",
            &rec,
        );
        let p = pixels(&hits(&b));
        assert_eq!(p[0].lambda, Some(4.5));
        assert_eq!(p[0].normal, Some([0.0, 0.0, 1.0]));
        assert_eq!(p[0].object, None);
    }

    #[test]
    fn npy_errors() {
        let e = Submission::parse(
            &npy("[('hit', '?'), ('lambda', '<f8')]", "(1, 1)", &[0; 9]),
            Hint::Auto,
        )
        .unwrap_err();
        assert!(
            matches!(e, GradeError::Unreadable(ReadError::MissingField { ref field, .. }) if field == "normal"),
            "{e}"
        );
        let e = Submission::parse(&npy("'<f8'", "(2, 2)", &[0; 32]), Hint::Auto).unwrap_err();
        assert!(
            matches!(e, GradeError::Unreadable(ReadError::WrongShape(_))),
            "{e}"
        );
        let e = Submission::parse(
            &npy(
                "[('hit', '?'), ('lambda', '<f8'), ('normal', '<f8', (3,))]",
                "(4,)",
                &[0; 33],
            ),
            Hint::Auto,
        )
        .unwrap_err();
        assert!(
            matches!(e, GradeError::Unreadable(ReadError::WrongShape(_))),
            "{e}"
        );
        let e = Submission::parse(
            &npy(
                "[('hit', '?'), ('lambda', '<f8'), ('normal', '<f8', (3,))]",
                "(2, 2)",
                &[0; 33],
            ),
            Hint::Auto,
        )
        .unwrap_err();
        assert!(
            matches!(e, GradeError::Unreadable(ReadError::WrongShape(_))),
            "{e}"
        );
        let e = Submission::parse(b"\x93NUMPY\x01\x00\xff\x00{'descr", Hint::Auto).unwrap_err();
        assert!(
            matches!(e, GradeError::Unreadable(ReadError::Npy(_))),
            "{e}"
        );
    }

    #[test]
    fn detection_and_unknown_content() {
        assert!(matches!(
            Submission::parse(b"hello world", Hint::Auto),
            Err(GradeError::UnknownFormat)
        ));
        assert!(matches!(
            Submission::parse(b"  \n", Hint::Auto),
            Err(GradeError::Empty)
        ));
        assert!(matches!(
            Submission::parse(b"{}", Hint::Png),
            Err(GradeError::NotPng)
        ));
        assert_eq!(Hint::from_media_type("text/csv; charset=utf-8"), Hint::Csv);
        assert_eq!(Hint::from_path(std::path::Path::new("a/b.NPY")), Hint::Npy);
    }
}
