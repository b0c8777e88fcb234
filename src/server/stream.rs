//! The bridge from the renderer's blocking world to an HTTP body.
//!
//! The sinks of [`crate::output`] write into any `std::io::Write`. [`BodyWriter`] is that
//! writer: it gathers bytes into chunks and hands each to a bounded tokio channel, waiting
//! on the rayon thread that produced them when the channel is full. [`StreamBody`] is the other
//! end, an `http_body::Body` that hyper polls on a tokio thread. So tokio only moves
//! bytes, and a slow client slows its own render (the channel is bounded) instead of
//! piling the image up in memory.
//!
//! A send into a closed channel means the client left: the write fails, the sink
//! refuses the next tile, and [`crate::render::run`] stops between tiles. A send into a
//! full channel waits for the client, but not for ever: [`Aborter::abort`] (the deadline,
//! the end of the shutdown grace period) ends the wait, so a client that stops reading
//! cannot hold a rayon thread past its deadline.
//!
//! The stream ends in one of three ways, and only the first is a complete body:
//! [`BodyWriter::finish`] (optionally with trailers), [`BodyWriter::fail`] (the body
//! errors, so hyper cuts the connection and the client sees a truncated transfer), or
//! the writer being dropped without either (treated as a failure, so a render that
//! died half-way can never look like a finished image).

use std::io::{self, Write};
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};

use axum::http::HeaderMap;
use bytes::Bytes;
use futures::future::{Either, select};
use http_body::{Frame, SizeHint};
use tokio::sync::{mpsc, watch};

/// Bytes gathered before a chunk is sent (unless a band completes first).
pub const CHUNK_BYTES: usize = 64 * 1024;

/// Chunks that may wait in the channel: up to `CHANNEL_CHUNKS × CHUNK_BYTES` (2 MiB)
/// buffered per response before the render waits for the client.
pub const CHANNEL_CHUNKS: usize = 32;

/// What travels down the channel.
#[derive(Debug)]
enum Item {
    Data(Bytes),
    End(Option<HeaderMap>),
    Fail(io::Error),
}

/// A body fed from another thread: the writer and the body it feeds. Called on the
/// runtime, whose timer then bounds each wait of the writer for the client by `stall`:
/// a client that stops reading must not hold the trace threads, which every other
/// render needs, until its deadline.
pub fn channel(stall: std::time::Duration) -> (BodyWriter, StreamBody) {
    let (tx, rx) = mpsc::channel(CHANNEL_CHUNKS);
    (
        BodyWriter {
            tx,
            pending: Arc::new(Mutex::new(Vec::with_capacity(CHUNK_BYTES))),
            abort: Arc::new(watch::Sender::new(false)),
            runtime: tokio::runtime::Handle::try_current().ok(),
            stall,
            stalled: Arc::new(std::sync::atomic::AtomicBool::new(false)),
        },
        StreamBody {
            rx,
            state: BodyState::Open,
        },
    )
}

/// The sending half: a blocking [`Write`] for rayon threads. Cheap to clone; all clones
/// share one buffer, so bytes leave in the order they were written.
#[derive(Debug, Clone)]
pub struct BodyWriter {
    tx: mpsc::Sender<Item>,
    pending: Arc<Mutex<Vec<u8>>>,
    abort: Arc<watch::Sender<bool>>,
    /// The runtime whose timer bounds a wait (none outside a runtime, e.g. in unit tests).
    runtime: Option<tokio::runtime::Handle>,
    /// The longest wait for room in the channel.
    stall: std::time::Duration,
    /// Set when a wait ran out: the client stopped reading.
    stalled: Arc<std::sync::atomic::AtomicBool>,
}

/// Ends any wait of a [`BodyWriter`] for room in the channel, now and later. Holding one
/// does not keep the body open.
#[derive(Debug, Clone)]
pub struct Aborter(Arc<watch::Sender<bool>>);

