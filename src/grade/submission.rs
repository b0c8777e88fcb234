//! A student's submission, parsed: an image (any PNG) or per-pixel hit data in one of
//! the forms raytile itself writes (JSON, NDJSON, NPY) or a CSV table.
//!
//! JSON, as `raytile hits` writes it (a bare array of pixel objects is accepted too;
//! `u`, `v` may be left out when the pixels are in row-major order):
//!
//! ```json
//! {"width": 5, "height": 5, "region": {"x": 0, "y": 0, "width": 5, "height": 5},
//!  "pixels": [{"u": 0, "v": 0, "hit": false}, {"u": 1, "v": 0, "hit": true, "object": 0,
//!              "lambda": 2.0, "normal": [-1, 0, 0]}]}
//! ```
//!
//! NDJSON: one `{"tile": {"x","y","width","height"}, "pixels": [...]}` per line. NPY: a
//! structured array of shape `(h, w)` with at least the fields `hit`, `lambda` and
//! `normal` (3 floats), optionally `object` (−1 for none) and `point`. CSV: a header
//! naming at least `u,v,hit,lambda,nx,ny,nz`, optionally `object,px,py,pz`; `hit` is
//! `0`/`1`/`true`/`false` and a miss leaves the other fields empty.
//!
//! Nothing here trusts the bytes: every problem is a [`GradeError`] saying where.

use serde::Deserialize;

use super::GradeError;
use super::image::{PNG_SIGNATURE, RgbImage};
use crate::render::Rect;

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

impl Hint {
    /// The hint of a format name: `png`, `json`, `ndjson` (or `jsonl`), `npy`, `csv`, `auto`.
    pub fn from_name(s: &str) -> Option<Hint> {
        match s.trim().to_ascii_lowercase().as_str() {
            "auto" => Some(Hint::Auto),
            "png" => Some(Hint::Png),
            "json" => Some(Hint::Json),
            "ndjson" | "jsonl" => Some(Hint::Ndjson),
            "npy" => Some(Hint::Npy),
            "csv" => Some(Hint::Csv),
            _ => None,
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
        let essence = t
            .split(';')
            .next()
            .unwrap_or("")
            .trim()
            .to_ascii_lowercase();
        match essence.as_str() {
            "image/png" => Hint::Png,
            "application/json" => Hint::Json,
            "application/x-ndjson" | "application/jsonl" => Hint::Ndjson,
            "application/x-npy" => Hint::Npy,
            "text/csv" => Hint::Csv,
            _ => Hint::Auto,
        }
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

/// Hit data as submitted, not yet placed in the frame.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct HitData {
    /// The form it came in: `"json"`, `"ndjson"`, `"npy"` or `"csv"`.
    pub format: &'static str,
    /// The frame size it declares (JSON's `width`/`height`, NPY's shape), if any.
    pub size: Option<(u32, u32)>,
    /// Groups of pixels; a group without explicit `u`, `v` is laid out row-major over its
    /// rectangle (a tile, a region, the NPY array, or else the whole frame).
    pub groups: Vec<Group>,
}

/// Pixels that share a layout.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Group {
    /// Where the group lies, when known.
    pub rect: Option<Rect>,
    /// Its pixels in order.
    pub pixels: Vec<SubmittedHit>,
}

/// One submitted pixel.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SubmittedHit {
    /// Column, when given.
    pub u: Option<u32>,
    /// Row, when given.
    pub v: Option<u32>,
    /// Whether something was hit.
    pub hit: bool,
    /// Object index, when given.
    pub object: Option<u32>,
    /// Ray parameter.
    pub lambda: Option<f64>,
    /// World point.
    pub point: Option<[f64; 3]>,
    /// World normal.
    pub normal: Option<[f64; 3]>,
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
        match hint {
            Hint::Png => RgbImage::decode_png(bytes, frame).map(Submission::Image),
            Hint::Json => parse_json(bytes).map(Submission::Hits),
            Hint::Ndjson => parse_ndjson(bytes).map(Submission::Hits),
            Hint::Npy => parse_npy(bytes).map(Submission::Hits),
            Hint::Csv => parse_csv(bytes).map(Submission::Hits),
            Hint::Auto => Err(GradeError::UnknownFormat),
        }
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
    if bytes.starts_with(NPY_MAGIC) {
        return Ok(Hint::Npy);
    }
    let text = bytes.trim_ascii_start();
    match text.first() {
        Some(b'[') => Ok(Hint::Json),
        Some(b'{') => {
            // NDJSON when there is more than one line and the first is a whole value.
            let mut lines = text
                .split(|&b| b == b'\n')
                .filter(|l| !l.trim_ascii().is_empty());
            let first = lines.next().unwrap_or_default();
            let more = lines.next().is_some();
            if more && serde_json::from_slice::<serde::de::IgnoredAny>(first).is_ok() {
                Ok(Hint::Ndjson)
            } else {
                Ok(Hint::Json)
            }
        }
        _ => {
            let first_line = text.split(|&b| b == b'\n').next().unwrap_or_default();
            let looks_like_header = std::str::from_utf8(first_line).is_ok_and(|l| {
                l.contains(',') && l.split(',').any(|c| c.trim().eq_ignore_ascii_case("hit"))
            });
            if looks_like_header {
                Ok(Hint::Csv)
            } else {
                Err(GradeError::UnknownFormat)
            }
        }
    }
}

