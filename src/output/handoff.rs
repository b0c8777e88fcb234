//! Finished tiles handed to whichever worker is writing, so that a worker whose tile is
//! done goes back to tracing instead of waiting for the writer: the PNG's encoder and
//! the NPY records' writer each take one tile at a time, in a sink's lock.
//!
//! A worker queues its tile, then writes the queue if it can take the writer at once.
//! If another worker holds it, that one writes the tile too: whoever writes looks at
//! the queue again once it has let the writer go, so no tile queued meanwhile is left
//! behind. Past [`QUEUED_TILES`] queued tiles a worker waits for the writer, as
//! without the queue, so what waits is bounded (and charged: `super::footprint`).

use std::sync::{Mutex, TryLockError};

use super::rows::QUEUED_TILES;
use crate::render::{SinkClosed, Tile};

fn poisoned() -> SinkClosed {
    SinkClosed("a worker panicked while writing".into())
}

/// Tiles waiting for the worker that holds a sink's writer.
pub struct Handoff<T> {
    queue: Mutex<Vec<Tile<T>>>,
}

impl<T> Default for Handoff<T> {
    fn default() -> Self {
        Handoff {
            queue: Mutex::new(Vec::new()),
        }
    }
}

impl<T> Handoff<T> {
    /// Queues `tile` and writes what is queued into `writer`'s state with `write`,
    /// unless another worker holds it now (then that worker writes it) and at most
    /// [`QUEUED_TILES`] tiles wait.
    pub fn hand<S>(
        &self,
        writer: &Mutex<S>,
        tile: Tile<T>,
        write: impl FnMut(&mut S, Tile<T>) -> Result<(), SinkClosed>,
    ) -> Result<(), SinkClosed> {
        let queued = {
            let mut queue = self.queue.lock().map_err(|_| poisoned())?;
            queue.push(tile);
            queue.len()
        };
        self.drain(writer, queued > QUEUED_TILES, write)
    }

    /// Writes the queued tiles into `writer`'s state with `write`: waits for the
    /// writer when `wait` (as a sink does before it finishes), else leaves them to the
    /// worker writing now.
    pub fn drain<S>(
        &self,
        writer: &Mutex<S>,
        wait: bool,
        mut write: impl FnMut(&mut S, Tile<T>) -> Result<(), SinkClosed>,
    ) -> Result<(), SinkClosed> {
        let mut batch = Vec::new();
        loop {
            let mut state = if wait {
                writer.lock().map_err(|_| poisoned())?
            } else {
                match writer.try_lock() {
                    Ok(g) => g,
                    Err(TryLockError::WouldBlock) => return Ok(()),
                    Err(TryLockError::Poisoned(_)) => return Err(poisoned()),
                }
            };
            loop {
                std::mem::swap(&mut batch, &mut *self.queue.lock().map_err(|_| poisoned())?);
                if batch.is_empty() {
                    break;
                }
                for tile in batch.drain(..) {
                    write(&mut state, tile)?;
                }
            }
            drop(state);
            if self.queue.lock().map_err(|_| poisoned())?.is_empty() {
                return Ok(());
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::Rect;
    use std::sync::mpsc;
    use std::time::Duration;

    fn tile(x: u32) -> Tile<u32> {
        let rect = Rect {
            x,
            y: 0,
            width: 1,
            height: 1,
        };
        Tile::filled(rect, |u, _| u)
    }

    /// Appends a tile's pixel to the writer's state.
    fn append(written: &mut Vec<u32>, t: Tile<u32>) -> Result<(), SinkClosed> {
        written.extend(t.pixels);
        Ok(())
    }

    #[test]
    fn a_free_writer_writes_the_tile_at_once() {
        let (handoff, writer) = (Handoff::default(), Mutex::new(Vec::new()));
        handoff.hand(&writer, tile(7), append).unwrap();
        assert_eq!(*writer.lock().unwrap(), [7]);
    }

    /// While another worker holds the writer, a tile is queued and its worker goes
    /// on; the worker writing takes it on its next look at the queue.
    #[test]
    fn a_busy_writer_takes_the_tiles_handed_meanwhile() {
        let handoff = Handoff::default();
        let writer = Mutex::new(Vec::new());
        let busy = writer.lock().unwrap();
        std::thread::scope(|s| {
            s.spawn(|| {
                for x in 0..QUEUED_TILES as u32 {
                    handoff.hand(&writer, tile(x), append).unwrap();
                }
            });
        });
        assert!(
            busy.is_empty(),
            "a worker wrote while another held the writer"
        );
        drop(busy);
        handoff.drain(&writer, true, append).unwrap();
        assert_eq!(*writer.lock().unwrap(), [0, 1, 2, 3]);
    }

    /// Past `QUEUED_TILES` waiting tiles, the next worker waits for the writer, then
    /// writes them all in order.
    #[test]
    fn past_the_queue_a_worker_waits_for_the_writer() {
        let handoff = Handoff::default();
        let writer = Mutex::new(Vec::new());
        let busy = writer.lock().unwrap();
        let (done, finished) = mpsc::channel();
        std::thread::scope(|s| {
            s.spawn(|| {
                for x in 0..=QUEUED_TILES as u32 {
                    handoff.hand(&writer, tile(x), append).unwrap();
                }
                done.send(()).unwrap();
            });
            // The worker cannot finish while the writer is held.
            assert!(finished.recv_timeout(Duration::from_millis(200)).is_err());
            drop(busy);
        });
        assert_eq!(*writer.lock().unwrap(), [0, 1, 2, 3, 4]);
    }

    #[test]
    fn an_error_of_the_writer_reaches_the_worker_writing() {
        let (handoff, writer) = (Handoff::default(), Mutex::new(()));
        let failed = handoff.hand(&writer, tile(0), |_, _| Err(SinkClosed("full".into())));
        assert_eq!(failed.unwrap_err().0, "full");
    }
}
