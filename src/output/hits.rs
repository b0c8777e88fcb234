//! Hit data streamed while tiles trace, in any [`HitFormat`]: NDJSON a line per tile in
//! the order tiles finish; JSON, NPY and CSV row by row, top to bottom, as soon as each
//! row (or, in a frame too wide for a band, each piece of a row) can leave. The bytes of
//! each format are its file's in [`crate::format`]; this sink only decides when they
//! are written, and writes them in pieces of at most [`PIECE_BYTES`] (a row of a wide
//! frame is never built in one buffer).

use std::io::{self, Write};
use std::sync::{Arc, Mutex};

use super::file::write_all_vectored;
use super::handoff::Handoff;
use super::rows::{PIECE_BYTES, QUEUED_TILES, RowAssembler};
use crate::format::npy::{NPY_RECORD_BYTES, npy_header, npy_record_bytes};
use crate::format::{HitFormat, PixelHit, csv, json, ndjson};
use crate::geometry::Surface;
use crate::render::{BAND_PIXELS, Rect, SinkClosed, Tile, TileShape, TileSink};
use crate::scene::Scene;

fn closed(e: impl std::fmt::Display) -> SinkClosed {
    SinkClosed(e.to_string())
}

/// A tile of encoded NPY records.
type RecordTile = Tile<[u8; NPY_RECORD_BYTES]>;

/// A [`TileSink`] writing hit data of `region` in one of the formats.
pub struct HitSink<W: Write + Send> {
    scene: Arc<Scene>,
    format: HitFormat,
    state: Mutex<HitState<W>>,
    /// Boxed: the sink stays small beside the others, and only NPY uses it.
    npy: Box<NpyQueue>,
}

/// What NPY workers hand over between them.
#[derive(Default)]
struct NpyQueue {
    /// Encoded tiles waiting for whichever worker holds the state to write them.
    queue: Handoff<[u8; NPY_RECORD_BYTES]>,
    /// Record buffers of tiles already written, reused for the next tiles.
    spare: Mutex<Vec<Vec<[u8; NPY_RECORD_BYTES]>>>,
}

struct HitState<W> {
    out: W,
    /// Rows of surfaces, for JSON and CSV.
    rows: RowAssembler<Option<Surface>>,
    /// Rows of encoded records, for NPY.
    records: RowAssembler<[u8; NPY_RECORD_BYTES]>,
    buf: Vec<u8>,
    first: bool,
}

impl<W: Write + Send> HitSink<W> {
    /// Writes the format's header (JSON's opening, NPY's dtype and shape, CSV's column
    /// names) at once.
    pub fn new(scene: Arc<Scene>, format: HitFormat, mut out: W, region: Rect) -> io::Result<Self> {
        match format {
            HitFormat::Json => json::write_start(&mut out, scene.width, scene.height, region)?,
            HitFormat::Npy => out.write_all(&npy_header(region.height, region.width))?,
            HitFormat::Csv => {
                let mut header = Vec::new();
                csv::push_header(&mut header);
                out.write_all(&header)?;
            }
            HitFormat::Ndjson => {}
        }
        Ok(HitSink {
            scene,
            format,
            state: Mutex::new(HitState {
                out,
                rows: RowAssembler::new(region),
                records: RowAssembler::new(region),
                buf: Vec::new(),
                first: true,
            }),
            npy: Box::default(),
        })
    }

    /// Writes every queued NPY tile, waiting for the writer if another worker holds it
    /// ([`Handoff::drain`]; a worker that hands a tile drains without waiting).
    fn drain_records(&self) -> Result<(), SinkClosed> {
        self.npy.queue.drain(&self.state, true, |state, tile| {
            self.write_records(state, tile)
        })
    }

    /// Writes an NPY tile's records as its rows can leave, and keeps its spent buffer.
    fn write_records(&self, state: &mut HitState<W>, tile: RecordTile) -> Result<(), SinkClosed> {
        let HitState { out, records, .. } = state;
        records
            .push_reclaiming(
                tile,
                |_, _, segments| {
                    // A row in one call where the writer takes several buffers (a
                    // file), straight from the tiles' records: no copy into a buffer.
                    let mut pieces: Vec<io::IoSlice<'_>> = segments
                        .iter()
                        .flat_map(|seg| seg.chunks(PIECE_BYTES / NPY_RECORD_BYTES))
                        .map(|piece| io::IoSlice::new(piece.as_flattened()))
                        .collect();
                    write_all_vectored(out, &mut pieces)
                },
                |pixels| {
                    if let Ok(mut spare) = self.npy.spare.lock()
                        && keeps_spare(&spare, &pixels)
                    {
                        spare.push(pixels);
                    }
                },
            )
            .map_err(closed)
    }