// ---------------------------------------------------------------------------------------
// JSON and NDJSON

/// A pixel object as JSON and NDJSON carry it (the fields of SPEC §5).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PixelIn {
    #[serde(default)]
    u: Option<u32>,
    #[serde(default)]
    v: Option<u32>,
    hit: bool,
    /// −1 is accepted for "none", as NPY writes it.
    #[serde(default)]
    object: Option<i64>,
    #[serde(default)]
    #[allow(dead_code)]
    name: Option<String>,
    #[serde(default)]
    lambda: Option<f64>,
    #[serde(default)]
    point: Option<[f64; 3]>,
    #[serde(default)]
    #[allow(dead_code)]
    object_point: Option<[f64; 3]>,
    #[serde(default)]
    normal: Option<[f64; 3]>,
    #[serde(default)]
    #[allow(dead_code)]
    face: Option<String>,
}

/// A JSON document (`raytile hits` output) or one NDJSON line.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct DocIn {
    #[serde(default)]
    width: Option<u32>,
    #[serde(default)]
    height: Option<u32>,
    #[serde(default)]
    region: Option<Rect>,
    #[serde(default)]
    tile: Option<Rect>,
    pixels: Vec<PixelIn>,
}

fn json_error(
    format: &'static str,
    line_offset: usize,
) -> impl Fn(serde_json::Error) -> GradeError {
    move |e| GradeError::Syntax {
        format,
        line: e.line() + line_offset,
        column: e.column(),
        message: strip_position(&e.to_string()),
    }
}

fn strip_position(msg: &str) -> String {
    match msg.rfind(" at line ") {
        Some(i) => msg[..i].to_string(),
        None => msg.to_string(),
    }
}

/// Deserialises with the path of the offending field in the message.
fn from_json<T: serde::de::DeserializeOwned>(
    bytes: &[u8],
    format: &'static str,
    line_offset: usize,
) -> Result<T, GradeError> {
    let mut de = serde_json::Deserializer::from_slice(bytes);
    let value: T = serde_path_to_error::deserialize(&mut de).map_err(|e| {
        let path = e.path().to_string();
        let inner = e.into_inner();
        let mut err = json_error(format, line_offset)(inner);
        if let GradeError::Syntax { message, .. } = &mut err
            && path != "."
        {
            *message = format!("{path}: {message}");
        }
        err
    })?;
    de.end().map_err(json_error(format, line_offset))?;
    Ok(value)
}

