//! Hit data as a NumPy `.npy` file (`application/x-npy`): a structured array of shape
//! `(h, w)`, one record a pixel, row-major.
//!
//! The writer gives NPY format 1.0 with the dtype [`NPY_DESCR`] (every field of
//! [`super::PixelHit`] but `name`), the header padded so the data starts 64-byte
//! aligned, numbers as raw little-endian values (so they read back exactly); a miss has
//! `object` −1, NaN vectors and an empty `face`. The reader takes any structured array
//! with at least the fields `hit`, `lambda` and `normal` (3 numbers), optionally
//! `object` (−1 for none) and `point`, found by name in any order; C or Fortran order,
//! either byte order, format 1.0 to 3.0. The header, a Python literal, is parsed by hand.

use super::ReadError;
use super::hit::{Group, HitData, HitFormat, SubmittedHit};
use crate::geometry::Surface;
use crate::render::Rect;

/// The NumPy dtype of a hit record: the fields of [`super::PixelHit`], `name` left out.
pub const NPY_DESCR: &str = "[('u', '<i4'), ('v', '<i4'), ('hit', '|b1'), ('object', '<i4'), ('lambda', '<f8'), ('point', '<f8', (3,)), ('object_point', '<f8', (3,)), ('normal', '<f8', (3,)), ('face', '<U2')]";

/// Bytes per NPY record.
pub const NPY_RECORD_BYTES: usize = 4 + 4 + 1 + 4 + 8 + 24 + 24 + 24 + 8;

/// The NPY 1.0 header of an `(h, w)` array of hit records, padded to 64 bytes.
pub fn npy_header(h: u32, w: u32) -> Vec<u8> {
    let dict = format!("{{'descr': {NPY_DESCR}, 'fortran_order': False, 'shape': ({h}, {w}), }}");
    let unpadded = 10 + dict.len() + 1;
    let pad = (64 - unpadded % 64) % 64;
    let header_len = dict.len() + pad + 1;
    let mut out = Vec::with_capacity(10 + header_len);
    out.extend_from_slice(NPY_MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&(header_len as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out.extend(std::iter::repeat_n(b' ', pad));
    out.push(b'\n');
    out
}

/// Appends one record: a miss has `object = −1`, NaN vectors and an empty face.
#[inline]
pub fn npy_record(buf: &mut Vec<u8>, u: u32, v: u32, s: &Option<Surface>) {
    buf.extend_from_slice(&npy_record_bytes(u, v, s));
}

/// One record's bytes.
#[inline]
pub fn npy_record_bytes(u: u32, v: u32, s: &Option<Surface>) -> [u8; NPY_RECORD_BYTES] {
    let mut r = [0u8; NPY_RECORD_BYTES];
    r[0..4].copy_from_slice(&(u as i32).to_le_bytes());
    r[4..8].copy_from_slice(&(v as i32).to_le_bytes());
    r[8] = s.is_some() as u8;
    r[9..13].copy_from_slice(&s.as_ref().map_or(-1, |s| s.object as i32).to_le_bytes());
    let values: [f64; 10] = match s {
        Some(s) => {
            let (p, o, n) = (s.point, s.object_point, s.normal);
            [s.lambda, p.x, p.y, p.z, o.x, o.y, o.z, n.x, n.y, n.z]
        }
        None => [f64::NAN; 10],
    };
    for (k, x) in values.iter().enumerate() {
        r[13 + 8 * k..21 + 8 * k].copy_from_slice(&x.to_le_bytes());
    }
    // '<U2': two UCS-4 code units; an empty string is all zeros.
    if let Some(f) = s.as_ref().and_then(|s| s.face) {
        let b = f.label().as_bytes();
        r[93] = b[0];
        r[97] = b[1];
    }
    r
}

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
    fn err(&self, what: &str) -> ReadError {
        ReadError::Npy(format!(
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

    fn value(&mut self, depth: usize) -> Result<Py, ReadError> {
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

/// Reads a structured array of shape `(h, w)`, its fields found by name.
pub fn read(bytes: &[u8]) -> Result<HitData, ReadError> {
    let npy = |m: &str| ReadError::Npy(m.to_owned());
    if !bytes.starts_with(NPY_MAGIC) || bytes.len() < 10 {
        return Err(npy("it does not start with the NPY signature"));
    }
    let (header_len, start): (usize, usize) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        v => return Err(ReadError::Npy(format!("unknown format version {v}"))),
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
            return Err(ReadError::WrongShape(format!(
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
        return Err(ReadError::WrongShape(format!(
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
        return Err(ReadError::WrongShape(format!(
            "the NPY data holds {} bytes but a ({h}, {w}) array of {item}-byte records needs {}",
            data.len(),
            n.saturating_mul(item)
        )));
    }
    let find = |name: &str| fields.iter().find(|f| f.name == name);
    let need = |name: &str, count: usize| -> Result<&Field, ReadError> {
        let f = find(name).ok_or_else(|| ReadError::MissingField {
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
        format: HitFormat::Npy.name(),
        size: Some((w, h)),
        groups: vec![Group {
            rect: Some(Rect::frame(w, h)),
            pixels,
        }],
    })
}

fn check_numeric(f: &Field, count: usize) -> Result<(), ReadError> {
    let numeric =
        matches!(f.scalar.kind, b'b' | b'i' | b'u' | b'f') && f.scalar.number(&[0; 8]).is_some();
    if !numeric || f.count != count {
        return Err(ReadError::WrongShape(format!(
            "the NPY field `{}` must be {} number{}",
            f.name,
            count,
            if count == 1 { "" } else { "s" }
        )));
    }
    Ok(())
}

fn dtype_fields(items: &[Py]) -> Result<Vec<Field>, ReadError> {
    let bad = |m: String| ReadError::Npy(format!("the dtype is not understood: {m}"));
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

    #[test]
    fn npy_header_is_aligned_and_parsable_text() {
        let h = npy_header(720, 1280);
        assert_eq!(h.len() % 64, 0);
        assert_eq!(&h[..8], b"\x93NUMPY\x01\x00");
        let len = u16::from_le_bytes([h[8], h[9]]) as usize;
        assert_eq!(10 + len, h.len());
        assert!(
            std::str::from_utf8(&h[10..])
                .unwrap()
                .contains("'shape': (720, 1280)")
        );
        assert_eq!(*h.last().unwrap(), b'\n');
    }

    #[test]
    fn npy_record_size_matches_dtype() {
        let mut b = Vec::new();
        npy_record(&mut b, 1, 2, &None);
        assert_eq!(b.len(), NPY_RECORD_BYTES);
        assert_eq!(&b[9..13], &(-1i32).to_le_bytes());
    }

    #[test]
    fn what_is_written_reads_back_the_same() {
        use crate::format::PixelHit;
        use crate::format::hit::tests::sample_records;
        let records = sample_records();
        let mut b = npy_header(2, 2);
        for (u, v, s) in &records {
            npy_record(&mut b, *u, *v, s);
        }
        let back = read(&b).unwrap();
        assert_eq!(back.format, "npy");
        assert_eq!(back.size, Some((2, 2)));
        // The array's order is row-major whatever order the records were listed in.
        let mut expected: Vec<SubmittedHit> = records
            .iter()
            .map(|(u, v, s)| SubmittedHit::from(&PixelHit::from_surface(*u, *v, s, None)))
            .collect();
        expected.sort_by_key(|p| (p.v, p.u));
        assert_eq!(
            back.groups,
            vec![Group {
                rect: Some(Rect::frame(2, 2)),
                pixels: expected
            }]
        );
    }
}
