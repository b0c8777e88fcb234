//! Hit data as NDJSON (`.ndjson`, `application/x-ndjson`): one line per tile, in the
//! order tiles finish, so each line can be sent the moment its tile is traced:
//!
//! ```json
//! {"tile":{"x":0,"y":0,"width":2,"height":1},"pixels":[{"u":0,"v":0,"hit":false,…},…]}
//! ```
//!
//! The pixel objects are JSON's ([`super::json`]), `NaN` and `Infinity` included; the
//! reader takes the lines in any order and skips blank ones.

use super::ReadError;
use super::hit::{HitData, HitFormat, PixelHit};
use super::json::{DocIn, from_json, group};
use crate::render::Rect;

/// Appends the line of the tile `rect` with its `pixels` (row-major), newline included.
pub fn push_line(
    line: &mut Vec<u8>,
    rect: Rect,
    pixels: impl IntoIterator<Item = PixelHit>,
) -> serde_json::Result<()> {
    line.extend_from_slice(b"{\"tile\":");
    serde_json::to_writer(&mut *line, &rect)?;
    line.extend_from_slice(b",\"pixels\":[");
    for (k, p) in pixels.into_iter().enumerate() {
        if k > 0 {
            line.push(b',');
        }
        serde_json::to_writer(&mut *line, &p)?;
    }
    line.extend_from_slice(b"]}\n");
    Ok(())
}

/// Whether text that starts with `{` is NDJSON rather than one document: more than one
/// line, and the first a whole JSON value.
pub fn sniff(text: &[u8]) -> bool {
    let mut lines = text
        .split(|&b| b == b'\n')
        .filter(|l| !l.trim_ascii().is_empty());
    let first = lines.next().unwrap_or_default();
    let more = lines.next().is_some();
    more && crate::json::from_slice_non_finite::<serde::de::IgnoredAny>(first).is_ok()
}

/// Reads the lines, each a group of pixels.
pub fn read(bytes: &[u8]) -> Result<HitData, ReadError> {
    let format = HitFormat::Ndjson;
    let mut groups = Vec::new();
    for (k, line) in bytes.split(|&b| b == b'\n').enumerate() {
        if line.trim_ascii().is_empty() {
            continue;
        }
        let d: DocIn = from_json(line, format, k)?;
        if d.width.is_some() || d.height.is_some() {
            return Err(ReadError::WrongShape(format!(
                "line {}: an NDJSON line holds a `tile` and its `pixels`, not `width`/`height`",
                k + 1
            )));
        }
        groups.push(group(d.tile.or(d.region), d.pixels, k + 1)?);
    }
    Ok(HitData {
        format: format.name(),
        size: None,
        groups,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::hit::tests::sample_records;
    use crate::format::hit::{Group, SubmittedHit};

    #[test]
    fn what_is_written_reads_back_the_same() {
        let records: Vec<PixelHit> = sample_records()
            .iter()
            .map(|(u, v, s)| PixelHit::from_surface(*u, *v, s, None))
            .collect();
        // Two tiles of one row each, the second finished first.
        let tile = |y| Rect {
            x: 0,
            y,
            width: 2,
            height: 1,
        };
        let mut out = Vec::new();
        push_line(&mut out, tile(1), records[2..].iter().cloned()).unwrap();
        push_line(&mut out, tile(0), records[..2].iter().cloned()).unwrap();
        assert!(sniff(&out));
        let back = read(&out).unwrap();
        assert_eq!(back.format, "ndjson");
        let group = |y, r: &[PixelHit]| Group {
            rect: Some(tile(y)),
            pixels: r.iter().map(SubmittedHit::from).collect(),
        };
        assert_eq!(
            back.groups,
            vec![group(1, &records[2..]), group(0, &records[..2])]
        );
    }

    #[test]
    fn errors_name_the_line() {
        let text = b"{\"tile\":{\"x\":0,\"y\":0,\"width\":1,\"height\":1},\"pixels\":[{\"hit\":false}]}\n\
                     \n\
                     {\"tile\":{\"x\":1,\"y\":0,\"width\":1,\"height\":1},\"pixels\":[{\"hit\":true}]}\n";
        let e = read(text).unwrap_err();
        assert!(e.to_string().starts_with("line 3, pixels[0]"), "{e}");
        let e = read(b"{\"width\":1,\"height\":1,\"pixels\":[]}\n").unwrap_err();
        assert!(matches!(e, ReadError::WrongShape(_)), "{e}");
    }
}
