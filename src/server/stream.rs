//! The bridge from the renderer's blocking world to an HTTP body.
//!
//! The sinks of [`crate::output`] write into any `std::io::Write`. [`BodyWriter`] is that
//! writer: it cuts the bytes into chunks of at most [`CHUNK_BYTES`] and queues them for
//! [`StreamBody`], the `http_body::Body` that hyper polls on a tokio thread. So tokio
//! only moves bytes, and whatever a sink writes at once (a whole band of rows, an NDJSON
//! line), no chunk is larger than 64 KiB.
//!
//! A write never waits: a render thread must not be held by a client that does not
//! read. Instead the render asks before each tile whether the output is backed up
//! ([`BodyWriter::is_backed_up`]: [`IN_FLIGHT_BYTES`] queued, [`IN_FLIGHT_CHUNKS`] full
//! chunks) and, when it is, parks: it traces nothing, gives back its thread and its
//! render slot, and waits on the runtime in [`BodyWriter::room`] until the client has
//! taken half of it (the body's poll wakes the wait), or until `--stall-seconds` pass
//! without the client taking anything, which stops the render for good
//! ([`crate::server::render`]). So the queue holds at most [`IN_FLIGHT_BYTES`] plus what
//! the tiles being traced when it filled release, which [`crate::output::rows`] bounds.
//!
//! A write into a body that is gone means the client left: the write fails, the sink
//! refuses the next tile, and the render stops. [`Aborter::abort`] (the deadline, the
//! end of the shutdown grace period) makes every later write fail and ends a wait for
//! room.
//!
//! The stream ends in one of three ways, and only the first is a complete body:
//! [`BodyWriter::finish`] (optionally with trailers), [`BodyWriter::fail`] (the body
//! errors, so hyper cuts the connection and the client sees a truncated transfer), or
//! the last writer being dropped without either (treated as a failure, so a render that
//! died half-way can never look like a finished image).

use std::collections::VecDeque;
use std::io::{self, Write};
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard};
use std::task::{Context, Poll, Waker};
use std::time::Duration;

use axum::http::HeaderMap;
use bytes::Bytes;
use http_body::{Frame, SizeHint};
use tokio::sync::{Notify, watch};

/// The largest chunk a body sends.
pub const CHUNK_BYTES: usize = 64 * 1024;

/// Full chunks a response may have queued for its client before its render parks.
pub const IN_FLIGHT_CHUNKS: usize = 32;

/// Bytes a response may have queued for its client before its render parks (2 MiB).
pub const IN_FLIGHT_BYTES: usize = IN_FLIGHT_CHUNKS * CHUNK_BYTES;

/// A parked render resumes once the queue is down to this.
pub const RESUME_BYTES: usize = IN_FLIGHT_BYTES / 2;

/// How the body ends.
#[derive(Debug)]
enum End {
    Trailers(Option<HeaderMap>),
    Fail(io::Error),
}

/// The queue between the writers and the body.
#[derive(Debug, Default)]
struct Queue {
    /// Bytes not yet a chunk (fewer than [`CHUNK_BYTES`]).
    pending: Vec<u8>,
    chunks: VecDeque<Bytes>,
    /// Bytes in `chunks`.
    queued: usize,
    /// Set once, by the first of finish, fail, or the last writer's drop.
    end: Option<End>,
    /// The body has taken `end`.
    done: bool,
    /// The body was dropped (the client left or the response was discarded).
    body_gone: bool,
    /// Chunks the body has taken: progress, for the stall rule.
    taken: u64,
    waker: Option<Waker>,
}

#[derive(Debug)]
struct Shared {
    queue: Mutex<Queue>,
    /// Woken when the body takes a chunk or goes away.
    room: Notify,
    abort: watch::Sender<bool>,
}

impl Shared {
    fn lock(&self) -> io::Result<MutexGuard<'_, Queue>> {
        self.queue.lock().map_err(|_| poisoned())
    }

    /// Ends the body (unless it has ended) and wakes it.
    fn end(&self, end: End) -> bool {
        let Ok(mut q) = self.queue.lock() else {
            return false;
        };
        if q.end.is_some() {
            return false;
        }
        q.end = Some(end);
        if let Some(w) = q.waker.take() {
            w.wake();
        }
        true
    }
}

/// A body fed from other threads: the writer and the body it feeds.
pub fn channel() -> (BodyWriter, StreamBody) {
    let shared = Arc::new(Shared {
        queue: Mutex::new(Queue::default()),
        room: Notify::new(),
        abort: watch::Sender::new(false),
    });
    (
        BodyWriter {
            _last: Arc::new(LastWriter(shared.clone())),
            shared: shared.clone(),
        },
        StreamBody { shared },
    )
}