fn parse_json(bytes: &[u8]) -> Result<HitData, GradeError> {
    // A bare array of pixels, or a document; chosen by the first character so that an
    // error names the field at fault rather than "matched no variant".
    if bytes.trim_ascii_start().first() == Some(&b'[') {
        let pixels: Vec<PixelIn> = from_json(bytes, "JSON", 0)?;
        return Ok(HitData {
            format: "json",
            size: None,
            groups: vec![group(None, pixels, 0)?],
        });
    }
    let d: DocIn = from_json(bytes, "JSON", 0)?;
    let size = match (d.width, d.height) {
        (Some(w), Some(h)) => Some((w, h)),
        (None, None) => None,
        _ => {
            return Err(GradeError::WrongShape(
                "the document gives only one of `width` and `height`".into(),
            ));
        }
    };
    let rect = d.tile.or(d.region);
    Ok(HitData {
        format: "json",
        size,
        groups: vec![group(rect, d.pixels, 0)?],
    })
}

fn parse_ndjson(bytes: &[u8]) -> Result<HitData, GradeError> {
    let mut groups = Vec::new();
    for (k, line) in bytes.split(|&b| b == b'\n').enumerate() {
        if line.trim_ascii().is_empty() {
            continue;
        }
        let d: DocIn = from_json(line, "NDJSON", k)?;
        if d.width.is_some() || d.height.is_some() {
            return Err(GradeError::WrongShape(format!(
                "line {}: an NDJSON line holds a `tile` and its `pixels`, not `width`/`height`",
                k + 1
            )));
        }
        groups.push(group(d.tile.or(d.region), d.pixels, k + 1)?);
    }
    Ok(HitData {
        format: "ndjson",
        size: None,
        groups,
    })
}

