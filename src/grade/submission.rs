//! A student's submission, parsed: an image (PNG, PPM, BMP, TGA, JPEG; PFM and OpenEXR
//! in linear floats) or per-pixel hit data in one of the forms raytile itself writes
//! (JSON, NDJSON, NPY, CSV).
//!
//! Each form is read by its file in [`crate::format`], where its layout is described;
//! here the form is chosen and a reader's [`ReadError`] becomes the [`GradeError`] a
//! report or a problem document shows. Binary forms are told by their content (a file
//! named `.png` that holds a JPEG is read as the JPEG it is); a [`Hint`] (what the caller
//! knows: a file extension, a media type, `--format`) chooses among the text forms and
//! names the image format expected when the content has no signature. Nothing here
//! trusts the bytes: every problem says where.

use serde::Deserialize;

use super::GradeError;
use super::image::RgbImage;
use crate::format::{
    DecodeLimits, HitFormat, LinearImage, Raster, RasterFormat, ReadError, csv, json, ndjson, npy,
};
pub use crate::format::{Group, HitData, SubmittedHit};

/// Every accepted form, as the error for unrecognised content names them.
pub const ACCEPTED: &str = "an image as PNG, PPM (or PGM, PBM, PAM), BMP, TGA, JPEG, PFM or \
     OpenEXR, or hit data as JSON, NDJSON, NPY or CSV (with a header)";

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
    /// A Netpbm image: PPM (P3, P6), PGM, PBM or PAM.
    Ppm,
    /// A BMP image.
    Bmp,
    /// A TGA image.
    Tga,
    /// A JPEG image.
    Jpeg,
    /// A PFM float image (linear).
    Pfm,
    /// An OpenEXR float image (linear).
    Exr,
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

impl From<RasterFormat> for Hint {
    fn from(f: RasterFormat) -> Hint {
        match f {
            RasterFormat::Png => Hint::Png,
            RasterFormat::Pnm => Hint::Ppm,
            RasterFormat::Bmp => Hint::Bmp,
            RasterFormat::Tga => Hint::Tga,
            RasterFormat::Jpeg => Hint::Jpeg,
            RasterFormat::Pfm => Hint::Pfm,
            RasterFormat::Exr => Hint::Exr,
        }
    }
}

impl Hint {
    /// The hint of a format name or extension: an image's (`png`, `ppm`, `pgm`, `bmp`,
    /// `tga`, `jpg`, `jpeg`, `pfm`, `exr`, …), hit data's (`json`, `ndjson` or `jsonl`,
    /// `npy`, `csv`), or `auto`.
    pub fn from_name(s: &str) -> Option<Hint> {
        match s.trim().to_ascii_lowercase().as_str() {
            "auto" => Some(Hint::Auto),
            other => RasterFormat::from_name(other)
                .map(Hint::from)
                .or_else(|| HitFormat::from_name(other).map(Hint::from)),
        }
    }

    /// The hint of a file name's extension; [`Hint::Auto`] when it says nothing.
    pub fn from_path(p: &std::path::Path) -> Hint {
        p.extension()
            .and_then(|e| e.to_str())
            .and_then(Hint::from_name)
            .unwrap_or(Hint::Auto)
    }

    /// The hint of a media type (`image/png`, `image/x-portable-pixmap`, `image/jpeg`,
    /// `image/x-exr`, …, `application/json`, `application/x-ndjson`,
    /// `application/x-npy`, `text/csv`); [`Hint::Auto`] for anything else.
    pub fn from_media_type(t: &str) -> Hint {
        RasterFormat::from_media_type(t)
            .map(Hint::from)
            .or_else(|| HitFormat::from_media_type(t).map(Hint::from))
            .unwrap_or(Hint::Auto)
    }

    /// The image format it names, if any.
    pub fn raster(self) -> Option<RasterFormat> {
        Some(match self {
            Hint::Png => RasterFormat::Png,
            Hint::Ppm => RasterFormat::Pnm,
            Hint::Bmp => RasterFormat::Bmp,
            Hint::Tga => RasterFormat::Tga,
            Hint::Jpeg => RasterFormat::Jpeg,
            Hint::Pfm => RasterFormat::Pfm,
            Hint::Exr => RasterFormat::Exr,
            _ => return None,
        })
    }
}