/// Fails the body when the last writer goes without finishing it.
#[derive(Debug)]
struct LastWriter(Arc<Shared>);

impl Drop for LastWriter {
    fn drop(&mut self) {
        self.0.end(End::Fail(io::Error::other(
            "the render stopped without finishing",
        )));
    }
}

/// The sending half: a [`Write`] that never blocks. Cheap to clone; all clones share
/// one queue, so bytes leave in the order they were written.
#[derive(Debug, Clone)]
pub struct BodyWriter {
    shared: Arc<Shared>,
    /// Shared by the clones: the body fails when the last one goes unfinished.
    _last: Arc<LastWriter>,
}

/// Makes every later write of a [`BodyWriter`] fail and ends its waits for room.
/// Holding one does not keep the body open.
#[derive(Debug, Clone)]
pub struct Aborter(Arc<Shared>);

impl Aborter {
    /// Makes every later write fail at once, and ends a wait for room.
    pub fn abort(&self) {
        self.0.abort.send_replace(true);
    }
}

/// How a wait for room ended ([`BodyWriter::room`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Room {
    /// The client took enough: the render may go on.
    Ready,
    /// The body is gone: the client left.
    Closed,
    /// The writer was aborted (deadline, shutdown).
    Aborted,
    /// The client took nothing for the whole stall period.
    Stalled,
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

fn ended() -> io::Error {
    io::Error::other("the response has already ended")
}

impl Queue {
    /// Queues the pending bytes as a chunk of their own size.
    fn push_pending(&mut self) {
        if self.pending.is_empty() {
            return;
        }
        let chunk = if self.pending.len() == CHUNK_BYTES {
            Bytes::from(std::mem::take(&mut self.pending))
        } else {
            // A copy of its own size: a short chunk must not pin a 64 KiB buffer.
            let c = Bytes::copy_from_slice(&self.pending);
            self.pending.clear();
            c
        };
        self.queued += chunk.len();
        self.chunks.push_back(chunk);
        if let Some(w) = self.waker.take() {
            w.wake();
        }
    }

    fn writable(&self, abort: &watch::Sender<bool>) -> io::Result<()> {
        if self.body_gone {
            Err(gone())
        } else if *abort.borrow() {
            Err(aborted())
        } else if self.end.is_some() {
            Err(ended())
        } else {
            Ok(())
        }
    }
}

impl BodyWriter {
    /// A handle that cuts the writer.
    pub fn aborter(&self) -> Aborter {
        Aborter(self.shared.clone())
    }

    /// Whether the receiving body is gone (the client disconnected or the response was
    /// dropped): checked between tiles so that tracing stops even while no bytes flow.
    pub fn is_closed(&self) -> bool {
        self.shared.lock().map_or(true, |q| q.body_gone)
    }

    /// Whether the client is behind: [`IN_FLIGHT_BYTES`] or more wait for it. A render
    /// traces no further tile then, but parks until [`BodyWriter::room`].
    pub fn is_backed_up(&self) -> bool {
        self.shared.lock().is_ok_and(|q| {
            q.queued + q.pending.len() >= IN_FLIGHT_BYTES || q.chunks.len() >= IN_FLIGHT_CHUNKS
        })
    }

    /// Bytes waiting for the client now (queued chunks and the bytes not yet a chunk).
    pub fn queued_bytes(&self) -> usize {
        self.shared.lock().map_or(0, |q| q.queued + q.pending.len())
    }

    /// Waits until the client has taken enough that at most [`RESUME_BYTES`] wait for
    /// it, or the body is gone, or the writer is aborted, or `stall` passes without the
    /// client taking a single chunk. Runs on the runtime (never on a render thread).
    pub async fn room(&self, stall: Duration) -> Room {
        let mut abort = self.shared.abort.subscribe();
        loop {
            let notified = self.shared.room.notified();
            let mut notified = std::pin::pin!(notified);
            notified.as_mut().enable();
            let taken = match self.shared.lock() {
                Err(_) => return Room::Closed,
                Ok(q) if q.body_gone => return Room::Closed,
                Ok(q) if q.queued + q.pending.len() <= RESUME_BYTES => return Room::Ready,
                Ok(q) => q.taken,
            };
            if *abort.borrow_and_update() {
                return Room::Aborted;
            }
            // Each chunk the client takes starts the stall period again.
            tokio::select! {
                _ = notified => {}
                _ = abort.wait_for(|a| *a) => return Room::Aborted,
                _ = tokio::time::sleep(stall) => {
                    let now = self.shared.lock().map_or(taken, |q| q.taken);
                    if now == taken {
                        return Room::Stalled;
                    }
                }
            }
        }
    }