fn group(rect: Option<Rect>, pixels: Vec<PixelIn>, line: usize) -> Result<Group, GradeError> {
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
                return Err(GradeError::BadValue {
                    at: at(k),
                    message: "gives only one of `u` and `v`".into(),
                });
            }
            let object = match p.object {
                None => None,
                Some(o) if o < 0 => None,
                Some(o) => Some(u32::try_from(o).map_err(|_| GradeError::BadValue {
                    at: at(k),
                    message: format!("`object` {o} is not a valid index"),
                })?),
            };
            let s = SubmittedHit {
                u: p.u,
                v: p.v,
                hit: p.hit,
                object,
                lambda: p.lambda,
                point: p.point,
                normal: p.normal,
            };
            check_values(&s, || at(k))?;
            Ok(s)
        })
        .collect::<Result<Vec<_>, _>>()?;
    if let Some(r) = rect
        && pixels.iter().any(|p| p.u.is_none())
        && r.pixels() != pixels.len() as u64
    {
        return Err(GradeError::WrongShape(format!(
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

/// A hit must say where: `lambda` and `normal` are what is graded.
fn check_values(s: &SubmittedHit, at: impl Fn() -> String) -> Result<(), GradeError> {
    if s.hit {
        for (field, present) in [
            ("lambda", s.lambda.is_some()),
            ("normal", s.normal.is_some()),
        ] {
            if !present {
                return Err(GradeError::BadValue {
                    at: at(),
                    message: format!("`hit` is true but `{field}` is missing"),
                });
            }
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------
// CSV

/// The CSV columns, in the order raytile documents them.
pub const CSV_HEADER: &str = "u,v,hit,object,lambda,px,py,pz,nx,ny,nz";
const CSV_REQUIRED: &str = "u, v, hit, lambda, nx, ny, nz";

fn parse_csv(bytes: &[u8]) -> Result<HitData, GradeError> {
    let mut rdr = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .has_headers(true)
        .from_reader(bytes);
    let csv_err = |e: csv::Error| {
        let line = e.position().map_or(0, |p| p.line() as usize);
        let (column, message) = match e.kind() {
            csv::ErrorKind::Utf8 { err, .. } => (err.field() + 1, "not UTF-8 text".to_owned()),
            csv::ErrorKind::UnequalLengths {
                expected_len, len, ..
            } => (
                0,
                format!("a row has {len} fields but the header has {expected_len}"),
            ),
            _ => (0, e.to_string()),
        };
        GradeError::Syntax {
            format: "CSV",
            line,
            column,
            message,
        }
    };
    let headers = rdr.headers().map_err(csv_err)?.clone();
    let col = |name: &str| {
        headers
            .iter()
            .position(|h| h.trim().eq_ignore_ascii_case(name))
    };
    let need = |name: &str| {
        col(name).ok_or_else(|| GradeError::MissingField {
            what: "CSV column",
            field: name.into(),
            needed: CSV_REQUIRED,
        })
    };
    let (cu, cv, chit, clambda) = (need("u")?, need("v")?, need("hit")?, need("lambda")?);
    let cn = [need("nx")?, need("ny")?, need("nz")?];
    let cobj = col("object");
    let cp = match (col("px"), col("py"), col("pz")) {
        (Some(x), Some(y), Some(z)) => Some([x, y, z]),
        _ => None,
    };
    let mut pixels = Vec::new();
    for rec in rdr.records() {
        let rec = rec.map_err(csv_err)?;
        let line = rec.position().map_or(0, |p| p.line());
        let at = |c: usize| {
            format!(
                "CSV line {line}, column `{}`",
                headers.get(c).unwrap_or("?")
            )
        };
        let field = |c: usize| rec.get(c).unwrap_or("").trim();
        let bad = |c: usize, message: String| GradeError::BadValue { at: at(c), message };
        let int = |c: usize| -> Result<Option<i64>, GradeError> {
            let s = field(c);
            if s.is_empty() {
                return Ok(None);
            }
            s.parse::<i64>()
                .map(Some)
                .map_err(|_| bad(c, format!("`{s}` is not a whole number")))
        };
        let float = |c: usize| -> Result<Option<f64>, GradeError> {
            let s = field(c);
            if s.is_empty() {
                return Ok(None);
            }
            s.parse::<f64>()
                .map(Some)
                .map_err(|_| bad(c, format!("`{s}` is not a number")))
        };
        let index = |c: usize| -> Result<u32, GradeError> {
            let n = int(c)?.ok_or_else(|| bad(c, "is empty".into()))?;
            u32::try_from(n).map_err(|_| bad(c, format!("{n} is not a pixel coordinate")))
        };
        let hit = match field(chit).to_ascii_lowercase().as_str() {
            "1" | "true" => true,
            "0" | "false" => false,
            other => {
                return Err(bad(chit, format!("`{other}` is not 0, 1, true or false")));
            }
        };
        let vec3 = |cs: [usize; 3]| -> Result<Option<[f64; 3]>, GradeError> {
            let [x, y, z] = [float(cs[0])?, float(cs[1])?, float(cs[2])?];
            match (x, y, z) {
                (Some(x), Some(y), Some(z)) => Ok(Some([x, y, z])),
                (None, None, None) => Ok(None),
                _ => Err(bad(cs[0], "a vector needs all three components".into())),
            }
        };
        let object = match cobj {
            Some(c) => match int(c)? {
                Some(o) if o >= 0 => Some(
                    u32::try_from(o).map_err(|_| bad(c, format!("{o} is not an object index")))?,
                ),
                _ => None,
            },
            None => None,
        };
        let s = SubmittedHit {
            u: Some(index(cu)?),
            v: Some(index(cv)?),
            hit,
            object,
            lambda: float(clambda)?,
            point: match cp {
                Some(cs) => vec3(cs)?,
                None => None,
            },
            normal: vec3(cn)?,
        };
        check_values(&s, || format!("CSV line {line}"))?;
        pixels.push(s);
    }
    Ok(HitData {
        format: "csv",
        size: None,
        groups: vec![Group { rect: None, pixels }],
    })
}

// ---------------------------------------------------------------------------------------
// NPY

/// The six bytes every `.npy` file starts with.
pub const NPY_MAGIC: &[u8] = b"\x93NUMPY";

/// A Python literal, as far as `.npy` headers use them.
#[derive(Debug, Clone, PartialEq)]
enum Py {
    Str(String),
    Int(i64),
    Bool(bool),
    None,
    List(Vec<Py>),
    Dict(Vec<(Py, Py)>),
}

struct PyParser<'a> {
    s: &'a [u8],
    i: usize,
}

impl PyParser<'_> {
    fn err(&self, what: &str) -> GradeError {
        GradeError::Npy(format!(
            "the header is not a Python literal: {what} at byte {}",
            self.i
        ))
    }

    fn ws(&mut self) {
        while self.s.get(self.i).is_some_and(|b| b.is_ascii_whitespace()) {
            self.i += 1;
        }
    }

    fn eat(&mut self, b: u8) -> bool {
        self.ws();
        if self.s.get(self.i) == Some(&b) {
            self.i += 1;
            true
        } else {
            false
        }
    }

    fn value(&mut self, depth: usize) -> Result<Py, GradeError> {
        if depth > 16 {
            return Err(self.err("nesting too deep"));
        }
        self.ws();
        match self.s.get(self.i).copied() {
            Some(b'{') => {
                self.i += 1;
                let mut items = Vec::new();
                loop {
                    if self.eat(b'}') {
                        break;
                    }
                    let k = self.value(depth + 1)?;
                    if !self.eat(b':') {
                        return Err(self.err("expected `:`"));
                    }
                    let v = self.value(depth + 1)?;
                    items.push((k, v));
                    if self.eat(b',') {
                        continue;
                    }
                    if self.eat(b'}') {
                        break;
                    }
                    return Err(self.err("expected `,` or `}`"));
                }
                Ok(Py::Dict(items))
            }
            Some(open @ (b'[' | b'(')) => {
                let close = if open == b'[' { b']' } else { b')' };
                self.i += 1;
                let mut items = Vec::new();
                loop {
                    if self.eat(close) {
                        break;
                    }
                    items.push(self.value(depth + 1)?);
                    if self.eat(b',') {
                        continue;
                    }
                    if self.eat(close) {
                        break;
                    }
                    return Err(self.err("expected `,` or a closing bracket"));
                }
                Ok(Py::List(items))
            }
            Some(q @ (b'\'' | b'"')) => {
                self.i += 1;
                let start = self.i;
                while self.s.get(self.i).is_some_and(|&b| b != q) {
                    if self.s[self.i] == b'\\' {
                        self.i += 1;
                    }
                    self.i += 1;
                }
                if self.i >= self.s.len() {
                    return Err(self.err("unterminated string"));
                }
                let text = String::from_utf8_lossy(&self.s[start..self.i]).into_owned();
                self.i += 1;
                Ok(Py::Str(text))
            }
            Some(b'-' | b'0'..=b'9') => {
                let start = self.i;
                self.i += 1;
                while self.s.get(self.i).is_some_and(u8::is_ascii_digit) {
                    self.i += 1;
                }
                // Python 2 era headers may write `3L`.
                let digits = std::str::from_utf8(&self.s[start..self.i]).unwrap_or("");
                if self.s.get(self.i) == Some(&b'L') {
                    self.i += 1;
                }
                digits
                    .parse()
                    .map(Py::Int)
                    .map_err(|_| self.err("bad integer"))
            }
            Some(b'A'..=b'Z' | b'a'..=b'z') => {
                let start = self.i;
                while self.s.get(self.i).is_some_and(u8::is_ascii_alphanumeric) {
                    self.i += 1;
                }
                match &self.s[start..self.i] {
                    b"True" => Ok(Py::Bool(true)),
                    b"False" => Ok(Py::Bool(false)),
                    b"None" => Ok(Py::None),
                    _ => Err(self.err("unknown name")),
                }
            }
            _ => Err(self.err("unexpected character")),
        }
    }
}

/// A scalar type of a structured dtype.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Scalar {
    kind: u8,
    size: usize,
    big_endian: bool,
}

impl Scalar {
    fn parse(s: &str) -> Option<Scalar> {
        let b = s.as_bytes();
        let (big_endian, rest) = match b.first()? {
            b'<' | b'=' | b'|' => (false, &b[1..]),
            b'>' | b'!' => (true, &b[1..]),
            _ => (false, b),
        };
        if rest == b"?" {
            return Some(Scalar {
                kind: b'b',
                size: 1,
                big_endian,
            });
        }
        let kind = *rest.first()?;
        let n: usize = std::str::from_utf8(&rest[1..]).ok()?.parse().ok()?;
        let size = match kind {
            b'U' => n.checked_mul(4)?,
            b'b' | b'i' | b'u' | b'f' | b'S' | b'a' | b'V' => n,
            _ => return None,
        };
        Some(Scalar {
            kind,
            size,
            big_endian,
        })
    }

    /// The value at the start of `b` as a number, when it is one.
    fn number(&self, b: &[u8]) -> Option<f64> {
        fn arr<const N: usize>(b: &[u8], big: bool) -> Option<[u8; N]> {
            let mut a: [u8; N] = b.get(..N)?.try_into().ok()?;
            if big {
                a.reverse();
            }
            Some(a)
        }
        let be = self.big_endian;
        Some(match (self.kind, self.size) {
            (b'b', 1) => (*b.first()? != 0) as u8 as f64,
            (b'i', 1) => *b.first()? as i8 as f64,
            (b'u', 1) => *b.first()? as f64,
            (b'i', 2) => i16::from_le_bytes(arr(b, be)?) as f64,
            (b'u', 2) => u16::from_le_bytes(arr(b, be)?) as f64,
            (b'i', 4) => i32::from_le_bytes(arr(b, be)?) as f64,
            (b'u', 4) => u32::from_le_bytes(arr(b, be)?) as f64,
            (b'i', 8) => i64::from_le_bytes(arr(b, be)?) as f64,
            (b'u', 8) => u64::from_le_bytes(arr(b, be)?) as f64,
            (b'f', 4) => f32::from_le_bytes(arr(b, be)?) as f64,
            (b'f', 8) => f64::from_le_bytes(arr(b, be)?),
            _ => return None,
        })
    }
}

#[derive(Debug, Clone)]
struct Field {
    name: String,
    scalar: Scalar,
    count: usize,
    offset: usize,
}

const NPY_REQUIRED: &str = "hit, lambda, normal (3 floats); optional: object, point";

fn parse_npy(bytes: &[u8]) -> Result<HitData, GradeError> {
    let npy = |m: &str| GradeError::Npy(m.to_owned());
    if !bytes.starts_with(NPY_MAGIC) || bytes.len() < 10 {
        return Err(npy("it does not start with the NPY signature"));
    }
    let (header_len, start): (usize, usize) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        v => return Err(GradeError::Npy(format!("unknown format version {v}"))),
    };
    let header = bytes
        .get(start..start.saturating_add(header_len))
        .ok_or_else(|| npy("the header is truncated"))?;
    let data = &bytes[start + header_len..];
    let dict = match (PyParser { s: header, i: 0 }).value(0)? {
        Py::Dict(d) => d,
        _ => return Err(npy("the header is not a dictionary")),
    };
    let get = |k: &str| {
        dict.iter()
            .find(|(key, _)| *key == Py::Str(k.into()))
            .map(|(_, v)| v)
    };
    let fortran = match get("fortran_order") {
        Some(Py::Bool(b)) => *b,
        _ => return Err(npy("the header has no `fortran_order`")),
    };
    let shape: Vec<i64> = match get("shape") {
        Some(Py::List(items)) => items
            .iter()
            .map(|d| match d {
                Py::Int(n) if *n >= 0 => Ok(*n),
                _ => Err(npy("`shape` holds something other than sizes")),
            })
            .collect::<Result<_, _>>()?,
        _ => return Err(npy("the header has no `shape`")),
    };
    let fields = match get("descr") {
        Some(Py::List(items)) => dtype_fields(items)?,
        Some(Py::Str(s)) => {
            return Err(GradeError::WrongShape(format!(
                "the NPY array holds plain `{s}` values, not hit records with the fields {NPY_REQUIRED}"
            )));
        }
        _ => return Err(npy("the header has no `descr`")),
    };
    let [h, w] = shape[..] else {
        let dims: Vec<String> = shape.iter().map(i64::to_string).collect();
        let tuple = if dims.len() == 1 {
            format!("({},)", dims[0])
        } else {
            format!("({})", dims.join(", "))
        };
        return Err(GradeError::WrongShape(format!(
            "the NPY array has shape {tuple}; hit data is an (h, w) array"
        )));
    };
    let (h, w) = match (u32::try_from(h), u32::try_from(w)) {
        (Ok(h), Ok(w)) => (h, w),
        _ => return Err(npy("the shape is too large")),
    };
    let item: usize = fields.iter().map(|f| f.scalar.size * f.count).sum();
    let n = h as usize * w as usize;
    if n.checked_mul(item).is_none_or(|need| data.len() < need) {
        return Err(GradeError::WrongShape(format!(
            "the NPY data holds {} bytes but a ({h}, {w}) array of {item}-byte records needs {}",
            data.len(),
            n.saturating_mul(item)
        )));
    }
    let find = |name: &str| fields.iter().find(|f| f.name == name);
    let need = |name: &str, count: usize| -> Result<&Field, GradeError> {
        let f = find(name).ok_or_else(|| GradeError::MissingField {
            what: "NPY field",
            field: name.into(),
            needed: NPY_REQUIRED,
        })?;
        check_numeric(f, count)?;
        Ok(f)
    };
    let fhit = need("hit", 1)?;
    let flambda = need("lambda", 1)?;
    let fnormal = need("normal", 3)?;
    let fobject = find("object");
    if let Some(f) = fobject {
        check_numeric(f, 1)?;
    }
    let fpoint = find("point");
    if let Some(f) = fpoint {
        check_numeric(f, 3)?;
    }

    let mut pixels = Vec::with_capacity(n);
    for v in 0..h {
        for u in 0..w {
            // C order stores rows one after the other; Fortran order columns.
            let k = if fortran {
                u as usize * h as usize + v as usize
            } else {
                v as usize * w as usize + u as usize
            };
            let rec = &data[k * item..(k + 1) * item];
            let value = |f: &Field, i: usize| {
                let at = f.offset + i * f.scalar.size;
                rec.get(at..)
                    .and_then(|b| f.scalar.number(b))
                    .unwrap_or(f64::NAN)
            };
            let vec3 = |f: &Field| [value(f, 0), value(f, 1), value(f, 2)];
            let hit = value(fhit, 0) != 0.0;
            let some = |x: f64| (hit || !x.is_nan()).then_some(x);
            let object = fobject
                .map(|f| value(f, 0))
                .filter(|&o| o >= 0.0 && o <= u32::MAX as f64)
                .map(|o| o as u32);
            let normal = vec3(fnormal);
            pixels.push(SubmittedHit {
                u: Some(u),
                v: Some(v),
                hit,
                object,
                lambda: some(value(flambda, 0)),
                point: fpoint.map(vec3).filter(|p| hit || !p[0].is_nan()),
                normal: (hit || !normal[0].is_nan()).then_some(normal),
            });
        }
    }
    Ok(HitData {
        format: "npy",
        size: Some((w, h)),
        groups: vec![Group {
            rect: Some(Rect::frame(w, h)),
            pixels,
        }],
    })
}

fn check_numeric(f: &Field, count: usize) -> Result<(), GradeError> {
    let numeric =
        matches!(f.scalar.kind, b'b' | b'i' | b'u' | b'f') && f.scalar.number(&[0; 8]).is_some();
    if !numeric || f.count != count {
        return Err(GradeError::WrongShape(format!(
            "the NPY field `{}` must be {} number{}",
            f.name,
            count,
            if count == 1 { "" } else { "s" }
        )));
    }
    Ok(())
}

fn dtype_fields(items: &[Py]) -> Result<Vec<Field>, GradeError> {
    let bad = |m: String| GradeError::Npy(format!("the dtype is not understood: {m}"));
    let mut fields = Vec::with_capacity(items.len());
    let mut offset = 0usize;
    for it in items {
        let Py::List(parts) = it else {
            return Err(bad("a field is not a tuple".into()));
        };
        let (name, ty, shape) = match &parts[..] {
            [Py::Str(n), Py::Str(t)] => (n, t, None),
            [Py::Str(n), Py::Str(t), s] => (n, t, Some(s)),
            [Py::Str(n), Py::List(_), ..] => {
                return Err(bad(format!("field `{n}` is a nested record")));
            }
            _ => return Err(bad("a field is not (name, type[, shape])".into())),
        };
        let scalar = Scalar::parse(ty).ok_or_else(|| bad(format!("type `{ty}` of `{name}`")))?;
        let count = match shape {
            None => 1,
            Some(Py::Int(n)) if *n >= 0 => *n as usize,
            Some(Py::List(dims)) => dims
                .iter()
                .try_fold(1usize, |acc, d| match d {
                    Py::Int(n) if *n >= 0 => acc.checked_mul(*n as usize),
                    _ => None,
                })
                .ok_or_else(|| bad(format!("shape of `{name}`")))?,
            Some(_) => return Err(bad(format!("shape of `{name}`"))),
        };
        let size = scalar
            .size
            .checked_mul(count)
            .ok_or_else(|| bad(format!("size of `{name}`")))?;
        fields.push(Field {
            name: name.clone(),
            scalar,
            count,
            offset,
        });
        offset = offset
            .checked_add(size)
            .ok_or_else(|| bad("the record is too large".into()))?;
    }
    Ok(fields)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::output::hits::{npy_header, npy_record};

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
            matches!(e, GradeError::MissingField { ref field, .. } if field == "nz"),
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
            matches!(e, GradeError::MissingField { ref field, .. } if field == "normal"),
            "{e}"
        );
        let e = Submission::parse(&npy("'<f8'", "(2, 2)", &[0; 32]), Hint::Auto).unwrap_err();
        assert!(matches!(e, GradeError::WrongShape(_)), "{e}");
        let e = Submission::parse(
            &npy(
                "[('hit', '?'), ('lambda', '<f8'), ('normal', '<f8', (3,))]",
                "(4,)",
                &[0; 33],
            ),
            Hint::Auto,
        )
        .unwrap_err();
        assert!(matches!(e, GradeError::WrongShape(_)), "{e}");
        let e = Submission::parse(
            &npy(
                "[('hit', '?'), ('lambda', '<f8'), ('normal', '<f8', (3,))]",
                "(2, 2)",
                &[0; 33],
            ),
            Hint::Auto,
        )
        .unwrap_err();
        assert!(matches!(e, GradeError::WrongShape(_)), "{e}");
        let e = Submission::parse(b"\x93NUMPY\x01\x00\xff\x00{'descr", Hint::Auto).unwrap_err();
        assert!(matches!(e, GradeError::Npy(_)), "{e}");
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