    /// Writes the closing bytes and flushes the writer, once every row is out.
    pub fn finish(&self) -> io::Result<()> {
        let mut s = self
            .state
            .lock()
            .map_err(|_| io::Error::other("a worker panicked while writing"))?;
        if self.format == HitFormat::Npy {
            drop(s);
            self.drain_records().map_err(|e| io::Error::other(e.0))?;
            s = self
                .state
                .lock()
                .map_err(|_| io::Error::other("a worker panicked while writing"))?;
        }
        let complete = match self.format {
            HitFormat::Json | HitFormat::Csv => s.rows.is_complete(),
            HitFormat::Npy => s.records.is_complete(),
            HitFormat::Ndjson => true,
        };
        if !complete {
            return Err(io::Error::other("the hit data is incomplete"));
        }
        if self.format == HitFormat::Json {
            s.out.write_all(json::END)?;
        }
        s.out.flush()
    }

    /// Hands back the writer.
    pub fn into_writer(self) -> io::Result<W> {
        self.state
            .into_inner()
            .map(|s| s.out)
            .map_err(|_| io::Error::other("a worker panicked while writing"))
    }
}

/// Whether a written tile's record buffer is kept for the next tiles, beside those
/// already kept: while they hold [`QUEUED_TILES`] tiles or a band's records at most.
/// A band's tiles are written together once its last one is in, so keeping fewer
/// freed most of them, and the next band's tiles were encoded into fresh pages.
fn keeps_spare(
    spare: &[Vec<[u8; NPY_RECORD_BYTES]>],
    buffer: &Vec<[u8; NPY_RECORD_BYTES]>,
) -> bool {
    let kept: usize = spare.iter().map(Vec::capacity).sum();
    spare.len() < QUEUED_TILES || kept + buffer.capacity() <= BAND_PIXELS as usize
}

impl<W: Write + Send> TileSink<Option<Surface>> for HitSink<W> {
    /// Rows in order for every format but NDJSON, whose lines are tiles.
    fn tile_shape(&self, region: Rect, tile_px: u32) -> TileShape {
        match self.format {
            HitFormat::Ndjson => TileShape::square(tile_px),
            _ => TileShape::rows(region, tile_px),
        }
    }