    /// Resolves once the writer is aborted.
    pub async fn aborted(&self) {
        let mut abort = self.shared.abort.subscribe();
        let _ = abort.wait_for(|a| *a).await;
    }

    /// Hands over the bytes not yet a chunk if the client has nothing else to read, so
    /// that the first rows leave early while a client that is behind gets full chunks.
    pub fn send_pending(&self) -> io::Result<()> {
        let mut q = self.shared.lock()?;
        q.writable(&self.shared.abort)?;
        if q.chunks.is_empty() {
            q.push_pending();
        }
        Ok(())
    }

    /// Sends the rest and ends the body, with `trailers` if the client accepts them.
    pub fn finish(&self, trailers: Option<HeaderMap>) -> io::Result<()> {
        {
            let mut q = self.shared.lock()?;
            q.writable(&self.shared.abort)?;
            q.push_pending();
        }
        if self.shared.end(End::Trailers(trailers)) {
            Ok(())
        } else {
            Err(ended())
        }
    }

    /// Ends the body with an error: hyper aborts the response, so the client sees an
    /// incomplete transfer rather than a short file that looks whole. What was queued
    /// and not yet taken is thrown away.
    pub fn fail(&self, why: impl Into<String>) {
        if let Ok(mut q) = self.shared.lock() {
            q.pending = Vec::new();
            q.chunks.clear();
            q.queued = 0;
        }
        self.shared.end(End::Fail(io::Error::other(why.into())));
    }
}

impl Write for BodyWriter {
    /// Takes all of `buf` at once, cut into chunks of at most [`CHUNK_BYTES`].
    fn write(&mut self, mut buf: &[u8]) -> io::Result<usize> {
        let n = buf.len();
        let mut q = self.shared.lock()?;
        q.writable(&self.shared.abort)?;
        while !buf.is_empty() {
            if q.pending.capacity() == 0 {
                q.pending.reserve_exact(CHUNK_BYTES);
            }
            let take = (CHUNK_BYTES - q.pending.len()).min(buf.len());
            q.pending.extend_from_slice(&buf[..take]);
            buf = &buf[take..];
            if q.pending.len() == CHUNK_BYTES {
                q.push_pending();
            }
        }
        Ok(n)
    }

    /// Hands over the bytes not yet a chunk, whatever the client has queued.
    fn flush(&mut self) -> io::Result<()> {
        let mut q = self.shared.lock()?;
        q.writable(&self.shared.abort)?;
        q.push_pending();
        Ok(())
    }
}

/// The receiving half: the response body hyper polls.
#[derive(Debug)]
pub struct StreamBody {
    shared: Arc<Shared>,
}

impl Drop for StreamBody {
    fn drop(&mut self) {
        if let Ok(mut q) = self.shared.queue.lock() {
            q.body_gone = true;
            q.chunks.clear();
            q.pending = Vec::new();
            q.queued = 0;
        }
        self.shared.room.notify_one();
    }
}

impl http_body::Body for StreamBody {
    type Data = Bytes;
    type Error = io::Error;