/// The members of a JSON request's `submission` object that carry a file, and the form
/// each names: `*_base64` members hold the file in base64, the others its text.
pub const ENCODED_MEMBERS: [(&str, Hint); 12] = [
    ("png_base64", Hint::Png),
    ("ppm_base64", Hint::Ppm),
    ("bmp_base64", Hint::Bmp),
    ("tga_base64", Hint::Tga),
    ("jpeg_base64", Hint::Jpeg),
    ("pfm_base64", Hint::Pfm),
    ("exr_base64", Hint::Exr),
    ("image_base64", Hint::Auto),
    ("npy_base64", Hint::Npy),
    ("ppm", Hint::Ppm),
    ("csv", Hint::Csv),
    ("ndjson", Hint::Ndjson),
];

fn quoted(names: impl IntoIterator<Item = &'static str>) -> String {
    names
        .into_iter()
        .map(|n| format!("`{n}`"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// What a JSON request's `submission` may be, in one sentence: every accepted member.
pub fn submission_members() -> String {
    format!(
        "hit data (a document with {}, or an array of pixels), or an object with exactly one \
         of {}",
        quoted(json::DOCUMENT_FIELDS),
        quoted(ENCODED_MEMBERS.map(|(n, _)| n))
    )
}

/// Checks the member names of a JSON request's `submission` object that is not one of
/// [`ENCODED_MEMBERS`] alone: each must be a field of a hit-data document, and the error
/// for one that is not lists every accepted name.
pub fn check_submission_members<'a>(
    members: impl IntoIterator<Item = &'a str>,
) -> Result<(), GradeError> {
    let Some(name) = members
        .into_iter()
        .find(|k| !json::DOCUMENT_FIELDS.contains(k))
    else {
        return Ok(());
    };
    let message = if ENCODED_MEMBERS.iter().any(|(n, _)| *n == name) {
        format!(
            "must be the only member of `submission`; it is {}",
            submission_members()
        )
    } else {
        format!(
            "is not an accepted member: `submission` is {}",
            submission_members()
        )
    };
    Err(GradeError::Unreadable(ReadError::BadValue {
        at: format!("submission.{name}"),
        message,
    }))
}

/// A submitted image, decoded.
#[derive(Debug, Clone, PartialEq)]
pub struct SubmittedImage {
    /// The format it was in (told from its content).
    pub format: RasterFormat,
    /// Its pixels: 8-bit RGB, or linear floats (PFM, OpenEXR).
    pub pixels: Raster,
}

impl From<RgbImage> for SubmittedImage {
    /// An 8-bit image as if handed in as a PNG.
    fn from(image: RgbImage) -> SubmittedImage {
        SubmittedImage {
            format: RasterFormat::Png,
            pixels: Raster::Rgb8(image),
        }
    }
}

impl SubmittedImage {
    /// Its width and height.
    pub fn size(&self) -> (u32, u32) {
        match &self.pixels {
            Raster::Rgb8(i) => (i.width, i.height),
            Raster::Linear(i) => (i.width, i.height),
        }
    }

    /// What a report should warn of: a lossy format.
    pub fn warnings(&self) -> Vec<String> {
        match self.format {
            RasterFormat::Jpeg => vec![
                "the submission is a JPEG, whose lossy compression changes pixels slightly: \
                 it rarely matches the reference exactly (even at quality 100 without chroma \
                 subsampling, pixels are off by up to about 3/255); hand in a PNG or PPM to be \
                 graded without that loss"
                    .to_owned(),
            ],
            _ => Vec::new(),
        }
    }

    /// The 8-bit image, when it is one.
    pub fn rgb8(&self) -> Option<&RgbImage> {
        match &self.pixels {
            Raster::Rgb8(i) => Some(i),
            Raster::Linear(_) => None,
        }
    }

    /// The linear image, when it is one.
    pub fn linear(&self) -> Option<&LinearImage> {
        match &self.pixels {
            Raster::Linear(i) => Some(i),
            Raster::Rgb8(_) => None,
        }
    }
}

/// A parsed submission.
#[derive(Debug, Clone, PartialEq)]
pub enum Submission {
    /// An image.
    Image(SubmittedImage),
    /// Per-pixel hit data.
    Hits(HitData),
}

impl Submission {
    /// Parses a submission's bytes with the default decoding limits (see
    /// [`Submission::parse_with`]).
    pub fn parse(bytes: &[u8], hint: Hint) -> Result<Submission, GradeError> {
        Submission::parse_with(bytes, hint, &DecodeLimits::default())
    }

    /// [`Submission::parse`] for a scene of `width × height` pixels: an image of another
    /// size is refused from its header, before it is decompressed, and decoding may take
    /// what that frame needs (what a server should call; hit data is checked against the
    /// frame when graded).
    pub fn parse_for_frame(
        bytes: &[u8],
        hint: Hint,
        width: u32,
        height: u32,
    ) -> Result<Submission, GradeError> {
        Submission::parse_with(bytes, hint, &DecodeLimits::for_frame(width, height))
    }

    /// Parses a submission's bytes under `limits` (the frame an image must match, the
    /// memory its decoding may take). An image or NPY signature decides whatever the
    /// hint says; otherwise an image hint decodes as that format (PNG: the bytes must
    /// carry its signature), a hit-data hint picks the parser, and [`Hint::Auto`] tells
    /// JSON by `{` or `[`, several JSON lines as NDJSON, else CSV with a header.
    pub fn parse_with(
        bytes: &[u8],
        hint: Hint,
        limits: &DecodeLimits,
    ) -> Result<Submission, GradeError> {
        if bytes.iter().all(u8::is_ascii_whitespace) {
            return Err(GradeError::Empty);
        }
        let image = match (RasterFormat::sniff(bytes), hint.raster()) {
            (Some(f), _) => Some(f),
            (None, Some(RasterFormat::Png)) => return Err(GradeError::NotPng),
            (None, f) => f,
        };
        if let Some(format) = image {
            let pixels = crate::format::raster::decode(bytes, format, limits)?;
            return Ok(Submission::Image(SubmittedImage { format, pixels }));
        }
        let hint = if bytes.starts_with(npy::NPY_MAGIC) {
            Hint::Npy
        } else if hint == Hint::Auto {
            detect_text(bytes)?
        } else {
            hint
        };
        let hits = match hint {
            Hint::Json => json::read(bytes),
            Hint::Ndjson => ndjson::read(bytes),
            Hint::Npy => npy::read(bytes),
            Hint::Csv => csv::read(bytes),
            _ => return Err(GradeError::UnknownFormat),
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

fn detect_text(bytes: &[u8]) -> Result<Hint, GradeError> {
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
    use crate::format::RasterFormat;
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
    fn an_image_signature_decides_whatever_the_hint_says() {
        let p3 = b"P3\n1 1\n255\n1 2 3\n";
        for hint in [Hint::Auto, Hint::Png, Hint::Jpeg, Hint::Csv, Hint::Json] {
            match Submission::parse(p3, hint).unwrap() {
                Submission::Image(img) => {
                    assert_eq!(img.format, RasterFormat::Pnm);
                    assert_eq!(img.rgb8().unwrap().data, vec![1, 2, 3]);
                    assert!(img.linear().is_none() && img.warnings().is_empty());
                }
                Submission::Hits(_) => panic!("hits"),
            }
        }
        // Without a signature an image hint names the decoder, which says what is wrong.
        let e = Submission::parse(b"u,v,hit\n", Hint::Tga).unwrap_err();
        assert!(e.to_string().starts_with("the TGA file is corrupt"), "{e}");
        assert_eq!(Hint::from_name("JPG"), Some(Hint::Jpeg));
        assert_eq!(Hint::from_name("pgm"), Some(Hint::Ppm));
        assert_eq!(Hint::from_media_type("image/x-exr"), Hint::Exr);
        assert_eq!(Hint::from_path(std::path::Path::new("out.pfm")), Hint::Pfm);
        for f in RasterFormat::ALL {
            assert_eq!(Hint::from(f).raster(), Some(f));
        }
    }

    #[test]
    fn a_submission_object_s_unknown_member_lists_every_accepted_name() {
        let m = |v: serde_json::Value| {
            v.as_object()
                .unwrap()
                .keys()
                .map(|k| &*String::leak(k.clone()))
                .collect::<Vec<&str>>()
        };
        assert!(check_submission_members(m(serde_json::json!({"pixels": [], "width": 1}))).is_ok());
        let e = check_submission_members(m(serde_json::json!({"pgm": "P2"}))).unwrap_err();
        let text = e.to_string();
        assert!(
            text.starts_with("submission.pgm: is not an accepted member"),
            "{text}"
        );
        for (name, _) in ENCODED_MEMBERS {
            assert!(text.contains(&format!("`{name}`")), "{name}: {text}");
        }
        for name in json::DOCUMENT_FIELDS {
            assert!(text.contains(&format!("`{name}`")), "{name}: {text}");
        }
        let e =
            check_submission_members(m(serde_json::json!({"csv": "", "pixels": []}))).unwrap_err();
        assert!(e.to_string().contains("must be the only member"), "{e}");
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