    fn tile(&self, tile: Tile<Option<Surface>>) -> Result<(), SinkClosed> {
        let scene = &*self.scene;
        match self.format {
            HitFormat::Ndjson => {
                // Serialise outside the lock: only the write is serialised.
                let mut line = Vec::with_capacity(tile.pixels.len() * 160);
                let r = tile.rect;
                let pixels = tile.pixels.iter().enumerate().map(|(k, s)| {
                    let (u, v) = (r.x + k as u32 % r.width, r.y + k as u32 / r.width);
                    PixelHit::new(scene, u, v, s)
                });
                ndjson::push_line(&mut line, r, pixels).map_err(closed)?;
                let mut st = self.state.lock().map_err(closed)?;
                st.out.write_all(&line).map_err(closed)
            }
            HitFormat::Json | HitFormat::Csv => {
                let csv = self.format == HitFormat::Csv;
                let mut guard = self.state.lock().map_err(closed)?;
                let HitState {
                    out,
                    rows,
                    buf,
                    first,
                    ..
                } = &mut *guard;
                rows.push(tile, |v, x, segments| {
                    buf.clear();
                    for (k, s) in segments.iter().flat_map(|s| s.iter()).enumerate() {
                        let p = PixelHit::new(scene, x + k as u32, v, s);
                        if csv {
                            csv::push_row(buf, &p);
                        } else {
                            json::push_pixel(buf, first, &p)?;
                        }
                        if buf.len() >= PIECE_BYTES {
                            out.write_all(buf)?;
                            buf.clear();
                        }
                    }
                    out.write_all(buf)
                })
                .map_err(closed)
            }
            HitFormat::Npy => {
                // Encode outside the lock, into a buffer a written tile left behind.
                let r = tile.rect;
                let mut records = self
                    .npy
                    .spare
                    .lock()
                    .map_err(closed)?
                    .pop()
                    .unwrap_or_default();
                records.clear();
                // Exactly a tile: a kept buffer counts its capacity (`keeps_spare`).
                records.reserve_exact(tile.pixels.len());
                records.extend(tile.pixels.iter().enumerate().map(|(k, s)| {
                    npy_record_bytes(r.x + k as u32 % r.width, r.y + k as u32 / r.width, s)
                }));
                let encoded = Tile {
                    rect: r,
                    pixels: records,
                    rays: tile.rays,
                };
                self.npy.queue.hand(&self.state, encoded, |state, tile| {
                    self.write_records(state, tile)
                })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::{HitData, ReadError, SubmittedHit, npy};
    use crate::geometry::Face;
    use crate::scene::Limits;
    use glam::DVec3;

    /// A made-up first hit for every pixel: misses, hits with and without a face.
    fn surface(u: u32, v: u32) -> Option<Surface> {
        (!(u + v).is_multiple_of(3)).then(|| Surface {
            lambda: 1.0 + u as f64 / 7.0 + v as f64 * 0.1,
            object: 0,
            point: DVec3::new(u as f64 / 3.0, v as f64, -0.0),
            object_point: DVec3::new(0.1, 0.2, 0.3),
            normal: DVec3::new(0.0, 0.6, -0.8),
            front: true,
            face: u.is_multiple_of(2).then_some(Face::PosY),
        })
    }

    #[test]
    fn npy_tiles_from_many_threads_give_the_bytes_of_one() {
        let scene = Arc::new(
            crate::scene::parse(include_bytes!("../../scenes/lecture.json"), &Limits::NONE)
                .unwrap(),
        );
        let region = Rect {
            x: 0,
            y: 0,
            width: 40,
            height: 30,
        };
        let write = |threads: usize| {
            let sink = HitSink::new(scene.clone(), HitFormat::Npy, Vec::new(), region).unwrap();
            crate::output::feed_from_threads(&sink, region, 3, threads, surface);
            sink.finish().unwrap();
            sink.into_writer().unwrap()
        };
        let one = write(1);
        assert_eq!(
            one.len(),
            npy_header(30, 40).len() + 40 * 30 * NPY_RECORD_BYTES
        );
        for threads in [2, 4, 8] {
            assert!(write(threads) == one, "{threads} threads");
        }
    }

    #[test]
    fn a_written_band_leaves_its_record_buffers_for_the_next() {
        let scene = Arc::new(
            crate::scene::parse(include_bytes!("../../scenes/lecture.json"), &Limits::NONE)
                .unwrap(),
        );
        // A frame 1280 wide: bands of sixteen tiles of 80 × 12.
        let region = Rect::frame(1280, 24);
        let sink = HitSink::new(scene, HitFormat::Npy, Vec::new(), region).unwrap();
        let shape = sink.tile_shape(region, 32);
        let tiles = shape.cut(region);
        assert_eq!(tiles.len(), 32);
        for &t in &tiles[..16] {
            sink.tile(Tile::filled(t, surface)).unwrap();
        }
        sink.drain_records().unwrap();
        let kept = |sink: &HitSink<Vec<u8>>| sink.npy.spare.lock().unwrap().len();
        assert_eq!(kept(&sink), 16, "every buffer of the first band is kept");
        // The second band is encoded into them, and leaves as many.
        for &t in &tiles[16..] {
            sink.tile(Tile::filled(t, surface)).unwrap();
        }
        sink.drain_records().unwrap();
        assert_eq!(kept(&sink), 16);
        sink.finish().unwrap();
    }

    #[test]
    fn spare_buffers_hold_a_band_or_queued_tiles_at_most() {
        let buffers = |n: usize, records: usize| -> Vec<Vec<[u8; NPY_RECORD_BYTES]>> {
            (0..n).map(|_| Vec::with_capacity(records)).collect()
        };
        let band = BAND_PIXELS as usize;
        // Small tiles: as many as a band holds.
        let tile = band / 16;
        assert!(keeps_spare(&buffers(15, tile), &buffers(1, tile)[0]));
        assert!(!keeps_spare(&buffers(16, tile), &buffers(1, tile)[0]));
        // Large tiles: the queued count still.
        let tile = band;
        assert!(keeps_spare(
            &buffers(QUEUED_TILES - 1, tile),
            &buffers(1, tile)[0]
        ));
        assert!(!keeps_spare(
            &buffers(QUEUED_TILES, tile),
            &buffers(1, tile)[0]
        ));
    }

    #[test]
    fn every_format_reads_back_the_region_whatever_order_tiles_finish_in() {
        let scene = Arc::new(
            crate::scene::parse(include_bytes!("../../scenes/lecture.json"), &Limits::NONE)
                .unwrap(),
        );
        let region = Rect {
            x: 1,
            y: 2,
            width: 4,
            height: 3,
        };
        let mut expected = Vec::new();
        for v in region.y..region.y + region.height {
            for u in region.x..region.x + region.width {
                let p = PixelHit::new(&scene, u, v, &surface(u, v));
                expected.push(SubmittedHit::from(&p));
            }
        }
        for format in HitFormat::ALL {
            let write = |reverse: bool| {
                let sink = HitSink::new(scene.clone(), format, Vec::new(), region).unwrap();
                let mut tiles = sink.tile_shape(region, 2).cut(region);
                if reverse {
                    tiles.reverse();
                }
                for t in tiles {
                    sink.tile(Tile::filled(t, surface)).unwrap();
                }
                sink.finish().unwrap();
                sink.into_writer().unwrap()
            };
            let (forward, backward) = (write(false), write(true));
            if format != HitFormat::Ndjson {
                assert!(forward == backward, "{format:?} depends on the tile order");
            }
            let read: fn(&[u8]) -> Result<HitData, ReadError> = match format {
                HitFormat::Json => json::read,
                HitFormat::Ndjson => ndjson::read,
                HitFormat::Npy => npy::read,
                HitFormat::Csv => csv::read,
            };
            let data = read(&backward).unwrap();
            assert_eq!(data.format, format.name());
            let mut got: Vec<SubmittedHit> =
                data.groups.into_iter().flat_map(|g| g.pixels).collect();
            if format == HitFormat::Npy {
                // The array knows only its own indices; the region is where it lies.
                for p in &mut got {
                    p.u = p.u.map(|u| u + region.x);
                    p.v = p.v.map(|v| v + region.y);
                }
            }
            got.sort_by_key(|p| (p.v, p.u));
            assert_eq!(got, expected, "{format:?}");
        }
    }
}
