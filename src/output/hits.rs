//! Per-pixel hit data (SPEC §5) in three forms:
//! - JSON: one document, pixels in row-major order, written row by row;
//! - NDJSON: one line per tile, in the order tiles finish;
//! - NPY: a NumPy structured array of shape `(h, w)`, written row by row.
//!
//! Numbers are f64 written in their shortest round-trip form (JSON) or as raw
//! little-endian doubles (NPY), so they read back exactly.

use std::io::{self, Write};
use std::sync::Mutex;

use serde::{Deserialize, Serialize};

use super::rows::RowAssembler;
use crate::geometry::Surface;
use crate::render::{Rect, SinkClosed, Tile, TileSink};
use crate::scene::Scene;

/// One pixel's hit data as it appears in JSON and NDJSON.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PixelHit {
    /// Column.
    pub u: u32,
    /// Row.
    pub v: u32,
    /// Whether anything was hit.
    pub hit: bool,
    /// Index of the object hit.
    pub object: Option<u32>,
    /// Its name.
    pub name: Option<String>,
    /// Ray parameter along the unnormalised primary direction.
    pub lambda: Option<f64>,
    /// World-space point.
    pub point: Option<[f64; 3]>,
    /// Object-space point.
    pub object_point: Option<[f64; 3]>,
    /// Unit world-space normal.
    pub normal: Option<[f64; 3]>,
    /// Cube face (`"+x"` … `"-z"`).
    pub face: Option<String>,
}

impl PixelHit {
    /// The record of pixel `(u, v)`.
    pub fn new(scene: &Scene, u: u32, v: u32, s: &Option<Surface>) -> PixelHit {
        match s {
            None => PixelHit {
                u,
                v,
                hit: false,
                object: None,
                name: None,
                lambda: None,
                point: None,
                object_point: None,
                normal: None,
                face: None,
            },
            Some(s) => PixelHit {
                u,
                v,
                hit: true,
                object: Some(s.object),
                name: scene.object_name(s.object).map(str::to_owned),
                lambda: Some(s.lambda),
                point: Some(s.point.to_array()),
                object_point: Some(s.object_point.to_array()),
                normal: Some(s.normal.to_array()),
                face: s.face.map(|f| f.label().to_owned()),
            },
        }
    }
}

/// The hit-data formats, by media type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HitFormat {
    /// `application/json`.
    Json,
    /// `application/x-ndjson`.
    Ndjson,
    /// `application/x-npy`.
    Npy,
}

impl HitFormat {
    /// The media type.
    pub fn media_type(self) -> &'static str {
        match self {
            HitFormat::Json => "application/json",
            HitFormat::Ndjson => "application/x-ndjson",
            HitFormat::Npy => "application/x-npy",
        }
    }

    /// The format for a file name's extension (`.json`, `.ndjson`, `.npy`).
    pub fn from_path(p: &std::path::Path) -> Option<HitFormat> {
        match p.extension()?.to_str()? {
            "json" => Some(HitFormat::Json),
            "ndjson" | "jsonl" => Some(HitFormat::Ndjson),
            "npy" => Some(HitFormat::Npy),
            _ => None,
        }
    }
}

fn closed(e: impl std::fmt::Display) -> SinkClosed {
    SinkClosed(e.to_string())
}

/// A [`TileSink`] writing hit data of `region` in one of the formats.
pub struct HitSink<'s, W: Write + Send> {
    scene: &'s Scene,
    format: HitFormat,
    state: Mutex<HitState<W>>,
}

struct HitState<W> {
    out: W,
    /// Rows of surfaces, for JSON.
    rows: RowAssembler<Option<Surface>>,
    /// Rows of encoded records, for NPY.
    records: RowAssembler<[u8; NPY_RECORD_BYTES]>,
    buf: Vec<u8>,
    first: bool,
}

