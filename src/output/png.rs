//! A PNG written row by row as soon as rows are complete (the encoder and its settings
//! are [`crate::format::png`]'s).
//!
//! Rows are always fed to the encoder one at a time, so the bytes depend only on the
//! pixels: the same image gives the same file whatever the tile size or thread count.

use std::io::{self, Write};
use std::sync::{Arc, Mutex};

use super::rows::RowAssembler;
use crate::format::png::stream_writer;
use crate::render::{Rect, SinkClosed, Tile, TileSink};

/// A [`TileSink`] that streams a PNG of `region` into a writer.
pub struct PngSink<W: Write + Send + 'static> {
    state: Mutex<State<W>>,
    error: Arc<Mutex<Option<io::Error>>>,
}

struct State<W: Write + 'static> {
    rows: RowAssembler<[u8; 3]>,
    stream: Option<png::StreamWriter<'static, Checked<W>>>,
    line: Vec<u8>,
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
    pub fn new(writer: W, region: Rect, tile_px: u32) -> io::Result<Self> {
        let error = Arc::new(Mutex::new(None));
        let checked = Checked {
            inner: writer,
            error: error.clone(),
        };
        let stream = stream_writer(checked, region.width, region.height).map_err(png_err)?;
        Ok(PngSink {
            state: Mutex::new(State {
                rows: RowAssembler::new(region, tile_px),
                stream: Some(stream),
                line: Vec::with_capacity(region.width as usize * 3),
            }),
            error,
        })
    }

    /// Completes the file (the last compressed data and the trailer).
    pub fn finish(self) -> io::Result<()> {
        let state = self
            .state
            .into_inner()
            .map_err(|_| io::Error::other("a worker panicked while writing"))?;
        if !state.rows.is_complete() {
            return Err(io::Error::other("the image is incomplete"));
        }
        if let Some(s) = state.stream {
            s.finish().map_err(png_err)?;
        }
        match self.error.lock().ok().and_then(|mut e| e.take()) {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}

impl<W: Write + Send + 'static> TileSink<[u8; 3]> for PngSink<W> {
    fn tile(&self, tile: Tile<[u8; 3]>) -> Result<(), SinkClosed> {
        let mut guard = self
            .state
            .lock()
            .map_err(|_| SinkClosed("a worker panicked while writing".into()))?;
        let State { rows, stream, line } = &mut *guard;
        let Some(stream) = stream.as_mut() else {
            return Err(SinkClosed("the PNG is already finished".into()));
        };
        rows.push(tile, |_, segments| {
            line.clear();
            for seg in segments {
                line.extend(seg.iter().flatten());
            }
            stream.write_all(line)
        })
        .map_err(|e| SinkClosed(e.to_string()))
    }
}
