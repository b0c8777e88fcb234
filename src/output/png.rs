//! A PNG written row by row as soon as rows are complete (the encoder and its settings
//! are [`crate::format::png`]'s).
//!
//! Rows are fed to the encoder in order, whole or (in a frame too wide for a band) in
//! pieces left to right, straight from the tiles' pixels; the encoder filters and
//! compresses whole rows, so the bytes depend only on the pixels: the same image gives
//! the same file whatever the tile size or shape, the thread count or the pieces.

use std::io::{self, Write};
use std::sync::{Arc, Mutex};

use super::handoff::Handoff;
use super::rows::RowAssembler;
use crate::format::png::stream_writer;
use crate::render::{Rect, SinkClosed, Tile, TileShape, TileSink};

/// A [`TileSink`] that streams a PNG of `region` into a writer.
pub struct PngSink<W: Write + Send + 'static> {
    state: Mutex<State<W>>,
    /// Tiles waiting for whichever worker holds the encoder. A worker that waited for
    /// it while another compressed a band lost that time to tracing: with two
    /// threads, the sink's time was twice the encoder's own.
    queue: Handoff<[u8; 3]>,
    error: Arc<Mutex<Option<io::Error>>>,
}

struct State<W: Write + 'static> {
    rows: RowAssembler<[u8; 3]>,
    stream: Option<png::StreamWriter<'static, Checked<W>>>,
}

/// Remembers the first error of the inner writer: the PNG encoder writes its trailer
/// when dropped and would otherwise swallow a failure there.
struct Checked<W> {
    inner: W,
    error: Arc<Mutex<Option<io::Error>>>,
}

impl<W: Write> Write for Checked<W> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.inner.write(buf).inspect_err(|e| self.record(e))
    }
    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush().inspect_err(|e| self.record(e))
    }
}

impl<W> Checked<W> {
    fn record(&self, e: &io::Error) {
        if let Ok(mut slot) = self.error.lock()
            && slot.is_none()
        {
            *slot = Some(io::Error::new(e.kind(), e.to_string()));
        }
    }
}

fn png_err(e: png::EncodingError) -> io::Error {
    match e {
        png::EncodingError::IoError(e) => e,
        other => io::Error::other(other.to_string()),
    }
}

impl<W: Write + Send + 'static> PngSink<W> {
    /// Writes the PNG header for a `region.width × region.height` image at once.
    pub fn new(writer: W, region: Rect) -> io::Result<Self> {
        let error = Arc::new(Mutex::new(None));
        let checked = Checked {
            inner: writer,
            error: error.clone(),
        };
        let stream = stream_writer(checked, region.width, region.height).map_err(png_err)?;
        Ok(PngSink {
            state: Mutex::new(State {
                rows: RowAssembler::new(region),
                stream: Some(stream),
            }),
            queue: Handoff::default(),
            error,
        })
    }

    /// Completes the file (the last compressed data and the trailer).
    pub fn finish(&self) -> io::Result<()> {
        self.queue
            .drain(&self.state, true, write_tile)
            .map_err(|e| io::Error::other(e.0))?;
        let mut state = self
            .state
            .lock()
            .map_err(|_| io::Error::other("a worker panicked while writing"))?;
        if !state.rows.is_complete() {
            return Err(io::Error::other("the image is incomplete"));
        }
        if let Some(s) = state.stream.take() {
            s.finish().map_err(png_err)?;
        }
        match self.error.lock().ok().and_then(|mut e| e.take()) {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}

impl<W: Write + Send + 'static> TileSink<[u8; 3]> for PngSink<W> {
    fn tile_shape(&self, region: Rect, tile_px: u32) -> TileShape {
        TileShape::rows(region, tile_px)
    }

    fn tile(&self, tile: Tile<[u8; 3]>) -> Result<(), SinkClosed> {
        self.queue.hand(&self.state, tile, write_tile)
    }
}

/// Feeds a tile's rows to the encoder as they can leave.
fn write_tile<W: Write>(state: &mut State<W>, tile: Tile<[u8; 3]>) -> Result<(), SinkClosed> {
    let State { rows, stream } = state;
    let Some(stream) = stream.as_mut() else {
        return Err(SinkClosed("the PNG is already finished".into()));
    };
    rows.push(tile, |_, _, segments| {
        segments
            .iter()
            .try_for_each(|seg| stream.write_all(seg.as_flattened()))
    })
    .map_err(|e| SinkClosed(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::{Arc, Mutex};

    /// A writer whose bytes stay readable after the sink is done with it.
    #[derive(Clone, Default)]
    struct Shared(Arc<Mutex<Vec<u8>>>);
    impl Write for Shared {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    fn colour(u: u32, v: u32) -> [u8; 3] {
        [(u * 7) as u8, (v * 31) as u8, ((u ^ v) % 251) as u8]
    }

    fn encode(region: Rect, tiles: Vec<Rect>) -> Vec<u8> {
        let out = Shared::default();
        let sink = PngSink::new(out.clone(), region).unwrap();
        for t in tiles.into_iter().rev() {
            sink.tile(Tile::filled(t, colour)).unwrap();
        }
        sink.finish().unwrap();
        out.0.lock().unwrap().clone()
    }

    /// Tiles handed in by many workers at once, some queued while another encodes,
    /// give the file one worker writes: every tile written, none twice, in order.
    #[test]
    fn tiles_from_many_threads_give_the_file_of_one() {
        let region = Rect::frame(40, 30);
        let write = |threads: usize| {
            let out = Shared::default();
            let sink = PngSink::new(out.clone(), region).unwrap();
            crate::output::feed_from_threads(&sink, region, 3, threads, colour);
            sink.finish().unwrap();
            out.0.lock().unwrap().clone()
        };
        let one = write(1);
        use crate::format::raster::{self, DecodeLimits, Raster, RasterFormat};
        let limits = DecodeLimits::for_frame(40, 30);
        let Raster::Rgb8(img) = raster::decode(&one, RasterFormat::Png, &limits).unwrap() else {
            panic!("a PNG decodes to 8-bit RGB")
        };
        assert_eq!(img.get(39, 29), colour(39, 29));
        for threads in [2, 4, 8] {
            assert!(write(threads) == one, "{threads} threads");
        }
    }

    #[test]
    fn the_file_is_the_same_whether_rows_leave_whole_or_in_pieces() {
        // Wide enough that its bands are one row high and rows leave tile by tile.
        let region = Rect::frame(40_000, 3);
        let shape = PngSink::<Shared>::new(Shared::default(), region)
            .unwrap()
            .tile_shape(region, 32);
        assert_eq!(shape.height, 1);
        let pieces = encode(region, shape.cut(region));
        let whole = encode(region, region.tiles(32));
        assert!(pieces == whole, "the bytes depend on how rows were fed");
        use crate::format::raster::{self, DecodeLimits, Raster, RasterFormat};
        let limits = DecodeLimits::for_frame(40_000, 3);
        let Raster::Rgb8(img) = raster::decode(&pieces, RasterFormat::Png, &limits).unwrap() else {
            panic!("a PNG decodes to 8-bit RGB")
        };
        assert_eq!(img.get(39_999, 2), colour(39_999, 2));
    }
}