    fn poll_frame(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, io::Error>>> {
        let Ok(mut q) = self.shared.queue.lock() else {
            return Poll::Ready(Some(Err(poisoned())));
        };
        if q.done {
            return Poll::Ready(None);
        }
        let failed = matches!(q.end, Some(End::Fail(_)));
        if !failed && let Some(chunk) = q.chunks.pop_front() {
            q.queued -= chunk.len();
            q.taken += 1;
            drop(q);
            // Wakes a parked render's wait (which checks whether enough room is free).
            self.shared.room.notify_one();
            return Poll::Ready(Some(Ok(Frame::data(chunk))));
        }
        match q.end.take() {
            None => {
                q.waker = Some(cx.waker().clone());
                Poll::Pending
            }
            Some(End::Trailers(t)) => {
                q.done = true;
                Poll::Ready(t.map(|t| Ok(Frame::trailers(t))))
            }
            Some(End::Fail(e)) => {
                q.done = true;
                Poll::Ready(Some(Err(e)))
            }
        }
    }

    fn is_end_stream(&self) -> bool {
        self.shared.queue.lock().map_or(true, |q| q.done)
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
            .enable_time()
            .build()
            .unwrap()
    }

    #[test]
    fn bytes_arrive_in_order_then_trailers() {
        let (mut w, body) = channel();
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

    /// Collects the body's data frames one by one.
    fn frames(mut body: StreamBody) -> Vec<Bytes> {
        runtime().block_on(async {
            let mut out = Vec::new();
            while let Some(f) = body.frame().await {
                if let Ok(d) = f.unwrap().into_data() {
                    out.push(d);
                }
            }
            out
        })
    }

    #[test]
    fn no_chunk_is_larger_than_64_kib_whatever_the_writes() {
        let (mut w, body) = channel();
        // One huge write, many odd small ones, one just over a chunk, and flushes between.
        let huge: Vec<u8> = (0..10 * CHUNK_BYTES + 12_345).map(|i| i as u8).collect();
        let mut expected = Vec::new();
        w.write_all(&huge).unwrap();
        expected.extend_from_slice(&huge);
        for k in 0..5000usize {
            let piece = vec![(k % 251) as u8; k % 97 + 1];
            w.write_all(&piece).unwrap();
            expected.extend_from_slice(&piece);
            if k % 700 == 0 {
                w.flush().unwrap();
            }
        }
        let over = vec![7u8; CHUNK_BYTES + 1];
        w.write_all(&over).unwrap();
        expected.extend_from_slice(&over);
        w.finish(None).unwrap();
        let chunks = frames(body);
        assert!(
            chunks
                .iter()
                .all(|c| !c.is_empty() && c.len() <= CHUNK_BYTES)
        );
        assert!(chunks.iter().filter(|c| c.len() == CHUNK_BYTES).count() >= 11);
        assert_eq!(chunks.concat(), expected);
    }

    #[test]
    fn a_writer_dropped_without_finishing_fails_the_body() {
        let (mut w, body) = channel();
        std::thread::spawn(move || {
            w.write_all(b"half").unwrap();
            w.send_pending().unwrap();
        })
        .join()
        .unwrap();
        assert!(runtime().block_on(body.collect()).is_err());
    }

    #[test]
    fn writes_never_wait_and_the_queue_says_when_it_is_backed_up() {
        let (mut w, body) = channel();
        let chunk = vec![0u8; CHUNK_BYTES];
        for _ in 0..IN_FLIGHT_CHUNKS - 1 {
            w.write_all(&chunk).unwrap();
        }
        assert!(!w.is_backed_up());
        w.write_all(&chunk).unwrap();
        assert!(w.is_backed_up());
        // Nobody reads, and still a write more returns at once.
        w.write_all(&chunk).unwrap();
        assert_eq!(w.queued_bytes(), (IN_FLIGHT_CHUNKS + 1) * CHUNK_BYTES);
        drop(body);
        assert!(w.is_closed());
        assert_eq!(w.write(b"x").unwrap_err().kind(), io::ErrorKind::BrokenPipe);
    }

    #[test]
    fn room_comes_when_the_client_reads_and_stalls_when_it_does_not() {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_time()
            .build()
            .unwrap();
        let (mut w, mut body) = channel();
        let chunk = vec![1u8; CHUNK_BYTES];
        for _ in 0..IN_FLIGHT_CHUNKS {
            w.write_all(&chunk).unwrap();
        }
        rt.block_on(async {
            let stall = Duration::from_millis(200);
            assert_eq!(w.room(stall).await, Room::Stalled);
            let waiter = {
                let w = w.clone();
                tokio::spawn(async move { w.room(Duration::from_secs(30)).await })
            };
            for _ in 0..=IN_FLIGHT_CHUNKS - RESUME_BYTES / CHUNK_BYTES {
                tokio::time::sleep(Duration::from_millis(5)).await;
                assert!(!waiter.is_finished() || w.queued_bytes() <= RESUME_BYTES);
                body.frame().await.unwrap().unwrap();
            }
            assert_eq!(waiter.await.unwrap(), Room::Ready);
            assert!(!w.is_backed_up());
        });
    }

    #[test]
    fn abort_ends_a_wait_for_room_and_fails_later_writes() {
        let rt = runtime();
        let (mut w, _body) = channel();
        w.write_all(&vec![0u8; IN_FLIGHT_BYTES]).unwrap();
        let aborter = w.aborter();
        rt.block_on(async {
            let wait = w.room(Duration::from_secs(30));
            let abort = async {
                tokio::time::sleep(Duration::from_millis(20)).await;
                aborter.abort();
                std::future::pending::<()>().await
            };
            tokio::select! {
                r = wait => assert_eq!(r, Room::Aborted),
                _ = abort => unreachable!(),
            }
        });
        assert_eq!(w.write(b"x").unwrap_err().kind(), io::ErrorKind::TimedOut);
    }
}