impl<'s, W: Write + Send> HitSink<'s, W> {
    /// Writes the format's header (JSON's opening, NPY's dtype and shape) at once.
    pub fn new(
        scene: &'s Scene,
        format: HitFormat,
        mut out: W,
        region: Rect,
        tile_px: u32,
    ) -> io::Result<Self> {
        match format {
            HitFormat::Json => {
                write!(
                    out,
                    "{{\"width\":{},\"height\":{},\"region\":",
                    scene.width, scene.height
                )?;
                serde_json::to_writer(&mut out, &region)?;
                out.write_all(b",\"pixels\":[")?;
            }
            HitFormat::Npy => out.write_all(&npy_header(region.height, region.width))?,
            HitFormat::Ndjson => {}
        }
        Ok(HitSink {
            scene,
            format,
            state: Mutex::new(HitState {
                out,
                rows: RowAssembler::new(region, tile_px),
                records: RowAssembler::new(region, tile_px),
                buf: Vec::new(),
                first: true,
            }),
        })
    }

    /// Writes the closing bytes and hands back the writer.
    pub fn finish(self) -> io::Result<W> {
        let mut s = self
            .state
            .into_inner()
            .map_err(|_| io::Error::other("a worker panicked while writing"))?;
        let complete = match self.format {
            HitFormat::Json => s.rows.is_complete(),
            HitFormat::Npy => s.records.is_complete(),
            HitFormat::Ndjson => true,
        };
        if !complete {
            return Err(io::Error::other("the hit data is incomplete"));
        }
        if self.format == HitFormat::Json {
            s.out.write_all(b"]}\n")?;
        }
        s.out.flush()?;
        Ok(s.out)
    }
}

impl<W: Write + Send> TileSink<Option<Surface>> for HitSink<'_, W> {
    fn tile(&self, tile: Tile<Option<Surface>>) -> Result<(), SinkClosed> {
        let scene = self.scene;
        match self.format {
            HitFormat::Ndjson => {
                // Serialise outside the lock: only the write is serialised.
                let mut line = Vec::with_capacity(tile.pixels.len() * 160);
                line.extend_from_slice(b"{\"tile\":");
                serde_json::to_writer(&mut line, &tile.rect).map_err(closed)?;
                line.extend_from_slice(b",\"pixels\":[");
                let r = tile.rect;
                for (k, s) in tile.pixels.iter().enumerate() {
                    if k > 0 {
                        line.push(b',');
                    }
                    let (u, v) = (r.x + k as u32 % r.width, r.y + k as u32 / r.width);
                    serde_json::to_writer(&mut line, &PixelHit::new(scene, u, v, s))
                        .map_err(closed)?;
                }
                line.extend_from_slice(b"]}\n");
                let mut st = self.state.lock().map_err(closed)?;
                st.out.write_all(&line).map_err(closed)
            }
            HitFormat::Json => {
                let mut guard = self.state.lock().map_err(closed)?;
                let HitState {
                    out,
                    rows,
                    buf,
                    first,
                    ..
                } = &mut *guard;
                let x0 = rows.region().x;
                rows.push(tile, |v, segments| {
                    buf.clear();
                    for (k, s) in segments.iter().flat_map(|s| s.iter()).enumerate() {
                        if !*first {
                            buf.push(b',');
                        }
                        *first = false;
                        serde_json::to_writer(
                            &mut *buf,
                            &PixelHit::new(scene, x0 + k as u32, v, s),
                        )
                        .map_err(io::Error::other)?;
                    }
                    out.write_all(buf)
                })
                .map_err(closed)
            }
            HitFormat::Npy => {
                // Encode outside the lock, so workers only queue for the copy and write.
                let r = tile.rect;
                let records = tile
                    .pixels
                    .iter()
                    .enumerate()
                    .map(|(k, s)| {
                        npy_record_bytes(r.x + k as u32 % r.width, r.y + k as u32 / r.width, s)
                    })
                    .collect();
                let encoded = Tile {
                    rect: r,
                    pixels: records,
                    rays: tile.rays,
                };
                let mut guard = self.state.lock().map_err(closed)?;
                let HitState {
                    out, records, buf, ..
                } = &mut *guard;
                records
                    .push(encoded, |_, segments| {
                        buf.clear();
                        for seg in segments {
                            buf.extend(seg.iter().flatten());
                        }
                        out.write_all(buf)
                    })
                    .map_err(closed)
            }
        }
    }
}

/// The NumPy dtype of a hit record, fields as SPEC §5 names them (`name` left out).
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
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
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
}