impl Aborter {
    /// Makes every later or waiting send fail at once.
    pub fn abort(&self) {
        self.0.send_replace(true);
    }
}

fn gone() -> io::Error {
    io::Error::new(io::ErrorKind::BrokenPipe, "the client went away")
}

fn poisoned() -> io::Error {
    io::Error::other("a render thread panicked while writing")
}

fn aborted() -> io::Error {
    io::Error::new(io::ErrorKind::TimedOut, "the response was cut")
}

fn stalled() -> io::Error {
    io::Error::new(
        io::ErrorKind::TimedOut,
        "the client took nothing for too long",
    )
}

impl BodyWriter {
    /// A handle that ends waits for the client.
    pub fn aborter(&self) -> Aborter {
        Aborter(self.abort.clone())
    }

    /// Hands `item` to the body, waiting while the channel is full, until the client
    /// leaves or the writer is aborted. Must not be called on a tokio thread.
    fn send(&self, item: Item) -> io::Result<()> {
        if *self.abort.borrow() {
            return Err(aborted());
        }
        let item = match self.tx.try_send(item) {
            Ok(()) => return Ok(()),
            Err(mpsc::error::TrySendError::Closed(_)) => return Err(gone()),
            Err(mpsc::error::TrySendError::Full(item)) => item,
        };
        let mut abort = self.abort.subscribe();
        let wait = async {
            let send = std::pin::pin!(self.tx.send(item));
            let stop = std::pin::pin!(abort.wait_for(|a| *a));
            match select(send, stop).await {
                Either::Left((Ok(()), _)) => Ok(()),
                Either::Left((Err(_), _)) => Err(gone()),
                Either::Right(_) => Err(aborted()),
            }
        };
        match &self.runtime {
            // A rayon thread is no runtime thread, so it may block on the runtime's handle.
            Some(rt) => rt.block_on(async {
                tokio::time::timeout(self.stall, wait)
                    .await
                    .unwrap_or_else(|_| {
                        self.stalled
                            .store(true, std::sync::atomic::Ordering::Relaxed);
                        Err(stalled())
                    })
            }),
            None => futures::executor::block_on(wait),
        }
    }

