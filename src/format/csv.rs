//! Hit data as a CSV table (`.csv`, `text/csv`) with a header, one pixel a row:
//!
//! ```csv
//! u,v,hit,object,lambda,px,py,pz,nx,ny,nz
//! 0,0,0,,,,,,,,
//! 2,2,1,0,2.0,0.0,0.0,2.0,-1.0,0.0,0.0
//! ```
//!
//! The writer gives the columns of [`HEADER`] in that order, pixels row-major, `hit` as
//! `0` or `1`, a miss with every other field empty, and numbers in their shortest
//! round-trip form (Rust's `{:?}`: `2.0`, `1e-300`), so they read back exactly. The
//! reader needs at least `u,v,hit,lambda,nx,ny,nz` (`object` and `px,py,pz` optional),
//! in any order, ignores other columns, and takes `hit` as `0`, `1`, `true` or `false`
//! and `object` −1 as none.

use std::fmt::Write as _;

use super::ReadError;
use super::hit::{Group, HitData, HitFormat, PixelHit, SubmittedHit};

/// The columns, in the order raytile writes and documents them.
pub const HEADER: &str = "u,v,hit,object,lambda,px,py,pz,nx,ny,nz";
const REQUIRED: &str = "u, v, hit, lambda, nx, ny, nz";

/// Appends the header line.
pub fn push_header(buf: &mut Vec<u8>) {
    buf.extend_from_slice(HEADER.as_bytes());
    buf.push(b'\n');
}

/// Appends the row of one pixel, newline included.
pub fn push_row(buf: &mut Vec<u8>, p: &PixelHit) {
    let mut row = String::with_capacity(128);
    // Writing to a `String` cannot fail.
    let _ = write!(row, "{},{},{},", p.u, p.v, p.hit as u8);
    if let Some(o) = p.object {
        let _ = write!(row, "{o}");
    }
    let point = p.point.map(|a| a.map(Some)).unwrap_or([None; 3]);
    let normal = p.normal.map(|a| a.map(Some)).unwrap_or([None; 3]);
    for x in std::iter::once(p.lambda).chain(point).chain(normal) {
        row.push(',');
        if let Some(x) = x {
            let _ = write!(row, "{x:?}");
        }
    }
    row.push('\n');
    buf.extend_from_slice(row.as_bytes());
}

/// Whether the first line of `text` looks like a header of hit data: comma-separated,
/// with a `hit` column.
pub fn sniff(text: &[u8]) -> bool {
    let first_line = text.split(|&b| b == b'\n').next().unwrap_or_default();
    std::str::from_utf8(first_line).is_ok_and(|l| {
        l.contains(',') && l.split(',').any(|c| c.trim().eq_ignore_ascii_case("hit"))
    })
}

/// Reads the table.
pub fn read(bytes: &[u8]) -> Result<HitData, ReadError> {
    let mut rdr = ::csv::ReaderBuilder::new()
        .trim(::csv::Trim::All)
        .has_headers(true)
        .from_reader(bytes);
    let csv_err = |e: ::csv::Error| {
        let line = e.position().map_or(0, |p| p.line() as usize);
        let (column, message) = match e.kind() {
            ::csv::ErrorKind::Utf8 { err, .. } => (err.field() + 1, "not UTF-8 text".to_owned()),
            ::csv::ErrorKind::UnequalLengths {
                expected_len, len, ..
            } => (
                0,
                format!("a row has {len} fields but the header has {expected_len}"),
            ),
            _ => (0, e.to_string()),
        };
        ReadError::Syntax {
            format: HitFormat::Csv.title(),
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
        col(name).ok_or_else(|| ReadError::MissingField {
            what: "CSV column",
            field: name.into(),
            needed: REQUIRED,
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
        let bad = |c: usize, message: String| ReadError::BadValue { at: at(c), message };
        let int = |c: usize| -> Result<Option<i64>, ReadError> {
            let s = field(c);
            if s.is_empty() {
                return Ok(None);
            }
            s.parse::<i64>()
                .map(Some)
                .map_err(|_| bad(c, format!("`{s}` is not a whole number")))
        };
        let float = |c: usize| -> Result<Option<f64>, ReadError> {
            let s = field(c);
            if s.is_empty() {
                return Ok(None);
            }
            s.parse::<f64>()
                .map(Some)
                .map_err(|_| bad(c, format!("`{s}` is not a number")))
        };
        let index = |c: usize| -> Result<u32, ReadError> {
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
        let vec3 = |cs: [usize; 3]| -> Result<Option<[f64; 3]>, ReadError> {
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
        s.check(|| format!("CSV line {line}"))?;
        pixels.push(s);
    }
    Ok(HitData {
        format: HitFormat::Csv.name(),
        size: None,
        groups: vec![Group { rect: None, pixels }],
    })
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
        let mut out = Vec::new();
        push_header(&mut out);
        for p in &records {
            push_row(&mut out, p);
        }
        assert!(sniff(&out));
        let back = read(&out).unwrap();
        assert_eq!(back.format, "csv");
        assert_eq!(back.size, None);
        let expected: Vec<SubmittedHit> = records.iter().map(SubmittedHit::from).collect();
        assert_eq!(
            back.groups,
            vec![Group {
                rect: None,
                pixels: expected
            }]
        );
    }

    #[test]
    fn rows_are_laid_out_as_documented() {
        let mut out = Vec::new();
        push_header(&mut out);
        let s = crate::geometry::Surface {
            lambda: 2.0,
            object: 0,
            point: glam::DVec3::new(0.0, 0.0, 2.0),
            object_point: glam::DVec3::new(-1.0, 0.0, 0.0),
            normal: glam::DVec3::new(-1.0, 0.0, 0.0),
            front: true,
            face: None,
        };
        push_row(&mut out, &PixelHit::from_surface(0, 0, &None, None));
        push_row(&mut out, &PixelHit::from_surface(2, 2, &Some(s), None));
        assert_eq!(
            std::str::from_utf8(&out).unwrap(),
            "u,v,hit,object,lambda,px,py,pz,nx,ny,nz\n\
             0,0,0,,,,,,,,\n\
             2,2,1,0,2.0,0.0,0.0,2.0,-1.0,0.0,0.0\n"
        );
    }
}