    /// Whether a wait for the client ran out (it stopped reading).
    pub fn has_stalled(&self) -> bool {
        self.stalled.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Whether the receiving body is gone (the client disconnected or the response was
    /// dropped): checked between tiles so that tracing stops even while no bytes flow.
    pub fn is_closed(&self) -> bool {
        self.tx.is_closed()
    }

    /// Sends whatever is buffered now, e.g. after a band of rows is complete.
    /// Blocks while the channel is full. Must not be called on a tokio thread.
    pub fn send_pending(&self) -> io::Result<()> {
        let mut p = self.pending.lock().map_err(|_| poisoned())?;
        if p.is_empty() {
            return Ok(());
        }
        // Send under the lock: a buffer taken here must not be overtaken by a later one.
        let chunk = Bytes::from(std::mem::replace(&mut *p, Vec::with_capacity(CHUNK_BYTES)));
        self.send(Item::Data(chunk))
    }

    /// Sends the rest and ends the body, with `trailers` if the client accepts them.
    pub fn finish(&self, trailers: Option<HeaderMap>) -> io::Result<()> {
        self.send_pending()?;
        self.send(Item::End(trailers))
    }

    /// Ends the body with an error: hyper aborts the response, so the client sees an
    /// incomplete transfer rather than a short file that looks whole.
    pub fn fail(&self, why: impl Into<String>) {
        if let Ok(mut p) = self.pending.lock() {
            p.clear();
        }
        // Never waits: if the channel is full or closed, the body still ends in an
        // error once the last writer is dropped without `finish`.
        let _ = self.tx.try_send(Item::Fail(io::Error::other(why.into())));
    }
}

impl Write for BodyWriter {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        if self.tx.is_closed() {
            return Err(gone());
        }
        let full = {
            let mut p = self.pending.lock().map_err(|_| poisoned())?;
            p.extend_from_slice(buf);
            p.len() >= CHUNK_BYTES
        };
        if full {
            self.send_pending()?;
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        self.send_pending()
    }
}

#[derive(Debug)]
enum BodyState {
    Open,
    Done,
}

/// The receiving half: the response body hyper polls.
#[derive(Debug)]
pub struct StreamBody {
    rx: mpsc::Receiver<Item>,
    state: BodyState,
}

impl http_body::Body for StreamBody {
    type Data = Bytes;
    type Error = io::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, io::Error>>> {
        if matches!(self.state, BodyState::Done) {
            return Poll::Ready(None);
        }
        let item = match self.rx.poll_recv(cx) {
            Poll::Pending => return Poll::Pending,
            Poll::Ready(item) => item,
        };
        Poll::Ready(match item {
            Some(Item::Data(b)) => Some(Ok(Frame::data(b))),
            Some(Item::End(trailers)) => {
                self.state = BodyState::Done;
                trailers.map(|t| Ok(Frame::trailers(t)))
            }
            Some(Item::Fail(e)) => {
                self.state = BodyState::Done;
                Some(Err(e))
            }
            None => {
                self.state = BodyState::Done;
                Some(Err(io::Error::other(
                    "the render stopped without finishing",
                )))
            }
        })
    }

    fn is_end_stream(&self) -> bool {
        matches!(self.state, BodyState::Done)
    }

    fn size_hint(&self) -> SizeHint {
        SizeHint::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use http_body_util::BodyExt;

    fn runtime() -> tokio::runtime::Runtime {
        tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap()
    }

    #[test]
    fn bytes_arrive_in_order_then_trailers() {
        let (mut w, body) = channel(std::time::Duration::from_secs(15));
        let writer = std::thread::spawn(move || {
            for i in 0..1000u32 {
                w.write_all(&i.to_le_bytes()).unwrap();
                if i % 100 == 0 {
                    w.send_pending().unwrap();
                }
            }
            let mut t = HeaderMap::new();
            t.insert("server-timing", "render;dur=1".parse().unwrap());
            w.finish(Some(t)).unwrap();
        });
        let collected = runtime().block_on(body.collect()).unwrap();
        writer.join().unwrap();
        assert_eq!(
            collected.trailers().unwrap()["server-timing"],
            "render;dur=1"
        );
        let bytes = collected.to_bytes();
        let expected: Vec<u8> = (0..1000u32).flat_map(|i| i.to_le_bytes()).collect();
        assert_eq!(bytes.as_ref(), expected.as_slice());
    }

    #[test]
    fn a_writer_dropped_without_finishing_fails_the_body() {
        let (mut w, body) = channel(std::time::Duration::from_secs(15));
        std::thread::spawn(move || {
            w.write_all(b"half").unwrap();
            w.send_pending().unwrap();
        })
        .join()
        .unwrap();
        assert!(runtime().block_on(body.collect()).is_err());
    }

    #[test]
    fn abort_ends_a_wait_for_a_client_that_does_not_read() {
        let (mut w, _body) = channel(std::time::Duration::from_secs(15));
        let aborter = w.aborter();
        let writer = std::thread::spawn(move || {
            let chunk = vec![0u8; CHUNK_BYTES];
            loop {
                if let Err(e) = w.write_all(&chunk) {
                    return e.kind();
                }
            }
        });
        std::thread::sleep(std::time::Duration::from_millis(50));
        aborter.abort();
        assert_eq!(writer.join().unwrap(), io::ErrorKind::TimedOut);
    }

    #[test]
    fn writing_to_a_dropped_body_fails() {
        let (mut w, body) = channel(std::time::Duration::from_secs(15));
        drop(body);
        assert!(w.is_closed());
        assert_eq!(w.write(b"x").unwrap_err().kind(), io::ErrorKind::BrokenPipe);
    }
}
